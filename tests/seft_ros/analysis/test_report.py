"""The report writes strict JSON, Markdown tables per run and across predictors, PNG figures;
structure tests per degree of freedom, in one report with the study's."""

import json
import math
import re

import numpy as np
import pytest
from scipy import signal as sps

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.reference import reference_response
from seft_ros.analysis.report import write_report, write_summary_json
from seft_ros.analysis.rundata import RunData

# The reference rig (paper Sec. 3.1).
M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002


@pytest.fixture(scope='module')
def runs():
    """Runs at alpha = 0, 0.5 and 1.5 built from the reference: delayed 10 ms; at 0.5 with
    high-frequency vibration; at 1.5 a growing oscillation aborted at 6 s with NaN samples."""
    n = 10000
    t = np.arange(n) * DT
    b, a = sps.butter(4, [0.5, 15.0], btype='band', fs=1 / DT)
    ag = sps.lfilter(b, a, np.random.default_rng(11).normal(size=n))
    ag *= np.minimum(1.0, t / 2.0) * np.exp(-np.maximum(0.0, t - 8.0) / 4.0)
    ag *= 1000.0 / M / np.max(np.abs(ag))
    out = []
    for alpha, vibration, n_run in ((0.0, 0.0, n), (0.5, 0.2, n), (1.5, 0.0, 3000)):
        params = {'alpha': alpha, 'dt': DT, 'mass_kg': M, 'damping_N_s_per_m': C,
                  'stiffness_N_per_m': K, 'rig_model': 'servohydraulic', 'predictor': 'none',
                  'record': 'default', 'tau_s': 0.01, 'io_latency_s': 0.003}
        ref = reference_response(alpha=alpha, mass_kg=M, damping_N_s_per_m=C,
                                 stiffness_N_per_m=K, dt=DT, ground_acceleration_m_s2=ag)

        def delayed(x):
            return np.concatenate([np.zeros(5), x[:-5]])[:n_run]

        tt = t[:n_run]
        hf = vibration * np.sin(2 * np.pi * 45 * tt)
        run = RunData.one_rig(params=params, time_s=tt, ground_acceleration_m_s2=ag[:n_run],
                      reference_force_N=ref.force_N[:n_run],
                      measured_force_N=delayed(ref.force_N) + 1000 * hf,
                      displacement_m=delayed(ref.displacement_m),
                      velocity_m_s=delayed(ref.velocity_m_s),
                      acceleration_m_s2=delayed(ref.acceleration_m_s2) + 500 * hf,
                      record_name='synthetic', source='test')
        if n_run < n:
            growth = 1e-4 * np.exp(1.5 * tt) * np.sin(2 * np.pi * 30 * tt)
            run.displacement_m = run.displacement_m + growth
            run.measured_force_N = run.measured_force_N + K * growth
            run.acceleration_m_s2 = run.acceleration_m_s2 - (2 * np.pi * 30) ** 2 * growth
            run.acceleration_m_s2[-2:] = np.nan
            run.stable = False
            run.unstable_at_s = n_run * DT
            run.abort_reason = 'stroke limit exceeded'
        out.append(run)
    return out


def test_write_report(runs, tmp_path):
    paths = write_report(runs, tmp_path / 'report', title='test report')
    summary = json.loads(paths.summary_json.read_text())  # strict: NaN would not parse back
    assert len(summary['runs']) == 3
    assert [e['alpha'] for e in summary['runs']] == [0.0, 0.5, 1.5]
    assert [e['stable'] for e in summary['runs']] == [True, True, False]
    assert summary['runs'][2]['unstable_at_s'] == pytest.approx(6.0)
    assert summary['runs'][0]['lag_s'] == pytest.approx(0.01, abs=1e-5)
    assert summary['runs'][0]['nrms']['force'] < 1e-4
    hf = [e['high_frequency_force_fraction'] for e in summary['runs'][:2]]
    assert hf[0] < 0.05 < hf[1]  # the added 45 Hz vibration shows up

    for png in paths.figures:
        assert png.exists() and png.stat().st_size > 10_000
        assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'

    md = paths.report_md.read_text()
    assert md.startswith('# test report')
    for name in ('displacement', 'force', 'acceleration'):
        assert md.count(f'| {name} [') == 3  # one row per signal and run
    assert '| signal | peak test | peak ref | peak ratio | lag [ms] | NRMS own lag [%] |' in md
    assert '**aborted at t = 6.000 s**: stroke limit exceeded' in md
    # the vibration at alpha 0.5 puts the acceleration's peak beyond 1.5 x the reference's:
    # flagged, not plainly stable (issue 39)
    assert md.count('**stable**') == 1 and md.count('**stable, flagged**') == 1
    assert ('  - peak beyond the prediction: rig acceleration (relative to the ground) peaks '
            'at') in md
    assert [e['verdict'] for e in summary['runs']] == ['stable', 'stable, flagged', 'aborted']
    # the criteria table's status column says the verdict too (before: 'stable' for the
    # flagged run, where the console, summary.json and its own section said flagged)
    rows = [[c.strip() for c in line.strip('|').split('|')] for line in md.splitlines()
            if line.startswith('| 2 | 0.5 |')]
    assert rows and all('stable, flagged' in r and 'stable' not in r for r in rows), rows
    assert 'I/O latency = 3 ms' in md and 'dt = 2 ms' in md  # servohydraulic: no tau
    assert '(time_histories.png)' in md and '(time_histories_zoom.png)' in md
    # The displacement row of the alpha = 0 run: 10 ms lag, NRMS 0.00 %.
    row = next(line for line in md.splitlines() if line.startswith('| displacement'))
    cells = [c.strip() for c in row.strip('|').split('|')]
    assert cells[3] == '1.000' and cells[4] == '10.00' and cells[5] == '0.00'


def test_write_summary_json_writes_null_for_nan(tmp_path):
    path = write_summary_json([{'nrms': {'force': math.nan}, 'lag_s': np.float64(np.inf)}],
                              tmp_path / 'sub' / 'summary.json')
    assert json.loads(path.read_text()) == {'runs': [{'nrms': {'force': None}, 'lag_s': None}]}


def test_write_report_errors(tmp_path):
    with pytest.raises(ParameterError, match='at least one run'):
        write_report([], tmp_path)


# -- several predictors -------------------------------------------------------------------
def _ground_motion(n, seed=5):
    t = np.arange(n) * DT
    b, a = sps.butter(4, [0.5, 15.0], btype='band', fs=1 / DT)
    ag = sps.lfilter(b, a, np.random.default_rng(seed).normal(size=n))
    ag *= np.minimum(1.0, t / 2.0) * np.exp(-np.maximum(0.0, t - 5.0) / 3.0)
    return ag * 1000.0 / M / np.max(np.abs(ag))


def _predictor_run(alpha, predictor, ag, *, scale=1.0, delay=0, vibration=0.0, n_run=None,
                   record='synthetic'):
    """A run built from the reference: scaled, delayed by whole samples, with a 45 Hz
    vibration in force and acceleration; aborted (growing 30 Hz oscillation) if n_run is
    shorter than the record."""
    n = ag.shape[0]
    n_run = n if n_run is None else n_run
    params = {'alpha': alpha, 'dt': DT, 'mass_kg': M, 'damping_N_s_per_m': C,
              'stiffness_N_per_m': K, 'rig_model': 'delay', 'predictor': predictor,
              'record': record, 'tau_s': 0.01}
    ref = reference_response(alpha=alpha, mass_kg=M, damping_N_s_per_m=C, stiffness_N_per_m=K,
                             dt=DT, ground_acceleration_m_s2=ag)

    def test(x):
        x = scale * x
        return (np.concatenate([np.zeros(delay), x[:n - delay]]) if delay else x)[:n_run]

    t = np.arange(n_run) * DT
    hf = vibration * np.sin(2 * np.pi * 45 * t)
    run = RunData.one_rig(params=params, time_s=t, ground_acceleration_m_s2=ag[:n_run],
                  reference_force_N=ref.force_N[:n_run],
                  measured_force_N=test(ref.force_N) + 1000 * hf,
                  displacement_m=test(ref.displacement_m),
                  velocity_m_s=test(ref.velocity_m_s),
                  acceleration_m_s2=test(ref.acceleration_m_s2) + 500 * hf,
                  record_name=record, source='test')
    if n_run < n:
        growth = 1e-4 * np.exp(1.5 * t) * np.sin(2 * np.pi * 30 * t)
        run.displacement_m = run.displacement_m + growth
        run.measured_force_N = run.measured_force_N + K * growth
        run.acceleration_m_s2 = run.acceleration_m_s2 - (2 * np.pi * 30) ** 2 * growth
        run.stable = False
        run.unstable_at_s = n_run * DT
        run.abort_reason = 'stroke limit exceeded'
    return run


@pytest.fixture(scope='module')
def predictor_runs():
    """alpha = 0.5 and 1.0 x predictors 'polynomial' (1.05 x reference), 'none' (delayed
    10 ms, displacement 1.10 x, 45 Hz vibration) and 'model' (1.02 x reference; aborted at
    4 s at alpha = 1.0), in the order a sweep might list them ('none' not first)."""
    ag = _ground_motion(4000)
    out = []
    for alpha in (0.5, 1.0):
        out.append(_predictor_run(alpha, 'polynomial', ag, scale=1.05))
        out.append(_predictor_run(alpha, 'none', ag, delay=5, vibration=0.2))
        out[-1].displacement_m = 1.10 * out[-1].displacement_m
        out.append(_predictor_run(alpha, 'model', ag, scale=1.02,
                                  n_run=2000 if alpha == 1.0 else None))
    return out


def _table_after(md, heading):
    """Rows (lists of cells) of the first Markdown table after `heading`, header excluded."""
    lines = md.splitlines()
    start = lines.index(heading)
    rows = []
    for line in lines[start + 1:]:
        if line.startswith('#'):
            break
        if line.startswith('|'):
            rows.append([c.strip() for c in line.strip('|').split('|')])
        elif rows:
            break
    return rows[2:]  # header and alignment row


def test_write_report_across_predictors(predictor_runs, tmp_path):
    paths = write_report(predictor_runs, tmp_path / 'report', title='sweep')
    entries = json.loads(paths.summary_json.read_text())['runs']
    assert [(e['alpha'], e['predictor']) for e in entries] == [
        (0.5, 'polynomial'), (0.5, 'none'), (0.5, 'model'),
        (1.0, 'polynomial'), (1.0, 'none'), (1.0, 'model')]
    for e in entries:
        assert {'alpha', 'rig', 'predictor', 'record', 'stable', 'unstable_at_s', 'lag_s',
                'nrms', 'peak_ratio', 'high_frequency_force_fraction',
                'high_frequency_force_fraction_reference',
                'high_frequency_cutoff_hz'} <= set(e)
        assert e['high_frequency_cutoff_hz'] == 20.0
        assert e['high_frequency_force_fraction_reference'] < 0.02
    assert entries[0]['nrms']['displacement'] == pytest.approx(0.05, abs=1e-6)
    assert entries[1]['high_frequency_force_fraction'] > 0.05

    # Figures: no 16-column grid, one Figure-6 grid per predictor, one Figures-7/8 per alpha.
    assert paths.time_histories_png is None and paths.zoom_png is None
    assert not (paths.out_dir / 'time_histories.png').exists()
    assert list(paths.predictor_time_histories) == ['none', 'polynomial', 'model']
    assert {p.name for p in paths.predictor_comparisons.values()} == {
        'predictors_alpha_0.5.png', 'predictors_alpha_1.png'}
    assert {p.name for p in paths.figures} >= {
        'time_histories_none.png', 'time_histories_none_zoom.png',
        'time_histories_model.png', 'time_histories_polynomial_zoom.png',
        'predictors_alpha_0.5.png', 'predictors_alpha_1.png'}
    # the eight above and criteria_vs_alpha.png (several alphas; > 4 runs: no runs_compared)
    assert len(paths.figures) == 9 and paths.criteria_png.name == 'criteria_vs_alpha.png'
    for png in paths.figures:
        assert png.exists() and png.stat().st_size > 10_000
        assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'

    md = paths.report_md.read_text()
    for png in paths.figures:
        assert f'({png.name})' in md
    # Cross-predictor table at alpha = 0.5: 'none' first, one row per run.
    rows = _table_after(md, '### alpha = 0.5, rig delay')
    assert [(r[0], r[1], r[2]) for r in rows] == [
        ('2', 'none', 'synthetic'), ('1', 'polynomial', 'synthetic'),
        ('3', 'model', 'synthetic')]
    none, poly, model = rows
    assert poly[3:9] == ['5.00', '5.00', '5.00', '1.050', '1.050', '1.050']
    assert model[3:9] == ['2.00', '2.00', '2.00', '1.020', '1.020', '1.020']
    assert none[3] == '10.00' and none[6] == '1.100'
    assert float(none[9]) > 5.0 and float(poly[9]) < 2.0  # HF force [%]
    assert none[10] == poly[10] == model[10]  # the same reference
    assert [r[11] for r in rows] == ['10.00', '0.00', '0.00']  # lag x [ms]
    # the status is the run's verdict: the uncompensated run's 45 Hz vibration puts its
    # acceleration's peak beyond the reference's (flagged, as on the console)
    assert [r[12] for r in rows] == ['stable, flagged', 'stable', 'stable']
    rows = _table_after(md, '### alpha = 1, rig delay')
    assert rows[2][1] == 'model' and rows[2][12] == 'aborted at 4.000 s'

    # Uncompensated vs best compensated: model at 0.5, polynomial at 1.0 (model aborted).
    rows = _table_after(md, '## Uncompensated vs best compensated')
    assert len(rows) == 2
    assert rows[0][:4] == ['0.5', 'delay', '10.00', '1.100']
    assert rows[0][5:9] == ['stable, flagged', 'model', '2.00', '1.020']
    assert rows[1][6:9] == ['polynomial', '5.00', '1.050']
    assert float(rows[0][4]) > 5.0 and float(rows[0][9]) < 2.0
    # The per-run sections are kept.
    assert md.count('## Run ') == 6
    assert md.count('| displacement [mm] |') == 6


def test_write_report_keeps_runs_sharing_a_setup_apart(tmp_path):
    """Two 'polynomial' runs of one record and one of another record, with 'none'."""
    ag = _ground_motion(1500)
    runs = [_predictor_run(0.5, 'none', ag, vibration=0.2),
            _predictor_run(0.5, 'polynomial', ag, scale=1.05),
            _predictor_run(0.5, 'polynomial', ag, scale=1.01),
            _predictor_run(0.5, 'polynomial', ag, scale=1.03, record='other')]
    paths = write_report(runs, tmp_path, high_frequency_cutoff_hz=30.0)
    assert json.loads(paths.summary_json.read_text())['runs'][0][
        'high_frequency_cutoff_hz'] == 30.0
    assert {p.name for p in paths.predictor_comparisons.values()} == {
        'predictors_alpha_0.5_synthetic.png', 'predictors_alpha_0.5_other.png'}
    assert list(paths.predictor_time_histories) == ['none', 'polynomial']
    md = paths.report_md.read_text()
    rows = _table_after(md, '### alpha = 0.5, rig delay')
    assert [(r[0], r[1], r[2], r[3]) for r in rows] == [
        ('1', 'none', 'synthetic', '0.00'), ('2', 'polynomial', 'synthetic', '5.00'),
        ('3', 'polynomial', 'synthetic', '1.00'), ('4', 'polynomial', 'other', '3.00')]
    assert 'above 30 Hz' in md
    best = _table_after(md, '## Uncompensated vs best compensated')
    assert best == [['0.5', 'delay', '0.00', '1.000', best[0][4], 'stable, flagged',
                     'polynomial', '1.00', '1.010', best[0][9]]]


def test_the_best_compensated_table_names_the_runs_that_tie_to_its_digit(tmp_path):
    """Two compensated runs whose displacement NRMS shows the same to the table's 0.01 %:
    both named ('adaptive' alone read as the better one, session 35); a third 0.01 %
    behind is not."""
    ag = _ground_motion(1500)
    runs = [_predictor_run(0.5, 'none', ag, scale=1.1),
            _predictor_run(0.5, 'polynomial', ag, scale=1.0201),
            _predictor_run(0.5, 'adaptive', ag, scale=1.01002),
            _predictor_run(0.5, 'model', ag, scale=1.01004)]
    md = write_report(runs, tmp_path).report_md.read_text()
    best = _table_after(md, '## Uncompensated vs best compensated')
    assert [row[6:8] for row in best] == [['adaptive = model', '1.00']]


def test_a_short_runs_zoom_is_the_run_and_a_long_title_is_wrapped():
    """The zoom of a run shorter than ZOOM_WINDOW_S is the run (a 0.6 s run's zoom spanned
    0-2 s, and its whole-record panel with it), and a figure's title longer than its width
    is wrapped (the default record's name ran off both edges; a new user, session 36)."""
    from matplotlib.figure import Figure

    from seft_ros.analysis.metrics import compare_run
    from seft_ros.analysis.report import ZOOM_WINDOW_S, _suptitle, _zoom_window
    ag = _ground_motion(300)                            # 0.6 s at 2 ms
    run = _predictor_run(0.5, 'model', ag)
    assert _zoom_window(run, compare_run(run)) == (0.0, float(run.time_s[-1]))
    long_run = _predictor_run(0.5, 'model', _ground_motion(1500))
    start, end = _zoom_window(long_run, compare_run(long_run))
    assert end - start == pytest.approx(ZOOM_WINDOW_S)
    fig = Figure(figsize=(13.2, 9.7))
    title = ('seft simulate main5: alpha = 1.5, rig servohydraulic, record '
             'synthetic-default(seed=1): reference vs uncompensated vs compensated')
    _suptitle(fig, title)
    lines = fig._suptitle.get_text().split('\n')
    assert len(lines) == 2 and ' '.join(lines) == title
    assert all(len(line) <= 13.2 * 9.5 for line in lines)
    _suptitle(fig, 'a short title')
    assert fig._suptitle.get_text() == 'a short title'


def test_a_simulated_runs_report_says_it_has_no_rig_contract(tmp_path):
    """seft simulate steps seft's rig in process: its report says there is no rig node to
    report a contract (it read 'not reported (a bag before it)'; a new user, session 36)."""
    from seft_msgs_py import parameters
    from seft_ros.core.experiment import simulate
    run = simulate(parameters.resolve({'rig_model': 'delay', 'duration_s': 0.2}))
    md = write_report([run], tmp_path).report_md.read_text()
    assert ("- rig contract: none: seft simulate steps seft's simulated rig in process (no rig "
            'node)') in md.splitlines()


def test_a_structures_figure_marks_its_abort_and_each_column_has_a_time_axis(
        tmp_path, monkeypatch):
    """The two piers uncompensated (aborted at about 0.6 s): the abort in the title and on
    every panel, and the interface force's column, which ends above the deck's empty panel,
    keeps its time axis (it had none, and the abort no mark; a new user, session 36)."""
    from pathlib import Path

    from matplotlib.figure import Figure

    from seft_msgs_py import parameters
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.analysis.report import plot_structure_time_histories
    from seft_ros.cli.config import load_config
    from seft_ros.core.experiment import simulate
    config = load_config(Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml')
    run = simulate(parameters.resolve(dict(config, predictor='none', duration_s=1.0)))
    assert not run.stable
    saved = []
    monkeypatch.setattr(Figure, 'savefig', lambda fig, path, **kw: saved.append(fig))
    plot_structure_time_histories(run, compare_run(run), tmp_path / 's.png', title='bridge')
    fig, = saved
    at = f'aborted at t = {run.unstable_at_s:.3f} s'
    assert fig._suptitle.get_text() == f'bridge ({at})'
    axes = [ax for ax in fig.axes if ax.axison]
    assert len(axes) == 8 and all(
        any(line.get_label() == at for line in ax.get_lines()) for ax in axes)
    force = [ax for ax in fig.axes[2::3] if ax.axison]        # the third column
    assert force[-1].get_xlabel() == 'time [s]'
    assert all(label.get_visible() for label in force[-1].get_xticklabels())


def test_write_report_single_predictor_keeps_one_grid(runs, tmp_path):
    paths = write_report(runs, tmp_path)
    assert paths.predictor_time_histories == {} and paths.predictor_comparisons == {}
    assert paths.figures == (paths.criteria_png, paths.runs_png, paths.time_histories_png,
                             paths.zoom_png)
    md = paths.report_md.read_text()
    assert 'Comparison across predictors' not in md and 'best compensated' not in md
    assert not list(tmp_path.glob('predictors_alpha_*.png'))


def test_write_report_cutoff_error(predictor_runs, tmp_path):
    with pytest.raises(ParameterError, match='cutoff_hz=300'):
        write_report(predictor_runs[:1], tmp_path, high_frequency_cutoff_hz=300.0)


# -- structure tests and mixed reports -----------------------------------------------------

#: A two-story shear building, the first story tested on rig 'lab', the second computational.
TWO_STORY = {'dofs': ['story_1', 'story_2'], 'physical': {'story_1': 'lab'},
             'story_masses_kg': [M, M], 'story_stiffnesses_N_per_m': [K, K],
             'story_damping_N_s_per_m': [C, 133.4]}


def _structure_params(lab=None, **over):
    from seft_msgs_py import parameters
    from seft_ros.core.structure import parse_structure
    s = parse_structure(TWO_STORY, rigs={'lab': {'rig_model': 'delay', **(lab or {})}})
    return parameters.resolve(dict({'structure': s.to_json(), 'predictor': 'model',
                                    'duration_s': 6.0}, **over))


def test_report_of_structure_runs_holds_the_summary_numbers(tmp_path):
    """Per degree of freedom: the tables hold summary.json's numbers, one figure per run,
    the structure's M, K, C as tables (not '<br>' text in a cell)."""
    from seft_ros.analysis.htmlreport import check_html
    from seft_ros.core.experiment import simulate as simulate_structure
    runs = [simulate_structure(_structure_params(predictor=p)) for p in ('none', 'model')]
    assert not runs[0].stable         # uncompensated, the coupling's negative damping
    paths = write_report(runs, tmp_path, title='two stories')
    summary = json.loads(paths.summary_json.read_text())['runs']
    assert [e['predictor'] for e in summary] == ['none', 'model']
    assert summary[0]['stable'] is False and summary[0]['abort_reason']
    report = paths.report_md.read_text()
    dof = summary[1]['dofs']['story_2']
    run_2 = report[report.index('## Run 2'):]
    row = next(line for line in run_2.splitlines()
               if line.startswith('| story_2 | computational |'))
    # each signal after its own lag, after the DOF's displacement lag (the common lag) and as
    # recorded (before: the own-lag figure only, which can hide a phase error)
    x, a = dof['displacement'], dof['acceleration']
    assert f"| {100 * x['nrms']:.2f} / {100 * x['nrms_unshifted']:.2f} |" in row
    assert (f"| {100 * a['nrms']:.2f} / {100 * a['nrms_common_lag']:.2f} / "
            f"{100 * a['nrms_unshifted']:.2f} |") in row
    assert x['nrms_common_lag'] == x['nrms'] and a['nrms_common_lag'] != a['nrms']
    assert paths.time_histories_png is None and paths.hysteresis == {}
    assert set(paths.structure_time_histories) == {1, 2}
    for i in (1, 2):
        assert (tmp_path / f'structure_run_{i}.png').stat().st_size > 10_000
        assert f'structure_run_{i}.png' in report
    assert re.search(r'natural frequencies [0-9.]+, [0-9.]+ Hz', report)
    assert '| M [kg] | story_1 | story_2 |' in report
    assert '| **story_2** | 0 | 52.7 |' in report                  # the mass matrix's row
    assert '<br>' not in report and '## Software' in report
    html = paths.report_html.read_text()
    assert 'data:image/png;base64,' in html and '&lt;br&gt;' not in html
    assert '<th>K [N/m]</th><th class="r">story_1</th><th class="r">story_2</th>' in html
    assert '<td><strong>story_1</strong></td><td class="r">422000</td>' in html
    check = check_html(html)
    # the summary, the three matrices, three tables per run (DOFs, links, rigs)
    assert check.self_contained and check.tables == 1 + 3 + 2 * 3


def test_one_report_mixes_the_study_and_structure_tests(tmp_path):
    """A study run and a structure run in one report: each gets its own tables and figures,
    numbered in the given order, and summary.json one layout for both."""
    from seft_msgs_py import parameters
    from seft_ros.core.experiment import simulate
    from seft_ros.core.experiment import simulate as simulate_structure
    structure = simulate_structure(_structure_params(duration_s=1.0))
    single = simulate(parameters.resolve({'duration_s': 1.0, 'rig_model': 'delay'}))
    paths = write_report([structure, single], tmp_path, title='mixed')
    summary = json.loads(paths.summary_json.read_text())['runs']
    assert [set(e) == set(summary[0]) for e in summary] == [True, True]
    assert summary[0]['structure']['dofs'] == ['story_1', 'story_2']
    assert summary[1]['structure']['dofs'] == ['specimen']
    assert summary[1]['nrms'] == summary[1]['rigs']['']['nrms']
    md = paths.report_md.read_text()
    assert md.index('## Evaluation criteria') < md.index('## Structure tests')
    assert '## Run 2: alpha = 0, rig delay, predictor none' in md   # the study's run: 2
    assert '## Run 1: predictor model, builders central' in md      # the structure's: 1
    criteria = md[md.index('## Evaluation criteria'):md.index('## Structure tests')]
    assert '| 2 | 0 | delay | none |' in criteria
    assert paths.time_histories_png.name == 'time_histories.png'
    assert set(paths.structure_time_histories) == {1}
    assert (tmp_path / 'structure_run_1.png').is_file()
    assert 'Parameters of run 2:' in md                  # the study's run's parameters


def test_structure_report_of_a_yielding_rig_has_its_hysteresis(tmp_path):
    """A structure whose rig's specimen is Bouc-Wen: compared against the nonlinear
    reference (here the run is that reference, so every NRMS is 0), with the rig's
    hysteresis loops and its 'nonlinear' block."""
    from seft_ros.analysis.reference import run_reference
    from seft_ros.analysis.rundata import RigData
    from seft_ros.core.ground_motion import prepared_record
    params = _structure_params({'specimen_model': 'bouc_wen', 'yield_displacement_m': 0.002},
                               duration_s=4.0)
    ag = prepared_record(params).acceleration_m_s2
    t = np.arange(ag.shape[0]) * DT
    ref = run_reference(RunData(params=params, rigs={}, time_s=t, ground_acceleration_m_s2=ag))
    assert set(ref.hysteretic_z) == {'lab'} and 'solve_ivp' in ref.method
    lab = ref.rig('lab')
    rig_params = dict(params, specimen_model='bouc_wen', yield_displacement_m=0.002,
                      rig_model='delay')
    run = RunData(params=params, time_s=t, ground_acceleration_m_s2=ag, rigs={'lab': RigData(
        params=rig_params, reference_force_N=lab.force_N, measured_force_N=lab.force_N,
        displacement_m=lab.displacement_m, velocity_m_s=lab.velocity_m_s,
        acceleration_m_s2=lab.acceleration_m_s2)}, computational={
        f'story_2/{q}': np.append(a[:-1, 1], np.nan) for q, a in (
            ('displacement_m', ref.displacement_m), ('velocity_m_s', ref.velocity_m_s),
            ('acceleration_m_s2', ref.acceleration_m_s2))})
    paths = write_report([run], tmp_path, title='yielding story')
    (entry,) = json.loads(paths.summary_json.read_text())['runs']
    block = entry['rigs']['lab']['nonlinear']
    assert entry['nonlinear'] == block and block['specimen_model'] == 'bouc_wen'
    assert block['nrms_displacement'] == pytest.approx(0.0, abs=1e-12)
    assert entry['worst_nrms']['displacement'] == pytest.approx(0.0, abs=1e-12)
    assert np.max(np.abs(lab.hysteretic_z)) > 0.99                     # it yields
    assert paths.structure_hysteresis[1].name == 'hysteresis_run_1.png'
    assert paths.structure_hysteresis[1].stat().st_size > 10_000
    md = paths.report_md.read_text()
    assert '(hysteresis_run_1.png)' in md and 'rig lab, nonlinear specimen (bouc_wen)' in md
    assert 'Reference: scipy.integrate.solve_ivp, LSODA' in md


def test_the_report_says_how_the_record_was_prepared():
    from seft_ros.analysis.report import _preparation
    assert _preparation({'record': '/data/kobe.AT2', 'time_scale': 0.5,
                         'record_resampling': 'auto'}) == \
        ' (time scale 0.5, resampling band_limited)'
    assert _preparation({'record': 'default', 'time_scale': 0.5,
                         'record_resampling': 'auto'}) == ' (time scale 0.5, resampling linear)'
    assert _preparation({'record': '/data/kobe.AT2', 'time_scale': 1,
                         'record_resampling': 'linear'}) == ' (time scale 1, resampling linear)'
    # a bag from before the parameter, and an identification run (no record played)
    assert _preparation({'record': 'default', 'time_scale': 0.5}) == ''
    assert _preparation({'record': 'default', 'record_resampling': 'auto',
                         'excitation': 'noise'}) == ''


def test_each_rig_reports_its_own_delay():
    """The report's delay is the rig model's own: seft's servohydraulic rig's io_latency_s,
    the delay rig's tau, a state_space rig's plant model's io_delay_s (it gave every rig
    io_latency_s: 3 ms on a new user's plant of 2 ms, whose io_latency_s did nothing;
    session 38)."""
    import json
    from types import SimpleNamespace

    from seft_ros.analysis.report import _latency_text
    plant = json.dumps({'form': 'transfer_function', 'dt': 0, 'io_delay_s': 0.002,
                        'num': [1.0], 'den': [1.0, 1.0]})
    assert _latency_text(SimpleNamespace(params={
        'rig_model': 'servohydraulic', 'io_latency_s': 0.003})) == 'I/O latency = 3 ms, '
    assert _latency_text(SimpleNamespace(params={'rig_model': 'delay', 'tau_s': 0.01})) == \
        'tau = 10 ms, '
    assert _latency_text(SimpleNamespace(params={
        'rig_model': 'state_space', 'rig_plant_model': plant, 'io_latency_s': 0.008})) == \
        "I/O latency = 2 ms (its plant model's io_delay_s), "
    assert _latency_text(SimpleNamespace(params={'rig_model': 'actuator'})) == \
        "I/O latency: the actuator rig's own, "
