"""``seft run --live``: start the live view's process beside the runs, print where it is.

The live view (``seft_ros.live``, :mod:`seft_ros.live.node`) runs in a process of its own in
the run's ROS domain for the whole command (every run of a sweep), started once the domain
is known and stopped after the last run. Its lines go to the command's progress lines (the
web page's URL and the Foxglove address at start; a refused client, an operator's stop as
they happen) and to ``live.log`` in the output directory. Nothing it does can end a test: a
port in use or an address that cannot be bound is one line, and the runs go on without (that
part of) it.
"""

import os
from pathlib import Path
import subprocess
import sys
import threading
import time
from typing import Callable

from seft_msgs_py.errors import InputError
from seft_ros.live.access import TOKEN_ENV, LiveOptions

__all__ = ['LiveProcess', 'start_live', 'options_from_args', 'LIVE_MODULE',
           'READY_TIMEOUT_S']

LIVE_MODULE = 'seft_ros.live.node'
#: Longest wait for the live view to listen before the first run starts [s] (it imports
#: rclpy, numpy, scipy and the Foxglove SDK: about 1-2 s here).
READY_TIMEOUT_S = 20.0


class LiveProcess:
    """The live view's process (:func:`start_live`); :meth:`close` ends it."""

    def __init__(self, proc: subprocess.Popen, log_path: Path,
                 progress: Callable[[str], None]):
        self.proc = proc
        self.log_path = log_path
        self.progress = progress
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._forward, name='seft-live-lines',
                                       daemon=True)
        self.thread.start()

    def _forward(self) -> None:
        from seft_ros.live.node import OFF_LINE, READY_LINE
        with open(self.log_path, 'a', encoding='utf-8') as log:
            for line in self.proc.stdout:
                line = line.rstrip('\n')
                log.write(line + '\n')
                log.flush()
                if line == READY_LINE:
                    self.ready.set()
                    continue
                if line.startswith('live view: '):
                    self.progress(line)
                if line == OFF_LINE:
                    self.ready.set()
        self.ready.set()

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> bool:
        """Wait until the view listens (or gave up); False after `timeout_s`."""
        return self.ready.wait(timeout_s)

    def close(self) -> None:
        """End the process (SIGTERM, then SIGKILL after 5 s) and its line forwarder."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        self.thread.join(2.0)


def start_live(options: LiveOptions, env: dict, out_dir: Path,
               progress: Callable[[str], None]) -> LiveProcess | None:
    """Start the live view with `options` in the environment `env` (the runner's: its ROS
    domain, discovery range and DDS profile); wait until it listens, so that it sees the
    first run from its start. Returns None (after one line) if it could not be started."""
    argv = [sys.executable, '-m', LIVE_MODULE, '--host', options.host, '--port',
            str(options.port), '--rate', f'{options.rate_hz:g}']
    if options.tls_cert:
        argv += ['--tls-cert', options.tls_cert, '--tls-key', options.tls_key]
    if options.stop:
        argv.append('--stop')
    child_env = dict(env, PYTHONUNBUFFERED='1')
    child_env[TOKEN_ENV] = options.token
    child_env.setdefault('ROS_LOG_DIR', str(Path(out_dir) / 'live_ros_log'))
    try:
        proc = subprocess.Popen(argv, env=child_env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True,
                                start_new_session=True)
    except OSError as exc:
        progress(f'live view: could not start ({exc}); the test runs without it')
        return None
    live = LiveProcess(proc, Path(out_dir) / 'live.log', progress)
    t0 = time.monotonic()
    if not live.wait_ready():
        progress(f'live view: not listening after {time.monotonic() - t0:.0f} s (see '
                 f'{live.log_path}); the test runs on')
    return live


def options_from_args(args) -> LiveOptions | None:
    """The live view's options of ``seft run``'s arguments (None without ``--live``).

    Raises
    ------
    InputError
        A bad ``--live`` address or ``--live-tls`` pair (one line).
    """
    if getattr(args, 'live', None) is None:
        if getattr(args, 'live_stop', False) or getattr(args, 'live_tls', None):
            raise InputError('--live-stop and --live-tls need --live [ADDRESS]')
        return None
    if args.live.endswith(('.yaml', '.yml')):
        raise InputError(f'--live {args.live}: expected [HOST][:PORT], not a configuration '
                         'file; give the configuration before --live, or --live=HOST')
    return LiveOptions.from_command_line(args.live or None, tls=args.live_tls,
                                         stop=args.live_stop, environ=os.environ)
