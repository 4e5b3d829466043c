"""A structure over three hosts on this machine (``tools/hosts.sh``): a bridge whose piers are
each in their own lab (links of 5 and 20 ms +/- 20 %) and whose deck and recorder are on the
compute host, the default partition (loop_local: each lab's builder integrates a replica of
the deck and closes its rig's loop locally). Pier b's link is cut 0.5 s into the run: every
rig goes to its safe state and the run ends with the reason on every host; the bag holds
everything up to the cut (one known defect, open: see the test) and the links the runners
measured.

Needs root (network namespaces, TUN devices); skipped with the reason elsewhere.
"""

import json
import re
import subprocess

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from test_two_hosts import ROOT, _can_make_namespaces, _left_behind

from seft_ros.analysis.bag import read_run
from seft_ros.analysis.structure_metrics import dof_signals

DT = 0.002


def test_a_bridge_over_three_hosts_and_a_cut_link(tmp_path, ros_env):
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    out = tmp_path / 'hosts'
    proc = subprocess.run(
        ['bash', str(ROOT / 'tools' / 'hosts.sh'), '--link', 'pier_a=5,1',
         '--link', 'pier_b=20,4', '--cut-after', '0.5', '--cut-site', 'pier_b', '--out',
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
    # the links the runners measured: each lab's round trip at least twice its delay
    link = entry['link']
    assert link['emulation'] == 'link emulator' and link['reference'] == 'compute'
    assert set(link['hosts']) == {'pier_a', 'pier_b'}
    assert link['hosts']['pier_a']['round_trip_ms']['p50'] > 8.0
    assert link['hosts']['pier_b']['round_trip_ms']['p50'] > 32.0
    assert link['playout'] in ('none', 'dropped: the loop does not cross hosts')
    # the bag: the cut 0.5 s after the rigs' sample 0 (hosts.sh times it from the rig's own
    # start line), found by the watchdogs within 0.1 s: early in the record, before the
    # two-pier bridge over three hosts is known to diverge at times on this 2-core machine
    # (0.9-2.3 s into the record, docs/network.md); a cut timed from when the script saw the
    # start came 1.5-2.5 s after it on a busy host and made this a test of that divergence
    bag = next(out.glob('compute/*/bag'))
    cut_s = float(re.search(r'link cut \(.+ down\) ([0-9.]+) s after the rigs started',
                            err).group(1))
    with AnyReader([bag]) as reader:
        samples = {c.topic: c.msgcount for c in reader.connections}
    pier_a_s = samples['/pier_a/seft/measured_force'] * DT
    pier_b_s = samples['/pier_b/seft/measured_force'] * DT
    # pier a's link stayed up: its samples run past the cut, to the abort the cut caused
    assert cut_s < pier_a_s < cut_s + 1.0, (cut_s, pier_a_s)
    if pier_b_s < cut_s - 0.1:
        # Known defect, open (docs/network.md): in about one run in three on this saturated
        # host the recorder stops receiving the cut lab's samples 0.1-0.2 s into the run,
        # long before the cut, and they are not resent before it; its other assertions hold
        pytest.xfail(f"the bag has pier b's samples up to {pier_b_s:.2f} s only, the link "
                     f'was cut at {cut_s:.2f} s (known defect: the recorder on a saturated '
                     'host)')
    run = read_run(bag)
    assert cut_s - 0.1 < run.n_steps * DT < cut_s + 1.0
    assert set(run.rigs) == {'pier_a', 'pier_b'}
    # up to the cut the bag holds every DOF, finite, and the rigs moved
    for dof, sig in dof_signals(run).items():
        x = sig['displacement'][:run.n_steps - 1]
        assert np.all(np.isfinite(x)) and np.max(np.abs(x)) > 0.0, dof
