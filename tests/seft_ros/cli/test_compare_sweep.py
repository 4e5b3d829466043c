"""``seft compare`` takes bags, run directories and folders of run directories (a sweep).

The folders have the layout ``seft run --out DIR`` writes (``DIR/<run>/bag/metadata.yaml``);
reading the bags is replaced by simulated runs (the bag reader has its own tests and the node
graph test compares a real bag), so that these tests need no ROS and take seconds.
"""

import json

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError
from seft_ros.cli import api
from seft_ros.cli.main import main
from seft_ros.core.experiment import simulate

LABELS = ('alpha_0_servohydraulic_none', 'alpha_0.5_servohydraulic_none',
          'alpha_1_servohydraulic_none', 'alpha_0_servohydraulic_model',
          'alpha_0.5_servohydraulic_model', 'alpha_1_servohydraulic_model')


@pytest.fixture(scope='module')
def simulated():
    """``{run label: RunData}`` of short simulated runs (2 s of the default record)."""
    out = {}
    for label in LABELS:
        _, alpha, _, predictor = label.split('_')
        p = parameters.resolve({'alpha': float(alpha), 'predictor': predictor,
                                'rig_model': 'servohydraulic', 'amplitude_N': 500.0,
                                'duration_s': 2.0})
        out[label] = simulate(p)
    return out


@pytest.fixture
def sweep_dir(tmp_path, simulated, monkeypatch):
    """A folder of run directories, and read_run answering from the simulated runs."""
    root = tmp_path / 'sweep'
    for label in LABELS:
        bag = root / label / 'bag'
        bag.mkdir(parents=True)
        (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
        (root / label / 'params.yaml').write_text('/**: {ros__parameters: {}}\n')
    (root / 'report.md').write_text('# an earlier report\n')
    monkeypatch.setattr(api, 'read_run', lambda path: simulated[path.parent.name])
    return root


def test_find_bags_of_a_sweep_in_natural_order(sweep_dir):
    bags = api.find_bags([str(sweep_dir)])
    # numbers by value (alpha_0 < alpha_0.5 < alpha_1), not as text ('.' < '_')
    assert [b.parent.name for b in bags] == [
        'alpha_0_servohydraulic_model', 'alpha_0_servohydraulic_none',
        'alpha_0.5_servohydraulic_model', 'alpha_0.5_servohydraulic_none',
        'alpha_1_servohydraulic_model', 'alpha_1_servohydraulic_none']
    # a run directory and a bag name themselves; the order of the paths is kept
    one = sweep_dir / 'alpha_1_servohydraulic_model'
    assert api.find_bags([str(one), str(one / 'bag')]) == [one / 'bag', one / 'bag']


def test_find_bags_errors(tmp_path):
    with pytest.raises(InputError, match='nothere: no such bag or run directory'):
        api.find_bags([str(tmp_path / 'nothere')])
    sim = tmp_path / 'simulated' / 'alpha_0_delay_none'
    sim.mkdir(parents=True)
    (sim / 'params.yaml').write_text('{}\n')
    with pytest.raises(InputError, match='seft simulate keeps no bag'):
        api.find_bags([str(tmp_path / 'simulated')])


def test_compare_a_sweep_folder(sweep_dir, tmp_path, capsys):
    out = tmp_path / 'cmp'
    assert main(['compare', str(sweep_dir), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'J1_ms' in printed and 'J4%' in printed
    # the first table removes each signal's own lag, and says so; the criteria table the
    # displacement's (session 23's D3: the first table had no label)
    assert '(NRMS: each signal after removing its own lag;' in printed.splitlines()[0]
    assert f'(self-contained page: {out / "report.html"})' in printed
    summary = json.loads((out / 'summary.json').read_text())['runs']
    assert len(summary) == len(LABELS)
    for entry in summary:
        assert set(entry['criteria']) == {'J1', 'J2', 'J3', 'J4', 'J5'}
        assert all(isinstance(v, float) for v in entry['criteria'].values())
        assert set(entry['nrms_common_lag']) == set(entry['nrms_unshifted']) == {
            'displacement', 'acceleration', 'force'}
    assert (out / 'criteria_vs_alpha.png').read_bytes()[:4] == b'\x89PNG'
    assert not (out / 'runs_compared.png').exists()   # six runs: the table and plot only
    html = (out / 'report.html').read_text(encoding='utf-8')
    assert html.count('<img ') == html.count('src="data:image/png;base64,')


def test_a_folders_run_without_a_readable_bag_is_said_and_the_rest_compared(
        sweep_dir, simulated, tmp_path, monkeypatch):
    """A run directory of the folder whose bag/ is gone, and one whose bag does not read:
    each named on the console and under the report's title, the other runs compared (before:
    the first left the report silently, the second stopped the whole folder; a new user,
    session 36). A folder with no readable bag is one error line."""
    import shutil

    from seft_msgs_py.errors import InputError as Refused
    shutil.rmtree(sweep_dir / LABELS[0] / 'bag')

    def read(path):
        if path.parent.name == LABELS[1]:
            raise Refused(f'{path}: cannot read the bag: damaged')
        return simulated[path.parent.name]
    monkeypatch.setattr(api, 'read_run', read)
    said = []
    result = api.compare_bags(bags=[str(sweep_dir)], out_dir=tmp_path / 'cmp',
                              progress=said.append)
    assert len(result.summary) == len(LABELS) - 2
    assert said == [f'WARNING: {sweep_dir / LABELS[0]}: no bag (bag/ missing or empty): not '
                    'compared',
                    f'WARNING: {sweep_dir / LABELS[1] / "bag"}: cannot read the bag: damaged: '
                    'not compared']
    head = (tmp_path / 'cmp' / 'report.md').read_text().splitlines()[:4]
    assert head[2:] == [f'- **not compared**: {sweep_dir / LABELS[0]}: no bag (bag/ missing or '
                        'empty)',
                        f'- **not compared**: {sweep_dir / LABELS[1] / "bag"}: cannot read the '
                        'bag: damaged']
    # a run given again, by its directory after its folder: compared once, and said
    said.clear()
    result = api.compare_bags(bags=[str(sweep_dir), str(sweep_dir / LABELS[2])],
                              out_dir=tmp_path / 'cmp3', progress=said.append)
    assert len(result.summary) == len(LABELS) - 2
    assert said[-1] == (f'WARNING: {sweep_dir / LABELS[2] / "bag"}: given more than once: '
                        'compared once')
    monkeypatch.setattr(api, 'read_run', lambda path: read(sweep_dir / LABELS[1] / 'bag'))
    with pytest.raises(InputError, match=r'sweep: no run of the folder has a readable bag'):
        api.compare_bags(bags=[str(sweep_dir)], out_dir=tmp_path / 'cmp2')


def test_compare_says_what_the_run_read_from_its_record_file(tmp_path):
    """seft compare of a bag whose run read a record file: the record line (samples, PGA,
    the scale applied) in the summary and the report, as seft simulate gives it, while the
    file is at the path the run read it from (before: never; a new user missed the scale
    factor, session 36); without the file, none."""
    import numpy as np

    from seft_ros.analysis.bagwrite import write_run_bag
    from seft_ros.core.ground_motion import record_read
    t = np.arange(0.0, 2.0, 0.01)
    csv = tmp_path / 'own.csv'
    csv.write_text(''.join(f'{ti:.2f},{0.5 * np.sin(2 * np.pi * 3 * ti):.6f}\n' for ti in t))
    params = parameters.resolve({'record': str(csv), 'predictor': 'model', 'alpha': 0.5,
                                 'rig_model': 'delay', 'amplitude_N': 300.0})
    bag = write_run_bag(simulate(params), tmp_path / 'run')
    result = api.compare_bags(bags=[str(bag)], out_dir=tmp_path / 'cmp')
    read, = [e['record_read'] for e in result.summary]
    assert read == json.loads(json.dumps(record_read(params)))
    assert read['scale'] > 0 and f"scaled x{read['scale']:.4g}" in (
        tmp_path / 'cmp' / 'report.md').read_text()
    # the file edited since the run: not the run's record, so not said (the review)
    csv.write_text(''.join(f'{ti:.2f},{0.5 * np.sin(2 * np.pi * 4 * ti):.6f}\n' for ti in t))
    result = api.compare_bags(bags=[str(bag)], out_dir=tmp_path / 'cmp3')
    assert 'record_read' not in result.summary[0]
    csv.unlink()
    result = api.compare_bags(bags=[str(bag)], out_dir=tmp_path / 'cmp2')
    assert 'record_read' not in result.summary[0]


def test_compare_numbers_a_folders_runs_as_its_command_did(sweep_dir, simulated, tmp_path):
    """The folder's summary.json (the entries seft run writes, ``metrics.summary_entry``: the
    runs in LABELS order, none before model) numbers the runs, not the directory listing
    (before: run 1 was alpha_0_servohydraulic_model, the folder's run 4). One report, the
    comparison's: the folder's summary.json is written without seft run's figures, and the
    order with another folder's summary is ``compare_bags``' own ``_recorded_order`` (the
    figures are test_compare_a_sweep_folder's; three reports took 15-35 s here)."""
    from seft_ros.analysis.metrics import compare_run, summary_entry
    from seft_ros.analysis.report import write_summary_json
    write_summary_json([summary_entry(simulated[label], compare_run(simulated[label]))
                        for label in LABELS], sweep_dir / 'summary.json')
    result = api.compare_bags(bags=[str(sweep_dir)], out_dir=tmp_path / 'cmp')
    assert [(e['predictor'], e['alpha']) for e in result.summary] == [
        (label.split('_')[3], float(label.split('_')[1])) for label in LABELS]
    # a summary that does not name each run once (another folder's): the listing's order
    listing = [simulated[b.parent.name] for b in api.find_bags([str(sweep_dir)])]

    def order(runs):
        return [(rd.params['predictor'], rd.params['alpha']) for rd in runs]
    assert order(api._recorded_order(sweep_dir, listing)) == order(
        simulated[label] for label in LABELS)
    entries = json.loads((sweep_dir / 'summary.json').read_text())
    entries['runs'] = entries['runs'][:1] * 6
    (sweep_dir / 'summary.json').write_text(json.dumps(entries))
    assert order(api._recorded_order(sweep_dir, listing))[:2] == [('model', 0.0),
                                                                  ('none', 0.0)]


def test_criteria_table_of_missing_values():
    table = api.criteria_table([{'alpha': 0.5, 'predictor': 'none', 'criteria':
                                 {'J1': None, 'J2': 1.0, 'J3': None, 'J4': 2.0, 'J5': 3.0},
                                 'nrms_common_lag': {'displacement': 0.01}}])
    row = table.splitlines()[1].split()
    assert row == ['0.5', 'none', '-', '1.00', '-', '2.00', '3.00', '1.00', '-', '-']


def test_compare_a_study_bag_and_a_structure_bag(tmp_path, capsys):
    """One report for both kinds: the table per degree of freedom, the study's run on its
    one DOF 'specimen' of the rig of the root namespace ('rig'), the bridge's per pier and
    deck; no criteria table of the study's kind (the criteria are per rig)."""
    from pathlib import Path

    from seft_ros.analysis.bagwrite import write_run_bag
    from seft_ros.cli.config import load_config
    from seft_ros.core.experiment import simulate as simulate_structure
    config = load_config(Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml')
    bridge = simulate_structure(parameters.resolve(dict(config, predictor='model',
                                                        duration_s=0.6)))
    study = simulate(parameters.resolve({'rig_model': 'delay', 'duration_s': 0.6}))
    bags = [write_run_bag(study, tmp_path / 'study'), write_run_bag(bridge, tmp_path / 'bridge')]
    out = tmp_path / 'cmp'
    assert main(['compare', *map(str, bags), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    rows = [line.split() for line in printed.splitlines()]
    assert ['1', 'none', 'True', '-', 'specimen', 'rig'] == rows[1][:6]
    assert [r[4:6] for r in rows[2:5]] == [['pier_a', 'pier_a'], ['pier_b', 'pier_b'],
                                          ['deck', '-']]
    assert 'J1_ms' in printed and '(criteria: Silva et al. 2020' not in printed
    assert api.criteria_table(json.loads((out / 'summary.json').read_text())['runs']) == ''
    summary = json.loads((out / 'summary.json').read_text())['runs']
    # the table says which NRMS it prints, each signal's own lag removed (session 23's D3:
    # unlabelled), and prints that; summary.json has the other two per DOF as well
    assert printed.splitlines()[0].endswith(
        "(NRMS: each signal after removing its own lag; after the displacement's lag and as "
        'recorded: summary.json, report.md)')
    deck = summary[1]['dofs']['deck']['acceleration']
    assert f"{100 * deck['nrms']:8.2f}" in printed.splitlines()[4]
    assert deck['nrms_common_lag'] > 0 and deck['nrms_unshifted'] > 0
    assert [e['structure']['dofs'] for e in summary] == [['specimen'],
                                                         ['pier_a', 'pier_b', 'deck']]


def test_the_structure_tables_notes_follow_its_criteria_rows():
    """The notes of a structure's runs (flags, aborts) come after the criteria table, not
    between its rows (a new user, session 35); each names its run."""
    from pathlib import Path

    from seft_ros.analysis.metrics import compare_run, summary_entry
    from seft_ros.cli.config import load_config
    config = load_config(Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml')
    run = simulate(parameters.resolve(dict(config, predictor='model', duration_s=0.3)))
    entry = summary_entry(run, compare_run(run))
    entries = [dict(entry, flags=['the NRMS x of 9 % is beyond the prediction']),
               dict(entry, stable=False, unstable_at_s=0.2, abort_reason='watchdog: lost')]
    lines = api.structure_table(entries).splitlines()
    head = next(i for i, line in enumerate(lines) if 'J1_ms' in line)
    rows = [line.split()[:2] for line in lines[head + 1:head + 5]]
    assert rows == [['1', 'pier_a'], ['1', 'pier_b'], ['2', 'pier_a'], ['2', 'pier_b']]
    assert lines[head + 5:] == [
        'note: run 1 (model): flagged: the NRMS x of 9 % is beyond the prediction',
        'note: run 2 (model): aborted: watchdog: lost']
    # a real-time run: each rig's stale% its own node's (it repeated the run's; session 39),
    # and a watchdog's abort names watchdog_timeout_s
    timing = {'loop_latency_ms': {'p50': 0.75, 'p99': 8.96, 'max': 20.0},
              'stale_command_fraction': 0.059,
              'nodes': {'pier_a/rig': {'stale_fraction': 0.0547},
                        'pier_b/rig': {'stale_fraction': 0.0633}}}
    timed = dict(entry, mode='realtime', timing=timing, stable=False, unstable_at_s=0.2,
                 abort_reason='pier_b/force_servo_controller: watchdog: no measurement for 21 '
                              'ms (limit 20 ms; node or link lost)')
    lines = api.structure_table([timed]).splitlines()
    head = next(i for i, line in enumerate(lines) if 'J1_ms' in line)
    assert [line.split()[-1] for line in lines[head + 1:head + 3]] == ['5.47', '6.33']
    assert lines[head + 3].endswith('--set watchdog_timeout_s=0.2')


def test_replay_timing_of_lockstep_runs_says_there_is_none(sweep_dir, tmp_path, capsys):
    """``--replay-timing`` on lockstep runs: one line each that there is nothing to replay,
    and the report is the plain one (tests/seft_ros/analysis/test_timing_replay.py replays
    a real-time run)."""
    out = tmp_path / 'cmp'
    assert main(['compare', str(sweep_dir / 'alpha_1_servohydraulic_model'),
                 '--replay-timing', '--out', str(out)]) == 0
    printed = ''.join(capsys.readouterr())        # progress lines: stderr
    assert 'replaying its timing' in printed
    assert 'no timing replay (a lockstep run' in printed
    entry = json.loads((out / 'summary.json').read_text())['runs'][0]
    assert 'timing_replay' not in entry
