"""The link between the hosts of a split run, measured by the runners (``seft run --nodes``).

Before their nodes start, the runners of a run over several hosts meet on DDS:

1. every runner announces itself and the nodes it starts (``/seft/link/hello``, latched);
2. the **reference** runner (the one that runs the recorder: its host's clock is the run's
   clock, :mod:`seft_msgs_py.clock`) waits until the announced nodes cover the graph, then
   pings every other runner (``/seft/link/ping``; each answers on ``/seft/link/pong``) for
   :data:`BURST_S`, and estimates each link's round trip and the other host's clock offset
   (:mod:`seft_ros.core.link_probe`, four timestamps as NTP);
3. it decides (:func:`decide`): where a builder and a rig it commands are on different hosts
   and ``network_delay_s`` is 0 (``auto``), the playout delay covers the longest round trip's
   p99 plus :data:`~seft_ros.core.link_probe.PLAYOUT_MARGIN_S`; where the ground-motion
   publisher and a builder are on different hosts, the preview covers it too; and publishes
   the decision with every host's offset (``/seft/link/decision``, latched);
4. every other runner waits for the decision and starts its nodes with it (the parameters of
   all hosts then agree) and its host's offset (:data:`~seft_msgs_py.clock.OFFSET_ENV`).

During the run the reference pings every host once a second (a host that stops hearing them
after its own nodes have ended takes the reference for lost, and the reference takes a host
that stops answering them, and whose nodes are silent too, for lost:
``REFERENCE_SILENT_S`` of seft_ros.cli.runner) and publishes the link figures
(``/seft/link``), which the recorder writes into the bag: round trip p50/p99/max and offset
per host pair, and the emulation used (:data:`EMULATION_ENV`, which ``tools/hosts.sh`` sets).
"""

import json
import math
import os
import socket
import time
from typing import Callable

from std_msgs.msg import String

from seft_msgs_py import clock
from seft_msgs_py.errors import SeftError
from seft_msgs_py.graph import Graph, qualified
from seft_msgs_py.topics import CLOCK_QOS, STATUS_QOS
from seft_ros.core.link_probe import (
    PLAYOUT_MARGIN_S,
    PingSample,
    estimate,
    playout_steps,
    preview_steps,
)

__all__ = ['LinkPhase', 'decide', 'HELLO', 'PING', 'PONG', 'DECISION', 'LINK', 'BURST_S',
           'EMULATION_ENV', 'SITE_ENV']

HELLO = '/seft/link/hello'
PING = '/seft/link/ping'
PONG = '/seft/link/pong'
DECISION = '/seft/link/decision'
#: The link figures during the run (recorded into the bag).
LINK = '/seft/link'
#: How long the reference pings each host before the nodes start [s].
BURST_S = 1.5
#: Pings a second during the burst.
BURST_HZ = 40.0
#: The link emulation a script set up (``tools/hosts.sh``: 'netem', 'link emulator', ...).
EMULATION_ENV = 'SEFT_LINK_EMULATION'
#: This runner's site name (``seft run --site``), else the host name and pid.
SITE_ENV = 'SEFT_SITE'

#: Announcements, decisions and figures: reliable, latched (as the statuses).
_LATCHED = STATUS_QOS
#: Pings and answers: reliable, volatile (a late joiner needs no old ping; as /clock).
_LIVE = CLOCK_QOS


def decide(params: dict, hosts: dict[str, list[str]], estimates: dict[str, dict],
           reference: str) -> dict:
    """The playout delay and the preview of a split run from the measured links.

    Parameters
    ----------
    params : dict
        The run's parameters.
    hosts : dict of str to list of str
        Host -> the nodes it starts (the reference's included).
    estimates : dict of str to dict
        Host -> its link to the reference (:meth:`~seft_ros.core.link_probe.LinkEstimate.as_dict`).
    reference : str
        The reference host.

    Returns
    -------
    dict
        ``{'network_delay_s', 'preview_steps', 'playout': 'auto' | 'given' | 'none',
        'round_trip_p99_ms'}``: the values the nodes of every host get (in lockstep the
        run's own: the nodes wait for their inputs there).
    """
    graph = Graph.from_parameters(params)
    where = {n: h for h, nodes in hosts.items() for n in nodes}
    realtime = params.get('mode') == 'realtime'

    def trip_ms(a: str, b: str) -> float:
        """The round trip between hosts a and b [ms] (through the reference if neither is)."""
        if a == b:
            return 0.0
        legs = [h for h in (a, b) if h != reference]
        return sum(estimates[h]['round_trip_ms']['p99'] for h in legs)
    dt = float(params['dt'])
    crossing, preview_trip = 0.0, 0.0
    for builder in graph.builder_nodes():
        for rig in graph.local_rigs(builder):
            # the node that takes the rig's reference force (a playout delay needs a force
            # servo controller: the servohydraulic rig)
            target = qualified('force_servo_controller', rig)
            if graph.has_controller(rig) and builder in where and target in where:
                crossing = max(crossing, trip_ms(where[builder], where[target]))
        if builder in where and 'ground_motion_publisher' in where:
            # the publisher follows the rig's /clock: the rig's host to the publisher and on
            rig_host = where.get(graph.master, where[builder])
            preview_trip = max(preview_trip,
                               trip_ms(rig_host, where['ground_motion_publisher'])
                               + trip_ms(where['ground_motion_publisher'], where[builder]))
    out = {'network_delay_s': float(params.get('network_delay_s', 0.0)),
           'preview_steps': int(params['preview_steps']),
           'round_trip_p99_ms': crossing, 'playout': 'none'}
    if not realtime:
        # lockstep: every node waits for its inputs, the network only slows the run down
        return out
    if crossing == 0.0 and out['network_delay_s'] > 0.0:
        # every builder beside its rigs' controllers: no reference force crosses a link
        out.update(network_delay_s=0.0, playout='dropped: the loop does not cross hosts')
    if crossing > 0.0:
        if out['network_delay_s'] > 0.0:
            out['playout'] = 'given'
        else:
            steps = playout_steps(1e-3 * crossing, dt, PLAYOUT_MARGIN_S)
            out.update(network_delay_s=steps * dt, playout='auto')
    if preview_trip > 0.0:
        # one way each: the clock to the publisher, its samples to the builder
        out['preview_steps'] = preview_steps(0.5e-3 * preview_trip, dt,
                                             int(params['preview_steps']))
    return out


class LinkPhase:
    """The link measurement of one runner (module notes).

    Parameters
    ----------
    node : rclpy.node.Node
        The runner's node.
    spin : callable(seconds)
        Spins the runner's executor.
    progress : callable(str)
        Progress lines.
    site : str, optional
        This host's name (default ``$SEFT_SITE``, else host name and pid).
    """

    def __init__(self, node, spin: Callable[[float], None], progress: Callable[[str], None],
                 site: str | None = None):
        self.node, self.spin, self.progress = node, spin, progress
        self.site = site or os.environ.get(SITE_ENV) or f'{socket.gethostname()}:{os.getpid()}'
        self.emulation = os.environ.get(EMULATION_ENV, 'none')
        self.hellos: dict[str, dict] = {}
        self.decisions: dict[str, dict] = {}
        self.samples: dict[str, list[PingSample]] = {}
        self._seq = 0
        self._sent: dict[int, tuple[str, int]] = {}
        self._last_ping = -math.inf
        self._last_publish = 0.0
        #: The reference: when each host last answered a ping, and when this runner's pings
        #: of the run in progress began (monotonic [s]; a host's silence counts from then)
        self.answered_at: dict[str, float] = {}
        self._pinging_since = 0.0
        self.label = ''
        self.reference = False
        self.decision: dict | None = None
        #: When this host last heard the reference (monotonic [s]; its decision, its pings)
        self.reference_heard_at: float | None = None
        self.hello_pub = node.create_publisher(String, HELLO, _LATCHED)
        self.decision_pub = node.create_publisher(String, DECISION, _LATCHED)
        self.link_pub = node.create_publisher(String, LINK, _LATCHED)
        self.ping_pub = node.create_publisher(String, PING, _LIVE)
        self.pong_pub = node.create_publisher(String, PONG, _LIVE)
        node.create_subscription(String, HELLO, self._on_hello, _LATCHED)
        node.create_subscription(String, DECISION, self._on_decision, _LATCHED)
        node.create_subscription(String, PING, self._on_ping, _LIVE)
        node.create_subscription(String, PONG, self._on_pong, _LIVE)

    # -- messages ---------------------------------------------------------------------------

    def _send(self, pub, **doc) -> None:
        pub.publish(String(data=json.dumps(doc, sort_keys=True)))

    def _on_hello(self, msg) -> None:
        doc = json.loads(msg.data)
        if doc.get('site') != self.site:
            self.hellos[doc['site']] = doc

    def _on_decision(self, msg) -> None:
        doc = json.loads(msg.data)
        self.decisions[doc['label']] = doc

    def _on_ping(self, msg) -> None:
        t2 = clock.system_ns()
        doc = json.loads(msg.data)
        if doc.get('to') != self.site:
            return
        self.reference_heard_at = time.monotonic()
        self._send(self.pong_pub, to=doc['from'], frm=self.site, seq=doc['seq'], t1=doc['t1'],
                   t2=t2, t3=clock.system_ns())

    def _on_pong(self, msg) -> None:
        t4 = clock.system_ns()
        doc = json.loads(msg.data)
        if doc.get('to') != self.site or doc['seq'] not in self._sent:
            return
        peer, t1 = self._sent.pop(doc['seq'])
        self.answered_at[peer] = time.monotonic()
        self.samples.setdefault(peer, []).append(PingSample(t1, doc['t2'], doc['t3'], t4))

    def _ping(self, peer: str) -> None:
        self._seq += 1
        t1 = clock.system_ns()
        self._sent[self._seq] = (peer, t1)
        self._send(self.ping_pub, to=peer, **{'from': self.site}, seq=self._seq, t1=t1)

    # -- the start of a run -----------------------------------------------------------------

    def agree(self, params: dict, label: str, local: list[str], graph: Graph,
              timeout_s: float) -> dict:
        """Meet the other runners, measure the links (the reference) and agree on the
        values of the run (module notes).

        Returns
        -------
        dict
            The decision: ``network_delay_s``, ``preview_steps``, ``offsets_ns`` (host ->
            its clock minus the reference's), ``links``, ``playout`` and ``run_token`` (the
            reference's, which every host's nodes take: ``seft_msgs_py.provenance``).

        Raises
        ------
        SeftError
            The other hosts did not show up, or did not decide, within `timeout_s`.
        """
        self.label = label
        self.reference = 'recorder' in local
        self.samples.clear()
        self._send(self.hello_pub, site=self.site, label=label, nodes=list(local),
                   reference=self.reference)
        deadline = time.monotonic() + timeout_s
        if not self.reference:
            while label not in self.decisions:
                if time.monotonic() > deadline:
                    raise SeftError(f'no link decision from the host with the recorder after '
                                    f'{timeout_s:.0f} s (is seft run --site compute running '
                                    'there, in the same ROS domain?)')
                self.spin(0.05)
            self.decision = self.decisions[label]
            self.reference_heard_at = time.monotonic()
            return self.decision
        wanted = set(['recorder', *graph.nodes()])
        said = 0.0
        while True:
            hosts = {s: h['nodes'] for s, h in self.hellos.items() if h.get('label') == label}
            covered = set(local).union(*hosts.values()) if hosts else set(local)
            if wanted <= covered:
                break
            if time.monotonic() > deadline:
                raise SeftError('the other hosts of the run did not show up after '
                                f'{timeout_s:.0f} s: missing ' + ', '.join(
                                    sorted(wanted - covered)))
            if time.monotonic() - said > 10.0:
                said = time.monotonic()
                self.progress('waiting for the other hosts: '
                              + ', '.join(sorted(wanted - covered)))
            self.spin(0.05)
        peers = sorted(hosts)
        end = time.monotonic() + BURST_S
        while time.monotonic() < end:
            for peer in peers:
                self._ping(peer)
            self.spin(1.0 / BURST_HZ)
        self.spin(0.2)
        links = {}
        for peer in peers:
            if not self.samples.get(peer):
                raise SeftError(f'host {peer} did not answer the link pings')
            links[peer] = estimate(self.samples[peer]).as_dict()
        everyone = dict(hosts, **{self.site: list(local)})
        decision = decide(params, everyone, links, self.site)
        decision.update(label=label, reference=self.site, links=links,
                        emulation=self.emulation, run_token=params.get('run_token', 'none'),
                        offsets_ns={p: int(round(1e6 * links[p]['offset_ms'])) for p in peers})
        self._send(self.decision_pub, **decision)
        self.decision = decision
        self._publish_link()
        return decision

    def offset_ns(self) -> int:
        """This host's clock minus the reference's [ns], from the decision (0 for the
        reference)."""
        if self.reference or self.decision is None:
            return 0
        return int(self.decision.get('offsets_ns', {}).get(self.site, 0))

    # -- during the run ---------------------------------------------------------------------

    def reference_silent_s(self) -> float:
        """How long this host has not heard the reference host [s]: since its last ping (once
        a second during the run) or its decision; 0 on the reference itself."""
        if self.reference or self.reference_heard_at is None:
            return 0.0
        return time.monotonic() - self.reference_heard_at

    def hosts_silent_s(self) -> dict[str, float]:
        """The reference: how long each other host has not answered its pings [s], counted
        from the first ping of the run in progress (none while its nodes start); {} elsewhere."""
        if not self.reference or self.decision is None:
            return {}
        now = time.monotonic()
        return {p: now - max(self.answered_at.get(p, -math.inf), self._pinging_since)
                for p in self.decision['links']}

    def tick(self) -> None:
        """The reference: a ping to every host each second, the figures every 2 s."""
        if not self.reference or self.decision is None:
            return
        now = time.monotonic()
        if now - self._last_ping >= 1.0:
            if now - self._last_ping > 2.0:
                self._pinging_since = now     # pings resume: a run is watched from here
            self._last_ping = now
            for peer in self.decision['links']:
                self._ping(peer)
        if now - self._last_publish >= 2.0:
            self._publish_link()

    def _publish_link(self) -> None:
        self._last_publish = time.monotonic()
        links = {p: estimate(s).as_dict() for p, s in self.samples.items() if s}
        self._send(self.link_pub, label=self.label, reference=self.site,
                   emulation=self.emulation, links=links,
                   network_delay_s=self.decision.get('network_delay_s'),
                   preview_steps=self.decision.get('preview_steps'),
                   playout=self.decision.get('playout'),
                   decided_round_trip_p99_ms=self.decision.get('round_trip_p99_ms'))

