"""The excitation signals of identification runs and where they enter the loop."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.core.controller import ForceServoController
from seft_ros.core.excitation import (
    OpenLoopValve,
    excitation_record,
    excitation_signal,
    make_valve_controller,
)
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepared_record


def _params(**kw):
    return parameters.resolve(dict({'duration_s': 4.0}, **kw))


def test_noise_is_band_limited_scaled_and_seeded():
    p = _params(excitation='noise', excitation_band_low_hz=2.0, excitation_band_hz=40.0,
                excitation_amplitude=50.0)
    e = excitation_signal(p)
    assert e.shape == (2000,)
    # the fades take a little of the variance: std within 5 % of the amplitude
    assert np.std(e) == pytest.approx(50.0, rel=0.05)
    spec = np.abs(np.fft.rfft(e)) ** 2
    f = np.fft.rfftfreq(e.size, 0.002)
    assert spec[(f < 1.5) | (f > 45.0)].sum() < 1e-3 * spec.sum()
    assert np.array_equal(e, excitation_signal(p))
    assert not np.array_equal(e, excitation_signal(dict(p, excitation_seed=2)))


@pytest.mark.parametrize('kind', ['chirp', 'stepped_sine'])
def test_chirp_and_stepped_sine_peak(kind):
    e = excitation_signal(_params(excitation=kind, excitation_amplitude=20.0,
                                  excitation_band_hz=50.0))
    assert np.max(np.abs(e)) == pytest.approx(20.0, rel=1e-2)
    assert e[0] == pytest.approx(0.0, abs=1e-9)


def test_default_amplitude_and_length():
    p = parameters.resolve({'excitation': 'noise', 'excitation_input': 'valve_command'})
    e = excitation_signal(p)
    assert e.shape == (10000,)                       # duration_s 0: 20 s
    assert np.std(e) == pytest.approx(0.05, rel=0.05)  # 0.05 V


@pytest.mark.parametrize('kw, match', [
    ({'excitation_band_hz': 300.0}, 'excitation_band_hz=300.0: expected below the Nyquist'),
    ({'excitation_band_low_hz': 60.0, 'excitation_band_hz': 50.0},
     'excitation_band_low_hz=60.0: expected > 0 and below'),
    ({'excitation_band_low_hz': 0.1, 'duration_s': 2.0}, 'duration_s=2.0: expected at least'),
])
def test_bad_band_one_line(kw, match):
    with pytest.raises(ParameterError, match=match):
        excitation_signal(_params(excitation='noise', **kw))


def test_closed_loop_excitation_is_the_ground_force():
    """alpha = 0.5, predictor none: f_r[k] = e[k] - alpha m a[k-1]."""
    p = _params(excitation='chirp', alpha=0.5, excitation_band_hz=30.0,
                monitor_threshold=0.0)
    gm = prepared_record(p)
    assert gm.source == 'excitation'
    e = excitation_signal(p)
    assert np.allclose(-(1.5 * p['mass_kg']) * gm.acceleration_m_s2, e, atol=1e-9)
    rd = simulate(p)
    fr = rd.reference_force_N
    m = p['mass_kg']
    assert np.allclose(fr[1:], e[1:rd.n_steps] - 0.5 * m * rd.acceleration_m_s2[:-1],
                       atol=1e-6)


def test_open_loop_drives_the_valve():
    p = _params(excitation='noise', excitation_input='valve_command', monitor_threshold=0.0)
    ctrl = make_valve_controller(p)
    assert isinstance(ctrl, OpenLoopValve)
    assert isinstance(make_valve_controller(_params()), ForceServoController)
    rd = simulate(p)
    assert np.array_equal(rd.valve_command_V, excitation_signal(p))
    assert not np.any(rd.ground_acceleration_m_s2)


def test_open_loop_valve_saturates_and_ends_at_zero():
    v = OpenLoopValve([0.5, 20.0, -20.0], 0.002, 10.0)
    assert [v.step(), v.step(), v.step(), v.step()] == [0.5, 10.0, -10.0, 0.0]
    v.reset()
    assert v.step(1e3, -1e3) == 0.5 and not v.saturated


def test_open_loop_needs_the_servohydraulic_rig():
    p = _params(excitation='noise', excitation_input='valve_command', rig_model='delay')
    with pytest.raises(ParameterError, match="excitation_input='valve_command': expected "
                       "rig_model 'servohydraulic'"):
        excitation_record(p)
    with pytest.raises(ParameterError, match='delay rig has no valve'):
        make_valve_controller(p)
