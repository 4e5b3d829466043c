"""The reference analysis of a structure with a hysteretic (Bouc-Wen) load-resisting member:
the study's one-DOF case against an independent RK4 solution, and a structure with a yielding
pier against a finer integration and against the linear solution in the linear limit."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.specimen import BoucWenSpecimen, make_specimen
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import (
    LINEAR_METHOD,
    NONLINEAR_METHOD,
    hysteretic_reference_response,
    reference_from_run,
    reference_response,
    run_reference,
    structure_reference,
)
from seft_ros.analysis.rundata import RunData
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepared_record
from seft_ros.core.structure import parse_structure
from seft_ros.core.structure import test_setup as setup_of

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


#: The two-pier bridge of config/two_piers.yaml: pier_a the study's specimen, pier_b 1.6 times
#: stiffer, the deck computational on a bearing on each pier.
BRIDGE = {'dofs': ['pier_a', 'pier_b', 'deck'],
          'physical': {'pier_a': 'pier_a', 'pier_b': 'pier_b'},
          'mass_matrix_kg': [[M, 0, 0], [0, M, 0], [0, 0, 2 * M]],
          'stiffness_matrix_N_per_m': [[2 * K, 0, -K], [0, K + 3.376e5, -K], [-K, -K, 2 * K]],
          'damping_matrix_N_s_per_m': [[1036.678, 0, -133.4], [0, 1036.678, -133.4],
                                       [-133.4, -133.4, 266.8]]}


def _bridge(**pier_a):
    """A 2 s run of the bridge with pier a's specimen Bouc-Wen (its parameters `pier_a`):
    ``(params, structure, specimens, record)``."""
    s = parse_structure(BRIDGE, rigs={'pier_a': {'specimen_model': 'bouc_wen', **pier_a},
                                      'pier_b': {'stiffness_N_per_m': 3.376e5}})
    params = parameters.resolve({'structure': s.to_json(), 'duration_s': 2.0})
    setup = setup_of(params)
    specimens = [make_specimen(setup.rig_params[r]) for r in setup.rig_names]
    return params, setup.structure, specimens, prepared_record(params).acceleration_m_s2


def _worst(got, want):
    """The largest difference per column over the column's peak."""
    return np.max(np.abs(got - want), axis=0) / np.max(np.abs(want), axis=0)


def test_structure_with_a_yielding_pier_against_a_finer_integration():
    """The error the docstring states: the default tolerances against 1e-12 (measured 1.5e-8 to
    6e-8 of the peaks on the whole default record, displacement, floor acceleration, force)."""
    params, structure, specimens, ag = _bridge()
    ref = structure_reference(structure, specimens, params['dt'], ag)
    fine = structure_reference(structure, specimens, params['dt'], ag, rtol=1e-12, atol=1e-12)
    assert ref.method == NONLINEAR_METHOD.format(rtol=1e-9, atol=1e-9)
    assert set(ref.hysteretic_z) == {'pier_a'}
    assert np.max(np.abs(ref.hysteretic_z['pier_a'])) > 0.99                 # pier a yields
    assert np.max(np.abs(fine.displacement_m[:, 0])) > 3 * specimens[0].yield_displacement_m
    for name in ('displacement_m', 'velocity_m_s', 'absolute_acceleration_m_s2',
                 'interface_force_N'):
        assert np.all(_worst(getattr(ref, name), getattr(fine, name)) < 1e-6), name
    # the equation of motion of the yielding pier at every sample: its load cell's force is
    # m x'' + c x' + f_s(x, z)
    pier = ref.rig('pier_a')
    fs = specimens[0].restoring_force(pier.displacement_m, pier.hysteretic_z)
    np.testing.assert_allclose(pier.restoring_force_N, fs, rtol=1e-15)
    c = specimens[0].damping_N_s_per_m
    np.testing.assert_allclose(pier.force_N, M * pier.acceleration_m_s2 + c * pier.velocity_m_s
                               + fs, rtol=0, atol=1e-9 * np.max(np.abs(pier.force_N)))
    assert ref.rig('pier_b').hysteretic_z is None


def test_structure_linear_limit_equals_the_linear_solution():
    """A Bouc-Wen pier with post-yield ratio 1 is the linear spring k x: the integrated
    structure equals the exact (first-order-hold) solution of the linear one (a closed form for the
    integrator's error)."""
    params, structure, specimens, ag = _bridge(post_yield_stiffness_ratio=1.0)
    hys = structure_reference(structure, specimens, params['dt'], ag)
    linear = [specimens[0].linearized(), specimens[1]]
    lin = structure_reference(structure, linear, params['dt'], ag)
    assert lin.hysteretic_z == {} and lin.method == LINEAR_METHOD
    for name in ('displacement_m', 'absolute_acceleration_m_s2', 'interface_force_N'):
        assert np.all(_worst(getattr(hys, name), getattr(lin, name)) < 1e-7), name


def test_run_reference_of_a_structure_run_with_a_yielding_pier():
    params, structure, specimens, ag = _bridge(yield_displacement_m=0.003)
    run = RunData(params=params, time_s=np.arange(ag.shape[0]) * DT,
                  ground_acceleration_m_s2=ag, rigs={})
    ref = run_reference(run)
    assert ref.dofs == ('pier_a', 'pier_b', 'deck') and ref.rigs == ('pier_a', 'pier_b')
    direct = structure_reference(structure, specimens, DT, ag)
    np.testing.assert_array_equal(ref.displacement_m, direct.displacement_m)
    assert specimens[0].yield_displacement_m == 0.003
    with pytest.raises(ParameterError, match='2 rigs'):
        reference_from_run(run)


def test_a_run_and_its_comparison_integrate_the_yielding_structure_once(monkeypatch):
    """A yielding member's run: its divergence guard's reference before the run and its
    comparison's after it are one integration (they were two, the same), and what the
    comparison holds is its own copy (a caller that changes it changes nothing kept)."""
    from seft_ros.analysis import reference
    calls = []
    real = reference._integrate_nonlinear

    def counted(*args):
        calls.append(args[4])                # dt
        return real(*args)

    monkeypatch.setattr(reference, '_integrate_nonlinear', counted)
    monkeypatch.setattr(reference, '_NONLINEAR', {})
    run = simulate({'rig_model': 'delay', 'specimen_model': 'bouc_wen', 'alpha': 0.5,
                    'duration_s': 2.0})
    first = compare_run(run).reference
    assert len(calls) == 1
    first.displacement_m[:] = 0.0
    again = compare_run(run).reference
    assert len(calls) == 1 and np.max(np.abs(again.displacement_m)) > DY
    # the integration kept equals a new one to the last bit
    monkeypatch.setattr(reference, '_NONLINEAR', {})
    fresh = compare_run(run).reference
    assert len(calls) == 2
    np.testing.assert_array_equal(fresh.displacement_m, again.displacement_m)
    np.testing.assert_array_equal(fresh.force_N, again.force_N)
