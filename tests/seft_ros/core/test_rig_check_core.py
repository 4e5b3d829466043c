"""The checks of seft rig-check on arrays: seft's lockstep rigs pass them, broken data fails
them by name, with the measured value in the line."""

import math
import re

import numpy as np
import pytest
from scipy.integrate import quad

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


# -- the profile -------------------------------------------------------------------------------

def test_profile_step_and_sine(profile):
    f = profile.step_reference()
    assert f.size == 1000 and profile.onset_step == 250
    assert np.all(f[:250] == 0) and np.all(f[250:750] == 100.0) and np.all(f[750:] == 0)
    s = profile.sine_reference()
    assert profile.fault_step == 250 + 531                   # 2.125 cycles of 2 Hz
    # a checker that heard that sample late injects the fault a cycle later, or two: the
    # record goes on 1 s after the last chance
    assert profile.fault_steps == (250 + 531, 250 + 781, 250 + 1031)
    assert s.size == profile.fault_steps[-1] + 500
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


@pytest.mark.parametrize('value', [0, 1.5, True])
def test_profile_refuses_bad_fault_chances(value):
    with pytest.raises(ParameterError, match=rf'^fault_chances={value!r}: expected a whole '
                       'number >= 1$'):
        rc.CheckProfile(dt=DT, fault_chances=value)


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
    # a rig that publishes no sensor ranges: said, not failed (issue 39)
    assert ok.measured == ('seft-rig/3.0, takes valve_command_V, command latency 3 ms, 17 of '
                           '17 required parameters published; ranges not declared: '
                           'force_range_N, displacement_range_m, velocity_range_m_s, '
                           "accelerometer_range_m_s2, actuator_velocity_limit_m_s (the "
                           "configuration's are taken)")
    declared = dict(params, **{n: 1.0 for n in rig_contract.RANGE_PARAMETERS})
    ok = rc.check_contract(_ready(), declared, 'valve_command_V')
    assert ok.passed and ok.measured.endswith('required parameters published, 5 ranges '
                                              'declared')
    assert ok.values['undeclared_ranges'] == []
    bad = rc.check_contract(_ready(contract='seft-rig/1.0', command_latency_s='-1'),
                            {k: v for k, v in params.items() if k != 'dt'}, 'reference_force_N')
    assert not bad.passed
    assert bad.measured == ("contract 'seft-rig/1.0', expected seft-rig/3.0; command_kind "
                            "'valve_command_V', expected 'reference_force_N'; "
                            "command_latency_s '-1', expected seconds >= 0; parameters not "
                            'published: dt')
    assert not rc.check_contract(None, params, 'valve_command_V').passed


def test_a_rig_of_contract_2_whose_reports_are_unsealed_is_told_what_to_change():
    """Contract 3.0: a rig of 2.0 seals its measurement but not its status reports; the
    graph drops them (its ready and final too), and the contract line says so and what to
    change, not just 'no ready report'."""
    params = {n: 0 for n in rig_contract.REQUIRED_PARAMETERS}
    unsealed = [_ready(contract='seft-rig/2.0', hardware_id='seft'),
                {'state': 'running', 'hardware_id': 'seft'},
                {'state': 'done', 'hardware_id': 'seft', 'contract': 'seft-rig/2.0'}]
    r = rc.check_contract(None, params, 'valve_command_V', unsealed,
                          'run token 0123abcd in the clear (message_auth token)')
    assert not r.passed and r.values == {'contract': 'seft-rig/2.0', 'unsealed_reports': 3}
    assert r.measured == (
        "the rig's 3 status reports do not carry the run's seal (hardware id 'seft'; run "
        "token 0123abcd in the clear (message_auth token)): a rig of 'seft-rig/2.0' that "
        'does not seal its status reports: the graph drops them, its ready and final '
        "reports too; seft-rig/3.0 asks the run's seal in hardware_id of every report "
        "('seft#' + run_token; with message_auth hmac 'seft#' + the HMAC of "
        'provenance.status_mac_input) and that the rig act only on reports that carry it '
        "(docs/rig_contract.md: the run's seal)")
    # a sealed ready report is the rig's word: a stray unsealed one beside it changes nothing
    assert rc.check_contract(_ready(), params, 'valve_command_V', unsealed).passed
    final = rc.check_final_status({'step': None, 'abort': None}, 1000,
                                  {'step': unsealed[-1]})
    assert not final.passed and final.measured == (
        "step: its final report ('done') without the run's seal, dropped by the graph; "
        'abort: no final status')


def _clock_data(n=1000, period=DT, burst=0):
    steps = np.arange(n)
    arrival = 10.0 + steps * period
    arrival[:burst] = arrival[burst]            # the first samples heard at once
    return steps, steps * DT_NS, arrival


def test_clock_passes_on_time_and_through_a_first_burst():
    steps, _, arrival = _clock_data(burst=300)
    r = rc.check_clock(steps, arrival, DT, clock_ns=np.arange(30, 100) * CLOCK_EVERY * DT_NS)
    assert r.passed and r.values['period_s'] == pytest.approx(DT, rel=1e-9)
    assert re.match(r'period 2\.0000 ms \([+-]0\.00 % of dt 2 ms, limit 2 %\) over 1000 '
                    r'samples; /clock 70 messages, 0 off the grid', r.measured)


@pytest.mark.parametrize('change, expected', [
    ('slow', r"period 2\.5000 ms \(\+25\.00 % of dt.*: the rig's clock runs slow"),
    ('clock', r'/clock 70 messages, 1 off the grid'),
])
def test_clock_fails(change, expected):
    steps, _, arrival = _clock_data(period=1.25 * DT if change == 'slow' else DT)
    clock_ns = np.arange(30, 100) * CLOCK_EVERY * DT_NS
    if change == 'clock':
        clock_ns = clock_ns.copy()
        clock_ns[-1] += DT_NS
    r = rc.check_clock(steps, arrival, DT, clock_ns=clock_ns)
    assert not r.passed and re.search(expected, r.measured), r.measured


def test_clock_without_samples():
    r = rc.check_clock([], [], DT)
    assert not r.passed and r.measured == '0 samples arrived (expected at least 10)'


def test_sample_period_is_the_median_of_spans():
    steps, _, arrival = _clock_data(burst=400)
    assert rc.sample_period(steps, arrival) == pytest.approx(DT)
    steps, _, arrival = _clock_data(period=2.1e-3)
    assert rc.sample_period(steps, arrival) == pytest.approx(2.1e-3)


T0_NS = 10**18


def _stamped(n=1000, sent_after_s=1e-4):
    """Stamps k dt and their send times t0 + k dt + `sent_after_s` [s]."""
    stamps = np.arange(n) * DT_NS
    return stamps, (T0_NS + stamps) * 1e-9 + sent_after_s


def test_stamps_pass():
    r = rc.check_stamps(*_stamped(), DT, expected=1000, t0_ns=T0_NS)
    assert r.passed, r.measured
    assert r.measured == ('0 off the grid, 0 missing, 0 repeated, 0 outside 0..999 of 1000 '
                          'samples, sent a median 0.10 ms after t0 + k dt (limit +/-3 ms)')
    # the sending is not judged without the rig's t0
    r = rc.check_stamps(*_stamped(sent_after_s=1.0), DT, expected=1000, t0_ns=None)
    assert r.passed and r.measured.endswith('no t0_ns in the running reports: the sending '
                                            'not judged')


@pytest.mark.parametrize('change, expected', [
    ('off_grid', r'^1000 off the grid.*; stamps off the grid of k dt: stamp each sample '
     r'with k dt_ns'),
    ('gap', r'2 missing.*; 2 samples never published: a late tick is caught up, never '
     r'skipped$'),
    ('repeat', r'1 repeated.*; 1 steps published more than once$'),
    ('ahead', r'2 missing, 0 repeated, 2 outside.*; the stamps are not 0 \.\. 999 \(the '
     r'first says step 2\): number the samples from 0, one step each; sent 3\.9 ms before '
     r"their stamps' instants: the stamps run 1\.9 samples ahead"),
    ('buffered', r'sent a median 4\.10 ms after t0.*: the samples are 2\.0 samples late'),
    ('behind', r'the first says step -2.*sent 4\.1 ms after their stamps'),
    ('fell_behind', r"sent 4\.1 ms after their stamps' instants, the first 50 a median 0\.10 "
     r'ms: the rig fell 2\.0 samples behind after its start and did not catch up'),
])
def test_stamps_fail(change, expected):
    stamps, sent = _stamped()
    if change == 'off_grid':
        stamps = stamps + DT_NS // 4
    if change == 'gap':
        keep = (stamps != 500 * DT_NS) & (stamps != 501 * DT_NS)
        stamps, sent = stamps[keep], sent[keep]
    if change == 'repeat':
        stamps, sent = np.insert(stamps, 5, stamps[5]), np.insert(sent, 5, sent[5])
    if change == 'ahead':              # sample k stamped k + 2, sent at its own instant
        stamps = stamps + 2 * DT_NS
    if change == 'behind':             # sample k stamped k - 2, sent at its own instant
        stamps = stamps - 2 * DT_NS
    if change == 'buffered':           # sample k sent two periods late
        sent = sent + 2 * DT
    if change == 'fell_behind':        # on time, then two periods late from sample 100 on
        sent = sent + np.where(stamps >= 100 * DT_NS, 2 * DT, 0.0)
    r = rc.check_stamps(stamps, sent, DT, expected=1000, t0_ns=T0_NS)
    assert not r.passed and re.search(expected, r.measured), r.measured


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


def test_measurement_without_the_runs_seal():
    """A rig that does not seal its measurement (a rig of contract 1.0): the graph's nodes
    drop every sample, and the check says why."""
    values = np.ones((50, 4))
    ok = rc.check_measurement(MEASUREMENT_FIELDS, values, seal='run token ab in the clear')
    assert ok.passed and ok.measured.endswith('; every message sealed for the run')
    r = rc.check_measurement(MEASUREMENT_FIELDS, values, unsealed=50, frame_id='actuator',
                             seal='run token ab in the clear')
    assert not r.passed and r.values['unsealed'] == 50
    assert r.measured.endswith("; 50 of 50 messages without the run's seal (frame id "
                               "'actuator'; run token ab in the clear): the graph's nodes "
                               "drop them; a rig puts the run's seal in header.frame_id (rig "
                               "contract: the run's seal)")


def test_second_sender_check():
    """The controller behind the UDP bridge refused the second sender (it heard nothing,
    the rig reported the refusal, the run ended done), or it did not: each way named."""
    trial = {'from': '127.0.0.1:40000', 'session': 7, 't_s': 1.625, 'sent': 10, 'heard': []}
    done = {'state': 'done', 'published': '1000', 'controller_start_refused': '1'}
    ok = rc.check_second_sender(trial, done, 1000)
    assert ok.passed and ok.measured == (
        'a start of session 7 from 127.0.0.1:40000 at t = 1.625 s (10 datagrams, then 0 V '
        "commands): refused: no answer to it, reason 6 'start refused' in the live run's "
        'datagrams, the run went on to its end (done, 1000 of 1000 samples)')
    taken = dict(trial, heard=[(7, 'running')] * 3)
    lost = {'state': 'aborted', 'published': '820', 'controller_start_refused': '0',
            'message': 'udp_bridge: no datagram from the controller for 51.0 ms'}
    bad = rc.check_second_sender(taken, lost, 1000)
    assert not bad.passed and bad.values['own_session_heard'] == 3
    assert bad.measured == (
        'a start of session 7 from 127.0.0.1:40000 at t = 1.625 s (10 datagrams, then 0 V '
        'commands): the controller took it: it answered the second sender 3 times with its '
        'session (state running): a second PC takes the rig over; the controller did not '
        "name the refusal in its datagrams to the live PC (reason 6 'start refused'; the "
        "rig's final status controller_start_refused='0'); the run did not go on to its "
        "end: 'aborted', 820 of 1000 samples (udp_bridge: no datagram from the controller "
        'for 51.0 ms). A controller refuses a start while a session is live and answers the '
        'live PC alone (rig contract: sessions)')
    # a checker that heard the rig late sent its start alone (the run's end near)
    late = rc.check_second_sender(dict(trial, sent=1, withheld=9), done, 1000)
    assert late.passed and late.measured.startswith(
        "a start of session 7 from 127.0.0.1:40000 at t = 1.625 s (its start datagram; 9 more "
        "withheld, the live run's end near): refused")
    leak = rc.check_second_sender(dict(trial, heard=[(9, 'running')]), done, 1000)
    assert not leak.passed and 'not with its session' in leak.measured
    assert not rc.check_second_sender(None, done, 1000).passed


def test_measurement_against_the_bags_record():
    """The bag's record stream must carry what the graph used: a rig node that converts a
    unit in one of its two paths only fails here."""
    live = np.arange(200.0).reshape(50, 4)
    record = live.copy()
    record[10:, 1] *= 1e3                          # the record in mm, the live value in m
    record[0] = np.nan                              # a sample the bag lacks is not compared
    r = rc.check_measurement(MEASUREMENT_FIELDS, live, record)
    assert not r.passed and r.values['record_differs'] == 40
    assert r.measured.endswith("the bag's record differs in 40 of 49 samples (the record "
                               'stream must carry the samples the rig published)')
    assert rc.check_measurement(MEASUREMENT_FIELDS, live, live).passed


# -- the signals, on seft's lockstep rigs ------------------------------------------------------

def signals(fields, profile, stiffness=2.11e5):
    """check_signals of the step run's `fields` (f, x, v, a): name -> result."""
    return {r.name: r for r in rc.check_signals(fields, dt=DT, amplitude_N=100.0,
                                                stiffness_N_per_m=stiffness,
                                                hold=profile.hold, rest=profile.rest)}


@pytest.fixture(scope='module')
def delay_step(profile):
    """The delay rig's step run: (command, f, x, v, a), noise free."""
    command, x, v, a, f, _ = drive('delay', profile.step_reference())
    return command, f, x, v, a


@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_seft_rigs_pass_the_signals_and_timing(model, profile):
    command, x, v, a, f, p = drive(model, profile.step_reference())
    results = signals((f, x, v, a), profile)
    assert all(r.passed for r in results.values()), [r.measured for r in results.values()]
    assert list(results) == [*rc.SIGNAL_CHECKS, 'swapped fields']
    for name in rc.SIGNAL_CHECKS:
        assert results[name].values['ratio'] == pytest.approx(1.0, abs=0.05), name
    for q in ('velocity', 'acceleration'):
        assert results[f'{q} sign'].values['correlation'] > 0.99
    assert re.fullmatch(r'k x / f_r = \+(1|0\.98\d) \(x 0\.000(47|46)\d\d m for f_r 100 N\)',
                        results['displacement sign'].measured)
    quiet = profile.quiet
    timing = rc.check_command_timing(command, f, quiet, 250, DT,
                                     rig_contract.command_latency_s(p), 100.0)
    assert timing.passed, timing.measured
    assert timing.values['command_step'] == 250
    assert timing.values['first_effect'] == timing.values['promised'] == (
        255 if model == 'delay' else 252)


def test_realistic_noise_and_a_stiffness_off_by_60_percent_pass(profile):
    """Noise of a lab's sensors (5 N, 2 um, 0.2 mm/s, 0.05 m/s^2) and a specimen stiffer or
    softer than configured pass every signal check."""
    _, x, v, a, f, _ = drive('servohydraulic', profile.step_reference(), noise_force_N=5.0,
                             noise_displacement_m=2e-6, noise_velocity_m_s=2e-4,
                             noise_acceleration_m_s2=0.05)
    for stiffness in (2.11e5, 1.6 * 2.11e5, 2.11e5 / 1.6):
        results = signals((f, x, v, a), profile, stiffness)
        assert all(r.passed for r in results.values()), [r.measured for r in results.values()]


G = 9.80665


@pytest.mark.parametrize('fault, failed, text', [
    # the case: one transducer mounted the other way round, v and a taken from it
    (lambda f, x, v, a: (f, -x, -v, -a), {'displacement sign', 'velocity sign',
                                          'acceleration sign'},
     {'displacement sign': "N): displacement reversed against the force: check the "
      "transducer's mounting or the sign in your rig node; the velocity and acceleration "
      'read reversed too: one transducer mounted the other way round'}),
    (lambda f, x, v, a: (-f, x, v, a), {'force sign'},
     {'force sign': "f / f_r = -1 (f -100 N for f_r 100 N): the measured force is reversed "
      "against the reference: check the load cell's sign"}),
    (lambda f, x, v, a: (f / 1e3, x, v, a), {'force scale'},
     {'force scale': '|f / f_r| = 0.001 (expected 0.8..1.2): the force reads 0.001 times '
      'what it should: kN instead of N?'}),
    (lambda f, x, v, a: (f, -x, v, a), {'displacement sign'}, {}),
    (lambda f, x, v, a: (f, 1e3 * x, v, a), {'displacement scale'},
     {'displacement scale': '|k x / f_r| = 1e+03 (expected 0.5..2; k = 211000 N/m): the '
      'displacement reads 1e+03 times what it should: mm instead of m?',
      'velocity scale': '|v / (dx/dt)| = 1 (expected 0.5..2)'}),
    (lambda f, x, v, a: (f, x, -v, a), {'velocity sign'}, {}),
    (lambda f, x, v, a: (f, x, 100 * v, a), {'velocity scale'},
     {'velocity scale': 'cm/s instead of m/s?'}),
    (lambda f, x, v, a: (f, x, v, -a), {'acceleration sign'},
     {'acceleration sign': 'the builder would feed back -a'}),
    (lambda f, x, v, a: (f, x, v, a / G), {'acceleration scale'},
     {'acceleration scale': 'g instead of m/s^2?'}),
    (lambda f, x, v, a: (f, x, v, np.zeros_like(a)), {'acceleration sign',
                                                      'acceleration scale'},
     {'acceleration sign': 'acceleration against d2x/dt2: it does not follow d2x/dt2 '
      '(correlation 0.00, expected at least 0.5 in magnitude)'}),
    (lambda f, x, v, a: (x, f, v, a), {'force scale', 'displacement scale', 'swapped fields'},
     {'swapped fields': 'measured_force_N and displacement_m look swapped: exchanged, every '
      'sign and scale check passes'}),
    (lambda f, x, v, a: (f, x, a, v), {'velocity sign', 'velocity scale', 'acceleration sign',
                                       'acceleration scale', 'swapped fields'},
     {'swapped fields': 'velocity_m_s and acceleration_m_s2 look swapped'}),
    (lambda f, x, v, a: (f, v, x, a), {'displacement sign', 'displacement scale',
                                       'velocity sign', 'velocity scale', 'swapped fields'},
     {'swapped fields': 'displacement_m and velocity_m_s look swapped'}),
])
def test_each_signal_fault_fails_its_own_checks(fault, failed, text, delay_step, profile):
    """One fault fails the checks of its channel (and names itself), no other: a channel
    derived from the displacement is judged against the displacement as it should read."""
    _, f, x, v, a = delay_step
    results = signals(fault(f, x, v, a), profile)
    assert {n for n, r in results.items() if not r.passed} == failed, \
        [r.measured for r in results.values() if not r.passed]
    for name, words in text.items():
        assert words in results[name].measured, results[name].measured


def test_a_static_change_within_the_noise_is_not_judged(profile):
    f = np.random.default_rng(2).normal(0.0, 10.0, 1000)        # a load cell not connected
    _, x, v, a, _, _ = drive('delay', profile.step_reference())
    r = signals((f, x, v, a), profile)['force sign']
    assert not r.passed and 'it did not move under the static force' in r.measured


def test_first_departure_uses_the_noise(profile):
    rng = np.random.default_rng(1)
    s = rng.normal(0.0, 1.0, 600)
    s[300:] += 20.0
    assert rc.first_departure(s, slice(0, 250), 249, 20.0) == 300
    assert rc.first_departure(np.zeros(10), slice(0, 5), 0, 1.0) is None


def test_command_timing_of_a_late_rig_and_of_a_step_hidden_by_noise(delay_step, profile):
    command, f, *_ = delay_step
    quiet = profile.quiet
    early = rc.check_command_timing(command, np.roll(f, -1), quiet, 250, DT, 0.01, 100.0)
    assert not early.passed and early.values['first_effect'] == 254
    assert early.measured == ('the command stamped step 250 first shows at step 254: 4 steps '
                              'after it (promised 5 for command_latency_s 10 ms, at most 3 '
                              'later)')
    late = rc.check_command_timing(command, np.roll(f, 4), quiet, 250, DT, 0.01, 100.0)
    assert not late.passed and late.values['first_effect'] == 259
    assert rc.check_command_timing(command, np.roll(f, 3), quiet, 250, DT, 0.01, 100.0).passed
    # a force in kN departs at the same sample
    assert rc.check_command_timing(command, f / 1e3, quiet, 250, DT, 0.01, 100.0).passed
    noisy = f + np.random.default_rng(3).normal(0.0, 50.0, f.size)
    hidden = rc.check_command_timing(command, noisy, quiet, 250, DT, 0.01, 100.0)
    assert not hidden.passed and re.match(r"not measured: the measured force's noise at rest "
                                          r'\(\d\d\.\d N RMS\) hides a step of 100 N',
                                          hidden.measured)


def test_stuck_sensor(delay_step, profile):
    _, f, x, v, a = delay_step
    sine_run = drive('delay', profile.sine_reference())
    sine = [s[250:1281] for s in (sine_run[4], sine_run[1], sine_run[2], sine_run[3])]
    ok = rc.check_stuck((f, x, v, a), sine)
    assert ok.passed and ok.values['stuck'] == []
    # the delay rig's force holds exactly under the static force: not stuck
    assert max(np.mean(s[1:] == s[:-1]) for s in (f,)) > 0.9
    flat = rc.check_stuck((f, x, v, np.zeros_like(a)), None)
    assert not flat.passed and flat.measured == (
        '1 of 4 fields stuck over the step run (no sine run): acceleration_m_s2 read a '
        'constant: a stuck or disconnected sensor, or a rig node that does not update the '
        'field')
    frozen = list(sine)
    frozen[1] = np.where(np.arange(sine[1].size) > 50, sine[1][50], sine[1])
    r = rc.check_stuck((f, x, v, a), frozen)
    assert not r.passed and r.values['stuck'] == ['displacement_m']
    assert r.values['repeats']['displacement_m'] == pytest.approx(0.95, abs=0.01)


MONITOR = dict(dt=DT, mass_kg=52.7, cutoff_hz=25.0, threshold=1.0, floor_N=50.0)


def test_sensor_noise_against_the_monitor(profile):
    """The check's ratio is the monitor's own at a quiet start: white load-cell noise that
    trips the monitor (InstabilityMonitor itself) fails, a tenth of it passes."""
    from seft_ros.core.monitor import InstabilityMonitor
    rng = np.random.default_rng(4)
    quiet = slice(0, 2500)
    for sigma, passes in ((100.0, False), (10.0, True)):
        f = rng.normal(0.0, sigma, 2500)
        r = rc.check_noise(f, np.zeros(2500), quiet, alpha=0.0, **MONITOR)
        assert r.passed is passes, r.measured
        monitor = InstabilityMonitor(DT)
        trips = any(monitor.update(x, 0.0, 0.0) for x in f)
        assert trips is not passes
        assert r.values['ratio'] == pytest.approx(monitor.ratio, rel=0.15)
    # the accelerometer's noise enters as alpha m a
    a = rng.normal(0.0, 2.0, 2500)
    fed = rc.check_noise(np.zeros(2500), a, quiet, alpha=1.0, **MONITOR)
    assert not fed.passed and 'the accelerometer (fed back) noise would trip' in fed.measured
    assert rc.check_noise(np.zeros(2500), a, quiet, alpha=0.0, **MONITOR).passed
    off = rc.check_noise(rng.normal(0.0, 100.0, 2500), a, quiet, alpha=1.0,
                         **{**MONITOR, 'threshold': 0.0})
    assert off.passed and off.measured.endswith('(the monitor is off: monitor_threshold 0)')


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
    assert ok.values['rest_limit'] == pytest.approx(0.35 * 0.01, rel=1e-3)
    moving = _safe(final, np.zeros(700), np.where(t < 1.0, v, 0.007), fault_ns=int(0.98e9),
                   kind='valve_command_V')
    assert not moving.passed and '|velocity| <= 7 mm/s' in moving.measured
    other = _safe({**final, 'message': 'seft_runner: abort'}, np.zeros(700), v,
                  fault_ns=int(0.98e9), kind='valve_command_V', reason_prefix='watchdog:')
    assert not other.passed and other.measured.endswith("(expected 'watchdog:' ...)")



def test_a_valve_rig_creeps_in_proportion_to_the_force_it_holds():
    """A closed valve leaks: v = -L f, f = k x, so the held force relaxes as exp(-L k t). A
    long watchdog left 340 N (3.4 x the amplitude) to hold: the creep is 3.4 x faster than
    at the amplitude, and passes; the same velocity loading the specimen (a valve held
    open: the force grows) fails, at any force."""
    final = {'state': 'aborted', 'abort_at_s': '1.000', 'message': 'watchdog: no command'}
    k, leak = 2.11e5, 7.2e-6                      # N/m, m/s per N (the bridge's rig check)
    t = np.arange(700) * DT
    sine = 0.006 * np.sin(2 * np.pi * 2 * t) * (t >= 0.5) * (t < 1.0)
    # the force held through the ramp of the valve's command, then the creep (the check
    # judges from the command's latency, 10 ms, and 10 ms of settling after the ramp)
    settled = 1.0 + 0.01 + float(PARAMS['safe_ramp_s']) + 0.01
    rest = t >= settled - 1e-9
    f = np.where(t >= 1.0, -340.0 * np.exp(-leak * k * np.clip(t - settled, 0, None)), 0.0)
    creep = _safe(final, f, np.where(rest, -leak * f, sine * (t < 1.0)), fault_ns=int(0.98e9),
                  kind='valve_command_V')
    ratio, growth = rc.held_force(t[rest], f[rest], 100.0)
    assert ratio == pytest.approx(3.4)
    span = t[rest][-1] - t[rest][0]
    # the least-squares line's slope of |f| = 340 exp(-L k t) over [0, span] is the average of
    # its derivative weighted by 6 t (span - t) / span^3 (continuous; the samples are dense)
    slope, _ = quad(lambda s: -340.0 * leak * k * np.exp(-leak * k * s) * 6 * s * (span - s)
                    / span**3, 0.0, span)
    assert growth == pytest.approx(slope * span, rel=1e-2)
    assert creep.passed, creep.measured
    assert creep.values['rest_limit'] == pytest.approx(0.35 * 0.006 * 3.4, rel=1e-3)
    assert 'the creep of a held force 3.40 x the amplitude), |f| fell' in creep.measured
    # without the held force's factor the creep (2.45 mm/s) would fail 0.35 x 6 mm/s
    assert creep.values['rest_value'] > 0.35 * 0.006
    # a valve held open: the same speed, into the spring (|f| grows k v per second)
    v_open = leak * 340.0
    loading = np.where(t >= 1.0, -340.0 - k * v_open * np.clip(t - settled, 0, None), 0.0)
    held = _safe(final, loading, np.where(rest, -v_open, sine * (t < 1.0)), fault_ns=int(0.98e9),
                 kind='valve_command_V')
    assert rc.held_force(t[rest], loading[rest], 100.0) == pytest.approx(
        (1.0, k * v_open * span))
    assert not held.passed and held.measured.endswith(
        'the valve still loads the specimen); reason: watchdog: no command')
    # no creep bound beyond the run's force limit (the check's: 5 x the amplitude): a rig
    # that let the force run to 1264 N and then moved at 12 mm/s is not at rest
    runaway = np.where(t >= 1.0, -1264.0 * np.exp(-leak * k * np.clip(t - settled, 0, None)),
                       0.0)
    moving = np.where(rest, 0.012, sine * (t < 1.0))
    args = dict(final=final, command_kind='valve_command_V', time_s=t, force_N=runaway,
                velocity_m_s=moving, quiet=slice(0, 100), before=slice(300, 500),
                fault_ns=int(0.98e9), t0_ns=0, latency_s=0.01, amplitude_N=100.0)
    assert rc.check_safe_state('safe state: watchdog', params=PARAMS, **args).passed
    capped = rc.check_safe_state('safe state: watchdog', params=dict(
        PARAMS, force_limit_N=500.0), **args)
    assert not capped.passed and capped.values['rest_limit'] == pytest.approx(
        0.35 * 0.006 * 5.0, rel=1e-3)

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
                                         'abort aborted), contract seft-rig/3.0')
    bad = rc.check_final_status({**finals, 'abort': {'state': 'done', 'message': 'x',
                                                     'contract': 'seft-rig/1.0'},
                                 'watchdog': None}, 999)
    assert not bad.passed
    assert bad.measured == ("step: published 1000 samples, expected 999; abort: 'done' ('x'), "
                            "expected 'aborted'; abort: contract 'seft-rig/1.0', expected "
                            'seft-rig/3.0; watchdog: no final status')
    assert rc.check_bags_closed({'step': True, 'abort': True}).passed
    r = rc.check_bags_closed({'step': True, 'abort': False})
    assert not r.passed and r.measured == '1 of 2 bags closed (not: abort)'
    assert rc.format_line(r) == 'FAIL bag closed: 1 of 2 bags closed (not: abort)'
    assert rc.CHECKS[0] == 'contract' and len(rc.CHECKS) == 22
    assert rc.checks_for(udp_bridge=False) == tuple(c for c in rc.CHECKS
                                                    if c != 'second sender')
