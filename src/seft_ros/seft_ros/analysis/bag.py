"""Read a seft rosbag2 bag (written by the recorder node) back into a
:class:`~seft_ros.analysis.rundata.RunData`: any bag, the reference study's and a structure
test's alike.

Uses rosbags (no rclpy). The run's graph (:class:`seft_msgs_py.graph.Graph`, from its
parameters) says where each rig's signals are: the study's one rig in the root namespace
(``/seft/measured_force``, ...), each rig of a structure in its namespace
(``/<rig>/seft/measured_force``, ...), and a builder's computational state
(``/[<rig>/]seft/structure_state``). Each parameter comes from the node that used it (the
``/seft/node_parameters`` message of its ``parameters.value_source`` node: alpha from the
reference-force builder, the specimen and the rig from the rig, ...), from the next node that
declared it when that node is not in the bag, and from ``/seft/run_parameters`` in a bag
without node parameters; a structure's rig takes its own from its rig node. The signals come
from the scalar topics (one message per step, stamped ``t_k``), the abort reason from the
final ``/seft/status`` reports.

A bag its recorder never closed (killed with SIGKILL: no ``metadata.yaml``, an MCAP file
without its summary, an uncommitted sqlite3 transaction) reads too: every message of its
complete records (:mod:`seft_ros.analysis.bag_recovery`); :func:`read_run` says that the
recording was not closed (the recorder killed, or still recording: the file cannot tell) and
how much it recovered.

A bag recorded from the live topics (``ros2 bag record`` on a full ROS install, which sees
the rig's one ``/seft/measurement`` message and the nodes' record batches instead of the
recorder's per-signal topics) reads the same: a signal missing as its own topic is taken
from the measurement or the batches.
"""

import json
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.graph import STRUCTURE_STATE, Graph, qualified, scoped
from seft_msgs_py.provenance import AUTH_TOKEN, SEPARATOR, STATUS_ID, status_id_of_run
from seft_msgs_py.provenance import NONE as NO_TOKEN
from seft_msgs_py.rig_contract import (
    BRIDGE_REASON,
    CONTRACT_KEY,
    WATCHDOG_REASON,
    is_runner_interrupt,
)
from seft_ros.analysis.bag_recovery import FLUSH_EVERY_S, is_unclosed_bag, recover_bag
from seft_ros.analysis.rundata import RECORDING_CUT_SHORT, RigData, RunData
from seft_ros.analysis.timing import (
    node_timings,
    timing_row,
    timing_summary,
)
from seft_ros.core.structure import test_setup

__all__ = ['read_run', 'BagSignals', 'read_signals', 'recording_end', 'rig_contract_of',
           'bag_lost_messages', 'rig_end_step']

#: The scalar topics of the study's bag (``/clock`` and the sample signals) and their fields.
_SCALARS = {s.name: s.field for s in (signals.CLOCK,) + signals.SCALAR_SIGNALS}
#: The states of a node's final status report.
_FINAL = ('done', 'aborted', 'failed')


def _get(msg, path: str):
    for p in path.split('.'):
        msg = getattr(msg, p)
    return msg


#: ``param_sources`` value of a parameter taken from ``/seft/run_parameters``.
RUN_PARAMETERS_SOURCE = 'run_parameters'
#: ``param_sources`` value of a parameter the bag does not hold at all (schema default).
DEFAULT_SOURCE = 'default'


class BagSignals:
    """The raw content of a seft bag.

    Attributes
    ----------
    params : dict
        Run parameters, every schema parameter validated: each from its source node (see
        `param_sources`), in a bag without node parameters the JSON of
        ``/seft/run_parameters``.
    graph : Graph
        The run's node graph (:class:`~seft_msgs_py.graph.Graph`, from the parameters): its
        rigs and their topics.
    samples : dict of str -> dict of int -> float
        Per scalar topic of the graph (every rig's), the value of each step (stamp // dt);
        ``/clock`` maps step -> step.
    counts : dict of str -> int
        Messages per topic (duplicates included).
    duplicates : dict of str -> list of int
        Per scalar topic, the steps recorded more than once with the same value (read as one
        sample); empty when none. A step recorded twice with different values is an
        :class:`~seft_msgs_py.errors.InputError` of :func:`read_signals`.
    statuses : list of dict
        Every status report of the run: ``name``, ``message`` and its key/values
        (another run's are left out: a report with another seal than the run's).
    foreign_statuses : int
        The status reports in the bag that are not the run's (another seal), left out of
        `statuses`; 0 in a bag recorded before the statuses were sealed.
    node_params : dict of str -> dict
        ``{node: {parameter: value}}`` as each node published it on
        ``/seft/node_parameters`` (the last message of a node); empty in an older bag.
    param_sources : dict of str -> str
        ``{parameter: where params took it from}``: a node name, ``'run_parameters'``
        (``RUN_PARAMETERS_SOURCE``) or ``'default'`` (``DEFAULT_SOURCE``: in no
        message of the bag).
    parameter_mismatches : list of str
        ``parameters.shared_mismatches(node_params)``: one line per shared parameter on which
        the nodes disagree (empty when they agree or the bag has no node parameters).
    timing : dict of str -> NodeTiming
        The real-time timing records per node (:mod:`seft_ros.analysis.timing`; empty for a
        lockstep run).
    fields : dict of str -> dict of int -> dict of str -> float
        Per fields topic of the graph (one ``JointState`` per step: the compensator's
        estimates, a builder's computational state ``/[<rig>/]seft/structure_state``), each
        step's values by name.
    estimates : dict of int -> dict of str -> float
        The compensator's estimates in effect for each step's reference force
        (``/seft/estimates``, ``fields``; empty without an adaptive compensator).
    recovery : RecoveredBag or None
        For a bag that was not closed, what :func:`~seft_ros.analysis.bag_recovery.recover_bag`
        read (its messages emptied once read); None for a closed bag.
    """

    def __init__(self, params, samples, counts, statuses, node_params=None,
                 param_sources=None, parameter_mismatches=None, timing=None):
        self.params = params
        self.samples = samples
        self.counts = counts
        self.statuses = statuses
        self.node_params = {} if node_params is None else node_params
        self.param_sources = {} if param_sources is None else param_sources
        self.parameter_mismatches = [] if parameter_mismatches is None else parameter_mismatches
        self.timing = {} if timing is None else timing
        self.graph: Graph | None = None
        self.fields: dict[str, dict[int, dict[str, float]]] = {}
        self.estimates: dict[int, dict[str, float]] = {}
        self.recovery = None
        self.duplicates: dict[str, list[int]] = {}
        #: The last link figures of a run over several hosts (``/seft/link``), or None.
        self.link: dict | None = None
        self.foreign_statuses = 0


def _link(data: str, path: Path) -> dict:
    """One ``/seft/link`` message (JSON), checked to be an object."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise InputError(f'{path}: {signals.LINK.name}: invalid JSON ({exc})') from None
    if not isinstance(doc, dict):
        raise InputError(f'{path}: {signals.LINK.name}: expected a JSON object')
    return doc


def _node_parameters(data: str, where: str) -> tuple[str, dict]:
    """``(node, parameters)`` of one ``/seft/node_parameters`` message (JSON text)."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise InputError(f'{where}: invalid JSON ({exc})') from None
    node = doc.get('node') if isinstance(doc, dict) else None
    values = doc.get('parameters') if isinstance(doc, dict) else None
    if not isinstance(node, str) or not node or not isinstance(values, dict):
        raise InputError(f'{where}: expected {{"node": <name>, "parameters": {{...}}}}')
    return node, values


def _candidates(name: str, node_params: dict) -> list[str]:
    """The nodes to take parameter `name` from, in order: its source node, then the graph's
    other nodes in ``parameters.NODES`` order, then any other node of the root namespace by
    name (a structure's rig nodes, ``<rig>/rig``, hold their rig's values, not the run's)."""
    first = parameters.value_source(name)
    rest = [n for n in parameters.NODES if n != first]
    rest += sorted(n for n in node_params if n not in parameters.NODES and '/' not in n)
    return [first] + rest


def _resolve_sources(node_params: dict, run_params: dict | None,
                     path: Path) -> tuple[dict, dict]:
    """``(params, param_sources)``: every schema parameter from the first node of
    :func:`_candidates` that declared it, else from the run parameters, else the default."""
    values, sources = {}, {}
    for s in parameters.SCHEMA:
        node = next((n for n in _candidates(s.name, node_params)
                     if s.name in node_params.get(n, {})), None)
        if node is not None:
            value, source, where = node_params[node][s.name], node, f'{path}: node {node}'
        elif run_params is not None and s.name in run_params:
            value, source, where = run_params[s.name], RUN_PARAMETERS_SOURCE, str(path)
        else:
            value, source, where = s.default, DEFAULT_SOURCE, str(path)
        try:
            values[s.name] = parameters.validate_value(s.name, value, where=where)
        except parameters.ParameterError as exc:
            raise InputError(str(exc)) from None
        sources[s.name] = source
    return values, sources


def read_signals(path) -> BagSignals:
    """Read every seft topic of the bag at `path`, of every rig.

    Parameters
    ----------
    path : str or Path
        Bag directory: a closed bag (rosbags reads it), or one its recorder never closed
        (no ``metadata.yaml``; the complete records of its file, ``BagSignals.recovery``).

    Returns
    -------
    BagSignals
        The parameters (each from the node that used it, see ``BagSignals.param_sources``),
        the run's graph (:class:`~seft_msgs_py.graph.Graph`: its rigs and their topics), the
        samples per step of every rig's topics, the message counts and the status reports.
        Nodes that disagree on a shared parameter do not stop the reading: the lines are in
        ``BagSignals.parameter_mismatches``. The parameters of a node with another
        ``run_token`` than the run parameters' (another run's node on the domain, recorded
        as it was heard) are not the run's and are left out. A step recorded more than once
        with the same value reads as one sample (listed in ``BagSignals.duplicates``).

    Raises
    ------
    InputError
        No bag there, not a seft bag (neither run nor node parameters), a malformed
        parameter message, a parameter out of its schema range, unreadable, or a step of a
        signal recorded more than once with different values (the error names the topic,
        the step and both values: which one the test saw cannot be known).

    Notes
    -----
    The bag is read once: the parameters, statuses and link figures as they come, every
    other message kept as it is. Then, the parameters giving the graph, each kept message
    is read in bag order by its topic: the scalar signals of each rig (stamp -> step), a
    rig's live measurement and the nodes' record batches (a bag recorded from the live
    topics), the fields topics (the compensator's estimates, a builder's computational
    state: one ``JointState`` per step) and the timing records.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f'{path}: no such bag')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    counts = {}
    statuses = []
    params = None
    node_params = {}
    heard_params: list[tuple[str, dict]] = []   # (node, parameters), in bag order
    kept: list[tuple] = []                     # (topic, type, CDR) of the data, in bag order
    reader = recovery = None
    link = None
    try:
        reader, recovery = _open_bag(path)
        for topic, msgtype, raw in _messages(reader, recovery):
            counts[topic] = counts.get(topic, 0) + 1
            if topic == signals.RUN_PARAMETERS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                params = json.loads(msg.data)
            elif topic == signals.NODE_PARAMETERS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                heard_params.append(_node_parameters(
                    msg.data, f'{path}: {signals.NODE_PARAMETERS.name}'))
            elif topic == signals.LINK.name:
                link = _link(typestore.deserialize_cdr(raw, msgtype).data, path)
            elif topic == signals.STATUS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                entry = {kv.key: kv.value for kv in msg.values}
                entry.update(name=msg.name, message=msg.message)
                statuses.append((str(msg.hardware_id), entry))
            else:
                kept.append((topic, msgtype, bytes(raw)))
    except InputError:
        raise
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    finally:
        if reader is not None:
            reader.close()
    # the run's nodes only: parameters with another run_token than the run's are another
    # run's node on the domain (recorded, never taken for this run's)
    token = params.get('run_token') if isinstance(params, dict) else None
    for node, values in heard_params:
        if token is None or values.get('run_token', token) == token:
            node_params[node] = values
    if params is None and not node_params:
        if recovery is not None:
            cut = f' ({recovery.end})' if recovery.end else ''
            how = (f'the reader refuses its file ({recovery.damaged}), cut or damaged after '
                   'the recording,' if recovery.damaged else
                   'the bag was not closed (recorder killed?)')
            raise InputError(f'{path}: {how} and holds no run parameters in its complete '
                             f'records{cut}')
        raise InputError(f'{path}: not a seft bag (no /seft/run_parameters message)')
    if params is not None and not isinstance(params, dict):
        raise InputError(f'{path}: {signals.RUN_PARAMETERS.name}: expected a JSON object')
    if node_params:
        params, sources = _resolve_sources(node_params, params, path)
        mismatches = parameters.shared_mismatches(node_params)
    else:  # a bag written before the nodes published their parameters
        given = {k: v for k, v in params.items() if k in parameters.defaults()}
        try:
            params = parameters.resolve(given, where=str(path))
        except parameters.ParameterError as exc:
            raise InputError(str(exc)) from None
        sources = {name: RUN_PARAMETERS_SOURCE if name in given else DEFAULT_SOURCE
                   for name in params}
        mismatches = []
    try:
        graph = Graph.from_parameters(params)
    except parameters.ParameterError as exc:
        raise InputError(f'{path}: {exc}') from None
    try:
        data = _read_data(graph, kept, typestore, path)
    except InputError:
        raise
    except Exception as exc:  # a damaged message
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    dt_ns = int(round(params['dt'] * 1e9))
    steps = _Steps(dt_ns)
    by_step = {name: steps.of(name, vals.items(), listed=True)
               for name, vals in data.samples.items()}
    for name, entries in data.repeats.items():
        for key, first, other in entries:
            steps.repeat(name, key, first, other, step_keys=False)
    for name, vals in data.live.items():
        if vals and not by_step[name]:     # recorded from the live topics only
            # the rig's measurement and its record batches: two sources of the same samples
            measured = steps.of(name, ((k, v) for k, v in vals.items() if isinstance(k, tuple)),
                                listed=True)
            batches = steps.of(name, ((k, v) for k, v in vals.items()
                                      if not isinstance(k, tuple)), listed=True, step_keys=True)
            by_step[name] = steps.of(name, list(measured.items()) + list(batches.items()),
                                     listed=False, step_keys=True)
            for key, first, other in data.live_repeats.get(name, ()):
                steps.repeat(name, key, first, other, step_keys=True)
    if steps.conflicts:
        topic, k, first, other = steps.conflicts[0]
        more = len(steps.conflicts) - 1
        raise InputError(
            f'{path}: {topic}: step {k} (t = {k * dt_ns * 1e-9:.6f} s) recorded more than once '
            f'with different values ({first!r} and {other!r})'
            + (f'; {more} more such sample{"s" if more > 1 else ""}' if more else ''))
    timing_rows = data.timing_rows
    for node, rows in data.live_timing.items():
        if node not in timing_rows:
            timing_rows[node] = [(step * dt_ns, values) for step, values in rows]
    statuses, foreign_statuses = _run_statuses(statuses, params)
    bag = BagSignals(params, by_step, counts, statuses, node_params=node_params,
                     param_sources=sources, parameter_mismatches=mismatches,
                     timing=node_timings(timing_rows, params['dt']))
    bag.graph = graph
    bag.foreign_statuses = foreign_statuses
    bag.fields = {topic: {(key[1] if isinstance(key, tuple) else int(round(key / dt_ns))):
                          values for key, values in rows.items()}
                  for topic, rows in data.fields.items()}
    bag.estimates = bag.fields.get(signals.ESTIMATES.name, {})
    bag.duplicates = {name: sorted(ks) for name, ks in steps.duplicates.items()}
    bag.link = link
    if recovery is not None:
        recovery.messages = []       # read: the counts say how many
    bag.recovery = recovery
    return bag


def _scalar_topics(graph: Graph) -> dict[str, str]:
    """``{topic: field}`` of the scalar signals of the run (``/clock``, the ground motion,
    each rig's reference force, valve command and sensors), in the order of
    :data:`seft_msgs_py.signals.SCALAR_SIGNALS` per rig."""
    out = {signals.CLOCK.name: signals.CLOCK.field,
           signals.GROUND_ACCELERATION.name: signals.GROUND_ACCELERATION.field}
    for r in graph.rigs:
        for s in (graph.reference_force(r), graph.valve_command(r)) + graph.sensors(r):
            out[s.name] = s.field
    return out


class _Data:
    """What :func:`_read_data` read: per topic its samples (``samples``: stamp [ns] ->
    value; ``live``: ``('ns', stamp)`` or step -> value), the repeated stamps, the fields
    topics' rows (stamp or ``('step', k)`` -> ``{name: value}``) and the timing rows."""

    def __init__(self, scalars):
        self.samples = {name: {} for name in scalars}
        self.live = {name: {} for name in scalars}
        self.repeats: dict[str, list] = {}          # topic -> [(stamp, first, repeated)]
        self.live_repeats: dict[str, list] = {}     # the same for `live` (its keys)
        self.fields: dict[str, dict] = {}           # topic -> {stamp or ('step', k): values}
        self.timing_rows: dict[str, list] = {}      # node -> [(stamp, values)]
        self.live_timing: dict[str, list] = {}      # node -> [(step, values)]


def _read_data(graph: Graph, kept: list, typestore, path: Path) -> _Data:
    """The data messages of a bag (``(topic, type, CDR)`` in bag order) by their topics in
    the run's graph (:func:`read_signals`, Notes); a topic of no seft signal is skipped."""
    scalars = _scalar_topics(graph)
    data = _Data(scalars)
    measurements = {graph.measurement(r).name: tuple(s.name for s in graph.sensors(r))
                    for r in graph.rigs}
    streams = {s.name: s for s in graph.record_streams()}
    fields_topics = {s.fields_topic for s in graph.record_streams() if s.fields_topic}
    fields_topics |= {scoped(signals.ESTIMATES.name, r) for r in graph.rigs}
    timing = {graph.timing_topic(s): s.node for s in graph.record_streams() if s.timing}
    for topic, msgtype, raw in kept:
        if topic in timing:
            data.timing_rows.setdefault(timing[topic], []).append(
                timing_row(typestore.deserialize_cdr(raw, msgtype)))
        elif topic in measurements:
            msg = typestore.deserialize_cdr(raw, msgtype)
            by_name = dict(zip(msg.name, msg.position))
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            for name, field in zip(measurements[topic], signals.MEASUREMENT_FIELDS):
                if field in by_name:
                    _store(data.live[name], ('ns', stamp), float(by_name[field]), name,
                           data.live_repeats)
        elif topic in fields_topics:
            msg = typestore.deserialize_cdr(raw, msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            data.fields.setdefault(topic, {})[stamp] = dict(
                zip(msg.name, (float(v) for v in msg.position)))
        elif topic in streams and streams[topic].fields_topic:
            stream = streams[topic]
            msg = typestore.deserialize_cdr(raw, msgtype)
            names = stream.columns_of(msg)
            rows = np.asarray(msg.data, dtype=float).reshape(-1, 1 + len(names))
            rows_of = data.fields.setdefault(stream.fields_topic, {})
            for r in rows:
                rows_of.setdefault(('step', int(r[0])), dict(zip(names, r[1:])))
        elif topic in streams:
            _read_batch(streams[topic], typestore.deserialize_cdr(raw, msgtype), data.live,
                        data.live_timing, path, data.live_repeats)
        elif topic in scalars:
            msg = typestore.deserialize_cdr(raw, msgtype)
            if topic == signals.CLOCK.name:
                stamp, value = msg.clock, None
            else:
                stamp, value = msg.header.stamp, float(_get(msg, scalars[topic]))
            _store(data.samples[topic], stamp.sec * 1_000_000_000 + stamp.nanosec, value,
                   topic, data.repeats)
    return data


def _open_bag(path: Path):
    """``(reader, None)``, rosbags' reader opened, for a closed bag it opens (read as it
    streams; the caller closes it); ``(None, recovery)`` for an unclosed bag and for one whose
    file the reader refuses at its opening (``metadata.yaml`` there, the file cut or damaged
    after the recording: a copy cut short): its complete records
    (:func:`~seft_ros.analysis.bag_recovery.recover_bag`; ``damaged``, the reader's error).
    Before, such a bag was 'cannot read the bag: File end magic is invalid', while the same
    file without its metadata was recovered (a new user, session 36)."""
    if is_unclosed_bag(path):
        return None, recover_bag(path)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises several types for a damaged bag
        try:
            recovery = recover_bag(path)
        except ValueError:
            raise exc from None             # no file to recover from: the reader's error
        recovery.damaged = str(exc) or type(exc).__name__
        return None, recovery
    return reader, None


def _messages(reader, recovery):
    """``(topic, message type, CDR bytes)`` of every message, in log-time order: from the
    opened `reader` of a closed bag, or the recovered messages of another (:func:`_open_bag`)."""
    if recovery is not None:
        for topic, msgtype, _, raw in recovery.messages:
            yield topic, msgtype, raw
        return
    for conn, _, raw in reader.messages():
        yield conn.topic, conn.msgtype, raw


def _read_batch(stream, msg, live: dict, live_timing: dict, path: Path,
                repeats: dict) -> None:
    """The rows of one record batch into `live` ({topic: {step: value}}; a step seen before
    into `repeats`, see :func:`_store`) or, for a timing stream, `live_timing` ({node:
    [(step, values)]})."""
    try:
        width = 1 + len(stream.columns_of(msg))
    except ValueError as exc:
        raise InputError(f'{path}: {exc}') from None
    rows = np.asarray(msg.data, dtype=float).reshape(-1, width)
    if stream.timing:
        live_timing.setdefault(stream.node, []).extend(
            (int(r[0]), [float(v) for v in r[1:]]) for r in rows)
        return
    for j, topic in enumerate(stream.columns, start=1):
        for r in rows:
            _store(live[topic], int(r[0]), float(r[j]), topic, repeats)


def _store(store: dict, key, value, topic: str, repeats: dict) -> None:
    """``store[key] = value``, or, for a `key` seen before, ``(key, first value, value)``
    appended to ``repeats[topic]`` (the first value stays)."""
    if key in store:
        repeats.setdefault(topic, []).append((key, store[key], value))
    else:
        store[key] = value


def _same(a, b) -> bool:
    """Whether two recorded values are the same sample (NaN is NaN; /clock's are None)."""
    return a == b or (a != a and b != b)


class _Steps:
    """Keys of the samples (stamps [ns], ``('ns', stamp)`` or steps) to steps, collecting
    the steps recorded more than once: ``duplicates`` ({topic: {step}}, the same value) and
    ``conflicts`` ([(topic, step, first value, other value)])."""

    def __init__(self, dt_ns: int):
        self.dt_ns = dt_ns
        self.duplicates: dict[str, set] = {}
        self.conflicts: list[tuple] = []

    def step(self, key, step_keys: bool) -> int:
        if isinstance(key, tuple):
            return int(round(key[1] / self.dt_ns))
        return int(key) if step_keys else int(round(key / self.dt_ns))

    def repeat(self, topic: str, key, first, other, *, step_keys: bool, listed=True) -> None:
        """One more sample of the step of `key`, whose first value was `first`."""
        if not _same(first, other):
            self.conflicts.append((topic, self.step(key, step_keys), first, other))
        elif listed:
            self.duplicates.setdefault(topic, set()).add(self.step(key, step_keys))

    def of(self, topic: str, items, *, listed: bool, step_keys: bool = False) -> dict:
        """``{step: value}`` of ``(key, value)`` pairs (an int key is a stamp [ns] unless
        `step_keys`); a step met again is a duplicate (`listed`) or a conflict."""
        out = {}
        for key, value in items:
            k = self.step(key, step_keys)
            if k in out:
                self.repeat(topic, k, out[k], value, step_keys=True, listed=listed)
            else:
                out[k] = value
        return out


def recording_end(bag: BagSignals, n_steps: int) -> dict:
    """How the recording of `bag` ended, and what it holds.

    Parameters
    ----------
    bag : BagSignals
        A bag read by :func:`read_signals`.
    n_steps : int
        Its complete steps (every signal present).

    Returns
    -------
    dict
        ``'end'``: ``'closed'`` (the recorder closed the bag after every rig's final
        status), ``'stopped'`` (the recorder closed the bag, but the run's end is not in it:
        no final status of a rig; the recorder was stopped by a signal, or lost the rig),
        ``'crashed'`` (never closed: recovered from the file; the recorder was killed, or
        is still recording), ``'damaged'`` (closed, its ``metadata.yaml`` there, but its
        file refused by the reader: cut or damaged afterwards; recovered from the file, the
        reader's error in ``'reader_error'``) or
        ``'unknown'`` (no recorder status: a bag not written by the recorder);
        ``'steps'`` and ``'duration_s'``: the complete steps and their time span [s];
        ``'messages'``: the messages read; ``'note'``: one line for the report. A crashed
        bag adds ``'flush_every_s'`` (the recorder's flush period [s]: the bound of what the
        crash lost, at most that much of the last complete steps, see
        ``seft_ros.nodes.recorder``), ``'storage'``, ``'file_complete'`` (the file ended
        as a closed one, killed during the close) and ``'cut'`` (where the file was cut).
    """
    dt = bag.params['dt']
    recorder = [s for s in bag.statuses if s['name'] == 'recorder']
    closed = any(s.get('state') == 'closed' for s in recorder)
    rigs = bag.graph.rig_nodes() if bag.graph is not None else ('rig',)
    run_ended = all(any(s['name'] == rig and s.get('state') in _FINAL for s in bag.statuses)
                    for rig in rigs)
    out = {'steps': n_steps, 'duration_s': n_steps * dt,
           'messages': int(sum(bag.counts.values()))}
    held = f'{n_steps * dt:.3f} s ({n_steps} steps, {out["messages"]} messages)'
    planned = next((int(s['n_steps']) for s in bag.statuses
                    if s['name'] == 'ground_motion_publisher' and 'n_steps' in s), None)
    # the record's steps the file does not hold (a run cut short, or a file cut)
    short = (f'; the run played {planned * dt:.3f} s of record ({planned} steps): '
             f'{(planned - n_steps) * dt:.3f} s of it are not in the file'
             if planned is not None and planned > n_steps else '')
    if bag.recovery is not None and bag.recovery.damaged:
        out.update(end='damaged', storage=bag.recovery.storage,
                   file_complete=bag.recovery.file_complete, cut=bag.recovery.end,
                   reader_error=bag.recovery.damaged)
        # metadata.yaml written at the close, the file cut or damaged afterwards: what it
        # lost is not bounded by the recorder's flush
        # (a whole file the reader refuses for its metadata: a metadata.yaml of another
        # version or cut itself; the session's review)
        state = ('its file is whole: read from it' if bag.recovery.file_complete else
                 'its file was cut or damaged after the recording: recovered')
        out['note'] = ('its metadata.yaml says the recorder closed this bag, but the reader '
                       f'refuses it ({bag.recovery.damaged}); {state} {held} from its '
                       'complete records' + short)
    elif bag.recovery is not None:
        flush = next((float(s['flush_every_s']) for s in recorder if 'flush_every_s' in s),
                     FLUSH_EVERY_S)
        out.update(end='crashed', flush_every_s=flush, storage=bag.recovery.storage,
                   file_complete=bag.recovery.file_complete, cut=bag.recovery.end)
        # a bag without its metadata: the recorder was killed, or it is still writing (a
        # run still going, or a recorder left behind): the file cannot tell which; or the
        # file was cut afterwards, and the flush does not bound what it lost
        out['note'] = (f'the recording was not closed (recorder killed, or still recording): '
                       f'recovered {held}; at most the last {flush:g} s before the end of '
                       'the file is missing (not flushed) if the recorder wrote it so, more '
                       'if the file was cut afterwards' + short)
    elif closed and run_ended:
        out.update(end='closed', note=f'bag closed by the recorder: {held}')
    elif recorder:
        out.update(end='stopped', note='the recording was stopped before the run ended (bag '
                                       f"closed without the rig's final status): {held}")
    else:
        out.update(end='unknown', note=f'no recorder status in the bag: {held}')
    return out


def _builder_json(statuses, key: str) -> dict:
    """A JSON mapping of the builders' final statuses, by rig, merged over the builders:
    ``sensor_range`` (each rig's samples at a sensor's range,
    ``ReferenceForceBuilder.range_counts``), ``specimen_ratios`` (each rig's identified
    specimen stiffness over the declared one), ``part_findings`` (what the computational
    part found, ``ReferenceForceBuilder.part_findings``); empty for a bag before issue 39
    (before session 32 for ``part_findings``)."""
    out = {}
    for s in statuses:
        if s.get('state') in _FINAL and s['name'].endswith('reference_force_builder') \
                and s.get(key):
            try:
                out.update(json.loads(s[key]))
            except ValueError:
                continue
    return out


def read_run(path) -> RunData:
    """Read any seft bag into a :class:`~seft_ros.analysis.rundata.RunData`: every rig's
    signals (the study's test: its one rig, ``''``, in the root namespace; a structure's: each
    rig in its namespace) and a structure's computational state, from step 0 up to the first
    step a signal lacks (the analysis needs contiguous samples), and what the bag misses after
    it.

    The parameters are ``BagSignals.params``; each rig's (``RigData.params``) are those the
    run declares for it (:func:`~seft_ros.core.structure.test_setup`: the study's rig, the
    run's), updated, for a rig in a namespace of its own, with what its rig node published,
    and its ``alpha`` the rigid computational mass on its DOF over its specimen mass. A
    builder's computational state (``/[<rig>/]seft/structure_state``, the first builder's)
    gives ``RunData.computational``, NaN where the bag has none (the last sample).
    ``extra`` holds ``'rig_final'`` (the first rig's final status) and ``'rig_finals'``
    (``{rig node: final status}``), ``'counts'``, ``'node_params'`` (``{node: {parameter:
    value}}``, empty for a bag without node parameters), ``'param_sources'``
    (``{parameter: node, 'run_parameters' or 'default'}``), ``'parameter_mismatches'`` (one
    line per shared parameter on which the nodes disagree; empty when they agree),
    ``'node_statuses'`` (every status report, in bag order), ``'recording'`` (how the
    recording ended and what it holds, :func:`recording_end`: a bag whose recorder was killed
    reads too, from its complete records; ``'recovered'`` says so), ``'gaps'`` and
    ``'duplicates'`` (below), ``'wall_s'`` (the rigs' longest wall time of the stepping [s],
    or None), ``'rig_contract'`` (the contract the rigs reported, None when they did not, or
    did not all report the same), ``'abort_node'`` (the node whose abort ended the run, or
    None), ``'bag_lost_messages'`` (what the nodes published and the bag does not hold,
    from the recorder's closing status) and, for a real-time run, ``'timing_data'``
    (``BagSignals.timing``) and ``'timing'`` (its
    :func:`~seft_ros.analysis.timing.timing_summary`). Each rig's ``extra`` holds its
    ``'rig_final'`` and ``'rig_contract'``. A real-time run aborted into the rigs' safe
    state ends at the first abort (``abort_at_s`` of a rig's final status): the ramp after it
    is not part of the test. A bag that ends before the run did (no final status of a rig;
    the recorder killed or stopped) is a run cut short: not ``stable``, ended at its last
    complete step, with the reason ``'recorder: the recording was not closed (recorder
    killed, or still recording)'`` (or ``'... was stopped before the run ended'``).

    **Gaps.** A step missing on a signal before the run's end (the step at which the rig
    that ended the run stopped: its final ``step``, the safe state of a real-time abort,
    else the last step every signal has) ends the analysed run there, and nothing after it
    is dropped unsaid: ``extra['gaps']`` is ``{'at_step', 'at_s', 'missing': {topic:
    [steps]}, 'steps_after_gap', 'last_step', 'note'}`` (the first incomplete step and its
    time [s], the steps each signal misses up to the run's last step, the complete steps
    after the gap that were not analysed, that last step and one line), and
    ``extra['recording']`` gains ``'gap_at_step'``, ``'steps_not_analysed'`` and the line at
    the end of its ``'note'`` (``'gap at step 12 (t = 0.024 s): /seft/measured_force misses
    steps 12-14; 25 complete steps after it (to step 39) were not analysed'``); None without
    a gap. Samples past the run's end on some topics only (the ground motion's preview, the
    rig's sample after an abort) are no gap. A gap does not change ``stable``; an aborted
    run whose bag lost the steps before the abort keeps the rig's abort time as
    ``unstable_at_s``. Compensator estimates missing for an analysed step are not read
    (``estimates`` None): ``extra['estimates_missing_steps']`` lists the steps and the note
    says so.

    **Duplicates.** A step recorded more than once with the same value is one sample
    (``extra['duplicates']``: ``{topic: [steps]}``, empty when none); with different values
    the bag is refused (:func:`read_signals`).

    **Aborts.** An 'aborted' or 'failed' report, of any node, makes the run not ``stable``;
    the node that aborted is the first whose report does not pass on another's (a node that
    ends on another's abort reports ``'<that node>: <its message>'``, and the bag may hold it
    first); the reason is the message of the study's rig (``rig``), else ``'<node>:
    <message>'`` (``'reference_force_builder: unstable at t=...'`` when its instability
    monitor trips, ``'pier_b/rig: stroke limit exceeded ...'``); ``unstable_at_s`` is the
    real-time abort's ``abort_at_s``, else the end of the analysed steps (in the graph,
    where the rigs stopped stepping).

    Raises
    ------
    InputError
        As :func:`read_signals`, the structure disagrees with a rig's parameters, or the bag
        holds no complete step (a signal without a sample: the message names its topics;
        step 0 missing on some).
    """
    bag = read_signals(path)
    p = bag.params
    graph = bag.graph
    dt = p['dt']
    needed = [signals.GROUND_ACCELERATION.name]
    per_rig = {}
    for r in graph.rigs:
        per_rig[r] = [graph.reference_force(r).name] + [s.name for s in graph.sensors(r)]
        if graph.has_controller(r):
            per_rig[r].append(graph.valve_command(r).name)
        needed += per_rig[r]
    n = 0
    while all(n in bag.samples[name] for name in needed):
        n += 1
    complete = set.intersection(*(set(bag.samples[name]) for name in needed))
    if n == 0:
        missing = [name for name in needed if not bag.samples[name]]
        first = [name for name in needed if 0 not in bag.samples[name]]
        later = len(complete)
        raise InputError(f'{path}: the bag holds no complete step: '
                         + (f'no samples on {", ".join(missing)}' if missing else
                            f'step 0 missing on {", ".join(first)}'
                            + (f' ({later} complete steps after it)' if later else '')))
    try:
        setup = test_setup(p)
    except ParameterError as exc:
        raise InputError(f'{path}: {exc}') from None
    finals = {node: next((s for s in reversed(bag.statuses) if s['name'] == node
                          and s.get('state') in _FINAL), None) for node in graph.rig_nodes()}
    aborted = [s for s in bag.statuses if s.get('state') in ('aborted', 'failed')]
    recording = recording_end(bag, n)
    aborts = [float(f['abort_at_s']) for f in finals.values() if f and 'abort_at_s' in f]
    abort_at_s = min(aborts) if aborts else None
    end_step, ended = _end_step(finals, abort_at_s, dt)
    gaps = _gaps(bag, needed, n, complete, end_step, dt)
    if abort_at_s is not None:
        # real time: the rigs kept sampling their safe-state ramp after the abort
        n = max(1, min(n, int(round(abort_at_s / dt))))
    if gaps is not None:
        recording.update(gap_at_step=gaps['at_step'],
                         steps_not_analysed=gaps['steps_after_gap'])
        recording['note'] += f'; {gaps["note"]}'
    stable = not aborted
    reason = None
    first = _first_abort(aborted)
    cut = False                         # the run ends where its recording was cut
    interrupted = first is not None and _interrupt(first)
    if interrupted:
        # the operator's stop (Ctrl-C reaches every node of the terminal's process group,
        # and the first node to report is not the cause): the runner's interrupt if heard
        first = next((s for s in aborted if is_runner_interrupt(s['message'])), first)
    if first is not None:
        reason = first['message'] if first['name'] == 'rig' else (
            f"{first['name']}: {first['message']}")
        if interrupted and not is_runner_interrupt(first['message']):
            reason = f"interrupted ({first['signal']}): {reason}"
    elif not all(finals.values()) and recording['end'] in RECORDING_CUT_SHORT:
        # the bag ends before the run did: the test is cut short at its last complete step
        stable = False
        cut = True
        reason = {'crashed': 'recorder: the recording was not closed (recorder killed, or '
                             'still recording)',
                  'stopped': 'recorder: the recording was stopped before the run ended',
                  'damaged': 'the bag: its file was cut or damaged after the recording (the '
                             'run went on past its end, or ended there: the file cannot '
                             'tell)'}[recording['end']]
    record_name = next((s.get('record') for s in bag.statuses
                        if s['name'] == 'ground_motion_publisher' and s.get('record')),
                       Path(str(p['record'])).stem)
    unstable_at_s = None
    if not stable:
        unstable_at_s = abort_at_s if abort_at_s is not None else n * dt
        if abort_at_s is None and end_step is not None and end_step > n and ended:
            unstable_at_s = end_step * dt      # the bag lost steps before the rig's abort
    contracts = {rig_contract_of(bag.statuses, node) for node in graph.rig_nodes()}
    walls = [float(f['wall_s']) for f in finals.values() if f and 'wall_s' in f]
    extra = {'rig_final': finals[graph.master], 'counts': bag.counts,
             'recording': recording, 'gaps': gaps, 'duplicates': bag.duplicates,
             'node_params': bag.node_params, 'param_sources': bag.param_sources,
             'parameter_mismatches': bag.parameter_mismatches,
             'wall_s': max(walls) if walls else None,
             'rig_contract': contracts.pop() if len(contracts) == 1 else None,
             'rig_finals': finals, 'node_statuses': bag.statuses,
             'recovered': bag.recovery is not None,
             'abort_node': first['name'] if first is not None else None,
             'interrupted': interrupted, 'cut_short': cut,
             # what the builders reported during the run (a specimen not the declared one)
             'warnings': [s['warning'] for s in bag.statuses if s.get('warning')],
             # each rig's samples at a sensor's range, as its builder counted them, and its
             # specimen check's identified stiffness over the declared one
             'sensor_range': _builder_json(bag.statuses, 'sensor_range'),
             'specimen_ratios': _builder_json(bag.statuses, 'specimen_ratios'),
             # what the computational part found (an OpenSees part's pushover)
             'part_findings': _builder_json(bag.statuses, 'part_findings')}
    lost = bag_lost_messages(bag.statuses)
    if lost is not None:
        extra['bag_lost_messages'] = lost
    if p.get('mode') == 'realtime':
        extra['timing_data'] = bag.timing
        # the test's steps: not the safe-state ramp the rigs sampled after an abort
        extra['timing'] = timing_summary(bag.timing, until_step=None if abort_at_s is None
                                         else int(round(abort_at_s / dt)))
    if bag.link is not None:
        extra['link'] = bag.link

    def arr(name):
        d = bag.samples[name]
        return np.array([d[k] for k in range(n)])

    rigs = {}
    for j, r in enumerate(graph.rigs):
        node = qualified('rig', r)
        names = per_rig[r]
        rigs[r] = RigData(
            params=_rig_params(bag, setup, r, j, path), reference_force_N=arr(names[0]),
            measured_force_N=arr(names[1]), displacement_m=arr(names[2]),
            velocity_m_s=arr(names[3]), acceleration_m_s2=arr(names[4]),
            valve_command_V=arr(names[5]) if graph.has_controller(r) else None,
            estimates=_estimates(bag, scoped(signals.ESTIMATES.name, r), n, extra, recording),
            extra={'rig_final': finals[node],
                   'rig_contract': rig_contract_of(bag.statuses, node)})
    return RunData(
        params=p, time_s=np.arange(n) * dt, ground_acceleration_m_s2=arr(needed[0]),
        rigs=rigs, computational=_computational(bag, n), stable=stable,
        unstable_at_s=unstable_at_s, abort_reason=reason, record_name=record_name,
        source=str(path), extra=extra)


def _interrupt(status: dict) -> bool:
    """Whether an abort report is a stop signal's (a node's ``signal``) or the runner's
    interrupt (:func:`~seft_msgs_py.rig_contract.is_runner_interrupt`)."""
    return bool(status.get('signal')) or is_runner_interrupt(status['message'])


def _first_abort(aborted: list[dict]) -> dict | None:
    """The report of the node that aborted first, of the 'aborted'/'failed' reports in bag
    order: the first whose message does not pass on another's (a node ending on another's
    abort reports ``'<that node>: <its message>'``, and the bag may hold it first); a
    watchdog's (``rig_contract.WATCHDOG_REASON``) yields to a rig's that names what its UDP
    bridge saw (``rig_contract.BRIDGE_REASON``: the controller silent, its samples lost)."""
    names = {s['name'] for s in aborted}
    first = next((s for s in aborted if not any(s['message'].startswith(f'{name}: ')
                                                 for name in names - {s['name']})),
                 aborted[0] if aborted else None)
    if first is not None and first['message'].startswith(WATCHDOG_REASON):
        # a watchdog (an input of the graph stopped) yields to a UDP bridge's rig that saw
        # its controller fall silent or its samples lost: the cause, reported a little later
        # (before: 'force_servo_controller: watchdog: no /seft/reference_force for 201 ms'
        # was the reason of a run whose controller had gone silent). A rig by its name's
        # last part: the reports include seft's tools ('seft_runner'), no graph node's
        first = next((s for s in aborted if s['name'].rpartition('/')[2] == 'rig'
                      and s['message'].startswith(BRIDGE_REASON)), first)
    return first


def _end_step(finals: dict, abort_at_s: float | None, dt: float) -> tuple[int | None, bool]:
    """``(step, aborted)``: where the rigs say the run ended (:func:`rig_end_step` of the
    rig that aborted on its own, else of every rig's final status, the earliest) and whether
    that rig's final status is an abort."""
    if abort_at_s is not None:
        return int(round(abort_at_s / dt)), True
    reported = [f for f in finals.values() if f]
    own = [f for f in reported if f.get('state') in ('aborted', 'failed')
           and 'ended_by' not in f]
    chosen = own or reported
    steps = [s for s in (rig_end_step(f, None, dt) for f in chosen) if s is not None]
    if not steps:
        return None, False
    return min(steps), any(f.get('state') in ('aborted', 'failed') for f in chosen)


def _rig_params(bag: BagSignals, setup, rig: str, index: int, path) -> dict:
    """A rig's parameters: the run's declaration of it, updated (a rig in a namespace of its
    own) with what its rig node published; its ``alpha`` the split's."""
    out = dict(setup.rig_params[rig])
    own = bag.node_params.get(qualified('rig', rig)) if rig else None
    known = parameters.defaults()
    for name, value in (own or {}).items():
        if name in known:           # only what it declared: the rest is the run's, not a default
            try:
                out[name] = parameters.validate_value(
                    name, value, where=f'{path}: node {qualified("rig", rig)}')
            except parameters.ParameterError as exc:
                raise InputError(str(exc)) from None
    out['alpha'] = float(setup.substructures.alpha[index])
    return out


def _estimates(bag: BagSignals, topic: str, n: int, extra: dict,
               recording: dict) -> dict | None:
    """A rig's compensator's estimates over the first `n` steps from its fields topic, or
    None: none in the bag, or missing for an analysed step (``extra`` and the recording's
    note then say which)."""
    rows = bag.fields.get(topic)
    if not rows:
        return None
    if all(k in rows for k in range(n)):
        names = list(rows[0])
        return {name: np.array([rows[k].get(name, np.nan) for k in range(n)])
                for name in names}
    lost = [k for k in range(n) if k not in rows]
    extra['estimates_missing_steps'] = lost
    recording['note'] += (f'; {topic} misses steps {_ranges(lost)}: the compensator'
                          "'s estimates were not read")
    return None


def _computational(bag: BagSignals, n: int) -> dict[str, np.ndarray]:
    """The computational DOFs' state over the first `n` steps (NaN where not recorded) from
    the first builder's ``structure_state`` topic; empty without one."""
    topic = next((s.fields_topic for s in bag.graph.record_streams()
                  if s.fields_topic.endswith(STRUCTURE_STATE.name)), None)
    values: dict[str, np.ndarray] = {}
    for k, row in sorted(bag.fields.get(topic, {}).items()):
        if k >= n:
            continue
        for name, value in row.items():
            values.setdefault(name, np.full(n, np.nan))[k] = float(value)
    return values


def _run_statuses(read, params) -> tuple[list[dict], int]:
    """The run's status reports of those read from a bag, and how many were not the run's.

    `read`: ``(hardware_id, report)`` in bag order; `params`: the run's parameters
    (``run_token``, ``message_auth``). A bag whose reports carry no seal (recorded before the
    statuses were sealed, ``seft simulate``'s, a run of nodes by hand): every report, as
    before. Otherwise the reports with the run's seal
    (:func:`~seft_msgs_py.provenance.status_id_of_run`): with ``message_auth: token``,
    ``'seft#' + run_token``; with ``hmac``, a seal of ``2 * MAC_BYTES`` hex digits (the key
    is not in the bag: the recorder checked each MAC before it wrote the report, and writes
    no other).
    """
    if not any(hardware_id.startswith(STATUS_ID + SEPARATOR) for hardware_id, _ in read):
        return [entry for _, entry in read], 0
    token = str(params.get('run_token', NO_TOKEN))
    auth = str(params.get('message_auth', AUTH_TOKEN))
    kept = [entry for hardware_id, entry in read if status_id_of_run(hardware_id, token, auth)]
    return kept, len(read) - len(kept)


def rig_contract_of(statuses, rig: str = 'rig') -> str | None:
    """The rig contract (``seft_msgs_py.rig_contract.CONTRACT``, e.g. ``'seft-rig/1.1'``) that
    the rig node `rig` reported in its status (its last report with one), or None: a bag
    recorded before the contract existed, or a rig that does not follow it."""
    found = [s[CONTRACT_KEY] for s in statuses if s['name'] == rig and CONTRACT_KEY in s]
    return found[-1] if found else None


def bag_lost_messages(statuses) -> int | None:
    """What the nodes published and the bag does not hold, from the recorder's 'closed'
    report (its last), or None: a bag the recorder did not close, or one recorded before it
    reported the count."""
    closed = [s for s in statuses if s['name'] == 'recorder' and s.get('state') == 'closed']
    return int(closed[-1]['lost']) if closed and 'lost' in closed[-1] else None


def rig_end_step(final: dict, abort_at_s: float | None, dt: float) -> int | None:
    """The step at which the rig says the run ended (its final status): the safe state of a
    real-time abort (`abort_at_s`), else the final ``step`` (at most ``n_steps``); None
    without a final status or a step in it."""
    if abort_at_s is not None:
        return int(round(abort_at_s / dt))
    try:
        step = int(final['step'])
        if 'n_steps' in final:
            step = min(step, int(final['n_steps']))
    except (KeyError, ValueError):
        return None
    return step


def _ranges(steps, most: int = 6) -> str:
    """Sorted steps as ``'10-12, 20'`` (at most `most` ranges, then how many more)."""
    runs: list[list[int]] = []
    for k in steps:
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    text = [f'{a}-{b}' if b > a else f'{a}' for a, b in runs[:most]]
    if len(runs) > most:
        text.append(f'and {len(runs) - most} more ranges')
    return ', '.join(text)


def _gaps(bag: BagSignals, needed: list[str], n: int, complete: set, end_step: int | None,
          dt: float) -> dict | None:
    """The steps the bag misses between its first incomplete step `n` and the run's end
    (`end_step`, or the last complete step), or None when the complete steps reach the end.

    Returns ``{'at_step', 'at_s', 'missing': {topic: [steps]}, 'steps_after_gap',
    'last_step', 'note'}``: the first incomplete step and its time [s], the steps each topic
    misses in ``[at_step, last_step]``, the complete steps after the gap (not analysed), the
    run's last step and one line for the report.
    """
    after = [k for k in complete if k > n and (end_step is None or k < end_step)]
    end = end_step if end_step is not None else (max(after) + 1 if after else n)
    if end <= n:
        return None
    missing = {name: [k for k in range(n, end) if k not in bag.samples[name]]
               for name in needed}
    missing = {name: steps for name, steps in missing.items() if steps}
    what = '; '.join(f'{name} misses steps {_ranges(steps)}' for name, steps in missing.items())
    note = (f'gap at step {n} (t = {n * dt:.3f} s): {what}; {len(after)} complete steps after '
            f'it (to step {end - 1}) were not analysed')
    return {'at_step': n, 'at_s': n * dt, 'missing': missing, 'steps_after_gap': len(after),
            'last_step': end - 1, 'note': note}
