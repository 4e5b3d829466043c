"""Tests of the delay compensators (``seft_ros.core.predictors``) against known answers."""

import os
import signal
import time

import numpy as np
import pytest
from scipy.signal import cont2discrete

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.parameters import spec
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.servohydraulic import ServoHydraulicParams
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.analysis.metrics import compare_run
from seft_ros.core import experiment
from seft_ros.core.controller import ForceServoController
from seft_ros.core.predictors import (
    AdaptivePredictor,
    AtsPredictor,
    DelayImpulseModel,
    ForceLoopInverse,
    ModelPredictor,
    PolynomialPredictor,
    foh_step_average,
    lagrange_extrapolation_weights,
    step_average_force_impulse_response,
)
from seft_ros.core.reference_force import (
    PREDICTORS,
    Predictor,
    RigReferenceForce,
    ground_window,
    make_predictor,
)

M, K = 52.7, 2.11e5
C = 17.14 * M
C_2PCT = 0.02 * 2 * np.sqrt(K * M)
DT = 0.002


def meas(k, x=0.0, v=0.0, a=0.0, f=0.0):
    return Measurement(k, k * DT, x, v, a, f)


def nrms_percent(**params):
    run = experiment.simulate(params)
    return 100 * compare_run(run).displacement.nrms, run


# -- building blocks against closed forms ---------------------------------------------------

@pytest.mark.parametrize('order', [1, 2, 3])
def test_lagrange_extrapolation_is_exact_for_polynomials(order):
    coeff = np.random.default_rng(order).standard_normal(order + 1)
    h = 6.5
    w = lagrange_extrapolation_weights(order, h)
    samples = np.polyval(coeff, -np.arange(order + 1.0))
    assert np.dot(w, samples) == pytest.approx(np.polyval(coeff, h), rel=1e-12, abs=1e-12)


def test_polynomial_predictor_extrapolates_tau_plus_one_and_a_half_steps():
    tau = 0.01
    p = PolynomialPredictor(DT, tau, order=2)
    acc = lambda t: 3.0 - 40.0 * t + 900.0 * t * t  # noqa: E731
    for k in range(5):
        got = p.predict(meas(k, a=acc(k * DT)), [])
    assert got == pytest.approx(acc(4 * DT + tau + 1.5 * DT), rel=1e-12)
    with pytest.raises(ParameterError, match=r'^parameter polynomial_order=4: expected 1, 2 '):
        PolynomialPredictor(DT, tau, order=4)


def test_foh_step_average_against_quadrature():
    y = np.random.default_rng(3).standard_normal(8)
    for shift in (0.0, 1.0, 2.4, 3.75):
        t = np.linspace(shift, shift + 1.0, 20001)
        exact = np.trapezoid(np.interp(t, np.arange(8.0), y), t)
        assert foh_step_average(y, shift) == pytest.approx(exact, abs=1e-8)


@pytest.mark.parametrize('tau', [0.01, 0.009, 0.0])
def test_model_prediction_of_a_free_vibration_is_the_closed_form(tau):
    """No force: s_hat is the damped free vibration tau + dt after the measurement."""
    model = DelayImpulseModel(M, C, K, DT, tau)
    x0, v0 = 0.01, -0.3
    s = model.state_ahead(x0, v0, np.zeros(model.n + 2))
    wn = np.sqrt(K / M)
    zeta = C / (2 * np.sqrt(K * M))
    wd = wn * np.sqrt(1 - zeta ** 2)
    t = tau + DT
    e = np.exp(-zeta * wn * t)
    x = e * (x0 * np.cos(wd * t) + (v0 + zeta * wn * x0) / wd * np.sin(wd * t))
    v = e * (v0 * np.cos(wd * t) - (x0 * wn ** 2 + zeta * wn * v0) / wd * np.sin(wd * t))
    np.testing.assert_allclose(s, [x, v], rtol=1e-10, atol=1e-14)


def test_model_prediction_of_the_forced_response_matches_the_delay_rig():
    """The model predicts exactly the delay rig's state under the forces it was sent."""
    tau = 0.0093
    rig = DelayRig(LinearSpecimen(M, C, K), DT, tau)
    model = DelayImpulseModel(M, C, K, DT, tau)
    forces = list(np.random.default_rng(5).standard_normal(40) * 300.0)
    states = []
    for f in forces:
        m = rig.measure()
        states.append((m.displacement_m, m.velocity_m_s))
        rig.apply(f)
    # prediction from step 20 (latest = 19) to t_20 + tau: compare with a fine-step rerun
    kk = 20
    s_hat = model.state_ahead(*states[kk - 1], np.array(forces[kk - 2 - model.n:kk]))
    a = np.array([[0.0, 1.0], [-K / M, -C / M]])
    b = np.array([[0.0], [1.0 / M]])
    h = 1e-6
    phi, gam, *_ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), h, 'zoh')
    s = np.array(states[kk - 1])
    t0 = (kk - 1) * DT
    for i in range(int(round((tau + DT) / h))):
        t = t0 + (i + 0.5) * h
        j = int(np.floor((t - tau) / DT))
        s = phi @ s + gam[:, 0] * (forces[j] if j >= 0 else 0.0)
    np.testing.assert_allclose(s_hat, s, rtol=1e-6, atol=1e-12)


def test_impulse_matching_solves_its_algebraic_loop():
    model = DelayImpulseModel(M, C, K, DT, 0.01)
    p = ModelPredictor(model, 1.7, M, matching='impulse')
    hist = list(np.random.default_rng(2).standard_normal(30) * 200.0)
    ground = -2.7 * M * 1.3
    a_hat = p.predict(meas(29, x=0.004, v=0.05), hist, ground)
    force = ground - 1.7 * M * a_hat
    s_hat = model.state_ahead(0.004, 0.05, np.array(hist[-(model.n + 2):]))
    r = (model.phi - np.eye(2))[1]
    # the step-average acceleration over the force's own interval, with that force
    assert a_hat == pytest.approx((r @ s_hat + model.q * force) / DT, rel=1e-12)


@pytest.mark.parametrize('tau', [0.01, 0.0093])
def test_pole_matching_prediction_is_the_gain_law(tau):
    """predict() (one precomputed row) equals F = beta G - K s_hat from its parts, also
    while fewer forces than the model needs were sent (rest before t = 0)."""
    model = DelayImpulseModel(M, C, K, DT, tau)
    alpha = 1.3
    p = ModelPredictor(model, alpha, M)
    gain, beta = model.matching_gains(alpha)
    rng = np.random.default_rng(6)
    hist = []
    for k in range(20):
        x, v, ground = rng.standard_normal() * 1e-3, rng.standard_normal() * 0.05, \
            rng.standard_normal() * 200.0
        past = np.array(([0.0] * (model.n + 2) + hist)[-(model.n + 2):])
        force = beta * ground - gain @ model.state_ahead(x, v, past)
        a_hat = p.predict(meas(k, x=x, v=v), hist, ground)
        assert a_hat == pytest.approx((ground - force) / (alpha * M), rel=1e-11, abs=1e-9)
        hist.append(rng.standard_normal() * 300.0)
    assert p.predict(meas(20), np.array(hist), 0.0) == pytest.approx(p.predict(meas(20), hist,
                                                                              0.0), rel=1e-15)


def test_force_loop_inverse_step_is_the_fir():
    y = np.zeros(100)
    y[3:8] = [0.1, 0.4, 0.3, 0.15, 0.03]
    inv = ForceLoopInverse(y, DT, 4, 12)
    f = np.random.default_rng(1).standard_normal(60) * 500.0
    got = [inv.step(v) for v in f.tolist()]
    np.testing.assert_allclose(got, np.convolve(inv.taps, f)[:60], rtol=0, atol=1e-12 * 500)


@pytest.mark.parametrize('alpha', [0.0, 0.5, 3.0])
def test_pole_matching_gives_the_sampled_reference_poles(alpha):
    model = DelayImpulseModel(M, C_2PCT, K, DT, 0.01)
    gain, beta = model.matching_gains(alpha)
    closed = model.phi - np.outer(model.gamma, gain)
    poles = np.sort_complex(np.linalg.eigvals(closed))
    ref = np.sort_complex(np.exp(np.roots([(1 + alpha) * M, C_2PCT, K]) * DT))
    np.testing.assert_allclose(poles, ref, rtol=1e-12)
    static = np.linalg.solve(np.eye(2) - closed, model.gamma)[0] * beta
    assert static == pytest.approx(1 / K, rel=1e-12)
    if alpha == 0.0:
        np.testing.assert_allclose(gain / [K, C_2PCT], 0.0, atol=1e-12)
        assert beta == pytest.approx(1.0, rel=1e-12)


def test_force_loop_inverse_makes_the_loop_a_delay_in_band():
    y = step_average_force_impulse_response(ServoHydraulicParams(), LinearSpecimen(M, C, K),
                                            ForceServoController(DT), 1000)
    assert y.sum() == pytest.approx(0.983, abs=1e-3)          # |T(0)| of the calibrated rig
    inv = ForceLoopInverse(y, DT, 10, 48)
    assert inv.band_error < 0.015 and inv.max_gain < 3.0
    f = np.array([1.0, 5.0, 10.0, 20.0])
    z = np.exp(2j * np.pi * f * DT)
    w_t = (np.polyval(inv.taps[::-1], 1 / z) * np.polyval(y[::-1], 1 / z))
    np.testing.assert_allclose(w_t, z ** -10, atol=0.015)


# -- registry and builder -------------------------------------------------------------------

def test_registry_schema_and_protocol():
    assert set(PREDICTORS) == set(spec('predictor').choices) \
        == {'none', 'polynomial', 'model', 'adaptive', 'ats'}
    for name in PREDICTORS:
        for rig in ('delay', 'servohydraulic'):
            from seft_msgs_py.parameters import resolve
            p = make_predictor(resolve({'predictor': name, 'rig_model': rig}))
            assert isinstance(p, Predictor) and p.name == name


def test_ground_window_pads_after_the_record():
    ag = [1.0, 2.0, 3.0]
    assert ground_window(ag.__getitem__, 1, 3, 3) == [2.0, 3.0, 0.0, 0.0]
    b = RigReferenceForce(1.0, M, ModelPredictor(DelayImpulseModel(M, C, K, DT, 0.01),
                                                     1.0, M), dt=DT, ground_preview=True)
    assert b.lookahead_steps == 6
    with pytest.raises(ParameterError, match=r'^ground window of 1 samples: expected 7'):
        b.step(0.5, None)


# -- closed-loop targets on the simulated rigs ----------------------------------------------

@pytest.mark.parametrize('alpha', [0.5, 1.0, 1.5, 2.0, 3.0])
def test_delay_rig_target_default_damping(alpha):
    err, run = nrms_percent(rig_model='delay', alpha=alpha, predictor='model')
    assert run.stable and err <= 0.5            # measured 0.03-0.08 %


@pytest.mark.parametrize('alpha', [0.5, 1.5, 3.0])
def test_delay_rig_target_two_percent_damping(alpha):
    err, run = nrms_percent(rig_model='delay', alpha=alpha, predictor='model',
                            damping_N_s_per_m=C_2PCT, stroke_limit_m=10.0, force_limit_N=1e9)
    assert run.stable and err <= 1.0            # measured 0.05-0.09 %
    # the lightly damped specimen takes the delay rig's 4 g accelerometer past its range in
    # every run (issue 39): counted; model's law does not feed the reading back
    assert run.extra['sensor_range']['']['samples']['acceleration'] > 50


@pytest.mark.parametrize('alpha', [1.0, 3.0])
def test_delay_rig_fractional_delay(alpha):
    err, run = nrms_percent(rig_model='delay', tau_s=0.0093, alpha=alpha, predictor='model')
    assert run.stable and err <= 0.5


@pytest.mark.parametrize('alpha, bound', [(0.5, 1.0), (1.0, 1.0), (1.5, 1.0), (2.0, 2.0)])
def test_servohydraulic_target(alpha, bound):
    """Within the valve's flow capacity (400 N): measured 0.42, 0.40, 0.58, 1.06 %."""
    err, run = nrms_percent(rig_model='servohydraulic', amplitude_N=400.0, alpha=alpha,
                            predictor='model')
    assert run.stable and err <= bound


def test_servohydraulic_full_amplitude_saturates_the_valve_beyond_alpha_half():
    err, run = nrms_percent(rig_model='servohydraulic', alpha=0.5, predictor='model')
    assert run.stable and err <= 3.0            # measured 2.5 %: brief valve saturation


@pytest.mark.parametrize('rig, amplitude', [('delay', 1000.0), ('servohydraulic', 400.0)])
def test_ground_preview_removes_the_lag(rig, amplitude):
    base = dict(rig_model=rig, amplitude_N=amplitude, alpha=1.0, predictor='model')
    # the preview is on by default since issue 7: switch it off for the lagging run
    lag = compare_run(experiment.simulate(dict(base, ground_preview=False))).displacement.lag_s
    assert lag > 0.009
    c = compare_run(experiment.simulate(dict(base, ground_preview=True)))
    assert abs(c.displacement.lag_s) < 0.001 and c.displacement.nrms < 0.01


@pytest.fixture
def made(monkeypatch):
    """The ``adaptive`` predictors that ``experiment.simulate`` makes, in order (a list)."""
    out = []

    def factory(params):
        out.append(AdaptivePredictor.from_parameters(params))
        return out[-1]

    monkeypatch.setitem(PREDICTORS, 'adaptive', factory)
    return out


def test_adaptive_identifies_a_fixed_fractional_delay(made):
    err, run = nrms_percent(rig_model='delay', tau_s=0.0123, alpha=1.0, predictor='adaptive')
    assert run.stable and err < 0.5
    assert made[0].tau_s == pytest.approx(0.0123, abs=2e-4)
    assert made[0].gain == pytest.approx(1.0, abs=0.01)


class DriftingDelayRig(DelayRig):
    """Delay rig whose delay drifts linearly from tau0 to tau1 over n steps (test only)."""

    def __init__(self, specimen, dt, tau0, tau1, n):
        super().__init__(specimen, dt, tau0)
        self.tau0, self.tau1, self.n = tau0, tau1, n
        self.past = []
        a, b = specimen.state_space()
        self._a, self._b = a, b
        self.cache = {}

    def _matrices(self, key):
        from seft_plant_sim.delay_rig import _zoh
        if key not in self.cache:
            delta = key * 1e-5
            self.cache[key] = (*_zoh(self._a, self._b, self.dt - delta),
                               *_zoh(self._a, self._b, delta))
        return self.cache[key]

    def tau(self, step):
        return self.tau0 + (self.tau1 - self.tau0) * min(step / self.n, 1.0)

    def _f(self, i):
        return self.past[i] if 0 <= i < len(self.past) else 0.0

    def _force_now(self):
        return self._f(int(np.floor((self.step * self.dt - self.tau(self.step)) / self.dt
                                    + 1e-9)))

    def apply(self, command):
        self.past.append(float(command))
        k = self.step
        tau = round(self.tau(k) / 1e-5) * 1e-5          # 10 us grid: cached matrices
        n = int(np.floor(tau / self.dt + 1e-9))
        delta = tau - n * self.dt
        phi_rest, g_late, phi_d, g_e = self._matrices(round(delta / 1e-5))
        self._state = (phi_rest @ (phi_d @ self._state + g_e[:, 0] * self._f(k - n - 1))
                       + g_late[:, 0] * self._f(k - n))
        self.step += 1


def test_adaptive_tracks_a_drifting_delay(monkeypatch, made):
    """tau drifts from 8 to 12 ms over the first 8 s; the estimate follows it."""
    rig = DriftingDelayRig(LinearSpecimen(M, C, K), DT, 0.008, 0.012, 4000)
    monkeypatch.setattr(experiment, 'make_rig', lambda params: rig)
    run = experiment.simulate(dict(rig_model='delay', alpha=1.0, predictor='adaptive'))
    assert run.stable
    est = {j: tau for j, tau, *_ in made[0].history_tau_s}
    for step in (1000, 2000, 3000, 4000, 4900):
        j = min(est, key=lambda i: abs(i - step))
        assert est[j] == pytest.approx(rig.tau(j), abs=5e-4), step


# -- adaptive: the specimen, the delay and the gain identified online (issue 7) -------------

NOISE = {'noise_force_N': 5.0, 'noise_displacement_m': 1e-5, 'noise_velocity_m_s': 1e-4,
         'noise_acceleration_m_s2': 0.05}      # benchmarks/compensation_targets.py NOISE
WRONG = {'m': ('predictor_mass_kg', M), 'c': ('predictor_damping_N_s_per_m', C),
         'k': ('predictor_stiffness_N_per_m', K), 'tau': ('predictor_tau_s', 0.01)}


def wrong_model(names, sign):
    return {WRONG[n][0]: WRONG[n][1] * (1 + 0.1 * sign) for n in names}


def adaptive(**kwargs):
    args = dict(mass_kg=M, damping_N_s_per_m=C, stiffness_N_per_m=K, dt=DT, tau0_s=0.01,
                alpha=1.0, mass_ref_kg=M)
    args.update(kwargs)
    return AdaptivePredictor(**args)


def feed(pred, n, *, mass=M, damping=C, stiffness=K, amplitude=1e-3, start=0):
    """Measurements of a specimen (m, c, k) in a two-tone motion of `amplitude` [m]."""
    for j in range(start, start + n):
        t = j * DT
        w1, w2 = 2 * np.pi * 3.0, 2 * np.pi * 11.0
        x = amplitude * (np.sin(w1 * t) + 0.5 * np.sin(w2 * t))
        v = amplitude * (w1 * np.cos(w1 * t) + 0.5 * w2 * np.cos(w2 * t))
        a = -amplitude * (w1 ** 2 * np.sin(w1 * t) + 0.5 * w2 ** 2 * np.sin(w2 * t))
        f = mass * a + damping * v + stiffness * x
        pred.predict(Measurement(j, t, x, v, a, f), [], 0.0)
        pred.command(f)


def test_adaptive_identification_converges_on_a_known_specimen():
    """m, c, k of a specimen 20 % off the prior (two-tone motion, no noise): within 0.1 %."""
    pred = adaptive(mass_kg=1.2 * M, damping_N_s_per_m=0.8 * C, stiffness_N_per_m=1.2 * K)
    feed(pred, 1500)
    est = pred.estimates()
    assert set(est) == set(AdaptivePredictor.ESTIMATES)
    assert est['mass_kg'] == pytest.approx(M, rel=1e-3)
    assert est['damping_N_s_per_m'] == pytest.approx(C, rel=1e-3)
    assert est['stiffness_N_per_m'] == pytest.approx(K, rel=1e-3)


def test_adaptive_holds_its_estimates_on_quiet_input():
    """Motion whose force RMS stays below adaptive_excitation_N moves nothing."""
    pred = adaptive(mass_kg=1.1 * M, excitation_N=20.0)
    feed(pred, 2000, amplitude=2e-5)                # force RMS ~ 10 N
    assert pred.estimates() == pytest.approx({**pred.prior})
    assert pred.rls.updates == 0 and pred.history_tau_s == []


def test_adaptive_estimates_are_bounded_and_rate_limited():
    """A specimen of twice the mass: the estimate rises at the rate limit, stops at the bound."""
    pred = adaptive(max_deviation=0.3, max_rate_per_s=0.5)
    history = []
    for block in range(40):
        feed(pred, 50, mass=2 * M, start=50 * block)
        history.append(pred.estimates()['mass_kg'])
    steps = np.diff([M] + history)
    assert np.all(steps <= 0.5 * M * 50 * DT * (1 + 1e-9))   # at most 50 %/s of m0
    assert max(history) == pytest.approx(1.3 * M)             # and never above m0 (1 + 0.3)


@pytest.mark.parametrize('name, value, message', [
    ('excitation_N', -1.0, r'^parameter adaptive_excitation_N=-1.0: out of range'),
    ('max_deviation', 1.0, r'^parameter adaptive_max_deviation=1.0: out of range'),
    ('max_rate_per_s', 0.0, r'^parameter adaptive_max_rate_per_s=0.0: out of range'),
    ('window_s', 0.0, r'^parameter adaptive_window_s=0.0: out of range'),
])
def test_adaptive_parameter_errors(name, value, message):
    with pytest.raises(ParameterError, match=message):
        adaptive(**{name: value})


@pytest.mark.parametrize('names, sign, alpha', [
    (('m', 'c', 'k', 'tau'), +1, 0.5), (('m', 'c', 'k', 'tau'), -1, 0.5),
    (('m', 'c', 'k', 'tau'), +1, 1.0), (('m', 'c', 'k', 'tau'), -1, 1.0),
    (('m', 'c', 'k', 'tau'), +1, 2.0), (('m', 'c', 'k', 'tau'), -1, 2.0),
    (('m',), -1, 2.0), (('c',), +1, 2.0), (('k',), +1, 2.0), (('tau',), -1, 1.5),
])
def test_adaptive_delay_rig_target_with_a_wrong_model(names, sign, alpha):
    """Issue 7: every +/-10 % error, sensor noise on, delay rig: <= 0.5 % for alpha <= 2
    (``model`` gives 3-43 % here; measured with ``adaptive``: 0.17-0.49 %)."""
    err, run = nrms_percent(rig_model='delay', alpha=alpha, predictor='adaptive',
                            **NOISE, **wrong_model(names, sign))
    assert run.stable and err <= 0.5
    # at alpha 2 the delay rig's 4 g accelerometer reads its range in a sample or few:
    # counted, and skipped by the identification (issue 39)
    at_range = run.extra['sensor_range']['']['samples']['acceleration']
    assert (at_range > 0) == (alpha == 2.0) and at_range < 20


def test_adaptive_estimates_converge_within_two_seconds_of_strong_motion():
    """All four +10 % wrong; after 2 s of strong motion every estimate is within 2 %."""
    run = experiment.simulate(dict(rig_model='delay', alpha=1.0, predictor='adaptive',
                                   **NOISE, **wrong_model(('m', 'c', 'k', 'tau'), +1)))
    est = run.estimates
    assert set(est) == set(AdaptivePredictor.ESTIMATES)
    assert est['mass_kg'][0] == pytest.approx(1.1 * M)       # starts at the configured model
    f = run.measured_force_N
    rms = np.sqrt(np.convolve(f * f, np.ones(250) / 250, mode='same'))
    strong = int(np.argmax(rms > 100.0))                      # 0.5 s on the default record
    end = strong + int(2.0 / DT)
    for name, truth in (('mass_kg', M), ('damping_N_s_per_m', C), ('stiffness_N_per_m', K),
                        ('tau_s', 0.01)):
        assert np.max(np.abs(est[name][end:] / truth - 1)) < 0.02, name


def test_adaptive_identifies_a_stiff_specimen_before_its_prior_law_drives_the_test():
    """A 32 Hz specimen (40 kg, 0.5 % damping) whose model is 20 % off (k x 1.2, m x 0.8),
    alpha 1, delay rig, 200 N, 4 s. The prior law drives the test unstable from its first
    samples; the specimen's regression takes measured signals alone, so m, c and k are
    identified from 0.05 of the delay fit's level (here 0.2 N) at 5 of their values a second
    (measured: NRMS x 1.06 %, a 3.30 %, f 0.92 %). With one level and one rate for every
    estimate (the behaviour until 2026-11-27) the prior law ran until the force passed 4 N:
    105 %."""
    m = 40.0
    k = m * (2 * np.pi * 32.0) ** 2
    base = dict(rig_model='delay', alpha=1.0, predictor='adaptive', duration_s=4.0,
                amplitude_N=200.0, mass_kg=m, stiffness_N_per_m=k,
                damping_N_s_per_m=2 * 0.005 * np.sqrt(k * m),
                predictor_stiffness_N_per_m=1.2 * k, predictor_mass_kg=0.8 * m)
    run = experiment.simulate(base)
    c = compare_run(run)
    assert run.stable
    assert 100 * c.displacement.nrms < 2 and 100 * c.acceleration.nrms < 5
    assert 100 * c.force.nrms < 2
    # m and k are at the specimen's within 1 % after the first second
    est, i = run.estimates, int(1.0 / DT)
    assert np.max(np.abs(est['stiffness_N_per_m'][i:] / k - 1)) < 0.01
    assert np.max(np.abs(est['mass_kg'][i:] / m - 1)) < 0.01
    one_gate, _ = nrms_percent(**base, adaptive_specimen_excitation_ratio=1.0,
                               adaptive_specimen_max_rate_per_s=1.0)
    assert one_gate > 50


def test_adaptive_servohydraulic_stays_stable_at_alpha_two_with_a_wrong_model():
    err, run = nrms_percent(rig_model='servohydraulic', alpha=2.0, predictor='adaptive',
                            **NOISE, **wrong_model(('m', 'c', 'k'), +1))
    assert run.stable and err <= 3.0


def test_adaptive_delay_fit_on_a_narrow_band_motion_with_sensor_noise(tmp_path):
    """A 3 Hz ground pulse (1.5 s, then the free vibration): the velocity increments' window
    is narrow-band, where two neighbouring commanded forces are nearly collinear. Unconstrained,
    the delay fit took a neighbouring whole step and extrapolated (g_e / (g_e + g_l) outside
    [0, 1]), with the sensor noise choosing which: 8.7 % at alpha 1.5, the gain estimate 2.6 %
    off. With g_e, g_l >= 0: 1.76 %, the gain within 0.7 % (noise-free 0.34 %, was 0.51 %)."""
    dt = 0.005
    t = np.arange(0.0, 6.0, dt)
    pulse = np.where(t < 1.5, np.sin(2 * np.pi * 3.0 * t) * np.sin(np.pi * t / 1.5) ** 2, 0.0)
    record = tmp_path / 'pulse.csv'
    np.savetxt(record, np.c_[t, pulse], delimiter=',')
    common = dict(record=str(record), alpha=1.5, rig_model='servohydraulic',
                  predictor='adaptive', amplitude_N=150.0)
    clean, _ = nrms_percent(**common)
    err, run = nrms_percent(**common, **NOISE)
    assert clean < 1.0
    assert run.stable and err < 3.0
    gain = run.estimates['gain']
    assert np.max(np.abs(gain - 1.0)) < 0.01


def test_adaptive_data_loop_starts_at_the_model_inverse():
    """adaptive_loop 'data' before any data: the model compensator's inverse (1e-9)."""
    from seft_ros.core.predictors import ForceLoopInverse, IdentifiedForceLoop
    params = parameters.resolve({'rig_model': 'servohydraulic', 'predictor': 'adaptive',
                                 'adaptive_loop': 'data'})
    pred = AdaptivePredictor.from_parameters(params)
    assert isinstance(pred.loop_identification, IdentifiedForceLoop)
    assert pred.ESTIMATES[-3:] == ('loop_gain', 'loop_delay_s', 'loop_change')
    assert list(pred.estimates()) == list(pred.ESTIMATES)
    model = ForceLoopInverse.from_parameters(params)
    assert np.max(np.abs(pred.loop_inverse.taps - model.taps)) < 1e-9


def test_adaptive_data_loop_holds_on_quiet_input():
    """Measured force below adaptive_excitation_N: no loop update, the same inverse."""
    params = parameters.resolve({'rig_model': 'servohydraulic', 'predictor': 'adaptive',
                                 'adaptive_loop': 'data'})
    pred = AdaptivePredictor.from_parameters(params)
    before = pred.estimates()
    inverse = pred.loop_inverse
    feed(pred, 1000, amplitude=2e-5)                # force RMS ~ 10 N
    assert pred.loop_identification.identifier.rls.updates == 0
    assert pred.loop_inverse is inverse and pred.estimates() == before


@pytest.mark.parametrize('names, sign, alpha, bound', [
    (('m',), -1, 0.5, 2.0), (('m', 'c', 'k'), +1, 1.5, 2.0), (('m', 'c', 'k'), -1, 2.0, 3.0),
])
def test_adaptive_data_loop_servohydraulic_targets(names, sign, alpha, bound):
    """Issue 7 on the servohydraulic rig with the loop from data: <= 2 % for alpha <= 1.5,
    stable at 2 (measured 0.6-1.1 %); the loop estimates within 2 % of the true loop's
    after 2 s of strong motion."""
    run = experiment.simulate(dict(rig_model='servohydraulic', alpha=alpha,
                                   predictor='adaptive', adaptive_loop='data', **NOISE,
                                   **wrong_model(names, sign)))
    assert run.stable and 100 * compare_run(run).displacement.nrms <= bound
    from seft_ros.core.predictors import IdentifiedForceLoop
    truth = IdentifiedForceLoop.from_parameters(parameters.resolve(
        {'rig_model': 'servohydraulic'})).estimates()
    f = run.measured_force_N
    rms = np.sqrt(np.convolve(f * f, np.ones(250) / 250, mode='same'))
    end = int(np.argmax(rms > 100.0)) + int(2.0 / DT)
    for name in ('loop_gain', 'loop_delay_s'):
        assert np.max(np.abs(run.estimates[name][end:] / truth[name] - 1)) < 0.02, name


@pytest.mark.parametrize('declared_s', [0.0015, 0.0045])
def test_adaptive_identifies_an_io_latency_declared_half_or_one_and_a_half_times_off(declared_s):
    """adaptive_loop 'model_latency': the servohydraulic rig's 3 ms I/O latency declared as
    1.5 ms or 4.5 ms (the loop's equivalent delay off by about 10 % over 1-5 Hz, 30-70 % over
    5-20 Hz): the latency fitted from command and measured force (the rig simulated by
    seft_plant_sim, sensor noise on) is within dt / 10 = 0.2 ms of the truth from 4 s after
    strong motion starts (measured: 0.08 and 0.15 ms at most, the sensor noise's spread),
    and the test within 2 %; with the declared latency kept (``adaptive_loop: model``) the
    same test is at least twice as far off."""
    truth_s = ServoHydraulicParams().io_latency_s
    common = dict(rig_model='servohydraulic', alpha=1.0, predictor='adaptive',
                  predictor_io_latency_s=declared_s, duration_s=12.0, **NOISE)
    err, run = nrms_percent(adaptive_loop='model_latency', **common)
    latency = run.estimates['loop_latency_s']
    assert latency[0] == pytest.approx(declared_s)              # starts at the declaration
    f = run.measured_force_N
    rms = np.sqrt(np.convolve(f * f, np.ones(250) / 250, mode='same'))
    settled = int(np.argmax(rms > 100.0)) + int(4.0 / DT)
    assert np.max(np.abs(latency[settled:] - truth_s)) < DT / 10
    assert run.stable and err <= 2.0
    err_declared, _ = nrms_percent(adaptive_loop='model', **common)
    assert err_declared > 2 * err


def test_adaptive_with_the_latency_fitted_holds_the_delay_fit_and_equals_model():
    """adaptive_loop 'model_latency' (the loop refitted with the identified specimen and I/O
    latency) holds the delay and gain fit ('auto'): on a fast record (the embedded one at
    time scale 0.3, 1000 N, alpha 1) with the exact specimen the held-force regression read
    its own bias as a loop error (19.96-20.27 ms and 0.993-1.000 against the inverse's 20 ms
    and 1) and cost 1.88 % against model's 0.39 %; held, adaptive is within 0.05 points of
    model. With a yielding member's law the latency is not fitted and the delay fit stays."""
    from seft_ros.core.predictors import adaptive_fits_loop, adaptive_loop_mode
    common = dict(rig_model='servohydraulic', alpha=1.0, record='default', time_scale=0.3,
                  amplitude_N=1000.0)
    params = parameters.resolve(dict(common, predictor='adaptive',
                                     adaptive_loop='model_latency'))
    assert not adaptive_fits_loop(params)
    assert adaptive_fits_loop(dict(params, predictor_restoring_force='hysteretic'))
    assert adaptive_fits_loop(dict(params, adaptive_loop='model'))
    assert adaptive_fits_loop(dict(params, adaptive_loop_fit='fit'))
    assert adaptive_loop_mode(params) == 'model_latency'
    assert adaptive_loop_mode(parameters.resolve(dict(common, predictor='adaptive'))) == (
        'model_latency')                                          # the default, 'auto'
    plant = ('{"form": "transfer_function", "dt": 0.002, "num": {"force_N": [0, 1]}, '
             '"den": [1, -0.5], "specimen": {"mass_kg": 52.7, "stiffness_N_per_m": 211000, '
             '"damping_N_s_per_m": 903.3}}')
    assert adaptive_loop_mode(dict(params, adaptive_loop='auto', plant_model=plant)) == 'data'
    run = experiment.simulate(params)
    assert run.stable
    assert np.ptp(run.estimates['tau_s']) == 0.0 and np.all(run.estimates['gain'] == 1.0)
    err = 100 * compare_run(run).displacement.nrms
    err_model, _ = nrms_percent(predictor='model', **common)
    assert err == pytest.approx(err_model, abs=0.05) and err < 0.6


def test_latency_fit_recovers_the_latency_of_its_own_model_exactly():
    """LoopLatencyFit on noise-free data made by its own model with a 2.6 ms latency (the
    declared 1 ms): the fit returns 2.6 ms to its tolerance, dt / 200."""
    from dataclasses import replace

    from seft_ros.core.predictors import LoopLatencyFit, force_loop_impulse_responses
    params = parameters.resolve({'rig_model': 'servohydraulic'})
    ctrl = ForceServoController.from_parameters(params)
    rig = replace(ServoHydraulicParams.from_parameters(params), io_latency_s=0.001)
    spec = LinearSpecimen(M, C, K)
    fit = LoopLatencyFit(rig, ctrl, 0.001)
    h = force_loop_impulse_responses(replace(rig, io_latency_s=0.0026), spec, ctrl,
                                     fit.n).sampled
    rng = np.random.default_rng(3)
    u = 500.0 * rng.standard_normal(fit.window + fit.n)
    y = np.convolve(u, h)[:u.shape[0]]
    for j in range(u.shape[0]):
        fit.record(u[j])
        due = fit.observe(j, y[j], True)
    assert due
    assert fit.fit(u.shape[0] - 1, spec)
    assert fit.latency_s == pytest.approx(0.0026, abs=DT / 200)
    assert fit.estimates() == {'loop_latency_s': fit.latency_s}
    # the impulse responses are tabulated once per specimen (within 1 %) and interpolated:
    # the search equals a search of the exact residual, computed at each candidate
    from scipy.optimize import minimize_scalar
    table = fit._table
    noisy = y[-fit.window:] + 2.0 * rng.standard_normal(fit.window)
    near = LinearSpecimen(M, C, 1.005 * K)
    found, res = fit.search(near, u[-(fit.window + fit.n - 1):], noisy)
    assert fit._table is table
    exact = minimize_scalar(fit.residual, bounds=fit.bounds_s, method='bounded',
                            args=(spec, u[-(fit.window + fit.n - 1):], noisy),
                            options={'xatol': DT / 1000})
    assert found == pytest.approx(exact.x, abs=fit.resolution_s)
    assert res == pytest.approx(exact.fun, rel=1e-3)
    fit.search(LinearSpecimen(M, C, 1.02 * K), u[-(fit.window + fit.n - 1):], noisy)
    assert fit._table is not table


def test_adaptive_delay_fit_takes_no_increment_across_a_missing_sample():
    """Real time: a measurement that never arrived leaves a gap; the velocity change across it
    is two steps' and must not enter the one-step delay regression (lockstep: no gap, every
    sample gives its row)."""
    pred = adaptive()
    feed(pred, 100)
    rows = len(pred._rows)
    assert rows == 99                                    # one per consecutive pair
    feed(pred, 1, start=101)                             # sample 100 missing
    assert len(pred._rows) == rows
    feed(pred, 1, start=102)
    assert len(pred._rows) == rows + 1


def test_latency_fit_takes_no_window_with_a_late_reference():
    """Real time: four commands held (the controller extrapolated a late reference) in the
    window of noise-free data with a 2.6 ms latency bias the fit (2.66 ms, six times its
    resolution); told of them (``disturbed``, what the builder node does
    for a late reference), it fits the window after their response and returns 2.6 ms to
    its tolerance; with the disturbance too close to the newest sample no fit is made."""
    from dataclasses import replace

    from seft_ros.core.predictors import LoopLatencyFit, force_loop_impulse_responses
    params = parameters.resolve({'rig_model': 'servohydraulic'})
    ctrl = ForceServoController.from_parameters(params)
    rig = replace(ServoHydraulicParams.from_parameters(params), io_latency_s=0.001)
    spec = LinearSpecimen(M, C, K)
    h = force_loop_impulse_responses(replace(rig, io_latency_s=0.0026), spec, ctrl, 128).sampled
    rng = np.random.default_rng(5)
    n_total = 500 + 128 + 200
    u = 500.0 * rng.standard_normal(n_total)
    held = list(range(n_total - 330, n_total - 326))
    applied = u.copy()
    for j in held:
        applied[j] = applied[j - 1]
    y = np.convolve(applied, h)[:n_total]
    found = {}
    for report in (False, True):
        fit = LoopLatencyFit(rig, ctrl, 0.001)
        for j in range(n_total):
            fit.record(u[j])
            if report and j in held:
                fit.disturbed(j)
            fit.observe(j, y[j], True)
        assert fit.fit(n_total - 1, spec)
        found[report] = fit.latency_s
    assert abs(found[False] - 0.0026) > fit.resolution_s, found
    assert found[True] == pytest.approx(0.0026, abs=fit.resolution_s)
    fit.disturbed(n_total - 100)                          # 28 clean samples left: no window
    assert fit.window_data() is None


class StallingRig(DelayRig):
    """Delay rig whose command is held over stalls (test only): at the samples of `stalls` it
    applies the last command it had before, as a force servo-controller acting on its
    extrapolation of a late reference force does; with `predictor` (a list whose first item
    is the predictor), it is told (what the builder node does for a reference force more
    than two periods late)."""

    def __init__(self, specimen, dt, tau_s, stalls, predictor=None):
        super().__init__(specimen, dt, tau_s)
        self.stalls, self.predictor, self.held = set(stalls), predictor, 0.0

    def apply(self, command):
        if self.step in self.stalls:
            if self.predictor is not None:
                self.predictor[0].reference_late(self.step)
            command = self.held
        self.held = command
        super().apply(command)


def test_adaptive_delay_fit_takes_no_row_of_a_late_reference_force(monkeypatch, made):
    """Real time: five stalls of six periods in the strong motion, the rig's force held
    meanwhile (not the force the predictor sent). Regressed on the sent forces, the stalls move
    the gain estimate (measured 0.992-1.004; 1.082 for 0.5-1 s on the bridge over three
    emulated hosts, where the servohydraulic rig's force rang); told of the late references,
    the delay fit skips their rows and the delay and the gain stay where they were (exact)."""
    stalls = [s + i for s in (1250, 1400, 1600, 2000, 2500) for i in range(6)]
    params = dict(rig_model='delay', tau_s=0.0123, alpha=1.0, predictor='adaptive')
    ranges = {}
    for report in (False, True):
        made.clear()
        rig = StallingRig(LinearSpecimen(M, C, K), DT, 0.0123, stalls, made if report else None)
        monkeypatch.setattr(experiment, 'make_rig', lambda params, rig=rig: rig)
        run = experiment.simulate(params)
        assert run.stable
        gain, tau = run.estimates['gain'], run.estimates['tau_s']
        ranges[report] = (np.ptp(gain), np.ptp(tau))
        assert len(made[0].history_tau_s) > 400          # fits go on between the stalls
    assert ranges[False][0] > 5e-3                       # the stalls moved the gain
    assert ranges[True][0] < 1e-6 and ranges[True][1] < 1e-9, ranges


class _HeldFits:
    """BackgroundFits stand-in whose fits run only when released (a slow worker thread)."""

    def __init__(self):
        self.queued = []

    def submit(self, fn, *args):
        from concurrent.futures import Future
        future = Future()
        self.queued.append((future, fn, args))
        return future

    def release(self):
        for future, fn, args in self.queued:
            future.set_result(fn(*args))
        self.queued = []


def test_adaptive_refits_in_the_background_and_installs_them_when_done():
    """Real time (run_fits_in_background): the step goes on with the last force-loop inverse
    while the refit for the identified specimen runs; the first step after it is done installs
    it, its filter state carried over, the same taps as the refit in the step
    (``seft simulate``) for the same estimates. The delay fit's table for the new specimen
    (adaptive_loop 'model' fits the delay) is made there too, and taken in with the step's
    numbers."""
    from seft_ros.core.predictors import ForceLoopInverse, _fraction_table
    params = parameters.resolve({'rig_model': 'servohydraulic', 'predictor': 'adaptive',
                                 'adaptive_loop': 'model',
                                 'predictor_stiffness_N_per_m': 1.2 * K})
    pred = AdaptivePredictor.from_parameters(params)
    fits = _HeldFits()
    pred.run_fits_in_background(fits)
    first = pred.loop_inverse
    table = pred._frac_grid
    feed(pred, 1500)
    assert [fn for _, fn, _ in fits.queued] == [pred._loop_factory, _fraction_table]
    assert pred.loop_inverse is first and pred._frac_grid is table    # one of each at a time
    m, c, k = fits.queued[0][2]                                       # adaptive_loop: model
    assert k < 1.19 * K                                                # the estimate moved
    model = fits.queued[1][2]
    fits.release()
    feed(pred, 1, start=1500)
    assert pred.loop_inverse is not first and pred.loop_inverse._x is first._x
    assert pred._frac_model == model[:3]
    assert np.array_equal(pred._frac_grid, _fraction_table(*model)[0])
    exact = ForceLoopInverse.from_parameters(dict(
        params, predictor_mass_kg=m, predictor_damping_N_s_per_m=c, predictor_stiffness_N_per_m=k))
    assert np.array_equal(pred.loop_inverse.taps, exact.taps)


class _Count:
    """A stateful fit stand-in: the count of its calls (BackgroundFits keeps it in its worker)."""

    def __init__(self):
        self.calls = 0

    def __call__(self, step):
        self.calls += 1
        return os.getpid(), self.calls, step


def test_background_fits_run_in_a_worker_process_with_the_steps_numbers():
    """BackgroundFits (real time) runs each fit in one worker process, not in the node's
    (whose interpreter lock the long numpy/scipy calls would hold): the force-loop refit there
    gives the taps of the refit in the step bit for bit; a callable is sent once and keeps its
    state in the worker; the fit's ParameterError comes back as itself; a worker that ended
    is a SeftError naming it, not a traceback."""
    from seft_msgs_py.errors import SeftError
    from seft_ros.core.predictors import BackgroundFits, fit_result
    params = parameters.resolve({'rig_model': 'servohydraulic', 'predictor': 'adaptive'})
    pred = AdaptivePredictor.from_parameters(params)
    est = pred.estimates()
    args = (est['mass_kg'], est['damping_N_s_per_m'], 1.1 * est['stiffness_N_per_m'], 0.0012)
    fits = BackgroundFits()
    try:
        fits.start()
        remote = fit_result(fits.submit(pred._loop_factory, *args))
        local = pred._loop_factory(*args)
        assert np.array_equal(remote.taps, local.taps) and remote.taps.shape == (48,)
        x = list(np.random.default_rng(1).standard_normal(remote.taps.shape[0]))
        assert remote._fir(x) == local._fir(x)                 # the filter rebuilt from taps
        count = _Count()
        got = [fit_result(fits.submit(count, j)) for j in range(3)]
        assert [g[1:] for g in got] == [(1, 0), (2, 1), (3, 2)] and count.calls == 0
        worker = got[0][0]
        assert worker != os.getpid() and {g[0] for g in got} == {worker}
        with pytest.raises(ParameterError, match='cannot be inverted'):
            fit_result(fits.submit(pred._loop_factory, est['mass_kg'], 100.0,
                                   est['stiffness_N_per_m']))
        pending = fits.submit(time.sleep, 30.0)
        os.kill(worker, signal.SIGKILL)
        with pytest.raises(SeftError, match="fits' worker process ended"):
            fit_result(pending)
        with pytest.raises(SeftError, match="fits' worker process has ended"):
            fits.submit(count, 3)
    finally:
        fits.shutdown()


# -- ats ------------------------------------------------------------------------------------

def ats(**kwargs):
    return AtsPredictor(DelayImpulseModel(M, C, K, DT, 0.0), 1.0, M, 0.01, **kwargs)


def test_ats_command_is_the_time_series_by_hand():
    pred = ats()
    a0, a1, a2 = pred.coefficients
    assert (a0, a1, a2) == (1.0, 0.01, pytest.approx(5e-5))
    forces = [10.0, 30.0, 20.0, -5.0]
    out = [pred.command(f) for f in forces]
    past = [0.0, 0.0] + forces
    for i, u in enumerate(out):
        f, f1, f2 = past[i + 2], past[i + 1], past[i]
        assert u == pytest.approx(a0 * f + a1 * (f - f1) / DT + a2 * (f - 2 * f1 + f2) / DT ** 2)
    assert pred.estimates() == {'a0': a0, 'a1': a1, 'a2': a2}


def test_ats_update_is_the_least_squares_of_the_filtered_window():
    """After a refit the coefficients move toward the hand-computed least squares of the
    filtered window (rate limited)."""
    from scipy.signal import butter, sosfiltfilt
    pred = ats(window_s=0.2, max_rate_per_s=1e3)
    t = np.arange(600) * DT
    desired = 400 * np.sin(2 * np.pi * 2.0 * t) + 150 * np.sin(2 * np.pi * 6.0 * t)
    sent = []
    for j in range(600):
        if j:
            # f_m[j-1] = 0.95 u[j-4]: a 3-step delay, gain 0.95
            f_m = 0.95 * sent[j - 4] if j >= 4 else 0.0
            pred.predict(Measurement(j - 1, (j - 1) * DT, 0.0, 0.0, 0.0, f_m), [], 0.0)
        sent.append(pred.command(desired[j]))
    assert pred.history, 'no refit happened'
    step = pred.history[-1][0]
    sos = butter(2, 20.0, fs=1 / DT, output='sos')
    u = np.array(sent[step - pred.window + 1:step + 1])
    f = np.array([0.95 * sent[j - 3] for j in range(step - pred.window + 1, step + 1)])
    uf, ff = sosfiltfilt(sos, u), sosfiltfilt(sos, f)
    x = np.column_stack([ff[2:], (ff[2:] - ff[1:-1]) / DT,
                         (ff[2:] - 2 * ff[1:-1] + ff[:-2]) / DT ** 2])
    by_hand = np.linalg.solve(x.T @ x, x.T @ uf[2:])
    by_hand = np.clip(by_hand, [0.7, 0.0, 0.0], [1.3, 0.03, 0.5 * 0.03 ** 2])
    np.testing.assert_allclose(pred.history[-1][1:], by_hand, rtol=1e-6, atol=1e-12)
    assert pred.coefficients[0] == pytest.approx(1 / 0.95, rel=0.02)
    assert pred.coefficients[1] == pytest.approx(3 * DT / 0.95, rel=0.15)


def test_ats_parameter_errors():
    with pytest.raises(ParameterError,
                       match=r'^parameter ats_window_s=0.01: expected at least 16 samples'):
        ats(window_s=0.01)
    with pytest.raises(ParameterError, match=r'^ats: the model law must have tau_s = 0'):
        AtsPredictor(DelayImpulseModel(M, C, K, DT, 0.01), 1.0, M, 0.01)


def test_ats_runs_on_the_delay_rig_and_records_its_estimates():
    err, run = nrms_percent(rig_model='delay', alpha=1.0, predictor='ats', **NOISE)
    assert run.stable and err < 10.0                # measured 3.7 %: the baseline
    assert set(run.estimates) == {'a0', 'a1', 'a2'}
    assert 0.005 < run.estimates['a1'][-1] < 0.012


def _nnls_scan(rows, y, candidates):
    """The delay fit's choice among `candidates` (the order and strict comparison of
    ``AdaptivePredictor._identify_delay``): (n, solution, residual)."""
    from scipy.optimize import nnls
    width, best = rows.shape[1], None
    for n in candidates:
        sol, rnorm = nnls(rows[:, [width - 2 - n, width - 1 - n]], y)
        if best is None or rnorm ** 2 < best[2]:
            best = (n, sol, rnorm ** 2)
    return best


def test_the_delay_shortlist_keeps_the_fit_the_full_scan_makes():
    """The shortlist of the adaptive delay fit (Gram-matrix residuals of every two-column
    non-negative least squares) keeps the delay that scanning every candidate with
    scipy.optimize.nnls chooses, with the same solution bit for bit: on forces delayed by
    each n with any split between the two steps and noise, on negative splits (one column
    alone, or neither), and on windows with nearly collinear and all-zero columns."""
    from seft_ros.core.predictors import _delay_shortlist
    rng = np.random.default_rng(7)
    max_n, rows_n = 15, 250
    lengths = []
    for case in range(300):
        forces = rng.standard_normal(rows_n + max_n + 2)
        if case % 3 == 1:                      # a narrow-band window (free vibration)
            t = np.arange(forces.size) * 0.002
            forces = np.sin(2 * np.pi * 10.1 * t) + 1e-3 * forces
        rows = np.lib.stride_tricks.sliding_window_view(forces, max_n + 2)[:rows_n].copy()
        if case % 10 == 0:
            rows[:, :5] = 0.0                  # the start of a run: no force yet
        n_true = int(rng.integers(0, max_n))
        ge, gl = rng.uniform(-0.3, 1.0, 2)
        w = rows.shape[1]
        y = ge * rows[:, w - 2 - n_true] + gl * rows[:, w - 1 - n_true]
        y = y + rng.uniform(0.0, 0.2) * rng.standard_normal(rows_n)
        short = _delay_shortlist(rows, y, max_n)
        lengths.append(len(short))
        full = _nnls_scan(rows, y, range(max_n))
        kept = _nnls_scan(rows, y, short)
        assert kept[0] == full[0] and np.array_equal(kept[1], full[1]), (case, short, full)
    # what it is for: one or two least squares instead of fifteen, most of the time
    assert np.median(lengths) <= 2, np.bincount(lengths)
