"""The two readings of paper Eq. 3.1 (V/lbf, V/N): one force loop, two valves.

The loop numbers are derived here from the rig's equations (Merritt 1967, Ch. 5) typed anew,
then compared with the sampled-loop analysis of the code in both readings.
"""

import numpy as np
import pytest
from scipy import optimize

from seft_msgs_py import parameters
from seft_msgs_py.calibration import (
    CALIBRATIONS,
    DEFAULT_CALIBRATION,
    LBF_N,
    calibration,
    controller_gain_V_per_N,
    valve_flow_gain_m3_per_s_V,
)
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.servohydraulic import (
    ServoHydraulicParams,
    closed_loop_force_response,
    loop_margins,
    stability_boundary_alpha,
)
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.cli.api import actuator_velocity_limit_m_s
from seft_ros.core import stability
from seft_ros.core.controller import ForceServoController

#: 1 lbf [N] from its definition (0.45359237 kg x 9.80665 m/s^2).
LBF = 0.45359237 * 9.80665
#: The reference rig (paper Sec. 3.1) and the model constants of the default parameters.
M, C, K = 52.7, 17.14 * 52.7, 2.11e5
AREA, BETA, VT, TAU_V, KCE, TAU_IO, DT = 1.18e-3, 1e9, 3.35e-4, 0.0025, 1e-11, 0.003, 0.002
#: The two readings: force unit of Eq. 3.1 [N] and the valve flow gain [m^3/(s V)].
READINGS = {'us_customary': (LBF, 5.3e-5 * LBF), 'si': (1.0, 5.3e-5)}


def continuous_loop(f_hz, force_unit_N, kq):
    """L(j w) = C_f H_fu e^{-j w (tau_io + dt/2)}: paper Eq. 3.1 in V per `force_unit_N`, the
    valve-to-force function of Merritt's valve-controlled piston on the specimen, the I/O
    latency and the zero-order hold's half sample."""
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    cf = 37.0 / force_unit_N / (s ** 2 + 17.14 * s + 4002.0)
    spec = M * s ** 2 + C * s + K
    ch = VT / (4 * BETA)
    hfu = AREA * kq * spec / ((TAU_V * s + 1) * ((ch * s + KCE) * spec + AREA ** 2 * s))
    return cf * hfu * np.exp(-s * (TAU_IO + DT / 2))


def run_params(reading):
    return parameters.resolve({'rig_calibration': reading})


def sampled(reading):
    """The code's rig, specimen and controller of a reading, built from the parameters."""
    p = run_params(reading)
    return (ServoHydraulicParams.from_parameters(p), LinearSpecimen.from_parameters(p),
            ForceServoController.from_parameters(p))


def test_the_readings():
    assert LBF_N == LBF == pytest.approx(4.4482216152605, abs=1e-13)
    assert DEFAULT_CALIBRATION == 'us_customary'
    assert parameters.spec('rig_calibration').default == DEFAULT_CALIBRATION
    assert parameters.spec('rig_calibration').choices == tuple(CALIBRATIONS) == tuple(READINGS)
    for name, (unit, kq) in READINGS.items():
        p = run_params(name)
        assert calibration(p).name == name
        assert controller_gain_V_per_N(p) == pytest.approx(37.0 / unit, rel=1e-15)
        assert valve_flow_gain_m3_per_s_V(p) == pytest.approx(kq, rel=1e-15)
        # the loop gain (controller gain x valve flow gain) is the reading's invariant
        assert controller_gain_V_per_N(p) * valve_flow_gain_m3_per_s_V(p) == pytest.approx(
            37.0 * 5.3e-5, rel=1e-15)
    assert calibration({}).name == 'us_customary'


def test_explicit_valve_flow_gain_wins():
    p = parameters.resolve({'rig_calibration': 'si', 'valve_flow_gain_m3_per_s_V': 1e-4})
    assert valve_flow_gain_m3_per_s_V(p) == 1e-4
    assert ServoHydraulicParams.from_parameters(p).valve_flow_gain_m3_per_s_V == 1e-4
    assert controller_gain_V_per_N(p) == 37.0
    with pytest.raises(ParameterError, match=r"^parameter rig_calibration='V/N': expected one "
                       r"of 'us_customary', 'si'$"):
        calibration({'rig_calibration': 'V/N'})
    with pytest.raises(ParameterError, match='parameter rig_calibration'):
        parameters.resolve({'rig_calibration': 'lbf'})


@pytest.mark.parametrize('reading', list(READINGS))
def test_valve_velocity_at_10_volts(reading):
    """The crossover fixes k_q/A: Eq. 3.1 in V/lbf gives 4.448 times the velocity."""
    unit, kq = READINGS[reading]
    expected = kq * 10.0 / AREA              # 2.00 m/s (V/lbf), 0.449 m/s (V/N)
    assert expected == pytest.approx({'us_customary': 2.0, 'si': 0.45}[reading], rel=0.01)
    p = run_params(reading)
    assert actuator_velocity_limit_m_s(p) == pytest.approx(expected, rel=1e-12)
    rig, _, _ = sampled(reading)
    assert rig.valve_flow_gain_m3_per_s_V * 10.0 / rig.piston_area_m2 == pytest.approx(
        expected, rel=1e-12)


def test_zero_and_oil_column_do_not_depend_on_the_reading():
    """H_fu's zeros are the specimen's poles and its resonance is the oil column's: no k_q."""
    zero = np.abs(np.roots([M, C, K])) / (2 * np.pi)
    np.testing.assert_allclose(zero, 10.07, atol=0.01)
    ch = VT / (4 * BETA)
    poles = np.roots(np.polyadd(np.polymul([ch, KCE], [M, C, K]), [AREA ** 2, 0.0]))
    oil = np.abs(poles[np.abs(poles.imag) > 0]) / (2 * np.pi)
    np.testing.assert_allclose(oil, 90.2, atol=0.05)
    f = np.array([1.0, 10.07, 90.2, 200.0])
    np.testing.assert_allclose(continuous_loop(f, *READINGS['us_customary']),
                               continuous_loop(f, *READINGS['si']), rtol=1e-13)


def test_crossover_and_margins_are_the_same_in_both_readings():
    cont = {}
    for reading, (unit, kq) in READINGS.items():
        fc = optimize.brentq(lambda f: abs(continuous_loop(f, unit, kq)) - 1, 5.0, 30.0)
        f180 = optimize.brentq(lambda f: np.angle(-continuous_loop(f, unit, kq)), 25.0, 60.0)
        cont[reading] = (fc, 1 / abs(continuous_loop(f180, unit, kq)))
    assert cont['us_customary'] == pytest.approx(cont['si'], rel=1e-10)
    fc, gm = cont['si']
    assert fc == pytest.approx(13.68, abs=0.02)        # continuous approximation
    assert gm == pytest.approx(2.62, abs=0.02)
    mg = {r: loop_margins(*sampled(r)) for r in READINGS}
    for r in READINGS:   # the exact sampled loop: 13.62 Hz, 57.3 deg, 2.75 (Fig. 3c: 12 Hz)
        assert mg[r].crossover_hz == pytest.approx(fc, abs=0.1)
        assert mg[r].crossover_hz == pytest.approx(13.62, abs=0.05)
        assert mg[r].phase_margin_deg == pytest.approx(57.3, abs=0.5)
        assert mg[r].gain_margin == pytest.approx(2.75, abs=0.02)
    for name in ('crossover_hz', 'phase_margin_deg', 'gain_margin', 'phase_crossover_hz'):
        assert getattr(mg['us_customary'], name) == pytest.approx(getattr(mg['si'], name),
                                                                   rel=1e-9), name


def test_closed_loop_to_25hz_is_the_same_in_both_readings():
    f = np.linspace(0.5, 25.0, 491)
    t_cont = {}
    t_code = {}
    for reading, (unit, kq) in READINGS.items():
        loop = continuous_loop(f, unit, kq)
        t_cont[reading] = np.abs(loop / (1 + loop))
        t_code[reading] = np.abs(closed_loop_force_response(*sampled(reading), f))
    np.testing.assert_allclose(t_cont['us_customary'], t_cont['si'], rtol=1e-12)
    np.testing.assert_allclose(t_code['us_customary'], t_code['si'], rtol=1e-9)
    # flat within 0.9..1.06 (Fig. 4): continuous 0.944..1.053, sampled 0.915..1.047
    for mag in (t_cont['si'], t_code['si']):
        assert 0.9 < mag.min() and mag.max() < 1.06
    np.testing.assert_allclose(t_code['si'], t_cont['si'], atol=0.035)


def test_uncompensated_boundary_is_the_same_in_both_readings():
    rig = {r: sampled(r) for r in READINGS}
    boundary = {r: stability_boundary_alpha(*rig[r]) for r in READINGS}
    assert boundary['us_customary'] == pytest.approx(boundary['si'], abs=2e-4)   # bisection
    assert boundary['si'] == pytest.approx(1.317, abs=0.002)
    # the pre-run stability guard (its own loop model, from the run parameters) agrees
    for r in READINGS:
        guard = stability.largest_stable_alpha(dict(run_params(r), predictor='none'))
        assert guard == pytest.approx(1.317, abs=0.002), r


def test_time_stepped_runs_differ_only_in_the_valve_volts():
    """The same run in both readings: the same forces and motion, the valve command 4.448
    times smaller with Eq. 3.1 in V/lbf (the time-stepped rig, not the analysis). At 300 N,
    where the 'si' valve does not saturate either."""
    from seft_ros.core.experiment import simulate
    runs = {r: simulate(dict(run_params(r), alpha=1.0, duration_s=2.0, amplitude_N=300.0))
            for r in READINGS}
    us, si = runs['us_customary'], runs['si']
    assert us.stable and si.stable and np.max(np.abs(si.valve_command_V)) < 10.0
    scale = np.max(np.abs(si.measured_force_N))
    np.testing.assert_allclose(us.measured_force_N, si.measured_force_N, rtol=0,
                               atol=1e-9 * scale)
    np.testing.assert_allclose(us.valve_command_V * LBF, si.valve_command_V, rtol=0,
                               atol=1e-9 * np.max(np.abs(si.valve_command_V)))
