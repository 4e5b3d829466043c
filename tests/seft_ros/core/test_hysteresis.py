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


# -- the model: edges of its ranges, the RK4 substeps, branch changes ---------------------------

HK = (1 - A) * K * DY              # hysteretic strength (1 - a) k D_y of the guess [N]


def branch_z(z, d, direction, dy=DY):
    """Closed form of z after a displacement `d` [m] on the branch of `direction` (n = 2,
    beta = gamma = 1/2): where direction z > 0 (loading) dz/dx = (1 - z^2)/D_y, i.e.
    d atanh(z) = dx/D_y; elsewhere (unloading) dz/dx = 1/D_y. Reversible along the branch."""
    if direction < 0:
        return -branch_z(-z, -d, 1.0, dy)
    w = (math.atanh(z) if z > 0 else z) + d / dy
    return math.tanh(w) if w > 0 else w


def tangent_cf(z, direction):
    """Tangent stiffness dr/dx = a k + (1 - a) k D_y dz/dx of the guess's model at z."""
    return K * (A + (1 - A) * (1 - z * z)) if direction * z > 0 else K


def test_model_takes_the_edges_of_its_ranges():
    """a = 0 (elastic-perfectly plastic): r = k D_y tanh(x/D_y); n = 1 (beta = gamma = 1/2):
    dz/dx = (1 - z)/D_y from 0, so z = 1 - exp(-x/D_y); a stiffness of 1 N/m is a stiffness."""
    x = 6e-3
    flat = BoucWenModel(K, 0.0, DY, N)
    assert flat.restoring_force(x, flat.advance(0.0, x)) == pytest.approx(
        K * DY * math.tanh(x / DY), rel=5e-6)
    linear_knee = BoucWenModel(1.0, A, DY, 1.0)
    assert linear_knee.advance(0.0, x) == pytest.approx(1 - math.exp(-x / DY), rel=5e-6)
    assert linear_knee.z_max == 1.0
    # beta + gamma only has to be positive
    assert BoucWenModel(K, A, DY, N, beta=1.0, gamma=-0.75).z_max == pytest.approx(4 ** 0.5)


MODEL_MESSAGE = ('hysteresis model: expected k > 0, 0 <= a < 1, D_y > 0 and n >= 1, got '
                 '{!r}, {!r}, {!r}, {!r}')


@pytest.mark.parametrize('k, a, dy, n', [
    (K, A, 0.0, N),               # no yield displacement (1/D_y)
    (K, A, math.inf, N),          # an infinite strength
    (K, A, DY, math.inf),
    (1e300, A, 1e10, N),          # a strength (1 - a) k D_y that overflows
    (K, -0.1, DY, N),
])
def test_model_rejects_a_strength_that_is_not_a_number(k, a, dy, n):
    with pytest.raises(ParameterError, match='^' + re.escape(MODEL_MESSAGE.format(
            float(k), float(a), float(dy), float(n))) + '$'):
        BoucWenModel(k, a, dy, n)


def test_model_rejects_a_shape_without_saturation():
    """beta + gamma = 0: z would never saturate ((beta + gamma)^(-1/n))."""
    with pytest.raises(ParameterError,
                       match=r'^hysteresis: expected beta \+ gamma > 0, got 0\.25, -0\.25$'):
        BoucWenModel(K, A, DY, N, beta=0.25, gamma=-0.25)


def rk4_reference(z, dx, direction, dy=DY, n=N, beta=0.5, gamma=0.5):
    """Classical RK4 of dz/dx = (1 - |z|^n (beta sgn(direction z) + gamma))/D_y, written here
    from the model's equation, in the substeps the docstring gives: floor(8 |dx|/D_y) + 1
    equal substeps (at most D_y/8 each)."""
    def rate(zz):
        b = beta if direction * zz > 0 else -beta
        return (1 - abs(zz) ** n * (b + gamma)) / dy

    steps = int(abs(dx) / dy * 8) + 1
    h = dx / steps
    for _ in range(steps):
        k1 = rate(z)
        k2 = rate(z + h / 2 * k1)
        k3 = rate(z + h / 2 * k2)
        k4 = rate(z + h * k3)
        z += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return z


@pytest.mark.parametrize('z0, dx', [(0.3, 3.6e-3), (0.3, 7.9e-3), (-0.2, 12.34e-3),
                                    (0.9, -5.5e-3)])
def test_advance_is_rk4_in_substeps_of_at_most_an_eighth_of_the_yield_displacement(z0, dx):
    """The same numbers as an RK4 written in the test with the documented substeps (to
    rounding), and the closed form within the RK4 error (3.6 mm from z = 0.3: 2e-6)."""
    model = BoucWenModel(K, A, DY, N)
    direction = 1.0 if dx > 0 else -1.0
    assert model.advance(z0, dx) == pytest.approx(rk4_reference(z0, dx, direction),
                                                  rel=1e-13)
    assert model.advance(z0, dx) == pytest.approx(branch_z(z0, dx, direction), rel=1e-5)


def test_advance_through_zero_within_one_substep():
    """D_y = 1 m, one substep of 0.1 m in +x from z = -0.05: unloading (dz/dx = 1) to z = 0,
    then loading (z = tanh(0.05)); the RK4 stages land on z = 0 exactly (the branch test
    there must not divide by z). From z = -0.1 the path ends at z = 0 exactly."""
    model = BoucWenModel(1.0, 0.0, 1.0, 2.0)
    assert model.advance(-0.05, 0.1, 1.0) == pytest.approx(math.tanh(0.05), rel=1e-5)
    assert model.advance(-0.1, 0.1, 1.0) == 0.0
    assert model.advance(0.4, 0.0) == 0.4


def test_advance_far_past_yield_saturates():
    """A metre of loading (4 D_y with D_y = 0.25 m) from z = 0: z = tanh(4) -> z_max."""
    model = BoucWenModel(K, A, 0.25, N)
    assert model.advance(0.0, 1.0) == pytest.approx(math.tanh(4.0), rel=1e-6)


# -- the configured guess ---------------------------------------------------------------------

def test_guess_takes_the_schemas_defaults_and_the_plain_model_where_unset():
    """No hysteresis_* keys: the schema's defaults (D_y 4 mm, a 0.1, n 2); the predictor's
    m, c, k where set (non-zero), else the specimen's."""
    plain = dict(mass_kg=50.0, damping_N_s_per_m=900.0, stiffness_N_per_m=2.0e5,
                 predictor_mass_kg=0.0, predictor_damping_N_s_per_m=0.0,
                 predictor_stiffness_N_per_m=0.0)
    assert MemberGuess.from_parameters(plain) == MemberGuess(50.0, 900.0, 2.0e5, 0.1, 0.004,
                                                             2.0)
    own = dict(plain, predictor_mass_kg=60.0, predictor_damping_N_s_per_m=700.0,
               predictor_stiffness_N_per_m=1.5e5, hysteresis_n=3.0)
    assert MemberGuess.from_parameters(own) == MemberGuess(60.0, 700.0, 1.5e5, 0.1, 0.004,
                                                           3.0)
    # the force controller declares no predictor_* parameters: the specimen's
    assert MemberGuess.from_parameters(own, predictor=False) == MemberGuess(
        50.0, 900.0, 2.0e5, 0.1, 0.004, 3.0)
    # small values are values
    tiny = dict(plain, mass_kg=0.5, stiffness_N_per_m=0.5)
    assert MemberGuess.from_parameters(tiny, predictor=False) == MemberGuess(
        0.5, 900.0, 0.5, 0.1, 0.004, 2.0)


@pytest.mark.parametrize('name, value, expected', [
    ('hysteresis_post_yield_ratio', 0.0, 'float in (0, 1)'),
    ('hysteresis_yield_displacement_m', 0.0, 'float > 0'),
    ('hysteresis_yield_displacement_m', math.inf, 'float > 0'),
    ('mass_kg', 0.0, 'float > 0'),
    ('stiffness_N_per_m', 0.0, 'float > 0'),
    ('stiffness_N_per_m', -1.0, 'float > 0'),
])
def test_guess_errors_are_whole_lines(name, value, expected):
    params = dict(parameters.defaults(), **{name: value})
    with pytest.raises(ParameterError, match='^' + re.escape(
            f'parameter {name}={value!r}: expected {expected}') + '$'):
        MemberGuess.from_parameters(params, predictor=False)


# -- the identifier's recursion -----------------------------------------------------------------

def r_virgin(x):
    """The guess's own member on its virgin loading curve (n = 2):
    r = a k x + (1 - a) k D_y tanh(x/D_y)."""
    return A * K * x + HK * math.tanh(x / DY)


@pytest.mark.parametrize('memory_s', [0.5, 2.0])
def test_identifier_covariance_and_noise_follow_their_recursions(memory_s):
    """The guess's own member loaded from rest by 20 um a sample (10 samples, z < 0.05): the
    data are the model's, so e ~ 0 and
    - the residual variance decays from its prior 100 N^2 as 100 lambda^j (running mean of
      e^2 with weight 1 - lambda, lambda = exp(-dt/memory_s));
    - only ln k is visible (the others' sensitivities are O(z^2)), and its covariance follows
      the information recursion 1/P <- lambda/P + J^2/R from 1/P0 = 20 (Ljung and Soderstrom
      1983), J = d r_hat / d ln k from the closed form of the prediction;
    - every sample that moved updates, and the estimates stay at the guess."""
    ident = HystereticIdentifier(guess(), DT, memory_s=memory_s)
    v, count = 0.01, 10
    lam = math.exp(-DT / memory_s)
    info, noise = 1 / 0.05, 100.0
    for j in range(count + 1):
        ident.observe(j * v * DT, r_virgin(j * v * DT), v)
        if j == 0:
            continue
        x0, x1 = (j - 1) * v * DT, j * v * DT

        def r_hat(ln_k):
            k = K * math.exp(ln_k)
            z0 = (r_virgin(x0) - A * k * x0) / ((1 - A) * k * DY)
            return A * k * x1 + (1 - A) * k * DY * math.tanh(math.atanh(z0) + (x1 - x0) / DY)

        jac = (r_hat(1e-6) - r_hat(-1e-6)) / 2e-6
        noise *= lam
        info = lam * info + jac * jac / noise
    assert ident.updates == count
    assert ident.noise_var_N2 == pytest.approx(100 * lam ** count, rel=1e-9)
    assert ident.P[0][0] == pytest.approx(1 / info, rel=1e-4)
    assert ident.parameters() == pytest.approx((K, A, DY, N, 0.5, 0.5), rel=1e-6)


def test_identifier_updates_at_the_noise_floor_on_small_increments():
    """Exact data (the guess's member), memory 0.05 s: after 150 samples of 20 um the residual
    variance is at its floor (1 N^2) and ln k well known; then 50 samples of 1 um (what a
    record's quiet part moves), with min_increment_m = 0: each still updates (there the
    update's denominator lambda R + J'PJ is below 1, which is no reason to skip it)."""
    ident = HystereticIdentifier(guess(), DT, memory_s=0.05, min_increment_m=0.0)
    x, v = 0.0, 0.01
    ident.observe(x, r_virgin(x), v)
    for speed, count in ((0.01, 150), (5e-4, 50)):
        for _ in range(count):
            x, v = x + 0.5 * (v + speed) * DT, speed    # the path of the velocity readings
            ident.observe(x, r_virgin(x), v)
    assert ident.updates == 200
    assert ident.noise_var_N2 < 0.1
    assert ident.parameters() == pytest.approx((K, A, DY, N, 0.5, 0.5), rel=1e-6)


@pytest.mark.parametrize('dx, updates', [(1.6e-4, 10), (1.2e-4, 5)])
def test_identifier_waits_for_motion_that_stands_out_of_the_noise(dx, updates):
    """With the sensors' noise at sigma = 10 N the least increment is 3 sigma / k = 142 um:
    10 samples of 160 um update at each; of 120 um at every second (240 um)."""
    ident = HystereticIdentifier(guess(), DT)
    ident.observe(0.0, 0.0, dx / DT)
    ident.sensor_var_N2 = 100.0
    for j in range(1, 11):
        ident.observe(j * dx, r_virgin(j * dx), dx / DT)
    assert ident.updates == updates


def test_identifier_updates_from_the_first_motion():
    """From rest (v = 0: no reversal) to 2.5 mm/s: the trapezoid moves 2.5 um in the first
    step, then 5 um a step; no noise estimate yet, so the least increment is min_increment_m
    (2 um) and every sample after the first updates."""
    ident = HystereticIdentifier(guess(), DT)
    ident.observe(0.0, 0.0, 0.0)
    for j in range(5):
        x = 2.5e-6 + j * 5e-6
        ident.observe(x, r_virgin(x), 2.5e-3)
    assert ident.updates == 5


@pytest.mark.parametrize('bad', ['displacement', 'force'])
def test_identifier_skips_a_non_finite_sample_and_goes_on(bad):
    """A NaN displacement or force in mid-motion is skipped; the samples after it update as
    before (no NaN kept in the anchor or the residual variance)."""
    ident = HystereticIdentifier(guess(), DT)
    v = 0.01
    for j in range(20):
        x, r = j * v * DT, r_virgin(j * v * DT)
        if j == 8:
            x, r = (math.nan, r) if bad == 'displacement' else (x, math.nan)
        ident.observe(x, r, v)
    assert ident.updates == 18
    assert math.isfinite(ident.noise_var_N2)
    assert all(math.isfinite(t) for t in ident.theta)


def test_identifier_errors():
    for kw in (dict(memory_s=0.0), dict(memory_s=-1.0), dict(min_increment_m=-1e-6)):
        with pytest.raises(ParameterError, match=r'^hysteresis identifier: expected dt > 0, '
                                                 r'memory_s > 0, got 0\.002, '):
            HystereticIdentifier(guess(), DT, **kw)


# -- the member: yield evidence, confidence, tangent ahead (closed forms) -----------------------

STEP_M = 1e-4                       # 0.1 mm a sample: 0.05 m/s at 2 ms


def load_member(member, dy_true, x_end, sign=1.0, skip=None):
    """Feed `member` the plant's member with D_y = `dy_true` (a, k of the guess) loaded from
    rest to sign x_end at 0.05 m/s (z = tanh(x/D_y) of the virgin curve); yield (reading, r)
    of each sample. `skip`: indices whose displacement reading is 20 um behind the previous
    sample's (sensor noise while the velocity keeps its sign)."""
    specimen = BoucWenSpecimen(M, C, K, yield_displacement_m=dy_true)
    for j in range(int(round(x_end / STEP_M)) + 1):
        x = sign * j * STEP_M
        r = float(specimen.restoring_force(x, math.tanh(x / dy_true)))
        reading = x - sign * (STEP_M + 2e-5) if skip and j in skip else x
        member.observe(reading, sign * 0.05, 0.0, M * 0.0 + C * sign * 0.05 + r)
        yield reading, r


def departures(reading, r):
    """Departure from the elastic line k x through the start (rest, the last reversal):
    measured |r - k x|, and the model's (z carried from 0 along the guess's loading branch,
    reversibly: the virgin curve at the reading)."""
    predicted = abs(A * K * reading + HK * math.tanh(reading / DY) - K * reading)
    return abs(r - K * reading), predicted


@pytest.mark.parametrize('noise_sigma', [0.0, 5.0])
def test_yield_evidence_and_confidence_of_a_stronger_member(noise_sigma):
    """The member is stronger than guessed (D_y 6 mm, guess 4 mm): it counts as yielded at the
    first sample whose measured departure from the elastic line exceeds 5 % of the guess's
    strength (1 - a) k D_y = 759.6 N plus twice the sensors' noise sigma; from then on the
    confidence is measured / predicted departure (each plus 2 sigma), the model predicting
    more loss of stiffness than the member shows. A displacement reading that goes 20 um back
    while the velocity is positive is carried back along the loading branch (reversibly)."""
    member = HystereticMember(guess(), DT, identify=noise_sigma > 0)
    if noise_sigma:                         # the identifier's noise estimate, held
        member.identifier.min_increment_m = 1.0
        member.identifier.sensor_var_N2 = noise_sigma ** 2
    noise = 2 * noise_sigma
    yielded = False
    for j, (reading, r) in enumerate(load_member(member, 0.006, 0.004, skip={31})):
        measured, predicted = departures(reading, r)
        if j == 0:
            assert member.confidence == 0.0 and not member.has_yielded
            continue
        yielded = yielded or measured > 0.05 * HK + noise
        assert member.has_yielded == yielded, j
        if yielded:
            assert predicted > measured
            assert member.confidence == pytest.approx((measured + noise) / (predicted + noise),
                                                      rel=1e-5), j
        else:
            assert member.confidence == 0.0
            assert member.tangent_ahead(0.005) == member.model.stiffness_N_per_m
    assert yielded                      # (at 2.9 mm without noise, 3.2 mm with)
    # the tangent 5 ms ahead: z anchored on the measured force, carried 0.25 mm on the
    # loading branch, its loss of stiffness weighted by the confidence
    z = (r - A * K * reading) / HK
    z_end = branch_z(z, 0.05 * 0.005, 1.0)
    assert member.tangent_ahead(0.005) == pytest.approx(
        K - member.confidence * (K - tangent_cf(z_end, 1.0)), rel=1e-6)


def test_a_weaker_member_gets_full_confidence():
    """D_y 3 mm, guess 4 mm: the member departs from the elastic line more than the model
    predicts, so once yielded the confidence is 1 (not more)."""
    member = HystereticMember(guess(), DT, identify=False)
    states = list(load_member(member, 0.003, 0.005))
    assert member.has_yielded and member.confidence == 1.0
    measured, predicted = departures(*states[-1])
    assert measured > predicted


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_reversal_restarts_the_evidence_and_a_hold_keeps_full_confidence(sign):
    """The stronger member (D_y 6 mm) loaded to 4 mm has a confidence of about 0.5; a
    momentary stop (v = 0) is no reversal and keeps it; a reversal anchors the elastic line
    anew with full confidence (the member has shown that it yields); held still right after
    (no motion since), measured and predicted departures are both 0: confidence 1, no 0/0."""
    member = HystereticMember(guess(), DT, identify=False)
    reading, r = list(load_member(member, 0.006, 0.004, sign))[-1]
    loading = member.confidence
    assert 0.4 < loading < 0.6
    member.observe(reading, 0.0, 0.0, r)
    assert member.confidence == (loading if sign > 0 else 1.0)   # v = 0 counts as positive
    for _ in range(2):
        member.observe(reading, -sign * 0.05, 0.0, C * -sign * 0.05 + r)
        assert member.confidence == 1.0


@pytest.mark.parametrize('sign', [1.0, -1.0])
@pytest.mark.parametrize('v, a, horizon', [
    (0.05, 30.0, 0.005),        # speeding up: 0.625 mm on along the loading branch
    (0.1, -10.0, 0.05),         # reverses after 0.5 mm, then 8 mm back: unloading
                                # through z = 0 and loading the other way
    (-0.05, 5.0, 0.005),        # unloading, slowing down: elastic, k
    (-0.01, 10.0, 0.005),       # reverses after 5 um back, then 80 um of loading
    (-0.01, 100.0, 0.02),       # reverses after 0.5 um back, then 19.8 mm of loading
])
def test_tangent_ahead_follows_the_path_of_velocity_and_acceleration(sign, v, a, horizon):
    """A yielded member (weaker than guessed: confidence 1) at x = 5 mm, z anchored on the
    measured force; path x + v t + a t^2/2 over the horizon, through its reversal at
    t_r = -v/a; the tangent at the end on the branch of the final velocity, from the closed
    form of the branches (n = 2). Mirrored for sign -1."""
    member = HystereticMember(guess(), DT, identify=False)
    reading, r = list(load_member(member, 0.003, 0.005, sign))[-1]
    v, a = sign * v, sign * a
    member.observe(reading, v, a, M * a + C * v + r)
    assert member.confidence == 1.0
    z = (r - A * K * reading) / HK
    assert member.z == pytest.approx(z, rel=1e-12)
    v_end = v + a * horizon
    end = v * horizon + 0.5 * a * horizon ** 2
    if v * v_end < 0:
        t_r = -v / a
        peak = v * t_r + 0.5 * a * t_r ** 2
        z = branch_z(z, peak, math.copysign(1.0, v))
        z = branch_z(z, end - peak, math.copysign(1.0, v_end))
    else:
        z = branch_z(z, end, math.copysign(1.0, end))
    # (RK4 in substeps of D_y/8 over the kink of dz/dx at z = 0: within 4e-5)
    assert member.tangent_ahead(horizon) == pytest.approx(
        tangent_cf(z, math.copysign(1.0, v_end)), rel=1e-4)


@pytest.mark.parametrize('sign', [1.0, -1.0])
@pytest.mark.parametrize('v', [0.05, -0.05, 0.0])
def test_the_tangent_now_is_the_tangent_ahead_over_no_time(sign, v):
    """estimates()' tangent is the model's at the anchored z on the branch of the velocity
    (a zero velocity counts as positive, in both), and tangent_ahead(0) with full confidence
    is the same; after loading in +x that is the loading tangent for v >= 0 and k for v < 0
    (elastic unloading), mirrored after loading in -x (then v = 0 is unloading: k)."""
    member = HystereticMember(guess(), DT, identify=False)
    reading, r = list(load_member(member, 0.003, 0.005, sign))[-1]
    member.observe(reading, v, 0.0, C * v + r)
    if v * sign < 0:
        assert member.confidence == 1.0        # reversal of a yielded member
    z = (r - A * K * reading) / HK
    expected = tangent_cf(z, 1.0 if v >= 0 else -1.0)
    assert member.estimates()['tangent_stiffness_N_per_m'] == pytest.approx(expected,
                                                                            rel=1e-12)
    if member.confidence == 1.0:
        assert member.tangent_ahead(0.0) == pytest.approx(expected, rel=1e-12)


def test_tangent_ahead_with_the_velocity_reaching_zero_at_the_horizon():
    """v = 0.1 m/s, a = -20 m/s^2, h = 5 ms: v + a h is exactly 0 (no reversal inside);
    the path is 0.25 mm on the loading branch, the tangent on the positive branch."""
    member = HystereticMember(guess(), DT, identify=False)
    reading, r = list(load_member(member, 0.003, 0.005))[-1]
    member.observe(reading, 0.1, -20.0, M * -20.0 + C * 0.1 + r)
    z = branch_z((r - A * K * reading) / HK, 0.1 * 0.005 - 10.0 * 0.005 ** 2, 1.0)
    assert member.tangent_ahead(0.005) == pytest.approx(tangent_cf(z, 1.0), rel=1e-6)


def test_member_before_any_sample_and_after_a_nan():
    """At rest before the first sample: the tangent ahead and now is k. A NaN displacement is
    kept as the latest reading but moves neither z nor the evidence."""
    member = HystereticMember(guess(), DT)
    assert member.tangent_ahead(0.005) == K
    assert member.estimates()['tangent_stiffness_N_per_m'] == K
    states = list(load_member(member, 0.003, 0.005))
    z, confidence = member.z, member.confidence
    member.observe(math.nan, 0.05, 0.0, C * 0.05 + states[-1][1])
    assert math.isnan(member.displacement_m)
    assert member.z == z and member.confidence == confidence


def test_member_observes_a_measurement_message():
    """observe_measurement() is observe() with the message's fields."""
    from seft_msgs_py.interface import Measurement
    by_message = HystereticMember(guess(), DT, identify=False)
    by_value = HystereticMember(guess(), DT, identify=False)
    for j in range(30):
        x, v, acc = j * STEP_M, 0.05, 3.0 - 0.2 * j
        f = M * acc + C * v + r_virgin(x)
        by_message.observe_measurement(Measurement(j, j * DT, x, v, acc, f))
        by_value.observe(x, v, acc, f)
        assert (by_message.z, by_message.confidence) == (by_value.z, by_value.confidence)
    assert by_message.displacement_m == x and by_message.velocity_m_s == v
    assert by_message.acceleration_m_s2 == acc
    assert by_message.restoring_force_N == pytest.approx(r_virgin(x), rel=1e-12)
    assert by_message.has_yielded


def test_member_identifies_by_default_and_its_model_is_the_identified_one():
    """HystereticMember(guess, dt) identifies: after the plant's member with D_y 6 mm
    (guess 4 mm) the member's model (and so its tangent and estimates) has D_y within 3 %;
    identify=False keeps the guess and has no identifier."""
    specimen = BoucWenSpecimen(M, C, K, yield_displacement_m=0.006)
    x, v, r = plant_history(specimen, seconds=4.0)
    member = HystereticMember(guess(), DT)
    fixed = HystereticMember(guess(), DT, identify=False)
    for xi, vi, ri in zip(x, v, r):
        member.observe(xi, vi, 0.0, C * vi + ri)
        fixed.observe(xi, vi, 0.0, C * vi + ri)
    assert member.estimates()['hysteresis_yield_displacement_m'] == pytest.approx(0.006,
                                                                                 rel=0.03)
    assert member.model.yield_displacement_m == member.identifier.parameters()[2]
    assert fixed.identifier is None and fixed.model.yield_displacement_m == DY
