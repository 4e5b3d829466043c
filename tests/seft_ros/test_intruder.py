"""Only the run's own publishers command the rig (issue 42): a foreign sender on the run's
ROS domain during a real-time run of ``config/main.yaml`` (alpha 0.5, ``model``), as a user
runs it (``seft run``, every node a process over DDS), checked from the console, the bag and
the report.

The intruder (``intruder.py``, a process of its own named ``intruder``, started with the
run) publishes forged reference forces of 3000 N at 5 kHz from the run's step 400 (0.8 s) on,
each stamped for one of the run's next samples (the issue's scenario: before, the run
completed "stable" with NRMS x 9.76 % instead of 0.44 %, and nothing named it). On a topic
that commands the rig the run must stop safely, naming the publisher and the topic, without
taking one forged force; on a topic that does not (a record stream of the bag) the run goes
on, the forged rows are kept out of the bag, and a warning names it.

On ``/seft/node_parameters`` (session 23's D2: the nodes-by-hand recorder, run_token 'none',
on the domain of a live test made every node exit 'failed' mid-run, the rig with no safe
ramp, and the runner said "nothing was run"), lockstep graphs: another run's parameters are
named once and the run completes; parameters of the run's own token that differ once it has
begun stop it safely, the report written.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys

import numpy as np
import pytest
from test_node_graph_integration import leftover_processes

from seft_ros.analysis.bag import read_run
from seft_ros.core.experiment import simulate

ROOT = Path(__file__).resolve().parents[2]
MAIN = ROOT / 'config' / 'main.yaml'
INTRUDER = Path(__file__).with_name('intruder.py')
#: The run: 4 s of the main job's record at alpha 0.5 with its compensator, in real time.
RUN = ['--alpha', '0.5', '--predictor', 'model', '--mode', 'realtime', '--duration', '4']
#: The same run in lockstep, 8 s: a lockstep run goes faster than real time, and an intruder
#: that the run's participants learn of only at a periodic announcement (up to ~3 s, module
#: notes of intruder.py) reached a 4 s run after its bag had closed, or never (in the suite on
#: 2 cores, session 25: the warning on the console but not in the report, the intruder
#: waiting for a measurement it never heard, or the rig done before the abort came).
LOCKSTEP = ['--alpha', '0.5', '--predictor', 'model', '--mode', 'lockstep', '--duration', '8']
#: The bound of the run's own reference force, over the peak seft's pre-run reference analysis
#: predicts for the run (``summary.json``'s ``range_check``: 1911 N at 3.61 s for this run;
#: the lockstep run's reference peaks at 1910 N, a real-time run's at 1909 N on a loaded host).
#: The intruder's match, hence the abort, comes anywhere from 0.8 s to the run's end (the
#: intruder learns of the controller's subscription at a periodic announcement, up to ~3 s
#: later: aborts at 0.87-3.23 s in 6 runs beside a busy loop), so the whole run's peak is the
#: one to bound. Over it: a host stall of 5-8 ms (seen beside a busy loop at step 535: the rig
#: held the command 5 steps and its measured force swung to 1514 N where lockstep has 412 N)
#: moves the reference the builder makes from that measurement; the suite saw 2197 N (1.15 x)
#: against the former bound of 2000 N, written for a reference "below 1.1 kN" (true only of an
#: abort before 2.9 s). 1.25 covers that, below the divergence guard's 3 x (healthy runs
#: of docs/design/safety.md's calibration: at most 1.015 for the shipped configurations).
REFERENCE_MARGIN = 1.25


def run_with_intruder(tmp_path, seft_exe, env, topic, *extra, intruder=('3000', '5000'),
                      from_step=400, seconds=2.0, run=RUN, copy=False):
    """``seft run config/main.yaml RUN`` (or `run`) and the intruder, started together (the
    intruder's module notes: its participant takes part in the run's start-up discovery),
    the intruder publishing from the run's step `from_step` on for `seconds` (`copy`: with
    the run's seal or token); returns (the run's stdout, its run directory, the intruder's
    output)."""
    out = tmp_path / 'out'
    run = subprocess.Popen([str(seft_exe), 'run', str(MAIN), *run, '--out', str(out),
                            *extra], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, start_new_session=True)
    sender = subprocess.Popen([sys.executable, str(INTRUDER), topic, *intruder, str(seconds),
                               str(from_step), *(['copy'] if copy else [])], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              start_new_session=True)
    try:
        console, _ = run.communicate(timeout=120)
        try:
            said, _ = sender.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            # it never saw the run step (it waits up to intruder.WAIT_S): the run's own
            # console says why (the CI of 6bb3e60 showed only this timeout, twice)
            said = 'the intruder still waited 60 s after the run ended'
    finally:
        for p in (run, sender):                 # each a session: its nodes go with it
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert run.returncode == 0, f'{console}\nintruder: {said}'
    assert leftover_processes(str(out)) == []
    # the intruder published to the run: it reached the step and a subscription matched
    assert sender.returncode == 0 and ', matched by 0 ' not in said, said
    return console, next(out.glob('alpha_*')), said


def statuses(run_dir):
    data = read_run(run_dir / 'bag')
    return data, data.extra['node_statuses']


def test_a_forged_reference_force_is_never_applied_and_the_run_stops_naming_it(
        tmp_path, seft_exe, ros_env):
    """Target 3: the forged /seft/reference_force (3000 N at 5 kHz, stamped for the run's
    next samples): the run ends at once, naming the topic and the publisher: the force servo
    controller when its subscription matches a second publisher (by the publisher's gid: a
    new process's node announces its name ~80 ms after its publisher matches; the name
    follows as a warning), or the runner's check of the graph, whichever sees it first; the
    rig goes to its safe state; not one forged force was taken (the controller took no more
    reference forces than the builder sent, and the measured force followed them)."""
    console, run_dir, intruder = run_with_intruder(tmp_path, seft_exe, ros_env,
                                                    '/seft/reference_force')
    assert intruder.startswith('sent '), intruder
    summary = json.loads((run_dir.parent / 'summary.json').read_text())['runs'][0]
    reason = summary['abort_reason']
    assert 'foreign publisher' in console, f'the host stalled before the intruder came: {reason}'
    # whichever saw it first: the controller (its subscription matched a second publisher)
    # or the runner (its check of the graph every 0.25 s)
    assert reason.startswith(('force_servo_controller: foreign publisher on '
                              '/seft/reference_force: ', 'seft_runner: foreign publisher on '
                              '/seft/reference_force: ')), reason
    assert "'intruder' (gid " in reason or 'a node not named yet (gid ' in reason, reason
    # the publisher by its name, in the console and in the bag (the node's warning once the
    # name is announced, the runner's abort of its check)
    named = "foreign publisher on /seft/reference_force: 'intruder' (gid "
    assert named in console, console
    data, reports = statuses(run_dir)
    assert any(named in s.get('message', '') for s in reports), reports
    assert named in (run_dir.parent / 'report.md').read_text()
    # the rig in its safe state, the run aborted, the bag closed
    finals = {s['name']: s for s in reports if s.get('state') in ('done', 'aborted',
                                                                   'failed')}
    assert finals['rig']['state'] == 'aborted' and 'abort_at_s' in finals['rig']
    # not one forged force taken: the controller took no more reference forces than the
    # builder published (each once: reliable, in order), and the measured force followed the
    # builder's reference force, the run's own (within REFERENCE_MARGIN of the reference
    # analysis's peak: 3000 N forged against 1911 N predicted); the bag's reference force is
    # the builder's record stream, sealed: no forged message reaches it
    controller = finals['force_servo_controller']
    taken = int(controller['taken:/seft/reference_force'])
    assert 0 < taken <= int(finals['reference_force_builder']['published'])
    rig = data.rigs['']
    n = min(int(float(finals['rig']['abort_at_s']) / float(data.params['dt'])),
            rig.reference_force_N.size)
    peak = np.max(np.abs(rig.reference_force_N[:n]))
    predicted = summary['range_check']['rigs']['']['force']['peak']
    assert peak < REFERENCE_MARGIN * predicted, (peak, predicted, n)
    assert np.max(np.abs(rig.measured_force_N[:n])) < 1.2 * peak


def test_a_foreign_record_stream_is_a_warning_and_the_run_completes(tmp_path, seft_exe,
                                                                     ros_env):
    """A foreign publisher on a topic that does not command the rig (the rig's record
    stream, which the recorder writes into the bag), in a run with message_auth hmac (the
    shared key): the recorder keeps its batches out of the bag and a warning names it, in
    the console, the bag and the report; the run completes with every sample, and its
    displacement is the lockstep simulation's within 1 % NRMS (a clean real-time run's
    difference is 0.0-0.2 %)."""
    key = tmp_path / 'test.key'
    key.write_text('3a' * 32 + '\n')
    os.chmod(key, 0o600)
    console, run_dir, intruder = run_with_intruder(
        tmp_path, seft_exe, ros_env, '/seft/record/rig', '--set', 'message_auth=hmac',
        '--set', f'auth_key_file={key}', intruder=('1e6', '500'))
    assert intruder.startswith('sent '), intruder
    data, reports = statuses(run_dir)
    assert data.stable, data.abort_reason
    warning = [s['warning'] for s in reports if 'foreign publisher on /seft/record/rig'
               in s.get('warning', '')]
    assert any("'intruder' (gid " in w for w in warning), warning
    assert any(w in console for w in warning)
    assert f'- **warning**: {warning[0]}' in (run_dir.parent / 'report.md').read_text()
    rig = data.rigs['']
    assert rig.measured_force_N.size == 2000 and np.all(np.isfinite(rig.displacement_m))
    # no forged row in the bag: the intruder's carry 1e6 N; the run's own force, in real
    # time, peaked at 2064 N on a loaded host (the bound was 2e3 N; session 39)
    assert np.max(np.abs(rig.measured_force_N)) < 1e5
    reference = simulate(dict(data.params, mode='lockstep')).rigs[''].displacement_m
    nrms = np.sqrt(np.mean((rig.displacement_m - reference) ** 2)) / np.ptp(reference)
    assert nrms < 0.01, nrms


def test_another_runs_node_parameters_are_named_once_and_the_run_completes(
        tmp_path, seft_exe, ros_env):
    """The nodes-by-hand recorder's parameters (run_token 'none', alpha 0, 4 s, lockstep)
    published on the run's domain from step 300 of an 8 s lockstep run: not the run's. Before:
    every node refused them ('parameter run_token differs: recorder='none', ...'), exit 2,
    "4 shared parameter(s) differ between the nodes (listed above); nothing was run", no
    report. Now one warning names them, and the run completes with every sample, its bag's
    parameters the run's own."""
    console, run_dir, intruder = run_with_intruder(
        tmp_path, seft_exe, ros_env, '/seft/node_parameters', run=LOCKSTEP,
        intruder=('0.0', '20'), from_step=300, seconds=1.0)
    assert intruder.startswith('sent '), intruder
    assert 'differs' not in console and 'nothing was run' not in console, console
    named = ("foreign publisher on /seft/node_parameters: parameters of a node 'recorder' "
             "with run_token 'none', not this run's: ignored")
    assert console.count(named) == 1, console
    data, reports = statuses(run_dir)
    assert data.stable, data.abort_reason
    assert data.extra['parameter_mismatches'] == []
    assert data.params['alpha'] == 0.5 and data.params['run_token'] != 'none'
    finals = {s['name']: s['state'] for s in reports
              if s.get('state') in ('done', 'aborted', 'failed')}
    assert set(finals.values()) == {'done'}, finals
    assert data.rigs[''].measured_force_N.size == 4000
    assert named in (run_dir.parent / 'report.md').read_text(), (intruder, console)


def test_a_node_of_the_run_with_other_parameters_after_the_start_stops_it_safely(
        tmp_path, seft_exe, ros_env):
    """Parameters with the run's own token (a node of this run) that differ (alpha 0,
    duration 4 s) heard from step 300 of an 8 s lockstep run (LOCKSTEP: in the suite
    the 4 s run once ended, its rig 'done', before the abort reached it): the run is stopped
    through the abort path, at the step it had reached, the report written. Before: every
    node exited 'failed' at once and the runner said "nothing was run" (exit 2, no report)."""
    console, run_dir, intruder = run_with_intruder(
        tmp_path, seft_exe, ros_env, '/seft/node_parameters', run=LOCKSTEP,
        intruder=('0.0', '20'), from_step=300, seconds=1.0, copy=True)
    assert intruder.startswith('sent '), intruder
    assert 'nothing was run' not in console, console
    assert 'parameter alpha differs: recorder=0.0' in console, console
    summary = json.loads((run_dir.parent / 'summary.json').read_text())['runs'][0]
    reason = summary['abort_reason']
    assert ('parameters differ between nodes after the start: parameter alpha differs: '
            'recorder=0.0, ') in reason and 'the run is stopped safely' in reason, reason
    # the console's last line says when: at or after the intruder's first step (0.6 s)
    stopped = float(console.split('ABORTED at ')[1].split(' s: ')[0])
    data, reports = statuses(run_dir)
    assert not data.stable and data.unstable_at_s == pytest.approx(stopped, abs=1e-3)
    finals = {s['name']: s for s in reports if s.get('state') in ('done', 'aborted',
                                                                   'failed')}
    assert finals['rig']['state'] == 'aborted', finals['rig']
    assert not any(s['state'] == 'failed' for s in finals.values()), finals
    # the samples up to there in the bag
    n = data.rigs[''].measured_force_N.size
    assert 300 <= n < 4000 and 0.6 <= stopped <= n * 0.002, (n, stopped)
    assert reason in (run_dir.parent / 'report.md').read_text()
