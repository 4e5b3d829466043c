"""link_emulator: the network between two hosts, emulated by relaying DDS domains.

Where the kernel has no ``tc netem`` (this machine's has not), a distributed test's two
"hosts" use two ROS domains, and this process joins them: it subscribes to every live topic
of the graph on the side of the node that publishes it and republishes it on the other side,
after the delay, jitter and loss of :class:`seft_ros.core.link.LinkModel`. Topics every node
publishes (``/seft/status``, ``/seft/node_parameters``) go both ways; the relay recognises its
own republished messages and does not send them back.

Raw (serialized) messages are relayed, so nothing is converted; each topic keeps its QoS
(reliable, transient-local where the graph's is). Each side has its own context and
executor thread (rclpy's SingleThreadedExecutor: the EventsExecutor keeps the GIL while it
waits, which starves the other threads); a sender thread publishes every message at its
departure time.

Run: ``ros2 run seft_ros link_emulator --lab-domain 201 --compute-domain 202
--lab-nodes rig,force_servo_controller --delay-ms 5 --jitter-ms 1 --loss 0.01``
(``tools/two_hosts.sh`` starts it). Ctrl-C ends it with a line of what it relayed.
"""

import argparse
from collections import Counter
import heapq
import itertools
import signal
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from seft_msgs_py import parameters
from seft_msgs_py.topics import (
    CLOCK,
    LINK_EMULATOR_NODE,
    MEASUREMENT,
    NODE_PARAMETERS,
    RECORD,
    REFERENCE_FORCE,
    RUN_PARAMETERS,
    STATUS,
    VALVE_COMMAND,
)
from seft_ros.core.link import LinkModel

__all__ = ['LIVE_TOPICS', 'LinkEmulator', 'main']

#: The topics the graph's nodes exchange while a run goes (the bag-only topics are not sent).
LIVE_TOPICS = (CLOCK, REFERENCE_FORCE, VALVE_COMMAND, MEASUREMENT, STATUS, NODE_PARAMETERS,
               RUN_PARAMETERS) + tuple(RECORD.values())
SIDES = ('lab', 'compute')


class LinkEmulator:
    """Relays the graph's live topics between two domains with an emulated link.

    Parameters
    ----------
    domains : dict
        ``{'lab': id, 'compute': id}``: the ROS domain of each side.
    lab_nodes : iterable of str
        The graph's nodes on the lab side (the others are on the compute side).
    delay_s, jitter_s, loss, seed
        The link (:class:`~seft_ros.core.link.LinkModel`), the same both ways.

    Raises
    ------
    ValueError
        A node name that is not a graph node, or a link parameter out of range.
    """

    def __init__(self, domains: dict, lab_nodes, *, delay_s=0.0, jitter_s=0.0, loss=0.0,
                 seed=0):
        lab_nodes = set(lab_nodes)
        unknown = lab_nodes - set(parameters.NODES)
        if unknown:
            raise ValueError(f'--lab-nodes {",".join(sorted(unknown))}: expected graph nodes '
                             f'({", ".join(parameters.NODES)})')
        self.contexts, self.nodes, self.executors = {}, {}, {}
        for side in SIDES:
            ctx = rclpy.Context()
            rclpy.init(context=ctx, domain_id=int(domains[side]),
                       signal_handler_options=SignalHandlerOptions.NO)
            self.contexts[side] = ctx
            self.nodes[side] = Node(LINK_EMULATOR_NODE, context=ctx)
            self.executors[side] = SingleThreadedExecutor(context=ctx)
            self.executors[side].add_node(self.nodes[side])
        self.queue: list = []
        self.cond = threading.Condition()
        self.order = itertools.count()
        self.echo = {side: Counter() for side in SIDES}   # what the relay sent on each side
        self.relayed = Counter()
        self.models = []
        self.running = True
        for i, spec in enumerate(LIVE_TOPICS):
            if spec.publisher.startswith('('):            # every node publishes it
                sources = SIDES
            else:
                sources = ('lab',) if spec.publisher in lab_nodes else ('compute',)
            for j, src in enumerate(sources):
                dst = SIDES[1 - SIDES.index(src)]
                pub = self.nodes[dst].create_publisher(spec.msg_type, spec.name, spec.qos)
                model = LinkModel(delay_s, jitter_s, loss, seed=seed * 1000 + 2 * i + j)
                self.models.append(model)
                self.nodes[src].create_subscription(
                    spec.msg_type, spec.name,
                    lambda raw, s=src, d=dst, p=pub, m=model, n=spec.name:
                        self._arrive(s, d, p, m, n, raw),
                    spec.qos, raw=True)
        self.threads = [threading.Thread(target=self.executors[s].spin, daemon=True)
                        for s in SIDES]
        self.threads.append(threading.Thread(target=self._send, daemon=True))

    def _arrive(self, src, dst, pub, model, name, raw: bytes) -> None:
        if self.echo[src][raw]:               # our own copy of a message from the other side
            self.echo[src][raw] -= 1
            if not self.echo[src][raw]:
                del self.echo[src][raw]
            return
        with self.cond:
            heapq.heappush(self.queue, (model.departure(time.monotonic()), next(self.order),
                                        dst, pub, name, raw))
            self.cond.notify()

    def _send(self) -> None:
        while self.running:
            with self.cond:
                while self.running and (not self.queue
                                        or self.queue[0][0] > time.monotonic()):
                    wait = self.queue[0][0] - time.monotonic() if self.queue else 0.1
                    self.cond.wait(timeout=max(wait, 0.0))
                if not self.running:
                    return
                _, _, dst, pub, name, raw = heapq.heappop(self.queue)
            if name in (STATUS.name, NODE_PARAMETERS.name):
                self.echo[dst][raw] += 1
            try:
                pub.publish(raw)
            except Exception:   # noqa: BLE001 - the context is shutting down
                return
            self.relayed[name] += 1

    def start(self) -> None:
        """Start relaying (threads)."""
        for t in self.threads:
            t.start()

    def close(self) -> str:
        """Stop relaying; return a one-line account of what was relayed."""
        self.running = False
        with self.cond:
            self.cond.notify_all()
        for side in SIDES:
            self.executors[side].shutdown(timeout_sec=1.0)
        for t in self.threads:
            t.join(timeout=2.0)
        for side in SIDES:
            self.nodes[side].destroy_node()
            rclpy.try_shutdown(context=self.contexts[side])
        lost = sum(m.lost for m in self.models)
        return (f'link emulator: relayed {sum(self.relayed.values())} messages '
                f'({self.relayed[MEASUREMENT.name]} measurements, '
                f'{self.relayed[REFERENCE_FORCE.name]} reference forces), {lost} resent after '
                'a loss')


def build_parser() -> argparse.ArgumentParser:
    """The emulator's arguments."""
    p = argparse.ArgumentParser(prog='link_emulator', description=__doc__.splitlines()[0])
    p.add_argument('--lab-domain', type=int, required=True, help='ROS domain of the lab host')
    p.add_argument('--compute-domain', type=int, required=True,
                   help='ROS domain of the compute host')
    p.add_argument('--lab-nodes', default='rig,force_servo_controller',
                   help='graph nodes on the lab host (default: rig,force_servo_controller)')
    p.add_argument('--delay-ms', type=float, default=0.0, help='one-way delay [ms]')
    p.add_argument('--jitter-ms', type=float, default=0.0,
                   help='half-width of the uniform jitter [ms] (<= delay)')
    p.add_argument('--loss', type=float, default=0.0,
                   help='packet loss probability (a lost packet of these reliable topics is '
                   'resent 2 delay + 5 ms later)')
    p.add_argument('--seed', type=int, default=0, help='seed of the jitter and loss draws')
    return p


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros link_emulator``."""
    a = build_parser().parse_args(args)
    if a.lab_domain == a.compute_domain:
        print('link_emulator: error: --lab-domain and --compute-domain must differ (one '
              'domain per host)', file=sys.stderr)
        return 2
    try:
        relay = LinkEmulator({'lab': a.lab_domain, 'compute': a.compute_domain},
                             [n.strip() for n in a.lab_nodes.split(',') if n.strip()],
                             delay_s=1e-3 * a.delay_ms, jitter_s=1e-3 * a.jitter_ms,
                             loss=a.loss, seed=a.seed)
    except ValueError as exc:
        print(f'link_emulator: error: {exc}', file=sys.stderr)
        return 2
    relay.start()
    print(f'link emulator: domains lab={a.lab_domain} <-> compute={a.compute_domain}, delay '
          f'{a.delay_ms} ms +/- {a.jitter_ms} ms, loss {a.loss}', file=sys.stderr, flush=True)
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    while not stop.wait(0.2):
        pass
    print(relay.close(), file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
