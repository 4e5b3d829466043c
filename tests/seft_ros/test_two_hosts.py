"""Two hosts on this machine (``tools/two_hosts.sh``): the graph split over two network
namespaces joined by an emulated link, and the link cut in the middle of the run (issue 8).

Needs root (network namespaces, TUN devices); where it cannot create them the test skips
with that reason (CI runs as root, so it runs there). The run is real time across a link of
5 ms +/- 1 ms one way (the link emulator's hub; this kernel has no netem), split the earlier
way (``--partition builder_remote``: the loop crosses the link, the runners size the playout
delay from the measured round trip, ``network_delay_s`` auto); the link is taken down 3 s
after the rig started. The default partition (``loop_local``) with its link cut: the compute
host, which holds the recorder, ends the run and writes the report.
"""

import json
import os
from pathlib import Path
import re
import shutil
import subprocess

from conftest import realtime_accuracy
import pytest

from seft_ros.analysis.bag import read_run

ROOT = Path(__file__).resolve().parents[2]
DT = 0.002


def _can_make_namespaces() -> str | None:
    if os.geteuid() != 0:
        return 'needs root to create network namespaces (CI runs as root)'
    if shutil.which('ip') is None:
        return 'iproute2 (ip) is not installed'
    probe = f'seft-probe-{os.getpid()}'
    made = subprocess.run(['ip', 'netns', 'add', probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f'cannot create a network namespace here: {made.stderr.strip()}'
    subprocess.run(['ip', 'netns', 'del', probe], capture_output=True)
    return None


def _left_behind(err: str) -> str:
    """The pattern of the network namespaces the script run whose stderr is ``err`` made
    (other runs may hold their own at the same time)."""
    made = re.search(r'network namespaces seft-\*-(\d+)', err)
    assert made, err
    return rf'seft-\d+-{made.group(1)}\b'


def _run_and_cut(cwd, ros_env, out):
    """Run the script with the cut; check what every run must show; return its stderr, the
    lab host's outcome and the time from the cut to the rig's abort [s] (< 0: before)."""
    proc = subprocess.run(
        ['bash', str(ROOT / 'tools' / 'two_hosts.sh'), '--partition', 'builder_remote',
         '--delay-ms', '5', '--jitter-ms', '1', '--cut-after', '3', '--out', str(out), '--',
         '--duration', '10', '--alpha', '0.5', '--predictor', 'model',
         '--set', 'watchdog_timeout_s=0.04', '--set', 'monitor_threshold=0'],
        cwd=cwd, env=ros_env, capture_output=True, text=True, timeout=300)
    err = proc.stderr
    assert 'Traceback' not in err
    # a safety function ended the run: a result, as any aborted run (exit 0 on both hosts)
    assert proc.returncode == 0, err
    cut = re.search(r'link cut \(.+ of lab, both ways\) .* at wall time (\d+) ns', err)
    assert cut, err
    # nothing left behind: namespaces (and the devices in them) removed, no process
    names = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not re.search(_left_behind(err), names), names
    leftover = subprocess.run(['pgrep', '-f', str(out)], capture_output=True, text=True)
    assert leftover.stdout.strip() == ''
    # the lab host: the rig went to its safe state on its own watchdog or the controller's
    lab = json.loads(next(out.glob('lab/*/outcome.json')).read_text())
    rig = lab['rig_final']
    assert rig['state'] == 'aborted' and 'watchdog' in rig['message'], rig
    detected_s = lab['rig_t0_ns'] * 1e-9 + float(rig['abort_at_s']) - int(cut.group(1)) * 1e-9
    return err, lab, detected_s


def test_a_cut_link_ends_the_run_safely_on_both_hosts(tmp_path, ros_env):
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    for attempt in (1, 2):
        out = tmp_path / f'two_hosts_{attempt}'
        err, lab, detected_s = _run_and_cut(tmp_path, ros_env, out)
        if detected_s > 0.0:
            break
        # the run ended before the cut: a stall of this shared machine longer than the
        # 40 ms watchdog (seen once in about ten runs); run it once more
        print(f'attempt {attempt}: the run ended {-1e3 * detected_s:.0f} ms before the cut: '
              f'{lab["rig_final"]["message"]}')
    else:
        pytest.skip('both runs ended before the cut (stalls of this machine)')
    # detected within the watchdog's 40 ms plus its timer period (10 ms) and a stall of
    # this shared machine
    print(f'link cut detected {1e3 * detected_s:.1f} ms after the cut: '
          f'{lab["rig_final"]["message"]}')
    assert detected_s < 0.1, detected_s
    # the lab, cut off from the recorder's host, ends its nodes once that host has been
    # silent for REFERENCE_SILENT_S after they ended (they lingered 20 s for the bag before)
    assert re.search(r'^lab: .*no word from the host with the recorder for [\d.]+ s after '
                     r'the nodes here ended \(link or host lost\)', err, re.MULTILINE), err

    # the compute host: the run recorded as aborted, the bag complete up to the cut
    entry = json.loads((out / 'compute' / 'summary.json').read_text())['runs'][0]
    assert entry['stable'] is False and 'watchdog' in entry['abort_reason']
    assert entry['bag_lost_messages'] == 0
    run = read_run(next(out.glob('compute/*/bag')))
    assert run.stable is False and 'watchdog' in run.abort_reason
    assert 2.5 < run.n_steps * DT < 4.0
    for name in ('reference_force_N', 'measured_force_N', 'displacement_m',
                 'valve_command_V'):
        signal = getattr(run, name)
        assert signal.shape == (run.n_steps,) and (signal == signal).all(), name
    # the hub forwarded both hosts' packets; the runners measured the link and sized the
    # playout delay from it (the round trip of 5 ms +/- 1 ms each way, and the hub's own)
    assert re.search(r'sh\d+1: [1-9]\d* forwarded, 0 dropped', err), err
    assert re.search(r'sh\d+2: [1-9]\d* forwarded, 0 dropped', err), err
    link = entry['link']
    assert link['playout'] == 'auto' and link['emulation'] == 'link emulator'
    rtt = link['hosts']['lab']['round_trip_ms']
    assert 8.0 < rtt['p50'] < 30.0, rtt
    # sized from the start-up measurement (the run's own is in 'hosts'), with the margin
    assert link['network_delay_s'] >= 1e-3 * (link['decided_round_trip_p99_ms'] + 3.0) - 1e-9
    assert link['decided_round_trip_p99_ms'] <= rtt['max']


def test_a_cut_link_on_the_default_partition_ends_the_run_on_the_compute_host(tmp_path,
                                                                              ros_env):
    """The default partition (the loop on the lab host, the recorder on the compute host),
    the link cut 1 s into a 3 s run: the lab stops its rig on its watchdog, and the compute
    host, which then hears nothing more of the lab, takes it for lost once it has answered no
    ping for REFERENCE_SILENT_S, ends the run with the reason and writes the report. Before,
    it waited for the lab's rig until 'the run stalled: no report for 30 s' (exit 2, no
    report; the recorder closed the bag 40 s after the start)."""
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    for attempt in (1, 2):
        out = tmp_path / f'cut_{attempt}'
        proc = subprocess.run(
            ['bash', str(ROOT / 'tools' / 'two_hosts.sh'), '--cut-after', '1', '--out',
             str(out), '--', '--duration', '3', '--set', 'watchdog_timeout_s=0.04'],
            cwd=tmp_path, env=ros_env, capture_output=True, text=True, timeout=300)
        err = proc.stderr
        assert 'Traceback' not in err
        # a safety function ended the run: a result on both hosts (exit 0), as one host's abort
        assert proc.returncode == 0, err
        if 'lab host lab lost' in err:
            break
        # the run ended before the cut (a stall of this shared machine): once more
        print(f'attempt {attempt}: the run ended before the cut:\n{err}')
    else:
        pytest.skip('both runs ended before the cut (stalls of this machine)')
    cut = re.search(r'link cut \(.+ of lab, both ways\) ([0-9.]+) s after the rigs started '
                    r'.* at wall time (\d+) ns', err)
    assert cut, err
    cut_s, cut_wall_s = float(cut.group(1)), int(cut.group(2)) * 1e-9
    lost = re.search(r'^compute: .*lab host lab lost after t = ([0-9.]+) s \(its last sample '
                     r'here\): link cut or host down, no word from it for ([0-9.]+) s; '
                     r'recording closed$', err, re.MULTILINE)
    assert lost, err
    # the lab's samples reached the bag up to the cut; the silence the pings measured
    assert cut_s - 0.15 < float(lost.group(1)) <= cut_s + 0.05, (cut_s, lost.group(1))
    assert 5.0 <= float(lost.group(2)) < 6.0, lost.group(2)
    # the bag closed within a few seconds of the cut: the lab's last answer to a ping (at
    # most 1 s before the cut) plus REFERENCE_SILENT_S (5 s), and a margin for this machine
    log = next(out.glob('compute/*/logs/recorder.log')).read_text()
    closed = re.search(r'\[(\d+\.\d+)\] \[recorder\]: bag .* closed', log)
    assert closed, log
    assert 3.5 < float(closed.group(1)) - cut_wall_s < 7.5, float(closed.group(1)) - cut_wall_s
    # the report, as seft compare writes it from the bag: aborted, with the reason
    entry = json.loads((out / 'compute' / 'summary.json').read_text())['runs'][0]
    assert entry['stable'] is False and entry['abort_node'] == 'seft_runner'
    assert entry['abort_reason'].startswith('seft_runner: lab host lab lost: no word from it')
    assert entry['recording']['end'] == 'stopped'
    assert abs(entry['unstable_at_s'] - float(lost.group(1))) < 0.01, entry['unstable_at_s']
    report = (out / 'compute' / 'report.md').read_text()
    assert 'lab host lab lost' in report and 'recording stopped' in report
    # the lab ended its nodes too, with its own reason
    assert re.search(r'^lab: .*no word from the host with the recorder', err, re.MULTILINE)
    names = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not re.search(_left_behind(err), names), names


def test_a_lossy_link_does_not_stop_the_run(tmp_path, ros_env):
    """1 % of the packets lost each way on a 5 ms link (the default partition): DDS resends
    them, the run completes and the bag is whole. A lost packet holds back every later sample
    of its writer until the writer's next heartbeat (seft_msgs_py.dds): with Fast DDS's 3 s
    default every such run stopped on a 20 ms watchdog at 0.4-1.2 s (3 of 3).

    At alpha 0: what crosses the link (the ground motion one way, the record and the statuses
    the other) is the same at any alpha, and without the acceleration fed back the host's
    late steps cannot make the run unstable. At alpha 0.5 on the slow VMs of 2026-11-29/30 the
    runs that completed were within 2 % in time, but 2 of 5 went unstable, over this link
    and over a clean one (70-115 late commands, stale steps up to 4-6 steps behind; as run,
    the timing replay stayed stable: part of that timing is not modelled)."""
    why = _can_make_namespaces()
    if why:
        pytest.skip(why)
    out = tmp_path / 'lossy'
    proc = subprocess.run(
        ['bash', str(ROOT / 'tools' / 'two_hosts.sh'), '--delay-ms', '5', '--jitter-ms', '1',
         '--loss', '0.01', '--out', str(out), '--', '--duration', '4', '--alpha', '0',
         '--predictor', 'model'],
        cwd=tmp_path, env=ros_env, capture_output=True, text=True, timeout=300)
    err = proc.stderr
    assert 'Traceback' not in err
    assert proc.returncode == 0, err
    # packets were lost both ways (the hub's model), and resent: nothing missing in the bag
    assert re.search(r'sh\d+1: [1-9]\d* forwarded, [1-9]\d* dropped', err), err
    assert re.search(r'sh\d+2: [1-9]\d* forwarded, [1-9]\d* dropped', err), err
    entry = json.loads((out / 'compute' / 'summary.json').read_text())['runs'][0]
    # no watchdog stopped it (a lost packet held back for a heartbeat period would); a run
    # the host's own scheduling ended (its stale steps, replayed as run: unstable too) is
    # judged by its replay in time (conftest.realtime_accuracy)
    assert 'watchdog' not in (entry['abort_reason'] or ''), entry['abort_reason']
    nrms, judged = realtime_accuracy(entry)
    assert entry['bag_lost_messages'] == 0
    run = read_run(next(out.glob('compute/*/bag')))
    if entry['stable']:
        assert run.stable and run.n_steps * DT >= 4.0 - DT
    # the run as accurate as over a clean link (one-host real time 0.4-0.9 % at alpha 0-1;
    # 0.4-0.8 % measured over this lossy link at alpha 1 on a faster host)
    assert nrms['displacement'] < 0.02, (judged, nrms)
