"""Force control of members that yield (issue 10): the tangent-scheduled loop shaping and the
hysteretic compensator in closed loop (simulate), against the study's controller and the
independent nonlinear reference (scipy's solve_ivp of the whole structure,
seft_ros.analysis.reference). The controller as a unit: test_tangent_loop_shaping.py."""

import math

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import reference_from_run
from seft_ros.core.experiment import simulate

K = 2.11e5
TANGENT = dict(force_controller='tangent_loop_shaping')
YIELDING = dict(specimen_model='bouc_wen', rig_model='servohydraulic')
HYSTERETIC = dict(predictor='model', predictor_restoring_force='hysteretic')


# -- the targets, against the independent nonlinear reference -------------------------

def nrms_x(params):
    """Displacement NRMS (lag removed) of simulate() against the reference of seft's analysis
    (the whole nonlinear structure by scipy's solve_ivp, independent of the rig's RK4)."""
    run = simulate(params)
    assert run.stable, run.abort_reason
    return compare_run(run, reference_from_run(run)).signal('displacement').nrms


@pytest.mark.parametrize('alpha, opts, limit, study', [
    # alpha = 0, no feedback: the force loop alone (the study's C_f: 43.5 %)
    (0.0, {}, 0.05, 0.40),
    (1.0, HYSTERETIC, 0.05, 0.14),
    (1.5, HYSTERETIC, 0.08, 0.45),
])
def test_servohydraulic_targets_on_the_yielding_member(alpha, opts, limit, study):
    """Bouc-Wen defaults, embedded record at 1000 N: within the targets of issue 10 with the
    recommended controller; the study's loop shaping with the same compensator far off."""
    base = dict(YIELDING, alpha=alpha, amplitude_N=1000.0, **opts)
    assert nrms_x(dict(base, **TANGENT)) < limit
    assert nrms_x(base) > study


@pytest.mark.parametrize('alpha', [0.5, 2.0])
def test_delay_rig_target_on_the_yielding_member(alpha):
    """Pure-delay rig, Bouc-Wen defaults, 1000 N: the hysteretic compensator within 2 % up
    to alpha = 2 (measured 0.2-0.4 %); the elastic model's runs away there."""
    base = dict(YIELDING, rig_model='delay', alpha=alpha, amplitude_N=1000.0)
    assert nrms_x(dict(base, **HYSTERETIC)) < 0.02
    if alpha == 2.0:
        run = simulate(dict(base, predictor='model'))
        assert not run.stable


@pytest.mark.parametrize('predictor, rig, limit', [
    ('adaptive', 'delay', 0.015), ('adaptive', 'servohydraulic', 0.05),
    ('ats', 'delay', 0.12), ('ats', 'servohydraulic', 0.12)])
def test_adaptive_compensators_do_not_run_away_on_the_yielding_member(predictor, rig, limit):
    """Issue 10: every compensator with a specimen model takes the member's restoring force
    (predictor_restoring_force: hysteretic); at alpha = 2 on both rigs it stays stable (with
    the elastic k, adaptive and ats hit the stroke limit at every alpha from 0.5; measured
    with the member: adaptive 0.8 % delay / 2.8 % servohydraulic, ats 7.6 % / 7.5 %)."""
    base = dict(YIELDING, rig_model=rig, alpha=2.0, amplitude_N=1000.0, predictor=predictor,
                **(TANGENT if rig == 'servohydraulic' else {}))
    assert nrms_x(dict(base, predictor_restoring_force='hysteretic')) < limit
    assert not simulate(base).stable


@pytest.mark.parametrize('alpha, predictor', [(0.0, 'none'), (1.0, 'model'), (1.5, 'model')])
def test_linear_specimen_is_not_worse_with_the_scheduled_controller(alpha, predictor):
    """The linear specimen never leaves its elastic line, so the scheduled controller is
    specimen_loop_shaping, the study's rule for its own specimen (1, 17.14, 4003.8) where
    Eq. 3.1 rounds 4002: not worse than the study's (measured 2.42 / 0.37 / 0.51 % against
    2.48 / 0.40 / 0.58 %)."""
    base = dict(rig_model='servohydraulic', alpha=alpha, predictor=predictor,
                amplitude_N=1000.0)
    study = nrms_x(base)
    assert nrms_x(dict(base, **TANGENT)) < 1.05 * study


def test_hysteretic_compensator_records_the_member_model():
    run = simulate(dict(YIELDING, alpha=1.0, amplitude_N=1000.0, duration_s=4.0,
                        **HYSTERETIC, **TANGENT))
    est = run.estimates
    assert set(est) >= {'tangent_stiffness_N_per_m', 'hysteresis_yield_displacement_m'}
    # the guess is the member's: the identified model stays on it; the tangent falls to
    # the post-yield stiffness while the member yields
    assert est['hysteresis_stiffness_N_per_m'][-1] == pytest.approx(K, rel=0.01)
    assert est['hysteresis_yield_displacement_m'][-1] == pytest.approx(0.004, rel=0.05)
    assert np.min(est['tangent_stiffness_N_per_m']) < 0.2 * K
    assert math.isclose(est['tangent_stiffness_N_per_m'][0], K, rel_tol=1e-9)


@pytest.mark.parametrize('opts', [
    dict(predictor='adaptive'), dict(predictor='ats'),
    dict(predictor='model', predictor_restoring_force='measured'), dict(HYSTERETIC),
    dict(predictor='adaptive', predictor_restoring_force='hysteretic'),
    dict(predictor='ats', predictor_restoring_force='hysteretic')])
def test_every_compensator_with_estimates_names_them(opts):
    """The builder node records estimates under ESTIMATES (the batch's columns): it must list
    what estimates() returns, in order (the 'measured' option had none, so its graph run
    failed at the first reference force)."""
    from seft_ros.core.reference_force import make_predictor
    pred = make_predictor(parameters.resolve(dict(rig_model='delay', alpha=1.0, **opts)))
    assert tuple(pred.ESTIMATES) == tuple(pred.estimates())


@pytest.mark.parametrize('stiffness_N_per_m', [1.5e5, 2.5e5])
def test_member_of_another_stiffness_keeps_the_target(stiffness_N_per_m):
    """The scheduled controller cancels the rig's own specimen, (1, c/m, k/m), not the study's
    (1, 17.14, 4002): a member 29 % softer or 18 % stiffer than the study's, alpha = 1, 700 N,
    the first 5 s, `model` with the member's model, measured 1.60 / 1.69 % (with the study's
    denominator, session 23's D1: 16.2 / 10.7 %; the study's member 2.96 %)."""
    params = dict(YIELDING, **TANGENT, **HYSTERETIC, alpha=1.0, amplitude_N=700.0,
                  duration_s=5.0, stiffness_N_per_m=stiffness_N_per_m)
    assert nrms_x(params) < 0.025
