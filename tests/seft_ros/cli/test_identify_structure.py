"""The pre-test path of a structure (issue 31): an identification run of its rigs, seft
identify, and the structure test with the written parameter file.

``config/two_piers.yaml`` with each pier 15 % stiffer than declared to its compensator
(``predictor_stiffness_N_per_m`` = k / 1.15; the simulated pier is the configured one).
Without sensor noise the fit is exact to rounding, so the identified stiffness is the true
one within 1e-6; the structure test with ``model`` and the identified parameters follows the
reference as the exact model does (0.16-0.19 % NRMS per DOF on the default record at 1000 N,
``benchmarks/identify_structure.py``), the wrong declaration by 200 % and more.
"""

import json
from pathlib import Path

import pytest
import yaml

from seft_msgs_py.errors import InputError, ParameterError
from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.api import build_runs
from seft_ros.cli.config import RIGS, ConfigLoader, load_config
from seft_ros.cli.main import main
from seft_ros.core.experiment import simulate
from seft_ros.core.structure import test_setup as setup_of

CONFIG = Path(__file__).resolve().parents[3] / 'config'
TRUE_K = {'pier_a': 2.11e5, 'pier_b': 3.376e5}
STIFFER = 1.15


@pytest.fixture(scope='module')
def lab(tmp_path_factory):
    """The declared configuration, its identification run's bag and seft identify's files."""
    root = tmp_path_factory.mktemp('structure_ident')
    doc = yaml.load((CONFIG / 'two_piers.yaml').read_text(), Loader=ConfigLoader)
    for rig, k in TRUE_K.items():
        doc['rigs'][rig]['predictor_stiffness_N_per_m'] = k / STIFFER
    declared = root / 'declared.yaml'
    declared.write_text(yaml.safe_dump(doc))
    assert main(['simulate', str(declared), '--predictor', 'none', '--duration', '8',
                 '--set', 'excitation=noise', '--set', 'excitation_band_hz=50', '--bag',
                 '--out', str(root / 'id_run')]) == 0
    assert main(['identify', str(root / 'id_run'), '--out', str(root / 'identify'),
                 '--params', str(root / 'piers.yaml')]) == 0
    return root


def test_identify_reports_each_rig_and_writes_its_section(lab, capsys):
    doc = json.loads((lab / 'identify' / 'identification.json').read_text())
    assert [(r['rig'], r['kind']) for r in doc['runs']] == [('pier_a', 'closed_loop'),
                                                          ('pier_b', 'closed_loop')]
    assert list(doc['rigs']) == ['pier_a', 'pier_b']
    for rig, k in TRUE_K.items():
        spec, = doc['rigs'][rig]['specimen']
        assert spec['stiffness_N_per_m'] == pytest.approx(k, rel=1e-6)
        assert spec['declared']['stiffness_N_per_m'] == pytest.approx(k / STIFFER)
        assert spec['linear'] is True
        assert 11.0 < doc['rigs'][rig]['delay_ms'] < 13.0
    for r in doc['runs']:
        assert [p.split('_')[0] for p in r['plots']] == ['bode', 'specimen']
        for name in r['plots']:
            assert (lab / 'identify' / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    report = (lab / 'identify' / 'identification.md').read_text()
    assert '| pier_b | ' in report and 'k [N/m]' in report
    # the parameter file: a rigs section per rig, only the rig's parameters
    sections = load_config(lab / 'piers.yaml', layer=True)[RIGS]
    assert list(sections) == ['pier_a', 'pier_b']
    for rig, k in TRUE_K.items():
        assert sections[rig]['predictor_stiffness_N_per_m'] == pytest.approx(k, rel=1e-6)
        assert sections[rig]['predictor_mass_kg'] == pytest.approx(52.7, rel=1e-6)
        assert sections[rig]['predictor_damping_N_s_per_m'] == pytest.approx(903.278, rel=1e-6)
        assert set(sections[rig]) == {'predictor_mass_kg', 'predictor_damping_N_s_per_m',
                                      'predictor_stiffness_N_per_m', 'predictor_tau_s'}


def test_the_structure_test_takes_the_parameter_file(lab):
    run, = build_runs(config=str(lab / 'declared.yaml'), params_files=[str(lab / 'piers.yaml')],
                      overrides={'predictor': 'model'})
    rigs = setup_of(run).rig_params
    sections = load_config(lab / 'piers.yaml', layer=True)[RIGS]
    for rig in TRUE_K:
        for name, value in sections[rig].items():
            assert rigs[rig][name] == value
        assert rigs[rig]['predictor_loop_delay_steps'] == 14      # the configuration's, kept
    assert rigs['pier_b']['stiffness_N_per_m'] == 3.376e5
    # the first --params file wins, as for the test's parameters
    other = lab / 'other.yaml'
    other.write_text('rigs:\n  pier_a: {predictor_stiffness_N_per_m: 1.0e5, '
                     'predictor_tau_s: 0.02}\n')
    run, = build_runs(config=str(lab / 'declared.yaml'), overrides={'predictor': 'model'},
                      params_files=[str(lab / 'piers.yaml'), str(other)])
    pier_a = setup_of(run).rig_params['pier_a']
    assert pier_a['predictor_stiffness_N_per_m'] == sections['pier_a'][
        'predictor_stiffness_N_per_m']
    run, = build_runs(config=str(lab / 'declared.yaml'), overrides={'predictor': 'model'},
                      params_files=[str(other), str(lab / 'piers.yaml')])
    assert setup_of(run).rig_params['pier_a']['predictor_stiffness_N_per_m'] == 1.0e5


def test_the_identified_structure_test_is_accurate(lab):
    """Per-DOF displacement NRMS with model: the identified parameters as the exact model,
    the declared ones far off."""
    nrms = {}
    for case, files in (('declared', []), ('identified', [str(lab / 'piers.yaml')])):
        run, = build_runs(config=str(lab / 'declared.yaml'), params_files=files,
                          overrides={'predictor': 'model', 'duration_s': 6.0})
        rd = simulate(run)
        assert rd.stable
        nrms[case] = {d.dof: d.displacement.nrms for d in compare_run(rd).dofs}
        # with the declared (wrong) model the piers ring past their 4 g accelerometers:
        # counted (issue 39; model's law does not feed the reading back); identified, not
        clipped = sum(v['samples']['acceleration'] for v in rd.extra['sensor_range'].values())
        assert (clipped > 0) == (case == 'declared'), (case, clipped)
    assert set(nrms['identified']) == {'pier_a', 'pier_b', 'deck'}
    assert max(nrms['identified'].values()) < 0.005
    assert min(nrms['declared'].values()) > 0.2


def test_an_aborted_structure_bag_is_refused_in_one_line(tmp_path, capsys):
    assert main(['simulate', str(CONFIG / 'two_piers.yaml'), '--predictor', 'none', '--force',
                 '--duration', '2', '--bag', '--out', str(tmp_path / 'coupled')]) == 0
    bag = tmp_path / 'coupled' / 'structure_none' / 'bag'
    capsys.readouterr()
    assert main(['identify', str(bag), '--out', str(tmp_path / 'id')]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f'seft: error: {bag}: the run was aborted at 0.6')
    assert 's of 2 s (reference_force_builder: pier_b: unstable at' in err and '\n' not in err


def test_study_and_structure_bags_are_identified_apart(lab, capsys):
    assert main(['simulate', '--duration', '3', '--set', 'excitation=noise', '--bag',
                 '--out', str(lab / 'study')]) == 0
    capsys.readouterr()
    assert main(['identify', str(lab / 'study'), str(lab / 'id_run'),
                 '--out', str(lab / 'mixed')]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('seft: error: ') and "is a bag of the study's rig and" in err
    assert 'identify them apart' in err and '\n' not in err


@pytest.mark.parametrize('text, config, error, match', [
    ('rigs:\n  pier_a: {predictor_mass_kg: 50.0}\n', None, InputError,
     r'rigs: a rigs section needs a structure, and the configuration has none'),
    ('rigs:\n  pier_c: {predictor_mass_kg: 50.0}\n', 'two_piers.yaml', InputError,
     r"rigs\.pier_c: the structure has no rig 'pier_c' \(its rigs: pier_a, pier_b\)$"),
    ('rigs:\n  pier_a: {dt: 0.001}\n', 'two_piers.yaml', InputError,
     r'rigs\.pier_a\.dt: a parameter of the whole test, not of one rig; set it for all$'),
    ('rigs:\n  pier_a: {predictor_mass: 50.0}\n', 'two_piers.yaml', InputError,
     r"rigs\.pier_a: unknown parameter 'predictor_mass' \(did you mean 'predictor_mass_kg' or "
     r"'predictor_tau_s'\?\)$"),
    ('rigs:\n  pier_a: {predictor_mass_kg: -1.0}\n', 'two_piers.yaml', ParameterError,
     r'rigs\.pier_a: parameter predictor_mass_kg=-1\.0: expected'),
    ('rigs: [pier_a]\n', 'two_piers.yaml', InputError,
     r'rigs: expected a mapping of rig names to their parameters'),
])
def test_a_bad_rigs_section_is_one_line(tmp_path, text, config, error, match):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(error, match=f'^{path}: ' + match):
        build_runs(config=str(CONFIG / config) if config else None, params_files=[str(path)])


def test_a_rigs_section_alone_is_no_configuration(tmp_path):
    path = tmp_path / 'rigs_only.yaml'
    path.write_text('rigs:\n  pier_a: {predictor_mass_kg: 50.0}\n')
    with pytest.raises(InputError, match=f'^{path}: rigs: a rigs section needs a structure '
                       'section'):
        build_runs(config=str(path))
