"""The whole structure as data (core.structure): the study's test as its one-DOF case, and
checks that name what the user wrote."""

import json
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


BRIDGE = ('predictor: model\nstructure:\n  dofs: [pier_a, pier_b, deck]\n'
          '  physical: {{pier_a: pier_a, pier_b: pier_b}}\n'
          '  mass_matrix_kg: {m}\n'
          '  stiffness_matrix_N_per_m: {k}\n'
          '  damping_matrix_N_s_per_m: [[1036.678, 0, -133.4], [0, 1036.678, -133.4], '
          '[-133.4, -133.4, 266.8]]\n'
          'rigs:\n  pier_a: {{force_controller: specimen_loop_shaping}}\n'
          '  pier_b: {{stiffness_N_per_m: 3.376e+5, force_controller: specimen_loop_shaping}}\n')
M3 = '[[52.7, 0, 0], [0, 52.7, 0], [0, 0, 105.4]]'
K3 = '[[4.22e+5, 0, -2.11e+5], [0, 5.486e+5, -2.11e+5], [-2.11e+5, -2.11e+5, 4.22e+5]]'
#: A two-DOF general form; {k21}, {influence} filled in by each case.
TWO = ('predictor: model\nstructure:\n  dofs: [a, b]\n  physical: {{a: lab}}\n'
       '  mass_matrix_kg: [[60, 0], [0, 40]]\n'
       '  stiffness_matrix_N_per_m: [[3.61e+5, -1.5e+5], [{k21}, 1.5e+5]]\n'
       '  damping_matrix_N_s_per_m: [[1000, -100], [-100, 100]]\n{influence}'
       'rigs:\n  lab: {{force_controller: specimen_loop_shaping}}\n')
#: A four-story shear building; {physical} and {damping} by each case.
SHEAR = ('predictor: model\nstructure:\n  dofs: [f1, f2, f3, f4]\n'
         '  physical: {{{physical}: lab}}\n'
         '  story_masses_kg: [60.0, 60.0, 60.0, 60.0]\n'
         '  story_stiffnesses_N_per_m: [2.11e+5, 2.11e+5, 2e+5, 1e+5]\n  {damping}\n'
         'rigs:\n  lab: {{force_controller: specimen_loop_shaping}}\n')
GROUNDED = ("structure.physical: dof 'f2' has no spring to the ground (the row sum of the "
            "stiffness matrix is 0 N/m): it is joined to other dofs only, but a specimen joins "
            "its dof to the ground (rig lab's actuator reacts on the lab floor), so a member "
            'between two dofs (a story above the first) cannot be one; test a dof with a '
            'spring to the ground (here: f1)')

#: id -> (configuration text, the error after '<file>: '); the exploratory test's bad inputs
#: (session 23, structure_explore D6, D7)
BAD_STRUCTURES = {
    # the mass matrix is the odd one out, not the dofs (before: 'structure.dofs: expected a
    # list of 2 names')
    'mass_size': (BRIDGE.format(m='[[52.7, 0], [0, 52.7]]', k=K3),
                  'structure.mass_matrix_kg: has 2 rows, but dofs, stiffness_matrix_N_per_m '
                  'and damping_matrix_N_s_per_m give 3 dofs; expected a 3 x 3 matrix (one row '
                  'per dof)'),
    # a dof without mass named (a new user's massless deck: 'its smallest eigenvalue is 0'
    # alone, session 36)
    'massless': (BRIDGE.format(m='[[52.7, 0, 0], [0, 52.7, 0], [0, 0, 0]]', k=K3),
                 'structure.mass_matrix_kg: expected a positive definite matrix, but its '
                 "smallest eigenvalue is 0 (dof 'deck' without mass: every dof of the matrix "
                 'form carries a mass; a massless node belongs in an OpenSees model, which '
                 'condenses it)'),
    'influence_size': (TWO.format(k21=-1.5e5, influence='  influence: [1, 1, 1]\n'),
                       'structure.influence: has 3 entries, but dofs, mass_matrix_kg, '
                       'stiffness_matrix_N_per_m and damping_matrix_N_s_per_m give 2 dofs; '
                       'expected 2 entries (one per dof)'),
    # plain numbers (before: np.float64(-211000.0))
    'not_symmetric': (BRIDGE.format(m=M3, k=K3.replace('[-2.11e+5, -2.11e+5, 4.22e+5]',
                                                       '[-2.0e+5, -2.11e+5, 4.22e+5]')),
                      'structure.stiffness_matrix_N_per_m: expected a symmetric matrix (to '
                      '1e-08 of its largest entry), but row 1 column 3 is -211000.0 and row 3 '
                      'column 1 is -200000.0'),
    # 3 units in the 8th digit of the largest entry: past the tolerance
    'not_symmetric_8th_digit': (TWO.format(k21=-150001.1, influence=''),
                                'structure.stiffness_matrix_N_per_m: expected a symmetric '
                                'matrix (to 1e-08 of its largest entry), but row 1 column 2 is '
                                '-150000.0 and row 2 column 1 is -150001.1'),
    # nothing excited (before: ran, every NRMS '-')
    'influence_zero': (TWO.format(k21=-1.5e5, influence='  influence: [0, 0]\n'),
                       "structure.influence: all zero: the ground motion loads no dof (the "
                       "load -M iota xg'' of Eq. 1 is zero); expected a non-zero entry "
                       '(default: ones)'),
    # 300 % and 150 % of critical (before: accepted)
    'modal_damping_over_critical': (
        SHEAR.format(physical='f1', damping='modal_damping_ratios: [3.0, 1.5, 0.02, 0.02]'),
        'structure.modal_damping_ratios: expected ratios < 1 (fractions of critical damping: '
        '0.05 is 5 %; at 1 a mode no longer oscillates), got [3.0, 1.5, 0.02, 0.02]'),
    'modal_damping_critical': (
        SHEAR.format(physical='f1', damping='modal_damping_ratios: 1'),
        'structure.modal_damping_ratios: expected ratios < 1 (fractions of critical damping: '
        '0.05 is 5 %; at 1 a mode no longer oscillates), got [1]'),
    # a story between two floors as the specimen: said so, whether its damping or its
    # stiffness would have been refused first (before: 'gives physical dof f2 a damping of
    # 273.979 N s/m', 'the stiffness to the ground at physical dof f2 is 0.0 N/m')
    'specimen_between_floors': (
        SHEAR.format(physical='f2', damping='modal_damping_ratios: 0.03'), GROUNDED),
    'specimen_between_floors_damped': (
        SHEAR.format(physical='f2', damping='story_damping_N_s_per_m: [500, 950, 100, 100]'),
        GROUNDED),
    # the rig section named, and the closest names (before: "unknown parameter
    # 'bouc_wen_post_yield_ratio'")
    'rig_parameter_typo': (
        SHEAR.format(physical='f1', damping='story_damping_N_s_per_m: [950, 100, 100, 100]')
        .replace('{force_controller: specimen_loop_shaping}',
                 '{specimen_model: bouc_wen, bouc_wen_post_yield_ratio: 0.05}'),
        "rigs.lab: unknown parameter 'bouc_wen_post_yield_ratio' (did you mean "
        "'hysteresis_post_yield_ratio' or 'post_yield_stiffness_ratio'?)"),
}


@pytest.mark.parametrize('case', sorted(BAD_STRUCTURES))
def test_a_bad_structure_is_one_line_naming_the_field(tmp_path, case):
    text, message = BAD_STRUCTURES[case]
    path = tmp_path / 'structure.yaml'
    path.write_text(text)
    with pytest.raises(ParameterError) as info:
        expand_runs(load_config(path), where=str(path))
    assert str(info.value) == f'{path}: {message}'


def test_a_matrix_printed_to_9_digits_is_taken_symmetrized(tmp_path):
    """K21 -150000.001 against K12 -150000 (one unit in the 9th digit, 2.8e-9 of the largest
    entry: an FE program's export) is accepted, and the structure uses (K + K^T) / 2."""
    path = tmp_path / 'structure.yaml'
    path.write_text(TWO.format(k21=-150000.001, influence=''))
    run, = expand_runs(load_config(path), where=str(path))
    stiffness = np.array(json.loads(run['structure'])['stiffness_matrix_N_per_m'])
    assert stiffness[0, 1] == stiffness[1, 0] == -150000.0005
