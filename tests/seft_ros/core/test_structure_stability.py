"""The pre-run guard of a structure test: its closed sampled loop's eigenvalues against the
study's guard (the rigid limit) and against stepped runs."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_ros.core import stability
from seft_ros.core.structure import parse_structure
from seft_ros.core.structure_experiment import simulate_structure
from seft_ros.core.structure_stability import (
    StructureLoop,
    check_structure,
    largest_stable_scale,
    scaled_parameters,
)
from seft_ros.core.substructure import structure_setup

M, K, C = 52.7, 2.11e5, 903.278


def _two_story(mu, fr, predictor, rig='servohydraulic', **rig_section):
    m2, k2 = mu * M, mu * fr ** 2 * K
    s = parse_structure({'dofs': ['s1', 's2'], 'physical': {'s1': 'lab'},
                         'story_masses_kg': [M, m2], 'story_stiffnesses_N_per_m': [K, k2],
                         'story_damping_N_s_per_m': [C, 0.04 * np.sqrt(k2 * m2)]},
                        rigs={'lab': dict(rig_model=rig, **rig_section)})
    return parameters.resolve({'structure': s.to_json(), 'predictor': predictor,
                               'duration_s': 20.0, 'monitor_threshold': 0.0})


@pytest.mark.parametrize('rig', ['servohydraulic', 'delay'])
def test_the_rigid_limit_has_the_studys_boundary(rig):
    """One physical DOF carrying the rigid mass alpha m = m: the coupling scale is alpha, and
    uncompensated the boundary is the study's largest stable alpha (1.32 / 0.93)."""
    s = parse_structure({'physical': {'floor_1': 'lab'}, 'story_masses_kg': [2 * M],
                         'story_stiffnesses_N_per_m': [K], 'story_damping_N_s_per_m': [C]},
                        rigs={'lab': {'rig_model': rig}})
    p = parameters.resolve({'structure': s.to_json(), 'predictor': 'none'})
    study = stability.largest_stable_alpha(parameters.resolve(
        {'alpha': 1.0, 'predictor': 'none', 'rig_model': rig}))
    assert largest_stable_scale(p, step=0.05, tol=1e-4) == pytest.approx(study, abs=2e-4)


def test_scaling_keeps_the_specimens_and_scales_the_rest():
    p = _two_story(1.0, 2.0, 'model')
    sub = structure_setup(scaled_parameters(p, 0.5)).substructures
    whole = structure_setup(p).substructures
    assert sub.specimen_stiffness_N_per_m == pytest.approx(whole.specimen_stiffness_N_per_m)
    np.testing.assert_allclose(sub.stiffness_c_N_per_m, 0.5 * whole.stiffness_c_N_per_m)
    np.testing.assert_allclose(sub.mass_c_kg, 0.5 * whole.mass_c_kg)
    with pytest.raises(parameters.ParameterError, match='coupling scale 0: expected > 0'):
        scaled_parameters(p, 0)


def _grows(params) -> bool:
    """Stepped (monitor off): the story's motion still near its peak in the record's quiet
    end, or a limit reached."""
    run = simulate_structure(params)
    x = run.rigs['lab'].displacement_m
    return (not run.stable) or np.max(np.abs(x[-1000:])) > 0.5 * np.max(np.abs(x))


@pytest.mark.parametrize('mu, fr, predictor, stable', [
    (1.0, 1.0, 'model', True),
    (1.5, 3.0, 'model', False),     # the second mode at 48 Hz, beyond the force loop's band
    (0.5, 0.5, 'none', True),       # a soft coupling survives the delay's negative damping
    (1.0, 1.0, 'none', False),
])
def test_the_guard_says_what_the_stepped_run_does(mu, fr, predictor, stable):
    p = _two_story(mu, fr, predictor)
    radius = StructureLoop(p).spectral_radius
    assert (radius < 1.0) == stable
    assert _grows(p) == (not stable)


def test_check_structure_says_it_in_one_line():
    check = check_structure(_two_story(1.0, 1.0, 'none'))
    assert check.stable is False
    assert check.message.startswith('structure with predictor none is predicted UNSTABLE '
                                    '(spectral radius 1.0')
    ok = check_structure(_two_story(1.0, 1.0, 'model'))
    assert ok.stable and 'predicted stable' in ok.message
