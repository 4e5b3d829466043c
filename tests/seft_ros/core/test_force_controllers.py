"""The force controller designs (``force_controller``) against independent computations."""

import math
import re
import warnings

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py import parameters
from seft_msgs_py.calibration import controller_gain_V_per_N, valve_flow_gain_m3_per_s_V
from seft_msgs_py.errors import ParameterError
from seft_ros.core.controller import FORCE_CONTROLLERS, ForceServoController
from seft_ros.core.stability import LoopModel, check_run

DT = 0.002


def params(**kw):
    return parameters.resolve(dict(rig_model='servohydraulic', predictor='none', **kw))


def run_linear(ctrl, e, v=None, a=None):
    v = np.zeros_like(e) if v is None else v
    a = np.zeros_like(e) if a is None else a
    return np.array([ctrl.step(float(ei), 0.0, float(vi), float(ai))
                     for ei, vi, ai in zip(e, v, a)])


def test_schema_lists_the_designs():
    assert spec_choices() == FORCE_CONTROLLERS
    assert parameters.spec('force_controller').default == 'loop_shaping'


def spec_choices():
    return parameters.spec('force_controller').choices


def test_default_is_the_loop_shaping_controller_unchanged():
    """from_parameters with the defaults equals the paper controller, with or without motion."""
    p = params()
    ctrl = ForceServoController.from_parameters(p)
    ref = ForceServoController(DT, num=(controller_gain_V_per_N(p),))
    np.testing.assert_allclose(ctrl.bz, ref.bz, rtol=1e-12)
    rng = np.random.default_rng(0)
    e = rng.normal(scale=50.0, size=300)
    u1 = run_linear(ctrl, e, rng.normal(size=300), rng.normal(size=300))
    u2 = np.array([ref.step(float(x), 0.0) for x in e])
    np.testing.assert_array_equal(u1, u2)
    assert not ctrl.uses_motion


def test_integral_equals_the_tustin_product_of_cf_and_pi():
    """C_f (1 + w_i/s), both by bilinear at the prewarped period: lfilter on the product."""
    fi = 2.0
    ctrl = ForceServoController.from_parameters(params(force_controller='integral',
                                                       force_integral_hz=fi))
    w0 = math.sqrt(4002.0)
    period = 2 * math.tan(w0 * DT / 2) / w0
    wi = 2 * math.pi * fi
    num = np.polymul([controller_gain_V_per_N(params())], [1.0, wi])         # C_f (s + w_i)/s
    den = np.polymul([1.0, 17.14, 4002.0], [1.0, 0.0])
    bz, az, _ = signal.cont2discrete((num, den), period, method='bilinear')
    e = np.random.default_rng(1).normal(scale=20.0, size=400)
    expected = signal.lfilter(np.ravel(bz), np.ravel(az), e)
    np.testing.assert_allclose(run_linear(ctrl, e), expected, rtol=1e-7, atol=1e-10)
    # the integrator: the response to a constant error grows linearly (type 2 loop)
    np.testing.assert_allclose(np.polyval(ctrl.az, 1.0), 0.0, atol=1e-12)


def test_integral_does_not_wind_up():
    ctrl = ForceServoController(DT, 1.0, integral_hz=5.0, kind='integral')
    for _ in range(2000):
        u = ctrl.step(5000.0, 0.0)
    assert u == 1.0 and ctrl.saturated
    held = ctrl._i
    assert abs(held) < 1.0          # frozen while saturated
    # back inside the range at once when the error reverses
    steps = 0
    while abs(ctrl.step(0.0, 0.0)) >= 1.0:
        steps += 1
    assert steps < 100


def test_velocity_feedback_gains_are_the_hydraulic_formulas():
    """g_v = A/k_q, K_p = 2 pi f_c C_h/(A k_q), w_h = (K_c + C_l)/C_h."""
    p = params(force_controller='velocity_feedback', force_crossover_hz=10.0,
               velocity_filter_hz=0.0, velocity_lead_s=0.004)
    ctrl = ForceServoController.from_parameters(p)
    area, kq = 1.18e-3, valve_flow_gain_m3_per_s_V(p)      # 2.358e-4 (us_customary)
    assert kq == pytest.approx(2.358e-4, rel=1e-3)
    c_h = 3.35e-4 / (4 * 1e9)
    assert ctrl.velocity_gain_V_s_per_m == pytest.approx(area / kq, rel=1e-3)
    kp = 2 * math.pi * 10.0 * c_h / (area * kq)
    wh = (8e-12 + 2e-12) / c_h
    assert ctrl.integral_hz == pytest.approx(wh / (2 * math.pi), rel=1e-12)
    # static path: u = K_p (1 + w_h/s) e + g_v (v + T a); the velocity part alone
    u = ctrl.step(0.0, 0.0, 0.01, 2.0)
    assert u == pytest.approx(area / kq * (0.01 + 0.004 * 2.0), rel=1e-3)
    ctrl.reset()
    # the error path at high frequency is K_p (Tustin of 1 + w_h/s at z = -1 is 1)
    h = signal.freqz(ctrl.bz, ctrl.az, worN=[math.pi])[1][0]
    assert abs(h) == pytest.approx(kp, rel=1e-9)


def test_state_space_equals_the_step_recursion():
    """state_space() (the stability map's controller) reproduces step() without saturation."""
    p = params(force_controller='velocity_feedback', velocity_lead_s=0.003)
    ctrl = ForceServoController.from_parameters(p)
    ctrl.valve_limit_V = 1e9
    a, b, c, d = ctrl.state_space()
    rng = np.random.default_rng(2)
    w = rng.normal(size=(200, 3)) * [10.0, 0.01, 1.0]
    x = np.zeros(a.shape[0])
    ys = []
    for wk in w:
        ys.append((c @ x + d @ wk).item())
        x = a @ x + b @ wk
    got = run_linear(ctrl, w[:, 0], w[:, 1], w[:, 2])
    np.testing.assert_allclose(got, ys, rtol=1e-8, atol=1e-12)


def test_stability_model_uses_the_configured_controller():
    """The guard covers each controller: the loop-shaping boundary is unchanged (1.317) and
    the velocity design's measured low-frequency instability is predicted."""
    assert check_run(params(alpha=1.0)).stable
    assert not check_run(params(alpha=1.5)).stable
    assert check_run(params(alpha=1.0, force_controller='integral')).stable
    rho = LoopModel(params(force_controller='velocity_feedback')).radii([0.0])[0]
    assert rho > 1.0
    assert check_run(params(force_controller='velocity_feedback')).stable is False


@pytest.mark.parametrize('kw, message', [
    (dict(force_controller='pid'), "parameter force_controller='pid'"),
])
def test_from_parameters_errors(kw, message):
    p = dict(parameters.defaults(), **kw)
    with pytest.raises(ParameterError, match=re.escape(message)):
        ForceServoController.from_parameters(p)


@pytest.mark.parametrize('kw, message', [
    (dict(integral_hz=-1.0), 'parameter force_integral_hz=-1.0'),
    (dict(velocity_gain_V_s_per_m=math.nan), 'parameter velocity_feedback_gain=nan'),
    (dict(velocity_lead_s=-0.1), 'parameter velocity_lead_s=-0.1'),
    (dict(velocity_gain_V_s_per_m=1.0, velocity_filter_hz=300.0),
     'parameter velocity_filter_hz=300.0'),
])
def test_constructor_errors(kw, message):
    with pytest.raises(ParameterError, match=re.escape(message)):
        ForceServoController(DT, **kw)


# -- Hand-computed references (issue 11: killing the mutmut survivors) -----------------------

def test_integral_conditional_integration_by_hand():
    """Static error path 1 V/N (den of order 0: Tustin at dt, no prewarping) and w_i chosen so
    that the Tustin integrator gain is k_i = w_i dt/2 = 0.25: i[k] = i[k-1] + 0.25 (x[k] +
    x[k-1]), u = x + i, held (not updated) while |u| > 0.8 V. Computed by hand:

    ===  ====  =========================  ======  ====
    k    e     candidate i                u       i
    ===  ====  =========================  ======  ====
    0    0.4   0 + 0.25 (0.4 + 0) = 0.1   0.5     0.1
    1    0.4   0.1 + 0.2 = 0.3            0.7     0.3
    2    0.4   0.3 + 0.2 = 0.5            0.9 ->  0.8  (held 0.3)
    3    0.4   0.3 + 0.2 = 0.5            0.9 ->  0.8  (held 0.3)
    4    -0.2  0.3 + 0.25 (-0.2 + 0.4)    0.15    0.35
    5    0     0.35 + 0.25 (0 - 0.2)      0.3     0.3
    6    -2    0.3 + 0.25 (-2 + 0) = -0.2 -2.2 -> -0.8 (held 0.3)
    7    0     0.3 + 0.25 (0 - 2) = -0.2  -0.2    -0.2
    ===  ====  =========================  ======  ====

    With wind-up the integrator would hold 0.75 at k = 4 (u = 0.55, not 0.15)."""
    fi = 0.25 / (math.pi * DT)                      # w_i dt / 2 = 2 pi fi dt / 2 = 0.25
    ctrl = ForceServoController(DT, 0.8, num=(1.0,), den=(1.0,), integral_hz=fi,
                                kind='integral')
    e = [0.4, 0.4, 0.4, 0.4, -0.2, 0.0, -2.0, 0.0]
    expected = [0.5, 0.7, 0.8, 0.8, 0.15, 0.3, -0.8, -0.2]
    saturated = [False, False, True, True, False, False, True, False]
    for _ in range(2):                              # reset() restores the initial state
        got, flags = [], []
        for ek in e:
            got.append(ctrl.step(ek + 10.0, 10.0))
            flags.append(ctrl.saturated)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        assert flags == saturated
        ctrl.reset()
        assert ctrl.saturated is False


def test_integral_below_1_hz_is_integral_action():
    """Any w_i > 0 adds the pole z = 1 (the Tustin integrator (z + 1)/(z - 1)); at 0.5 Hz the
    loop-shaping controller becomes third order."""
    ctrl = ForceServoController(DT, integral_hz=0.5, kind='integral')
    assert len(ctrl.az) == 4
    assert np.polyval(ctrl.az, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert ctrl.design.method == ('bilinear, prewarped at 63.26 rad/s; integral action below '
                                  '0.5 Hz (bilinear)')


def test_first_order_error_path_is_plain_tustin():
    """C(s) = 1/(s + 10): no prewarping (not resonant), s = (2/T)(z - 1)/(z + 1) at T = dt
    gives C(z) = (z + 1)/((2/T + 10) z + (10 - 2/T)), normalized here by hand."""
    ctrl = ForceServoController(DT, num=(1.0,), den=(1.0, 10.0))
    g = 2.0 / DT + 10.0
    np.testing.assert_allclose(ctrl.bz, [1.0 / g, 1.0 / g], rtol=1e-12)
    np.testing.assert_allclose(ctrl.az, [1.0, (10.0 - 2.0 / DT) / g], rtol=1e-12)
    assert ctrl.design.method == 'bilinear'


def test_static_gain_error_path():
    """num/den of order 0: the gain 3/2 with no dynamics (no z = 1 pole-zero pair)."""
    ctrl = ForceServoController(DT, num=(3.0,), den=(2.0,))
    np.testing.assert_array_equal(ctrl.bz, [1.5])
    np.testing.assert_array_equal(ctrl.az, [1.0])
    assert [ctrl.step(x, 0.0) for x in (1.0, 2.0, -4.0)] == [1.5, 3.0, -6.0]


def test_velocity_feedback_pi_is_the_tustin_pi_by_hand():
    """K_p (1 + w_h/s) by Tustin at dt: K_p ((1 + k) z + (k - 1))/(z - 1), k = w_h dt/2, with
    the default hydraulics: C_h = V_t/(4 beta) = 3.35e-4/4e9 m^3/Pa, w_h = (8e-12 + 2e-12)/C_h
    = 119.4 rad/s, K_p = 2 pi 12 C_h/(A k_q), A = 1.18e-3 m^2, k_q = 5.3e-5 x 4.448 m^3/(s V)."""
    p = params(force_controller='velocity_feedback', valve_limit_V=7.5)
    ctrl = ForceServoController.from_parameters(p)
    c_h = 3.35e-4 / 4e9
    wh = 1e-11 / c_h
    kq = 5.3e-5 * 4.4482216152605
    kp = 2 * math.pi * 12.0 * c_h / (1.18e-3 * kq)
    k = wh * DT / 2
    np.testing.assert_allclose(ctrl.bz, [kp * (1 + k), kp * (k - 1)], rtol=1e-12)
    np.testing.assert_allclose(ctrl.az, [1.0, -1.0], rtol=1e-12)
    assert ctrl.design.method == (f'bilinear; integral action below {wh / 2 / math.pi:g} Hz '
                                  '(bilinear)')
    assert (ctrl.kind, ctrl.valve_limit_V) == ('velocity_feedback', 7.5)
    assert ctrl.velocity_filter_hz == 20.0         # the schema's default


@pytest.mark.parametrize('kind', ['loop_shaping', 'integral'])
def test_from_parameters_names_the_design_and_reads_the_limit(kind):
    ctrl = ForceServoController.from_parameters(params(force_controller=kind, valve_limit_V=7.5))
    assert (ctrl.kind, ctrl.valve_limit_V) == (kind, 7.5)
    assert ctrl.step(1e9, 0.0) == 7.5


def test_from_parameters_takes_absent_keys_from_the_schema():
    """Only dt and valve_limit_V given: the default design (loop_shaping, Eq. 3.1 in V/lbf)."""
    ctrl = ForceServoController.from_parameters({'dt': DT, 'valve_limit_V': 4.0})
    assert ctrl.kind == 'loop_shaping'
    np.testing.assert_array_equal(ctrl.bz, ForceServoController(DT).bz)


def test_unknown_design_message_lists_the_designs():
    """from_parameters checks the name itself (the mapping need not come from resolve())."""
    with pytest.raises(ParameterError, match=re.escape(
            "parameter force_controller='pid': expected one of 'loop_shaping', 'integral', "
            "'velocity_feedback', 'tangent_loop_shaping', 'specimen_loop_shaping', "
            "'transfer_function'") + '$'):
        ForceServoController.from_parameters(dict(parameters.defaults(), force_controller='pid'))


@pytest.mark.parametrize('kw', [dict(piston_area_m2=0.0), dict(actuator_volume_m3=0.0),
                                dict(force_crossover_hz=0.0)])
def test_velocity_feedback_needs_positive_hydraulics(kw):
    p = dict(params(force_controller='velocity_feedback'), **kw)
    fc = kw.get('force_crossover_hz', 12.0)
    with pytest.raises(ParameterError, match=re.escape(
            f'parameter force_crossover_hz={fc!r}: expected float > 0 (and positive piston '
            'area, volume, bulk modulus, flow gain)') + '$'):
        ForceServoController.from_parameters(p)


def test_velocity_feedback_crossover_below_1_hz_is_accepted():
    """f_c = 0.5 Hz is > 0: K_p scales with f_c (1/24 of the 12 Hz default's)."""
    slow = ForceServoController.from_parameters(params(force_controller='velocity_feedback',
                                                       force_crossover_hz=0.5))
    fast = ForceServoController.from_parameters(params(force_controller='velocity_feedback'))
    np.testing.assert_allclose(slow.bz, fast.bz / 24.0, rtol=1e-12)


def test_motion_defaults_of_step_and_of_the_constructor():
    """Static error path 2 V/N and g_v = 0.5 V s/m, no filter and no lead by default:
    u = 2 e + 0.5 v exactly; step(f_r, f_m) means v = a = 0."""
    ctrl = ForceServoController(DT, 100.0, num=(2.0,), den=(1.0,),
                                velocity_gain_V_s_per_m=0.5)
    assert (ctrl.velocity_lead_s, ctrl.velocity_filter_hz) == (0.0, 0.0)
    assert ctrl.uses_motion
    assert ctrl.step(1.0, 0.0, 2.0, 1000.0) == 3.0        # 2*1 + 0.5*2, a ignored (no lead)
    ctrl = ForceServoController(DT, 100.0, num=(2.0,), den=(1.0,),
                                velocity_gain_V_s_per_m=0.5, velocity_lead_s=0.1)
    assert ctrl.step(1.0, 0.0) == 2.0
    assert ctrl.step(1.0, 0.0, 0.0, 10.0) == 2.5          # 2 + 0.5*0.1*10


def test_velocity_path_saturation_boundaries():
    """u = 2 e + 0.5 v against a 3 V valve: exactly +-3 V is valid, beyond it is clipped to
    the limit of the command's sign, and the flag clears when back inside. With a limit below
    1 V the clipped sign is still that of u (u = 0.45 x 2 = 0.9 V -> +0.8 V)."""
    ctrl = ForceServoController(DT, 3.0, num=(2.0,), den=(1.0,),
                                velocity_gain_V_s_per_m=0.5)
    cases = [((1.0, 0.0, 2.0), 3.0, False), ((1.0, 0.0, 2.5), 3.0, True),
             ((0.0, 0.0, 1.5), 0.75, False), ((-1.0, 0.0, -2.0), -3.0, False),
             ((-1.0, 0.0, -2.5), -3.0, True), ((0.0, 0.0, 0.0), 0.0, False)]
    for args, u, sat in cases:
        assert (ctrl.step(*args), ctrl.saturated) == (u, sat)
    ctrl = ForceServoController(DT, 0.8, num=(0.45,), den=(1.0,), velocity_gain_V_s_per_m=1.0)
    assert ctrl.step(2.0, 0.0) == 0.8 and ctrl.saturated


@pytest.mark.parametrize('fc', [0.5, 20.0])
def test_velocity_filter_is_the_2nd_order_butterworth(fc):
    """The impulse response of the velocity path, g_v h[k], against the bilinear Butterworth
    by hand, K = tan(pi f_c dt): h[0] = K^2/(1 + sqrt(2) K + K^2), DC gain 1, and
    |H(f)|^2 = 1/(1 + (tan(pi f dt)/K)^4) (exactly -3 dB at f_c); the lead T_v feeds a
    through the same filter."""
    gv, lead = 2.0, 0.01
    ctrl = ForceServoController(DT, 1e6, velocity_gain_V_s_per_m=gv, velocity_filter_hz=fc,
                                velocity_lead_s=lead)
    n = 6000                                        # 12 s: the 0.5 Hz poles decay as e^-27
    h = np.array([ctrl.step(0.0, 0.0, 1.0 if k == 0 else 0.0) for k in range(n)]) / gv
    K = math.tan(math.pi * fc * DT)
    assert h[0] == pytest.approx(K ** 2 / (1 + math.sqrt(2) * K + K ** 2), rel=1e-12)
    t = np.arange(n) * DT
    for f in (0.0, fc, 2 * fc):
        mag2 = abs(np.sum(h * np.exp(-2j * np.pi * f * t))) ** 2
        assert mag2 == pytest.approx(1 / (1 + (math.tan(math.pi * f * DT) / K) ** 4), rel=1e-8)
    ctrl.reset()
    ha = [ctrl.step(0.0, 0.0, 0.0, 1.0 if k == 0 else 0.0) for k in range(50)]
    np.testing.assert_allclose(ha, gv * lead * h[:50], rtol=1e-12, atol=0)


def test_from_parameters_filters_the_velocity():
    """velocity_filter_hz = 20 Hz: the first response to a velocity impulse is g_v h[0]."""
    p = params(force_controller='velocity_feedback', velocity_filter_hz=20.0)
    ctrl = ForceServoController.from_parameters(p)
    K = math.tan(math.pi * 20.0 * DT)
    gv = 1.18e-3 / (5.3e-5 * 4.4482216152605)
    assert ctrl.step(0.0, 0.0, 1.0) == pytest.approx(gv * K ** 2 / (1 + math.sqrt(2) * K
                                                                    + K ** 2), rel=1e-12)


@pytest.mark.parametrize('kw, message', [
    (dict(velocity_gain_V_s_per_m=1.0, velocity_filter_hz=250.0),
     'parameter velocity_filter_hz=250.0: expected below the Nyquist frequency'),
    (dict(velocity_filter_hz=-1.0), 'parameter velocity_filter_hz=-1.0: expected float >= 0'),
])
def test_constructor_filter_messages(kw, message):
    """At dt = 2 ms the Nyquist frequency is 250 Hz: a cut-off there is refused."""
    with pytest.raises(ParameterError, match='^' + re.escape(message) + '$'):
        ForceServoController(DT, **kw)


@pytest.mark.parametrize('kind', [k for k in FORCE_CONTROLLERS if k != 'tangent_loop_shaping'])
def test_state_space_equals_the_step_recursion_for_every_design(kind):
    """state_space() against step() for each linear design (no saturation: a 1 MV limit),
    built without a warning (tf2ss warns on badly conditioned coefficients). The scheduled
    design has its own tests (test_tangent_loop_shaping.py)."""
    # a lab's own: a third-order continuous controller (lead, resonance, roll-off)
    lab = ('{"num": [4.0, 120.0], "den": [0.001, 1.2, 60.0, 4000.0], "dt": 0}'
           if kind == 'transfer_function' else 'none')
    ctrl = ForceServoController.from_parameters(params(force_controller=kind,
                                                       velocity_lead_s=0.002,
                                                       force_controller_tf=lab))
    ctrl.valve_limit_V = 1e6
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        a, b, c, d = ctrl.state_space()
    rng = np.random.default_rng(3)
    w = rng.normal(size=(300, 3)) * [100.0, 0.01, 1.0]
    x = np.zeros(a.shape[0])
    ys = []
    for wk in w:
        ys.append((c @ x + d @ wk).item())
        x = a @ x + b @ wk
    np.testing.assert_allclose(run_linear(ctrl, w[:, 0], w[:, 1], w[:, 2]), ys,
                               rtol=1e-8, atol=1e-12)


def test_specimen_loop_shaping_cancels_this_rigs_specimen():
    """The study's rule for another specimen: poles at (c/m, k/m) of the rig's own specimen,
    Eq. 3.1's gain; a 1.6 k pier keeps force control with it and 'model' follows the
    reference as closely as on the study's specimen. With Eq. 3.1 the test diverges
    uncompensated (the divergence guard ends it at 3 x the predicted displacement, 1.3 s,
    before the valve saturates), and 'model' is refused before the run: that loop is unstable
    (its spectral radius 1.008), no loop for its force-loop inverse to follow."""
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.core.experiment import simulate
    k = 1.6 * 2.11e5
    p = parameters.resolve({'stiffness_N_per_m': k, 'force_controller': 'specimen_loop_shaping',
                            'rig_model': 'servohydraulic'})
    ctrl = ForceServoController.from_parameters(p)
    assert ctrl.design.den == (1.0, 903.278 / 52.7, k / 52.7)
    assert ctrl.design.num == ForceServoController.from_parameters(
        parameters.resolve()).design.num
    study = simulate(dict(p, force_controller='loop_shaping', duration_s=8.0))
    assert not study.stable and study.abort_reason.startswith('unstable at t=1.3'), (
        study.abort_reason)
    assert 'diverging, the measured displacement' in study.abort_reason
    with pytest.raises(ParameterError, match=r'force_controller loop_shaping with the declared '
                       r'specimen .* is unstable \(closed-loop spectral radius 1\.008\): no '
                       r'loop to invert'):
        simulate(dict(p, force_controller='loop_shaping', predictor='model', duration_s=8.0))
    run = simulate(dict(p, predictor='model', duration_s=8.0))
    assert run.stable
    assert compare_run(run).displacement.nrms < 0.006
