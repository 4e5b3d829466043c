"""The whole structure as data (core.structure): the study's test as its one-DOF case, and
checks that name what the user wrote."""

import re

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.structure import STUDY_DOF, STUDY_RIG, study_structure, test_setup


def test_the_study_is_the_one_dof_structure_with_its_alpha_exactly():
    """M = (1 + alpha) m, C = c, K = k at the DOF 'specimen' of the root namespace's rig;
    the split keeps the user's alpha (not mu / m rounded) and has nothing else
    computational."""
    for alpha in (0.0, 0.3, 1.5, 2.0 / 3.0):
        p = parameters.resolve({'alpha': alpha})
        setup = test_setup(p)
        assert setup.is_study and setup.rig_names == (STUDY_RIG,)
        assert setup.structure.dofs == (STUDY_DOF,)
        assert setup.rig_params[STUDY_RIG] == p
        sub = setup.substructures
        assert sub.alpha[0] == alpha                       # exactly
        assert not sub.coupled
        np.testing.assert_array_equal(study_structure(p).mass_kg, [[(1 + alpha) * 52.7]])
        assert sub.rigid_mass_kg[0] == pytest.approx(alpha * 52.7, rel=1e-12)


def test_a_damping_below_the_specimens_names_the_users_field(tmp_path):
    """Modal damping of 2 % on a building whose first story is the study's specimen (903 N
    s/m of its own): the structure gives that DOF 179 N s/m, less than the specimen alone.
    The error names modal_damping_ratios (what the user wrote) and both numbers, not the
    derived damping matrix."""
    path = tmp_path / 'building.yaml'
    path.write_text('predictor: model\nstructure:\n  dofs: [story_1, story_2]\n'
                    '  physical: {story_1: lab}\n  story_masses_kg: [52.7, 52.7]\n'
                    '  story_stiffnesses_N_per_m: [2.11e5, 2.11e5]\n'
                    '  modal_damping_ratios: 0.02\nrigs:\n  lab: {rig_model: servohydraulic}\n')
    with pytest.raises(ParameterError, match=re.escape(
            f"{path}: structure.modal_damping_ratios: gives physical dof 'story_1' a damping "
            "of 178.955 N s/m (the diagonal of the damping matrix), less than rig lab's "
            'specimen alone, damping_N_s_per_m=903.278')):
        expand_runs(load_config(path), where=str(path))
    path.write_text(path.read_text().replace('modal_damping_ratios: 0.02',
                                             'story_damping_N_s_per_m: [903.278, 133.4]'))
    assert expand_runs(load_config(path), where=str(path))[0]['predictor'] == 'model'
