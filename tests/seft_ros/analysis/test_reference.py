"""The reference analysis against closed-form SDOF solutions (not against lsim itself)."""

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.reference import reference_from_run, reference_response
from seft_ros.analysis.rundata import RunData

# The reference rig (paper Sec. 3.1): 52.7 kg, 2.11e5 N/m, c = 17.14 m, dt = 2 ms.
M = 52.7
K = 2.11e5
C = 17.14 * M
DT = 0.002


@pytest.fixture
def rig():
    return {'mass_kg': M, 'damping_N_s_per_m': C, 'stiffness_N_per_m': K, 'dt': DT}


def _fit_harmonic(t, x, omega):
    """Least-squares amplitude and phase of x = A sin(omega t - phi)."""
    basis = np.column_stack([np.sin(omega * t), np.cos(omega * t)])
    (s, c), *_ = np.linalg.lstsq(basis, x, rcond=None)
    return np.hypot(s, c), np.arctan2(-c, s)


@pytest.mark.parametrize('alpha', [0.0, 0.5, 1.0])
def test_harmonic_steady_state_matches_closed_form(rig, alpha):
    # xg'' = A sin(w t): steady state x = X sin(w t - phi) of the SDOF with mass (1+alpha) m,
    # X = M_t A / sqrt((k - M_t w^2)^2 + (c w)^2) (sign -1), phi = atan2(c w, k - M_t w^2).
    total = (1 + alpha) * M
    amp, omega = 3.0, 2 * np.pi * 7.0
    t = np.arange(int(10.0 / DT)) * DT
    ref = reference_response(alpha=alpha, ground_acceleration_m_s2=amp * np.sin(omega * t),
                             **rig)
    x_amp = total * amp / np.hypot(K - total * omega**2, C * omega)
    phase = np.arctan2(C * omega, K - total * omega**2)
    steady = t > 6.0  # transients decay as exp(-zeta w_n t) < 1e-9 after 6 s
    amp_fit, phase_fit = _fit_harmonic(t[steady], -ref.displacement_m[steady], omega)
    # Linear interpolation of the sampled sine attenuates it by ~ (w dt)^2/12 = 6.4e-4.
    assert amp_fit == pytest.approx(x_amp, rel=1e-3)
    assert phase_fit == pytest.approx(phase, abs=1e-3)
    closed = -x_amp * np.sin(omega * t[steady] - phase)
    assert np.max(np.abs(ref.displacement_m[steady] - closed)) < 1e-3 * x_amp
    closed_v = -x_amp * omega * np.cos(omega * t[steady] - phase)
    assert np.max(np.abs(ref.velocity_m_s[steady] - closed_v)) < 1e-3 * x_amp * omega


@pytest.mark.parametrize('alpha', [0.0, 1.0])
def test_step_ground_acceleration_matches_damped_step_response(rig, alpha):
    # xg'' = a0 from t = 0, at rest: x = -(a0/wn^2)[1 - e^{-s t}(cos wd t + s/wd sin wd t)],
    # v = -(a0/wd) e^{-s t} sin wd t, with s = zeta wn.
    total = (1 + alpha) * M
    a0 = 2.5
    n = int(3.0 / DT)
    t = np.arange(n) * DT
    ref = reference_response(alpha=alpha, ground_acceleration_m_s2=np.full(n, a0), **rig)
    wn = np.sqrt(K / total)
    sigma = C / (2 * total)
    wd = np.sqrt(wn**2 - sigma**2)
    decay = np.exp(-sigma * t)
    x = -(a0 / wn**2) * (1 - decay * (np.cos(wd * t) + sigma / wd * np.sin(wd * t)))
    v = -(a0 / wd) * decay * np.sin(wd * t)
    static = a0 / wn**2
    # The hold is exact for a constant input: agreement to rounding.
    np.testing.assert_allclose(ref.displacement_m, x, rtol=0, atol=1e-9 * static)
    np.testing.assert_allclose(ref.velocity_m_s, v, rtol=0, atol=1e-9 * static * wn)
    assert ref.acceleration_m_s2[0] == pytest.approx(-a0)
    assert ref.displacement_m[-1] == pytest.approx(-static, rel=1e-3)
    assert ref.force_N[-1] == pytest.approx(-(1 + alpha) * M * a0, rel=1e-3)


def test_alpha_equals_sdof_with_total_mass_and_force_identity(rig):
    rng = np.random.default_rng(3)
    ag = np.cumsum(rng.normal(size=3000)) * 0.05
    alpha = 1.0
    ref = reference_response(alpha=alpha, ground_acceleration_m_s2=ag, **rig)
    sdof = reference_response(alpha=0.0, ground_acceleration_m_s2=ag,
                              **{**rig, 'mass_kg': (1 + alpha) * M})
    scale = np.max(np.abs(sdof.displacement_m))
    np.testing.assert_allclose(ref.displacement_m, sdof.displacement_m, atol=1e-12 * scale)
    np.testing.assert_allclose(ref.acceleration_m_s2, sdof.acceleration_m_s2,
                               atol=1e-9 * np.max(np.abs(sdof.acceleration_m_s2)))
    # Member force (Eq. 2.4) equals the substructure reference force (Eq. 2.5).
    member = M * ref.acceleration_m_s2 + C * ref.velocity_m_s + K * ref.displacement_m
    eq_2_5 = -(1 + alpha) * M * ag - alpha * M * ref.acceleration_m_s2
    fscale = np.max(np.abs(eq_2_5))
    np.testing.assert_allclose(ref.force_N, member, atol=1e-9 * fscale)
    np.testing.assert_allclose(ref.force_N, eq_2_5, atol=1e-9 * fscale)
    np.testing.assert_allclose(ref.time_s, np.arange(3000) * DT)


def test_short_records(rig):
    empty = reference_response(alpha=0.5, ground_acceleration_m_s2=[], **rig)
    assert empty.n_steps == 0 and empty.force_N.shape == (0,)
    one = reference_response(alpha=0.5, ground_acceleration_m_s2=[2.0], **rig)
    assert one.displacement_m[0] == 0 and one.acceleration_m_s2[0] == -2.0
    assert one.force_N[0] == pytest.approx(-1.5 * M * 2.0 + 0.5 * M * 2.0)


@pytest.mark.parametrize('name, value', [
    ('alpha', -0.1), ('alpha', float('nan')), ('mass_kg', 0.0), ('damping_N_s_per_m', -1.0),
    ('stiffness_N_per_m', float('inf')), ('dt', 0.0), ('dt', True), ('mass_kg', '52.7'),
])
def test_bad_parameter_is_named(rig, name, value):
    kwargs = {'alpha': 0.5, **rig, name: value}
    with pytest.raises(ParameterError, match=f'parameter {name}='):
        reference_response(ground_acceleration_m_s2=np.zeros(10), **kwargs)


@pytest.mark.parametrize('ag, match', [
    (np.zeros((3, 2)), 'finite 1-D array'), ([0.0, float('nan')], 'non-finite'),
    (['a', 'b'], 'array of floats'),
])
def test_bad_ground_acceleration(rig, ag, match):
    with pytest.raises(ParameterError, match=match):
        reference_response(alpha=0.0, ground_acceleration_m_s2=ag, **rig)


def _run(params, n=200):
    t = np.arange(n) * DT
    z = np.zeros(n)
    return RunData.one_rig(params=params, time_s=t, ground_acceleration_m_s2=np.sin(20 * t),
                   reference_force_N=z, measured_force_N=z, displacement_m=z, velocity_m_s=z,
                   acceleration_m_s2=z)


def test_reference_from_run(rig):
    run = _run({'alpha': 0.5, **rig, 'rig_model': 'delay'})
    ref = reference_from_run(run)
    direct = reference_response(alpha=0.5, ground_acceleration_m_s2=run.ground_acceleration_m_s2,
                                **rig)
    np.testing.assert_array_equal(ref.displacement_m, direct.displacement_m)
    with pytest.raises(ParameterError, match='missing alpha, dt'):
        reference_from_run(_run({'mass_kg': M, 'damping_N_s_per_m': C,
                                 'stiffness_N_per_m': K}))


def test_signal_names(rig):
    ref = reference_response(alpha=0.0, ground_acceleration_m_s2=np.ones(5), **rig)
    assert ref.signal('force') is ref.force_N
    with pytest.raises(ParameterError, match="signal 'velocity'"):
        ref.signal('velocity')


def _study_reference_before_structures(alpha, ag, hysteretic=None):
    """The study's reference as it was computed before every test was a structure (the
    one-DOF code, kept here to hold the general one to it): ``(x, v, a, force)``."""
    from scipy import integrate, signal
    total, n = (1.0 + alpha) * M, ag.shape[0]
    t = np.arange(n) * DT
    if hysteretic is None:
        a_mat = np.array([[0.0, 1.0], [-K / total, -C / total]])
        system = signal.StateSpace(a_mat, np.array([[0.0], [-1.0]]), np.eye(2), np.zeros((2, 1)))
        _, _, states = signal.lsim(system, ag, t, interp=True)
        x, v = np.ascontiguousarray(states[:, 0]), np.ascontiguousarray(states[:, 1])
        a = -(C * v + K * x) / total - ag
        return x, v, a, M * a + C * v + K * x
    samples, last = ag.tolist(), n - 2
    restoring, rate = hysteretic.restoring_force, hysteretic.hysteretic_rate

    def rhs(time, y):
        x, v, z = y
        pos = time / DT
        i = min(max(int(pos), 0), last)
        xg = samples[i] + (pos - i) * (samples[i + 1] - samples[i])
        return [v, -(C * v + restoring(x, z)) / total - xg, rate(v, z)]

    w0, dy = 2.0 * np.pi * hysteretic.natural_frequency_hz, hysteretic.yield_displacement_m
    sol = integrate.solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0, 0.0], method='LSODA', t_eval=t,
                              rtol=1e-9, atol=1e-9 * np.array([dy, dy * w0, 1.0]), max_step=DT)
    x, v, z = (np.ascontiguousarray(row) for row in sol.y)
    fs = restoring(x, z)
    a = -(C * v + fs) / total - ag
    return x, v, a, M * a + C * v + fs


@pytest.mark.parametrize('alpha', [0.0, 0.5, 1.5])
@pytest.mark.parametrize('model', ['linear', 'bouc_wen'])
def test_the_one_dof_structure_is_the_study_reference(rig, alpha, model):
    """The general structure reference, one DOF with M = (1 + alpha) m: the study's numbers
    (the main job's table does not move). Yielding, bit for bit; linear, where the study
    stepped ``lsim``'s recurrence in Python and the structure steps the same recurrence in
    SLICOT's TF01MD, within 1e-12 of the peak (measured 2e-14 to 7e-13)."""
    from seft_plant_sim.specimen import BoucWenSpecimen
    t = np.arange(1000) * DT
    ag = 30.0 * np.sin(2 * np.pi * 3.0 * t) + np.random.default_rng(5).normal(size=t.shape)
    ref = reference_response(alpha=alpha, ground_acceleration_m_s2=ag, specimen_model=model,
                             **rig)
    member = BoucWenSpecimen(M, C, K) if model == 'bouc_wen' else None
    if member is not None:
        assert np.max(np.abs(ref.hysteretic_z)) > 0.9                 # it yields
    for got, want in zip((ref.displacement_m, ref.velocity_m_s, ref.acceleration_m_s2,
                          ref.force_N), _study_reference_before_structures(alpha, ag, member)):
        if member is not None:
            np.testing.assert_array_equal(got, want)
        else:
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))
