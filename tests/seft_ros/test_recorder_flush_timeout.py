"""The recorder's flush time-out (issue 11, gap 5): a partial bag closed, and read back.

Two recorder processes (``python -m seft_ros.nodes.recorder``, one writing MCAP, one sqlite3)
record a scripted graph in the test session's ROS domain: one process with the delay rig's
three data nodes, which publishes known record rows and final statuses through the nodes' own
``RecordBatch``. The rig reports 'done' after 30 steps; the reference-force builder reports 30
published but only its first 20 rows reach the bag (10 lost on the way); the ground-motion
publisher never sends its final status (hung). Each recorder must wait ``FLUSH_TIMEOUT_S``
after the rig's final status, then close the bag anyway with its account of what is missing,
and the bag must read back from disk with the rows as sent.
"""

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from seft_ros.analysis.bag import read_run

DT = 0.002
N_RIG = 30          # steps the rig ran and published
N_BUILDER = 20      # reference forces that reach the recorder (the builder says 30)


def rig_row(k):
    """Row k of the rig's stream: measured force [N], x [m], x' [m/s], x'' [m/s^2]."""
    return [k, 100.0 + k, 1e-3 * k, -2e-3 * k, 0.5 * k]


ROWS = {
    'rig': [rig_row(k) for k in range(N_RIG)],
    'ground_motion_publisher': [[k, 0.01 * k] for k in range(N_RIG)],
    'reference_force_builder': [[k, 50.0 - k] for k in range(N_BUILDER)],
}
#: Final statuses: node -> (published count, extra values); the ground-motion publisher none.
FINALS = {'rig': (N_RIG, {'step': N_RIG, 'n_steps': N_RIG}),
          'reference_force_builder': (N_RIG, {})}

#: The scripted graph: argv[1] the rows, argv[2] the finals, argv[3] how many recorders.
FAKE_GRAPH = r"""
import json, sys, time
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from seft_msgs_py.convert import status_msg, status_values
from seft_msgs_py.node_support import RecordBatch
from seft_msgs_py.signals import record_streams_of
from seft_msgs_py.topics import STATUS

rows, finals, recorders = json.loads(sys.argv[1]), json.loads(sys.argv[2]), int(sys.argv[3])
rclpy.init()
try:
    nodes = {name: Node(name) for name in rows}
    executor = SingleThreadedExecutor()
    for node in nodes.values():
        executor.add_node(node)
    first = next(iter(nodes.values()))
    heard = []
    first.create_subscription(STATUS.msg_type, STATUS.name,
                              lambda m: heard.append((m.name, status_values(m))), STATUS.qos)
    status = first.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
    batches = {name: RecordBatch(node, record_streams_of(name)[0])
               for name, node in nodes.items()}

    def of_recorders(**values):
        return [v for name, v in heard
                if name == 'recorder' and all(v.get(k) == x for k, x in values.items())]

    def spin_until(done, timeout):
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                sys.exit(f'fake graph: timed out; heard {heard}')
            executor.spin_once(timeout_sec=0.05)

    # every recorder has discovered the three nodes' batches, and they its subscriptions
    spin_until(lambda: len(of_recorders(inputs='matched')) >= recorders and all(
        b.pub.get_subscription_count() >= recorders for b in batches.values()), 60.0)
    for name in nodes:
        status.publish(status_msg(name, 'ready', 'scripted'))
    for name, node_rows in rows.items():
        for row in node_rows:
            batches[name].add(*row)
        batches[name].flush()
    for name, (published, values) in finals.items():
        status.publish(status_msg(name, 'done', 'scripted', published=published, **values))
    spin_until(lambda: len(of_recorders(state='closed')) >= recorders, 60.0)
    print(json.dumps(of_recorders(state='closed')))
finally:
    rclpy.try_shutdown()
"""


def _stop(procs):
    for proc in procs:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.fixture(scope='module')
def timed_out(tmp_path_factory, ros_env):
    """Run the scripted graph and two recorders; return ``(bags by storage, the recorders'
    stderr, the closing statuses the graph heard)``."""
    root = tmp_path_factory.mktemp('flush_timeout')
    bags = {storage: root / f'bag_{storage}' for storage in ('mcap', 'sqlite3')}
    recorders = [subprocess.Popen(
        [sys.executable, '-m', 'seft_ros.nodes.recorder', '--ros-args', '-p',
         f'bag_path:={bag}', '-p', f'bag_storage:={storage}', '-p', 'rig_model:=delay'],
        cwd=root, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True) for storage, bag in bags.items()]
    graph = subprocess.Popen(
        [sys.executable, '-c', FAKE_GRAPH, json.dumps(ROWS), json.dumps(FINALS),
         str(len(recorders))], cwd=root, env=ros_env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = graph.communicate(timeout=120)
        assert graph.returncode == 0, err
        errs = []
        for proc in recorders:
            _, rec_err = proc.communicate(timeout=30)
            assert proc.returncode == 0, rec_err
            errs.append(rec_err)
    finally:
        _stop([graph, *recorders])
    return bags, errs, json.loads(out)


#: What each recorder must say it closed without: the hung node, then the short topic
#: (recorded/published), and 30 - 20 = 10 messages lost.
INCOMPLETE = 'ground_motion_publisher (no final status), /seft/reference_force (20/30)'


def test_the_recorder_closes_a_partial_bag_after_the_flush_time_out(timed_out):
    _, errs, closed = timed_out
    assert len(closed) == 2
    for values in closed:
        assert values['incomplete'] == INCOMPLETE
        assert values['lost'] == '10'
        assert (values['measured_force'], values['ground_acceleration'],
                values['reference_force']) == ('30', '30', '20')
    for err in errs:
        assert 'Traceback' not in err
        assert f'closing the bag without: {INCOMPLETE}' in err


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_the_partial_bag_reads_back_from_disk(timed_out, storage):
    bags, _, _ = timed_out
    bag = bags[storage]
    assert f'storage_identifier: {storage}' in (bag / 'metadata.yaml').read_text()
    # the closing status is the bag's last status, as the graph heard it
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        topics = {'/seft/status': [], '/seft/run_parameters': []}
        conns = [c for c in reader.connections if c.topic in topics]
        for c, _, raw in reader.messages(connections=conns):
            topics[c.topic].append(store.deserialize_cdr(raw, c.msgtype))
    # the run's parameters: this recorder's own, written first (read_run takes a node's
    # parameters from /seft/node_parameters, where the two recorders of this test overlap)
    (params,) = topics['/seft/run_parameters']
    assert json.loads(params.data)['bag_path'] == str(bag)
    last = topics['/seft/status'][-1]
    assert last.name == 'recorder'
    values = {kv.key: kv.value for kv in last.values}
    assert (values['state'], values['incomplete'], values['lost']) == ('closed', INCOMPLETE,
                                                                      '10')

    run = read_run(bag)
    assert run.params['rig_model'] == 'delay' and run.params['dt'] == DT
    # the complete steps are those the builder's 20 rows reach; every value as sent
    assert run.n_steps == N_BUILDER
    k = np.arange(N_BUILDER)
    np.testing.assert_array_equal(run.measured_force_N, 100.0 + k)
    np.testing.assert_array_equal(run.displacement_m, 1e-3 * k)
    np.testing.assert_array_equal(run.velocity_m_s, -2e-3 * k)
    np.testing.assert_array_equal(run.acceleration_m_s2, 0.5 * k)
    np.testing.assert_array_equal(run.ground_acceleration_m_s2, 0.01 * k)
    np.testing.assert_array_equal(run.reference_force_N, 50.0 - k)
    # what is lost is said: a gap from step 20 to the rig's last step 29, 10 messages
    gaps = run.extra['gaps']
    assert (gaps['at_step'], gaps['last_step'], gaps['steps_after_gap']) == (20, 29, 0)
    assert gaps['missing'] == {'/seft/reference_force': list(range(N_BUILDER, N_RIG))}
    assert run.extra['bag_lost_messages'] == 10
    assert run.extra['recording']['end'] == 'closed'
    assert run.extra['counts']['/seft/measured_force'] == N_RIG
