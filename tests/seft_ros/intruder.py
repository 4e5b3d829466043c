"""A foreign sender on a run's ROS domain (issue 42's intruder), for the tests.

``python intruder.py TOPIC VALUE RATE_HZ SECONDS FROM_STEP [copy]``: a node named ``intruder``
waits until the rig's measurement shows the run at step FROM_STEP or later and its graph knows
a subscription on TOPIC (one of the run's), then creates its publisher on TOPIC (seft's data
QoS, so that the run's subscriptions match it) and sends ``geometry_msgs/WrenchStamped``
messages with ``wrench.force.x = VALUE``, RATE_HZ of them a second for SECONDS, each stamped
for one of the next five samples of the run; ``copy``: with the frame id it sees on TOPIC (a
sender that copies the run's seal in the clear), else ``'actuator'``. On a record stream
(``/seft/record/...``) it sends record batches instead: one row ``[k, VALUE, VALUE, ...]``
each, labelled as the stream's. On ``/seft/node_parameters`` it sends the parameters of a
node named ``recorder`` (the nodes-by-hand tutorial's: the schema's defaults, alpha VALUE,
``duration_s`` 4, mode lockstep) with ``run_token`` 'none' (a node of another run), or with
``copy`` the run's token read from ``/seft/run_parameters`` (a node of this run started with
other parameters), RATE_HZ messages a second for SECONDS.

Start it together with the run: its DDS participant then takes part in the run's start-up
discovery, and its publisher (a new endpoint of a known participant) reaches the run's nodes
within milliseconds. A participant that joins a running domain is discovered at the others'
next periodic announcement, up to ~3 s later with Fast DDS (``seft_ros.cli.runner``'s
``DISCOVERY_SETTLE_S``): no message of it reaches the run before then, and a 2 s burst started
mid-run could come and go unseen (what made the tests flaky, 2 of 5 runs on this machine). Even
started together, a participant may learn of another only at that announcement (with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, 14 processes started 0.3 s apart: some saw 6 of
the 14 for 3 s; in CI the intruder saw the rig's measurement but not the controller's
subscription for its whole 2 s burst, 'matched by 0'): hence it waits for the subscription.

It prints ``sent N, matched by M subscription(s), from step S`` when it is done (exit 0), or
``sent 0: ...`` and exits 1 when the run ended (its measurement silent for ``ENDED_S``) or
``WAIT_S`` passed before.
"""

import json
import sys
import threading
import time

from geometry_msgs.msg import WrenchStamped
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from seft_msgs_py import parameters
from seft_msgs_py.convert import FieldsReader, frame_id_of_raw
from seft_msgs_py.signals import MEASUREMENT_FIELDS, RECORD_STREAMS
from seft_msgs_py.topics import DATA_QOS, MEASUREMENT, NODE_PARAMETERS, RUN_PARAMETERS

#: The longest the intruder waits for the run to reach FROM_STEP [s].
WAIT_S = 90.0
#: The run counts as ended when its measurement has been silent this long [s]. At 2.0 s the
#: intruder said 'it ended at step 154' of a run that completed its 2000 steps (1 of 8 runs
#: of the test alone in session 39, and in two fresh-clone CIs): its measurement stopped
#: reaching this ordinary-priority process for 2 s while the run's nodes ran at SCHED_FIFO on
#: a loaded 2-core host (starved, or its best-effort reader dropping; not told apart). 0 of 6
#: such failures with 6 s.
ENDED_S = 6.0
#: The run's sample period [ns] (config/main.yaml).
DT_NS = 2_000_000


def main(argv) -> int:
    topic, value, rate, seconds = argv[0], float(argv[1]), float(argv[2]), float(argv[3])
    from_step = int(argv[4])
    copy = argv[5:] == ['copy']
    rclpy.init()
    node = rclpy.create_node('intruder')
    stream = next((r for r in RECORD_STREAMS if r.name == topic), None)
    node_parameters = topic == NODE_PARAMETERS.name
    seen = {'step': None, 'at': None, 'frame': 'actuator', 'from': None, 'token': None}
    read = FieldsReader(MEASUREMENT.msg_type, MEASUREMENT_FIELDS)
    reached = threading.Event()

    def known_subscriptions():
        return sum(info.node_name != 'intruder'
                   for info in node.get_subscriptions_info_by_topic(topic))

    def on_measurement(raw):
        stamp, _ = read(raw)
        seen['step'], seen['at'] = stamp // DT_NS, time.monotonic()
        copied = seen['token'] is not None if node_parameters else seen['frame'] != 'actuator'
        if (seen['step'] >= from_step and (not copy or copied)
                and not reached.is_set() and known_subscriptions() > 0):
            seen['from'] = seen['step']
            reached.set()

    def on_command(raw):
        seen['frame'] = frame_id_of_raw(raw, WrenchStamped).decode()
    node.create_subscription(MEASUREMENT.msg_type, MEASUREMENT.name, on_measurement, DATA_QOS,
                             raw=True)
    def on_run_parameters(msg):
        seen['token'] = json.loads(msg.data)['run_token']
    if copy and node_parameters:
        node.create_subscription(String, RUN_PARAMETERS.name, on_run_parameters,
                                 RUN_PARAMETERS.qos)
    elif copy:
        node.create_subscription(WrenchStamped, topic, on_command, DATA_QOS, raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    spinner = threading.Thread(target=spin)
    spinner.start()
    try:
        deadline = time.monotonic() + WAIT_S
        while not reached.wait(0.25):
            quiet = time.monotonic() - seen['at'] if seen['at'] is not None else 0.0
            if time.monotonic() > deadline or quiet > ENDED_S:
                print(f'sent 0: the run never reached step {from_step} with a subscription on '
                      f'{topic} known ({"it ended" if quiet > ENDED_S else "waited"} at step '
                      f'{seen["step"]}, {known_subscriptions()} subscription(s) known)',
                      flush=True)
                return 1
        if node_parameters:
            pub = node.create_publisher(String, topic, NODE_PARAMETERS.qos)
            values = {s.name: s.default for s in parameters.specs_for_node('recorder')}
            values.update(alpha=value, duration_s=4.0, mode='lockstep',
                          run_token=seen['token'] if copy else 'none')
            text = String(data=json.dumps({'node': 'recorder', 'parameters': values},
                                          sort_keys=True))
        else:
            pub = node.create_publisher(
                WrenchStamped if stream is None else Float64MultiArray, topic, DATA_QOS)
        msg = WrenchStamped()
        msg.wrench.force.x = value
        batch = Float64MultiArray()
        if stream is not None:
            width = 1 + len(stream.columns)
            batch.layout.dim = [MultiArrayDimension(label='step', size=1, stride=width),
                                MultiArrayDimension(label=stream.labels, size=width,
                                                    stride=width)]
        sent = matched = 0
        period = 1.0 / rate
        next_at = time.monotonic()
        end = next_at + seconds
        while time.monotonic() < end:
            k = seen['step'] + 1 + sent % 5
            if node_parameters:
                pub.publish(text)
            elif stream is not None:
                batch.data = [float(k)] + [value] * len(stream.columns)
                pub.publish(batch)
            else:
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * DT_NS, 10 ** 9)
                msg.header.frame_id = seen['frame']
                pub.publish(msg)
            sent += 1
            matched = max(matched, pub.get_subscription_count())
            next_at += period
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        print(f'sent {sent}, matched by {matched} subscription(s), from step {seen["from"]}',
              flush=True)
        return 0
    finally:
        stop.set()
        spinner.join()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
