"""WallClockRig: the rig of real-time mode against the lockstep rig it must reduce to.

Every check compares with an independent solution: the lockstep rig sampled exactly at dt
with its own (fractional) delay split, which a command timing that is the same for every step
reduces to. Arrival times are on the 0.1 ms sub-step grid, so the comparison is exact up to
rounding.
"""

import json

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.realtime import ReplayRig, WallClockRig, applied_commands
from seft_plant_sim.rigs import make_rig

N = 600
DT = 0.002


@pytest.fixture
def command():
    """A valve-command-sized random sequence with content up to the oil-column resonance."""
    rng = np.random.default_rng(7)
    return np.convolve(rng.standard_normal(N), np.ones(3) / 3, mode='same')


def _params(**kw):
    return parameters.resolve(dict(dict(dt=DT), **kw))


def _lockstep(params, u):
    rig = make_rig(params)
    out = []
    for k in range(N):
        m = rig.measure()
        out.append((m.displacement_m, m.velocity_m_s, m.acceleration_m_s2, m.force_N))
        rig.apply(u[k])
    return np.array(out)


def _realtime(params, u, latency_s, *, source_lag=0):
    """Command stamped j arrives latency_s after sample j - source_lag."""
    rig = WallClockRig(params)
    assert rig.source_lag == source_lag
    out = []
    for k in range(N):
        m = rig.measure()
        assert m.step == k and m.time_s == pytest.approx(k * DT)
        out.append((m.displacement_m, m.velocity_m_s, m.acceleration_m_s2, m.force_N))
        # the command stamped k (delay rig: k + 1 is computed from sample k)
        stamp = k + source_lag
        if stamp < N:
            rig.arrive(stamp, u[stamp], k * DT + latency_s)
        if source_lag and k == 0:
            rig.arrive(0, u[0], -DT + latency_s)   # f_r[0]: before the clock starts
        rig.advance()
    return np.array(out), rig


def _close(a, b):
    scale = np.max(np.abs(b), axis=0)
    return np.max(np.abs(a - b) / scale)


def test_latched_in_time_equals_lockstep_servohydraulic(command):
    p = _params(rig_model='servohydraulic', io_latency_s=0.003)
    rt, rig = _realtime(p, command, 0.0012)
    assert rig.hardware_latency_s == pytest.approx(0.001)
    assert _close(rt, _lockstep(p, command)) < 1e-9
    assert not any(rig.stale(k) for k in range(1, N))
    assert rig.loop_latency_s(10) == pytest.approx(0.0012)


def test_latched_late_commands_act_on_arrival(command):
    # every command misses its tick by 0.5 ms: it acts at t_k + 2.5 ms + 1 ms, which is the
    # lockstep rig with a 3.5 ms I/O latency
    p = _params(rig_model='servohydraulic', io_latency_s=0.003)
    rt, rig = _realtime(p, command, 0.0025)
    assert _close(rt, _lockstep(dict(p, io_latency_s=0.0035), command)) < 1e-9
    assert all(rig.stale(k) for k in range(1, N))


def test_on_arrival_replaces_the_control_period(command):
    # on arrival after 1.2 ms + hardware 1 ms = lockstep with 2.2 ms
    p = _params(rig_model='servohydraulic', io_latency_s=0.003, realtime_output='on_arrival')
    rt, _ = _realtime(p, command, 0.0012)
    assert _close(rt, _lockstep(dict(p, io_latency_s=0.0022), command)) < 1e-9


def test_delay_rig_latched_and_on_arrival(command):
    force = 500.0 * command
    p = _params(rig_model='delay', tau_s=0.01)
    rt, rig = _realtime(p, force, 0.0007, source_lag=1)
    assert rig.hardware_latency_s == pytest.approx(0.01)
    assert _close(rt, _lockstep(p, force)) < 1e-9
    # on arrival: f_r[j] acts at t_j-1 + 0.7 ms + tau = t_j + 8.7 ms
    p2 = dict(p, realtime_output='on_arrival')
    rt2, _ = _realtime(p2, force, 0.0007, source_lag=1)
    assert _close(rt2, _lockstep(dict(p, tau_s=0.0087), force)) < 1e-9


def test_older_command_is_discarded():
    p = _params(rig_model='delay', tau_s=0.002, realtime_output='on_arrival')
    rig = WallClockRig(p)
    rig.arrive(2, 100.0, 0.0)      # newer, acts at 2 ms
    rig.arrive(1, -50.0, 0.0011)   # older, would act at 3.1 ms: dropped
    for _ in range(3):
        rig.advance()
    assert rig.discarded == 1
    assert rig.measure().force_N == pytest.approx(100.0)


def test_safe_state_ramps_the_force_to_zero():
    p = _params(rig_model='delay', tau_s=0.002, safe_ramp_s=0.02)
    rig = WallClockRig(p)
    rig.arrive(0, 1000.0, -0.001)
    for _ in range(5):
        rig.advance()
    assert rig.measure().force_N == pytest.approx(1000.0)
    rig.enter_safe_state()                 # at t = 10 ms
    rig.arrive(6, 5000.0, rig.time_s)      # ignored
    forces = []
    while not rig.safe_ramp_done:
        rig.advance()
        forces.append(rig.measure().force_N)
    # the ramp reaches the specimen tau = 2 ms later: 1000 N at 12 ms, 0 from 32 ms on
    assert rig.time_s == pytest.approx(0.032)
    assert forces[0] == pytest.approx(1000.0)             # t = 12 ms
    assert forces[5] == pytest.approx(500.0)               # t = 22 ms: half way
    assert forces[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.diff(forces) <= 1e-9)
    assert rig.discarded == 1


def test_bad_output_timing_is_named():
    with pytest.raises(ParameterError, match='realtime_output'):
        WallClockRig(dict(_params(), realtime_output='soon'))


def test_an_actuator_of_the_family_holds_its_own_latency(command):
    """The family's actuator (its io_delay_s inside the model; io_latency_s, seft's rig's,
    is not added on top: it was, 3 ms late): latched (the default), a command that arrives
    0.5 ms after its sample, as the graph's do, acts at the next tick, whatever its arrival
    within the period: the lockstep rig one sample later (an independent solution: the
    lockstep rig fed u[k-1] at step k); on arrival, one arriving at its sample acts then,
    exactly as in lockstep."""
    p = _params(rig_model='actuator', actuator_family='leaky')
    u = 0.2 * command
    late = np.concatenate(([0.0], u[:-1]))
    for latency in (0.0005, 0.0013):
        rt, rig = _realtime(p, u, latency)
        assert rig.hardware_latency_s == 0.0
        assert _close(rt, _lockstep(p, late)) < 1e-6   # sampled at 0.1 ms and at dt
    assert _close(rt, _lockstep(p, u)) > 0.01
    rt, _ = _realtime(dict(p, realtime_output='on_arrival'), u, 0.0)
    assert _close(rt, _lockstep(p, u)) < 1e-6


def test_a_discrete_lab_model_is_refused_in_real_time_in_one_line():
    plant = {'form': 'transfer_function', 'dt': DT, 'num': {'force_N': [0.0, 1.0]},
             'den': [1.0, -0.5],
             'specimen': {'mass_kg': 52.7, 'stiffness_N_per_m': 2.11e5,
                          'damping_N_s_per_m': 903.3}}
    p = _params(rig_model='state_space', plant_model=json.dumps(plant))
    with pytest.raises(ParameterError, match=r'^rig_model state_space in real time: the '
                       r'plant_model is discrete at dt \(2 ms\) .* 0\.1 ms grid'):
        WallClockRig(p)
    WallClockRig(dict(p, realtime_substep_s=DT))        # on the model's own grid
    # the rig's own plant (rig_plant_model) is the one stepped, and the one named: a
    # continuous plant_model beside it does not let a discrete rig plant through
    continuous = dict(plant, dt=0.0, num={'force_N': [1.0e4]}, den=[1.0, 100.0])
    p = _params(rig_model='state_space', plant_model=json.dumps(continuous),
                rig_plant_model=json.dumps(plant))
    with pytest.raises(ParameterError, match=r'^rig_model state_space in real time: the '
                       r'rig_plant_model is discrete at dt \(2 ms\)'):
        WallClockRig(p)
    WallClockRig(dict(p, rig_plant_model=json.dumps(continuous)))


def test_the_applied_command_of_each_step_by_the_latching_rule():
    """applied_commands, by hand: a command in time holds its step; one 1 ms late holds the
    previous one for the first half of its step (the mean of the two); one that acts after
    the next command's start, or never arrives, is replaced by the previous one held on."""
    u = np.arange(1.0, 9.0)
    lat = np.full(8, 0.0005)
    assert applied_commands(u, lat, DT, DT) == (pytest.approx(u, abs=0), 0)
    lat[3] = DT + 0.001
    applied, late = applied_commands(u, lat, DT, DT)
    assert late == 1 and applied[3] == pytest.approx(3.5)
    assert np.delete(applied, 3) == pytest.approx(np.delete(u, 3), abs=0)
    for never_in_time in (2 * DT + 0.0005, np.nan):
        lat[3] = never_in_time
        applied, late = applied_commands(u, lat, DT, DT)
        assert late == 1 and list(applied) == [1, 2, 3, 3, 5, 6, 7, 8]
    # seft's servohydraulic rig latches io_latency_s = 1.5 ms after the sample
    lat[3] = 0.002
    assert applied_commands(u, lat, DT, 0.0015)[0][3] == pytest.approx(0.75 * 4 + 0.25 * 3)
    with pytest.raises(ParameterError, match='same length'):
        applied_commands(u, lat[:-1], DT, DT)


def test_the_applied_commands_reproduce_a_real_time_rig_with_late_commands(command):
    """Late commands that act at a tick (one late by a step, displaced by its successor;
    two late together, both displaced): the lockstep rig fed the applied commands
    one sample later reproduces the real-time rig (an independent solution), and fed the
    commands sent it does not."""
    p = _params(rig_model='actuator', actuator_family='valve_2nd_order')
    u = 0.2 * command
    latency = np.full(N, 0.0005)
    latency[[100, 300, 301]] = [2 * DT, 3 * DT, 2 * DT]
    rig = WallClockRig(p)
    out = []
    for k in range(N):
        m = rig.measure()
        out.append((m.displacement_m, m.velocity_m_s, m.acceleration_m_s2, m.force_N))
        rig.arrive(k, u[k], k * DT + latency[k])
        rig.advance()
    rt = np.array(out)
    applied, late = applied_commands(u, latency, DT, DT)
    assert late == 3 and list(applied[[100, 300, 301]]) == list(u[[99, 299, 299]])
    assert np.count_nonzero(applied != u) == 3
    assert _close(rt, _lockstep(p, np.concatenate(([0.0], applied[:-1])))) < 1e-6
    assert _close(rt, _lockstep(p, np.concatenate(([0.0], u[:-1])))) > 1e-3


def _replayed(params, u, latency_s):
    """The real-time rig with the command of step k arriving latency_s[k] after sample k."""
    rig = ReplayRig(params, latency_s)
    out = []
    for k in range(len(u)):
        m = rig.measure()
        out.append((m.displacement_m, m.velocity_m_s, m.acceleration_m_s2, m.force_N))
        rig.apply(u[k])
    return np.array(out), rig.rig


def test_a_late_command_is_predicted_where_the_rig_predicts():
    """``realtime_late_command: predict``: a late command acts as its linear prediction from
    the ones received until it arrives. A sinusoidal command (which an order-2 predictor
    follows exactly) is then as if in time to 1e-4 of each signal's largest value (the
    predictor's ridge); held, the late steps kick the specimen. The commands of the stall
    arrive together, before they act: the predictor's window keeps room for them (when it
    did not, they overwrote its oldest samples and it fell back to linear extrapolation,
    1e-2 here). In time, or in an open-loop run, the rig holds (the same
    floats)."""
    t = np.arange(N) * DT
    u = 0.2 * np.sin(2 * np.pi * 7.0 * t) + 0.05 * np.sin(2 * np.pi * 23.0 * t + 0.4)
    p = _params(rig_model='servohydraulic', io_latency_s=0.003)
    in_time, _ = _replayed(p, u, {})
    # one command 2.7 ms late (after the next tick) and a 10 ms stall of five at once
    late = {400: 2 * DT + 0.0007}
    late.update({k: (505 - k) * DT + 0.0003 for k in range(500, 505)})
    held, rig_h = _replayed(p, u, late)
    predicted, rig_p = _replayed(dict(p, realtime_late_command='predict'), u, late)
    assert rig_p.predicted == 6 and rig_h.predicted == 0
    err_hold, err_pred = _close(held, in_time), _close(predicted, in_time)
    assert err_hold > 1.0                       # of the largest value of some signal
    assert err_pred < 1e-3
    # in time the prediction never acts; an open-loop run's commands are held
    same, rig_s = _replayed(dict(p, realtime_late_command='predict'), u, {})
    assert np.array_equal(same, in_time) and rig_s.predicted == 0
    open_loop = dict(p, realtime_late_command='predict', excitation_input='valve_command')
    held_open, rig_o = _replayed(open_loop, u, late)
    assert np.array_equal(held_open, held) and rig_o.predicted == 0


def test_bad_late_command_rule_is_named():
    with pytest.raises(ParameterError, match='realtime_late_command'):
        WallClockRig(dict(_params(), realtime_late_command='guess'))
