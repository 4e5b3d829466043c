"""Two runners of one split run meet, measure their link and agree before their nodes start
(seft_ros/cli/link.py): on one host in one ROS domain, the "lab" host's clock shifted by
50 ms with the test-only setting, so that the offset estimate and its correction of the
timing ages are checked against a known offset."""

import json
import os
import signal
import subprocess

import pytest

from seft_ros.analysis.bag import read_run

OFFSET_S = 0.05


def _start(seft_exe, ros_env, tmp_path, site, extra_env=None):
    env = dict(ros_env, **(extra_env or {}))
    return subprocess.Popen(
        [str(seft_exe), 'run', '--partition', 'builder_remote', '--site', site, '--mode',
         'realtime', '--alpha', '0.5', '--predictor', 'model', '--duration', '2',
         # what is checked is the link, not the loop: the instability monitor's high-frequency
         # test tripped once on a CI host under load (1.09 x its threshold at 0.84 s, a 8 ms
         # playout), so it is off here; the stroke and force limits still stop a run away
         '--set', 'watchdog_timeout_s=0.2', '--set', 'monitor_threshold=0',
         '--out', str(tmp_path / site)], cwd=tmp_path,
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)


def test_the_hosts_measure_their_link_and_run_in_one_clock(tmp_path, seft_exe, ros_env):
    lab = _start(seft_exe, ros_env, tmp_path, 'lab',
                 {'SEFT_TEST_CLOCK_OFFSET_S': str(OFFSET_S)})
    compute = _start(seft_exe, ros_env, tmp_path, 'compute')
    try:
        c_out, c_err = compute.communicate(timeout=150)
        l_out, l_err = lab.communicate(timeout=60)
    finally:
        for p in (lab, compute):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert compute.returncode == 0, c_err
    assert lab.returncode == 0, l_err
    # the compute host (the recorder's) measured the link and chose the playout delay
    link_line = next(ln for ln in c_err.splitlines() if 'link compute - lab: round trip' in ln)
    offset_ms = float(link_line.split('clock offset ')[1].split(' ms')[0])
    assert offset_ms == pytest.approx(1e3 * OFFSET_S, abs=2.0)
    assert 'network_delay_s auto:' in c_err
    assert any("this host's clock offset from the reference host: +" in ln
               for ln in l_err.splitlines())
    run = read_run(next((tmp_path / 'compute').glob('*/bag')))
    assert run.n_steps == 1000 and run.stable, run.abort_reason
    summary = json.loads((tmp_path / 'compute' / 'summary.json').read_text())['runs'][0]
    link = summary['link']
    assert link['reference'] == 'compute' and link['playout'] == 'auto'
    assert link['hosts']['lab']['offset_ms'] == pytest.approx(1e3 * OFFSET_S, abs=2.0)
    rtt = link['hosts']['lab']['round_trip_ms']
    # the p99 on loopback well within 50 ms; the max is the host's worst stall of the run
    # (60.9 ms once on the slow VMs of 2026-11-30: the fresh-clone CI of f196ad5)
    assert 0.0 < rtt['p50'] <= rtt['p99'] <= rtt['max'] and rtt['p99'] < 50.0
    # network_delay_s covers the round trip's p99 measured at start-up (the one it was chosen
    # from) plus the margin, in whole steps; the pings of the whole run (in `rtt`) may reach
    # past it on this shared host (7.7 ms against 7 ms measured once), which the summary
    # counts as commands that missed their playout step
    decided = link['decided_round_trip_p99_ms']
    assert 0.0 < decided < 50.0
    assert link['network_delay_s'] >= (decided + 3.0) * 1e-3 - 1e-9
    assert (link['network_delay_s'] - 2e-3) < (decided + 3.0) * 1e-3   # the least whole steps
    assert 0.0 <= link['playout_missed_fraction'] < 0.01
    assert run.params['network_delay_s'] == pytest.approx(link['network_delay_s'])
    # ages across the hosts in the reference clock: the builder (compute) takes the rig's
    # samples (lab) a fraction of a millisecond old, not 50 ms; within the clock offset's own
    # error (asserted above to 2 ms), so it can read below 0 (-0.38 ms once: the fresh-clone
    # CI of 6d4f70a)
    age = summary['timing']['nodes']['reference_force_builder']['input_age_ms']['p50']
    assert -2.0 < age < 10.0
