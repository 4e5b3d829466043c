"""Read a seft rosbag2 bag (written by the recorder node) back into a :class:`RunData`.

Uses rosbags (no rclpy): the run's parameters come from ``/seft/run_parameters``, the
signals from the scalar topics (one message per step, stamped ``t_k``), the abort reason
from the final ``/seft/status`` reports.
"""

import json
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError
from seft_ros.analysis.rundata import RunData

__all__ = ['read_run', 'BagSignals', 'read_signals']

_SCALARS = {s.name: s.field for s in (signals.CLOCK,) + signals.SCALAR_SIGNALS}


def _get(msg, path: str):
    for p in path.split('.'):
        msg = getattr(msg, p)
    return msg


class BagSignals:
    """The raw content of a seft bag.

    Attributes
    ----------
    params : dict
        Run parameters (JSON of ``/seft/run_parameters``).
    samples : dict of str -> dict of int -> float
        Per topic, the value of each step (stamp // dt); ``/clock`` maps step -> step.
    counts : dict of str -> int
        Messages per topic (duplicates included).
    statuses : list of dict
        Every status report: ``name``, ``message`` and its key/values.
    """

    def __init__(self, params, samples, counts, statuses):
        self.params = params
        self.samples = samples
        self.counts = counts
        self.statuses = statuses


def read_signals(path) -> BagSignals:
    """Read every seft topic of the bag at `path`.

    Raises
    ------
    InputError
        No bag there, not a seft bag (no run parameters), or unreadable.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f'{path}: no such bag')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    samples = {name: {} for name in _SCALARS}
    counts = {}
    statuses = []
    params = None
    try:
        with Reader(path) as reader:
            for conn, _, raw in reader.messages():
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
                if conn.topic == signals.RUN_PARAMETERS.name:
                    msg = typestore.deserialize_cdr(raw, conn.msgtype)
                    params = json.loads(msg.data)
                elif conn.topic == signals.STATUS.name:
                    msg = typestore.deserialize_cdr(raw, conn.msgtype)
                    entry = {kv.key: kv.value for kv in msg.values}
                    entry.update(name=msg.name, message=msg.message)
                    statuses.append(entry)
                elif conn.topic in _SCALARS:
                    msg = typestore.deserialize_cdr(raw, conn.msgtype)
                    if conn.topic == signals.CLOCK.name:
                        stamp, value = msg.clock, None
                    else:
                        stamp, value = msg.header.stamp, float(_get(msg, _SCALARS[conn.topic]))
                    samples[conn.topic][stamp.sec * 1_000_000_000 + stamp.nanosec] = value
    except InputError:
        raise
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the bag: {exc}') from None
    if params is None:
        raise InputError(f'{path}: not a seft bag (no /seft/run_parameters message)')
    try:
        params = parameters.resolve({k: v for k, v in params.items()
                                     if k in parameters.defaults()}, where=str(path))
    except parameters.ParameterError as exc:
        raise InputError(str(exc)) from None
    dt_ns = int(round(params['dt'] * 1e9))
    by_step = {name: {int(round(ns / dt_ns)): v for ns, v in vals.items()}
               for name, vals in samples.items()}
    return BagSignals(params, by_step, counts, statuses)


def read_run(path) -> RunData:
    """Read a seft bag into a :class:`RunData` (the steps for which every signal exists).

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
        raise InputError(f'{path}: the bag holds no complete step')

    def arr(name):
        d = bag.samples[name]
        return np.array([d[k] for k in range(n)])

    aborted = [s for s in bag.statuses if s.get('state') in ('aborted', 'failed')]
    rig_final = [s for s in bag.statuses
                 if s['name'] == 'rig' and s.get('state') in ('done', 'aborted', 'failed')]
    stable = not aborted
    reason = None
    if aborted:
        first = aborted[0]
        reason = first['message'] if first['name'] == 'rig' else (
            f"{first['name']}: {first['message']}")
    record_name = next((s.get('record') for s in bag.statuses
                        if s['name'] == 'ground_motion_publisher' and s.get('record')),
                       Path(str(p['record'])).stem)
    dt = p['dt']
    return RunData(
        params=p, time_s=np.arange(n) * dt, ground_acceleration_m_s2=arr(needed[0]),
        reference_force_N=arr(needed[1]), measured_force_N=arr(needed[2]),
        displacement_m=arr(needed[3]), velocity_m_s=arr(needed[4]),
        acceleration_m_s2=arr(needed[5]),
        valve_command_V=arr(signals.VALVE_COMMAND.name) if valve else None, stable=stable,
        unstable_at_s=None if stable else n * dt, abort_reason=reason,
        record_name=record_name, source=str(path),
        extra={'rig_final': rig_final[-1] if rig_final else None, 'counts': bag.counts})
