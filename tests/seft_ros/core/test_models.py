"""The computational-model plug-in point (issue 40, :mod:`seft_ros.core.models`): the core
finds a model's plug-in by the key of its ``structure`` section and dispatches the structure,
its split and its computational part to it, without importing it."""

from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate
from seft_ros.core.models import model_kinds, model_plugin, register
from seft_ros.core.structure import Structure, parse_structure, split
from seft_ros.core.substructure import StructureState

ROOT = Path(__file__).resolve().parents[3]


class MatrixPlugin:
    """A plug-in whose 'program' is seft's own matrices (the section's general form under
    its key): a test of the dispatch, not of a program."""

    name = 'matrix_model'

    def __init__(self):
        self.parts = 0

    def structure(self, section, *, rigs=None, where='structure', base=None):
        inner = dict(section[self.name], physical=section['physical'])
        s = parse_structure(inner, rigs=rigs, where=where)
        return replace(s, model_kind=self.name, model=MappingProxyType({'source': 'matrices'}))

    def split(self, structure, specimens, *, where='structure'):
        sub = split(replace(structure, model_kind=None, model=None), specimens, where=where)
        return replace(sub, structure=structure)

    def part(self, sub, dt):
        self.parts += 1
        return StructureState(sub, dt)


@pytest.fixture
def plugin():
    p = MatrixPlugin()
    remove = register(p)
    yield p
    remove()


def test_a_registered_plugin_runs_the_matrix_test_bit_for_bit(plugin):
    """config/two_story.yaml's building under a plug-in's key: the structure's JSON keeps
    the plug-in's name and model, the builder steps the plug-in's part, and the run equals
    the matrix path to the last bit (the first 2 s)."""
    params = expand_runs(dict(load_config(ROOT / 'config' / 'two_story.yaml'),
                              predictor='model', duration_s=2.0))[0]
    s = Structure.from_json(params['structure'])
    section = {'matrix_model': {'dofs': list(s.dofs), 'mass_matrix_kg': s.mass_kg.tolist(),
                                'stiffness_matrix_N_per_m': s.stiffness_N_per_m.tolist(),
                                'damping_matrix_N_s_per_m': s.damping_N_s_per_m.tolist()},
               'physical': dict(s.physical)}
    via = parse_structure(section, rigs={'lab': dict(s.rigs['lab'])})
    assert via.model_kind == 'matrix_model'
    again = Structure.from_json(via.to_json())
    assert again.model_kind == 'matrix_model' and again.model == {'source': 'matrices'}
    ours = simulate(dict(params, structure=via.to_json()))
    theirs = simulate(params)
    assert plugin.parts >= 1
    np.testing.assert_array_equal(ours.rig.signal('displacement'),
                                  theirs.rig.signal('displacement'))
    np.testing.assert_array_equal(ours.rig.signal('force'), theirs.rig.signal('force'))
    assert set(ours.computational) == set(theirs.computational)
    for name, values in theirs.computational.items():
        np.testing.assert_array_equal(ours.computational[name], values)


def test_an_unknown_section_key_names_the_plugins():
    with pytest.raises(ParameterError, match=r'^structure\.fem: unknown key \(expected one of '
                       r'dofs, .*, or a model plug-in: .*opensees.*\)$'):
        parse_structure({'fem': {}, 'physical': {'a': 'lab'}})


def test_a_plugin_not_installed_is_one_line():
    assert 'opensees' in model_kinds()
    with pytest.raises(ParameterError, match=r"^structure\.sap: no computational-model "
                       r"plug-in 'sap' is installed \(installed: .*opensees.*\)$"):
        model_plugin('sap')
