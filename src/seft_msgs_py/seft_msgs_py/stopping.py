"""How a node process is asked to stop: signals, and the end of the runner that started it.

A node process (:func:`~seft_msgs_py.node_support.main_for_nodes`) takes SIGINT (Ctrl-C),
SIGTERM and SIGHUP (its terminal closed, an SSH session dropped) alike: the first one asks
every node to end the run safely (the rig ramps to its safe state, the recorder records the
ramp and closes the bag). A second signal ends the process at once, unless one of its nodes
holds it (:meth:`~seft_msgs_py.node_support.SeftNode.stop_hold_s`: the rig, a bridge to a
lab's rig, while its safe ramp runs; the recorder, while it records it): then the process
says so and goes on, and a third signal, or the hold's bound (:data:`STOP_HOLD_MARGIN_S`
past the hold), ends it at once. An operator pressing Ctrl-C twice in 0.1 s cut the rig's
200 ms ramp at 100 ms, and the rig sent no final status.

A signal that ends the process never raises inside a node's callback: while the process loop
hands its thread to the executor (:attr:`StopRequests.spinning`), the end is left to the loop
(:meth:`StopRequests.check`, at most one ``spin_once`` later), which says it in one line.
Raised from the handler, it surfaced in whatever callback ran (a rig refused before its first
sample, stopped by the runner's SIGINT and then its SIGTERM, logged ``[FATAL] [rig]:
Exception in 'timers' callback`` with a ``KeyboardInterrupt`` traceback). A further signal
while that end is pending (a callback that does not return) raises at once.

A node started by a runner (``seft run``, ``seft rig-check``) gets the runner's process id
in ``$SEFT_RUNNER_PID`` (:data:`RUNNER_PID_ENV`) and stops the run safely, as on SIGTERM,
once that process has ended (:class:`RunnerWatch`): a runner killed, or ended by a hang-up
before it could stop its nodes, left them running the rig unsupervised (and, in lockstep,
a graph whose node then died waited forever). A forked node's parent is the runner's fork
server (``seft_ros.cli.spawn``), not the runner, so the watch names the runner itself; the
kernel's parent-death signal (``PR_SET_PDEATHSIG``) would follow the fork server, which
outlives the runner while the nodes hold its pipe.
"""

from __future__ import annotations

from contextlib import contextmanager
import os
import signal
import sys
import threading
import time
from typing import Callable

__all__ = ['STOP_SIGNALS', 'RUNNER_PID_ENV', 'RUNNER_CHECK_S', 'STOP_HOLD_MARGIN_S',
           'RunnerWatch', 'StopRequests', 'signal_name', 'raise_stop', 'spinning']

#: The signals that stop a node process safely (a second one ends it at once, see above).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Environment variable by which a runner gives the nodes it starts its process id.
RUNNER_PID_ENV = 'SEFT_RUNNER_PID'
#: How often a node process checks that its runner still runs [s] (reading
#: ``/proc/<pid>/stat``: about 20 us).
RUNNER_CHECK_S = 0.25
#: A process held by a node's safe stop ends at a second signal anyway this long past the
#: hold (its stop, plus ``LINGER_S`` to serve its final status) [s]: the hold has a known
#: length, and a stop that outlasts it by this much is stuck.
STOP_HOLD_MARGIN_S = 2.0


#: A thread of this process's CLI is in rclpy's executor (:func:`spinning`): a stop signal
#: is left to it (``_pending``), not raised there.
_spinning = False
#: The stop signal left to the executor's caller (None: none).
_pending: str | None = None


def raise_stop(name: str) -> None:
    """What a CLI's stop-signal handler does: raise ``KeyboardInterrupt(name)``, or, while
    the main thread is in rclpy's executor (:func:`spinning`), leave it to be raised when the
    executor returns. Raised inside the executor, it surfaced wherever Python code ran: in
    rclpy's ``take_message``, which converts a message with Python code under pybind11, it
    was dropped for ``RuntimeError: Unable to convert call argument '0' ...`` (a runner
    hung up at 4.5 s of a lockstep run exited 1 with that traceback instead of ending the
    run safely). The nodes' processes leave it to their loop the same way
    (:attr:`StopRequests.spinning`).

    Raises
    ------
    KeyboardInterrupt
        Outside the executor, or a second signal while one is left to it.
    """
    global _pending
    if _spinning and _pending is None:
        _pending = str(name)
        return
    raise KeyboardInterrupt(name)


@contextmanager
def spinning():
    """The block hands this thread to rclpy's executor (one ``spin_once``); on the main
    thread, a stop signal meanwhile is raised as ``KeyboardInterrupt`` when it ends
    (:func:`raise_stop`).

    Raises
    ------
    KeyboardInterrupt
        A stop signal came while the block ran.
    """
    global _spinning, _pending
    # (signals reach the main thread only: another thread's spin leaves them raised)
    _spinning = threading.current_thread() is threading.main_thread()
    try:
        yield
    finally:
        _spinning = False
        name, _pending = _pending, None
        if name is not None:
            raise KeyboardInterrupt(name)


def signal_name(exc: BaseException) -> str:
    """The signal that raised the ``KeyboardInterrupt`` `exc`: its first argument when a
    handler gave one (``seft``'s: ``SIGINT``, ``SIGTERM``, ``SIGHUP``), else ``SIGINT``
    (Python's own handler: Ctrl-C)."""
    if isinstance(exc, KeyboardInterrupt) and getattr(exc, 'signame', None):
        return exc.signame
    name = exc.args[0] if exc.args else ''
    return name if isinstance(name, str) and name.startswith('SIG') else 'SIGINT'


def _proc_state(pid: int) -> tuple[str, int] | None:
    """``(state, start time in clock ticks)`` of process `pid` from ``/proc/<pid>/stat``, or
    None if there is no such process (or no ``/proc``)."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as f:
            text = f.read().decode(errors='replace')
    except OSError:
        return None
    # 'pid (comm) state ppid ...': comm may hold spaces and parentheses, the rest does not
    fields = text[text.rfind(')') + 2:].split()
    try:
        return fields[0], int(fields[19])
    except (IndexError, ValueError):
        return None


class RunnerWatch:
    """Whether the runner of this node process still runs.

    Parameters
    ----------
    pid : int
        The runner's process id (``$SEFT_RUNNER_PID``).

    Linux: the runner is gone when ``/proc/<pid>`` is gone, a zombie (ended, not yet waited
    for by its shell), or another process (a pid reused: its start time differs). Elsewhere:
    ``kill(pid, 0)`` fails with no such process. A runner already gone when the watch starts
    (it died while this process started) is gone at the first check.
    """

    def __init__(self, pid: int):
        self.pid = pid
        self._start = _proc_state(pid) if os.path.isdir('/proc/self') else None
        self._proc = os.path.isdir('/proc/self')
        self._gone = self._proc and self._start is None
        self._checked_at = -float('inf')

    @classmethod
    def from_environment(cls) -> RunnerWatch | None:
        """The watch of ``$SEFT_RUNNER_PID``; None when unset or not a process id (a node
        started by hand, ``ros2 run``: its parent is a shell, to be left when it ends)."""
        text = os.environ.get(RUNNER_PID_ENV, '').strip()
        if not text.isdigit() or int(text) <= 1:
            return None
        return cls(int(text))

    @property
    def reason(self) -> str:
        """What stopped the node, in place of a signal's name: 'the end of its runner (pid N)'."""
        return f'the end of its runner (pid {self.pid})'

    def gone(self, now: float | None = None) -> bool:
        """Whether the runner has ended; checked at most every :data:`RUNNER_CHECK_S`
        (`now`: ``time.monotonic()``)."""
        now = time.monotonic() if now is None else now
        if self._gone or now - self._checked_at < RUNNER_CHECK_S:
            return self._gone
        self._checked_at = now
        if self._proc:
            state = _proc_state(self.pid)
            self._gone = (state is None or state[0] in ('Z', 'X')
                          or state[1] != self._start[1])
        else:
            try:
                os.kill(self.pid, 0)
            except ProcessLookupError:
                self._gone = True
            except PermissionError:
                pass
        return self._gone


class StopRequests:
    """The stop requests a node process has had, in order: signals (by name) and the end
    of its runner (:attr:`RunnerWatch.reason`).

    Parameters
    ----------
    hold_s : callable
        ``() -> float``: how long the process's nodes hold it against a second signal from
        the first request [s] (0: they do not; a second signal ends the process at once).
    name : str
        The process's name in the line it writes when it holds a signal.

    Install :meth:`on_signal` as the handler of :data:`STOP_SIGNALS`; call :meth:`check`
    from the process's loop.
    """

    def __init__(self, hold_s: Callable[[], float], name: str):
        self.hold_s = hold_s
        self.name = name
        #: The requests: the first stops the process's nodes safely.
        self.names: list[str] = []
        self.first_at: float | None = None
        #: The second signal, held (None: none held).
        self.held: str | None = None
        self.hold_until: float | None = None
        self._said = False
        #: The process loop has handed its thread to the executor (a node's callback may be
        #: running): a signal that ends the process is left to :meth:`check`.
        self.spinning = False
        #: The signal that ends the process, left to :meth:`check` (None: none).
        self.end_now: str | None = None

    def request(self, name: str) -> None:
        """A stop request that is not a signal (the runner's end): a first request only."""
        if not self.names:
            self.names.append(name)
            self.first_at = time.monotonic()

    def on_signal(self, signum, frame) -> None:
        """Signal handler: the first signal is a request; a second one ends the process
        (``KeyboardInterrupt``) unless a node holds it; a third one ends it. While
        :attr:`spinning` the end is left to :meth:`check` (:attr:`end_now`), so that it
        does not surface inside a node's callback; a signal after that raises.

        Raises
        ------
        KeyboardInterrupt
            A second signal not held, or a third, outside the executor's spin; any signal
            while such an end is pending.
        """
        name = signal.Signals(signum).name
        now = time.monotonic()
        if not self.names:
            self.request(name)
            return
        if self.held is None:
            hold = self.hold_s()
            until = self.first_at + hold + STOP_HOLD_MARGIN_S
            if hold > 0 and now < until:
                self.held, self.hold_until = name, until
                return
        if self.spinning and self.end_now is None:
            self.end_now = name
            return
        raise KeyboardInterrupt

    def check(self) -> None:
        """From the process's loop: end the process on a signal left to it
        (:attr:`end_now`), in one line; say once that a second signal is held (stderr, the
        node's log); past the hold's bound, end the process.

        Raises
        ------
        KeyboardInterrupt
            A signal ends the process, or a held signal's bound has passed.
        """
        if self.end_now is not None:
            print(f'{self.name}: {self.end_now} again: ending the process now',
                  file=sys.stderr, flush=True)
            raise KeyboardInterrupt(self.end_now)
        if self.held is None:
            return
        now = time.monotonic()
        if not self._said:
            self._said = True
            print(f'{self.name}: {self.held} again: finishing the safe stop first (at most '
                  f'{self.hold_until - now:.1f} s more; one more signal ends the process now)',
                  file=sys.stderr, flush=True)
        if now > self.hold_until:
            print(f'{self.name}: the safe stop did not end within its bound; ending the '
                  'process now', file=sys.stderr, flush=True)
            raise KeyboardInterrupt
