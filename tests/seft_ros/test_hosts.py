"""A structure over three hosts on this machine (``tools/hosts.sh``): a bridge whose piers are
each in their own lab (links of 5 and 20 ms +/- 20 %) and whose deck and recorder are on the
compute host, the default partition (loop_local: each lab's builder integrates a replica of
the deck and closes its rig's loop locally). Pier b's link is cut early in the run: every
rig goes to its safe state and the run ends with the reason on every host; the bag holds
everything up to the cut and the links the runners measured.

Needs root (network namespaces, TUN devices); skipped with the reason elsewhere.
"""

import json
import re
import subprocess

import numpy as np
import pytest
from test_two_hosts import ROOT, _can_make_namespaces, _left_behind

from seft_ros.analysis.bag import read_run
from seft_ros.analysis.structure_metrics import dof_signals


def test_a_bridge_over_three_hosts_and_a_cut_link(tmp_path, ros_env):
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    out = tmp_path / 'hosts'
    proc = subprocess.run(
        ['bash', str(ROOT / 'tools' / 'hosts.sh'), '--link', 'pier_a=5,1',
         '--link', 'pier_b=20,4', '--cut-after', '1', '--cut-site', 'pier_b', '--out',
         str(out), '--', str(ROOT / 'config' / 'two_piers.yaml'), '--predictor', 'model',
         '--duration', '8', '--set', 'monitor_threshold=0',
         '--set', 'watchdog_timeout_s=0.1'],
        cwd=tmp_path, env=ros_env, capture_output=True, text=True, timeout=400)
    err = proc.stderr
    assert 'Traceback' not in err
    assert proc.returncode == 0, err          # a safety function ended the run: a result
    assert re.search(r'link cut \(\S+ of pier_b down\)', err), err
    names = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not re.search(_left_behind(err), names), names
    # every lab: its rig went to its safe state, and says why
    for site, other in (('pier_a', 'pier_b'), ('pier_b', 'pier_a')):
        outcome = json.loads(next(out.glob(f'{site}/*/outcome.json')).read_text())
        rig = outcome['rig_final']
        assert rig['state'] == 'aborted' and 'watchdog' in rig['message'], (site, rig)
    # the compute host: the run aborted with a watchdog, the bag complete up to the cut
    entry = json.loads((out / 'compute' / 'summary.json').read_text())['runs'][0]
    assert entry['stable'] is False and 'watchdog' in entry['abort_reason']
    run = read_run(next(out.glob('compute/*/bag')))
    # the cut 1 s of wall time after the rigs started (their clock starts 0.5 s later), found
    # by the watchdogs within 0.1 s: early in the record, before the two-pier bridge over
    # three hosts is known to diverge at times on this 2-core machine (1.0-1.3 s into the
    # record, docs/network.md), which made a later cut a test of that instead
    assert 0.3 < run.n_steps * 0.002 < 2.0
    assert set(run.rigs) == {'pier_a', 'pier_b'}
    # up to the cut the bag holds every DOF, finite, and the rigs moved
    for dof, sig in dof_signals(run).items():
        x = sig['displacement'][:run.n_steps - 1]
        assert np.all(np.isfinite(x)) and np.max(np.abs(x)) > 0.0, dof
    # the links the runners measured: each lab's round trip at least twice its delay
    link = entry['link']
    assert link['emulation'] == 'link emulator' and link['reference'] == 'compute'
    assert set(link['hosts']) == {'pier_a', 'pier_b'}
    assert link['hosts']['pier_a']['round_trip_ms']['p50'] > 8.0
    assert link['hosts']['pier_b']['round_trip_ms']['p50'] > 32.0
    assert link['playout'] in ('none', 'dropped: the loop does not cross hosts')
