"""Tests of the hysteretic (Bouc-Wen) specimen and of the rigs' RK4 stepping with it."""

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import resolve
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.rigs import make_rig
from seft_plant_sim.servohydraulic import ServoHydraulicParams, ServoHydraulicRig
from seft_plant_sim.specimen import (
    BoucWenSpecimen,
    LinearSpecimen,
    make_specimen,
    rk4_hysteretic,
    rk4_step,
    substeps,
)

DT = 0.002
MASS = 52.7
C = 17.14 * MASS
K = 2.11e5
DY = 0.004


@pytest.fixture(scope='module')
def bouc_wen():
    """The default hysteretic specimen: k = 2.11e5 N/m, D_y = 4 mm, a = 0.1, n = 2."""
    return BoucWenSpecimen(MASS, C, K)


def run(rig, commands):
    """Apply the commands one step each; return [f, x, v, a, z] before each step."""
    rows = []
    for u in commands:
        m = rig.measure()
        z = getattr(rig, 'hysteretic_z', None)
        rows.append((m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2,
                     0.0 if z is None else z))
        rig.apply(u)
    return np.array(rows)


def rel(got, ref):
    """Largest difference per column relative to the reference's peak."""
    return np.max(np.abs(got - ref), axis=0) / np.maximum(np.max(np.abs(ref), axis=0), 1e-300)


def quake(n, amplitude_N, seed=7):
    """A band-limited random force history (0.5-15 Hz content), peak `amplitude_N`."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    f = sum(rng.standard_normal() * np.sin(2 * np.pi * fr * t + rng.uniform(0, 6.3))
            for fr in (0.7, 1.6, 2.9, 4.1, 6.3, 9.8, 14.0))
    f *= np.minimum(1.0, t / 0.5) * np.exp(-np.maximum(t - 3.0, 0.0) / 2.0)
    return f * amplitude_N / np.max(np.abs(f))


def cyclic_path(amplitude_m, cycles, points_per_cycle=4000):
    """Quasi-static displacement history: a sine of growing amplitude, then full cycles."""
    s = np.linspace(0.0, cycles, cycles * points_per_cycle + 1)
    return amplitude_m * np.sin(2 * np.pi * s)


def integrate_z(specimen, x):
    """z along a displacement path: RK4 in x of dz/dx = z'(v, z)/v (rate independent)."""
    z = np.zeros_like(x)
    for i in range(x.shape[0] - 1):
        dx = x[i + 1] - x[i]
        v = 1.0 if dx >= 0 else -1.0           # any velocity of the right sign
        zi = z[i]
        k1 = specimen.hysteretic_rate(v, zi) / v
        k2 = specimen.hysteretic_rate(v, zi + 0.5 * dx * k1) / v
        k3 = specimen.hysteretic_rate(v, zi + 0.5 * dx * k2) / v
        k4 = specimen.hysteretic_rate(v, zi + dx * k3) / v
        z[i + 1] = zi + dx / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return z


# -- the constitutive model -----------------------------------------------------------------

def test_parameters_and_derived_values(bouc_wen):
    assert bouc_wen.yield_force_N == pytest.approx(844.0)
    assert bouc_wen.z_max == pytest.approx(1.0)
    assert bouc_wen.natural_frequency_hz == pytest.approx(10.07, abs=0.01)
    assert bouc_wen.linearized() == LinearSpecimen(MASS, C, K)
    spec = BoucWenSpecimen(MASS, C, K, bouc_wen_n=3.0, bouc_wen_beta=0.6, bouc_wen_gamma=-0.2)
    assert spec.z_max == pytest.approx(0.4 ** (-1 / 3))


@pytest.mark.parametrize('overrides, match', [
    ({'post_yield_stiffness_ratio': -0.1}, 'post_yield_stiffness_ratio=-0.1'),
    ({'post_yield_stiffness_ratio': 1.5}, 'post_yield_stiffness_ratio=1.5'),
    ({'yield_displacement_m': 0.0}, 'yield_displacement_m=0.0'),
    ({'bouc_wen_n': 0.5}, 'bouc_wen_n=0.5'),
    ({'bouc_wen_beta': 0.2, 'bouc_wen_gamma': 0.5}, 'bouc_wen_beta >= bouc_wen_gamma'),
    ({'bouc_wen_beta': -0.5, 'bouc_wen_gamma': -0.5}, 'bouc_wen_beta=-0.5'),
    ({'bouc_wen_gamma': float('nan')}, 'bouc_wen_gamma=nan'),
    ({'stiffness_N_per_m': 0.0}, 'stiffness_N_per_m=0.0'),
])
def test_bad_parameters_raise(overrides, match):
    kwargs = dict(mass_kg=MASS, damping_N_s_per_m=C, stiffness_N_per_m=K)
    kwargs.update(overrides)
    with pytest.raises(ParameterError, match=match):
        BoucWenSpecimen(**kwargs)


def test_make_specimen_dispatches_on_specimen_model():
    params = resolve({})
    assert make_specimen(params) == LinearSpecimen(MASS, C, K)
    assert make_specimen({k: v for k, v in params.items() if k != 'specimen_model'}) == \
        LinearSpecimen(MASS, C, K)
    spec = make_specimen(resolve({'specimen_model': 'bouc_wen', 'yield_displacement_m': 0.01}))
    assert spec == BoucWenSpecimen(MASS, C, K, yield_displacement_m=0.01)
    with pytest.raises(ParameterError, match="specimen_model='plastic': expected one of"):
        make_specimen({**params, 'specimen_model': 'plastic'})


def test_virgin_loading_curve_is_tanh(bouc_wen):
    # n = 2, beta + gamma = 1: dz/dx = (1 - z^2)/D_y on loading, so z = tanh(x/D_y) exactly.
    x = np.linspace(0.0, 5 * DY, 5001)
    z = integrate_z(bouc_wen, x)
    np.testing.assert_allclose(z, np.tanh(x / DY), rtol=0, atol=1e-10)
    force = bouc_wen.restoring_force(x, z)
    np.testing.assert_allclose(force, 0.1 * K * x + 0.9 * K * DY * np.tanh(x / DY), rtol=1e-9)


def test_cyclic_loop_yields_and_dissipates(bouc_wen):
    x = cyclic_path(5 * DY, 3)
    z = integrate_z(bouc_wen, x)
    force = bouc_wen.restoring_force(x, z)
    last = slice(2 * 4000, 3 * 4000 + 1)                       # the third (stable) cycle
    hysteretic = force - 0.1 * K * x                            # (1-a) k D_y z
    # strength of the hysteretic spring at the displacement peaks: (1-a) k D_y z_max
    assert np.max(hysteretic[last]) == pytest.approx(0.9 * K * DY, rel=2e-3)
    assert np.min(hysteretic[last]) == pytest.approx(-0.9 * K * DY, rel=2e-3)
    assert np.max(np.abs(z)) <= bouc_wen.z_max
    # dissipated energy of one cycle: positive, below the elastic-perfectly-plastic bound
    # 4 F_y (X - D_y) of a spring with the same strength and initial stiffness, and above
    # half of it (the smooth knee with n = 2 loses some of the rectangle's area)
    energy = np.trapezoid(force[last], x[last])
    epp = 4 * 0.9 * K * DY * (5 * DY - DY)
    assert 0.5 * epp < energy < epp
    # beta = gamma: unloading from a displacement peak at the initial stiffness k
    peak = np.argmax(x[last]) + last.start
    tangent = (force[peak + 5] - force[peak]) / (x[peak + 5] - x[peak])
    assert tangent == pytest.approx(K, rel=1e-3)


def test_small_amplitude_equals_linear_specimen(bouc_wen):
    """At 1 % of D_y the hysteretic rigs reproduce the linear rigs to 1e-3."""
    f = quake(1500, 0.01 * K * DY)
    for make in (lambda s: DelayRig(s, DT, 0.01), lambda s: ServoHydraulicRig(s, DT)):
        # valve volts: 1/400 V per N in the 'si' reading of Eq. 3.1, 4.448 times less in the
        # default 'us_customary' reading (its valve passes 4.448 times the flow per volt)
        commands = f if isinstance(make(bouc_wen), DelayRig) else f / (400.0 * 4.4482216)
        lin = run(make(LinearSpecimen(MASS, C, K)), commands)
        hys = run(make(bouc_wen), commands)
        assert np.max(np.abs(lin[:, 1])) < 0.02 * DY
        assert np.all(rel(hys[:, :4], lin[:, :4]) < 1e-3)


# -- the rigs' RK4 stepping -------------------------------------------------------------------

@pytest.mark.parametrize('tau', [0.01, 0.0135, 0.0013])
def test_delay_rig_with_linear_bouc_wen_matches_exact_rig(tau):
    """a = 1 makes f_s = k x: the RK4 rig reproduces the exact (ZOH) rig, timing included."""
    f = quake(1500, 1000.0)
    exact = run(DelayRig(LinearSpecimen(MASS, C, K), DT, tau), f)
    rk4 = run(DelayRig(BoucWenSpecimen(MASS, C, K, post_yield_stiffness_ratio=1.0), DT, tau),
              f)
    assert np.all(rel(rk4[:, :4], exact[:, :4]) < 1e-7)


@pytest.mark.parametrize('params', [
    ServoHydraulicParams(),
    ServoHydraulicParams(io_latency_s=0.004, anti_alias_cutoff_hz=60.0),
])
def test_servo_rig_with_linear_bouc_wen_matches_exact_rig(params):
    u = quake(1500, 2.0)
    exact = run(ServoHydraulicRig(LinearSpecimen(MASS, C, K), DT, params), u)
    spec = BoucWenSpecimen(MASS, C, K, post_yield_stiffness_ratio=1.0)
    rk4 = run(ServoHydraulicRig(spec, DT, params), u)
    assert np.all(rel(rk4[:, :4], exact[:, :4]) < 1e-6)


def test_rk4_stepping_converges(bouc_wen):
    """Halving the substep changes a yielding response by less than 1e-6 (relative)."""
    f = quake(2000, 1500.0)
    u = quake(2000, 8.0)
    cases = [
        (lambda n: DelayRig(bouc_wen, DT, 0.0135, rk4_substeps=n), f, 10),
        (lambda n: ServoHydraulicRig(bouc_wen, DT, rk4_substeps=n), u, 20),
    ]
    for make, commands, default in cases:
        coarse = run(make(default), commands)
        fine = run(make(2 * default), commands)
        assert np.max(np.abs(fine[:, 1])) > 2 * DY                 # it yields
        assert np.max(np.abs(fine[:, 4])) > 0.99 * bouc_wen.z_max
        assert np.all(rel(coarse, fine) < 1e-6)
        np.testing.assert_array_equal(run(make(default), commands[:50]), coarse[:50])


def test_reversal_location_beats_plain_rk4(bouc_wen):
    """Locating velocity reversals makes RK4 far more accurate than the plain sgn(x' z) rate.

    At a reversal the tangent stiffness jumps from the post-yield to the unloading value, a
    jump in the derivative of the rate that plain RK4 steps straight across.
    """
    inv_m, c, ak, bk, inv_dy, n, beta, gamma = bouc_wen.coefficients()

    def rates(s, f, direction):
        x, v, z = s
        az = abs(z)
        return [v, (f - c * v - ak * x - bk * z) * inv_m,
                v * inv_dy * (1 - az ** (n - 1) * (beta * direction * z + gamma * az))]

    def plain(s, f, direction):
        x, v, z = s
        return [v, (f - c * v - ak * x - bk * z) * inv_m, bouc_wen.hysteretic_rate(v, z)]

    def response(h, located=True):
        step = rk4_step(rates if located else plain)
        s = [0.0, 0.0, 0.0]
        n_force = int(round(0.25 / h))
        for k in range(2 * n_force):                         # 1500 N for 0.25 s, then free
            f = 1500.0 if k < n_force else 0.0
            s = rk4_hysteretic(step, s, f, h, 1) if located else step(s, f, h, 1.0)
        return np.array(s) / [DY, 0.1, 1.0]

    ref = response(1e-3 / 64)
    assert abs(ref[2]) > 0.5                                 # it yielded and reversed
    for h in (1e-3, 5e-4):
        located = np.max(np.abs(response(h) - ref))
        plain_error = np.max(np.abs(response(h, located=False) - ref))
        assert located < 1e-6
        assert located < plain_error / 20.0


def test_substeps_split_the_fractional_delay():
    assert substeps(0.002, 0.0, 10) == (0, 0.0, 10, pytest.approx(0.0002))
    n_e, h_e, n_l, h_l = substeps(0.002, 0.0005, 10)
    assert (n_e, n_l) == (3, 8)
    assert n_e * h_e + n_l * h_l == pytest.approx(0.002)
    assert max(h_e, h_l) <= 0.0002 + 1e-15


def test_make_rig_builds_hysteretic_rigs_and_linear_default_is_unchanged():
    base = resolve({'rig_model': 'delay'})
    assert make_rig(base).hysteretic_z is None
    rig = make_rig({**base, 'specimen_model': 'bouc_wen'})
    assert isinstance(rig.specimen, BoucWenSpecimen) and rig.hysteretic_z == 0.0
    servo = make_rig(resolve({'specimen_model': 'bouc_wen', 'bouc_wen_n': 1.0}))
    assert servo.specimen.bouc_wen_n == 1.0
    assert servo.state.shape == (4,)
    # the linear path: absent specimen_model and 'linear' give the same samples bit for bit
    f = quake(300, 1000.0)
    legacy = {k: v for k, v in base.items() if k != 'specimen_model'}
    np.testing.assert_array_equal(run(make_rig(legacy), f), run(make_rig(base), f))
    with pytest.raises(ParameterError, match='rk4_substeps=0'):
        DelayRig(BoucWenSpecimen(MASS, C, K), DT, 0.01, rk4_substeps=0)
    with pytest.raises(ParameterError, match='rk4_substeps=0'):
        ServoHydraulicRig(BoucWenSpecimen(MASS, C, K), DT, rk4_substeps=0)


def test_limits_and_measurement_of_hysteretic_rigs(bouc_wen):
    rig = DelayRig(bouc_wen, DT, 0.002)
    for _ in range(3):
        rig.apply(5000.0)
    m = rig.measure()
    x, v, z = rig._state
    assert m.force_N == 5000.0
    assert m.acceleration_m_s2 == pytest.approx(
        (5000.0 - C * v - bouc_wen.restoring_force(x, z)) / MASS, rel=1e-12)
    rig = DelayRig(bouc_wen, DT, 0.002)
    for _ in range(2):
        rig.apply(30e3)
    assert 'force limit' in rig.limit_violation()
    servo = ServoHydraulicRig(bouc_wen, DT)
    for _ in range(20):
        servo.apply(1.0)
    y = servo.outputs()
    x, v, p, _, z = servo._s
    assert y[0] == pytest.approx(servo.params.piston_area_m2 * p) == servo.true_force()
    assert y[1] == pytest.approx(
        (servo.true_force() - C * v - bouc_wen.restoring_force(x, z)) / MASS, rel=1e-12)
    assert servo.limit_violation() is None
