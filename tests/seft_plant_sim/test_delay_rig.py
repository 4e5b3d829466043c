"""Tests of the pure-delay rig (paper Sec. 5.2, Eqs. 5.1-5.2) against independent references."""

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_FORCE, Rig
from seft_msgs_py.parameters import defaults
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.specimen import LinearSpecimen

DT = 0.002
MASS = 52.7


@pytest.fixture(scope='module')
def specimen():
    """The reference study's mass-spring system (paper Sec. 3.1), c = 17.14 m."""
    return LinearSpecimen(MASS, 17.14 * MASS, 2.11e5)


def run(rig, forces):
    """Apply the reference forces one step each; return the readings before each step."""
    rows = []
    for f in forces:
        m = rig.measure()
        rows.append((m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
        rig.apply(f)
    return np.array(rows)


@pytest.mark.parametrize('tau, lag_steps', [
    (0.01, 5),          # the reference study: 5 whole steps
    (0.002, 1),         # one step
    (0.005, 3),         # 2.5 steps: f_r(t_k - tau) is the value held since t_k-3
    (0.0013, 1),        # below one step
])
def test_measured_force_is_delayed_reference(specimen, tau, lag_steps):
    fr = np.random.default_rng(3).standard_normal(200) * 1000.0
    out = run(DelayRig(specimen, DT, tau), fr)
    np.testing.assert_array_equal(out[lag_steps:, 0], fr[:-lag_steps])
    np.testing.assert_array_equal(out[:lag_steps, 0], 0.0)


@pytest.mark.parametrize('tau, substeps', [(0.01, 1), (0.005, 2), (0.0013, 20)])
def test_specimen_response_matches_lsim(specimen, tau, substeps):
    """x, v and a equal scipy.signal.lsim of the SDOF under the delayed, held force."""
    n = 400
    fr = np.random.default_rng(5).standard_normal(n) * 1000.0
    out = run(DelayRig(specimen, DT, tau), fr)
    h = DT / substeps
    lag = int(round(tau / h))
    assert abs(lag * h - tau) < 1e-12
    fine = np.concatenate([np.zeros(lag), np.repeat(fr, substeps)])[:n * substeps]
    a, b = specimen.state_space()
    sys = signal.StateSpace(a, b, np.eye(2), np.zeros((2, 1)))
    t = np.arange(n * substeps) * h
    _, y, _ = signal.lsim(sys, fine, t, interp=False)
    x_ref, v_ref = y[::substeps, 0], y[::substeps, 1]
    f_ref = fine[::substeps]                      # force held from t_k on (t_k+)
    a_ref = (f_ref - specimen.damping_N_s_per_m * v_ref
             - specimen.stiffness_N_per_m * x_ref) / MASS
    for got, ref in ((out[:, 1], x_ref), (out[:, 2], v_ref), (out[:, 3], a_ref)):
        assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_protocol_and_limits(specimen):
    rig = DelayRig(specimen, DT, 0.01)
    assert isinstance(rig, Rig)
    assert rig.command_kind == COMMAND_FORCE
    for _ in range(5):
        assert rig.limit_violation() is None
        rig.apply(30e3)
    # the first 30 kN reaches the specimen tau = 10 ms later
    reason = rig.limit_violation()
    assert reason == 'force limit exceeded at t=0.010 s: |f|=3e+04 N > 24500 N'


def test_from_parameters(specimen):
    values = defaults()
    values.update(rig_model='delay', tau_s=0.006, noise_force_N=1.0)
    rig = DelayRig.from_parameters(values)
    assert (rig.dt, rig.tau_s, rig.specimen) == (0.002, 0.006, specimen)
    assert (rig._n, rig._delta) == (3, 0.0)
    assert rig.sensors.noise_force_N == 1.0


@pytest.mark.parametrize('dt, tau, match', [
    (0.0, 0.01, r'parameter dt=0\.0: expected float > 0'),
    (-0.002, 0.01, r'parameter dt=-0\.002: expected float > 0'),
    (float('nan'), 0.01, r'parameter dt=nan: expected float > 0'),
    (DT, 0.0, r'parameter tau_s=0\.0: expected float > 0'),
    (DT, -0.01, r'parameter tau_s=-0\.01: expected float > 0'),
    (DT, float('nan'), r'parameter tau_s=nan: expected float > 0'),
])
def test_parameter_errors(specimen, dt, tau, match):
    with pytest.raises(ParameterError, match=match):
        DelayRig(specimen, dt, tau)


def test_infinite_delay_is_a_parameter_error(specimen):
    with pytest.raises(ParameterError, match=r'parameter tau_s=inf'):
        DelayRig(specimen, DT, float('inf'))
