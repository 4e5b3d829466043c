"""Tests of the discrete force servo controller and its saturation interlock against hand-typed
references: paper Eq. 3.1 evaluated by hand (C_f(j w), its DC gain 37/4002), scipy.signal.lfilter,
the interlock's counts from exact fractions, and the documented limits and messages."""

from fractions import Fraction
import math

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_ros.core.controller import (
    LOOP_SHAPING_DEN,
    LOOP_SHAPING_NUM,
    DiscreteFilter,
    ForceServoController,
    SaturationInterlock,
)

DT = 0.002
#: 1 lbf [N], typed from its definition (0.45359237 kg x 9.80665 m/s^2).
LBF = 0.45359237 * 9.80665


@pytest.fixture(scope='module')
def controller():
    return ForceServoController(DT)


def continuous_cf(w, force_unit_N=LBF):
    """C_f(j w) = 37 / ((j w)^2 + 17.14 j w + 4002) [V/N], typed from paper Eq. 3.1 read in
    V per `force_unit_N` (default: V/lbf, the default rig calibration)."""
    s = 1j * np.asarray(w)
    return 37.0 / force_unit_N / (s ** 2 + 17.14 * s + 4002.0)


# -- DiscreteFilter --------------------------------------------------------------------------

@pytest.mark.parametrize('b, a', [
    ([0.5], [1.0]),                                   # a gain
    ([1.0, -0.3], [1.0]),                             # FIR
    ([0.2, 0.3, 0.1], [2.0, -1.2, 0.5]),              # a[0] != 1 is normalized
    ([1.0], [1.0, -1.5, 0.7]),                        # shorter numerator
    ([0.1, 0.2, 0.3, 0.4], [1.0, 0.1]),               # shorter denominator
    signal.butter(4, 0.2),
])
def test_discrete_filter_equals_lfilter(b, a):
    x = np.random.default_rng(11).standard_normal(2000) * 100.0
    f = DiscreteFilter(b, a)
    y = np.array([f.step(v) for v in x])
    ref = signal.lfilter(b, a, x)
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))
    f.reset()
    assert [f.step(v) for v in x[:10]] == pytest.approx(ref[:10], rel=1e-12, abs=1e-12)


@pytest.mark.parametrize('b, a', [
    ([1.0], [0.0, 1.0]),
    ([1.0], [1.0, math.nan]),
    ([math.inf], [1.0]),
])
def test_discrete_filter_bad_coefficients(b, a):
    with pytest.raises(ParameterError,
                       match=r'^filter coefficients: expected finite values with a\[0\] != 0$'):
        DiscreteFilter(b, a)


# -- ForceServoController --------------------------------------------------------------------

def test_coefficients_are_the_paper_controller(controller):
    # Eq. 3.1 read in V/lbf by default: 37 V/lbf = 37/4.448 V/N
    assert LOOP_SHAPING_NUM == (pytest.approx(37.0 / LBF, rel=1e-15),)
    assert LOOP_SHAPING_DEN == (1.0, 17.14, 4002.0)
    ct = controller.continuous()
    np.testing.assert_allclose(np.ravel(ct.num), [37.0 / LBF], rtol=1e-15)
    np.testing.assert_array_equal(ct.den, [1.0, 17.14, 4002.0])
    assert controller.discrete().dt == DT
    assert 'bilinear' in controller.design.method


def test_frequency_response_matches_continuous_to_25hz(controller):
    f = np.linspace(0.01, 25.0, 2500)
    _, hd = signal.freqz(controller.bz, controller.az, worN=f, fs=1 / DT)
    ratio = hd / continuous_cf(2 * np.pi * f)
    assert np.max(np.abs(np.abs(ratio) - 1)) < 0.02
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 0.2


def test_prewarping_is_exact_at_the_resonance(controller):
    w0 = math.sqrt(4002.0)
    z = np.exp(1j * w0 * DT)
    hd = np.polyval(controller.bz, z) / np.polyval(controller.az, z)
    assert abs(hd / continuous_cf(w0) - 1) < 1e-4
    # without prewarping (plain Tustin) the response at w0 is off by more than that
    bz, az, _ = signal.cont2discrete((LOOP_SHAPING_NUM, LOOP_SHAPING_DEN), DT, 'bilinear')
    plain = np.polyval(np.ravel(bz), z) / np.polyval(np.ravel(az), z)
    assert abs(plain / continuous_cf(w0) - 1) > 5e-3


def test_discrete_poles_are_the_mapped_continuous_poles(controller):
    """Tustin with prewarping maps s to z; the lightly damped poles stay at about w0."""
    zp = np.roots(controller.az)
    assert np.all(np.abs(zp) < 1)
    sp = np.log(zp) / DT
    np.testing.assert_allclose(np.sort(np.abs(sp)), [math.sqrt(4002.0)] * 2, rtol=1e-3)


def test_step_filters_the_force_error_and_saturates(controller):
    c = ForceServoController(DT, valve_limit_V=2.5)
    rng = np.random.default_rng(2)
    fr, fm = rng.standard_normal(3000) * 3000.0, rng.standard_normal(3000) * 1000.0
    u = []
    sat = []
    for a, b in zip(fr, fm):
        u.append(c.step(a, b))
        sat.append(c.saturated)
    u, sat = np.array(u), np.array(sat)
    # an unsaturated linear filter of the error (no integrator: saturation does not wind up)
    raw = signal.lfilter(c.bz, c.az, fr - fm)
    np.testing.assert_allclose(u, np.clip(raw, -2.5, 2.5), rtol=0, atol=1e-12)
    assert np.array_equal(sat, np.abs(raw) > 2.5)
    assert sat.any() and not sat.all()
    assert np.max(np.abs(u)) == 2.5
    c.reset()
    assert c.saturated is False
    assert c.step(fr[0], fm[0]) == pytest.approx(raw[0], abs=1e-15)


@pytest.mark.parametrize('reading, gain_V_per_N', [('us_customary', 37.0 / LBF), ('si', 37.0)])
def test_from_parameters_reads_eq_3_1_in_the_rig_calibration(reference_params, reading,
                                                             gain_V_per_N):
    c = ForceServoController.from_parameters(dict(reference_params, rig_calibration=reading))
    assert c.design.num == (pytest.approx(gain_V_per_N, rel=1e-15),)
    assert c.design.den == LOOP_SHAPING_DEN
    w = 2 * np.pi * np.array([0.5, 10.0, 25.0])
    force_unit = 1.0 if reading == 'si' else LBF
    np.testing.assert_allclose(c.continuous().freqresp(w)[1], continuous_cf(w, force_unit),
                               rtol=1e-12)
    with pytest.raises(ParameterError, match="^parameter rig_calibration='metric': expected "
                       "one of 'us_customary', 'si'$"):
        ForceServoController.from_parameters(dict(reference_params, rig_calibration='metric'))


def test_default_limit_and_from_parameters(reference_params):
    c = ForceServoController.from_parameters(reference_params)
    assert (c.dt, c.valve_limit_V) == (0.002, 10.0)
    assert c.design.num == ForceServoController(DT).design.num
    assert c.step(1e9, 0.0) == 10.0 and c.saturated
    assert c.step(-1e12, 0.0) == -10.0 and c.saturated


@pytest.mark.parametrize('kwargs, message', [
    ({'dt': 0.0}, 'parameter dt=0.0: expected float > 0'),
    ({'dt': -0.002}, 'parameter dt=-0.002: expected float > 0'),
    ({'dt': math.nan}, 'parameter dt=nan: expected float > 0'),
    ({'dt': DT, 'valve_limit_V': 0.0}, 'parameter valve_limit_V=0.0: expected float > 0'),
])
def test_controller_parameter_errors(kwargs, message):
    with pytest.raises(ParameterError, match='^' + message.replace('.', r'\.') + '$'):
        ForceServoController(**kwargs)


# -- SaturationInterlock ---------------------------------------------------------------------

def first_trip(interlock, flags):
    """Feed saturation flags at t = k*DT; return (index, reason) of the first trip or None."""
    for k, flag in enumerate(flags):
        reason = interlock.update(flag, k * DT)
        if reason:
            return k, reason
    return None


def test_interlock_trips_on_the_26th_saturated_sample_of_50():
    il = SaturationInterlock(DT, 0.1, 0.5)
    assert il.window == 50 and il.window_s == pytest.approx(0.1)
    k, reason = first_trip(il, [True] * 50)
    assert k == 25    # the 26th sample: 26/50 > 0.5, 25/50 is not
    assert reason == ('force control lost at t=0.050 s: valve command saturated in 26/50 '
                      'samples of the last 0.100 s')


def test_interlock_counts_a_sliding_window():
    # 25 saturated of every 50 (alternating) never trips ...
    il = SaturationInterlock(DT, 0.1, 0.5)
    assert first_trip(il, [True, False] * 500) is None
    # ... old saturated samples leave the window: 25 saturated, 30 clear, then 25 more
    il = SaturationInterlock(DT, 0.1, 0.5)
    assert first_trip(il, [True] * 25 + [False] * 30 + [True] * 25) is None
    # ... but 25 + 24 clear + 1 more is 26 within the window
    il = SaturationInterlock(DT, 0.1, 0.5)
    assert first_trip(il, [True] * 25 + [False] * 24 + [True]) == (
        49, 'force control lost at t=0.098 s: valve command saturated in 26/50 samples of '
        'the last 0.100 s')


@pytest.mark.parametrize('window, fraction', [
    (50, 0.5), (50, 0.1), (10, 0.7), (100, 0.25), (200, 0.99), (1, 0.5), (50, 0.3),
    (100, 0.29), (50, 0.58),  # 0.29*100 = 28.999999999999996 in floats
])
def test_interlock_trips_exactly_above_the_fraction(window, fraction):
    il = SaturationInterlock(DT, window * DT, fraction)
    assert il.window == window
    expected = math.floor(Fraction(str(fraction)) * window) + 1   # smallest count > f*w
    k, reason = first_trip(il, [True] * window)
    assert k + 1 == expected
    assert f'{expected}/{window} samples' in reason



@pytest.mark.parametrize('seed', range(6))
def test_interlock_is_the_sliding_window_count_across_quiet_stretches(seed):
    """Saturated bursts between long unsaturated stretches (the interlock skips its ring
    while the window holds no saturated sample): its trip is the first sample whose last 50
    samples, counted here, hold more than 25 saturated."""
    rng = np.random.default_rng(seed)
    flags = []
    while len(flags) < 3000:
        flags += [False] * int(rng.integers(0, 120)) + list(rng.random(int(rng.integers(1, 60)))
                                                             < rng.uniform(0.3, 0.9))
    counts = [sum(flags[max(0, k - 49):k + 1]) for k in range(len(flags))]
    first = next((k for k, c in enumerate(counts) if c > 25), None)
    got = first_trip(SaturationInterlock(DT, 0.1, 0.5), flags)
    if first is None:
        assert got is None
    else:
        assert got == (first, f'force control lost at t={first * DT:.3f} s: valve command '
                              f'saturated in {counts[first]}/50 samples of the last 0.100 s')

def test_interlock_fraction_one_never_trips():
    il = SaturationInterlock(DT, 0.1, 1.0)
    assert first_trip(il, [True] * 5000) is None


def test_interlock_reason_names_the_time(reference_params):
    il = SaturationInterlock.from_parameters(reference_params)
    for k in range(25):
        assert il.update(True, 12.345 + k) is None
    assert il.update(True, 3.14159).startswith('force control lost at t=3.142 s:')


@pytest.mark.parametrize('window_s, fraction, message', [
    (0.0, 0.5, r'^parameter saturation_window_s=0\.0: expected > 0$'),
    (-1.0, 0.5, r'^parameter saturation_window_s=-1\.0: expected > 0$'),
    (0.1, 0.0, r'^parameter saturation_abort_fraction=0\.0: expected in \(0, 1\]$'),
    (0.1, 1.5, r'^parameter saturation_abort_fraction=1\.5: expected in \(0, 1\]$'),
    (0.1, math.nan, r'^parameter saturation_abort_fraction=nan: expected in \(0, 1\]$'),
])
def test_interlock_parameter_errors(window_s, fraction, message):
    with pytest.raises(ParameterError, match=message):
        SaturationInterlock(DT, window_s, fraction)


@pytest.mark.parametrize('dt', [0.0, -0.002])
def test_interlock_bad_dt(dt):
    with pytest.raises(ParameterError, match='dt'):
        SaturationInterlock(dt, 0.1, 0.5)


# -- Closed-form checks and boundaries (issue 11: killing the mutmut survivors) ---------------

def test_dc_gain_is_37_over_4002_per_unit_error():
    """A constant error e settles at e C_f(0) = e 37/4002 V/lbf (Tustin maps s = 0 to z = 1,
    so the DC gain is exact); the poles decay as exp(-17.14/2 t), e^-25.7 after 3 s."""
    c = ForceServoController(DT)
    dc = 37.0 / LBF / 4002.0                                 # [V/N], by hand from Eq. 3.1
    assert np.sum(c.bz) / np.sum(c.az) == pytest.approx(dc, rel=1e-10)
    e = 100.0
    u = [c.step(e + 250.0, 250.0) for _ in range(1500)]
    assert u[-1] == pytest.approx(e * dc, rel=1e-9)
    assert not c.saturated


def test_a_scaled_denominator_is_prewarped_at_the_same_resonance():
    """C_f written as 2*37/(2 s^2 + 34.28 s + 8004) is the same controller: w0 = sqrt(den[2] /
    den[0]) = sqrt(4002) rad/s, so the discrete response is exact at w0 as before."""
    c = ForceServoController(DT, num=(2.0 * 37.0 / LBF,), den=(2.0, 34.28, 8004.0))
    w0 = math.sqrt(4002.0)
    z = np.exp(1j * w0 * DT)
    hd = np.polyval(c.bz, z) / np.polyval(c.az, z)
    assert abs(hd / continuous_cf(w0) - 1) < 1e-9
    assert c.design.method == 'bilinear, prewarped at 63.26 rad/s'     # sqrt(4002) = 63.261


def test_constructor_defaults():
    """Defaults: the paper controller, 10 V valve, no motion path, not saturated yet."""
    c = ForceServoController(DT)
    assert c.kind == 'loop_shaping'
    assert c.saturated is False
    assert c.design.dt == DT
    assert (c.integral_hz, c.velocity_gain_V_s_per_m, c.velocity_lead_s,
            c.velocity_filter_hz) == (0.0, 0.0, 0.0, 0.0)
    assert not c.uses_motion
    assert c.step(1e9, 0.0) == 10.0 and c.saturated


def test_loop_shaping_ignores_the_motion_inputs_even_when_not_finite():
    """g_v = 0: the command depends on the force error alone, whatever v and a are (a rig
    without a velocity measurement may send NaN)."""
    rng = np.random.default_rng(5)
    fr, fm = rng.normal(scale=400.0, size=200), rng.normal(scale=400.0, size=200)
    c1, c2 = ForceServoController(DT, 1.0), ForceServoController(DT, 1.0)
    u1 = [c1.step(a, b) for a, b in zip(fr, fm)]
    u2 = [c2.step(a, b, math.nan, math.inf) for a, b in zip(fr, fm)]
    assert np.all(np.isfinite(u2))
    np.testing.assert_array_equal(u1, u2)


def test_a_command_equal_to_the_limit_is_not_saturated():
    """|u| <= valve_limit_V is the valid range: the first command for a unit error is b0 (the
    filter state is zero), so a limit of exactly b0 passes it unsaturated, either sign."""
    b0 = ForceServoController(DT).bz[0]
    c = ForceServoController(DT, valve_limit_V=b0)
    assert c.step(1.0, 0.0) == b0 and c.saturated is False
    c.reset()
    assert c.step(0.0, 1.0) == -b0 and c.saturated is False
    c.reset()
    assert c.step(1.5, 0.0) == b0 and c.saturated is True
    c.reset()
    assert c.step(0.0, 1.5) == -b0 and c.saturated is True


@pytest.mark.parametrize('coefficients', [([None], [1.0]), ([1.0], [1.0, None])])
def test_discrete_filter_missing_coefficient(coefficients):
    """A missing (None) coefficient is a non-finite one (NaN as a float), not a TypeError."""
    with pytest.raises(ParameterError, match=r'^filter coefficients: expected finite'):
        DiscreteFilter(*coefficients)


def test_interlock_defaults_are_half_of_0_1_s():
    """Defaults window_s = 0.1 s (50 samples at 2 ms) and abort_fraction = 0.5: the 26th
    saturated sample trips (26/50 > 0.5)."""
    il = SaturationInterlock(DT)
    assert (il.window, il.abort_fraction) == (50, 0.5)
    assert first_trip(il, [True] * 50)[0] == 25


def test_interlock_from_parameters_reads_window_and_fraction(reference_params):
    """0.2 s at 2 ms = 100 samples; fraction 0.3: the smallest count above 30 is 31."""
    il = SaturationInterlock.from_parameters(dict(reference_params, saturation_window_s=0.2,
                                                  saturation_abort_fraction=0.3))
    assert (il.window, il.abort_fraction) == (100, 0.3)
    k, reason = first_trip(il, [True] * 100)
    assert k == 30
    assert reason == ('force control lost at t=0.060 s: valve command saturated in 31/100 '
                      'samples of the last 0.200 s')
