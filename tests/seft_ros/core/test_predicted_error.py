"""The study's test's accuracy predicted from its linear loop (core/stability
``LoopModel.ground_response``, ``predicted_error``) and the force-loop inverse the design
chooses by it (core/force_design), issue 38.

The frequency response is checked against the steady state of lockstep runs on sine records
(an independent solution: the nonlinear-capable simulation, not the loop's matrices); the
error against its closed form where the test is the reference delayed; the design's choice
against runs of the test in every signal.
"""

import json
import math

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import SeftError
from seft_ros.analysis.metrics import compare_run
from seft_ros.core.experiment import simulate
from seft_ros.core.force_design import PREDICTED_ERROR_GOAL
from seft_ros.core.ground_motion import GroundMotion
from seft_ros.core.reference_force import make_predictor
from seft_ros.core.stability import GroundSpectrum, LoopModel, kanai_tajimi, predicted_error

DT = 0.002
SIGNALS = ('displacement', 'acceleration', 'force')


def study(**kw):
    return parameters.resolve({'rig_model': 'servohydraulic', 'predictor': 'model',
                               'alpha': 1.0, **kw})


def steady_amplitude(signal: np.ndarray, freq_hz: float, cycles: int = 20) -> complex:
    """The complex amplitude of `signal` at `freq_hz` over its last `cycles` periods (least
    squares on cos and sin)."""
    n = int(round(cycles / freq_hz / DT))
    t = np.arange(len(signal))[-n:] * DT
    basis = np.column_stack([np.cos(2 * np.pi * freq_hz * t), np.sin(2 * np.pi * freq_hz * t)])
    (a, b), *_ = np.linalg.lstsq(basis, signal[-n:], rcond=None)
    return complex(a, -b)


@pytest.mark.parametrize('freq_hz', [3.0, 7.1, 20.0])
def test_the_ground_response_is_the_steady_state_of_a_sine_record(freq_hz):
    """|x / E| of the loop's matrices against a lockstep run of the study's test on a sine
    record (7.1 Hz: the reference structure's resonance at alpha 1), within 0.5 %. The
    builder's ground term is the step average of the linearly interpolated record, on a
    sine a gain of sinc(f dt)^2 over the samples E[k] the run records."""
    params = study(duration_s=6.0)
    n = int(6.0 / DT) + 8
    ground = 0.2 * np.sin(2 * np.pi * freq_hz * np.arange(n) * DT)
    run = simulate(params, record=GroundMotion(DT, ground, 'sine', 'test'))
    assert run.stable
    rig = run.rigs['']
    force = -(1.0 + params['alpha']) * params['mass_kg'] * run.ground_acceleration_m_s2
    measured = abs(steady_amplitude(rig.displacement_m, freq_hz)
                   / steady_amplitude(force, freq_hz))
    response, radius = LoopModel(params).ground_response(params['alpha'], [freq_hz])
    assert radius < 1.0
    assert make_predictor(params).step_average
    step_average = np.sinc(freq_hz * DT) ** 2
    assert abs(response[0]) * step_average == pytest.approx(measured, rel=5e-3)


def test_a_test_that_is_the_reference_delayed_is_predicted_exact():
    """At alpha = 0 the delay rig applies the ground force late by tau and nothing else:
    the test is the reference delayed, the predicted error (the lag removed) vanishes; with
    the delayed acceleration fed back at alpha 0.5 it is above 10 %: the study's
    uncompensated test loses its accuracy as alpha grows (paper Sec. 5.1)."""
    params = parameters.resolve({'rig_model': 'delay', 'predictor': 'none', 'tau_s': 0.01,
                                 'alpha': 0.0})
    exact, uncompensated = predicted_error(params, [0.0, 0.5])
    assert exact < 2e-3
    assert uncompensated > 0.1


def test_the_kanai_tajimi_spectrum_is_its_closed_form():
    """1 at 0 Hz; at the ground's own frequency (1 + 4 z^2) / (4 z^2)."""
    wg, zg = 15.6, 0.6
    assert kanai_tajimi([0.0])[0] == pytest.approx(1.0)
    assert kanai_tajimi([wg / (2 * math.pi)])[0] == pytest.approx(
        (1 + 4 * zg ** 2) / (4 * zg ** 2))


def test_a_records_spectrum_holds_its_variance_and_its_tones():
    """Welch's density of a record integrates to its mean square (Parseval: white noise of
    0.5 m/s^2 rms plus a 0.3 m/s^2 tone at 4 Hz, 0.295 within 5 %), and the tone stands out
    at its frequency; bad records are refused with a one-line error naming the record."""
    rng = np.random.default_rng(3)
    n = 15000
    t = np.arange(n) * DT
    a = 0.5 * rng.standard_normal(n) + 0.3 * np.sin(2 * np.pi * 4.0 * t)
    spec = GroundSpectrum.of_record(a, DT, 'noise and tone')
    df = spec.freq_hz[1] - spec.freq_hz[0]
    assert df == pytest.approx(0.2)
    assert np.sum(spec.density) * df == pytest.approx(0.25 + 0.045, rel=0.05)
    assert spec(4.0) > 20 * np.median(spec.density)
    assert spec(0.0) == spec.density[0] and spec(1e3) == spec.density[-1]
    for bad in (np.zeros(500), np.ones(10), np.r_[np.ones(100), np.nan]):
        with pytest.raises(SeftError, match=r'^ground spectrum of quake: expected at least '
                                            r'64 finite samples, not all zero \(got \d+\)$'):
            GroundSpectrum.of_record(bad, DT, 'quake')


def test_a_narrow_band_ground_weighs_the_error_at_its_frequency():
    """A ground with all its power in 2.9-3.1 Hz: the predicted error is the test's
    amplitude error there, the phase taken by the lag (|H_test| / |H_ref| - 1 of the
    uncompensated delay rig at alpha 0.5, tau 10 ms, from the loop's own response, within
    2 %); a record's spectrum weighs the band the test is shaken in, where the Kanai-Tajimi
    one weighs every frequency (measured 0.52 % against 31 %)."""
    params = parameters.resolve({'rig_model': 'delay', 'predictor': 'none', 'tau_s': 0.01,
                                 'alpha': 0.5})
    f = np.linspace(0.0, 250.0, 5001)
    spec = GroundSpectrum(f, np.where(np.abs(f - 3.0) <= 0.1, 1.0, 0.0), 'band')
    banded, = predicted_error(params, [0.5], spectrum=spec)
    m, c, k = (params[key] for key in ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'))
    w = 2 * np.pi * 3.0
    h_test, _ = LoopModel(params).ground_response(0.5, [3.0])
    h_ref = 1.0 / (k - 1.5 * m * w * w + 1j * w * c)
    assert banded == pytest.approx(abs(abs(h_test[0]) / abs(h_ref) - 1.0), rel=0.02)
    broad, = predicted_error(params, [0.5])
    assert broad > 10 * banded


@pytest.fixture(scope='module')
def valve_3_stage():
    """The 10 Hz, 5 % specimen on the three-stage-valve actuator of seft_plant_sim, its
    20 s identification run identified (the lab's path), and the design."""
    from seft_ros.analysis.rig_identification import identify_rigs
    from seft_ros.cli.api import build_runs
    mass = 40.0
    k = mass * (2 * math.pi * 10.0) ** 2
    specimen = {'mass_kg': mass, 'stiffness_N_per_m': k,
                'damping_N_s_per_m': 2 * 0.05 * math.sqrt(k * mass)}
    base = dict(specimen, rig_model='actuator', actuator_family='valve_3_stage')
    ident_run, = build_runs(overrides=dict(base, predictor='none', excitation='noise',
                                           excitation_input='valve_command',
                                           duration_s=20.0, alpha=0.0))
    ident, = identify_rigs(simulate(ident_run))
    return base, ident.plant.model, ident.design


def test_the_design_chooses_the_inverse_by_the_predicted_test_error(valve_3_stage):
    """The design takes the shortest inverse within the band error when its test is predicted
    within the goal, else a longer one predicted within it (issue 38 target 3): the test errs
    below 1 % in every signal, and an inverse passed over is predicted beyond the goal and
    runs worse. Which of the two the identification gives rides on the host's rounding: the
    identified order and the design move with the CPU's BLAS. Sessions 26-33: order 7,
    3 steps, the shortest, predicted within 0.07 %, run 0.06 / 0.70 / 0.83 % x / a / f at
    alpha 0.5. 2026-12-01's host: order 8, the shortest 4 steps predicted at 2.4 % and run
    at 2.66 / 3.47 / 2.74 %, the design's 11 steps predicted at 0.17 % and run at 0.15 /
    0.48 / 0.55 %. (Session 25: 11 steps for a 4-step inverse's closed-loop pole beside the
    reference structure, 2.66 %; session 26 balanced the loop's frequency response,
    seft_msgs_py.plant.schur_response.)"""
    base, plant, design = valve_3_stage
    assert max(design.predicted_error.values()) <= PREDICTED_ERROR_GOAL
    shortest = design.shortest_loop_delay_steps
    assert 2 <= shortest <= design.loop_delay_steps

    written = dict(design.parameters(),
                   force_controller_tf=json.dumps(design.controller_mapping()))

    def run_params(delay_steps):
        return parameters.resolve({**base, **written, 'plant_model': plant.to_json(),
                                   'predictor': 'model', 'alpha': 0.5, 'duration_s': 6.0,
                                   'amplitude_N': 150.0,
                                   'predictor_loop_delay_steps': delay_steps})

    def errors(delay_steps):
        cmp = compare_run(simulate(run_params(delay_steps)))
        return [cmp.signal(s).nrms for s in SIGNALS]
    chosen = errors(design.loop_delay_steps)
    assert max(chosen) < 0.01, chosen
    if shortest != design.loop_delay_steps:
        passed_over = predicted_error(run_params(shortest), sorted(design.predicted_error))
        assert max(passed_over) > PREDICTED_ERROR_GOAL, passed_over
        ran = errors(shortest)
        assert ran[0] > 2 * chosen[0], (ran, chosen)
