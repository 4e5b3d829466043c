"""The hysteretic compensator (``predictor_restoring_force: hysteretic``) and the member law of
``adaptive`` and ``ats`` (issue 10), without closed-loop runs: for a member that has not yielded
against the linear impulse-matching law (exact ZOH, itself checked against closed forms in
test_predictors_closed_forms.py), for a member that has against scipy's solve_ivp of the
plant's Bouc-Wen member (seft_plant_sim.specimen.BoucWenSpecimen) with the held-force law
solved by brentq, and ``adaptive``'s delay identification against a delay rig with a known
delay and gain. The member model itself: test_hysteresis.py."""

import math
import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.specimen import BoucWenSpecimen
from seft_ros.core.hysteresis import HYSTERESIS_ESTIMATES, HystereticMember, MemberGuess
from seft_ros.core.predictors import (
    ADAPTIVE_ESTIMATES,
    ATS_ESTIMATES,
    AdaptivePredictor,
    AtsPredictor,
    DelayImpulseModel,
    HystereticModelPredictor,
    ModelPredictor,
    TangentModelPredictor,
    _member_law,
    model_predictor,
)

M, K = 52.7, 2.11e5             # specimen of the reference study [kg, N/m]
C = 17.14 * M                   # its damping [N s/m]
A, DY, N = 0.1, 0.004, 2.0      # the default Bouc-Wen member (and guess)
DT = 0.002
#: The plant's member with the guess's parameters: its equations, coded independently.
PLANT = BoucWenSpecimen(M, C, K)


def member(identify=False):
    return HystereticMember(MemberGuess(M, C, K, A, DY, N), DT, identify=identify)


def meas(j, x, v, a, r):
    """The sensors' sample j of a member with restoring force r: f_m = m a + c v + r."""
    return Measurement(j, j * DT, x, v, a, M * a + C * v + r)


def loaded(pred, x_end=0.005, v=0.05):
    """Feed `pred`'s member the plant's member (the guess's own) loaded from rest along its
    virgin curve (z = tanh(x/D_y)) to x_end at v; return the last (x, v, z)."""
    for j in range(int(round(x_end / (v * DT))) + 1):
        x = j * v * DT
        pred.member.observe_measurement(meas(j, x, v, 0.0, float(
            PLANT.restoring_force(x, math.tanh(x / DY)))))
    return x, v, math.tanh(x / DY)


# -- the member that has not yielded: the linear law ----------------------------------------

@pytest.mark.parametrize('tau, alpha', [(0.0123, 1.0), (0.004, 0.5), (0.0, 1.7), (0.0193, 2.0)])
def test_a_member_that_has_not_yielded_is_the_linear_impulse_law(tau, alpha):
    """Until the member has shown that it yields it is carried elastically (dz/dx = 1/D_y),
    so with a measured restoring force k x (a linear spring up to z = 0.55, where the
    Bouc-Wen branch would be 30 % softer) the prediction is the linear model's with impulse
    matching, F = G - alpha m a_hat (exact ZOH; RK4 with 1 ms substeps: within 1e-6, or
    1e-5 m/s^2 where a_hat nearly cancels, against 1-10 m/s^2); the
    commands before t = 0 are rest, and without a sample the specimen is at rest."""
    rng = np.random.default_rng(7)
    hyst = HystereticModelPredictor(member(), alpha, M, DT, tau)
    lin = ModelPredictor(DelayImpulseModel(M, C, K, DT, tau), alpha, M, matching='impulse')
    commanded = list(rng.normal(0, 400.0, 30))
    g = rng.normal(0, 500.0)
    assert hyst.predict(None, [], g) == pytest.approx(lin.predict(None, [], g), rel=1e-6)
    assert hyst.predict(None, commanded) == pytest.approx(lin.predict(None, commanded),
                                                          rel=1e-6)     # G = 0 by default
    samples = [(2.0e-3, 0.05, 3.0), (2.2e-3, 0.06, -5.0), (1.9e-3, -0.2, 10.0),
               (-1.0e-3, -0.1, 0.0)]
    for j, (x, v, acc) in enumerate(samples):
        latest = meas(j, x, v, acc, K * x)
        past = commanded[:3 + 8 * j]
        g = rng.normal(0, 500.0)
        assert hyst.predict(latest, past, g) == pytest.approx(lin.predict(latest, past, g),
                                                              rel=1e-6, abs=1e-5)
    assert not hyst.member.has_yielded


def test_alpha_zero_feeds_nothing_back_but_the_member_observes():
    pred = HystereticModelPredictor(member(), 0.0, M, DT, 0.01)
    assert pred.predict(meas(0, 1e-3, 0.1, 0.0, K * 1e-3), [500.0] * 10, 300.0) == 0.0
    assert pred.member.displacement_m == 1e-3


# -- the member that has yielded: scipy's integration of the plant's member -----------------

def carry_ivp(state, forces, durations):
    """(x, v, z) of m x'' + c x' + r(x, z) = f, z' = the plant's Bouc-Wen rate, over the held
    forces (DOP853, rtol 1e-12)."""
    def rhs(_, s, f):
        x, v, z = s
        return [v, (f - C * v - PLANT.restoring_force(x, z)) / M, PLANT.hysteretic_rate(v, z)]

    for f, d in zip(forces, durations):
        if d > 0:
            state = solve_ivp(rhs, (0.0, d), state, args=(f,), method='DOP853', rtol=1e-12,
                              atol=1e-14).y[:, -1]
    return state


@pytest.mark.parametrize('held', [False, True])
@pytest.mark.parametrize('tau, alpha', [(0.0123, 1.0), (0.0, 2.0), (0.008, 0.5)])
def test_a_yielded_member_is_integrated_over_the_horizon(tau, alpha, held):
    """Loaded to 5 mm (z = 0.85), moving on at 0.05 m/s (or held at rest there: pushed on,
    it goes on loading, the branch of v >= 0) under 900-1350 N: the state at
    t_k + tau from the latest sample, carried by the forces already sent (the first over the
    fraction delta of tau = n dt + delta), then a_hat(F) = (v(t_k+1 + tau) - v(t_k + tau))/dt
    and F = G - alpha m a_hat(F) (paper Eq. 2.5, impulse matching) solved here by brentq:
    the predictor's RK4 (2 substeps a step) and its secant step within 1e-5."""
    pred = HystereticModelPredictor(member(), alpha, M, DT, tau)
    x, v, z = loaded(pred)
    if held:
        v = 0.0
        pred.member.observe_measurement(meas(0, x, v, 0.0, float(PLANT.restoring_force(x, z))))
    assert pred.member.has_yielded
    n, delta = int(tau // DT), tau - DT * int(tau // DT)
    commanded = list(900.0 + 50.0 * np.arange(n + 6) % 500.0)
    g = 1200.0
    got = pred.predict_observed(True, commanded, g)
    past = commanded[-(n + 2):]
    start = carry_ivp([x, v, z], past, [delta] + [DT] * (n + 1))

    def residual(force):
        return force - g + alpha * M * (carry_ivp(start, [force], [DT])[1] - start[1]) / DT

    force = brentq(residual, g - 5e4, g + 5e4, xtol=1e-10)
    assert got == pytest.approx((g - force) / (alpha * M), rel=1e-5)


def test_free_velocity_increment_is_the_members_free_step():
    """No force for one step: for a member that has not yielded, the velocity row of the
    exact ZOH (Phi - I) [x, v] (z = x/D_y on the elastic line); for one that has, scipy's
    integration of the plant's member."""
    pred = HystereticModelPredictor(member(), 1.0, M, DT, 0.01)
    phi = DelayImpulseModel(M, C, K, DT, 0.0).phi
    state = (1.5e-3, -0.08, 1.5e-3 / DY)
    assert pred.free_velocity_increment(state) == pytest.approx(
        float((phi - np.eye(2))[1] @ state[:2]), rel=1e-6)
    x, v, z = loaded(pred)
    assert pred.free_velocity_increment((x, v, z)) == pytest.approx(
        carry_ivp([x, v, z], [0.0], [DT])[1] - v, rel=1e-6)


def test_set_delay_splits_the_new_delay():
    pred = HystereticModelPredictor(member(), 1.0, M, DT, 0.01)
    assert (pred.delay_s, pred.n, pred.delta) == (0.01, 5, 0.0)
    pred.set_delay(0.0123)
    assert (pred.delay_s, pred.n) == (0.0123, 6)
    assert pred.delta == pytest.approx(0.0003, abs=1e-15)


@pytest.mark.parametrize('args', [(-0.1, M, DT, 0.0), (1.0, 0.0, DT, 0.0), (1.0, M, 0.0, 0.0),
                                  (1.0, M, DT, -0.001)])
def test_predictor_errors(args):
    with pytest.raises(ParameterError, match='^' + re.escape(
            'hysteretic predictor: expected alpha >= 0, m > 0, dt > 0 and tau >= 0, got '
            + ', '.join(repr(float(a)) for a in args)) + '$'):
        HystereticModelPredictor(member(), *args)
    assert HystereticModelPredictor(member(), 0.0, 0.5, DT, 0.0).mass_kg == 0.5


# -- construction from the parameters ---------------------------------------------------------

def params(**kw):
    return parameters.resolve(dict(dict(predictor='model', predictor_restoring_force='hysteretic',
                                        specimen_model='bouc_wen'), **kw))


def test_from_parameters_on_the_delay_rig():
    """The delay rig: tau = predictor_tau_s (0: tau_s), no loop inverse, the reference force's
    m; the member is the compensator's model (predictor_* where set) with the hysteresis_*
    guesses, identified online; its estimates are the member's."""
    p = params(rig_model='delay', alpha=1.3, tau_s=0.0123, predictor_stiffness_N_per_m=2.0e5,
               predictor_mass_kg=50.0, hysteresis_n=3.0)
    pred = model_predictor(p)
    assert isinstance(pred, HystereticModelPredictor)
    assert (pred.alpha, pred.mass_kg, pred.dt, pred.delay_s) == (1.3, M, DT, 0.0123)
    assert pred.loop_inverse is None and pred.command(321.0) == 321.0
    model = pred.member.model
    assert (model.stiffness_N_per_m, model.n, pred.member.mass_kg) == (2.0e5, 3.0, 50.0)
    assert pred.member.identifier is not None
    assert (pred.name, pred.step_average, pred.ESTIMATES) == ('model', True,
                                                              HYSTERESIS_ESTIMATES)
    assert pred.estimates() == pred.member.estimates()


def test_from_parameters_on_the_servohydraulic_rig_inverts_the_force_loop():
    """The loop inverse and its delay are those of the linear 'model' (ForceLoopInverse from
    the rig model): the same delay and the same commands."""
    p = params(rig_model='servohydraulic', alpha=1.0)
    pred = HystereticModelPredictor.from_parameters(p)
    linear = ModelPredictor.from_parameters(dict(p, predictor_restoring_force='model'))
    assert pred.delay_s == linear.delay_s > 0
    forces = np.random.default_rng(8).normal(0, 300.0, 60)
    np.testing.assert_array_equal([pred.command(f) for f in forces],
                                  [linear.command(f) for f in forces])


def test_model_predictor_picks_the_restoring_force():
    base = params(rig_model='delay', alpha=1.0)
    assert type(model_predictor(base)) is HystereticModelPredictor
    assert type(model_predictor(dict(base, predictor_restoring_force='measured'))) is \
        TangentModelPredictor
    assert type(model_predictor(dict(base, predictor_restoring_force='model'))) is \
        ModelPredictor
    assert type(model_predictor({k: v for k, v in base.items()
                                 if k != 'predictor_restoring_force'})) is ModelPredictor


@pytest.mark.parametrize('restoring', ['measured', 'hysteretic'])
def test_member_law_of_adaptive_and_ats(restoring):
    """'measured' and 'hysteretic' give adaptive and ats the member model (the compensator's
    m, c, k with the guesses) with the given delay and the reference force's m; 'model' (or
    none) the linear law (None)."""
    p = params(rig_model='delay', alpha=1.4, predictor_restoring_force=restoring,
               predictor_damping_N_s_per_m=800.0, hysteresis_yield_displacement_m=0.006)
    law = _member_law(p, 0.0086)
    assert isinstance(law, HystereticModelPredictor) and law.loop_inverse is None
    assert (law.alpha, law.mass_kg, law.dt, law.delay_s) == (1.4, M, DT, 0.0086)
    assert law.member.damping_N_s_per_m == 800.0
    assert law.member.model.yield_displacement_m == 0.006
    assert law.member.identifier is not None
    assert _member_law(dict(p, predictor_restoring_force='model'), 0.01) is None
    assert _member_law({k: v for k, v in p.items() if k != 'predictor_restoring_force'},
                       0.01) is None


# -- adaptive and ats with the member law -----------------------------------------------------

def run_on_the_member(pred, tau, gain, n, amplitude):
    """Open loop as test_predictors_closed_forms.run_on_delay_rig, on the Bouc-Wen member: a
    three-tone desired force through pred.command, applied by a delay rig (delay tau) as gain
    x command, each measurement into pred.predict. Returns the measurements and commands."""
    rig = DelayRig(BoucWenSpecimen(M, C, K), DT, tau)
    t = np.arange(n) * DT
    desired = amplitude * (np.sin(2 * np.pi * 3 * t) + np.sin(2 * np.pi * 7.3 * t + 1)
                           + 0.5 * np.sin(2 * np.pi * 13.1 * t + 2))
    seen, sent = [], []
    for j in range(n):
        seen.append(rig.measure())
        pred.predict(seen[-1], [], 0.0)
        sent.append(pred.command(desired[j]))
        rig.apply(gain * sent[-1])
    return seen, sent


def adaptive_with_law(tau0=0.01):
    law = HystereticModelPredictor(member(identify=True), 1.0, M, DT, tau0)
    return AdaptivePredictor(M, C, K, DT, tau0, 1.0, M, window_s=0.1, max_delay_s=0.02,
                             max_rate_per_s=20.0, member_law=law)


def test_adaptive_identifies_delay_and_gain_on_a_yielding_member():
    """Delay rig (tau 12.3 ms, actuator gain 0.9) with the default Bouc-Wen member driven to
    25-30 mm (6-7 D_y): with the member's free response taken out of the velocity
    increments, adaptive finds tau within 20 us and the gain within 0.3 %, its law uses that
    delay (to the dt/64 grid), and m, c, k stay the configured ones; the linear law's
    increments leave the fit rejected (quality below 0.995) and the prior in place."""
    pred = adaptive_with_law()
    seen, _ = run_on_the_member(pred, 0.0123, 0.9, 400, 900.0)
    assert max(abs(s.displacement_m) for s in seen) > 6 * DY
    assert pred.tau_s == pytest.approx(0.0123, abs=2e-5)
    assert pred.gain == pytest.approx(0.9, rel=3e-3)
    est = pred.estimates()
    assert (est['mass_kg'], est['damping_N_s_per_m'], est['stiffness_N_per_m']) == (M, C, K)
    assert abs(pred.model.tau_s - 0.0123) <= DT / 128 + 2e-5
    assert not pred.identify_specimen
    linear = AdaptivePredictor(M, C, K, DT, 0.01, 1.0, M, window_s=0.1, max_delay_s=0.02,
                               max_rate_per_s=20.0)
    run_on_the_member(linear, 0.0123, 0.9, 400, 900.0)
    assert linear.fit_quality < 0.995 and (linear.tau_s, linear.gain) == (0.01, 1.0)


def test_adaptive_predicts_with_the_member_over_its_delay_and_gain():
    """At every step of a run on the yielding member, adaptive's a_hat is the member law's
    with the delay and gain identified so far and the forces sent times that gain (a twin
    law whose member saw the same samples; the forces before t = 0 at rest); its estimates
    are the adaptive ones, then the member's."""
    pred = adaptive_with_law()
    twin = HystereticModelPredictor(member(identify=True), 1.0, M, DT, 0.01)
    rig = DelayRig(BoucWenSpecimen(M, C, K), DT, 0.0123)
    t = np.arange(300) * DT
    desired = 900.0 * (np.sin(2 * np.pi * 3 * t) + np.sin(2 * np.pi * 7.3 * t + 1))
    sent = []
    for j in range(300):
        latest = rig.measure()
        g = 200.0 * math.sin(j)
        got = pred.predict(latest, [], g)
        twin.set_delay(pred.model.tau_s)
        assert got == pytest.approx(twin.predict(latest, [pred.gain * f for f in sent], g),
                                    rel=1e-12, abs=1e-12), j
        sent.append(pred.command(desired[j]))
        rig.apply(0.9 * sent[-1])
    assert pred.gain != 1.0 and pred.model.tau_s != 0.01        # identified on the way
    assert tuple(pred.estimates()) == ADAPTIVE_ESTIMATES + HYSTERESIS_ESTIMATES
    assert {k: pred.estimates()[k] for k in HYSTERESIS_ESTIMATES} == pytest.approx(
        twin.estimates(), rel=1e-12)
    assert pred.predict(None, [], 0.0) == pytest.approx(
        twin.predict(None, [pred.gain * f for f in sent], 0.0), rel=1e-12)


def test_adaptive_from_parameters_takes_the_member_law():
    p = params(predictor='adaptive', rig_model='delay', alpha=1.0, tau_s=0.0086)
    pred = AdaptivePredictor.from_parameters(p)
    # ESTIMATES: the recorded columns (the builder node's), in the order of estimates()
    assert tuple(pred.estimates()) == pred.ESTIMATES == ADAPTIVE_ESTIMATES + HYSTERESIS_ESTIMATES
    assert not pred.identify_specimen
    plain = AdaptivePredictor.from_parameters(dict(p, predictor_restoring_force='model'))
    assert tuple(plain.estimates()) == plain.ESTIMATES == ADAPTIVE_ESTIMATES
    assert plain.identify_specimen


def test_ats_compensates_the_lag_with_the_member():
    """ats's one-step law is the member law with tau = 0: its a_hat is that of a twin
    HystereticModelPredictor (same samples, tau 0); its estimates are a0, a1, a2, then the
    member's."""
    p = params(predictor='ats', rig_model='delay', alpha=1.2)
    pred = AtsPredictor.from_parameters(p)
    twin = HystereticModelPredictor(HystereticMember(MemberGuess.from_parameters(p), DT), 1.2,
                                    M, DT, 0.0)
    commanded = []
    for j in range(60):
        x = j * 1e-4
        latest = meas(j, x, 0.05, 2.0, float(PLANT.restoring_force(x, math.tanh(x / DY))))
        got = pred.predict(latest, commanded, 40.0 * j)
        assert got == pytest.approx(twin.predict(latest, commanded, 40.0 * j), rel=1e-12)
        commanded.append(pred.command(1000.0 + 10.0 * j))
    assert twin.member.has_yielded
    assert tuple(pred.estimates()) == pred.ESTIMATES == ATS_ESTIMATES + HYSTERESIS_ESTIMATES
    assert [pred.estimates()[k] for k in ATS_ESTIMATES] == list(pred.coefficients)
    assert {k: pred.estimates()[k] for k in HYSTERESIS_ESTIMATES} == pytest.approx(
        twin.estimates(), rel=1e-12)
    plain = AtsPredictor.from_parameters(dict(p, predictor_restoring_force='model'))
    assert tuple(plain.estimates()) == plain.ESTIMATES == ATS_ESTIMATES
