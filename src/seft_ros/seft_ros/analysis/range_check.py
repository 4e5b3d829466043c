"""Before a run: will a rig's sensors or actuator reach their range? From the reference.

The analytical reference of the whole structure
(:func:`~seft_ros.analysis.reference.run_reference`: the declared specimens, linear or
yielding, and the prepared record; an OpenSees model's, OpenSees' own transient analysis of
it, which the report then takes back) is what a perfectly
compensated test reproduces; its peaks at each rig's degree of freedom are the test's, before
the test. Each is compared with what the rig can read or do (the rig contract):

============================  =======================================  =====================
channel                       peak of the reference                    against
============================  =======================================  =====================
``force``                     interface force (the load cell's)        ``force_range_N``
``displacement``              displacement relative to the ground      ``displacement_range_m``
``velocity``                  velocity                                 ``velocity_range_m_s``
``acceleration``              acceleration                             ``accelerometer_range_m_s2``
``actuator force``            interface force                          ``force_limit_N``
``actuator stroke``           displacement                             ``stroke_limit_m``
``actuator velocity``         velocity                                 the valve's capacity
``actuator valve command``    the valve command the force needs        ``valve_limit_V``
============================  =======================================  =====================

(the valve's capacity: ``actuator_velocity_limit_m_s``, or on the servohydraulic and
``actuator`` rigs the valve flow at ``valve_limit_V`` over the piston area, Merritt 1967 Ch.
5; the delay rig and a ``state_space`` model declare none unless it is set). A channel whose
peak exceeds its limit gives one line: the rig, the channel, the peak, the limit and the
largest amplitude that fits (the run's ``amplitude_N`` or ``scale_factor`` times limit / peak:
the reference is linear in the record; for a yielding member or an OpenSees model, which may
yield, that scaling is an estimate and the line says so).

The valve command a valve-driven rig needs for the reference's interface force ``f`` is
``u = P^-1 f`` on the rig's force-loop plant ``P``
(:func:`~seft_ros.core.force_loop.force_loop_plant`: seft's rig model or the
``plant_model`` of data, valve command to load-cell force with the specimen in the loop),
on the FFT of ``f``: the command of a test that follows its reference force exactly,
whatever the actuator (its flow through the piston's motion and the oil's compression, its
valve's dynamics, its I/O delay). Measured (session 26): within 0.5 % of the peak command of
``model`` runs on seft's rig (main job, alpha 0.5 and 1) and on a lab's ``state_space``
plant with a flexible reaction frame (alpha 0.5 and 1.5), whose velocity capacity the range
check did not know: that plant at 650 N saturated its valve in 33 samples and erred by
10-17 % where the accelerometer's channel allowed 658 N.

A test's own peaks sit above the reference's by its error and the force loop's ringing, so a
channel within a few per cent of its range may still clip: the run counts what did
(:mod:`seft_msgs_py.sensor_range`).
"""

from dataclasses import dataclass, field
import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from seft_msgs_py.calibration import valve_flow_gain_m3_per_s_V
from seft_msgs_py.errors import InputError, SeftError
from seft_msgs_py.parameters import identification_run
from seft_msgs_py.plant import schur_response
from seft_msgs_py.rig_contract import COMMAND_KINDS, command_kind
from seft_msgs_py.sensor_range import CHANNEL_UNITS, RANGE_PARAMETERS

__all__ = ['CHANNELS', 'ChannelPeak', 'RangeCheck', 'range_check', 'divergence_prediction',
           'actuator_velocity_limit_m_s', 'valve_command_needed']

#: The channels checked: name -> (the reference's signal, the thing whose limit it is).
CHANNELS = {
    'force': ('force_N', 'load cell range'),
    'displacement': ('displacement_m', 'displacement transducer range'),
    'velocity': ('velocity_m_s', 'velocity sensor range'),
    'acceleration': ('acceleration_m_s2', 'accelerometer range'),
    'actuator force': ('force_N', "actuator's force limit"),
    'actuator stroke': ('displacement_m', "actuator's stroke limit"),
    'actuator velocity': ('velocity_m_s', "actuator's velocity at the valve limit"),
    'actuator valve command': ('valve_command_V', "valve's command limit"),
}
_UNITS = {'force_N': 'N', 'displacement_m': 'm', 'velocity_m_s': 'm/s',
          'acceleration_m_s2': 'm/s^2', 'valve_command_V': 'V'}
#: |P| below this fraction of its largest value on the FFT grid is taken at it (a zero of
#: the force response on the unit circle; the force there is zero too) [-].
_RESPONSE_FLOOR = 1e-9


def actuator_velocity_limit_m_s(params) -> float | None:
    """Largest piston velocity the rig's actuator delivers [m/s] (None: not declared).

    ``actuator_velocity_limit_m_s`` when set (> 0); else, on the servohydraulic rig, the valve
    flow at full command over the piston area, ``v_max = k_q * valve_limit_V / A`` (no load
    pressure; Merritt 1967, Ch. 5), with k_q of the rig calibration (2.0 m/s at 10 V with Eq.
    3.1 in V/lbf, 0.45 m/s in V/N; :mod:`seft_msgs_py.calibration`); on the ``actuator``
    family's rigs the same with the member's k_q and A (its Monte-Carlo draw included: 0.6
    m/s at 10 V nominal); None on the delay rig and a lab's ``state_space`` model (its
    capacity is not in the model: declare it).
    """
    declared = float(params.get('actuator_velocity_limit_m_s', 0.0) or 0.0)
    if declared > 0:
        return declared
    if params.get('rig_model') == 'actuator':
        from seft_plant_sim.actuator import actuator_spec
        spec = actuator_spec(params)
        return (spec.valve_flow_gain_m3_per_s_V * float(params['valve_limit_V'])
                / spec.piston_area_m2)
    if params.get('rig_model') != 'servohydraulic':
        return None
    return (valve_flow_gain_m3_per_s_V(params) * float(params['valve_limit_V'])
            / float(params['piston_area_m2']))


def _limit(params, channel: str) -> float | None:
    """The limit of `channel` for a rig's parameters (None: unlimited or not declared)."""
    if channel in RANGE_PARAMETERS:
        value = float(params.get(RANGE_PARAMETERS[channel], 0.0) or 0.0)
    elif channel == 'actuator force':
        value = float(params.get('force_limit_N', 0.0) or 0.0)
    elif channel == 'actuator stroke':
        value = float(params.get('stroke_limit_m', 0.0) or 0.0)
    elif channel == 'actuator valve command':
        value = float(params.get('valve_limit_V', 0.0) or 0.0)
    else:
        value = actuator_velocity_limit_m_s(params) or 0.0
    return value if value > 0 else None


@dataclass(frozen=True)
class ChannelPeak:
    """One channel of one rig: the reference's peak against the rig's limit.

    Attributes
    ----------
    rig : str
        The rig ('' for the study's rig).
    channel : str
        One of :data:`CHANNELS`.
    peak : float
        The reference's peak ``max |y|`` in the channel's SI unit.
    limit : float or None
        The range or capacity (None: unlimited or not declared).
    unit : str
    """

    rig: str
    channel: str
    peak: float
    limit: float | None
    unit: str

    @property
    def exceeded(self) -> bool:
        """Whether the peak is beyond the limit."""
        return self.limit is not None and self.peak > self.limit

    @property
    def fraction(self) -> float | None:
        """peak / limit (None without a limit)."""
        return None if self.limit is None else self.peak / self.limit


@dataclass
class RangeCheck:
    """The pre-run range check of one run.

    Attributes
    ----------
    peaks : list of ChannelPeak
        Every rig's channels, in rig order, then :data:`CHANNELS` order.
    scale_name : str
        ``'amplitude_N'`` or ``'scale_factor'``: what scales the record.
    scale : float
        Its value (N or -).
    linear : bool
        Whether the reference is linear in the record (no yielding member).
    note : str
        Why there is no check ('' when there is one).
    """

    peaks: list = field(default_factory=list)
    scale_name: str = 'amplitude_N'
    scale: float = 0.0
    linear: bool = True
    note: str = ''

    @property
    def exceeded(self) -> list:
        """The channels whose peak exceeds their limit."""
        return [p for p in self.peaks if p.exceeded]

    def fits(self, peak: ChannelPeak) -> float:
        """The largest amplitude (``scale_name``'s value) at which `peak` stays within its
        limit: the run's, times limit / peak."""
        return self.scale * peak.limit / peak.peak

    def line(self, peak: ChannelPeak) -> str:
        """One line of an exceeded channel: the rig, the channel, the peak, the limit and the
        largest amplitude that fits."""
        who = peak.rig or 'rig'
        unit = 'N' if self.scale_name == 'amplitude_N' else ''
        fits = f'{self.scale_name} {self.fits(peak):.4g}{" " + unit if unit else ""}'
        if not self.linear:
            fits += ' (scaled linearly: a member that yields makes it an estimate)'
        what = CHANNELS[peak.channel][1]
        if peak.channel == 'actuator valve command':
            return (f'{who} {peak.channel}: the reference force needs {peak.peak:.4g} V of '
                    f"valve command through the force loop's plant model, beyond the {what} "
                    f'of {peak.limit:.4g} V (the valve saturates and the force loop opens); '
                    f'the largest amplitude that fits: {fits}')
        return (f'{who} {peak.channel}: the reference peaks at {peak.peak:.4g} {peak.unit}, '
                f'beyond the {what} of {peak.limit:.4g} {peak.unit}; the largest amplitude '
                f'that fits: {fits}')

    def lines(self) -> list[str]:
        """:meth:`line` of every exceeded channel."""
        return [self.line(p) for p in self.exceeded]

    def predicted(self, rig: str, channel: str) -> float | None:
        """The predicted peak of a rig's channel (None: not checked)."""
        return next((p.peak for p in self.peaks if p.rig == rig and p.channel == channel),
                    None)

    def as_dict(self) -> dict[str, Any]:
        """For ``summary.json``: ``{'lines': [...], 'note', 'scale_name', 'scale', 'linear',
        'rigs': {rig: {channel: {'peak', 'limit', 'unit', 'exceeded', 'fits'}}}}``."""
        rigs: dict[str, dict] = {}
        for p in self.peaks:
            rigs.setdefault(p.rig, {})[p.channel] = {
                'peak': p.peak, 'limit': p.limit, 'unit': p.unit, 'exceeded': p.exceeded,
                'fits': self.fits(p) if p.exceeded else None}
        return {'lines': self.lines(), 'note': self.note, 'scale_name': self.scale_name,
                'scale': self.scale, 'linear': self.linear, 'rigs': rigs}


def range_check(params, ground_acceleration_m_s2=None, *, valve: bool = True,
                program_reference: bool = True) -> RangeCheck:
    """The pre-run range check of a run (module notes).

    Parameters
    ----------
    params : mapping
        The run's resolved parameters.
    ground_acceleration_m_s2 : array_like (n,), optional
        The prepared record [m/s^2] (default:
        :func:`~seft_ros.core.ground_motion.prepared_record`).
    valve : bool
        Check the valve command too (:func:`valve_command_needed`; about 0.08 s a run on
        seft's rig, its model's sampling): the divergence guard, which reads the
        displacement and force, leaves it out.
    program_reference : bool
        Make a program's model's reference (OpenSees' analysis of it). False: such a run
        gets a ``note`` and no peaks: the divergence guard's prediction, made in the
        builder's process and in ``seft simulate`` alike (OpenSees' one domain per process
        holds the part the builder steps, which an analysis of the whole model would
        replace), so an OpenSees test has no divergence guard.

    Returns
    -------
    RangeCheck
        With ``note`` and no peaks for a run it cannot check: an identification run (an
        ``excitation``), or one whose reference cannot be made (an OpenSees model that
        does not build or converge: the reason). An OpenSees model's reference is OpenSees'
        own analysis of it (a few seconds for a frame; the report takes the same one back),
        not linear in the record (``linear`` False).

    Raises
    ------
    InputError, ParameterError
        Bad record or parameter (as the run would).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 2.1 (the reference);
    H. E. Merritt (1967), Hydraulic Control Systems, Ch. 5 (the valve's flow).
    """
    from seft_ros.analysis.reference import run_reference
    from seft_ros.core.ground_motion import prepared_record
    from seft_ros.core.structure import is_study, test_setup

    amplitude = float(params.get('amplitude_N', 0.0) or 0.0)
    check = RangeCheck(scale_name='amplitude_N' if amplitude > 0 else 'scale_factor',
                       scale=amplitude if amplitude > 0 else float(params.get('scale_factor',
                                                                              1.0)))
    if identification_run(params):
        check.note = 'an identification run (its excitation is not a record to check)'
        return check
    program = None
    if is_study(params):
        rigs = {'': params}
    else:
        setup = test_setup(params)
        program = setup.structure.model_kind
        if program is not None and not program_reference:
            check.note = (f'the computational part is an {program} model (its reference is '
                          "its program's own analysis, not made in this process)")
            return check
        rigs = {r: setup.rig_params[r] for r in setup.rig_names}
    # a program's model (OpenSees) may yield: its reference is its own analysis, made here
    # before the run (the report takes the same one back: opensees_reference keeps it); it
    # was left to the report, and a lab's OpenSees test had no range check before it, nor
    # could --strict refuse it (session 39)
    check.linear = program is None and all(p.get('specimen_model', 'linear') == 'linear'
                                           for p in rigs.values())
    if ground_acceleration_m_s2 is None:
        ground_acceleration_m_s2 = prepared_record(params).acceleration_m_s2
    try:
        reference = run_reference(SimpleNamespace(
            params=params, ground_acceleration_m_s2=ground_acceleration_m_s2))
    except SeftError as exc:
        check.note = f'no reference: {exc}'
        return check
    for rig, rp in rigs.items():
        response = reference.rig(rig)
        for channel, (signal, _) in CHANNELS.items():
            if signal == 'valve_command_V':
                values = valve_command_needed(rp, response.force_N) if valve else None
                if values is None:
                    continue
            else:
                values = getattr(response, signal)
            peak = float(abs(values).max()) if values.shape[0] else 0.0
            if not math.isfinite(peak):
                continue
            unit = CHANNEL_UNITS.get(channel, _UNITS[signal])
            check.peaks.append(ChannelPeak(rig, channel, peak, _limit(rp, channel), unit))
    return check


def valve_command_needed(params, force_N):
    """The valve command a rig needs to apply `force_N` (module notes), or None.

    ``u = IFFT(FFT(f) / P)`` on ``2^ceil(log2(2 n))`` points, ``P`` the force response of
    the rig's force-loop plant (valve command to load-cell force, the specimen in the loop)
    at the FFT's frequencies (where ``P`` is infinite, the mean of an actuator that
    integrates its flow without leakage, the command is zero).

    Parameters
    ----------
    params : mapping
        The rig's resolved parameters.
    force_N : array_like, shape (n,)
        The interface force to apply [N] (the reference's, at the rig's sample period).

    Returns
    -------
    ndarray, shape (n,) or None
        [V]; None for a rig without a valve (the delay rig) or without a linear model of
        its force loop.
    """
    if command_kind(params) != COMMAND_KINDS[0]:
        return None
    from seft_ros.core.force_loop import force_loop_plant
    try:
        plant = force_loop_plant(params)
    except SeftError:
        return None
    f = np.asarray(force_N, dtype=float)
    n = f.shape[0]
    if n < 2:
        return np.zeros(n)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    z = np.exp(2j * np.pi * np.fft.rfftfreq(nfft, plant.dt) * plant.dt)
    # c (zI - A)^-1 b at every frequency, from one Schur form (an order-n solve per
    # frequency costs 30 times more on 8,000 frequencies)
    with np.errstate(divide='ignore', invalid='ignore'):
        response, _ = schur_response(plant.a, plant.b[:, 0], plant.row('force_N'), z)
        magnitude = np.abs(response)
        finite = np.isfinite(magnitude)
        floor = _RESPONSE_FLOOR * float(magnitude[finite].max())
        response = np.where(magnitude < floor, floor, response)
        command = np.where(finite, np.fft.rfft(f, nfft) / response, 0.0)
    return np.fft.irfft(command, nfft)[:n]


def divergence_prediction(params) -> tuple[RangeCheck | None, str]:
    """The range check a node's divergence guard reads, or None and why.

    The reference-force builder node reads the record itself for it
    (:class:`~seft_ros.core.monitor.DivergenceGuard`). On a host that cannot read the record
    (a run over several hosts whose record file lives on the ground-motion publisher's) the
    guard is off for the run, which goes on, and the node says so.

    Parameters
    ----------
    params : mapping
        The node's resolved parameters.

    Returns
    -------
    check : RangeCheck or None
        :func:`range_check`; None where the record cannot be read here.
    note : str
        Empty, or the one-line warning that the guard is off and why.

    Raises
    ------
    ParameterError
        Bad parameters (as the run would).
    """
    try:
        return range_check(params, valve=False, program_reference=False), ''
    except InputError as exc:
        return None, (f'divergence guard off: the record cannot be read on this host ({exc}); '
                      'the run goes on without it (the instability monitor and the limits '
                      'still watch it)')
