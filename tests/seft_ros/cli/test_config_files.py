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
    runs = build_runs(config=str(path))
    assert runs
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
