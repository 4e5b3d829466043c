"""The emulated network link (``seft_ros.core.link.LinkModel``) against its definition."""

import numpy as np
import pytest

from seft_ros.core.link import LinkModel


def test_delay_and_jitter_bounds_and_order():
    link = LinkModel(delay_s=0.005, jitter_s=0.001, seed=3)
    arrivals = np.arange(2000) * 0.002               # 500 Hz
    out = np.array([link.departure(t) for t in arrivals])
    hold = out - arrivals
    # each message held delay +/- jitter, unless it waits behind an earlier one (in order)
    assert hold.min() >= 0.004 - 1e-12 and hold.max() <= 0.006 + 1e-12
    assert np.all(np.diff(out) >= 0)
    # uniform jitter: mean = delay, standard deviation = jitter / sqrt(3)
    assert hold.mean() == pytest.approx(0.005, abs=5e-5)
    assert hold.std() == pytest.approx(0.001 / np.sqrt(3), rel=0.05)


def test_fifo_holds_a_message_behind_a_late_one():
    """Departures are the running maximum of arrival + delay + uniform draw (same seed)."""
    import random
    link = LinkModel(delay_s=0.010, jitter_s=0.010, seed=7)
    arrivals = np.arange(5000) * 1e-4            # faster than the jitter: draws would reorder
    out = np.array([link.departure(t) for t in arrivals])
    rng = random.Random(7)
    drawn = arrivals + np.array([0.010 + rng.uniform(-0.010, 0.010) for _ in arrivals])
    assert np.array_equal(out, np.maximum.accumulate(drawn))
    assert np.sum(out > drawn) > 1000           # many held behind a later-drawn one


def test_loss_is_a_resend_later():
    link = LinkModel(delay_s=0.002, loss=0.1, seed=1)
    arrivals = np.arange(20000) * 0.002
    out = np.array([link.departure(t) for t in arrivals])
    hold = out - arrivals
    resent = hold > 0.002 + 1e-9
    # every lost packet arrives 2 delay + 5 ms later (reliable DDS resends it), none is dropped
    assert link.lost == pytest.approx(0.1 * 20000, rel=0.1)
    assert hold.max() == pytest.approx(0.002 + 0.009)
    assert resent.sum() >= link.lost
    assert len(out) == len(arrivals)


def test_no_link_is_no_delay():
    link = LinkModel()
    assert [link.departure(t) for t in (0.0, 0.5, 1.0)] == [0.0, 0.5, 1.0]


@pytest.mark.parametrize('kwargs, text', [
    ({'delay_s': -1.0}, 'delay -1.0 s: expected >= 0'),
    ({'delay_s': 0.001, 'jitter_s': 0.002}, 'jitter 0.002 s: expected 0 .. delay'),
    ({'loss': 1.0}, 'loss 1.0: expected a probability in [0, 1)'),
])
def test_bad_link_parameters(kwargs, text):
    with pytest.raises(ValueError) as err:
        LinkModel(**kwargs)
    assert str(err.value).startswith(text)
