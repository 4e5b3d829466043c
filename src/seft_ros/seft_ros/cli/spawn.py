"""Start node processes: forked from a server that has imported the nodes once, or executed.

A node process spends most of its start-up importing (numpy, rclpy, scipy.signal and seft:
about 0.8 s of CPU of its 1 s, measured on this 2-core machine); a graph starts five of them
at once. ``fork`` (the default) starts them from a fork server
(``multiprocessing.forkserver``, the standard library's) that imported every node's module
once, before any ROS context exists, and then froze its objects out of the garbage
collector's way (``seft_ros.cli.fork_server_freeze``): each node then only creates its
context and node. The
child takes the command line it would have been executed with as its process title
(``setproctitle``), so ``ps``, ``pgrep -f`` and ``/proc/<pid>/cmdline`` show each node as
``python -m <module> --ros-args ...``, and runs the module's ``main()`` as ``python -m`` would.
``exec`` starts ``python -m <module>`` as a new process, as ``ros2 run`` does.

The choice is ``$SEFT_NODE_START`` (``fork`` or ``exec``); a command that is not seft's own
node module (``seft rig-check --rig-command``) is always executed.
"""

from __future__ import annotations

import importlib
import multiprocessing
from multiprocessing import forkserver
import os
import signal
import subprocess
import sys
from typing import Mapping, Sequence

import setproctitle

from seft_msgs_py.errors import SeftError

__all__ = ['NODE_START_ENV', 'NodeProcess', 'node_start', 'prepare', 'start_node']

#: Environment variable that chooses how nodes are started: ``fork`` (default) or ``exec``.
NODE_START_ENV = 'SEFT_NODE_START'
_CHOICES = ('fork', 'exec')

_context = None


def node_start() -> str:
    """How nodes are started: ``$SEFT_NODE_START``, else ``fork``.

    Raises
    ------
    SeftError
        The variable is set to something else than ``fork`` or ``exec``.
    """
    text = os.environ.get(NODE_START_ENV, '').strip() or 'fork'
    if text not in _CHOICES:
        raise SeftError(f'{NODE_START_ENV}={text!r}: expected one of {", ".join(_CHOICES)}')
    return text


class NodeProcess:
    """A forked node process with the part of ``subprocess.Popen``'s interface the
    runner uses (``pid``, ``poll``, ``wait``, ``send_signal``, ``kill``, ``returncode``).

    ``returncode`` follows Popen: the exit code, or ``-N`` when signal ``N`` ended it.
    """

    def __init__(self, process: multiprocessing.process.BaseProcess):
        self._process = process
        self.pid = process.pid
        self.args = None

    @property
    def returncode(self) -> int | None:
        return self._process.exitcode

    def poll(self) -> int | None:
        """The exit code, or None while the process runs."""
        return self._process.exitcode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the process to end; return its exit code.

        Raises
        ------
        subprocess.TimeoutExpired
            It still runs after `timeout` seconds.
        """
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(self.args or str(self.pid), timeout)
        return self._process.exitcode

    def send_signal(self, sig: int) -> None:
        """Send `sig` unless the process has already ended (its pid may be reused)."""
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


#: Imported by the fork server before the nodes' modules: it ignores the stop signals
#: meant for the runner's process group (seft_ros.cli.fork_server_signals).
_SERVER_SIGNALS = 'seft_ros.cli.fork_server_signals'
#: Imported by the fork server after the nodes' modules: it freezes what it holds out of the
#: garbage collector's way (seft_ros.cli.fork_server_freeze).
_SERVER_FREEZE = 'seft_ros.cli.fork_server_freeze'


def _fork_context(modules: Sequence[str]):
    global _context
    if _context is None:
        ctx = multiprocessing.get_context('forkserver')
        ctx.set_forkserver_preload([_SERVER_SIGNALS, *modules, _SERVER_FREEZE])
        _context = ctx
    return _context


def prepare(modules: Sequence[str]) -> None:
    """Start the fork server now (``fork``), so that it imports `modules` while the caller
    does other work; a no-op with ``exec``.

    Raises
    ------
    SeftError
        ``$SEFT_NODE_START`` is not ``fork`` or ``exec``.
    """
    if node_start() == 'fork':
        _fork_context(modules)
        forkserver.ensure_running()


def _run_module(module: str, argv: Sequence[str], env: Mapping[str, str],
                log_path: str) -> None:
    """In the forked child: become ``python -m module argv...`` with `env`, output to the
    log, and exit with what the module's ``main()`` returns.

    The signals the fork server ignores (:mod:`seft_ros.cli.fork_server_signals`) are the
    node's again, as in a process of its own: SIGINT raises ``KeyboardInterrupt``, SIGTERM
    and SIGHUP end it, until its ``main()`` takes them
    (:func:`~seft_msgs_py.node_support.main_for_nodes`)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    fd = os.open(log_path, os.O_WRONLY | os.O_APPEND)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout = open(1, 'w', buffering=1, closefd=False)
    sys.stderr = open(2, 'w', buffering=1, closefd=False)
    # the title first: setproctitle finds the memory it may use from the environment as the
    # process started with, before it changes
    setproctitle.setproctitle(' '.join([sys.executable, '-m', module, *argv]))
    os.environ.clear()
    os.environ.update(env)
    sys.argv = [module, *argv]
    code = importlib.import_module(module).main()
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)


def start_node(argv: Sequence[str], env: Mapping[str, str], log_path, preload: Sequence[str]
               ) -> subprocess.Popen | NodeProcess:
    """Start a node whose command line is `argv` with environment `env`, its output (stdout
    and stderr) written to the file `log_path` (created, or emptied).

    `argv` of the form ``[python, '-m', module, *args]`` whose module is in `preload` is
    forked (``$SEFT_NODE_START`` fork); any other command, or ``exec``, is executed.

    Raises
    ------
    SeftError
        ``$SEFT_NODE_START`` is not ``fork`` or ``exec``.
    """
    argv = [str(a) for a in argv]
    fork = (node_start() == 'fork' and len(argv) >= 3 and argv[0] == sys.executable
            and argv[1] == '-m' and argv[2] in preload)
    with open(log_path, 'w') as log:
        if not fork:
            return subprocess.Popen(argv, env=dict(env), stdout=log, stderr=subprocess.STDOUT)
    ctx = _fork_context(preload)
    process = ctx.Process(target=_run_module, args=(argv[2], argv[3:], dict(env),
                                                    str(log_path)), daemon=False)
    process.start()
    node = NodeProcess(process)
    node.args = argv
    return node
