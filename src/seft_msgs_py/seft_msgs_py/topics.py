"""Topic names, message types and QoS of the seft node graph: the one place they live.

Every core signal is a scalar in a standard common_interfaces message with a header whose
stamp is the sample time ``t_k = k*dt`` (REP-103 SI units). The table :data:`TOPICS` is what
the nodes, the recorder, the bag reader and the README use.
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
from std_msgs.msg import String

__all__ = [
    'TopicSpec', 'TOPICS', 'CLOCK', 'GROUND_ACCELERATION', 'REFERENCE_FORCE', 'VALVE_COMMAND',
    'MEASURED_FORCE', 'DISPLACEMENT', 'VELOCITY', 'ACCELERATION', 'STATUS', 'RUN_PARAMETERS',
    'DATA_QOS', 'STATUS_QOS', 'CLOCK_QOS', 'MEASUREMENT_TOPICS', 'topic', 'FRAME_ID',
]

#: ``header.frame_id`` of every seft signal: the actuator axis (x: positive extension).
FRAME_ID = 'actuator'

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


CLOCK = TopicSpec('/clock', Clock, 'rosgraph_msgs/msg/Clock', 'clock', 's', 'rig',
                  'Simulated time t_k = k*dt (lockstep mode; use_sim_time).', CLOCK_QOS)
GROUND_ACCELERATION = TopicSpec(
    '/seft/ground_acceleration', AccelStamped, 'geometry_msgs/msg/AccelStamped',
    'accel.linear.x', 'm/s^2', 'ground_motion_publisher',
    "Ground acceleration xg'' after scaling and resampling (published ahead of the clock).",
    DATA_QOS)
REFERENCE_FORCE = TopicSpec(
    '/seft/reference_force', WrenchStamped, 'geometry_msgs/msg/WrenchStamped', 'wrench.force.x',
    'N', 'reference_force_builder',
    "Reference force f_r[k] = -(1+alpha) m xg''[k] - alpha m a_hat[k] (paper Eq. 5.3).",
    DATA_QOS)
VALVE_COMMAND = TopicSpec(
    '/seft/valve_command', Vector3Stamped, 'geometry_msgs/msg/Vector3Stamped', 'vector.x', 'V',
    'force_servo_controller', 'Servo-valve command u[k] (saturated at +/-valve_limit_V).',
    DATA_QOS)
MEASURED_FORCE = TopicSpec(
    '/seft/measured_force', WrenchStamped, 'geometry_msgs/msg/WrenchStamped', 'wrench.force.x',
    'N', 'rig', 'Load-cell force f_m[k] on the specimen.', DATA_QOS)
DISPLACEMENT = TopicSpec(
    '/seft/displacement', PointStamped, 'geometry_msgs/msg/PointStamped', 'point.x', 'm', 'rig',
    'Specimen displacement x[k] relative to the ground.', DATA_QOS)
VELOCITY = TopicSpec(
    '/seft/velocity', TwistStamped, 'geometry_msgs/msg/TwistStamped', 'twist.linear.x', 'm/s',
    'rig', "Specimen velocity x'[k].", DATA_QOS)
ACCELERATION = TopicSpec(
    '/seft/acceleration', AccelStamped, 'geometry_msgs/msg/AccelStamped', 'accel.linear.x',
    'm/s^2', 'rig', "Specimen acceleration x''[k] (accelerometer).", DATA_QOS)
STATUS = TopicSpec(
    '/seft/status', DiagnosticStatus, 'diagnostic_msgs/msg/DiagnosticStatus', '', '', '(all)',
    'Node state (ready/running/done/aborted), progress and abort reasons.', STATUS_QOS)
RUN_PARAMETERS = TopicSpec(
    '/seft/run_parameters', String, 'std_msgs/msg/String', 'data', '', 'recorder',
    "The run's resolved parameters as JSON (written once into the bag).", STATUS_QOS)

#: Every topic, in report order.
TOPICS = (CLOCK, GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
          DISPLACEMENT, VELOCITY, ACCELERATION, STATUS, RUN_PARAMETERS)

#: The rig's sensor topics, published together at every step.
MEASUREMENT_TOPICS = (MEASURED_FORCE, DISPLACEMENT, VELOCITY, ACCELERATION)

_BY_NAME = {t.name: t for t in TOPICS}


def topic(name: str) -> TopicSpec:
    """Return the :class:`TopicSpec` of a topic name (KeyError if it is not a seft topic)."""
    return _BY_NAME[name]
