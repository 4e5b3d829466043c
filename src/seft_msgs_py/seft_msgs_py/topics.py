"""Topic names, message types and QoS of the seft node graph: the one place they live.

Names, type names, fields and units come from the ROS-free table ``seft_msgs_py.signals``;
this module adds the rclpy message classes and the QoS profiles.

Every core signal is a scalar in a standard common_interfaces message with a header whose
stamp is the sample time ``t_k = k*dt`` (REP-103 SI units). The table :data:`TOPICS` is what
the nodes, the recorder, the bag reader and the docs use.
"""

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import (
    AccelStamped,
    PointStamped,
    TwistStamped,
    Vector3Stamped,
    WrenchStamped,
)
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from seft_msgs_py import signals as sig

__all__ = [
    'TopicSpec', 'TOPICS', 'CLOCK', 'GROUND_ACCELERATION', 'REFERENCE_FORCE', 'VALVE_COMMAND',
    'MEASURED_FORCE', 'DISPLACEMENT', 'VELOCITY', 'ACCELERATION', 'STATUS', 'RUN_PARAMETERS',
    'DATA_QOS', 'STATUS_QOS', 'CLOCK_QOS', 'MEASUREMENT_TOPICS', 'topic', 'FRAME_ID',
    'NODE_PARAMETERS', 'TIMING', 'timing_topic', 'CLOCK_EVERY', 'MEASUREMENT', 'RECORD',
    'BAG_TOPICS', 'record_topic', 'SCALAR_TOPICS', 'ESTIMATES', 'spec_for', 'LINK',
]

#: ``header.frame_id`` of every seft signal: the actuator axis (x: positive extension).
FRAME_ID = 'actuator'
#: The rig publishes /clock every this many steps (``signals.CLOCK_EVERY``): the ground-motion
#: publisher, ahead of it by ``preview_steps`` + CLOCK_EVERY - 1, then wakes up once for that
#: many samples (on two cores every wake-up of a process costs about 0.1 ms of CPU, more than
#: the work it does).
CLOCK_EVERY = sig.CLOCK_EVERY

#: Lockstep data topics: every sample matters, so reliable, and transient-local with a deep
#: history so that a subscriber matched a little late still receives the first samples.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Status/progress reports of the nodes (and the run's parameters), late joiners included.
STATUS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /clock as rclpy's time source subscribes to it (reliable, volatile).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the graph.

    Attributes
    ----------
    name : str
        Topic name.
    msg_type : type
        rclpy message class.
    type_name : str
        ROS type name ``pkg/msg/Type`` (what a bag stores).
    field : str
        Where the scalar lives in the message ('' for non-scalar messages).
    unit : str
        SI unit of the scalar.
    publisher : str
        Publishing node.
    description : str
        What the signal is.
    qos : QoSProfile
    """

    name: str
    msg_type: type
    type_name: str
    field: str
    unit: str
    publisher: str
    description: str
    qos: QoSProfile


def _spec(signal: sig.Signal, msg_type: type, qos: QoSProfile) -> TopicSpec:
    return TopicSpec(signal.name, msg_type, signal.type_name, signal.field, signal.unit,
                     signal.publisher, signal.description, qos)


CLOCK = _spec(sig.CLOCK, Clock, CLOCK_QOS)
GROUND_ACCELERATION = _spec(sig.GROUND_ACCELERATION, AccelStamped, DATA_QOS)
REFERENCE_FORCE = _spec(sig.REFERENCE_FORCE, WrenchStamped, DATA_QOS)
VALVE_COMMAND = _spec(sig.VALVE_COMMAND, Vector3Stamped, DATA_QOS)
MEASURED_FORCE = _spec(sig.MEASURED_FORCE, WrenchStamped, DATA_QOS)
DISPLACEMENT = _spec(sig.DISPLACEMENT, PointStamped, DATA_QOS)
VELOCITY = _spec(sig.VELOCITY, TwistStamped, DATA_QOS)
ACCELERATION = _spec(sig.ACCELERATION, AccelStamped, DATA_QOS)
STATUS = _spec(sig.STATUS, DiagnosticStatus, STATUS_QOS)
RUN_PARAMETERS = _spec(sig.RUN_PARAMETERS, String, STATUS_QOS)

NODE_PARAMETERS = _spec(sig.NODE_PARAMETERS, String, STATUS_QOS)
#: The links of a run over several hosts (the runners', recorded).
LINK = _spec(sig.LINK, String, STATUS_QOS)
#: Per-node timing topics (real-time mode), in the order of ``signals.TIMING``.
TIMING = tuple(_spec(s, JointState, DATA_QOS) for s in sig.TIMING)

#: The compensator's online estimates per reference force (bag; live in record batches).
ESTIMATES = _spec(sig.ESTIMATES, JointState, DATA_QOS)
#: The rig's sensor readings of a sample in one live message (the bag: the four topics).
MEASUREMENT = _spec(sig.MEASUREMENT, JointState, DATA_QOS)
#: The nodes' record batches for the recorder (``signals.RECORD_STREAMS``), keyed by name.
RECORD = {r.name: TopicSpec(r.name, Float64MultiArray, sig.RECORD_TYPE, 'data', '', r.node,
                            f'Live: record batches of {r.node} (columns {r.labels}).',
                            DATA_QOS)
          for r in sig.RECORD_STREAMS}

#: What the recorder writes into a bag (``signals.BAG_SIGNALS``).
BAG_TOPICS = (GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
              DISPLACEMENT, VELOCITY, ACCELERATION, STATUS, RUN_PARAMETERS,
              NODE_PARAMETERS) + TIMING + (ESTIMATES,)
#: Every topic, in report order.
TOPICS = (CLOCK,) + BAG_TOPICS[:7] + (MEASUREMENT,) + BAG_TOPICS[7:] + tuple(RECORD.values())

#: The stamped scalar topics, one sample per control step (``signals.SCALAR_SIGNALS``).
SCALAR_TOPICS = (GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
                 DISPLACEMENT, VELOCITY, ACCELERATION)
#: The rig's sensor topics of the bag (live, the rig publishes them as :data:`MEASUREMENT`).
MEASUREMENT_TOPICS = (MEASURED_FORCE, DISPLACEMENT, VELOCITY, ACCELERATION)

_BY_NAME = {t.name: t for t in TOPICS}


def topic(name: str) -> TopicSpec:
    """Return the :class:`TopicSpec` of a topic name (KeyError if it is not a seft topic)."""
    return _BY_NAME[name]


def record_topic(stream: sig.RecordStream) -> TopicSpec:
    """The :class:`TopicSpec` of a record stream (a study stream, or one of a structure's
    graph, :mod:`seft_msgs_py.graph`)."""
    if stream.name in RECORD:
        return RECORD[stream.name]
    return spec_for(sig.record_signal(stream))


def timing_topic(node: str) -> TopicSpec:
    """The :class:`TopicSpec` of `node`'s timing topic (KeyError if it publishes none)."""
    return {t.publisher: t for t in TIMING}[node]


#: The message class of each type name the graph uses.
_MSG_TYPES = {t.type_name: t.msg_type for t in TOPICS}


def spec_for(signal: sig.Signal) -> TopicSpec:
    """The :class:`TopicSpec` of any topic of a run's graph (``seft_msgs_py.graph``): a study
    topic, or one in a rig's namespace (its QoS is that of the study topic it scopes)."""
    if signal.name in _BY_NAME:
        return _BY_NAME[signal.name]
    base = '/' + signal.name.split('/', 2)[2] if signal.name.count('/') >= 2 else signal.name
    qos = _BY_NAME[base].qos if base in _BY_NAME else DATA_QOS
    return TopicSpec(signal.name, _MSG_TYPES[signal.type_name], signal.type_name, signal.field,
                     signal.unit, signal.publisher, signal.description, qos)
