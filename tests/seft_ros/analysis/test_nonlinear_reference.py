"""The reference analysis of a structure with a hysteretic (Bouc-Wen) load-resisting member."""

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_plant_sim.specimen import BoucWenSpecimen
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import (
    hysteretic_reference_response,
    reference_from_run,
    reference_response,
)
from seft_ros.analysis.rundata import RunData
from seft_ros.core.experiment import simulate

M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002
DY = 0.004


@pytest.fixture
def member():
    return {'mass_kg': M, 'damping_N_s_per_m': C, 'stiffness_N_per_m': K, 'dt': DT}


def ground(n=1500, peak_force_N=1500.0):
    """Ground acceleration: ramped 3 Hz + 7 Hz sines, peak ``m xg''`` = `peak_force_N`."""
    t = np.arange(n) * DT
    ag = (np.sin(2 * np.pi * 3.0 * t) + 0.4 * np.sin(2 * np.pi * 7.0 * t + 1.0))
    ag *= np.minimum(1.0, t / 0.5) * np.exp(-np.maximum(t - 1.5, 0.0))
    return ag * peak_force_N / M / np.max(np.abs(ag))


def rk4_reference(specimen, alpha, ag, substeps=40):
    """Independent solution: classical RK4, `substeps` steps per sample, sgn(x' z) per stage,
    the ground acceleration linearly interpolated; returns [x, v, z] at the samples."""
    total = (1 + alpha) * specimen.mass_kg
    c = specimen.damping_N_s_per_m

    def rhs(t, y):
        x, v, z = y
        k = min(int(t / DT), len(ag) - 2)
        xg = ag[k] + (t / DT - k) * (ag[k + 1] - ag[k])
        return np.array([v, -(c * v + specimen.restoring_force(x, z)) / total - xg,
                         specimen.hysteretic_rate(v, z)])

    y = np.zeros(3)
    out = [y]
    h = DT / substeps
    ag = list(ag)
    for k in range(len(ag) - 1):
        for j in range(substeps):
            t = k * DT + j * h
            k1 = rhs(t, y)
            k2 = rhs(t + h / 2, y + h / 2 * k1)
            k3 = rhs(t + h / 2, y + h / 2 * k2)
            k4 = rhs(t + h, y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(y)
    return np.array(out)


def test_linear_limit_equals_linear_reference(member):
    # post-yield ratio 1: f_s = k x, the Bouc-Wen reference is the lsim one
    ag = ground()
    lin = reference_response(alpha=0.5, ground_acceleration_m_s2=ag, **member)
    hys = reference_response(alpha=0.5, ground_acceleration_m_s2=ag, specimen_model='bouc_wen',
                             post_yield_stiffness_ratio=1.0, **member)
    assert lin.hysteretic_z is None
    for name in ('displacement', 'force', 'acceleration'):
        ref = lin.signal(name)
        assert np.max(np.abs(hys.signal(name) - ref)) < 1e-7 * np.max(np.abs(ref)), name


@pytest.mark.parametrize('alpha', [0.0, 1.0])
def test_matches_independent_rk4(member, alpha):
    ag = ground()
    spec = BoucWenSpecimen(M, C, K)
    ref = hysteretic_reference_response(alpha=alpha, specimen=spec, dt=DT,
                                        ground_acceleration_m_s2=ag)
    indep = rk4_reference(spec, alpha, ag)
    assert np.max(np.abs(ref.displacement_m)) > 2 * DY          # the member yields
    for got, want in ((ref.displacement_m, indep[:, 0]), (ref.velocity_m_s, indep[:, 1]),
                      (ref.hysteretic_z, indep[:, 2])):
        assert np.max(np.abs(got - want)) < 1e-5 * np.max(np.abs(want))
    # force = m x'' + c x' + f_s = -(1+alpha) m xg'' - alpha m x'' (paper Eq. 2.5)
    np.testing.assert_allclose(
        ref.force_N, -(1 + alpha) * M * ag - alpha * M * ref.acceleration_m_s2,
        rtol=0, atol=1e-9 * np.max(np.abs(ref.force_N)))
    fs = spec.restoring_force(ref.displacement_m, ref.hysteretic_z)
    np.testing.assert_allclose(ref.force_N, M * ref.acceleration_m_s2 + C * ref.velocity_m_s
                               + fs, rtol=0, atol=1e-9 * np.max(np.abs(ref.force_N)))


def test_yielding_softens_and_comes_to_rest_on_the_hysteretic_branch(member):
    ag = ground(3000)
    ag[1500:] = 0.0                                              # 3 s of free vibration
    lin = reference_response(alpha=0.0, ground_acceleration_m_s2=ag, **member)
    hys = reference_response(alpha=0.0, ground_acceleration_m_s2=ag, specimen_model='bouc_wen',
                             **member)
    assert np.max(np.abs(hys.hysteretic_z)) > 0.99
    assert np.max(np.abs(hys.displacement_m)) > 1.15 * np.max(np.abs(lin.displacement_m))
    assert abs(lin.displacement_m[-1]) < 1e-9                    # at rest again
    # at rest: f_s = a k x + (1-a) k D_y z = 0, i.e. x = -9 D_y z with a = 0.1
    x_end, z_end = hys.displacement_m[-1], hys.hysteretic_z[-1]
    assert abs(hys.velocity_m_s[-1]) < 1e-6
    assert x_end == pytest.approx(-9 * DY * z_end, rel=1e-3, abs=1e-8)


def test_edge_cases_and_errors(member):
    spec = BoucWenSpecimen(M, C, K)
    one = hysteretic_reference_response(alpha=0.0, specimen=spec, dt=DT,
                                        ground_acceleration_m_s2=[2.0])
    assert one.n_steps == 1 and one.displacement_m[0] == 0.0 and one.force_N[0] == -2.0 * M
    assert hysteretic_reference_response(alpha=0.0, specimen=spec, dt=DT,
                                         ground_acceleration_m_s2=[]).n_steps == 0
    with pytest.raises(ParameterError, match="specimen_model='plastic'"):
        reference_response(alpha=0.0, ground_acceleration_m_s2=ground(10),
                           specimen_model='plastic', **member)
    with pytest.raises(ParameterError, match="unknown parameter 'bouc_wen_a'"):
        reference_response(alpha=0.0, ground_acceleration_m_s2=ground(10),
                           specimen_model='bouc_wen', bouc_wen_a=1.0, **member)
    with pytest.raises(ParameterError, match='yield_displacement_m=-1.0'):
        reference_response(alpha=0.0, ground_acceleration_m_s2=ground(10),
                           specimen_model='bouc_wen', yield_displacement_m=-1.0, **member)
    with pytest.raises(ParameterError, match='bouc_wen_n=nan'):
        reference_response(alpha=0.0, ground_acceleration_m_s2=ground(10),
                           specimen_model='bouc_wen', bouc_wen_n=float('nan'), **member)
    with pytest.raises(ParameterError, match='expected a BoucWenSpecimen'):
        hysteretic_reference_response(alpha=0.0, specimen=None, dt=DT,
                                      ground_acceleration_m_s2=ground(10))
    with pytest.raises(ParameterError, match='ground_acceleration_m_s2'):
        hysteretic_reference_response(alpha=0.0, specimen=spec, dt=DT,
                                      ground_acceleration_m_s2=[0.0, np.inf])


def _run(params, ag):
    n = ag.shape[0]
    zeros = np.zeros(n)
    return RunData.one_rig(params=params, time_s=np.arange(n) * DT, ground_acceleration_m_s2=ag,
                   reference_force_N=zeros, measured_force_N=zeros, displacement_m=zeros,
                   velocity_m_s=zeros, acceleration_m_s2=zeros)


def test_reference_from_run_dispatches_on_specimen_model(member):
    ag = ground(400)
    base = {'alpha': 0.0, **member}
    legacy = reference_from_run(_run(base, ag))                  # no specimen_model: linear
    assert legacy.hysteretic_z is None
    linear = reference_from_run(_run({**base, 'specimen_model': 'linear'}, ag))
    np.testing.assert_array_equal(linear.displacement_m, legacy.displacement_m)
    hys = reference_from_run(_run({**base, 'specimen_model': 'bouc_wen',
                                   'yield_displacement_m': 0.002, 'record': 'x'}, ag))
    direct = hysteretic_reference_response(
        alpha=0.0, specimen=BoucWenSpecimen(M, C, K, yield_displacement_m=0.002), dt=DT,
        ground_acceleration_m_s2=ag)
    np.testing.assert_array_equal(hys.displacement_m, direct.displacement_m)


def test_delay_rig_test_of_yielding_member_matches_reference():
    """alpha = 0 on the delay rig: only the 10 ms delay (and the held force) differ."""
    params = {'rig_model': 'delay', 'specimen_model': 'bouc_wen', 'alpha': 0.0,
              'duration_s': 6.0}
    run = simulate(params)
    assert run.stable
    cmp = compare_run(run)
    assert cmp.displacement.nrms < 0.03
    assert cmp.force.nrms < 0.03
    assert cmp.acceleration.nrms < 0.06        # the held actuator force: 3.9 % when linear
    assert cmp.displacement.lag_s == pytest.approx(0.011, abs=0.001)
    assert np.max(np.abs(run.displacement_m)) > 2 * DY                  # it yields
    assert np.max(np.abs(cmp.reference.hysteretic_z)) > 0.99
