"""The run metrics (``seft_ros.analysis.metrics``) against their definitions, evaluated here.

Each expected figure is computed in this file without the module: the lag from the
cross-correlation written as its sum ``r[l] = sum_k test[k+l] reference[k]`` (numpy only) and
the vertex of the parabola through the three samples at its peak (``numpy.polyfit``); shifts
against closed forms (an index shift, a cubic polynomial, which a not-a-knot cubic spline
reproduces exactly); NRMS and peaks with numpy; the high-frequency fraction of tones centred
on the Welch bins, whose Hann-window spectrum is known in closed form (Harris 1978); the
drift as its documented even extension and forward-backward Butterworth, written out with
``scipy.signal.sosfilt``; the residual displacement of constant ends and the restoring force
``f_m - m a - c v`` by hand; the summary entry and the choice of the best runs from hand-made
comparisons.
"""

import json
import math

import numpy as np
import pytest
from scipy import signal as sps

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.criteria import Criteria
from seft_ros.analysis.metrics import (
    DofComparison,
    LinkComparison,
    RigComparison,
    RunComparison,
    SignalComparison,
    best_runs,
    compare_run,
    drift,
    estimate_lag,
    high_frequency_fraction,
    json_safe,
    nrms_error,
    peak,
    peak_ratio,
    residual_displacement,
    restoring_force,
    shift,
    summary_entry,
)
from seft_ros.analysis.reference import ReferenceResponse
from seft_ros.analysis.rundata import RunData

DT = 0.002


def lag_by_definition(test, reference, dt, max_lag_s):
    """The lag [s] as documented, in plain numpy: means removed over the common finite
    samples, r[l] = sum_k x[k+l] y[k] for |l| <= max_lag, the parabola's vertex at an interior
    positive peak, the bound at an edge peak, 0 when undefined."""
    n = min(len(test), len(reference))
    x, y = np.array(test[:n], dtype=float), np.array(reference[:n], dtype=float)
    good = np.isfinite(x) & np.isfinite(y)
    if n < 2 or not good.any():
        return 0.0
    x = np.where(good, x - x[good].mean(), 0.0)
    y = np.where(good, y - y[good].mean(), 0.0)
    if not (x.any() and y.any()):
        return 0.0
    max_lag = min(int(math.floor(round(max_lag_s / dt, 6))), n - 1)
    lags = np.arange(-max_lag, max_lag + 1)
    r = np.array([np.dot(x[max(j, 0):n + min(j, 0)], y[max(-j, 0):n - max(j, 0)])
                  for j in lags])
    i = int(np.argmax(r))
    if r[i] <= 0:
        return 0.0
    if i in (0, len(r) - 1):
        return float(lags[i] * dt)
    a, b, _ = np.polyfit([-1.0, 0.0, 1.0], r[i - 1:i + 2], 2)
    return float((lags[i] - b / (2 * a)) * dt)


def tones(t, *pairs):
    """Sum of a sin(2 pi f t + phase) over (a, f, phase) triples."""
    return sum(a * np.sin(2 * np.pi * f * t + ph) for a, f, ph in pairs)


# -- estimate_lag -------------------------------------------------------------------------

@pytest.mark.parametrize('seed, max_lag_s, offset, n_nan', [
    (1, 0.1, 0.0, 0), (2, 0.02, 3.0, 0), (3, 0.1, -0.4, 7), (4, 0.006, 0.0, 0),
    (5, 0.05, 1e3, 25),
])
def test_lag_matches_its_definition(seed, max_lag_s, offset, n_nan):
    """Random lagged noise with an offset and NaN samples: the lag of the definition."""
    rng = np.random.default_rng(seed)
    reference = np.convolve(rng.standard_normal(600), np.hanning(9), mode='same')
    test = np.roll(reference, 3) * 0.8 + 0.05 * rng.standard_normal(600) + offset
    test[rng.choice(600, n_nan, replace=False)] = np.nan
    expected = lag_by_definition(test, reference, DT, max_lag_s)
    assert estimate_lag(test, reference, DT, max_lag_s) == pytest.approx(expected, abs=1e-12)
    assert abs(expected) <= max_lag_s


def test_lag_of_a_signal_in_metres():
    """The lag does not depend on the unit: a response of a few mm has the lag of its
    copy in mm (r < 1 m^2 there)."""
    t = np.arange(3000) * DT
    reference = tones(t, (1.0, 6.1, 0.2), (0.4, 11.3, 1.0))
    test = tones(t - 0.0073, (1.0, 6.1, 0.2), (0.4, 11.3, 1.0))
    in_mm = estimate_lag(test, reference, DT)
    assert in_mm == pytest.approx(lag_by_definition(test, reference, DT, 0.1), abs=1e-12)
    assert in_mm == pytest.approx(0.0073, abs=2e-4)
    assert estimate_lag(1e-3 * test, 1e-3 * reference, DT) == pytest.approx(in_mm, abs=1e-12)


def test_lag_search_bound_of_a_whole_number_of_samples():
    """max_lag_s = 6 ms is 3 samples of 2 ms (6e-3 / 2e-3 = 2.9999999999999996 in floats):
    a 3-sample delay is found at the bound, not clamped to 2 samples."""
    rng = np.random.default_rng(6)
    reference = rng.standard_normal(400)
    test = np.concatenate([np.zeros(3), reference[:-3]])
    assert estimate_lag(test, reference, DT, 0.006) == pytest.approx(0.006, abs=1e-15)
    assert estimate_lag(test, reference, DT, 0.004) == pytest.approx(0.004, abs=1e-15)
    assert estimate_lag(reference, test, DT, 0.006) == pytest.approx(-0.006, abs=1e-15)
    # a bound of 2.5 samples searches 2: the peak at its edge, 2 samples (not the bound)
    assert estimate_lag(test, reference, DT, 0.005) == pytest.approx(0.004, abs=1e-15)


def test_lag_without_a_positive_correlation_is_zero():
    """x = [-3, -1, 1, 3], y = [2, -1, 1, -2] (means 0): r[l] for l = -2..2 is
    [-1, 0, -10, 0, -1] by hand; the peak r = 0 correlates nothing, so no lag."""
    x, y = [-3.0, -1.0, 1.0, 3.0], [2.0, -1.0, 1.0, -2.0]
    assert estimate_lag(x, y, 1.0, 2.0) == 0.0
    assert estimate_lag(x, [-v for v in x], 1.0, 0.0) == 0.0     # r[0] = -20 < 0


def test_lag_uses_the_common_samples_and_tiny_windows():
    rng = np.random.default_rng(9)
    reference = rng.standard_normal(300)
    test = np.concatenate([np.zeros(2), reference[:-2], rng.standard_normal(50)])  # longer
    assert estimate_lag(test, reference, DT, 0.02) == pytest.approx(
        lag_by_definition(test, reference, DT, 0.02), abs=1e-12)
    # by hand: means removed, x = [-1, -1, 2] / 3 and y = [-1, 2, -1] / 3 give
    # r[0], r[1], r[2] = -3/9, 5/9, -2/9; the vertex lies 0.5 (r0 - r2) / (r0 - 2 r1 + r2)
    # = 1/30 after the peak at l = 1
    assert estimate_lag([0.0, 0.0, 1.0], [0.0, 1.0, 0.0], DT, 1.0) == pytest.approx(
        31 / 30 * DT, rel=1e-12)
    assert estimate_lag([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], DT, 1.0) == pytest.approx(
        -31 / 30 * DT, rel=1e-12)
    # two samples, means removed: x = -y = [-0.5, 0.5] correlate at -1 and +1 sample alike
    # (r = 0.25) and anti-correlate at 0 (r = -0.5): one of the two, not 0
    assert abs(estimate_lag([0.0, 1.0], [1.0, 0.0], DT, 1.0)) == pytest.approx(DT, rel=1e-15)
    # a zero bound: lag 0 whatever the signals
    assert estimate_lag(test, reference, DT, 0) == 0.0
    assert estimate_lag(np.full(10, np.nan), np.ones(10), DT) == 0.0
    assert estimate_lag(np.ones(10), np.arange(10.0), DT) == 0.0        # constant test


@pytest.mark.parametrize('max_lag_s', [True, '0.1', math.inf, math.nan, -1e-3, None])
def test_lag_bound_errors(max_lag_s):
    message = f'^parameter max_lag_s={max_lag_s!r}: expected a finite float >= 0$'
    with pytest.raises(ParameterError, match=message.replace('(', r'\(').replace(')', r'\)')):
        estimate_lag(np.zeros(10), np.zeros(10), DT, max_lag_s)


def test_lag_signal_errors():
    with pytest.raises(ParameterError, match=r'^test: expected a 1-D array, got shape \(2, 2\)$'):
        estimate_lag(np.zeros((2, 2)), np.zeros(4), DT)
    with pytest.raises(ParameterError, match=r'^reference: expected a 1-D array, got shape'):
        estimate_lag(np.zeros(4), np.zeros((2, 2)), DT)


def test_lag_accepts_numpy_bounds():
    rng = np.random.default_rng(2)
    reference = rng.standard_normal(200)
    test = np.concatenate([np.zeros(1), reference[:-1]])
    assert estimate_lag(test, reference, DT, np.float32(0.01)) == pytest.approx(DT, abs=1e-4)
    assert estimate_lag(test, reference, DT, np.int64(1)) == pytest.approx(DT, abs=1e-4)


# -- shift --------------------------------------------------------------------------------

def test_shift_of_a_cubic_is_exact():
    """A not-a-knot cubic spline reproduces a cubic: y[k] = p(k + s) exactly, NaN where
    k + s falls outside [0, n - 1]."""
    n = 40
    k = np.arange(n, dtype=float)

    def p(u):
        return 0.3 - 0.2 * u + 0.05 * u ** 2 - 1e-3 * u ** 3
    for steps, n_nan_head, n_nan_tail in ((0.4, 0, 1), (-1.5, 2, 0), (2.25, 0, 3)):
        y = shift(p(k), steps * DT, DT)
        inside = np.arange(n_nan_head, n - n_nan_tail)
        np.testing.assert_allclose(y[inside], p(k[inside] + steps), rtol=0, atol=1e-12)
        assert np.isnan(y[:n_nan_head]).all() and np.isnan(y[n - n_nan_tail:]).all()


def test_shift_by_whole_samples_within_rounding():
    """6 ms / 2 ms = 2.9999999999999996: an exact shift by 3 samples, not an interpolation."""
    x = np.random.default_rng(1).standard_normal(12)
    y = shift(x, 0.006, DT)
    np.testing.assert_array_equal(y[:9], x[3:])
    assert np.isnan(y[9:]).all()
    np.testing.assert_array_equal(shift(x, 0.0, DT), x)
    np.testing.assert_array_equal(shift(x, 0, DT), x)
    y = shift(x, np.float64(-0.006), DT)
    np.testing.assert_array_equal(y[3:], x[:9])
    assert np.isnan(y[:3]).all()


def test_shift_of_one_and_two_samples():
    assert np.isnan(shift([2.0], 0.5 * DT, DT)).all()
    assert shift([2.0], 0.0, DT).tolist() == [2.0]
    # two samples: the spline is the straight line through them, 1 + 0.25 (3 - 1) = 1.5
    y = shift([1.0, 3.0], 0.25 * DT, DT)
    assert y[0] == pytest.approx(1.5, rel=1e-15) and np.isnan(y[1])


def test_whole_sample_shift_moves_a_missing_sample_only():
    """An index shift has no support to poison: the NaN moves by 2 samples, nothing else."""
    x = np.arange(10.0)
    x[5] = np.nan
    y = shift(x, 2 * DT, DT)
    assert np.flatnonzero(np.isnan(y)).tolist() == [3, 8, 9]
    np.testing.assert_array_equal(y[[0, 1, 2, 4, 5, 6, 7]], [2.0, 3.0, 4.0, 6.0, 7.0, 8.0, 9.0])


def test_shift_of_a_zero_record_with_a_missing_sample_stays_zero():
    """The missing sample contributes nothing to the samples kept (it counts as 0)."""
    x = np.zeros(30)
    x[12] = np.nan
    y = shift(x, 0.3 * DT, DT)
    kept = np.isfinite(y)
    assert np.flatnonzero(~kept).tolist() == list(range(9, 15)) + [29]
    assert np.all(y[kept] == 0.0)


@pytest.mark.parametrize('bad, steps, expected', [
    # k + 0.5 brackets k and k+1: poisoned where either is within 2 samples of index 10
    (10, 0.5, list(range(7, 13)) + [19]),
    # k - 0.5 brackets k-1 and k: [8, 13], and sample 0 falls before the record
    (10, -0.5, [0] + list(range(8, 14))),
    # 4 is 4 samples from sample 0 and 3 from its neighbour 1: sample 0 is kept
    (4, 0.5, [1, 2, 3, 4, 5, 6, 19]),
    # a non-finite first sample: the clipped brackets at the start
    (0, -0.5, [0, 1, 2, 3]),
    (19, 0.5, [16, 17, 18, 19]),
])
def test_shift_poisons_exactly_the_samples_near_a_non_finite_one(bad, steps, expected):
    x = np.sin(0.3 * np.arange(20))
    x[bad] = np.inf if bad % 2 else np.nan
    y = shift(x, steps * DT, DT)
    assert np.flatnonzero(np.isnan(y)).tolist() == expected


@pytest.mark.parametrize('lag_s', [True, '0.1', math.inf, -math.inf, math.nan, None])
def test_shift_lag_errors(lag_s):
    with pytest.raises(ParameterError, match=f'^parameter lag_s={lag_s!r}: expected a finite '
                                             'float$'):
        shift(np.zeros(5), lag_s, DT)


def test_shift_signal_errors():
    with pytest.raises(ParameterError, match=r'^signal: expected a 1-D array, got shape'):
        shift(np.zeros((2, 3)), 0.001, DT)


# -- nrms, peaks --------------------------------------------------------------------------

def test_nrms_by_hand():
    # sqrt(0 + 1 + 4) / sqrt(1 + 1 + 1) = sqrt(5 / 3)
    assert nrms_error([1.0, 2.0, 3.0], [1.0, 1.0, 1.0]) == pytest.approx(math.sqrt(5 / 3),
                                                                         rel=1e-15)
    # the samples not finite in either signal are left out: sqrt(4) / sqrt(4) = 1
    assert nrms_error([1.0, np.nan, 5.0, 0.0], [np.inf, 7.0, 3.0, 2.0]) == pytest.approx(
        math.sqrt(4 + 4) / math.sqrt(9 + 4), rel=1e-15)


def test_nrms_matches_numpy():
    rng = np.random.default_rng(5)
    ref, test = rng.standard_normal(500), rng.standard_normal(500)
    test[::11] = np.nan
    ref[::13] = -np.inf
    ok = np.isfinite(test) & np.isfinite(ref)
    expected = np.linalg.norm(test[ok] - ref[ok]) / np.linalg.norm(ref[ok])
    assert nrms_error(test, ref) == pytest.approx(expected, rel=1e-13)


def test_nrms_errors():
    message = r'^nrms_error: test and reference have shapes \(3,\) and \(2,\); expected the same$'
    with pytest.raises(ParameterError, match=message):
        nrms_error([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ParameterError, match=r'^reference: expected a 1-D array'):
        nrms_error(np.ones(3), np.ones((3, 1)))
    with pytest.raises(ParameterError, match=r'^test: expected a 1-D array'):
        nrms_error(np.ones((3, 1)), np.ones(3))
    assert math.isnan(nrms_error([], []))


def test_peaks():
    assert peak([np.nan, -np.inf, 1.0]) == math.inf
    assert math.isnan(peak([np.nan, np.nan]))
    assert peak(np.array([0.5, -2.5])) == 2.5
    assert peak_ratio([-4.0, 1.0], [np.nan, 2.0, -0.5]) == 2.0
    assert math.isnan(peak_ratio([1.0], [np.nan]))
    assert math.isnan(peak_ratio([1.0], []))
    with pytest.raises(ParameterError, match=r'^x: expected a 1-D array'):
        peak(np.ones((2, 2)))


# -- high-frequency fraction --------------------------------------------------------------

# Welch segments of 512 samples at 500 Hz: bins every 500 / 512 Hz. A tone on bin j has its
# Hann-windowed power on bins j - 1, j, j + 1 only, in the ratio 1/16 : 1/4 : 1/16
# (the periodic Hann window's transform, Harris 1978), whatever its phase.
BIN = 500.0 / 512


@pytest.mark.parametrize('cutoff_bin, expected', [
    (20.5, 0.25 / (1.0 + 0.25)),             # all of the 0.5 tone (bin 41) lies above
    (40.0, 0.25 * 5 / 6 / (1.0 + 0.25)),     # its lower side bin (1/6 of it) is not above
    (41.0, 0.25 / 6 / (1.0 + 0.25)),         # only its upper side bin
    (4.0, (5 / 6 + 0.25) / (1.0 + 0.25)),    # 5/6 of the 1.0 tone (bin 5) and all of the other
])
def test_high_frequency_fraction_of_tones_on_bins(cutoff_bin, expected):
    t = np.arange(6000) * DT
    x = tones(t, (1.0, 5 * BIN, 0.3), (0.5, 41 * BIN, 1.1))
    assert high_frequency_fraction(x, DT, cutoff_bin * BIN) == pytest.approx(expected,
                                                                             rel=1e-9)


def test_high_frequency_fraction_of_a_short_or_truncated_record():
    """n < 512: one segment of n samples, bins every 500 / n Hz (here 256: tones on bins
    3 and 40, cut-off between them): a2^2 / (a1^2 + a2^2) = 0.04 / 1.04. A non-finite sample
    ends the record (the 512 finite ones before it)."""
    t = np.arange(256) * DT
    x = tones(t, (1.0, 3 * 500 / 256, 0.0), (0.2, 40 * 500 / 256, 2.0))
    assert high_frequency_fraction(x, DT) == pytest.approx(0.04 / 1.04, rel=1e-9)
    t = np.arange(700) * DT
    x = tones(t, (1.0, 5 * BIN, 0.3), (0.5, 41 * BIN, 1.1))
    x[512] = np.nan
    x[600:] = 1e6                          # after the first non-finite sample: ignored
    assert high_frequency_fraction(x, DT) == pytest.approx(0.25 / 1.25, rel=1e-9)


def test_high_frequency_fraction_needs_eight_samples():
    x = np.array([0.0, 1.0, 0.0, -1.0] * 2)         # 125 Hz on 8 samples: all above 20 Hz
    assert high_frequency_fraction(x, DT) == pytest.approx(1.0, rel=1e-12)
    assert math.isnan(high_frequency_fraction(x[:7], DT))


@pytest.mark.parametrize('cutoff', [0.0, -1.0, 250.0, 300.0, True, '20', None])
def test_high_frequency_cutoff_errors(cutoff):
    message = (f'^parameter cutoff_hz={cutoff!r}: expected a float in (0, 250) Hz$'
               .replace('(', r'\(').replace(')', r'\)'))
    with pytest.raises(ParameterError, match=message):
        high_frequency_fraction(np.ones(100), DT, cutoff)


def test_high_frequency_cutoff_types():
    t = np.arange(1024) * DT
    x = tones(t, (1.0, 5 * BIN, 0.3), (0.5, 41 * BIN, 1.1))
    for cutoff in (20, np.float32(20.0), np.int64(20)):
        assert high_frequency_fraction(x, DT, cutoff) == pytest.approx(0.2, rel=1e-6)
    # a cut-off of 0.5 Hz, below both tones: all the power
    assert high_frequency_fraction(x, DT, 0.5) == pytest.approx(1.0, rel=1e-12)
    with pytest.raises(ParameterError, match=r'^x: expected a 1-D array'):
        high_frequency_fraction(np.ones((20, 2)), DT)


# -- compare_run ----------------------------------------------------------------------------

N = 2000                                    # 4 s at 2 ms
T = np.arange(N) * DT
END = T >= 3.5                              # the last 0.5 s (250 samples)


def _structure():
    """A reference whose displacement comes to rest at 1.0 mm in the last 0.5 s (an
    oscillation tapered to 0 at 3.5 s on a smooth offset); force and acceleration tones."""
    taper = np.clip(3.5 - T, 0.0, 1.0) ** 2
    x = 1e-3 * np.clip(T / 2.0, 0.0, 1.0) + 2e-3 * taper * tones(T, (1.0, 3.3, 0.1),
                                                                   (0.5, 7.1, 0.4))
    assert np.all(x[END] == 1e-3)
    force = tones(T, (400.0, 5 * BIN, 0.3), (200.0, 41 * BIN, 1.1))     # 40 Hz: 0.2 of it
    acc = tones(T, (3.0, 4.4, 0.2), (1.0, 9.6, 0.7))
    return ReferenceResponse(time_s=T, displacement_m=x, velocity_m_s=np.zeros(N),
                             acceleration_m_s2=acc, force_N=force)


def _test_of(reference, delay=0, offset_m=0.0):
    """The reference delayed by whole samples (at rest before), the displacement offset."""
    def late(v):
        return np.concatenate([np.full(delay, v[0]), v[:N - delay]])
    return RunData.one_rig(params={'dt': DT}, time_s=T, ground_acceleration_m_s2=np.zeros(N),
                   reference_force_N=reference.force_N, measured_force_N=late(reference.force_N),
                   displacement_m=late(reference.displacement_m) + offset_m,
                   velocity_m_s=np.zeros(N), acceleration_m_s2=late(reference.acceleration_m_s2))


def test_compare_run_removes_a_constant_offset_with_the_drift():
    """A test offset by d = 0.5 mm: the displacement NRMS is |d| sqrt(N) / ||x_ref|| (numpy),
    the residual displacements are the end values 1.5 and 1.0 mm (the Hann-weighted mean of
    a constant), and without the drifts the test is the reference (the drift passes a
    constant, so x - drift(x) is the same for both)."""
    reference = _structure()
    run = _test_of(reference, offset_m=5e-4)
    c = compare_run(run, reference, drift_cutoff_hz=0.5, residual_window_s=0.5)
    x_ref = reference.displacement_m
    assert c.displacement.lag_s == pytest.approx(0.0, abs=1e-9)
    assert c.displacement.nrms == pytest.approx(5e-4 * math.sqrt(N) / np.linalg.norm(x_ref),
                                                rel=1e-9)
    r = c.residual
    assert (r.drift_cutoff_hz, r.residual_window_s) == (0.5, 0.5)
    assert r.residual_test_m == pytest.approx(1.5e-3, rel=1e-12)
    assert r.residual_reference_m == pytest.approx(1.0e-3, rel=1e-12)
    assert r.peak_test_m == pytest.approx(np.max(np.abs(x_ref + 5e-4)), rel=1e-15)
    assert r.peak_reference_m == pytest.approx(np.max(np.abs(x_ref)), rel=1e-15)
    assert (r.lag_s, r.nrms) == (c.displacement.lag_s, c.displacement.nrms)
    assert r.nrms_residual_removed < 1e-8
    for name in ('force', 'acceleration'):
        assert c.signal(name).nrms == pytest.approx(0.0, abs=1e-12)
    # the default window (2 s) reaches into the oscillation: no longer the end value
    default = compare_run(run, reference).residual
    assert (default.drift_cutoff_hz, default.residual_window_s) == (0.25, 2.0)
    assert abs(default.residual_reference_m - 1.0e-3) > 1e-6


def test_compare_run_passes_its_bounds_and_cutoff():
    """A 5-sample delay searched within 4 ms: every lag is the bound's 2 samples, and so is
    J1 within 4 ms (10 ms, the delay, within its default 0.1 s). The reference force's tones
    of 400 N and 200 N on bins 5 and 41: 200^2 / (400^2 + 200^2) = 0.2 of the power above
    20 Hz, none above 45 Hz (the upper side bin of the 200 N tone, 42, is at 41 Hz)."""
    reference = _structure()
    run = _test_of(reference, delay=5)
    c = compare_run(run, reference, max_lag_s=0.004, j1_max_lag_s=0.004)
    for name in ('displacement', 'force', 'acceleration'):
        assert c.signal(name).lag_s == pytest.approx(0.004, abs=1e-15)
        # the common lag (the displacement's) is searched within the same bound
        assert c.signal(name).nrms_common_lag == pytest.approx(c.signal(name).nrms, rel=1e-12)
    assert c.force.nrms > 0.05                   # 3 samples of the delay are left
    assert c.criteria.j1_ms == pytest.approx(4.0) and c.criteria.j1_max_lag_s == 0.004
    assert c.residual.lag_s == pytest.approx(0.004, abs=1e-15)
    c = compare_run(run, reference, high_frequency_cutoff_hz=45.0)
    assert c.criteria.j1_ms == pytest.approx(10.0)
    assert c.displacement.lag_s == pytest.approx(0.010, abs=1e-5)
    assert c.high_frequency_cutoff_hz == 45.0
    assert c.high_frequency_force_fraction_reference == pytest.approx(0.0, abs=1e-12)
    assert compare_run(run, reference).high_frequency_force_fraction_reference == \
        pytest.approx(0.2, rel=1e-9)


def test_compare_run_errors():
    reference = _structure()
    run = _test_of(reference)
    short = ReferenceResponse(time_s=T[:5], displacement_m=T[:5], velocity_m_s=T[:5],
                              acceleration_m_s2=T[:5], force_N=T[:5])
    with pytest.raises(ParameterError, match=r'^reference has 5 samples, the run 2000; '
                                             r'expected at least as many as the run$'):
        compare_run(run, short)
    c = compare_run(run, reference)
    with pytest.raises(ParameterError, match=r"^signal 'velocity': expected one of "
                                             r'displacement, force, acceleration$'):
        c.signal('velocity')


# -- residual displacement, drift, restoring force: edges -----------------------------------

def test_residual_of_a_window_shorter_than_a_sample_is_the_last_sample():
    """round(0.9 ms / 2 ms) = 0 samples: at least one, the Hann weight of which is 1."""
    assert residual_displacement([1.0, 2.0, 3.0], DT, window_s=0.0009) == 3.0
    # 2 samples: hann(4)[1:-1] = [0.75, 0.75], the mean of the last two
    assert residual_displacement([1.0, 2.0, 3.0], DT, window_s=0.004) == pytest.approx(2.5)


def test_residual_and_drift_errors():
    with pytest.raises(ParameterError, match=r'^x: expected a 1-D array'):
        residual_displacement(np.zeros((3, 3)), DT)
    with pytest.raises(ParameterError, match=r'^x: expected a 1-D array'):
        drift(np.zeros((3, 3)), DT)
    with pytest.raises(ParameterError,
                       match=r'^parameter window_s=True: expected a finite float > 0$'):
        residual_displacement([1.0, 2.0], DT, window_s=True)


def drift_by_definition(x, dt, cutoff_hz):
    """The documented drift written out: the record extended at both ends by its even
    reflection of n - 1 samples, the 4th-order Butterworth low-pass run forward and then
    backward (``sosfilt`` from the steady state of the first sample), the extension cut off."""
    x = np.asarray(x, dtype=float)
    p = x.shape[0] - 1
    ext = np.concatenate([x[1:p + 1][::-1], x, x[-p - 1:-1][::-1]])
    sos = sps.butter(4, cutoff_hz, fs=1.0 / dt, output='sos')
    zi = sps.sosfilt_zi(sos)
    y = sps.sosfilt(sos, ext, zi=zi * ext[0])[0][::-1]
    y = sps.sosfilt(sos, y, zi=zi * y[0])[0][::-1]
    return y[p:p + x.shape[0]]


@pytest.mark.parametrize('n, cutoff_hz', [(2, 0.25), (3, 0.25), (40, 5.0), (1500, 0.25)])
def test_drift_matches_its_definition(n, cutoff_hz):
    x = 1e-3 * np.cumsum(np.random.default_rng(n).standard_normal(n))
    np.testing.assert_allclose(drift(x, DT, cutoff_hz), drift_by_definition(x, DT, cutoff_hz),
                               rtol=0, atol=1e-12 * np.max(np.abs(x)))


def _member_run(mass, damping, n_time=3):
    """A run of 3 samples (its signals 4 long: the sample count is that of time_s)."""
    return RunData.one_rig(params={'dt': DT, 'mass_kg': mass, 'damping_N_s_per_m': damping},
                   time_s=np.arange(n_time) * DT, ground_acceleration_m_s2=np.zeros(n_time),
                   reference_force_N=np.zeros(n_time),
                   measured_force_N=np.array([10.0, -4.0, 2.5, 99.0]),
                   displacement_m=np.zeros(n_time), velocity_m_s=np.array([0.5, 1.0, -2.0, 9.0]),
                   acceleration_m_s2=np.array([2.0, -1.0, 0.25, 9.0]))


@pytest.mark.parametrize('mass, damping, expected', [
    # f_s = f_m - m a - c v, by hand: 10 - 2*2 - 3*0.5 = 4.5; -4 + 2 - 3 = -5;
    # 2.5 - 0.5 + 6 = 8
    (2.0, 3.0, [4.5, -5.0, 8.0]),
    (0.5, 0.0, [9.0, -3.5, 2.375]),          # a light member without damping
    (0.5, 0.5, [8.75, -4.0, 3.375]),
])
def test_restoring_force_by_hand(mass, damping, expected):
    assert restoring_force(_member_run(mass, damping)).tolist() == pytest.approx(expected,
                                                                                rel=1e-15)


@pytest.mark.parametrize('mass, damping, message', [
    (0.0, 1.0, r'^parameter mass_kg=0\.0: expected a finite float > 0$'),
    (math.inf, 1.0, r'^parameter mass_kg=inf: expected a finite float > 0$'),
    (True, 1.0, r'^parameter mass_kg=True: expected a finite float > 0$'),
    (1.0, -0.1, r'^parameter damping_N_s_per_m=-0\.1: expected a finite float >= 0$'),
    (1.0, '2', r"^parameter damping_N_s_per_m='2': expected a finite float >= 0$"),
])
def test_restoring_force_errors(mass, damping, message):
    with pytest.raises(ParameterError, match=message):
        restoring_force(_member_run(mass, damping))
    run = _member_run(1.0, 1.0)
    del run.params['damping_N_s_per_m']
    with pytest.raises(ParameterError, match=r'^run parameters: missing damping_N_s_per_m$'):
        restoring_force(run)


# -- json_safe, summary_entry, best_runs ----------------------------------------------------

def test_json_safe_by_type():
    value = {1: (np.float32(0.5), -np.inf, None), 'b': [np.int32(-3), True, np.bool_(False)],
             'c': {'d': math.nan, 'e': 2, 'f': 1.5, 'g': 'text'}}
    safe = json_safe(value)
    assert safe == {'1': [0.5, None, None], 'b': [-3, True, False],
                    'c': {'d': None, 'e': 2, 'f': 1.5, 'g': 'text'}}
    assert [type(v) for v in safe['b']] == [int, bool, bool]
    assert type(safe['1'][0]) is float and type(safe['c']['e']) is int
    assert json.loads(json.dumps(safe, allow_nan=False)) == safe


def _signal(base):
    """A comparison whose fields are base + 0.1, ..., base + 0.6, each one told apart."""
    return SignalComparison(peak_test=base + 0.1, peak_reference=base + 0.2, lag_s=base + 0.3,
                            nrms=base + 0.4, peak_ratio=base + 0.5, nrms_unshifted=base + 0.6,
                            nrms_common_lag=base + 0.7)


def _hand_made(params, criteria=None, **run_fields):
    zeros = np.zeros(3)
    run = RunData.one_rig(params=params, time_s=np.arange(3) * DT, ground_acceleration_m_s2=zeros,
                  reference_force_N=zeros, measured_force_N=zeros, displacement_m=zeros,
                  velocity_m_s=zeros, acceleration_m_s2=zeros, **run_fields)
    reference = ReferenceResponse(time_s=run.time_s, displacement_m=zeros, velocity_m_s=zeros,
                                  acceleration_m_s2=zeros, force_N=zeros)
    rig = RigComparison(displacement=_signal(1.0), force=_signal(2.0),
                        acceleration=_signal(3.0), reference=reference,
                        high_frequency_force_fraction=0.25,
                        high_frequency_force_fraction_reference=math.nan,
                        high_frequency_cutoff_hz=30.0, criteria=criteria)
    dof = DofComparison('specimen', '', rig.displacement, rig.acceleration, _signal(4.0),
                        rig.force)
    comparison = RunComparison({'': rig}, (dof,), (LinkComparison('specimen-ground',
                                                                  _signal(5.0)),),
                               n_steps=3)
    return run, comparison


def _signal_entry(base):
    """The summary of :func:`_signal`."""
    return {'nrms': base + 0.4, 'peak_ratio': base + 0.5, 'lag_s': base + 0.3,
            'peak_test': base + 0.1, 'peak_reference': base + 0.2, 'nrms_common_lag': base + 0.7,
            'nrms_unshifted': base + 0.6}


def test_summary_entry_of_a_hand_made_comparison():
    criteria = Criteria(j1_ms=4.0, j2_pct=1.5, j3_pct=math.inf, j4_pct=2.5, j5_pct=3.5)
    run, comparison = _hand_made(
        {'alpha': 1.5, 'rig_model': 'servohydraulic', 'predictor': 'model', 'record': 'kobe',
         'mode': 'realtime'}, criteria, stable=False, unstable_at_s=math.inf,
        abort_reason='force limit', record_name='',
        extra={'wall_s': np.float64(3.25), 'bag_lost_messages': np.int64(4),
               'recording': {'end': 'crashed'}})
    entry = summary_entry(run, comparison)
    signals = ('displacement', 'acceleration', 'force')
    base = {'displacement': 1.0, 'force': 2.0, 'acceleration': 3.0}
    rig = {key: entry[key] for key in ('alpha', 'rig', 'lag_s', 'nrms', 'nrms_common_lag',
                                       'nrms_unshifted', 'criteria', 'peak_ratio',
                                       'high_frequency_force_fraction',
                                       'high_frequency_force_fraction_reference',
                                       'high_frequency_cutoff_hz')}
    study = {key: value for key, value in entry.items()
             if key not in ('abort_node', 'n_steps', 'structure', 'worst_nrms', 'dofs',
                            'links', 'rigs')}
    assert study == {
        'alpha': 1.5, 'rig': 'servohydraulic', 'predictor': 'model', 'record': 'kobe',
        'stable': False, 'unstable_at_s': None, 'lag_s': 1.3,
        'nrms': {s: base[s] + 0.4 for s in signals},
        'nrms_common_lag': {s: base[s] + 0.7 for s in signals},
        'nrms_unshifted': {s: base[s] + 0.6 for s in signals},
        'criteria': {'J1': 4.0, 'J2': 1.5, 'J3': None, 'J4': 2.5, 'J5': 3.5},
        'peak_ratio': {s: base[s] + 0.5 for s in signals},
        'high_frequency_force_fraction': 0.25,
        'high_frequency_force_fraction_reference': None, 'high_frequency_cutoff_hz': 30.0,
        'abort_reason': 'force limit', 'mode': 'realtime', 'wall_s': 3.25,
        'bag_lost_messages': 4, 'recording': {'end': 'crashed'}, 'rig_contract': None,
        'warnings': [],
        # issue 39: no ranges in these parameters, nothing counted (from the signals), no
        # flags, and the verdict of an aborted run
        'sensor_range': {'': {'samples': dict.fromkeys(('force', 'displacement', 'velocity',
                                                        'acceleration'), 0),
                              'ranges': dict.fromkeys(('force', 'displacement', 'velocity',
                                                       'acceleration')),
                              'first_s': {}, 'last_s': {}, 'acceleration_estimated': None,
                              'source': 'signals'}},
        'valve_saturation': {}, 'flags': [], 'verdict': 'aborted'}
    # the sections of every run: the one DOF, its link, the rig (the study's keys again)
    assert (entry['abort_node'], entry['n_steps']) == (None, 3)
    assert entry['structure'] == {'dofs': ['specimen'], 'physical': {'specimen': ''},
                                  'builders': 'central'}
    assert entry['dofs'] == {'specimen': {
        'rig': '', 'displacement': _signal_entry(1.0), 'acceleration': _signal_entry(3.0),
        'floor_acceleration': _signal_entry(4.0), 'interface_force': _signal_entry(2.0)}}
    assert entry['links'] == {'specimen-ground': _signal_entry(5.0)}
    assert entry['worst_nrms'] == {'displacement': 1.4, 'acceleration': 3.4,
                                   'floor_acceleration': 4.4, 'interface_force': 2.4}
    rig['rig_model'] = rig.pop('rig')
    assert entry['rigs'] == {'': {'dof': 'specimen', **rig, 'specimen_model': 'linear',
                                  'rig_contract': None}}
    assert list(entry['nrms']) == list(signals) and type(entry['bag_lost_messages']) is int
    assert entry['recording'] is not run.extra['recording']      # a copy
    assert json.loads(json.dumps(entry, allow_nan=False)) == entry


def test_summary_entry_defaults():
    """No criteria, no mode, no record name or record, alpha NaN, no extra data."""
    run, comparison = _hand_made({'alpha': math.nan}, record_name='')
    entry = summary_entry(run, comparison)
    assert entry['criteria'] == {'J1': None, 'J2': None, 'J3': None, 'J4': None, 'J5': None}
    assert (entry['alpha'], entry['rig'], entry['predictor'], entry['record']) == \
        (None, None, None, '')
    assert (entry['mode'], entry['wall_s'], entry['stable'], entry['unstable_at_s']) == \
        ('lockstep', None, True, None)
    assert not {'timing', 'bag_lost_messages', 'recording', 'nonlinear',
                'parameter_mismatches'} & set(entry)
    run, comparison = _hand_made({'alpha': 0, 'record': 'kobe'}, record_name='kobe_x2',
                                 unstable_at_s=7.5, extra={'timing': None})
    entry = summary_entry(run, comparison)
    assert (entry['alpha'], entry['record'], entry['unstable_at_s']) == (0.0, 'kobe_x2', 7.5)
    assert type(entry['alpha']) is float and 'timing' not in entry


def test_best_runs_skips_what_is_not_a_finite_nrms():
    entries = [
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True,
         'nrms': {'displacement': True}},                       # a bool is no NRMS
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True,
         'nrms': {'displacement': math.inf}},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True, 'nrms': None},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'nrms': {'displacement': 0.01}},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True,
         'nrms': {'displacement': '0.01'}},
        {'alpha': 1.0, 'rig': 'delay', 'stable': True, 'nrms': {'displacement': 0.01}},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'ats', 'stable': True,
         'nrms': {'displacement': 2}},                          # an int is a number
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'model', 'stable': True,
         'nrms': {'displacement': 1.5}},
        {'alpha': 1.0, 'rig': 'delay', 'predictor': 'adaptive', 'stable': True,
         'nrms': {'displacement': 1.5}},                        # a tie: the first one stays
    ]
    best = best_runs(entries)
    assert list(best) == [(1.0, 'delay')] and best[(1.0, 'delay')] is entries[8]
    with pytest.raises(ParameterError, match=r"^summary entry \('a', 1\): expected a dict$"):
        best_runs([('a', 1)])


@pytest.mark.parametrize('lag_steps', [10, 12, -10, -12, 10.5])
def test_shift_past_the_record_is_all_nan(lag_steps):
    """A lag of the record's length or more leaves no sample (10 samples, dt 2 ms)."""
    out = shift(np.arange(10.0), lag_steps * 0.002, 0.002)
    assert out.shape == (10,) and np.all(np.isnan(out))
