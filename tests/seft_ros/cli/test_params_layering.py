"""``--params`` files over a configuration: what a parameter file replaces is said, and a
state_space rig's own plant (``rig_plant_model``) is kept apart from the identified one."""

import re

import pytest

from seft_msgs_py.errors import InputError, ParameterError
from seft_plant_sim.rigs import make_rig
from seft_ros.cli import api

#: A lab's plant model of the force alone (a first-order loop), as a file.
PLANT = ('form: transfer_function\nnum: {{force_N: [{gain}]}}\nden: [1.0, 100.0]\n'
         'io_delay_s: 0.004\nspecimen: {{mass_kg: 52.7, damping_N_s_per_m: 903.3, '
         'stiffness_N_per_m: 211000.0}}\n')


def test_an_identified_plant_model_replacing_the_labs_on_a_state_space_rig_is_said(tmp_path):
    """A state_space rig simulates its plant_model, which its compensator and the guard read
    too: a --params file's identified model replaced the configuration's (the lab's own
    plant) without a line, so that the 'rehearsal' rehearsed the design on its own model
    (session 24's explorer: every state_space case passed for that reason)."""
    (tmp_path / 'lab_plant.yaml').write_text(PLANT.format(gain=1.0e6))
    (tmp_path / 'lab.yaml').write_text('rig_model: state_space\nplant_model: lab_plant.yaml\n'
                                       'duration_s: 1.0\n')
    (tmp_path / 'rig.yaml').write_text('plant_model:\n' + ''.join(
        f'  {line}\n' for line in PLANT.format(gain=1.02e6).splitlines()))
    lines = []
    run, = api.build_runs(config=str(tmp_path / 'lab.yaml'),
                          params_files=[str(tmp_path / 'rig.yaml')], progress=lines.append)
    said = [ln for ln in lines if ln.startswith('settings: --params')]
    assert said == [
        f"settings: --params {tmp_path / 'rig.yaml'}: its plant_model replaces "
        f"{tmp_path / 'lab.yaml'}'s, and the state_space rig simulates it: this run rehearses "
        "the design on the model it was made from, not on the configuration's plant (without "
        'a rig_plant_model one plant_model serves the rig, its compensator and the guard; to '
        "rehearse the design on the configuration's plant, give that plant as "
        'rig_plant_model there)'], lines
    assert '1020000' in str(run['plant_model'])            # the file's, as the line says
    # on seft's own servohydraulic rig the plant model is the compensator's only: no line
    (tmp_path / 'servo.yaml').write_text('rig_model: servohydraulic\nduration_s: 1.0\n')
    lines.clear()
    api.build_runs(config=str(tmp_path / 'servo.yaml'),
                   params_files=[str(tmp_path / 'rig.yaml')], progress=lines.append)
    assert not [ln for ln in lines if ln.startswith('settings: --params')], lines


def _steady_force_N(params, command_V=1.0, steps=500):
    """The rig's force after `steps` samples of a constant valve command."""
    rig = make_rig(params)
    for _ in range(steps):
        rig.apply(command_V)
    return rig.true_force()


def test_a_labs_rig_plant_model_stays_the_rigs_under_an_identified_plant_model(tmp_path):
    """The lab's path with its own plant as the rig (rig_plant_model) and --params rig.yaml
    (seft identify's plant_model): the rig steps the lab's plant, the compensators and the
    guard read the identified one, and no line says the rig was replaced. Before, one
    plant_model served both, so a rehearsal ran the design on its own model (session 24:
    every state_space case passed for that reason)."""
    (tmp_path / 'lab_plant.yaml').write_text(PLANT.format(gain=1.02e6))   # the lab's hardware
    (tmp_path / 'lab.yaml').write_text('rig_model: state_space\nrig_plant_model: '
                                       'lab_plant.yaml\nduration_s: 1.0\n')
    (tmp_path / 'rig.yaml').write_text('plant_model:\n' + ''.join(
        f'  {line}\n' for line in PLANT.format(gain=1.0e6).splitlines()))  # as identified
    lines = []
    run, = api.build_runs(config=str(tmp_path / 'lab.yaml'),
                          params_files=[str(tmp_path / 'rig.yaml')], progress=lines.append)
    assert not [ln for ln in lines if ln.startswith('settings: --params')], lines
    assert '1000000' in run['plant_model'] and '1020000' in run['rig_plant_model']
    # the rig's force follows the lab's plant: 1.02e6 / 100 = 10200 N/V at DC, not 10000
    assert _steady_force_N(run) == pytest.approx(10200.0, rel=1e-9)
    assert _steady_force_N(dict(run, rig_plant_model='none')) == pytest.approx(10000.0,
                                                                                rel=1e-9)
    # the open-loop identification run has the lab's plant alone (no plant_model yet)
    run, = api.build_runs(config=str(tmp_path / 'lab.yaml'))
    assert run['plant_model'] == 'none'
    assert _steady_force_N(run) == pytest.approx(10200.0, rel=1e-9)


def test_a_rig_plant_model_is_refused_off_a_state_space_rig_and_checked_by_its_name(tmp_path):
    """rig_plant_model is read by the state_space rig only: on another rig it would be
    silently ignored, so it is refused in one line; a bad field names the parameter."""
    (tmp_path / 'lab_plant.yaml').write_text(PLANT.format(gain=1.0e6))
    (tmp_path / 'servo.yaml').write_text('rig_model: servohydraulic\nrig_plant_model: '
                                         'lab_plant.yaml\n')
    with pytest.raises(ParameterError, match=(
            r"^.*parameter rig_plant_model: the plant a rig_model 'state_space' steps, and "
            r"this rig is 'servohydraulic' \(its physics is its own\): set rig_model "
            r'state_space, or rig_plant_model none$')):
        api.build_runs(config=str(tmp_path / 'servo.yaml'))
    (tmp_path / 'bad.yaml').write_text('form: transfer_function\nnum: {force_N: [1.0]}\n')
    (tmp_path / 'lab.yaml').write_text('rig_model: state_space\nrig_plant_model: bad.yaml\n')
    # named by its file and the parameter that reads it
    with pytest.raises(ParameterError, match=r'^' + re.escape(str(tmp_path / 'bad.yaml'))
                       + r': rig_plant_model: .*\(den missing\)$'):
        api.build_runs(config=str(tmp_path / 'lab.yaml'))
    (tmp_path / 'lab.yaml').write_text('rig_model: state_space\nrig_plant_model: none.yaml\n')
    with pytest.raises(InputError, match=r'rig_plant_model: none\.yaml: no such file'):
        api.build_runs(config=str(tmp_path / 'lab.yaml'))
