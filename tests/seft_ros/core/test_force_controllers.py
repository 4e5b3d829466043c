"""The force controller designs (``force_controller``) against independent computations."""

import math
import re

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
