"""The pre-run actuator capacity check: v_max = k_q V_lim / A against the reference's peak."""

import pytest

from seft_msgs_py import parameters
from seft_ros.cli import api


def _runs(amplitude_N, alphas, rig='servohydraulic', reading='us_customary'):
    return [parameters.resolve({'alpha': a, 'amplitude_N': amplitude_N, 'predictor': 'model',
                                'rig_model': rig, 'rig_calibration': reading})
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


def test_warns_only_for_runs_beyond_the_valve_capacity():
    lines = []
    # the default record at 1000 N needs up to 0.97 m/s at alpha = 2: within 2.0 m/s
    api.check_capacity(runs=_runs(1000.0, [0.0, 0.5, 1.0, 1.5, 2.0]), progress=lines.append)
    assert lines == []
    # at 2500 N, alpha = 2 needs 2.4 m/s
    api.check_capacity(runs=_runs(2500.0, [1.0, 2.0]), progress=lines.append)
    assert [ln.split(' (')[0] for ln in lines] == ['warning: alpha=2']
    assert '2.00 m/s at 10 V' in lines[0]
    lines.clear()
    # Eq. 3.1 in V/N: alpha >= 0.5 needs more than the valve's 0.45 m/s at 1000 N
    api.check_capacity(runs=_runs(1000.0, [0.0, 0.5, 1.0, 1.5], reading='si'),
                       progress=lines.append)
    assert [ln.split(' (')[0] for ln in lines] == ['warning: alpha=0.5', 'warning: alpha=1',
                                                  'warning: alpha=1.5']
    assert '0.67 m/s' in lines[1] and '0.45 m/s at 10 V' in lines[1]
    lines.clear()
    api.check_capacity(runs=_runs(500.0, [0.0, 0.5, 1.0, 1.5], reading='si'),
                       progress=lines.append)
    assert lines == []


def test_delay_rig_has_no_capacity_check():
    lines = []
    api.check_capacity(runs=_runs(1000.0, [1.5], rig='delay'), progress=lines.append)
    assert lines == []
