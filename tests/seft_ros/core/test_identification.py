"""Tests of the online identification (``seft_ros.core.identification``) against batch answers."""

import math

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.core.identification import (
    ArxLoopIdentifier,
    ExcitationGate,
    GuardedResponse,
    GuardedValue,
    RecursiveLeastSquares,
    arx_from_impulse_response,
    ats_coefficients,
    backward_differences,
    fir_band_basis,
    forgetting_factor,
)

DT = 0.002


@pytest.fixture
def regression():
    """A known linear system y = phi . theta + noise (the specimen's m, c, k, normalised)."""
    rng = np.random.default_rng(3)
    phi = rng.normal(size=(400, 3)) * [300.0, 100.0, 800.0]
    theta = np.array([1.1, 0.9, 1.05])
    y = phi @ theta + rng.normal(scale=1.0, size=400)
    return phi, y, theta


def test_rls_equals_the_weighted_batch_least_squares(regression):
    """RLS with forgetting = exponentially weighted least squares with the prior as a term."""
    phi, y, _ = regression
    lam, p0 = 0.99, 1e-3
    rls = RecursiveLeastSquares(np.ones(3), p0, lam, max_trace=1e9)
    for row, value in zip(phi, y):
        rls.update(row, value)
    n = y.shape[0]
    w = lam ** np.arange(n - 1, -1, -1)
    # minimise sum w_j (y_j - phi_j theta)^2 + lam^n / p0 |theta - 1|^2 (normal equations)
    a = (phi * w[:, None]).T @ phi + lam ** n / p0 * np.eye(3)
    b = (phi * w[:, None]).T @ y + lam ** n / p0 * np.ones(3)
    np.testing.assert_allclose(rls.theta, np.linalg.solve(a, b), rtol=1e-8)
    np.testing.assert_allclose(rls.P, np.linalg.inv(a), rtol=1e-6)


def test_rls_converges_on_a_known_system(regression):
    phi, y, theta = regression
    rls = RecursiveLeastSquares(np.ones(3), 1e-4, forgetting_factor(DT, 5.0))
    for row, value in zip(phi, y):
        rls.update(row, value)
    np.testing.assert_allclose(rls.theta, theta, rtol=2e-3)


def test_rls_covariance_is_bounded_under_poor_excitation():
    """Excitation in one direction only: forgetting would wind P up; the trace stays bounded."""
    rls = RecursiveLeastSquares(np.ones(3), 1e-3, 0.99)
    for _ in range(5000):
        rls.update([1.0, 0.0, 0.0], 1.0)
    assert np.trace(rls.P) <= 3e-3 * (1 + 1e-12)
    assert rls.theta[1] == rls.theta[2] == 1.0


@pytest.mark.parametrize('kwargs, message', [
    ({'forgetting': 0.0}, r'^forgetting=0.0: expected 0 < lambda <= 1'),
    ({'forgetting': 1.5}, r'^forgetting=1.5'),
    ({'p0': -1.0}, r'^p0=-1.0: expected a positive definite covariance'),
])
def test_rls_parameter_errors(kwargs, message):
    args = dict(theta0=np.ones(3), p0=1.0, forgetting=1.0)
    args.update(kwargs)
    with pytest.raises(ParameterError, match=message):
        RecursiveLeastSquares(**args)


def test_forgetting_factor():
    assert forgetting_factor(DT, 5.0) == pytest.approx(math.exp(-DT / 5.0))
    with pytest.raises(ParameterError, match=r'^parameter adaptive_memory_s=0.0: expected'):
        forgetting_factor(DT, 0.0)


def test_excitation_gate_holds_on_quiet_input():
    gate = ExcitationGate(DT, 0.5, 20.0)
    rng = np.random.default_rng(0)
    assert not any(gate.update(v) for v in rng.normal(scale=5.0, size=2000))   # noise only
    t = np.arange(2000) * DT
    flags = [gate.update(v) for v in 100.0 * np.sin(2 * np.pi * 3 * t)]
    assert flags[-1] and gate.excited
    assert gate.mean_square == pytest.approx(100.0 ** 2 / 2, rel=0.05)


def test_guarded_value_bounds_and_rate():
    g = GuardedValue(1.0, 0.5, 1.5, 0.1)
    assert [round(g.follow(2.0), 12) for _ in range(7)] == [1.1, 1.2, 1.3, 1.4, 1.5, 1.5, 1.5]
    assert g.follow(1.45) == pytest.approx(1.45)
    assert g.follow(float('nan')) == pytest.approx(1.45)      # a failed fit changes nothing
    assert GuardedValue(3.0, 0.5, 1.5, 0.1).value == 1.5      # the start is clipped too
    with pytest.raises(ParameterError, match=r'^estimate range \[2.0, 1.0\]'):
        GuardedValue(1.0, 2.0, 1.0, 0.1)


def test_backward_differences_by_hand():
    d = backward_differences([1.0, 2.0, 4.0, 7.0], 0.5)
    np.testing.assert_allclose(d, [[4.0, 4.0, 4.0], [7.0, 6.0, 4.0]])


def test_ats_coefficients_against_hand_computed_least_squares():
    """The ATS fit is the least squares of u on [r, r', r''] (Chae et al. 2013, Eq. 13)."""
    rng = np.random.default_rng(7)
    t = np.arange(500) * DT
    r = 300 * np.sin(2 * np.pi * 2.1 * t) + 120 * np.sin(2 * np.pi * 7.3 * t + 1.0)
    u = np.roll(r, -5) + rng.normal(scale=2.0, size=r.shape)        # u leads r by 5 steps
    a = ats_coefficients(u, r, DT)
    # by hand: the normal equations X^T X a = X^T u
    x = np.column_stack([r[2:], (r[2:] - r[1:-1]) / DT,
                         (r[2:] - 2 * r[1:-1] + r[:-2]) / DT ** 2])
    np.testing.assert_allclose(a, np.linalg.solve(x.T @ x, x.T @ u[2:]), rtol=1e-9)
    assert a[0] == pytest.approx(1.0, abs=0.02) and a[1] == pytest.approx(0.010, abs=0.0015)


def test_ats_coefficients_recover_an_exact_relation():
    t = np.arange(300) * DT
    r = np.sin(2 * np.pi * 1.7 * t) + 0.3 * np.cos(2 * np.pi * 4.1 * t)
    x = backward_differences(r, DT)
    u = np.concatenate([[0.0, 0.0], x @ [1.1, 0.012, 7e-5]])
    np.testing.assert_allclose(ats_coefficients(u, r, DT), [1.1, 0.012, 7e-5], rtol=1e-7)
    assert np.isnan(ats_coefficients(np.zeros(10), np.zeros(10), DT)).all()
    with pytest.raises(ParameterError, match=r'^ATS window: expected two equal 1-D arrays'):
        ats_coefficients(np.zeros(5), np.zeros(5), DT)


# -- the closed force loop from data (ARX by RLS, guarded frequency response) ---------------

#: A known discrete loop ``B/A`` (a lightly damped pair at about 20 Hz, DC gain 1, one step of
#: delay) and a prior 20 % slower and less damped.
TRUE_LOOP = ([0.0, 0.0, 0.1, 0.05], [1.0, -1.5, 0.65])
PRIOR_LOOP = ([0.0, 0.0, 0.08, 0.04], [1.0, -1.6, 0.72])
BAND = np.linspace(0.0, 40.0, 81)


def _impulse(system, n=400):
    from scipy.signal import lfilter
    u = np.zeros(n)
    u[0] = 1.0
    return lfilter(*system, u)


def _loop_identifier(**kwargs):
    args = dict(prior=_impulse(PRIOR_LOOP), na=2, nb=3, dt=DT, freq_hz=BAND,
                forgetting=forgetting_factor(DT, 5.0), p0=1e-4, max_deviation=5.0,
                max_step=5.0)
    args.update(kwargs)
    return ArxLoopIdentifier(**args)


def _drive(ident, system, n, noise=0.0, seed=4):
    """Multi-sine input of about 500 N through `system`, output noise; every sample in."""
    from scipy.signal import lfilter
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = sum(300.0 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (1.3, 4.1, 9.7,
                                                                             17.0, 31.0))
    y = lfilter(*system, u) + rng.normal(scale=noise, size=n) if noise else lfilter(*system, u)
    for j in range(ident.nb + 1, n):
        ident.update(y[j - ident.na:j][::-1], u[j - ident.nb:j][::-1], y[j])


def _frequency_response(system, freq):
    from scipy.signal import freqz
    return freqz(*system, worN=freq, fs=1.0 / DT)[1]


def test_arx_from_impulse_response_is_exact_at_the_true_order():
    theta = arx_from_impulse_response(_impulse(TRUE_LOOP), 2, 3)
    assert theta == pytest.approx([-1.5, 0.65, 0.0, 0.1, 0.05], abs=1e-12)


def test_arx_loop_identifier_starts_at_the_prior():
    ident = _loop_identifier()
    assert ident.response == pytest.approx(_frequency_response(PRIOR_LOOP, BAND), abs=1e-12)
    assert ident.deviation == 0.0


@pytest.mark.parametrize('noise, tolerance', [(0.0, 5e-3), (2.0, 0.02)])
def test_arx_loop_identifier_converges_on_a_known_discrete_system(noise, tolerance):
    """2 s of a multi-sine through the true loop: its frequency response up to 40 Hz within
    0.5 % of the true loop's without noise, 2 % with 2 N output noise (the ARX bias,
    class notes); the prior is up to 30 % off."""
    ident = _loop_identifier()
    truth = _frequency_response(TRUE_LOOP, BAND)
    assert np.max(np.abs(ident.response - truth)) > 0.25
    _drive(ident, TRUE_LOOP, 1000, noise=noise)
    for _ in range(10):
        ident.follow()
    assert np.max(np.abs(ident.response - truth)) < tolerance


def test_arx_loop_identifier_is_bounded_and_rate_limited():
    ident = _loop_identifier(max_deviation=0.2, max_step=0.05)
    _drive(ident, TRUE_LOOP, 1000)
    prior = ident.response.copy()
    previous = prior
    for _ in range(8):
        now = ident.follow().copy()
        assert np.max(np.abs(now - previous)) <= 0.05 + 1e-12
        previous = now
    assert ident.deviation == pytest.approx(0.2)
    assert np.max(np.abs(ident.response - prior)) == pytest.approx(0.2)


def test_guarded_response_on_fir_taps_and_a_non_finite_target():
    basis = fir_band_basis(3, DT, 40.0)
    guard = GuardedResponse([0.0, 1.0, 0.0], basis, max_deviation=0.3, max_step=0.1)
    guard.follow([0.0, 0.0, 0.0])                     # |d|_B = 1 (a delay's gain): 0.1 of it
    assert guard.value == pytest.approx([0.0, 0.9, 0.0])
    assert guard.deviation == pytest.approx(0.1)
    held = guard.value.copy()
    assert guard.follow([np.nan, 0.0, 0.0]) == pytest.approx(held)
    for _ in range(10):
        guard.follow([0.0, 0.0, 0.0])
    assert guard.value == pytest.approx([0.0, 0.7, 0.0])


@pytest.mark.parametrize('kwargs, message', [
    (dict(na=0), r'^ARX loop model: expected orders >= 1'),
    (dict(prior=np.ones(4)), r'^ARX loop model: expected orders >= 1 and a finite prior'),
    (dict(p0=0.0), r'^ARX loop prior covariance p0=0.0: expected > 0'),
    (dict(max_deviation=0.0), r'^guarded response: expected max_deviation > 0'),
])
def test_arx_loop_identifier_errors(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        _loop_identifier(**kwargs)


def test_guarded_response_basis_must_fit_the_taps():
    with pytest.raises(ParameterError, match=r'^guarded response: basis of shape \(41, 3\)'):
        GuardedResponse(np.zeros(4), fir_band_basis(3, DT, 40.0), 1.0, 1.0)
