"""Conversions between SI floats of the core and seft messages (integer ns at the boundary).

The functions work on rclpy message objects and, for reading, on any object with the same
attribute names (rosbags' deserialized messages), so the bag reader uses them too.
"""

import json
import struct

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock

from seft_msgs_py.topics import FRAME_ID, TopicSpec

__all__ = [
    'dt_to_ns', 'ns_to_stamp', 'stamp_to_ns', 'step_of', 'scalar_msg', 'scalar_value',
    'clock_msg', 'status_msg', 'status_values', 'STATE_READY', 'STATE_RUNNING', 'STATE_DONE',
    'STATE_ABORTED', 'STATE_CLOSED', 'STATE_FAILED', 'STATE_RECORDING', 'parameters_json',
    'ScalarMessage', 'ScalarReader', 'clock_ns_from_raw',
]

STATE_READY = 'ready'
STATE_RUNNING = 'running'
STATE_DONE = 'done'
STATE_ABORTED = 'aborted'
STATE_CLOSED = 'closed'
STATE_FAILED = 'failed'
STATE_RECORDING = 'recording'


def dt_to_ns(dt: float) -> int:
    """Sample period [s] as integer nanoseconds."""
    return int(round(dt * 1e9))


def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds as a ``builtin_interfaces/Time``."""
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def stamp_to_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (or anything with sec/nanosec) as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def step_of(stamp, dt_ns: int) -> int:
    """The sample index k of a stamp ``t_k = k*dt``."""
    return int(round(stamp_to_ns(stamp) / dt_ns))


def _set(msg, path: str, value: float) -> None:
    *parents, last = path.split('.')
    obj = msg
    for p in parents:
        obj = getattr(obj, p)
    setattr(obj, last, float(value))


def scalar_msg(spec: TopicSpec, stamp_ns: int, value: float):
    """Build the message of a scalar topic with ``header.stamp = stamp_ns``."""
    msg = spec.msg_type()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = FRAME_ID
    _set(msg, spec.field, value)
    return msg


class ScalarMessage:
    """One reusable message of a scalar topic: ``msg = writer(stamp_ns, value)``.

    Builds the message once and only sets its stamp and value per sample: about a third of
    the cost of :func:`scalar_msg` (rclpy message construction dominates a publish). rclpy
    serializes on ``publish``, so the same object can be published again at the next step.

    Parameters
    ----------
    spec : TopicSpec
        A scalar topic.
    """

    def __init__(self, spec: TopicSpec):
        self.msg = spec.msg_type()
        self.msg.header.frame_id = FRAME_ID
        *parents, self._attr = spec.field.split('.')
        obj = self.msg
        for p in parents:
            obj = getattr(obj, p)
        self._obj = obj
        self._stamp = self.msg.header.stamp

    def __call__(self, stamp_ns: int, value: float):
        """Set the stamp [ns] and the value [SI]; return the message."""
        self._stamp.sec = int(stamp_ns // 1_000_000_000)
        self._stamp.nanosec = int(stamp_ns % 1_000_000_000)
        setattr(self._obj, self._attr, float(value))
        return self.msg


_STAMP = struct.Struct('<iI')
_LENGTH = struct.Struct('<I')
_DOUBLE = struct.Struct('<d')


class ScalarReader:
    """Read ``(stamp [ns], value)`` from a serialized message of a scalar topic.

    For ``raw=True`` subscriptions: skips building an rclpy message object, the larger part
    of a Python subscription's cost. Every scalar field of the topic table is the first
    float64 after the ``std_msgs/Header``, so in little-endian CDR (XCDR1, the encapsulation
    header ``00 01``) it sits at the first 8-aligned payload offset after the frame id. Any
    other encoding is deserialized the ordinary way.

    Parameters
    ----------
    spec : TopicSpec
        A scalar topic.
    """

    def __init__(self, spec: TopicSpec):
        self.spec = spec

    def __call__(self, raw: bytes) -> tuple[int, float]:
        """``(header stamp [ns], scalar value [SI])`` of one serialized message."""
        if raw[0] == 0 and raw[1] == 1:
            sec, nanosec = _STAMP.unpack_from(raw, 4)
            end = 12 + _LENGTH.unpack_from(raw, 12)[0]        # payload offset after frame_id
            return (sec * 1_000_000_000 + nanosec,
                    _DOUBLE.unpack_from(raw, 4 + ((end + 7) & ~7))[0])
        msg = deserialize_message(raw, self.spec.msg_type)
        return stamp_to_ns(msg.header.stamp), scalar_value(self.spec, msg)


def clock_ns_from_raw(raw: bytes) -> int:
    """The time [ns] of a serialized ``rosgraph_msgs/Clock``."""
    if raw[0] == 0 and raw[1] == 1:
        sec, nanosec = _STAMP.unpack_from(raw, 4)
        return sec * 1_000_000_000 + nanosec
    return stamp_to_ns(deserialize_message(raw, Clock).clock)


def scalar_value(spec: TopicSpec, msg) -> float:
    """Read the scalar of a seft topic's message [SI unit of the topic]."""
    obj = msg
    for p in spec.field.split('.'):
        obj = getattr(obj, p)
    return float(obj)


def clock_msg(stamp_ns: int) -> Clock:
    """A ``/clock`` message."""
    return Clock(clock=ns_to_stamp(stamp_ns))


def status_msg(node: str, state: str, message: str = '', *, level: bytes | None = None,
               **values) -> DiagnosticStatus:
    """A node status report: ``name`` = node, ``values['state']`` = state, extra key/values.

    The level defaults to ERROR for aborted/failed, OK otherwise.
    """
    if level is None:
        level = (DiagnosticStatus.ERROR if state in (STATE_ABORTED, STATE_FAILED)
                 else DiagnosticStatus.OK)
    kv = [KeyValue(key='state', value=state)]
    kv += [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return DiagnosticStatus(level=level, name=node, message=message,
                            hardware_id='seft', values=kv)


def status_values(msg) -> dict[str, str]:
    """The key/values of a status message as a dict (``'state'`` included)."""
    return {kv.key: kv.value for kv in msg.values}


def parameters_json(params: dict) -> str:
    """The run's parameters as canonical JSON (sorted keys)."""
    return json.dumps(params, sort_keys=True)
