"""A foreign sender on a run's ROS domain (issue 42's intruder), for the tests.

``python intruder.py TOPIC VALUE RATE_HZ SECONDS [copy]``: a node named ``intruder`` publishes
``geometry_msgs/WrenchStamped`` messages with ``wrench.force.x = VALUE`` on TOPIC (seft's data
QoS, so that the run's subscriptions match it), RATE_HZ of them a second for SECONDS, each
stamped for one of the next five samples of the run (it reads the rig's measurement to know
where the run is); ``copy``: with the frame id it sees on TOPIC (a sender that copies the
run's seal in the clear), else ``'actuator'``. On a record stream (``/seft/record/...``) it
sends record batches instead: one row ``[k, VALUE, VALUE, ...]`` each, labelled as the
stream's. It prints ``sent N`` when it is done.
"""

import sys
import time

from geometry_msgs.msg import WrenchStamped
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from seft_msgs_py.convert import FieldsReader, frame_id_of_raw
from seft_msgs_py.signals import MEASUREMENT_FIELDS, RECORD_STREAMS
from seft_msgs_py.topics import DATA_QOS, MEASUREMENT


def main(argv):
    topic, value, rate, seconds = argv[0], float(argv[1]), float(argv[2]), float(argv[3])
    copy = argv[4:] == ['copy']
    rclpy.init()
    node = rclpy.create_node('intruder')
    stream = next((r for r in RECORD_STREAMS if r.name == topic), None)
    pub = node.create_publisher(WrenchStamped if stream is None else Float64MultiArray, topic,
                                DATA_QOS)
    seen = {'step': None, 'frame': 'actuator'}
    read = FieldsReader(MEASUREMENT.msg_type, MEASUREMENT_FIELDS)

    def on_measurement(raw):
        stamp, _ = read(raw)
        seen['step'] = stamp // 2_000_000

    def on_command(raw):
        seen['frame'] = frame_id_of_raw(raw, WrenchStamped).decode()
    node.create_subscription(MEASUREMENT.msg_type, MEASUREMENT.name, on_measurement, DATA_QOS,
                             raw=True)
    if copy:
        node.create_subscription(WrenchStamped, topic, on_command, DATA_QOS, raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    msg = WrenchStamped()
    msg.wrench.force.x = value
    batch = Float64MultiArray()
    if stream is not None:
        width = 1 + len(stream.columns)
        batch.layout.dim = [MultiArrayDimension(label='step', size=1, stride=width),
                            MultiArrayDimension(label=stream.labels, size=width,
                                                stride=width)]
    sent, i = 0, 0
    end = time.monotonic() + seconds
    period = 1.0 / rate
    next_at = time.monotonic()
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0)
        if seen['step'] is None or (copy and seen['frame'] == 'actuator'):
            time.sleep(0.001)
            continue
        k = seen['step'] + 1 + i % 5
        i += 1
        if stream is not None:
            batch.data = [float(k)] + [value] * len(stream.columns)
            pub.publish(batch)
        else:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 2_000_000, 10 ** 9)
            msg.header.frame_id = seen['frame']
            pub.publish(msg)
        sent += 1
        next_at += period
        delay = next_at - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    print(f'sent {sent}', flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main(sys.argv[1:])
