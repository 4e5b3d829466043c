"""The 'model' compensator with the measured restoring force (predictor_restoring_force:
measured): the offset and the tangent stiffness against hand-computed values, the linear
specimen unchanged, and the yielding member stable on the pure-delay rig up to alpha = 2
against the independent nonlinear reference analysis."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import reference_from_run
from seft_ros.core.experiment import simulate
from seft_ros.core.predictors import (
    TANGENT_REGULARIZATION_M,
    TANGENT_STIFFNESS_RATIOS,
    DelayImpulseModel,
    ModelPredictor,
    TangentModelPredictor,
)
from seft_ros.core.reference_force import make_predictor

# The reference rig (paper Sec. 3.1) and its 10 ms delay.
M, K, DT, TAU = 52.7, 2.11e5, 0.002, 0.01
C = 17.14 * M


def _meas(x, v, a, f, step=0):
    return Measurement(step=step, time_s=step * DT, displacement_m=x, velocity_m_s=v,
                       acceleration_m_s2=a, force_N=f)


def _params(**over):
    return parameters.resolve({'rig_model': 'delay', 'alpha': 1.0, 'predictor': 'model',
                               'predictor_restoring_force': 'measured', **over})


def test_the_parameter_selects_the_tangent_predictor_and_refuses_other_values():
    assert isinstance(make_predictor(_params()), TangentModelPredictor)
    assert isinstance(make_predictor(_params(predictor_restoring_force='model')),
                      ModelPredictor)
    with pytest.raises(ParameterError, match='predictor_restoring_force'):
        parameters.resolve({'predictor_restoring_force': 'elastic'})
    with pytest.raises(ParameterError, match='predictor_restoring_force'):
        ModelPredictor(DelayImpulseModel(M, C, K, DT, TAU), 1.0, M, restoring_force='x')


def test_restoring_offset_is_measured_force_less_inertia_damping_and_model_stiffness():
    model = DelayImpulseModel(M, C, K, DT, TAU)
    pred = ModelPredictor(model, 1.0, M, restoring_force='measured')
    x, v, a, f = 0.004, 0.1, -3.0, 500.0
    # by hand: f_s = f - m a - c v; d = f_s - k x
    expected = f - M * a - C * v - K * x
    assert pred.restoring_offset(_meas(x, v, a, f)) == pytest.approx(expected, rel=1e-12)
    assert pred.restoring_offset(None) == 0.0
    linear = ModelPredictor(model, 1.0, M)
    assert linear.restoring_offset(_meas(x, v, a, f)) == 0.0


@pytest.mark.parametrize('matching', ['poles', 'impulse'])
def test_offset_law_is_the_linear_law_on_shifted_forces(matching):
    """F = d + beta (G - d) - K s_hat(f - d) (poles), or the impulse law on G - d and f - d,
    written out here from the model's public matrices."""
    model = DelayImpulseModel(M, C, K, DT, TAU)
    alpha = 1.5
    pred = ModelPredictor(model, alpha, M, matching=matching, restoring_force='measured')
    rng = np.random.default_rng(3)
    past = list(rng.normal(scale=300.0, size=12))
    x, v, a, f_m, g = 0.006, -0.05, 2.0, 900.0, -400.0
    d = f_m - M * a - C * v - K * x
    forces = np.array(past[-(model.n + 2):]) - d
    s_hat = model.E @ np.array([x, v]) + model.H @ forces
    if matching == 'poles':
        gain, beta = model.matching_gains(alpha)
        force = d + beta * (g - d) - gain @ s_hat
    else:
        r = (model.phi - np.eye(2))[1]
        force = d + ((g - d) * DT - alpha * M * (r @ s_hat)) / (DT + alpha * M * model.q)
    a_hat = pred.predict(_meas(x, v, a, f_m), past, g)
    assert a_hat == pytest.approx((g - force) / (alpha * M), rel=1e-9)


def _tangent():
    return TangentModelPredictor.from_parameters(_params())


def test_tangent_stiffness_is_the_regularized_secant_of_the_measured_restoring_force():
    pred = _tangent()
    assert pred.stiffness_ratio == 1.0          # k before any change is measured
    # a member at its post-yield slope 0.1 k over a 1 mm step (f_s = f since a = v = 0)
    dx = 1e-3
    pred.observe(_meas(0.0, 0.0, 0.0, 0.0))
    pred.observe(_meas(dx, 0.0, 0.0, 0.1 * K * dx))
    # by hand: (df dx + d0^2 k) / (dx^2 + d0^2) with d0 = 1e-5 m
    d0 = TANGENT_REGULARIZATION_M
    k_t = (0.1 * K * dx * dx + d0 ** 2 * K) / (dx ** 2 + d0 ** 2)
    nearest = TANGENT_STIFFNESS_RATIOS[np.argmin(np.abs(np.log(TANGENT_STIFFNESS_RATIOS)
                                                        - np.log(k_t / K)))]
    assert pred.stiffness_ratio == nearest
    assert nearest == pytest.approx(0.1, rel=0.03)
    assert pred.estimates() == {'tangent_stiffness_N_per_m': pytest.approx(nearest * K)}
    # a step far below d0 (near a reversal) keeps the configured k
    pred.observe(_meas(dx + 1e-8, 0.0, 0.0, 0.1 * K * dx))
    assert pred.stiffness_ratio == 1.0
    # softening below the table's floor is clipped to its smallest ratio
    pred.observe(_meas(2 * dx, 0.0, 0.0, 0.1 * K * dx - 50.0))
    assert pred.stiffness_ratio == TANGENT_STIFFNESS_RATIOS[0]


def test_table_holds_the_configured_stiffness_exactly_and_spans_post_yield():
    r = TANGENT_STIFFNESS_RATIOS
    assert 1.0 in r
    assert r[0] < 0.1 < 1.0 < r[-1]
    assert np.allclose(r[1:] / r[:-1], 1.05)
    with pytest.raises(ParameterError, match='ratios'):
        TangentModelPredictor(lambda ratio: None, [], K, M, C)


def test_linear_specimen_runs_as_with_the_model_restoring_force():
    """Exact sensors: f_m - m a - c v - k x is zero to rounding, so the run is the linear
    model's (to 1e-9 of the peak)."""
    base = {'rig_model': 'delay', 'alpha': 1.0, 'predictor': 'model', 'duration_s': 3.0}
    linear = simulate(base)
    measured = simulate(dict(base, predictor_restoring_force='measured'))
    assert measured.stable and linear.stable
    scale = np.max(np.abs(linear.displacement_m))
    assert np.max(np.abs(measured.displacement_m - linear.displacement_m)) < 1e-9 * scale


def test_yielding_member_stays_stable_to_alpha_2_on_the_delay_rig():
    """Bouc-Wen defaults, delay rig, alpha = 2, 4 s of the default record: the elastic
    model runs away (stroke limit); with the measured restoring force the run is stable and
    within 25 % displacement NRMS of the nonlinear reference (solve_ivp of the whole
    structure), peaks within 20 %."""
    base = {'rig_model': 'delay', 'alpha': 2.0, 'predictor': 'model',
            'specimen_model': 'bouc_wen', 'duration_s': 4.0}
    elastic = simulate(base)
    assert not elastic.stable
    run = simulate(dict(base, predictor_restoring_force='measured'))
    assert run.stable and run.n_steps == 2000
    cmp = compare_run(run, reference_from_run(run))
    assert cmp.signal('displacement').nrms < 0.25
    assert abs(cmp.signal('displacement').peak_ratio - 1.0) < 0.2
    # the estimate followed the member into its post-yield range and back (unloading is
    # elastic), within the table
    k_t = run.estimates['tangent_stiffness_N_per_m']
    assert np.min(k_t) < 0.2 * K
    assert K <= np.max(k_t) <= TANGENT_STIFFNESS_RATIOS[-1] * K * (1 + 1e-12)
