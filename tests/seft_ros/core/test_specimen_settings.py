"""Settings that follow the specimen, and the combinations the docs show cost accuracy
(issue 39)."""

import json

import pytest

from seft_msgs_py import parameters
from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate
from seft_ros.core.specimen_settings import costly_settings, follow_specimen

CHOSEN = {'force_controller': 'tangent_loop_shaping', 'predictor_restoring_force': 'hysteretic',
          'predictor_loop_delay_steps': 5, 'predictor_loop_taps': 48,
          'predictor_loop_hf_weight': 1e-3}


def test_a_yielding_member_gets_its_settings_unless_set():
    config = {'specimen_model': 'bouc_wen', 'predictor': 'model'}
    params, notes = follow_specimen(config, parameters.resolve(config))
    assert {k: params[k] for k in CHOSEN} == CHOSEN
    assert notes == ['rig: specimen_model bouc_wen (a member that yields): chose '
                     'force_controller tangent_loop_shaping, predictor_restoring_force '
                     'hysteretic, predictor_loop_delay_steps 5, predictor_loop_taps 48, '
                     'predictor_loop_hf_weight 0.001 (the settings for a yielding member, '
                     'docs: structures); set any of them to choose otherwise']
    # what the user set stays; the delay rig has no valve controller nor loop inverse
    config = dict(config, force_controller='loop_shaping', predictor_loop_delay_steps=10)
    params, notes = follow_specimen(config, parameters.resolve(config))
    assert (params['force_controller'], params['predictor_loop_delay_steps']) == (
        'loop_shaping', 10)
    assert params['predictor_restoring_force'] == 'hysteretic'
    config = {'specimen_model': 'bouc_wen', 'rig_model': 'delay'}
    params, notes = follow_specimen(config, parameters.resolve(config))
    assert params['predictor_restoring_force'] == 'hysteretic'
    assert params['force_controller'] == 'loop_shaping'            # the default, unused
    assert 'chose predictor_restoring_force hysteretic (' in notes[0]
    linear = parameters.resolve({})
    assert follow_specimen({}, linear) == (linear, [])


def _piers(pier_a: dict, **top):
    """config/two_piers.yaml with pier_a's section replaced (a dict of its parameters)."""
    values = load_config('config/two_piers.yaml')
    doc = json.loads(values['structure'])
    doc['rigs']['pier_a'] = pier_a
    values.update(structure=json.dumps(doc), predictor='model', **top)
    return values


def test_a_structures_yielding_pier_declared_alone():
    notes = []
    run = expand_runs(_piers({'specimen_model': 'bouc_wen'}), notes=notes)[0]
    pier_a = json.loads(run['structure'])['rigs']['pier_a']
    assert pier_a == dict(CHOSEN, specimen_model='bouc_wen')
    assert notes[0].startswith('pier_a: specimen_model bouc_wen (a member that yields): '
                               'chose force_controller tangent_loop_shaping, ')
    assert costly_settings(run) == []
    # its section's own settings (two_piers.yaml's, for an elastic pier) stay, and cost
    notes = []
    section = {'specimen_model': 'bouc_wen', 'force_controller': 'specimen_loop_shaping',
               'predictor_loop_delay_steps': 14, 'predictor_loop_taps': 96,
               'predictor_loop_hf_weight': 1e-4}
    run = expand_runs(_piers(section), notes=notes)[0]
    assert json.loads(run['structure'])['rigs']['pier_a'] == dict(
        section, predictor_restoring_force='hysteretic')
    assert [line.split(':')[1].strip() for line in costly_settings(run)] == [
        'force_controller specimen_loop_shaping on a member that yields',
        'a force-loop inverse of 14 steps on a member that yields']
    # a setting of the whole test is the user's for every rig
    notes = []
    run = expand_runs(_piers({'specimen_model': 'bouc_wen'},
                             predictor_restoring_force='model'), notes=notes)[0]
    assert 'predictor_restoring_force' not in json.loads(run['structure'])['rigs']['pier_a']
    assert costly_settings(run)[-1].startswith(
        'pier_a: predictor model with predictor_restoring_force model on a member that yields')


def test_costly_combinations_of_the_study():
    p = parameters.resolve({'alpha': 1.0, 'predictor': 'none'})
    assert costly_settings(p) == [
        "rig: predictor none at alpha 1: the force loop's lag is not compensated (the "
        "study's finding: on its rig it costs 35-49 % at alpha 0.5-1 and is unstable near "
        "1.5, README: the main job; the guard gives this rig's figures); 'model' or "
        "'adaptive' compensate it"]
    assert costly_settings(p, flagging=True) == []           # said, not flagged
    assert costly_settings(dict(p, alpha=0.0)) == []
    # a structure uncompensated: said too (a completed one erred 37 % unflagged; session
    # 36's review), not for its identification run
    from pathlib import Path

    from seft_ros.cli.api import build_runs
    two_story = str(Path(__file__).resolve().parents[3] / 'config' / 'two_story.yaml')
    structure = build_runs(config=two_story, overrides={'predictor': 'none'})[0]
    assert costly_settings(structure) == [
        "lab: predictor none on a structure: the force loop's lag is not compensated, and no "
        'error flag judges the run (a two-story whose uncompensated run completed erred 37 % '
        "of x; session 36); 'model' or 'adaptive' compensate it"]
    assert costly_settings(structure, flagging=True) == []
    assert costly_settings(dict(structure, excitation='noise')) == []
    p = parameters.resolve({'predictor': 'adaptive'})              # adaptive_loop: auto
    assert costly_settings(p) == []                                # the latency fitted
    p = parameters.resolve({'predictor': 'adaptive', 'adaptive_loop': 'model'})
    assert costly_settings(p) == [
        "rig: predictor adaptive with adaptive_loop model: the force loop's I/O latency as "
        'declared; 10 % off it costs 2-2.7 % (the two piers, the one-rig test), 20 % off up to '
        '5.4 % (docs: results/robustness); adaptive_loop: model_latency (the default, auto) '
        'identifies it']
    assert costly_settings(p, flagging=True) == []
    assert costly_settings(dict(p, adaptive_loop='model_latency')) == []
    # with a plant model of data the latency is the model's (model_latency is refused there)
    plant = ('{"form": "transfer_function", "dt": 0.002, "num": {"force_N": [0, 1]}, '
             '"den": [1, -0.5], "specimen": {"mass_kg": 52.7, "stiffness_N_per_m": 211000, '
             '"damping_N_s_per_m": 903.3}}')
    assert costly_settings(dict(p, plant_model=plant)) == []
    assert costly_settings(dict(p, rig_model='delay')) == []
    p = parameters.resolve({'predictor': 'model', 'specimen_uncertainty': 0.15})
    assert costly_settings(p, flagging=True)[0].startswith(
        'rig: predictor model with specimen_uncertainty 0.15: model needs the specimen as it '
        'is')
    p = parameters.resolve({'predictor': 'model', 'specimen_model': 'bouc_wen',
                            'predictor_restoring_force': 'measured',
                            'force_controller': 'tangent_loop_shaping',
                            'predictor_loop_delay_steps': 5})
    assert [line.split(':')[1] for line in costly_settings(p)] == [
        ' predictor model with predictor_restoring_force measured on a member that yields']


def test_the_yielding_pier_declared_alone_follows_the_reference():
    """Issue 39's target: a Bouc-Wen pier of the two piers declared with specimen_model
    alone, 700 N, the embedded record (4 s): within 5 % per DOF (measured 0.68 / 1.51 /
    0.67 %; with two_piers.yaml's settings of an elastic pier the monitor stops it)."""
    run = expand_runs(_piers({'specimen_model': 'bouc_wen'}, amplitude_N=700.0,
                             duration_s=4.0))[0]
    rd = simulate(run)
    assert rd.stable
    per_dof = [d.displacement.nrms for d in compare_run(rd).dofs]
    assert max(per_dof) < 0.02


def test_a_linear_specimen_other_than_the_one_loop_shaping_cancels():
    """The study's C_f cancels s^2 + 17.14 s + 4002: a rig whose specimen's k/m is more than
    0.5 % or c/m more than 2 % from it gets one line on loop_shaping, and the run is flagged
    (session 23's D4: a two-story with k 2.5e5 erred 24.7 % silently, 0.49 % with
    specimen_loop_shaping); the study's own specimen (k/m 4003.8, 0.045 % off) gets none."""
    assert costly_settings(parameters.resolve({'predictor': 'model'})) == []
    p = parameters.resolve({'predictor': 'model', 'stiffness_N_per_m': 2.5e5})
    line = ("rig: force_controller loop_shaping cancels the study's specimen (s^2 + 17.14 s + "
            "4002, 10.07 Hz), this rig's is s^2 + 17.14 s + 4743.8 (10.96 Hz): 1 % stiffer "
            'costs the one-rig test 1.5 % of x where it had 0.4 %, 18 % stiffer a two-story '
            '24.7 % where it had 0.49 % (docs: structures); use force_controller: '
            'specimen_loop_shaping')
    assert costly_settings(p) == [line] and costly_settings(p, flagging=True) == [line]
    for name, ratio, said in (('stiffness_N_per_m', 1.004, False),
                              ('stiffness_N_per_m', 0.994, True),
                              ('damping_N_s_per_m', 1.019, False),
                              ('damping_N_s_per_m', 0.97, True),
                              ('mass_kg', 1.006, True)):
        q = dict(p, stiffness_N_per_m=2.11e5)
        q[name] *= ratio
        assert bool(costly_settings(q)) == said, (name, ratio)
    assert costly_settings(dict(p, force_controller='specimen_loop_shaping')) == []
    assert costly_settings(dict(p, rig_model='delay')) == []          # no valve controller
    # an open-loop identification run: the valve driven directly, the controller bypassed
    # (session 24's F and J were flagged for the controller that the next step replaces)
    open_loop = dict(p, predictor='none', excitation='noise', excitation_input='valve_command')
    assert costly_settings(open_loop) == [] and costly_settings(open_loop, flagging=True) == []
    assert costly_settings(dict(open_loop, excitation_input='reference_force')) == [line]
    yielding = dict(p, specimen_model='bouc_wen', predictor_restoring_force='hysteretic',
                    predictor_loop_delay_steps=5)
    assert [line.split(':')[1] for line in costly_settings(yielding)] == [
        ' force_controller loop_shaping on a member that yields']
    # a structure's rig, by its name
    config = {'predictor': 'model', 'structure': json.dumps({
        'dofs': ['f1', 'f2'], 'physical': {'f1': 'lab'}, 'story_masses_kg': [60.0, 40.0],
        'story_stiffnesses_N_per_m': [2.5e5, 1.5e5], 'story_damping_N_s_per_m': [950.0, 150.0],
        'rigs': {'lab': {'stiffness_N_per_m': 2.5e5}}})}
    run = expand_runs(config)[0]
    said = costly_settings(run)
    assert said[0] == 'lab' + line[3:]
    # (and its default force-loop inverse: not chosen for this structure)
    assert len(said) == 2 and 'not chosen for the structure' in said[1]


def test_the_tolerance_of_the_cancelled_specimen_measured():
    """The basis of CANCELLED_STIFFNESS_TOLERANCE: the one-rig test at alpha 1 with 'model'
    (embedded record, 1000 N, 20 s) on a specimen 1 % stiffer than the study's errs 1.52 %
    with loop_shaping against 0.37 % with its own C_f (0.40 % at the study's stiffness)."""
    base = parameters.resolve({'predictor': 'model', 'alpha': 1.0, 'duration_s': 20.0,
                               'stiffness_N_per_m': 1.01 * 2.11e5})

    def nrms(**kw):
        run = simulate(dict(base, **kw))
        assert run.stable
        return compare_run(run).signal('displacement').nrms

    assert nrms() == pytest.approx(0.0152, abs=0.001)
    assert nrms(force_controller='specimen_loop_shaping') == pytest.approx(0.0037, abs=0.0005)


def test_a_declared_specimen_other_than_the_plant_models_is_said():
    """A rig whose declared specimen is not its plant model's (a mass typed in grams: 1000
    times the plant's, session 38, refused by the guard at a largest stable alpha of 0.0007
    with no word of the cause) gets a line naming both; within 10 % (an identification's
    scatter), none."""
    from pathlib import Path
    rig = Path(__file__).resolve().parents[1] / 'analysis' / 'data' / 'own_actuator_F_rig.yaml'
    values = dict(load_config(rig), predictor='model', alpha=0.5)
    exact = dict(values, mass_kg=200.0, stiffness_N_per_m=1776500.0)
    assert not [line for line in costly_settings(parameters.resolve(exact))
                if 'plant model' in line]
    near = dict(exact, mass_kg=215.0)                  # 7.5 % off: within the tolerance
    assert not [line for line in costly_settings(parameters.resolve(near))
                if 'plant model' in line]
    grams = dict(exact, mass_kg=200000.0)
    lines = [line for line in costly_settings(parameters.resolve(grams))
             if 'plant model' in line]
    assert lines == [
        "rig: the declared specimen (2e+05 kg, 1.776e+06 N/m, 0.47 Hz) is 1e+03 x the plant "
        "model's mass and 1 x its stiffness (200 kg, 1.777e+06 N/m, 15.00 Hz): the reference "
        'structure, the guard and the compensators take the declared specimen, the force loop '
        "the plant model's (a unit slip? a plant model of another specimen?); declare the "
        'specimen the plant model has (seft identify wrote it), or identify this one']
    # said before the run, not a flag of it
    assert not [line for line in costly_settings(parameters.resolve(grams), flagging=True)
                if 'plant model' in line]


def test_the_settings_lines_come_before_the_guards_refusal(tmp_path):
    """The settings lines may say why the guard refuses a run: they come first (a new
    user's specimen 1000 times too soft was refused, and the line naming it came only under
    --force, after the refusal would have stopped the run; session 38)."""
    from pathlib import Path

    from seft_ros.cli.api import simulate_experiments
    from seft_ros.core.stability import PredictedUnstableError
    rig = Path(__file__).resolve().parents[1] / 'analysis' / 'data' / 'own_actuator_F_rig.yaml'
    p = parameters.resolve(dict(load_config(rig), predictor='none', alpha=0.5,
                                mass_kg=200000.0, stiffness_N_per_m=1776500.0,
                                duration_s=1.0))
    lines = []
    with pytest.raises(PredictedUnstableError):
        simulate_experiments(runs=[p], out_dir=tmp_path, progress=lines.append)
    assert any("the plant model's mass" in line for line in lines), lines


def test_a_run_of_several_that_cannot_be_set_up_is_named():
    """One run of a batch whose compensator cannot be set up (`model` with a specimen model
    20 % off: its pole calibration refuses it) is named by its label (a new user's batch of
    `model` and `adaptive` was refused in a line naming no run; session 38); alone, as
    before."""
    from pathlib import Path

    from seft_msgs_py.errors import ParameterError
    from seft_ros.cli.api import build_runs, check_stability
    rig = Path(__file__).resolve().parents[1] / 'analysis' / 'data' / 'own_actuator_F_rig.yaml'
    off = {'mass_kg': 200.0, 'stiffness_N_per_m': 1776500.0, 'damping_N_s_per_m': 1130.97,
           'predictor_stiffness_N_per_m': 1.2 * 1776500.0, 'predictor_mass_kg': 160.0,
           'duration_s': 1.0}
    runs = build_runs(params_files=[str(rig)], overrides=dict(off, predictor=['adaptive',
                                                                               'model']))
    with pytest.raises(ParameterError, match=r'^\[alpha_0_servohydraulic_model\] '
                       r'predictor_calibration poles: .*\(the other runs: run them without '
                       r'this one\)$'):
        check_stability(runs=runs, progress=lambda line: None)
    with pytest.raises(ParameterError, match=r'^predictor_calibration poles: '):
        check_stability(runs=runs[1:], progress=lambda line: None)
    check_stability(runs=runs[:1], progress=lambda line: None)      # adaptive alone runs


def test_a_coupled_rig_with_the_default_loop_inverse_is_told_to_design_it(tmp_path):
    """A structure's rig on a DOF the computational part pulls on, compensated with the
    default force-loop inverse (10 steps, 48 taps: no structure's), gets the line that
    names seft design (a new user's OpenSees frame, as the tutorial wrote it, erred 4.27 %
    where the shipped file's inverse gave 1.63 %; session 38); the shipped two_story (its
    own inverse) and a rehearsed one do not."""
    from pathlib import Path
    text = (Path(__file__).resolve().parents[3] / 'config' / 'two_story.yaml').read_text()

    def said(text):
        path = tmp_path / 'two_story.yaml'
        path.write_text(text)
        return [line for p in expand_runs(load_config(path)) for line in costly_settings(p)
                if 'not chosen for the structure' in line]
    assert said(text) == []
    default = '\n'.join(line for line in text.splitlines()
                        if not line.strip().startswith(('predictor_loop_delay_steps',
                                                         'predictor_loop_taps',
                                                         'predictor_loop_hf_weight')))
    assert said(default) == [
        'lab: predictor model on a DOF coupled to the computational part with the default '
        'force-loop inverse (10 steps, 48 taps), not chosen for the structure: seft design '
        "CONFIG --out FILE chooses it by rehearsing the structure on the rig's model (a new "
        "user's OpenSees steel frame erred 4.27 % of x with the default, 1.63 % with the 5 "
        'steps the shipped file sets; session 38)']
    rehearsed = default.replace('\n  lab:\n', '\n  lab:\n    predictor_loop_rehearsed: true\n')
    assert rehearsed != default and said(rehearsed) == []
