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
