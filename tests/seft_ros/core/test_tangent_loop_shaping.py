"""The tangent-scheduled loop shaping (``force_controller: tangent_loop_shaping``, issue 10)
as a unit: its recursion against the docstring's trapezoidal equations written here, its frozen
designs against scipy's prewarped bilinear transform, its scheduling against the member model
(whose closed forms test_hysteresis.py checks) and against the rig model's loops. The closed
loops with simulate() are in test_tangent_controller.py."""

import math
import re

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py import parameters
from seft_msgs_py.calibration import controller_gain_V_per_N
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.servohydraulic import ServoHydraulicParams, closed_loop_force_response
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.core.controller import ForceServoController, TangentLoopShaping
from seft_ros.core.hysteresis import HystereticMember, MemberGuess

DT = 0.002
K = 2.11e5
TANGENT = dict(force_controller='tangent_loop_shaping')
YIELDING = dict(specimen_model='bouc_wen', rig_model='servohydraulic')
#: g [V/N] of paper Eq. 3.1 in the default reading (37 V/lbf) and the denominator's c1, w2:
#: the rig's own specimen's c/m and k/m (the study's: 17.14 and 4003.8; Eq. 3.1 rounds 4002).
G = controller_gain_V_per_N(parameters.defaults())
C1, W2 = 903.278 / 52.7, K / 52.7


def controller(**kw):
    return ForceServoController.from_parameters(dict(parameters.defaults(), **TANGENT, **kw))


def held(ctrl: TangentLoopShaping, rho: float) -> TangentLoopShaping:
    """The controller with its tangent stiffness held at rho k (the member model bypassed)."""
    ctrl.member.tangent_ahead = lambda horizon: rho * ctrl.member.model.stiffness_N_per_m
    return ctrl


def test_from_parameters_builds_the_scheduled_design():
    ctrl = controller()
    assert isinstance(ctrl, TangentLoopShaping) and ctrl.kind == 'tangent_loop_shaping'
    assert ctrl.uses_motion and ctrl.horizon_s == 0.005
    # the nominal (elastic) design cancels the rig's own specimen: the discrete C_f of
    # specimen_loop_shaping, (1, c/m, k/m) = (1, 17.14, 4003.8) for the study's specimen
    base = ForceServoController.from_parameters(dict(parameters.defaults(),
                                                     force_controller='specimen_loop_shaping'))
    np.testing.assert_allclose(ctrl.bz, base.bz, rtol=1e-15)
    np.testing.assert_allclose(ctrl.az, base.az, rtol=1e-15)
    assert ctrl.design.den == pytest.approx((1.0, 17.14, 2.11e5 / 52.7), rel=1e-12)


@pytest.mark.parametrize('stiffness_N_per_m', [1.5e5, 2.5e5])
def test_the_design_cancels_the_rigs_own_member(stiffness_N_per_m):
    """Session 23's D1: the controller cancelled the study's specimen (1, 17.14, 4002)
    whatever the rig's k, so a member 18 % stiffer erred 10x more. Its elastic design, the
    design the stability guard and the compensators' force-loop model use
    (ForceServoController.from_parameters), and every frozen design are the rig's own
    (1, c/m, rho k/m)."""
    p = dict(parameters.defaults(), **TANGENT, stiffness_N_per_m=stiffness_N_per_m,
             mass_kg=60.0, damping_N_s_per_m=950.0)
    ctrl = ForceServoController.from_parameters(p)
    own = ForceServoController.from_parameters(dict(p, force_controller='specimen_loop_shaping'))
    assert ctrl.design.den == pytest.approx((1.0, 950.0 / 60.0, stiffness_N_per_m / 60.0),
                                            rel=1e-12)
    np.testing.assert_allclose(ctrl.az, own.az, rtol=1e-15)
    np.testing.assert_allclose(ctrl.frozen(1.0).az, own.az, rtol=1e-12)
    half = ctrl.frozen(0.5).design.den
    assert half == pytest.approx((1.0, 950.0 / 60.0, 0.5 * stiffness_N_per_m / 60.0), rel=1e-12)


def test_elastic_member_gives_the_specimen_controller_to_rounding():
    """rho = 1: the trapezoidal state recursion is specimen_loop_shaping's filter (both Tustin
    at the period prewarped at sqrt(k/m) rad/s)."""
    ctrl = held(controller(valve_limit_V=1e6), 1.0)
    base = ForceServoController.from_parameters(dict(
        parameters.defaults(), valve_limit_V=1e6, force_controller='specimen_loop_shaping'))
    e = np.random.default_rng(1).normal(0, 200.0, 2000)
    got = np.array([ctrl.step(ek, 0.0) for ek in e])
    want = np.array([base.step(ek, 0.0) for ek in e])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.max(np.abs(want)))


@pytest.mark.parametrize('rho', [0.1, 0.47, 1.3])
def test_frozen_state_space_is_the_recursion_at_that_stiffness(rho):
    ctrl = held(controller(valve_limit_V=1e6), rho)
    a, b, c, d = ctrl.frozen(rho).state_space()
    e = np.random.default_rng(2).normal(0, 100.0, 500)
    x, ys = np.zeros(a.shape[0]), []
    for ek in e:
        w = np.array([ek, 0.0, 0.0])
        ys.append((c @ x + d @ w).item())
        x = a @ x + b @ w
    got = [ctrl.step(ek, 0.0) for ek in e]
    np.testing.assert_allclose(got, ys, rtol=0, atol=1e-9 * np.max(np.abs(ys)))


def test_scheduling_keeps_the_force_loop_whatever_the_tangent_stiffness():
    """The point of the design, from the rig model (paper Fig. 4 loops): with the member at
    k_t = rho k the study's C_f loses low-frequency tracking (|T| at 1 Hz: 0.983 at k, 0.717
    at 0.1 k), while C_f scheduled to rho keeps T within 3 % of the elastic loop up to
    20 Hz, the loop being g m k_q/(A s) below the oil column for every rho (what is left:
    the leakage's static gain A k_q/K over C_f(0) ~ 1/rho, so |T(0)| is 0.983 elastic and
    closer to 1 when yielded)."""
    rig = ServoHydraulicParams.from_parameters(parameters.defaults())
    f = np.linspace(0.5, 20.0, 40)
    ctrl = controller()
    base = ForceServoController.from_parameters(parameters.defaults())
    elastic = closed_loop_force_response(rig, LinearSpecimen(52.7, 903.278, K), base, f)
    for rho in (0.1, 0.3):
        spec = LinearSpecimen(52.7, 903.278, rho * K)
        fixed = closed_loop_force_response(rig, spec, base, f)
        scheduled = closed_loop_force_response(rig, spec, ctrl.frozen(rho), f)
        assert np.max(np.abs(scheduled / elastic - 1)) < 0.03
        assert np.max(np.abs(fixed[f <= 10.0] / elastic[f <= 10.0] - 1)) > 0.2
    one = [abs(closed_loop_force_response(rig, LinearSpecimen(52.7, 903.278, r * K), base,
                                          [1.0])[0]) for r in (1.0, 0.1)]
    assert one == pytest.approx([0.983, 0.717], abs=0.002)


def test_saturation_and_errors():
    ctrl = held(controller(valve_limit_V=0.5), 1.0)
    assert ctrl.step(1e5, 0.0) == 0.5 and ctrl.saturated
    assert ctrl.step(-1e7, 0.0) == -0.5 and ctrl.saturated
    with pytest.raises(ParameterError, match=re.escape(
            'parameter force_tangent_horizon_s=-0.001: expected float >= 0')):
        TangentLoopShaping(DT, member=controller().member, horizon_s=-0.001)
    with pytest.raises(ParameterError, match='tangent_loop_shaping: expected C_f'):
        TangentLoopShaping(DT, den=(1.0, 2.0), member=controller().member, horizon_s=0.0)


def test_frozen_loops_are_stable_over_the_whole_tangent_range():
    """The guard's linearizations of the yielding member (seft_ros.core.stability): with the
    scheduled controller the force loop alone (alpha = 0) has the same spectral radius at
    every frozen tangent stiffness."""
    from seft_ros.core.stability import LoopModel
    p = dict(parameters.resolve(dict(YIELDING, **TANGENT)))
    radii = [float(LoopModel(p, tangent_ratio=r).radii(0.0)[0]) for r in (1.0, 0.3, 0.1, 0.03)]
    assert max(radii) < 0.99
    assert max(radii) - min(radii) < 1e-3


# -- the recursion and its schedule --------------------------------------------------------------

def trapezoid_reference(errors, rhos, g=G, dt=DT):
    """u'' + c1 u' + w2 rho u = g e on the state s = (u, u'), by the trapezoidal rule at the
    period prewarped at w0 = sqrt(w2) (class notes), written here with numpy:
    s+ = (I - H A)^-1 ((I + H A) s + H B (e + e_prev)), H = tan(w0 dt/2)/w0 (half the
    prewarped period), A = [[0, 1], [-w2 rho, -c1]], B = (0, g), rho of the current sample."""
    w0 = math.sqrt(W2)
    h = math.tan(w0 * dt / 2) / w0
    s, e_prev, out = np.zeros(2), 0.0, []
    for e, rho in zip(errors, rhos):
        a = np.array([[0.0, 1.0], [-W2 * rho, -C1]])
        rhs = (np.eye(2) + h * a) @ s + h * np.array([0.0, g]) * (e + e_prev)
        s = np.linalg.solve(np.eye(2) - h * a, rhs)
        e_prev = e
        out.append(s[0])
    return np.array(out)


def scheduled(ctrl: TangentLoopShaping, ratios) -> TangentLoopShaping:
    """The controller with its member's tangent ahead held at ratios[j] k at step j."""
    it = iter(ratios)
    ctrl.member.tangent_ahead = lambda horizon: next(it) * ctrl.member.model.stiffness_N_per_m
    return ctrl


def test_step_is_the_trapezoidal_recursion_with_the_current_stiffness():
    """A stiffness ratio that moves every sample between 0.1 and 1.9 and a force error
    f_r - f_m of both signs: the commands equal the recursion written here to rounding."""
    rng = np.random.default_rng(4)
    n = 400
    rhos = np.clip(1.0 + 0.9 * np.sin(np.arange(n) / 15.0) + rng.normal(0, 0.05, n), 0.1, 1.9)
    f_r, f_m = rng.normal(0, 300.0, n), rng.normal(0, 100.0, n)
    ctrl = scheduled(controller(valve_limit_V=1e6), rhos)
    got = []
    for j in range(n):
        got.append(ctrl.step(f_r[j], f_m[j]))
        assert ctrl.rho == pytest.approx(rhos[j], rel=1e-15)
    want = trapezoid_reference(f_r - f_m, rhos)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * np.max(np.abs(want)))


def test_a_scaled_design_is_the_same_controller():
    """num and den scaled by 2 (den[0] = 2): g, c1 and w2 are read per unit den[0]."""
    rng = np.random.default_rng(5)
    e, rhos = rng.normal(0, 200.0, 200), rng.uniform(0.1, 1.5, 200)
    ctrl = scheduled(TangentLoopShaping(DT, 1e6, num=(2 * G,), den=(2.0, 2 * C1, 2 * W2),
                                        member=controller().member, horizon_s=0.0), rhos)
    want = trapezoid_reference(e, rhos)
    np.testing.assert_allclose([ctrl.step(ek, 0.0) for ek in e], want, rtol=0,
                               atol=1e-11 * np.max(np.abs(want)))


@pytest.mark.parametrize('ratio, rho', [
    (0.001, 0.01), (0.01, 0.01), (-3.0, 0.01), (math.nan, 0.01),     # NaN: the lower bound
    (2.0, 2.0), (5.0, 2.0), (math.inf, 2.0), (0.3, 0.3)])
def test_stiffness_ratio_is_bounded(ratio, rho):
    """RHO_RANGE (0.01, 2): a tangent below 1 % of k or above 2 k is taken as the bound."""
    ctrl = scheduled(controller(valve_limit_V=1e6), [ratio] * 3)
    u = [ctrl.step(100.0, 0.0) for _ in range(3)]
    assert ctrl.rho == rho
    np.testing.assert_allclose(u, trapezoid_reference([100.0] * 3, [rho] * 3), rtol=1e-12)


def member_samples():
    """(x, v, a, f_m) of the default Bouc-Wen member (n = 2, D_y 4 mm) loaded from rest to
    6 mm at 0.05 m/s (z = tanh(x/D_y)), then unloading to 3 mm (elastic: z falls by dx/D_y),
    with an acceleration that changes every sample; f_m = m a + c v + r(x, z)."""
    m, c, a_k, dy = 52.7, 903.278, 0.1, 0.004
    out = []
    for j in range(90):
        if j <= 60:
            x, v, z = j * 1e-4, 0.05, math.tanh(j * 1e-4 / dy)
        else:
            x, v = (120 - j) * 1e-4, -0.05
            z = math.tanh(0.006 / dy) - (0.006 - x) / dy
        acc = 8.0 * math.sin(0.7 * j)
        r = a_k * K * x + (1 - a_k) * K * dy * z
        out.append((x, v, acc, m * acc + c * v + r))
    return out


def test_the_member_sees_each_measurement_and_schedules_rho():
    """step(f_r, f_m, v, a, x) feeds the member (x, v, a, f_m) and schedules on its tangent
    h = force_tangent_horizon_s ahead over its stiffness: a twin member fed the same samples
    gives the same rho at every step; the member yields (rho well below 1) and unloads
    elastically (rho = 1). step(f_r, f_m) means x = v = a = 0."""
    p = dict(parameters.defaults(), **TANGENT, force_tangent_horizon_s=0.004)
    ctrl = ForceServoController.from_parameters(p)
    twin = HystereticMember(MemberGuess.from_parameters(p, predictor=False), DT)
    rhos = []
    for x, v, acc, f in member_samples():
        ctrl.step(f + 50.0, f, v, acc, x)
        twin.observe(x, v, acc, f)
        expected = min(max(twin.tangent_ahead(0.004) / twin.model.stiffness_N_per_m, 0.01), 2)
        assert ctrl.rho == pytest.approx(expected, rel=1e-12)
        rhos.append(ctrl.rho)
    assert min(rhos) < 0.3 and rhos[-1] == pytest.approx(1.0, rel=1e-9)
    for f in (120.0, 80.0):
        ctrl.step(0.0, f)
        twin.observe(0.0, 0.0, 0.0, f)
        assert ctrl.member.z == twin.z and ctrl.member.restoring_force_N == f


def test_reset_zeroes_the_filter_and_keeps_the_member():
    """reset(): the recursion starts again from rest (the next command is the first of the
    recursion), rho back to 1, the flag cleared; the member keeps its state and estimates."""
    ctrl = controller(valve_limit_V=0.5)
    for x, v, acc, f in member_samples():
        ctrl.step(f + 1e4, f, v, acc, x)
    assert ctrl.saturated and ctrl.member.has_yielded
    updates = ctrl.member.identifier.updates
    ctrl.reset()
    assert (ctrl.rho, ctrl.saturated) == (1.0, False)
    assert ctrl.member.has_yielded and ctrl.member.identifier.updates == updates
    x, v, acc, f = member_samples()[-1]
    u = ctrl.step(f + 30.0, f, v, acc, x)
    assert u == pytest.approx(trapezoid_reference([30.0], [ctrl.rho])[0], rel=1e-12)
    assert not ctrl.saturated


def test_saturation_clears_when_back_inside():
    ctrl = scheduled(controller(valve_limit_V=0.5), [1.0] * 3)
    assert ctrl.step(-1e6, 0.0) == -0.5 and ctrl.saturated
    ctrl.reset()
    small = ctrl.step(10.0, 0.0)
    assert small == pytest.approx(trapezoid_reference([10.0], [1.0])[0], rel=1e-12)
    assert 0 < small < 0.5 and ctrl.saturated is False


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_command_equal_to_the_limit_is_not_saturated(sign):
    """The limit is the largest valid command (|u| <= valve_limit_V): the first command for a
    500 N error, used as the limit, passes unchanged and unflagged."""
    first = scheduled(controller(valve_limit_V=1e6), [0.4]).step(sign * 500.0, 0.0)
    ctrl = scheduled(controller(valve_limit_V=abs(first)), [0.4])
    assert (ctrl.step(sign * 500.0, 0.0), ctrl.saturated) == (first, False)


def test_constructor_defaults():
    """As ForceServoController: the reference rig's 10 V valve and Eq. 3.1 (V/lbf); rho = 1
    (the elastic design) until the first sample."""
    ctrl = TangentLoopShaping(DT, member=controller().member, horizon_s=0.0)
    assert (ctrl.valve_limit_V, ctrl.rho, ctrl.saturated) == (10.0, 1.0, False)
    np.testing.assert_array_equal(ctrl.bz, ForceServoController(DT).bz)


# -- its frozen designs and its construction -----------------------------------------------------

@pytest.mark.parametrize('rho', [0.05, 0.3, 1.0, 1.7])
def test_frozen_is_tustin_prewarped_at_the_elastic_resonance(rho):
    """C(s; rho) = g/(s^2 + c1 s + w2 rho) by scipy's bilinear transform at the sampling rate
    w0/(2 tan(w0 dt/2)), w0 = sqrt(w2): the elastic resonance for every rho, as in the
    recursion (not the frozen design's own sqrt(w2 rho))."""
    ctrl = controller()
    frozen = ctrl.frozen(rho)
    w0 = math.sqrt(W2)
    b, a = signal.bilinear([G], [1.0, C1, W2 * rho], fs=w0 / (2 * math.tan(w0 * DT / 2)))
    np.testing.assert_allclose(frozen.bz, b, rtol=1e-10)
    np.testing.assert_allclose(frozen.az, a, rtol=1e-10)
    assert frozen.kind == f'tangent_loop_shaping at rho = {rho:g}'
    assert (frozen.dt, frozen.valve_limit_V) == (DT, ctrl.valve_limit_V)


def test_from_parameters_reads_horizon_limit_calibration_and_the_specimens_model():
    """The force controller declares no predictor_* parameters: its member is the specimen's
    m, c, k with the hysteresis_* guesses; Eq. 3.1 in the rig calibration ('si': 37 V/N);
    no force_tangent_horizon_s: the schema's 5 ms."""
    p = dict(parameters.defaults(), **TANGENT, force_tangent_horizon_s=0.012, dt=0.001,
             valve_limit_V=6.0, rig_calibration='si', predictor_stiffness_N_per_m=1.0e5,
             hysteresis_yield_displacement_m=0.006)
    ctrl = ForceServoController.from_parameters(p)
    assert isinstance(ctrl, TangentLoopShaping)
    assert (ctrl.horizon_s, ctrl.dt, ctrl.valve_limit_V) == (0.012, 0.001, 6.0)
    assert ctrl.design.num == (37.0,)
    model = ctrl.member.model
    assert (model.stiffness_N_per_m, model.yield_displacement_m) == (K, 0.006)
    absent = {k: v for k, v in p.items() if k != 'force_tangent_horizon_s'}
    assert TangentLoopShaping.from_parameters(absent).horizon_s == 0.005


@pytest.mark.parametrize('horizon', [math.nan, math.inf])
def test_horizon_must_be_a_finite_time(horizon):
    with pytest.raises(ParameterError, match='^' + re.escape(
            f'parameter force_tangent_horizon_s={horizon!r}: expected float >= 0') + '$'):
        TangentLoopShaping(DT, member=controller().member, horizon_s=horizon)
    assert TangentLoopShaping(DT, member=controller().member, horizon_s=0.0).horizon_s == 0.0


@pytest.mark.parametrize('num, den', [((1.0,), (1.0, 2.0)), ((1.0, 0.0), (1.0, 2.0, 3.0)),
                                      ((1.0,), (1.0, 2.0, 3.0, 4.0))])
def test_design_must_be_a_gain_over_a_second_order(num, den):
    with pytest.raises(ParameterError, match=r'^tangent_loop_shaping: expected C_f = '
                                             r'g/\(s\^2 \+ b s \+ c\)$'):
        TangentLoopShaping(DT, num=num, den=den, member=controller().member, horizon_s=0.0)
