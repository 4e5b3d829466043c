"""Metrics against signals with a known lag, scale and spectrum: per rig (the study's test)
and per degree of freedom (structure tests, whose runs here are the reference itself, scaled
or delayed by known amounts, or a run on the delay rig compared within a stated tolerance)."""

import json
import math

import numpy as np
import pytest
from scipy import signal as sps

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.metrics import (
    best_runs,
    compare_run,
    dof_signals,
    estimate_lag,
    high_frequency_fraction,
    json_safe,
    nrms_error,
    peak,
    peak_ratio,
    shift,
    summary_entry,
)
from seft_ros.analysis.reference import reference_response, run_reference
from seft_ros.analysis.rundata import RigData, RunData
from seft_ros.core.experiment import simulate as simulate_structure
from seft_ros.core.ground_motion import prepared_record
from seft_ros.core.structure import parse_structure

# The reference rig (paper Sec. 3.1).
M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002


def _band_limited(t, seed=1, n_tones=40, f_max=15.0):
    """A random sum of sines in 0.5-f_max Hz, evaluated exactly at any instants t [s]."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.5, f_max, n_tones)
    phase = rng.uniform(0, 2 * np.pi, n_tones)
    amp = rng.normal(size=n_tones)
    return np.sum(amp[:, None] * np.sin(2 * np.pi * f[:, None] * t[None, :] + phase[:, None]),
                  axis=0)


@pytest.fixture(scope='module')
def ground_motion():
    """A 20 s synthetic accelerogram: band-passed (0.5-15 Hz) noise, ramped and decaying,
    scaled so that the peak of m*xg'' is 1000 N (the reference study's amplitude)."""
    n = 10000
    t = np.arange(n) * DT
    b, a = sps.butter(4, [0.5, 15.0], btype='band', fs=1 / DT)
    ag = sps.lfilter(b, a, np.random.default_rng(7).normal(size=n))
    ag *= np.minimum(1.0, t / 2.0) * np.exp(-np.maximum(0.0, t - 8.0) / 4.0)
    return ag * 1000.0 / M / np.max(np.abs(ag))


def _params(alpha):
    return {'alpha': alpha, 'dt': DT, 'mass_kg': M, 'damping_N_s_per_m': C,
            'stiffness_N_per_m': K, 'rig_model': 'delay', 'predictor': 'none',
            'record': 'default', 'tau_s': 0.01}


def _reference(alpha, ag):
    return reference_response(alpha=alpha, mass_kg=M, damping_N_s_per_m=C,
                              stiffness_N_per_m=K, dt=DT, ground_acceleration_m_s2=ag)


def _delayed(x, d):
    """x delayed by d whole samples; the response starts at rest, so zeros are exact."""
    return np.concatenate([np.zeros(d), x[:-d]])


def _run_from(ref, ag, alpha, d, **kwargs):
    return RunData.one_rig(params=_params(alpha), time_s=np.arange(ag.shape[0]) * DT,
                   ground_acceleration_m_s2=ag, reference_force_N=ref.force_N,
                   measured_force_N=_delayed(ref.force_N, d),
                   displacement_m=_delayed(ref.displacement_m, d),
                   velocity_m_s=_delayed(ref.velocity_m_s, d),
                   acceleration_m_s2=_delayed(ref.acceleration_m_s2, d),
                   record_name='synthetic', source='test', **kwargs)


# -- estimate_lag -------------------------------------------------------------------------

@pytest.mark.parametrize('lag', [0.0073, -0.0073, 0.0100, 0.0411])
def test_lag_of_band_limited_signal(lag):
    t = np.arange(5000) * DT
    reference = _band_limited(t)
    test = _band_limited(t - lag)  # the test lags the reference by `lag`
    # 7.3 ms at dt = 2 ms is 3.65 samples: the parabolic refinement recovers it to 0.2 ms
    # (measured: 8 us).
    assert estimate_lag(test, reference, DT) == pytest.approx(lag, abs=2e-4)


def test_lag_is_clamped_to_the_search_bound():
    t = np.arange(2000) * DT
    pulse = np.exp(-((t - 1.5) / 0.1) ** 2)
    late = np.exp(-((t - 1.8) / 0.1) ** 2)  # 0.3 s late, beyond max_lag_s
    assert estimate_lag(late, pulse, DT, max_lag_s=0.1) == pytest.approx(0.1)
    assert estimate_lag(pulse, late, DT, max_lag_s=0.1) == pytest.approx(-0.1)
    assert estimate_lag(late, pulse, DT, max_lag_s=0.5) == pytest.approx(0.3, abs=2e-4)


def test_lag_undefined_cases_and_nan():
    assert estimate_lag(np.zeros(100), np.ones(100), DT) == 0.0
    assert estimate_lag([1.0], [1.0], DT) == 0.0
    t = np.arange(3000) * DT
    test = _band_limited(t - 0.006)
    test[-50:] = np.nan  # an aborted tail is ignored
    assert estimate_lag(test, _band_limited(t), DT) == pytest.approx(0.006, abs=2e-4)


@pytest.mark.parametrize('kwargs, match', [
    ({'dt': 0.0}, 'parameter dt='), ({'dt': float('nan')}, 'parameter dt='),
    ({'max_lag_s': -1.0}, 'parameter max_lag_s='), ({'test': np.zeros((2, 2))}, 'test: '),
])
def test_lag_errors(kwargs, match):
    args = {'test': np.zeros(10), 'reference': np.zeros(10), 'dt': DT, **kwargs}
    with pytest.raises(ParameterError, match=match):
        estimate_lag(**args)


# -- shift --------------------------------------------------------------------------------

def test_shift_removes_sub_sample_delay():
    t = np.arange(5000) * DT
    reference = _band_limited(t)
    test = _band_limited(t - 0.0073)
    aligned = shift(test, 0.0073, DT)
    assert np.isnan(aligned[-4:]).all() and np.isfinite(aligned[:-4]).all()
    assert nrms_error(aligned, reference) < 1e-3
    assert nrms_error(shift(test, estimate_lag(test, reference, DT), DT), reference) < 1e-3
    assert nrms_error(test, reference) > 0.1  # the delay matters before the shift


def test_shift_whole_samples_is_exact():
    x = np.arange(10.0)
    np.testing.assert_array_equal(shift(x, 3 * DT, DT)[:7], x[3:])
    assert np.isnan(shift(x, 3 * DT, DT)[7:]).all()
    np.testing.assert_array_equal(shift(x, -2 * DT, DT)[2:], x[:8])
    assert np.isnan(shift(x, -2 * DT, DT)[:2]).all()


def test_shift_poisons_samples_next_to_non_finite_input():
    t = np.arange(400) * DT
    x = np.sin(2 * np.pi * 3 * t)
    x[200] = np.nan
    y = shift(x, 0.5 * DT, DT)
    assert np.isnan(y[197:203]).all()
    assert np.allclose(y[:190], np.sin(2 * np.pi * 3 * (t[:190] + 0.5 * DT)), atol=1e-5)


def test_shift_errors():
    with pytest.raises(ParameterError, match='parameter lag_s='):
        shift(np.zeros(5), float('inf'), DT)
    with pytest.raises(ParameterError, match='parameter dt='):
        shift(np.zeros(5), 0.001, -DT)


# -- nrms, peaks --------------------------------------------------------------------------

def test_nrms_of_scaled_signal():
    reference = _band_limited(np.arange(2000) * DT)
    assert nrms_error(1.1 * reference, reference) == pytest.approx(0.1, rel=1e-12)
    assert nrms_error(np.zeros_like(reference), reference) == pytest.approx(1.0)
    test = 1.1 * reference
    test[::7] = np.nan  # excluded samples do not change a uniform scale error
    assert nrms_error(test, reference) == pytest.approx(0.1, rel=1e-12)


def test_nrms_undefined_and_errors():
    assert math.isnan(nrms_error(np.ones(5), np.zeros(5)))
    assert math.isnan(nrms_error(np.full(5, np.nan), np.ones(5)))
    with pytest.raises(ParameterError, match='expected the same'):
        nrms_error(np.ones(5), np.ones(6))


def test_peak_and_ratio():
    assert peak([1.0, -3.0, np.nan, 2.0]) == 3.0
    assert peak([1.0, -np.inf]) == math.inf
    assert math.isnan(peak([]))
    assert peak_ratio([0.5, -1.5], [3.0, -1.0]) == 0.5
    assert math.isnan(peak_ratio([1.0], [0.0]))


# -- high-frequency fraction --------------------------------------------------------------

def test_high_frequency_fraction_of_two_tones():
    # Powers of a1 sin(2 pi 5 t) and a2 sin(2 pi 40 t) are a1^2/2 and a2^2/2, so the fraction
    # above 20 Hz is a2^2 / (a1^2 + a2^2) = 0.2; Welch's Hann window leaks < 0.1 %.
    t = np.arange(10000) * DT
    x = 1.0 * np.sin(2 * np.pi * 5 * t) + 0.5 * np.sin(2 * np.pi * 40 * t + 0.3)
    assert high_frequency_fraction(x, DT) == pytest.approx(0.2, abs=1e-3)
    assert high_frequency_fraction(x, DT, cutoff_hz=50.0) == pytest.approx(0.0, abs=1e-3)
    assert high_frequency_fraction(x, DT, cutoff_hz=2.0) == pytest.approx(1.0, abs=1e-3)


def test_high_frequency_fraction_edge_cases():
    assert math.isnan(high_frequency_fraction(np.ones(1000), DT))
    assert math.isnan(high_frequency_fraction(np.ones(5), DT))
    x = np.sin(2 * np.pi * 40 * np.arange(1000) * DT)
    x[600] = np.inf  # only the finite head is analysed
    assert high_frequency_fraction(x, DT) == pytest.approx(1.0, abs=1e-3)
    with pytest.raises(ParameterError, match='parameter cutoff_hz='):
        high_frequency_fraction(x, DT, cutoff_hz=250.0)


# -- compare_run, summary_entry -----------------------------------------------------------

@pytest.mark.parametrize('alpha', [0.0, 1.0])
def test_compare_run_of_the_delayed_reference(ground_motion, alpha):
    ref = _reference(alpha, ground_motion)
    run = _run_from(ref, ground_motion, alpha, d=5)
    comparison = compare_run(run)
    for name in ('displacement', 'force', 'acceleration'):
        c = comparison.signal(name)
        assert c.lag_s == pytest.approx(5 * DT, abs=1e-5)
        assert c.nrms < 1e-4  # measured: 2e-6 or less
        assert c.peak_ratio == pytest.approx(1.0, rel=1e-12)
        assert c.peak_reference == pytest.approx(np.max(np.abs(ref.signal(name))))
    # A longer reference (of the whole record) is cut to the run.
    short = _run_from(ref, ground_motion, alpha, d=5)
    for field in ('time_s', 'ground_acceleration_m_s2', 'reference_force_N', 'measured_force_N',
                  'displacement_m', 'velocity_m_s', 'acceleration_m_s2'):
        setattr(short, field, getattr(short, field)[:6000])
    cut = compare_run(short, ref)
    for name in ('displacement', 'force', 'acceleration'):      # the rig's reference: ref's
        np.testing.assert_array_equal(cut.reference.signal(name), ref.signal(name))
    assert cut.displacement.lag_s == pytest.approx(5 * DT, abs=1e-5)
    with pytest.raises(ParameterError, match='expected at least as many'):
        compare_run(run, compare_run(short).reference)


def test_compare_run_of_scaled_test(ground_motion):
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    run.displacement_m = 1.1 * run.displacement_m
    comparison = compare_run(run, ref)
    assert comparison.displacement.nrms == pytest.approx(0.1, rel=1e-4)
    assert comparison.displacement.peak_ratio == pytest.approx(1.1, rel=1e-12)
    assert comparison.force.nrms < 1e-4


def test_common_lag_shows_what_a_signal_of_its_own_lag_hides(ground_motion):
    """The acceleration lags 5 samples more than the displacement: aligned by its own lag it
    looks perfect; aligned by the displacement's (common) lag it does not; unshifted, every
    signal carries the delay."""
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    run.acceleration_m_s2 = _delayed(ref.acceleration_m_s2, 10)
    c = compare_run(run, ref)
    assert c.displacement.lag_s == pytest.approx(5 * DT, abs=1e-5)
    assert c.acceleration.lag_s == pytest.approx(10 * DT, abs=1e-5)
    assert c.acceleration.nrms < 1e-4
    assert c.acceleration.nrms_common_lag > 0.1
    assert c.displacement.nrms_common_lag == c.displacement.nrms
    assert c.force.nrms_common_lag < 1e-4
    for name in ('displacement', 'force', 'acceleration'):
        assert c.signal(name).nrms_unshifted > 0.1
        assert c.signal(name).nrms_unshifted == pytest.approx(
            nrms_error(np.asarray(run.signal(name)), ref.signal(name)[:run.n_steps]))


def test_compare_run_criteria_are_those_of_the_recorded_signals(ground_motion):
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    c = compare_run(run, ref).criteria
    f_r, f_m = np.asarray(run.reference_force_N), np.asarray(run.measured_force_N)
    x, x_ref = np.asarray(run.displacement_m), ref.displacement_m[:run.n_steps]
    assert c.j1_ms == pytest.approx(10.0)
    assert c.j2_pct == pytest.approx(100 * np.std(f_m - f_r) / np.std(f_r), rel=1e-12)
    assert c.j3_pct == pytest.approx(100 * np.max(np.abs(f_m - f_r)) / np.max(np.abs(f_r)),
                                     rel=1e-12)
    assert c.j4_pct == pytest.approx(100 * np.std(x - x_ref) / np.std(x_ref), rel=1e-12)
    assert c.j5_pct == pytest.approx(100 * np.max(np.abs(x - x_ref)) / np.max(np.abs(x_ref)),
                                     rel=1e-12)


def _aborted_run(ground_motion):
    """An unstable run: a growing 30 Hz oscillation, stopped at 8 s with inf/NaN samples."""
    ref = _reference(1.5, ground_motion)
    n = 4000
    run = _run_from(ref, ground_motion, 1.5, d=5, stable=False, unstable_at_s=n * DT,
                    abort_reason='stroke limit exceeded')
    t = np.arange(n) * DT
    growth = 1e-4 * np.exp(t) * np.sin(2 * np.pi * 30 * t)
    for field in ('time_s', 'ground_acceleration_m_s2', 'reference_force_N', 'velocity_m_s'):
        setattr(run, field, getattr(run, field)[:n])
    run.displacement_m = run.displacement_m[:n] + growth
    run.measured_force_N = run.measured_force_N[:n] + K * growth
    run.acceleration_m_s2 = run.acceleration_m_s2[:n] - (2 * np.pi * 30) ** 2 * growth
    run.measured_force_N[-1] = np.inf
    run.acceleration_m_s2[-3:] = np.nan
    return run


def test_summary_entry_keys_and_values(ground_motion):
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    entry = summary_entry(run, compare_run(run))
    study_keys = ['alpha', 'rig', 'predictor', 'record', 'stable', 'unstable_at_s', 'lag_s',
                  'nrms', 'nrms_common_lag', 'nrms_unshifted', 'criteria', 'peak_ratio',
                  'high_frequency_force_fraction', 'high_frequency_force_fraction_reference',
                  'high_frequency_cutoff_hz', 'abort_reason', 'mode', 'wall_s', 'rig_contract']
    # the study's keys first, in their order; then the sections every run has
    assert list(entry) == study_keys + ['warnings', 'sensor_range', 'valve_saturation',
                                        'flags', 'verdict',
                                        'abort_node', 'n_steps', 'structure', 'worst_nrms',
                                        'dofs', 'links', 'rigs']
    assert entry['warnings'] == [] and entry['flags'] == [] and entry['verdict'] == 'stable'
    assert entry['rig_contract'] is None           # a RunData not read from a bag
    assert list(entry['criteria']) == ['J1', 'J2', 'J3', 'J4', 'J5']
    assert entry['criteria']['J1'] == pytest.approx(10.0)  # the 5-sample delay, in ms
    assert entry['nrms_common_lag']['force'] < 1e-4
    assert entry['mode'] == 'lockstep' and entry['wall_s'] is None
    assert entry['abort_reason'] is None
    assert entry['high_frequency_cutoff_hz'] == 20.0
    # The delayed reference: the same spectrum as the reference force.
    assert entry['high_frequency_force_fraction'] == pytest.approx(
        entry['high_frequency_force_fraction_reference'], rel=0.05)
    assert list(entry['nrms']) == ['displacement', 'acceleration', 'force']
    assert list(entry['peak_ratio']) == ['displacement', 'acceleration', 'force']
    assert (entry['alpha'], entry['rig'], entry['predictor'], entry['record']) == \
        (0.5, 'delay', 'none', 'synthetic')
    assert entry['stable'] is True and entry['unstable_at_s'] is None
    assert entry['lag_s'] == pytest.approx(0.01, abs=1e-5)
    assert json.loads(json.dumps(entry, allow_nan=False)) == entry


def test_a_study_run_is_its_one_dof_structure(ground_motion):
    """The study's test per degree of freedom: one DOF, 'specimen', on the rig '' of the root
    namespace; its displacement, acceleration and interface force are the rig's comparisons,
    its floor acceleration is x'' + xg''; its one link is the displacement."""
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    c = compare_run(run)
    (dof,) = c.dofs
    assert (dof.dof, dof.rig) == ('specimen', '')
    assert (dof.displacement, dof.acceleration, dof.interface_force) == \
        (c.displacement, c.acceleration, c.force)
    # the floor acceleration: the test's x'' + xg'' (the ground not delayed) against the
    # reference's, over the samples both have
    floor = dof.floor_acceleration
    assert floor.peak_reference == pytest.approx(
        np.max(np.abs(ref.acceleration_m_s2 + ground_motion)), rel=1e-12)
    assert floor.peak_test == pytest.approx(
        np.max(np.abs(_delayed(ref.acceleration_m_s2, 5) + ground_motion)), rel=1e-12)
    assert 0 < floor.nrms < 0.5
    # and with the displacement's lag removed (the common lag; before: NaN at every DOF of a
    # structure): the ground is not delayed, so the floor acceleration has a lag of its own
    assert c.displacement.lag_s == pytest.approx(5 * DT, abs=1e-4)
    assert floor.lag_s == pytest.approx(0.01174, abs=1e-5)
    assert floor.nrms_common_lag == pytest.approx(nrms_error(
        shift(_delayed(ref.acceleration_m_s2, 5) + ground_motion, c.displacement.lag_s, DT),
        ref.acceleration_m_s2 + ground_motion), rel=1e-12)
    assert floor.nrms_common_lag > floor.nrms
    (link,) = c.links
    assert link.name == 'specimen-ground'
    assert link.drift.nrms == pytest.approx(c.displacement.nrms, rel=1e-12)
    assert c.worst_nrms('displacement') == c.displacement.nrms
    entry = summary_entry(run, c)
    assert entry['structure'] == {'dofs': ['specimen'], 'physical': {'specimen': ''},
                                  'builders': 'central'}
    assert entry['n_steps'] == run.n_steps and entry['abort_node'] is None
    rig = entry['rigs']['']
    assert (rig['dof'], rig['rig_model'], rig['specimen_model']) == \
        ('specimen', 'delay', 'linear')
    for key in ('alpha', 'lag_s', 'nrms', 'nrms_common_lag', 'nrms_unshifted', 'peak_ratio',
                'criteria', 'high_frequency_force_fraction'):
        assert rig[key] == entry[key], key
    assert entry['dofs']['specimen']['displacement']['nrms'] == entry['nrms']['displacement']
    assert entry['dofs']['specimen']['interface_force']['nrms'] == entry['nrms']['force']
    assert entry['worst_nrms']['displacement'] == entry['nrms']['displacement']


def test_summary_entry_of_a_realtime_run_has_the_timing_block(ground_motion):
    run = _run_from(_reference(0.5, ground_motion), ground_motion, 0.5, d=5)
    timing = {'loop_latency_ms': {'p50': 1.2, 'p99': 4.0, 'max': 6.5},
              'period_jitter_ms': {'p50': 0.1, 'p99': 0.9, 'max': 2.0},
              'missed_deadline_fraction': 0.004, 'stale_command_fraction': 0.01}
    run.params['mode'] = 'realtime'
    run.extra.update(wall_s=12.5, timing=timing)
    entry = summary_entry(run, compare_run(run))
    assert (entry['mode'], entry['wall_s'], entry['timing']) == ('realtime', 12.5, timing)


def test_summary_entry_of_aborted_run_is_valid_json(ground_motion):
    run = _aborted_run(ground_motion)
    comparison = compare_run(run)
    assert comparison.reference.n_steps == run.n_steps
    assert comparison.force.peak_test == math.inf
    entry = summary_entry(run, comparison)
    text = json.dumps(entry, allow_nan=False)
    back = json.loads(text)
    assert back['stable'] is False
    assert back['unstable_at_s'] == pytest.approx(8.0)
    assert back['peak_ratio']['force'] is None  # inf -> null
    assert isinstance(back['nrms']['displacement'], float)
    assert -0.1 <= back['lag_s'] <= 0.1  # possibly meaningless, but clamped


def test_json_safe():
    value = {'a': np.float64('nan'), 'b': [np.inf, np.int64(3), np.bool_(True)], 'c': 'x'}
    assert json_safe(value) == {'a': None, 'b': [None, 3, True], 'c': 'x'}


# -- high-frequency cutoff and best_runs -------------------------------------------------
def test_compare_run_high_frequency_cutoff(ground_motion):
    """A 45 Hz tone added to the force counts above a 20 Hz cutoff, not above 60 Hz."""
    ref = _reference(0.5, ground_motion)
    run = _run_from(ref, ground_motion, 0.5, d=5)
    t = run.time_s
    run.measured_force_N = run.measured_force_N + 200.0 * np.sin(2 * np.pi * 45.0 * t)
    low = compare_run(run, ref)
    high = compare_run(run, ref, high_frequency_cutoff_hz=60.0)
    assert low.high_frequency_cutoff_hz == 20.0 and high.high_frequency_cutoff_hz == 60.0
    assert low.high_frequency_force_fraction > 0.1
    assert high.high_frequency_force_fraction < 0.01
    entry = summary_entry(run, high)
    assert entry['high_frequency_cutoff_hz'] == 60.0
    assert entry['high_frequency_force_fraction_reference'] < 0.01
    with pytest.raises(ParameterError, match='cutoff_hz=250'):
        compare_run(run, ref, high_frequency_cutoff_hz=250.0)  # Nyquist of dt = 2 ms


def _entry(alpha, predictor, nrms_x, stable=True, rig='delay', record='r'):
    return {'alpha': alpha, 'rig': rig, 'predictor': predictor, 'record': record,
            'stable': stable, 'nrms': {'displacement': nrms_x}}


def test_best_runs_picks_stable_compensated_with_smallest_displacement_nrms():
    entries = [
        _entry(0.5, 'none', 0.01),                 # uncompensated: never picked
        _entry(0.5, 'polynomial', 0.05),
        _entry(0.5, 'model', 0.03),
        _entry(0.5, 'lms', 0.001, stable=False),   # aborted: never picked
        _entry(1.0, 'polynomial', None),           # NRMS undefined (null in JSON)
        _entry(1.0, 'model', 0.20),
        _entry(1.0, 'lms', 0.20),                  # tie: the first one wins
        _entry(1.0, 'model', 0.02, rig='servohydraulic'),
        _entry(1.5, 'none', 0.5),                  # no compensated run: absent
        _entry(2.0, 'model', math.nan),            # NaN: not a candidate
    ]
    best = best_runs(entries)
    assert list(best) == [(0.5, 'delay'), (1.0, 'delay'), (1.0, 'servohydraulic')]
    assert best[(0.5, 'delay')] is entries[2]
    assert best[(1.0, 'delay')] is entries[5]
    assert best[(1.0, 'servohydraulic')] is entries[7]
    assert best_runs([]) == {}
    with pytest.raises(ParameterError, match='expected a dict'):
        best_runs(['x'])


# -- structure tests, per degree of freedom --------------------------------------------------

#: A two-story shear building, the first story tested on rig 'lab', the second computational.
TWO_STORY = {'dofs': ['story_1', 'story_2'], 'physical': {'story_1': 'lab'},
             'story_masses_kg': [M, M], 'story_stiffnesses_N_per_m': [K, K],
             'story_damping_N_s_per_m': [C, 133.4]}


def _structure_params(**over):
    s = parse_structure(TWO_STORY, rigs={'lab': {'rig_model': 'delay'}})
    return parameters.resolve(dict({'structure': s.to_json(), 'predictor': 'model',
                                    'duration_s': 6.0}, **over))


def _structure_run_from_reference(params, scale=1.0, delay_steps=0):
    """A RunData whose every signal is the reference's, times `scale`, `delay_steps` late
    (zeros before), the computational state's last sample NaN as the builder records."""
    ag = prepared_record(params).acceleration_m_s2
    n = ag.shape[0]
    stub = RunData(params=params, rigs={}, time_s=np.arange(n) * params['dt'],
                   ground_acceleration_m_s2=ag)
    ref = run_reference(stub)

    def test(x):
        out = np.zeros_like(x)
        out[delay_steps:] = scale * x[:n - delay_steps]
        return out
    force = ref.interface_force_N[:, 0]
    rig = RigData(params=dict(params), reference_force_N=test(force),
                  measured_force_N=test(force),
                  displacement_m=test(ref.displacement_m[:, 0]),
                  velocity_m_s=test(ref.velocity_m_s[:, 0]),
                  acceleration_m_s2=test(ref.acceleration_m_s2[:, 0]), valve_command_V=None)
    state = {f'story_2/{q}': np.append(test(a[:, 1])[:-1], np.nan) for q, a in (
        ('displacement_m', ref.displacement_m), ('velocity_m_s', ref.velocity_m_s),
        ('acceleration_m_s2', ref.acceleration_m_s2))}
    return RunData(params=params, rigs={'lab': rig}, time_s=stub.time_s,
                   ground_acceleration_m_s2=ag, computational=state)


def test_the_structure_reference_itself_compares_perfectly():
    c = compare_run(_structure_run_from_reference(_structure_params()))
    assert [d.dof for d in c.dofs] == ['story_1', 'story_2']
    assert [d.rig for d in c.dofs] == ['lab', None]
    for d in c.dofs:
        assert d.displacement.nrms == pytest.approx(0.0, abs=1e-12)
        assert d.floor_acceleration.peak_ratio == pytest.approx(1.0, rel=1e-12)
    assert c.dof('story_1').interface_force.nrms == pytest.approx(0.0, abs=1e-12)
    assert c.dof('story_2').interface_force is None
    assert [lk.name for lk in c.links] == ['story_1', 'story_2']
    assert c.rigs['lab'].criteria.j4_pct == pytest.approx(0.0, abs=1e-9)
    # one rig: the comparison reads as the rig's, whose DOF is story_1
    assert c.displacement is c.dof('story_1').displacement
    with pytest.raises(KeyError):
        c.dof('story_3')


def test_scaled_and_delayed_structure_signals_give_known_errors():
    params = _structure_params()
    scaled = compare_run(_structure_run_from_reference(params, scale=1.02))
    for d in scaled.dofs:
        # a 2 % gain: NRMS 2 %, peaks 1.02, no lag
        assert d.displacement.nrms == pytest.approx(0.02, rel=1e-6)
        assert d.displacement.peak_ratio == pytest.approx(1.02, rel=1e-9)
        assert d.displacement.lag_s == pytest.approx(0.0, abs=1e-12)
    # the relative displacement of both floors scaled: the drift too
    assert scaled.links[1].drift.nrms == pytest.approx(0.02, rel=1e-6)
    # the floor acceleration is x'' + xg'': the ground is not scaled, so it is not 2 %
    assert 0.0 < scaled.dof('story_1').floor_acceleration.nrms < 0.02
    late = compare_run(_structure_run_from_reference(params, delay_steps=6))
    for d in late.dofs:
        # 12 ms late: the lag is found and removed (the first 6 samples are the loss)
        assert d.displacement.lag_s == pytest.approx(0.012, abs=1e-4)
        assert d.displacement.nrms < 1e-3
        assert d.displacement.nrms_unshifted > 0.1


def test_a_delay_rig_structure_run_follows_the_structure_and_its_entry_is_strict_json():
    run = simulate_structure(_structure_params())
    c = compare_run(run)
    for d in c.dofs:
        # the delay rig's force is exactly the command, delayed: the model compensator's
        # impulse matching leaves 0.1-0.2 % (substructure.py)
        assert d.displacement.nrms < 0.005, d.dof
        # held over each step, the force makes the sampled acceleration differ from the
        # reference's by about its change within a step (the study's SDOF on this rig:
        # 3.8-5.2 %); the computational story's, driven by the smooth motion, much less
        assert d.floor_acceleration.nrms < (0.06 if d.rig else 0.01), d.dof
    entry = summary_entry(run, c)
    back = json.loads(json.dumps(entry, allow_nan=False))
    assert back['structure'] == {'dofs': ['story_1', 'story_2'],
                                 'physical': {'story_1': 'lab'}, 'builders': 'central'}
    assert back['dofs']['story_2']['interface_force'] is None
    assert back['dofs']['story_2']['rig'] is None and back['dofs']['story_1']['rig'] == 'lab'
    assert back['worst_nrms']['displacement'] == pytest.approx(
        max(d.displacement.nrms for d in c.dofs))
    assert back['worst_nrms']['interface_force'] == pytest.approx(c.force.nrms)
    assert back['rigs']['lab']['rig_model'] == 'delay'
    assert set(back['rigs']['lab']['criteria']) == {'J1', 'J2', 'J3', 'J4', 'J5'}
    # one rig: the study's keys are the rig's
    assert back['rig'] == 'delay' and back['nrms'] == back['rigs']['lab']['nrms']
    assert back['alpha'] == 0.0                              # no rigid mass on story 1
    assert back['n_steps'] == run.n_steps


def test_a_run_of_several_rigs_has_the_study_keys_empty():
    from pathlib import Path

    from seft_ros.cli.config import load_config
    config = load_config(Path(__file__).parents[3] / 'config' / 'two_piers.yaml')
    run = simulate_structure(parameters.resolve(dict(config, predictor='model',
                                                     duration_s=1.0)))
    c = compare_run(run)
    assert list(c.rigs) == ['pier_a', 'pier_b']
    with pytest.raises(AttributeError, match='2 rigs'):
        c.displacement
    entry = summary_entry(run, c)
    assert entry['nrms'] == {'displacement': None, 'acceleration': None, 'force': None}
    assert entry['criteria'] == {key: None for key in ('J1', 'J2', 'J3', 'J4', 'J5')}
    assert entry['alpha'] is None and entry['rig'] is None and entry['lag_s'] is None
    assert set(entry['rigs']) == {'pier_a', 'pier_b'}
    for rig in ('pier_a', 'pier_b'):
        assert entry['rigs'][rig]['nrms']['displacement'] == pytest.approx(
            c.rigs[rig].displacement.nrms)
        assert entry['rigs'][rig]['nrms']['displacement'] < 0.01
    assert entry['worst_nrms']['displacement'] == pytest.approx(
        max(d.displacement.nrms for d in c.dofs))
    signals = dof_signals(run)
    assert set(signals) == {'pier_a', 'pier_b', 'deck'}
    np.testing.assert_array_equal(signals['pier_b']['interface_force'],
                                  run.rigs['pier_b'].measured_force_N)
    assert set(signals['deck']) == {'displacement', 'velocity', 'acceleration',
                                    'floor_acceleration'}


def test_structure_comparison_errors():
    params = _structure_params()
    run = _structure_run_from_reference(params)
    short = run_reference(RunData(params=params, rigs={}, time_s=run.time_s[:10],
                                  ground_acceleration_m_s2=run.ground_acceleration_m_s2[:10]))
    with pytest.raises(ParameterError, match='reference has 10 samples'):
        compare_run(run, short)
    with pytest.raises(ParameterError, match='give a structure test its StructureReference'):
        compare_run(run, reference_response(alpha=0.0, mass_kg=M, damping_N_s_per_m=C,
                                            stiffness_N_per_m=K, dt=DT,
                                            ground_acceleration_m_s2=run.ground_acceleration_m_s2))
    run.computational.clear()
    with pytest.raises(ParameterError, match="computational dof 'story_2'"):
        compare_run(run)
