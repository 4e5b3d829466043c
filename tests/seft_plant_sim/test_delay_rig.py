"""Tests of the pure-delay rig (paper Sec. 5.2, Eqs. 5.1-5.2) against independent references.

The linear specimen against ``scipy.signal.lsim`` and the closed-form step response of the
SDOF; the hysteretic (Bouc-Wen) specimen against ``scipy.integrate.solve_ivp`` (DOP853) of
its equations typed anew here, under the same held, delayed force.
"""

import math

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_FORCE, Rig
from seft_msgs_py.parameters import defaults
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.specimen import BoucWenSpecimen, LinearSpecimen, SafetyLimits

DT = 0.002
MASS = 52.7


@pytest.fixture(scope='module')
def specimen():
    """The reference study's mass-spring system (paper Sec. 3.1), c = 17.14 m."""
    return LinearSpecimen(MASS, 17.14 * MASS, 2.11e5)


@pytest.mark.parametrize('tau, lag_steps', [
    (0.01, 5),          # the reference study: 5 whole steps
    (0.002, 1),         # one step
    (0.005, 3),         # 2.5 steps: f_r(t_k - tau) is the value held since t_k-3
    (0.0013, 1),        # below one step
])
def test_measured_force_is_delayed_reference(specimen, tau, lag_steps, drive):
    fr = np.random.default_rng(3).standard_normal(200) * 1000.0
    out = drive(DelayRig(specimen, DT, tau), fr)
    np.testing.assert_array_equal(out[lag_steps:, 0], fr[:-lag_steps])
    np.testing.assert_array_equal(out[:lag_steps, 0], 0.0)


@pytest.mark.parametrize('tau, substeps', [
    (0.01, 1),          # 5 whole steps
    (0.005, 2),         # 2.5 steps
    (0.003, 2),         # 1.5 steps: the late force is the newest of the history
    (0.0013, 20),       # below one step: the late force is the command being applied
])
def test_specimen_response_matches_lsim(specimen, tau, substeps, drive):
    """x, v and a equal scipy.signal.lsim of the SDOF under the delayed, held force."""
    n = 400
    fr = np.random.default_rng(5).standard_normal(n) * 1000.0
    out = drive(DelayRig(specimen, DT, tau), fr)
    h = DT / substeps
    lag = int(round(tau / h))
    assert abs(lag * h - tau) < 1e-12
    fine = np.concatenate([np.zeros(lag), np.repeat(fr, substeps)])[:n * substeps]
    a, b = specimen.state_space()
    sys = signal.StateSpace(a, b, np.eye(2), np.zeros((2, 1)))
    t = np.arange(n * substeps) * h
    _, y, _ = signal.lsim(sys, fine, t, interp=False)
    x_ref, v_ref = y[::substeps, 0], y[::substeps, 1]
    f_ref = fine[::substeps]                      # force held from t_k on (t_k+)
    a_ref = (f_ref - specimen.damping_N_s_per_m * v_ref
             - specimen.stiffness_N_per_m * x_ref) / MASS
    for got, ref in ((out[:, 1], x_ref), (out[:, 2], v_ref), (out[:, 3], a_ref)):
        assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_protocol_and_limits(specimen):
    rig = DelayRig(specimen, DT, 0.01)
    assert isinstance(rig, Rig)
    assert rig.command_kind == COMMAND_FORCE
    for _ in range(5):
        assert rig.limit_violation() is None
        rig.apply(30e3)
    # the first 30 kN reaches the specimen tau = 10 ms later
    reason = rig.limit_violation()
    assert reason == 'force limit exceeded at t=0.010 s: |f|=3e+04 N > 24500 N'


def test_from_parameters(specimen):
    values = defaults()
    values.update(rig_model='delay', tau_s=0.006, noise_force_N=1.0)
    rig = DelayRig.from_parameters(values)
    assert (rig.dt, rig.tau_s, rig.specimen) == (0.002, 0.006, specimen)
    assert (rig._n, rig._delta) == (3, 0.0)
    assert rig.sensors.noise_force_N == 1.0


@pytest.mark.parametrize('dt, tau, match', [
    (0.0, 0.01, r'^parameter dt=0\.0: expected float > 0$'),
    (-0.002, 0.01, r'^parameter dt=-0\.002: expected float > 0$'),
    (float('nan'), 0.01, r'^parameter dt=nan: expected float > 0$'),
    (DT, 0.0, r'^parameter tau_s=0\.0: expected float > 0$'),
    (DT, -0.01, r'^parameter tau_s=-0\.01: expected float > 0$'),
    (DT, float('nan'), r'^parameter tau_s=nan: expected float > 0$'),
])
def test_parameter_errors(specimen, dt, tau, match):
    with pytest.raises(ParameterError, match=match):
        DelayRig(specimen, dt, tau)


def test_infinite_delay_is_a_parameter_error(specimen):
    with pytest.raises(ParameterError, match=r'parameter tau_s=inf'):
        DelayRig(specimen, DT, float('inf'))


@pytest.mark.parametrize('tau', [1e-12, 1.9e-12])
def test_a_delay_that_rounds_to_none_is_a_parameter_error(specimen, tau):
    """Under 1e-9 dt (2e-12 s) a delay rounds to 0 whole steps and no remainder: the force of
    step k would act at t_k+, before its command is known (the rig measured NaN forces before
    this was refused; the stability check's model: test_stability.py)."""
    match = (rf'^parameter tau_s={tau!r}: expected float > 0 \(at least 1e-09 dt = 2e-12 s: '
             r'shorter rounds to no delay\)$')
    with pytest.raises(ParameterError, match=match):
        DelayRig(specimen, DT, tau)


def test_the_shortest_delay_measures_the_previous_command(specimen, drive):
    """Just above 1e-9 dt (2.1e-12 s: 0 whole steps, remainder 2.1e-12 s) f_m[k] = f_r(t_k -
    tau) is the command held over the previous step, f_r[k-1], and the specimen moves as under
    the command without delay (lsim with the force of step k over [t_k, t_k+1)) to 1e-8 of
    its peak: ten times the share of a step the previous force still acts, 2.1 ps / 2 ms."""
    fr = np.random.default_rng(7).standard_normal(200) * 1000.0
    out = drive(DelayRig(specimen, DT, 2.1e-12), fr)
    np.testing.assert_array_equal(out[1:, 0], fr[:-1])
    assert out[0, 0] == 0.0
    a, b = specimen.state_space()
    sys = signal.StateSpace(a, b, np.eye(2), np.zeros((2, 1)))
    _, y, _ = signal.lsim(sys, fr, np.arange(len(fr)) * DT, interp=False)
    for got, ref in ((out[:, 1], y[:, 0]), (out[:, 2], y[:, 1])):
        assert np.max(np.abs(got - ref)) <= 1e-8 * np.max(np.abs(ref))


def test_readings_carry_the_sample_step_and_time(specimen):
    rig = DelayRig(specimen, DT, 0.01)
    for _ in range(3):
        rig.apply(100.0)
    m = rig.measure()
    assert (m.step, rig.step) == (3, 3)
    assert m.time_s == pytest.approx(3 * DT, rel=1e-12) == rig.time_s


def test_stroke_limit_at_the_closed_form_step_response(specimen):
    """20 kN held from t = 0 reaches the specimen at tau = 10 ms; the stroke limit trips at the
    first sample where the SDOF step response exceeds 76 mm.

    x(t) = (F/k) (1 - e^{-zeta w t'} (cos w_d t' + zeta/sqrt(1 - zeta^2) sin w_d t')), with
    t' = t - tau, w = sqrt(k/m), zeta = c/(2 sqrt(k m)), w_d = w sqrt(1 - zeta^2): static
    94.8 mm, so the response crosses 76 mm on its first rise (force 20 kN < 24.5 kN limit).
    """
    force, tau, stroke = 20e3, 0.01, 0.076
    m, c, k = MASS, specimen.damping_N_s_per_m, specimen.stiffness_N_per_m
    w = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w * math.sqrt(1 - zeta ** 2)

    def x_exact(t):
        tp = max(t - tau, 0.0)
        return force / k * (1 - math.exp(-zeta * w * tp) * (
            math.cos(wd * tp) + zeta / math.sqrt(1 - zeta ** 2) * math.sin(wd * tp)))

    k_trip = next(i for i in range(1000) if x_exact(i * DT) > stroke)
    assert x_exact((k_trip - 1) * DT) < stroke - 1e-3 < stroke + 1e-3 < x_exact(k_trip * DT)
    rig = DelayRig(specimen, DT, tau)
    for i in range(k_trip):
        assert rig.limit_violation() is None, i
        rig.apply(force)
    assert rig.limit_violation() == (f'stroke limit exceeded at t={k_trip * DT:.3f} s: '
                                     f'|x|={x_exact(k_trip * DT):.4g} m > 0.076 m')


# -- the hysteretic (Bouc-Wen) specimen --------------------------------------------------------

@pytest.fixture(scope='module')
def bouc_wen():
    """The default hysteretic specimen: k = 2.11e5 N/m, D_y = 4 mm, a = 0.1, n = 2,
    beta = gamma = 0.5 (yield force k D_y = 844 N)."""
    return BoucWenSpecimen(MASS, 17.14 * MASS, 2.11e5)


def bouc_wen_rates(spec):
    """``[x, x', z]' `` of ``m x'' + c x' + a k x + (1-a) k D_y z = f`` with the Bouc-Wen rate
    ``z' = (x'/D_y)(1 - |z|^n (beta sgn(x' z) + gamma))`` (Bouc 1967, Wen 1976), typed from
    the equations (not from the code's coefficients)."""
    m, c, k = spec.mass_kg, spec.damping_N_s_per_m, spec.stiffness_N_per_m
    a, dy, n = spec.post_yield_stiffness_ratio, spec.yield_displacement_m, spec.bouc_wen_n
    beta, gamma = spec.bouc_wen_beta, spec.bouc_wen_gamma

    def rates(t, s, f):
        x, v, z = s
        restoring = a * k * x + (1 - a) * k * dy * z
        zdot = v / dy * (1 - abs(z) ** n * (beta * np.sign(v * z) + gamma))
        return [v, (f - c * v - restoring) / m, zdot]

    return rates


def hysteretic_reference(spec, forces, tau):
    """States ``[x, x', z]`` at t_k and the force acting at t_k+ under the reference forces
    held over each step and delayed by tau = n dt + delta (paper Eq. 5.2): f_r[k-n-1] over
    [t_k, t_k + delta), f_r[k-n] over [t_k + delta, t_k+1). DOP853 on each piece, rtol 1e-12.
    """
    n = int(math.floor(tau / DT + 1e-9))
    delta = tau - n * DT
    held = np.concatenate([np.zeros(n + 1), forces])       # held[j + n + 1] = f_r[j]
    rates = bouc_wen_rates(spec)
    s = np.zeros(3)
    states, acting = [], []
    for k in range(len(forces)):
        states.append(s)
        acting.append(held[k] if delta > 0 else held[k + 1])
        for f, h in ((held[k], delta), (held[k + 1], DT - delta)):
            if h > 0:
                s = solve_ivp(rates, (0.0, h), s, args=(f,), method='DOP853', rtol=1e-12,
                              atol=1e-15).y[:, -1]
    return np.array(states), np.array(acting)


def yielding_forces(n=300):
    """A 2 Hz sine of 2 kN (2.4 times the yield force), ramped in over 0.3 s."""
    t = np.arange(n) * DT
    return 2000.0 * np.sin(2 * np.pi * 2.0 * t) * np.minimum(1.0, t / 0.3)


@pytest.mark.parametrize('tau, shape', [
    (0.0135, {}),
    (0.003, {}),
    (0.004, {}),
    (0.0135, {'bouc_wen_n': 3.0, 'bouc_wen_beta': 0.7, 'bouc_wen_gamma': 0.1}),
])
def test_hysteretic_response_matches_ode_solution(bouc_wen, tau, shape):
    """x, x', z, f and a of the RK4 rig against DOP853 of the Bouc-Wen SDOF (independent
    integrator, its own reversal handling), while the specimen yields (|z| -> z_max); the
    default shape (n = 2, beta = gamma) and a sharper, asymmetric one (n = 3, z_max = 1.17).

    Tolerance 1e-6 of each peak: the rig's RK4 at 0.2 ms converges to about 1e-8 (class
    notes); a wrong coefficient, substep or force ordering gives errors of 1e-3 or more.
    """
    if shape:
        bouc_wen = BoucWenSpecimen(MASS, 17.14 * MASS, 2.11e5, **shape)
    forces = yielding_forces()
    ref, acting = hysteretic_reference(bouc_wen, forces, tau)
    rig = DelayRig(bouc_wen, DT, tau)
    got = []
    for f in forces:
        m = rig.measure()
        got.append((m.displacement_m, m.velocity_m_s, rig.hysteretic_z, m.force_N,
                    m.acceleration_m_s2))
        rig.apply(f)
    got = np.array(got)
    x, v, z = ref.T
    k, a = bouc_wen.stiffness_N_per_m, bouc_wen.post_yield_stiffness_ratio
    dy = bouc_wen.yield_displacement_m
    accel = (acting - bouc_wen.damping_N_s_per_m * v - a * k * x
             - (1 - a) * k * dy * z) / MASS                 # paper Eq. 5.1, Bouc-Wen spring
    zmax = (bouc_wen.bouc_wen_beta + bouc_wen.bouc_wen_gamma) ** (-1 / bouc_wen.bouc_wen_n)
    assert np.max(np.abs(z)) > 0.95 * zmax                   # it yields
    for col, want in enumerate((x, v, z, acting, accel)):
        assert np.max(np.abs(got[:, col] - want)) <= 1e-6 * np.max(np.abs(want)), col
    # after the last step the acting force is f_r(t_N - tau) = f_r[N - n - 1] (delta > 0)
    # or f_r[N - n] (delta = 0), with N = len(forces) and tau = n dt + delta
    n_whole = int(math.floor(tau / DT + 1e-9))
    late = 0 if tau - n_whole * DT > 1e-12 else 1
    assert rig.true_force() == forces[len(forces) - n_whole - 1 + late]


def test_hysteretic_substeps(bouc_wen, drive):
    """The default is the documented 10 RK4 substeps per step; 1 substep is allowed, and fewer
    than one or a non-integer count is a parameter error."""
    forces = yielding_forces(100)
    default = drive(DelayRig(bouc_wen, DT, 0.0135), forces)
    np.testing.assert_array_equal(default, drive(DelayRig(bouc_wen, DT, 0.0135, rk4_substeps=10),
                                               forces))
    assert np.max(np.abs(default - drive(DelayRig(bouc_wen, DT, 0.0135, rk4_substeps=11),
                                       forces))) > 0.0
    one = drive(DelayRig(bouc_wen, DT, 0.0135, rk4_substeps=1), forces)
    assert np.max(np.abs(one - default)) < 1e-3 * np.max(np.abs(default))
    for bad in (0, -1, 2.5):
        with pytest.raises(ParameterError,
                           match=rf'^parameter rk4_substeps={bad!r}: expected int >= 1$'):
            DelayRig(bouc_wen, DT, 0.01, rk4_substeps=bad)


def test_from_parameters_hysteretic_limits_and_substeps(bouc_wen, drive):
    """The specimen, the limits and the substeps reach the rig built from the parameters."""
    values = defaults()
    values.update(rig_model='delay', tau_s=0.0135, specimen_model='bouc_wen',
                  stroke_limit_m=0.05, force_limit_N=3000.0)
    rig = DelayRig.from_parameters(values, rk4_substeps=3)
    assert rig.specimen == bouc_wen
    assert rig.limits == SafetyLimits(0.05, 3000.0)
    forces = yielding_forces(100)
    np.testing.assert_array_equal(
        drive(rig, forces), drive(DelayRig(bouc_wen, DT, 0.0135, rk4_substeps=3), forces))
    np.testing.assert_array_equal(
        drive(DelayRig.from_parameters(values), forces),
        drive(DelayRig(bouc_wen, DT, 0.0135), forces))
