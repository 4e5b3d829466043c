"""Forward TCP ports of this machine's 127.0.0.1 into a network namespace's 127.0.0.1.

tools/hosts.sh runs each emulated host in a network namespace of its own; the live view of
the compute host (``seft run --live``) listens on that namespace's loopback, which this
machine's browser cannot reach. This forwarder listens on 127.0.0.1:PORT here and, for each
connection, connects to 127.0.0.1:PORT inside the namespace (a thread that entered it with
setns(2) opens the socket) and copies bytes both ways. Stops on SIGINT or SIGTERM.

Usage: python tools/netns_forward.py NAMESPACE PORT [PORT ...]   (root)
"""

import ctypes
import os
import selectors
import signal
import socket
import sys
import threading

CLONE_NEWNET = 0x40000000
_libc = ctypes.CDLL(None, use_errno=True)


def connect_in(namespace: str, port: int) -> socket.socket:
    """A socket connected to 127.0.0.1:`port` inside the network namespace `namespace`."""
    result: list = []

    def inside():
        fd = os.open(f'/var/run/netns/{namespace}', os.O_RDONLY)
        try:
            if _libc.setns(fd, CLONE_NEWNET) != 0:
                result.append(OSError(ctypes.get_errno(), 'setns'))
                return
            result.append(socket.create_connection(('127.0.0.1', port), timeout=5))
        except OSError as exc:
            result.append(exc)
        finally:
            os.close(fd)
    thread = threading.Thread(target=inside)     # setns changes this thread only
    thread.start()
    thread.join()
    if isinstance(result[0], Exception):
        raise result[0]
    return result[0]


def pipe(a: socket.socket, b: socket.socket) -> None:
    """Copy both ways until either side closes."""
    sel = selectors.DefaultSelector()
    sel.register(a, selectors.EVENT_READ, b)
    sel.register(b, selectors.EVENT_READ, a)
    try:
        while True:
            for key, _ in sel.select():
                data = key.fileobj.recv(65536)
                if not data:
                    return
                key.data.sendall(data)
    except OSError:
        return
    finally:
        a.close()
        b.close()


def serve(namespace: str, port: int) -> None:
    server = socket.create_server(('127.0.0.1', port))
    while True:
        client, _ = server.accept()
        try:
            far = connect_in(namespace, port)
        except OSError:
            client.close()
            continue
        threading.Thread(target=pipe, args=(client, far), daemon=True).start()


def main(argv) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    namespace, ports = argv[0], [int(p) for p in argv[1:]]
    for port in ports:
        threading.Thread(target=serve, args=(namespace, port), daemon=True).start()
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    stop.wait()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
