"""The runner's run-time errors (issue 11, gap 8) that the other tests do not reach: a graph
that stalls, a domain that already carries seft topics, a bad ``ROS_DOMAIN_ID``, and a sweep
over several predictors through the node graph (one aborted run, the next one still runs).

Covered elsewhere: a node that crashes or is stopped (``test_faults.py``), the recorder
killed (``test_recorder_crash.py``), a domain another seft process claimed
(``workspace/test_domain_claim.py``), ``--domain-id`` out of range
(``cli/test_cli_errors.py``) and every file in ``config/`` (``cli/test_config_files.py``).
"""

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from conftest import DOMAIN_ID
import numpy as np
import pytest
from test_faults import _wait_for_rig
from test_node_graph_integration import DATA, leftover_processes, read_bag, value
from test_realtime_integration import _pid_of

from seft_ros.analysis.bag import read_run
from seft_ros.core.experiment import simulate

#: The runner's stall time-out in the stall test [s] (30 s in ``seft run``: the same path).
STALL_S = 3
#: ``seft run`` with the runner's stall time-out set to STALL_S.
RUNNER = ('import sys; from seft_ros.cli import runner; runner.STALL_TIMEOUT_S = {}; '
          'from seft_ros.cli.main import main; sys.exit(main())')


def _pending(pid: int, signum: int) -> bool:
    """Whether `signum` is pending, not yet delivered, for process `pid` (a stopped one)."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('ShdPnd:'):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


def test_a_stalled_graph_ends_in_one_error_line_and_a_closed_bag(tmp_path, ros_env):
    """The force servo controller hangs (SIGSTOP) in a lockstep run: the rig waits for its
    command, nobody reports, and after STALL_S the runner says the run stalled. It then stops
    the nodes with SIGINT; the controller, resumed once its SIGINT is pending, takes it as
    every node does, and the bag closes with the run up to the stall."""
    out = tmp_path / 'run'
    log = tmp_path / 'stderr.txt'
    with open(log, 'w') as err:
        proc = subprocess.Popen(
            [sys.executable, '-c', RUNNER.format(STALL_S), 'run', '--alpha', '0.5',
             '--duration', '30', '--time-scale', '2', '--out', str(out)], cwd=tmp_path,
            env=ros_env, stdout=subprocess.DEVNULL, stderr=err, text=True,
            start_new_session=True)
    pid = None
    try:
        _wait_for_rig(out)
        # the runner has heard every node ready and watches the run (a node stopped before
        # that is a start-up failure: 'nodes not ready after 60 s')
        # and the run has made steps (its progress line past step 0: on a loaded machine
        # the first steps can take longer than a fixed wait, and the bag would hold none)
        deadline = time.monotonic() + 60.0
        while not re.search(r'step [1-9]\d*/', log.read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        pid = _pid_of('force_servo_controller', str(out))
        os.kill(pid, signal.SIGSTOP)
        deadline = time.monotonic() + 90.0
        while not _pending(pid, signal.SIGINT):
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, 'the runner never stopped the stalled node'
            time.sleep(0.05)
        os.kill(pid, signal.SIGCONT)
        proc.wait(timeout=60)
        stderr = log.read_text()
    finally:
        if pid is not None:
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    run_dir = next(out.glob('alpha_*'))
    assert proc.returncode == 2, stderr
    assert 'Traceback' not in stderr
    assert stderr.strip().splitlines()[-1] == (
        f'seft: error: the run stalled: no report for {STALL_S} s (logs in {run_dir}/logs)')
    assert leftover_processes(str(out)) == []
    assert 'stalled' in json.loads((run_dir / 'outcome.json').read_text())['error']
    # the bag: closed, the run aborted by the stop, lockstep samples simulate's to the stall
    bag = run_dir / 'bag'
    assert (bag / 'metadata.yaml').is_file()
    run = read_run(bag)
    assert run.stable is False and 'SIGINT' in run.abort_reason, run.abort_reason
    assert run.n_steps > 0
    sim = simulate(run.params)
    for name in ('measured_force_N', 'displacement_m', 'reference_force_N', 'valve_command_V'):
        np.testing.assert_allclose(getattr(run, name), getattr(sim, name)[:run.n_steps],
                                   rtol=0, atol=1e-9, err_msg=name)


#: A node started by hand in the session's domain that publishes a seft topic.
BY_HAND = r"""
import sys
import rclpy
from seft_msgs_py.topics import REFERENCE_FORCE
rclpy.init()
node = rclpy.create_node('by_hand')
node.create_publisher(REFERENCE_FORCE.msg_type, REFERENCE_FORCE.name, REFERENCE_FORCE.qos)
print('up', flush=True)
sys.stdin.read()
rclpy.try_shutdown()
"""


def test_a_domain_that_carries_seft_topics_is_refused(tmp_path, ros_env, seft_exe,
                                                      run_process):
    """Two runs in one domain would mix their samples: with a publisher of
    /seft/reference_force already there, ``seft run`` starts nothing and says so in one
    line."""
    other = subprocess.Popen([sys.executable, '-c', BY_HAND], env=ros_env, text=True,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    default = {k: v for k, v in ros_env.items() if k != 'SEFT_DISCOVERY_SETTLE_S'}
    try:
        assert other.stdout.readline().strip() == 'up'
        proc = run_process([seft_exe, 'run', '--duration', '0.2', '--out', tmp_path / 'out'],
                           cwd=tmp_path, env=default)
    finally:
        other.stdin.close()
        other.wait(timeout=30)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f'seft: error: ROS_DOMAIN_ID={DOMAIN_ID} already carries seft topics '
        '(/seft/reference_force): another run? Choose another --domain-id')
    assert not list((tmp_path / 'out').glob('*/logs'))          # no node was started


@pytest.mark.parametrize('domain', ['233', 'abc'])
def test_a_bad_ros_domain_id_is_one_error_line(tmp_path, ros_env, seft_exe, run_process,
                                               domain):
    proc = run_process([seft_exe, 'run', '--duration', '0.2', '--out', tmp_path / 'out'],
                       cwd=tmp_path, env=dict(ros_env, ROS_DOMAIN_ID=domain))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"seft: error: ROS_DOMAIN_ID='{domain}': expected an integer 0-232"]
    assert not list((tmp_path / 'out').rglob('*'))               # nothing started


def test_an_unknown_node_start_method_is_one_error_line(tmp_path, ros_env, seft_exe,
                                                      run_process):
    proc = run_process([seft_exe, 'run', '--duration', '0.2', '--out', tmp_path / 'out'],
                       cwd=tmp_path, env=dict(ros_env, SEFT_NODE_START='thread'))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "seft: error: SEFT_NODE_START='thread': expected one of fork, exec"]
    assert not list((tmp_path / 'out').rglob('*'))               # nothing started


def test_a_sweep_over_two_predictors_runs_both_graphs(tmp_path, seft_exe, run_process):
    """``--predictor none model`` at alpha = 1.5 on the delay rig: two graphs one after the
    other in one domain. 'none' diverges and is aborted (a result, not an error), 'model' then
    runs the whole record; each bag equals ``seft simulate`` of its own parameters."""
    out = tmp_path / 'sweep'
    proc = run_process([seft_exe, 'run', '--rig', 'delay', '--alpha', '1.5', '--predictor',
                        'none', 'model', '--duration', '2', '--force', '--out', out],
                       cwd=tmp_path, timeout=240)
    assert proc.returncode == 0, proc.stderr
    assert 'Traceback' not in proc.stderr
    assert leftover_processes(str(out)) == []
    domains = re.findall(r'graph up in [\d.]+ s \(ROS_DOMAIN_ID=(\d+)\)', proc.stderr)
    assert domains == [str(DOMAIN_ID)] * 2, proc.stderr
    # each run's wall time, and the rigs' stepping without the start-up (the graph's
    # discovery and settling: a real-time run read 'x0.47 real time' before)
    walls = re.findall(r'\] (\d+) steps in ([\d.]+) s wall \(stepping ([\d.]+) s\);',
                       proc.stderr)
    assert len(walls) == 2 and walls[1][0] == '1000', proc.stderr
    assert all(0 < float(stepping) <= float(wall) for _, wall, stepping in walls), walls
    entries = json.loads((out / 'summary.json').read_text())['runs']
    assert [f'{e["wall_s"]:.1f}' for e in entries] == [w[2] for w in walls]
    assert [(e['predictor'], e['stable']) for e in entries] == [('none', False),
                                                                ('model', True)]
    bags = [next(out.glob(f'*_{predictor}/bag')) for predictor in ('none', 'model')]
    for bag, entry in zip(bags, entries):
        _, messages = read_bag(bag)
        params = json.loads(messages['/seft/run_parameters'][0][1].data)
        assert params['predictor'] == entry['predictor']
        sim = simulate(params)
        assert sim.stable is entry['stable']
        assert sim.n_steps == (1000 if sim.stable else round(sim.unstable_at_s / 0.002))
        for topic, (attr, path) in DATA.items():
            expected = getattr(sim, attr)
            if expected is None:
                assert topic not in messages, topic
                continue
            got = np.array([value(m, path) for _, m in messages[topic][:sim.n_steps]])
            np.testing.assert_allclose(got, expected, rtol=0,
                                       atol=1e-9 * np.max(np.abs(expected)), err_msg=topic)
        run = read_run(bag)
        assert (run.n_steps, run.stable) == (sim.n_steps, sim.stable)


@pytest.mark.parametrize('text, expected', [(None, 3.5), ('', 3.5), ('0.5', 0.5), ('0', 0.0),
                                            ('abc', None), ('-1', None), ('61', None)])
def test_discovery_settle_time_from_the_environment(monkeypatch, text, expected):
    from seft_msgs_py.errors import SeftError
    from seft_ros.cli.runner import discovery_settle_s
    if text is None:
        monkeypatch.delenv('SEFT_DISCOVERY_SETTLE_S', raising=False)
    else:
        monkeypatch.setenv('SEFT_DISCOVERY_SETTLE_S', text)
    if expected is None:
        with pytest.raises(SeftError, match=re.escape(
                f'SEFT_DISCOVERY_SETTLE_S={text!r}: expected a number of seconds in 0..60')):
            discovery_settle_s()
    else:
        assert discovery_settle_s() == expected
