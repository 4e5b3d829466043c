"""Write a run computed in one process (``seft simulate --bag``) as the bag the graph records.

Same topics, types, stamps and parameter messages as the recorder node writes
(``seft_ros.nodes.recorder``) for the run's graph (:class:`seft_msgs_py.graph.Graph`: the
study's one rig in the root namespace, a structure's rigs each in its namespace), through
rosbags (no rclpy), so that ``seft compare`` and ``seft identify`` read a simulated run and a
recorded one alike:

- ``/seft/run_parameters``: the run's parameters as JSON (sorted keys), at t = 0;
- ``/seft/node_parameters``: for each node of the run's graph and the recorder, the schema
  parameters it declares (``parameters.specs_for_node``) with the run's values (a
  structure's rig and controller nodes: their rig's);
- one message per sample on each scalar topic of every rig (``graph.bag_signals``: the
  ground motion, the reference force, the valve command only on the servohydraulic rig,
  the sensors), stamped ``t_k = k dt`` (log time = the stamp, frame ``actuator``),
  ``/seft/estimates`` with an online compensator and a structure's computational state
  (``/[<rig>/]seft/structure_state``);
- ``/seft/status``: each node 'ready' (the ground-motion publisher with its record name and
  length), then the final reports: 'done' or 'aborted' with the reason (the aborting node's
  report first, then the rigs', as in the graph), and the recorder's 'closed' (nothing
  lost).

What the graph's bag has and this one does not: the progress reports ('running',
'recording') and, in the graph, the ground acceleration ``preview_steps`` past an abort.
"""

import json
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, rig_contract, signals
from seft_msgs_py.errors import InputError
from seft_msgs_py.graph import RIG_NODES, STRUCTURE_STATE, Graph, scoped, split_qualified
from seft_ros.analysis.rundata import RunData
from seft_ros.core.structure import test_setup

__all__ = ['write_run_bag', 'FRAME_ID']

#: Header frame of every stamped message (``seft_msgs_py.topics.FRAME_ID``).
FRAME_ID = 'actuator'


def _builders(ts):
    t = ts.types
    v3 = t['geometry_msgs/msg/Vector3']

    def header(ns):
        return t['std_msgs/msg/Header'](
            stamp=t['builtin_interfaces/msg/Time'](sec=ns // 1_000_000_000,
                                                   nanosec=ns % 1_000_000_000),
            frame_id=FRAME_ID)

    zero = v3(x=0.0, y=0.0, z=0.0)
    return {
        'geometry_msgs/msg/AccelStamped': lambda ns, v: t['geometry_msgs/msg/AccelStamped'](
            header=header(ns), accel=t['geometry_msgs/msg/Accel'](linear=v3(x=v, y=0.0, z=0.0),
                                                                  angular=zero)),
        'geometry_msgs/msg/WrenchStamped': lambda ns, v: t['geometry_msgs/msg/WrenchStamped'](
            header=header(ns), wrench=t['geometry_msgs/msg/Wrench'](
                force=v3(x=v, y=0.0, z=0.0), torque=zero)),
        'geometry_msgs/msg/Vector3Stamped': lambda ns, v: t['geometry_msgs/msg/Vector3Stamped'](
            header=header(ns), vector=v3(x=v, y=0.0, z=0.0)),
        'geometry_msgs/msg/PointStamped': lambda ns, v: t['geometry_msgs/msg/PointStamped'](
            header=header(ns), point=t['geometry_msgs/msg/Point'](x=v, y=0.0, z=0.0)),
        'geometry_msgs/msg/TwistStamped': lambda ns, v: t['geometry_msgs/msg/TwistStamped'](
            header=header(ns), twist=t['geometry_msgs/msg/Twist'](
                linear=v3(x=v, y=0.0, z=0.0), angular=zero)),
        'joint_state': lambda ns, names, values: t['sensor_msgs/msg/JointState'](
            header=header(ns), name=list(names), position=np.asarray(values, dtype=float),
            velocity=np.zeros(0), effort=np.zeros(0)),
    }


def write_run_bag(run: RunData, path, *, storage: str | None = None) -> Path:
    """Write `run` to a new rosbag2 bag at `path`, as the recorder node would.

    The run's graph (:class:`~seft_msgs_py.graph.Graph`) gives the layout: the study's test
    its one rig in the root namespace (``/seft/...``), a structure test each rig in its
    namespace (``/<rig>/seft/...``) and the computational state on the builder's
    ``structure_state`` topic (a sample whose state is not finite, the last, not written);
    each rig node publishes its rig's parameters (the run's with its ``rigs`` section). An
    aborted run's rigs report 'aborted', the one that stopped the run with the reason, the
    others passing it on (``'<node>: <reason>'``, ``ended_by``), as in the graph.
    :func:`~seft_ros.analysis.bag.read_run` of the bag gives the run back: its parameters,
    every sample (bit for bit), the outcome (the abort reason of a node other than the
    study's rig prefixed with ``'<node>: '``) and the estimates.

    Parameters
    ----------
    run : RunData
        A run of ``seft_ros.core.experiment.simulate`` or
        ``seft_ros.core.experiment.simulate``
        (``extra['abort_node']`` names the node that stopped an aborted run; default the
        first rig).
    path : str or Path
        Bag directory; must not exist.
    storage : {'mcap', 'sqlite3'}, optional
        Storage plugin (default: the run's ``bag_storage``).

    Returns
    -------
    Path
        The bag directory.

    Raises
    ------
    InputError
        `path` exists already.
    ParameterError
        The run's structure is invalid.
    """
    path = Path(path)
    if path.exists():
        raise InputError(f'{path}: the bag exists already; expected a new directory name')
    p = dict(run.params)
    storage = storage or p.get('bag_storage', 'mcap')
    graph = Graph.from_parameters(p)
    setup = test_setup(p)
    ts = get_typestore(Stores.ROS2_JAZZY)
    build = _builders(ts)
    t = ts.types
    dt_ns = int(round(float(p['dt']) * 1e9))
    n = run.n_steps
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    timing = {graph.timing_topic(s) for s in graph.record_streams() if s.timing}
    topics = [s for s in graph.bag_signals() if s.name not in timing]
    state_topic = next((s.fields_topic for s in graph.record_streams()
                        if s.fields_topic.endswith(STRUCTURE_STATE.name)), None)
    rig_nodes = graph.rig_nodes()
    end_ns = max(n - 1, 0) * dt_ns
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {s.name: writer.add_connection(s.name, s.type_name, typestore=ts)
                 for s in topics}

        def write(name, ns, msg):
            if name not in conns:       # a rig's estimates in its namespace
                conns[name] = writer.add_connection(name, msg.__msgtype__, typestore=ts)
            writer.write(conns[name], ns, ts.serialize_cdr(msg, msg.__msgtype__))

        def status(node, state, message='', **values):
            kv = [t['diagnostic_msgs/msg/KeyValue'](key='state', value=state)]
            kv += [t['diagnostic_msgs/msg/KeyValue'](key=k, value=str(v))
                   for k, v in values.items()]
            level = 2 if state in ('aborted', 'failed') else 0
            return t['diagnostic_msgs/msg/DiagnosticStatus'](
                level=level, name=node, message=message, hardware_id='seft', values=kv)

        string = t['std_msgs/msg/String']
        write(signals.RUN_PARAMETERS.name, 0, string(data=json.dumps(p, sort_keys=True)))
        nodes = ('recorder',) + graph.nodes()
        for node in nodes:
            rig, kind = split_qualified(node)
            own = setup.rig_params[rig] if graph.rig_of(node) is not None and kind in RIG_NODES \
                else p
            values = {s.name: own[s.name] for s in parameters.specs_for_node(kind)}
            write(signals.NODE_PARAMETERS.name, 0, string(data=json.dumps(
                {'node': node, 'parameters': values}, sort_keys=True)))
        for node in nodes:
            extra = ({'n_steps': n, 'record': run.record_name}
                     if node == 'ground_motion_publisher' else {})
            write(signals.STATUS.name, 0, status(node, 'ready', **extra))
        series = [(signals.GROUND_ACCELERATION, run.ground_acceleration_m_s2)]
        estimates = []
        for r in graph.rigs:
            rig = run.rigs[r]
            sensors = graph.sensors(r)
            series += [(graph.reference_force(r), rig.reference_force_N),
                       (sensors[0], rig.measured_force_N), (sensors[1], rig.displacement_m),
                       (sensors[2], rig.velocity_m_s), (sensors[3], rig.acceleration_m_s2)]
            if graph.has_controller(r) and rig.valve_command_V is not None:
                series.append((graph.valve_command(r), rig.valve_command_V))
            if rig.estimates:
                estimates.append((scoped(signals.ESTIMATES.name, r), rig.estimates))
        state = [(name, np.asarray(values, dtype=float))
                 for name, values in run.computational.items()]
        for k in range(n):
            ns = k * dt_ns
            for sig, values in series:
                write(sig.name, ns, build[sig.type_name](ns, float(values[k])))
            for topic, values in estimates:
                write(topic, ns, build['joint_state'](ns, list(values),
                                                      [values[m][k] for m in values]))
            # the computational state of the sample: its recorded entries (an OpenSees
            # part's step time has none at sample 0; nothing at the last sample)
            row = [(name, float(v[k])) for name, v in state if np.isfinite(v[k])] \
                if state_topic else ()
            if row:
                write(state_topic, ns, build['joint_state'](ns, [name for name, _ in row],
                                                            [value for _, value in row]))
        wall = run.extra.get('wall_s')
        final = {'step': n, 'n_steps': n, 'time_s': f'{n * float(p["dt"]):.6f}',
                 'published': n, 'mode': p.get('mode', 'lockstep'),
                 rig_contract.CONTRACT_KEY: rig_contract.CONTRACT}
        if wall is not None:
            final['wall_s'] = f'{float(wall):.3f}'
        stopped_by = None if run.stable else (run.extra.get('abort_node') or graph.master)
        # what the builder said during the run, its count of the samples at a sensor's range
        # and its specimen check's ratios (the first builder's final status holds every rig's)
        builder = next(node for node in graph.nodes() if node.endswith('reference_force_builder'))
        for warning in run.extra.get('warnings') or ():
            write(signals.STATUS.name, end_ns, status(builder, 'running', warning,
                                                      warning=warning))
        counted = {key: json.dumps(run.extra[key], sort_keys=True)
                   for key in ('sensor_range', 'specimen_ratios') if run.extra.get(key)}
        if run.stable:
            for node in rig_nodes:
                write(signals.STATUS.name, end_ns, status(node, 'done', f'completed {n} steps',
                                                          **final))
        else:
            reason = run.abort_reason or 'aborted'
            if stopped_by not in rig_nodes:
                write(signals.STATUS.name, end_ns, status(
                    stopped_by, 'aborted', reason, **(counted if stopped_by == builder else {})))
            for node in rig_nodes:
                if node == stopped_by:
                    write(signals.STATUS.name, end_ns, status(node, 'aborted', reason, **final))
                else:
                    write(signals.STATUS.name, end_ns, status(
                        node, 'aborted', f'{stopped_by}: {reason}', **final,
                        ended_by=stopped_by))
        for node in graph.nodes():
            if node not in rig_nodes and node != stopped_by:
                write(signals.STATUS.name, end_ns, status(
                    node, 'done', published=n, **(counted if node == builder else {})))
        write(signals.STATUS.name, end_ns, status('recorder', 'closed', f'bag {path} closed',
                                                  incomplete='', lost=0))
    return path
