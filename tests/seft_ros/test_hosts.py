"""A structure over three hosts on this machine (``tools/hosts.sh``): a bridge whose piers are
each in their own lab (links of 5 and 20 ms +/- 20 %) and whose deck and recorder are on the
compute host, the default partition (loop_local: each lab's builder integrates a replica of
the deck and closes its rig's loop locally). Pier b's link is cut 0.5 s into the run: every
rig goes to its safe state and the run ends with the reason on every host; the bag holds
everything up to the cut, nothing lost on the way, and the links the runners measured.
The compute host's live view (``hosts.sh --live``) is watched from this machine by a
Foxglove client through the script's forwarder: every rig's and DOF's channels (the cut
lab's where it showed them), the links and the run's end, against the bag.

Needs root (network namespaces, TUN devices); skipped with the reason elsewhere.
"""

import json
import re
import subprocess
import threading

from foxglove_client import FoxgloveClient
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from test_live_view import check_channels_against_bag, free_port_pair
from test_two_hosts import ROOT, _can_make_namespaces, _left_behind

from seft_ros.analysis.bag import read_run
from seft_ros.analysis.metrics import dof_signals

DT = 0.002


def _run_and_cut(cwd, ros_env, out):
    """Run the bridge over three hosts with pier b's link cut 0.5 s in, watched live; check
    what every run must show; return the script's output, the cut's time after the rigs'
    start [s] and the Foxglove client (closed)."""
    port = free_port_pair()
    proc = subprocess.Popen(
        ['bash', str(ROOT / 'tools' / 'hosts.sh'), '--link', 'pier_a=5,1',
         '--link', 'pier_b=20,4', '--cut-after', '0.5', '--cut-site', 'pier_b', '--live',
         str(port), '--out', str(out), '--', str(ROOT / 'config' / 'two_piers.yaml'),
         '--predictor', 'model', '--duration', '8', '--set', 'monitor_threshold=0',
         '--set', 'watchdog_timeout_s=0.1'],
        cwd=cwd, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    timer = threading.Timer(400, proc.kill)
    timer.start()
    lines, client = [], None
    for line in proc.stdout:
        lines.append(line)
        if client is None and re.search(r'compute: (\[seft\] )?live view: Foxglove '
                                        r'ws://127\.0\.0\.1:', line):
            client = FoxgloveClient(f'ws://127.0.0.1:{port}')
    proc.wait()
    timer.cancel()
    err = ''.join(lines)
    assert client is not None, err
    client.close()
    assert 'Traceback' not in err
    assert proc.returncode == 0, err          # a safety function ended the run: a result
    cut = re.search(r'link cut \(\S+ of pier_b, both ways\) ([0-9.]+) s after the rigs '
                    r'started', err)
    assert cut, err
    names = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not re.search(_left_behind(err), names), names
    return err, float(cut.group(1)), client


def test_a_bridge_over_three_hosts_and_a_cut_link(tmp_path, ros_env):
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    for attempt in (1, 2):
        out = tmp_path / f'hosts_{attempt}'
        err, cut_s, client = _run_and_cut(tmp_path, ros_env, out)
        ended_s = min(float(json.loads(next(out.glob(f'{site}/*/outcome.json')).read_text())
                            ['rig_final'].get('abort_at_s') or 1e9)
                      for site in ('pier_a', 'pier_b'))
        if ended_s >= cut_s:
            break
        # the run ended before the cut: the bridge over three hosts on this 2-core machine
        # diverges at times (0.4-2.3 s into the record, docs/network.md); run it once more
        print(f'attempt {attempt}: the run ended at {ended_s:.3f} s, before the cut at '
              f'{cut_s:.3f} s')
    else:
        pytest.fail('both runs ended before the link was cut (the saturated three-host '
                    'bridge, docs/network.md): the cut was not tested')
    # pier b, cut off from the recorder's host, ends its nodes once that host has been silent
    # for REFERENCE_SILENT_S after they ended; pier a still hears it and waits for the bag
    assert re.search(r'^pier_b: .*no word from the host with the recorder for [\d.]+ s '
                     r'after the nodes here ended', err, re.MULTILINE), err
    assert not re.search(r'^pier_a: .*no word from the host with the recorder', err,
                         re.MULTILINE), err
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
    with AnyReader([bag]) as reader:
        samples = {c.topic: c.msgcount for c in reader.connections}
    pier_a_s = samples['/pier_a/seft/measured_force'] * DT
    pier_b_s = samples['/pier_b/seft/measured_force'] * DT
    # pier a's link stayed up: its samples run past the cut, to the abort the cut caused
    assert cut_s < pier_a_s < cut_s + 1.0, (cut_s, pier_a_s)
    # and pier b's up to the cut: none lost on the way (the recorder's host, busy with the
    # labs' nodes on this machine, overflowed its 208 KiB socket buffers 500-560 times a run
    # and lost pier b's samples from 0.1-0.2 s on in 2 runs of 4, before the 4 MiB of
    # seft_msgs_py.dds)
    assert re.search(r'compute: UDP \d+ received, 0 receive-buffer overflows', err), err
    assert cut_s - 0.15 < pier_b_s <= cut_s + 0.05, (cut_s, pier_b_s)
    run = read_run(bag)
    assert cut_s - 0.1 < run.n_steps * DT < cut_s + 1.0
    assert set(run.rigs) == {'pier_a', 'pier_b'}
    # up to the cut the bag holds every DOF, finite, and the rigs moved
    for dof, sig in dof_signals(run).items():
        x = sig['displacement'][:run.n_steps - 1]
        assert np.all(np.isfinite(x)) and np.max(np.abs(x)) > 0.0, dof
    # the live view of the compute host: every channel it advertised, the rigs' against the
    # bag, every DOF, the links, and the end with its reason
    with AnyReader([bag]) as reader:
        x = {rig: {} for rig in ('pier_a', 'pier_b')}
        for conn, stamp, raw in reader.messages(
                [c for c in reader.connections if c.topic.endswith('/seft/displacement')]):
            x[conn.topic.split('/')[1]][stamp // 2_000_000] = \
                reader.deserialize(raw, conn.msgtype).point.x
    # the cut lab's channels may be empty: the live view is a best-effort reader that joins
    # a run's streams as the graph publishes them, and pier b's run lasts 0.5 s across its
    # 20 ms link (in CI, 2 runs of 2 showed none of pier b's three timing channels while its
    # data channels came; not reproduced here in 10 runs, idle, under three busy loops and
    # with 5 % loss on the links); what it shows of pier b is checked against the bag
    cut_lab = {t for t in client.advertised
               if t.startswith('/pier_b/') or t == '/seft/live/dof/pier_b'}
    received = check_channels_against_bag(client, {}, may_be_empty=cut_lab)
    shown = received['/pier_a/seft/live/measurement']
    assert shown and all(x['pier_a'][m['step']] == m['displacement_m'] for m in shown)
    shown = received['/pier_b/seft/live/measurement']
    assert all(x['pier_b'][m['step']] == m['displacement_m'] for m in shown)
    empty = sorted(t for t in cut_lab if not received[t])
    if empty:
        print(f'pier b (cut): channels the live view never showed: {empty}')
    assert {'/seft/live/dof/pier_a', '/seft/live/dof/pier_b', '/seft/live/dof/deck'} <= \
        set(received)
    links = received['/seft/live/link']
    assert {m['host'] for m in links} == {'pier_a', 'pier_b'}
    assert all(m['round_trip_p50_ms'] > 8.0 for m in links if m['host'] == 'pier_a')
    final = received['/seft/live/run'][-1]
    assert final['state'] == 'aborted' and 'watchdog' in final['reason'], final
