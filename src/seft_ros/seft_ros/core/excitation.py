"""Excitation signals of identification runs, and where they enter the loop (no rclpy).

An identification run (parameter ``excitation`` other than ``'none'``) plays a known
broadband signal instead of an earthquake record, so that ``seft identify`` can measure the
rig's frequency responses from its bag:

``excitation_input: reference_force`` (closed loop)
    The excitation force ``e[k]`` [N] takes the place of the ground-motion term of the
    reference force: :func:`excitation_record` returns the ground acceleration
    ``xg''[k] = -e[k]/((1 + alpha) m)``, which the ground-motion publisher publishes and
    :func:`seft_ros.core.experiment.simulate` plays like any record, so that
    ``f_r[k] = e[k] - alpha m a_hat[k]`` (``e[k]`` itself at alpha = 0 with predictor
    ``none``). The bag, the reference analysis and the report stay what they are for a test.
``excitation_input: valve_command`` (open loop, servohydraulic rig)
    The force controller is bypassed: :func:`make_valve_controller` returns an
    :class:`OpenLoopValve` that outputs ``e[k]`` [V] with the controller's call signature,
    in the force servo controller node and in ``simulate`` alike; the ground motion is 0.

The signal depends only on the parameters (seeded), so every node that generates it gets the
same samples, bit for bit.

**A structure's identification run tests each rig alone** (:func:`rigs_alone`): the
computational part is switched off (no interface forces, no rigid computational mass, no
computational DOFs), so no coupling can drive a rig and nothing but the excitation does; the
rigs are excited together, each in its namespace with its own parameters (its rig, specimen,
force controller), all by the same excitation ``e[k]``: with the computational part off they
share no force, and each rig is identified from its own measured force and motion alone.
Every rig's ground-motion term is ``e[k]`` in N whatever its specimen mass (the structure's
influence vector is scaled for it), as the study's rig at alpha = 0.
"""

import math
from types import MappingProxyType

import numpy as np
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import valve_commanded
from seft_ros.core.controller import ControllerDesign, ForceServoController
from seft_ros.core.structure import Link, Structure, test_setup

__all__ = ['EXCITATIONS', 'EXCITATION_INPUTS', 'DEFAULT_DURATION_S', 'DEFAULT_AMPLITUDE',
           'DEFAULT_BAND_FRACTION', 'excitation_band_hz',
           'STEPPED_SINE_STEPS', 'FADE_S', 'excitation_signal', 'excitation_record',
           'open_loop', 'OpenLoopValve', 'make_valve_controller', 'rigs_alone']

#: Excitation signals (parameter ``excitation``).
EXCITATIONS = ('none', 'noise', 'chirp', 'stepped_sine')
#: Where the excitation enters (parameter ``excitation_input``).
EXCITATION_INPUTS = ('reference_force', 'valve_command')
#: Length of an excitation when ``duration_s`` is 0 [s].
DEFAULT_DURATION_S = 20.0
#: Amplitude when ``excitation_amplitude`` is 0, per input: N on the reference force, V on
#: the valve (0.05 V of noise gives about 300 N at 1 Hz on the default rig, whose valve to
#: force gain is 27.8 kN/V at DC).
DEFAULT_AMPLITUDE = {'reference_force': 100.0, 'valve_command': 0.05}
#: The upper band edge when ``excitation_band_hz`` is 0, a fraction of the Nyquist frequency:
#: 150 Hz at dt = 2 ms. An absolute 150 Hz left 150-500 Hz unexcited at dt = 1 ms, and the
#: identification of seft_plant_sim's second-order-valve actuator fitted an order-10 model to
#: 0.1 % whose design closed no loop (with 300 Hz: order 5, exact, its test 0.04 %).
DEFAULT_BAND_FRACTION = 0.6
#: Number of frequencies of a stepped sine.
STEPPED_SINE_STEPS = 20
#: Raised-cosine fade in and out of noise and chirp [s] (no step at the start or the end).
FADE_S = 0.2


def _get(params, name):
    from seft_msgs_py.parameters import spec
    return params[name] if name in params else spec(name).default


def excitation_band_hz(params) -> tuple[float, float]:
    """The excitation's band ``(low, high)`` [Hz]: ``excitation_band_low_hz`` and
    ``excitation_band_hz``, whose 0 is :data:`DEFAULT_BAND_FRACTION` of the Nyquist frequency
    ``1/(2 dt)`` (absent names: the schema's defaults; ``dt`` required). Not checked here
    (:func:`excitation_signal` checks them)."""
    hi = float(_get(params, 'excitation_band_hz'))
    if hi == 0.0:
        hi = DEFAULT_BAND_FRACTION * (0.5 / float(params['dt']))
    return float(_get(params, 'excitation_band_low_hz')), hi


def _settings(params):
    """``(kind, input, amplitude, lo, hi, n, dt, seed)`` checked across parameters."""
    kind = _get(params, 'excitation')
    where = _get(params, 'excitation_input')
    if kind not in EXCITATIONS:
        raise ParameterError(f'parameter excitation={kind!r}: expected one of '
                             + ', '.join(repr(e) for e in EXCITATIONS))
    if where not in EXCITATION_INPUTS:
        raise ParameterError(f'parameter excitation_input={where!r}: expected one of '
                             + ', '.join(repr(e) for e in EXCITATION_INPUTS))
    dt = float(params['dt'])
    amplitude = float(_get(params, 'excitation_amplitude')) or DEFAULT_AMPLITUDE[where]
    lo, hi = excitation_band_hz(params)
    nyquist = 0.5 / dt
    if not hi < nyquist:
        raise ParameterError(f'parameter excitation_band_hz={hi!r}: expected below the Nyquist '
                             f'frequency {nyquist:g} Hz (dt={dt:g} s)')
    if not 0 < lo < hi:
        raise ParameterError(f'parameter excitation_band_low_hz={lo!r}: expected > 0 and below '
                             f'excitation_band_hz={hi!r}')
    duration = float(_get(params, 'duration_s')) or DEFAULT_DURATION_S
    n = int(round(duration / dt))
    if n * dt * lo < 1.0:
        raise ParameterError(f'parameter duration_s={duration!r}: expected at least one period '
                             f'of excitation_band_low_hz={lo!r} ({1 / lo:g} s)')
    return kind, where, amplitude, lo, hi, n, dt, int(_get(params, 'excitation_seed'))


def _fade(n: int, dt: float) -> np.ndarray:
    m = min(n // 4, int(round(FADE_S / dt)))
    w = np.ones(n)
    if m > 0:
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
        w[:m] = ramp
        w[n - m:] = ramp[::-1]
    return w


def excitation_signal(params) -> np.ndarray:
    """The excitation ``e[k]`` of a run, one sample per control step.

    Parameters
    ----------
    params : mapping
        ``excitation``, ``excitation_input``, ``excitation_amplitude``,
        ``excitation_band_low_hz``, ``excitation_band_hz``, ``excitation_seed``,
        ``duration_s`` and ``dt`` (absent names: the schema's defaults but ``dt``).

    Returns
    -------
    ndarray, shape (n,)
        ``n = round(duration_s/dt)`` samples (``duration_s`` 0: :data:`DEFAULT_DURATION_S`)
        in N (``reference_force``) or V (``valve_command``); all zeros for ``'none'``.

        - ``noise``: Gaussian white noise (``numpy.random.default_rng(excitation_seed)``),
          band-limited to [lo, hi] by zeroing its FFT outside the band, scaled to the
          standard deviation ``excitation_amplitude``, faded in and out over :data:`FADE_S`.
        - ``chirp``: ``scipy.signal.chirp`` from lo to hi over the run, logarithmic (equal
          time per octave), peak ``excitation_amplitude``, faded likewise.
        - ``stepped_sine``: :data:`STEPPED_SINE_STEPS` log-spaced frequencies in the band,
          each held for ``n/STEPPED_SINE_STEPS`` samples and rounded to whole cycles of it
          (each segment starts and ends at zero), peak ``excitation_amplitude``.

    Raises
    ------
    ParameterError
        An unknown name, a band not within (0, Nyquist), or a run shorter than one period of
        the lower band edge (the message names the parameter).
    """
    kind, _, amplitude, lo, hi, n, dt, seed = _settings(params)
    if kind == 'none':
        return np.zeros(n)
    t = np.arange(n) * dt
    if kind == 'noise':
        white = np.random.default_rng(seed).standard_normal(n)
        spectrum = np.fft.rfft(white)
        f = np.fft.rfftfreq(n, dt)
        spectrum[(f < lo) | (f > hi)] = 0.0
        e = np.fft.irfft(spectrum, n)
        e *= amplitude / e.std()
        return e * _fade(n, dt)
    if kind == 'chirp':
        e = amplitude * signal.chirp(t, f0=lo, t1=t[-1], f1=hi, method='logarithmic',
                                     phi=-90.0)
        return e * _fade(n, dt)
    freqs = np.geomspace(lo, hi, STEPPED_SINE_STEPS)
    seg = n // STEPPED_SINE_STEPS
    e = np.zeros(n)
    for i, f in enumerate(freqs):
        cycles = max(1, int(math.floor(f * seg * dt)))
        fi = cycles / (seg * dt)            # whole cycles in the segment
        e[i * seg:(i + 1) * seg] = amplitude * np.sin(2 * np.pi * fi * t[:seg])
    return e


def open_loop(params) -> bool:
    """True when the run drives the valve directly (an excitation on ``valve_command``)."""
    return (_get(params, 'excitation') != 'none'
            and _get(params, 'excitation_input') == 'valve_command')


def excitation_record(params):
    """The ground motion of an identification run, as a prepared record.

    Parameters
    ----------
    params : mapping
        As :func:`excitation_signal`, with ``alpha`` and ``mass_kg``.

    Returns
    -------
    GroundMotion
        At ``dt``: ``-e/((1 + alpha) m)`` [m/s^2] (closed loop; then the ground-motion term
        of the reference force is ``e``), or zeros (open loop); named after the excitation.

    Raises
    ------
    ParameterError
        As :func:`excitation_signal`.
    """
    from seft_ros.core.ground_motion import GroundMotion
    kind, where, amplitude, lo, hi, n, dt, seed = _settings(params)
    if where == 'valve_command' and not valve_commanded(params):
        raise ParameterError("parameter excitation_input='valve_command': expected a rig_model "
                             "driven by a valve, e.g. 'servohydraulic' (the delay rig has no "
                             'valve)')
    e = excitation_signal(params)
    unit = 'V' if where == 'valve_command' else 'N'
    name = f'excitation-{kind}({amplitude:g} {unit}, {lo:g}-{hi:g} Hz' + (
        f', seed={seed})' if kind == 'noise' else ')')
    if where == 'valve_command':
        return GroundMotion(dt, np.zeros(n), name, 'excitation')
    gain = (1.0 + float(params['alpha'])) * float(params['mass_kg'])
    return GroundMotion(dt, -e / gain, name, 'excitation')


class OpenLoopValve:
    """The valve driven by the excitation: the force controller bypassed (open loop).

    Has the call signature of :class:`~seft_ros.core.controller.ForceServoController`: its
    :meth:`step` is called once per step, in order, and returns ``sat(e[k])`` [V] for the
    k-th call (0 after the excitation's end), whatever the forces.

    Parameters
    ----------
    excitation_V : array_like, shape (n,)
        ``e[k]`` [V].
    dt : float > 0
        Control period [s].
    valve_limit_V : float > 0
        Saturation [V].

    Attributes
    ----------
    saturated : bool
        The last command was clipped.
    design : ControllerDesign
        Its description (``method``), as the force controller's.
    """

    def __init__(self, excitation_V, dt: float, valve_limit_V: float):
        self._e = [float(v) for v in np.asarray(excitation_V, dtype=float)]
        self.dt = float(dt)
        self.valve_limit_V = float(valve_limit_V)
        self.design = ControllerDesign((), (), self.dt, 'open loop: the valve driven by the '
                                       'excitation (force controller bypassed)')
        self.saturated = False
        self._k = 0

    uses_motion = False

    def reset(self) -> None:
        """Back to the first sample."""
        self._k = 0
        self.saturated = False

    def step(self, reference_force_N: float = 0.0, measured_force_N: float = 0.0,
             velocity_m_s: float = 0.0, acceleration_m_s2: float = 0.0,
             displacement_m: float = 0.0) -> float:
        """Return the valve command [V] of the next step (the forces are ignored)."""
        k = self._k
        self._k = k + 1
        u = self._e[k] if k < len(self._e) else 0.0
        lim = self.valve_limit_V
        self.saturated = u > lim or u < -lim
        return lim if u > lim else -lim if u < -lim else u


def make_valve_controller(params):
    """The valve's command law of a run: the force controller, or the open-loop excitation.

    The force servo controller node and :func:`seft_ros.core.experiment.simulate` both build
    it here.

    Returns
    -------
    ForceServoController or OpenLoopValve

    Raises
    ------
    ParameterError
        As :meth:`~seft_ros.core.controller.ForceServoController.from_parameters` or
        :func:`excitation_signal`; or an
        open-loop excitation on the ``delay`` rig (it has no valve).
    """
    if not open_loop(params):
        return ForceServoController.from_parameters(params)
    if not valve_commanded(params):
        raise ParameterError("parameter excitation_input='valve_command': expected a rig_model "
                             "driven by a valve, e.g. 'servohydraulic' (the delay rig has no "
                             'valve)')
    return OpenLoopValve(excitation_signal(params), float(params['dt']),
                         float(params['valve_limit_V']))


def rigs_alone(params) -> dict:
    """The parameters of a structure's identification run: each rig alone (module notes).

    Parameters
    ----------
    params : mapping
        Resolved parameters of a run with a ``structure`` (the JSON of
        :class:`~seft_ros.core.structure.Structure`) and ``excitation`` other than ``'none'``.

    Returns
    -------
    dict
        `params` with the structure replaced by the structure of the rigs alone: one DOF per
        rig (the physical DOFs of the structure, their names and rigs kept, with their rig
        sections), ``M = diag(m_p)``, ``C = diag(c_p)``, ``K = diag(k_p)`` of the rigs'
        specimens, nothing computational, influence ``iota_p = m / m_p`` (``m`` the run's
        ``mass_kg``, with which :func:`excitation_record` scales the ground motion, so that
        every rig's ground-motion term ``-m_p iota_p xg''`` is the excitation ``e`` [N]).

    Raises
    ------
    ParameterError
        The structure disagrees with a rig's parameters (as the test would), or the run sets
        ``alpha`` (a structure's computational mass is the structure's).

    Notes
    -----
    The run then needs no stability margin from the coupling (there is none): each rig's
    loop is its force loop at alpha = 0, the loop a lab checks its rig with. Its bag is a
    structure bag (each rig in its namespace), which ``seft identify`` identifies rig by rig.
    """
    if float(params.get('alpha', 0.0)) != 0.0:
        raise ParameterError(f'parameter alpha={params["alpha"]!r}: with a structure the '
                             "computational mass is the structure's; leave alpha at 0")
    sub = test_setup(params).substructures
    s = sub.structure
    dofs = tuple(s.dofs[i] for i in s.physical_index)
    m = np.asarray(sub.specimen_mass_kg, dtype=float)
    alone = Structure(
        dofs, np.diag(m), np.diag(np.asarray(sub.specimen_damping_N_s_per_m, dtype=float)),
        np.diag(np.asarray(sub.specimen_stiffness_N_per_m, dtype=float)),
        float(params['mass_kg']) / m, MappingProxyType({d: s.physical[d] for d in dofs}),
        s.rigs, tuple(Link(j, None, f'{d}-ground') for j, d in enumerate(dofs)))
    return dict(params, structure=alone.to_json())
