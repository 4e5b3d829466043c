"""The checks of seft rig-check on arrays: seft's lockstep rigs pass them, broken data fails
them by name, with the measured value in the line."""

import math
import re

import numpy as np
import pytest

from seft_msgs_py import parameters, rig_contract
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.signals import CLOCK_EVERY, MEASUREMENT_FIELDS
from seft_plant_sim.rigs import make_rig
from seft_ros.core import rig_check as rc
from seft_ros.core.excitation import make_valve_controller

DT = 0.002
DT_NS = 2_000_000


@pytest.fixture(scope='module')
def profile():
    return rc.CheckProfile(dt=DT)


def drive(model: str, reference: np.ndarray, **overrides):
    """Step seft's lockstep rig with the reference force as the graph does (the delay rig
    takes f_r[k] at step k; the servohydraulic rig the valve command u[k] of seft's force
    servo controller); return (command, x, v, a, f, params) per sample."""
    p = parameters.resolve(dict(rig_model=model, **overrides))
    rig = make_rig(p)
    controller = make_valve_controller(p)
    rows, commands = [], []
    for k in range(reference.size):
        m = rig.measure()
        rows.append((m.displacement_m, m.velocity_m_s, m.acceleration_m_s2, m.force_N))
        u = reference[k] if model == 'delay' else controller.step(
            reference[k], m.force_N, m.velocity_m_s, m.acceleration_m_s2, m.displacement_m)
        commands.append(u)
        rig.apply(u)
    x, v, a, f = np.array(rows).T
    return np.array(commands), x, v, a, f, p


def slices(profile):
    q = profile.onset_step
    h = int(round(profile.hold_s / DT))
    return slice(0, q), slice(q + h // 2, q + h)


# -- the profile -------------------------------------------------------------------------------

def test_profile_step_and_sine(profile):
    f = profile.step_reference()
    assert f.size == 1000 and profile.onset_step == 250
    assert np.all(f[:250] == 0) and np.all(f[250:750] == 100.0) and np.all(f[750:] == 0)
    s = profile.sine_reference()
    assert profile.fault_step == 250 + 1031                  # 4.125 cycles of 2 Hz
    assert s.size == profile.fault_step + 500
    t = (profile.fault_step - 250) * DT
    assert s[profile.fault_step] == pytest.approx(100 * math.sin(2 * math.pi * 2 * t))
    assert s[profile.fault_step] == pytest.approx(100 / math.sqrt(2), rel=0.01)   # 45 deg
    assert np.all(s[:250] == 0)


@pytest.mark.parametrize('field, value', [('amplitude_N', 0.0), ('amplitude_N', -5.0),
                                          ('hold_s', math.nan), ('dt', 'x')])
def test_profile_refuses_bad_values(field, value):
    kwargs = {'dt': DT, field: value}
    with pytest.raises(ParameterError, match=rf'^{field}=.*: expected a number > 0$'):
        rc.CheckProfile(**kwargs)


def test_profile_refuses_a_sine_too_fast():
    with pytest.raises(ParameterError, match=r'sine_hz=200\.0: expected at most a quarter of '
                       r'the sample rate, 125 Hz'):
        rc.CheckProfile(dt=DT, sine_hz=200.0)


# -- contract, clock, measurement ---------------------------------------------------------------

def _ready(**changes):
    ready = {'state': 'ready', 'contract': rig_contract.CONTRACT,
             'command_kind': 'valve_command_V', 'command_latency_s': '0.003'}
    ready.update(changes)
    return ready


def test_contract_check():
    params = {n: 0 for n in rig_contract.REQUIRED_PARAMETERS}
    ok = rc.check_contract(_ready(), params, 'valve_command_V')
    assert ok.passed and ok.values['command_latency_s'] == 0.003
    assert ok.measured == ('seft-rig/1.0, takes valve_command_V, command latency 3 ms, 14 of '
                           '14 required parameters published')
    bad = rc.check_contract(_ready(contract='seft-rig/2.0', command_latency_s='-1'),
                            {k: v for k, v in params.items() if k != 'dt'}, 'reference_force_N')
    assert not bad.passed
    assert bad.measured == ("contract 'seft-rig/2.0', expected seft-rig/1.0; command_kind "
                            "'valve_command_V', expected 'reference_force_N'; "
                            "command_latency_s '-1', expected seconds >= 0; parameters not "
                            'published: dt')
    assert not rc.check_contract(None, params, 'valve_command_V').passed


def _clock_data(n=1000, period=DT, burst=0):
    steps = np.arange(n)
    arrival = 10.0 + steps * period
    arrival[:burst] = arrival[burst]            # the first samples heard at once
    return steps, steps * DT_NS, arrival


def test_clock_passes_on_time_and_through_a_first_burst():
    r = rc.check_clock(*_clock_data(burst=300), DT, expected=1000,
                       clock_ns=np.arange(30, 100) * CLOCK_EVERY * DT_NS)
    assert r.passed and r.values['period_s'] == pytest.approx(DT, rel=1e-9)
    assert re.match(r'period 2\.0000 ms \([+-]0\.00 % of dt 2 ms, limit 2 %\), 0 missing',
                    r.measured)


@pytest.mark.parametrize('change, expected', [
    ('slow', r'period 2\.5000 ms \(\+25\.00 % of dt'),
    ('gap', r'2 missing'),
    ('stamp', r'1 misstamped'),
    ('repeat', r'1 repeated'),
    ('clock', r'/clock 70 messages, 1 off the grid'),
])
def test_clock_fails(change, expected):
    steps, stamps, arrival = _clock_data(period=1.25 * DT if change == 'slow' else DT)
    clock_ns = np.arange(30, 100) * CLOCK_EVERY * DT_NS
    if change == 'gap':
        keep = (steps != 500) & (steps != 501)
        steps, stamps, arrival = steps[keep], stamps[keep], arrival[keep]
    if change == 'stamp':
        stamps = stamps.copy()
        stamps[10] += 1
    if change == 'repeat':
        steps, stamps, arrival = (np.insert(a, 5, a[5]) for a in (steps, stamps, arrival))
    if change == 'clock':
        clock_ns = clock_ns.copy()
        clock_ns[-1] += DT_NS
    r = rc.check_clock(steps, stamps, arrival, DT, expected=1000, clock_ns=clock_ns)
    assert not r.passed and re.search(expected, r.measured), r.measured


def test_clock_without_samples():
    r = rc.check_clock([], [], [], DT, expected=1000)
    assert not r.passed and r.measured == '0 samples arrived (expected 1000)'


def test_sample_period_is_the_median_of_spans():
    steps, _, arrival = _clock_data(burst=400)
    assert rc.sample_period(steps, arrival) == pytest.approx(DT)
    steps, _, arrival = _clock_data(period=2.1e-3)
    assert rc.sample_period(steps, arrival) == pytest.approx(2.1e-3)


def test_measurement_check():
    values = np.ones((50, 4))
    assert rc.check_measurement(MEASUREMENT_FIELDS, values).passed
    values[7, 2] = np.nan
    r = rc.check_measurement(MEASUREMENT_FIELDS, values)
    assert not r.passed and r.measured == ('4 fields in order, 1 of 50 samples with a value '
                                           'not finite')
    swapped = (MEASUREMENT_FIELDS[1], MEASUREMENT_FIELDS[0]) + MEASUREMENT_FIELDS[2:]
    r = rc.check_measurement(swapped, np.ones((50, 4)))
    assert not r.passed and r.measured.startswith("fields ['displacement_m', 'measured_force_N'")
    assert not rc.check_measurement(MEASUREMENT_FIELDS, np.ones((50, 3))).passed


# -- units, static force, command timing on seft's lockstep rigs -------------------------------

@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_seft_rigs_pass_units_force_and_timing(model, profile):
    command, x, v, a, f, p = drive(model, profile.step_reference())
    quiet, hold = slices(profile)
    units = rc.check_units(x, v, a, f, DT, p['stiffness_N_per_m'], hold)
    assert units.passed, units.measured
    for key in ('velocity_gain', 'acceleration_gain', 'stiffness_ratio'):
        assert units.values[key] == pytest.approx(1.0, abs=0.05), key
    static = rc.check_static_force(f, hold, quiet, 100.0)
    assert static.passed, static.measured
    timing = rc.check_command_timing(command, f, quiet, 250, DT,
                                     rig_contract.command_latency_s(p), 100.0)
    assert timing.passed, timing.measured
    assert timing.values['command_step'] == 250
    assert timing.values['first_effect'] == timing.values['promised'] == (
        255 if model == 'delay' else 252)


def test_broken_data_fails_by_name(profile):
    command, x, v, a, f, p = drive('delay', profile.step_reference())
    quiet, hold = slices(profile)
    k = p['stiffness_N_per_m']
    # a load cell of the wrong sign: the static force check, not the units
    static = rc.check_static_force(-f, hold, quiet, 100.0)
    assert not static.passed
    assert static.measured == ('gain -1.000 (f_m -100 N for 100 N, the opposite sign; '
                               'expected 0.8..1.2)')
    assert rc.check_units(x, v, a, -f, DT, k, hold).passed
    # the displacement in mm, the velocity in cm/s, the acceleration in g
    for scaled, key in ((1e3 * x, 'velocity_gain'), ):
        units = rc.check_units(scaled, v, a, f, DT, k, hold)
        assert not units.passed and units.values[key] == pytest.approx(1e-3, rel=0.05)
    assert rc.check_units(x, 100 * v, a, f, DT, k, hold).values['velocity_gain'] \
        == pytest.approx(100, rel=0.05)
    assert rc.check_units(x, v, a / 9.81, f, DT, k, hold).values['acceleration_gain'] \
        == pytest.approx(1 / 9.81, rel=0.05)
    # a kN load cell
    assert rc.check_units(x, v, a, f / 1e3, DT, k, hold).values['stiffness_ratio'] \
        == pytest.approx(1e-3, rel=0.05)
    # a rig that acts a step early (acausal), or five late
    early = rc.check_command_timing(command, np.roll(f, -1), quiet, 250, DT, 0.01, 100.0)
    assert not early.passed and early.values['first_effect'] == 254
    assert early.measured == ('the command stamped step 250 first shows at step 254: 4 steps '
                              'after it (promised 5 for command_latency_s 10 ms, at most 3 '
                              'later)')
    late = rc.check_command_timing(command, np.roll(f, 4), quiet, 250, DT, 0.01, 100.0)
    assert not late.passed and late.values['first_effect'] == 259
    assert rc.check_command_timing(command, np.roll(f, 3), quiet, 250, DT, 0.01, 100.0).passed


def test_first_departure_uses_the_noise(profile):
    rng = np.random.default_rng(1)
    s = rng.normal(0.0, 1.0, 600)
    s[300:] += 20.0
    assert rc.first_departure(s, slice(0, 250), 249, 20.0) == 300
    assert rc.first_departure(np.zeros(10), slice(0, 5), 0, 1.0) is None


def test_static_force_too_short(profile):
    quiet, hold = slices(profile)
    r = rc.check_static_force(np.zeros(100), hold, quiet, 100.0)
    assert not r.passed and r.measured == ('not measured: the run ended before the static '
                                           'force settled')


# -- safe state --------------------------------------------------------------------------------

PARAMS = {'watchdog_timeout_s': 0.02, 'dt': DT, 'safe_ramp_s': 0.2}


def _safe(final, force, velocity, fault_ns=10**9, t0_ns=0, kind='reference_force_N', **kw):
    n = force.size
    return rc.check_safe_state('safe state: abort', final=final, command_kind=kind,
                               time_s=np.arange(n) * DT, force_N=force, velocity_m_s=velocity,
                               quiet=slice(0, 100), before=slice(300, 500), fault_ns=fault_ns,
                               t0_ns=t0_ns, params=PARAMS, latency_s=0.01, amplitude_N=100.0,
                               **kw)


def _ramped(hold: bool):
    """A force rig's force: 70 N at the abort (t = 1.0 s), ramped to 0 over 0.2 s, or held."""
    t = np.arange(700) * DT
    f = np.where(t < 1.0, 70.0, 70.0 * np.clip(1 - (t - 1.01) / 0.2, 0, 1))
    return np.where(t < 1.0, 70.0, 70.0) if hold else f


def test_safe_state_of_a_force_rig():
    final = {'state': 'aborted', 'abort_at_s': '1.000', 'message': 'seft_runner: abort'}
    ok = _safe(final, _ramped(False), np.zeros(700), fault_ns=int(0.995e9))
    assert ok.passed, ok.measured
    assert ok.values['reaction_s'] == pytest.approx(0.005)
    assert ok.measured.startswith('safe state 5.0 ms after the fault (limit 24 ms), then '
                                  '|force| <= 0 N after the ramp (limit 10 N)')
    held = _safe(final, _ramped(True), np.zeros(700), fault_ns=int(0.995e9))
    assert not held.passed and held.values['rest_value'] == 70.0
    slow = _safe(final, _ramped(False), np.zeros(700), fault_ns=int(0.97e9))
    assert not slow.passed and slow.values['reaction_s'] == pytest.approx(0.03)


def test_safe_state_of_a_valve_rig():
    final = {'state': 'aborted', 'abort_at_s': '1.000', 'message': 'watchdog: no command'}
    t = np.arange(700) * DT
    # at rest, the sine from 0.5 s, then the valve closed at 1 s: it creeps
    v = 0.01 * np.sin(2 * np.pi * 2 * t) * (t >= 0.5) * (t < 1.0) + 0.0005 * (t >= 1.0)
    ok = _safe(final, np.zeros(700), v, fault_ns=int(0.98e9), kind='valve_command_V',
               reason_prefix='watchdog:')
    assert ok.passed, ok.measured
    assert ok.values['rest_limit'] == pytest.approx(0.25 * 0.01, rel=1e-3)
    moving = _safe(final, np.zeros(700), np.where(t < 1.0, v, 0.007), fault_ns=int(0.98e9),
                   kind='valve_command_V')
    assert not moving.passed and '|velocity| <= 7 mm/s' in moving.measured
    other = _safe({**final, 'message': 'seft_runner: abort'}, np.zeros(700), v,
                  fault_ns=int(0.98e9), kind='valve_command_V', reason_prefix='watchdog:')
    assert not other.passed and other.measured.endswith("(expected 'watchdog:' ...)")


def test_safe_state_not_reached():
    z = np.zeros(700)
    assert _safe(None, z, z).measured == ('no final status from the rig (it never reported '
                                          'its safe state)')
    done = _safe({'state': 'done', 'message': 'completed 700 steps'}, z, z)
    assert not done.passed and done.measured == ("the rig ended 'done' ('completed 700 steps')"
                                                 ' without a safe state (abort_at_s)')
    short = _safe({'state': 'aborted', 'abort_at_s': '1.3', 'message': 'x'}, z, z)
    assert not short.passed and 'sampled 0 samples after its ramp ended' in short.measured


def test_final_status_and_bags():
    c = rig_contract.CONTRACT
    finals = {'step': {'state': 'done', 'published': '1000', 'contract': c},
              'abort': {'state': 'aborted', 'contract': c}}
    ok = rc.check_final_status(finals, 1000)
    assert ok.passed and ok.measured == ('2 runs ended with the expected report (step done, '
                                         'abort aborted), contract seft-rig/1.0')
    bad = rc.check_final_status({**finals, 'abort': {'state': 'done', 'message': 'x',
                                                     'contract': 'seft-rig/2.0'},
                                 'watchdog': None}, 999)
    assert not bad.passed
    assert bad.measured == ("step: published 1000 samples, expected 999; abort: 'done' ('x'), "
                            "expected 'aborted'; abort: contract 'seft-rig/2.0', expected "
                            'seft-rig/1.0; watchdog: no final status')
    assert rc.check_bags_closed({'step': True, 'abort': True}).passed
    r = rc.check_bags_closed({'step': True, 'abort': False})
    assert not r.passed and r.measured == '1 of 2 bags closed (not: abort)'
    assert rc.format_line(r) == 'FAIL bag closed: 1 of 2 bags closed (not: abort)'
    assert rc.CHECKS[0] == 'contract' and len(rc.CHECKS) == 11
