"""Imported last by the nodes' fork server (:mod:`seft_ros.cli.spawn`), after the nodes'
modules: the server collects once, then moves every object it holds out of the cyclic
garbage collector's way (``gc.freeze``), so that a node forked from it never traverses them.

A forked node's first full collection traversed the server's 92,000 objects: 0.13-0.27 s of
CPU in each node of a graph starting together on this loaded 2-core host, and 6,900 pages
(27 MB) copied from the server by writing their collector headers; with the objects frozen
in the server, 0.001-0.003 s and 140 pages (``benchmarks/rig_check_time.py`` for what it
does to a graph's start). The objects are the modules' and live as long as the process
anyway. Imports nothing of seft.
"""

import gc
import sys

if 'multiprocessing.forkserver' in sys.modules and sys.argv[:1] == ['-c']:
    # the fork server's process (python -c 'from multiprocessing.forkserver import main;
    # main(...)'), not a test or a tool that imports this module
    gc.collect()
    gc.freeze()
