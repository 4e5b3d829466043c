"""``seft stability`` and the pre-run stability guard of ``seft simulate``/``seft run``."""

import json
from pathlib import Path
import re

import pytest

from seft_msgs_py.errors import SeftError
from seft_ros.cli import api
from seft_ros.core.stability import PredictedUnstableError

REFUSED = ('alpha=1.5 with predictor none on the servohydraulic rig is predicted unstable '
           '(largest stable alpha 1.32); use --force to run it anyway')


def test_simulate_refuses_a_predicted_unstable_run(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'simulate', '--alpha', '0.5', '1.5', '--duration', '1',
                        '--out', 'out'], cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr and proc.stdout == ''
    lines = proc.stderr.splitlines()
    assert lines[-1] == f'seft: error: {REFUSED}'
    assert all(ln.startswith('[seft] ') for ln in lines[:-1]), proc.stderr
    assert not any('simulating' in ln for ln in lines)          # nothing ran


def test_force_runs_it_with_a_warning(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'simulate', '--alpha', '1.5', '--duration', '1', '--out',
                        'out', '--force'], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    warning = [ln for ln in proc.stderr.splitlines() if 'warning:' in ln]
    assert warning[0] == ('[seft] warning: alpha=1.5 with predictor none on the servohydraulic '
                          'rig is predicted unstable (largest stable alpha 1.32); running it '
                          'anyway (--force)')
    # the unstable loop takes the accelerometer to its range before the monitor stops it: said
    # once during the run (issue 39)
    assert [ln.split(' at t=')[0] for ln in warning[1:]] == [
        '[seft] [alpha_1.5_servohydraulic_none] warning: acceleration at its sensor range '
        '(39.2 m/s^2)']
    assert (tmp_path / 'out' / 'summary.json').is_file()


def test_api_guard(reference_params, tmp_path):
    runs = [dict(reference_params, alpha=a, duration_s=0.2) for a in (1.0, 1.5, 2.0)]
    with pytest.raises(PredictedUnstableError, match=re.escape(
            'predicted unstable (largest stable alpha 1.32) (and 1 more run(s)); use --force')):
        api.simulate_experiments(runs=runs, out_dir=tmp_path, progress=lambda s: None)
    assert issubclass(PredictedUnstableError, SeftError)
    notes = []
    checks = api.check_stability(runs=[dict(reference_params, alpha=1.5,
                                            predictor='adaptive')], progress=notes.append)
    assert checks[0].stable is None
    assert notes and notes[0].startswith('note: alpha=1.5 with predictor adaptive')


def test_stability_verb(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'stability', '--rig', 'delay', '--predictor', 'none',
                        'adaptive', '--tau-min', '0.004', '--tau-max', '0.02', '--points', '3',
                        '--out', 'map'], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert out[0].split() == ['tau_s', '[ms]', 'none', 'adaptive']
    assert out[1].split() == ['4.00', '0.972', 'n/a']
    assert out[3].split() == ['20.00', '0.813', 'n/a']
    assert (tmp_path / 'map' / 'stability.png').stat().st_size > 10000
    doc = json.loads((tmp_path / 'map' / 'stability.json').read_text())
    assert doc['rig'] == 'delay' and doc['delay_parameter'] == 'tau_s'
    assert doc['taus_s'] == pytest.approx([0.004, 0.012, 0.02])
    assert doc['predictors']['none']['boundary_alpha'] == pytest.approx([0.972, 0.913, 0.813],
                                                                        abs=1e-3)
    assert doc['predictors']['adaptive']['note'].startswith('n/a')
    assert doc['configured'] == {'alpha': [0.0], 'tau_s': 0.01}


def test_stability_verb_bad_predictor(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'stability', '--predictor', 'foo', '--out', 'map'],
                       cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        "seft: error: predictor 'foo': expected one of 'none', 'polynomial', 'model', "
        "'adaptive', 'ats'"]


TWO_STORY = """\
predictor: [none, model]
duration_s: 1.0
structure:
  physical: {floor_1: lab}
  story_masses_kg: [52.7, 52.7]
  story_stiffnesses_N_per_m: [2.11e5, 2.11e5]
  story_damping_N_s_per_m: [903.278, 133.4]
"""


def test_a_structure_predicted_unstable_is_refused_then_forced(seft_exe, run_process,
                                                               tmp_path):
    """The guard of a structure: the coupled loop's eigenvalues; uncompensated the delay's
    negative damping at the coupling makes this building unstable, 'model' not."""
    (tmp_path / 'c.yaml').write_text(TWO_STORY)
    proc = run_process([seft_exe, 'simulate', 'c.yaml', '--out', 'out'], cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == ''
    assert re.fullmatch(r'seft: error: structure with predictor none is predicted UNSTABLE '
                        r'\(spectral radius 1\.0[0-9]{3}; unstable already at 0\.1 times its '
                        r"computational part\); it grows at 14\.2\d Hz, the structure's mode "
                        r'at 16\.29 Hz \(its modes: 6\.224, 16\.29 Hz\); use --force to run it '
                        r'anyway',
                        proc.stderr.splitlines()[-1]), proc.stderr
    proc = run_process([seft_exe, 'simulate', 'c.yaml', '--out', 'forced', '--force'],
                       cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    runs = json.loads((tmp_path / 'forced' / 'summary.json').read_text())['runs']
    assert [r['stable'] for r in runs] == [False, True]


def test_stability_map_of_a_structure(seft_exe, run_process, tmp_path):
    (tmp_path / 'c.yaml').write_text(TWO_STORY)
    proc = run_process([seft_exe, 'stability', 'c.yaml', '--points', '2', '--out', 'map'],
                       cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    # every compensator, in the registry's order (adaptive: no linear model)
    assert lines[0].split() == ['io_latency_s', '[ms]', 'none', 'polynomial', 'model',
                                'adaptive', 'ats']
    assert lines[1].split() == ['0.00', 'unstable', '>3', '>3', 'n/a', '>3']
    doc = json.loads((tmp_path / 'map' / 'stability.json').read_text())
    assert doc['quantity'] == 'largest stable coupling scale of the computational part'
    assert (tmp_path / 'map' / 'stability.png').stat().st_size > 10_000


def test_a_declared_uncertainty_wider_than_the_margin_is_refused(seft_exe, run_process,
                                                                   tmp_path):
    """The guard prints each run's robustness margin; specimen_uncertainty 0.2 on the two
    piers with 'model' (stable for 0.38-1.17 x) is one error line naming both ranges and
    exits 2, nothing run; 'adaptive' (identifies within +-50 %) runs."""
    config = Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml'
    common = [seft_exe, 'simulate', config, '--set', 'specimen_uncertainty=0.2',
              '--duration', '1']
    proc = run_process(common + ['--predictor', 'model', '--out', 'model'], cwd=tmp_path,
                       timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert re.search(r'robustness: \[structure_model\] stable for a specimen stiffness '
                     r'0\.3\d\d-1\.1\d x the declared one', proc.stderr), proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith('seft: error:')]
    assert len(errors) == 1 and 'Traceback' not in proc.stderr
    assert re.search(r'parameter specimen_uncertainty=0\.2: the specimens may be 0\.8-1\.2 x '
                     r'their declared stiffness, but predictor model stays stable only for '
                     r'0\.3\d\d-1\.1\d x', errors[0]), errors[0]
    assert not (tmp_path / 'model' / 'summary.json').exists()
    proc = run_process(common + ['--predictor', 'adaptive', '--out', 'adaptive'],
                       cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'robustness: [structure_adaptive] stable for a specimen stiffness 0.5-1.5 x' \
        in proc.stderr
    summary = json.loads((tmp_path / 'adaptive' / 'summary.json').read_text())['runs'][0]
    assert summary['stability']['robustness_margin']['stiffness_ratio_high'] == 1.5


#: A two-story whose uncompensated loop the guard predicts just unstable (spectral radius
#: 1.0002): the growth is slow, the record ends first (session 23's D2, a1.0_none.yaml).
SLOWLY_UNSTABLE = """\
predictor: [none]
amplitude_N: 600.0
duration_s: 2.0
structure:
  dofs: [f1, f2]
  physical: {f1: lab}
  story_masses_kg: [105.4, 40.0]
  story_stiffnesses_N_per_m: [208051.26077496368, 150000.0]
  story_damping_N_s_per_m: [331.1238656883643, 150.0]
rigs:
  lab:
    stiffness_N_per_m: 208051.26077496368
    damping_N_s_per_m: 331.1238656883643
    force_controller: specimen_loop_shaping
"""


def test_a_forced_run_predicted_unstable_that_completes_is_flagged(seft_exe, run_process,
                                                                   tmp_path):
    """Completing the record is not stability: the guard's prediction flags the run in the
    summary, on the console and in the report (before: verdict 'stable', flags [], and the
    report never named the prediction)."""
    (tmp_path / 'c.yaml').write_text(SLOWLY_UNSTABLE)
    proc = run_process([seft_exe, 'simulate', 'c.yaml', '--out', 'out', '--force'],
                       cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    run, = json.loads((tmp_path / 'out' / 'summary.json').read_text())['runs']
    assert run['stable'] is True and run['stability']['predicted_stable'] is False
    flag = ('predicted unstable: before the run the stability guard said: structure with '
            'predictor none is predicted UNSTABLE (spectral radius 1.0002; largest stable '
            "coupling 0.106 times its computational part); it grows at 12.34 Hz, the "
            "structure's mode at 12.21 Hz (its modes: 5.642, 12.21 Hz); it ran anyway "
            '(--force) and '
            'completed, but its loop grows: a longer record or a larger input may diverge')
    # (uncompensated: its error is its settings line's, not judged by a flag)
    assert run['flags'] == [flag] and run['verdict'] == 'stable, flagged'
    assert f'note: run 1 (none): flagged: {flag}' in proc.stdout.splitlines()
    assert f'- flagged: {flag}' in (tmp_path / 'out' / 'report.md').read_text().splitlines()
