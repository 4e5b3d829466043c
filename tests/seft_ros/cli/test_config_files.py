"""Every file in ``config/`` loads as the runner loads it (``seft run``/``simulate``)."""

from pathlib import Path

import pytest

from seft_msgs_py import parameters
from seft_ros.cli.api import build_runs

CONFIG = Path(__file__).resolve().parents[3] / 'config'
FILES = sorted(CONFIG.glob('*.yaml'))


def test_there_are_config_files():
    assert {p.name for p in FILES} >= {'default.yaml', 'main.yaml', 'kobe.yaml'}


@pytest.mark.parametrize('path', FILES, ids=[p.name for p in FILES])
def test_config_file_loads(path):
    lines = []
    runs = build_runs(config=str(path), progress=lines.append)
    assert runs
    # every shipped structure declares its rigs' specimens
    assert not [line for line in lines if 'declares no specimen' in line], lines
    for p in runs:
        assert parameters.resolve(p) == p


def test_default_yaml_is_the_schema_defaults():
    assert build_runs(config=str(CONFIG / 'default.yaml')) == [parameters.resolve()]


def test_main_yaml_is_the_studys_experiment():
    """docs "Your first test": alpha 0, 0.5, 1, 1.5 with 'none' and 'model' on the
    servohydraulic rig, the default record at time scale 0.5 and 1000 N."""
    runs = build_runs(config=str(CONFIG / 'main.yaml'))
    assert sorted((p['predictor'], p['alpha']) for p in runs) == sorted(
        (pr, a) for pr in ('none', 'model') for a in (0.0, 0.5, 1.0, 1.5))
    assert {(p['rig_model'], p['record'], p['time_scale'], p['amplitude_N']) for p in runs} \
        == {('servohydraulic', 'default', 0.5, 1000.0)}


def test_a_command_line_value_every_rig_section_overrides_is_refused(tmp_path):
    """``--rig state_space`` on a structure whose rigs set ``rig_model: actuator`` changed no
    rig: the documented rehearsal ran the actuators themselves, to the digit, and was taken
    for a rehearsal. A rig section beats a test-wide value, so such a value is refused in
    one line; one that a rig takes (a rig without its own value, or the same value) is not."""
    import yaml

    from seft_msgs_py.errors import InputError
    from seft_ros.cli import api
    doc = {'predictor': 'none', 'duration_s': 0.2,
           'structure': {'dofs': ['a', 'b'], 'physical': {'a': 'ra', 'b': 'rb'},
                         'mass_matrix_kg': [[52.7, 0], [0, 52.7]],
                         'stiffness_matrix_N_per_m': [[2.11e5, 0], [0, 2.11e5]],
                         'damping_matrix_N_s_per_m': [[903.278, 0], [0, 903.278]]},
           'rigs': {'ra': {'rig_model': 'delay'}, 'rb': {'rig_model': 'delay'}}}
    path = tmp_path / 'two.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"^command line: rig_model=servohydraulic: no rig of "
                       r"the structure takes it, every rig section sets its own \(ra: delay, "
                       r"rb: delay\) and a rig section beats a test-wide value; set it in the "
                       r"rigs' sections \(or a --params file's rigs section\)$"):
        api.build_runs(config=str(path), overrides={'rig_model': 'servohydraulic'})
    assert api.build_runs(config=str(path), overrides={'rig_model': 'delay'})
    doc['rigs'] = {'ra': {'rig_model': 'delay'}}            # rb takes the test-wide value
    path.write_text(yaml.safe_dump(doc))
    runs = api.build_runs(config=str(path), overrides={'rig_model': 'servohydraulic'})
    assert len(runs) == 1 and runs[0]['rig_model'] == 'servohydraulic'


def test_a_structures_rig_without_a_specimen_is_said_to_take_the_studys(tmp_path):
    """A structure whose physical rig's section declares no specimen (a new user left it
    out) runs on the study's (52.7 kg, 2.11e5 N/m): said in one settings line naming the
    rig and the values (before: nothing, the report and params.yaml alone held them)."""
    config = tmp_path / 'norig.yaml'
    config.write_text('predictor: model\nstructure:\n  dofs: [f1, f2]\n'
                      '  physical: {f1: lab}\n  story_masses_kg: [80.0, 40.0]\n'
                      '  story_stiffnesses_N_per_m: [2.11e5, 1.2e5]\n'
                      '  story_damping_N_s_per_m: [1200.0, 250.0]\n')
    lines = []
    runs = build_runs(config=str(config), progress=lines.append)
    assert runs[0]['predictor'] == 'model'
    assert lines[0] == (f"settings: {config}: rig lab (structure.physical.f1) declares no "
                        "specimen in its rigs.lab section: the study's is taken (mass_kg=52.7, "
                        'stiffness_N_per_m=211000, damping_N_s_per_m=903.278)')
    # declared at the top level: said nowhere
    config.write_text(config.read_text() + 'mass_kg: 60.0\n')
    lines.clear()
    build_runs(config=str(config), progress=lines.append)
    assert not [line for line in lines if 'declares no specimen' in line]


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_plant_model_that_diverges_by_itself_is_warned(sign):
    """A lab's plant model with a pole in the right half plane (a sign typo: a new user's
    valve-and-column model with one entry flipped was taken in silence, and its open-loop
    run ended at the force limit) is warned before the runs; the stable one is not. By hand:
    s = 2.5 +- j sqrt(1000 - 6.25) (5.02 Hz), |z| = exp(2.5 * 0.002) = 1.00501."""
    import json
    model = {'form': 'state_space', 'dt': 0, 'a': [[0.0, 1.0], [-1000.0, sign * 5.0]],
             'b': [0.0, 1.0],
             'c': {'force_N': [1000.0, 0.0], 'displacement_m': [1.0, 0.0],
                   'velocity_m_s': [0.0, 1.0], 'acceleration_m_s2': [-1000.0, sign * 5.0]}}
    lines = []
    build_runs(overrides={'rig_model': 'state_space', 'rig_plant_model': json.dumps(model),
                          'predictor': 'none', 'excitation': 'noise',
                          'excitation_input': 'valve_command'}, progress=lines.append)
    warned = [line for line in lines if 'pole outside the unit circle' in line]
    if sign < 0:
        assert warned == []
        return
    assert warned == [
        'warning: parameter rig_plant_model of the rig: a pole outside the unit circle at dt '
        '(|z| 1.00501: grows at 2.5 1/s, 5.02 Hz): the plant diverges by itself, without a '
        'controller; check its signs (a state matrix entry, a denominator coefficient)']


def test_servohydraulic_values_given_to_a_state_space_rig_are_said_to_do_nothing():
    """seft's servohydraulic rig's parameters given to a state_space rig, whose plant model
    is the actuator, are named in one settings line (a new user's io_latency_s=0.01 there was
    silently without effect, session 36); the valve's and the oil's are used by
    velocity_feedback, and defaults are not named."""
    import json
    model = {'form': 'state_space', 'dt': 0, 'a': [[0.0, 1.0], [-1000.0, -5.0]],
             'b': [0.0, 1.0],
             'c': {'force_N': [1000.0, 0.0], 'displacement_m': [1.0, 0.0],
                   'velocity_m_s': [0.0, 1.0], 'acceleration_m_s2': [-1000.0, -5.0]}}
    base = {'rig_model': 'state_space', 'rig_plant_model': json.dumps(model),
            'predictor': 'none', 'excitation': 'noise', 'excitation_input': 'valve_command'}

    def said(**values):
        lines = []
        build_runs(overrides=dict(base, **values), progress=lines.append)
        return [line for line in lines if "seft's servohydraulic rig's" in line]
    assert said(io_latency_s=0.01, piston_area_m2=2e-3) == [
        "settings: io_latency_s=0.01, piston_area_m2=0.002: seft's servohydraulic rig's, not "
        'read by the state_space rig, whose plant model (rig_plant_model, else plant_model) '
        'is the actuator and its delay: they do nothing in this run; put a delay or a valve '
        'into the plant model']
    assert said(io_latency_s=0.003) == []                   # the default
    assert said(piston_area_m2=2e-3, force_controller='velocity_feedback') == []
    lines = []
    build_runs(overrides={'io_latency_s': 0.01}, progress=lines.append)   # its own rig
    assert not [line for line in lines if "seft's servohydraulic rig's" in line]


def test_a_bad_command_line_value_is_named_as_the_command_lines(tmp_path):
    """With a configuration file, a bad --alpha or --predictor was named as the file's ('s5.yaml:
    parameter alpha=-0.5', a new user): it is the command line's."""
    from seft_msgs_py.errors import ParameterError
    config = tmp_path / 'lab.yaml'
    config.write_text('mass_kg: 50.0\n')
    with pytest.raises(ParameterError, match=r'^command line: parameter alpha=-0\.5: '):
        build_runs(config=str(config), alphas=[-0.5])
    with pytest.raises(ParameterError, match=r"^command line: parameter predictor='modle': "):
        build_runs(config=str(config), overrides={'predictor': ['modle']})
    # the configuration file taken by --predictor's list (--predictor model lab.yaml)
    with pytest.raises(ParameterError, match=r"predictor='lab\.yaml': expected one of .*\(lab"
                       r'\.yaml taken as its value: an option of several values takes every '
                       r'word after it; give the configuration file first\)$'):
        build_runs(overrides={'predictor': ['model', 'lab.yaml']})
    # values checked against others after their validation: named as their own source's
    config.write_text('mass_kg: 50.0\namplitude_N: 400.0\n')
    with pytest.raises(ParameterError, match=r'^command line: parameter scale_factor=2\.0: '):
        build_runs(config=str(config), overrides={'scale_factor': 2.0})
    with pytest.raises(ParameterError,
                       match=r'^command line: parameter watchdog_timeout_s=0\.001: '):
        build_runs(config=str(config), overrides={'mode': 'realtime',
                                                  'watchdog_timeout_s': 0.001})
    # an alpha for a structure (its masses are its own), also of an identification run
    for extra in ({}, {'excitation': 'noise', 'excitation_input': 'valve_command',
                       'predictor': 'none'}):
        with pytest.raises(ParameterError, match=r'^command line: parameter alpha=0\.5: with a '
                           r'structure the computational masses'):
            build_runs(config=str(CONFIG / 'two_story.yaml'), alphas=[0.5], overrides=extra)
    with pytest.raises(ParameterError, match=r'lab\.yaml: parameter mass_kg=-1\.0: '):
        config.write_text('mass_kg: -1.0\n')
        build_runs(config=str(config))


def test_a_bad_value_of_a_params_file_is_named_as_that_files(tmp_path):
    """A --params file's plant_model (discrete at 2 ms) against the command line's dt 1 ms
    was named as the configuration's ('lab.yaml: parameter plant_model.dt=0.002', a new user
    whose lab.yaml has no plant_model; session 36): it is the --params file's."""
    from pathlib import Path

    from seft_msgs_py.errors import ParameterError
    rig = Path(__file__).resolve().parents[1] / 'analysis' / 'data' / 'own_actuator_F_rig.yaml'
    config = tmp_path / 'lab.yaml'
    config.write_text('mass_kg: 200.0\nstiffness_N_per_m: 1776500.0\n'
                      'damping_N_s_per_m: 1130.97\npredictor: model\n')
    with pytest.raises(ParameterError, match=rf'^{rig}: parameter plant_model'):
        build_runs(config=str(config), params_files=[str(rig)], overrides={'dt': 0.001})
    # a value of the configuration itself: still the configuration's
    config.write_text(config.read_text() + 'alpha: -1.0\n')
    with pytest.raises(ParameterError, match=r'lab\.yaml: parameter alpha=-1\.0: '):
        build_runs(config=str(config), params_files=[str(rig)])


def test_a_files_test_wide_value_every_rig_sets_otherwise_is_said_to_do_nothing(tmp_path):
    """A configuration's top-level value that every rig section of the structure sets
    otherwise changes nothing: said in one settings line naming the file and each rig's own
    (a new user's top-level force_controller and stiffness, taken in silence; session 36);
    one the rigs take (noise_force_N: no section sets it) is not named."""
    from pathlib import Path
    two_piers = Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml'
    config = tmp_path / 'bridge.yaml'
    config.write_text(two_piers.read_text() + 'force_controller: loop_shaping\n'
                      'stiffness_N_per_m: 2.0e5\nnoise_force_N: 1.0\n')
    lines = []
    build_runs(config=str(config), progress=lines.append)
    assert [line for line in lines if 'does nothing' in line] == [
        f'settings: {config}: force_controller=loop_shaping: does nothing, every rig section '
        'sets its own (pier_a: specimen_loop_shaping, pier_b: specimen_loop_shaping) and a rig '
        "section beats a test-wide value; set it in the rigs' sections",
        f'settings: {config}: stiffness_N_per_m=200000.0: does nothing, every rig section sets '
        'its own (pier_a: 211000.0, pier_b: 337600.0) and a rig section beats a test-wide '
        "value; set it in the rigs' sections"]


def test_half_of_the_identification_runs_settings_is_warned():
    """--set excitation_input=valve_command without --set excitation=noise ran a closed-loop
    test of the record without a word (a new user forgot one of the two): warned."""
    lines = []
    build_runs(overrides={'excitation_input': 'valve_command'}, progress=lines.append)
    assert [line for line in lines if line.startswith(
        'warning: excitation_input valve_command without an excitation (excitation none) '
        'does nothing: these runs are closed-loop tests of the record')]
    lines.clear()
    build_runs(overrides={'excitation_input': 'valve_command', 'excitation': 'noise'},
               progress=lines.append)
    assert not [line for line in lines if 'does nothing' in line]
