"""SCHED_FIFO for every thread of a process (seft_msgs_py.scheduling), checked in a child
process so that the test process keeps its scheduler."""

import json
import os
import subprocess
import sys

import pytest

CHILD = r"""
import os, subprocess, sys, threading
from seft_msgs_py.scheduling import set_fifo
worker = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)
worker.start()
try:
    got = set_fifo(int(sys.argv[1]), reset_on_fork=sys.argv[2] == '1')
except OSError as exc:
    print('refused', exc)
    sys.exit(0)
tids = os.listdir('/proc/self/task')
policies = {os.sched_getscheduler(int(t)) & ~os.SCHED_RESET_ON_FORK for t in tids}
priorities = {os.sched_getparam(int(t)).sched_priority for t in tids}
child = subprocess.run([sys.executable, '-c', 'import os; print(os.sched_getscheduler(0))'],
                       capture_output=True, text=True, check=True).stdout.strip()
print(got, len(tids), policies == {os.SCHED_FIFO}, sorted(priorities), int(child) == os.SCHED_FIFO)
"""


def _child(priority, reset_on_fork):
    out = subprocess.run([sys.executable, '-c', CHILD, str(priority), str(int(reset_on_fork))],
                         capture_output=True, text=True, timeout=30, check=True).stdout.split()
    if out[0] == 'refused':
        pytest.skip('SCHED_FIFO refused on this host (needs root or CAP_SYS_NICE): '
                    + ' '.join(out[1:]))
    return out


def test_every_thread_runs_fifo_at_the_clipped_priority_and_children_inherit_it():
    got, threads, all_fifo, priorities, child_fifo = _child(150, False)
    assert got == '99' and int(threads) >= 2 and all_fifo == 'True'
    assert priorities == '[99]' and child_fifo == 'True'


def test_reset_on_fork_keeps_children_on_the_normal_scheduler():
    got, threads, all_fifo, priorities, child_fifo = _child(7, True)
    assert got == '7' and all_fifo == 'True' and priorities == '[7]'
    assert child_fifo == 'False'


BLAS_CHILD = r"""
import json, os, sys
import scipy.signal
from threadpoolctl import threadpool_info
from seft_msgs_py.node_support import SeftNode

class Stub:                       # what apply_priority reads of a node
    realtime = sys.argv[1] == 'realtime'
    kind = 'reference_force_builder'
    params = {'realtime_priority': 0}

before = sorted(i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas')
SeftNode.apply_priority(Stub())
after = sorted(i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas')
print(json.dumps([before, after, os.sched_getscheduler(0) == os.SCHED_OTHER]))
"""


@pytest.mark.parametrize('mode', ['realtime', 'lockstep'])
def test_a_node_keeps_blas_to_one_thread_without_sched_fifo(mode):
    """realtime_priority 0 (the normal scheduler): a node limits BLAS to one thread in real
    time and in lockstep alike (a pool of two made 2x2 products take 4-20 ms on a loaded
    host, adaptive's refits 24 ms). The BLAS threads are counted in a child (the limit lasts
    the process's life)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS='2')
    out = subprocess.run([sys.executable, '-c', BLAS_CHILD, mode], capture_output=True,
                         text=True, timeout=60, check=True, env=env).stdout
    before, after, normal = json.loads(out)
    assert normal and before and max(before) == 2
    assert after == [1] * len(before)
