"""What every seft node shares: schema parameters, status reports, a clean ``main``, and the
run's seal on what it publishes and takes (:mod:`seft_msgs_py.provenance`).

``main`` follows ``ros2/demos`` ``demo_nodes_py/topics/talker.py``: spin in ``try``, catch
``KeyboardInterrupt`` and ``ExternalShutdownException``, destroy the node and
``rclpy.try_shutdown()`` in ``finally``. A :class:`~seft_msgs_py.errors.SeftError` (bad parameter
or input file)
becomes a one-line message on stderr and exit code 2.
"""

import contextlib
from dataclasses import replace
import faulthandler
import gc
import json
import math
import os
import signal
import sys
import threading
import time
import traceback
from typing import Callable, Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from seft_msgs_py import clock, parameters
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RUNNING,
    FieldsReader,
    ScalarReader,
    SerializedStamped,
    dt_to_ns,
    frame_id_of_raw,
    status_msg,
    status_values,
)
from seft_msgs_py.dds import use_seft_profile
from seft_msgs_py.errors import ParameterError, SeftError
from seft_msgs_py.graph import UNKNOWN_NODE, Graph, qualified, scoped, split_qualified
from seft_msgs_py.provenance import NONE as NO_TOKEN
from seft_msgs_py.provenance import RunSeal
from seft_msgs_py.rig_contract import FOREIGN_REASON
from seft_msgs_py.scheduling import set_fifo
from seft_msgs_py.signals import (
    ESTIMATES,
    MEASUREMENT_FIELDS,
    RECORD_ROWS,
    RecordStream,
)
from seft_msgs_py.stopping import STOP_SIGNALS, RunnerWatch, StopRequests
from seft_msgs_py.topics import MEASUREMENT, NODE_PARAMETERS, STATUS, record_topic

__all__ = ['SeftNode', 'StepTiming', 'RecordBatch', 'InputWatchdog', 'main_for',
           'main_for_nodes', 'descriptor_of', 'STACKS_SIGNAL', 'LINGER_S', 'shut_down',
           'SHUTDOWN_TIMEOUT_S', 'exit_if_longer']

#: The signal that makes a node process write every thread's Python stack to stderr (its
#: log) and go on (``faulthandler.register``): ``kill -USR1 PID`` of a node that does not end.
#: Seen under the test suite's load (load average 5): a reference-force builder that had done
#: its 500 lockstep steps was alive 60 s later, printed nothing and ignored SIGINT for 10 s.
STACKS_SIGNAL = signal.SIGUSR1
#: How long a finished node keeps serving its publishers before it exits [s].
LINGER_S = 1.0
#: With a recorder in the graph, the longest wait for it to close the bag [s].
RECORDER_WAIT_S = 20.0
#: The longest the nodes' destruction and rclpy's shutdown may take after a run [s]
#: (:func:`shut_down`).
SHUTDOWN_TIMEOUT_S = 10.0
#: SCHED_FIFO priority of each node relative to ``realtime_priority``. The builder is on a
#: par with the controller: its f_r[k+1] is due at the controller's next activation. Measured
#: on a bridge on two rigs at 500 Hz (7 processes, 2 cores): with the builder one below the
#: controllers its reference forces missed their step 9 % of the time, the controllers used an
#: older one 6-7 % of the time and the displacement NRMS was 1.4-2.2 %; on a par, 0.1 % and
#: 0.16-0.26 % (lockstep: 0.17 %); above the rigs, the rigs' own commands came late (1.3 %).
#: The study's single rig: unchanged (alpha 1, model: 0.40 %, 0.04 % stale).
PRIORITY_OFFSET = {'rig': 3, 'force_servo_controller': 2, 'reference_force_builder': 2,
                   'ground_motion_publisher': 1, 'recorder': -1}
#: Lockstep, a rig aborted the run: the longest a node waits for the inputs of the steps the
#: run holds before it ends anyway (:meth:`SeftNode.end_after_drain`) [s].
DRAIN_TIMEOUT_S = 2.0
#: Start of the 'failed' status message of a node that refused differing parameters.
MISMATCH_MESSAGE = 'parameters differ between nodes: '
#: Start of the 'aborted' reason of a node that found differing parameters once the run had
#: begun stepping (:meth:`SeftNode._refuse_parameters`): the run is stopped safely.
MISMATCH_ABORT = 'parameters differ between nodes after the start: '
#: The ROS arguments of the node being created by :func:`main_for_nodes` (None: the
#: process's own, as ``ros2 run`` gives them).
_node_arguments: list[str] | None = None
#: A foreign publisher whose node has not announced its name yet: how long a node looks for
#: the name in its view of the graph after it named the publisher by its gid [s], and how
#: often [s].
FOREIGN_LOOKUP_S = 1.0
FOREIGN_LOOKUP_EVERY_S = 0.01


def descriptor_of(spec: parameters.ParamSpec) -> ParameterDescriptor:
    """The ``ParameterDescriptor`` of a schema parameter (description, unit, range).

    Dynamic typing is on so that ``alpha: 1`` in a YAML file is accepted for a float
    parameter; the schema validation that follows checks type and range with a clear message.
    """
    unit = f' [{spec.unit}]' if spec.unit else ''
    d = ParameterDescriptor(name=spec.name, description=spec.description + unit,
                            additional_constraints=f'expected {spec.expected()}',
                            read_only=False, dynamic_typing=True)
    lo, hi = spec.minimum, spec.maximum
    if lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi):
        if isinstance(spec.default, int) and not isinstance(spec.default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
        elif isinstance(spec.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
    return d


#: The process-wide BLAS thread limit of a node process (:meth:`SeftNode.apply_priority`).
_BLAS_LIMIT = None

class SeftNode(Node):
    """A node of the seft graph: declares its schema parameters and reports its state.

    A node of a rig of a structure runs in the rig's ROS namespace (``-r __ns:=/<rig>``,
    :mod:`seft_msgs_py.graph`): its qualified name ``seft_name`` is ``<rig>/<node>``.

    Parameters
    ----------
    node_name : str
        One of ``seft_msgs_py.parameters.NODES``.

    Attributes
    ----------
    kind : str
        `node_name`.
    rig_name : str
        The rig of the node's namespace ('' in the root namespace).
    seft_name : str
        The qualified name (status reports, parameters, ``seft run --nodes``).
    graph : Graph
        The run's graph, from the parameters.
    seal : RunSeal
        The run's seal (``run_token``, ``message_auth``; :mod:`seft_msgs_py.provenance`):
        what this node puts on the messages it publishes and checks on those it takes.
    foreign : dict
        Topic -> how many messages without the run's seal this node dropped.
    taken : dict
        Topic -> how many sealed messages of its stamped inputs (the measurement, a
        command) this node took while it ran (its final status: ``taken:<topic>``).

    Raises
    ------
    ParameterError
        If a parameter value is out of its schema range (message names it), the node's
        namespace is not a rig of the run's graph where it must be, or the run's seal
        (its token, the key file of ``message_auth: hmac``).
    """

    def __init__(self, node_name: str, **kwargs):
        if _node_arguments is not None:
            # one of several nodes of a process (main_for_nodes): its own ROS arguments
            kwargs.setdefault('cli_args', list(_node_arguments))
            kwargs.setdefault('use_global_arguments', False)
        super().__init__(node_name, **kwargs)
        self.kind = node_name
        namespace = self.get_namespace().strip('/')
        if '/' in namespace:
            raise ParameterError(f'namespace /{namespace}: expected the root namespace or one '
                                 'level named after a rig of the structure')
        self.rig_name = namespace
        self.seft_name = qualified(node_name, namespace)
        self.params = self._declare(node_name)
        self.graph = Graph.from_parameters(self.params)
        if namespace and namespace not in self.graph.rigs:
            raise ParameterError(f'node {self.seft_name}: namespace /{namespace} is not a rig '
                                 "of the run's structure (rigs: "
                                 f'{", ".join(r for r in self.graph.rigs if r) or "none"})')
        self.realtime = self.params.get('mode') == 'realtime'
        self.dt_ns = dt_to_ns(self.params['dt'])
        self.seal = RunSeal.from_parameters(self.params)
        self.foreign: dict[str, int] = {}
        self.taken: dict[str, int] = {}
        self._foreign_named: set[str] = set()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.status_pub = self.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
        self.recorder_ready = False
        self.recorder_closed = False
        self.create_subscription(STATUS.msg_type, STATUS.name, self._on_any_status, STATUS.qos)
        self.done = False
        self.exit_code = 0
        #: System-clock time [ns] of sample 0, from the rig's status (real-time mode).
        self.t0_ns: int | None = None
        #: The run's number of steps, from the rig's 'running' status (None before).
        self.run_steps: int | None = None
        self.timing: StepTiming | None = None
        #: The parameters each node of the graph resolved: {node: {name: value}}.
        self.node_params: dict[str, dict] = {}
        #: When (monotonic [s]) each node's parameters were first heard (this one's: sent).
        self.node_heard_at: dict[str, float] = {}
        #: ``(node, run_token)`` of the parameters heard from nodes of another run (another
        #: token: not this run's, never compared; said once each in this node's log).
        self.foreign_params: set[tuple[str, str]] = set()
        self.node_params_pub = self.create_publisher(
            NODE_PARAMETERS.msg_type, NODE_PARAMETERS.name, NODE_PARAMETERS.qos)
        self.create_subscription(NODE_PARAMETERS.msg_type, NODE_PARAMETERS.name,
                                 self._on_node_parameters, NODE_PARAMETERS.qos)
        #: This node refused the graph's parameters (a shared value differs between nodes).
        self.refused = False
        #: This node stopped the run on parameters that differ once it had begun.
        self.mismatch_stopped = False
        #: The nodes whose status this node has received.
        self.heard: set[str] = set()
        #: This node's record batches (flushed before its final status).
        self.records: list[RecordBatch] = []
        #: The rigs (qualified names) whose final status has been heard.
        self.rigs_final: set[str] = set()
        #: Lockstep, a rig aborted the run: that rig (named by its own final status or by
        #: another rig's that passed it on) and, once its own final status is in, the steps
        #: the run holds (its samples published; :meth:`note_run_end`).
        self.run_end_rig: str | None = None
        self.run_end_step: int | None = None
        self.draining = False

    def record_stream(self, stream: RecordStream | None = None,
                      columns: tuple[str, ...] = ()) -> 'RecordBatch':
        """The :class:`RecordBatch` of one of this node's record streams (default: its data
        stream), created once; `columns` names the fields of a ``fields_topic`` stream."""
        stream = stream or self.graph.record_streams_of(self.seft_name)[0]
        batch = RecordBatch(self, stream, columns)
        self.records.append(batch)
        return batch

    def next_due(self) -> float | None:
        """Monotonic time [s] of this node's next scheduled work (None: events only).

        A node on a fixed schedule (the rig in real-time mode) overrides this and
        :meth:`run_due`; :func:`main_for` then waits for events only until that time.
        Measured here: an rclpy timer on the EventsExecutor drifts (at 500 Hz it lost 1-4 %
        of its periods and fell 10-180 ms behind a 5 s schedule), while waiting in
        ``spin_once(timeout)`` up to absolute deadlines kept the lateness at 0.13-0.18 ms p50.
        """
        return None

    def run_due(self) -> None:
        """Do the work scheduled at :meth:`next_due` (called once it is due)."""

    def apply_priority(self) -> None:
        """BLAS to one thread (lockstep too); in real time with ``realtime_priority`` > 0, run
        this process under SCHED_FIFO.

        The priority is ``realtime_priority`` plus ``PRIORITY_OFFSET`` of the node: the
        rig highest, then the controller and the builder, then the ground-motion publisher,
        and the recorder lowest: it must keep up (at the normal priority the loop's nodes
        starved it and the bag lost samples), but its bag writes must never delay the loop.
        Where the system refuses (no root, no CAP_SYS_NICE, no RT budget) the node logs one
        warning and keeps the normal scheduler: a run never fails for it.

        In real time the BLAS libraries are limited to one thread for the process's life,
        with or without SCHED_FIFO. Under it, OpenBLAS's pool threads inherit the real-time
        priority and busy-wait between calls, and on two cores they starved the other nodes
        for 20-80 ms at the first large solve (the ``adaptive`` compensator's refit of the
        force-loop inverse: every real-time run of it aborted on a watchdog within 0.6 s; with
        one thread none did). At the normal scheduler a pool of two made the compensators'
        small products slow on a loaded host: a ``DelayImpulseModel`` (2x2 matrices) took
        4.2 ms at p99 and 20 ms at most, 0.13 and 1.1 ms with one thread. Lockstep keeps one
        thread too, as ``seft simulate`` does: ``adaptive``'s refits during the run (2x2
        matrix exponentials) took 24 ms each with a pool of two on a loaded host, 0.2 ms with
        one, and the numbers are the same.
        """
        if self.kind not in PRIORITY_OFFSET:
            return
        global _BLAS_LIMIT
        if _BLAS_LIMIT is None:
            from threadpoolctl import ThreadpoolController
            _BLAS_LIMIT = ThreadpoolController().limit(limits=1)     # kept: never restored
        if not self.realtime:
            return
        base = int(self.params.get('realtime_priority', 0))
        if base <= 0:
            return
        priority = max(1, min(99, base + PRIORITY_OFFSET[self.kind]))
        try:
            set_fifo(priority)
        except (OSError, AttributeError) as exc:
            self.get_logger().warning(f'realtime_priority={priority}: SCHED_FIFO refused '
                                      f'({exc}); keeping the normal scheduler')
            return
        self.get_logger().info(f'SCHED_FIFO priority {priority}')

    def scalar_subscription(self, spec, callback: Callable[[int, float], None]):
        """Subscribe to a scalar topic; `callback(step, value)` gets the sample's step and value.

        A raw subscription read by :class:`~seft_msgs_py.convert.ScalarReader` (no rclpy message
        object per sample), guarded like every callback. A message without the run's seal is
        dropped before the callback (:meth:`foreign_input`: the topic commands the rig).
        """
        read, dt_ns, guarded = ScalarReader(spec), self.dt_ns, self.guard(callback)
        frame_ok, topic, msg_type = self.seal.frame_ok, spec.name, spec.msg_type
        foreign, taken = self.guard(self.foreign_input), self.taken
        taken[topic] = 0

        def on_raw(raw):
            stamp, value = read(raw)
            frame = frame_id_of_raw(raw, msg_type)
            if not frame_ok(frame, topic, stamp, (value,)):
                foreign(topic, frame, True)
                return
            if not self.done:
                taken[topic] += 1
            guarded(int(round(stamp / dt_ns)), value)
        return self.create_subscription(spec.msg_type, spec.name, on_raw, spec.qos, raw=True,
                                        event_callbacks=self.publisher_watch(topic))

    def measurement_subscription(self, callback: Callable[[int, tuple], None],
                                 rig: str | None = None):
        """Subscribe to a rig's measurement (default: this node's rig); `callback(step,
        values)` gets the sample's step and the values of
        :data:`~seft_msgs_py.signals.MEASUREMENT_FIELDS` (measured force [N], displacement [m],
        velocity [m/s], acceleration [m/s^2]). Raw and guarded, like
        :meth:`scalar_subscription`, and sealed likewise."""
        read = FieldsReader(MEASUREMENT.msg_type, MEASUREMENT_FIELDS, self.seal.frame_id)
        dt_ns, guarded = self.dt_ns, self.guard(callback)
        topic = scoped(MEASUREMENT.name, self.rig_name if rig is None else rig)
        frame_ok, msg_type = self.seal.frame_ok, MEASUREMENT.msg_type
        foreign, taken = self.guard(self.foreign_input), self.taken
        taken[topic] = 0

        def on_raw(raw):
            stamp, values = read(raw)
            frame = frame_id_of_raw(raw, msg_type)
            if not frame_ok(frame, topic, stamp, values):
                foreign(topic, frame, True)
                return
            if not self.done:
                taken[topic] += 1
            guarded(int(round(stamp / dt_ns)), values)
        return self.create_subscription(MEASUREMENT.msg_type, topic, on_raw, MEASUREMENT.qos,
                                        raw=True, event_callbacks=self.publisher_watch(topic))

    def sealed_writer(self, template: SerializedStamped) -> Callable[[str, int, tuple], bytes]:
        """``write(topic, stamp_ns, values) -> bytes``: the serialized message of one sample
        of `template` (made with this run's frame id, ``seal``), sealed for `topic`."""
        seal = self.seal
        if not seal.authenticated:
            return lambda topic, stamp_ns, values: template(stamp_ns, values)

        def write(topic, stamp_ns, values):
            return template(stamp_ns, values, seal.seal(topic, stamp_ns, values).encode())
        return write

    def batch_sealed(self, stream: RecordStream, msg) -> bool:
        """Whether a record batch (a deserialized ``Float64MultiArray`` of `stream`) carries
        the run's seal in its first label."""
        dims = msg.layout.dim
        label = dims[0].label if dims else ''
        return self.seal.label_ok(label, stream.name, msg.data)

    def foreign_input(self, topic: str, seen, commands: bool) -> None:
        """A message on `topic` without the run's seal (`seen`: its frame id or label): it
        is dropped (never applied) and counted, and its publisher named once
        (:meth:`foreign_publisher`)."""
        self.foreign[topic] = self.foreign.get(topic, 0) + 1
        if isinstance(seen, bytes):
            seen = seen.decode('utf-8', 'replace')
        self.foreign_publisher(topic, commands, 'its message was not sealed for this run '
                               f'(frame id {seen!r}; {self.seal.describe()}); dropped, never '
                               'applied')

    def publisher_watch(self, topic: str, commands: bool = True) -> SubscriptionEventCallbacks:
        """The event callbacks of a subscription to `topic`: when more publishers match it
        than the run has (:meth:`~seft_msgs_py.graph.Graph.publishers_of`), the new one is
        foreign (:meth:`foreign_publisher`), named before its first message is taken (the
        match comes first: measured here 16-100 ms before the first message of a new
        process's publisher)."""
        expected = len(self.graph.publishers_of(topic))
        foreign = self.guard(self.foreign_publisher)

        def matched(info):
            if info.current_count > expected:
                foreign(topic, commands, f'{info.current_count} publishers where the run has '
                        f'{expected}')
        return SubscriptionEventCallbacks(matched=matched)

    def foreign_publisher(self, topic: str, commands: bool, what: str) -> None:
        """A foreign publisher on `topic` (`what` it did), once per topic: named from this
        node's view of the graph (:meth:`~seft_msgs_py.graph.Graph.foreign_publishers`) in
        an abort on a topic that commands the rig (`commands`), at once, and a warning
        elsewhere. A new process's node announces its name some 80 ms after its publisher
        matches (measured here): the abort names it by its gid then, and once the name is
        known (within ``FOREIGN_LOOKUP_S``) a warning names it."""
        if topic in self._foreign_named:
            return
        self._foreign_named.add(topic)
        who, unnamed = self._foreign_found(topic)
        line = (f'{FOREIGN_REASON}{topic}: '
                + (', '.join(who) if who else "no publisher but the run's own in this node's "
                   'view (a sender that has left, or a node of the run with another token '
                   'or key)') + f': {what}')
        if commands:
            self.abort_run(line, int(getattr(self, 'next_step', 0)), foreign_topic=topic)
        else:
            self.warn(line, foreign_topic=topic)
        if not unnamed:
            return
        deadline = time.monotonic() + FOREIGN_LOOKUP_S

        def name_it():
            # after the abort too (this node has finished, and lingers): not guarded
            who, unnamed = self._foreign_found(topic)
            if unnamed and time.monotonic() < deadline:
                return
            timer.cancel()
            if who:
                named = f'{FOREIGN_REASON}{topic}: ' + ', '.join(who) + ' (named)'
                self.get_logger().warning(named)
                self.report(STATE_RUNNING, named, warning=named, foreign_topic=topic)
        timer = self.create_timer(FOREIGN_LOOKUP_EVERY_S, name_it,
                                  clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _foreign_found(self, topic: str) -> tuple[list[str], bool]:
        """The foreign publishers of `topic` named, and whether one's node has not
        announced its name yet."""
        found = [(i.node_name, i.node_namespace, i.endpoint_gid)
                 for i in self.get_publishers_info_by_topic(topic)]
        return (self.graph.foreign_publishers(topic, found),
                any(node == UNKNOWN_NODE for node, _, _ in found))

    def foreign_publishers(self, topic: str) -> list[str]:
        """The publishers of `topic` this node knows of that are not the run's (named)."""
        return self._foreign_found(topic)[0]

    def warn(self, line: str, **values) -> None:
        """A named warning: this node's log, and a status report with ``warning`` (the
        console, the bag, the report)."""
        self.get_logger().warning(line)
        self.report(STATE_RUNNING, line, warning=line, **values)

    def scoped_spec(self, spec, rig: str | None = None):
        """A study topic's spec in the namespace of `rig` (default: this node's)."""
        return replace(spec, name=scoped(spec.name, self.rig_name if rig is None else rig))

    def subscribed_by(self, node: str, topic: str) -> bool:
        """Whether the node of qualified name `node` subscribes to `topic` (discovered)."""
        rig, kind = split_qualified(node)
        namespace = '/' + rig
        return any(i.node_name == kind and i.node_namespace == namespace
                   for i in self.get_subscriptions_info_by_topic(topic))

    def publishes(self, node: str, topic: str) -> bool:
        """Whether the node of qualified name `node` publishes `topic` (discovered)."""
        rig, kind = split_qualified(node)
        namespace = '/' + rig
        return any(i.node_name == kind and i.node_namespace == namespace
                   for i in self.get_publishers_info_by_topic(topic))

    def publish_parameters(self) -> None:
        """Publish the parameters this node resolved (latched), and check them at once.

        Call at the end of ``__init__``, once ``self.params`` is complete.
        """
        self.node_params[self.seft_name] = dict(self.params)
        self.node_heard_at.setdefault(self.seft_name, time.monotonic())
        self.node_params_pub.publish(String(data=json.dumps(
            {'node': self.seft_name, 'parameters': self.params}, sort_keys=True)))

    def _on_node_parameters(self, msg) -> None:
        """Collect another node's parameters (also once this node has finished: after a
        refusal :func:`main_for` lingers until every node is heard); refuse to go on when a
        shared value differs.

        Parameters with another ``run_token`` than this node's are another run's (a node
        started by hand on the run's domain, another test): never taken for this run's
        nor compared, and said once per node and token in this node's log (the runner
        names them on the console). The run's own nodes share its token, so a node of the
        run started with other parameters is still refused.
        """
        try:
            data = json.loads(msg.data)
            node, values = str(data['node']), dict(data['parameters'])
        except (ValueError, KeyError, TypeError):
            self.get_logger().warning('ignoring a malformed /seft/node_parameters message')
            return
        try:
            split_qualified(node)
        except ParameterError:
            return
        token = str(values.get('run_token', NO_TOKEN))
        if token != str(self.params.get('run_token')):
            if (node, token) not in self.foreign_params:
                self.foreign_params.add((node, token))
                self.get_logger().warning(
                    f'{FOREIGN_REASON}{NODE_PARAMETERS.name}: parameters of a node {node!r} '
                    f"with run_token {token!r}, not this run's: ignored (another run's node)")
            return
        self.node_params[node] = values
        self.node_heard_at.setdefault(node, time.monotonic())
        self.guard(self._check_parameters)()

    def _check_parameters(self) -> None:
        lines = parameters.shared_mismatches(self.node_params)
        if lines:
            self._refuse_parameters(lines)

    def stepping_begun(self) -> bool:
        """Whether the run has begun stepping as this node knows it (its clock master's
        'running' report with the run's steps has been heard); the rig overrides it."""
        return self.run_steps is not None

    def run_time_s(self) -> float | None:
        """The run's time [s] where this node stops it, for an abort's reason (None: this
        node does not step the run; the rig overrides it)."""
        return None

    def _refuse_parameters(self, lines: list[str]) -> None:
        """Name every differing parameter in one line on stderr; before the run has begun
        stepping, report 'failed' and exit 2 (nothing was run); once it has, stop the run
        safely, once (:meth:`abort_run`: the rig to its safe state, the recording closed;
        the rig's reason says the time it stopped at)."""
        if self.mismatch_stopped:
            return
        for line in lines:
            print(f'{self.seft_name}: error: {line}', file=sys.stderr, flush=True)
        if self.stepping_begun():
            self.mismatch_stopped = True
            at = self.run_time_s()
            self.abort_run(MISMATCH_ABORT + '; '.join(lines) + '; the run is stopped safely'
                           + ('' if at is None else f' at t = {at:.3f} s'),
                           int(getattr(self, 'next_step', 0)))
            return
        self.refused = True
        self.report(STATE_FAILED, MISMATCH_MESSAGE + '; '.join(lines))
        self.finish(2)

    def refused_by_another_node(self, msg) -> bool:
        """Another node refused the graph's parameters: refuse too (True), else False.

        Call first in every status callback that ends the node. The 'failed' status of the
        node that found the mismatch may arrive before the parameters that differ (two
        topics, no order between them): the node then names the parameters as that node
        reported them, instead of taking the failure for the end of a run.
        """
        if msg.name == self.seft_name or not msg.message.startswith(MISMATCH_MESSAGE):
            return False
        if status_values(msg).get('state') != STATE_FAILED:
            return False
        lines = (parameters.shared_mismatches(self.node_params)
                 or msg.message[len(MISMATCH_MESSAGE):].split('; '))
        self._refuse_parameters(lines)
        return True

    def refusal_heard(self) -> bool:
        """After a refusal: every node of the graph has published its parameters or a status
        here, so it is up and receives the refusal too (the graph: every node, the force servo
        controller only unless every node says rig_model 'delay'; without a recorder the
        refusing nodes linger ``RECORDER_WAIT_S``)."""
        expected = set(self.graph.nodes()) | {'recorder'}
        return expected <= set(self.node_params) | self.heard

    def _declare(self, node_name: str) -> dict:
        values = {}
        for spec in parameters.specs_for_node(node_name):
            try:
                p = self.declare_parameter(spec.name, spec.default, descriptor_of(spec))
            except Exception:  # rclpy raises several types for a bad override
                given = getattr(self, '_parameter_overrides', {}).get(spec.name)
                shown = f'={given.value!r}' if given is not None else ''
                raise ParameterError(f'parameter {spec.name}{shown}: expected '
                                     f'{spec.expected()}') from None
            values[spec.name] = parameters.validate_value(spec.name, p.value)
        return values

    def status_of_run(self, msg) -> bool:
        """Whether the status report `msg` carries the run's seal (its ``hardware_id``,
        :meth:`~seft_msgs_py.provenance.RunSeal.status_ok`; a node by hand: none). Every
        status callback acts on the run's reports only; ``_on_any_status`` counts and names
        the others (:meth:`foreign_status`)."""
        return self.seal.status_ok(msg, STATUS.name)

    def foreign_status(self, msg) -> None:
        """A status report without the run's seal (another run's node, a node by hand on
        the domain): dropped (it never ends nor changes the run), counted with this node's
        dropped messages (``foreign_dropped``) and its publisher named once, in a warning
        (:meth:`foreign_publisher`)."""
        self.foreign[STATUS.name] = self.foreign.get(STATUS.name, 0) + 1
        self.foreign_publisher(
            STATUS.name, False, f'its status report was not sealed for this run (node '
            f"{msg.name!r}, state {status_values(msg).get('state')!r}, hardware id "
            f'{msg.hardware_id!r}; {self.seal.describe()}); dropped, never acted on')

    def _on_any_status(self, msg) -> None:
        """Track the nodes heard and the recorder, also once this node has finished
        (:func:`main_for` lingers until the recorder has closed the bag, or failed: then it
        records nothing more; after a refusal, until every node is heard), then
        :meth:`_watch_run`. A report without the run's seal: :meth:`foreign_status` only."""
        if not self.status_of_run(msg):
            self.guard(self.foreign_status)(msg)     # not after this node's end (guard)
            return
        self.heard.add(msg.name)
        if msg.name == 'recorder':
            self.recorder_ready = True
            self.recorder_closed = (self.recorder_closed or status_values(msg).get('state')
                                    in (STATE_CLOSED, STATE_FAILED))
        elif status_values(msg).get('failed_node') == 'recorder':
            self.recorder_closed = True     # a runner's report: the recorder died
        self.guard(self._watch_run)(msg)

    def own_rigs(self) -> tuple[str, ...]:
        """The rig nodes whose end ends this node: its own rig for a node in a rig's
        namespace, every rig for a node of the root namespace."""
        rig = self.graph.rig_of(self.seft_name)
        return (qualified('rig', rig),) if rig is not None else self.graph.rig_nodes()

    def _watch_run(self, msg) -> None:
        """Refuse another node's parameter mismatch; end this node when its rig (a node of
        the root namespace: every rig) has finished the run."""
        if self.refused_by_another_node(msg):
            return
        values = status_values(msg)
        state = values.get('state')
        master = msg.name == self.graph.master
        if master and 't0_ns' in values and self.t0_ns is None:
            self.t0_ns = int(values['t0_ns'])
        if master and state == STATE_RUNNING and 'n_steps' in values:
            self.run_steps = int(values['n_steps'])
        ended = None
        if msg.name in self.graph.rig_nodes() and state in (STATE_DONE, STATE_ABORTED,
                                                            STATE_FAILED):
            ended = msg.name
        elif values.get('failed_node') in self.graph.rig_nodes() and state in (
                STATE_ABORTED, STATE_FAILED):
            # a runner's report of a rig that died: it will send no final status of its own
            # (waiting for one, this node sent none either, and the recorder closed the bag
            # without them after its FLUSH_TIMEOUT_S)
            ended = values['failed_node']
        if ended is not None:
            self.rigs_final.add(ended)
            self.note_run_end(msg)
        if (self.kind not in ('rig', 'recorder') and ended is not None
                and set(self.own_rigs()) <= self.rigs_final):
            self.end_after_drain(self._rig_finished)
        elif (msg.name == 'recorder' and state == STATE_CLOSED
              and self.kind not in ('rig', 'recorder')):
            # the bag closed without the rig's final status (rig or link lost): over too
            self.report(STATE_DONE, 'the recorder closed the bag', **self.final_counts())
            self.finish(0)

    def note_run_end(self, msg) -> None:
        """Lockstep: from a rig's 'aborted' or 'failed' final status, the rig whose abort
        ended the run and the steps the run holds.

        A rig that ends on another node's abort names it (``ended_by``); the rig that aborted
        the run on its own names none, and its ``published`` is the run's steps: ``seft
        simulate`` stops at the same step (its ``n_steps``), and every other node has the
        inputs to publish its samples of those steps (:meth:`end_after_drain`). Status reports
        from several writers arrive in any order: a rig that passed the abort on may be heard
        before the rig that aborted.
        """
        values = status_values(msg)
        if (self.realtime or msg.name not in self.graph.rig_nodes()
                or values.get('state') not in (STATE_ABORTED, STATE_FAILED)):
            return
        by = values.get('ended_by')
        if by is None:
            self.run_end_rig = self.run_end_rig or msg.name
            if 'published' in values:
                step = int(values['published'])
                self.run_end_step = step if self.run_end_step is None else min(
                    self.run_end_step, step)
        elif self.run_end_rig in (None, msg.name):
            self.run_end_rig = by

    def end_after_drain(self, end: Callable[[], None]) -> None:
        """Call `end` now, or (lockstep, a rig aborted the run) once this node has published
        its samples of every step the run holds.

        The other nodes end on the aborting rig's report, which can reach them before their
        last inputs (another writer, another topic): a controller then never sent the valve
        command of the run's last step, and the bag lacked a step that ``seft simulate``
        holds. Every input of those steps exists (the aborting rig took them in), so the wait
        is short; after ``DRAIN_TIMEOUT_S`` (an input lost with a node) the node ends
        anyway, and the bag holds what it holds.
        """
        if self.draining or self.done:
            return
        deadline = time.monotonic() + DRAIN_TIMEOUT_S

        def drained() -> bool:
            step = self.run_end_step
            return (self.realtime or self.run_end_rig not in self.graph.rig_nodes()
                    or (step is not None and self.published_count() >= step)
                    or time.monotonic() > deadline)

        def check():
            if drained():
                timer.cancel()
                end()
        if drained():
            end()
            return
        self.draining = True
        timer = self.wall_timer(0.002, check)

    def _rig_finished(self) -> None:
        self.report(STATE_DONE, 'rig finished', **self.final_counts())
        self.finish(0)

    def abort_run(self, reason: str, step: int, **values) -> None:
        """Stop the run safely from this node: log, report 'aborted' with the step (and
        `values`), finish."""
        self.get_logger().error(reason)
        # with what it published so far, so that the recorder can tell what is missing
        self.report(STATE_ABORTED, reason, step=step, time_s=f'{step * self.dt_ns * 1e-9:.6f}',
                    **self.final_counts(), **values)
        self.finish(0)

    def on_stop_signal(self, signame: str) -> None:
        """SIGINT, SIGTERM or SIGHUP during the run, or the end of the runner (`signame`:
        the signal's name, or :attr:`~seft_msgs_py.stopping.RunnerWatch.reason`): end it
        safely from this node (the rig goes to its safe state when it hears the abort; the
        recorder closes the bag after it).

        Nodes override this (the rig ramps to its safe state itself). A second signal ends
        the process at once, unless a node of the process holds it (:meth:`stop_hold_s`).
        """
        self.abort_run(f'{self.seft_name} stopped by {signame}',
                       int(getattr(self, 'next_step', 0)), signal=signame)

    def stop_hold_s(self) -> float:
        """How long this node's safe stop holds its process against a second stop signal,
        from the first [s]; 0 (the default): it does not, a second signal ends the process
        at once. The rig holds it for its safe ramp, the recorder to record it
        (:mod:`seft_msgs_py.stopping`)."""
        return 0.0

    def final_counts(self) -> dict:
        """What the final status reports: samples published, and timing records with their
        missed deadlines and stale inputs (real-time mode)."""
        counts = {'published': self.published_count()}
        counts.update({f'taken:{topic}': n for topic, n in self.taken.items()})
        if self.foreign:
            counts['foreign_dropped'] = sum(self.foreign.values())
        if self.timing is not None:
            counts.update(self.timing.counts())
        for batch in self.records:
            if batch.stream.fields_topic:
                # each fields topic's rows (a builder may have several: the structure's state,
                # each rig's estimates); the study's estimates also as 'published_estimates'
                counts[f'published:{batch.stream.fields_topic}'] = batch.added
                if batch.stream.fields_topic == ESTIMATES.name:
                    counts['published_estimates'] = batch.added
        return counts

    def sample_time_ns(self, step: int) -> float:
        """System-clock instant [ns] of sample `step` (nan before the rig has started)."""
        if self.t0_ns is None:
            return math.nan
        return self.t0_ns + step * self.dt_ns

    def published_count(self) -> int:
        """Samples this node published on its data topic (its final status reports it)."""
        return int(getattr(self, 'next_step', 0))

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Validation at run time (``demo_nodes_py/parameters/set_parameters_callback.py``).

        Values are checked against the schema; they are read once at start-up, so a change
        takes effect in the next run, never in the middle of one.
        """
        for p in params:
            if p.name == 'use_sim_time':
                continue
            try:
                parameters.validate_value(p.name, p.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def watch_inputs(self, subscriptions, publishers=()) -> None:
        """Real time: report ``inputs=matched`` (state 'ready') once each of `subscriptions`
        has discovered a publisher and each of `publishers` a subscriber, so that the rig
        starts its clock only when the samples will be taken in on both ends (across a link to
        another host, discovery takes round trips, one end may match long before the other,
        and a sample sent before both have matched waits for DDS's repair)."""
        subs, pubs = list(subscriptions), list(publishers)

        def check():
            if (all(sub.get_publisher_count() > 0 for sub in subs)
                    and all(pub.get_subscription_count() > 0 for pub in pubs)):
                timer.cancel()
                self.report(STATE_READY, 'inputs matched', inputs='matched')
        timer = self.wall_timer(0.02, check)

    def wall_timer(self, period_s: float, callback: Callable):
        """A guarded timer on the steady (wall) clock.

        Node timers follow ROS time, which is frozen until the rig publishes ``/clock`` when
        ``use_sim_time`` is on; start-up and housekeeping timers must not depend on it.
        """
        return self.create_timer(period_s, self.guard(callback),
                                 clock=Clock(clock_type=ClockType.STEADY_TIME))

    def report(self, state: str, message: str = '', **values) -> None:
        """Publish a status report on ``/seft/status``; a final one (done, aborted, failed)
        after the rows of the record batches that are still pending."""
        if state in (STATE_DONE, STATE_ABORTED, STATE_FAILED):
            for batch in self.records:
                batch.flush()
        self.status_pub.publish(status_msg(self.seft_name, state, message, seal=self.seal,
                                           **values))

    def guard(self, callback: Callable) -> Callable:
        """Wrap a callback so that an exception ends the node cleanly instead of the executor.

        A :class:`~seft_msgs_py.errors.SeftError` is reported as one line (status 'failed', exit
        code 2); anything
        else with its traceback (exit code 1).
        """
        def wrapper(*args):
            if self.done:
                return None
            try:
                return callback(*args)
            except SeftError as exc:
                print(f'{self.seft_name}: error: {exc}', file=sys.stderr)
                self.report(STATE_FAILED, str(exc))
                self.finish(2)
            except Exception as exc:  # noqa: BLE001 - a node must not die silently
                traceback.print_exc()
                self.report(STATE_FAILED, f'{type(exc).__name__}: {exc}')
                self.finish(1)
            return None
        return wrapper

    def close_outputs(self) -> None:
        """Close what the node writes (the recorder: its bag) before its ROS teardown, which
        :func:`shut_down` bounds and this must not be (no data lost to the bound)."""

    def finish(self, exit_code: int = 0) -> None:
        """Ask :func:`main_for` to stop spinning and exit with `exit_code`."""
        self.done = True
        self.exit_code = exit_code


class RecordBatch:
    """Rows of one record stream, published in batches for the recorder.

    The first label of each batch carries the run's seal (``SeftNode.seal``).
    ``add(step, *values)`` appends a row; every :data:`~seft_msgs_py.signals.RECORD_ROWS`
    rows (and on :meth:`flush`, which the node's final status report calls) the rows go out
    as one ``std_msgs/Float64MultiArray`` (layout: ``signals.RecordStream``). The recorder
    writes each row back as the per-sample messages of the bag. Measured on two cores: every
    message a process receives costs about 0.15 ms of CPU, so the recorder taking one batch
    per stream every ten steps instead of one message per topic per step is what lets the
    graph run at 1 kHz.

    Parameters
    ----------
    node : SeftNode
    stream : RecordStream
    columns : tuple of str
        The field names of a ``fields_topic`` stream (the stream's own columns otherwise).

    Raises
    ------
    ValueError
        `columns` given for a stream with fixed columns, or missing for a fields stream.
    """

    def __init__(self, node: 'SeftNode', stream: RecordStream, columns: tuple[str, ...] = ()):
        if bool(columns) != bool(stream.fields_topic):
            raise ValueError(f'{stream.name}: columns are given by the publisher only for a '
                             'fields stream')
        spec = record_topic(stream)
        self.stream = stream
        self.columns = tuple(columns) or stream.columns
        self.pub = node.create_publisher(spec.msg_type, spec.name, spec.qos)
        self.width = 1 + len(self.columns)
        self.msg = Float64MultiArray()
        label = ','.join(('step',) + self.columns)
        self.seal = getattr(node, 'seal', None) or RunSeal()     # a plain node: no seal
        self.msg.layout.dim = [MultiArrayDimension(label=self.seal.label, size=0, stride=0),
                               MultiArrayDimension(label=label, size=self.width,
                                                   stride=self.width)]
        self.rows: list[float] = []
        self.published = 0
        #: Rows added (published or pending).
        self.added = 0

    def add(self, step: int, *values: float) -> None:
        """Append the row of sample `step` (values in the order of the stream's columns)."""
        self.rows.append(float(step))
        self.rows.extend(values)
        self.added += 1
        if len(self.rows) >= RECORD_ROWS * self.width:
            self.flush()

    def flush(self) -> None:
        """Publish the pending rows (if any)."""
        if not self.rows:
            return
        n = len(self.rows) // self.width
        dim = self.msg.layout.dim[0]
        dim.size, dim.stride = n, n * self.width
        if self.seal.authenticated:
            dim.label = self.seal.label_of(self.stream.name, self.rows)
        self.msg.data = self.rows
        self.pub.publish(self.msg)
        self.published += n
        self.rows = []


class StepTiming:
    """Per-step timing records of a node in real-time mode.

    One row per step (the fields of :data:`~seft_msgs_py.signals.TIMING_FIELDS`) on the
    node's timing record stream; the recorder writes each row to ``/seft/timing/<node>`` as a
    ``sensor_msgs/JointState`` stamped with the step's sample time, ``name`` = the fields and
    ``position`` = their values. The period jitter is measured on the monotonic clock between
    two activations of the node; ages and deadlines against the rig's sample instants on the
    system clock (one clock on one host; several hosts need synchronized clocks, e.g. PTP).

    Parameters
    ----------
    node : SeftNode
        The publishing node (its ``dt`` is the nominal period).
    """

    def __init__(self, node: 'SeftNode'):
        self.batch = node.record_stream(
            next(r for r in node.graph.record_streams_of(node.seft_name) if r.timing))
        self.dt = float(node.params['dt'])
        self.dt_ns = node.dt_ns
        self.missed = 0
        self.stale = 0
        self._last_start: float | None = None

    def start(self) -> tuple[float, float]:
        """Mark the start of an activation; return (start [s, monotonic], period jitter [s]).

        The jitter is the time since the previous activation minus ``dt`` (nan the first
        time).
        """
        now = time.monotonic()
        jitter = math.nan if self._last_start is None else now - self._last_start - self.dt
        self._last_start = now
        return now, jitter

    def publish(self, stamp_ns: int, jitter_s: float, compute_s: float, input_age_s: float,
                missed: bool, stale: bool, loop_latency_s: float = math.nan) -> None:
        """Record one step (fields as :data:`~seft_msgs_py.signals.TIMING_FIELDS`; the stamp is
        the sample's)."""
        self.missed += bool(missed)
        self.stale += bool(stale)
        self.batch.add(stamp_ns // self.dt_ns, jitter_s, compute_s, input_age_s,
                       float(bool(missed)), float(bool(stale)), loop_latency_s)

    def counts(self) -> dict:
        """Final-status counts: ``published_timing``, ``missed_deadlines``, ``stale``."""
        return {'published_timing': self.batch.added, 'missed_deadlines': self.missed,
                'stale': self.stale}


#: Real-time mode: the input watchdogs' limit for an input not heard since the start [s]
#: (at least; ``watchdog_timeout_s`` if larger). Across an emulated 5 ms link the first
#: reference force once took more than 0.25 s to come (DDS's repair of a sample sent before
#: both ends had matched); the rig is at rest until it comes.
WATCHDOG_START_S = 1.0


class InputWatchdog:
    """Real-time mode: end the run when an input has stopped arriving (a node or the link to
    another host lost).

    Armed by the node once the run is under way (its first measurement, :meth:`arm`); from
    then on a steady-clock timer (period half the limit, at most 10 ms) aborts the run through
    :meth:`SeftNode.abort_run` once an input has been silent for longer than
    ``watchdog_timeout_s`` (an input that has not arrived since the arming: for longer than
    ``max(watchdog_timeout_s, WATCHDOG_START_S)``, as the first sample over a new path to
    another host can take longer). The rig then
    goes to its safe state when it hears the abort; on a lost link the rig's own watchdog (no
    valve command) or the force servo controller's (no reference force) does it on that side.
    Detection time: the limit plus at most one timer period (two when this node's own check
    was held up longer than the limit, :meth:`check`).

    Parameters
    ----------
    node : SeftNode
        The node (real-time mode, ``watchdog_timeout_s`` declared).
    inputs : sequence of str
        Names of the watched inputs, as the abort reason names them.
    """

    def __init__(self, node: 'SeftNode', inputs):
        self.node = node
        self.timeout_s = float(node.params['watchdog_timeout_s'])
        self.inputs = tuple(inputs)
        self.last_at = dict.fromkeys(self.inputs, -math.inf)
        self.armed_at: float | None = None
        self.complete = False            # the last step's measurement has arrived
        self.checked_at: float | None = None   # the previous check [s, monotonic]
        self.deferred = False            # the previous check was held up and judged nothing
        node.wall_timer(min(0.5 * self.timeout_s, 0.01), self.check)

    def arm(self) -> None:
        """The run is under way: watch from now (a no-op once armed)."""
        if self.armed_at is None:
            self.armed_at = time.monotonic()

    def feed(self, name: str, step: int | None = None) -> None:
        """An input `name` arrived now; with `step`, the measurement of that step.

        The measurement of the run's last step (``n_steps - 1``, from the rig's 'running'
        status) ends the watch: no input is due after it, and the rig's final status (which
        may come later, after the rig has waited for its last commands) ends the node.
        """
        self.last_at[name] = time.monotonic()
        n = self.node.run_steps
        if step is not None and n is not None and step >= n - 1:
            self.complete = True

    def check(self) -> None:
        """Abort the run when an input has been silent for longer than the limit.

        A check that comes more than the limit after the previous one (this node itself was
        held up: the process stopped, or the host stalled) judges nothing, once: the inputs
        that arrived meanwhile are still in this node's queue, and the next check, one timer
        period later, comes after they are read. A builder resumed after a 1 s SIGSTOP aborted
        on its own 'no measurement for 1001 ms' at times (1 run in 3 full test runs) instead
        of reading the measurements waiting for it.
        """
        now = time.monotonic()
        held_up = now - self.checked_at if self.checked_at is not None else 0.0
        self.checked_at = now
        if self.node.done or self.armed_at is None or self.complete:
            return
        if held_up > self.timeout_s and not self.deferred:
            self.deferred = True
            return
        self.deferred = False
        for name in self.inputs:
            last = self.last_at[name]
            silent = now - max(last, self.armed_at)
            # an input not heard yet since the start: the first sample over a new path
            # (another host) may take longer than the steady-state limit
            limit = self.timeout_s if last > -math.inf else max(self.timeout_s,
                                                                  WATCHDOG_START_S)
            if silent > limit:
                self.node.abort_run(
                    f'watchdog: no {name} for {1e3 * silent:.0f} ms (limit '
                    f'{1e3 * self.timeout_s:g} ms; node or link lost)',
                    int(getattr(self.node, 'next_step', 0)))
                return


def main_for(factory: Callable[[], SeftNode], name: str, args=None) -> int:
    """Create the node, spin it until it finishes, shut down cleanly; return the exit code.

    One node in its process, as ``ros2 run`` starts it: :func:`main_for_nodes` with the
    process's arguments `args` (None: ``sys.argv``).
    """
    return main_for_nodes([(factory, name, None)], args)


def main_for_nodes(specs: Sequence[tuple[Callable[[], SeftNode], str, Sequence[str] | None]],
                   args=None) -> int:
    """Create the nodes, spin them in one executor until each has finished, shut down
    cleanly; return the exit code (the first node's that is not 0, else 0).

    Several nodes in one process are ROS 2's composition (``rclcpp_components``' container;
    in Python, one executor with several nodes): one participant, so Fast DDS's
    intra-process delivery (on by default) hands the messages between them over without a
    transport, and one thread does the work of all of them, with no task switch between
    them. Measured on the two-pier bridge over three hosts on this 2-core machine: a lab's
    rig, force servo controller and builder take 47 % of a core as one process against
    55-60 % as three (``seft run --processes loop``; docs/network.md, "Processes").

    Uses rclpy's ``EventsExecutor`` (about twice the lockstep rate of the default executor
    on two cores). It cannot be stopped from inside a callback, so a node sets ``done``
    and this loop stops spinning it. A node with a schedule (:meth:`SeftNode.next_due`) gets
    its :meth:`SeftNode.run_due` called from this loop at absolute deadlines (the earliest
    of all the nodes' first). The process runs at the highest real-time priority of its
    nodes (:meth:`SeftNode.apply_priority`).

    Parameters
    ----------
    specs : sequence of (factory, name, node_args)
        Each node's constructor, its name (error messages) and its ROS arguments
        (``['--ros-args', '--params-file', ...]``; None: the process's own, `args`).
    args : list of str, optional
        The process's arguments for ``rclpy.init`` (None: ``sys.argv``).
    """
    global _node_arguments
    # SIGINT, SIGTERM and SIGHUP are this loop's (rclpy's handlers would shut the context
    # down at once): the first one asks every node to stop safely
    # (:meth:`SeftNode.on_stop_signal`), a second one ends the process now unless a node
    # holds it for its safe stop (seft_msgs_py.stopping); so does the end of the runner
    use_seft_profile()            # before the first participant (seft_msgs_py.dds)
    clock.read_environment()      # this process's (a forked node's, seft_ros.cli.spawn)
    # a node that does not end can be asked where it is: SIGUSR1 prints every thread's
    # Python stack to stderr (its log) from the signal itself, so also when its main thread
    # is stuck in a call into ROS or DDS that Ctrl-C cannot interrupt
    faulthandler.register(STACKS_SIGNAL, all_threads=True)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[SeftNode] = []
    name = specs[0][1]

    def hold_s() -> float:
        # a node's safe stop, then its final status served (the linger after a stop)
        hold = max((n.stop_hold_s() for n in nodes), default=0.0)
        return hold + LINGER_S if hold > 0 else 0.0

    requests = StopRequests(hold_s, name)
    stop = requests.names
    runner = RunnerWatch.from_environment()
    previous = {s: signal.signal(s, requests.on_signal) for s in STOP_SIGNALS}
    code = 0
    try:
        for factory, name, node_args in specs:
            _node_arguments = None if node_args is None else list(node_args)
            try:
                nodes.append(factory())
            finally:
                _node_arguments = None
        max(nodes, key=lambda n: PRIORITY_OFFSET.get(n.kind, -99)).apply_priority()
        if any(n.realtime for n in nodes):
            # the set-up's objects never need collecting again: move them out of the
            # collector's way, so that a run's collections stay short
            gc.collect()
            gc.freeze()
        executor = EventsExecutor()
        for node in nodes:
            executor.add_node(node)

        def spin(timeout_s: float) -> None:
            # the nodes' callbacks run in here: a signal that ends the process is left to
            # requests.check() (a KeyboardInterrupt raised inside a callback was logged as
            # the executor's '[FATAL] Exception in 'timers' callback', with its traceback)
            requests.spinning = True
            try:
                executor.spin_once(timeout_sec=timeout_s)
            finally:
                requests.spinning = False
            requests.check()

        stop_handled = False
        while not all(n.done for n in nodes):
            if runner is not None and not stop and runner.gone():
                print(f'{name}: its runner (pid {runner.pid}) has ended: stopping the run safely',
                      file=sys.stderr, flush=True)
                requests.request(runner.reason)
            requests.check()
            if stop and not stop_handled:
                stop_handled = True
                for node in nodes:
                    if not node.done:
                        node.guard(node.on_stop_signal)(stop[0])
                continue
            due, node = _next_due(nodes)
            if due is None:
                spin(0.1)
                continue
            wait = due - time.monotonic()
            if wait > 0:
                spin(min(wait, 0.1))
            else:
                node.run_due()
        code = _exit_code(nodes)
        # linger, so that the last samples and the final status reach their subscribers: with a
        # recorder in the graph, until it has closed the bag (a publisher that exits earlier
        # takes its unsent samples with it); bounded as a whole too (its own bound is
        # RECORDER_WAIT_S; the outputs are closed and the teardown bounded after it, shut_down)
        longest = RECORDER_WAIT_S + LINGER_S + SHUTDOWN_TIMEOUT_S
        with exit_if_longer(longest, f'{name}: {_NOT_DONE.format(longest)}', code):
            start = time.monotonic()
            heard_at: dict[int, float] = {}
            while True:
                now = time.monotonic()
                waited = now - start
                if stop and (not stop_handled or waited > LINGER_S):
                    break             # stopped by a signal: serve the final status briefly
                if all(_lingered(n, now, waited, heard_at) for n in nodes):
                    break
                spin(0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        code = _exit_code(nodes)
    except SeftError as exc:
        print(f'{name}: error: {exc}', file=sys.stderr)
        code = 2
    finally:
        shut_down(nodes, name, code)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return code


def shut_down(nodes: Sequence[Node], name: str, code: int) -> None:
    """Close the nodes' outputs (:meth:`SeftNode.close_outputs`, unbounded: a bag is never
    cut short), then destroy the nodes and shut rclpy down within :data:`SHUTDOWN_TIMEOUT_S`:
    past it the process exits with `code` and one line on stderr naming `name`.

    The run is over by then (the linger of :func:`main_for_nodes` has let the recorder close
    its bag); what can still hang is the DDS participant's teardown. Seen once in CI on the
    2-core host under the test suite's load: a rig node that had completed its 500 steps,
    the recorder's bag closed, was still alive 57 s later, where the other nodes had exited.
    Not diagnosed; the live view bounds its close with the same :func:`exit_if_longer`.
    """
    for node in nodes:
        close = getattr(node, 'close_outputs', None)
        if close is not None:
            close()
    with exit_if_longer(SHUTDOWN_TIMEOUT_S, f'{name}: {_NOT_DONE.format(SHUTDOWN_TIMEOUT_S)}',
                        code):
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


#: The line of a process whose way out outlasted its bound (seconds as ``{:g}``).
_NOT_DONE = 'its ROS shutdown did not finish within {:g} s; exiting'


@contextlib.contextmanager
def exit_if_longer(seconds: float, line: str, code: int, stream=None):
    """Run the block; if it lasts more than `seconds` [s], write `line` to `stream`
    (default: stderr) and end the process at once with `code` (``os._exit``, from a timer
    thread). For a process's way out, where a teardown (a DDS participant, a server's close)
    can hang and nothing is left to lose: :func:`shut_down`, the linger of
    :func:`main_for_nodes`, the live view's close."""
    def exit_now():
        print(line, file=stream or sys.stderr, flush=True)
        os._exit(code)

    bound = threading.Timer(seconds, exit_now)
    bound.daemon = True
    bound.start()
    try:
        yield
    finally:
        bound.cancel()


def _next_due(nodes: Sequence[SeftNode]) -> tuple[float | None, SeftNode | None]:
    """The earliest scheduled work of the unfinished nodes: (monotonic time, node), or
    (None, None) when none has a schedule."""
    best: tuple[float | None, SeftNode | None] = (None, None)
    for node in nodes:
        if node.done:
            continue
        due = node.next_due()
        if due is not None and (best[0] is None or due < best[0]):
            best = (due, node)
    return best


def _exit_code(nodes: Sequence[SeftNode]) -> int:
    """The first node's exit code that is not 0, else 0."""
    return next((n.exit_code for n in nodes if n.exit_code), 0)


def _lingered(node: SeftNode, now: float, waited: float, heard_at: dict[int, float]) -> bool:
    """Whether `node` has lingered long enough after the run (`waited` [s] since it ended).

    After a refusal: until every node of the graph has heard it (a node started later names
    the mismatch too, instead of waiting for a graph that is gone), at most
    ``RECORDER_WAIT_S``. Otherwise until the recorder has closed the bag (at most
    ``RECORDER_WAIT_S``), or ``LINGER_S`` without a recorder.
    """
    if node.refused:
        if id(node) not in heard_at and node.refusal_heard():
            heard_at[id(node)] = now
        return waited > RECORDER_WAIT_S or (id(node) in heard_at
                                            and now - heard_at[id(node)] > LINGER_S)
    if waited > (RECORDER_WAIT_S if node.recorder_ready else LINGER_S):
        return True
    return node.recorder_ready and node.recorder_closed and waited > 0.2
