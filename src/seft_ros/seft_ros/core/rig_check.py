"""The checks of ``seft rig-check`` on arrays: does a rig node follow the rig contract?

``seft rig-check`` (``seft_ros.cli.rig_check``) runs the rest of the graph against a rig node
in real time, a few short runs with a small force (:class:`CheckProfile`), and hands what it
measured to the functions here: each returns one :class:`CheckResult`, pass or fail with the
measured value. They import no rclpy, so they are tested on arrays.

The checks (:data:`CHECKS`, in the order they are reported):

``contract``
    the rig's ready report names a compatible contract, its command kind (the one the graph
    sends it) and its command latency, and it publishes every required parameter;
``clock``
    the measurement's samples are stamped ``k dt`` with no gap, and arrive every ``dt``
    (:func:`sample_period` within :data:`PERIOD_TOLERANCE` of ``dt``), and /clock is on the
    grid of ``CLOCK_EVERY`` samples;
``measurement``
    every field of the contract, in its order, every value finite;
``units``
    SI units: the velocity is the derivative of the displacement and the acceleration that
    of the velocity (least-squares gains within :data:`UNIT_RANGE`), and the static force
    over the displacement is the specimen's stiffness within that range (a unit error is a
    factor of 9.8, 100 or 1000);
``static force``
    a small static reference force gives a measured force of the same sign and a gain within
    :data:`GAIN_RANGE`;
``command timing``
    the first sample that shows a command step is the one the contract promises
    (:func:`~seft_msgs_py.rig_contract.first_effect_step`, never earlier, at most
    :data:`TIMING_TOLERANCE_STEPS` later);
``safe state: abort``, ``safe state: stopped controller``, ``safe state: watchdog``
    the rig enters its safe state within :func:`~seft_msgs_py.rig_contract.reaction_limit_s`
    of an abort report, of the command node reporting itself stopped, and of the command node
    going silent, and is at rest after the ramp (:func:`check_safe_state`);
``final status``
    every run ends with the rig's final report (done after the run's samples, or aborted
    with its reason), which names a compatible contract;
``bag closed``
    the recorder closed every bag.
"""

from dataclasses import dataclass, field
import math
from typing import Mapping, Sequence

import numpy as np

from seft_msgs_py import rig_contract
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.signals import CLOCK_EVERY, MEASUREMENT_FIELDS

__all__ = [
    'CheckProfile', 'CheckResult', 'CHECKS', 'FAULT_RUNS', 'PERIOD_TOLERANCE', 'GAIN_RANGE',
    'UNIT_RANGE', 'TIMING_TOLERANCE_STEPS', 'REST_FORCE_FRACTION', 'REST_VELOCITY_FRACTION',
    'check_contract', 'sample_period', 'check_clock', 'check_measurement', 'check_units',
    'check_static_force', 'check_command_timing', 'check_safe_state', 'check_final_status',
    'check_bags_closed', 'first_departure', 'not_run', 'format_line',
]

#: The faults of the safe-state runs: run name -> check name.
FAULT_RUNS = {'abort': 'safe state: abort', 'stopped_controller': 'safe state: stopped '
              'controller', 'watchdog': 'safe state: watchdog'}
#: Every check, in report order.
CHECKS = ('contract', 'clock', 'measurement', 'units', 'static force', 'command timing',
          *FAULT_RUNS.values(), 'final status', 'bag closed')
#: Largest relative error of the measured sample period (a straight-line fit of the arrival
#: times) [-]: a rig clock 2 % slow fails.
PERIOD_TOLERANCE = 0.02
#: Allowed static gain measured force / reference force [-] (the force loop's static error
#: of a real rig, a load cell's calibration).
GAIN_RANGE = (0.8, 1.2)
#: Allowed ratio of a channel to the derivative it must be, and of the static force to k x
#: [-]: wide for noise and for an uncertain stiffness, narrow against a unit error (>= 9.8).
UNIT_RANGE = (0.5, 2.0)
#: How many samples later than promised a command may first show [-]: a valve command moves
#: the force slowly at first (the spool's lag), and a real load cell's noise hides it longer.
TIMING_TOLERANCE_STEPS = 3
#: At rest on a force-commanded rig: |f| at most this fraction of the amplitude (+ noise).
REST_FORCE_FRACTION = 0.1
#: At rest on a valve-commanded rig (valve closed, the actuator holds): |v| at most this
#: fraction of the peak velocity of the last cycle before the fault (+ noise); the oil that
#: the specimen's force pushes through the closed valve and the seals lets it creep.
REST_VELOCITY_FRACTION = 0.25
#: A departure from rest is this many standard deviations of the quiet samples, at least
#: ``1e-3`` of the step (noise-free simulated rigs).
_DEPARTURE_SIGMAS = 6.0


@dataclass(frozen=True)
class CheckResult:
    """One line of ``seft rig-check``.

    Attributes
    ----------
    name : str
        One of :data:`CHECKS`.
    passed : bool
    measured : str
        What was measured, with the limit it was held to.
    values : dict
        The measured numbers (SI units, as their keys say).
    """

    name: str
    passed: bool
    measured: str
    values: dict = field(default_factory=dict)


def format_line(result: CheckResult) -> str:
    """``'PASS clock: ...'`` or ``'FAIL clock: ...'``."""
    return f"{'PASS' if result.passed else 'FAIL'} {result.name}: {result.measured}"


def not_run(name: str, why: str) -> CheckResult:
    """A failed check that could not be measured (`why`)."""
    return CheckResult(name, False, f'not measured: {why}')


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f'{name}={value!r}: expected a number > 0')
    return v


@dataclass(frozen=True)
class CheckProfile:
    """The reference forces of the rig-check runs, in SI units.

    The **step run**: ``quiet_s`` at rest, the static force ``amplitude_N`` for ``hold_s``,
    then ``release_s`` at rest. The **fault runs**: ``quiet_s`` at rest, then the sine
    ``amplitude_N sin(2 pi sine_hz (t - quiet_s))``; the fault comes ``fault_cycles`` cycles
    into it (a whole number and 45 degrees: force and velocity both about 0.7 of their peaks,
    so that a rig that holds its last command, force or valve opening, is seen), and the run
    would go on ``after_fault_s`` longer. The default 4 cycles and 45 degrees at 2 Hz put the
    fault 2.56 s into the run: a checker that discovers the rig late (measured here: up to
    1.3 s after it started, on two loaded cores) hears it live by then.

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    amplitude_N : float > 0
        Static force and sine amplitude [N] (small: the check may run on a real actuator).
    quiet_s, hold_s, release_s, after_fault_s : float > 0
        Durations [s].
    sine_hz : float > 0
        Frequency of the fault runs' sine [Hz], below a quarter of the sample rate.
    fault_cycles : float > 0
        When the fault comes, in cycles of the sine [-] (default 4.125).

    Raises
    ------
    ParameterError
        A value out of range; the message names it.
    """

    dt: float
    amplitude_N: float = 100.0
    quiet_s: float = 0.5
    hold_s: float = 1.0
    release_s: float = 0.5
    sine_hz: float = 2.0
    fault_cycles: float = 4.125
    after_fault_s: float = 1.0

    def __post_init__(self):
        for name in ('dt', 'amplitude_N', 'quiet_s', 'hold_s', 'release_s', 'sine_hz',
                     'fault_cycles', 'after_fault_s'):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        if self.sine_hz > 0.25 / self.dt:
            raise ParameterError(f'sine_hz={self.sine_hz!r}: expected at most a quarter of '
                                 f'the sample rate, {0.25 / self.dt:g} Hz')

    def _steps(self, seconds: float) -> int:
        return max(1, int(round(seconds / self.dt)))

    @property
    def onset_step(self) -> int:
        """The first sample of the static force (and of the sine) [-]."""
        return self._steps(self.quiet_s)

    def step_reference(self) -> np.ndarray:
        """The step run's reference force ``f_r[k]`` [N], shape (n,)."""
        q, h = self.onset_step, self._steps(self.hold_s)
        f = np.zeros(q + h + self._steps(self.release_s))
        f[q:q + h] = self.amplitude_N
        return f

    @property
    def fault_step(self) -> int:
        """The sample after which the fault runs' fault is injected [-]."""
        return self.onset_step + self._steps(self.fault_cycles / self.sine_hz)

    def sine_reference(self) -> np.ndarray:
        """A fault run's reference force ``f_r[k]`` [N], shape (n,)."""
        n = self.fault_step + self._steps(self.after_fault_s)
        k = np.arange(n)
        t = (k - self.onset_step) * self.dt
        return np.where(k >= self.onset_step,
                        self.amplitude_N * np.sin(2 * np.pi * self.sine_hz * t), 0.0)


# -- the checks -------------------------------------------------------------------------------

def check_contract(ready: Mapping | None, rig_params: Mapping | None, command_kind: str
                   ) -> CheckResult:
    """The rig says which contract it follows, what it takes, and takes the parameters.

    Parameters
    ----------
    ready : mapping or None
        The rig's 'ready' status values (the first that carries ``contract``), None if none.
    rig_params : mapping or None
        The parameters the rig published on ``/seft/node_parameters``.
    command_kind : str
        The command the graph sends it (``rig_contract.command_kind`` of the run).

    Returns
    -------
    CheckResult
        ``values``: ``contract``, ``command_latency_s`` [s], ``missing_parameters``.
    """
    if not ready:
        return CheckResult('contract', False, 'no ready report from the rig with a contract')
    problems = []
    contract = ready.get(rig_contract.CONTRACT_KEY)
    if not rig_contract.is_compatible(contract):
        problems.append(f'contract {contract!r}, expected {rig_contract.CONTRACT}')
    if ready.get('command_kind') != command_kind:
        problems.append(f"command_kind {ready.get('command_kind')!r}, expected "
                        f'{command_kind!r}')
    try:
        latency = float(ready.get('command_latency_s', 'nan'))
    except ValueError:
        latency = math.nan
    if not (math.isfinite(latency) and latency >= 0):
        problems.append(f"command_latency_s {ready.get('command_latency_s')!r}, expected "
                        'seconds >= 0')
    missing = [n for n in rig_contract.REQUIRED_PARAMETERS if n not in (rig_params or {})]
    if missing:
        problems.append(f'parameters not published: {", ".join(missing)}')
    values = {'contract': contract, 'command_latency_s': latency, 'missing_parameters': missing}
    if problems:
        return CheckResult('contract', False, '; '.join(problems), values)
    n = len(rig_contract.REQUIRED_PARAMETERS)
    return CheckResult('contract', True, f'{contract}, takes {command_kind}, command latency '
                       f'{1e3 * latency:g} ms, {n} of {n} required parameters published',
                       values)


def sample_period(steps, arrival_s) -> float:
    """The period at which samples arrive [s]: the median over spans of ``N`` samples of the
    arrival time difference over the step difference, ``N = max(50, n // 10)``.

    A checker that discovers the rig's publisher after it started receives the samples it
    missed at once (the measurement is transient-local): the spans over that burst are the
    minority the median ignores, while a clock that runs slow or fast moves every span.

    Parameters
    ----------
    steps : array_like of int, shape (n,)
        Sample index of each arrival.
    arrival_s : array_like of float, shape (n,)
        Arrival times [s].
    """
    k = np.asarray(steps, dtype=float)
    a = np.asarray(arrival_s, dtype=float)
    span = min(max(50, k.size // 10), k.size - 1)
    dk = k[span:] - k[:-span]
    ok = dk > 0
    return float(np.median((a[span:] - a[:-span])[ok] / dk[ok]))


def check_clock(steps: Sequence[int], stamps_ns: Sequence[int], arrival_s: Sequence[float],
                dt: float, *, expected: int, clock_ns: Sequence[int] | None = None
                ) -> CheckResult:
    """The clock advances by dt without gaps.

    Parameters
    ----------
    steps : sequence of int, shape (n,)
        Sample index ``round(stamp / dt)`` of each live measurement, in arrival order.
    stamps_ns : sequence of int, shape (n,)
        Their header stamps [ns].
    arrival_s : sequence of float, shape (n,)
        When the rig sent each [s] (the DDS source timestamp: a sample the checker hears late
        keeps it).
    dt : float > 0
        Control period [s].
    expected : int
        How many samples the rig should have published (its run's ``n_steps``, or up to its
        safe state).
    clock_ns : sequence of int, optional
        The ``/clock`` values received [ns] (the rig is the clock master): each must be a
        sample time and follow the previous one by ``CLOCK_EVERY dt``. None: not checked.

    Returns
    -------
    CheckResult
        ``values``: ``period_s`` (:func:`sample_period`), ``missing``, ``misstamped``,
        ``duplicates``, ``samples``, ``clock_messages``, ``clock_bad`` (/clock values off
        the grid or out of step).
    """
    steps = np.asarray(steps, dtype=np.int64)
    if steps.size < 10:
        return CheckResult('clock', False, f'{steps.size} samples arrived (expected '
                           f'{expected})', {'samples': int(steps.size)})
    dt_ns = int(round(dt * 1e9))
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    misstamped = int(np.count_nonzero(stamps != steps * dt_ns))
    unique, counts = np.unique(steps, return_counts=True)
    duplicates = int(np.count_nonzero(counts > 1))
    missing = int(expected - np.count_nonzero((unique >= 0) & (unique < expected)))
    period = sample_period(steps, arrival_s)
    error = period / dt - 1.0
    passed = (missing == 0 and misstamped == 0 and duplicates == 0
              and abs(error) <= PERIOD_TOLERANCE)
    text = (f'period {1e3 * period:.4f} ms ({100 * error:+.2f} % of dt {1e3 * dt:g} ms, limit '
            f'{100 * PERIOD_TOLERANCE:g} %), {missing} missing, {misstamped} misstamped, '
            f'{duplicates} repeated of {expected} samples')
    values = {'period_s': period, 'missing': missing, 'misstamped': misstamped,
              'duplicates': duplicates, 'samples': int(steps.size)}
    if clock_ns is not None:
        c = np.asarray(clock_ns, dtype=np.int64)
        bad = int(np.count_nonzero(c % dt_ns)
                  + np.count_nonzero(np.diff(c) != CLOCK_EVERY * dt_ns))
        passed = passed and c.size > 0 and bad == 0
        text += f'; /clock {c.size} messages, {bad} off the grid of {CLOCK_EVERY} samples'
        values.update(clock_messages=int(c.size), clock_bad=bad)
    return CheckResult('clock', passed, text, values)


def check_measurement(names: Sequence[str], values: np.ndarray) -> CheckResult:
    """The measurement has every field of the contract, in order, every value finite.

    Parameters
    ----------
    names : sequence of str
        The ``name`` list of the live measurement messages (the first one's; '' entries
        where messages disagreed).
    values : ndarray, shape (n, m)
        Their ``position`` values, one row per sample.
    """
    values = np.asarray(values, dtype=float)
    if tuple(names) != MEASUREMENT_FIELDS:
        return CheckResult('measurement', False, f'fields {list(names)}, expected '
                           f'{list(MEASUREMENT_FIELDS)}')
    if values.ndim != 2 or values.shape[1] != len(MEASUREMENT_FIELDS) or not values.size:
        return CheckResult('measurement', False, f'values of shape {values.shape}, expected '
                           f'(n, {len(MEASUREMENT_FIELDS)})')
    bad = int(np.count_nonzero(~np.isfinite(values).all(axis=1)))
    return CheckResult('measurement', bad == 0,
                       f'{len(MEASUREMENT_FIELDS)} fields in order, {bad} of '
                       f'{values.shape[0]} samples with a value not finite',
                       {'not_finite': bad, 'samples': int(values.shape[0])})


def _gain(y: np.ndarray, x: np.ndarray) -> float:
    """Least-squares gain of ``y = g x`` (nan when x is all zero)."""
    den = float(np.dot(x, x))
    return float(np.dot(x, y) / den) if den > 0 else math.nan


def check_units(displacement_m, velocity_m_s, acceleration_m_s2, force_N, dt: float,
                stiffness_N_per_m: float, hold: slice) -> CheckResult:
    """SI units: the channels are consistent with one another and with the specimen.

    Parameters
    ----------
    displacement_m, velocity_m_s, acceleration_m_s2, force_N : ndarray, shape (n,)
        The step run's samples [m, m/s, m/s^2, N].
    dt : float > 0
        Control period [s].
    stiffness_N_per_m : float > 0
        The specimen's stiffness as configured [N/m].
    hold : slice
        The samples of the static force (its second half: the response has settled).

    Returns
    -------
    CheckResult
        ``values``: ``velocity_gain`` (v against the central difference of x),
        ``acceleration_gain`` (a against that of v), ``stiffness_ratio`` (the static force
        over ``k x``, in magnitude); each must lie in :data:`UNIT_RANGE`.

    Notes
    -----
    The central difference ``(x[k+1] - x[k-1]) / (2 dt)`` of a motion of frequency ``f`` is
    ``sin(w dt) / (w dt)`` of the derivative: 0.987 at 10 Hz and 2 ms, well within the range.
    """
    x, v, a, f = (np.asarray(s, dtype=float) for s in (displacement_m, velocity_m_s,
                                                        acceleration_m_s2, force_N))
    gains = {'velocity_gain': _gain(v[1:-1], (x[2:] - x[:-2]) / (2 * dt)),
             'acceleration_gain': _gain(a[1:-1], (v[2:] - v[:-2]) / (2 * dt))}
    x_hold = float(np.mean(x[hold])) if x[hold].size else math.nan
    # magnitudes: a sign error is the static force check's, not a unit error
    gains['stiffness_ratio'] = (abs(float(np.mean(f[hold]))) / (stiffness_N_per_m * abs(x_hold))
                                if x_hold else math.nan)
    lo, hi = UNIT_RANGE
    passed = all(lo <= g <= hi for g in gains.values())
    return CheckResult(
        'units', passed,
        f'v / dx/dt = {gains["velocity_gain"]:.3g}, a / dv/dt = '
        f'{gains["acceleration_gain"]:.3g}, static |f| / (k |x|) = '
        f'{gains["stiffness_ratio"]:.3g} '
        f'(k = {stiffness_N_per_m:g} N/m; each expected {lo:g}..{hi:g})', gains)


def check_static_force(force_N, hold: slice, quiet: slice, amplitude_N: float) -> CheckResult:
    """A small static reference force gives a force of the right sign and gain.

    Parameters
    ----------
    force_N : ndarray, shape (n,)
        Measured force of the step run [N].
    hold, quiet : slice
        The settled static force, and the samples at rest before it.
    amplitude_N : float
        The reference force [N].

    Returns
    -------
    CheckResult
        ``values``: ``gain`` = (mean over `hold` - mean over `quiet`) / `amplitude_N`,
        within :data:`GAIN_RANGE`.
    """
    f = np.asarray(force_N, dtype=float)
    if not f[hold].size or not f[quiet].size:
        return not_run('static force', 'the run ended before the static force settled')
    change = float(np.mean(f[hold]) - np.mean(f[quiet]))
    gain = change / amplitude_N
    lo, hi = GAIN_RANGE
    sign = 'the sign of the reference' if gain > 0 else 'the opposite sign'
    return CheckResult('static force', lo <= gain <= hi,
                       f'gain {gain:.3f} (f_m {change:.4g} N for {amplitude_N:g} N, {sign}; '
                       f'expected {lo:g}..{hi:g})', {'gain': gain})


def first_departure(signal, quiet: slice, start: int, step_size: float) -> int | None:
    """The first sample from `start` on where `signal` leaves its rest value (the mean over
    `quiet`) by more than 6 standard deviations of the quiet samples, at least
    ``1e-3 |step_size|``; None if it never does."""
    s = np.asarray(signal, dtype=float)
    rest = s[quiet]
    threshold = max(_DEPARTURE_SIGMAS * float(np.std(rest)), 1e-3 * abs(step_size))
    moved = np.flatnonzero(np.abs(s[start:] - float(np.mean(rest))) > threshold)
    return int(start + moved[0]) if moved.size else None


def check_command_timing(command, force_N, quiet: slice, onset: int, dt: float,
                         latency_s: float, amplitude_N: float) -> CheckResult:
    """Commands act at the promised step.

    Parameters
    ----------
    command : ndarray, shape (n,)
        The rig's command by step (valve command [V] or reference force [N]) in the step run.
    force_N : ndarray, shape (n,)
        The measured force [N].
    quiet : slice
        Samples at rest before the step.
    onset : int
        The step's first sample in the reference force (the command departs from there).
    dt : float > 0
        Control period [s].
    latency_s : float
        The command latency the rig reported (``command_latency_s``) [s].
    amplitude_N : float
        The step of the reference force [N].

    Returns
    -------
    CheckResult
        ``values``: ``command_step`` j (the command's first departure), ``first_effect``
        (the force's), ``promised`` (:func:`~seft_msgs_py.rig_contract.first_effect_step`);
        passes when ``promised <= first_effect <= promised + TIMING_TOLERANCE_STEPS``.
    """
    c = np.asarray(command, dtype=float)
    j = first_departure(c, quiet, max(onset - 1, 0), np.max(np.abs(c)) if c.size else 0.0)
    if j is None:
        return not_run('command timing', 'the command never left its rest value')
    k1 = first_departure(force_N, quiet, max(onset - 1, 0), amplitude_N)
    if k1 is None:
        return not_run('command timing', 'the measured force never left its rest value')
    promised = rig_contract.first_effect_step(j, latency_s, dt)
    late = k1 - promised
    return CheckResult(
        'command timing', 0 <= late <= TIMING_TOLERANCE_STEPS,
        f'the command stamped step {j} first shows at step {k1}: {k1 - j} steps after it '
        f'(promised {promised - j} for command_latency_s {1e3 * latency_s:g} ms, at most '
        f'{TIMING_TOLERANCE_STEPS} later)',
        {'command_step': j, 'first_effect': k1, 'promised': promised})


def check_safe_state(name: str, *, final: Mapping | None, command_kind: str,
                     time_s, force_N, velocity_m_s, quiet: slice, before: slice,
                     fault_ns: int | None, t0_ns: int | None, params: Mapping,
                     latency_s: float, amplitude_N: float, reason_prefix: str = ''
                     ) -> CheckResult:
    """A fault brings the rig to its safe state within the promised time, at rest.

    Parameters
    ----------
    name : str
        The check (one of :data:`FAULT_RUNS`' values).
    final : mapping or None
        The rig's final status values (``state``, ``abort_at_s``, ``message``), None if none
        came.
    command_kind : str
        What the rig acts on (``rig_contract.COMMAND_KINDS``).
    time_s, force_N, velocity_m_s : ndarray, shape (n,)
        The run's samples as recorded [s, N, m/s].
    quiet : slice
        Samples at rest before the sine (their noise).
    before : slice
        The last cycle before the fault (the velocity it reached).
    fault_ns : int or None
        System-clock time the fault was injected [ns].
    t0_ns : int or None
        System-clock time of the rig's sample 0 (its ``t0_ns``) [ns].
    params : mapping
        The run's parameters (``watchdog_timeout_s``, ``dt``, ``safe_ramp_s``).
    latency_s : float
        The rig's command latency [s].
    amplitude_N : float
        The sine's amplitude [N].
    reason_prefix : str
        The final message must start with it (``rig_contract.WATCHDOG_REASON`` for a
        watchdog: the rig, not another node, noticed the silence).

    Returns
    -------
    CheckResult
        ``values``: ``reaction_s`` (the safe state's entry ``t0 + abort_at_s`` after the
        fault), ``rest_value`` (largest |f| [N] or |v| [m/s] after the ramp) and
        ``rest_limit``.

    Notes
    -----
    At rest means after ``abort_at_s + command_latency_s + safe_ramp_s`` (the command at
    zero and at the actuator) plus 10 ms of settling: on a rig commanded by the force,
    ``|f| <= REST_FORCE_FRACTION amplitude``; on a valve-commanded rig, whose closed valve
    holds the actuator, ``|v| <= REST_VELOCITY_FRACTION`` of the last cycle's peak velocity;
    each plus 6 standard deviations of the quiet samples (sensor noise). The rig must have
    sampled at least 5 samples there (``SAFE_HOLD_S`` is 25 at 500 Hz).
    """
    if final is None:
        return CheckResult(name, False, 'no final status from the rig (it never reported '
                           'its safe state)')
    if final.get('state') != 'aborted' or 'abort_at_s' not in final:
        return CheckResult(name, False, f"the rig ended {final.get('state')!r} "
                           f"({final.get('message', '')!r}) without a safe state (abort_at_s)")
    abort_at = float(final['abort_at_s'])
    limit = rig_contract.reaction_limit_s(params)
    reaction = math.nan
    if fault_ns is not None and t0_ns is not None:
        reaction = (t0_ns + abort_at * 1e9 - fault_ns) * 1e-9
    t = np.asarray(time_s, dtype=float)
    settled = abort_at + latency_s + float(params['safe_ramp_s']) + 0.01
    after = t >= settled - 1e-9
    if np.count_nonzero(after) < 5:
        return CheckResult(name, False, f'safe state at t = {abort_at:.3f} s, but the rig '
                           f'sampled {np.count_nonzero(after)} samples after its ramp ended '
                           f'(t = {settled:.3f} s; expected at least 5)',
                           {'reaction_s': reaction})
    if command_kind == rig_contract.COMMAND_KINDS[1]:
        what, unit, scale, s = 'force', 'N', 1.0, np.asarray(force_N, dtype=float)
        bound = REST_FORCE_FRACTION * amplitude_N
    else:
        what, unit, scale, s = 'velocity', 'mm/s', 1e3, np.asarray(velocity_m_s, dtype=float)
        bound = REST_VELOCITY_FRACTION * float(np.max(np.abs(s[before]), initial=0.0))
    bound += _DEPARTURE_SIGMAS * float(np.std(s[quiet]))
    rest = float(np.max(np.abs(s[after])))
    in_time = math.isfinite(reaction) and reaction <= limit
    reason = str(final.get('message', ''))
    passed = in_time and rest <= bound and reason.startswith(reason_prefix)
    return CheckResult(
        name, passed,
        f'safe state {1e3 * reaction:.1f} ms after the fault (limit {1e3 * limit:.0f} ms), '
        f'then |{what}| <= {scale * rest:.3g} {unit} after the ramp (limit '
        f'{scale * bound:.3g} {unit}); reason: {reason}'
        + (f' (expected {reason_prefix!r} ...)' if not reason.startswith(reason_prefix)
           else ''),
        {'reaction_s': reaction, 'rest_value': rest, 'rest_limit': bound})


def check_final_status(finals: Mapping[str, Mapping | None], expected_steps: int
                       ) -> CheckResult:
    """Every run ends with the rig's final report naming a compatible contract.

    Parameters
    ----------
    finals : mapping of str to mapping or None
        Run name -> the rig's final status values (None: none arrived). The step run
        (``'step'``) must end 'done' after `expected_steps` samples, a fault run 'aborted'.
    expected_steps : int
        The step run's samples.
    """
    problems = []
    for run, final in finals.items():
        if final is None:
            problems.append(f'{run}: no final status')
            continue
        state = final.get('state')
        want = 'done' if run == 'step' else 'aborted'
        if state != want:
            problems.append(f'{run}: {state!r} ({final.get("message", "")!r}), expected '
                            f'{want!r}')
        elif run == 'step' and int(final.get('published', -1)) != expected_steps:
            problems.append(f'{run}: published {final.get("published")} samples, expected '
                            f'{expected_steps}')
        contract = final.get(rig_contract.CONTRACT_KEY)
        if not rig_contract.is_compatible(contract):
            problems.append(f'{run}: contract {contract!r}, expected {rig_contract.CONTRACT}')
    if problems:
        return CheckResult('final status', False, '; '.join(problems))
    contracts = sorted({f[rig_contract.CONTRACT_KEY] for f in finals.values()})
    ends = ', '.join(f"{run} {final['state']}" for run, final in finals.items())
    return CheckResult('final status', True, f'{len(finals)} runs ended with the expected '
                       f'report ({ends}), contract {", ".join(contracts)}')


def check_bags_closed(closed: Mapping[str, bool]) -> CheckResult:
    """The recorder closed the bag of every run (`closed`: run name -> closed)."""
    open_ = [r for r, c in closed.items() if not c]
    return CheckResult('bag closed', not open_ and bool(closed),
                       f'{len(closed) - len(open_)} of {len(closed)} bags closed'
                       + (f' (not: {", ".join(open_)})' if open_ else ''))
