"""SampleHistory: the linear predictor a late reference force and a late valve command share."""

import numpy as np
import pytest

from seft_msgs_py.prediction import PREDICTION_ORDER, SampleHistory, window_steps


def test_a_damped_sinusoid_is_predicted_ahead_and_a_gap_declines():
    """A damped sinusoid obeys an order-2 recursion exactly: the predictor fitted to 250 of
    its samples runs it 10 steps ahead to the ridge's bias (5e-6 here, of an amplitude of
    0.74); linear extrapolation errs by 0.044 there. A gap in the history, or fewer
    samples than the window, and it declines (None): the caller extrapolates linearly."""
    dt = 0.002
    n = window_steps(dt)
    assert n == 250
    k = np.arange(400)
    x = np.exp(-0.5 * k * dt) * np.sin(2 * np.pi * 9.0 * k * dt + 0.3)
    h = SampleHistory(n)
    for j in range(300):
        h.store(j, x[j])
    assert h.value(299) == x[299] and h.value(10) is None      # beyond the ring
    predicted = h.predict(299, 10)
    assert abs(predicted - x[309]) < 2e-5
    linear = x[299] + 10 * (x[299] - x[298])
    assert abs(linear - x[309]) > 0.04
    h.store(310, 0.0)                                 # slot of 310 - 258 = 52 overwritten
    assert h.predict(299, 1) is None
    short = SampleHistory(n)
    for j in range(100):
        short.store(j, x[j])
    assert short.predict(99, 1) is None


def test_too_short_a_window_is_refused():
    with pytest.raises(ValueError, match='prediction window'):
        SampleHistory(4 * PREDICTION_ORDER - 1)
