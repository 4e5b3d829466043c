"""The seft topics as plain data: name, ROS type name, scalar field, unit, publisher.

Imports no rclpy, so the ROS-free bag reader uses the same table as the nodes;
``seft_msgs_py.topics`` adds the message classes and QoS profiles to each entry.
"""

from dataclasses import dataclass

__all__ = [
    'Signal', 'CLOCK', 'GROUND_ACCELERATION', 'REFERENCE_FORCE', 'VALVE_COMMAND',
    'MEASURED_FORCE', 'DISPLACEMENT', 'VELOCITY', 'ACCELERATION', 'STATUS', 'RUN_PARAMETERS',
    'SIGNALS', 'SCALAR_SIGNALS', 'NODE_PARAMETERS', 'TIMING', 'TIMING_FIELDS', 'TIMING_TYPE',
    'timing_signal', 'MEASUREMENT', 'MEASUREMENT_FIELDS', 'RecordStream', 'RECORD_STREAMS',
    'RECORD_TYPE', 'RECORD_ROWS', 'BAG_SIGNALS', 'record_streams_of', 'ESTIMATES',
    'record_signal', 'LINK', 'STATE_READY', 'STATE_RUNNING', 'STATE_DONE', 'STATE_ABORTED',
    'STATE_CLOSED', 'STATE_FAILED', 'STATE_RECORDING', 'FINAL_STATES', 'CLOCK_EVERY',
]

#: The rig publishes /clock every this many steps (``seft_msgs_py.topics`` says why).
CLOCK_EVERY = 10

#: The states of a node's ``/seft/status`` report (``DiagnosticStatus.values['state']``).
STATE_READY = 'ready'
STATE_RUNNING = 'running'
STATE_DONE = 'done'
STATE_ABORTED = 'aborted'
STATE_CLOSED = 'closed'
STATE_FAILED = 'failed'
STATE_RECORDING = 'recording'
#: The states that end a node's run.
FINAL_STATES = (STATE_DONE, STATE_ABORTED, STATE_FAILED)


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

LINK = Signal(
    '/seft/link', 'std_msgs/msg/String', 'data', '', 'seft_runner',
    "Several hosts: the links as the reference host (the recorder's) measured them, JSON "
    '(round trip p50/p99/max and clock offset per host, the emulation, the playout delay and '
    'preview chosen), every 2 s.')

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

#: Fields of the rig's live measurement message, in order (SI units as named).
MEASUREMENT_FIELDS = ('measured_force_N', 'displacement_m', 'velocity_m_s', 'acceleration_m_s2')
#: The rig's sensor readings of one sample in one live message (``name`` lists
#: :data:`MEASUREMENT_FIELDS`, ``position`` holds their values): the builder and the controller
#: take one message a step instead of four. The bag holds them as the four sensor topics.
MEASUREMENT = Signal(
    '/seft/measurement', 'sensor_msgs/msg/JointState', 'position', '', 'rig',
    'Live: the sensor readings of sample k in one message (name: '
    + ', '.join(MEASUREMENT_FIELDS) + '); recorded as the four sensor topics.')
#: The compensator's online estimates in effect for each reference force (``adaptive``,
#: ``ats``): ``name`` lists them (the predictor's ``ESTIMATES``), ``position`` their values.
ESTIMATES = Signal(
    '/seft/estimates', 'sensor_msgs/msg/JointState', 'position', '',
    'reference_force_builder',
    "The compensator's online estimates in effect for f_r[k] ('adaptive': mass_kg, "
    "damping_N_s_per_m, stiffness_N_per_m, tau_s, gain, with adaptive_loop 'data' also "
    "loop_gain, loop_delay_s, loop_change, with 'model_latency' loop_latency_s; 'ats': a0, "
    "a1, a2), by name.")


@dataclass(frozen=True)
class RecordStream:
    """A node's record batches: what it published (or timed) for the bag, in table rows.

    A node publishes a ``std_msgs/Float64MultiArray`` on ``name`` every :data:`RECORD_ROWS`
    rows (and at its end): ``layout.dim[0]`` = ('step', rows; ``'step#<seal>'`` in a run with
    a token, ``seft_msgs_py.provenance``), ``layout.dim[1]`` = the column
    labels joined by commas ('step' then ``columns``), ``data`` = the rows, row-major. The
    recorder writes every row back as the per-sample messages the bag holds (same topics,
    types and stamps as if it had subscribed to each of them), so it receives one message
    per stream every ten steps instead of one per topic per step.

    Attributes
    ----------
    name : str
        Live topic of the batches.
    node : str
        Publishing node.
    columns : tuple of str
        After the step: bag topic names of scalar signals, or :data:`TIMING_FIELDS` for
        a timing stream.
    timing : bool
        The rows are the node's timing records (``/seft/timing/<node>`` in the bag).
    fields_topic : str
        If set, every row is one ``sensor_msgs/JointState`` on this bag topic, ``name`` = the
        columns, which the publisher chooses (``columns`` is empty; the batch's label names
        them): the compensator's estimates.
    """

    name: str
    node: str
    columns: tuple[str, ...]
    timing: bool = False
    fields_topic: str = ''

    @property
    def labels(self) -> str:
        """The column labels of ``layout.dim[1]``."""
        return ','.join(('step',) + self.columns)

    def columns_of(self, msg) -> tuple[str, ...]:
        """The columns after 'step' of one batch of this stream (a deserialized
        ``Float64MultiArray``, rclpy's or rosbags'), checked against its layout.

        Raises
        ------
        ValueError
            The batch's labels are not this stream's (for a fields stream: do not start with
            'step'), or its data is not whole rows; the message names what was expected.
        """
        dims = msg.layout.dim
        label = dims[1].label if len(dims) == 2 else ''
        if self.fields_topic:
            columns = tuple(label.split(',')[1:])
            ok = label.startswith('step,')
        else:
            columns, ok = self.columns, label == self.labels
        if not ok or len(msg.data) % (1 + len(columns)):
            raise ValueError(f'{self.name}: expected a batch with columns '
                             f'{self.labels if not self.fields_topic else "step,..."}, got '
                             f'{label or "no layout"}')
        return columns


#: ROS type of the record batches.
RECORD_TYPE = 'std_msgs/msg/Float64MultiArray'
#: Rows of a record batch: a node publishes its batch every this many steps. A node killed
#: (SIGKILL) loses at most this many unpublished rows of each of its streams.
RECORD_ROWS = 10
RECORD_STREAMS = (
    RecordStream('/seft/record/rig', 'rig', (MEASURED_FORCE.name, DISPLACEMENT.name,
                                             VELOCITY.name, ACCELERATION.name)),
    RecordStream('/seft/record/ground_motion_publisher', 'ground_motion_publisher',
                 (GROUND_ACCELERATION.name,)),
    RecordStream('/seft/record/reference_force_builder', 'reference_force_builder',
                 (REFERENCE_FORCE.name,)),
    RecordStream('/seft/record/force_servo_controller', 'force_servo_controller',
                 (VALVE_COMMAND.name,)),
) + tuple(RecordStream(f'/seft/record/{node}/timing', node, TIMING_FIELDS, timing=True)
          for node in _TIMED) + (
    RecordStream('/seft/record/reference_force_builder/estimates', 'reference_force_builder',
                 (), fields_topic=ESTIMATES.name),
)
def record_signal(stream: RecordStream) -> Signal:
    """The live topic of a record stream's batches."""
    return Signal(stream.name, RECORD_TYPE, 'data', '', stream.node,
                  f'Live: record batches of {stream.node} for the recorder (columns '
                  f'{stream.labels}).')


_RECORD = tuple(record_signal(r) for r in RECORD_STREAMS)


def record_streams_of(node: str) -> tuple[RecordStream, ...]:
    """The record streams `node` publishes (data first, then timing, then estimates)."""
    return tuple(r for r in RECORD_STREAMS if r.node == node)


#: What the recorder writes into a bag: every topic but /clock (its value is every sample's
#: header stamp) and the live-only measurement and record batches.
BAG_SIGNALS = (GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
               DISPLACEMENT, VELOCITY, ACCELERATION, STATUS, RUN_PARAMETERS,
               NODE_PARAMETERS) + TIMING + (ESTIMATES,)
#: Every topic, in report order.
SIGNALS = ((CLOCK,) + BAG_SIGNALS[:7] + (MEASUREMENT,) + BAG_SIGNALS[7:] + _RECORD)

#: The stamped scalar signals, one sample per control step.
SCALAR_SIGNALS = (GROUND_ACCELERATION, REFERENCE_FORCE, VALVE_COMMAND, MEASURED_FORCE,
                  DISPLACEMENT, VELOCITY, ACCELERATION)


def timing_signal(node: str) -> Signal:
    """The timing topic of `node` (KeyError if the node publishes none)."""
    return {t.publisher: t for t in TIMING}[node]
