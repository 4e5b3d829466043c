"""The pre-run range check: each rig's reference peaks against its sensors' ranges and its
actuator's capacity (v_max = k_q V_lim / A on the servohydraulic rig)."""

import json

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_ros.analysis.range_check import range_check
from seft_ros.cli import api


def _runs(amplitude_N, alphas, rig='servohydraulic', reading='us_customary', **extra):
    return [parameters.resolve({'alpha': a, 'amplitude_N': amplitude_N, 'predictor': 'model',
                                'rig_model': rig, 'rig_calibration': reading, **extra})
            for a in alphas]


def test_velocity_limit_of_the_calibrated_rig():
    p = parameters.defaults()
    # Eq. 3.1 in V/lbf (default): k_q = 5.3e-5 x 4.448 m^3/(s V), 2.0 m/s at 10 V
    lbf = 0.45359237 * 9.80665
    assert api.actuator_velocity_limit_m_s(p) == pytest.approx(5.3e-5 * lbf * 10.0 / 1.18e-3)
    assert api.actuator_velocity_limit_m_s(p) == pytest.approx(2.0, abs=0.01)
    # Eq. 3.1 in V/N: 0.45 m/s
    assert api.actuator_velocity_limit_m_s(dict(p, rig_calibration='si')) == pytest.approx(
        5.3e-5 * 10.0 / 1.18e-3)
    assert api.actuator_velocity_limit_m_s(dict(p, valve_flow_gain_m3_per_s_V=1e-4)) == (
        pytest.approx(1e-4 * 10.0 / 1.18e-3))
    assert api.actuator_velocity_limit_m_s(dict(p, rig_model='delay')) is None
    # the actuator family: the member's k_q and area, 1.2e-4 m^3/(s V) x 10 V / 2e-3 m^2, and
    # its Monte-Carlo draw's (each parameter within +/- 30 %: k_q / A within 0.7/1.3..1.3/0.7)
    family = dict(p, rig_model='actuator', actuator_family='leaky')
    assert api.actuator_velocity_limit_m_s(family) == pytest.approx(0.6, rel=1e-12)
    drawn = api.actuator_velocity_limit_m_s(dict(family, actuator_spread=0.3, actuator_seed=4))
    assert drawn != pytest.approx(0.6, rel=1e-3) and 0.6 * 0.7 / 1.3 < drawn < 0.6 * 1.3 / 0.7
    assert api.actuator_velocity_limit_m_s(dict(p, rig_model='state_space')) is None
    # declared: whatever the rig
    assert api.actuator_velocity_limit_m_s(dict(p, rig_model='delay',
                                                actuator_velocity_limit_m_s=0.3)) == 0.3


def _short(lines):
    return [ln.split(' the reference')[0] for ln in lines]


def test_one_line_per_channel_beyond_its_range_or_capacity():
    lines = []
    # the default record (time scale 1) at 1000 N: alpha = 2 takes the 4 g accelerometer
    # just past its range (39.9 m/s^2); its velocity (0.97 m/s) is within the valve's 2.0
    api.check_ranges(runs=_runs(1000.0, [0.0, 0.5, 1.0, 1.5, 2.0]), progress=lines.append)
    assert _short(lines) == ['range check: [alpha_2_servohydraulic_model] rig acceleration:']
    assert ('peaks at 39.91 m/s^2, beyond the accelerometer range of 39.2 m/s^2; the largest '
            'amplitude that fits: amplitude_N 982.1 N') in lines[0]
    lines.clear()
    # at 2500 N, alpha = 2 also needs 2.4 m/s of the valve's 2.0, and so more than its 10 V
    api.check_ranges(runs=_runs(2500.0, [1.0, 2.0]), progress=lines.append)
    assert _short(lines)[:4] == ['range check: [alpha_1_servohydraulic_model] rig acceleration:',
                                 'range check: [alpha_2_servohydraulic_model] rig acceleration:',
                                 'range check: [alpha_2_servohydraulic_model] rig actuator '
                                 'velocity:',
                                 'range check: [alpha_2_servohydraulic_model] rig actuator valve '
                                 'command:']
    assert "2.418 m/s, beyond the actuator's velocity at the valve limit of 1.998 m/s" \
        in lines[2] and 'amplitude_N 2066 N' in lines[2]
    # and the one amplitude that fits every line (the least: alpha 2's accelerometer, 982 N),
    # which the first line's (alpha 1's, 1184 N) does not
    fits = {a: min(c.fits(p) for p in c.exceeded)
            for a, c in zip((1.0, 2.0), map(range_check, _runs(2500.0, [1.0, 2.0])))}
    assert fits[2.0] == pytest.approx(982.1, abs=0.1) and fits[1.0] > 1100.0
    assert 'amplitude_N 1184 N' in lines[0]
    assert lines[4] == ('range check: the largest amplitude that fits them all: amplitude_N '
                        f'{fits[2.0]:.4g} N')
    lines.clear()
    # Eq. 3.1 in V/N: alpha >= 0.5 needs more than the valve's 0.45 m/s at 1000 N
    api.check_ranges(runs=_runs(1000.0, [0.0, 0.5, 1.0, 1.5], reading='si'),
                     progress=lines.append)
    # (each of them the valve's velocity and its command: the command includes the velocity)
    assert [ln.split(': the reference')[0] for ln in lines[:-1]] == [
        f'range check: [alpha_{a}_servohydraulic_model] rig actuator {channel}'
        for a in ('0.5', '1', '1.5') for channel in ('velocity', 'valve command')]
    assert lines[-1].startswith('range check: the largest amplitude that fits them all: ')
    assert '0.667 m/s' in lines[2] and '0.4492 m/s' in lines[2]
    lines.clear()
    api.check_ranges(runs=_runs(500.0, [0.0, 0.5, 1.0, 1.5], reading='si'),
                     progress=lines.append)
    assert lines == []


def test_delay_rig_checks_its_sensors_and_a_declared_capacity_only():
    lines = []
    api.check_ranges(runs=_runs(1000.0, [1.5], rig='delay'), progress=lines.append)
    assert lines == []
    check = range_check(_runs(1000.0, [1.5], rig='delay')[0])
    velocity = next(p for p in check.peaks if p.channel == 'actuator velocity')
    assert velocity.limit is None and not velocity.exceeded
    api.check_ranges(runs=_runs(1000.0, [1.5], rig='delay', actuator_velocity_limit_m_s=0.2),
                     progress=lines.append)
    assert _short(lines) == ['range check: rig actuator velocity:']


def test_strict_refuses_and_names_the_channel():
    runs = _runs(2500.0, [2.0])
    with pytest.raises(api.RangeRefusedError,
                       match=r'^range check: rig acceleration: the reference peaks at 99\.78 '
                       r'.* \(and 2 more; the largest amplitude that fits them all: '
                       r'amplitude_N 982\.1 N\); refused \(--strict\)'):
        api.check_ranges(runs=runs, strict=True)


def test_the_largest_amplitude_that_fits_fits():
    p = _runs(2500.0, [2.0])[0]
    check = range_check(p)
    for peak in check.exceeded:
        again = range_check(dict(p, amplitude_N=check.fits(peak)))
        assert again.predicted('', peak.channel) == pytest.approx(peak.limit, rel=1e-9)
    summary = check.as_dict()
    assert summary['rigs']['']['acceleration']['exceeded'] is True
    assert summary['rigs']['']['force']['exceeded'] is False
    assert summary['lines'] == check.lines() and len(summary['lines']) == 3


def test_a_real_time_run_beyond_its_actuators_capacity_is_refused_unless_forced():
    """A real-time run (a lab's rig on the wall clock) whose reference needs more than its
    actuator's velocity is refused before anything starts (before: a warning line, and the
    interlock stopped the run 0.86 s in, session 23's operations tester); --force runs it
    with the warning. The same run in lockstep, and a sensor's range in real time, warn."""
    realtime = _runs(2500.0, [2.0], mode='realtime')
    with pytest.raises(api.RangeRefusedError, match=(
            r"^range check: rig actuator velocity: the reference peaks at 2\.418 m/s, beyond "
            r"the actuator's velocity at the valve limit of 1\.998 m/s; the largest amplitude "
            r"that fits: amplitude_N 2066 N \(and 1 more\); refused: a real-time run beyond its "
            r"actuator's "
            r'capacity, which the interlock would stop; lower the amplitude, or --force to '
            r'run it anyway$')):
        api.check_ranges(runs=realtime)
    lines = []
    api.check_ranges(runs=realtime, force=True, progress=lines.append)
    assert _short(lines) == ['range check: rig acceleration:',
                             'range check: rig actuator velocity:',
                             'range check: rig actuator valve command:',
                             'range check: the largest amplitude that fits them all: '
                             'amplitude_N 982.1 N']
    lines.clear()
    api.check_ranges(runs=_runs(2500.0, [2.0], mode='lockstep'), progress=lines.append)
    assert len(lines) == 4
    lines.clear()
    # alpha 2 at 1000 N: the accelerometer's range only (39.9 of 39.2 m/s^2), in real time
    api.check_ranges(runs=_runs(1000.0, [2.0], mode='realtime'), progress=lines.append)
    assert _short(lines) == ['range check: rig acceleration:']
    # two runs, one beyond: the refusal names it, and nothing of the other
    with pytest.raises(api.RangeRefusedError, match=r'^range check: \[alpha_2_servohydraulic_'
                       r'model\] rig actuator velocity: .*; refused: a real-time run'):
        api.check_ranges(runs=_runs(2500.0, [0.5, 2.0], mode='realtime'))


def test_the_valve_command_a_force_needs_on_a_first_order_plant():
    """u = P^-1 f: on a plant F[k+1] = 0.9 F[k] + 100 u[k] (a lab's discrete model), the
    command of a smooth force that starts and ends at rest is (F[k+1] - 0.9 F[k]) / 100."""
    from seft_ros.analysis.range_check import valve_command_needed
    plant = {'form': 'state_space', 'dt': 0.002, 'a': [[0.9]], 'b': [100.0],
             'c': {'force_N': [1.0]},
             'specimen': {'mass_kg': 52.7, 'damping_N_s_per_m': 100.0,
                          'stiffness_N_per_m': 2.11e5}}
    p = parameters.resolve({'rig_model': 'state_space', 'plant_model': json.dumps(plant)})
    t = np.arange(3000) * 0.002
    force = 500.0 * np.sin(2 * np.pi * 3.0 * t) * np.sin(np.pi * t / t[-1]) ** 2
    u = valve_command_needed(p, force)
    assert u.shape == force.shape
    expected = (force[1:] - 0.9 * force[:-1]) / 100.0
    assert np.max(np.abs(u[:-1] - expected)) < 1e-9 * np.max(np.abs(expected))
    # the delay rig applies its force: no valve
    assert valve_command_needed(dict(p, rig_model='delay'), force) is None


def test_the_valve_command_needed_is_the_exact_tests():
    """On seft's rig with its own model (exact), model's valve command peaks where the
    prediction says (0.1-0.3 % measured, session 26); with the valve's limit below that
    peak the range check says so, with the amplitude that fits."""
    from seft_ros.core.experiment import simulate
    p = _runs(1000.0, [1.0], duration_s=6.0)[0]
    run = simulate(p)
    check = range_check(p)
    predicted = check.predicted('', 'actuator valve command')
    assert predicted == pytest.approx(np.max(np.abs(run.valve_command_V)), rel=0.01)
    limited = dict(p, valve_limit_V=0.8 * predicted)
    check = range_check(limited)
    [peak] = [q for q in check.exceeded if q.channel == 'actuator valve command']
    assert check.fits(peak) == pytest.approx(800.0, rel=1e-9)
    assert ('rig actuator valve command: the reference force needs '
            f'{predicted:.4g} V of valve command') in check.line(peak)
