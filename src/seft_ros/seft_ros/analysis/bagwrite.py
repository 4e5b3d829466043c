"""Write a run computed in one process (``seft simulate --bag``) as the bag the graph records.

Same topics, types, stamps and parameter messages as the recorder node writes
(``seft_ros.nodes.recorder``), through rosbags (no rclpy), so that ``seft compare`` and
``seft identify`` read a simulated run and a recorded one alike:

- ``/seft/run_parameters``: the run's parameters as JSON (sorted keys), at t = 0;
- ``/seft/node_parameters``: for each node of the run's graph and the recorder, the schema
  parameters it declares (``parameters.specs_for_node``) with the run's values;
- one message per sample on each scalar topic of ``seft_msgs_py.signals.SCALAR_SIGNALS``
  (the valve command only on the servohydraulic rig), stamped ``t_k = k dt`` (log time = the
  stamp, frame ``actuator``), and ``/seft/estimates`` with an online compensator;
- ``/seft/status``: each node 'ready' (the ground-motion publisher with its record name and
  length), then the final reports: 'done' or 'aborted' with the reason (the aborting node's
  report first, then the rig's, as in the graph), and the recorder's 'closed' (nothing lost).

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
from seft_ros.analysis.rundata import RunData

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

    Parameters
    ----------
    run : RunData
        A run of ``seft_ros.core.experiment.simulate`` (``extra['abort_node']`` names the
        node that stopped an aborted run; default the rig).
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
    """
    path = Path(path)
    if path.exists():
        raise InputError(f'{path}: the bag exists already; expected a new directory name')
    p = dict(run.params)
    storage = storage or p.get('bag_storage', 'mcap')
    ts = get_typestore(Stores.ROS2_JAZZY)
    build = _builders(ts)
    t = ts.types
    dt_ns = int(round(float(p['dt']) * 1e9))
    n = run.n_steps
    valve = p['rig_model'] == 'servohydraulic'
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    topics = [s for s in signals.BAG_SIGNALS if not s.name.startswith('/seft/timing/')]
    end_ns = max(n - 1, 0) * dt_ns
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {s.name: writer.add_connection(s.name, s.type_name, typestore=ts)
                 for s in topics}

        def write(name, ns, msg):
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
        graph = parameters.graph_nodes(p['rig_model'])
        for node in ('recorder',) + graph:
            values = {s.name: p[s.name] for s in parameters.specs_for_node(node)}
            write(signals.NODE_PARAMETERS.name, 0, string(data=json.dumps(
                {'node': node, 'parameters': values}, sort_keys=True)))
        for node in ('recorder',) + graph:
            extra = ({'n_steps': n, 'record': run.record_name}
                     if node == 'ground_motion_publisher' else {})
            write(signals.STATUS.name, 0, status(node, 'ready', **extra))
        series = [(signals.GROUND_ACCELERATION, run.ground_acceleration_m_s2),
                  (signals.REFERENCE_FORCE, run.reference_force_N),
                  (signals.MEASURED_FORCE, run.measured_force_N),
                  (signals.DISPLACEMENT, run.displacement_m),
                  (signals.VELOCITY, run.velocity_m_s),
                  (signals.ACCELERATION, run.acceleration_m_s2)]
        if valve and run.valve_command_V is not None:
            series.append((signals.VALVE_COMMAND, run.valve_command_V))
        names = list(run.estimates) if run.estimates else []
        for k in range(n):
            ns = k * dt_ns
            for sig, values in series:
                write(sig.name, ns, build[sig.type_name](ns, float(values[k])))
            if names:
                write(signals.ESTIMATES.name, ns, build['joint_state'](
                    ns, names, [run.estimates[m][k] for m in names]))
        wall = run.extra.get('wall_s')
        final = {'step': n, 'n_steps': n, 'time_s': f'{n * float(p["dt"]):.6f}',
                 'published': n, 'mode': p.get('mode', 'lockstep'),
                 rig_contract.CONTRACT_KEY: rig_contract.CONTRACT}
        if wall is not None:
            final['wall_s'] = f'{float(wall):.3f}'
        if run.stable:
            write(signals.STATUS.name, end_ns, status('rig', 'done', f'completed {n} steps',
                                                      **final))
        else:
            node = run.extra.get('abort_node') or 'rig'
            reason = run.abort_reason or 'aborted'
            if node != 'rig':
                write(signals.STATUS.name, end_ns, status(node, 'aborted', reason))
                reason = f'{node}: {reason}'
            write(signals.STATUS.name, end_ns, status('rig', 'aborted', reason, **final))
        stopped_by = None if run.stable else run.extra.get('abort_node')
        for node in graph[:-1]:
            if node != stopped_by:
                write(signals.STATUS.name, end_ns, status(node, 'done', published=n))
        write(signals.STATUS.name, end_ns, status('recorder', 'closed', f'bag {path} closed',
                                                  incomplete='', lost=0))
    return path
