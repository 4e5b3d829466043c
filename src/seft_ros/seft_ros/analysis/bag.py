"""Read a seft rosbag2 bag (written by the recorder node) back into a :class:`RunData`.

Uses rosbags (no rclpy): each parameter comes from the node that used it (the
``/seft/node_parameters`` message of its ``parameters.value_source`` node: alpha from the
reference-force builder, the specimen and the rig from the rig, ...), from the next node that
declared it when that node is not in the bag, and from ``/seft/run_parameters`` in a bag
without node parameters; the signals from the scalar topics (one message per step, stamped
``t_k``), the abort reason from the final ``/seft/status`` reports.

A bag its recorder never closed (killed with SIGKILL: no ``metadata.yaml``, an MCAP file
without its summary, an uncommitted sqlite3 transaction) reads too: every message of its
complete records (:mod:`seft_ros.analysis.bag_recovery`); :func:`read_run` says that the
recording ended in a crash and how much it recovered.

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
from seft_msgs_py.errors import InputError
from seft_ros.analysis.bag_recovery import FLUSH_EVERY_S, is_unclosed_bag, recover_bag
from seft_ros.analysis.rundata import RunData
from seft_ros.analysis.timing import (
    TIMING_PUBLISHER,
    node_timings,
    timing_row,
    timing_summary,
)

__all__ = ['read_run', 'BagSignals', 'read_signals', 'recording_end']

_SCALARS = {s.name: s.field for s in (signals.CLOCK,) + signals.SCALAR_SIGNALS}
_RECORD = {r.name: r for r in signals.RECORD_STREAMS}
_MEASURED = (signals.MEASURED_FORCE.name, signals.DISPLACEMENT.name, signals.VELOCITY.name,
             signals.ACCELERATION.name)


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
    samples : dict of str -> dict of int -> float
        Per topic, the value of each step (stamp // dt); ``/clock`` maps step -> step.
    counts : dict of str -> int
        Messages per topic (duplicates included).
    statuses : list of dict
        Every status report: ``name``, ``message`` and its key/values.
    node_params : dict of str -> dict
        ``{node: {parameter: value}}`` as each node published it on
        ``/seft/node_parameters`` (the last message of a node); empty in an older bag.
    param_sources : dict of str -> str
        ``{parameter: where params took it from}``: a node name, ``'run_parameters'``
        (:data:`RUN_PARAMETERS_SOURCE`) or ``'default'`` (:data:`DEFAULT_SOURCE`: in no
        message of the bag).
    parameter_mismatches : list of str
        ``parameters.shared_mismatches(node_params)``: one line per shared parameter on which
        the nodes disagree (empty when they agree or the bag has no node parameters).
    timing : dict of str -> NodeTiming
        The real-time timing records per node (:mod:`seft_ros.analysis.timing`; empty for a
        lockstep run).
    estimates : dict of int -> dict of str -> float
        The compensator's estimates in effect for each step's reference force
        (``/seft/estimates``; empty without an adaptive compensator).
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
        self.estimates: dict[int, dict[str, float]] = {}
        self.recovery = None


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
    other nodes in ``parameters.NODES`` order, then any other node by name."""
    first = parameters.value_source(name)
    rest = [n for n in parameters.NODES if n != first]
    rest += sorted(n for n in node_params if n not in parameters.NODES)
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
    """Read every seft topic of the bag at `path`.

    Parameters
    ----------
    path : str or Path
        Bag directory: a closed bag (rosbags reads it), or one its recorder never closed
        (no ``metadata.yaml``; the complete records of its file, ``BagSignals.recovery``).

    Returns
    -------
    BagSignals
        The parameters (each from the node that used it, see ``BagSignals.param_sources``),
        the samples per step, the message counts and the status reports. Nodes that disagree
        on a shared parameter do not stop the reading: the lines are in
        ``BagSignals.parameter_mismatches``.

    Raises
    ------
    InputError
        No bag there, not a seft bag (neither run nor node parameters), a malformed
        parameter message, a parameter out of its schema range, or unreadable.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f'{path}: no such bag')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    samples = {name: {} for name in _SCALARS}
    counts = {}
    statuses = []
    params = None
    node_params = {}
    timing_rows: dict[str, list] = {}
    live = {name: {} for name in _SCALARS}      # topic -> {step or ('ns', stamp): value}
    live_timing: dict[str, list] = {}          # node -> [(step, values)]
    estimates: dict = {}                       # stamp [ns] or ('step', k) -> {name: value}
    recovery = None
    try:
        if is_unclosed_bag(path):
            recovery = recover_bag(path)
        for topic, msgtype, raw in _messages(path, recovery):
            counts[topic] = counts.get(topic, 0) + 1
            if topic == signals.RUN_PARAMETERS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                params = json.loads(msg.data)
            elif topic == signals.NODE_PARAMETERS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                node, values = _node_parameters(
                    msg.data, f'{path}: {signals.NODE_PARAMETERS.name}')
                node_params[node] = values
            elif topic in TIMING_PUBLISHER:
                timing_rows.setdefault(TIMING_PUBLISHER[topic], []).append(
                    timing_row(typestore.deserialize_cdr(raw, msgtype)))
            elif topic == signals.STATUS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                entry = {kv.key: kv.value for kv in msg.values}
                entry.update(name=msg.name, message=msg.message)
                statuses.append(entry)
            elif topic == signals.MEASUREMENT.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                by_name = dict(zip(msg.name, msg.position))
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                for name, field in zip(_MEASURED, signals.MEASUREMENT_FIELDS):
                    if field in by_name:
                        live[name][('ns', stamp)] = float(by_name[field])
            elif topic == signals.ESTIMATES.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                estimates[stamp] = dict(zip(msg.name, (float(v) for v in msg.position)))
            elif topic in _RECORD and _RECORD[topic].fields_topic:
                msg = typestore.deserialize_cdr(raw, msgtype)
                names = _RECORD[topic].columns_of(msg)
                rows = np.asarray(msg.data, dtype=float).reshape(-1, 1 + len(names))
                for r in rows:
                    estimates.setdefault(('step', int(r[0])), dict(zip(names, r[1:])))
            elif topic in _RECORD:
                _read_batch(_RECORD[topic], typestore.deserialize_cdr(raw, msgtype),
                            live, live_timing, path)
            elif topic in _SCALARS:
                msg = typestore.deserialize_cdr(raw, msgtype)
                if topic == signals.CLOCK.name:
                    stamp, value = msg.clock, None
                else:
                    stamp, value = msg.header.stamp, float(_get(msg, _SCALARS[topic]))
                samples[topic][stamp.sec * 1_000_000_000 + stamp.nanosec] = value
    except InputError:
        raise
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    if params is None and not node_params:
        if recovery is not None:
            cut = f' ({recovery.end})' if recovery.end else ''
            raise InputError(f'{path}: the bag was not closed (recorder killed?) and holds no '
                             f'run parameters in its complete records{cut}')
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
    dt_ns = int(round(params['dt'] * 1e9))
    by_step = {name: {int(round(ns / dt_ns)): v for ns, v in vals.items()}
               for name, vals in samples.items()}
    for name, vals in live.items():
        if vals and not by_step[name]:     # recorded from the live topics only
            by_step[name] = {(int(round(key[1] / dt_ns)) if isinstance(key, tuple) else key): v
                             for key, v in vals.items()}
    for node, rows in live_timing.items():
        if node not in timing_rows:
            timing_rows[node] = [(step * dt_ns, values) for step, values in rows]
    bag = BagSignals(params, by_step, counts, statuses, node_params=node_params,
                     param_sources=sources, parameter_mismatches=mismatches,
                     timing=node_timings(timing_rows, params['dt']))
    bag.estimates = {(key[1] if isinstance(key, tuple) else int(round(key / dt_ns))): values
                     for key, values in estimates.items()}
    if recovery is not None:
        recovery.messages = []       # read: the counts say how many
    bag.recovery = recovery
    return bag


def _messages(path: Path, recovery):
    """``(topic, message type, CDR bytes)`` of every message, in log-time order: rosbags'
    reader for a closed bag, the recovered messages of an unclosed one."""
    if recovery is not None:
        for topic, msgtype, _, raw in recovery.messages:
            yield topic, msgtype, raw
        return
    with Reader(path) as reader:
        for conn, _, raw in reader.messages():
            yield conn.topic, conn.msgtype, raw


def _read_batch(stream, msg, live: dict, live_timing: dict, path: Path) -> None:
    """The rows of one record batch into `live` ({topic: {step: value}}) or, for a timing
    stream, `live_timing` ({node: [(step, values)]})."""
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
        live[topic].update((int(r[0]), float(r[j])) for r in rows)


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
        ``'end'``: ``'closed'`` (the recorder closed the bag after the rig's final status),
        ``'stopped'`` (the recorder closed the bag, but the run's end is not in it: no final
        status of the rig; the recorder was stopped by a signal, or lost the rig),
        ``'crashed'`` (never closed: recovered from the file, the recorder was killed) or
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
    run_ended = any(s['name'] == 'rig' and s.get('state') in ('done', 'aborted', 'failed')
                    for s in bag.statuses)
    out = {'steps': n_steps, 'duration_s': n_steps * dt,
           'messages': int(sum(bag.counts.values()))}
    held = f'{n_steps * dt:.3f} s ({n_steps} steps, {out["messages"]} messages)'
    if bag.recovery is not None:
        flush = next((float(s['flush_every_s']) for s in recorder if 'flush_every_s' in s),
                     FLUSH_EVERY_S)
        out.update(end='crashed', flush_every_s=flush, storage=bag.recovery.storage,
                   file_complete=bag.recovery.file_complete, cut=bag.recovery.end)
        out['note'] = (f'the recording ended in a crash (recorder killed, bag not closed): '
                       f'recovered {held}; at most the last {flush:g} s before the crash '
                       'is lost')
    elif closed and run_ended:
        out.update(end='closed', note=f'bag closed by the recorder: {held}')
    elif recorder:
        out.update(end='stopped', note='the recording was stopped before the run ended (bag '
                                       f"closed without the rig's final status): {held}")
    else:
        out.update(end='unknown', note=f'no recorder status in the bag: {held}')
    return out


def read_run(path) -> RunData:
    """Read a seft bag into a :class:`RunData` (the steps for which every signal exists).

    The parameters are ``BagSignals.params``; ``extra`` holds, besides ``'rig_final'`` and
    ``'counts'``, ``'node_params'`` (``{node: {parameter: value}}``, empty for a bag without
    node parameters), ``'param_sources'`` (``{parameter: node, 'run_parameters' or
    'default'}``), ``'parameter_mismatches'`` (one line per shared parameter on which the
    nodes disagree; empty when they agree), ``'recording'`` (how the recording ended and what
    it holds, :func:`recording_end`: a bag whose recorder was killed reads too, from its
    complete records), ``'wall_s'`` (the rig's wall time of the stepping
    [s], or None), ``'bag_lost_messages'`` (what the nodes published and the bag does not
    hold, from the recorder's closing status) and, for a real-time run, ``'timing_data'``
    (``BagSignals.timing``) and ``'timing'`` (its
    :func:`~seft_ros.analysis.timing.timing_summary`). A real-time run aborted into the
    rig's safe state ends at the abort (``abort_at_s`` of the rig's final status): the ramp
    after it is not part of the test. A bag that ends before the run did (no final status of
    the rig; the recorder killed or stopped) is a run cut short: not ``stable``, ended at its
    last complete step, with the reason ``'recorder: the recording ended in a crash (recorder
    killed)'`` (or ``'... was stopped before the run ended'``).

    Raises
    ------
    InputError
        As :func:`read_signals`, or the bag holds no complete step.
    """
    bag = read_signals(path)
    p = bag.params
    valve = p['rig_model'] == 'servohydraulic'
    needed = [s.name for s in (signals.GROUND_ACCELERATION, signals.REFERENCE_FORCE,
                               signals.MEASURED_FORCE, signals.DISPLACEMENT, signals.VELOCITY,
                               signals.ACCELERATION)]
    if valve:
        needed.append(signals.VALVE_COMMAND.name)
    n = 0
    while all(n in bag.samples[name] for name in needed):
        n += 1
    if n == 0:
        missing = [name for name in needed if not bag.samples[name]]
        first = [name for name in needed if 0 not in bag.samples[name]]
        raise InputError(f'{path}: the bag holds no complete step: '
                         + (f'no samples on {", ".join(missing)}' if missing else
                            f'step 0 missing on {", ".join(first)}'))

    def arr(name):
        d = bag.samples[name]
        return np.array([d[k] for k in range(n)])

    aborted = [s for s in bag.statuses if s.get('state') in ('aborted', 'failed')]
    rig_final = [s for s in bag.statuses
                 if s['name'] == 'rig' and s.get('state') in ('done', 'aborted', 'failed')]
    recording = recording_end(bag, n)
    final = rig_final[-1] if rig_final else {}
    dt = p['dt']
    abort_at_s = float(final['abort_at_s']) if 'abort_at_s' in final else None
    if abort_at_s is not None:
        # real time: the rig kept sampling its safe-state ramp after the abort
        n = max(1, min(n, int(round(abort_at_s / dt))))
    stable = not aborted
    reason = None
    if aborted:
        first = aborted[0]
        reason = first['message'] if first['name'] == 'rig' else (
            f"{first['name']}: {first['message']}")
    elif not rig_final and recording['end'] in ('crashed', 'stopped'):
        # the bag ends before the run did: the test is cut short at its last complete step
        stable = False
        reason = ('recorder: the recording ended in a crash (recorder killed)'
                  if recording['end'] == 'crashed' else
                  'recorder: the recording was stopped before the run ended')
    record_name = next((s.get('record') for s in bag.statuses
                        if s['name'] == 'ground_motion_publisher' and s.get('record')),
                       Path(str(p['record'])).stem)
    extra = {'rig_final': rig_final[-1] if rig_final else None, 'counts': bag.counts,
             'recording': recording,
             'node_params': bag.node_params, 'param_sources': bag.param_sources,
             'parameter_mismatches': bag.parameter_mismatches,
             'wall_s': float(final['wall_s']) if 'wall_s' in final else None}
    closed = [s for s in bag.statuses if s['name'] == 'recorder' and s.get('state') == 'closed']
    if closed and 'lost' in closed[-1]:
        extra['bag_lost_messages'] = int(closed[-1]['lost'])
    if p.get('mode') == 'realtime':
        extra['timing_data'] = bag.timing
        extra['timing'] = timing_summary(bag.timing)
    estimates = None
    if bag.estimates and all(k in bag.estimates for k in range(n)):
        names = list(bag.estimates[0])
        estimates = {name: np.array([bag.estimates[k].get(name, np.nan) for k in range(n)])
                     for name in names}
    return RunData(
        params=p, time_s=np.arange(n) * dt, ground_acceleration_m_s2=arr(needed[0]),
        reference_force_N=arr(needed[1]), measured_force_N=arr(needed[2]),
        displacement_m=arr(needed[3]), velocity_m_s=arr(needed[4]),
        acceleration_m_s2=arr(needed[5]),
        valve_command_V=arr(signals.VALVE_COMMAND.name) if valve else None, stable=stable,
        unstable_at_s=None if stable else (abort_at_s if abort_at_s is not None else n * dt),
        abort_reason=reason, record_name=record_name, source=str(path), extra=extra,
        estimates=estimates)
