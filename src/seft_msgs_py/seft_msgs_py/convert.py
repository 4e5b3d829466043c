"""Conversions between SI floats of the core and seft messages (integer ns at the boundary).

The functions work on rclpy message objects and, for reading, on any object with the same
attribute names (rosbags' deserialized messages), so the bag reader uses them too.
"""

import json
import struct
from typing import Callable

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock

from seft_msgs_py.provenance import STATUS_ID

# the node states live in the ROS-free table (re-exported here)
from seft_msgs_py.signals import (
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RECORDING,
    STATE_RUNNING,
    STATUS,
)
from seft_msgs_py.topics import FRAME_ID, TopicSpec

__all__ = [
    'dt_to_ns', 'ns_to_stamp', 'stamp_to_ns', 'step_of', 'scalar_msg', 'scalar_value',
    'clock_msg', 'status_msg', 'status_values', 'STATE_READY', 'STATE_RUNNING', 'STATE_DONE',
    'STATE_ABORTED', 'STATE_CLOSED', 'STATE_FAILED', 'STATE_RECORDING', 'parameters_json',
    'ScalarMessage', 'ScalarReader', 'clock_ns_from_raw', 'SerializedStamped', 'FieldsReader',
    'frame_id_of_raw', 'FRAME_AT',
]

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
    frame_id : str
        ``header.frame_id`` (default ``'actuator'``; a run's sealed frame id,
        :class:`~seft_msgs_py.provenance.RunSeal`).
    """

    def __init__(self, spec: TopicSpec, frame_id: str = FRAME_ID):
        self.msg = spec.msg_type()
        self.msg.header.frame_id = frame_id
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
#: Where ``header.frame_id``'s characters start in a serialized stamped message [bytes]: the
#: encapsulation (4), the stamp (8) and the string's length (4), little-endian CDR.
FRAME_AT = 16


def frame_id_of_raw(raw: bytes, msg_type) -> bytes:
    """``header.frame_id`` of a serialized stamped message, as bytes (no terminating NUL);
    read in place from little-endian CDR, else from the deserialized message."""
    if raw[0] == 0 and raw[1] == 1 and len(raw) >= FRAME_AT:
        n = _LENGTH.unpack_from(raw, 12)[0]
        return bytes(raw[FRAME_AT:FRAME_AT + max(n - 1, 0)])
    return deserialize_message(raw, msg_type).header.frame_id.encode('utf-8', 'replace')


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


#: Marker values located in a serialized template to find where its float64 fields lie.
_MARKERS = tuple(-1.2345678901234567e-299 * (i + 1) for i in range(16))


def _markers(n: int) -> tuple:
    """`n` distinct marker values (more than :data:`_MARKERS` holds: a structure's state of
    nine computational DOFs has 28 values)."""
    if n <= len(_MARKERS):
        return _MARKERS[:n]
    return tuple(-1.2345678901234567e-299 * (i + 1) for i in range(n))


_TYPESTORE = None


def _exact(msg) -> bytes:
    """``serialize_message(msg)`` as exact, deterministic bytes.

    rclpy's serializer leaves the alignment padding uninitialized (other bytes in every
    process) and, for some types, returns a buffer longer than the message (a
    ``sensor_msgs/JointState`` with empty sequences: 8 bytes more), which strict CDR readers
    refuse (rosbags: "CDR message size mismatch"). The bytes are read back with rosbags
    (its reader skips padding; the shortest readable end is the message's) and written again
    by rosbags' serializer, zero padding included, as a bag written by rosbags holds them.
    """
    global _TYPESTORE
    from rosbags.serde import SerdeError
    from rosbags.typesys import Stores, get_typestore
    if _TYPESTORE is None:
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    module = type(msg).__module__.split('.')[0]
    type_name = f'{module}/msg/{type(msg).__name__}'
    raw = serialize_message(msg)
    for length in range(len(raw), max(4, len(raw) - 16), -1):
        try:
            obj = _TYPESTORE.deserialize_cdr(raw[:length], type_name)
        except SerdeError:
            continue
        return bytes(_TYPESTORE.serialize_cdr(obj, type_name))
    raise ValueError(f'SerializedStamped: cannot read back a serialized {type_name}')


class SerializedStamped:
    """Serialized bytes of a stamped message, with its stamp and float64 fields set per sample.

    Serializes `msg` once with marker values in its float64 fields, finds where they lie, and
    then only writes the stamp and the values into a copy of those bytes (about 0.5 us against
    11-16 us for ``rclpy.serialization.serialize_message``). A publisher publishes the bytes
    (``Publisher.publish`` takes serialized messages); the recorder writes them to the bag.
    The layout is that of little-endian CDR (XCDR1, encapsulation ``00 01``), which rclpy
    produces on every platform it runs on here; anything else raises.

    A run's seal (:class:`~seft_msgs_py.provenance.RunSeal`) goes into the frame id: the
    template is made with the run's frame id, and an HMAC seal, which changes with every
    message, is written in place (`seal` of ``__call__``).

    Parameters
    ----------
    msg : rclpy message
        A stamped message (``header`` first), with everything but the values set.
    set_values : callable(msg, values)
        Writes `n` float64 values into `msg`.
    n : int
        Number of values (>= 1).

    Raises
    ------
    ValueError
        The encoding is not little-endian CDR, or a value's place is not unique.
    """

    def __init__(self, msg, set_values: Callable, n: int):
        markers = _markers(n)
        set_values(msg, markers)
        raw = _exact(msg)
        if raw[:2] != b'\x00\x01':
            raise ValueError('SerializedStamped: expected little-endian CDR')
        self.offsets = []
        for m in markers:
            packed = _DOUBLE.pack(m)
            at = raw.find(packed)
            if at < 0 or raw.find(packed, at + 1) >= 0:
                raise ValueError('SerializedStamped: a value has no unique place')
            self.offsets.append(at)
        set_values(msg, (0.0,) * n)
        self.template = _exact(msg)
        contiguous = all(b - a == 8 for a, b in zip(self.offsets, self.offsets[1:]))
        self._block = struct.Struct(f'<{n}d') if contiguous else None
        #: Where a seal is written in the frame id (after ``'actuator#'``) [bytes].
        self.seal_at = FRAME_AT + len(FRAME_ID) + 1

    @classmethod
    def scalar(cls, spec: TopicSpec, frame_id: str = FRAME_ID) -> 'SerializedStamped':
        """The template of a scalar topic (:class:`ScalarMessage`'s message)."""
        writer = ScalarMessage(spec, frame_id)
        return cls(writer.msg, lambda msg, v: writer(0, v[0]), 1)

    @classmethod
    def fields(cls, msg_type, names, frame_id: str = FRAME_ID) -> 'SerializedStamped':
        """A ``sensor_msgs/JointState``-like message: ``name`` = `names`, ``position`` = values."""
        msg = msg_type()
        msg.header.frame_id = frame_id
        msg.name = list(names)

        def set_values(m, values):
            m.position = [float(v) for v in values]
        return cls(msg, set_values, len(names))

    def __call__(self, stamp_ns: int, values, seal: bytes | None = None) -> bytes:
        """The serialized message of one sample: stamp [ns] and values (sequence of n); a
        `seal` (ASCII, the length of the template's) written after ``'actuator#'``."""
        b = bytearray(self.template)
        _STAMP.pack_into(b, 4, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
        if seal is not None:
            b[self.seal_at:self.seal_at + len(seal)] = seal
        if self._block is not None:
            self._block.pack_into(b, self.offsets[0], *values)
        else:
            for at, v in zip(self.offsets, values):
                _DOUBLE.pack_into(b, at, v)
        return bytes(b)


class FieldsReader:
    """Read ``(stamp [ns], values)`` from a serialized message of a named-fields topic
    (``name`` = the fields, ``position`` = the values, as :meth:`SerializedStamped.fields`).

    A message laid out like the template (a frame id of the same length, whatever its
    characters: the run's seal is checked apart; the same names) is read in place; any other
    (another length of frame id, names in another order) is deserialized and its values are
    taken by name.

    Parameters
    ----------
    msg_type : type
        The rclpy message class (``sensor_msgs.msg.JointState``).
    names : sequence of str
        The fields, in the order the values are returned.
    frame_id : str
        A frame id of the length the run's messages have (default ``'actuator'``).

    Raises
    ------
    KeyError
        (on a call) A field is missing from a message.
    """

    def __init__(self, msg_type, names, frame_id: str = FRAME_ID):
        self.msg_type = msg_type
        self.names = tuple(names)
        t = SerializedStamped.fields(msg_type, names, frame_id)
        self._start = t.offsets[0]
        self._length = t.template[12:FRAME_AT]
        self._after = FRAME_AT + len(frame_id)        # the frame id's NUL, then the names
        self._suffix = t.template[self._after:self._start]
        self._block = struct.Struct(f'<{len(self.names)}d')

    def __call__(self, raw: bytes) -> tuple[int, tuple]:
        """``(header stamp [ns], values)`` of one serialized message."""
        if (raw[:2] == b'\x00\x01' and raw[12:FRAME_AT] == self._length
                and raw[self._after:self._start] == self._suffix):
            sec, nanosec = _STAMP.unpack_from(raw, 4)
            return sec * 1_000_000_000 + nanosec, self._block.unpack_from(raw, self._start)
        msg = deserialize_message(raw, self.msg_type)
        by_name = dict(zip(msg.name, msg.position))
        return stamp_to_ns(msg.header.stamp), tuple(float(by_name[n]) for n in self.names)


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
               seal=None, **values) -> DiagnosticStatus:
    """A node status report: ``name`` = node, ``values['state']`` = state, extra key/values.

    The level defaults to ERROR for aborted/failed, OK otherwise. With `seal` (a
    :class:`~seft_msgs_py.provenance.RunSeal`) the report carries the run's seal in its
    ``hardware_id`` (``'seft#' + seal``; :meth:`~seft_msgs_py.provenance.RunSeal.seal_status`),
    without it the plain ``'seft'`` (a node by hand, ``seft simulate``'s bag).
    """
    if level is None:
        level = (DiagnosticStatus.ERROR if state in (STATE_ABORTED, STATE_FAILED)
                 else DiagnosticStatus.OK)
    kv = [KeyValue(key='state', value=state)]
    kv += [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    msg = DiagnosticStatus(level=level, name=node, message=message,
                           hardware_id=STATUS_ID, values=kv)
    return msg if seal is None else seal.seal_status(msg, STATUS.name)


def status_values(msg) -> dict[str, str]:
    """The key/values of a status message as a dict (``'state'`` included)."""
    return {kv.key: kv.value for kv in msg.values}


def parameters_json(params: dict) -> str:
    """The run's parameters as canonical JSON (sorted keys)."""
    return json.dumps(params, sort_keys=True)
