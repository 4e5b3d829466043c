"""Tests of the reference-force builder (paper Eqs. 2.5, 5.3) and its predictor registry.

Against figures worked out by hand from Eq. 5.3 (f_r = -(1 + alpha) m xg'' - alpha m a_hat),
numpy evaluations of it, step averages of the linearly interpolated record integrated here by
trapezoids between its knots (exact for a piecewise linear record), and the delays that
``with_loop_latency`` must give, by hand.
"""

import dataclasses
import math
import re

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.parameters import spec
from seft_ros.core.reference_force import (
    PREDICTORS,
    NoPredictor,
    Predictor,
    RigReferenceForce,
    ground_window,
    make_predictor,
    with_loop_latency,
)

M = 52.7


def meas(k, acceleration):
    """A measurement of step k whose only relevant reading is the acceleration."""
    return Measurement(k, k * 0.002, 1e-3 * k, -2e-2 * k, acceleration, 100.0 * k)


def test_formula_by_hand():
    b = RigReferenceForce(0.5, M, NoPredictor())
    # step 0, specimen at rest: -(1 + 0.5) * 52.7 * 2.0 = -158.1
    assert b.step(2.0, None) == pytest.approx(-158.1, rel=1e-15)
    # step 1: -(1.5) 52.7 (-1.0) - 0.5 * 52.7 * (-3.0) = 79.05 + 79.05 = 158.1
    assert b.step(-1.0, meas(0, -3.0)) == pytest.approx(158.1, rel=1e-15)
    # step 2: -(1.5) 52.7 (0.4) - 0.5 * 52.7 * 7.0 = -31.62 - 184.45 = -216.07
    assert b.step(0.4, meas(1, 7.0)) == pytest.approx(-216.07, rel=1e-14)
    assert b.commanded_N == pytest.approx([-158.1, 158.1, -216.07], rel=1e-14)


def test_alpha_zero_is_the_effective_force():
    b = RigReferenceForce(0.0, M, NoPredictor())
    ag = np.random.default_rng(4).standard_normal(50)
    forces = [b.step(a, meas(k, 1e3 * (k + 1))) for k, a in enumerate(ag)]
    np.testing.assert_array_equal(forces, -M * ag)


def test_none_predictor_uses_the_previous_measurement():
    alpha = 1.3
    b = RigReferenceForce(alpha, M, make_predictor({'predictor': 'none'}))
    rng = np.random.default_rng(8)
    ag, am = rng.standard_normal(200), rng.standard_normal(200) * 5.0
    got = [b.step(ag[0], None)]
    got += [b.step(ag[k], meas(k - 1, am[k - 1])) for k in range(1, 200)]
    a_hat = np.concatenate([[0.0], am[:-1]])
    np.testing.assert_allclose(got, -(1 + alpha) * M * ag - alpha * M * a_hat, rtol=1e-14,
                               atol=1e-12)
    p = NoPredictor()
    assert p.predict(None, []) == 0.0
    assert p.predict(meas(3, -4.5), [1.0, 2.0]) == -4.5


def test_predictor_registry_and_protocol(reference_params):
    """Every registered compensator has the members of the protocol.

    Checked member by member rather than with ``isinstance(p, Predictor)``: mutmut adds its
    trampoline methods to its copy of the ``Predictor`` class, and a runtime-checkable
    protocol then requires them of every instance (tools/mutation.sh).
    """
    assert set(PREDICTORS) == set(spec('predictor').choices) and 'none' in PREDICTORS
    assert {'name', 'step_average', 'delay_s'} <= set(Predictor.__annotations__)
    assert callable(Predictor.predict) and callable(Predictor.command)
    p = make_predictor(reference_params)
    assert isinstance(p, NoPredictor) and p.name == 'none'
    for name in PREDICTORS:
        q = make_predictor(dict(reference_params, predictor=name))
        assert q.name == name and isinstance(q.step_average, bool)
        assert isinstance(q.delay_s, float) and q.delay_s >= 0.0
        assert callable(q.predict) and callable(q.command)
    b = RigReferenceForce.from_parameters(dict(reference_params, alpha=2))
    assert (b.alpha, b.mass_kg, b.predictor.name) == (2.0, 52.7, 'none')


def test_unknown_predictor():
    choices = ', '.join(repr(name) for name in PREDICTORS)
    assert choices.startswith("'none'")
    with pytest.raises(ParameterError, match='^' + re.escape(
            f"parameter predictor='smith': expected one of {choices}") + '$'):
        make_predictor({'predictor': 'smith'})


@pytest.mark.parametrize('alpha, mass, message', [
    (-0.1, M, r'^parameter alpha=-0\.1: expected float >= 0$'),
    (math.nan, M, r'^parameter alpha=nan: expected float >= 0$'),
    (0.5, 0.0, r'^parameter mass_kg=0\.0: expected float > 0$'),
    (0.5, -52.7, r'^parameter mass_kg=-52\.7: expected float > 0$'),
])
def test_builder_parameter_errors(alpha, mass, message):
    with pytest.raises(ParameterError, match=message):
        RigReferenceForce(alpha, mass, NoPredictor())


def test_loop_latency_moves_the_modelled_delay_by_latency_minus_dt():
    """predictor_loop_latency_s = L: the predictor models tau + L - dt (real time, on arrival).

    The delay rig with tau = 10 ms whose commands act on arrival 0.7 ms after their sample is
    the lockstep rig with tau = 8.7 ms (tests/seft_plant_sim/test_realtime_rig.py), so the
    model predictor must then be the one built for 8.7 ms.
    """
    from seft_msgs_py import parameters
    from seft_ros.core.reference_force import make_predictor, with_loop_latency
    base = parameters.resolve({'rig_model': 'delay', 'predictor': 'model', 'alpha': 1.0,
                               'realtime_output': 'on_arrival'})
    assert with_loop_latency(base) == base                       # 0: unchanged
    shifted = with_loop_latency(dict(base, predictor_loop_latency_s=0.0007))
    assert shifted['predictor_tau_s'] == pytest.approx(0.0087)
    assert make_predictor(dict(base, predictor_loop_latency_s=0.0007)).delay_s == \
        pytest.approx(make_predictor(dict(base, predictor_tau_s=0.0087)).delay_s)
    servo = parameters.resolve({'predictor': 'model', 'predictor_loop_latency_s': 0.0012,
                                'realtime_output': 'on_arrival'})
    assert with_loop_latency(servo)['io_latency_s'] == pytest.approx(0.0022)


def test_loop_latency_with_latched_output_is_refused():
    """With the default latched output a command acts at the next tick whatever its latency:
    a predictor told the latency would predict too far. Told the 3.6 ms measured across a 0 ms
    link, 'model' gave about 4 % where 0.42 % is right (the earlier two-host table)."""
    from seft_msgs_py import parameters
    from seft_ros.core.experiment import simulate
    from seft_ros.core.reference_force import make_predictor
    latched = parameters.resolve({'predictor': 'model', 'predictor_loop_latency_s': 0.0036})
    with pytest.raises(ParameterError, match=re.escape(
            "parameter predictor_loop_latency_s=0.0036: applies with realtime_output "
            "'on_arrival' only; with 'latched' output a command acts at the next tick whatever "
            'its latency, and a predictor told it would predict too far (set it to 0; a builder '
            'on another host: network_delay_s)')):
        make_predictor(latched)
    with pytest.raises(ParameterError, match='predictor_loop_latency_s=0.0036'):
        simulate(dict(latched, duration_s=1.0))


# -- with_loop_latency: the delay the predictor models -----------------------------------------

@pytest.mark.parametrize('params, tau', [
    # tau + L - dt with the predictor's own tau (not the rig's): 4 + 5 - 2 = 7 ms
    ({'dt': 0.002, 'predictor_loop_latency_s': 0.005, 'predictor_tau_s': 0.004,
      'tau_s': 0.010}, 0.007),
    # predictor_tau_s = 0 means the rig's tau_s: 10 + 3 - 2 = 11 ms
    ({'dt': 0.002, 'predictor_loop_latency_s': 0.003, 'predictor_tau_s': 0.0,
      'tau_s': 0.010}, 0.011),
    # no actuator delay at all: 0 + 5 - 2 = 3 ms
    ({'dt': 0.002, 'predictor_loop_latency_s': 0.005}, 0.003),
    # 0 + 0.7 - 2 ms < 0: held at 1 us, a delay above 0
    ({'dt': 0.002, 'predictor_loop_latency_s': 0.0007}, 1e-6),
])
def test_loop_latency_by_hand(params, tau):
    """predictor_tau_s = max(tau + L - dt, 1e-6), figures by hand; no io_latency_s is added."""
    out = with_loop_latency(params)
    assert out['predictor_tau_s'] == pytest.approx(tau, rel=1e-12)
    assert 'io_latency_s' not in out
    assert dict(out, predictor_tau_s=None) == dict(params, predictor_tau_s=None)


def test_loop_latency_zero_returns_an_unchanged_copy():
    params = {'dt': 0.002, 'predictor_loop_latency_s': 0.0, 'tau_s': 0.01, 'io_latency_s': 0.003}
    out = with_loop_latency(params)
    assert out == params and out is not params


@pytest.mark.parametrize('latency, io_latency, tau, io_out', [
    # network only: N = round(4.1 ms / 2 ms) = 2 steps = 4 ms on top of tau_s = 10 ms;
    # no loop latency, so io_latency_s stays 3 ms
    (0.0, 0.003, 0.014, 0.003),
    # and a loop latency of 1.2 ms: 10 + 1.2 - 2 + 4 = 13.2 ms; io 3 + 1.2 - 2 = 2.2 ms
    (0.0012, 0.003, 0.0132, 0.0022),
    # io 0.5 + 1.2 - 2 ms < 0: held at 0
    (0.0012, 0.0005, 0.0132, 0.0),
])
def test_network_delay_adds_whole_steps(latency, io_latency, tau, io_out):
    """network_delay_s adds round(network_delay_s / dt) dt to the modelled actuator delay."""
    from seft_msgs_py import parameters
    params = parameters.resolve({'mode': 'realtime', 'rig_model': 'servohydraulic',
                                 'predictor': 'model', 'network_delay_s': 0.0041,
                                 'predictor_loop_latency_s': latency,
                                 'realtime_output': 'on_arrival', 'io_latency_s': io_latency})
    assert (params['dt'], params['tau_s'], params['predictor_tau_s']) == (0.002, 0.01, 0.0)
    out = with_loop_latency(params)
    assert out['predictor_tau_s'] == pytest.approx(tau, rel=1e-12)
    assert out['io_latency_s'] == pytest.approx(io_out, abs=1e-15)


# -- the builder with a hold-consistent compensator -----------------------------------------

class RecordingPredictor:
    """A step-average compensator stub: a fixed a_hat, a gain as force-loop inverse.

    Records what the builder hands it (a copy of the forces already built, the ground part).
    """

    name = 'recording'
    step_average = True

    def __init__(self, delay_s=0.0, a_hat=0.0, gain=1.0, max_delay_s=None):
        self.delay_s, self.a_hat, self.gain = delay_s, a_hat, gain
        if max_delay_s is not None:
            self.max_delay_s = max_delay_s
        self.calls = []

    def predict(self, latest, commanded_N, ground_force_N=0.0):
        self.calls.append((latest, list(commanded_N), ground_force_N))
        return self.a_hat

    def command(self, force_N):
        return self.gain * force_N


def step_average_by_trapezoids(window, shift):
    """(1/dt) int over [t_k + shift dt, t_k + (shift + 1) dt] of the linearly interpolated
    window, by trapezoids between the knots (exact for a piecewise linear function); an
    independent reference for the builder's closed form."""
    knots = [shift] + [j for j in range(len(window)) if shift < j < shift + 1] + [shift + 1]
    y = np.interp(knots, np.arange(len(window)), window)
    return float(sum(0.5 * (y[i] + y[i + 1]) * (knots[i + 1] - knots[i])
                     for i in range(len(knots) - 1)))


def test_step_average_reference_by_hand():
    # [1, 3, -1, 5] over [1.5, 2.5]: y = 1, -1, 2 at 1.5, 2, 2.5: 0.5 * 0 + 0.5 * 0.5 = 0.25
    assert step_average_by_trapezoids([1.0, 3.0, -1.0, 5.0], 1.5) == pytest.approx(0.25)
    assert step_average_by_trapezoids([1.0, 3.0], 0.0) == pytest.approx(2.0)


def test_step_average_ground_without_preview():
    """g[k] = (xg[k] + xg[k+1]) / 2: F = -(1.5)(52.7)(2) - 0.5 (52.7)(4) = -158.1 - 105.4."""
    pred = RecordingPredictor(delay_s=0.003, a_hat=4.0, gain=-3.0)
    b = RigReferenceForce(0.5, M, pred, dt=0.002)
    assert (b.ground_preview, b.lookahead_steps, b.last_ground_force_N) == (False, 1, 0.0)
    assert b.ground([1.0, 3.0]) == 2.0
    latest = meas(0, 9.0)
    # a longer window than needed: its extra samples are not read
    assert b.step([1.0, 3.0, 100.0], latest) == pytest.approx(-3.0 * -263.5, rel=1e-14)
    assert b.commanded_N == pytest.approx([-263.5], rel=1e-14)
    assert b.last_ground_force_N == pytest.approx(-158.1, rel=1e-14)
    assert pred.calls == [(latest, [], pytest.approx(-158.1, rel=1e-14))]


def test_ground_preview_shifts_the_step_average_by_the_delay():
    """With preview the ground term is the step average over [t_k + tau, t_k+1 + tau].

    tau = 3 ms, dt = 2 ms: the shift is 1.5 steps and xg[k..k+3] is read (lookahead
    1 + ceil(1.5) = 3). g = 0.25 (test_step_average_reference_by_hand), so
    G = -(1.5)(52.7)(0.25) = -19.7625 N and F = G - 0.5 (52.7)(2) = -72.4625 N.
    """
    pred = RecordingPredictor(delay_s=0.003, a_hat=2.0, gain=2.0)
    b = RigReferenceForce(0.5, M, pred, dt=0.002, ground_preview=True)
    assert (b.ground_preview, b.dt, b.lookahead_steps) == (True, 0.002, 3)
    window = [1.0, 3.0, -1.0, 5.0]
    assert b.ground(window) == pytest.approx(0.25, rel=1e-14)
    assert b.step(window, None) == pytest.approx(2.0 * -72.4625, rel=1e-14)
    assert b.last_ground_force_N == pytest.approx(-19.7625, rel=1e-14)
    # the next step: the predictor sees the force already built
    rng = np.random.default_rng(3)
    window2 = rng.standard_normal(4).tolist()
    g2 = step_average_by_trapezoids(window2, 1.5)
    f2 = -1.5 * M * g2 - 0.5 * M * 2.0
    assert b.step(window2, meas(0, 1.0)) == pytest.approx(2.0 * f2, rel=1e-12)
    assert pred.calls[1][1:] == ([pytest.approx(-72.4625, rel=1e-14)],
                                 pytest.approx(-1.5 * M * g2, rel=1e-12))
    assert b.commanded_N == pytest.approx([-72.4625, f2], rel=1e-12)


@pytest.mark.parametrize('delay_s', [0.0, 0.001, 0.002, 0.0037, 0.005])
def test_ground_method_matches_the_step_average(delay_s):
    """ground() and step() use the same g[k], the step average shifted by tau / dt."""
    rng = np.random.default_rng(11)
    b = RigReferenceForce(1.0, M, RecordingPredictor(delay_s=delay_s), dt=0.001,
                              ground_preview=True)
    # 1 + ceil(tau / dt) samples after xg[k]
    assert b.lookahead_steps == 1 + math.ceil(round(delay_s / 0.001, 9))
    window = rng.standard_normal(b.lookahead_steps + 1).tolist()
    g = step_average_by_trapezoids(window, delay_s / 0.001)
    assert b.ground(window) == pytest.approx(g, rel=1e-12, abs=1e-15)
    b.step(window, None)
    assert b.last_ground_force_N == pytest.approx(-2.0 * M * g, rel=1e-12, abs=1e-12)


def test_the_preview_follows_a_delay_that_moves():
    """An adaptive compensator's delay moves during a run: each step's ground term is the
    step average at the delay of that step (the law keeps its split only while the delay
    holds), whole and fractional shifts, and back; the same float as ground()."""
    rng = np.random.default_rng(7)
    pred = RecordingPredictor(delay_s=0.004, max_delay_s=0.012)
    b = RigReferenceForce(1.0, M, pred, dt=0.002, ground_preview=True)
    assert b.lookahead_steps == 7
    for delay_s in (0.004, 0.004, 0.0051, 0.0051, 0.012, 0.0, 0.0037, 0.004):
        pred.delay_s = delay_s
        window = rng.standard_normal(b.lookahead_steps + 1).tolist()
        b.step(window, None)
        g = step_average_by_trapezoids(window, delay_s / 0.002)
        assert b.last_ground_force_N == pytest.approx(-2.0 * M * g, rel=1e-12, abs=1e-12)
        assert b.last_ground_force_N == -2.0 * M * b.ground(window)


def test_ground_of_the_sample_predictor_is_the_sample():
    b = RigReferenceForce(0.5, M, NoPredictor(), dt=0.002, ground_preview=True)
    assert (b.ground_preview, b.lookahead_steps) == (True, 0)
    assert b.ground([-0.7]) == -0.7 and b.ground([0.3, 5.0]) == 0.3


@pytest.mark.parametrize('delay_s, max_delay_s, dt, look', [
    (0.003, None, 0.002, 3),     # 1 + ceil(1.5)
    (0.004, None, 0.002, 3),     # 1 + 2: a whole number of steps needs no extra sample
    (0.006, None, 0.002, 4),     # 0.006 / 0.002 = 2.9999999999999996 in floats: 1 + 3
    (0.007, None, 0.001, 8),     # 0.007 / 0.001 = 7.000000000000001 in floats: 1 + 7
    (0.003, 0.007, 0.002, 5),    # an adaptive delay: room for its largest, 1 + ceil(3.5)
])
def test_preview_window_length(delay_s, max_delay_s, dt, look):
    """lookahead = 1 + ceil(tau_max / dt) (rounding errors of the division aside)."""
    pred = RecordingPredictor(delay_s=delay_s, max_delay_s=max_delay_s)
    b = RigReferenceForce(0.5, M, pred, dt=dt, ground_preview=True)
    assert b.lookahead_steps == look
    b.step([0.0] * (look + 1), None)                      # long enough to be read
    assert RigReferenceForce(0.5, M, pred, dt=dt).lookahead_steps == 1


def test_preview_needs_dt():
    """Without dt (the default 0) the preview is off: the window is 2 samples, no division."""
    b = RigReferenceForce(0.5, M, RecordingPredictor(delay_s=0.003), ground_preview=True)
    assert (b.dt, b.ground_preview, b.lookahead_steps) == (0.0, False, 1)
    assert b.ground([1.0, 3.0, -1.0]) == 2.0


def test_from_parameters_preview():
    """The model predictor on the delay rig (tau = 10 ms, dt = 2 ms): 1 + 5 samples ahead."""
    from seft_msgs_py import parameters
    p = parameters.resolve({'rig_model': 'delay', 'predictor': 'model'})
    assert (p['tau_s'], p['dt'], p['ground_preview']) == (0.01, 0.002, True)
    b = RigReferenceForce.from_parameters(p)
    assert (b.dt, b.ground_preview, b.lookahead_steps) == (0.002, True, 6)
    b = RigReferenceForce.from_parameters(dict(p, ground_preview=False))
    assert (b.dt, b.ground_preview, b.lookahead_steps) == (0.002, False, 1)


def test_short_ground_window():
    b = RigReferenceForce(0.5, M, RecordingPredictor(), dt=0.002)
    message = r'^ground window of 1 samples: expected 2 \(xg\[k\.\.k\+1\]\)$'
    with pytest.raises(ParameterError, match=message):
        b.step([0.5], None)
    with pytest.raises(ParameterError, match=message):
        b.step(0.5, None)
    assert b.commanded_N == []


@pytest.mark.parametrize('ground', [[2.0], np.array([2.0]), (2.0, 7.0), np.float64(2.0), 2])
def test_sample_predictor_takes_a_float_or_a_window(ground):
    """-(1 + 0.5) 52.7 2 = -158.1 N whatever the form of xg[k]."""
    b = RigReferenceForce(0.5, M, NoPredictor())
    assert b.step(ground, None) == pytest.approx(-158.1, rel=1e-15)


def test_small_mass():
    """A 0.5 kg specimen is valid: -(1 + 0) 0.5 2 = -1 N."""
    assert RigReferenceForce(0.0, 0.5, NoPredictor()).step(2.0, None) == -1.0


# -- ground_window ----------------------------------------------------------------------------

def test_ground_window_inside_at_and_after_the_end():
    record = [1, 2, 3, 4, 5]                       # lookup raises IndexError past the record
    look = record.__getitem__
    assert ground_window(look, 1, 2, 5) == [2.0, 3.0, 4.0]
    assert ground_window(look, 2, 2, 5) == [3.0, 4.0, 5.0]    # ends on the last sample
    assert ground_window(look, 3, 3, 5) == [4.0, 5.0, 0.0, 0.0]
    assert ground_window(look, 5, 1, 5) == [0.0, 0.0]
    assert ground_window(look, 0, 0, 5) == [1.0]
    assert all(type(v) is float for v in ground_window(look, 3, 3, 5))
    assert all(type(v) is float for v in ground_window(look, 0, 4, 5))


def test_a_builder_of_one_rig_steps_its_law_alone_with_the_same_numbers(reference_params):
    """A one-DOF test's builder steps its one law directly (issue 41): the same commands as
    the builder's general step over its rigs, the measurements that came too late to be used
    forgotten, and a missing one refused, as there."""
    from seft_ros.core.reference_force import ReferenceForceBuilder
    params = dict(reference_params, predictor='model', alpha=0.5)
    one, general = (ReferenceForceBuilder.from_parameters(params) for _ in range(2))
    assert one._only_law is one.laws[0]
    general._only_law = None                      # the loop over the laws
    rng = np.random.default_rng(2)
    ground = rng.standard_normal(300).tolist() + [0.0] * (1 + one.lookahead_steps)
    width = 1 + one.lookahead_steps
    for k in range(300):
        if k:
            m = Measurement(k - 1, (k - 1) * 0.002, *(rng.standard_normal(4) * [1e-3, 1e-2,
                                                                             1.0, 300.0]))
            for b in (one, general):
                b.observe(0, m)
                if k % 50 == 0:                   # a sample of the past, too late to be used
                    b.observe(0, dataclasses.replace(m, step=k - 6))
        out = one.step(ground[k:k + width])
        assert out == general.step(ground[k:k + width]) and isinstance(out[0], float)
        assert one.last_ground_forces_N == general.last_ground_forces_N
    assert one.laws[0].commanded_N == general.laws[0].commanded_N
    assert len(one._latest[0]) <= 4
    for b in (one, general):
        with pytest.raises(ParameterError, match=r'^rig rig: no measurement of sample 299 '
                                                 r'observed$'):
            b.step(ground[300:300 + width])


@pytest.mark.parametrize('predictor', ['none', 'model', 'adaptive'])
def test_observe_and_step_is_observe_then_step(predictor):
    """The one-rig builder's fused step (what ``simulate`` calls for a test of one rig) gives
    the commands of ``observe`` then ``step`` bit for bit, its range guard counting the same
    samples (accelerations past the accelerometer's 39.2 m/s^2 range among them), and takes
    the long way for a sample out of order; a builder of two rigs refuses it."""
    from seft_msgs_py import parameters
    from seft_ros.core.reference_force import ReferenceForceBuilder
    p = parameters.resolve({'predictor': predictor, 'alpha': 1.0})
    fused, plain = (ReferenceForceBuilder.from_parameters(p) for _ in range(2))
    rng = np.random.default_rng(3)
    look = fused.lookahead_steps
    ag = rng.standard_normal(400 + look + 1)
    a = 30.0 * rng.standard_normal(400)
    got, want = [fused.step(ag[:look + 1])[0]], [plain.step(ag[:look + 1])[0]]
    for k in range(1, 400):
        m = Measurement(k - 1, (k - 1) * 0.002, 1e-4 * math.sin(k / 9), 1e-3 * math.cos(k / 9),
                        float(a[k - 1]), 50.0 * math.sin(k / 9))
        window = ag[k:k + look + 1].tolist()
        got.append(fused.observe_and_step(m, window))
        plain.observe(0, m)
        want.append(plain.step(window)[0])
    assert got == want
    assert fused.range_counts() == plain.range_counts()
    assert fused.range_counts()['']['samples']['acceleration'] > 0
    # a measurement not of sample k - 1 goes through observe and step, with their error
    with pytest.raises(ParameterError, match='no measurement of sample 399 observed'):
        fused.observe_and_step(dataclasses.replace(m, step=500), ag[:look + 1].tolist())


def test_observe_and_step_takes_one_rig():
    from pathlib import Path

    from seft_ros.cli.config import expand_runs, load_config
    from seft_ros.core.reference_force import ReferenceForceBuilder
    config = Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml'
    builder = ReferenceForceBuilder.from_parameters(expand_runs(load_config(config))[0])
    with pytest.raises(ParameterError, match='builder of 2 local rigs: observe_and_step'):
        builder.observe_and_step(meas(0, 1.0), [0.0] * (1 + builder.lookahead_steps))
