"""recorder node: every seft signal into a rosbag2 bag (rosbags), with the run's parameters.

Writes the topics of ``seft_msgs_py.topics.BAG_TOPICS`` to ``bag_path`` (``bag_storage``: mcap
by default): one message per sample of every signal, stamped with the sample time, with the
types of the live topics. It does not subscribe to each signal: every node publishes what it
sent (and, in real-time mode, its timing records) as record batches of ten rows
(``seft_msgs_py.signals.RECORD_STREAMS``), and the recorder writes every row back as the
per-sample messages (serialized in place, :class:`~seft_msgs_py.convert.SerializedStamped`).
On two cores each received message costs a process about 0.15 ms: one batch per stream per
ten steps instead of eleven messages a step is what lets it keep up at 1 kHz. Status and
parameter messages are subscribed to and written unchanged; a status report without the
run's seal (another run's node on the domain, ``seft_msgs_py.provenance``) is not the run's:
never written nor acted on, counted in the recorder's ``foreign_dropped``. Message
definitions are stored, so ``ros2 bag``, Foxglove and PlotJuggler open the bag. The log time
of a stamped message is its header stamp (the sample time); status messages take the latest
sample time seen. At start it writes the run's resolved parameters as JSON on
``/seft/run_parameters``, so the bag alone is enough to analyse and reproduce the run.

Every ``ACK_EVERY`` steps it reports how many steps it has recorded; the rig waits for it
(lockstep flow control), so no sample is ever dropped from a subscription queue.

**Crash-safe.** rosbags keeps a bag's index until close, so a recorder killed with SIGKILL
would lose the whole open bag. The recorder flushes the bag
(:func:`~seft_ros.analysis.bag_recovery.flush_bag`: the pending MCAP chunk closed into the
file, or the sqlite3 transaction committed) at the start, whenever the complete steps (every
signal of the step) have grown by ``FLUSH_EVERY_S`` of sample time since the last flush, and
at least every ``FLUSH_EVERY_S`` of wall time. **Bound:** after a SIGKILL the bag holds every
complete step the recorder had received but at most the last ``FLUSH_EVERY_S`` (0.25 s, 125
steps at dt = 2 ms), and every other message received more than ``FLUSH_EVERY_S`` (+ the 0.1 s
of its timer) of wall time before the kill; a kill that lands inside a flush's write (about a
millisecond) loses that chunk too, twice the bound. ``seft compare`` reads such a bag
(:mod:`seft_ros.analysis.bag_recovery`) and says the recording was not closed. Measured
(``benchmarks/bag_flush.py``): no cost within the noise for MCAP, whose chunks become smaller;
sqlite3 commits cost about 7 us a step. A closed bag is the same for every reader.

It ends by itself once the rig reported 'done' or 'aborted' and every node's final count of
published samples has arrived (or after ``FLUSH_TIMEOUT_S``), closes the bag, reports
'closed' and exits. On Ctrl-C, SIGTERM or SIGHUP it closes the bag too. A runner's abort that
names the nodes of a host it lost (``lost_nodes``: its link cut, ``seft_ros.cli.runner``)
counts them as ended: their reports cannot come.

Run by hand: ``ros2 run seft_ros recorder --ros-args -p bag_path:=my_run ...``.
"""

import os
import sys
import time

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import String

from seft_msgs_py import rig_contract
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RECORDING,
    SerializedStamped,
    parameters_json,
    status_msg,
    status_values,
)
from seft_msgs_py.errors import InputError
from seft_msgs_py.node_support import SeftNode, main_for
from seft_msgs_py.signals import SCALAR_SIGNALS, TIMING_FIELDS
from seft_msgs_py.topics import (
    ESTIMATES,
    LINK,
    NODE_PARAMETERS,
    RUN_PARAMETERS,
    STATUS,
    record_topic,
    spec_for,
)
from seft_ros.analysis.bag_recovery import FLUSH_EVERY_S, flush_bag
from seft_ros.live.view import LIVE_NAME

__all__ = ['RecorderNode', 'main', 'FLUSH_TIMEOUT_S', 'topics_of_node']

#: Longest wait for late samples after the rig finished [s].
FLUSH_TIMEOUT_S = 10.0
#: After an abort (or a stop signal) without the rig's final status, the recorder waits the
#: rig's safe ramp (``safe_ramp_s``) plus this long for it, then takes the rig for gone (a
#: killed rig, a lost link) and closes the bag with what it has [s]. Long enough for a rig
#: that is alive but slow on a loaded host (in lockstep runs while the test suite loaded the
#: machine, one took 2.9 s to act on an abort, another 3.9 s, with the controller killed):
#: its final status then still makes it into the bag.
RIG_SILENT_S = 6.0
#: The recorder acknowledges the recorded steps every this many steps (lockstep flow control).
ACK_EVERY = 50
#: ``wait_for_live_view``: the longest the rig's start waits for the live view to match the
#: run's streams after the nodes were discovered [s] (on one host it has matched before).
LIVE_VIEW_WAIT_S = 5.0
#: The scalar topic kinds (by ROS type and field) the recorder serializes from batch rows.
_SCALAR_KINDS = {(s.type_name, s.field) for s in SCALAR_SIGNALS}

_FINAL = (STATE_DONE, STATE_ABORTED, STATE_FAILED)


def topics_of_node(graph) -> dict[str, tuple[str, ...]]:
    """The bag topics each data node of `graph` publishes (its final status says how many
    samples: ``published`` for its data topics, ``published_timing`` for its timing topic,
    ``published:<topic>`` for each of its fields topics)."""
    signals = graph.bag_signals()
    return {node: tuple(t.name for t in signals if t.publisher == node)
            for node in graph.nodes()}

class RecorderNode(SeftNode):
    """Writes the seft topics to a rosbag2 bag."""

    def __init__(self):
        super().__init__('recorder')
        p = self.params
        self.bag_path = p['bag_path']
        if os.path.exists(self.bag_path):
            raise InputError(f'{self.bag_path}: bag_path exists already; expected a new '
                             'directory name')
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        storage = StoragePlugin.MCAP if p['bag_storage'] == 'mcap' else StoragePlugin.SQLITE3
        self.writer = Writer(self.bag_path, version=9, storage_plugin=storage)
        self.writer.open()
        recorded = [spec_for(t) for t in self.graph.bag_signals()]
        self.connections = {t.name: self.writer.add_connection(t.name, t.type_name,
                                                               typestore=self.typestore)
                            for t in recorded}
        self.counts = {t.name: 0 for t in recorded}
        self.topics_of_node = topics_of_node(self.graph)
        streams = self.graph.record_streams()
        self.timing_names = {self.graph.timing_topic(r) for r in streams if r.timing}
        self.fields_names = {r.fields_topic for r in streams if r.fields_topic}
        #: the topics whose counts the lockstep flow control acknowledges (every rig's sensors
        #: and reference force)
        self.lockstep_topics = tuple(
            name for r in self.graph.rigs for name in
            [s.name for s in self.graph.sensors(r)] + [self.graph.reference_force(r).name])
        self.acked = 0
        self.latest_ns = 0
        params_msg = self.typestore.types['std_msgs/msg/String'](data=parameters_json(p))
        self._write(RUN_PARAMETERS.name, 0,
                    self.typestore.serialize_cdr(params_msg, 'std_msgs/msg/String'))
        # crash safety: the topics, the types and the parameters on disk from the start; then a
        # flush every FLUSH_EVERY_S of complete steps (sample time) and of wall time
        self.complete_topics = self.graph.complete_step_topics()
        self.flush_steps = max(1, int(round(FLUSH_EVERY_S / p['dt'])))
        self.flushed_steps = 0
        self._flush()
        self.params_pub = self.create_publisher(String, RUN_PARAMETERS.name, RUN_PARAMETERS.qos)
        self.params_pub.publish(String(data=parameters_json(p)))
        self.create_subscription(
            NODE_PARAMETERS.msg_type, NODE_PARAMETERS.name,
            self.guard(lambda raw: self._on_unstamped(NODE_PARAMETERS.name, raw)),
            NODE_PARAMETERS.qos, raw=True)
        # the run's status reports only (their seal): another run's are dropped, counted and
        # named by SeftNode._on_any_status, never written (the bag reader takes the finals)
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status_raw),
                                 STATUS.qos, raw=True)
        # a run over several hosts: the runners' link figures (the topic added to the bag
        # with its first message: a run on one host has none)
        self.create_subscription(LINK.msg_type, LINK.name, self.guard(self._on_link), LINK.qos,
                                 raw=True)
        # the per-sample messages, serialized in place from the rows of the record batches
        self.serialized = {t.name: SerializedStamped.scalar(t) for t in recorded
                           if (t.type_name, t.field) in _SCALAR_KINDS}
        self.serialized.update({t.name: SerializedStamped.fields(t.msg_type, TIMING_FIELDS)
                                for t in recorded if t.name in self.timing_names})
        for stream in self.graph.record_streams():
            spec = record_topic(stream)
            self.create_subscription(spec.msg_type, spec.name,
                                     self.guard(lambda msg, r=stream: self._on_batch(r, msg)),
                                     spec.qos,
                                     event_callbacks=self.publisher_watch(spec.name, False))
        self.foreign_batches = set()
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status),
                                 STATUS.qos)
        self.finals = {}
        #: the live view's report that it matched this run's streams; when the nodes were
        #: discovered (monotonic) (``wait_for_live_view``)
        self.live_view_matched = False
        self.discovered_at = None
        # the nodes of this run's graph: the recorder waits for each one's final count
        self.participants = set(self.graph.nodes())
        self.rig_nodes = set(self.graph.rig_nodes())
        self.rig_final_at = None
        #: monotonic time of the first abort heard (or stop signal), None before
        self.abort_heard_at = None
        self.rig_silent_s = float(p['safe_ramp_s']) + RIG_SILENT_S
        self.wall_timer(0.1, self._on_timer)
        self.publish_parameters()
        self.report(STATE_READY, f'recording to {self.bag_path}', flush_every_s=FLUSH_EVERY_S)
        self.matched_timer = self.wall_timer(0.02, self._check_matched)

    def _check_matched(self) -> None:
        """Report ``inputs=matched`` once the record batches of every node of the graph are
        discovered (the rig starts only then, with ``wait_for_recorder``): the nodes start
        together, and a short run could otherwise end, and its nodes exit, before this
        recorder heard of one of them. With ``wait_for_live_view``, also once the live view
        has said that its subscriptions matched every record stream of this run (its status
        with this run's token), or ``LIVE_VIEW_WAIT_S`` after the nodes were discovered, with
        a warning: a best-effort view that matches a stream late never sees its start, and a
        short run (an abort 0.5 s in) could show nothing of a stream."""
        for node in self.participants:
            if not self.publishes(node, self.graph.record_streams_of(node)[0].name):
                return
        if self.params['wait_for_live_view'] and not self.live_view_matched:
            now = time.monotonic()
            if self.discovered_at is None:
                self.discovered_at = now
            if now - self.discovered_at < LIVE_VIEW_WAIT_S:
                return
            self.warn(f'the live view had not matched every stream of the run '
                      f'{LIVE_VIEW_WAIT_S:.0f} s after the nodes were discovered: the run '
                      'starts, and the view shows each stream from when it matches')
        self.matched_timer.cancel()
        self.report(STATE_READY, 'every node discovered', inputs='matched')

    def _flush(self) -> None:
        """Everything written so far into the bag's file (readable after a SIGKILL)."""
        if self.writer is not None:
            flush_bag(self.writer)
        self.flush_due = time.monotonic() + FLUSH_EVERY_S

    def _on_timer(self) -> None:
        if time.monotonic() >= self.flush_due:
            self._flush()
        self._check_complete()

    def _write(self, name: str, stamp_ns: int, raw) -> None:
        self.writer.write(self.connections[name], stamp_ns, raw)
        self.counts[name] += 1

    def _on_batch(self, stream, msg) -> None:
        """Write every row of a record batch as the per-sample messages of the bag (one
        without the run's seal is dropped: a named warning, the bag holds the run's own)."""
        if not self.batch_sealed(stream, msg):
            self.foreign_input(stream.name, msg.layout.dim[0].label if msg.layout.dim else '',
                               False)
            return
        try:
            columns = stream.columns_of(msg)
        except ValueError as exc:
            if stream.name not in self.foreign_batches:   # say it once, record the rest
                self.foreign_batches.add(stream.name)
                self.get_logger().error(f'{exc}; ignoring its batches')
            return
        if stream.fields_topic:
            self._write_fields(stream.fields_topic, columns, msg.data)
            return
        width = 1 + len(columns)
        data, dt_ns, write = msg.data, self.dt_ns, self._write
        if stream.timing:
            name = self.graph.timing_topic(stream)
            serialize = self.serialized[name]
            for i in range(0, len(data), width):
                stamp = int(data[i]) * dt_ns
                write(name, stamp, serialize(stamp, data[i + 1:i + width]))
            return
        columns = [(j + 1, c, self.serialized[c]) for j, c in enumerate(columns)]
        stamp = self.latest_ns
        for i in range(0, len(data), width):
            stamp = int(data[i]) * dt_ns
            for j, name, serialize in columns:
                write(name, stamp, serialize(stamp, (data[i + j],)))
        if stream.node in self.rig_nodes:
            self.latest_ns = max(self.latest_ns, stamp)
        complete = min(self.counts[n] for n in self.complete_topics)
        if complete >= self.flushed_steps + self.flush_steps:
            self.flushed_steps = complete
            self._flush()
        if self.counts[self.lockstep_topics[-1]] >= self.acked + ACK_EVERY:
            recorded = min(self.counts[n] for n in self.lockstep_topics)
            if recorded >= self.acked + ACK_EVERY:
                self.acked = recorded
                self.report(STATE_RECORDING, recorded=recorded)

    def _write_fields(self, name: str, fields: tuple[str, ...], data) -> None:
        """Rows of a fields stream (the estimates): one JointState per row, ``name`` = the
        columns the publisher's label gives."""
        serialize = self.serialized.get(fields)
        if serialize is None:
            serialize = self.serialized[fields] = SerializedStamped.fields(
                ESTIMATES.msg_type, fields)
        width = 1 + len(serialize.offsets)
        for i in range(0, len(data) - width + 1, width):
            stamp = int(data[i]) * self.dt_ns
            self._write(name, stamp, serialize(stamp, data[i + 1:i + width]))

    def _on_unstamped(self, name: str, raw: bytes) -> None:
        self._write(name, self.latest_ns, raw)

    def _on_status_raw(self, raw: bytes) -> None:
        if self.status_of_run(deserialize_message(raw, STATUS.msg_type)):
            self._write(STATUS.name, self.latest_ns, raw)

    def _on_link(self, raw: bytes) -> None:
        if self.writer is None:
            return
        if LINK.name not in self.connections:
            self.connections[LINK.name] = self.writer.add_connection(
                LINK.name, LINK.type_name, typestore=self.typestore)
            self.counts[LINK.name] = 0
        self._write(LINK.name, self.latest_ns, raw)

    def _on_status(self, msg) -> None:
        if not self.status_of_run(msg):
            return              # another run's (SeftNode._on_any_status counts it)
        values = status_values(msg)
        state = values.get('state')
        if state == STATE_READY and msg.name in self.topics_of_node:
            self.participants.add(msg.name)
        if (msg.name == LIVE_NAME and state == STATE_READY
                and values.get('run_token') == self.params['run_token']):
            self.live_view_matched = True
        if state in _FINAL:
            self.finals[msg.name] = values
            if state != STATE_DONE and self.abort_heard_at is None:
                self.abort_heard_at = time.monotonic()
            # a runner's report of a node that died: that node will send no final count
            dead = values.get('failed_node')
            if dead and dead not in self.finals:
                self.finals[dead] = {'state': STATE_FAILED}
            # a runner's report of a host lost (its link cut): its nodes' reports cannot come
            for lost in filter(None, values.get('lost_nodes', '').split(',')):
                self.finals.setdefault(lost, {'state': STATE_FAILED})
            # every rig has finished (the study's test: the rig)
            if self.rig_final_at is None and self.rig_nodes <= set(self.finals):
                self.rig_final_at = time.monotonic()

    def abort_run(self, reason: str, step: int, **values) -> None:
        """Stop the run from the recorder (parameters that differ once the run has begun):
        report the abort (the rig goes to its safe state, the other nodes end), and record
        on: the rig's safe ramp and the final statuses, then close as after any abort."""
        self.get_logger().error(reason)
        self.report(STATE_ABORTED, reason, step=step, **values)
        if self.abort_heard_at is None:
            self.abort_heard_at = time.monotonic()

    def on_stop_signal(self, signame: str) -> None:
        """SIGINT/SIGTERM/SIGHUP or the end of the runner: record the rig's safe ramp, then
        close (at most ``safe_ramp_s`` + ``RIG_SILENT_S`` later); a second signal during
        the rig's safe stop is held (:meth:`stop_hold_s`), a later one closes at once."""
        self.get_logger().warning(f'{signame}: closing the bag after the rig has stopped')
        if self.abort_heard_at is None:
            self.abort_heard_at = time.monotonic()

    def stop_hold_s(self) -> float:
        """Real time: the rig's safe stop (``seft_msgs_py.rig_contract.safe_stop_s``),
        so that the bag holds the whole ramp after a second Ctrl-C, as the rig makes it."""
        return rig_contract.safe_stop_s(self.params)

    def _published(self):
        """``(topic, recorded, published)`` of every topic of every node that has finished."""
        for node, values in self.finals.items():
            for name in self.topics_of_node.get(node, ()):
                key = ('published_timing' if name in self.timing_names else
                       f'published:{name}' if name in self.fields_names else 'published')
                yield name, self.counts[name], int(values.get(key, 0))

    def _missing(self) -> list[str]:
        """What has not arrived yet: nodes without a final status, topics short of samples."""
        missing = [f'{n} (no final status)' for n in sorted(self.participants)
                   if n not in self.finals]
        missing += [f'{name} ({got}/{want})' for name, got, want in self._published()
                    if got < want]
        return missing

    def _lost(self) -> int:
        """Messages the nodes published but the bag does not hold."""
        return sum(max(0, want - got) for _, got, want in self._published())

    def _check_complete(self) -> None:
        if self.done:
            return
        now = time.monotonic()
        if self.rig_final_at is not None:
            timed_out = now - self.rig_final_at >= FLUSH_TIMEOUT_S
        elif self.abort_heard_at is not None and now - self.abort_heard_at >= self.rig_silent_s:
            timed_out = True                  # the rig is gone (killed, link lost): close now
            self.get_logger().error('no final status of the rig '
                                    f'{self.rig_silent_s:.1f} s after the abort: rig or link '
                                    'lost; closing the bag')
        else:
            return
        missing = self._missing()
        if missing and not timed_out:
            return
        if missing:
            self.get_logger().warning('closing the bag without: ' + ', '.join(missing))
        counts = {name.rsplit('/', 1)[-1]: n for name, n in self.counts.items()}
        final = status_msg(self.seft_name, STATE_CLOSED, f'bag {self.bag_path} closed',
                           incomplete=', '.join(missing), lost=self._lost(), seal=self.seal,
                           **counts)
        # the bag's own account of what it holds and lost, as its last message
        self._write(STATUS.name, self.latest_ns, serialize_message(final))
        self._close()
        self.status_pub.publish(final)
        self.get_logger().info(f'bag {self.bag_path} closed: {sum(self.counts.values())} '
                               'messages')
        self.finish(0)

    def _close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None

    def close_outputs(self) -> None:
        """Close the bag before the node's bounded teardown (``node_support.shut_down``)."""
        self._close()

    def destroy_node(self):
        """Close the bag (also on Ctrl-C), then destroy the node."""
        self._close()
        return super().destroy_node()


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros recorder``."""
    return main_for(RecorderNode, 'recorder', args)


if __name__ == '__main__':
    sys.exit(main())
