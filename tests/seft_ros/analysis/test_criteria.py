"""The RTHS benchmark's criteria J1-J5 against values worked by hand on small arrays."""

import math

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.criteria import (
    J1_MAX_LAG_S,
    Criteria,
    evaluation_criteria,
    normalized_peak_error,
    normalized_std_error,
    tracking_delay,
)

# A 5-sample example, worked by hand:
#   target   t = [0, 1, 0, -1, 0]     mean 0, std = sqrt((0+1+0+1+0)/5) = sqrt(0.4)
#   measured m = [0, 1.5, 0, -1, 1]
#   error    e = m - t = [0, 0.5, 0, 0, 1]
#            mean 0.3, std = sqrt(((-0.3)^2 + 0.2^2 + (-0.3)^2 + (-0.3)^2 + 0.7^2)/5)
#                          = sqrt((0.09 + 0.04 + 0.09 + 0.09 + 0.49)/5) = sqrt(0.16) = 0.4
#   J2 = 100 * 0.4 / sqrt(0.4) = 100 * sqrt(0.4) = 63.2456 %
#   J3 = 100 * max|e| / max|t| = 100 * 1 / 1 = 100 %
#   (the RMS of e would be sqrt((0.25 + 1)/5) = 0.5: 79.06 % against rms(t) = sqrt(0.4))
TARGET = [0.0, 1.0, 0.0, -1.0, 0.0]
MEASURED = [0.0, 1.5, 0.0, -1.0, 1.0]


def test_j2_j3_by_hand():
    assert normalized_std_error(MEASURED, TARGET) == pytest.approx(100 * math.sqrt(0.4),
                                                                   rel=1e-12)
    assert normalized_peak_error(MEASURED, TARGET) == pytest.approx(100.0, rel=1e-12)


def test_std_not_rms_a_constant_offset_costs_nothing_in_j2():
    target = np.array(TARGET)
    assert normalized_std_error(target + 3.0, target) == pytest.approx(0.0, abs=1e-12)
    # ... but J3 sees it: max|3| / max|t| = 300 %
    assert normalized_peak_error(target + 3.0, target) == pytest.approx(300.0, rel=1e-12)


def test_j2_j4_of_a_scaled_signal():
    target = np.sin(np.linspace(0, 7, 200))
    assert normalized_std_error(1.1 * target, target) == pytest.approx(10.0, rel=1e-9)
    assert normalized_peak_error(0.5 * target, target) == pytest.approx(50.0, rel=1e-12)


def test_nan_samples_are_left_out():
    measured = MEASURED + [np.nan]
    target = TARGET + [5.0]
    assert normalized_std_error(measured, target) == pytest.approx(100 * math.sqrt(0.4))
    assert normalized_peak_error(measured, target) == pytest.approx(100.0)


def test_undefined_cases_are_nan():
    assert math.isnan(normalized_std_error(np.ones(4), np.ones(4)))      # constant target
    assert math.isnan(normalized_peak_error(np.ones(4), np.zeros(4)))    # zero target
    assert math.isnan(normalized_std_error([np.nan], [1.0]))              # no common sample
    assert math.isnan(tracking_delay(np.zeros(10), np.ones(10), 0.002))   # no correlation
    assert math.isnan(tracking_delay([1.0], [1.0], 0.002))                # one sample


def test_j1_by_hand():
    # measured = target delayed by two samples: r[l] = sum_k m[k+l] t[k]
    #   t = [1, 2, 3, 0, 0, 0], m = [0, 0, 1, 2, 3, 0]
    #   r[0] = 0*1 + 0*2 + 1*3 = 3;  r[1] = 0*1 + 1*2 + 2*3 = 8;  r[2] = 1 + 4 + 9 = 14;
    #   r[3] = 2*1 + 3*2 = 8;  r[4] = 3*1 = 3;  r[5] = 0  ->  l* = 2, J1 = 2 dt
    target = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0]
    measured = [0.0, 0.0, 1.0, 2.0, 3.0, 0.0]
    assert tracking_delay(measured, target, 0.002) == pytest.approx(0.004, abs=1e-15)
    # a measured signal leading its target is not searched: the best non-negative lag is 0
    assert tracking_delay(target, measured, 0.002) == 0.0


@pytest.mark.parametrize('delay', [0, 1, 6, 17, 50])
def test_j1_of_a_signal_shifted_by_a_known_number_of_samples(delay):
    dt = 0.002
    rng = np.random.default_rng(3)
    target = np.convolve(rng.normal(size=3000), np.hanning(15), mode='same')
    measured = np.concatenate([np.zeros(delay), target[:target.size - delay]])
    assert tracking_delay(measured, target, dt) == pytest.approx(delay * dt, abs=1e-12)


def test_j1_window():
    dt = 0.002
    rng = np.random.default_rng(4)
    target = np.convolve(rng.normal(size=3000), np.hanning(15), mode='same')
    measured = np.concatenate([np.zeros(60), target[:-60]])
    # 60 samples = 120 ms lie outside the default window (0..50 samples at 2 ms)
    assert J1_MAX_LAG_S == pytest.approx(0.1)
    assert tracking_delay(measured, target, dt) < 0.1 + 1e-12
    assert tracking_delay(measured, target, dt, max_lag_s=0.15) == pytest.approx(0.12)


def test_j1_stops_at_the_first_non_finite_sample():
    target = np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 5.0, 5.0])
    measured = np.array([0.0, 0.0, 1.0, 2.0, 3.0, 0.0, np.nan, 9.0])
    assert tracking_delay(measured, target, 0.002) == pytest.approx(0.004)


def test_evaluation_criteria_of_a_delayed_run():
    dt = 0.002
    t = np.arange(2000) * dt
    f_r = 100.0 * np.sin(2 * np.pi * 2.0 * t)
    f_m = 100.0 * np.sin(2 * np.pi * 2.0 * (t - 5 * dt))   # the force loop: 5 samples late
    x_ref = 1e-3 * np.sin(2 * np.pi * 2.0 * t)
    c = evaluation_criteria(target_force=f_r, measured_force=f_m, displacement=1.02 * x_ref,
                            reference_displacement=x_ref, dt=dt)
    assert isinstance(c, Criteria)
    assert c.j1_ms == pytest.approx(10.0)
    # a sine late by phi: |e| = 2 sin(phi/2) times the amplitude, phi = 2 pi f 5 dt
    phi = 2 * np.pi * 2.0 * 5 * dt
    assert c.j2_pct == pytest.approx(100 * 2 * math.sin(phi / 2), rel=1e-3)
    assert c.j3_pct == pytest.approx(100 * 2 * math.sin(phi / 2), rel=1e-3)
    assert c.j4_pct == pytest.approx(2.0, rel=1e-9)
    assert c.j5_pct == pytest.approx(2.0, rel=1e-9)
    assert list(c.as_dict()) == ['J1', 'J2', 'J3', 'J4', 'J5']


def test_errors():
    with pytest.raises(ParameterError, match='dt=0'):
        tracking_delay([1.0, 2.0], [1.0, 2.0], 0)
    with pytest.raises(ParameterError, match='max_lag_s=-1'):
        tracking_delay([1.0, 2.0], [1.0, 2.0], 0.002, max_lag_s=-1)
    with pytest.raises(ParameterError, match='same'):
        normalized_std_error([1.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match='1-D'):
        normalized_peak_error([[1.0]], [[1.0]])
    with pytest.raises(ParameterError, match='floats'):
        normalized_peak_error(['a'], [1.0])
