"""Tests of the one-process experiment (``seft simulate``) against independent solutions."""

import re

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py.errors import InputError, ParameterError
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepared_record

FIELDS = ('time_s', 'ground_acceleration_m_s2', 'reference_force_N', 'measured_force_N',
          'displacement_m', 'velocity_m_s', 'acceleration_m_s2', 'valve_command_V')


def delayed_sdof(params, ag):
    """x, v, a and the actuator force of the SDOF under f(t) = -m xg''(t - tau), held.

    Built from scratch: the continuous SDOF ``m x'' + c x' + k x = f`` stepped by
    ``scipy.signal.lsim`` with a zero-order hold of the force ``-m xg''[k - tau/dt]``.
    """
    m, c, k = params['mass_kg'], params['damping_N_s_per_m'], params['stiffness_N_per_m']
    dt, lag = params['dt'], int(round(params['tau_s'] / params['dt']))
    f = np.concatenate([np.zeros(lag), -m * ag])[:ag.shape[0]]
    sys = signal.StateSpace([[0.0, 1.0], [-k / m, -c / m]], [[0.0], [1.0 / m]], np.eye(2),
                            np.zeros((2, 1)))
    t = np.arange(ag.shape[0]) * dt
    _, y, _ = signal.lsim(sys, f, t, interp=False)
    x, v = y[:, 0], y[:, 1]
    return x, v, (f - c * v - k * x) / m, f


def assert_close(actual, desired, rel=1e-9):
    """Equal within `rel` of the signal's peak."""
    np.testing.assert_allclose(actual, desired, rtol=0, atol=rel * np.max(np.abs(desired)))


def assert_same_run(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert (a.stable, a.unstable_at_s, a.abort_reason) == (b.stable, b.unstable_at_s,
                                                           b.abort_reason)


def test_alpha_zero_delay_rig_equals_lsim(reference_params):
    params = dict(reference_params, rig_model='delay', alpha=0.0)
    assert params['tau_s'] == 0.01
    ag = prepared_record(params).acceleration_m_s2
    run = simulate(params)
    assert run.stable and run.n_steps == ag.shape[0] == 5000
    assert run.valve_command_V is None and run.source == 'simulate'
    np.testing.assert_array_equal(run.ground_acceleration_m_s2, ag)
    np.testing.assert_array_equal(run.time_s, np.arange(5000) * 0.002)
    np.testing.assert_array_equal(run.reference_force_N, -52.7 * ag)
    x, v, a, f = delayed_sdof(params, ag)
    assert_close(run.displacement_m, x)
    assert_close(run.velocity_m_s, v)
    assert_close(run.acceleration_m_s2, a)
    assert_close(run.measured_force_N, f, rel=1e-12)
    assert np.max(np.abs(x)) > 1e-3        # a real response, not zeros


def assert_aborted(run):
    """An aborted run: finite samples up to the abort, unstable_at_s = n_steps * dt."""
    assert not run.stable
    assert 0 < run.n_steps < 5000
    assert run.unstable_at_s == run.n_steps * 0.002
    for name in FIELDS:
        arr = getattr(run, name)
        if arr is not None:
            assert arr.shape == (run.n_steps,) and np.all(np.isfinite(arr)), name


def test_diverging_delay_run_is_aborted_at_a_limit(reference_params):
    """Without the instability monitor (and the divergence guard) the run diverges until the
    force limit (24.5 kN)."""
    run = simulate(dict(reference_params, rig_model='delay', alpha=1.5, monitor_threshold=0.0,
                        divergence_factor=0.0))
    assert_aborted(run)
    assert run.abort_reason.startswith(f'force limit exceeded at t={run.unstable_at_s:.3f} s: ')
    assert abs(run.measured_force_N[-1]) < 24.5e3
    # growing: the last 0.1 s is far beyond the first 0.1 s
    assert np.max(np.abs(run.measured_force_N[-50:])) > 5 * np.max(
        np.abs(run.measured_force_N[:50]))


def test_diverging_delay_run_is_stopped_earlier_by_the_monitor(reference_params):
    params = dict(reference_params, rig_model='delay', alpha=1.5)
    run = simulate(params)
    assert_aborted(run)
    # the monitor judges the last recorded sample, one step before unstable_at_s
    t = run.unstable_at_s - 0.002
    assert run.abort_reason.startswith(f'unstable at t={t:.3f} s: high-frequency oscillation')
    assert run.n_steps < simulate(dict(params, monitor_threshold=0.0)).n_steps
    assert np.max(np.abs(run.measured_force_N)) < 24.5e3 / 2


def test_servohydraulic_alpha_1_5_trips_the_interlock(reference_params):
    # the 'si' reading of Eq. 3.1: its valve (0.45 m/s at 10 V) saturates before the
    # accelerometer does, and the interlock ends the run
    run = simulate(dict(reference_params, alpha=1.5, monitor_threshold=0.0,
                        rig_calibration='si'))
    assert_aborted(run)
    assert run.abort_reason.startswith(f'force control lost at t={run.unstable_at_s:.3f} s')
    assert 'saturated in 26/50 samples' in run.abort_reason
    # the tripping sample is not recorded: 25 of the 49 recorded before it were saturated
    u = run.valve_command_V
    assert np.max(np.abs(u)) == 10.0
    assert np.count_nonzero(np.abs(u[-49:]) == 10.0) == 25


def test_default_reading_alpha_1_5_runs_to_the_force_limit_past_the_accelerometer(
        reference_params):
    """The default reading's valve passes 4.448 times the flow per volt: without the monitor
    the unstable loop grows past the 4 g accelerometer range. The saturated accelerometer
    once bounded it in a limit cycle below the valve limit (the fed-back acceleration
    clipped); the builder now feeds back the acceleration estimated from the measured force
    and motion while the sensor is at its range (issue 39), so the loop grows until the force
    limit stops it, as without a range, and every clipped sample is counted. The monitor (on
    by default, next test) is what stops such a run first (and, with it off, the divergence
    guard: off here too)."""
    run = simulate(dict(reference_params, alpha=1.5, monitor_threshold=0.0,
                        divergence_factor=0.0))
    assert_aborted(run)
    assert run.abort_reason.startswith(f'force limit exceeded at t={run.unstable_at_s:.3f} s')
    assert np.max(np.abs(run.acceleration_m_s2)) == 39.2       # the sensor read its range
    at_range = np.count_nonzero(np.abs(run.acceleration_m_s2) == 39.2)
    count = run.extra['sensor_range']['']
    assert count['samples'] == {'force': 0, 'displacement': 0, 'velocity': 0,
                                'acceleration': at_range}
    assert count['acceleration_estimated'] == at_range > 100
    # without the accelerometer range: the same end, nothing flagged
    run = simulate(dict(reference_params, alpha=1.5, monitor_threshold=0.0,
                        divergence_factor=0.0, accelerometer_range_m_s2=0.0))
    assert_aborted(run)
    assert run.abort_reason.startswith(f'force limit exceeded at t={run.unstable_at_s:.3f} s')
    assert run.extra['sensor_range']['']['samples']['acceleration'] == 0


@pytest.mark.parametrize('reading', ['us_customary', 'si'])
def test_servohydraulic_alpha_1_5_is_aborted_with_the_monitor_on(reference_params, reading):
    run = simulate(dict(reference_params, alpha=1.5, rig_calibration=reading))
    assert_aborted(run)
    assert re.match(r'(unstable|force control lost) at t=', run.abort_reason)


def test_servohydraulic_alpha_1_is_stable_on_the_default_record(reference_params):
    run = simulate(dict(reference_params, alpha=1.0, duration_s=10.0))
    assert run.stable and run.n_steps == 5000 and run.unstable_at_s is None
    assert run.abort_reason is None
    assert np.max(np.abs(run.displacement_m)) < reference_params['stroke_limit_m']
    assert np.max(np.abs(run.valve_command_V)) <= 10.0
    for name in FIELDS:
        assert np.all(np.isfinite(getattr(run, name))), name


@pytest.mark.parametrize('rig', ['delay', 'servohydraulic'])
def test_reproducible_with_sensor_noise(reference_params, rig):
    params = dict(reference_params, rig_model=rig, alpha=0.5, duration_s=3.0, noise_force_N=5.0,
                  noise_acceleration_m_s2=0.05)
    a, b = simulate(params), simulate(params)
    assert_same_run(a, b)
    quiet = simulate(dict(params, noise_force_N=0.0, noise_acceleration_m_s2=0.0))
    assert not np.array_equal(a.measured_force_N, quiet.measured_force_N)
    other = simulate(dict(params, noise_seed=2))
    assert not np.array_equal(a.measured_force_N, other.measured_force_N)


def test_force_noise_is_the_seeded_generator(reference_params):
    """alpha = 0 on the delay rig: the force noise does not feed back, so it is visible as is.

    Each reading draws four standard normals (force, displacement, velocity, acceleration)
    from PCG64(noise_seed); the force noise is the first, times noise_force_N.
    """
    params = dict(reference_params, rig_model='delay', alpha=0.0, noise_force_N=5.0,
                  noise_seed=7)
    noisy, quiet = simulate(params), simulate(dict(params, noise_force_N=0.0))
    e = np.random.Generator(np.random.PCG64(7)).standard_normal((5000, 4))[:, 0] * 5.0
    np.testing.assert_allclose(noisy.measured_force_N - quiet.measured_force_N, e, rtol=0,
                               atol=1e-9)
    np.testing.assert_array_equal(noisy.displacement_m, quiet.displacement_m)


def test_n_steps_truncates(reference_params):
    params = dict(reference_params, alpha=0.5, duration_s=2.0)
    full = simulate(params)
    part = simulate(dict(params, n_steps=123))
    assert part.n_steps == 123 and part.stable
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(part, name), getattr(full, name)[:123],
                                      err_msg=name)


def test_a_run_cut_short_previews_the_record_that_goes_on(reference_params):
    """The servohydraulic rig with ``model`` (a 10-step ground preview), alpha 1, the
    default record (one scale factor) cut at 3 s and at 4 s, both in its strong motion: the
    3 s run is the 4 s
    run's first 3 s bit for bit in every signal, its last commands built from the record
    that goes on after the cut (GroundMotion.following_m_s2). Given the cut record without
    what follows (zeros after it, as every cut run was before), the last samples of the
    rig's acceleration leave the run by several per cent of the signal's peak."""
    from seft_ros.core.ground_motion import GroundMotion
    params = dict(reference_params, rig_model='servohydraulic', predictor='model', alpha=1.0,
                  amplitude_N=0.0, scale_factor=1.0)
    # one scale factor for both cuts (an amplitude scales each cut to its own peak): 1000 N
    peak = prepared_record(dict(params, duration_s=4.0)).peak_m_s2
    params['scale_factor'] = 1000.0 / (params['mass_kg'] * peak)
    short = simulate(dict(params, duration_s=3.0))
    longer = simulate(dict(params, duration_s=4.0))
    n = short.n_steps
    assert n == 1500 and short.stable and longer.stable
    for name in FIELDS:
        if getattr(short, name) is not None:
            np.testing.assert_array_equal(getattr(short, name), getattr(longer, name)[:n],
                                          err_msg=name)
    gm = prepared_record(dict(params, duration_s=3.0))
    assert len(gm.following_m_s2) == 64 and max(map(abs, gm.following_m_s2)) > 0.5
    ended = simulate(params, record=GroundMotion(gm.dt, gm.acceleration_m_s2, gm.name,
                                                 gm.source))
    a, a_ended = longer.acceleration_m_s2[:n], ended.acceleration_m_s2
    np.testing.assert_array_equal(a_ended[:n - 20], a[:n - 20])
    assert np.max(np.abs(a_ended[n - 20:] - a[n - 20:])) > 0.03 * np.max(np.abs(a))


def test_n_steps_beyond_the_record(reference_params):
    with pytest.raises(ParameterError, match=r'^parameter n_steps=1001: expected <= 1000 '
                       r'\(the prepared record length\)$'):
        simulate(dict(reference_params, duration_s=2.0, n_steps=1001))


def test_simulate_validates_its_parameters(reference_params, tmp_path):
    with pytest.raises(ParameterError, match=r'^parameter alpha=-1: expected float >= 0'):
        simulate(dict(reference_params, alpha=-1))
    with pytest.raises(ParameterError, match=r"^unknown parameter 'mass' \(did you mean "
                                             r"'mass_kg'\?\)$"):
        simulate({'mass': 3.0})
    missing = tmp_path / 'nothing.AT2'
    with pytest.raises(InputError, match=re.escape(str(missing)) + ': no such file'):
        simulate(dict(reference_params, record=str(missing)))


def test_simulate_takes_a_prepared_record_and_reports_progress(reference_params):
    params = dict(reference_params, alpha=0.5, duration_s=1.0)
    gm = prepared_record(params)
    calls = []
    run = simulate(params, record=gm, progress=lambda k, n: calls.append((k, n)))
    assert_same_run(run, simulate(params))
    assert all(n == 500 and 0 < k <= 500 for k, n in calls)


def _one_rig_through_the_general_steps(monkeypatch):
    """Make simulate() step a test of one rig through the loop of any rigs (its lists of one
    element)."""
    from seft_ros.core import experiment

    def general(n_total, fr, est, lane, watch_of, builder, estimates, padded, width, warnings,
                state_rec, record_state, state_lag, est_row, progress):
        guarded = [(builder, g) for g in builder.range_guards if g is not None]
        return experiment._rig_steps(
            n_total, [fr], est, [lane], [watch_of], builder, estimates, padded, width,
            warnings, state_rec, record_state, state_lag, [est_row], progress, [watch_of[4]],
            [(builder.observe, 0)], guarded, builder, est is not None)
    monkeypatch.setattr(experiment, '_one_rig_steps', general)


@pytest.mark.parametrize('case', [
    {'predictor': 'adaptive'},                                   # completes, its estimates
    {'predictor': 'model', 'force_range_N': 300.0, 'accelerometer_range_m_s2': 5.0},
    {'predictor': 'model', 'predictor_stiffness_N_per_m': 2.532e5, 'specimen_check': 'abort'},
    {'predictor': 'none', 'alpha': 2.0},                          # the monitor stops it
    {'predictor': 'model', 'stroke_limit_m': 0.002},              # the rig's limit
    {'predictor': 'none', 'alpha': 1.5, 'monitor_threshold': 0.0,  # the interlock
     'rig_calibration': 'si'},
    {'predictor': 'model', 'rig_model': 'delay'}])
def test_a_test_of_one_rig_steps_as_a_test_of_many(reference_params, monkeypatch, case):
    """simulate()'s step for one rig (the study's test) is the step of any rigs with its
    lists taken apart: the same signals bit for bit, the same warnings and the same stop, on
    completed runs and on runs stopped by each watch; with stale steps replayed."""
    params = dict(reference_params, duration_s=3.0, amplitude_N=500.0, **case)
    if params['alpha'] == 1.5:                 # (saturates at 3.06 s of the default record)
        params.update(duration_s=3.5, amplitude_N=reference_params['amplitude_N'])
    stale = [] if params.get('rig_model') == 'delay' else range(100, 1500, 7)
    runs = []
    for general in (False, True):
        if general:
            _one_rig_through_the_general_steps(monkeypatch)
        runs.append(simulate(params, stale_steps=stale))
    one, many = runs
    if params['alpha'] == 1.5:
        assert one.extra['abort_node'] == 'force_servo_controller'
    assert_same_run(one, many)
    assert (one.abort_reason, one.extra['abort_node'], one.extra['warnings']) == (
        many.abort_reason, many.extra['abort_node'], many.extra['warnings'])
    assert one.extra['sensor_range'] == many.extra['sensor_range']
    if case.get('predictor') == 'adaptive':
        assert one.rigs[''].estimates.keys() == many.rigs[''].estimates.keys()
        for key, values in one.rigs[''].estimates.items():
            np.testing.assert_array_equal(values, many.rigs[''].estimates[key])
