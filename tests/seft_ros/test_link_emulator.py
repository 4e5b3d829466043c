"""The link emulator's packet wire (``seft_ros.cli.link_emulator.PacketWire``): packets move
between two descriptors after the link model's delay, in order, dropped at its loss rate.

The TUN devices need root; the wire itself is tested here on datagram socket pairs, which
keep packet boundaries as a TUN device does. The namespaces test runs it on TUN devices.
"""

import heapq
import os
import socket
import time

import pytest

from seft_ros.cli.link_emulator import PacketWire, main
from seft_ros.core.link import LinkModel


@pytest.fixture
def ends():
    """Two 'hosts' (a, b) and the wire's two descriptors between them."""
    a, wire_a = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    b, wire_b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    for s in (a, b, wire_a, wire_b):
        s.setblocking(False)
    yield a, b, (wire_a.fileno(), wire_b.fileno())
    for s in (a, b, wire_a, wire_b):
        s.close()


def _pump_until(wire, cond, receive, timeout=5.0):
    """Pump the wire, and take what it delivered at once (`receive`), until `cond`."""
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        wire.pump(0.01)
        receive()


def _recv_all(sock):
    got = []
    while True:
        try:
            got.append((time.monotonic(), sock.recv(70000)))
        except BlockingIOError:
            return got


def test_packets_cross_after_the_delay_in_order_both_ways(ends):
    a, b, fds = ends
    delay = 0.020
    wire = PacketWire(fds, (LinkModel(delay, 0.004, seed=1, resend=False),
                            LinkModel(delay, seed=2, resend=False)))
    sent, got, back = {}, [], []

    def receive():
        got.extend(_recv_all(b))
        back.extend(_recv_all(a))

    for i in range(50):
        payload = i.to_bytes(4, 'big') * 300            # 1200 bytes
        sent[payload] = time.monotonic()
        a.send(payload)
        b.send(b'back' + payload[:4])
        wire.pump(0.0)
        receive()
        time.sleep(0.002)
    _pump_until(wire, lambda: wire.forwarded == [50, 50], receive)
    assert wire.forwarded == [50, 50] and wire.dropped == [0, 0]
    # a -> b: every packet, whole and in order, held delay +/- jitter (plus select's slack)
    assert [p for _, p in got] == list(sent)
    holds = [t - sent[p] for t, p in got]
    assert min(holds) >= 0.016 - 1e-3
    assert max(holds) <= 0.024 + 0.015                  # a loaded machine's wake-up
    assert sorted(holds)[len(holds) // 2] <= 0.024 + 0.003
    assert [p for _, p in back] == [b'back' + i.to_bytes(4, 'big') for i in range(50)]


def test_no_delay_forwards_at_once(ends):
    a, b, fds = ends
    wire = PacketWire(fds, (LinkModel(resend=False), LinkModel(resend=False)))
    a.send(b'x' * 1500)
    wire.pump(0.5)
    assert wire.forwarded == [1, 0]
    assert b.recv(2000) == b'x' * 1500


def test_loss_drops_packets_at_its_rate(ends):
    a, b, fds = ends
    wire = PacketWire(fds, (LinkModel(loss=0.2, seed=5, resend=False), LinkModel()))
    n, got = 2000, []

    def receive():
        got.extend(int.from_bytes(p, 'big') for _, p in _recv_all(b))

    for i in range(n):
        a.send(i.to_bytes(4, 'big'))
        if i % 5 == 4:                                   # within the sockets' queues
            wire.pump(0.0)
            receive()
    _pump_until(wire, lambda: sum(wire.forwarded) + sum(wire.dropped) >= n, receive)
    assert wire.failed == [0, 0]
    assert wire.dropped[0] == n - len(got)
    assert wire.dropped[0] == pytest.approx(0.2 * n, abs=4 * (0.16 * n) ** 0.5)
    assert got == sorted(got)                            # the rest in order


def test_a_closed_receiver_counts_undeliverable(ends):
    a, b, fds = ends
    wire = PacketWire(fds, (LinkModel(resend=False), LinkModel(resend=False)))
    b.close()
    a.send(b'lost')
    wire.pump(0.5)
    assert wire.forwarded == [0, 0] and wire.failed == [1, 0]


@pytest.mark.parametrize('args, text', [
    (['--devices', 'a', 'b', '--delay-ms', '1', '--jitter-ms', '2'],
     'link_emulator: error: jitter 0.002 s: expected 0 .. delay'),
    (['--devices', 'x' * 20, 'b'], "link_emulator: error: cannot create TUN device 'xxxx"),
    (['--devices', 'a', 'b', '--cut-on-signal', 'a'],
     'link_emulator: error: --cut-on-signal: expected a hub (--port ...)'),
    (['--port', 'hc,10.9.0.1,0,0,0', '--port', 'ha,10.9.0.2,5,1,0', '--cut-on-signal', 'hb'],
     'link_emulator: error: --cut-on-signal hb: not a --port name (ports: hc, ha)'),
])
def test_bad_arguments_are_one_line(args, text, capsys):
    if os.geteuid() != 0 and '--jitter-ms' not in args and '--cut-on-signal' not in args:
        text = 'link_emulator: error: cannot create TUN device'
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(text) and len(err.splitlines()) == 1


def _ipv4(src: str, dst: str, payload: bytes = b'x' * 32) -> bytes:
    """A minimal IPv4 packet (header fields the hub reads: version and addresses)."""
    import ipaddress
    header = bytearray(20)
    header[0] = 0x45
    header[12:16] = ipaddress.IPv4Address(src).packed
    header[16:20] = ipaddress.IPv4Address(dst).packed
    return bytes(header) + payload


@pytest.fixture
def star():
    """Three hosts (compute, lab_a, lab_b) and the hub's three descriptors."""
    pairs = [socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM) for _ in range(3)]
    for pair in pairs:
        for s in pair:
            s.setblocking(False)
    yield [p[0] for p in pairs], [p[1].fileno() for p in pairs]
    for pair in pairs:
        for s in pair:
            s.close()


ADDRS = ['10.9.0.1', '10.9.0.2', '10.9.0.3']


def test_the_hub_routes_through_the_compute_host_with_each_links_delay(star):
    """Lab a's link 10 ms, lab b's 20 ms, the compute host in the middle: a -> compute
    10 ms, compute -> b 20 ms, a -> b 30 ms (the star's route), multicast from a to both
    others with its route's delay; a packet that is not IPv4, or to nobody, is not routed."""
    from seft_ros.cli.link_emulator import PacketHub
    hosts, fds = star
    models = [(None, None),
              (LinkModel(0.010, seed=1, resend=False), LinkModel(0.010, seed=2, resend=False)),
              (LinkModel(0.020, seed=3, resend=False), LinkModel(0.020, seed=4, resend=False))]
    hub = PacketHub(fds, ADDRS, models)
    t0 = time.monotonic()
    hosts[1].send(_ipv4(ADDRS[1], ADDRS[0], b'to compute'))
    hosts[0].send(_ipv4(ADDRS[0], ADDRS[2], b'to b'))
    hosts[1].send(_ipv4(ADDRS[1], ADDRS[2], b'a to b'))
    hosts[1].send(_ipv4(ADDRS[1], '239.255.0.1', b'discovery'))
    hosts[2].send(b'\x60' + b'\x00' * 40)                      # IPv6: not routed
    hosts[2].send(_ipv4(ADDRS[2], '10.9.0.99'))                 # nobody there
    got = {i: [] for i in range(3)}

    def receive():
        for i in range(3):
            got[i].extend((t - t0, p[20:]) for t, p in _recv_all(hosts[i]))
    _pump_until(hub, lambda: sum(map(len, got.values())) >= 5, receive)
    arrivals = {(i, payload): t for i in got for t, payload in got[i]}
    assert set(arrivals) == {(0, b'to compute'), (2, b'to b'), (2, b'a to b'),
                             (0, b'discovery'), (2, b'discovery')}
    for (host, payload), want in {(0, b'to compute'): 0.010, (2, b'to b'): 0.020,
                                  (2, b'a to b'): 0.030, (0, b'discovery'): 0.010,
                                  (2, b'discovery'): 0.030}.items():
        assert want <= arrivals[host, payload] < want + 0.02, (host, payload)
    assert hub.unroutable == [0, 0, 2]
    assert hub.forwarded == [1, 4, 0]            # per copy: the discovery packet twice


def test_a_cut_link_drops_everything_both_ways_at_once(star):
    """Lab b's link (20 ms) cut while a packet to it and one from it are on their way: both
    are lost, and so is what b sends or is sent after; lab a and the compute host go on."""
    from seft_ros.cli.link_emulator import PacketHub
    hosts, fds = star
    models = [(None, None),
              (LinkModel(0.010, seed=1, resend=False), LinkModel(0.010, seed=2, resend=False)),
              (LinkModel(0.020, seed=3, resend=False), LinkModel(0.020, seed=4, resend=False))]
    hub = PacketHub(fds, ADDRS, models)
    hosts[0].send(_ipv4(ADDRS[0], ADDRS[2], b'to b, in flight'))
    hosts[2].send(_ipv4(ADDRS[2], ADDRS[0], b'from b, in flight'))
    hub.pump(0.0)
    assert len(hub.queue) == 2
    at = hub.cut(2)
    assert hub.queue == [] and hub.cut(2) == at           # a cut link stays cut, once
    hosts[0].send(_ipv4(ADDRS[0], ADDRS[2], b'to b, after'))
    hosts[2].send(_ipv4(ADDRS[2], '239.255.0.1', b'from b, after'))   # 2 copies
    hosts[1].send(_ipv4(ADDRS[1], '239.255.0.1', b'a, multicast'))    # b's copy lost
    got = {i: [] for i in range(3)}

    def receive():
        for i in range(3):
            got[i].extend(p[20:] for _, p in _recv_all(hosts[i]))
    _pump_until(hub, lambda: got[0], receive)
    time.sleep(0.05)
    hub.pump(0.0)
    receive()
    assert got == {0: [b'a, multicast'], 1: [], 2: []}
    assert hub.cut_off == [2, 1, 3] and hub.forwarded == [0, 1, 0]
    assert hub.summary(['compute', 'lab_a', 'lab_b']).endswith(
        'lab_b: 0 forwarded, 0 dropped, 0 undeliverable, 0 unroutable, 3 lost to the cut')
    # a packet to b that was read just before the cut (the cut comes from a signal handler,
    # between two of the hub's statements) and queued after it is not written either
    heapq.heappush(hub.queue, (0.0, 99, 2, 0, _ipv4(ADDRS[0], ADDRS[2], b'raced')))
    hub.pump(0.0)
    assert _recv_all(hosts[2]) == [] and hub.cut_off[0] == 3
    with pytest.raises(IndexError, match='host 3: expected 0..2'):
        hub.cut(3)
