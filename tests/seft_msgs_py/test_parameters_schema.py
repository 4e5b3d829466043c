"""Tests of the parameter schema, the message conversions and the step synchronizer."""

from dataclasses import fields
import json
import math
import re

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from seft_msgs_py import parameters
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    FieldsReader,
    ScalarMessage,
    ScalarReader,
    SerializedStamped,
    clock_msg,
    clock_ns_from_raw,
    dt_to_ns,
    ns_to_stamp,
    parameters_json,
    scalar_msg,
    scalar_value,
    stamp_to_ns,
    status_msg,
    status_values,
    step_of,
)
from seft_msgs_py.errors import InputError, ParameterError, RigLimitError, SeftError
from seft_msgs_py.parameters import SCHEMA, resolve, spec, specs_for_node, validate_value
from seft_msgs_py.sync import StepSync
from seft_msgs_py.topics import (
    BAG_TOPICS,
    CLOCK,
    ESTIMATES,
    FRAME_ID,
    MEASUREMENT,
    MEASUREMENT_TOPICS,
    NODE_PARAMETERS,
    RECORD,
    RUN_PARAMETERS,
    SCALAR_TOPICS,
    STATUS,
    TIMING,
    TOPICS,
    timing_topic,
    topic,
)
from seft_plant_sim.servohydraulic import ServoHydraulicParams

#: Topics that carry one stamped scalar: every topic but /clock, status, parameters, timing,
#: the live measurement and the record batches.
OTHER = ((CLOCK, STATUS, RUN_PARAMETERS, NODE_PARAMETERS, MEASUREMENT, ESTIMATES) + TIMING
         + tuple(RECORD.values()))
assert SCALAR_TOPICS == tuple(t for t in TOPICS if t not in OTHER)


def bad(text):
    """``pytest.raises(ParameterError)`` for exactly this message."""
    return pytest.raises(ParameterError, match='^' + re.escape(text) + '$')


# -- validate_value / resolve ----------------------------------------------------------------

@pytest.mark.parametrize('name, value, message', [
    # float: range, exclusive minimum, maximum
    ('alpha', -1, 'parameter alpha=-1: expected float >= 0 <= 100'),
    ('alpha', 100.5, 'parameter alpha=100.5: expected float >= 0 <= 100'),
    ('dt', 1e-5, 'parameter dt=1e-05: expected float > 1e-05 <= 1'),
    ('dt', 0, 'parameter dt=0: expected float > 1e-05 <= 1'),
    ('mass_kg', 0.0, 'parameter mass_kg=0.0: expected float > 0'),
    ('saturation_abort_fraction', 0.0,
     'parameter saturation_abort_fraction=0.0: expected float > 0 <= 1'),
    # wrong types: bool and text are not numbers
    ('alpha', True, 'parameter alpha=True: expected float >= 0 <= 100'),
    ('alpha', '1', "parameter alpha='1': expected float >= 0 <= 100"),
    ('alpha', None, 'parameter alpha=None: expected float >= 0 <= 100'),
    ('noise_seed', False, 'parameter noise_seed=False: expected int >= 0'),
    # non-finite
    ('mass_kg', math.inf, 'parameter mass_kg=inf: expected float > 0'),
    ('alpha', math.nan, 'parameter alpha=nan: expected float >= 0 <= 100'),
    ('amplitude_N', -math.inf, 'parameter amplitude_N=-inf: expected float >= 0'),
    # int: no fraction, range
    ('n_steps', 3.5, 'parameter n_steps=3.5: expected int >= 0'),
    ('n_steps', -1, 'parameter n_steps=-1: expected int >= 0'),
    ('n_steps', math.inf, 'parameter n_steps=inf: expected int >= 0'),
    ('preview_steps', 0, 'parameter preview_steps=0: expected int >= 1 <= 100000'),
    ('recorder_window_steps', 1901,
     'parameter recorder_window_steps=1901: expected int >= 0 <= 1900'),
    # text: choices (case matters), type, non-empty
    ('rig_model', 'foo', "parameter rig_model='foo': expected one of 'delay', 'servohydraulic', "
     "'state_space', 'actuator'"),
    ('bag_storage', 'MCAP', "parameter bag_storage='MCAP': expected one of 'mcap', 'sqlite3'"),
    ('record', 5, 'parameter record=5: expected str'),
    ('record', '', 'parameter record: expected a non-empty text'),
])
def test_validate_value_errors(name, value, message):
    with bad(message):
        validate_value(name, value)


@pytest.mark.parametrize('value', [1, 0, 'true', None])
def test_bool_parameter_takes_only_bool(value):
    flags = [s for s in SCHEMA if isinstance(s.default, bool)]
    if not flags:
        pytest.skip('no bool parameter in the schema')
    name = flags[0].name
    assert validate_value(name, True) is True and validate_value(name, False) is False
    with bad(f'parameter {name}={value!r}: expected bool'):
        validate_value(name, value)


def test_validate_value_where_prefix():
    with bad('run.yaml: parameter tau_s=0: expected float > 0 <= 1'):
        validate_value('tau_s', 0, where='run.yaml')


def test_unknown_parameter():
    # the closest names of the schema (within 0.1 of the closest's similarity), or the
    # reference; a where prefix as for a bad value
    with bad("unknown parameter 'alpah' (did you mean 'alpha'?)"):
        validate_value('alpah', 1.0)
    with bad("run.yaml: unknown parameter 'alpah' (did you mean 'alpha'?)"):
        validate_value('alpah', 1.0, where='run.yaml')
    with bad("unknown parameter 'alpah' (did you mean 'alpha'?)"):
        spec('alpah')
    with bad("unknown parameter 'foo' (the parameter reference lists them)"):
        resolve({'foo': 1})
    with bad("unknown parameter 'bouc_wen_exponent' (did you mean 'bouc_wen_n' or "
             "'bouc_wen_beta'?)"):
        spec('bouc_wen_exponent')


@pytest.mark.parametrize('name, value, expected', [
    ('alpha', 1, 1.0),                 # int accepted for a float, returned as float
    ('dt', 1, 1.0),                    # the maximum is inclusive
    ('dt', 1.0000001e-5, 1.0000001e-5),
    ('alpha', 0, 0.0),                 # the minimum is inclusive unless exclusive
    ('n_steps', 3.0, 3),               # an integral float for an int, returned as int
    ('n_steps', 0, 0),
    ('rig_model', 'delay', 'delay'),
    ('record', 'some/file.AT2', 'some/file.AT2'),
])
def test_validate_value_accepts_and_coerces(name, value, expected):
    got = validate_value(name, value)
    assert got == expected and type(got) is type(expected)


def test_every_default_validates_to_itself():
    assert len({s.name for s in SCHEMA}) == len(SCHEMA)
    for s in SCHEMA:
        got = validate_value(s.name, s.default)
        assert got == s.default and type(got) is type(s.default), s.name
        assert s.type_name in ('bool', 'int', 'float', 'str'), s.name
        assert set(s.nodes) <= set(parameters.NODES), s.name
        assert s.description and s.description[-1] == '.', s.name


def test_resolve_merges_in_order_and_stops_at_the_first_bad_value():
    p = resolve({'alpha': 1, 'rig_model': 'delay'})
    assert p == dict(parameters.defaults(), alpha=1.0, rig_model='delay')
    assert type(p['alpha']) is float
    assert resolve([('alpha', 2), ('alpha', 3)])['alpha'] == 3.0
    assert resolve() == parameters.defaults()
    with bad('cfg: parameter mass_kg=-1: expected float > 0'):
        resolve([('alpha', 1), ('mass_kg', -1), ('dt', 0)], where='cfg')


def test_specs_for_node():
    assert specs_for_node('recorder') == list(SCHEMA)
    ctrl = [s.name for s in specs_for_node('force_servo_controller')]
    assert {'dt', 'valve_limit_V', 'saturation_window_s', 'saturation_abort_fraction',
            'rig_model'} <= set(ctrl)
    # the 'velocity_feedback' design derives its gains from the nominal hydraulics
    assert 'piston_area_m2' in ctrl and 'force_controller' in ctrl
    assert 'valve_time_constant_s' not in ctrl
    assert 'piston_area_m2' in [s.name for s in specs_for_node('rig')]
    assert specs_for_node('nobody') == []


def test_servohydraulic_defaults_equal_the_schema():
    names = [f.name for f in fields(ServoHydraulicParams)]
    assert len(names) == 10
    defaults = ServoHydraulicParams()
    assert ServoHydraulicParams.from_parameters(parameters.defaults()) == defaults
    for name in names:
        assert 'rig' in spec(name).nodes, name
        if name == 'valve_flow_gain_m3_per_s_V':    # schema 0: the rig calibration's k_q
            assert spec(name).default == 0.0
            assert defaults.valve_flow_gain_m3_per_s_V == pytest.approx(5.3e-5 * 4.4482216)
            continue
        assert getattr(defaults, name) == spec(name).default, name


def test_error_types():
    for cls in (InputError, ParameterError, RigLimitError):
        assert issubclass(cls, SeftError)
    assert issubclass(SeftError, Exception)


# -- convert ---------------------------------------------------------------------------------

@pytest.mark.parametrize('ns, sec, nanosec', [
    (0, 0, 0),
    (1, 0, 1),
    (999_999_999, 0, 999_999_999),
    (1_000_000_000, 1, 0),
    (1_234_567_890_123, 1234, 567_890_123),
    (2_147_483_647_999_999_999, 2_147_483_647, 999_999_999),   # the largest int32 second
])
def test_stamp_round_trip(ns, sec, nanosec):
    stamp = ns_to_stamp(ns)
    assert isinstance(stamp, Time)
    assert (stamp.sec, stamp.nanosec) == (sec, nanosec)
    assert stamp_to_ns(stamp) == ns


def test_dt_to_ns_and_step_of():
    assert dt_to_ns(0.002) == 2_000_000
    assert dt_to_ns(1e-5) == 10_000
    assert dt_to_ns(0.001 * 3) == 3_000_000        # 0.003000...0004 rounds to whole ns
    dt_ns = 2_000_000
    for k in (0, 1, 499, 500, 123_456):
        assert step_of(ns_to_stamp(k * dt_ns), dt_ns) == k
        # a stamp off by less than half a period still names its step
        assert step_of(ns_to_stamp(k * dt_ns + 999_999), dt_ns) == k
        assert step_of(ns_to_stamp(max(k * dt_ns - 999_999, 0)), dt_ns) == k
    # anything with sec/nanosec works (rosbags' deserialized stamps)
    assert step_of(type('S', (), {'sec': 3, 'nanosec': 2_000_000})(), dt_ns) == 1501


@pytest.mark.parametrize('spec_', SCALAR_TOPICS, ids=lambda t: t.name)
def test_scalar_msg_round_trip(spec_):
    value = -1234.5678e-3
    msg = scalar_msg(spec_, 7 * 2_000_000, value)
    assert type(msg) is spec_.msg_type
    assert msg.header.frame_id == FRAME_ID == 'actuator'
    assert stamp_to_ns(msg.header.stamp) == 14_000_000
    assert scalar_value(spec_, msg) == value
    # the value sits where the topic table says, read independently of scalar_value
    obj = msg
    for part in spec_.field.split('.'):
        obj = getattr(obj, part)
    assert obj == value
    pkg, kind, name = spec_.type_name.split('/')
    assert kind == 'msg' and type(msg).__name__ == name
    assert type(msg).__module__.startswith(f'{pkg}.msg.')
    assert topic(spec_.name) is spec_


def test_topic_table():
    assert [t.name for t in SCALAR_TOPICS] == [
        '/seft/ground_acceleration', '/seft/reference_force', '/seft/valve_command',
        '/seft/measured_force', '/seft/displacement', '/seft/velocity', '/seft/acceleration']
    assert [t.field for t in SCALAR_TOPICS] == [
        'accel.linear.x', 'wrench.force.x', 'vector.x', 'wrench.force.x', 'point.x',
        'twist.linear.x', 'accel.linear.x']
    assert [t.name for t in MEASUREMENT_TOPICS] == [
        '/seft/measured_force', '/seft/displacement', '/seft/velocity', '/seft/acceleration']
    with pytest.raises(KeyError, match='/seft/nothing'):
        topic('/seft/nothing')


def test_timing_and_node_parameter_topics():
    assert [t.name for t in TIMING] == [
        '/seft/timing/rig', '/seft/timing/force_servo_controller',
        '/seft/timing/reference_force_builder', '/seft/timing/ground_motion_publisher']
    assert all(t.type_name == 'sensor_msgs/msg/JointState' for t in TIMING)
    assert timing_topic('rig') is TIMING[0] and timing_topic('rig').publisher == 'rig'
    with pytest.raises(KeyError):
        timing_topic('recorder')
    assert NODE_PARAMETERS.type_name == 'std_msgs/msg/String'
    assert NODE_PARAMETERS.qos.durability == STATUS.qos.durability     # latched


@pytest.mark.parametrize('spec_', SCALAR_TOPICS, ids=lambda t: t.name)
def test_reused_scalar_message_equals_a_new_one(spec_):
    writer = ScalarMessage(spec_)
    first = writer(14_000_000, 1.5)
    assert first == scalar_msg(spec_, 14_000_000, 1.5)
    second = writer(3_002_000_000, -2.25)      # the same object, stamp and value replaced
    assert second is first and second == scalar_msg(spec_, 3_002_000_000, -2.25)
    assert scalar_value(spec_, second) == -2.25


@pytest.mark.parametrize('spec_', SCALAR_TOPICS, ids=lambda t: t.name)
@pytest.mark.parametrize('frame', ['actuator', '', 'a', 'abcdefg', 'abcdefgh'])
def test_scalar_reader_reads_the_serialized_message(spec_, frame):
    """The fast path against rclpy's own deserialization, for frame ids of every alignment."""
    msg = scalar_msg(spec_, 3_002_000_001, -1234.5678e-3)
    msg.header.frame_id = frame
    raw = serialize_message(msg)
    assert ScalarReader(spec_)(raw) == (3_002_000_001, -1234.5678e-3)
    back = deserialize_message(raw, spec_.msg_type)
    assert scalar_value(spec_, back) == -1234.5678e-3


def test_live_and_bag_topics():
    """Live, the rig sends its four sensors in one message and every node its record
    batches; the bag holds every signal per sample (the recorder writes the batches back)."""
    assert MEASUREMENT.name == '/seft/measurement'
    assert MEASUREMENT.type_name == 'sensor_msgs/msg/JointState'
    names = {t.name for t in TOPICS}
    bag_names = {t.name for t in BAG_TOPICS}
    live_only = {CLOCK.name, MEASUREMENT.name} | set(RECORD)
    assert ESTIMATES.name in bag_names
    assert names == bag_names | live_only and not live_only & bag_names
    assert sorted(RECORD) == sorted(
        [f'/seft/record/{n}' for n in ('rig', 'ground_motion_publisher',
                                       'reference_force_builder', 'force_servo_controller')]
        + [f'{t.name.replace("/seft/timing/", "/seft/record/")}/timing' for t in TIMING]
        + ['/seft/record/reference_force_builder/estimates'])
    assert all(t.type_name == 'std_msgs/msg/Float64MultiArray' for t in RECORD.values())
    assert RECORD['/seft/record/rig'].description.endswith(
        '(columns step,/seft/measured_force,/seft/displacement,/seft/velocity,'
        '/seft/acceleration).')


def _rosbags_scalar(ts, spec_, stamp_ns, value):
    """The message as rosbags builds it, independently of rclpy."""
    import numpy as np
    T, H = ts.types['builtin_interfaces/msg/Time'], ts.types['std_msgs/msg/Header']
    V = ts.types['geometry_msgs/msg/Vector3']
    header = H(stamp=T(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=FRAME_ID)
    vec = V(x=value, y=0.0, z=0.0)
    zero = V(x=0.0, y=0.0, z=0.0)
    kind = spec_.type_name.split('/')[-1]
    cls = ts.types[spec_.type_name]
    if kind == 'AccelStamped':
        return cls(header=header, accel=ts.types['geometry_msgs/msg/Accel'](linear=vec,
                                                                            angular=zero))
    if kind == 'WrenchStamped':
        return cls(header=header, wrench=ts.types['geometry_msgs/msg/Wrench'](force=vec,
                                                                              torque=zero))
    if kind == 'TwistStamped':
        return cls(header=header, twist=ts.types['geometry_msgs/msg/Twist'](linear=vec,
                                                                            angular=zero))
    if kind == 'PointStamped':
        return cls(header=header, point=ts.types['geometry_msgs/msg/Point'](x=value, y=0.0,
                                                                            z=0.0))
    assert kind == 'Vector3Stamped'
    del np
    return cls(header=header, vector=vec)


@pytest.mark.parametrize('spec_', SCALAR_TOPICS, ids=lambda t: t.name)
def test_serialized_stamped_scalar_equals_rosbags_bytes(spec_):
    """The bytes written in place equal rosbags' own serialization of the same message
    (exact length, zero padding), and rclpy and the fast reader read them back."""
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    write = SerializedStamped.scalar(spec_)
    for stamp, value in ((0, 0.0), (3_002_000_001, -1234.5678e-3), (7 * 10**9, 1e300)):
        raw = write(stamp, (value,))
        expected = ts.serialize_cdr(_rosbags_scalar(ts, spec_, stamp, value), spec_.type_name)
        assert raw == bytes(expected)
        assert ScalarReader(spec_)(raw) == (stamp, value)
        assert deserialize_message(raw, spec_.msg_type) == scalar_msg(spec_, stamp, value)


def test_serialized_fields_and_fields_reader():
    """The measurement and timing records: rosbags reads the bytes (the old rclpy bytes of a
    JointState carried 8 bytes too many, which rosbags refuses), and the reader takes the
    values in place, or by name from a message laid out another way."""
    import numpy as np
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import JointState

    from seft_msgs_py.signals import MEASUREMENT_FIELDS, TIMING_FIELDS
    ts = get_typestore(Stores.ROS2_JAZZY)
    # a ten-story frame's structure state: 9 computational DOFs' x, v, a and the step time
    many = tuple(f'floor_{i}/{q}' for q in ('x', 'v', 'a') for i in range(2, 11)) + ('t',)
    for names in (MEASUREMENT_FIELDS, TIMING_FIELDS, many):
        values = tuple(-1.5 * (i + 1) for i in range(len(names)))
        serialize = SerializedStamped.fields(JointState, names)
        assert len(serialize.offsets) == len(names)     # the recorder's row width
        raw = serialize(5_000_000_001, values)
        back = ts.deserialize_cdr(raw, 'sensor_msgs/msg/JointState')
        assert list(back.name) == list(names) and back.header.frame_id == FRAME_ID
        assert np.array_equal(back.position, values)
        assert (back.header.stamp.sec, back.header.stamp.nanosec) == (5, 1)
        assert FieldsReader(JointState, names)(raw) == (5_000_000_001, values)
    other = JointState(name=list(reversed(MEASUREMENT_FIELDS)), position=[4.0, 3.0, 2.0, 1.0])
    other.header.frame_id = 'hardware_bridge'
    other.header.stamp.sec = 2
    assert FieldsReader(JointState, MEASUREMENT_FIELDS)(serialize_message(other)) == (
        2_000_000_000, (1.0, 2.0, 3.0, 4.0))
    missing = JointState(name=['measured_force_N'], position=[1.0])
    with pytest.raises(KeyError, match='displacement_m'):
        FieldsReader(JointState, MEASUREMENT_FIELDS)(serialize_message(missing))


def test_clock_from_raw():
    assert clock_ns_from_raw(serialize_message(clock_msg(7_002_000_003))) == 7_002_000_003


def test_bag_reader_reads_the_fields_of_the_topic_table():
    from seft_ros.analysis import bag
    assert {t.name: t.field for t in SCALAR_TOPICS} == {
        k: v for k, v in bag._SCALARS.items() if k != '/clock'}


def test_clock_msg():
    msg = clock_msg(3_002_000_000)
    assert type(msg) is CLOCK.msg_type
    assert (msg.clock.sec, msg.clock.nanosec) == (3, 2_000_000)


def test_status_msg_and_values():
    msg = status_msg('rig', STATE_DONE, 'completed 500 steps', step=500, time_s='1.000000')
    assert type(msg) is STATUS.msg_type
    assert (msg.name, msg.message, msg.hardware_id) == ('rig', 'completed 500 steps', 'seft')
    assert msg.level == DiagnosticStatus.OK
    assert [kv.key for kv in msg.values] == ['state', 'step', 'time_s']
    assert status_values(msg) == {'state': 'done', 'step': '500', 'time_s': '1.000000'}
    for state in (STATE_ABORTED, STATE_FAILED):
        assert status_msg('x', state).level == DiagnosticStatus.ERROR
    assert status_msg('x', STATE_READY).level == DiagnosticStatus.OK
    assert status_msg('x', STATE_READY, level=DiagnosticStatus.WARN).level == \
        DiagnosticStatus.WARN
    assert status_values(status_msg('x', STATE_READY)) == {'state': 'ready'}


def test_parameters_json_is_canonical():
    p = resolve({'alpha': 0.5})
    text = parameters_json(p)
    assert json.loads(text) == p
    keys = list(json.loads(text))
    assert keys == sorted(keys)
    assert parameters_json(dict(reversed(list(p.items())))) == text


# -- StepSync --------------------------------------------------------------------------------

def test_step_sync():
    sync = StepSync(iter(['a', 'b', 'c']))
    assert sync.names == ('a', 'b', 'c')
    assert sync.add(1, 'a', 1.0) is None
    assert sync.add(0, 'b', 2.0) is None          # steps are collected independently
    assert sync.add(1, 'b', 3.0) is None
    assert sync.add(1, 'b', 4.0) is None          # a repeat overwrites, does not complete
    assert sync.add(1, 'c', 5.0) == {'a': 1.0, 'b': 4.0, 'c': 5.0}
    assert sync.add(0, 'a', 6.0) is None
    assert sync.add(0, 'c', 7.0) == {'a': 6.0, 'b': 2.0, 'c': 7.0}
    # a completed step is forgotten: the same step starts over
    assert sync.add(1, 'a', 8.0) is None
    assert StepSync(['only']).add(5, 'only', 9.0) == {'only': 9.0}
