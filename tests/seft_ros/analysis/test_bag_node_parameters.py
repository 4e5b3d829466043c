"""A bag's parameters come from the node that used each one (``/seft/node_parameters``).

Bags are written in ``tmp_path`` with rosbags, as the recorder writes them: run parameters,
node parameters, status reports and one message per step on every scalar topic, whose values
are the reference response of the whole structure at alpha = 0.5.
"""

import dataclasses
import json
import re

import numpy as np
import pytest
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import Reader, Writer
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError
from seft_ros.analysis.bag import read_run, read_signals
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import reference_from_run, reference_response
from seft_ros.analysis.report import write_report

STORE = get_typestore(Stores.ROS2_JAZZY)
DT = 0.002
N = 1500
ALPHA_RUN = 0.5   # what the reference-force builder (and the rig) used
#: The reference-force builder's model parameters (``nodes/reference_force_builder.py``).
RFB_MODEL = ('rig_model', 'tau_s', 'valve_limit_V', 'piston_area_m2', 'oil_bulk_modulus_Pa',
             'actuator_volume_m3', 'valve_time_constant_s', 'valve_flow_gain_m3_per_s_V',
             'valve_pressure_coefficient_m3_per_s_Pa', 'leakage_coefficient_m3_per_s_Pa',
             'io_latency_s', 'anti_alias_cutoff_hz', 'accelerometer_range_m_s2')


def default_of(typename):
    """A rosbags message of `typename` with every field zero or empty."""
    _, fields = STORE.fielddefs[typename]
    values = {}
    for name, (kind, arg) in fields:
        if kind == Nodetype.NAME:
            values[name] = default_of(arg)
        elif kind == Nodetype.BASE:
            values[name] = {'string': ''}.get(arg[0], 0.0 if 'float' in arg[0] else 0)
        else:
            values[name] = []
    return STORE.types[typename](**values)


def scalar_raw(sig, step, value):
    msg = default_of(sig.type_name)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * int(DT * 1e9), 10**9)
    obj = msg
    *head, last = sig.field.split('.')
    for part in head:
        obj = getattr(obj, part)
    setattr(obj, last, float(value))
    return STORE.serialize_cdr(msg, sig.type_name)


def string_raw(text):
    msg = STORE.types['std_msgs/msg/String'](data=text)
    return STORE.serialize_cdr(msg, 'std_msgs/msg/String')


def status_raw(node, state, message='', hardware_id='seft'):
    kv = STORE.types['diagnostic_msgs/msg/KeyValue']
    msg = STORE.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=b'\x00'[0], name=node, message=message, hardware_id=hardware_id,
        values=[kv(key='state', value=state)])
    return STORE.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticStatus')


def node_parameters(**overrides):
    """``{node: {name: value}}`` at the schema defaults, as each node publishes them;
    `overrides` maps a node to the values it changes (None: that node is not in the graph)."""
    out = {}
    for node in parameters.NODES:
        if node in overrides and overrides[node] is None:
            continue
        names = [s.name for s in parameters.specs_for_node(node)]
        if node == 'reference_force_builder':
            names += [n for n in RFB_MODEL if n not in names]
        values = {n: parameters.spec(n).default for n in names}
        values['use_sim_time'] = False
        values.update(overrides.get(node) or {})
        out[node] = values
    return out


@pytest.fixture(scope='module')
def response():
    """The reference response at ALPHA_RUN to a 2 Hz ground-motion burst: the samples of a
    run that reproduces its alpha perfectly."""
    t = np.arange(N) * DT
    ag = 3.0 * np.sin(2 * np.pi * 2.0 * t) * np.sin(np.pi * t / t[-1]) ** 2
    p = parameters.defaults()
    ref = reference_response(alpha=ALPHA_RUN, mass_kg=p['mass_kg'],
                             damping_N_s_per_m=p['damping_N_s_per_m'],
                             stiffness_N_per_m=p['stiffness_N_per_m'], dt=DT,
                             ground_acceleration_m_s2=ag)
    return {
        signals.GROUND_ACCELERATION.name: ag,
        signals.REFERENCE_FORCE.name: ref.force_N,
        signals.VALVE_COMMAND.name: 1e-3 * ref.force_N,
        signals.MEASURED_FORCE.name: ref.force_N,
        signals.DISPLACEMENT.name: ref.displacement_m,
        signals.VELOCITY.name: ref.velocity_m_s,
        signals.ACCELERATION.name: ref.acceleration_m_s2,
    }


def write_bag(path, response, *, run_params=None, node_params=None, raw_node_params=(),
              status_id='seft', statuses=()):
    """A seft bag: run parameters, node parameters (one message per node), every scalar
    topic for N steps, `statuses` (``(node, state, message, hardware_id)``) and the final
    statuses (hardware id `status_id`)."""
    with Writer(path, version=9) as writer:
        conns = {}

        def write(sig, stamp, raw):
            if sig.name not in conns:
                conns[sig.name] = writer.add_connection(sig.name, sig.type_name,
                                                        typestore=STORE)
            writer.write(conns[sig.name], stamp, raw)

        if run_params is not None:
            write(signals.RUN_PARAMETERS, 0, string_raw(json.dumps(run_params)))
        for node, values in (node_params or {}).items():
            write(signals.NODE_PARAMETERS, 0,
                  string_raw(json.dumps({'node': node, 'parameters': values})))
        for text in raw_node_params:
            write(signals.NODE_PARAMETERS, 0, string_raw(text))
        for step in range(N):
            for sig in signals.SCALAR_SIGNALS:
                write(sig, step * int(DT * 1e9), scalar_raw(sig, step, response[sig.name][step]))
        for status in statuses:
            write(signals.STATUS, N // 2 * int(DT * 1e9), status_raw(*status))
        for node in ('ground_motion_publisher', 'reference_force_builder', 'rig'):
            write(signals.STATUS, N * int(DT * 1e9), status_raw(node, 'done', 'finished',
                                                                status_id))
    return path


@pytest.fixture(scope='module')
def run_params():
    """The recorder's /seft/run_parameters of the issue: alpha 0 (its own default)."""
    return dict(parameters.defaults(), alpha=0.0)


@pytest.fixture(scope='module')
def issue_bag(tmp_path_factory, response, run_params):
    """The docs' run by hand with -p alpha:=0.5 on the reference-force builder and rig."""
    path = tmp_path_factory.mktemp('bags') / 'issue_bag'
    nodes = node_parameters(reference_force_builder={'alpha': ALPHA_RUN},
                            rig={'alpha': ALPHA_RUN})
    return write_bag(path, response, run_params=run_params, node_params=nodes)


@pytest.fixture(scope='module')
def old_bag(tmp_path_factory, response):
    """A bag written before the nodes published their parameters (alpha 0.5 in the run
    parameters, which lack the real-time parameters of a newer schema)."""
    path = tmp_path_factory.mktemp('bags') / 'old_bag'
    old = {k: v for k, v in parameters.defaults().items()
           if k not in ('mode', 'watchdog_timeout_s', 'realtime_output')}
    old.update(alpha=ALPHA_RUN, tau_s=0.012, obsolete_parameter=3)
    return write_bag(path, response, run_params=old)


# -- parameters from the nodes ---------------------------------------------------------------

def test_alpha_comes_from_the_reference_force_builder(issue_bag, run_params):
    run = read_run(issue_bag)
    assert run.params['alpha'] == 0.5
    assert run.extra['param_sources']['alpha'] == 'reference_force_builder'
    assert run.extra['param_sources']['mass_kg'] == 'rig'
    assert run.extra['param_sources']['dt'] == 'rig'
    assert run.extra['param_sources']['record'] == 'ground_motion_publisher'
    assert run.extra['param_sources']['valve_limit_V'] == 'force_servo_controller'
    assert run.extra['param_sources']['bag_path'] == 'recorder'
    assert set(run.extra['param_sources']) == set(parameters.defaults())
    assert set(run.extra['node_params']) == set(parameters.NODES)
    assert run.extra['node_params']['reference_force_builder']['alpha'] == 0.5
    assert run.extra['node_params']['recorder']['alpha'] == 0.0
    # the other nodes still had alpha 0: read, but recorded as a mismatch
    assert run.extra['parameter_mismatches'] == [
        'parameter alpha differs: reference_force_builder=0.5, rig=0.5, '
        'ground_motion_publisher=0.0, force_servo_controller=0.0, recorder=0.0']
    assert run.n_steps == N and run.time_s[-1] == pytest.approx((N - 1) * DT, abs=1e-12)
    assert run.stable


def test_issue_bag_compares_against_the_alpha_it_ran(issue_bag, response):
    """The issue: 60 % NRMS against the alpha = 0 reference; against the alpha the builder
    used, the recorded reference response matches to the integration's precision."""
    run = read_run(issue_bag)
    comparison = compare_run(run, reference_from_run(run))
    assert comparison.displacement.nrms < 1e-9
    assert comparison.force.nrms < 1e-9
    stale = dataclasses.replace(run, params=run.params | {'alpha': 0.0})
    wrong = compare_run(run, reference_from_run(stale))
    assert wrong.displacement.nrms > 0.4  # 53 % with the recorder's alpha = 0


def test_source_node_wins_over_the_other_nodes(tmp_path, response, run_params):
    nodes = node_parameters(rig={'mass_kg': 60.0, 'alpha': 0.5},
                            reference_force_builder={'alpha': 0.5, 'mass_kg': 52.7})
    bag = read_signals(write_bag(tmp_path / 'bag', response, run_params=run_params,
                                 node_params=nodes))
    assert bag.params['mass_kg'] == 60.0 and bag.param_sources['mass_kg'] == 'rig'
    assert bag.params['alpha'] == 0.5
    assert bag.parameter_mismatches[1] == (
        'parameter mass_kg differs: rig=60.0, ground_motion_publisher=52.7, '
        'reference_force_builder=52.7, force_servo_controller=52.7, recorder=52.7')


def test_missing_source_falls_back_to_the_next_node_then_run_parameters(tmp_path, response,
                                                                         run_params):
    """A delay-rig graph without the servo controller and, here, without recorder and
    ground-motion node parameters: valve_limit_V and amplitude_N from the builder, which
    declares them too (the amplitude for its estimators' hold level; the record's time scale
    for its divergence guard's prediction); the ground motion's preview, which only those two
    declare, from /seft/run_parameters."""
    nodes = node_parameters(force_servo_controller=None, recorder=None,
                            ground_motion_publisher=None,
                            reference_force_builder={'alpha': 0.5, 'valve_limit_V': 8.0,
                                                     'rig_model': 'delay', 'time_scale': 0.7},
                            rig={'alpha': 0.5, 'rig_model': 'delay'})
    given = dict(run_params, record='default', time_scale=0.7, valve_limit_V=9.0,
                 preview_steps=3)
    run = read_run(write_bag(tmp_path / 'bag', response, run_params=given, node_params=nodes))
    sources = run.extra['param_sources']
    assert (run.params['valve_limit_V'], sources['valve_limit_V']) == (
        8.0, 'reference_force_builder')
    assert (run.params['time_scale'], sources['time_scale']) == (0.7, 'reference_force_builder')
    assert (run.params['preview_steps'], sources['preview_steps']) == (3, 'run_parameters')
    assert sources['amplitude_N'] == 'reference_force_builder'
    assert sources['bag_path'] == 'run_parameters'
    assert run.params['rig_model'] == 'delay' and run.valve_command_V is None
    assert run.extra['parameter_mismatches'] == []


def test_node_parameters_without_run_parameters(tmp_path, response):
    nodes = node_parameters(recorder=None, reference_force_builder={'alpha': 0.5},
                            rig={'alpha': 0.5}, ground_motion_publisher={'alpha': 0.5},
                            force_servo_controller={'alpha': 0.5})
    bag = read_signals(write_bag(tmp_path / 'bag', response, node_params=nodes))
    assert bag.params['alpha'] == 0.5 and bag.parameter_mismatches == []
    assert bag.param_sources['bag_path'] == 'default'  # the recorder's: in no message
    assert bag.params['bag_path'] == 'seft_bag'


def test_last_message_of_a_node_wins(tmp_path, response, run_params):
    first = json.dumps({'node': 'reference_force_builder', 'parameters': {'alpha': 1.0}})
    nodes = node_parameters(reference_force_builder={'alpha': 0.5}, rig={'alpha': 0.5},
                            recorder={'alpha': 0.5}, ground_motion_publisher={'alpha': 0.5},
                            force_servo_controller={'alpha': 0.5})
    last = json.dumps({'node': 'reference_force_builder',
                       'parameters': nodes.pop('reference_force_builder')})
    bag = read_signals(write_bag(tmp_path / 'bag', response, run_params=run_params,
                                 node_params=nodes, raw_node_params=(first, last)))
    assert bag.params['alpha'] == 0.5 and bag.parameter_mismatches == []
    assert bag.node_params['reference_force_builder']['alpha'] == 0.5


def test_another_runs_node_parameters_are_not_the_runs(tmp_path, response, run_params):
    """A node of another run on the domain (the nodes-by-hand recorder, run_token 'none',
    alpha 0, 4 s) heard after the run's own recorder: recorded, but not taken for the run's
    (before: its values replaced the run's recorder's, and the bag listed 'parameter alpha
    differs: recorder=0.0, ...', 'parameter run_token differs: recorder='none', ...')."""
    token = '0123456789abcdef'
    nodes = node_parameters(**{n: {'alpha': 0.5, 'run_token': token}
                               for n in parameters.NODES})
    stray = json.dumps({'node': 'recorder', 'parameters': dict(
        nodes['recorder'], alpha=0.0, duration_s=4.0, run_token='none')})
    bag = read_signals(write_bag(tmp_path / 'bag', response,
                                 run_params=dict(run_params, alpha=0.5, run_token=token),
                                 node_params=nodes, raw_node_params=(stray,)))
    assert bag.parameter_mismatches == []
    assert bag.node_params['recorder']['run_token'] == token
    assert bag.node_params['recorder']['alpha'] == 0.5
    assert bag.params['run_token'] == token and bag.params['alpha'] == 0.5


@pytest.mark.parametrize('message_auth', ['token', 'hmac'])
def test_another_runs_statuses_are_not_the_runs(tmp_path, response, run_params, message_auth):
    """A stray rig's 'aborted' and a stray recorder's 'closed' in the bag (another run's
    seal, or none) are not the run's: its finals are its own rig's 'done' (before: the run
    read as aborted by the stray rig at 1.5 s, its bag closed by the stray recorder)."""
    token = '0123456789abcdef'
    seal = token if message_auth == 'token' else '5e' * 16
    nodes = node_parameters(**{n: {'run_token': token, 'message_auth': message_auth}
                               for n in parameters.NODES})
    stray = [('rig', 'aborted', 'another test: watchdog', 'seft#fedcba9876543210'),
             ('recorder', 'closed', 'bag closed', 'seft'),
             ('rig', 'aborted', 'a short seal', 'seft#' + seal[:8])]
    path = write_bag(tmp_path / 'bag', response, node_params=nodes, status_id='seft#' + seal,
                     run_params=dict(run_params, run_token=token, message_auth=message_auth),
                     statuses=stray)
    bag = read_signals(path)
    assert bag.foreign_statuses == 3
    assert [(s['name'], s['state']) for s in bag.statuses] == [
        ('ground_motion_publisher', 'done'), ('reference_force_builder', 'done'),
        ('rig', 'done')]
    run = read_run(path)
    assert run.stable and run.unstable_at_s is None
    assert run.extra['rig_finals']['rig']['state'] == 'done'


def test_an_unsealed_bag_reads_every_status_as_before(tmp_path, response, run_params):
    """A bag recorded before the statuses were sealed (a run token, every hardware id
    'seft'): every status is the run's, the rig's 'aborted' too."""
    token = '0123456789abcdef'
    nodes = node_parameters(**{n: {'run_token': token} for n in parameters.NODES})
    path = write_bag(tmp_path / 'bag', response, node_params=nodes,
                     run_params=dict(run_params, run_token=token),
                     statuses=[('rig', 'aborted', 'watchdog', 'seft')])
    bag = read_signals(path)
    assert bag.foreign_statuses == 0
    assert [(s['name'], s['state']) for s in bag.statuses][0] == ('rig', 'aborted')
    assert len(bag.statuses) == 4


# -- old bags --------------------------------------------------------------------------------

def read_json_run_params(path):
    """The JSON of the bag's /seft/run_parameters message."""
    with Reader(path) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic == signals.RUN_PARAMETERS.name:
                return json.loads(STORE.deserialize_cdr(raw, conn.msgtype).data)
    raise AssertionError('no run parameters')


def test_old_bag_reads_as_before(old_bag):
    run = read_run(old_bag)
    expected = parameters.resolve({k: v for k, v in read_json_run_params(old_bag).items()
                                   if k in parameters.defaults()})
    assert run.params == expected
    assert run.params['alpha'] == 0.5 and run.params['tau_s'] == 0.012
    assert run.params['mode'] == 'lockstep'  # absent from the old bag: the default
    assert run.extra['node_params'] == {}
    assert run.extra['parameter_mismatches'] == []
    sources = run.extra['param_sources']
    assert sources['alpha'] == 'run_parameters' and sources['mode'] == 'default'
    assert set(sources.values()) == {'run_parameters', 'default'}
    comparison = compare_run(run, reference_from_run(run))
    assert comparison.displacement.nrms < 1e-6


# -- errors ----------------------------------------------------------------------------------

@pytest.mark.parametrize('text, message', [
    ('{"node": "rig", "parameters": ', r'/seft/node_parameters: invalid JSON \(.+\)'),
    ('{"node": "rig"}', re.escape(
        '/seft/node_parameters: expected {"node": <name>, "parameters": {...}}')),
    ('["rig", {}]', re.escape(
        '/seft/node_parameters: expected {"node": <name>, "parameters": {...}}')),
    ('{"node": "", "parameters": {}}', re.escape(
        '/seft/node_parameters: expected {"node": <name>, "parameters": {...}}')),
])
def test_malformed_node_parameters(tmp_path, response, run_params, text, message):
    path = write_bag(tmp_path / 'bag', response, run_params=run_params, raw_node_params=(text,))
    with pytest.raises(InputError, match='^' + re.escape(str(path)) + ': ' + message + '$'):
        read_signals(path)


def test_out_of_range_node_value_names_the_node(tmp_path, response, run_params):
    nodes = node_parameters(rig={'mass_kg': -1.0})
    path = write_bag(tmp_path / 'bag', response, run_params=run_params, node_params=nodes)
    with pytest.raises(InputError, match='^' + re.escape(
            f'{path}: node rig: parameter mass_kg=-1.0: expected float > 0') + '$'):
        read_run(path)


def test_bag_without_any_parameters(tmp_path, response):
    path = write_bag(tmp_path / 'bag', response)
    with pytest.raises(InputError, match=re.escape(
            f'{path}: not a seft bag (no /seft/run_parameters message)')):
        read_run(path)


def test_run_parameters_not_an_object(tmp_path, response):
    path = write_bag(tmp_path / 'bag', response, run_params=[['alpha', 0.5]])
    with pytest.raises(InputError, match='^' + re.escape(
            f'{path}: /seft/run_parameters: expected a JSON object') + '$'):
        read_signals(path)


# -- report ----------------------------------------------------------------------------------

def test_report_names_the_sources_and_warns(issue_bag, old_bag, tmp_path):
    runs = [read_run(issue_bag), read_run(old_bag)]
    paths = write_report(runs, tmp_path / 'report')
    text = paths.report_md.read_text()
    run1, run2 = text.split('## Run 1')[1].split('## Run 2')
    assert ('- parameters: alpha, predictor from reference_force_builder; mass, stiffness, '
            'damping, rig, dt from rig; record, scaling from ground_motion_publisher\n'
            in run1)
    assert '**WARNING: the nodes ran with different values of shared parameters**' in run1
    assert ('  - parameter alpha differs: reference_force_builder=0.5, rig=0.5, '
            'ground_motion_publisher=0.0, force_servo_controller=0.0, recorder=0.0\n' in run1)
    assert 'alpha = 0.5' in run1.splitlines()[0]
    # an old bag: no node parameters, no sources line, no warning
    assert '- parameters:' not in run2 and 'WARNING' not in run2
    summary = json.loads(paths.summary_json.read_text())['runs']
    assert summary[0]['alpha'] == 0.5
    assert summary[0]['parameter_sources']['alpha'] == 'reference_force_builder'
    assert summary[0]['parameter_sources']['mass_kg'] == 'rig'
    assert 'parameter_sources' not in summary[1]
    assert summary[0]['nrms']['displacement'] < 1e-6



# -- a bag of the live topics (ros2 bag record) -------------------------------------------------

def measurement_raw(step, values, names=signals.MEASUREMENT_FIELDS):
    msg = default_of('sensor_msgs/msg/JointState')
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * int(DT * 1e9), 10**9)
    msg.name = list(names)
    msg.position = np.asarray(values, dtype=float)
    msg.velocity = np.zeros(0)
    msg.effort = np.zeros(0)
    return STORE.serialize_cdr(msg, 'sensor_msgs/msg/JointState')


def batch_raw(stream, rows, labels=None):
    dim = STORE.types['std_msgs/msg/MultiArrayDimension']
    layout = STORE.types['std_msgs/msg/MultiArrayLayout'](
        dim=[dim(label='step', size=len(rows), stride=len(rows) * len(rows[0])),
             dim(label=labels or stream.labels, size=len(rows[0]), stride=len(rows[0]))],
        data_offset=0)
    msg = STORE.types['std_msgs/msg/Float64MultiArray'](
        layout=layout, data=np.asarray(rows, dtype=float).ravel())
    return STORE.serialize_cdr(msg, 'std_msgs/msg/Float64MultiArray')


def write_live_bag(path, response, *, measured_from='measurement', labels=None):
    """What ``ros2 bag record`` keeps of a real-time run: the control topics, the rig's
    measurement message (in shuffled field order, from another frame), the record batches
    (ten rows each; the rig's data only in its batches when `measured_from` is 'batches')
    and the node parameters."""
    nodes = node_parameters(reference_force_builder={'alpha': ALPHA_RUN, 'mode': 'realtime'},
                            rig={'alpha': ALPHA_RUN, 'mode': 'realtime'})
    streams = {r.name: r for r in signals.RECORD_STREAMS}
    rig_stream = streams['/seft/record/rig']
    timing_stream = streams['/seft/record/rig/timing']
    order = (3, 0, 2, 1)
    names = [signals.MEASUREMENT_FIELDS[i] for i in order]
    sensors = [response[t] for t in rig_stream.columns]
    with Writer(path, version=9) as writer:
        conns = {}

        def write(name, typename, stamp, raw):
            if name not in conns:
                conns[name] = writer.add_connection(name, typename, typestore=STORE)
            writer.write(conns[name], stamp, raw)

        for node, values in nodes.items():
            write(signals.NODE_PARAMETERS.name, signals.NODE_PARAMETERS.type_name, 0,
                  string_raw(json.dumps({'node': node, 'parameters': values})))
        for step in range(N):
            stamp = step * int(DT * 1e9)
            for sig in (signals.GROUND_ACCELERATION, signals.REFERENCE_FORCE,
                        signals.VALVE_COMMAND):
                write(sig.name, sig.type_name, stamp,
                      scalar_raw(sig, step, response[sig.name][step]))
            if measured_from == 'measurement':
                write(signals.MEASUREMENT.name, signals.MEASUREMENT.type_name, stamp,
                      measurement_raw(step, [sensors[i][step] for i in order], names))
        for first in range(0, N, signals.RECORD_ROWS):
            steps = range(first, min(N, first + signals.RECORD_ROWS))
            stamp = steps[-1] * int(DT * 1e9)
            if measured_from == 'batches':
                write(rig_stream.name, signals.RECORD_TYPE, stamp, batch_raw(
                    rig_stream, [[k] + [s[k] for s in sensors] for k in steps], labels))
            write(timing_stream.name, signals.RECORD_TYPE, stamp, batch_raw(
                timing_stream, [[k, 1e-4, 2e-5, 3e-4, 0.0, float(k % 5 == 0), 8e-4]
                                for k in steps]))
        write(signals.STATUS.name, signals.STATUS.type_name, N * int(DT * 1e9),
              status_raw('rig', 'done', 'finished'))
    return path


@pytest.mark.parametrize('measured_from', ['measurement', 'batches'])
def test_a_bag_of_the_live_topics_reads_as_the_recorders(tmp_path, response, measured_from):
    run = read_run(write_live_bag(tmp_path / 'live', response, measured_from=measured_from))
    assert run.n_steps == N
    for name, values in ((signals.MEASURED_FORCE.name, run.measured_force_N),
                         (signals.DISPLACEMENT.name, run.displacement_m),
                         (signals.VELOCITY.name, run.velocity_m_s),
                         (signals.ACCELERATION.name, run.acceleration_m_s2),
                         (signals.REFERENCE_FORCE.name, run.reference_force_N)):
        assert np.array_equal(values, response[name]), name
    assert compare_run(run, reference_from_run(run)).displacement.nrms < 1e-9
    rig = run.extra['timing_data']['rig']
    assert rig.step.tolist() == list(range(N))
    # step 0 has no command before it: the fraction is over steps 1..N-1 (rounded to 1e-6)
    stale = run.extra['timing']['stale_command_fraction']
    assert stale == pytest.approx((N // 5 - 1) / (N - 1), abs=1e-6)
    assert run.extra['timing']['loop_latency_ms']['p50'] == pytest.approx(0.8)


def test_a_batch_with_other_columns_is_refused(tmp_path, response):
    path = write_live_bag(tmp_path / 'live', response, measured_from='batches',
                          labels='step,a,b,c,d')
    with pytest.raises(InputError, match=re.escape(
            '/seft/record/rig: expected a batch with columns step,/seft/measured_force,')):
        read_run(path)


def test_a_bag_without_a_signal_names_what_is_missing(tmp_path, response):
    """A bag whose rig data never arrived (the live topics, no measurement, no rig batches)
    is refused in one line that names the missing topics."""
    path = write_live_bag(tmp_path / 'live', response, measured_from='nowhere')
    with pytest.raises(InputError) as err:
        read_run(path)
    assert str(err.value) == (
        f'{path}: the bag holds no complete step: no samples on /seft/measured_force, '
        '/seft/displacement, /seft/velocity, /seft/acceleration')
