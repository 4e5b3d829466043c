"""``seft simulate`` with several runs: a process pool that gives each run's numbers alone."""

import multiprocessing

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_ros.cli import api
from seft_ros.core.experiment import simulate

FIELDS = ('time_s', 'ground_acceleration_m_s2', 'reference_force_N', 'measured_force_N',
          'displacement_m', 'velocity_m_s', 'acceleration_m_s2', 'valve_command_V')


@pytest.fixture
def no_report(monkeypatch):
    """Skip the stability guard and the report (tested elsewhere): only the runs matter here."""
    monkeypatch.setattr(api, 'check_stability', lambda **kw: [])
    monkeypatch.setattr(api, 'check_ranges', lambda **kw: [])
    monkeypatch.setattr(api, 'check_settings', lambda **kw: None)
    monkeypatch.setattr(api, '_finish', lambda out_dir, runs, title, t0:
                        api.Result(out_dir, runs, [], 0.0))


def _runs():
    """Both rigs, three predictors, a run the monitor aborts and one with sensor noise."""
    base = dict(duration_s=1.0, amplitude_N=500.0)
    sets = [dict(rig_model='servohydraulic', predictor='model', alpha=1.0),
            dict(rig_model='servohydraulic', predictor='none', alpha=1.5),        # aborts
            dict(rig_model='delay', predictor='model', alpha=0.5, ground_preview=True),
            dict(rig_model='delay', predictor='adaptive', alpha=1.0),
            dict(rig_model='servohydraulic', predictor='none', alpha=0.5, noise_force_N=5.0)]
    return [parameters.resolve(dict(base, **s)) for s in sets]


def test_pool_gives_the_numbers_of_each_run_alone(no_report, tmp_path):
    runs = _runs()
    lines = []
    result = api.simulate_experiments(runs=runs, out_dir=tmp_path, progress=lines.append,
                                      workers=2)
    assert '5 runs on 2 worker processes' in lines
    assert len(result.runs) == len(runs)
    for p, got in zip(runs, result.runs):
        alone = simulate(p)
        assert got.params == alone.params          # results in the order of the runs
        for name in FIELDS:
            a, b = getattr(got, name), getattr(alone, name)
            assert (a is None) == (b is None), name
            if a is not None:
                np.testing.assert_array_equal(a, b, err_msg=name)
        assert (got.stable, got.unstable_at_s, got.abort_reason) \
            == (alone.stable, alone.unstable_at_s, alone.abort_reason)
    assert not result.runs[1].stable and all(r.stable for r in result.runs[2:])
    # one line per finished run, counted in the order they finished
    done = [ln for ln in lines if 'runs done)' in ln]
    assert len(done) == 5
    assert [ln.rsplit('(', 1)[1] for ln in done] == [f'{i}/5 runs done)' for i in range(1, 6)]
    for p in runs:
        label = f'alpha_{p["alpha"]:g}_{p["rig_model"]}_{p["predictor"]}'
        assert (tmp_path / label / 'params.yaml').is_file()
    assert multiprocessing.active_children() == []


def test_one_worker_runs_in_process(no_report, tmp_path):
    runs = _runs()[:2]
    lines = []
    result = api.simulate_experiments(runs=runs, out_dir=tmp_path, progress=lines.append,
                                      workers=1)
    assert not any('worker processes' in ln for ln in lines)
    assert lines[0] == '[alpha_1_servohydraulic_model] simulating'
    np.testing.assert_array_equal(result.runs[0].displacement_m,
                                  simulate(runs[0]).displacement_m)


def _endless(params, progress=None):
    """Stands in for simulate in the workers (inherited by fork): reports until stopped."""
    import time
    for k in range(3000):
        time.sleep(0.01)
        progress(k, 3000)
    params['marker'].write_text('not stopped')          # 30 s later: the test fails


def test_ctrl_c_stops_the_workers(no_report, monkeypatch, tmp_path):
    monkeypatch.setattr(api, 'simulate', _endless)
    seen = []

    def progress(line):
        seen.append(line)
        if 'step' in line:                     # a run is under way: Ctrl-C
            raise KeyboardInterrupt

    runs = [dict(p, marker=tmp_path / f'unstopped{i}') for i, p in enumerate(_runs()[:3])]
    with pytest.raises(KeyboardInterrupt):
        api.simulate_experiments(runs=runs, out_dir=tmp_path, progress=progress, workers=2)
    # the running runs stopped at their next progress report and the workers exited
    assert multiprocessing.active_children() == []
    assert not any('runs done' in ln for ln in seen)
    assert not list(tmp_path.glob('*/params.yaml'))
    assert not list(tmp_path.glob('unstopped*'))


def test_a_sweep_over_records_predictors_and_alphas(no_report, tmp_path):
    """Records x predictors x alphas, records outermost; each run on its own record, in the
    pool as alone (the report of eight runs, 10-25 s here, is not what this asserts)."""
    csv = tmp_path / 'pulse.csv'
    t = np.arange(0, 2.0, 0.01)
    csv.write_text('time,acceleration\n' + '\n'.join(
        f'{ti:.2f},{a:.6f}' for ti, a in zip(t, np.sin(2 * np.pi * 2 * t) * np.exp(-t))))
    runs = api.build_runs(overrides={'record': ['default', str(csv)], 'duration_s': 1.0,
                                     'predictor': ['none', 'model']}, alphas=[0.0, 0.5])
    assert [(r['record'], r['predictor'], r['alpha']) for r in runs] == [
        (rec, pred, a) for rec in ('default', str(csv)) for pred in ('none', 'model')
        for a in (0.0, 0.5)]
    assert api._run_label(runs[4], runs) == 'alpha_0_servohydraulic_none_pulse'
    assert api._run_label(runs[0], runs[:1]) == 'alpha_0_servohydraulic_none'
    result = api.simulate_experiments(runs=runs, out_dir=tmp_path / 'out', progress=print,
                                      force=True)
    names = [r.record_name for r in result.runs]
    assert names[:4] == ['synthetic-default(seed=1)'] * 4 and len(set(names[4:])) == 1
    assert 'pulse' in names[4]
    first = simulate(runs[5])
    assert np.array_equal(result.runs[5].displacement_m, first.displacement_m)


def test_what_a_record_file_gave_is_said_once_and_kept_in_the_summary(tmp_path):
    """One console line per record file (not per run) with its samples, DT, PGA and the
    factor applied; the same figures in summary.json and the report; none for the default."""
    csv = tmp_path / 'sine.csv'
    t = np.arange(200) * 0.01
    csv.write_text('time,acceleration\n' + '\n'.join(
        f'{ti:.2f},{2.0 * np.sin(2 * np.pi * ti):.6f}' for ti in t))    # 2 m/s^2 at 0.25 s
    lines = []
    runs = api.build_runs(overrides={'record': str(csv), 'duration_s': 0.5,
                                     'predictor': 'model'}, alphas=[0.5, 1.0],
                          progress=lines.append)
    said = [ln for ln in lines if ln.startswith('record ')]
    assert said == [f'record {csv}: 200 samples at 0.01 s (2 s), PGA 0.2039 g at 0.25 s; run: '
                    'time scale 0.5, 0.5 s at dt 0.002 s, scaled x9.487 to amplitude_N=1000 N '
                    'over mass_kg=52.7 kg, peak 1.935 g']
    result = api.simulate_experiments(runs=runs, out_dir=tmp_path / 'out',
                                      progress=lines.append, force=True, workers=1)
    for entry in result.summary:
        read = entry['record_read']
        assert (read['npts'], read['dt_s'], read['pga_at_s']) == (200, 0.01, 0.25)
        assert read['pga_g'] == pytest.approx(2.0 / 9.80665, rel=1e-12)
        # amplitude_N 1000 N on the default 52.7 kg: the prepared peak times the mass
        assert read['run_peak_g'] * 9.80665 * 52.7 == pytest.approx(1000.0, rel=1e-12)
        assert read['scale'] == pytest.approx(1000.0 / (52.7 * 2.0), rel=2e-3)
        assert read['run_samples'] == 250 == entry['n_steps']
    report = (tmp_path / 'out' / 'report.md').read_text()
    assert report.count(said[0][len('record '):]) == 2             # one per run
    lines.clear()
    runs = api.build_runs(overrides={'duration_s': 0.5}, progress=lines.append)
    assert not [ln for ln in lines if ln.startswith('record ')]
    result = api.simulate_experiments(runs=runs, out_dir=tmp_path / 'default',
                                      progress=lines.append, force=True, workers=1)
    assert 'record_read' not in result.summary[0]
