"""The seft topics as plain data: name, ROS type name, scalar field, unit, publisher.

Imports no rclpy, so the ROS-free bag reader uses the same table as the nodes;
``seft_msgs_py.topics`` adds the message classes and QoS profiles to each entry.
"""

from dataclasses import dataclass

__all__ = [
    'Signal', 'CLOCK', 'GROUND_ACCELERATION', 'REFERENCE_FORCE', 'VALVE_COMMAND',
    'MEASURED_FORCE', 'DISPLACEMENT', 'VELOCITY', 'ACCELERATION', 'STATUS', 'RUN_PARAMETERS',
    'SIGNALS', 'SCALAR_SIGNALS', 'NODE_PARAMETERS', 'TIMING', 'TIMING_FIELDS', 'TIMING_TYPE',
    'timing_signal',
]


@dataclass(frozen=True)
class Signal:
    """One topic of the graph, without ROS types.

    Attributes
    ----------
    name : str
        Topic name.
    type_name : str
        ROS type name ``pkg/msg/Type`` (what a bag stores).
    field : str
        Dotted path of the scalar in the message ('' for non-scalar messages).
    unit : str
        SI unit of the scalar.
    publisher : str
        Publishing node.
    description : str
        What the signal is.
    """

    name: str
    type_name: str
    field: str
    unit: str
    publisher: str
    description: str


CLOCK = Signal('/clock', 'rosgraph_msgs/msg/Clock', 'clock', 's', 'rig',
               'Simulated time t_k = k*dt, every CLOCK_EVERY = 10 steps.')
GROUND_ACCELERATION = Signal(
    '/seft/ground_acceleration', 'geometry_msgs/msg/AccelStamped', 'accel.linear.x', 'm/s^2',
    'ground_motion_publisher',
    "Ground acceleration xg'' after scaling and resampling (published ahead of the clock).")
REFERENCE_FORCE = Signal(
    '/seft/reference_force', 'geometry_msgs/msg/WrenchStamped', 'wrench.force.x', 'N',
    'reference_force_builder',
    "Reference force f_r[k] = -(1+alpha) m xg''[k] - alpha m a_hat[k] (paper Eq. 5.3).")
VALVE_COMMAND = Signal(
    '/seft/valve_command', 'geometry_msgs/msg/Vector3Stamped', 'vector.x', 'V',
    'force_servo_controller', 'Servo-valve command u[k] (saturated at +/-valve_limit_V).')
MEASURED_FORCE = Signal(
    '/seft/measured_force', 'geometry_msgs/msg/WrenchStamped', 'wrench.force.x', 'N', 'rig',
    'Load-cell force f_m[k] on the specimen.')
DISPLACEMENT = Signal(
    '/seft/displacement', 'geometry_msgs/msg/PointStamped', 'point.x', 'm', 'rig',
    'Specimen displacement x[k] relative to the ground.')
VELOCITY = Signal(
    '/seft/velocity', 'geometry_msgs/msg/TwistStamped', 'twist.linear.x', 'm/s', 'rig',
    "Specimen velocity x'[k].")
ACCELERATION = Signal(
    '/seft/acceleration', 'geometry_msgs/msg/AccelStamped', 'accel.linear.x', 'm/s^2', 'rig',
    "Specimen acceleration x''[k] (accelerometer).")
STATUS = Signal(
    '/seft/status', 'diagnostic_msgs/msg/DiagnosticStatus', '', '', '(all)',
    'Node state (ready/running/done/aborted), progress and abort reasons.')
RUN_PARAMETERS = Signal(
    '/seft/run_parameters', 'std_msgs/msg/String', 'data', '', 'recorder',
    "The run's resolved parameters as JSON (written once into the bag).")

NODE_PARAMETERS = Signal(
    '/seft/node_parameters', 'std_msgs/msg/String', 'data', '', '(all)',
    'The parameters each node resolved, as JSON {"node": name, "parameters": {...}}, once at '
    'start (the graph refuses to start when shared values differ).')

#: Per-step timing record of a node (real-time mode), a sensor_msgs/JointState whose
#: ``name`` lists the fields and ``position`` holds their values (:data:`TIMING_FIELDS`).
TIMING_TYPE = 'sensor_msgs/msg/JointState'
#: Fields of a timing record, in order: period jitter (actual period - dt) [s], compute time
#: [s], age of the oldest input used, from its sample instant [s], missed deadline (0/1),
#: stale input (0/1: the rig's command of the previous sample, the controller's reference
#: force, the builder's ground acceleration had not arrived), loop latency (rig only: the
#: command computed from this sample arrived at the rig this long after the sample) [s].
TIMING_FIELDS = ('period_jitter_s', 'compute_s', 'input_age_s', 'missed_deadline', 'stale',
                 'loop_latency_s')
_TIMED = ('rig', 'force_servo_controller', 'reference_force_builder',
          'ground_motion_publisher')
TIMING = tuple(
    Signal(f'/seft/timing/{node}', TIMING_TYPE, 'position', 's', node,
           f'Real-time mode: per-step timing of {node} (fields: '
           + ', '.join(TIMING_FIELDS) + ').')
    for node in _TIMED)

#: Every topic, in report order.
SIGNALS = (CLOCK, GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
           DISPLACEMENT, VELOCITY, ACCELERATION, STATUS, RUN_PARAMETERS,
           NODE_PARAMETERS) + TIMING

#: The stamped scalar signals, one sample per control step.
SCALAR_SIGNALS = (GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
                  DISPLACEMENT, VELOCITY, ACCELERATION)


def timing_signal(node: str) -> Signal:
    """The timing topic of `node` (KeyError if the node publishes none)."""
    return {t.publisher: t for t in TIMING}[node]
