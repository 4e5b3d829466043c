"""rig node: the simulated actuator + specimen, master of the clock.

**Lockstep mode** (``mode: lockstep``): at each step k the rig checks its safety limits,
publishes the sensor readings stamped t_k (one ``/seft/measurement`` message, and a row of
its record batch for the bag) and, every ``CLOCK_EVERY`` steps, ``/clock`` = t_k, then waits
for the command of step k (the valve command of the force servo controller, or the reference
force for the 'delay' rig), applies it over the step and moves to k+1.

**Real-time mode** (``mode: realtime``): the rig ticks on the wall clock at the absolute
instants ``t0 + k dt`` (``main_for`` waits for events until the next one: an rclpy timer
drifts, see :meth:`~seft_msgs_py.node_support.SeftNode.next_due`). At each tick it integrates
its plant up to the tick with the commands that have arrived, each acting from its arrival as
:class:`~seft_plant_sim.realtime.WallClockRig` says, samples and publishes its sensors, and
records one timing record per sample (the bag's ``/seft/timing/rig``; period jitter, the tick's
lateness against its absolute schedule; compute time, age of the command in effect, missed
deadline, stale command, loop latency). A tick that ran late by more than a period is caught
up at once (never skipped) and counts as a missed deadline. It never waits: a command that has
not arrived is simply not applied yet (a *stale command*). Watchdog: when no command has
arrived for ``watchdog_timeout_s``, and on any abort (limits, another node's abort), the rig
goes to its safe state (a catch-up after the rig's own loop was held up longer than the limit
judges no silence, once, and the silence counts from its end: the commands sent meanwhile wait
in its queue; the input watchdogs' rule, :meth:`~seft_msgs_py.node_support.InputWatchdog.check`):
the command ramps to zero over ``safe_ramp_s`` while the rig keeps sampling (and
``SAFE_HOLD_S`` after), then the run ends aborted with the reason and the time it happened.

Start (both modes): once the command publisher is discovered, the recorder subscribes (if
``wait_for_recorder``), and the parameters of every node of the graph are in and agree (each
node publishes them on ``/seft/node_parameters``); in real-time mode also once the nodes that
read the sensors subscribe to them. The run ends after ``n_steps`` (or the length the
ground-motion publisher reports), or on an abort; the rig then reports 'done' or 'aborted'.

Run by hand: ``ros2 run seft_plant_sim rig --ros-args --params-file config/default.yaml``
(here: ``.venv/lib/seft_plant_sim/rig --ros-args ...``).
"""

import math
import sys
import threading
import time

from seft_msgs_py import clock, rig_contract
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RUNNING,
    SerializedStamped,
    status_values,
)
from seft_msgs_py.dds import DISCOVERY_SETTLE_S
from seft_msgs_py.errors import ParameterError, SeftError
from seft_msgs_py.graph import Graph, qualified
from seft_msgs_py.interface import COMMAND_VALVE
from seft_msgs_py.node_support import SeftNode, StepTiming, main_for
from seft_msgs_py.signals import MEASUREMENT_FIELDS, RECORD_ROWS
from seft_msgs_py.topics import (
    CLOCK,
    CLOCK_EVERY,
    MEASUREMENT,
    REFERENCE_FORCE,
    STATUS,
    VALVE_COMMAND,
)
from seft_plant_sim.realtime import WallClockRig
from seft_plant_sim.rigs import make_rig
from seft_plant_sim.udp_bridge import UdpBridgeRig

__all__ = ['RigNode', 'main', 'graph_nodes']

#: Sim-time interval of progress reports [steps] (the rig contract's).
PROGRESS_EVERY = rig_contract.PROGRESS_EVERY
#: Smallest lockstep flow-control window but 0 [steps]: it must exceed the recorder's
#: acknowledgement interval (50) plus a record batch of each node.
MIN_WINDOW_STEPS = 100
#: Real-time mode: how long the rig keeps sampling its safe state after the ramp [s].
SAFE_HOLD_S = rig_contract.SAFE_HOLD_S
#: UDP bridge: the interpreter's thread switch interval [s] (sys.setswitchinterval).
SWITCH_INTERVAL_S = 1e-4
#: Real time with several rigs: the clock master announces the common start instant this far
#: ahead of its own clock [s], so that the announcement reaches every rig (on other hosts,
#: across a network) before it.
START_LEAD_S = 0.5
#: Real-time mode: after the last tick the rig waits for the commands of its last samples
#: (their loop latency recorded, not counted lost) for watchdog_timeout_s, at least this [s].
DRAIN_MIN_S = 0.1
#: A UDP bridge's rig waits at most this long for the first valid datagram of the lab's
#: controller before the run is refused [s] (the controller starts in about a second; a wrong
#: address or a controller not started waited for the runner's 30 s stall bound, unnamed).
CONTROLLER_WAIT_S = 10.0


def graph_nodes(params, me: str = 'rig') -> tuple[str, ...]:
    """The nodes of the run's graph besides the rig `me` (qualified names; the recorder only
    with ``wait_for_recorder``)."""
    nodes = tuple(n for n in Graph.from_parameters(params).nodes() if n != me)
    return nodes + (('recorder',) if params['wait_for_recorder'] else ())


def input_nodes(graph: Graph) -> tuple[str, ...]:
    """Real-time mode: the nodes whose inputs must have matched their publishers before a
    rig starts its clock (they report it, ``SeftNode.watch_inputs``)."""
    return ('ground_motion_publisher',) + graph.builder_nodes() + graph.controller_nodes()


class RigNode(SeftNode):
    """Rig node around a :class:`seft_msgs_py.interface.Rig` (lockstep) or a
    :class:`~seft_plant_sim.realtime.WallClockRig` (real-time)."""

    def __init__(self):
        #: Serializes the callbacks with the UDP bridge's receive thread (uncontended else).
        self.lock = threading.RLock()
        super().__init__('rig')
        p = self.params
        #: The rig is a UDP bridge to a lab's real-time controller (its clock is the test's).
        self.bridge = p['rig_interface'] == 'udp_bridge'
        if self.bridge and not self.realtime:
            raise ParameterError('parameter rig_interface=udp_bridge: expected mode realtime '
                                 "(the lab's controller runs on its own clock)")
        if self.bridge:
            self.rig = UdpBridgeRig(p, log=self.get_logger().error)
        else:
            self.rig = WallClockRig(p) if self.realtime else make_rig(p)
        self.n_steps = int(p['n_steps'])
        self.command_topic = self.scoped_spec(
            VALVE_COMMAND if self.rig.command_kind == COMMAND_VALVE else REFERENCE_FORCE)
        #: The clock master (the first rig of a structure) publishes /clock.
        self.clock_master = self.seft_name == self.graph.master
        self.clock_pub = (self.create_publisher(CLOCK.msg_type, CLOCK.name, CLOCK.qos)
                          if self.clock_master else None)
        # one live message of the four sensors a step (serialized in place), and the rows
        # of the record batches that the recorder writes as the bag's four sensor topics
        self.measurement_topic = self.scoped_spec(MEASUREMENT).name
        self.measurement_pub = self.create_publisher(MEASUREMENT.msg_type,
                                                     self.measurement_topic, MEASUREMENT.qos)
        self.measurement_msg = self.sealed_writer(SerializedStamped.fields(
            MEASUREMENT.msg_type, MEASUREMENT_FIELDS, self.seal.frame_id))
        self.batch = self.record_stream()
        self.clock_msg = CLOCK.msg_type()
        on_command = self._on_command_realtime if self.realtime else self._on_command
        self.command_sub = self.scalar_subscription(self.command_topic, on_command)
        self.pending = {}
        self.window = int(p['recorder_window_steps'])
        if 0 < self.window < MIN_WINDOW_STEPS:
            raise ParameterError(
                f'parameter recorder_window_steps={self.window}: expected 0 or >= '
                f'{MIN_WINDOW_STEPS} (the recorder acknowledges every 50 steps and receives '
                f'the samples in batches of {RECORD_ROWS})')
        self.recorded = 0
        self.waiting_for_recorder = False
        self.published = 0
        self.running = False
        #: The signal that stopped the rig (SIGINT, SIGTERM), reported in its final status.
        self.stop_signal = None
        #: The node whose abort ended this rig's run (None: its own), in its final status.
        self.ended_by = None
        #: Real time: why the rig went to its safe state (None: it has not).
        self.abort_reason = None
        #: What an abort of this rig adds to its final status (``foreign_topic``).
        self.abort_values: dict = {}
        self.graph_names = graph_nodes(p, self.seft_name)
        #: The builders that read this rig's measurement, and its controller (if any).
        self.readers = (self.graph.builder_nodes() if self.graph.per_rig_builders
                        else (self.graph.builder_of(self.rig_name),))
        self.controller = (qualified('force_servo_controller', self.rig_name)
                           if self.graph.has_controller(self.rig_name) else None)
        #: Nodes that reported their inputs matched (real time, ``INPUT_NODES``).
        self.inputs_matched = set()
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status),
                                 STATUS.qos)
        if self.realtime:
            self.timing = StepTiming(self)
            self.watchdog_s = float(p['watchdog_timeout_s'])
            self.watchdog_steps = max(1, int(math.ceil(self.watchdog_s / self.rig.dt)))
            self.t0 = None                   # monotonic time of sample 0 [s]
            self.last_command_at = None      # monotonic time of the latest command [s]
            self.ticked_at = None            # monotonic time of the latest tick [s]
            self.deferred = False            # that tick was held up and judged no silence
            self.early_commands = []         # (stamp, value) received before the start
            self.abort_at_s = None
            self.safe_since = None           # plant time the safe ramp ended [s]
            self.timing_pending = {}         # sample -> record fields without the latency
            #: After the last tick: until when (monotonic [s]) the rig still waits for the
            #: commands of its last samples, so that their loop latency is recorded rather
            #: than counted lost (at most watchdog_timeout_s, and at least DRAIN_MIN_S).
            self.drain_until = None
        #: Real time with several rigs: the rigs armed (their graph is up), heard by the
        #: master; this rig's own arming; the monotonic instant of the common start.
        self.armed_rigs: set[str] = set()
        self.armed = False
        self.start_at = None
        #: When the rig began waiting for a UDP bridge's controller (monotonic [s]).
        self.controller_wait_since = None
        self.start_timer = self.wall_timer(0.05, self._try_start)
        if self.bridge:
            # the PC's heartbeat from the executor (a frozen node sends none), the
            # controller's datagrams taken by a thread of their own
            self.wall_timer(float(p['udp_heartbeat_s']), self.rig.heartbeat)
            # two threads share the interpreter: hand it over within 0.1 ms, not Python's
            # default 5 ms (a measurement or a command waiting for it would wait that long)
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            threading.Thread(target=self._receive_loop, name='udp_bridge', daemon=True).start()
        self.publish_parameters()
        self.report(STATE_READY, 'waiting for the graph: ' + ', '.join(self.graph_names),
                    n_steps=self.n_steps, **self.contract_values())

    def contract_values(self) -> dict:
        """What the rig contract asks in the ready report (``seft_msgs_py.rig_contract``):
        the contract, the mode, the command kind and its latency."""
        return {rig_contract.CONTRACT_KEY: rig_contract.CONTRACT, 'mode': self.params['mode'],
                'command_kind': self.rig.command_kind,
                'command_latency_s': repr(rig_contract.command_latency_s(self.params))}

    # -- start ------------------------------------------------------------------------------

    def guard(self, callback):
        """As :meth:`seft_msgs_py.node_support.SeftNode.guard`, under :attr:`lock` (the UDP
        bridge's thread)."""
        guarded = super().guard(callback)

        def locked(*args):
            lock = getattr(self, 'lock', None)
            if lock is None:
                return guarded(*args)
            with lock:
                return guarded(*args)
        return locked

    def _try_start(self) -> None:
        if self.running or self.done or self.n_steps <= 0:
            return
        if self.bridge:
            refused = self.rig.start_violation()
            if refused:                 # nothing was run: one line, exit 2
                raise SeftError(refused)
            if not self.rig.controller_heard:
                # the lab's controller is not up (or not reachable): said once, and past
                # CONTROLLER_WAIT_S the run is refused (it waited for the runner's 30 s stall
                # bound, and nothing named the controller)
                now = time.monotonic()
                if self.controller_wait_since is None:
                    self.controller_wait_since = now
                    host, port = self.rig.peer
                    self.get_logger().info(f'udp_bridge: waiting for the controller at '
                                           f'{host}:{port}')
                elif now - self.controller_wait_since > CONTROLLER_WAIT_S:
                    host, port = self.rig.peer
                    raise SeftError(
                        f'udp_bridge: no datagram from the controller at {host}:{port} for '
                        f'{CONTROLLER_WAIT_S:g} s: is it running and listening on that address '
                        '(udp_controller_address; seft emulate-controller for a rehearsal)?')
                return
        if self.command_sub.get_publisher_count() < 1:
            return
        # the recorder listens to this rig and has discovered the record batches of every
        # node of the graph (the nodes start together: a short run could otherwise end before
        # the recorder heard of one of them)
        if (self.params['wait_for_recorder']
                and (not self.subscribed_by('recorder', self.batch.stream.name)
                     or 'recorder' not in self.inputs_matched)):
            return
        if any(n not in self.node_params for n in self.graph_names):
            return
        if self.realtime and not all(self.subscribed_by(n, self.measurement_topic)
                                     for n in self.readers):
            return
        # real time: the ground-motion publisher, builder and controller have also matched
        # their inputs and outputs (SeftNode.watch_inputs): a sample sent before that waits
        # for DDS's repair
        if self.realtime and any(n not in self.inputs_matched
                                 for n in input_nodes(self.graph)):
            return
        if (self.realtime and self.controller is not None
                and not self.subscribed_by(self.controller, self.measurement_topic)):
            return
        # real time: not while the graph's participants still announce themselves (a node's
        # publish blocked for 21-150 ms by another's shared-memory port being opened meanwhile:
        # DISCOVERY_SETTLE_S)
        if self.realtime and time.monotonic() < max(self.node_heard_at.values()) + \
                DISCOVERY_SETTLE_S:
            return
        if self.realtime and len(self.graph.rigs) > 1:
            self._arm()
            return
        self.start_timer.cancel()
        self._begin()

    def _begin(self) -> None:
        """Start stepping (real time: sample 0 now)."""
        self.running = True
        self.get_logger().info(f'starting ({self.params["mode"]}): {self.n_steps} steps of '
                               f'{self.rig.dt} s, command {self.command_topic.name}')
        self.wall_start = time.monotonic()
        if self.realtime:
            self._start_realtime()
        else:
            self._publish_step()

    def _arm(self) -> None:
        """Real time, several rigs: one clock for all. Each rig whose graph is up reports
        itself armed; once every rig is, the clock master announces a start instant
        ``START_LEAD_S`` ahead on its system clock (``start_at_ns``), and every rig takes its
        sample 0 then (:meth:`next_due`), each on its own timer from there."""
        if not self.armed:
            self.armed = True
            self.armed_rigs.add(self.seft_name)
            self.report(STATE_READY, 'armed: waiting for the start instant', armed='1')
        if (self.clock_master and self.start_at is None
                and set(self.graph.rig_nodes()) <= self.armed_rigs):
            start_ns = clock.now_ns() + int(START_LEAD_S * 1e9)
            self.report(STATE_READY, 'the rigs start together', start_at_ns=start_ns)
            self._schedule_start(start_ns)

    def _schedule_start(self, start_ns: int) -> None:
        """Take sample 0 at `start_ns` (the master's system clock [ns])."""
        if self.start_at is not None or self.running:
            return
        self.start_timer.cancel()
        self.start_at = time.monotonic() + (start_ns - clock.now_ns()) * 1e-9

    def _on_status(self, msg) -> None:
        if not self.status_of_run(msg):
            return              # another run's (SeftNode._on_any_status counts it)
        if self.refused_by_another_node(msg):
            return
        values = status_values(msg)
        state = values.get('state')
        if msg.name == 'recorder':
            self.recorder_ready = True   # also set by SeftNode; this callback may run first
            if 'recorded' in values:
                self.recorded = int(values['recorded'])
                if self.waiting_for_recorder and self._recorder_keeps_up():
                    self.waiting_for_recorder = False
                    self._publish_step()
        if values.get('inputs') == 'matched':
            self.inputs_matched.add(msg.name)
        if values.get('armed') == '1':
            self.armed_rigs.add(msg.name)
            if self.armed:
                self._arm()
        if msg.name == self.graph.master and 'start_at_ns' in values and self.armed:
            self._schedule_start(int(values['start_at_ns']))
        if msg.name == 'ground_motion_publisher' and self.n_steps <= 0 and 'n_steps' in values:
            self.n_steps = int(values['n_steps'])
        if (msg.name != self.seft_name and state in (STATE_ABORTED, STATE_FAILED)
                and self.ended_by is None and self.abort_reason is None):
            self.ended_by = msg.name
            reason = f'{msg.name}: {msg.message}'
            view = (self.rig.view(time.monotonic(), self.watchdog_s)
                    if self.bridge and msg.message.startswith(rig_contract.WATCHDOG_REASON)
                    else None)
            if view:
                # the controller's silence or lost samples stopped the graph's inputs: the
                # bridge's view is the cause, the other node's watchdog its consequence
                # (before: the run's reason was 'force_servo_controller: watchdog: ...')
                reason = f'{view}; then {reason}'
            if self.realtime and self.running:
                self._abort_realtime(reason)
            else:
                # lockstep, on another rig's abort: first the samples of the steps the run
                # holds (that rig took its commands of them in), as seft simulate has them
                self.note_run_end(msg)
                self.end_after_drain(lambda: self._end(STATE_ABORTED, reason))

    # -- lockstep ---------------------------------------------------------------------------

    def _recorder_keeps_up(self) -> bool:
        return (not self.recorder_ready or self.window <= 0
                or self.rig.step - self.recorded < self.window)

    def _publish_step(self) -> None:
        """Limit check, then clock and sensor readings of the current step.

        In lockstep mode with a recorder, the rig holds the step until the recorder has
        recorded all but ``recorder_window_steps`` of the past steps: the simulated test waits
        rather than the bag losing samples.
        """
        if not self._recorder_keeps_up():
            self.waiting_for_recorder = True
            return
        reason = self.rig.limit_violation()
        if reason:
            self._end(STATE_ABORTED, reason)
            return
        self._publish_sample()

    def _publish_sample(self) -> None:
        """Publish /clock and the sensor readings of the rig's current step."""
        k = self.rig.step
        stamp = self.sample_stamp_ns(k)
        m = self.rig.measure()
        values = (m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2)
        self.measurement_pub.publish(self.measurement_msg(self.measurement_topic, stamp, values))
        self.batch.add(round(stamp / self.dt_ns), *values)
        if k % CLOCK_EVERY == 0 and self.clock_master:
            clock_ns = k * self.dt_ns
            self.clock_msg.clock.sec = int(clock_ns // 1_000_000_000)
            self.clock_msg.clock.nanosec = int(clock_ns % 1_000_000_000)
            self.clock_pub.publish(self.clock_msg)
        self.published = k + 1
        if k % PROGRESS_EVERY == 0:
            extra = {'t0_ns': self.t0_ns} if self.realtime else {}
            self.report(STATE_RUNNING, step=k, n_steps=self.n_steps, time_s=f'{m.time_s:.3f}',
                        **extra)

    def sample_stamp_ns(self, k: int) -> int:
        """The stamp of sample `k` [ns]: ``k dt`` (the rig contract; the fault rig of
        ``seft rig-check --inject`` shifts it)."""
        return k * self.dt_ns

    def _on_command(self, k: int, value: float) -> None:
        self.pending[k] = value
        while self.running and self.rig.step in self.pending:
            self.rig.apply(self.pending.pop(self.rig.step))
            if self.rig.step >= self.n_steps:
                self._end(STATE_DONE, f'completed {self.n_steps} steps')
                return
            self._publish_step()

    # -- real time --------------------------------------------------------------------------

    def _start_realtime(self) -> None:
        """Sample 0 now; the next ticks come at t0 + k dt (:meth:`next_due`, :meth:`run_due`).
        Through the UDP bridge: the controller starts, and its sample 0 starts the clock
        (:meth:`_on_datagram`)."""
        if self.bridge:
            self.last_command_at = time.monotonic()
            self.rig.start(self.n_steps)
            return
        self.t0 = time.monotonic()
        self.t0_ns = clock.now_ns()
        self.last_command_at = self.ticked_at = self.t0
        for stamp, value in self.early_commands:
            self.rig.arrive(stamp, value, 0.0)
        self.early_commands = []
        self.report(STATE_RUNNING, step=0, n_steps=self.n_steps, time_s='0.000',
                    t0_ns=self.t0_ns)
        self._sample_realtime(self.t0, self.t0)

    def next_due(self) -> float | None:
        """Real time, running: the instant of the next tick (absolute schedule t0 + k dt);
        before the common start of several rigs, that instant."""
        if self.realtime and not self.running and self.start_at is not None and not self.done:
            return self.start_at
        if not (self.realtime and self.running) or self.t0 is None:
            return None
        if self.drain_until is not None:
            return self.drain_until
        if self.bridge:
            return None             # the controller's samples drive it (_on_datagram)
        return self.t0 + (self.rig.step + 1) * self.rig.dt

    def due_step(self, now: float) -> int:
        """Real time: the ticks due by `now` [s, monotonic]: ``(now - t0) / dt``; through
        the UDP bridge the newest sample the controller sent."""
        if self.bridge:
            return self.rig.due_step()
        return int((now - self.t0) / self.rig.dt)

    # -- the UDP bridge -----------------------------------------------------------------------

    def _receive_loop(self) -> None:
        """The bridge's thread: take the controller's datagrams as they come; each sample
        is a tick (:meth:`_on_datagram`)."""
        while not self.done:
            taken = self.rig.receive()
            if self.done:
                return
            self.guard(self._on_datagram)(taken)

    def _on_datagram(self, taken: bool) -> None:
        """A datagram was taken (or the wait timed out): start the clock on the first
        sample, tick every sample, end on the controller's silence or after the drain.
        What the bridge names (a datagram from another address, the controller's refusal of
        another sender's start) is a warning, once each."""
        for line in self.rig.take_notices():
            self.warn(line)
        if not self.running:
            return
        refused = self.rig.start_violation() if self.t0 is None else None
        if refused:
            # before the first sample: the controller refused the run, or every datagram of
            # it is rejected (limit_violation judges them at a sample in effect only)
            self._abort_realtime(refused)
            self._flush_timing(final=True)
            self._end(STATE_ABORTED, refused)
            return
        if self.rig.left is not None and self.t0 is not None:
            # the controller no longer runs this session: nothing of it will come
            self._abort_realtime(self.rig.left)
            self._flush_timing(final=True)
            self._end(STATE_ABORTED, self.abort_reason)
            return
        now = time.monotonic()
        silent = self.rig.silent_s(now)
        if silent > self.watchdog_s:
            reason = (f'udp_bridge: no datagram from the controller for {1e3 * silent:.1f} '
                      f'ms (limit {1e3 * self.watchdog_s:g} ms) after t = '
                      f'{self.rig.time_s:.3f} s')
            self._abort_realtime(reason)
            self._flush_timing(final=True)
            self._end(STATE_ABORTED, reason)
            return
        if self.rig.safe_overdue(now):
            # the controller did not report its safe state within safe_confirm_s of the
            # request: the run ends, its final status says so (before: the PC waited for it
            # without a bound, as long as the controller sent anything)
            self.get_logger().error(self.rig.safe_state_values(now)['safe_unconfirmed'])
            self._flush_timing(final=True)
            self._end(STATE_ABORTED, self.abort_reason)
            return
        if self.t0 is None:
            if not self.rig.has_sample:
                return
            self.rig.advance()
            k = self.rig.step
            self.t0 = now - k * self.rig.dt
            self.t0_ns = clock.now_ns() - int(round(k * self.rig.dt * 1e9))
            self.last_command_at = self.ticked_at = now
            self.report(STATE_RUNNING, step=k, n_steps=self.n_steps,
                        time_s=f'{self.rig.time_s:.3f}', t0_ns=self.t0_ns)
            self._sample_realtime(now, now)
        if self.drain_until is not None:
            if self._drained():
                self._end_realtime()
            return
        self._tick()

    def warn(self, line: str, **values) -> None:
        """A named warning: the log, and a status report (the console, the bag, the
        report), with the rig's progress while it runs."""
        self.get_logger().warning(line)
        if self.running:
            self.report(STATE_RUNNING, line, warning=line, step=self.rig.step,
                        n_steps=self.n_steps, time_s=f'{self.rig.time_s:.3f}', **values)
        else:
            self.report(STATE_READY, line, warning=line, **values)

    def run_due(self) -> None:
        """The next tick is due: catch up with the wall clock (or the common start)."""
        if not self.running and self.start_at is not None:
            self.guard(self._begin)()
            return
        self.guard(self._tick)()

    def _on_command_realtime(self, stamp: int, value: float) -> None:
        now = time.monotonic()
        if self.t0 is None:
            self.early_commands.append((stamp, value))
            return
        self.rig.arrive(stamp, value, now - self.t0)
        self.last_command_at = now
        if self.drain_until is not None and self._drained():
            self._end_realtime()

    def _tick(self) -> None:
        """Catch up with the wall clock: every tick due by now, in order."""
        now = time.monotonic()
        if self.drain_until is not None:
            self._end_realtime()            # the drain's deadline: the rest count lost
            return
        # this rig's own loop held up longer than the limit since its last step ended (its
        # process stopped, the host stalled; before a tick or within its catch-up): the
        # commands sent meanwhile wait in its queue, read only once this catch-up has ended,
        # so the catch-up (to the moment the hold-up was seen) judges no silence of the
        # commands, and the silence counts again from its end; a second held-up tick in a row
        # judges. Before: a rig held up 263 ms after its sample 0 took its safe state on its
        # first tick (CI, seft rig-check of a lab's rig); a whole graph held up 0.5 s took it
        # after its catch-up, or within it
        held_up = False
        due = self.due_step(now)
        while self.running and self.drain_until is None and self.rig.step < due:
            start = time.monotonic()
            if (not held_up and not self.deferred and self.ticked_at is not None
                    and start - self.ticked_at > self.watchdog_s):
                held_up = True
                due = max(due, self.due_step(start))
            self.rig.advance()
            self._after_advance(start, judge_silence=not held_up)
            self.ticked_at = time.monotonic()
        self.deferred = held_up
        if held_up:
            self.last_command_at = max(self.last_command_at, self.ticked_at)

    def _after_advance(self, start: float, judge_silence: bool = True) -> None:
        rig = self.rig
        k = rig.step
        if k >= self.n_steps:
            # the last tick: wait (briefly) for the commands of the last samples
            self.drain_until = time.monotonic() + max(self.watchdog_s, DRAIN_MIN_S)
            if self._drained():
                self._end_realtime()
            return
        if rig.in_safe_state:
            if rig.safe_ramp_done:
                if self.safe_since is None:
                    self.safe_since = rig.time_s
                elif rig.time_s - self.safe_since >= SAFE_HOLD_S - 1e-9:
                    self._flush_timing(final=True)
                    self._end(STATE_ABORTED, self.abort_reason)
                    return
        else:
            reason = rig.limit_violation()
            if (reason is None and judge_silence
                    and start - self.last_command_at > self.watchdog_s):
                reason = (f'{rig_contract.WATCHDOG_REASON} no {self.command_topic.name} for '
                          f'{1e3 * (start - self.last_command_at):.1f} ms (limit '
                          f'{1e3 * self.watchdog_s:g} ms) at t = {rig.time_s:.3f} s')
            if reason:
                self._abort_realtime(reason)
        self._sample_realtime(start, time.monotonic())

    def _sample_realtime(self, start: float, now: float) -> None:
        """Publish the current tick's sample and keep its timing record pending."""
        rig = self.rig
        k = rig.step
        self._publish_sample()
        done = time.monotonic()
        scheduled = self.t0 + k * rig.dt
        jitter = now - scheduled         # the tick's lateness against the absolute schedule
        held = rig.held_source
        age = now - (self.t0 + held * rig.dt) if held >= 0 else math.nan
        self.timing_pending[k] = (jitter, done - start, age, now - scheduled >= rig.dt,
                                  k > 0 and rig.stale(k))
        self._flush_timing()

    def _flush_timing(self, final: bool = False) -> None:
        """Publish the timing records whose command arrived (or that waited long enough)."""
        k = self.rig.step
        for j in sorted(self.timing_pending):
            latency = self.rig.loop_latency_s(j)
            if latency is None and not final and k - j <= self.watchdog_steps:
                break
            jitter, compute, age, missed, stale = self.timing_pending.pop(j)
            self.timing.publish(j * self.dt_ns, jitter, compute, age, missed, stale,
                                math.nan if latency is None else latency)
        self.rig.forget_before(k - 2 * self.watchdog_steps)

    def _drained(self) -> bool:
        """The command of every sample with a pending timing record has arrived."""
        return all(self.rig.loop_latency_s(j) is not None for j in self.timing_pending)

    def _end_realtime(self) -> None:
        """After the last tick and its drain: the final timing records, then the end."""
        self._flush_timing(final=True)
        if self.abort_reason:
            self._end(STATE_ABORTED, self.abort_reason)
        else:
            self._end(STATE_DONE, f'completed {self.n_steps} steps')

    def _abort_realtime(self, reason: str) -> None:
        """Go to the safe state; the run ends once the ramp is done."""
        if self.abort_reason is not None or not self.running:
            return
        self.abort_reason = reason
        self.abort_at_s = self.rig.time_s
        self.get_logger().error(f'safe state at t = {self.abort_at_s:.3f} s: {reason}')
        self.rig.enter_safe_state()

    def on_stop_signal(self, signame: str) -> None:
        """SIGINT/SIGTERM/SIGHUP or the end of the runner: the safe state (real time: the
        command ramped to zero, sampled to the end), then the run ends aborted with that
        reason."""
        reason = f'rig stopped by {signame}'
        self.stop_signal = signame
        if self.realtime and self.running and self.drain_until is not None:
            self._end_realtime()            # every step was taken; the drain is cut short
        elif self.realtime and self.running:
            self._abort_realtime(reason)
        else:
            self._end(STATE_ABORTED, reason)

    def stepping_begun(self) -> bool:
        """Whether this rig has begun stepping (its sample 0 is out)."""
        return self.running or self.published > 0

    def run_time_s(self) -> float:
        """The rig's time [s]: its current step's."""
        return self.rig.step * self.rig.dt

    def abort_run(self, reason: str, step: int, **values) -> None:
        """Stop the run from this rig (a foreign publisher on its command topic, parameters
        that differ once the run has begun): in real time, running, its safe state (the
        command ramped to zero, sampled to the end, as after any abort); otherwise the
        run ends aborted at its current step. `step` is ignored (the rig's own is
        reported); `values` go into the final status.

        (The base class's abort reports and finishes at once: a real-time rig ending so
        stops with no safe ramp.)
        """
        self.abort_values.update(values)
        if self.realtime and self.running and self.drain_until is not None:
            # every step was taken (as on a stop signal then): the run is complete
            self.get_logger().error(f'{reason} (after the last step: the run is complete)')
            self._end_realtime()
        elif self.realtime and self.running:
            self._abort_realtime(reason)
        else:
            self._end(STATE_ABORTED, reason)

    def stop_hold_s(self) -> float:
        """Real time, once the rig has started: its safe stop (the commands already output,
        the ramp, the hold after it: ``seft_msgs_py.rig_contract.safe_stop_s``) holds
        the process against a second stop signal, so that a second Ctrl-C does not cut the
        ramp (a bridge's included: the lab's controller ramps on the rig's request; the
        bridge waits for its report at most ``rig_contract.safe_confirm_s``, then holds
        ``SAFE_HOLD_S``)."""
        if not self.realtime or self.t0 is None:
            return 0.0
        if self.bridge:
            # the wait for the controller's safe state, then the hold after it
            return rig_contract.safe_confirm_s(self.params) + SAFE_HOLD_S
        return rig_contract.safe_stop_s(self.params)

    def published_count(self) -> int:
        """Samples this rig published (its final status reports it)."""
        return self.published

    def _end(self, state: str, message: str) -> None:
        if self.done:
            return
        k = self.rig.step
        self.running = False
        if state == STATE_ABORTED:
            self.get_logger().error(f'run aborted at step {k}: {message}')
        else:
            self.get_logger().info(message)
        extra = {}
        if self.bridge:
            extra.update(self.rig.wire_counts())
            extra.update(self.rig.safe_state_values(time.monotonic()))
            self.rig.close()
        if self.realtime:
            extra.update(self.timing.counts())
            if self.abort_at_s is not None:
                extra['abort_at_s'] = f'{self.abort_at_s:.6f}'
            extra['discarded_commands'] = self.rig.discarded
            if getattr(self.rig, 'late_command', 'hold') == 'predict':
                extra['predicted_commands'] = self.rig.predicted
        if getattr(self, 'wall_start', None) is not None:
            extra['wall_s'] = f'{time.monotonic() - self.wall_start:.3f}'
        if self.stop_signal:
            extra['signal'] = self.stop_signal
        if self.ended_by is not None:
            extra['ended_by'] = self.ended_by
        extra.update(self.abort_values)
        self.report(state, message, step=k, n_steps=self.n_steps,
                    time_s=f'{k * self.rig.dt:.6f}', published=self.published,
                    mode=self.params['mode'],
                    **{rig_contract.CONTRACT_KEY: rig_contract.CONTRACT}, **extra)
        self.finish(0)


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_plant_sim rig``."""
    return main_for(RigNode, 'rig', args)


if __name__ == '__main__':
    sys.exit(main())
