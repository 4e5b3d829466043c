"""Residual (permanent) displacement, drift-removed NRMS and hysteresis loops of nonlinear runs."""

import json
import math

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.servohydraulic import ServoHydraulicRig
from seft_plant_sim.specimen import BoucWenSpecimen
from seft_ros.analysis.metrics import (
    compare_run,
    drift,
    is_nonlinear,
    residual_displacement,
    restoring_force,
    summary_entry,
)
from seft_ros.analysis.reference import ReferenceResponse, reference_response
from seft_ros.analysis.report import plot_hysteresis, write_report
from seft_ros.analysis.rundata import RunData
from seft_ros.cli.api import summary_table
from seft_ros.core.experiment import simulate

# The reference rig's specimen (paper Sec. 3.1) with the default Bouc-Wen member.
M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002
DY = 0.004
FC = 0.25          # the default drift cut-off [Hz]
WINDOW = 2.0       # the default residual window [s]


def hann_bound(f_hz, window_s=WINDOW):
    """Largest weighted mean of a unit sinusoid of frequency f under a Hann window of length
    T, relative to the window's sum: |W(f)/W(0)| = |sinc(fT)| / |1 - (fT)^2| <= 1/(pi fT
    ((fT)^2 - 1)) for fT > 1 (Harris 1978)."""
    u = f_hz * window_s
    return 1.0 / (math.pi * u * (u * u - 1.0))


def smooth_step(t, start, rise):
    """0 before `start`, 1 after `start + rise`, a half cosine in between."""
    s = np.clip((t - start) / rise, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * s)


def fft_lowpass(x, dt, cutoff_hz, order=4):
    """Independent zero-phase low-pass: the record and its mirror image as one period, every
    Fourier component multiplied by the forward-backward Butterworth magnitude
    1/(1 + (f/f_c)^(2 order))."""
    n = x.shape[0]
    y = np.fft.rfft(np.concatenate([x, x[::-1]]))
    f = np.fft.rfftfreq(2 * n, dt)
    return np.fft.irfft(y / (1.0 + (f / cutoff_hz) ** (2 * order)), 2 * n)[:n]


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope='module')
def shaking():
    """A yielding-like reference displacement [m], 20 s at 2 ms: 3 Hz and 5.3 Hz under an
    envelope, and a permanent offset of -2 mm taken between 4 and 7 s."""
    t = np.arange(10000) * DT
    env = np.minimum(1.0, t) * np.exp(-np.maximum(0.0, t - 8.0) / 2.0)
    x = (0.006 * np.sin(2 * np.pi * 3.0 * t) + 0.004 * np.sin(2 * np.pi * 5.3 * t + 1.0)) * env
    return t, x - 0.002 * smooth_step(t, 4.0, 3.0)


def _run_and_reference(x_test, x_ref, params=None):
    """A RunData and a ReferenceResponse that differ only in the displacement."""
    n = x_test.shape[0]
    t = np.arange(n) * DT
    wave = np.sin(2 * np.pi * 3.0 * t)
    ref = ReferenceResponse(time_s=t, displacement_m=x_ref, velocity_m_s=np.gradient(x_ref, DT),
                            acceleration_m_s2=wave, force_N=100.0 * wave,
                            restoring_force_N=K * x_ref)
    p = {'alpha': 0.0, 'dt': DT, 'mass_kg': M, 'damping_N_s_per_m': C,
         'stiffness_N_per_m': K, 'rig_model': 'delay', 'predictor': 'none',
         'specimen_model': 'bouc_wen'}
    p.update(params or {})
    run = RunData.one_rig(params=p, time_s=t, ground_acceleration_m_s2=np.zeros(n),
                  reference_force_N=100.0 * wave, measured_force_N=100.0 * wave,
                  displacement_m=x_test, velocity_m_s=np.gradient(x_test, DT),
                  acceleration_m_s2=wave, record_name='synthetic')
    return run, ref


# -- residual displacement -----------------------------------------------------------------

@pytest.mark.parametrize('f_hz', [1.3, 2.2, 7.0, 10.07])
def test_residual_of_an_offset_under_an_oscillation_that_does_not_end(f_hz):
    # the record ends while shaking: r + A sin(2 pi f t + phi) up to the last sample
    t = np.arange(5000) * DT
    r, a = 0.0032, 0.005
    for phase in np.linspace(0.0, 2 * np.pi, 9):
        got = residual_displacement(r + a * np.sin(2 * np.pi * f_hz * t + phase), DT)
        assert abs(got - r) <= 1.02 * a * hann_bound(f_hz)


def test_residual_of_a_free_vibration_and_of_a_trend():
    t = np.arange(5000) * DT
    w = 2 * np.pi * 10.07
    x = -0.0029 + 0.006 * np.exp(-0.05 * w * t) * np.sin(w * t)     # comes to rest at -2.9 mm
    assert residual_displacement(x, DT) == pytest.approx(-0.0029, abs=1e-9)
    # a linear trend: the value at the window's centre (the weights are symmetric)
    n = int(WINDOW / DT)
    trend = 1e-3 + 2e-4 * t
    centre = 0.5 * (t[-n] + t[-1])
    assert residual_displacement(trend, DT) == pytest.approx(1e-3 + 2e-4 * centre, rel=1e-12)
    # the window is the last window_s seconds; a shorter record is used whole
    assert residual_displacement(trend, DT, window_s=0.5) == pytest.approx(
        1e-3 + 2e-4 * 0.5 * (t[-250] + t[-1]), rel=1e-12)
    assert residual_displacement(trend[:100], DT) == pytest.approx(
        1e-3 + 2e-4 * 0.5 * t[99], rel=1e-12)
    # and the Hann weights are numpy's Hann window without its zero end points
    w_np = np.hanning(n + 2)[1:-1]
    assert residual_displacement(x, DT) == pytest.approx(
        np.dot(w_np, x[-n:]) / np.sum(w_np), rel=1e-12)


def test_residual_edge_cases_and_errors():
    assert math.isnan(residual_displacement([], DT))
    assert residual_displacement([0.25], DT) == 0.25
    x = np.full(3000, 0.004)
    x[2000:] = np.nan                                # an aborted run: the finite samples
    assert residual_displacement(x, DT) == pytest.approx(0.004, rel=1e-12)
    with pytest.raises(ParameterError, match='window_s=0'):
        residual_displacement(x, DT, window_s=0)
    with pytest.raises(ParameterError, match='window_s=nan'):
        residual_displacement(x, DT, window_s=float('nan'))
    with pytest.raises(ParameterError, match='dt'):
        residual_displacement(x, 0.0)
    with pytest.raises(ParameterError, match='x'):
        residual_displacement(np.zeros((3, 3)), DT)


# -- drift and the NRMS without it ---------------------------------------------------------

def test_drift_is_the_zero_phase_butterworth_lowpass(shaking):
    t, x = shaking
    scale = np.max(np.abs(x))
    got = drift(x, DT)
    np.testing.assert_allclose(got, fft_lowpass(x, DT, FC), rtol=0, atol=1e-4 * scale)
    # a constant passes exactly, so a constant offset leaves x - drift(x) unchanged
    np.testing.assert_allclose(drift(np.full(500, 0.003), DT), 0.003, rtol=1e-9)
    np.testing.assert_allclose((x + 0.003) - drift(x + 0.003, DT), x - got, rtol=0,
                               atol=1e-9 * scale)
    # the oscillation is gone: the drift is the permanent offset away from the ends
    middle = (t > 1.0) & (t < 19.0)
    np.testing.assert_allclose(got[middle], fft_lowpass(-0.002 * smooth_step(t, 4.0, 3.0),
                                                         DT, FC)[middle],
                               rtol=0, atol=2e-3 * scale)


def test_drift_edge_cases_and_errors():
    x = np.sin(np.arange(1000) * 0.1)
    x[600] = np.inf
    out = drift(x, DT)
    assert np.all(np.isfinite(out[:600])) and np.all(np.isnan(out[600:]))
    assert drift([0.1], DT).tolist() == [0.1]
    assert drift([], DT).shape == (0,)
    with pytest.raises(ParameterError, match='cutoff_hz=250'):
        drift(x, DT, cutoff_hz=250)                  # the Nyquist frequency
    with pytest.raises(ParameterError, match='cutoff_hz=0'):
        drift(x, DT, cutoff_hz=0)
    with pytest.raises(ParameterError, match='dt'):
        drift(x, -1.0)


def test_a_constant_offset_is_all_of_the_plain_error_and_none_of_the_other(shaking):
    _, x_ref = shaking
    d = 0.003
    run, ref = _run_and_reference(x_ref + d, x_ref)
    res = compare_run(run, ref).residual
    # no lag: the correlation's peak is symmetric to rounding (FFT correlation, 5e-17 s here)
    assert abs(res.lag_s) < 1e-12
    assert res.nrms == pytest.approx(d / rms(x_ref), rel=1e-9)           # 0.81 here
    assert res.nrms > 0.8
    assert res.nrms_residual_removed < 1e-9
    assert res.residual_test_m - res.residual_reference_m == pytest.approx(d, rel=1e-9)


def test_a_permanent_offset_taken_at_a_yield_excursion(shaking):
    t, x_ref = shaking
    d = 0.003                                        # the test settles 3 mm from the reference
    step = smooth_step(t, 5.0, 2.0)
    run, ref = _run_and_reference(x_ref + d * step, x_ref)
    res = compare_run(run, ref).residual
    assert abs(res.lag_s) < 0.05 * DT
    plain = rms(d * step) / rms(x_ref)
    removed = (rms(d * (step - fft_lowpass(step, DT, FC)))
               / rms(x_ref - fft_lowpass(x_ref, DT, FC)))
    assert plain > 0.6 and removed < 0.05
    # 0.67 and 0.036; sosfiltfilt's padded ends against the periodic FFT filter: 1e-5
    assert res.nrms == pytest.approx(plain, rel=1e-3)
    assert res.nrms_residual_removed == pytest.approx(removed, rel=1e-3)
    # the residual displacements: the oscillation has died out 12 s before the end
    assert res.residual_reference_m == pytest.approx(-0.002, abs=1e-7)
    assert res.residual_test_m == pytest.approx(-0.002 + d, abs=1e-7)
    assert res.peak_test_m == pytest.approx(np.max(np.abs(x_ref + d * step)), rel=1e-12)
    assert res.peak_reference_m == pytest.approx(np.max(np.abs(x_ref)), rel=1e-12)
    # and with the test 10 ms behind the reference: the lag is removed first
    late = np.concatenate([np.zeros(5), (x_ref + d * step)[:-5]])
    res_late = compare_run(_run_and_reference(late, x_ref)[0], ref).residual
    assert res_late.lag_s == pytest.approx(0.01, abs=1e-4)
    assert res_late.nrms_residual_removed == pytest.approx(removed, rel=0.05)


def test_summary_block_only_for_a_nonlinear_specimen(shaking):
    _, x_ref = shaking
    run, ref = _run_and_reference(x_ref + 0.001, x_ref)
    entry = summary_entry(run, compare_run(run, ref))
    block = entry['nonlinear']
    assert set(block) == {'specimen_model', 'nrms_displacement',
                          'nrms_displacement_residual_removed', 'peak_displacement_m',
                          'residual_displacement_m', 'drift_cutoff_hz', 'residual_window_s'}
    assert block['specimen_model'] == 'bouc_wen'
    assert block['nrms_displacement'] == entry['nrms']['displacement']
    assert (block['drift_cutoff_hz'], block['residual_window_s']) == (FC, WINDOW)
    assert json.loads(json.dumps(entry, allow_nan=False)) == entry
    linear, _ = _run_and_reference(x_ref + 0.001, x_ref, {'specimen_model': 'linear'})
    assert 'nonlinear' not in summary_entry(linear, compare_run(linear, ref))
    legacy, _ = _run_and_reference(x_ref + 0.001, x_ref)
    del legacy.params['specimen_model']              # runs recorded before the member existed
    assert not is_nonlinear(legacy.params)
    assert 'nonlinear' not in summary_entry(legacy, compare_run(legacy, ref))


def test_compare_run_rejects_bad_drift_and_window(shaking):
    _, x_ref = shaking
    run, ref = _run_and_reference(x_ref, x_ref)
    with pytest.raises(ParameterError, match='cutoff_hz=300'):
        compare_run(run, ref, drift_cutoff_hz=300.0)
    with pytest.raises(ParameterError, match='window_s=-1'):
        compare_run(run, ref, residual_window_s=-1.0)


# -- the restoring force of the hysteresis loops -------------------------------------------

def _driven(rig, commands):
    """Apply the commands; return a RunData of the readings and the rig's z at each sample."""
    rows, z = [], []
    for u in commands:
        m = rig.measure()
        rows.append((m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
        z.append(rig.hysteretic_z)
        rig.apply(u)
    f, x, v, a = (np.array(col) for col in zip(*rows))
    n = f.shape[0]
    run = RunData.one_rig(params={'mass_kg': M, 'damping_N_s_per_m': C}, time_s=np.arange(n) * DT,
                  ground_acceleration_m_s2=np.zeros(n), reference_force_N=np.zeros(n),
                  measured_force_N=f, displacement_m=x, velocity_m_s=v, acceleration_m_s2=a)
    return run, np.array(z)


@pytest.mark.parametrize('rig_name', ['delay', 'servohydraulic'])
def test_restoring_force_equals_the_rigs_internal_bouc_wen_force(rig_name):
    spec = BoucWenSpecimen(M, C, K)
    t = np.arange(750) * DT
    if rig_name == 'delay':
        rig = DelayRig(spec, DT, 0.01)
        commands = 1500.0 * np.sin(2 * np.pi * 3.0 * t)             # force [N]
    else:
        rig = ServoHydraulicRig(spec, DT)
        commands = 0.5 * np.sin(2 * np.pi * 3.0 * t)                 # valve command [V]
    run, z = _driven(rig, commands)
    assert np.max(np.abs(run.displacement_m)) > 1.5 * DY and np.max(np.abs(z)) > 0.9
    want = spec.restoring_force(run.displacement_m, z)
    np.testing.assert_allclose(restoring_force(run), want, rtol=0,
                               atol=1e-9 * np.max(np.abs(want)))


def test_restoring_force_errors():
    run, _ = _run_and_reference(np.zeros(10), np.zeros(10))
    del run.params['mass_kg']
    with pytest.raises(ParameterError, match='missing mass_kg'):
        restoring_force(run)
    run.params['mass_kg'] = 0.0
    with pytest.raises(ParameterError, match='mass_kg=0.0'):
        restoring_force(run)
    run.params.update(mass_kg=M, damping_N_s_per_m=-1.0)
    with pytest.raises(ParameterError, match='damping_N_s_per_m=-1.0'):
        restoring_force(run)


def test_reference_restoring_force():
    t = np.arange(1500) * DT
    ag = 30.0 * np.sin(2 * np.pi * 3.0 * t) * np.minimum(1.0, t / 0.5)
    common = {'alpha': 0.5, 'mass_kg': M, 'damping_N_s_per_m': C, 'stiffness_N_per_m': K,
              'dt': DT, 'ground_acceleration_m_s2': ag}
    lin = reference_response(**common)
    np.testing.assert_allclose(lin.restoring_force_N, K * lin.displacement_m, rtol=0, atol=0)
    hys = reference_response(**common, specimen_model='bouc_wen')
    spec = BoucWenSpecimen(M, C, K)
    fs = spec.restoring_force(hys.displacement_m, hys.hysteretic_z)
    np.testing.assert_allclose(hys.restoring_force_N, fs, rtol=0, atol=0)
    # the member force without its inertia and damping (paper Eq. 2.4)
    np.testing.assert_allclose(hys.restoring_force_N, hys.force_N - M * hys.acceleration_m_s2
                               - C * hys.velocity_m_s, rtol=0,
                               atol=1e-9 * np.max(np.abs(hys.force_N)))


def bouc_wen_from_displacement(x, substeps=20):
    """Independent Bouc-Wen force from a displacement history alone: the model is
    rate-independent, dz/dx = (1/D_y)(1 - |z|^n (beta sgn(dx z) + gamma)) with the
    defaults n = 2, beta = gamma = 0.5, integrated along x by RK4 (direction held per
    sample); f_s = a k x + (1 - a) k D_y z with a = 0.1."""
    def slope(z, sign):
        return (1.0 - z * z * (0.5 * math.copysign(1.0, sign * z) + 0.5)) / DY

    z, out = 0.0, [0.0]
    for k in range(x.shape[0] - 1):
        h = (x[k + 1] - x[k]) / substeps
        for _ in range(substeps):
            k1 = slope(z, h)
            k2 = slope(z + 0.5 * h * k1, h)
            k3 = slope(z + 0.5 * h * k2, h)
            k4 = slope(z + h * k3, h)
            z += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out.append(z)
    return 0.1 * K * x + 0.9 * K * DY * np.array(out)


@pytest.fixture(scope='module')
def yielding_run():
    """4 s of the default record at 1000 N on the servohydraulic rig, uncompensated, alpha =
    0, Bouc-Wen member: the record is cut while it still shakes."""
    return simulate({'rig_model': 'servohydraulic', 'specimen_model': 'bouc_wen',
                     'alpha': 0.0, 'predictor': 'none', 'duration_s': 4.0})


def test_restoring_force_of_a_run_follows_bouc_wen_from_its_displacement(yielding_run):
    run = yielding_run
    assert run.stable and np.max(np.abs(run.displacement_m)) > DY
    independent = bouc_wen_from_displacement(run.displacement_m)
    peak = np.max(np.abs(independent))
    assert peak > 0.8 * K * DY                       # it yields (strength 0.9 k D_y + a k x)
    # the samples miss the extremes between them by ~ a dt^2 / 8 = 1e-5 m (a ~ 20 m/s^2),
    # i.e. k * 1e-5 m = 2 N of the 870 N peak; measured 0.76 N
    np.testing.assert_allclose(restoring_force(run), independent, rtol=0, atol=0.003 * peak)


def test_report_of_a_yielding_run(yielding_run, tmp_path):
    run = yielding_run
    paths = write_report([run], tmp_path, title='yielding')
    png = tmp_path / 'hysteresis.png'
    assert paths.hysteresis == {'none': png} and png in paths.figures
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 20000
    entry = json.loads(paths.summary_json.read_text())['runs'][0]
    block = entry['nonlinear']
    x = run.displacement_m
    assert block['peak_displacement_m']['test'] == pytest.approx(np.max(np.abs(x)), rel=1e-12)
    n = int(WINDOW / DT)
    w = np.hanning(n + 2)[1:-1]
    assert block['residual_displacement_m']['test'] == pytest.approx(
        np.dot(w, x[-n:]) / np.sum(w), rel=1e-9)
    ref = reference_response(alpha=0.0, mass_kg=M, damping_N_s_per_m=C, stiffness_N_per_m=K,
                             dt=DT, ground_acceleration_m_s2=run.ground_acceleration_m_s2,
                             specimen_model='bouc_wen')
    xr = ref.displacement_m
    assert block['peak_displacement_m']['reference'] == pytest.approx(np.max(np.abs(xr)),
                                                                      rel=1e-9)
    assert block['residual_displacement_m']['reference'] == pytest.approx(
        np.dot(w, xr[-n:]) / np.sum(w), rel=1e-6, abs=1e-9)
    assert 0 < block['nrms_displacement_residual_removed'] < 2
    md = paths.report_md.read_text()
    assert '## Nonlinear specimen: residual displacement and hysteresis' in md
    assert '(hysteresis.png)' in md and '**Hysteresis, predictor none, alpha = 0.**' in md
    assert 'nonlinear specimen (bouc_wen): residual displacement test' in md
    assert 'title="hysteresis.png" src="data:image/png;base64,' in paths.report_html.read_text()
    table = summary_table([entry])
    assert 'nrms_xr%' in table.splitlines()[0]
    assert f"{100 * block['nrms_displacement_residual_removed']:8.2f}" in table


def test_plot_hysteresis_errors(tmp_path):
    with pytest.raises(ParameterError, match='plot_hysteresis'):
        plot_hysteresis([], [], tmp_path / 'h.png')
