"""The link emulator relays the graph's live topics between two domains (two emulated hosts),
in order, after its delay, and sends every node's status across once (no echo)."""

import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from seft_msgs_py.convert import SerializedStamped, status_msg
from seft_msgs_py.domain import claim_domain
from seft_msgs_py.signals import MEASUREMENT_FIELDS
from seft_msgs_py.topics import MEASUREMENT, STATUS
from seft_ros.nodes.link_emulator import LinkEmulator


@pytest.fixture
def two_domains(ros_env):
    """The test session's domain (lab) and a second claimed one (compute)."""
    from conftest import DOMAIN_ID, DOMAIN_RANGE
    other, claim = claim_domain([d for d in DOMAIN_RANGE if d != DOMAIN_ID])
    yield DOMAIN_ID, other
    claim.close()


def test_relay_delays_in_order_and_sends_status_once(two_domains, monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    lab_domain, compute_domain = two_domains
    relay = LinkEmulator({'lab': lab_domain, 'compute': compute_domain},
                         ['rig', 'force_servo_controller'], delay_s=0.02, jitter_s=0.004)
    relay.start()
    ctx = {}
    nodes = {}
    for side, domain in (('lab', lab_domain), ('compute', compute_domain)):
        ctx[side] = rclpy.Context()
        rclpy.init(context=ctx[side], domain_id=domain)
        nodes[side] = Node(f'probe_{side}', context=ctx[side])
    got = {'measurement': [], 'status_compute': [], 'status_lab': []}
    nodes['compute'].create_subscription(
        MEASUREMENT.msg_type, MEASUREMENT.name,
        lambda m: got['measurement'].append((time.monotonic(), m.header.stamp.nanosec)),
        MEASUREMENT.qos)
    nodes['compute'].create_subscription(STATUS.msg_type, STATUS.name,
                                         lambda m: got['status_compute'].append(m.name),
                                         STATUS.qos)
    nodes['lab'].create_subscription(STATUS.msg_type, STATUS.name,
                                     lambda m: got['status_lab'].append(m.name), STATUS.qos)
    meas_pub = nodes['lab'].create_publisher(MEASUREMENT.msg_type, MEASUREMENT.name,
                                             MEASUREMENT.qos)
    status_pub = nodes['lab'].create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
    serialize = SerializedStamped.fields(MEASUREMENT.msg_type, MEASUREMENT_FIELDS)
    executors = {}
    for side in nodes:
        executors[side] = SingleThreadedExecutor(context=ctx[side])
        executors[side].add_node(nodes[side])

    def spin(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for ex in executors.values():
                ex.spin_once(timeout_sec=0.001)

    try:
        deadline = time.monotonic() + 20
        while meas_pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            spin(0.1)
        spin(1.0)
        sent = []
        status_pub.publish(status_msg('rig', 'running', 'probe'))
        for k in range(40):
            sent.append(time.monotonic())
            meas_pub.publish(serialize(k * 1000, (float(k), 0.0, 0.0, 0.0)))
            spin(0.01)
        spin(1.0)
    finally:
        summary = relay.close()
        for side in nodes:
            executors[side].shutdown()
            nodes[side].destroy_node()
            rclpy.try_shutdown(context=ctx[side])
    stamps = [s for _, s in got['measurement']]
    assert stamps == [k * 1000 for k in range(40)]          # every one, in order
    holds = [t - s for (t, _), s in zip(got['measurement'], sent)]
    assert min(holds) >= 0.016 - 0.001                      # delay - jitter, at least
    assert got['status_compute'] == ['rig']                 # across once
    assert got['status_lab'] == ['rig']                     # and not echoed back
    assert 'relayed' in summary
