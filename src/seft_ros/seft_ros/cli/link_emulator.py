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

Run (as root; the devices are created in this process's namespace, then moved):
``ros2 run seft_ros link_emulator --devices tl0 tc0 --delay-ms 5 --jitter-ms 1 --loss 0.01``.
Ctrl-C (or SIGTERM) ends it with one line of what it forwarded.

References
----------
Linux ``Documentation/networking/tuntap.rst`` (TUNSETIFF, IFF_TUN, IFF_NO_PI);
``tc-netem(8)`` for the delay, jitter and loss it stands in for.
"""

import argparse
from collections import deque
import errno
import fcntl
import os
from pathlib import Path
import select
import signal
import struct
import sys
import time

from seft_ros.core.link import LinkModel

__all__ = ['PacketWire', 'open_tun', 'main']

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


def build_parser() -> argparse.ArgumentParser:
    """The emulator's arguments."""
    p = argparse.ArgumentParser(prog='link_emulator', description=__doc__.splitlines()[0])
    p.add_argument('--devices', nargs=2, required=True, metavar=('FIRST', 'SECOND'),
                   help='names of the two TUN devices to create (at most 15 characters)')
    p.add_argument('--delay-ms', type=float, default=0.0, help='one-way delay [ms]')
    p.add_argument('--jitter-ms', type=float, default=0.0,
                   help='half-width of the uniform jitter [ms] (<= delay)')
    p.add_argument('--loss', type=float, default=0.0,
                   help='packet loss probability (a lost packet is dropped; DDS resends it)')
    p.add_argument('--seed', type=int, default=0, help='seed of the jitter and loss draws')
    p.add_argument('--ready-file', type=Path,
                   help='written once both devices exist (for the script that moves them)')
    return p


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros link_emulator``."""
    a = build_parser().parse_args(args)
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
