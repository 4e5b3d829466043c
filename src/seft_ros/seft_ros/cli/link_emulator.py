"""link_emulator: the network between two hosts, emulated in user space (no ``tc netem``).

Where the kernel has no ``netem`` (this machine's has not), ``tools/two_hosts.sh`` joins its
two network namespaces ("lab" and "compute") not by a veth pair but by two TUN devices, one
in each namespace, and this process is the wire between them: every IP packet one side sends
is read from its TUN device, held for the delay, jitter and loss of
:class:`seft_ros.core.link.LinkModel` (one model per direction; a lost packet is dropped, as
netem drops it, and DDS's reliability protocol resends it), and written into the other side's
TUN device, where the kernel receives it as from a network. Both sides stay in one ROS
domain and DDS discovery (multicast) works across, so a run needs nothing that a real
network would not: it is the same ``seft run --nodes ...`` on both sides.

Packets, not topics, are what is delayed: a process that only moves bytes between two file
descriptors keeps up with a 500 Hz graph where a relay of ROS topics (deserializing and
publishing each message again through rclpy) did not on this 2-core machine.

**Several hosts** (``tools/hosts.sh``): a hub with one TUN device per host, the compute host
in the middle. Each lab's device has its own link to the hub (``--port
NAME,ADDRESS,DELAY_MS,JITTER_MS,LOSS``): a packet from lab A to the compute host waits A's
delay, one from the compute host to lab B waits B's, one from A to B both (the star's route
through the compute host); a multicast packet (DDS discovery) goes to every other host, each
copy with its route's delay. Packets are routed by their IPv4 destination. ``--cut-on-signal
NAME``: on SIGUSR1 the hub cuts NAME's link, both ways and at once (the packets on their way
too; a cut link stays cut), and prints the wall time of the cut. Cutting the wire, not taking
the device down: ``ip link set DEV down`` waits for the kernel's RCU grace periods, which a
host saturated by SCHED_FIFO nodes stretched to 40-170 ms.

Run (as root; the devices are created in this process's namespace, then moved):
``ros2 run seft_ros link_emulator --devices tl0 tc0 --delay-ms 5 --jitter-ms 1 --loss 0.01``
(two hosts), or ``... --port tc0,10.9.0.1,0,0,0 --port ta0,10.9.0.2,5,1,0 --port
tb0,10.9.0.3,20,4,0`` (a hub). Ctrl-C (or SIGTERM) ends it with one line of what it
forwarded.

References
----------
Linux ``Documentation/networking/tuntap.rst`` (TUNSETIFF, IFF_TUN, IFF_NO_PI);
``tc-netem(8)`` for the delay, jitter and loss it stands in for.
"""

import argparse
from collections import deque
import errno
import fcntl
import heapq
import ipaddress
import os
from pathlib import Path
import select
import signal
import struct
import sys
import time

from seft_msgs_py.scheduling import set_fifo
from seft_ros.cli.arguments import OneLineParser
from seft_ros.core.link import LinkModel

__all__ = ['PacketWire', 'PacketHub', 'open_tun', 'main']

#: ioctl request and flags of ``linux/if_tun.h``.
TUNSETIFF = 0x400454CA
IFF_TUN = 0x0001
IFF_NO_PI = 0x1000
#: Largest packet read from a device [bytes] (IPv4 maximum).
MAX_PACKET = 65535


def open_tun(name: str) -> int:
    """Create the TUN device `name` (layer 3, no packet information) in this process's
    network namespace; return its file descriptor (non-blocking).

    Raises
    ------
    PermissionError
        Not root (``/dev/net/tun`` needs CAP_NET_ADMIN).
    OSError
        No ``/dev/net/tun``, or the name is taken or invalid (at most 15 characters).
    """
    if not 0 < len(name.encode()) <= 15 or '/' in name or name.strip() != name:
        raise OSError(errno.EINVAL, 'not a device name')
    fd = os.open('/dev/net/tun', os.O_RDWR | os.O_NONBLOCK)
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack('16sH', name.encode(), IFF_TUN | IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


class PacketWire:
    """Moves packets between two file descriptors, each direction through a link model.

    Parameters
    ----------
    fds : (int, int)
        Non-blocking descriptors of the two ends (TUN devices; in tests, datagram sockets):
        a packet read from ``fds[i]`` is written to ``fds[1 - i]``.
    models : (LinkModel, LinkModel)
        ``models[i]`` holds the packets read from ``fds[i]`` (``resend=False``: a lost packet
        is dropped).
    clock : callable
        Monotonic time [s].

    Attributes
    ----------
    forwarded, dropped, failed : list of int, shape (2,)
        Per direction: packets written, lost by the model, not written (the receiving device
        down: a cut link).
    """

    def __init__(self, fds, models, clock=time.monotonic):
        self.fds = tuple(fds)
        self.models = tuple(models)
        self.clock = clock
        self.queues = (deque(), deque())        # (departure [s], packet), departures in order
        self.forwarded = [0, 0]
        self.dropped = [0, 0]
        self.failed = [0, 0]

    def _read(self, i: int) -> None:
        fd, model, queue = self.fds[i], self.models[i], self.queues[i]
        while True:
            try:
                packet = os.read(fd, MAX_PACKET)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return                         # the device went away: nothing to read
            out = model.departure(self.clock())
            if out is None:
                self.dropped[i] += 1
            else:
                queue.append((out, packet))

    def _send_due(self, now: float) -> None:
        for i, queue in enumerate(self.queues):
            while queue and queue[0][0] <= now:
                _, packet = queue.popleft()
                try:
                    os.write(self.fds[1 - i], packet)
                    self.forwarded[i] += 1
                except OSError:
                    self.failed[i] += 1        # the other side's device is down

    def pump(self, max_wait_s: float = 0.1) -> None:
        """Wait for packets at most until the next departure (or `max_wait_s`), read what
        came, write what is due."""
        now = self.clock()
        wait = max_wait_s
        for queue in self.queues:
            if queue:
                wait = min(wait, max(0.0, queue[0][0] - now))
        readable, _, _ = select.select(self.fds, (), (), wait)
        for i, fd in enumerate(self.fds):
            if fd in readable:
                self._read(i)
        self._send_due(self.clock())

    def summary(self) -> str:
        """One line: what was forwarded, dropped and not delivered, per direction."""
        def side(i):
            return (f'{self.forwarded[i]} forwarded, {self.dropped[i]} dropped, '
                    f'{self.failed[i]} undeliverable')
        return f'link emulator: first -> second: {side(0)}; second -> first: {side(1)}'


class PacketHub:
    """Routes IPv4 packets between several file descriptors, each through its host's link.

    Parameters
    ----------
    fds : sequence of int
        Non-blocking descriptors of the hosts' devices.
    addresses : sequence of str
        Each host's IPv4 address (a packet to it goes to its descriptor).
    models : sequence of (LinkModel or None, LinkModel or None)
        Each host's link to the hub: ``(up, down)``, the packets it sends and those it
        receives (None: no delay, the compute host in the middle).
    clock : callable
        Monotonic time [s].

    Attributes
    ----------
    forwarded, dropped, failed, unroutable, cut_off : list of int
        Per sending host: packets written (per copy), lost by a model, not written (the
        receiving device down), with no host to go to (or not IPv4), and lost to a cut link
        (:meth:`cut`: from or to a cut host, per copy).
    cut_at : dict of int -> float
        The hosts whose link is cut, and when [s, `clock`].
    """

    def __init__(self, fds, addresses, models, clock=time.monotonic):
        self.fds = tuple(fds)
        self.by_address = {ipaddress.IPv4Address(a).packed: i for i, a in enumerate(addresses)}
        self.models = tuple(models)
        self.clock = clock
        self.queue: list = []                  # heap of (departure [s], seq, to, from, packet)
        self._seq = 0
        n = len(self.fds)
        self.forwarded, self.dropped, self.failed, self.unroutable, self.cut_off = (
            [0] * n for _ in range(5))
        self.cut_at: dict[int, float] = {}

    def cut(self, i: int) -> float:
        """Cut host `i`'s link to the hub, both ways, now: the packets it sent and those on
        their way to it are dropped, and so is everything after (a cut link stays cut).
        Returns the time of the cut [s, `clock`] (the first one's, if already cut).

        Raises
        ------
        IndexError
            No host `i`.
        """
        if not 0 <= i < len(self.fds):
            raise IndexError(f'host {i}: expected 0..{len(self.fds) - 1}')
        if i not in self.cut_at:
            self.cut_at[i] = self.clock()
            kept = []
            for entry in self.queue:
                if i in (entry[2], entry[3]):
                    self.cut_off[entry[3]] += 1
                else:
                    kept.append(entry)
            heapq.heapify(kept)
            self.queue[:] = kept               # in place: a signal handler may call this
        return self.cut_at[i]

    def routes(self, i: int, packet: bytes) -> list[int]:
        """The hosts a packet from host `i` goes to: its IPv4 destination's, or every other
        host for a multicast or broadcast one; none for anything else."""
        if len(packet) < 20 or packet[0] >> 4 != 4:
            return []
        dst = packet[16:20]
        if dst[0] >> 4 == 14 or dst == b'\xff\xff\xff\xff' or dst[3] == 255:
            return [j for j in range(len(self.fds)) if j != i]
        j = self.by_address.get(dst)
        return [] if j is None or j == i else [j]

    def _read(self, i: int) -> None:
        while True:
            try:
                packet = os.read(self.fds[i], MAX_PACKET)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            targets = self.routes(i, packet)
            if not targets:
                self.unroutable[i] += 1
                continue
            if i in self.cut_at:
                self.cut_off[i] += len(targets)
                continue
            up = self.models[i][0]
            t = self.clock() if up is None else up.departure(self.clock())
            if t is None:
                self.dropped[i] += 1
                continue
            for j in targets:
                if j in self.cut_at:
                    self.cut_off[i] += 1
                    continue
                down = self.models[j][1]
                out = t if down is None else down.departure(t)
                if out is None:
                    self.dropped[i] += 1
                    continue
                self._seq += 1
                heapq.heappush(self.queue, (out, self._seq, j, i, packet))

    def pump(self, max_wait_s: float = 0.1) -> None:
        """Wait for packets at most until the next departure (or `max_wait_s`), read what
        came, write what is due."""
        now = self.clock()
        wait = min(max_wait_s, max(0.0, self.queue[0][0] - now)) if self.queue else max_wait_s
        readable, _, _ = select.select(self.fds, (), (), wait)
        for i, fd in enumerate(self.fds):
            if fd in readable:
                self._read(i)
        now = self.clock()
        while self.queue and self.queue[0][0] <= now:
            _, _, j, i, packet = heapq.heappop(self.queue)
            if i in self.cut_at or j in self.cut_at:
                self.cut_off[i] += 1           # queued as the cut came (from a signal)
                continue
            try:
                os.write(self.fds[j], packet)
                self.forwarded[i] += 1
            except OSError:
                self.failed[i] += 1

    def summary(self, names) -> str:
        """One line: per host, what it sent that was forwarded, dropped, not delivered."""
        return 'link emulator (hub): ' + '; '.join(
            f'{n}: {self.forwarded[i]} forwarded, {self.dropped[i]} dropped, '
            f'{self.failed[i]} undeliverable, {self.unroutable[i]} unroutable'
            + (f', {self.cut_off[i]} lost to the cut' if self.cut_at else '')
            for i, n in enumerate(names))


def _port(text: str):
    """``NAME,ADDRESS,DELAY_MS,JITTER_MS,LOSS`` of ``--port``."""
    parts = text.split(',')
    if len(parts) != 5:
        raise argparse.ArgumentTypeError(f'--port {text!r}: expected '
                                         'NAME,ADDRESS,DELAY_MS,JITTER_MS,LOSS')
    try:
        ipaddress.IPv4Address(parts[1])
        numbers = [float(v) for v in parts[2:]]
    except ValueError:
        raise argparse.ArgumentTypeError(f'--port {text!r}: expected an IPv4 address and '
                                         'three numbers') from None
    return parts[0], parts[1], *numbers


def build_parser() -> argparse.ArgumentParser:
    """The emulator's arguments."""
    p = OneLineParser(prog='link_emulator', description=__doc__.splitlines()[0])
    p.add_argument('--devices', nargs=2, metavar=('FIRST', 'SECOND'),
                   help='names of the two TUN devices to create (at most 15 characters)')
    p.add_argument('--port', type=_port, action='append', default=[],
                   metavar='NAME,ADDRESS,DELAY_MS,JITTER_MS,LOSS',
                   help='a hub instead: one TUN device per host with its link to the hub '
                   '(repeat; a host with delay 0 is the hub itself)')
    p.add_argument('--delay-ms', type=float, default=0.0, help='one-way delay [ms]')
    p.add_argument('--jitter-ms', type=float, default=0.0,
                   help='half-width of the uniform jitter [ms] (<= delay)')
    p.add_argument('--loss', type=float, default=0.0,
                   help='packet loss probability (a lost packet is dropped; DDS resends it)')
    p.add_argument('--seed', type=int, default=0, help='seed of the jitter and loss draws')
    p.add_argument('--cut-on-signal', metavar='NAME',
                   help="a hub's port (its device's name) whose link SIGUSR1 cuts, both ways")
    p.add_argument('--ready-file', type=Path,
                   help='written once both devices exist (for the script that moves them)')
    p.add_argument('--realtime-priority', type=int, default=WIRE_PRIORITY, metavar='N',
                   help='SCHED_FIFO priority of the wire (1-99; 0: the normal scheduler); '
                   f'default {WIRE_PRIORITY}, above every node: a real wire does not share '
                   "the hosts' cores")
    return p


#: SCHED_FIFO priority of the emulated wire: above the nodes' (``realtime_priority`` 50 plus
#: at most 3). A real network does not wait for the hosts' processors; at the normal
#: priority, on a loaded 2-core machine, the hub held packets for more than 100 ms and the
#: builders' watchdogs ended 3-host runs. It sleeps in ``select`` between packets.
WIRE_PRIORITY = 60


def _set_priority(priority: int) -> None:
    """Run this process under SCHED_FIFO `priority` (0: leave it); one warning if refused."""
    if priority <= 0:
        return
    try:
        set_fifo(priority)
    except (OSError, AttributeError) as exc:
        print(f'link_emulator: warning: SCHED_FIFO {priority} refused ({exc}); the normal '
              'scheduler: a loaded host delays the packets more than the link does',
              file=sys.stderr, flush=True)


def _run_hub(a) -> int:
    """``--port ...``: the hub (:class:`PacketHub`)."""
    names = [p[0] for p in a.port]
    if a.cut_on_signal is not None and a.cut_on_signal not in names:
        print(f'link_emulator: error: --cut-on-signal {a.cut_on_signal}: not a --port name '
              f'(ports: {", ".join(names)})', file=sys.stderr)
        return 2
    models = []
    try:
        for k, (name, _, delay, jitter, loss) in enumerate(a.port):
            pair = tuple(None if delay == jitter == loss == 0 else LinkModel(
                1e-3 * delay, 1e-3 * jitter, loss, seed=a.seed + 2 * k + d, resend=False)
                for d in range(2))
            models.append(pair)
    except ValueError as exc:
        print(f'link_emulator: error: {exc}', file=sys.stderr)
        return 2
    fds = []
    for name, *_ in a.port:
        try:
            fds.append(open_tun(name))
        except OSError as exc:
            print(f'link_emulator: error: cannot create TUN device {name!r}: {exc.strerror} '
                  '(needs root and /dev/net/tun; a free name of at most 15 characters)',
                  file=sys.stderr)
            return 2
    hub = PacketHub(fds, [p[1] for p in a.port], models)
    _set_priority(a.realtime_priority)
    stop = []
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.append(True))
    if a.cut_on_signal is not None:
        k = names.index(a.cut_on_signal)

        def cut(*_):
            # in the signal handler: the cut takes effect before select() is entered again
            if k not in hub.cut_at:
                hub.cut(k)
                print(f'link emulator (hub): {a.cut_on_signal} cut, both ways, at wall time '
                      f'{time.time_ns()} ns', file=sys.stderr, flush=True)
        signal.signal(signal.SIGUSR1, cut)
    if a.ready_file is not None:
        a.ready_file.write_text('ready\n')
    print('link emulator (hub): ' + ', '.join(f'{n} ({addr}) {d} ms +/- {j} ms, loss {p}'
                                              for n, addr, d, j, p in a.port),
          file=sys.stderr, flush=True)
    while not stop:
        hub.pump()
    print(hub.summary([p[0] for p in a.port]), file=sys.stderr, flush=True)
    return 0


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros link_emulator``."""
    a = build_parser().parse_args(args)
    if bool(a.port) == bool(a.devices):
        print('link_emulator: error: give either --devices FIRST SECOND or --port ... (two '
              'or more)', file=sys.stderr)
        return 2
    if a.cut_on_signal is not None and not a.port:
        print('link_emulator: error: --cut-on-signal: expected a hub (--port ...)',
              file=sys.stderr)
        return 2
    if a.port:
        if len(a.port) < 2:
            print('link_emulator: error: --port: expected two or more', file=sys.stderr)
            return 2
        return _run_hub(a)
    try:
        models = [LinkModel(1e-3 * a.delay_ms, 1e-3 * a.jitter_ms, a.loss, seed=a.seed + i,
                            resend=False) for i in range(2)]
    except ValueError as exc:
        print(f'link_emulator: error: {exc}', file=sys.stderr)
        return 2
    fds = []
    for name in a.devices:
        try:
            fds.append(open_tun(name))
        except OSError as exc:
            print(f'link_emulator: error: cannot create TUN device {name!r}: {exc.strerror} '
                  '(needs root and /dev/net/tun; a free name of at most 15 characters)',
                  file=sys.stderr)
            return 2
    wire = PacketWire(fds, models)
    _set_priority(a.realtime_priority)
    stop = []
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.append(True))
    if a.ready_file is not None:
        a.ready_file.write_text('ready\n')
    print(f'link emulator: {a.devices[0]} <-> {a.devices[1]}, delay {a.delay_ms} ms +/- '
          f'{a.jitter_ms} ms, loss {a.loss}', file=sys.stderr, flush=True)
    while not stop:
        wire.pump()
    print(wire.summary(), file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
