"""A node takes only messages with the run's seal (issue 42), one node by hand over DDS: the
force servo controller in a process of its own (lockstep), the test playing its builder and
its rig with the node names of the run.

The forged reference force comes from the run's own publisher (the builder's name, the one
publisher the run has on the topic: no second publisher to catch when it matches), so only
the seal tells it apart: the plain frame id of a sender that does not know the token, or, with
``message_auth: hmac``, the genuine MAC of the step before (a sender that copies the seal it
reads and changes the value). The controller drops it before it reads a value, and ends the
run naming the topic; the valve commands it sent before are the in-process controller's, bit
for bit.
"""

import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor

from seft_msgs_py import parameters
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    ScalarReader,
    SerializedStamped,
    frame_id_of_raw,
    status_msg,
    status_values,
)
from seft_msgs_py.provenance import RunSeal, new_run_token
from seft_msgs_py.signals import MEASUREMENT_FIELDS
from seft_msgs_py.topics import MEASUREMENT, REFERENCE_FORCE, STATUS, VALVE_COMMAND
from seft_ros.cli.config import write_params_file
from seft_ros.core.excitation import make_valve_controller

DT_NS = 2_000_000
STEPS = 5


def controller_by_hand(message_auth, tmp_path, ros_env):
    """The controller by hand with a run token (and a key): a generator that yields its
    parameters, seal and process, and ends the process."""
    key = tmp_path / 'key'
    key.write_text('c4' * 32)
    params = parameters.resolve({'mode': 'lockstep', 'rig_model': 'servohydraulic',
                                 'run_token': new_run_token(),
                                 'message_auth': message_auth, 'auth_key_file': str(key)})
    path = write_params_file(params, tmp_path / 'params.yaml')
    proc = subprocess.Popen([sys.executable, '-m', 'seft_ros.nodes.force_servo_controller',
                             '--ros-args', '--params-file', str(path)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    yield params, RunSeal.from_parameters(params), proc
    if proc.poll() is None:
        proc.terminate()
    proc.communicate(timeout=20)


@pytest.fixture(params=['token', 'hmac'])
def controller(request, tmp_path, ros_env):
    """The controller by hand with a run token (and a key); its parameters and seal."""
    for params, seal, _ in controller_by_hand(request.param, tmp_path, ros_env):
        yield params, seal


def nodes_of_test(ros_env, *names):
    """The test's own rclpy nodes `names` on the run's domain: (close, nodes, spin_until),
    spin_until(done, timeout) spinning them until done() or the timeout [s], close() ending
    them and their context."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    nodes = [rclpy.create_node(name, context=context) for name in names]
    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)

    def spin_until(done, timeout=20.0):
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
        return done()

    def close():
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return close, nodes, spin_until


def test_a_message_without_the_seal_is_dropped_and_ends_the_run(controller, ros_env):
    params, seal = controller
    close, (rig, builder), spin_until = nodes_of_test(ros_env, 'rig',
                                                        'reference_force_builder')
    measurement = rig.create_publisher(MEASUREMENT.msg_type, MEASUREMENT.name, MEASUREMENT.qos)
    reference = builder.create_publisher(REFERENCE_FORCE.msg_type, REFERENCE_FORCE.name,
                                         REFERENCE_FORCE.qos)
    m_msg = SerializedStamped.fields(MEASUREMENT.msg_type, MEASUREMENT_FIELDS, seal.frame_id)
    f_msg = SerializedStamped.scalar(REFERENCE_FORCE, seal.frame_id)
    valves, reports = {}, []

    read = ScalarReader(VALVE_COMMAND)

    def on_valve(raw):
        stamp, value = read(raw)
        valves[stamp // DT_NS] = (value, frame_id_of_raw(raw, VALVE_COMMAND.msg_type))
    rig.create_subscription(VALVE_COMMAND.msg_type, VALVE_COMMAND.name, on_valve,
                            VALVE_COMMAND.qos, raw=True)
    rig.create_subscription(STATUS.msg_type, STATUS.name,
                            lambda m: reports.append((m.name, status_values(m), m.message)),
                            STATUS.qos)

    def sealed(writer, topic, k, values):
        stamp = k * DT_NS
        mac = seal.seal(topic, stamp, values).encode() if seal.authenticated else None
        return writer(stamp, values, mac)
    try:
        assert spin_until(lambda: reference.get_subscription_count() > 0
                          and measurement.get_subscription_count() > 0
                          and any(n == 'force_servo_controller' for n, _, _ in reports))
        forces = [100.0 * k for k in range(STEPS)]
        sensed = [(10.0 * k, 1e-5 * k, 0.0, 0.0) for k in range(STEPS + 1)]
        for k in range(STEPS):
            reference.publish(sealed(f_msg, REFERENCE_FORCE.name, k, (forces[k],)))
            measurement.publish(sealed(m_msg, MEASUREMENT.name, k, sensed[k]))
        assert spin_until(lambda: len(valves) == STEPS), valves
        # the forged f_r[5] = 3000 N from the run's own publisher: the plain frame id, or the
        # genuine seal of step 4 (copied, the value changed)
        k = STEPS
        frame = (seal.frame_id_of(REFERENCE_FORCE.name, (k - 1) * DT_NS, (forces[-1],))
                 if seal.authenticated else 'actuator')
        forged = SerializedStamped.scalar(REFERENCE_FORCE, frame)(k * DT_NS, (3000.0,))
        reference.publish(forged)
        measurement.publish(sealed(m_msg, MEASUREMENT.name, k, sensed[k]))
        reference.publish(sealed(f_msg, REFERENCE_FORCE.name, k, (250.0,)))
        final = lambda: next((r for r in reports if r[0] == 'force_servo_controller'  # noqa
                              and r[1].get('state') in ('aborted', 'failed', 'done')), None)
        assert spin_until(final)
        time.sleep(0.3)
        spin_until(lambda: False, timeout=0.1)
    finally:
        close()
    name, values, message = final()
    assert values['state'] == 'aborted', message
    assert message.startswith("foreign publisher on /seft/reference_force: no publisher but "
                              "the run's own in this node's view (a sender that has left, or a "
                              'node of the run with another token or key): its message was '
                              "not sealed for this run (frame id "), message
    assert values['foreign_dropped'] == '1'
    assert values['taken:/seft/reference_force'] == str(STEPS)
    # no valve command of step 5 (the forged force was never applied; the node ended on it);
    # those of steps 0-4 sealed, and the in-process controller's values bit for bit
    assert sorted(valves) == list(range(STEPS))
    reference_controller = make_valve_controller(params)
    for k in range(STEPS):
        fm, x, v, a = sensed[k]
        u = reference_controller.step(forces[k], fm, v, a, x)
        value, frame = valves[k]
        assert value == u, (k, value, u)
        assert seal.frame_ok(frame, VALVE_COMMAND.name, k * DT_NS, (value,))


@pytest.fixture(params=['token', 'hmac'])
def lone_controller(request, tmp_path, ros_env):
    """The controller by hand with a run token (and a key); its parameters, seal and
    process."""
    yield from controller_by_hand(request.param, tmp_path, ros_env)


def test_a_status_of_another_run_never_ends_the_run(lone_controller, ros_env):
    """A stray 'rig' that reports 'aborted' and a stray 'recorder' that reports 'closed' on
    the run's domain (another test's nodes, a node by hand: no seal, another run's token, or
    the token in the clear without the key) do not end the run's controller: the statuses are
    dropped, counted and their publisher named once; the run's own rig's 'done' ends it."""
    params, seal, proc = lone_controller
    close, (rig, stray), spin_until = nodes_of_test(ros_env, 'rig', 'recorder')
    reports = []
    rig.create_subscription(STATUS.msg_type, STATUS.name,
                            lambda m: reports.append((m.name, status_values(m), m.message,
                                                      m.hardware_id)), STATUS.qos)
    own = rig.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
    foreign = stray.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)

    def final():
        return next((r for r in reports if r[0] == 'force_servo_controller'
                     and r[1].get('state') in ('aborted', 'failed', 'done')), None)
    other = new_run_token()
    ids = ['seft', 'seft#' + other]            # a node by hand; another run's token
    if seal.authenticated:
        ids.append('seft#' + seal.token)        # the token in the clear, without the key
    try:
        assert spin_until(lambda: foreign.get_subscription_count() > 0
                          and any(r[0] == 'force_servo_controller' for r in reports))
        for hardware_id in ids:
            foreign.publish(_with_id(status_msg('rig', STATE_ABORTED, 'another test: '
                                                'watchdog', step=3, published=3),
                                     hardware_id))
            foreign.publish(_with_id(status_msg('recorder', STATE_CLOSED, 'bag closed'),
                                     hardware_id))
        assert not spin_until(final, timeout=1.5), final()
        assert proc.poll() is None
        own.publish(seal.seal_status(status_msg('rig', STATE_DONE, 'completed 0 steps',
                                                published=0), STATUS.name))
        assert spin_until(final)
        time.sleep(0.3)
        spin_until(lambda: False, timeout=0.1)
    finally:
        close()
    name, values, message, hardware_id = final()
    assert values['state'] == 'done', message
    assert message == 'rig finished'
    assert values['foreign_dropped'] == str(2 * len(ids))
    assert seal.status_ok(_with_id(status_msg(name, 'done', message, **{
        k: v for k, v in values.items() if k != 'state'}), hardware_id), STATUS.name)
    # every report of the controller carries the run's seal
    mine = [r for r in reports if r[0] == 'force_servo_controller']
    assert all(r[3].startswith('seft#') for r in mine), mine
    warnings = [r[2] for r in mine if 'warning' in r[1]]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith('foreign publisher on /seft/status: '), warnings
    assert 'its status report was not sealed for this run' in warnings[0]


def _with_id(msg, hardware_id):
    msg.hardware_id = hardware_id
    return msg
