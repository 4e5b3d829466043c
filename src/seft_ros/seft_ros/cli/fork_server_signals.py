"""Imported first by the nodes' fork server (:mod:`seft_ros.cli.spawn`): the server ignores
SIGINT, SIGTERM and SIGHUP, from before its imports.

A Ctrl-C, SIGTERM or hang-up meant for the process group of ``seft run`` reached the server
too: during its imports it printed a ``KeyboardInterrupt`` traceback (a Ctrl-C during the
start-up), and it ended. The server ends by itself once the runner and every node it forked
have closed its pipe (``multiprocessing.forkserver``; it ignores SIGINT from after its
imports on). A node forked from it takes its own signals back (``spawn._run_module``).
Imports nothing of seft, so that it runs before the nodes' imports.
"""

import signal
import sys

#: The signals the fork server ignores.
IGNORED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

if 'multiprocessing.forkserver' in sys.modules and sys.argv[:1] == ['-c']:
    # the fork server's process (python -c 'from multiprocessing.forkserver import main;
    # main(...)'), not a test or a tool that imports this module
    for _signum in IGNORED:
        signal.signal(_signum, signal.SIG_IGN)
