"""Online guards of a run: the instability monitor (a growing high-frequency oscillation of
the measured force), the divergence guard (a rig's measured motion or force far beyond the
pre-run prediction) and the specimen check."""

import math

import numpy as np
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import identification_run
from seft_ros.core.controller import DiscreteFilter

__all__ = ['InstabilityMonitor', 'open_loop_identification', 'monitor_cutoff_hz', 'SpecimenCheck',
           'SPECIMEN_CHECK_ACTIONS', 'DEFAULT_SPECIMEN_TOLERANCE', 'DivergenceGuard',
           'DIVERGENCE_NOISE_SIGMAS', 'SPECIMEN_UNJUDGED']

#: The band split of ``monitor_cutoff_hz`` 0 where ``RESPONSE_BAND_FACTOR`` times the
#: reference structure's natural frequency is lower: the study's calibration (class notes) [Hz].
BASE_CUTOFF_HZ = 25.0
#: ``monitor_cutoff_hz`` 0 puts the band split at least this many times the reference
#: structure's natural frequency above it: a 2nd-order high pass passes a quarter of the
#: response's amplitude there. Measured on the family's 50 Hz, 0.5 % specimen
#: (``valve_2nd_order``, the reference at 35 Hz at alpha 1) with the 25 Hz split: a healthy
#: run aborted at 1.9 s ("high-frequency oscillation") that completed at 0.8 % NRMS without
#: the monitor [-].
RESPONSE_BAND_FACTOR = 2.0
# What the split cannot see: a loop whose own response mode loses its damping grows at the
# reference structure's frequency, in the low band with the response. Measured on the
# family's nonlinear orifice_flow actuator with the 50 Hz, 0.5 % specimen at alpha 1.5 (the
# reference at 31.6 Hz): the error grows at 31-33 Hz to 17 times the reference's RMS by 9 s;
# the 25 Hz split tripped on it at 1.6 s (and on the healthy linear members alike), the
# derived 63 Hz one does not (its ratio 0.25): the run completes, its NRMS x 247-265 %.
# Such growth is the DivergenceGuard's: the rig's measured motion against its predicted peak.


def reference_frequency_hz(params) -> float:
    """The natural frequency [Hz] of the rig's reference structure as the one-DOF study's test
    has it: ``sqrt(k / ((1 + alpha) m)) / (2 pi)`` of the declared specimen (paper Eq. 2.1; in
    a structure the rig's own ``alpha``, 0 where none); 0 without a positive mass and
    stiffness."""
    m = float(params.get('mass_kg', 0.0) or 0.0)
    k = float(params.get('stiffness_N_per_m', 0.0) or 0.0)
    alpha = float(params.get('alpha', 0.0) or 0.0)
    if not (m > 0 and k > 0 and alpha > -1):
        return 0.0
    return math.sqrt(k / ((1.0 + alpha) * m)) / (2.0 * math.pi)


def monitor_cutoff_hz(params) -> float:
    """The instability monitor's band split [Hz] of a rig's resolved parameters.

    ``monitor_cutoff_hz`` where set (> 0); 0 (the default) derives it: ``BASE_CUTOFF_HZ``
    (25 Hz), or ``RESPONSE_BAND_FACTOR`` (2) times the reference structure's natural frequency
    (``reference_frequency_hz``) where that is higher, so that the earthquake response of
    a stiff specimen stays in the low band (at most 0.4 of the sampling rate).

    Raises
    ------
    ParameterError
        A set cut-off below the reference structure's natural frequency: the monitor would
        take the healthy response for the loop's unstable mode and abort the run.
    """
    dt = float(params['dt'])
    f_ref = reference_frequency_hz(params)
    set_hz = float(params.get('monitor_cutoff_hz', 0.0))
    if set_hz > 0:
        if f_ref > 0 and set_hz < f_ref and not open_loop_identification(params):
            raise ParameterError(
                f"parameter monitor_cutoff_hz={set_hz:g}: below the reference structure's "
                f'natural frequency {f_ref:.3g} Hz (the response would trip the instability '
                f'monitor); expected at least {RESPONSE_BAND_FACTOR * f_ref:.3g} Hz, or 0 to '
                'derive it')
        return set_hz
    return max(BASE_CUTOFF_HZ, min(RESPONSE_BAND_FACTOR * f_ref, 0.4 / dt))


def open_loop_identification(params) -> bool:
    """Whether `params` describe an open-loop identification run.

    Parameters
    ----------
    params : mapping
        Run parameters (``excitation`` and ``excitation_input`` default to ``'none'`` and
        ``'reference_force'`` when absent).

    Returns
    -------
    bool
        True when an excitation plays on the valve (``excitation_input: valve_command``):
        the force controller is bypassed and the reference force drives nothing.
    """
    return (identification_run(params)
            and params.get('excitation_input', 'reference_force') == 'valve_command')


class InstabilityMonitor:
    """Detects the high-frequency oscillation of an unstable substructure EFT loop.

    The measured force is split by 2nd-order Butterworth filters (``scipy.signal.butter``)
    at ``cutoff_hz`` into a high band ``f_hf`` (the loop's unstable mode: about 37 Hz on the
    calibrated servohydraulic rig, near Nyquist on the delay rig) and a low band ``f_lf``
    (the earthquake response). Their running RMS values ``r_hf``, ``r_lf`` are exponential
    moving averages of the squares with time constant ``window_s``. The monitor trips when

        r_hf > threshold * (r_lf + 0.05 * F_g + floor_N)

    where ``F_g = (1 + alpha) m max|xg''|`` is the largest ground-motion force seen so far and
    ``floor_N`` an absolute floor; both keep sensor noise from tripping it at the quiet start
    of a record (white load-cell noise puts about 90 % of its power above 25 Hz).

    Calibration (``benchmarks/monitor_margin.py``): over the synthetic default, the Kobe
    KJM000/KJM090 and El Centro records, on both rigs, alpha = 0-1.2 (stable), the largest
    ratio ``r_hf / (r_lf + 0.05 F_g)`` of a stable run was 0.66; every unstable run reached
    1.5 or more. The default threshold 1.0 sits between them. With the later defaults (Eq.
    3.1 read in V/lbf, ground preview on) the margins narrowed: stable runs reach 0.69-0.80,
    unstable ones 1.44 or more (``tests/seft_ros/core/test_monitor.py``).

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    cutoff_hz : float > 0
        Band split [Hz]; must be below the Nyquist frequency.
    window_s : float > 0
        Time constant of the running RMS [s].
    threshold : float >= 0
        Trip ratio (0 disables the monitor).
    floor_N : float >= 0
        Absolute floor of the comparison [N] (default 50 N: ten times the noise of a
        typical 22 kN load cell).

    Raises
    ------
    ParameterError
        If a value is out of range.
    """

    def __init__(self, dt: float, cutoff_hz: float = 25.0, window_s: float = 0.2,
                 threshold: float = 1.0, floor_N: float = 50.0):
        if not cutoff_hz > 0:
            raise ParameterError(f'parameter monitor_cutoff_hz={cutoff_hz!r}: expected > 0')
        if not cutoff_hz < 0.5 / dt and cutoff_hz != BASE_CUTOFF_HZ:
            raise ParameterError(f'parameter monitor_cutoff_hz={cutoff_hz!r}: expected > 0 '
                                 f'and below the Nyquist frequency {0.5 / dt:g} Hz')
        if not cutoff_hz < 0.5 / dt:          # the derived cut-off: dt is what the user set
            raise ParameterError(f'parameter dt={dt!r}: the sample period is too long for the '
                                 f'instability monitor, whose band split monitor_cutoff_hz='
                                 f'{cutoff_hz:g} Hz must lie below the Nyquist frequency '
                                 f'1/(2 dt) = {0.5 / dt:g} Hz; expected dt < '
                                 f'{0.5 / cutoff_hz:g} s')
        if not window_s > 0:
            raise ParameterError(f'parameter monitor_window_s={window_s!r}: expected > 0')
        if not threshold >= 0:
            raise ParameterError(f'parameter monitor_threshold={threshold!r}: expected >= 0')
        if not floor_N >= 0:
            raise ParameterError(f'parameter monitor_floor_N={floor_N!r}: expected >= 0')
        self.floor_N = float(floor_N)
        self.dt = float(dt)
        self.threshold = float(threshold)
        hp = DiscreteFilter(*signal.butter(2, cutoff_hz, 'highpass', fs=1.0 / dt))
        lp = DiscreteFilter(*signal.butter(2, cutoff_hz, 'lowpass', fs=1.0 / dt))
        beta = float(np.exp(-dt / window_s))
        # what update steps: the two biquads' (b0, b1, b2, a1, a2), the high pass's then the
        # low pass's, and the running mean squares' weights (beta, 1 - beta); and its state:
        # the biquads' (z0, z1) in the same order, then the two mean squares
        self._coefficients = hp._biquad + lp._biquad + (beta, 1.0 - beta)
        self._state = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self.ground_force_scale_N = 0.0
        self.ratio = 0.0

    @classmethod
    def from_parameters(cls, params) -> 'InstabilityMonitor':
        """Build from ``dt`` and the ``monitor_*`` parameters.

        In an open-loop identification run (``excitation`` other than ``'none'`` with
        ``excitation_input: valve_command``) the monitor is built disarmed (threshold 0): the
        loop it guards (measured acceleration, reference force, force controller) is open
        there, since the valve plays the excitation and the reference force drives nothing,
        so no oscillation can grow through it; and the broadband valve excitation puts force
        above the cut-off by design (a healthy default rig reaches 4-10 times the threshold
        with 0.05-0.5 V of noise). The run's amplitude limits guard it instead: the rig's
        ``stroke_limit_m`` and ``force_limit_N``. A closed-loop identification run
        (``excitation_input: reference_force``) keeps the monitor: the excitation is the
        ground-motion term of the reference force, so the comparison scales with it (healthy
        runs up to 0.68 of the threshold at alpha 0-1, an unstable alpha = 1.5 trips).

        Parameters
        ----------
        params : mapping
            Resolved parameters: ``dt``, ``monitor_cutoff_hz`` (0: :func:`monitor_cutoff_hz`
            derives it from the specimen, ``mass_kg``, ``stiffness_N_per_m`` and ``alpha``),
            ``monitor_window_s``, ``monitor_threshold``, ``monitor_floor_N`` and, if
            present, ``excitation`` and ``excitation_input``.

        Returns
        -------
        InstabilityMonitor

        Raises
        ------
        ParameterError
            A value out of range, or a set ``monitor_cutoff_hz`` below the reference
            structure's natural frequency (the message names the parameter).
        """
        threshold = float(params['monitor_threshold'])
        if open_loop_identification(params):
            threshold = 0.0
        return cls(float(params['dt']), monitor_cutoff_hz(params),
                   float(params['monitor_window_s']), threshold,
                   float(params['monitor_floor_N']))

    def update(self, measured_force_N: float, ground_force_N: float,
               time_s: float) -> str | None:
        """Add one sample; return a one-line reason when the oscillation is detected.

        Parameters
        ----------
        measured_force_N : float
            Load-cell force of the sample [N].
        ground_force_N : float
            Ground-motion part of the reference force, ``-(1+alpha) m xg''`` [N].
        time_s : float
            Sample time [s], for the message.
        """
        x = measured_force_N
        # the two Butterworth sections (DiscreteFilter.step of a biquad, written out) and
        # their running mean squares, the state read and written once
        b0, b1, b2, a1, a2, c0, c1, c2, d1, d2, b, c = self._coefficients
        z0, z1, z2, z3, ms_hf, ms_lf = self._state
        hf = b0 * x + z0
        lf = c0 * x + z2
        ms_hf = b * ms_hf + c * hf * hf
        ms_lf = b * ms_lf + c * lf * lf
        self._state = (b1 * x - a1 * hf + z1, b2 * x - a2 * hf,
                       c1 * x - d1 * lf + z3, c2 * x - d2 * lf, ms_hf, ms_lf)
        scale = abs(ground_force_N)
        if scale > self.ground_force_scale_N:
            self.ground_force_scale_N = scale
        floor = math.sqrt(ms_lf) + 0.05 * self.ground_force_scale_N + self.floor_N
        ratio = self.ratio = math.sqrt(ms_hf) / floor if floor > 0 else 0.0
        if ratio > self.threshold > 0:
            return (f'unstable at t={time_s:.3f} s: high-frequency oscillation of the measured '
                    f'force, RMS above the cut-off {self.ratio:.2f} x the response band '
                    f'(threshold {self.threshold:g})')
        return None


#: The divergence guard's allowance for sensor noise: this many standard deviations of the
#: channel's declared noise (``noise_displacement_m``, ``noise_force_N``) are added to the
#: factor times the predicted peak (a Gaussian sample beyond 6 sigma: 2e-9) [-].
DIVERGENCE_NOISE_SIGMAS = 6.0
#: The channels the divergence guard watches: (the channel of the pre-run check, the
#: measurement's field, its noise parameter, its unit).
_DIVERGENCE_CHANNELS = (('displacement', 'displacement_m', 'noise_displacement_m', 'm'),
                        ('force', 'force_N', 'noise_force_N', 'N'))


class DivergenceGuard:
    """Ends a run whose rig's measured displacement or force diverges from the prediction.

    The pre-run range check (:func:`~seft_ros.analysis.range_check.range_check`) gives each
    rig's peaks of the analytical reference, what a compensated test reproduces. The guard
    trips at the first sample where a watched channel's measured magnitude exceeds::

        |y| > factor * peak_predicted + DIVERGENCE_NOISE_SIGMAS * sigma_noise + floor

    (``factor``: ``divergence_factor``, default 3; ``sigma_noise``: the rig's declared noise
    of the channel, 0 where none; ``floor``: the monitor's ``monitor_floor_N`` for the force,
    and the displacement it gives the specimen, ``monitor_floor_N / k``, for the
    displacement: a record that predicts next to nothing, such as a free response after a
    pulse, 1e-6 N, is not judged on round-off). It sees what the
    :class:`InstabilityMonitor` cannot: a loop whose own response mode loses its damping
    grows at the reference structure's frequency, inside the monitor's low band (session
    24: a 45 Hz specimen with the valve's gain 1 % above the identified model's reached 36
    times the predicted displacement and completed, 5894 % NRMS x).

    Calibration (``docs/design/safety.md``): the ratio measured peak / predicted peak over
    the whole record, of every completed run of the shipped configurations and of healthy
    runs with predictor errors, was at most 1.47 (``ats`` at alpha 2, 54 % NRMS x), 1.18
    for the rest; the diverging runs passed 3 within 1.9-5.1 s, at 2 0.1-0.9 s earlier.

    A yielding specimen (``specimen_model`` other than ``linear``) is watched on its force
    only: its drift may exceed the declared member's in a healthy test (a real member softer
    or degrading more), its force is bounded by its strength.

    Parameters
    ----------
    limits : dict
        ``{measurement field: (limit, predicted peak, channel name, unit)}``: the trip level
        and the predicted peak in SI units (``displacement_m`` [m], ``force_N`` [N]).
    factor : float > 0
        ``divergence_factor`` [-], for the message.

    Raises
    ------
    ParameterError
        A limit that is not positive and finite.
    """

    def __init__(self, limits: dict, factor: float):
        for field_name, (limit, *_rest) in limits.items():
            if not (math.isfinite(limit) and limit > 0):
                raise ParameterError(f'divergence guard: the limit of {field_name} is '
                                     f'{limit!r}; expected a positive finite value')
        self.factor = float(factor)
        # (limit, predicted peak, channel, unit) of the displacement and of the force; an
        # unwatched channel's limit is infinite
        unwatched = (math.inf, 0.0, '', '')
        self._x = tuple(limits.get('displacement_m', unwatched))
        self._f = tuple(limits.get('force_N', unwatched))
        self._x_limit, self._f_limit = float(self._x[0]), float(self._f[0])
        self._x_peak = self._f_peak = 0.0

    @property
    def ratio(self) -> float:
        """The largest ratio ``|y| / limit`` seen so far, of any watched channel [-]."""
        return max(self._x_peak / self._x_limit, self._f_peak / self._f_limit)

    @classmethod
    def from_parameters(cls, params, check, rig: str = '') -> 'DivergenceGuard | None':
        """The guard of one rig, or None where it cannot judge.

        Parameters
        ----------
        params : mapping
            The rig's resolved parameters: ``divergence_factor`` (0: off),
            ``specimen_model``, ``noise_displacement_m``, ``noise_force_N``,
            ``monitor_floor_N``, ``stiffness_N_per_m`` and, if present, ``excitation`` and
            ``excitation_input``.
        check : RangeCheck or None
            The run's pre-run range check (:func:`~seft_ros.analysis.range_check.range_check`).
        rig : str
            The rig's name ('' for the study's rig).

        Returns
        -------
        DivergenceGuard or None
            None when ``divergence_factor`` is 0, in an open-loop identification run, and
            without a prediction: no check (a run with an excitation, an OpenSees model,
            whose reference, OpenSees' own analysis, the builder's process does not make:
            :func:`~seft_ros.analysis.range_check.range_check`'s ``program_reference``) or
            no positive predicted peak of any watched channel.
        """
        factor = float(params.get('divergence_factor', 0.0) or 0.0)
        if factor <= 0 or check is None or open_loop_identification(params):
            return None
        yielding = params.get('specimen_model', 'linear') != 'linear'
        floor_N = float(params.get('monitor_floor_N', 0.0) or 0.0)
        stiffness = float(params.get('stiffness_N_per_m', 0.0) or 0.0)
        floors = {'force': floor_N,
                  'displacement': floor_N / stiffness if stiffness > 0 else 0.0}
        limits = {}
        for channel, name, noise, unit in _DIVERGENCE_CHANNELS:
            if yielding and channel == 'displacement':
                continue
            peak = check.predicted(rig, channel)
            if peak is None or not (math.isfinite(peak) and peak > 0):
                continue
            sigma = float(params.get(noise, 0.0) or 0.0)
            limits[name] = (factor * peak + DIVERGENCE_NOISE_SIGMAS * sigma + floors[channel],
                            peak, channel, unit)
        return cls(limits, factor) if limits else None

    def update(self, measurement) -> str | None:
        """Take one sample (a :class:`~seft_msgs_py.interface.Measurement`); return the
        one-line reason when a channel passes its limit: the signal, its value, the predicted
        peak and how many times it the value is."""
        x = abs(measurement.displacement_m)
        f = abs(measurement.force_N)
        if x > self._x_peak:
            self._x_peak = x
        if f > self._f_peak:
            self._f_peak = f
        if x <= self._x_limit and f <= self._f_limit:      # the common case: one compare each
            return None
        value, (_limit, peak, channel, unit) = (x, self._x) if x > self._x_limit else (f, self._f)
        return (f'unstable at t={measurement.time_s:.3f} s: diverging, the '
                f'measured {channel} reached {value:.4g} {unit}, '
                f'{value / peak:.2f} x the predicted peak {peak:.4g} {unit} '
                f'(divergence_factor {self.factor:g}: the pre-run reference analysis)')

#: ``specimen_check``: what the builder does when a rig's specimen is not the declared one.
SPECIMEN_CHECK_ACTIONS = ('warn', 'abort', 'off')
#: The specimen check takes every this many excited samples into its least squares (the
#: stiffness needs no more: 100 samples a second of a 500 Hz rig; a fifth of the cost).
CHECK_EVERY = 5
#: The time constant of the specimen check's running RMS of the measured force [s].
GATE_WINDOW_S = 0.5
#: The tolerance of the check when no ``specimen_uncertainty`` is declared [-].
DEFAULT_SPECIMEN_TOLERANCE = 0.1
#: With the sensors' noise declared, the specimen check judges the stiffness only where its
#: estimate is this many standard errors inside or outside the tolerance [-].
JUDGE_SIGMAS = 2.0
#: With the sensors' noise declared, the specimen check's stiffness ratio (what the run
#: reports) takes an estimate whose standard error is at most this fraction of the
#: tolerance [-].
JUDGE_ERROR_FRACTION = 1.0 / 3.0
#: The specimen check says once that it cannot judge when it could not for this many of its
#: memories in a row past its settle time (a 150 N test with the benchmark's noise: at most
#: 1.75 s of its 2 s memory, in the free decay at the end; 40 N: never judged) [-].
UNJUDGED_MEMORIES = 2.0
#: How the specimen check's line that it cannot judge begins (a note: neither a finding nor,
#: with ``specimen_check: abort``, a reason to stop).
SPECIMEN_UNJUDGED = 'specimen not judged'
#: The specimen check's hold level in a test with no amplitude (``amplitude_N`` 0, an
#: excitation played) and ``adaptive_excitation_N`` 0: the reference study's level [N].
SPECIMEN_CHECK_LEVEL_N = 20.0


class SpecimenCheck:
    """Is the rig's specimen the one its compensator models? Its stiffness from its own data.

    The specimen's equation of motion ``f_m = m x'' + c x' + k x`` (paper Eq. 5.1) is
    regressed on each sample's load-cell force, acceleration, velocity and displacement by
    recursive least squares with forgetting (memory ``memory_s``; unknowns normalised by the
    declared ``m0, c0, k0``, the damping scale at least 5 % of critical; every
    ``CHECK_EVERY``-th sample), only while the
    measured force's running RMS exceeds ``excitation_N``. Once the rig has been excited for
    ``settle_s``, a stiffness estimate outside ``(1 +- tolerance) k0`` for ``persist_s`` in a
    row gives one line naming the rig's declared and identified stiffness; the caller warns
    or stops the run (``specimen_check``).

    With the sensors' noise declared (`noise`), the noise of the regressors would bias the
    least squares (errors in variables: the stiffness 0.78-0.88 x on a 150 N test with the
    benchmark's noise, where the specimen is the declared one). The check then solves the
    exponentially weighted normal equations with the noise's covariance taken out,
    ``theta = (R - W Sigma)^-1 r`` (``W`` the weights' sum, ``Sigma`` the regressors' noise
    covariance: the readings are regressed unfiltered, so it is the declared variances), and
    judges only where the estimate is ``JUDGE_SIGMAS`` standard errors (from the equation
    error's residual) inside or outside the tolerance; otherwise it cannot judge (``judged``
    False) and says nothing, and after ``UNJUDGED_MEMORIES`` memories of it one note. Its
    ``stiffness_ratio`` takes the estimates whose standard error is at most
    ``JUDGE_ERROR_FRACTION`` of the tolerance (or a finding's). This is what a
    lab cannot see in the test's own
    signals: with a wrong model the ``model`` compensator makes a stable but wrong test (two
    piers, a pier's model 10 % soft: 84 % error) unless the loop goes unstable and the
    :class:`InstabilityMonitor` stops it.

    Parameters
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float > 0 (damping >= 0)
        The declared specimen m0 [kg], c0 [N s/m], k0 [N/m] (the compensator's model).
    dt : float > 0
        Control period [s].
    tolerance : float in (0, 1)
        Allowed relative deviation of the stiffness [-].
    rig : str
        The rig's name, for the message ('' for the study's rig).
    excitation_N : float >= 0
        Running-RMS level of the measured force below which nothing is learnt [N].
    memory_s, settle_s, persist_s : float > 0
        RLS memory, excitation needed before judging, and how long a deviation must last [s].
    ranges : SensorRanges, optional
        The rig's sensor ranges (:mod:`seft_msgs_py.sensor_range`): a sample with a reading
        at its range is not regressed on (default: every sample is).
    noise : tuple of 4 floats >= 0, optional
        The sensors' declared noise standard deviations (acceleration [m/s^2], velocity
        [m/s], displacement [m], force [N]); default: none (the recursive least squares).

    Attributes
    ----------
    stiffness_ratio : float
        The identified stiffness over the declared one [-] (1 before any excitation; with
        noise, the last precise one, see above).
    stiffness_error : float
        The standard error of the latest stiffness ratio [-] (0 without declared noise).
    judged : bool
        Whether the check could judge the stiffness at its latest sample (always True
        without declared noise).

    Raises
    ------
    ParameterError
        A value out of range (the message names the parameter).

    References
    ----------
    L. Ljung, System Identification, 2nd ed. (1999), Sec. 11.2 (RLS with forgetting);
    Nakata and Combs, Eq. 5.1 (the specimen's equation of motion); T. Söderström, Errors-in-
    variables methods in system identification, Automatica 43 (2007) 939-958, Sec. 5 (the
    bias-compensated least squares and its covariance).
    """

    def __init__(self, mass_kg: float, damping_N_s_per_m: float, stiffness_N_per_m: float,
                 dt: float, tolerance: float, *, rig: str = '', excitation_N: float = 20.0,
                 memory_s: float = 2.0, settle_s: float = 1.0, persist_s: float = 0.5,
                 ranges=None, noise=None):
        from seft_ros.core import identification as ident
        m0, c0, k0 = float(mass_kg), float(damping_N_s_per_m), float(stiffness_N_per_m)
        if not (m0 > 0 and c0 >= 0 and k0 > 0):
            raise ParameterError(f'specimen check: expected m > 0, c >= 0, k > 0, got {m0!r}, '
                                 f'{c0!r}, {k0!r}')
        if not 0 < tolerance < 1:
            raise ParameterError(f'parameter specimen_uncertainty={tolerance!r}: expected a '
                                 'fraction in (0, 1) for the specimen check')
        self.k0 = k0
        self.tolerance = float(tolerance)
        self.rig = rig
        self._scale = (m0, max(c0, 0.1 * math.sqrt(k0 * m0)), k0)
        level = max(float(excitation_N), 1.0)
        # the RLS of RecursiveLeastSquares (Ljung Eqs. 11.12-11.13), written out for three
        # unknowns in Python floats: it runs at every sample of every rig
        self._theta = [1.0, c0 / self._scale[1], 1.0]
        p0 = float(dt) / (0.01 * level * level)
        # the covariance P, symmetric (exactly: each update averages the pairs), as its six
        # entries (p00, p01, p02, p11, p12, p22)
        self._p = (p0, 0.0, 0.0, p0, 0.0, p0)
        self._max_trace = 3.0 * p0
        self._lambda = ident.forgetting_factor(float(dt) * CHECK_EVERY, memory_s)
        # the excitation gate, ExcitationGate(dt, GATE_WINDOW_S, excitation_N) written out in
        # update: the running mean square of the force against the level's square
        self._gate_weight = min(1.0, float(dt) / GATE_WINDOW_S)
        self._gate_limit = float(excitation_N) ** 2
        self._mean_square = 0.0
        self._settle = int(round(settle_s / float(dt)))
        self._persist = int(round(persist_s / float(dt)))
        self._excited = 0
        self._off = 0
        self._unjudged = 0
        # the latest verdict found the specimen within the tolerance (a sample without a
        # regression then gives the same verdict, with nothing to change)
        self._steady = False
        self._unjudged_limit = int(round(UNJUDGED_MEMORIES * memory_s / float(dt)))
        self.noted = False
        self.stiffness_ratio = 1.0
        self.stiffness_error = 0.0
        self.judged = True
        self.reported = False
        self._ranges = ranges if ranges is not None and ranges.limited else None
        sigma = tuple(float(v) for v in (noise or (0.0, 0.0, 0.0, 0.0)))
        if len(sigma) != 4 or not all(v >= 0 for v in sigma):
            raise ParameterError(f'specimen check: expected 4 noise deviations >= 0 '
                                 f'(acceleration, velocity, displacement, force), got {noise!r}')
        # the regressors' noise variances in the regression's units (N^2): Sigma's diagonal
        s = self._scale
        self._noise = tuple((s[i] * sigma[i]) ** 2 for i in range(3))
        if any(self._noise):
            # the weighted normal equations: R's six entries, r, the sums of the weights and
            # of their squares, and of the weighted squared force
            self._normal = [0.0] * 12
            self.judged = False
        else:
            self._normal = None
        # the latest bias-compensated stiffness ratio (None: Rc not positive definite)
        self._estimate = None

    @classmethod
    def from_parameters(cls, params, rig: str = '') -> 'SpecimenCheck | None':
        """The check of one rig from its parameters, or None when it cannot judge: turned off
        (``specimen_check: off``), a member that yields (its stiffness changes by design;
        the hysteretic compensator identifies it), or an open-loop identification run.

        The declared specimen is the compensator's model (``predictor_*``, 0: the
        specimen's); the tolerance ``specimen_uncertainty`` (0: 10 %), for ``adaptive`` at
        least its identification's range ``adaptive_max_deviation``; the sensors' noise the
        rig's declared ``noise_acceleration_m_s2``, ``noise_velocity_m_s``,
        ``noise_displacement_m`` and ``noise_force_N``.
        """
        from seft_ros.core.predictors import excitation_level_N, model_parameters
        if (params.get('specimen_check', 'warn') == 'off'
                or params.get('specimen_model', 'linear') != 'linear'
                or params.get('predictor_restoring_force', 'model') != 'model'
                or open_loop_identification(params)):
            return None
        from seft_msgs_py.sensor_range import SensorRanges
        mp = model_parameters(params)
        tolerance = float(params.get('specimen_uncertainty', 0.0) or 0.0) or \
            DEFAULT_SPECIMEN_TOLERANCE
        if params.get('predictor') == 'adaptive':
            tolerance = max(tolerance, float(params.get('adaptive_max_deviation', 0.5)))
        noise = tuple(float(params.get(name, 0.0) or 0.0) for name in (
            'noise_acceleration_m_s2', 'noise_velocity_m_s', 'noise_displacement_m',
            'noise_force_N'))
        return cls(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'],
                   float(params['dt']), tolerance, rig=rig,
                   excitation_N=excitation_level_N(params, SPECIMEN_CHECK_LEVEL_N),
                   ranges=SensorRanges.from_parameters(params), noise=noise)

    def _update(self, phi0: float, phi1: float, phi2: float, y: float) -> None:
        """One RLS step with forgetting and covariance limiting (``RecursiveLeastSquares``)
        on the regressor ``phi = (phi0, phi1, phi2)``, written out on P's six entries (the
        same operations in the same order as the 3 x 3 matrix form)."""
        p00, p01, p02, p11, p12, p22 = self._p
        theta, lam = self._theta, self._lambda
        pp0 = p00 * phi0 + p01 * phi1 + p02 * phi2
        pp1 = p01 * phi0 + p11 * phi1 + p12 * phi2
        pp2 = p02 * phi0 + p12 * phi1 + p22 * phi2
        denom = lam + phi0 * pp0 + phi1 * pp1 + phi2 * pp2
        g0, g1, g2 = pp0 / denom, pp1 / denom, pp2 / denom
        err = y - (phi0 * theta[0] + phi1 * theta[1] + phi2 * theta[2])
        theta[0] += g0 * err
        theta[1] += g1 * err
        theta[2] += g2 * err
        # (P - g pp^T) / lambda, each off-diagonal pair averaged
        n00 = (p00 - g0 * pp0) / lam
        n11 = (p11 - g1 * pp1) / lam
        n22 = (p22 - g2 * pp2) / lam
        n01 = 0.5 * ((p01 - g0 * pp1) / lam + (p01 - g1 * pp0) / lam)
        n02 = 0.5 * ((p02 - g0 * pp2) / lam + (p02 - g2 * pp0) / lam)
        n12 = 0.5 * ((p12 - g1 * pp2) / lam + (p12 - g2 * pp1) / lam)
        trace = n00 + n11 + n22
        if trace > self._max_trace:
            scale = self._max_trace / trace
            n00, n01, n02 = n00 * scale, n01 * scale, n02 * scale
            n11, n12, n22 = n11 * scale, n12 * scale, n22 * scale
        self._p = (n00, n01, n02, n11, n12, n22)

    def _update_corrected(self, phi0: float, phi1: float, phi2: float, y: float) -> None:
        """One step of the bias-compensated least squares: the weighted normal equations
        ``R, r`` (forgetting ``lambda``) take the sample; ``theta = (R - W Sigma)^-1 r`` and
        its covariance ``W2 Rc^-1 (s2 R / W + Sigma theta theta^T Sigma) Rc^-1`` (``Rc = R - W
        Sigma``, ``W2`` the sum of the squared weights, ``s2`` the weighted mean squared
        equation error; Gaussian noise) give the stiffness ratio and its standard error where
        ``Rc`` is positive definite."""
        lam = self._lambda
        n = self._normal
        a00, a01, a02, a11, a12, a22, b0, b1, b2, w, w2, yy = (
            lam * n[0] + phi0 * phi0, lam * n[1] + phi0 * phi1, lam * n[2] + phi0 * phi2,
            lam * n[3] + phi1 * phi1, lam * n[4] + phi1 * phi2, lam * n[5] + phi2 * phi2,
            lam * n[6] + phi0 * y, lam * n[7] + phi1 * y, lam * n[8] + phi2 * y,
            lam * n[9] + 1.0, lam * lam * n[10] + 1.0, lam * n[11] + y * y)
        self._normal = [a00, a01, a02, a11, a12, a22, b0, b1, b2, w, w2, yy]
        self._estimate = None
        v0, v1, v2 = self._noise
        c00, c11, c22 = a00 - w * v0, a11 - w * v1, a22 - w * v2
        # Rc positive definite: its leading minors; then its inverse by cofactors
        m01 = c00 * c11 - a01 * a01
        i00, i01, i02 = c11 * c22 - a12 * a12, a02 * a12 - a01 * c22, a01 * a12 - a02 * c11
        det = c00 * i00 + a01 * i01 + a02 * i02
        if not (c00 > 0 and m01 > 0 and det > 0):
            return
        i11, i12, i22 = c00 * c22 - a02 * a02, a01 * a02 - c00 * a12, m01
        t0 = (i00 * b0 + i01 * b1 + i02 * b2) / det
        t1 = (i01 * b0 + i11 * b1 + i12 * b2) / det
        t2 = (i02 * b0 + i12 * b1 + i22 * b2) / det
        # the weighted mean squared equation error of theta, on the noisy readings
        rt0 = a00 * t0 + a01 * t1 + a02 * t2
        rt1 = a01 * t0 + a11 * t1 + a12 * t2
        rt2 = a02 * t0 + a12 * t1 + a22 * t2
        s2 = max(yy - 2.0 * (t0 * b0 + t1 * b1 + t2 * b2)
                 + (t0 * rt0 + t1 * rt1 + t2 * rt2), 0.0) / w
        # the stiffness's variance: g = Rc^-1's last row, W2 (s2 g^T R g / W + (g^T Sigma t)^2)
        g0, g1, g2 = i02 / det, i12 / det, i22 / det
        grg = (g0 * (a00 * g0 + a01 * g1 + a02 * g2) + g1 * (a01 * g0 + a11 * g1 + a12 * g2)
               + g2 * (a02 * g0 + a12 * g1 + a22 * g2))
        gst = g0 * v0 * t0 + g1 * v1 * t1 + g2 * v2 * t2
        error = math.sqrt(max(w2 * (s2 * grg / w + gst * gst), 0.0))
        self.stiffness_error = error
        self._estimate = t2
        if error <= JUDGE_ERROR_FRACTION * self.tolerance:
            self.stiffness_ratio = t2

    def update(self, measurement) -> str | None:
        """Take one sample (a :class:`~seft_msgs_py.interface.Measurement`); return the
        one-line finding the first time the specimen is judged not the declared one, or the
        one-line note (beginning :data:`SPECIMEN_UNJUDGED`) the first time the check could
        not judge for ``UNJUDGED_MEMORIES`` memories in a row."""
        f = measurement.force_N
        ms = self._mean_square                       # ExcitationGate.update
        ms = self._mean_square = ms + self._gate_weight * (f * f - ms)
        if not ms > self._gate_limit:
            self._off = 0
            return None
        excited = self._excited
        self._excited = excited + 1
        if excited % CHECK_EVERY:
            # no regression at this sample: the estimate is the last sample's, and so is the
            # verdict where that one found the specimen within the tolerance
            if self._steady:
                return None
        elif self._ranges is None or not self._ranges.flags(measurement):
            s = self._scale
            if self._normal is None:
                self._update(s[0] * measurement.acceleration_m_s2,
                             s[1] * measurement.velocity_m_s, s[2] * measurement.displacement_m,
                             f)
            else:
                self._update_corrected(s[0] * measurement.acceleration_m_s2,
                                       s[1] * measurement.velocity_m_s,
                                       s[2] * measurement.displacement_m, f)
        if self._normal is None:
            self.stiffness_ratio = self._theta[2]
        if self._excited < self._settle or self.reported:
            return None
        self._steady = False
        ratio = self.stiffness_ratio
        if self._normal is not None:
            ratio = self._estimate
            margin = JUDGE_SIGMAS * self.stiffness_error
            self.judged = ratio is not None and not (
                self.tolerance - margin <= abs(ratio - 1.0) <= self.tolerance + margin)
        if not self.judged:
            self._off = 0
            self._unjudged += 1
            if self._unjudged < self._unjudged_limit or self.noted:
                return None
            self.noted = True
            who = f'rig {self.rig}' if self.rig else 'the rig'
            return (f'{SPECIMEN_UNJUDGED} at t={measurement.time_s:.3f} s: {who} cannot tell '
                    "its specimen's stiffness through the sensors' declared noise (standard "
                    f'error +-{100 * self.stiffness_error:.0f} % of the declared '
                    f'{self.k0:.4g} N/m against the tolerance +-{100 * self.tolerance:.0f} '
                    '%): the '
                    'check says nothing while it cannot; a larger amplitude makes '
                    'the motion judgeable')
        self._unjudged = 0
        if abs(ratio - 1.0) <= self.tolerance:
            self._off = 0
            self._steady = True
            return None
        self._off += 1
        if self._off < self._persist:
            return None
        self.reported = True
        self.stiffness_ratio = ratio
        who = f'rig {self.rig}' if self.rig else 'the rig'
        error = (f" +-{self.stiffness_error:.2g} (the sensors' noise)"
                 if self._normal is not None else '')
        return (f'specimen check at t={measurement.time_s:.3f} s: {who} identifies its specimen '
                f'at {ratio:.3g}{error} x the declared stiffness {self.k0:.4g} N/m '
                f'(tolerance +-{100 * self.tolerance:.0f} %): the compensation models another '
                'specimen; identify it (seft identify) or declare it')
