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
    with pytest.raises(ParameterError, match="excitation_input='valve_command': expected a "
                       "rig_model driven by a valve, e.g. 'servohydraulic'"):
        excitation_record(p)
    with pytest.raises(ParameterError, match='delay rig has no valve'):
        make_valve_controller(p)


FRAME = """
structure:
  dofs: [a, b, top]
  physical: {a: rig_a, b: rig_b}
  mass_matrix_kg: [[60, 0, 0], [0, 80, 0], [0, 0, 100]]
  stiffness_matrix_N_per_m: [[3.0e5, 0, -1.0e5], [0, 4.0e5, -1.0e5], [-1.0e5, -1.0e5, 2.0e5]]
  damping_matrix_N_s_per_m: [[900, 0, 0], [0, 1000, 0], [0, 0, 100]]
rigs:
  rig_a: {rig_model: delay, mass_kg: 50.0, stiffness_N_per_m: 2.0e5, damping_N_s_per_m: 800}
  rig_b: {rig_model: delay, mass_kg: 80.0, stiffness_N_per_m: 3.0e5, damping_N_s_per_m: 900}
"""


def test_a_structure_identification_run_tests_each_rig_alone(tmp_path):
    """The computational part off: each rig's DOF alone with its specimen, every rig's
    reference force the excitation itself (predictor none), whatever its specimen mass."""
    from seft_ros.cli.config import expand_runs, load_config
    from seft_ros.core.structure import Structure
    path = tmp_path / 'frame.yaml'
    path.write_text(FRAME)
    config = dict(load_config(path), predictor='none', excitation='chirp',
                  excitation_band_hz=30.0, duration_s=2.0, excitation_amplitude=50.0)
    run, = expand_runs(config)
    s = Structure.from_json(run['structure'])
    assert s.dofs == ('a', 'b') and dict(s.physical) == {'a': 'rig_a', 'b': 'rig_b'}
    assert np.array_equal(s.mass_kg, np.diag([50.0, 80.0]))
    assert np.array_equal(s.stiffness_N_per_m, np.diag([2.0e5, 3.0e5]))
    assert np.array_equal(s.damping_N_s_per_m, np.diag([800.0, 900.0]))
    assert s.rigs['rig_b']['mass_kg'] == 80.0
    rd = simulate(run)
    assert rd.stable and rd.rig_names == ('rig_a', 'rig_b') and not rd.computational
    e = excitation_signal(run)
    for name in rd.rig_names:
        assert np.allclose(rd.rigs[name].reference_force_N, e, rtol=1e-12, atol=1e-9)
    # without an excitation the test is the coupled structure
    test, = expand_runs(dict(config, excitation='none'))
    assert Structure.from_json(test['structure']).dofs == ('a', 'b', 'top')


def test_a_one_rig_structure_identifies_its_rig_in_its_namespace():
    """two_story's rig 'lab' alone is not the study's rig: it keeps its namespace."""
    from pathlib import Path

    from seft_ros.cli.config import expand_runs, load_config
    config = load_config(Path(__file__).resolve().parents[3] / 'config' / 'two_story.yaml')
    run = expand_runs(dict(config, excitation='noise', duration_s=2.0))[0]
    rd = simulate(run)
    assert rd.rig_names == ('lab',) and rd.stable
    assert not rd.is_study
