"""The rig on the wall clock: commands take effect when they arrive (real-time mode).

In lockstep mode the rig waits for the command of each step and holds it over the step
(:class:`~seft_msgs_py.interface.Rig`). A laboratory rig cannot wait: its plant moves on
whether a command has arrived or not. :class:`WallClockRig` is the same simulated rig driven
that way. Between two ticks ``t_k`` and ``t_k+1`` it integrates the plant on a fine sub-step
grid, and the actuator sees the latest command that has taken effect, switched at the
sub-step on which it takes effect. Its sensors are sampled at every tick.

When a command takes effect (``realtime_output``), for the command computed from sample
``j`` (the valve command ``u[j]``; on the delay rig the reference force ``f_r[j+1]``) that
arrived at time ``t_a``:

* ``'latched'`` (default): the output is latched at the next tick ``t_j+1`` (the lockstep
  timing: one control period of computation), or at ``t_a`` if the command arrives later,
  and reaches the actuator after the modelled hardware latency ``h``;
* ``'on_arrival'``: at ``t_a + h`` (the measured computation and communication replace the
  control period).

``h = io_latency_s - dt`` on the servohydraulic rig (its ``io_latency_s`` lumps one control
period of computation with the D/A, valve-amplifier and anti-alias delays; clipped at 0) and
``h = tau_s`` on the delay rig (its actuator delay). So with every command in time a
``'latched'`` run reproduces the lockstep rig exactly (up to rounding: tested), and a late
command (one that missed its tick: a *stale* command) acts from its arrival.

The ``state_space`` and ``actuator`` rigs hold the actuator's latency in their own model
(:data:`MODELS_WITH_OWN_DELAY`), with no control period in it: ``h = 0``, and the command
of sample ``j`` is latched at ``t_j+1`` (``'latched'``: a lab DAQ's output, one control
period of computation) or acts at its arrival (``'on_arrival'``), then through the model.
Lockstep applies it at ``t_j``, so a real-time run of these rigs is one sample behind
lockstep, deterministically. Taking each command at its arrival made the loop's delay the
graph's latency, 0.5 ms with 0.2-0.4 ms of jitter: an identification in real time fitted
the force to 4.8 % only (lockstep: 1e-14), and lockstep settings erred by 36 % at alpha 1
(a lightly damped 10 Hz specimen). A ``state_space`` model given in z is defined at ``dt``
only: it runs in real time with ``realtime_substep_s`` equal to ``dt`` (else refused in one
line); given continuous, it is sampled at the sub-step.

What acts while a command is late (``realtime_late_command``): ``'hold'`` (default) keeps
the newest command in effect, as a DAQ's zero-order hold; ``'predict'`` gives, from the
instant the late command was due until it arrives, its linear prediction from the commands
received (:class:`~seft_msgs_py.prediction.SampleHistory`: order 8 fitted over the last
0.5 s, at most :data:`LATE_COMMAND_HORIZON_S` beyond the newest; where the predictor
declines, the two newest extrapolated linearly over at most :data:`LATE_LINEAR_STEPS`). An
open-loop run (``excitation_input: valve_command``, noise) is held either way
(:func:`applied_commands` reconstructs it). A held valve command keeps the flow of the step
before: on a lightly damped specimen each late one is a kick that rings for seconds.
Replayed in process with their recorded arrivals (``seft compare --replay-timing``), 13
real-time runs of a loaded 2-core host erred less predicting, every one (the two piers of
issue 41, worst acceleration 0.80-15.1 % held, 0.44-1.00 % predicted, 0.44 % with every
command in time; docs: design, real time; ``benchmarks/late_commands.py``). The prediction of a
command between a slow computation's updates on the actuator controller's side is the
event-driven strategy of Mosqueda, Stojadinovic and Mahin (2007, Real-time error monitoring
for hybrid simulation, J. Struct. Eng. 133(8)) and the extrapolation of Nakashima and
Masaoka (1999, EESD 28(4)); a lab's real-time controller that does it declares the value
(docs: the rig contract).

The plant itself is the lockstep rig's own class, built at the sub-step period with no
internal latency (:func:`~seft_plant_sim.rigs.make_rig`), so the physics, the sensors and the
limits are the same code.
"""

from dataclasses import replace
import heapq
import math
from typing import Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE, Measurement
from seft_msgs_py.prediction import SampleHistory, window_steps
from seft_plant_sim.rigs import make_rig

__all__ = ['WallClockRig', 'ReplayRig', 'OUTPUT_TIMINGS', 'LATE_COMMANDS',
           'LATE_COMMAND_HORIZON_S', 'LATE_LINEAR_STEPS', 'CommandArrivals',
           'MODELS_WITH_OWN_DELAY', 'valve_latch_offset_s', 'applied_commands']

#: Rig models whose plant holds the actuator's I/O latency itself (not ``io_latency_s``).
MODELS_WITH_OWN_DELAY = ('state_space', 'actuator')

#: Values of the ``realtime_output`` parameter.
OUTPUT_TIMINGS = ('latched', 'on_arrival')
#: Values of the ``realtime_late_command`` parameter.
LATE_COMMANDS = ('hold', 'predict')
#: The longest prediction of a late command beyond the newest one [s] (then held).
LATE_COMMAND_HORIZON_S = 0.02
#: The longest linear extrapolation of a late command, where the predictor declines [steps].
LATE_LINEAR_STEPS = 2
_EPS = 1e-9


class CommandArrivals:
    """When the command of each sample arrived at the rig: a real-time rig's loop latency and
    stale commands (on the rig's time axis, ``t = 0`` at sample 0).

    Subclasses set ``dt`` [s] and fill ``_arrivals`` (source sample -> first arrival [s]).
    """

    dt: float
    _arrivals: dict

    def arrival_s(self, source: int) -> float | None:
        """First arrival time [s] of the command computed from sample `source` (or None)."""
        return self._arrivals.get(source)

    def loop_latency_s(self, source: int) -> float | None:
        """Sample `source` to the arrival of its command at the rig [s] (None: not arrived)."""
        a = self._arrivals.get(source)
        return None if a is None else a - source * self.dt

    def stale(self, tick: int) -> bool:
        """The command computed from sample ``tick - 1`` had not arrived by ``t_tick``."""
        a = self._arrivals.get(tick - 1)
        return a is None or a > tick * self.dt

    def forget_before(self, source: int) -> None:
        """Drop the arrival times of samples before `source` (bounded memory)."""
        for j in [j for j in self._arrivals if j < source]:
            del self._arrivals[j]


def valve_latch_offset_s(params: Mapping) -> float:
    """When a valve command in time is output after the sample it was computed from [s]
    (``latched``, module notes): ``dt`` for the rigs that hold their own latency
    (:data:`MODELS_WITH_OWN_DELAY`), ``min(dt, io_latency_s)`` for seft's servohydraulic
    rig (the rest of its latency is the hardware's)."""
    dt = float(params['dt'])
    if params.get('rig_model') in MODELS_WITH_OWN_DELAY:
        return dt
    return min(dt, float(params['io_latency_s']))


def applied_commands(command, loop_latency_s, dt: float, latch_offset_s: float):
    """The command a real-time rig applied over each step, from the commands sent and the
    instants they arrived: what a late (stale) command changed.

    A command computed from sample ``j`` acts from ``t_j + latch_offset_s`` or from its
    arrival if that is later, until a newer one acts (an older one arriving after a newer
    one is discarded; one that never arrived never acts): :class:`WallClockRig`'s rule
    (``realtime_output: latched``) and the rig contract's (``docs/rig_contract.md``). The
    step ``j`` of the result is the mean of the command in effect over
    ``[t_j + latch_offset_s, t_j+1 + latch_offset_s)``, the span the command of ``j`` holds
    when every command is in time (then the result equals `command`). An identification of
    the loop from a real-time run reads this, not the commands sent: a late command holds
    the previous one a fraction of a step longer, and on a lightly damped specimen that
    kick rings for seconds (5 of 10 000 commands late, 6.4 ms at most, made a
    32 Hz, 0.5 % specimen's valve-to-force fit err 1.2 % instead of 0.14 %).

    Parameters
    ----------
    command : array_like, shape (n,)
        The command computed from each sample (valve command [V]).
    loop_latency_s : array_like, shape (n,)
        Sample ``j`` to the arrival of its command at the rig [s] (the rig's timing
        records, ``loop_latency_s``); nan: it never arrived.
    dt : float > 0
        Sample period [s].
    latch_offset_s : float in [0, dt]
        When a command in time is output after its sample [s]
        (:func:`valve_latch_offset_s`).

    Returns
    -------
    applied : ndarray, shape (n,)
        The mean command in effect over each step's span (0 before the first arrived).
    late : int
        The commands that acted later than ``t_j + latch_offset_s`` or never.

    Raises
    ------
    ParameterError
        Arrays of different shapes, or `dt` / `latch_offset_s` out of range.
    """
    u = np.asarray(command, dtype=float)
    latency = np.asarray(loop_latency_s, dtype=float)
    if u.ndim != 1 or latency.shape != u.shape:
        raise ParameterError(f'command {u.shape} and loop latency {latency.shape}: expected '
                             'two arrays of the same length (n,)')
    if not (math.isfinite(dt) and dt > 0 and 0 <= latch_offset_s <= dt):
        raise ParameterError(f'dt={dt!r}, latch_offset_s={latch_offset_s!r}: expected '
                             'dt > 0 and 0 <= latch_offset_s <= dt [s]')
    n = u.size
    # when each command acts, on the axis of the spans (span j is [j, j + 1) in steps)
    arrived = np.isfinite(latency)
    lateness = np.where(arrived, (latency - latch_offset_s) / dt, np.inf)
    starts = np.arange(n) + np.maximum(lateness, 0.0)
    late = int(np.count_nonzero(lateness > _EPS))
    if not late:
        return u.copy(), 0
    applied = u.copy()
    # spans that a late command touched: from its own span to the one it acted in (and
    # the next, which the held value may reach)
    touched = set()
    for j in np.flatnonzero(lateness > _EPS):
        last = n - 1 if not arrived[j] else min(n - 1, int(math.floor(starts[j])) + 1)
        touched.update(range(j, last + 1))
    order = np.argsort(starts, kind='stable')
    events = [(float(starts[j]), int(j)) for j in order if arrived[j]]
    held, held_stamp, e = 0.0, -1, 0
    for span in sorted(touched):
        # the command in effect at the span's start: the newest to act by then
        while e < len(events) and events[e][0] <= span + _EPS:
            if events[e][1] > held_stamp:
                held, held_stamp = u[events[e][1]], events[e][1]
            e += 1
        total, t, ee = 0.0, float(span), e
        value, stamp = held, held_stamp
        while ee < len(events) and events[ee][0] < span + 1 - _EPS:
            t_next, j = events[ee]
            if j > stamp:
                total += value * (t_next - t)
                t, value, stamp = t_next, u[j], j
            ee += 1
        applied[span] = total + value * (span + 1 - t)
    return applied, late


def _discrete_model(params: Mapping) -> str | None:
    """The parameter holding a ``state_space`` rig's plant (parsed already by the rig) when
    that plant is given in z, else None."""
    from seft_msgs_py.parameters import mapping_value, rig_plant_parameter
    name = rig_plant_parameter(params)
    doc = mapping_value(params[name], where=f'parameter {name}',
                        expected='a plant model mapping')
    return name if float(doc.get('dt', 0.0) or 0.0) > 0 else None


class WallClockRig(CommandArrivals):
    """A simulated rig sub-stepped between wall-clock ticks, commanded by arrival time.

    Parameters
    ----------
    params : mapping
        Resolved experiment parameters: ``rig_model``, ``dt`` [s], ``realtime_substep_s``
        [s], ``realtime_output``, ``realtime_late_command``, ``safe_ramp_s`` [s],
        ``io_latency_s`` [s] (servohydraulic) or ``tau_s`` [s] (delay; the ``state_space`` and
        ``actuator`` models hold their own latency, :data:`MODELS_WITH_OWN_DELAY`) and
        everything
        :func:`~seft_plant_sim.rigs.make_rig` reads.

    Attributes
    ----------
    dt : float
        Tick (control) period [s].
    substep_s : float
        Integration sub-step ``dt / M`` [s], ``M = round(dt / realtime_substep_s)``.
    hardware_latency_s : float
        Delay from the output instant to the actuator ``h`` [s] (module notes).
    step : int
        Index k of the current tick (the plant is at ``t_k = k*dt``).
    command_kind : str
        As the lockstep rig's.
    source_lag : int
        A command stamped ``j`` is computed from sample ``j - source_lag`` (0: valve command,
        1: reference force on the delay rig).

    Raises
    ------
    ParameterError
        Unknown ``realtime_output`` or ``realtime_late_command``, a rig parameter out of
        range, or a ``state_space`` rig whose ``plant_model`` is discrete while the sub-step
        is shorter than ``dt``.

    Notes
    -----
    A command's effect time is rounded up to the sub-step grid, so it acts at most one
    sub-step (default 0.1 ms) after the instant the timing rule gives. A command older than
    the one already in effect is discarded (``discarded``).
    """

    def __init__(self, params: Mapping):
        dt = float(params['dt'])
        output = params.get('realtime_output', 'latched')
        if output not in OUTPUT_TIMINGS:
            raise ParameterError(f'parameter realtime_output={output!r}: expected one of '
                                 + ', '.join(repr(o) for o in OUTPUT_TIMINGS))
        self.output = output
        late = params.get('realtime_late_command', 'hold')
        if late not in LATE_COMMANDS:
            raise ParameterError(f'parameter realtime_late_command={late!r}: expected one of '
                                 + ', '.join(repr(o) for o in LATE_COMMANDS))
        self.late_command = late
        self.dt = dt
        self.substeps = max(1, int(round(dt / float(params['realtime_substep_s']))))
        h = dt / self.substeps
        self.substep_s = h
        probe = make_rig(dict(params))          # validates the model parameters at dt
        self.command_kind = probe.command_kind
        own_delay = params.get('rig_model') in MODELS_WITH_OWN_DELAY
        discrete = (params.get('rig_model') == 'state_space' and self.substeps > 1
                    and _discrete_model(params))
        if discrete:
            raise ParameterError(
                f'rig_model state_space in real time: the {discrete} is discrete at dt '
                f'({1e3 * dt:g} ms) and the real-time rig steps on a {1e3 * h:g} ms grid '
                '(realtime_substep_s); give the model continuous, set realtime_substep_s to '
                'dt, or rehearse it with seft simulate (lockstep, the model as identified)')
        if own_delay:
            # the model holds the actuator's latency (plant_model io_delay_s, the family's
            # io_delay_s): the command is latched at the next tick (or acts on arrival),
            # then goes through the model
            self.source_lag = 0
            self._latch_offset_s = valve_latch_offset_s(params)
            self.hardware_latency_s = 0.0
            self._lead = 0
            sub = dict(params, dt=h)
        elif self.command_kind == COMMAND_VALVE:
            self.source_lag = 0
            self._latch_offset_s = valve_latch_offset_s(params)
            self.hardware_latency_s = float(params['io_latency_s']) - self._latch_offset_s
            self._lead = 0
            sub = dict(params, dt=h, io_latency_s=0.0)
        else:
            self.source_lag = 1
            self._latch_offset_s = dt
            self.hardware_latency_s = float(params['tau_s'])
            # the delay rig needs tau > 0: one sub-step, commands applied one sub-step early
            self._lead = 1
            sub = dict(params, dt=h, tau_s=h)
        self.plant = make_rig(sub, rk4_substeps=1)
        self.safe_ramp_s = float(params['safe_ramp_s'])
        # the sub-step at which the command of sample 0 acts when it is in time (latched;
        # on arrival: by the next tick): a later source j acts ``j * substeps`` after it
        due_s = (self._latch_offset_s if output == 'latched' else dt) + self.hardware_latency_s
        self._due_sub = math.ceil(due_s / h - _EPS)
        # an open-loop identification's commands are noise, and its analysis reconstructs
        # them held (applied_commands): the rig predicts a test's commands only
        predict = late == 'predict' and params.get('excitation_input') != 'valve_command'
        self._late_steps = max(1, int(round(LATE_COMMAND_HORIZON_S / dt)))
        # the commands of a stall arrive together, before they act: room for them
        self._history = (SampleHistory(window_steps(dt), spare=4 * self._late_steps + 8)
                         if predict else None)
        self._late = (-1, -1, 0.0)          # (held stamp, due stamp, predicted command)
        #: late commands whose prediction acted (``realtime_late_command: predict``)
        self.predicted = 0
        self.step = 0
        self._sub = 0
        self._events: list[tuple[int, int, float]] = []   # (effect sub-step, stamp, value)
        self._held = 0.0
        self._held_stamp = -1 - self.source_lag
        self._arrivals: dict[int, float] = {}     # source sample -> first arrival time [s]
        self._safe_from_sub: int | None = None
        self._ramp_sub = 0
        self._safe_from_value = 0.0
        self.discarded = 0

    # -- commands ---------------------------------------------------------------------------

    def effect_time_s(self, stamp: int, arrival_s: float) -> float:
        """When the command stamped `stamp` arriving at `arrival_s` [s] acts (module notes)."""
        if self.output == 'latched':
            source = stamp - self.source_lag
            start = max(source * self.dt + self._latch_offset_s, arrival_s)
        else:
            start = arrival_s
        return start + self.hardware_latency_s

    def arrive(self, stamp: int, value: float, arrival_s: float) -> None:
        """A command arrived.

        Parameters
        ----------
        stamp : int
            Its step index j (header stamp ``t_j``).
        value : float
            Valve command [V] or reference force [N].
        arrival_s : float
            Arrival time on the plant's time axis (``t = 0`` at tick 0) [s]; may be negative
            (before the clock started).
        """
        source = stamp - self.source_lag
        self._arrivals.setdefault(source, arrival_s)
        if self._history is not None:
            self._history.store(stamp, float(value))
        if self._safe_from_sub is not None:
            self.discarded += 1
            return
        effect = self.effect_time_s(stamp, arrival_s)
        heapq.heappush(self._events, (math.ceil(effect / self.substep_s - _EPS), stamp,
                                      float(value)))

    # -- safe state -------------------------------------------------------------------------

    def enter_safe_state(self) -> None:
        """From now on ignore commands and ramp the command linearly to 0 over safe_ramp_s.

        The commands already output still reach the actuator; the ramp starts from the last
        of them, reaches the actuator after the hardware latency, then the command is held
        at 0 (valve closed; actuator force zero on the delay rig).
        """
        if self._safe_from_sub is None:
            # commands output before now still reach the actuator; the ramp starts from the
            # last of them and reaches the actuator after the hardware latency
            self._safe_from_sub = self._sub
            self._ramp_sub = self._sub + math.ceil(self.hardware_latency_s / self.substep_s
                                                   - _EPS)
            self._events = [e for e in self._events if e[0] <= self._ramp_sub]
            heapq.heapify(self._events)
            newest = max(self._events, key=lambda e: e[1], default=None)
            self._safe_from_value = (newest[2] if newest and newest[1] > self._held_stamp
                                     else self._held)

    @property
    def in_safe_state(self) -> bool:
        """Whether :meth:`enter_safe_state` was called."""
        return self._safe_from_sub is not None

    @property
    def safe_ramp_done(self) -> bool:
        """The safe-state ramp is over (the command is 0 and has reached the actuator)."""
        if self._safe_from_sub is None:
            return False
        return (self._sub - self._ramp_sub) * self.substep_s >= self.safe_ramp_s - _EPS

    def _safe_command(self, sub: int) -> float:
        elapsed = (sub - self._ramp_sub) * self.substep_s
        if self.safe_ramp_s <= 0 or elapsed >= self.safe_ramp_s:
            return 0.0
        return self._safe_from_value * (1.0 - elapsed / self.safe_ramp_s)

    # -- the plant --------------------------------------------------------------------------

    def advance(self) -> None:
        """Integrate ``[t_k, t_k+1)`` with the commands in effect; move to tick k+1."""
        plant = self.plant
        events = self._events
        lead = self._lead
        for i in range(self._sub, self._sub + self.substeps):
            if self._safe_from_sub is not None and i + lead >= self._ramp_sub:
                u = self._safe_command(i + lead)
            else:
                while events and events[0][0] <= i + lead:
                    _, stamp, value = heapq.heappop(events)
                    if stamp > self._held_stamp:
                        self._held, self._held_stamp = value, stamp
                    else:
                        self.discarded += 1
                u = self._held
                if self._history is not None:
                    u = self._late_command(i + lead, u)
            plant.apply(u)
        self._sub += self.substeps
        self.step += 1

    def _late_command(self, sub: int, held: float, count: bool = True) -> float:
        """The command on sub-step `sub` with ``realtime_late_command: predict``: where the
        command due by now (in time) has not arrived, its prediction from the ones received
        (:class:`~seft_msgs_py.prediction.SampleHistory`, over at most
        :data:`LATE_COMMAND_HORIZON_S` beyond the newest in effect; linear over at most
        :data:`LATE_LINEAR_STEPS` where the predictor declines); else `held`. `count`: a new
        late command counts in :attr:`predicted`."""
        if sub < self._due_sub:
            return held
        due = (sub - self._due_sub) // self.substeps + self.source_lag
        newest = self._held_stamp
        if newest >= due or newest < self.source_lag + 1:
            return held
        if self._late[:2] == (newest, due):
            return self._late[2]
        ahead = min(due - newest, self._late_steps)
        value = self._history.predict(newest, ahead)
        if value is None:
            before = self._history.value(newest - 1)
            value = held if before is None else (held + min(ahead, LATE_LINEAR_STEPS)
                                                 * (held - before))
        if count:
            if self._late[1] != due:
                self.predicted += 1
            self._late = (newest, due, value)
        return value

    @property
    def time_s(self) -> float:
        """Time of the current tick [s]."""
        return self.step * self.dt

    @property
    def held_source(self) -> int:
        """The sample the command in effect was computed from (negative: none yet)."""
        return self._held_stamp - self.source_lag

    @property
    def held_command(self) -> float:
        """The command in effect at the current sub-step [V or N] (in the safe state, the
        ramp's value once the ramp has reached the actuator; a late command's prediction
        with ``realtime_late_command: predict``)."""
        sub = self._sub + self._lead
        if self._safe_from_sub is not None and sub >= self._ramp_sub:
            return self._safe_command(sub)
        if self._history is not None:
            return self._late_command(sub, self._held, count=False)
        return self._held

    def measure(self) -> Measurement:
        """Sensor readings at the current tick (step k, time ``t_k``)."""
        return replace(self.plant.measure(), step=self.step, time_s=self.step * self.dt)

    def limit_violation(self) -> str | None:
        """Stroke/force limit check at the current tick (as the lockstep rig)."""
        return self.plant.limit_violation()


class ReplayRig:
    """:class:`WallClockRig` stepped in a lockstep loop, each command arriving at its
    recorded time: a real-time run replayed in one process (``seft compare
    --replay-timing``; :func:`seft_ros.core.experiment.simulate`'s ``command_latency_s``).

    The command stamped ``k`` (:meth:`apply` at step ``k``) arrives ``latency_s[k]`` after
    sample ``k - source_lag`` and is delivered before the first tick it arrives by, as the
    rig node does. A step without a latency (or a nan one: the command never arrived in the
    run) gets `default_s`, in time. The rig protocol of the lockstep rigs: ``measure``,
    ``apply``, ``limit_violation``, ``command_kind``.

    Parameters
    ----------
    params : mapping
        The rig's resolved parameters (:class:`WallClockRig`'s).
    latency_s : mapping of int to float
        Step -> the command's loop latency [s] (the rig's timing records'
        ``loop_latency_s``).
    default_s : float
        The latency of a step not in `latency_s` [s] (default 0.5 ms: in time).

    Raises
    ------
    ParameterError
        As :class:`WallClockRig`.
    """

    def __init__(self, params: Mapping, latency_s: Mapping[int, float],
                 default_s: float = 0.0005):
        self.rig = WallClockRig(params)
        self.command_kind = self.rig.command_kind
        self.latency_s = latency_s
        self.default_s = float(default_s)
        self._k = 0
        self._pending: list[tuple[float, int, float]] = []

    def limit_violation(self) -> str | None:
        """The real-time rig's limit check."""
        return self.rig.limit_violation()

    def measure(self) -> Measurement:
        """The real-time rig's sample of the current tick."""
        return self.rig.measure()

    def apply(self, command: float) -> None:
        """The command of this step, sent now: it arrives at its recorded latency; every
        command that has arrived by the next tick is delivered, then the rig advances."""
        k, dt = self._k, self.rig.dt
        latency = self.latency_s.get(k, self.default_s)
        if not math.isfinite(latency):
            latency = self.default_s
        source = k - self.rig.source_lag
        heapq.heappush(self._pending, (source * dt + latency, k, float(command)))
        while self._pending and self._pending[0][0] <= (k + 1) * dt:
            arrival, stamp, value = heapq.heappop(self._pending)
            self.rig.arrive(stamp, value, arrival)
        self.rig.advance()
        self._k += 1
