"""The structure configurations shipped in config/ (issue 20) do what their comments say."""

from pathlib import Path

import pytest

from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate as simulate_structure
from seft_ros.core.stability import TestLoop as StructureLoop

CONFIG = Path(__file__).resolve().parents[3] / 'config'


@pytest.mark.parametrize('name, dofs', [('two_story', ['story_1', 'story_2']),
                                        ('two_piers', ['pier_a', 'pier_b', 'deck'])])
def test_model_follows_every_dof_and_none_goes_unstable_as_predicted(name, dofs):
    runs = {p['predictor']: p for p in expand_runs(load_config(CONFIG / f'{name}.yaml'))}
    assert set(runs) == {'none', 'model'}
    # uncompensated: the delay's negative damping at the coupling, predicted and seen
    assert StructureLoop(runs['none']).spectral_radius > 1.0
    none = simulate_structure(runs['none'])
    assert not none.stable and 'unstable at t=' in none.abort_reason
    # model: predicted stable, within 1 % on every degree of freedom over the whole record
    assert StructureLoop(runs['model']).spectral_radius < 1.0
    run = simulate_structure(runs['model'])
    assert run.stable
    comparison = compare_run(run)
    assert [d.dof for d in comparison.dofs] == dofs
    for d in comparison.dofs:
        assert d.displacement.nrms < 0.01, d.dof
        assert d.floor_acceleration.nrms < 0.01, d.dof
