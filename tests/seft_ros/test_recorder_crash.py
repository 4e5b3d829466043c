"""The recorder itself killed with SIGKILL in the middle of a ``seft run`` (issue 8).

Separate node processes over DDS, as a user starts them. The bag the killed recorder leaves
has no ``metadata.yaml`` and an MCAP file without summary or footer; ``seft compare`` on the
run's directory reads what was saved, says the recording was not closed, and the samples
are those of ``simulate`` bit for bit up to there. The bound the recorder states
(``FLUSH_EVERY_S`` of complete steps) is checked against the rig's last step: with the
lockstep flow control the rig never runs more than ``recorder_window_steps`` ahead of what
the recorder acknowledged.
"""

import json
import os
import re
import signal
import subprocess
import time

import numpy as np
from test_node_graph_integration import leftover_processes
from test_realtime_integration import _pid_of

from seft_msgs_py.signals import RECORD_ROWS
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.bag_recovery import FLUSH_EVERY_S
from seft_ros.core.experiment import simulate

DT = 0.002
WINDOW = 100          # recorder_window_steps: the smallest, the tightest check


def _wait_for_rig(out, timeout=90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        logs = list(out.glob('*/logs/rig.log'))
        if logs and 'starting (' in logs[0].read_text():
            return
        time.sleep(0.05)
    raise AssertionError('the rig did not start')


def test_a_killed_recorder_leaves_a_bag_that_seft_compare_reads(tmp_path, seft_exe, ros_env,
                                                                run_process):
    out = tmp_path / 'run'
    # a 60 s record of its own: the kill, 1.5 s after the rig starts, comes in the middle of
    # the run (the embedded 10 s record ran in lockstep in 0.9-6 s on this machine and had at
    # times ended before it)
    record = tmp_path / 'long.csv'
    t = np.arange(0.0, 60.0, 0.01)
    record.write_text('time,acceleration\n' + '\n'.join(
        f'{ti:.2f},{a:.6f}' for ti, a in zip(t, 2.0 * np.sin(2 * np.pi * 1.5 * t))))
    proc = subprocess.Popen(
        [str(seft_exe), 'run', '--alpha', '0.5', '--record', str(record), '--rig',
         'servohydraulic', '--set', f'recorder_window_steps={WINDOW}', '--out', str(out)],
        cwd=tmp_path,
        env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    try:
        _wait_for_rig(out)
        time.sleep(1.5)
        os.kill(_pid_of('recorder', str(out)), signal.SIGKILL)
        _, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode != 0, stderr
    assert 'Traceback' not in stderr
    assert 'recorder' in [ln for ln in stderr.splitlines() if 'error' in ln][-1], stderr
    assert leftover_processes(str(out)) == []
    run_dir = next(out.glob('alpha_*'))
    bag = run_dir / 'bag'
    assert not (bag / 'metadata.yaml').exists() and list(bag.glob('*.mcap'))

    # what was saved, against the bound
    run = read_run(bag)
    rec = run.extra['recording']
    assert rec['end'] == 'crashed' and rec['file_complete'] is False, rec
    assert rec['flush_every_s'] == FLUSH_EVERY_S
    rig_log = (run_dir / 'logs' / 'rig.log').read_text()
    last = re.search(r'run aborted at step (\d+)', rig_log)
    assert last, rig_log
    rig_steps = int(last.group(1))
    # the rig published step k only while k - (the recorder's acknowledged steps) < WINDOW;
    # the controller's valve commands reach the recorder up to two batches after the rig's
    received = rig_steps - WINDOW - 2 * RECORD_ROWS
    lost = received - run.n_steps
    assert run.n_steps <= rig_steps
    assert lost <= round(FLUSH_EVERY_S / DT), (
        f'recovered {run.n_steps} steps, the recorder had received at least {received}')
    assert not run.stable and 'not closed (recorder killed' in run.abort_reason
    assert run.unstable_at_s == run.n_steps * DT
    # lockstep: the samples are simulate's, bit for bit, up to the crash
    sim = simulate(run.params)
    for name in ('measured_force_N', 'displacement_m', 'acceleration_m_s2', 'reference_force_N',
                 'valve_command_V', 'ground_acceleration_m_s2'):
        np.testing.assert_allclose(getattr(run, name), getattr(sim, name)[:run.n_steps],
                                   rtol=0, atol=1e-9, err_msg=name)

    # seft compare on the run's directory: reads it and says the recording was not closed
    cmp_out = tmp_path / 'compare'
    done = run_process([seft_exe, 'compare', run_dir, '--out', cmp_out], cwd=tmp_path,
                       timeout=60)
    assert done.returncode == 0, done.stderr
    note = [ln for ln in done.stdout.splitlines() if ln.startswith('note: run 1')]
    assert len(note) == 1 and ('the recording was not closed (recorder killed, or still '
                               'recording)') in note[0], done.stdout
    assert f'recovered {run.n_steps * DT:.3f} s ({run.n_steps} steps' in note[0]
    entry = json.loads((cmp_out / 'summary.json').read_text())['runs'][0]
    assert entry['recording']['end'] == 'crashed' and entry['stable'] is False
    assert entry['verdict'] == 'recording cut short'
    assert entry['recording']['steps'] == run.n_steps
    assert '**recording not closed**' in (cmp_out / 'report.md').read_text()
