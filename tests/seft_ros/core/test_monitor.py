"""Tests of the online instability monitor on synthetic signals with known spectra.

The expected numbers come from closed forms, not from the monitor's own output:

- the bands are 2nd-order Butterworth filters made by the bilinear transform with the cut-off
  pre-warped (``scipy.signal.butter(..., fs=...)``), so a sine of frequency ``f`` sampled at
  ``fs`` is passed with the gains (``w = tan(pi f / fs)``, ``wc = tan(pi f_c / fs)``)

      |H_lp| = 1 / sqrt(1 + (w / wc)^4),   |H_hp| = 1 / sqrt(1 + (wc / w)^4);

- in steady state the running mean square of a sine of amplitude ``A`` is ``A^2 / 2``, and
  after a sine is switched on it grows as ``(A^2 / 2) (1 - exp(-t / window))``;
- a sample-by-sample reference written with ``scipy.signal.lfilter`` (independent code).
"""

import math
import re

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_ros.core import experiment
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepare, synthetic_default
from seft_ros.core.monitor import InstabilityMonitor, monitor_cutoff_hz

DT = 0.002
FS = 1.0 / DT


def band_gains(f_hz, cutoff_hz=25.0, fs=FS):
    """(|H_lp|, |H_hp|) of the 2nd-order bilinear Butterworth pair at `f_hz`."""
    r = (math.tan(math.pi * f_hz / fs) / math.tan(math.pi * cutoff_hz / fs)) ** 4
    return 1.0 / math.sqrt(1.0 + r), 1.0 / math.sqrt(1.0 + 1.0 / r)


def steady_ratio(sines, *, ground_N=0.0, floor_N=50.0, cutoff_hz=25.0):
    """Closed-form steady ratio for a sum of sines ``[(amplitude, f_hz), ...]`` (frequencies
    far enough apart that the cross terms average out)."""
    ms_lf = ms_hf = 0.0
    for amp, f in sines:
        g_lf, g_hf = band_gains(f, cutoff_hz)
        ms_lf += (amp * g_lf) ** 2 / 2
        ms_hf += (amp * g_hf) ** 2 / 2
    return math.sqrt(ms_hf) / (math.sqrt(ms_lf) + 0.05 * ground_N + floor_N)


def feed(monitor, force, ground=None, dt=DT):
    """Feed the samples; return (index of the first trip or None, its message, ratios)."""
    ground = np.zeros_like(force) if ground is None else ground
    ratios = np.empty(force.shape[0])
    for k, (f, g) in enumerate(zip(force.tolist(), ground.tolist())):
        reason = monitor.update(f, g, k * dt)
        ratios[k] = monitor.ratio
        if reason is not None:
            return k, reason, ratios[:k + 1]
    return None, None, ratios


def sine(amp, f_hz, seconds, dt=DT, ramp_s=0.0):
    """A sine from t = 0, optionally faded in by a half cosine over `ramp_s` (a sine switched
    on abruptly has a broadband onset that the high band sees)."""
    t = np.arange(round(seconds / dt)) * dt
    fade = 0.5 - 0.5 * np.cos(np.pi * np.clip(t / ramp_s, 0, 1)) if ramp_s else 1.0
    return amp * fade * np.sin(2 * np.pi * f_hz * t)


def reference_ratio(force, ground, *, dt=DT, cutoff_hz=25.0, window_s=0.2, floor_N=50.0):
    """The docstring's ratio, vectorized with lfilter (independent of the per-sample code)."""
    fs = 1.0 / dt
    hf = signal.lfilter(*signal.butter(2, cutoff_hz, 'highpass', fs=fs), force)
    lf = signal.lfilter(*signal.butter(2, cutoff_hz, 'lowpass', fs=fs), force)
    beta = math.exp(-dt / window_s)
    ms_hf = signal.lfilter([1 - beta], [1, -beta], hf ** 2)
    ms_lf = signal.lfilter([1 - beta], [1, -beta], lf ** 2)
    scale = np.maximum.accumulate(np.abs(ground))
    return np.sqrt(ms_hf) / (np.sqrt(ms_lf) + 0.05 * scale + floor_N)


# -- the ratio, sample by sample and in steady state ---------------------------------------

@pytest.mark.parametrize('cutoff_hz, window_s, floor_N', [
    (25.0, 0.2, 50.0), (40.0, 0.05, 0.0), (10.0, 1.0, 200.0)])
def test_ratio_equals_the_vectorized_definition(cutoff_hz, window_s, floor_N):
    rng = np.random.Generator(np.random.PCG64(3))
    n = 3000
    force = (800 * np.sin(2 * np.pi * 1.7 * np.arange(n) * DT)
             + 60 * rng.standard_normal(n) + np.linspace(0, 300, n) * np.sin(0.8 * np.arange(n)))
    ground = 900 * np.sin(2 * np.pi * 0.6 * np.arange(n) * DT) * np.exp(-np.arange(n) / 800)
    mon = InstabilityMonitor(DT, cutoff_hz, window_s, threshold=0.0, floor_N=floor_N)
    k, reason, ratios = feed(mon, force, ground)
    assert k is None and reason is None                    # threshold 0: observe only
    np.testing.assert_allclose(ratios, reference_ratio(force, ground, cutoff_hz=cutoff_hz,
                                                       window_s=window_s, floor_N=floor_N),
                               rtol=1e-9, atol=0)
    # the ground-force scale is the largest |ground force| so far, not the latest
    assert mon.ground_force_scale_N == pytest.approx(np.max(np.abs(ground)), rel=1e-15)
    assert abs(ground[-1]) < 0.1 * mon.ground_force_scale_N


@pytest.mark.parametrize('sines, ground_N, floor_N, cutoff_hz', [
    ([(300.0, 100.0)], 0.0, 0.0, 25.0),            # high band only: |H_hp| / |H_lp|
    ([(300.0, 100.0)], 0.0, 50.0, 25.0),           # the floor in the denominator
    ([(300.0, 100.0)], 0.0, 200.0, 25.0),
    ([(300.0, 100.0)], 2000.0, 50.0, 25.0),        # 5 % of the ground force: + 100 N
    ([(300.0, 100.0)], 6000.0, 0.0, 25.0),         # ... + 300 N
    ([(1000.0, 2.0), (200.0, 37.0)], 0.0, 50.0, 25.0),   # a response plus the unstable mode
    ([(1000.0, 2.0), (200.0, 37.0)], 0.0, 50.0, 60.0),   # cut-off above the mode: ratio low
    ([(500.0, 30.0)], 0.0, 0.0, 20.0),             # 30 Hz above a 20 Hz cut-off ...
    ([(500.0, 30.0)], 0.0, 0.0, 45.0),             # ... and below a 45 Hz one
])
def test_steady_ratio_matches_the_closed_form(sines, ground_N, floor_N, cutoff_hz):
    force = sum(sine(a, f, 4.0) for a, f in sines)
    ground = np.zeros_like(force)
    ground[10] = -ground_N                         # seen once, kept as the scale
    mon = InstabilityMonitor(DT, cutoff_hz, threshold=0.0, floor_N=floor_N)
    ratios = feed(mon, force, ground)[2]
    expected = steady_ratio(sines, ground_N=ground_N, floor_N=floor_N, cutoff_hz=cutoff_hz)
    # the running mean square ripples at twice each frequency (+-19 % at 2 Hz with the 0.2 s
    # window): the mean over the last second (whole periods) is within 1.5 %
    assert np.mean(ratios[-500:]) == pytest.approx(expected, rel=0.015)
    assert mon.ground_force_scale_N == ground_N


def test_cutoff_moves_a_frequency_between_the_bands():
    force = sine(2000.0, 30.0, 3.0, ramp_s=1.0)
    below = InstabilityMonitor(DT, cutoff_hz=20.0, floor_N=20.0)
    above = InstabilityMonitor(DT, cutoff_hz=45.0, floor_N=20.0)
    assert feed(below, force)[0] is not None       # 30 Hz is high-frequency content: trips
    assert feed(above, force)[0] is None           # 30 Hz is response: does not
    assert above.ratio == pytest.approx(steady_ratio([(2000.0, 30.0)], floor_N=20.0,
                                                     cutoff_hz=45.0), rel=0.015)
    assert above.ratio < 0.5


# -- trips when it must, not otherwise -----------------------------------------------------

def test_trips_on_a_growing_oscillation_under_a_stable_response():
    """A 2 Hz, 1000 N response plus a 37 Hz mode growing from 5 N at 3 /s (the unstable
    loop's mode on the servohydraulic rig): it trips once the mode's high-band RMS exceeds
    the response band's RMS plus the floor, a window's lag after the crossing."""
    t = np.arange(round(4.0 / DT)) * DT
    mode = 5.0 * np.exp(3.0 * t)
    force = 1000 * np.sin(2 * np.pi * 2.0 * t) + mode * np.sin(2 * np.pi * 37.0 * t)
    k, reason, _ = feed(InstabilityMonitor(DT), force)
    assert k is not None
    # the time at which the mode's steady ratio would reach 1 (closed form, no lag)
    g_lf, g_hf = band_gains(37.0)
    lf_resp, _ = band_gains(2.0)
    # r_hf = A g_hf / sqrt2 ; r_lf ~ sqrt((1000 lf_resp)^2 + (A g_lf)^2) / sqrt2 ; solve = 1
    amps = np.linspace(1, 5e4, 200001)
    r = (amps * g_hf / math.sqrt(2)) / (np.hypot(1000 * lf_resp, amps * g_lf) / math.sqrt(2)
                                        + 50.0)
    a_cross = amps[np.argmax(r > 1.0)]
    t_cross = math.log(a_cross / 5.0) / 3.0
    # growing at 3 /s the running RMS lags by about the window (0.2 s): trips within it
    assert t_cross < k * DT < t_cross + 0.2
    assert re.fullmatch(
        rf'unstable at t={k * DT:.3f} s: high-frequency oscillation of the measured force, '
        r'RMS above the cut-off 1\.\d\d x the response band \(threshold 1\)', reason)


def test_stable_response_with_load_cell_noise_does_not_trip():
    """The default record's stable response with 5 N white load-cell noise (about 90 % of its
    power above 25 Hz): the floor keeps the quiet start from tripping."""
    rng = np.random.Generator(np.random.PCG64(11))
    n = round(20.0 / DT)
    t = np.arange(n) * DT
    envelope = np.clip(t / 2.0, 0, 1) * np.exp(-np.clip(t - 8.0, 0, None) / 3.0)
    force = envelope * 1500 * np.sin(2 * np.pi * 2.4 * t) + 5.0 * rng.standard_normal(n)
    k, _, ratios = feed(InstabilityMonitor(DT), force)
    assert k is None
    # the high band of white noise: sigma * sqrt(fraction of |H_hp|^2 over 0 .. fs/2)
    w, h = signal.freqz(*signal.butter(2, 25.0, 'highpass', fs=FS), worN=8192)
    hf_rms = 5.0 * math.sqrt(np.mean(np.abs(h) ** 2))
    assert 0.88 < (hf_rms / 5.0) ** 2 < 0.92        # the docstring's "about 90 %"
    assert np.max(ratios) < 2 * hf_rms / 50.0        # noise over the floor, at most
    # without the floor, the same noise alone trips at the quiet start ...
    noise_only = 5.0 * rng.standard_normal(n)
    k, _, _ = feed(InstabilityMonitor(DT, floor_N=0.0), noise_only)
    assert k is not None and k * DT < 0.1
    # ... unless the ground-motion term covers it (5 % of 200 N = 10 N > noise)
    ground = np.full(n, 200.0)
    assert feed(InstabilityMonitor(DT, floor_N=0.0), noise_only, ground)[0] is None


@pytest.mark.parametrize('window_s', [0.1, 0.2, 0.4])
def test_window_sets_the_time_to_trip(window_s):
    """A 100 Hz sine of 80 N switched on at t = 0: the running mean squares grow as
    1 - exp(-t/window), the ratio as sqrt of it; it trips when
    q = floor / (r_hf - r_lf) = sqrt(1 - exp(-t/window)), so t = -window ln(1 - q^2)."""
    amp = 80.0
    g_lf, g_hf = band_gains(100.0)
    q = 50.0 / (amp * (g_hf - g_lf) / math.sqrt(2))
    t_trip = -window_s * math.log(1 - q * q)
    k, _, _ = feed(InstabilityMonitor(DT, window_s=window_s), sine(amp, 100.0, 3.0))
    assert k is not None
    assert k * DT == pytest.approx(t_trip, rel=0.05, abs=0.01)


def test_threshold_is_the_trip_ratio():
    # one 100 Hz sine over the 50 N floor: the ratio rises with the amplitude and settles
    # with a ripple below 0.5 %
    sines = [(400.0, 100.0)]
    expected = steady_ratio(sines)
    force = sine(400.0, 100.0, 4.0, ramp_s=1.0)
    assert 3 < expected < 5
    assert feed(InstabilityMonitor(DT, threshold=1.03 * expected), force)[0] is None
    k, reason, _ = feed(InstabilityMonitor(DT, threshold=0.97 * expected), force)
    assert k is not None and k * DT > 1.0          # only once the oscillation is there
    assert reason.endswith(f'(threshold {0.97 * expected:g})')
    # threshold 0 disables it, however large the oscillation; the ratio is still computed
    off = InstabilityMonitor(DT, threshold=0.0)
    assert feed(off, sine(1e5, 100.0, 1.0))[0] is None
    assert off.ratio == pytest.approx(steady_ratio([(1e5, 100.0)]), rel=0.015) and off.ratio > 20


def test_trips_only_when_the_ratio_exceeds_the_threshold_strictly():
    """``r_hf > threshold * (...)``: a ratio equal to the threshold does not trip."""
    probe = InstabilityMonitor(DT, threshold=0.0, floor_N=0.0)
    probe.update(100.0, 0.0, 0.0)
    assert probe.ratio > 0
    assert InstabilityMonitor(DT, threshold=probe.ratio, floor_N=0.0).update(
        100.0, 0.0, 0.0) is None
    assert InstabilityMonitor(DT, threshold=probe.ratio * (1 - 1e-12), floor_N=0.0).update(
        100.0, 0.0, 0.0) is not None


def test_silence_gives_ratio_zero_and_small_forces_are_judged_by_their_shape():
    """A fresh monitor has ratio 0; with no floor, all-zero input (0 / 0) is ratio 0, not a
    trip; and without a floor the ratio does not depend on the force's scale, also below
    1 N (a milli-newton oscillation has the ratio of a kilo-newton one)."""
    mon = InstabilityMonitor(DT, threshold=0.5, floor_N=0.0)
    assert mon.ratio == 0.0 and mon.ground_force_scale_N == 0.0
    assert all(mon.update(0.0, 0.0, k * DT) is None for k in range(100))
    assert mon.ratio == 0.0
    small = InstabilityMonitor(DT, threshold=0.0, floor_N=0.0)
    large = InstabilityMonitor(DT, threshold=0.0, floor_N=0.0)
    r_small = feed(small, sine(1e-3, 100.0, 1.0))[2]
    r_large = feed(large, sine(1e3, 100.0, 1.0))[2]
    np.testing.assert_allclose(r_small, r_large, rtol=1e-9)
    assert small.ratio == pytest.approx(steady_ratio([(1.0, 100.0)], floor_N=0.0), rel=0.015)


def test_a_trip_is_reported_on_every_later_sample():
    mon = InstabilityMonitor(DT, floor_N=0.0)
    k, _, _ = feed(mon, sine(500.0, 100.0, 1.0))
    assert k is not None
    assert mon.update(500.0, 0.0, 9.0).startswith('unstable at t=9.000 s: ')


# -- parameters ----------------------------------------------------------------------------

@pytest.mark.parametrize('kwargs, message', [
    ({'cutoff_hz': 250.0}, r'parameter monitor_cutoff_hz=250\.0: expected > 0 and below the '
                           r'Nyquist frequency 250 Hz'),
    ({'cutoff_hz': 300.0}, r'parameter monitor_cutoff_hz=300\.0: expected > 0 and below the '
                           r'Nyquist frequency 250 Hz'),
    ({'cutoff_hz': 0.0}, r'parameter monitor_cutoff_hz=0\.0: expected > 0'),
    ({'cutoff_hz': -5.0}, r'parameter monitor_cutoff_hz=-5\.0: expected > 0'),
    ({'cutoff_hz': math.nan}, r'parameter monitor_cutoff_hz=nan: expected > 0'),
    ({'window_s': 0.0}, r'parameter monitor_window_s=0\.0: expected > 0$'),
    ({'window_s': math.nan}, r'parameter monitor_window_s=nan: expected > 0$'),
    ({'threshold': -0.1}, r'parameter monitor_threshold=-0\.1: expected >= 0$'),
    ({'threshold': math.nan}, r'parameter monitor_threshold=nan: expected >= 0$'),
    ({'floor_N': -1.0}, r'parameter monitor_floor_N=-1\.0: expected >= 0$'),
    ({'floor_N': math.nan}, r'parameter monitor_floor_N=nan: expected >= 0$'),
])
def test_out_of_range_parameters_are_refused(kwargs, message):
    with pytest.raises(ParameterError, match='^' + message):
        InstabilityMonitor(DT, **kwargs)


def test_cutoff_just_below_nyquist_and_zero_threshold_and_floor_are_accepted():
    InstabilityMonitor(DT, cutoff_hz=0.5)          # any cut-off above 0 Hz
    mon = InstabilityMonitor(DT, cutoff_hz=249.0, window_s=1e-3, threshold=0.0, floor_N=0.0)
    assert mon.threshold == 0.0 and mon.floor_N == 0.0 and mon.dt == DT
    # the Nyquist frequency follows dt: 300 Hz is fine at 1 kHz
    InstabilityMonitor(0.001, cutoff_hz=300.0)


def test_from_parameters_reads_the_monitor_parameters(reference_params):
    p = dict(reference_params, dt=0.001, monitor_cutoff_hz=40.0, monitor_window_s=0.5,
             monitor_threshold=2.0, monitor_floor_N=10.0)
    mon = InstabilityMonitor.from_parameters(p)
    assert (mon.dt, mon.threshold, mon.floor_N) == (0.001, 2.0, 10.0)
    force = sine(300.0, 37.0, 3.0, dt=0.001)
    ratios = feed(mon, force, dt=0.001)[2]
    np.testing.assert_allclose(ratios, reference_ratio(
        force, np.zeros_like(force), dt=0.001, cutoff_hz=40.0, window_s=0.5, floor_N=10.0),
        rtol=1e-9)
    # the schema's defaults are the docstring's: the cut-off derived (0) is 25 Hz for the
    # study's 10.1 Hz specimen
    default = InstabilityMonitor.from_parameters(reference_params)
    assert (reference_params['monitor_cutoff_hz'], monitor_cutoff_hz(reference_params),
            reference_params['monitor_window_s'], default.threshold,
            default.floor_N) == (0.0, 25.0, 0.2, 1.0, 50.0)


def stiff(reference_params, f_hz, alpha, **extra):
    """The study's parameters with a 40 kg specimen of natural frequency `f_hz`, 0.5 %."""
    k = 40.0 * (2 * math.pi * f_hz) ** 2
    return dict(reference_params, mass_kg=40.0, stiffness_N_per_m=k,
                damping_N_s_per_m=0.01 * math.sqrt(k * 40.0), alpha=alpha, **extra)


def test_the_derived_cut_off_lies_above_a_stiff_specimens_response(reference_params):
    # twice the reference structure's natural frequency sqrt(k / ((1 + alpha) m)) / 2 pi
    p = stiff(reference_params, 50.0, 1.0)
    assert monitor_cutoff_hz(p) == pytest.approx(2 * 50.0 / math.sqrt(2.0), rel=1e-12)
    assert monitor_cutoff_hz(stiff(reference_params, 50.0, 0.0)) == pytest.approx(100.0)
    # at most 0.4 of the sampling rate; a 12 Hz reference keeps the study's 25 Hz
    assert monitor_cutoff_hz(stiff(reference_params, 150.0, 0.0)) == pytest.approx(200.0)
    assert monitor_cutoff_hz(stiff(reference_params, 12.0, 0.0)) == 25.0
    # a set cut-off is taken as set, above the reference's frequency
    assert monitor_cutoff_hz(dict(p, monitor_cutoff_hz=40.0)) == 40.0
    # the 35.4 Hz response of the reference, steady, against the two splits (closed form):
    # the 25 Hz split takes it for the unstable mode, the derived one does not
    response = [(2000.0, 50.0 / math.sqrt(2.0))]
    assert steady_ratio(response, floor_N=50.0, cutoff_hz=25.0) > 1.0
    assert steady_ratio(response, floor_N=50.0, cutoff_hz=monitor_cutoff_hz(p)) < 0.3
    mon = InstabilityMonitor.from_parameters(p)
    k, reason, _ = feed(mon, sine(2000.0, 50.0 / math.sqrt(2.0), 3.0, ramp_s=0.5))
    assert k is None and reason is None
    k, reason, _ = feed(InstabilityMonitor(DT, cutoff_hz=25.0),     # the study's split
                        sine(2000.0, 50.0 / math.sqrt(2.0), 3.0, ramp_s=0.5))
    assert k is not None and 'high-frequency oscillation' in reason


def test_a_set_cut_off_below_the_reference_frequency_is_one_error(reference_params):
    p = stiff(reference_params, 50.0, 1.0, monitor_cutoff_hz=25.0)
    with pytest.raises(ParameterError, match=r'^parameter monitor_cutoff_hz=25: below the '
                       r"reference structure's natural frequency 35\.4 Hz .*expected at least "
                       r'70\.7 Hz, or 0 to derive it$'):
        InstabilityMonitor.from_parameters(p)


# -- the docs' calibration claim over several records -----------------------------------

class _RecordingMonitor(InstabilityMonitor):
    """The monitor of a run, observing (threshold 0) and keeping its largest ratio."""

    largest: list = []

    def update(self, measured_force_N, ground_force_N, time_s):
        out = super().update(measured_force_N, ground_force_N, time_s)
        if math.isfinite(self.ratio):
            _RecordingMonitor.largest[-1] = max(_RecordingMonitor.largest[-1], self.ratio)
        return out


OBSERVE = {'monitor_threshold': 0.0, 'saturation_abort_fraction': 1.0, 'force_limit_N': 1e12,
           'stroke_limit_m': 1e6, 'divergence_factor': 0.0}
STABLE = {'delay': (0.0, 0.5, 0.9), 'servohydraulic': (0.0, 0.5, 1.0, 1.2)}
UNSTABLE = {'delay': (1.5, 2.0), 'servohydraulic': (1.5, 2.0)}


@pytest.fixture(scope='module')
def calibration_ratios(request):
    """Largest in-loop monitor ratio of each run: 3 synthetic records (seeds 1-3, seed 1 is
    the default), both rigs, uncompensated, alpha in the stable and unstable groups of
    ``benchmarks/monitor_margin.py``; seed 1 also with sensor noise."""
    from seft_msgs_py import parameters
    mp = pytest.MonkeyPatch()
    mp.setattr(experiment, 'InstabilityMonitor', _RecordingMonitor)
    base = parameters.resolve()
    out = []
    try:
        for seed in (1, 2, 3):
            gm = prepare(synthetic_default(seed=seed), dt=base['dt'], mass_kg=base['mass_kg'],
                         amplitude_N=base['amplitude_N'], time_scale=base['time_scale'])
            noises = ({}, {'noise_force_N': 5.0, 'noise_acceleration_m_s2': 0.05}) \
                if seed == 1 else ({},)
            for noise in noises:
                for rig in ('delay', 'servohydraulic'):
                    for alpha in STABLE[rig] + UNSTABLE[rig]:
                        _RecordingMonitor.largest.append(0.0)
                        simulate(dict(base, **OBSERVE, **noise, rig_model=rig, alpha=alpha,
                                      predictor='none'), record=gm)
                        out.append((seed, bool(noise), rig, alpha, alpha in STABLE[rig],
                                    _RecordingMonitor.largest[-1]))
    finally:
        mp.undo()
    return out


def test_calibration_stable_and_unstable_runs_are_separated(calibration_ratios):
    """``benchmarks/monitor_margin.py``'s claim as a check. The docs (design, "Safety") states a
    largest stable ratio of 0.66 and 1.5 or more for every unstable run; with the current
    rig defaults (Eq. 3.1 read in V/lbf, ground preview) the default record alone gives 0.69
    (delay rig, alpha 0.9) and 1.46 (servohydraulic, alpha 1.5), and the seeds 2-3 records
    0.80 and 1.44. What the default threshold 1.0 needs, and what is asserted: every stable
    run below 1/1.2 of it, every unstable run above 1.4 times it."""
    stable = [r for *_, s, r in calibration_ratios if s]
    unstable = [r for *_, s, r in calibration_ratios if not s]
    assert len(stable) == 4 * 7 and len(unstable) == 4 * 4
    assert max(stable) < 1 / 1.2, calibration_ratios
    assert min(unstable) > 1.4, calibration_ratios
    # on the default record the delay rig's unstable runs are far beyond (neutral-type loop)
    assert min(r for seed, _, rig, _, s, r in calibration_ratios
               if rig == 'delay' and not s) > 3.0


# -- the specimen check -------------------------------------------------------------------

def _piers_on_delay_rigs(ratio, **run):
    """The two-pier bridge on delay rigs, each specimen `ratio` times as stiff as declared
    (the compensator's model)."""
    import json
    from pathlib import Path

    from seft_ros.cli.config import expand_runs, load_config
    config = Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml'
    params = expand_runs(dict(load_config(config), rig_model='delay', **run))[0]
    doc = json.loads(params['structure'])
    for rig in ('pier_a', 'pier_b'):
        section = doc['rigs'][rig]
        section['rig_model'] = 'delay'
        section['predictor_stiffness_N_per_m'] = section.get('stiffness_N_per_m', 2.11e5) / ratio
    return dict(params, structure=json.dumps(doc))


@pytest.mark.parametrize('ratio', [0.5, 2.0])
def test_a_specimen_far_from_its_declaration_is_reported(ratio):
    """Each pier half or twice as stiff as declared: 'model' runs on a wrong model (stable,
    not right); each rig identifies its specimen from its own force and motion, and the run
    says so (warn: the run goes on, its warnings name the rig and the ratio)."""
    run = simulate(_piers_on_delay_rigs(ratio, predictor='model', duration_s=6.0))
    assert run.stable
    assert run.extra['specimen_ratios'] == {'pier_a': pytest.approx(ratio, rel=0.01),
                                            'pier_b': pytest.approx(ratio, rel=0.01)}
    checks = [w for w in run.extra['warnings'] if w.startswith('specimen check')]
    assert len(checks) == 2
    # the other lines: a pier's accelerometer at its range (issue 39), counted
    for w in run.extra['warnings']:
        if w not in checks:
            rig = w.split(':')[0]
            assert w.startswith(f'{rig}: acceleration at its sensor range (39.2 m/s^2)')
            assert run.extra['sensor_range'][rig]['samples']['acceleration'] > 0
    for rig in ('pier_a', 'pier_b'):
        line = next(w for w in checks if f'rig {rig} ' in w)
        assert f'at {ratio:.3g} x the declared stiffness' in line
        assert '(tolerance +-10 %)' in line


def test_a_specimen_far_from_its_declaration_stops_the_run_with_abort():
    """specimen_check: abort: the builder stops the run safely at the finding, naming the
    rig; the exact declaration passes (identified within 1 %, no warning)."""
    run = simulate(_piers_on_delay_rigs(0.5, predictor='model', duration_s=6.0,
                                        specimen_check='abort'))
    assert not run.stable and run.extra['abort_node'] == 'reference_force_builder'
    assert run.abort_reason.startswith('pier_b: specimen check at t=')
    assert 1.5 < run.unstable_at_s < 3.0        # 1 s of excitation, then 0.5 s off
    exact = simulate(_piers_on_delay_rigs(1.0, predictor='model', duration_s=6.0,
                                          specimen_check='abort'))
    assert exact.stable and exact.extra['warnings'] == []
    assert exact.extra['specimen_ratios']['pier_a'] == pytest.approx(1.0, abs=0.01)


def test_the_specimen_check_judges_only_what_it_can():
    """Off, a yielding member and an open-loop identification run have no check; adaptive's
    tolerance is its identification's range; bad values are one line."""
    from seft_msgs_py import parameters
    from seft_ros.core.monitor import SpecimenCheck
    p = parameters.resolve()
    assert SpecimenCheck.from_parameters(dict(p, specimen_check='off')) is None
    assert SpecimenCheck.from_parameters(dict(p, specimen_model='bouc_wen')) is None
    assert SpecimenCheck.from_parameters(dict(p, excitation='noise',
                                              excitation_input='valve_command')) is None
    assert SpecimenCheck.from_parameters(p).tolerance == 0.1
    assert SpecimenCheck.from_parameters(dict(p, specimen_uncertainty=0.2)).tolerance == 0.2
    assert SpecimenCheck.from_parameters(dict(p, predictor='adaptive')).tolerance == 0.5
    with pytest.raises(ParameterError, match=r'specimen_uncertainty=1\.5: expected a fraction'):
        SpecimenCheck(52.7, 903.0, 2.11e5, 0.002, 1.5)


def _noisy_specimen_check(amplitude_m, stiffness_ratio, noise=True, seed=0):
    """K's specimen (200 kg, 15 Hz, 3 %) moved by five sines (0.7-5.5 Hz, `amplitude_m` RMS)
    with the true stiffness `stiffness_ratio` x the declared, read through the benchmark's
    sensor noise (5 N, 10 um, 0.1 mm/s, 0.05 m/s^2) into the check of its parameters; its
    lines and the check."""
    from seft_msgs_py import parameters
    from seft_msgs_py.interface import Measurement
    from seft_ros.core.monitor import SpecimenCheck
    m, c, k = 200.0, 1130.97, 1776500.0
    sigma = np.array([5.0, 1e-5, 1e-4, 0.05]) if noise else np.zeros(4)
    p = dict(parameters.resolve(), mass_kg=m, damping_N_s_per_m=c, stiffness_N_per_m=k,
             dt=0.002, noise_force_N=sigma[0], noise_displacement_m=sigma[1],
             noise_velocity_m_s=sigma[2], noise_acceleration_m_s2=sigma[3])
    check = SpecimenCheck.from_parameters(p)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 0.002)
    w = 2 * np.pi * np.array([0.7, 1.3, 2.1, 3.4, 5.5])
    phase = np.outer(t, w) + rng.uniform(0, 2 * np.pi, 5)
    scale = amplitude_m / np.sqrt(2.5)
    x = scale * np.sin(phase).sum(1)
    v = scale * (w * np.cos(phase)).sum(1)
    a = -scale * (w ** 2 * np.sin(phase)).sum(1)
    f = m * a + c * v + stiffness_ratio * k * x
    e = rng.standard_normal((len(t), 4)) * sigma
    lines = [line for i in range(len(t)) if (line := check.update(Measurement(
        i, float(t[i]), float(x[i] + e[i, 1]), float(v[i] + e[i, 2]), float(a[i] + e[i, 3]),
        float(f[i] + e[i, 0]))))]
    return lines, check


def test_the_specimen_check_takes_the_declared_sensor_noise_out():
    """Errors in variables: the regressors' noise biased the check's least squares low (K at
    150 N: 'identifies its specimen at 0.78-0.88 x' the declared, true, stiffness; here at
    40 um RMS 'at 0.894 x'). With the declared noise taken out of the normal equations the
    declared specimen passes and a 25 % stiffer one is found with its standard error; where
    the motion is too small to judge (20 um against 10 um of noise, before: 'at 0.747 x') the
    check says so once and reports no ratio; without noise nothing changes."""
    from seft_ros.core.monitor import SPECIMEN_UNJUDGED
    lines, check = _noisy_specimen_check(4e-5, 1.0)
    assert lines == [] and check.stiffness_ratio == pytest.approx(0.960, abs=0.001)
    lines, check = _noisy_specimen_check(8e-5, 1.0)
    assert lines == [] and check.stiffness_ratio == pytest.approx(0.987, abs=0.001)
    lines, check = _noisy_specimen_check(8e-5, 1.25)
    assert len(lines) == 1 and 'identifies its specimen at 1.2 +-0.022 (the sensors' in lines[0]
    lines, check = _noisy_specimen_check(2e-5, 1.0)
    assert len(lines) == 1 and lines[0].startswith(f'{SPECIMEN_UNJUDGED} at t=5.170 s: the rig '
                                                   "cannot tell its specimen's stiffness")
    assert check.stiffness_ratio == 1.0 and not check.judged
    lines, check = _noisy_specimen_check(8e-5, 1.25, noise=False)
    assert lines[0].startswith('specimen check at t=1.528 s: the rig identifies its specimen '
                               'at 1.25 x the declared')
    assert check.stiffness_ratio == pytest.approx(1.25, rel=1e-5) and check.stiffness_error == 0


@pytest.mark.parametrize('noise', [False, True])
def test_the_specimen_check_judges_a_sample_without_regression_as_the_one_before(noise):
    """The check skips its verdict on a sample without a regression (four in five) when the
    sample before found the specimen within the tolerance: the same lines at the same
    samples, and the same ratio, as a check that judges every sample. K's specimen as
    declared for 4 s, a pause of the excitation (the gate shut), then 20 % softer."""
    from seft_msgs_py import parameters
    from seft_msgs_py.interface import Measurement
    from seft_ros.core.monitor import SpecimenCheck

    class EverySample(SpecimenCheck):
        _steady = property(lambda self: False, lambda self, value: None)

    m, c, k = 200.0, 1130.97, 1776500.0
    sigma = np.array([5.0, 1e-5, 1e-4, 0.05]) if noise else np.zeros(4)
    p = dict(parameters.resolve(), mass_kg=m, damping_N_s_per_m=c, stiffness_N_per_m=k,
             dt=0.002, noise_force_N=sigma[0], noise_displacement_m=sigma[1],
             noise_velocity_m_s=sigma[2], noise_acceleration_m_s2=sigma[3])
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 12.0, 0.002)
    w = 2 * np.pi * np.array([0.9, 1.7, 2.9, 4.3])
    phase = np.outer(t, w) + rng.uniform(0, 2 * np.pi, 4)
    envelope = np.where((t > 4.0) & (t < 5.0), 0.0, 8e-5 / np.sqrt(2.0))
    x = envelope * np.sin(phase).sum(1)
    v = envelope * (w * np.cos(phase)).sum(1)
    a = -envelope * (w ** 2 * np.sin(phase)).sum(1)
    f = m * a + c * v + np.where(t < 4.5, 1.0, 0.8) * k * x
    e = rng.standard_normal((len(t), 4)) * sigma
    samples = [Measurement(i, float(t[i]), float(x[i] + e[i, 1]), float(v[i] + e[i, 2]),
                           float(a[i] + e[i, 3]), float(f[i] + e[i, 0]))
               for i in range(len(t))]
    runs = []
    for kind in (SpecimenCheck, EverySample):
        check = SpecimenCheck.from_parameters(p)
        check.__class__ = kind
        lines = [(s.step, line) for s in samples if (line := check.update(s))]
        runs.append((lines, check.stiffness_ratio, check.stiffness_error, check.judged))
    assert runs[0] == runs[1]
    lines = runs[0][0]
    assert len(lines) == 1 and 'identifies its specimen at 0.8' in lines[0][1]
    assert lines[0][0] * 0.002 > 5.0          # (the change at 4.5 s, the check persists)
