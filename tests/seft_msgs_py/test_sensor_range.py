"""The sensors' ranges of the rig contract and the samples read at them (issue 39)."""

import math

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sensor_range import (
    ACCELERATION,
    AT_RANGE_FRACTION,
    DISPLACEMENT,
    FORCE,
    VELOCITY,
    RangeCount,
    SensorRanges,
    channel_names,
)


def test_ranges_from_the_parameters():
    r = SensorRanges.from_parameters(parameters.defaults())
    assert r.ranges() == (24.5e3, 0.1, 2.5, 39.2) and r.limited
    none = SensorRanges.from_parameters({name: 0.0 for name in (
        'force_range_N', 'displacement_range_m', 'velocity_range_m_s',
        'accelerometer_range_m_s2')})
    assert all(math.isinf(v) for v in none.ranges()) and not none.limited
    assert SensorRanges.from_parameters({}) == none           # absent: unlimited
    assert r.range_of('acceleration') == 39.2


@pytest.mark.parametrize('bad', [0.0, -1.0, math.nan])
def test_a_range_must_be_positive(bad):
    with pytest.raises(ValueError, match=r'^accelerometer_range_m_s2=.*: expected a range > 0$'):
        SensorRanges(acceleration_m_s2=bad)


def test_flags_at_the_range_of_each_channel():
    r = SensorRanges(1000.0, 0.05, 1.0, 39.2)
    assert r.flags_of(0.0, 0.0, 0.0, 0.0) == 0
    assert r.flags_of(-1000.0, 0.0, 0.0, 0.0) == FORCE
    assert r.flags_of(0.0, 0.05, 0.0, 39.2) == DISPLACEMENT | ACCELERATION
    assert r.flags_of(0.0, 0.0, -1.0, 0.0) == VELOCITY
    # a converter's last code just below full scale counts; a reading below it does not
    assert r.flags_of(0.0, 0.0, 0.0, AT_RANGE_FRACTION * 39.2) == ACCELERATION
    assert r.flags_of(0.0, 0.0, 0.0, 0.998 * 39.2) == 0
    assert r.flags_of(math.nan, 0.0, 0.0, 0.0) == 0
    assert r.flags(Measurement(3, 0.006, 0.06, 0.0, 0.0, 10.0)) == DISPLACEMENT
    assert channel_names(FORCE | ACCELERATION) == ['force', 'acceleration']
    assert r.clip(2000.0, -0.1, 0.5, math.nan)[:3] == (1000.0, -0.05, 0.5)
    assert math.isnan(r.clip(0, 0, 0, math.nan)[3])


def test_thresholds_are_the_fraction_of_each_range():
    r = SensorRanges(1000.0, 0.05, math.inf, 39.2)
    assert r.thresholds == (AT_RANGE_FRACTION * 1000.0, AT_RANGE_FRACTION * 0.05, math.inf,
                            AT_RANGE_FRACTION * 39.2)
    assert SensorRanges().thresholds == (math.inf,) * 4


def test_count_per_channel():
    count = RangeCount()
    count.add(5, 0)
    count.add(7, ACCELERATION)
    count.add(8, ACCELERATION | FORCE)
    count.add(12, ACCELERATION)
    assert count.flagged == 3
    assert count.as_dict() == {'samples': {'force': 1, 'displacement': 0, 'velocity': 0,
                                           'acceleration': 3},
                               'flagged': 3, 'acceleration_estimated': 0,
                               'first_step': {'acceleration': 7, 'force': 8},
                               'last_step': {'acceleration': 12, 'force': 8}}
