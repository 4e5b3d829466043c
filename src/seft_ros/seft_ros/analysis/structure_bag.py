"""Read the bag of a structure test (several rigs) back into a
:class:`~seft_ros.analysis.rundata.RunData`.

Uses rosbags (no rclpy). The graph of the run (:mod:`seft_msgs_py.graph`: each rig's topics
in its namespace, the builders' computational state) comes from the run parameters the
recorder wrote first into the bag; each rig's signals from its topics
(``/<rig>/seft/measured_force``, ...), the computational degrees of freedom's state from
``/seft/structure_state`` (the central builder's, or the first rig's builder's), the end of
the run from the status reports. A bag whose recorder was killed reads too, from its complete
records (:mod:`seft_ros.analysis.bag_recovery`).

The steps analysed are those from 0 up to the first step a signal of any rig lacks; a
real-time run aborted into the rigs' safe state ends at the first rig's abort.
"""

import json
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.graph import Graph
from seft_ros.analysis.bag import _messages, bag_lost_messages, rig_end_step
from seft_ros.analysis.bag_recovery import is_unclosed_bag, recover_bag
from seft_ros.analysis.rundata import RigData, RunData
from seft_ros.analysis.timing import node_timings, timing_row, timing_summary

__all__ = ['read_structure_run', 'is_structure_bag', 'run_parameters']

_FINAL = ('done', 'aborted', 'failed')


def run_parameters(path) -> dict | None:
    """The run parameters the recorder wrote into the bag at `path` (None if none).

    Raises
    ------
    InputError
        No bag there, or unreadable.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f'{path}: no such bag')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        recovery = recover_bag(path) if is_unclosed_bag(path) else None
        for topic, msgtype, raw in _messages(path, recovery):
            if topic == signals.RUN_PARAMETERS.name:
                params = json.loads(typestore.deserialize_cdr(raw, msgtype).data)
                return params if isinstance(params, dict) else None
    except InputError:
        raise
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    return None


def is_structure_bag(path) -> bool:
    """Whether the bag at `path` records a structure test (its run parameters hold one)."""
    params = run_parameters(path)
    return bool(params) and params.get('structure', 'none') not in ('none', '', None)


def _first_abort(aborted: list[dict]) -> dict | None:
    """The report of the node that aborted first, of the 'aborted'/'failed' reports in bag
    order: the first whose message does not pass on another's (a node ending on another's
    abort reports ``'<that node>: <its message>'``, and the bag may hold it first)."""
    names = {s['name'] for s in aborted}
    for s in aborted:
        if not any(s['message'].startswith(f'{name}: ') for name in names - {s['name']}):
            return s
    return aborted[0] if aborted else None


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def read_structure_run(path) -> RunData:
    """Read the bag of a structure test.

    Parameters
    ----------
    path : str or Path
        Bag directory (closed, or left unclosed by a killed recorder).

    Returns
    -------
    RunData
        Every rig's signals (a :class:`~seft_ros.analysis.rundata.RunData` each, with the rig's
        own parameters as its
        node published them) and the computational degrees of freedom's state over the
        analysed steps; ``extra`` holds ``'node_params'``, ``'parameter_mismatches'``,
        ``'rig_finals'`` (each rig's final status), ``'counts'``, ``'recovered'`` (the bag
        was not closed), ``'node_statuses'`` (every status report, in order),
        ``'bag_lost_messages'`` (what the nodes published and the bag does not hold, from
        the recorder's 'closed' report; absent without one) and, in real time,
        ``'timing_data'`` and ``'timing'`` per node.

    Raises
    ------
    InputError
        No bag, not a structure test's bag, parameters out of range, or no complete step
        (the message names the topics without samples).
    """
    path = Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    raw_by_topic: dict[str, list] = {}
    params, node_params, statuses, counts, link = None, {}, [], {}, None
    recovery = None
    try:
        if is_unclosed_bag(path):
            recovery = recover_bag(path)
        for topic, msgtype, raw in _messages(path, recovery):
            counts[topic] = counts.get(topic, 0) + 1
            if topic == signals.RUN_PARAMETERS.name:
                params = json.loads(typestore.deserialize_cdr(raw, msgtype).data)
            elif topic == signals.NODE_PARAMETERS.name:
                doc = json.loads(typestore.deserialize_cdr(raw, msgtype).data)
                node_params[str(doc['node'])] = dict(doc['parameters'])
            elif topic == signals.LINK.name:
                link = json.loads(typestore.deserialize_cdr(raw, msgtype).data)
            elif topic == signals.STATUS.name:
                msg = typestore.deserialize_cdr(raw, msgtype)
                entry = {kv.key: kv.value for kv in msg.values}
                entry.update(name=msg.name, message=msg.message)
                statuses.append(entry)
            else:
                raw_by_topic.setdefault(topic, []).append((msgtype, raw))
    except InputError:
        raise
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    if not isinstance(params, dict):
        raise InputError(f'{path}: not a seft bag (no /seft/run_parameters message)')
    try:
        params = parameters.resolve({k: v for k, v in params.items()
                                     if k in parameters.defaults()}, where=str(path))
        graph = Graph.from_parameters(params)
    except ParameterError as exc:
        raise InputError(str(exc)) from None
    if not graph.is_structure:
        raise InputError(f'{path}: not a structure test (read it with read_run)')
    dt = params['dt']
    dt_ns = int(round(dt * 1e9))
    fields = {s.name: s.field for s in graph.bag_signals() if s.field not in ('', 'data')}

    def scalar(topic):
        out = {}
        for msgtype, raw in raw_by_topic.get(topic, ()):
            msg = typestore.deserialize_cdr(raw, msgtype)
            value = msg
            for part in fields[topic].split('.'):
                value = getattr(value, part)
            out.setdefault(int(round(_stamp(msg) / dt_ns)), float(value))
        return out

    per_rig = {}
    needed = [signals.GROUND_ACCELERATION.name]
    for r in graph.rigs:
        names = {'fr': graph.reference_force(r).name}
        names.update(zip(('fm', 'x', 'v', 'a'), (s.name for s in graph.sensors(r))))
        if graph.has_controller(r):
            names['u'] = graph.valve_command(r).name
        per_rig[r] = names
        needed += list(names.values())
    samples = {topic: scalar(topic) for topic in needed}
    n = 0
    while all(n in samples[t] for t in needed):
        n += 1
    if n == 0:
        missing = [t for t in needed if not samples[t]]
        raise InputError(f'{path}: the bag holds no complete step: '
                         + (f'no samples on {", ".join(missing)}' if missing
                            else 'step 0 missing on '
                            + ', '.join(t for t in needed if 0 not in samples[t])))
    rig_finals = {r: next((s for s in reversed(statuses) if s['name'] == r
                           and s.get('state') in _FINAL), None) for r in graph.rig_nodes()}
    aborts = [float(f['abort_at_s']) for f in rig_finals.values() if f and 'abort_at_s' in f]
    if aborts:
        n = max(1, min(n, int(round(min(aborts) / dt))))
    aborted = [s for s in statuses if s.get('state') in ('aborted', 'failed')]
    stable, reason, first = not aborted, None, _first_abort(aborted)
    if first is not None:
        reason = f"{first['name']}: {first['message']}"
    elif not all(rig_finals.values()):
        stable = False
        reason = ('recorder: the recording ended in a crash (recorder killed)'
                  if recovery is not None else
                  'recorder: the recording was stopped before the run ended')
    t = np.arange(n) * dt

    def arr(topic):
        d = samples[topic]
        return np.array([d[k] for k in range(n)], dtype=float)

    ag = arr(signals.GROUND_ACCELERATION.name)
    from seft_ros.core.structure import test_setup as structure_setup
    try:
        setup = structure_setup(params)
    except ParameterError as exc:
        raise InputError(f'{path}: {exc}') from None
    record_name = next((s.get('record') for s in statuses
                        if s['name'] == 'ground_motion_publisher' and s.get('record')),
                       Path(str(params['record'])).stem)
    # lockstep: the rig that aborted first says where the run ended, even where the bag lacks
    # a node's last samples (a node that ended without them: lost, or past DRAIN_TIMEOUT_S),
    # as read_run does
    end_step = (rig_end_step(rig_finals.get(first['name']) or {}, None, dt)
                if first is not None and not aborts else None)
    unstable_at_s = None if stable else (min(aborts) if aborts else max(n, end_step or 0) * dt)
    rigs = {}
    for j, r in enumerate(graph.rigs):
        names = per_rig[r]
        own = node_params.get(f'{r}/rig')
        rig_p = dict(setup.rig_params[r])
        if own:
            try:
                rig_p.update(parameters.resolve(
                    {k: v for k, v in own.items() if k in parameters.defaults()},
                    where=f'{path}: node {r}/rig'))
            except ParameterError as exc:
                raise InputError(str(exc)) from None
        rig_p['alpha'] = float(setup.substructures.alpha[j])
        rigs[r] = RigData(
            params=rig_p, reference_force_N=arr(names['fr']), measured_force_N=arr(names['fm']),
            displacement_m=arr(names['x']), velocity_m_s=arr(names['v']),
            acceleration_m_s2=arr(names['a']),
            valve_command_V=arr(names['u']) if 'u' in names else None,
            extra={'rig_final': rig_finals[f'{r}/rig']})
    computational = _structure_state(raw_by_topic, graph, typestore, dt_ns, n)
    extra = {'node_params': node_params, 'rig_finals': rig_finals, 'counts': counts,
             'node_statuses': statuses,
             'parameter_mismatches': parameters.shared_mismatches(node_params),
             'recovered': recovery is not None,
             'abort_node': first['name'] if first is not None else None}
    if link is not None:
        extra['link'] = link
    lost = bag_lost_messages(statuses)
    if lost is not None:
        extra['bag_lost_messages'] = lost
    if params.get('mode') == 'realtime':
        rows = {}
        for stream in graph.record_streams():
            if stream.timing:
                for msgtype, raw in raw_by_topic.get(graph.timing_topic(stream), ()):
                    rows.setdefault(stream.node, []).append(
                        timing_row(typestore.deserialize_cdr(raw, msgtype)))
        extra['timing_data'] = node_timings(rows, dt)
        extra['timing'] = timing_summary(extra['timing_data'])
    return RunData(
        params=params, rigs=rigs, time_s=t, ground_acceleration_m_s2=ag,
        computational=computational, stable=stable, unstable_at_s=unstable_at_s,
        abort_reason=reason, record_name=record_name, source=str(path), extra=extra)


def _structure_state(raw_by_topic, graph: Graph, typestore, dt_ns: int, n: int) -> dict:
    """The computational DOFs' state over the first `n` steps (NaN where not recorded) from
    the first builder's ``structure_state`` topic."""
    topic = next((s.name for s in graph.bag_signals()
                  if s.name.endswith('/seft/structure_state')), None)
    values: dict[str, np.ndarray] = {}
    for msgtype, raw in raw_by_topic.get(topic, ()):
        msg = typestore.deserialize_cdr(raw, msgtype)
        k = int(round(_stamp(msg) / dt_ns))
        if k >= n:
            continue
        for name, value in zip(msg.name, msg.position):
            values.setdefault(name, np.full(n, np.nan))[k] = float(value)
    return values
