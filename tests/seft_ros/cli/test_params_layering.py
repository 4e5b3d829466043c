"""``--params`` files over a configuration: what a parameter file replaces is said."""

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
        "the design on the model it was made from, not on the configuration's plant (one "
        'plant_model serves the rig, its compensator and the guard; to try the design on a '
        "plant other than its model, use rig_model servohydraulic or actuator with the lab's "
        'values)'], lines
    assert '1020000' in str(run['plant_model'])            # the file's, as the line says
    # on seft's own servohydraulic rig the plant model is the compensator's only: no line
    (tmp_path / 'servo.yaml').write_text('rig_model: servohydraulic\nduration_s: 1.0\n')
    lines.clear()
    api.build_runs(config=str(tmp_path / 'servo.yaml'),
                   params_files=[str(tmp_path / 'rig.yaml')], progress=lines.append)
    assert not [ln for ln in lines if ln.startswith('settings: --params')], lines
