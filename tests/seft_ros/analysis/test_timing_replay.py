"""A real-time run replayed in one process (``seft compare --replay-timing``): the rig
replays each command at its recorded arrival (seft_plant_sim.realtime.ReplayRig,
``simulate(command_latency_s=...)``), and ``replay_timing`` splits a run's error into the
host's timing and the method's.

The "real-time run" here is made in process with known late commands and stale steps, its
timing records those of a real-time bag (NodeTiming): the replay as run must give it back
exactly, and the replay in time the lockstep run.
"""

from pathlib import Path

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.findings import timing_replay_line
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.timing import NodeTiming
from seft_ros.analysis.timing_replay import replay_timing
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate

CONFIG = Path(__file__).resolve().parents[3] / 'config'
DT = 0.002
N = 1500                                        # 3 s of the study's test


@pytest.fixture(scope='module')
def params():
    p = [p for p in expand_runs(load_config(CONFIG / 'main.yaml'))
         if p['predictor'] == 'model'][0]
    return dict(p, alpha=1.0, n_steps=N)


def _timing(node, steps, latency=None, stale=None, age=None):
    n = steps.size
    nan = np.full(n, np.nan)
    return NodeTiming(node, steps, nan, nan, nan if age is None else age, np.zeros(n, bool),
                      np.zeros(n, bool) if stale is None else stale,
                      nan if latency is None else latency)


def test_commands_in_time_on_the_replayed_rig_are_the_lockstep_run(params):
    """seft's servohydraulic rig latches a command in time at the next tick: replayed with
    every command 0.5 ms after its sample, the run is the lockstep run (to rounding: the
    real-time rig integrates on a 0.1 ms grid)."""
    lockstep = simulate(params)
    replayed = simulate(params, command_latency_s={'': {}})
    np.testing.assert_allclose(replayed.displacement_m, lockstep.displacement_m,
                               rtol=0, atol=1e-9 * np.max(np.abs(lockstep.displacement_m)))
    with pytest.raises(ParameterError, match=r'command latencies of rig\(s\) pier_c'):
        simulate(params, command_latency_s={'pier_c': {}})


def test_the_replay_splits_a_runs_error_into_the_hosts_timing_and_the_methods(params):
    """Six commands 1.2-3.5 ms late, two lost and five stale reference forces: the replay
    as run gives the run's NRMS back to the digit, the replay in time the lockstep run's; the
    difference is what the late steps cost. The lost commands are counted apart from the
    late ones (a new user read them among the late; session 36)."""
    rng = np.random.default_rng(5)
    latency = np.full(N, 0.0005)
    late = rng.choice(np.arange(200, N - 10), 8, replace=False)
    latency[late] = DT + rng.uniform(1.2e-3, 3.5e-3, 8)
    latency[late[6:]] = np.nan
    stale = np.zeros(N, bool)
    stale[rng.choice(np.arange(300, N - 10), 5, replace=False)] = True
    run = simulate(params, command_latency_s={'': dict(enumerate(latency))},
                   stale_steps=set(np.flatnonzero(stale)))
    run.params = dict(run.params, mode='realtime')
    steps = np.arange(N)
    run.extra['timing_data'] = {
        'rig': _timing('rig', steps, latency=latency),
        'force_servo_controller': _timing('force_servo_controller', steps, stale=stale)}
    replay = replay_timing(run)
    assert replay['late_commands'] == {'': 6} and replay['lost_commands'] == {'': 2}
    assert replay['stale_steps'] == {'': 5}
    assert replay['as_run'] == replay['recorded']
    lockstep = compare_run(simulate(params)).displacement.nrms
    assert replay['in_time']['displacement'] == pytest.approx(lockstep, rel=1e-6)
    # the study's specimen (2.2 % damped, alpha 1) forgives them: 0.317 against 0.307 %
    assert replay['as_run']['displacement'] > 1.01 * replay['in_time']['displacement']
    # the rig held its late commands: what one that predicts them would have made of it
    # (acceleration 8.48 % as run, 0.722 % predicting, 0.719 % in time)
    as_run, predicting, in_time = (replay[k] for k in ('as_run', 'predicting', 'in_time'))
    assert in_time['displacement'] < predicting['displacement'] < as_run['displacement']
    assert predicting['acceleration'] - in_time['acceleration'] < 0.0002
    assert as_run['acceleration'] > 0.05
    line = timing_replay_line(replay)
    assert line.startswith('6 late command(s) and 2 lost (rig ticks on the previous command: '
                           'the stale commands), 5 controller stale step(s); worst NRMS x / a '
                           '/ f recorded')
    assert ', the rig predicting late commands (realtime_late_command: predict) ' in line
    assert 'does not reproduce' not in line
    # a predicting replay that a monitor stopped is said to be aborted
    stopped = dict(replay, predicting={'unstable_at_s': 14.062})
    assert ('the rig predicting late commands (realtime_late_command: predict) aborted at '
            '14.06 s, with every step in time') in timing_replay_line(stopped)
    # a replay that misses the run says so (a 40 ms stall of the rig's own tick: 42 % run,
    # 22 % replayed)
    missed = dict(replay, recorded=dict(replay['as_run'], displacement=0.42),
                  as_run=dict(replay['as_run'], displacement=0.22))
    assert 'replayed as run 22.00 / ' in timing_replay_line(missed)
    assert '(which does not reproduce the run: part of its timing is not modelled)' in \
        timing_replay_line(missed)
    # a lockstep run, or a lab's rig, has nothing to replay
    assert replay_timing(simulate(params)) is None
    run.params['rig_interface'] = 'udp_bridge'
    assert replay_timing(run) is None


def test_seft_run_replays_a_run_that_erred_with_late_steps_and_flags_the_hosts_cost(
        params, monkeypatch):
    """``seft run`` replays a real-time run by itself where it erred by more than 1 % with a
    late step (replay_due), and the report flags it when the late steps cost more than half
    a percentage point (timing_cost_flag); one late step on a run within 1 % is left."""
    from seft_ros.analysis.findings import run_flags, timing_cost_flag
    from seft_ros.analysis.timing_replay import replay_due
    from seft_ros.cli import api
    latency = np.full(N, 0.0005)
    latency[700] = 2 * DT + 0.0007
    run = simulate(params, command_latency_s={'': dict(enumerate(latency))})
    run.params = dict(run.params, mode='realtime')
    steps = np.arange(N)
    run.extra['timing_data'] = {'rig': _timing('rig', steps, latency=latency)}
    assert replay_due(run, {'displacement': 0.011, 'acceleration': None})
    assert not replay_due(run, {'displacement': 0.009, 'acceleration': 0.0099})
    assert replay_due(run, lambda: {'displacement': 0.011})
    # without a late step the run's error is not even compared (the callable not called)
    in_time = simulate(params)
    in_time.params = dict(in_time.params, mode='realtime')
    in_time.extra['timing_data'] = {'rig': _timing('rig', steps, latency=np.full(N, 5e-4))}
    assert not replay_due(in_time, lambda: pytest.fail('compared a run with no late step'))
    lines = []
    api._replay_if_due(run, 'run 1', lines.append)
    assert lines == []                              # the study's run errs 0.3 %: no replay
    from seft_ros.analysis import timing_replay
    monkeypatch.setattr(timing_replay, 'replay_due', lambda run, worst: True)
    api._replay_if_due(run, 'run 1', lines.append)
    assert lines[0].startswith('[run 1] late steps and an error above 1 %: replaying')
    assert lines[1].startswith('[run 1] timing: 1 late command(s) (rig ticks on the previous '
                               'command: the stale commands), 0 controller stale step(s)')
    assert run.extra['timing_replay']['late_commands'] == {'': 1}
    base = {'displacement': 0.01, 'acceleration': 0.02, 'floor_acceleration': 0.02,
            'interface_force': 0.01}
    replay = {'late_commands': {'': 1}, 'stale_steps': {'': 0}, 'recorded': dict(base),
              'as_run': dict(base, acceleration=0.0245), 'in_time': base}
    assert timing_cost_flag(replay) is None         # 0.45 points
    replay['as_run']['acceleration'] = 0.026
    flag = timing_cost_flag(replay)
    assert flag.startswith('timing: 1 late command(s) (rig ticks on the previous command: the '
                           'stale commands), 0 controller stale step(s); worst NRMS')
    replay['as_run'] = {'unstable_at_s': 1.2}
    assert 'stopped at 1.20 s' in timing_cost_flag(replay)
    run.extra['timing_replay'] = replay
    assert any(f.startswith('timing: ') for f in run_flags(run, compare_run(run)))


def test_a_controller_several_steps_behind_is_replayed_as_it_ran(params):
    """A builder that falls behind in a host stall leaves the controller several steps
    behind its reference forces; the controller's input age (from the newest force it held
    to its command) less the rig's loop latency of that command says how many
    (steps_behind), and the replay as run gives the run back exactly. Taken one step
    behind each (the replay before), it does not."""
    from seft_ros.analysis.timing_replay import steps_behind
    latency = np.full(N, 0.0005)
    behind = {600 + i: d for i, d in enumerate((1, 2, 3, 4, 5, 4, 3, 2, 1))}
    run = simulate(params, command_latency_s={'': dict(enumerate(latency))},
                   stale_steps={'': behind})
    run.params = dict(run.params, mode='realtime')
    steps = np.arange(N)
    stale = np.isin(steps, list(behind))
    # the command leaves 0.1 ms before it reaches the rig; the newest force d steps old
    age = latency - 1e-4 + DT * np.array([behind.get(k, 0) for k in steps])
    ctrl = _timing('force_servo_controller', steps, stale=stale, age=age)
    rig = _timing('rig', steps, latency=latency)
    assert steps_behind(ctrl, rig, DT) == behind
    run.extra['timing_data'] = {'rig': rig, 'force_servo_controller': ctrl}
    replay = replay_timing(run)
    assert replay['steps_behind'] == {'': 5}
    assert replay['as_run'] == replay['recorded']
    assert '9 controller stale step(s) (up to 5 steps behind)' in timing_replay_line(replay)
    one_behind = simulate(params, command_latency_s={'': dict(enumerate(latency))},
                          stale_steps={'': set(behind)})
    assert (compare_run(one_behind).displacement.nrms
            != pytest.approx(replay['recorded']['displacement'], rel=1e-3))


def test_a_rig_section_that_holds_is_replayed_predicting_too(tmp_path):
    """A structure whose run predicts late commands but whose pier_a section holds them
    (``realtime_late_command`` is a rig's parameter): pier_a's late commands are held as
    run, and the replay says what predicting them would have given, with the section's own
    setting overridden (before, the run's top-level ``predict`` hid it)."""
    import yaml
    doc = yaml.safe_load((CONFIG / 'two_piers.yaml').read_text())
    doc.update(predictor='model', realtime_late_command='predict')
    doc['rigs']['pier_a']['realtime_late_command'] = 'hold'
    path = tmp_path / 'two_piers.yaml'
    path.write_text(yaml.safe_dump(doc))
    p = dict(expand_runs(load_config(path))[0], n_steps=N)
    rng = np.random.default_rng(7)
    latency = {rig: np.full(N, 0.0005) for rig in ('pier_a', 'pier_b')}
    late = rng.choice(np.arange(200, N - 10), 8, replace=False)
    latency['pier_a'][late] = DT + rng.uniform(1.2e-3, 3.5e-3, 8)
    run = simulate(p, command_latency_s={r: dict(enumerate(v)) for r, v in latency.items()})
    run.params = dict(run.params, mode='realtime')
    steps = np.arange(N)
    run.extra['timing_data'] = {f'{r}/rig': _timing('rig', steps, latency=latency[r])
                                for r in latency}
    replay = replay_timing(run)
    assert replay['late_commands'] == {'pier_a': 8, 'pier_b': 0}
    assert replay['as_run'] == replay['recorded']
    as_run, predicting, in_time = (replay[k] for k in ('as_run', 'predicting', 'in_time'))
    # held, the late commands cost the rig's acceleration; predicted, nearly nothing
    assert predicting['acceleration'] < as_run['acceleration']
    assert predicting['acceleration'] - in_time['acceleration'] < \
        0.1 * (as_run['acceleration'] - in_time['acceleration'])


def test_an_aborted_real_time_run_with_late_steps_is_replayed_not_an_interrupted_one(
        params, monkeypatch):
    """A real-time run stopped by an abort (the monitor, the watchdog) after a late step is
    replayed whatever its error (it has no NRMS to judge): did the host's timing stop it?
    (Before: a 'model' run stopped by the monitor at 1.99 s on a loaded host showed 'stable
    False' only; the replay by hand gave 0.35 % with every step in time.) A run the operator
    interrupted, or one whose late steps came after its abort, is not replayed."""
    from types import SimpleNamespace

    from seft_ros.analysis.timing_replay import replay_due
    from seft_ros.cli import api
    latency = np.full(N, 0.0005)
    latency[700] = 2 * DT + 0.0007
    steps = np.arange(N)

    def aborted_run(n_steps, **extra):             # what replay_due reads of a RunData
        return SimpleNamespace(
            params=dict(params, mode='realtime'), stable=False, n_steps=n_steps,
            unstable_at_s=n_steps * DT,
            extra=dict({'timing_data': {'rig': _timing('rig', steps, latency=latency)}},
                       **extra))
    aborted = aborted_run(1000)
    assert replay_due(aborted, lambda: pytest.fail('an aborted run has no NRMS to judge'))
    before = aborted_run(600)
    assert not replay_due(before, lambda: pytest.fail('no late step before the abort'))
    interrupted = aborted_run(1000, interrupted=True)
    assert not replay_due(interrupted, lambda: pytest.fail('the operator stopped it'))
    lines = []
    from seft_ros.analysis import timing_replay
    monkeypatch.setattr(timing_replay, 'replay_timing', lambda run, recorded=None: None)
    api._replay_if_due(aborted, 'run 1', lines.append)
    assert lines == ['[run 1] late steps and an abort: replaying the run in process, as it '
                     'ran and in time']


def test_a_run_a_watchdog_stopped_is_judged_by_its_errors_to_then():
    """A real-time run a watchdog stopped (a host stall: no replay models it): its recorded
    cell gives its NRMS to the stop, and a replay as run (which runs to the same step and
    completes) that matches them reproduces it (a new user's, within 0.3 points, was said
    not to; session 39); one far off does not."""
    from seft_ros.analysis.findings import replay_reproduces_run
    from seft_ros.analysis.timing_replay import worst_nrms
    run = simulate({'alpha': 1.5, 'predictor': 'none', 'duration_s': 2.0})
    assert not run.stable
    assert set(worst_nrms(run)) == {'unstable_at_s'}              # the monitor's stop
    run.abort_reason = ('pier_b/force_servo_controller: watchdog: no measurement for 21 ms '
                        '(limit 20 ms; node or link lost)')
    worst = worst_nrms(run)
    assert worst['watchdog'] and worst['unstable_at_s'] == run.unstable_at_s
    assert 0 < worst['displacement'] < worst['acceleration']
    recorded = {'unstable_at_s': 9.924, 'watchdog': True, 'displacement': 0.0881,
                'acceleration': 0.7582, 'floor_acceleration': 0.455, 'interface_force': 0.2519}
    as_run = {'displacement': 0.0878, 'acceleration': 0.7604, 'floor_acceleration': 0.454,
              'interface_force': 0.2525}
    in_time = {'displacement': 0.0021, 'acceleration': 0.0039, 'floor_acceleration': 0.0024,
               'interface_force': 0.0017}
    replay = {'late_commands': {'pier_b': 40}, 'stale_steps': {'pier_b': 30},
              'recorded': recorded, 'as_run': as_run, 'in_time': in_time}
    assert replay_reproduces_run(replay)
    line = timing_replay_line(replay)
    assert ('recorded stopped at 9.92 s by a watchdog (8.81 / 75.82 / 25.19 % to then), '
            'replayed as run 8.78 / 76.04 / 25.25 %, with every step in time') in line
    far = dict(replay, as_run=dict(as_run, displacement=0.02))
    assert not replay_reproduces_run(far)
    assert 'does not reproduce the run' in timing_replay_line(far)
