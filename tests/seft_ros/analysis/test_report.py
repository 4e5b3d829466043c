"""The report writes strict JSON, a Markdown table per run and legible PNG figures."""

import json
import math

import numpy as np
import pytest
from scipy import signal as sps

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.reference import reference_response
from seft_ros.analysis.report import write_report, write_summary_json
from seft_ros.analysis.rundata import RunData

# The reference rig (paper Sec. 3.1).
M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002


@pytest.fixture(scope='module')
def runs():
    """Runs at alpha = 0, 0.5 and 1.5 built from the reference: delayed 10 ms; at 0.5 with
    high-frequency vibration; at 1.5 a growing oscillation aborted at 6 s with NaN samples."""
    n = 10000
    t = np.arange(n) * DT
    b, a = sps.butter(4, [0.5, 15.0], btype='band', fs=1 / DT)
    ag = sps.lfilter(b, a, np.random.default_rng(11).normal(size=n))
    ag *= np.minimum(1.0, t / 2.0) * np.exp(-np.maximum(0.0, t - 8.0) / 4.0)
    ag *= 1000.0 / M / np.max(np.abs(ag))
    out = []
    for alpha, vibration, n_run in ((0.0, 0.0, n), (0.5, 0.2, n), (1.5, 0.0, 3000)):
        params = {'alpha': alpha, 'dt': DT, 'mass_kg': M, 'damping_N_s_per_m': C,
                  'stiffness_N_per_m': K, 'rig_model': 'servohydraulic', 'predictor': 'none',
                  'record': 'default', 'tau_s': 0.01, 'io_latency_s': 0.003}
        ref = reference_response(alpha=alpha, mass_kg=M, damping_N_s_per_m=C,
                                 stiffness_N_per_m=K, dt=DT, ground_acceleration_m_s2=ag)

        def delayed(x):
            return np.concatenate([np.zeros(5), x[:-5]])[:n_run]

        tt = t[:n_run]
        hf = vibration * np.sin(2 * np.pi * 45 * tt)
        run = RunData(params=params, time_s=tt, ground_acceleration_m_s2=ag[:n_run],
                      reference_force_N=ref.force_N[:n_run],
                      measured_force_N=delayed(ref.force_N) + 1000 * hf,
                      displacement_m=delayed(ref.displacement_m),
                      velocity_m_s=delayed(ref.velocity_m_s),
                      acceleration_m_s2=delayed(ref.acceleration_m_s2) + 500 * hf,
                      record_name='synthetic', source='test')
        if n_run < n:
            growth = 1e-4 * np.exp(1.5 * tt) * np.sin(2 * np.pi * 30 * tt)
            run.displacement_m = run.displacement_m + growth
            run.measured_force_N = run.measured_force_N + K * growth
            run.acceleration_m_s2 = run.acceleration_m_s2 - (2 * np.pi * 30) ** 2 * growth
            run.acceleration_m_s2[-2:] = np.nan
            run.stable = False
            run.unstable_at_s = n_run * DT
            run.abort_reason = 'stroke limit exceeded'
        out.append(run)
    return out


def test_write_report(runs, tmp_path):
    paths = write_report(runs, tmp_path / 'report', title='test report')
    summary = json.loads(paths.summary_json.read_text())  # strict: NaN would not parse back
    assert len(summary['runs']) == 3
    assert [e['alpha'] for e in summary['runs']] == [0.0, 0.5, 1.5]
    assert [e['stable'] for e in summary['runs']] == [True, True, False]
    assert summary['runs'][2]['unstable_at_s'] == pytest.approx(6.0)
    assert summary['runs'][0]['lag_s'] == pytest.approx(0.01, abs=1e-5)
    assert summary['runs'][0]['nrms']['force'] < 1e-4
    hf = [e['high_frequency_force_fraction'] for e in summary['runs'][:2]]
    assert hf[0] < 0.05 < hf[1]  # the added 45 Hz vibration shows up

    for png in paths.figures:
        assert png.exists() and png.stat().st_size > 10_000
        assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'

    md = paths.report_md.read_text()
    assert md.startswith('# test report')
    for name in ('displacement', 'force', 'acceleration'):
        assert md.count(f'| {name} [') == 3  # one row per signal and run
    assert '| signal | peak test | peak ref | peak ratio | lag [ms] | NRMS [%] |' in md
    assert '**aborted at t = 6.000 s**: stroke limit exceeded' in md
    assert md.count('**stable**') == 2
    assert 'I/O latency = 3 ms' in md and 'dt = 2 ms' in md  # servohydraulic: no tau
    assert '(time_histories.png)' in md and '(time_histories_zoom.png)' in md
    # The displacement row of the alpha = 0 run: 10 ms lag, NRMS 0.00 %.
    row = next(line for line in md.splitlines() if line.startswith('| displacement'))
    cells = [c.strip() for c in row.strip('|').split('|')]
    assert cells[3] == '1.000' and cells[4] == '10.00' and cells[5] == '0.00'


def test_write_summary_json_writes_null_for_nan(tmp_path):
    path = write_summary_json([{'nrms': {'force': math.nan}, 'lag_s': np.float64(np.inf)}],
                              tmp_path / 'sub' / 'summary.json')
    assert json.loads(path.read_text()) == {'runs': [{'nrms': {'force': None}, 'lag_s': None}]}


def test_write_report_errors(tmp_path):
    with pytest.raises(ParameterError, match='at least one run'):
        write_report([], tmp_path)
