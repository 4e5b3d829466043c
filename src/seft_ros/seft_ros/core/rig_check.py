"""The checks of ``seft rig-check`` on arrays: does a rig node follow the rig contract?

``seft rig-check`` (``seft_ros.cli.rig_check``) runs the rest of the graph against a rig node
in real time, a few short runs with a small force (:class:`CheckProfile`), and hands what it
measured to the functions here: each returns one :class:`CheckResult`, pass or fail with the
measured value and, for a failure, the likely fault in words. They import no rclpy, so they
are tested on arrays.

The checks (:data:`CHECKS`, in the order they are reported):

``contract``
    the rig's ready report names a compatible contract, its command kind (the one the graph
    sends it) and its command latency, and it publishes every required parameter;
``clock``
    the samples are sent every ``dt`` (:func:`sample_period` within :data:`PERIOD_TOLERANCE`
    of ``dt``), and /clock is on the grid of ``CLOCK_EVERY`` samples;
``stamps``
    every sample is stamped ``k dt`` exactly (on the grid), ``k`` = 0 .. n-1 each once, and
    it was sent at its stamp's instant on the rig's clock, ``t0 + k dt`` (the median within
    :data:`STAMP_OFFSET_STEPS` periods): stamps ahead of or behind the samples are caught;
``measurement``
    every field of the contract, in its order, every value finite, every message sealed for
    the run (its frame id), and the bag's record of the samples equals the live measurement
    the graph used;
``force sign``, ``force scale``
    a static reference force gives a measured force of the same sign, with a gain within
    :data:`GAIN_RANGE` (a load cell in kN reads 0.001);
``displacement sign``, ``displacement scale``
    the static displacement has the sign of the static force (the contract's positive
    stiffness) and ``k x / f`` within :data:`UNIT_RANGE` (the specimen's configured
    stiffness; mm read 1000);
``velocity sign``, ``velocity scale``
    the velocity against the derivative of the displacement;
``acceleration sign``, ``acceleration scale``
    the acceleration against the second derivative of the displacement (not of the
    velocity: each channel is judged against the displacement alone). Both are judged
    against the displacement as it should read: a displacement found reversed or in a unit
    slip (its own checks fail) is corrected first, so that one fault fails one channel's
    checks (:func:`check_signals`);
``swapped fields``
    no two fields fit the contract better exchanged (a swap that makes every sign and scale
    check pass names the two fields);
``stuck sensor``
    no channel reads a constant: none is flat through the step run, and none repeats its
    previous value in :data:`STUCK_FRACTION` of the samples of the fault runs' sine;
``sensor noise``
    the noise of the measured force at rest, and that of the acceleration fed back as
    ``alpha m a``, stay below :data:`NOISE_FRACTION` of the instability monitor's trip level
    (the test's ``monitor_*`` parameters; :func:`check_noise`);
``command timing``
    the first sample that shows a command step is the one the contract promises
    (:func:`~seft_msgs_py.rig_contract.first_effect_step`, never earlier, at most
    :data:`TIMING_TOLERANCE_STEPS` later);
``safe state: abort``, ``safe state: stopped controller``, ``safe state: watchdog``
    the rig enters its safe state within :func:`~seft_msgs_py.rig_contract.reaction_limit_s`
    of an abort report, of the command node reporting itself stopped, and of the command node
    going silent, and is at rest after the ramp (:func:`check_safe_state`);
``second sender`` (a rig behind the UDP bridge)
    during the step run, at rest after the static force, a second sender on the checker's
    host sends the lab's controller a start flag of a session of its own and a few 0 V
    commands: the controller answers it nothing, names the refusal in the reason of its
    datagrams to the live PC, and the run goes on to its end (:func:`check_second_sender`;
    the rig contract's session rules);
``final status``
    every run ends with the rig's final report (done after the run's samples, or aborted
    with its reason), which names a compatible contract;
``bag closed``
    the recorder closed every bag.
"""

from dataclasses import dataclass, field
import itertools
import math
from typing import Mapping, Sequence

import numpy as np
from scipy import signal

from seft_msgs_py import rig_contract
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.signals import CLOCK_EVERY, MEASUREMENT_FIELDS

__all__ = [
    'CheckProfile', 'CheckResult', 'CHECKS', 'FAULT_RUNS', 'QUANTITIES', 'SIGNAL_CHECKS',
    'PERIOD_TOLERANCE', 'STAMP_OFFSET_STEPS', 'GAIN_RANGE', 'UNIT_RANGE', 'UNIT_SLIPS',
    'MIN_CORRELATION', 'STUCK_FRACTION', 'NOISE_FRACTION', 'TIMING_TOLERANCE_STEPS',
    'REST_FORCE_FRACTION', 'REST_VELOCITY_FRACTION', 'REST_GROWTH_FRACTION', 'check_contract',
    'sample_period',
    'check_clock', 'check_stamps', 'check_measurement', 'check_signals', 'check_stuck',
    'check_noise', 'check_command_timing', 'check_safe_state', 'check_final_status',
    'check_bags_closed', 'first_departure', 'not_run', 'format_line', 'SECOND_SENDER',
    'check_second_sender', 'checks_for', 'held_force', 'start_withheld',
]

#: The faults of the safe-state runs: run name -> check name.
FAULT_RUNS = {'abort': 'safe state: abort', 'stopped_controller': 'safe state: stopped '
              'controller', 'watchdog': 'safe state: watchdog'}
#: The measurement's four quantities, in the contract's field order
#: (:data:`~seft_msgs_py.signals.MEASUREMENT_FIELDS`).
QUANTITIES = ('force', 'displacement', 'velocity', 'acceleration')
#: The sign and scale check of each quantity.
SIGNAL_CHECKS = tuple(f'{q} {what}' for q in QUANTITIES for what in ('sign', 'scale'))
#: Every check, in report order.
#: The check of the controller's session rules (a rig behind the UDP bridge only).
SECOND_SENDER = 'second sender'
CHECKS = ('contract', 'clock', 'stamps', 'measurement', *SIGNAL_CHECKS, 'swapped fields',
          'stuck sensor', 'sensor noise', 'command timing', *FAULT_RUNS.values(),
          SECOND_SENDER, 'final status', 'bag closed')


def checks_for(udp_bridge: bool) -> tuple[str, ...]:
    """The checks of a rig, in report order: :data:`CHECKS`, the ``second sender`` only for
    a rig behind the UDP bridge (`udp_bridge`)."""
    return CHECKS if udp_bridge else tuple(c for c in CHECKS if c != SECOND_SENDER)
#: Largest relative error of the measured sample period (a straight-line fit of the arrival
#: times) [-]: a rig clock 2 % slow fails.
PERIOD_TOLERANCE = 0.02
#: Largest median offset of a sample's sending from its stamp's instant ``t0 + k dt`` on the
#: rig's clock, in periods [-]: a rig's samples leave a fraction of a period after their
#: instant (measured here: 0.12 ms median at 2 ms); a stamp two samples off is 2 periods.
STAMP_OFFSET_STEPS = 1.5
#: The first samples whose sending the stamps check also reads apart [-]: a rig whose first
#: ones went out on time and whose median is late fell behind after its start.
STAMP_EARLY_SAMPLES = 50
#: Allowed static gain measured force / reference force [-] (the force loop's static error
#: of a real rig, a load cell's calibration).
GAIN_RANGE = (0.8, 1.2)
#: Allowed ratio of a channel to what it must be (the derivative of the displacement, the
#: static displacement ``f / k``) [-]: wide for noise and for an uncertain stiffness, narrow
#: against a unit slip (a factor of at least 9.8).
UNIT_RANGE = (0.5, 2.0)
#: The unit slips a lab makes, per quantity: (what the channel reads in SI units' stead
#: [-], in words). A scale outside its range names the slip whose factor it is within
#: :data:`UNIT_RANGE` of.
UNIT_SLIPS = {
    'force': ((1e-3, 'kN instead of N'), (0.224809, 'lbf instead of N'),
              (2.24809e-4, 'kip instead of N'), (1e3, 'mN instead of N')),
    'displacement': ((1e3, 'mm instead of m'), (1e2, 'cm instead of m'),
                     (1e6, 'um instead of m'), (39.3701, 'in instead of m')),
    'velocity': ((1e3, 'mm/s instead of m/s'), (1e2, 'cm/s instead of m/s'),
                 (39.3701, 'in/s instead of m/s')),
    'acceleration': ((1 / 9.80665, 'g instead of m/s^2'), (1e3, 'mm/s^2 instead of m/s^2'),
                     (1e2, 'cm/s^2 instead of m/s^2')),
}
#: Least correlation of the velocity (acceleration) with the derivative (second derivative)
#: of the displacement for its sign to be judged [-]; below it the channel does not follow.
MIN_CORRELATION = 0.5
#: A channel that repeats its previous value exactly in this fraction of the samples of a
#: sine is stuck [-] (a moving, noisy or finely quantized channel repeats a few).
STUCK_FRACTION = 0.9
#: The noise at rest may take at most this fraction of the instability monitor's trip level
#: [-]: its running RMS over 0.2 s fluctuates by about 15 %, and the test's response needs
#: the rest.
NOISE_FRACTION = 0.5
#: How many samples later than promised a command may first show [-]: a valve command moves
#: the force slowly at first (the spool's lag), and a real load cell's noise hides it longer.
TIMING_TOLERANCE_STEPS = 3
#: At rest on a force-commanded rig: |f| at most this fraction of the amplitude (+ noise).
REST_FORCE_FRACTION = 0.1
#: At rest on a valve-commanded rig (valve closed, the actuator holds): |v| at most this
#: fraction of the peak velocity of the last cycle before the fault (+ noise); the oil that
#: the specimen's force pushes through the closed valve and the seals lets it creep. The
#: creep follows the held force, the sine's peak velocity falls as 1/k: measured on both
#: piers of config/two_piers.yaml (k and 1.6 k), watchdog 20 and 50 ms, a closed valve
#: creeps at 0.16-0.28 of the peak and a valve held open moves at 0.43-0.59 (0.25 failed
#: the stiffer pier's watchdog run). The creep is proportional to the force held: a larger
#: one that the creep relaxes raises the bound in proportion (:func:`held_force`), and a
#: force that grows at rest (a valve held open) fails (:data:`REST_GROWTH_FRACTION`).
REST_VELOCITY_FRACTION = 0.35
#: At rest on a valve-commanded rig, ``|f|`` may grow by at most this fraction of the
#: amplitude (+ noise) over the samples after the ramp: a closed valve's creep relaxes the
#: force, a valve held open loads the specimen further. Measured on both piers of
#: config/two_piers.yaml, watchdog 20 ms to 0.5 s: seft's rig relaxes by 7-25 N over its
#: 50 ms at rest, a valve held open loads by 6.7-28 N (at 0.5 s the load pressure nearly
#: stalls it) for an amplitude of 100 N.
REST_GROWTH_FRACTION = 0.02
#: A departure from rest is this many standard deviations of the quiet samples, at least
#: ``1e-3`` of the step (noise-free simulated rigs).
_DEPARTURE_SIGMAS = 6.0
#: A static change is judged when it exceeds this many standard deviations of its noise.
_SIGNIFICANT_SIGMAS = 6.0
#: Cut-off of the low-pass filter applied alike to a channel and to the derivative it is
#: compared with, as a fraction of the sample rate [-] (10 %: 50 Hz at 2 ms; a differentiated
#: displacement's noise grows with frequency).
_DERIVATIVE_CUTOFF = 0.1


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
    so that a rig that holds its last command, force or valve opening, is seen), or, when the
    checker heard that sample late, a whole cycle later (``fault_chances`` in all:
    :attr:`fault_steps`), and the run would go on ``after_fault_s`` after the last chance.
    The default 2 cycles and 45 degrees at 2 Hz put the fault 1.56 s into the run, its last
    chance 2.56 s: a checker that discovers the rig late (measured here: up to 1.3 s after it
    started, on two loaded cores) hears it live by then. Not earlier than 2 cycles: the
    first cycle from rest carries the specimen's transient, its peak velocity (the valve
    rig's rest bound, :func:`check_safe_state`) 1.5 times the steady cycle's, and a valve
    held open after the fault passed on the stiffer pier of ``config/two_piers.yaml`` (its
    velocity 1.00 of that bound; 1.38 of the second cycle's).

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
        When the fault comes at its first chance, in cycles of the sine [-] (default 2.125).
    fault_chances : int >= 1
        How many chances, a cycle apart, the fault has (default 3).

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
    fault_cycles: float = 2.125
    after_fault_s: float = 1.0
    fault_chances: int = 3

    def __post_init__(self):
        for name in ('dt', 'amplitude_N', 'quiet_s', 'hold_s', 'release_s', 'sine_hz',
                     'fault_cycles', 'after_fault_s'):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        if (isinstance(self.fault_chances, bool) or not isinstance(self.fault_chances, int)
                or self.fault_chances < 1):
            raise ParameterError(f'fault_chances={self.fault_chances!r}: expected a whole '
                                 'number >= 1')
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
    def quiet(self) -> slice:
        """The step run's samples at rest before the static force."""
        return slice(0, self.onset_step)

    @property
    def hold(self) -> slice:
        """The step run's settled static force: its last three quarters (a force loop has
        settled and the specimen's ringing averages out)."""
        h = self._steps(self.hold_s)
        return slice(self.onset_step + h // 4, self.onset_step + h)

    @property
    def rest(self) -> tuple[slice, slice]:
        """The step run's samples at rest: before the static force, and the second half of
        the release."""
        end = self.onset_step + self._steps(self.hold_s)
        r = self._steps(self.release_s)
        return self.quiet, slice(end + r // 2, end + r)

    @property
    def second_sender_step(self) -> int:
        """The step run's sample after which a second sender tries the lab's controller (a
        rig behind the UDP bridge): a quarter into the release, at rest, three quarters of
        the release before the run's end [-]."""
        return self.onset_step + self._steps(self.hold_s) + self._steps(self.release_s) // 4

    @property
    def fault_steps(self) -> tuple[int, ...]:
        """The samples after which the fault runs' fault may be injected, in order: its
        first chance, then a whole cycle later each [-]."""
        return tuple(self.onset_step + self._steps((self.fault_cycles + j) / self.sine_hz)
                     for j in range(self.fault_chances))

    @property
    def fault_step(self) -> int:
        """The fault's first chance (:attr:`fault_steps`) [-]."""
        return self.fault_steps[0]

    def sine_reference(self) -> np.ndarray:
        """A fault run's reference force ``f_r[k]`` [N], shape (n,): to ``after_fault_s``
        after the fault's last chance."""
        n = self.fault_steps[-1] + self._steps(self.after_fault_s)
        k = np.arange(n)
        t = (k - self.onset_step) * self.dt
        return np.where(k >= self.onset_step,
                        self.amplitude_N * np.sin(2 * np.pi * self.sine_hz * t), 0.0)


# -- the checks -------------------------------------------------------------------------------

def check_contract(ready: Mapping | None, rig_params: Mapping | None, command_kind: str,
                   unsealed: Sequence[Mapping] = (), seal: str = '') -> CheckResult:
    """The rig says which contract it follows, what it takes, and takes the parameters.

    Parameters
    ----------
    ready : mapping or None
        The rig's 'ready' status values (the first that carries ``contract``) among the
        reports with the run's seal, None if none.
    rig_params : mapping or None
        The parameters the rig published on ``/seft/node_parameters``.
    command_kind : str
        The command the graph sends it (``rig_contract.command_kind`` of the run).
    unsealed : sequence of mapping
        The rig's status reports without the run's seal (a rig of contract 2.0: the graph
        drops them), each its values with ``hardware_id``.
    seal : str
        What seals the run, in words (``RunSeal.describe``).

    Returns
    -------
    CheckResult
        ``values``: ``contract``, ``command_latency_s`` [s], ``missing_parameters`` and,
        when it passes, ``undeclared_ranges`` (of ``rig_contract.RANGE_PARAMETERS``);
        ``unsealed_reports`` when the rig's reports were not sealed.
    """
    if not ready and unsealed:
        contract = next((u[rig_contract.CONTRACT_KEY] for u in unsealed
                         if rig_contract.CONTRACT_KEY in u), None)
        ids = sorted({str(u.get('hardware_id', '')) for u in unsealed})
        return CheckResult(
            'contract', False, f"the rig's {len(unsealed)} status reports do not carry the "
            f"run's seal (hardware id {', '.join(map(repr, ids))}"
            + (f'; {seal}' if seal else '') + '): '
            + rig_contract.unsealed_status_advice(contract),
            {'contract': contract, 'unsealed_reports': len(unsealed)})
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
    # the sensors' ranges (contract 1.1): a rig that does not publish them is taken with the
    # configuration's (said, not failed)
    undeclared = [p for p in rig_contract.RANGE_PARAMETERS if p not in (rig_params or {})]
    values['undeclared_ranges'] = undeclared
    ranges = (f'; ranges not declared: {", ".join(undeclared)} (the configuration\'s are '
              'taken)' if undeclared else
              f', {len(rig_contract.RANGE_PARAMETERS)} ranges declared')
    return CheckResult('contract', True, f'{contract}, takes {command_kind}, command latency '
                       f'{1e3 * latency:g} ms, {n} of {n} required parameters published'
                       + ranges, values)


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


def check_clock(steps: Sequence[int], arrival_s: Sequence[float], dt: float, *,
                clock_ns: Sequence[int] | None = None) -> CheckResult:
    """The rig's clock ticks every dt, and /clock follows it.

    Parameters
    ----------
    steps : sequence of int, shape (n,)
        Sample index ``round(stamp / dt)`` of each live measurement, in arrival order.
    arrival_s : sequence of float, shape (n,)
        When the rig sent each [s] (the DDS source timestamp: a sample the checker hears late
        keeps it).
    dt : float > 0
        Control period [s].
    clock_ns : sequence of int, optional
        The ``/clock`` values received [ns] (the rig is the clock master): each must be a
        sample time and follow the previous one by ``CLOCK_EVERY dt``. None: not checked.

    Returns
    -------
    CheckResult
        ``values``: ``period_s`` (:func:`sample_period`), ``samples``, ``clock_messages``,
        ``clock_bad`` (/clock values off the grid or out of step).
    """
    steps = np.asarray(steps, dtype=np.int64)
    if steps.size < 10:
        return CheckResult('clock', False, f'{steps.size} samples arrived (expected at least '
                           '10)', {'samples': int(steps.size)})
    dt_ns = int(round(dt * 1e9))
    period = sample_period(steps, arrival_s)
    error = period / dt - 1.0
    passed = abs(error) <= PERIOD_TOLERANCE
    text = (f'period {1e3 * period:.4f} ms ({100 * error:+.2f} % of dt {1e3 * dt:g} ms, limit '
            f'{100 * PERIOD_TOLERANCE:g} %) over {steps.size} samples')
    if not passed:
        text += (": the rig's clock runs " + ('slow' if error > 0 else 'fast')
                 + ': check its timer, or a loop that takes longer than dt')
    values = {'period_s': period, 'samples': int(steps.size)}
    if clock_ns is not None:
        c = np.asarray(clock_ns, dtype=np.int64)
        bad = int(np.count_nonzero(c % dt_ns)
                  + np.count_nonzero(np.diff(c) != CLOCK_EVERY * dt_ns))
        passed = passed and c.size > 0 and bad == 0
        text += f'; /clock {c.size} messages, {bad} off the grid of {CLOCK_EVERY} samples'
        values.update(clock_messages=int(c.size), clock_bad=bad)
    return CheckResult('clock', passed, text, values)


def check_stamps(stamps_ns: Sequence[int], sent_s: Sequence[float], dt: float, *,
                 expected: int, t0_ns: int | None) -> CheckResult:
    """Every sample is stamped ``t_k = k dt`` exactly, once, and sent at that instant.

    Parameters
    ----------
    stamps_ns : sequence of int, shape (n,)
        The live measurements' header stamps [ns], in arrival order.
    sent_s : sequence of float, shape (n,)
        When the rig sent each [s, system clock] (the DDS source timestamp).
    dt : float > 0
        Control period [s].
    expected : int
        How many samples the rig should have published (``0 .. expected - 1``).
    t0_ns : int or None
        The rig's ``t0_ns`` (system-clock time of its sample 0) [ns]; None: the sending is
        not judged.

    Returns
    -------
    CheckResult
        ``values``: ``off_grid`` (stamps not a whole number of periods), ``missing``,
        ``repeated``, ``outside`` (a step below 0 or from `expected` on),
        ``median_offset_s`` (median of ``sent - (t0 + stamp)``, nan without `t0_ns`) [s].

    Notes
    -----
    A sample leaves the rig just after its instant (a fraction of a period); a rig whose
    stamps run ahead of its samples sends them before their instants, one whose samples wait
    in a buffer sends them after; :data:`STAMP_OFFSET_STEPS` periods either way fail.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    if stamps.size == 0:
        return CheckResult('stamps', False, f'0 samples arrived (expected {expected})')
    dt_ns = int(round(dt * 1e9))
    off_grid = int(np.count_nonzero(stamps % dt_ns))
    steps = np.round(stamps / dt_ns).astype(np.int64)
    unique, counts = np.unique(steps, return_counts=True)
    repeated = int(np.count_nonzero(counts > 1))
    inside = (unique >= 0) & (unique < expected)
    missing = int(expected - np.count_nonzero(inside))
    outside = int(np.count_nonzero(~inside))
    offset = early = math.nan
    if t0_ns is not None:
        offsets = np.asarray(sent_s, dtype=float) - (t0_ns + stamps) * 1e-9
        offset = float(np.median(offsets))
        first = np.argsort(stamps, kind='stable')[:STAMP_EARLY_SAMPLES]
        early = float(np.median(offsets[first]))
    limit = STAMP_OFFSET_STEPS * dt
    faults = []
    if off_grid:
        faults.append('stamps off the grid of k dt: stamp each sample with k dt_ns in '
                      'integer ns, not with a clock reading')
    if outside:
        first = int(steps.min())
        faults.append(f'the stamps are not 0 .. {expected - 1} (the first says step '
                      f'{first}): number the samples from 0, one step each')
    elif missing:
        faults.append(f'{missing} samples never published: a late tick is caught up, never '
                      'skipped')
    if repeated:
        faults.append(f'{repeated} steps published more than once')
    if offset < -limit:
        faults.append(f"sent {-1e3 * offset:.1f} ms before their stamps' instants: the "
                      f'stamps run {-offset / dt:.1f} samples ahead of the samples')
    elif offset > limit:
        if abs(early) <= limit:
            faults.append(f"sent {1e3 * offset:.1f} ms after their stamps' instants, the "
                          f'first {min(STAMP_EARLY_SAMPLES, stamps.size)} a median '
                          f'{1e3 * early:.2f} ms: the rig fell {offset / dt:.1f} samples '
                          'behind after its start and did not catch up (a tick that takes '
                          'longer than dt, or samples taken one a wake-up while more wait)')
        else:
            faults.append(f"sent {1e3 * offset:.1f} ms after their stamps' instants: the "
                          f'samples are {offset / dt:.1f} samples late (a buffer between the '
                          'sensors and the node?) or stamped early')
    when = (', no t0_ns in the running reports: the sending not judged' if t0_ns is None
            else f', sent a median {1e3 * offset:.2f} ms after t0 + k dt (limit '
            f'+/-{1e3 * limit:g} ms)')
    text = (f'{off_grid} off the grid, {missing} missing, {repeated} repeated, {outside} '
            f'outside 0..{expected - 1} of {stamps.size} samples{when}')
    return CheckResult('stamps', not faults, text + ''.join(f'; {f}' for f in faults),
                       {'off_grid': off_grid, 'missing': missing, 'repeated': repeated,
                        'outside': outside, 'median_offset_s': offset})


def check_measurement(names: Sequence[str], values: np.ndarray,
                      record: np.ndarray | None = None, *, unsealed: int = 0,
                      frame_id: str = '', seal: str = '') -> CheckResult:
    """The measurement has every field of the contract, in order, every value finite,
    every message sealed for the run, and the bag's record of each sample equals it.

    Parameters
    ----------
    names : sequence of str
        The ``name`` list of the live measurement messages (the first one's; '' entries
        where messages disagreed).
    values : ndarray, shape (n, m)
        Their ``position`` values, one row per sample.
    record : ndarray, shape (n, 4), optional
        The bag's sensor rows of the same samples, row for row (NaN where the bag lacks
        one), in the order of :data:`~seft_msgs_py.signals.MEASUREMENT_FIELDS`.
    unsealed : int
        Messages whose frame id was not the run's seal of them
        (:class:`~seft_msgs_py.provenance.RunSeal`; the graph's nodes drop them).
    frame_id : str
        The first such message's frame id.
    seal : str
        What seals the run, in words (``RunSeal.describe``).

    Returns
    -------
    CheckResult
        ``values``: ``not_finite``, ``samples``, ``record_differs`` (samples whose record
        differs from the live value by more than 1e-9 of it), ``unsealed``.
    """
    values = np.asarray(values, dtype=float)
    if tuple(names) != MEASUREMENT_FIELDS:
        return CheckResult('measurement', False, f'fields {list(names)}, expected '
                           f'{list(MEASUREMENT_FIELDS)}: name the fields as the contract '
                           'does, in its order')
    if values.ndim != 2 or values.shape[1] != len(MEASUREMENT_FIELDS) or not values.size:
        return CheckResult('measurement', False, f'values of shape {values.shape}, expected '
                           f'(n, {len(MEASUREMENT_FIELDS)})')
    bad = int(np.count_nonzero(~np.isfinite(values).all(axis=1)))
    differs = 0
    text = (f'{len(MEASUREMENT_FIELDS)} fields in order, {bad} of {values.shape[0]} samples '
            'with a value not finite')
    if record is not None:
        rec = np.asarray(record, dtype=float)
        both = np.isfinite(rec).all(axis=1) & np.isfinite(values).all(axis=1)
        gap = np.abs(rec[both] - values[both]) > 1e-9 * np.maximum(np.abs(values[both]), 1e-300)
        differs = int(np.count_nonzero(gap.any(axis=1)))
        text += (f"; the bag's record differs in {differs} of {int(both.sum())} samples"
                 + (' (the record stream must carry the samples the rig published)'
                    if differs else ''))
    if unsealed:
        text += (f"; {unsealed} of {values.shape[0]} messages without the run's seal (frame "
                 f"id {frame_id!r}; {seal}): the graph's nodes drop them; a rig puts the "
                 "run's seal in header.frame_id (rig contract: the run's seal)")
    elif seal:
        text += '; every message sealed for the run'
    return CheckResult('measurement', bad == 0 and differs == 0 and not unsealed, text,
                       {'not_finite': bad, 'samples': int(values.shape[0]),
                        'record_differs': differs, 'unsealed': int(unsealed)})


# -- the signals: sign and scale of each quantity ------------------------------------------------

@dataclass(frozen=True)
class _Fit:
    """A channel against what it must be: ``ratio`` (its reading over the reference's, as the
    reference should read), ``correlation`` (nan for a static comparison), whether the
    comparison says anything (``judged``) and, if not, why."""

    ratio: float
    correlation: float = math.nan
    judged: bool = True
    why: str = ''
    detail: str = ''


def _slip(quantity: str, ratio: float) -> tuple[float, str] | None:
    """The unit slip of `quantity` that `ratio` (> 0) is within :data:`UNIT_RANGE` of, the
    nearest one; None if none."""
    lo, hi = UNIT_RANGE
    found = [(abs(math.log(ratio / f)), f, what) for f, what in UNIT_SLIPS[quantity]
             if lo <= ratio / f <= hi]
    return min(found)[1:] if found else None


def _reading(quantity: str, fit: _Fit) -> float | None:
    """How a channel reads against SI with the contract's sign: its sign times the unit slip
    its ratio shows (1 if none): what a channel derived from it must be corrected by. None
    when its fit said nothing."""
    if not fit.judged or not math.isfinite(fit.ratio) or fit.ratio == 0:
        return None
    lo, hi = UNIT_RANGE
    size = abs(fit.ratio)
    slip = _slip(quantity, size) if not lo <= size <= hi else None
    return math.copysign(slip[0] if slip else 1.0, fit.ratio)


def _static_fit(s: np.ndarray, hold: slice, rest: Sequence[slice], per_unit: float,
                detail: str = '') -> _Fit:
    """The change of `s` from rest to the static force, over `per_unit` (what it must be);
    `detail` is formatted with the change."""
    h = s[hold]
    r = np.concatenate([s[sl] for sl in rest])
    if not h.size or not r.size:
        return _Fit(math.nan, judged=False, why='the run ended before the static force '
                    'settled')
    change = float(np.mean(h) - np.mean(r))
    noise = math.sqrt(float(np.var(h)) / h.size + float(np.var(r)) / r.size)
    if not (math.isfinite(change) and abs(change) > _SIGNIFICANT_SIGMAS * noise
            and change != 0.0):
        return _Fit(change / per_unit, judged=False,
                    why=f'it did not move under the static force (a change of {change:.3g} '
                    f'against a noise of {noise:.3g}): a stuck or disconnected channel?')
    return _Fit(change / per_unit, detail=detail.format(change=change))


def _lowpass(dt: float):
    return signal.butter(2, _DERIVATIVE_CUTOFF / dt, fs=1.0 / dt)


def _derivative_fit(y: np.ndarray, reference: np.ndarray, dt: float, rest: Sequence[slice],
                    reading: float | None, what: str) -> _Fit:
    """`y` against `reference` (a derivative of the displacement), both low-passed alike:
    the least-squares ratio and the correlation, corrected by the displacement's `reading`."""
    if reading is None:
        return _Fit(math.nan, judged=False, why='the displacement it is checked against '
                    'says nothing (see displacement sign)')
    offset = float(np.mean(np.concatenate([y[sl] for sl in rest])))
    b, a = _lowpass(dt)
    yf = signal.filtfilt(b, a, y - offset)
    rf = signal.filtfilt(b, a, reference) / reading       # the derivative as it should read
    den = float(np.dot(rf, rf))
    norm = math.sqrt(den * float(np.dot(yf, yf)))
    if not (den > 0 and math.isfinite(den)):
        return _Fit(math.nan, judged=False, why=f'{what} is flat')
    ratio = float(np.dot(yf, rf)) / den
    corr = float(np.dot(yf, rf)) / norm if norm > 0 else 0.0
    if not abs(corr) >= MIN_CORRELATION:
        return _Fit(ratio, corr, judged=False,
                    why=f'it does not follow {what} (correlation {corr:.2f}, expected at '
                    f'least {MIN_CORRELATION:g} in magnitude): a stuck, swapped or '
                    'disconnected channel?')
    return _Fit(ratio, corr)


#: The likely fault of a reversed channel, in words.
_REVERSED = {
    'force': "the measured force is reversed against the reference: check the load cell's "
             'sign (its wiring or calibration) or the sign in your rig node',
    'displacement': "displacement reversed against the force: check the transducer's "
                    'mounting or the sign in your rig node',
    'velocity': 'velocity reversed against the derivative of the displacement: check its '
                'sign in your rig node, or the transducer it comes from',
    'acceleration': 'acceleration reversed against the second derivative of the '
                    "displacement: check the accelerometer's mounting or the sign in your "
                    'rig node (the builder would feed back -a: the computational mass '
                    'acting with the wrong sign)',
}
#: What to check when a scale is off and no unit slip explains it.
_CALIBRATION = {
    'force': "check the load cell's calibration",
    'displacement': "check stiffness_N_per_m (the specimen configured) or the transducer's "
                    'calibration',
    'velocity': "check the velocity channel's calibration",
    'acceleration': "check the accelerometer's calibration",
}
#: What each quantity is compared with, in words, and the ratio reported.
_AGAINST = {'force': 'the reference force f_r', 'displacement': 'the static f_r / k',
            'velocity': 'dx/dt', 'acceleration': 'd2x/dt2'}
_RATIO = {'force': 'f / f_r', 'displacement': 'k x / f_r', 'velocity': 'v / (dx/dt)',
          'acceleration': 'a / (d2x/dt2)'}


def _signal_fits(fields: Sequence[np.ndarray], *, dt: float, amplitude_N: float,
                 stiffness_N_per_m: float, hold: slice, rest: Sequence[slice],
                 displacement: np.ndarray | None = None) -> dict:
    """Quantity -> its :class:`_Fit`, and ``'reading'`` -> the displacement's reading (the
    reference of the velocity and acceleration: `displacement`, default the field's)."""
    f, x, v, a = fields
    fits = {'force': _static_fit(f, hold, rest, amplitude_N,
                                 f' (f {{change:.4g}} N for f_r {amplitude_N:g} N)'),
            'displacement': _static_fit(x, hold, rest, amplitude_N / stiffness_N_per_m,
                                        f' (x {{change:.4g}} m for f_r {amplitude_N:g} N)')}
    if displacement is None:
        displacement, reading = x, _reading('displacement', fits['displacement'])
    else:
        reading = _reading('displacement', _static_fit(displacement, hold, rest,
                                                       amplitude_N / stiffness_N_per_m))
    dx = np.gradient(displacement, dt)
    fits['velocity'] = _derivative_fit(v, dx, dt, rest, reading, 'dx/dt')
    fits['acceleration'] = _derivative_fit(a, np.gradient(dx, dt), dt, rest, reading,
                                           'd2x/dt2')
    fits['reading'] = reading
    return fits


def _sign_and_scale(quantity: str, fit: _Fit, reading: float | None,
                    stiffness_N_per_m: float) -> tuple[CheckResult, CheckResult]:
    """The two checks of one quantity from its fit."""
    sign, scale = f'{quantity} sign', f'{quantity} scale'
    against = _AGAINST[quantity]
    corrected = ''
    if quantity in ('velocity', 'acceleration') and reading not in (None, 1.0):
        corrected = (f', against the displacement corrected by {reading:g} (see '
                     'displacement sign and scale)')
    corr = (f', correlation {fit.correlation:+.2f}' if math.isfinite(fit.correlation)
            else '')
    values = {'ratio': fit.ratio, 'correlation': fit.correlation}
    if not fit.judged:
        return (CheckResult(sign, False, f'{quantity} against {against}: {fit.why}', values),
                CheckResult(scale, False, f'{quantity} against {against}: {fit.why}',
                            values))
    ratio = _RATIO[quantity]
    measured = f'{ratio} = {fit.ratio:+.3g}{fit.detail}{corr}{corrected}'
    positive = fit.ratio > 0
    sign_result = CheckResult(sign, positive, measured + ('' if positive else
                                                          f': {_REVERSED[quantity]}'), values)
    lo, hi = GAIN_RANGE if quantity == 'force' else UNIT_RANGE
    size = abs(fit.ratio)
    ok = lo <= size <= hi
    text = f'|{ratio}| = {size:.3g} (expected {lo:g}..{hi:g}'
    text += f'; k = {stiffness_N_per_m:g} N/m)' if quantity == 'displacement' else ')'
    if not ok:
        slip = _slip(quantity, size)
        text += (f': the {quantity} reads {size:.3g} times what it should: '
                 + (f'{slip[1]}?' if slip else _CALIBRATION[quantity]))
    return sign_result, CheckResult(scale, ok, text, values)


def _signal_results(fields, *, stiffness_N_per_m: float, **kw) -> dict:
    fits = _signal_fits(fields, stiffness_N_per_m=stiffness_N_per_m, **kw)
    out = {}
    for q in QUANTITIES:
        out[f'{q} sign'], out[f'{q} scale'] = _sign_and_scale(q, fits[q], fits['reading'],
                                                              stiffness_N_per_m)
    return out


def check_signals(fields: Sequence[np.ndarray], *, dt: float, amplitude_N: float,
                  stiffness_N_per_m: float, hold: slice, rest: Sequence[slice]
                  ) -> list[CheckResult]:
    """The sign and scale of each quantity of the measurement, and swapped fields.

    Parameters
    ----------
    fields : sequence of 4 ndarray, each shape (n,)
        The step run's samples by step, in the contract's order
        (:data:`~seft_msgs_py.signals.MEASUREMENT_FIELDS`): force [N], displacement [m],
        velocity [m/s], acceleration [m/s^2].
    dt : float > 0
        Control period [s].
    amplitude_N : float > 0
        The static reference force [N].
    stiffness_N_per_m : float > 0
        The specimen's stiffness as configured [N/m].
    hold : slice
        The samples of the settled static force.
    rest : sequence of slice
        The samples at rest.

    Returns
    -------
    list of CheckResult
        :data:`SIGNAL_CHECKS` in order, then ``swapped fields``. ``values`` of each sign and
        scale check: ``ratio`` (the channel over what it must be) and ``correlation``.

    Notes
    -----
    The force is compared with the reference force, the static displacement with
    ``f_r / k`` (the reference force, not the measured one: a load cell's fault is the
    force's alone; the contract's positive stiffness: a positive static force gives a
    positive displacement), the velocity with ``dx/dt`` and the acceleration with
    ``d2x/dt2`` (central differences, ``numpy.gradient``), each after the same zero-phase
    2nd-order Butterworth low-pass at a tenth of the sample rate (a differentiated
    displacement's noise grows with frequency): a least-squares ratio, judged when the
    correlation is at least :data:`MIN_CORRELATION` in magnitude. The derivatives are of the
    displacement as it should read: a displacement found reversed, or in a unit slip of
    :data:`UNIT_SLIPS`, is corrected first, so that a fault of the displacement alone fails
    the displacement's checks alone, and one transducer mounted the other way round (the
    displacement, velocity and acceleration all reversed) fails all three signs.

    Swapped fields: when a check fails, each pair of fields is exchanged in turn; a pair
    whose exchange makes every sign and scale check pass is named (and a displacement found
    in another field is then the reference of the velocity and acceleration).
    """
    fields = [np.asarray(s, dtype=float) for s in fields]
    kw = dict(dt=dt, amplitude_N=amplitude_N, stiffness_N_per_m=stiffness_N_per_m,
              hold=hold, rest=rest)
    results = _signal_results(fields, **kw)
    swapped = None
    if not all(r.passed for r in results.values()):
        for i, j in itertools.combinations(range(len(fields)), 2):
            trial = list(fields)
            trial[i], trial[j] = fields[j], fields[i]
            if all(r.passed for r in _signal_results(trial, **kw).values()):
                swapped = (i, j)
                break
    if swapped is None:
        tried = ('' if all(r.passed for r in results.values())
                 else f'; no exchange of two of the {len(fields)} fields makes the signals '
                 'pass')
        swap = CheckResult('swapped fields', True, 'each field fits its own place' + tried)
    else:
        i, j = swapped
        names = f'{MEASUREMENT_FIELDS[i]} and {MEASUREMENT_FIELDS[j]}'
        swap = CheckResult('swapped fields', False, f'{names} look swapped: exchanged, every '
                           'sign and scale check passes; check the order of the fields your '
                           f'rig node publishes ({", ".join(MEASUREMENT_FIELDS)})',
                           {'swapped': [MEASUREMENT_FIELDS[i], MEASUREMENT_FIELDS[j]]})
        if 1 in swapped:          # the displacement is in the other field
            moved = _signal_results(fields, displacement=fields[i + j - 1], **kw)
            for q in ('velocity', 'acceleration'):
                for what in ('sign', 'scale'):
                    results[f'{q} {what}'] = moved[f'{q} {what}']
    reversed_ = [q for q in ('displacement', 'velocity', 'acceleration')
                 if results[f'{q} sign'].values.get('ratio', 0) < 0
                 and not results[f'{q} sign'].passed]
    if swapped is None and len(reversed_) == 3:
        r = results['displacement sign']
        results['displacement sign'] = CheckResult(
            r.name, False, r.measured + '; the velocity and acceleration read reversed too: '
            'one transducer mounted the other way round (the velocity and acceleration '
            'taken from it), or the axis of your rig node reversed', r.values)
    return [results[n] for n in SIGNAL_CHECKS] + [swap]


def check_stuck(step: Sequence[np.ndarray], sine: Sequence[np.ndarray] | None
                ) -> CheckResult:
    """No channel reads a constant.

    Parameters
    ----------
    step : sequence of 4 ndarray, each shape (n,)
        The step run's samples, in the contract's field order.
    sine : sequence of 4 ndarray, each shape (m,), or None
        A fault run's samples while the sine plays (before its fault); None: none was run.

    Returns
    -------
    CheckResult
        ``values``: ``stuck`` (the fields found stuck), ``repeats`` (field -> the fraction of
        the sine's samples equal to the previous one).

    Notes
    -----
    Stuck: flat (peak to peak zero) through the whole step run, or repeating its previous
    value exactly in at least :data:`STUCK_FRACTION` of the sine's samples. A channel moves
    all through a sine; in the step run a force-controlled rig's force may hold exactly.
    """
    stuck, repeats = [], {}
    for i, name in enumerate(MEASUREMENT_FIELDS):
        s = np.asarray(step[i], dtype=float)
        flat = s.size > 1 and float(np.ptp(s)) == 0.0
        if sine is not None and len(sine[i]) > 1:
            w = np.asarray(sine[i], dtype=float)
            repeats[name] = float(np.mean(w[1:] == w[:-1]))
        if flat or repeats.get(name, 0.0) >= STUCK_FRACTION:
            stuck.append(name)
    where = ('the step run' + (f' and {max(len(s) for s in sine)} samples of a sine'
                               if sine is not None else ' (no sine run)'))
    most = max(repeats.items(), key=lambda kv: kv[1], default=None)
    text = f'{len(stuck)} of {len(MEASUREMENT_FIELDS)} fields stuck over {where}'
    if most is not None:
        text += f" (most repeats: {most[0]}, {100 * most[1]:.0f} % of the sine's samples)"
    if stuck:
        text += (f': {", ".join(stuck)} read a constant: a stuck or disconnected sensor, or a '
                 'rig node that does not update the field')
    return CheckResult('stuck sensor', not stuck, text, {'stuck': stuck, 'repeats': repeats})


def check_noise(force_N, acceleration_m_s2, quiet: slice, *, dt: float, alpha: float,
                mass_kg: float, cutoff_hz: float, threshold: float, floor_N: float
                ) -> CheckResult:
    """The sensors' noise at rest would not trip the instability monitor.

    Parameters
    ----------
    force_N, acceleration_m_s2 : ndarray, shape (n,)
        The step run's measured force [N] and acceleration [m/s^2].
    quiet : slice
        The samples at rest before the static force (at least 0.2 s).
    dt : float > 0
        Control period [s].
    alpha, mass_kg : float
        The test's alpha and specimen mass [kg]: the acceleration enters the reference force
        as ``alpha m a`` (paper Eq. 2.5) and the force loop passes it to the measured force.
    cutoff_hz, threshold, floor_N : float
        The monitor's ``monitor_cutoff_hz`` [Hz], ``monitor_threshold`` [-] (0: off) and
        ``monitor_floor_N`` [N] (:class:`~seft_ros.core.monitor.InstabilityMonitor`).

    Returns
    -------
    CheckResult
        ``values``: ``force_hf_N`` and ``feedback_hf_N`` (the RMS above the cut-off of the
        force and of ``alpha m a``) [N], ``ratio`` (the monitor's, at rest) [-].

    Notes
    -----
    The monitor trips when ``r_hf > threshold (r_lf + 0.05 F_g + floor_N)``; at the quiet
    start of a record (``F_g = 0``) the noise alone gives ``r_hf / (r_lf + floor_N)``, with
    ``r_hf = sqrt(r_f^2 + (alpha m r_a)^2)`` the RMS above the cut-off (the monitor's 2nd-order
    Butterworth filters, the first 0.1 s of the quiet samples left to their transient). It
    must stay below :data:`NOISE_FRACTION` of the threshold.
    """
    f = np.asarray(force_N, dtype=float)[quiet]
    acc = np.asarray(acceleration_m_s2, dtype=float)[quiet]
    settle = min(int(round(0.1 / dt)), f.size // 2)
    if f.size - settle < 10:
        return not_run('sensor noise', f'{f.size} samples at rest (expected at least 0.2 s)')
    hp = signal.butter(2, cutoff_hz, 'highpass', fs=1.0 / dt)
    lp = signal.butter(2, cutoff_hz, 'lowpass', fs=1.0 / dt)

    def rms(s, ba):
        y = signal.lfilter(*ba, s - np.mean(s))[settle:]
        return float(np.sqrt(np.mean(y * y)))
    force_hf = rms(f, hp)
    feedback_hf = abs(alpha) * mass_kg * rms(acc, hp)
    r_hf = math.hypot(force_hf, feedback_hf)
    ratio = r_hf / (rms(f, lp) + floor_N) if rms(f, lp) + floor_N > 0 else math.inf
    values = {'force_hf_N': force_hf, 'feedback_hf_N': feedback_hf, 'ratio': ratio}
    measured = (f'at rest above {cutoff_hz:g} Hz: force {force_hf:.3g} N RMS, alpha m a '
                f"{feedback_hf:.3g} N RMS (alpha {alpha:g}): {ratio:.3g} of the monitor's "
                'trip level at a quiet start')
    if not threshold > 0:
        return CheckResult('sensor noise', True, measured + ' (the monitor is off: '
                           'monitor_threshold 0)', values)
    limit = NOISE_FRACTION * threshold
    passed = ratio <= limit
    text = measured + f' (limit {limit:g})'
    if not passed:
        which = 'load cell' if force_hf >= feedback_hf else 'accelerometer (fed back)'
        text += (f': the {which} noise would trip the instability monitor: shield or filter '
                 "it (an anti-alias filter, its delay in the rig's latency), or raise "
                 'monitor_floor_N')
    return CheckResult('sensor noise', passed, text, values)


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
    f = np.asarray(force_N, dtype=float)
    step = float(np.max(np.abs(f[onset:] - np.mean(f[quiet])), initial=0.0))
    k1 = first_departure(f, quiet, max(onset - 1, 0), step)
    if k1 is None:
        noise = float(np.std(np.asarray(force_N, dtype=float)[quiet]))
        if _DEPARTURE_SIGMAS * noise >= amplitude_N:
            return not_run('command timing', f"the measured force's noise at rest "
                           f'({noise:.3g} N RMS) hides a step of {amplitude_N:g} N (see '
                           'sensor noise; or a larger --amplitude)')
        return not_run('command timing', 'the measured force never left its rest value')
    promised = rig_contract.first_effect_step(j, latency_s, dt)
    late = k1 - promised
    return CheckResult(
        'command timing', 0 <= late <= TIMING_TOLERANCE_STEPS,
        f'the command stamped step {j} first shows at step {k1}: {k1 - j} steps after it '
        f'(promised {promised - j} for command_latency_s {1e3 * latency_s:g} ms, at most '
        f'{TIMING_TOLERANCE_STEPS} later)',
        {'command_step': j, 'first_effect': k1, 'promised': promised})


def held_force(time_s, force_N, amplitude_N: float, force_limit_N: float = math.inf
               ) -> tuple[float, float]:
    """The force that a closed valve holds at rest: how large, and whether the actuator
    relaxes it or loads the specimen further.

    A closed valve holds the actuator, and the specimen's force pushes oil through the valve
    and the seals: the actuator creeps at a velocity proportional to that force (the
    leakage), and the creep relaxes the force. A watchdog that waits longer leaves the valve
    at its last opening longer and the held force larger (the bridge's rig check at 0.2 s:
    3.4 x the amplitude, creep 2.4 mm/s; its stopped-controller run 1.4 x, 0.98 mm/s: the
    same 7.2 um/s per N). A valve held open instead keeps loading the specimen: the force
    grows (on the stiffer pier of ``config/two_piers.yaml`` after a 0.2 s watchdog, at
    1.1 mm/s, slower than the closed valve's creep of 1.5 mm/s: the load pressure throttles
    the open valve), and only the force's trend tells the two apart.

    Parameters
    ----------
    time_s, force_N : ndarray, shape (n,)
        The samples after the ramp (at rest) [s, N].
    amplitude_N : float > 0
        The sine's amplitude [N].
    force_limit_N : float > 0
        The run's force limit [N] (default none): no more than it is held (a rig past it
        has aborted at the limit).

    Returns
    -------
    ratio : float >= 1
        ``max(1, min(max|f|, force_limit_N) / amplitude_N)`` if the force relaxes
        (``growth_N <= 0``), else 1: the factor on the creep the rest bound allows.
    growth_N : float
        How much ``|f|`` grows over the samples [N]: the least-squares line's slope times
        their span (negative: it relaxes); 0 for fewer than 2 samples or a value not finite.
    """
    f = np.asarray(force_N, dtype=float)
    t = np.asarray(time_s, dtype=float)
    if f.size < 2 or not np.all(np.isfinite(f)):
        return 1.0, 0.0
    magnitude = f * (1.0 if np.mean(f) >= 0.0 else -1.0)
    growth = float(np.polyfit(t - t[0], magnitude, 1)[0] * (t[-1] - t[0]))
    if growth > 0.0:
        return 1.0, growth
    held = min(float(np.max(np.abs(f))), float(force_limit_N))
    return max(1.0, held / float(amplitude_N)), growth


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
        The run's parameters (``watchdog_timeout_s``, ``dt``, ``safe_ramp_s``; and
        ``force_limit_N`` if any, the cap on the held force's ratio).
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
    holds the actuator, ``|v| <= REST_VELOCITY_FRACTION`` of the last cycle's peak velocity,
    times :func:`held_force`'s ratio (a creep relaxing a force larger than the amplitude, as
    a long watchdog leaves; at most the run's ``force_limit_N`` over the amplitude), and
    ``|f|`` may not grow by more than ``REST_GROWTH_FRACTION`` of the amplitude (a valve
    held open loads the specimen further); each plus 6 standard deviations of the quiet
    samples (sensor noise). The rig must have sampled at least 5 samples there
    (``SAFE_HOLD_S`` is 25 at 500 Hz).
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
    creep, loads = '', False
    if command_kind == rig_contract.COMMAND_KINDS[1]:
        what, unit, scale, s = 'force', 'N', 1.0, np.asarray(force_N, dtype=float)
        bound = REST_FORCE_FRACTION * amplitude_N
    else:
        what, unit, scale, s = 'velocity', 'mm/s', 1e3, np.asarray(velocity_m_s, dtype=float)
        f = np.asarray(force_N, dtype=float)
        ratio, growth = held_force(t[after], f[after], amplitude_N,
                                   float(params.get('force_limit_N', math.inf)))
        bound = REST_VELOCITY_FRACTION * ratio * float(np.max(np.abs(s[before]), initial=0.0))
        growth_limit = (REST_GROWTH_FRACTION * amplitude_N
                        + _DEPARTURE_SIGMAS * float(np.std(f[quiet])))
        loads = growth > growth_limit
        held = f', the creep of a held force {ratio:.2f} x the amplitude' if ratio > 1.0 else ''
        creep = (f'{held}), |f| {"grew" if growth > 0 else "fell"} {abs(growth):.3g} N '
                 f'meanwhile (limit +{growth_limit:.3g} N'
                 + ('; the valve still loads the specimen' if loads else ''))
    bound += _DEPARTURE_SIGMAS * float(np.std(s[quiet]))
    rest = float(np.max(np.abs(s[after])))
    in_time = math.isfinite(reaction) and reaction <= limit
    reason = str(final.get('message', ''))
    passed = in_time and rest <= bound and not loads and reason.startswith(reason_prefix)
    return CheckResult(
        name, passed,
        f'safe state {1e3 * reaction:.1f} ms after the fault (limit {1e3 * limit:.0f} ms), '
        f'then |{what}| <= {scale * rest:.3g} {unit} after the ramp (limit '
        f'{scale * bound:.3g} {unit}{creep}); reason: {reason}'
        + (f' (expected {reason_prefix!r} ...)' if not reason.startswith(reason_prefix)
           else ''),
        {'reaction_s': reaction, 'rest_value': rest, 'rest_limit': bound})


def start_withheld(trial: Mapping | None) -> str | None:
    """Why the second sender sent nothing (it withheld every start: the live run's end too
    near by the rig's clock), or None if it sent or never fired (`trial`: as
    :func:`check_second_sender` takes it)."""
    if not trial or trial.get('sent'):
        return None
    return (f"the checker heard the rig {float(trial.get('lag_s', 0.0)):.2f} s late: the "
            "second sender's start would have come after the run's end")


def check_second_sender(trial: Mapping | None, final: Mapping | None, expected_steps: int
                        ) -> CheckResult:
    """The controller behind the UDP bridge refused a second sender's start during the step
    run (the rig contract's session rules).

    Parameters
    ----------
    trial : mapping or None
        What the second sender did and heard: ``from`` ('host:port'), ``session``, ``t_s``
        (the step run's time it sent its start [s]), ``sent`` (datagrams sent), ``heard`` (a
        list of ``(session, state name)`` of each datagram it received from the controller),
        ``lag_s`` (how far the rig's clock was past ``t_s`` at its last send or withheld
        start [s]; 0 if absent); ``sent`` 0: it withheld its start (the run's end too near;
        not measured); None: it never sent (the step run did not reach it).
    final : mapping or None
        The rig's final status of the step run (``state``, ``published``,
        ``controller_start_refused``).
    expected_steps : int
        The step run's samples.

    Returns
    -------
    CheckResult
        Passed when the second sender heard nothing, the rig reported the controller's
        refusal (``controller_start_refused`` 1: reason 6 in its datagrams) and the run ended
        done with every sample. ``values``: ``heard``, ``own_session_heard``,
        ``live_session_heard``, ``refused``.
    """
    name = SECOND_SENDER
    if trial is None:
        return not_run(name, 'the step run ended before the second sender sent its start')
    withheld_all = start_withheld(trial)
    if withheld_all:
        return not_run(name, withheld_all)
    final = final or {}
    heard = list(trial.get('heard', ()))
    sent, withheld = int(trial['sent']), int(trial.get('withheld', 0) or 0)
    what = f'{sent} datagrams, then 0 V commands' if sent > 1 else 'its start datagram'
    if withheld:
        what += f"; {withheld} more withheld, the live run's end near"
    who = (f"a start of session {trial['session']} from {trial['from']} at t = "
           f"{float(trial['t_s']):.3f} s ({what})")
    own = sum(1 for sess, _ in heard if sess == trial['session'])
    states = sorted({state for _, state in heard})
    refused = str(final.get('controller_start_refused', '0')) == '1'
    values = {'heard': len(heard), 'own_session_heard': own,
              'live_session_heard': len(heard) - own, 'refused': refused}
    problems = []
    if own:
        problems.append(f'the controller took it: it answered the second sender {own} times '
                        f'with its session (state {", ".join(states)}): a second PC takes the '
                        'rig over')
    elif heard:
        problems.append(f'the controller answered the second sender {len(heard)} times (not '
                        f'with its session; state {", ".join(states)}): it sends to an address '
                        'that is not the live PC')
    if not refused:
        problems.append("the controller did not name the refusal in its datagrams to the live "
                        "PC (reason 6 'start refused'; the rig's final status "
                        f"controller_start_refused={final.get('controller_start_refused')!r})")
    if final.get('state') != 'done' or str(final.get('published')) != str(expected_steps):
        problems.append(f"the run did not go on to its end: {final.get('state')!r}, "
                        f"{final.get('published')} of {expected_steps} samples "
                        f"({final.get('message', 'no final report')})")
    if problems:
        return CheckResult(name, False, f'{who}: ' + '; '.join(problems) + '. A controller '
                           'refuses a start while a session is live and answers the live PC '
                           'alone (rig contract: sessions)', values)
    return CheckResult(name, True, f"{who}: refused: no answer to it, reason 6 'start "
                       "refused' in the live run's datagrams, the run went on to its end "
                       f'(done, {expected_steps} of {expected_steps} samples)', values)


def check_final_status(finals: Mapping[str, Mapping | None], expected_steps: int,
                       unsealed: Mapping[str, Mapping] | None = None) -> CheckResult:
    """Every run ends with the rig's final report naming a compatible contract.

    Parameters
    ----------
    finals : mapping of str to mapping or None
        Run name -> the rig's final status values (None: none arrived). The step run
        (``'step'``) must end 'done' after `expected_steps` samples, a fault run 'aborted'.
    expected_steps : int
        The step run's samples.
    unsealed : mapping of str to mapping, optional
        Run name -> the rig's final report without the run's seal (the graph dropped it),
        for a run without a sealed one.
    """
    problems = []
    for run, final in finals.items():
        if final is None:
            dropped = (unsealed or {}).get(run)
            problems.append(f'{run}: no final status' if dropped is None else
                            f"{run}: its final report ({dropped.get('state')!r}) without the "
                            "run's seal, dropped by the graph")
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
