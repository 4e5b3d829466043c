"""The controller side's model of a yielding member (seft_ros.core.hysteresis), against closed
forms of the Bouc-Wen model and against the plant's own Bouc-Wen member (seft_plant_sim),
integrated independently."""

import math
import re

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.specimen import BoucWenSpecimen
from seft_ros.core.hysteresis import (
    BoucWenModel,
    HystereticIdentifier,
    HystereticMember,
    MemberGuess,
)

K, A, DY, N = 2.11e5, 0.1, 0.004, 2.0
M, C = 52.7, 17.14 * 52.7
DT = 0.002


def guess(**kw):
    values = dict(mass_kg=M, damping_N_s_per_m=C, stiffness_N_per_m=K, post_yield_ratio=A,
                  yield_displacement_m=DY, n=N)
    values.update(kw)
    return MemberGuess(**values)


# -- the model against closed forms ---------------------------------------------------------

@pytest.mark.parametrize('x', [0.5e-3, 2e-3, 4e-3, 9e-3, 20e-3])
def test_virgin_loading_curve_is_the_tanh_of_the_closed_form(x):
    """n = 2, beta = gamma = 1/2: dz/dx = (1 - z^2)/D_y from z = 0, so z = tanh(x/D_y) and
    r = a k x + (1 - a) k D_y tanh(x/D_y) (Ismail et al. 2009); RK4 in substeps of D_y/8."""
    model = BoucWenModel(K, A, DY, N)
    z = model.advance(0.0, x)
    assert z == pytest.approx(math.tanh(x / DY), rel=5e-6)
    assert model.restoring_force(x, z) == pytest.approx(
        A * K * x + (1 - A) * K * DY * math.tanh(x / DY), rel=5e-6)
    # the tangent there: k (a + (1 - a)(1 - z^2)), falling to a k
    assert model.tangent(z, 1.0) == pytest.approx(K * (A + (1 - A) * (1 - z * z)), rel=1e-12)


def test_unloading_is_elastic_and_reloading_retraces_the_branch():
    """beta = gamma: with x' z < 0, dz/dx = 1/D_y exactly, the tangent is k."""
    model = BoucWenModel(K, A, DY, N)
    z = model.advance(0.0, 12e-3)                         # yielded, z near 1
    back = model.advance(z, -3e-3)                        # unloading by 3 mm
    assert back == pytest.approx(z - 3e-3 / DY, rel=1e-12)
    assert model.tangent(z, -1.0) == pytest.approx(K, rel=1e-12)
    # the branch is taken from `direction`, not from the sign of the increment
    assert model.advance(z, -1e-4, 1.0) == pytest.approx(
        z - 1e-4 * (1 - z * z) / DY, rel=1e-3)


def test_unloading_shape_follows_its_closed_form():
    """beta - gamma = s > 0 (beta + gamma = 1), n = 2, unloading from z0 > 0 towards -x:
    dz/dx = (1 + s z^2)/D_y, so z = tan(sqrt(s) (x - x0)/D_y + atan(sqrt(s) z0))/sqrt(s)."""
    s = 0.5
    model = BoucWenModel(K, A, DY, N, beta=(1 + s) / 2, gamma=(1 - s) / 2)
    z0, dx = 0.8, -2.5e-3
    expected = math.tan(math.sqrt(s) * dx / DY + math.atan(math.sqrt(s) * z0)) / math.sqrt(s)
    assert model.advance(z0, dx) == pytest.approx(expected, rel=1e-6)
    assert model.tangent(z0, -1.0) == pytest.approx(K * (A + (1 - A) * (1 + s * z0 ** 2)))


def test_z_of_inverts_the_restoring_force_and_clips_at_saturation():
    model = BoucWenModel(K, A, DY, 3.0, beta=0.6, gamma=0.2)
    z_max = 0.8 ** (-1 / 3.0)
    assert model.z_max == pytest.approx(z_max)
    for x, z in ((1e-3, 0.3), (-6e-3, -0.95)):
        assert model.z_of(x, model.restoring_force(x, z)) == pytest.approx(z, rel=1e-12)
    assert model.z_of(0.0, 1e6) == z_max and model.z_of(0.0, -1e6) == -z_max


@pytest.mark.parametrize('kw, message', [
    (dict(stiffness_N_per_m=0.0), 'hysteresis model: expected k > 0'),
    (dict(post_yield_ratio=1.0), 'hysteresis model: expected k > 0, 0 <= a < 1'),
    (dict(n=0.5), 'hysteresis model: expected'),
    (dict(beta=-0.5, gamma=0.2), 'hysteresis: expected beta + gamma > 0'),
])
def test_model_errors(kw, message):
    args = dict(stiffness_N_per_m=K, post_yield_ratio=A, yield_displacement_m=DY, n=N)
    args.update(kw)
    with pytest.raises(ParameterError, match=re.escape(message)):
        BoucWenModel(**args)


@pytest.mark.parametrize('name, value, expected', [
    ('hysteresis_post_yield_ratio', 1.0, 'float in (0, 1)'),
    ('hysteresis_n', 1.0, 'float > 1'),
])
def test_guess_errors_name_the_parameter(name, value, expected):
    with pytest.raises(ParameterError, match=re.escape(f'parameter {name}={value!r}: expected '
                                                       f'{expected}')):
        MemberGuess.from_parameters(dict(parameters.defaults(), **{name: value}))


def test_guess_takes_the_predictors_model_only_for_the_predictor():
    p = dict(parameters.defaults(), predictor_stiffness_N_per_m=2.0e5)
    assert MemberGuess.from_parameters(p).stiffness_N_per_m == 2.0e5
    assert MemberGuess.from_parameters(p, predictor=False).stiffness_N_per_m == K


# -- identification against the plant's member ----------------------------------------------

def plant_history(specimen: BoucWenSpecimen, seconds: float = 6.0, noise=None, seed=0):
    """Displacement, velocity and restoring force of the plant's member driven along
    x(t) = X(t) sin(2 pi 1.5 t) with X growing to 3 D_y (cycles of growing yield), its z
    integrated with scipy's solve_ivp (an independent integrator); optional sensor noise
    (sigma of x [m], v [m/s], r [N])."""
    from scipy.integrate import solve_ivp
    t = np.arange(int(round(seconds / DT))) * DT
    w = 2 * np.pi * 1.5
    amp = 3 * specimen.yield_displacement_m * np.minimum(1.0, t / (0.6 * seconds) + 0.05)

    def xv(tt):
        a = 3 * specimen.yield_displacement_m * min(1.0, tt / (0.6 * seconds) + 0.05)
        da = 3 * specimen.yield_displacement_m / (0.6 * seconds) if tt < 0.57 * seconds else 0
        return a * np.sin(w * tt), da * np.sin(w * tt) + a * w * np.cos(w * tt)

    sol = solve_ivp(lambda tt, z: [specimen.hysteretic_rate(xv(tt)[1], z[0])], (0, t[-1]),
                    [0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=DT / 4)
    z = sol.y[0]
    x = amp * np.sin(w * t)
    v = np.array([xv(tt)[1] for tt in t])
    r = specimen.restoring_force(x, z)
    if noise is not None:
        rng = np.random.default_rng(seed)
        x = x + rng.normal(0, noise[0], x.shape)
        v = v + rng.normal(0, noise[1], v.shape)
        r = r + rng.normal(0, noise[2], r.shape)
    return x, v, r


@pytest.mark.parametrize('truth, start, expected', [
    # (the plant's member, the configured guess, what the identifier should find)
    (dict(post_yield_stiffness_ratio=0.1, yield_displacement_m=0.004, bouc_wen_n=2.0),
     dict(post_yield_ratio=0.15, yield_displacement_m=0.003, n=1.5),
     dict(a=0.1, dy=0.004, n=2.0, s=0.0)),
    (dict(post_yield_stiffness_ratio=0.05, yield_displacement_m=0.006, bouc_wen_n=3.0),
     dict(), dict(a=0.05, dy=0.006, n=3.0, s=0.0)),
    # beta = 0.75, gamma = 0.25: the shape s = (beta - gamma)/(beta + gamma) = 0.5
    (dict(bouc_wen_beta=0.75, bouc_wen_gamma=0.25), dict(),
     dict(a=0.1, dy=0.004, n=2.0, s=0.5)),
])
def test_identifier_finds_the_plant_members_parameters(truth, start, expected):
    specimen = BoucWenSpecimen(M, C, K, **truth)
    x, v, r = plant_history(specimen)
    ident = HystereticIdentifier(guess(**start), DT)
    for xi, vi, ri in zip(x, v, r):
        ident.observe(xi, ri, vi)
    k, a, dy, n, beta, gamma = ident.parameters()
    assert ident.updates > 2000
    assert k == pytest.approx(K, rel=5e-3)
    assert a == pytest.approx(expected['a'], rel=0.03)
    assert dy == pytest.approx(expected['dy'], rel=0.03)
    assert n == pytest.approx(expected['n'], rel=0.05)
    assert beta - gamma == pytest.approx(expected['s'], abs=0.03)
    assert beta + gamma == pytest.approx(1.0)


def test_identifier_under_sensor_noise_keeps_the_stiffness_and_the_strength():
    """Noise of the benchmarks' sensors (x 10 um, v 0.1 mm/s, r 5.7 N: load cell 5 N and the
    accelerometer's 0.05 m/s^2 times m): the stiffness within 1 % (the displacement
    increments come from the velocity, so x's noise does not bias it towards zero) and the
    hysteretic strength (1 - a) k D_y within 3 %."""
    specimen = BoucWenSpecimen(M, C, K)
    x, v, r = plant_history(specimen, noise=(1e-5, 1e-4, 5.7))
    ident = HystereticIdentifier(guess(yield_displacement_m=0.003), DT)
    for xi, vi, ri in zip(x, v, r):
        ident.observe(xi, ri, vi)
    k, a, dy, n, _, _ = ident.parameters()
    assert k == pytest.approx(K, rel=0.01)
    assert (1 - a) * k * dy == pytest.approx((1 - A) * K * DY, rel=0.03)
    assert math.sqrt(ident.sensor_var_N2) == pytest.approx(5.7 * math.sqrt(2), rel=0.35)


def test_identifier_skips_what_it_cannot_use():
    ident = HystereticIdentifier(guess(), DT)
    ident.observe(0.0, 0.0, 0.0)
    ident.observe(math.nan, 1.0, 0.0)
    ident.observe(1e-7, 20.0, 1e-6)         # 1 nm of motion: below the least increment
    assert ident.updates == 0
    with pytest.raises(ParameterError, match='hysteresis identifier'):
        HystereticIdentifier(guess(), 0.0)


# -- the member: state, yield evidence, tangent ahead -----------------------------------------

def measurements(specimen: BoucWenSpecimen, x, v, a, z):
    """(x, v, a, f_m) of the plant's member: f_m = m a + c v + r(x, z)."""
    return x, v, a, M * a + C * v + specimen.restoring_force(x, z)


def test_tangent_ahead_is_the_plant_members_tangent_after_the_horizon():
    """A member loading through its knee at 0.1 m/s: the tangent 5 ms ahead is the plant's at
    x + 0.5 mm, from the closed form of the virgin curve (z = tanh(x/D_y))."""
    specimen = BoucWenSpecimen(M, C, K)
    member = HystereticMember(guess(), DT, identify=False)
    vel = 0.1
    for j in range(40):                  # x from 0 to 7.8 mm: it has yielded
        x = vel * DT * j
        member.observe(*measurements(specimen, x, vel, 0.0, math.tanh(x / DY)))
    assert member.has_yielded and member.confidence == pytest.approx(1.0, abs=1e-6)
    x_end = x + vel * 0.005
    z_end = math.tanh(x_end / DY)
    assert member.tangent_ahead(0.005) == pytest.approx(K * (A + (1 - A) * (1 - z_end ** 2)),
                                                        rel=1e-6)
    # decelerating so hard that the velocity reverses within the horizon: elastic unloading
    member.observe(*measurements(specimen, x, vel, -40.0, math.tanh(x / DY)))
    assert member.tangent_ahead(0.005) == pytest.approx(K, rel=1e-12)


def test_an_elastic_member_never_counts_as_yielded():
    """A linear spring (r = k x) moved 3 D_y back and forth, beyond where the guess yields:
    the measured force never leaves the elastic line, so the tangent is k throughout (the
    tangent controller then is the study's loop shaping)."""
    member = HystereticMember(guess(), DT)
    for j in range(3000):
        t = j * DT
        x, v = 3 * DY * math.sin(2 * np.pi * t), 3 * DY * 2 * np.pi * math.cos(2 * np.pi * t)
        a = -(2 * np.pi) ** 2 * x
        member.observe(x, v, a, M * a + C * v + K * x)
        assert member.tangent_ahead(0.005) == member.model.stiffness_N_per_m
    assert not member.has_yielded
    assert member.model.stiffness_N_per_m == pytest.approx(K, rel=1e-3)


def test_estimates_name_the_model():
    member = HystereticMember(guess(), DT)
    est = member.estimates()
    assert list(est) == ['tangent_stiffness_N_per_m', 'hysteresis_stiffness_N_per_m',
                         'hysteresis_post_yield_ratio', 'hysteresis_yield_displacement_m',
                         'hysteresis_n', 'hysteresis_unloading_shape']
    assert est['tangent_stiffness_N_per_m'] == pytest.approx(K)
    assert est['hysteresis_unloading_shape'] == 0.0
