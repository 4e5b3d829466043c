"""seft_plant_sim's family of actuators and the lab-model rig (rig_model actuator, state_space).

The family's rig is integrated with Runge-Kutta substeps; its linearization at rest
(``ActuatorSpec.linear_plant``) is sampled exactly. A linear member driven by a small command
must give the same samples both ways; a nonlinear one (orifice flow, friction) must differ
from its linearization exactly where its physics says.
"""

import math

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import resolve
from seft_plant_sim.actuator import FAMILY, ActuatorRig, actuator_spec
from seft_plant_sim.lti_rig import StateSpaceRig
from seft_plant_sim.rigs import make_rig
from seft_plant_sim.specimen import LinearSpecimen

DT = 0.002
SPECIMEN = {'mass_kg': 29.13, 'stiffness_N_per_m': 1.19e6, 'damping_N_s_per_m': 117.75}


def params(**extra):
    return resolve(dict(SPECIMEN, rig_model='actuator', **extra))


def linear_run(plant, u):
    s = np.zeros(plant.order)
    out = []
    for uk in u:
        out.append(plant.c @ s)
        s = plant.a @ s + plant.b[:, 0] * uk
    return np.array(out)


@pytest.fixture(scope='module')
def small():
    return np.random.default_rng(7).standard_normal(250) * 1e-3


@pytest.mark.parametrize('member', ['valve_2nd_order', 'valve_3_stage', 'leaky', 'pure_delay'])
def test_a_linear_member_steps_as_its_exact_sampling(member, small, drive):
    p = params(actuator_family=member)
    rig = make_rig(p)
    assert isinstance(rig, ActuatorRig)
    got = drive(rig, small)
    want = linear_run(rig.spec.linear_plant(LinearSpecimen.from_parameters(p), DT), small)
    scale = np.max(np.abs(want), axis=0)
    np.testing.assert_allclose(got / scale, want / scale, atol=2e-6)


def test_every_member_has_a_valve_of_40_hz_or_more_and_differs_from_the_others():
    specs = {m: actuator_spec(params(actuator_family=m)) for m in FAMILY}
    for m, s in specs.items():
        assert s.valve_bandwidth_hz() >= 40.0, m
    # a second-order valve's -3 dB frequency: r^2 = 1 - 2 z^2 + sqrt((1 - 2 z^2)^2 + 1)
    z = 0.67
    r = math.sqrt(1 - 2 * z * z + math.sqrt((1 - 2 * z * z) ** 2 + 1))
    assert specs['valve_2nd_order'].valve_bandwidth_hz() == pytest.approx(50.0 * r, rel=1e-3)
    assert specs['pure_delay'].io_delay_s == 0.007
    assert specs['orifice_flow'].supply_pressure_Pa == 21e6
    assert specs['coulomb_friction'].coulomb_friction_N == pytest.approx(420.0)
    # the leaky actuator's real pole near 0.5 Hz with the 1.19e6 N/m column
    plant = specs['leaky'].linear_plant(LinearSpecimen.from_parameters(params()), DT)
    slow = [-math.log(abs(z)) / DT / (2 * math.pi) for z in plant.poles()
            if abs(z.imag) < 1e-12 and 0 < z.real < 1]
    assert min(slow) == pytest.approx(0.5, rel=0.05)


def test_a_monte_carlo_draw_is_reproducible_and_within_its_spread():
    nominal = actuator_spec(params())
    a = actuator_spec(params(actuator_spread=0.3, actuator_seed=4))
    b = actuator_spec(params(actuator_spread=0.3, actuator_seed=4))
    c = actuator_spec(params(actuator_spread=0.3, actuator_seed=5))
    assert a == b and a != c
    for name in ('piston_area_m2', 'valve_hz', 'valve_flow_gain_m3_per_s_V', 'io_delay_s'):
        ratio = getattr(a, name) / getattr(nominal, name)
        assert 0.7 <= ratio <= 1.3 and ratio != 1.0
    with pytest.raises(ParameterError,
                       match=r'^parameter actuator_spread=0.95: expected 0 to 0.9'):
        nominal.spread(0.95, np.random.default_rng(1))


def test_orifice_flow_drops_with_the_load_pressure(drive):
    """Q = k_q x_v sqrt(1 - sgn(x_v) p_L/p_s): a held command against a stiff specimen builds
    pressure and its flow, hence its force rate, falls as sqrt(1 - p/p_s); the linear member
    keeps its rate."""
    u = np.full(400, 2.0)
    # the load cell unlimited: at its 24.5 kN range both read the same
    lin = drive(make_rig(params(actuator_family='valve_2nd_order', force_range_N=0.0)), u)
    ori = drive(make_rig(params(actuator_family='orifice_flow', force_range_N=0.0)), u)
    spec = actuator_spec(params(actuator_family='orifice_flow'))
    p_ratio = ori[-1, 0] / spec.piston_area_m2 / spec.supply_pressure_Pa
    assert 0.3 < p_ratio < 1.0
    assert abs(ori[-1, 0]) < abs(lin[-1, 0])


def test_coulomb_friction_takes_its_force_off_the_load_cell_while_sliding():
    """With the piston sliding (a soft 2 Hz specimen driven at 5 Hz) the load cell reads
    A p_L - F_c sgn(v): the friction member's force differs from its pressure's by F_c."""
    soft = dict(mass_kg=40.0, stiffness_N_per_m=40.0 * (2 * math.pi * 2.0) ** 2,
                damping_N_s_per_m=50.0)
    rig = make_rig(resolve(dict(soft, rig_model='actuator', actuator_family='coulomb_friction')))
    u = 2.0 * np.sin(2 * np.pi * 5.0 * np.arange(300) * DT)
    gaps = []
    for uk in u:
        rig.apply(uk)
        x, v, p = rig.state[:3]
        if abs(v) > 20 * rig.spec.friction_velocity_m_s:
            gaps.append((rig.spec.piston_area_m2 * p - rig.true_force()) * math.copysign(1.0, v))
    assert len(gaps) > 100
    np.testing.assert_allclose(gaps, rig.spec.coulomb_friction_N, rtol=1e-6)


def test_the_lab_model_rig_steps_its_plant_model_through_the_sensors(drive):
    plant = actuator_spec(params()).linear_plant(LinearSpecimen.from_parameters(params()), DT)
    p = resolve(dict(SPECIMEN, rig_model='state_space', plant_model=plant.to_json(),
                     noise_force_N=2.0, noise_seed=3))
    rig = make_rig(p)
    assert isinstance(rig, StateSpaceRig)
    u = np.random.default_rng(2).standard_normal(100) * 0.01
    got = drive(rig, u)
    want = linear_run(plant, u)
    np.testing.assert_allclose(got[:, 1:], want[:, 1:], rtol=1e-12, atol=1e-18)
    noise = got[:, 0] - want[:, 0]
    assert 1.5 < np.std(noise) < 2.5                      # the load cell's 2 N noise
    with pytest.raises(ParameterError, match=r"^rig_model 'state_space': expected plant_model"):
        make_rig(resolve(dict(SPECIMEN, rig_model='state_space')))


def test_the_family_drives_a_linear_specimen_only():
    with pytest.raises(ParameterError, match=r"^rig_model 'actuator': expected specimen_model "
                                             r"'linear'"):
        make_rig(params(specimen_model='bouc_wen'))


@pytest.mark.parametrize('member', sorted(FAMILY))
def test_the_unrolled_runge_kutta_steps_bit_for_bit_as_the_textbook_one(member):
    """``ActuatorRig._rk4`` (unrolled over the state's scalars for speed) against the
    classical fourth-order Runge-Kutta step written over lists (Kutta 1901; the form the rig
    had before), the same derivatives: every member's state equal to the last bit over 300
    steps of a command that opens the valve both ways (its three valve kinds, the orifice's
    square root and the friction's tanh included)."""
    p = params(actuator_family=member)
    rig = make_rig(p)
    size = len(rig._s)

    def rates(s, u):                    # the rig's derivatives of its own states
        return list(rig._rates(*s, *[0.0] * (6 - size), u))[:size]

    def textbook(s, u, h, n):
        for _ in range(n):
            k1 = rates(s, u)
            k2 = rates([a + 0.5 * h * b for a, b in zip(s, k1)], u)
            k3 = rates([a + 0.5 * h * b for a, b in zip(s, k2)], u)
            k4 = rates([a + h * b for a, b in zip(s, k3)], u)
            s = [a + h / 6.0 * (b1 + 2.0 * (b2 + b3) + b4)
                 for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]
        return s

    state = list(rig._s)
    for u in 2.0 * np.sin(np.arange(300) * 0.05):
        h = DT / 40
        want = textbook(state, float(u), h, 40)
        state = rig._rk4(state, float(u), h, 40)
        assert state == want and len(state) == size
    assert max(abs(v) for v in state) > 0
