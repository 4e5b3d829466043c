"""Each run of a command gets a directory of its own (its label): runs that would share one
(two records of one file stem, alphas equal to six digits) are told apart, and the same run
twice is refused before anything starts (``seft_ros.cli.api.run_labels``)."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from seft_msgs_py.errors import InputError
from seft_ros.cli import api


def run(alpha=0.0, predictor='none', record='default', **extra):
    return dict(alpha=alpha, rig_model='servohydraulic', predictor=predictor, record=record,
                **extra)


def test_labels_of_a_plain_sweep_are_unchanged():
    runs = [run(a, p) for p in ('none', 'model') for a in (0.0, 0.5, 1.0)]
    assert api.run_labels(runs) == [f'alpha_{a}_servohydraulic_{p}' for p in ('none', 'model')
                                    for a in ('0', '0.5', '1')]


def test_alphas_equal_to_six_digits_get_every_digit():
    runs = [run(0.1234561), run(0.1234562), run(0.5)]
    assert api.run_labels(runs) == ['alpha_0.1234561_servohydraulic_none',
                                    'alpha_0.1234562_servohydraulic_none',
                                    'alpha_0.5_servohydraulic_none']


def test_records_of_one_stem_are_told_apart_by_folder_then_position(tmp_path):
    by_folder = [run(record='rec/dt001.AT2'), run(record='rec2/dt001.AT2'),
                 run(record='other.csv')]
    assert api.run_labels(by_folder) == ['alpha_0_servohydraulic_none_rec_dt001',
                                         'alpha_0_servohydraulic_none_rec2_dt001',
                                         'alpha_0_servohydraulic_none_other']
    by_position = [run(record='a/x/dt001.AT2'), run(record='b/x/dt001.AT2')]
    assert api.run_labels(by_position) == ['alpha_0_servohydraulic_none_dt001-1',
                                           'alpha_0_servohydraulic_none_dt001-2']


def test_structure_runs_of_several_alphas_name_their_alpha():
    runs = [run(a, p, structure='two_piers') for p in ('none', 'model') for a in (0.0, 0.5)]
    assert api.run_labels(runs) == ['structure_alpha_0_none', 'structure_alpha_0.5_none',
                                    'structure_alpha_0_model', 'structure_alpha_0.5_model']
    assert api.run_labels(runs[::2]) == ['structure_none', 'structure_model']


def test_the_same_run_twice_is_refused():
    with pytest.raises(InputError, match=r'^runs alpha_0.5_servohydraulic_model: the same run '
                       r'twice; expected each record, predictor and alpha once$'):
        api.run_labels([run(0.5, 'model'), run(0.5, 'none'), run(0.5, 'model')])


def test_simulate_writes_each_run_of_one_stem_and_close_alphas_apart(seft_exe, run_process,
                                                                     tmp_path):
    """Before: one directory held the last run's params.yaml for both records."""
    t = np.arange(0, 1.0, 0.01)
    for folder, gain in (('rec', 1.0), ('rec2', 2.0)):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / 'dt001.csv').write_text('time,acceleration\n' + '\n'.join(
            f'{ti:.2f},{gain * np.sin(2 * np.pi * 2 * ti):.6f}' for ti in t))
    proc = run_process([seft_exe, 'simulate', '--record', 'rec/dt001.csv', 'rec2/dt001.csv',
                        '--alpha', '0.1234561', '0.1234562', '--duration', '0.2', '--out',
                        'out'], cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    dirs = {d.name for d in (tmp_path / 'out').iterdir() if d.is_dir()}
    assert dirs == {f'alpha_{a}_servohydraulic_none_{f}_dt001' for a in ('0.1234561',
                                                                         '0.1234562')
                    for f in ('rec', 'rec2')}
    for d in dirs:
        params = yaml.safe_load(Path(tmp_path / 'out' / d / 'params.yaml').read_text())
        values = params.get('/**', {}).get('ros__parameters', params)
        assert values['record'] == f'{d.split("_")[-2]}/dt001.csv'
        assert f'alpha_{values["alpha"]!r}_' in d
    # the summary, the console table and the report name the records as the labels do
    # (before: both 'dt001', and the table had no record column: two rows alike)
    summary = json.loads((tmp_path / 'out' / 'summary.json').read_text())['runs']
    assert sorted({e['record'] for e in summary}) == ['rec2_dt001', 'rec_dt001']
    assert sorted(e['record_read']['file'] for e in summary)[::2] == ['rec/dt001.csv',
                                                                      'rec2/dt001.csv']
    rows = [ln for ln in proc.stdout.splitlines() if ln.rstrip().endswith('_dt001')]
    assert len(rows) == 4 and {ln.split()[-1] for ln in rows} == {'rec_dt001', 'rec2_dt001'}
    report = (tmp_path / 'out' / 'report.md').read_text()
    assert '| rec_dt001 |' in report and '| rec2_dt001 |' in report
