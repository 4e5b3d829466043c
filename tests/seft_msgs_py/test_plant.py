"""The force loop's plant as data (seft_msgs_py.plant): a lab's model read, sampled, stepped.

The reference for every sampled response is independent of the code's matrix exponentials:
the continuous model integrated by ``scipy.integrate.solve_ivp`` (RK45 at a 1e-10 relative
tolerance) under the held command, switched exactly at the delay's fractional instants.
"""

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.plant import (
    OUTPUTS,
    PlantModel,
    PlantUncertainty,
    Specimen,
    hold_factor,
    parse_plant,
    schur_response,
    step_average_of,
)

DT = 0.002
#: A lab's actuator as it might write it: a second-order valve (50 Hz, 0.67), an oil column
#: of 4.2e6 N/m and area 2e-3 m^2 behind it, flow gain 1.2e-4 m^3/(s V), K = 2e-12, on a
#: specimen of 29.13 kg, 1.19e6 N/m and 1 % damping; 3 ms of I/O latency.
M, K = 29.13, 1.19e6
C = 0.02 * math.sqrt(K * M)
AREA, CH, KQ, KL = 2.0e-3, 3.8e-3 / 4.0e9, 1.2e-4, 2e-12
WV, ZV = 2 * math.pi * 50.0, 0.67
LATENCY = 0.003
#: A specimen for the models that give the force alone.
SPECIMEN = {'mass_kg': 52.7, 'damping_N_s_per_m': 903.3, 'stiffness_N_per_m': 2.11e5}


def continuous():
    """States [x, v, p, xv, xv']; input u [V]; outputs (force, x, v, a)."""
    a = np.zeros((5, 5))
    a[0, 1] = 1.0
    a[1, :3] = [-K / M, -C / M, AREA / M]
    a[2, :4] = [0.0, -AREA / CH, -KL / CH, KQ / CH]
    a[3, 4] = 1.0
    a[4, 3:] = [-WV * WV, -2 * ZV * WV]
    b = np.zeros((5, 1))
    b[4, 0] = WV * WV
    c = np.zeros((4, 5))
    c[0, 2] = AREA
    c[1, 0] = 1.0
    c[2, 1] = 1.0
    c[3, :3] = a[1, :3]
    return a, b, c


def force_tf():
    """The valve-to-force transfer function in s (descending powers)."""
    spec = np.array([M, C, K])
    num = AREA * KQ * WV * WV * spec
    den = np.polymul([1.0, 2 * ZV * WV, WV * WV],
                     np.polyadd(np.polymul([CH, KL], spec), [AREA ** 2, 0.0]))
    return num, den


def reference_response(u, latency=LATENCY):
    """The continuous model's outputs at the samples for the held commands `u` (n,),
    integrated piecewise between the instants where the delayed command switches."""
    a, b, c = continuous()
    n = len(u)
    cuts = sorted({k * DT for k in range(n + 1)} | {k * DT + latency for k in range(n)})
    cuts = [t for t in cuts if t <= n * DT + 1e-15]
    x = np.zeros(5)
    out = np.zeros((n, 4))
    for t0, t1 in zip(cuts[:-1], cuts[1:]):
        k = int(math.floor((0.5 * (t0 + t1) - latency) / DT + 1e-12))
        uk = u[k] if 0 <= k < n else 0.0
        if t1 - t0 > 1e-15:
            sol = solve_ivp(lambda t, s: a @ s + b[:, 0] * uk, (t0, t1), x, rtol=1e-10,
                            atol=1e-14, method='RK45')
            x = sol.y[:, -1]
        j = int(round(t1 / DT))
        if abs(t1 - j * DT) < 1e-12 and j < n:
            out[j] = c @ x
    return out


@pytest.fixture(scope='module')
def commands():
    rng = np.random.default_rng(3)
    return rng.standard_normal(60) * 0.05


@pytest.fixture(scope='module')
def expected(commands):
    return reference_response(commands)


def simulate(plant: PlantModel, u) -> np.ndarray:
    s = np.zeros(plant.order)
    out = np.zeros((len(u), 4))
    for k, uk in enumerate(u):
        out[k] = plant.c @ s
        s = plant.a @ s + plant.b[:, 0] * uk
    return out


def scale(expected):
    return np.max(np.abs(expected), axis=0)


def test_a_continuous_state_space_is_sampled_exactly(commands, expected):
    a, b, c = continuous()
    doc = {'form': 'state_space', 'io_delay_s': LATENCY, 'a': a.tolist(), 'b': b[:, 0].tolist(),
           'c': {name: c[i].tolist() for i, name in enumerate(OUTPUTS)}}
    plant = parse_plant(doc, dt=DT)
    got = simulate(plant, commands)
    np.testing.assert_allclose(got / scale(expected), expected / scale(expected), atol=1e-7)


def test_a_transfer_function_of_the_force_with_its_specimen_gives_the_motion_too(
        commands, expected):
    """The lab gives only the valve-to-force transfer function and its specimen: the motion
    follows from m x'' + c x' + k x = f (paper Eq. 5.1), exactly in continuous time."""
    num, den = force_tf()
    doc = {'form': 'transfer_function', 'io_delay_s': LATENCY,
           'num': {'force_N': num.tolist()}, 'den': den.tolist(),
           'specimen': {'mass_kg': M, 'damping_N_s_per_m': C, 'stiffness_N_per_m': K}}
    plant = parse_plant(json.dumps(doc), dt=DT)
    got = simulate(plant, commands)
    np.testing.assert_allclose(got / scale(expected), expected / scale(expected), atol=1e-7)
    assert plant.specimen == Specimen(M, C, K)
    assert plant.specimen.natural_frequency_hz == pytest.approx(32.17, abs=0.01)
    assert plant.specimen.damping_ratio == pytest.approx(0.01)


def test_a_discrete_model_is_taken_as_it_is_and_its_delay_in_whole_steps(commands):
    a = [[0.9, 0.1], [-0.2, 0.8]]
    b = [0.0, 1.0]
    rows = {'force_N': [3.0, 1.0], 'displacement_m': [1e-4, 0.0], 'velocity_m_s': [0.0, 1e-3],
            'acceleration_m_s2': [0.1, 0.2]}
    plant = parse_plant({'form': 'state_space', 'dt': DT, 'io_delay_s': 2 * DT, 'a': a, 'b': b,
                         'c': rows}, dt=DT)
    assert plant.order == 4                      # two delay states
    got = simulate(plant, commands)
    s, want = np.zeros(2), np.zeros((len(commands), 4))
    delayed = np.concatenate([[0.0, 0.0], commands])
    for k in range(len(commands)):
        want[k] = [np.dot(rows[o], s) for o in OUTPUTS]
        s = np.array(a) @ s + np.array(b) * delayed[k]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_the_motion_of_a_discrete_force_model_is_within_its_first_order_hold(commands,
                                                                           expected):
    """A discrete force model's motion through the specimen sampled with a first-order hold:
    its displacement off the plant's by the hold's (omega dt)^2/12 (0.5 % at 20 Hz, 2 ms), its
    acceleration by (omega_n dt)^2/12 everywhere: a lab should give all four outputs when it
    has them (seft identify does)."""
    a, b, c = continuous()
    exact = parse_plant({'form': 'state_space', 'io_delay_s': LATENCY, 'a': a.tolist(),
                         'b': b[:, 0].tolist(),
                         'c': {n: c[i].tolist() for i, n in enumerate(OUTPUTS)}}, dt=DT)
    disc = parse_plant({'form': 'state_space', 'dt': DT, 'a': exact.a.tolist(),
                        'b': exact.b[:, 0].tolist(), 'c': {'force_N': exact.c[0].tolist()},
                        'specimen': {'mass_kg': M, 'damping_N_s_per_m': C,
                                     'stiffness_N_per_m': K}}, dt=DT)
    f = np.array([1.0, 5.0, 10.0, 20.0])
    bound = (2 * np.pi * f * DT) ** 2 / 12.0
    ratio = (disc.frequency_response(f, 'displacement_m')
             / exact.frequency_response(f, 'displacement_m'))
    assert np.all(np.abs(ratio - 1.0) <= 1.05 * bound)
    # the acceleration (f - c v - k x)/m: the displacement's error times k over its own
    # size, (omega_n dt)^2/12 with the specimen's natural frequency (1.3 % here)
    ratio = (disc.frequency_response(f, 'acceleration_m_s2')
             / exact.frequency_response(f, 'acceleration_m_s2'))
    bound_a = (math.sqrt(K / M) * DT) ** 2 / 12.0
    assert np.all(np.abs(ratio - 1.0) <= 1.05 * bound_a)
    assert np.all(np.abs(ratio - 1.0) >= 0.9 * bound_a)


def test_the_mapping_and_its_json_give_the_same_model_back(commands):
    num, den = force_tf()
    doc = {'form': 'transfer_function', 'io_delay_s': LATENCY, 'num': {'force_N': num.tolist()},
           'den': den.tolist(), 'specimen': {'mass_kg': M, 'damping_N_s_per_m': C,
                                             'stiffness_N_per_m': K},
           'uncertainty': {'relative': 0.03, 'band_hz': [0.5, 40.0], 'frequency': 0.002}}
    plant = parse_plant(doc, dt=DT)
    again = PlantModel.from_mapping(json.loads(plant.to_json()), dt=DT)
    np.testing.assert_array_equal(again.a, plant.a)
    np.testing.assert_array_equal(again.c, plant.c)
    assert again.uncertainty == PlantUncertainty(0.03, (0.5, 40.0), '', 0.002)
    assert again.specimen == plant.specimen


def test_frequency_response_is_the_model_evaluated_on_the_unit_circle():
    plant = parse_plant({'form': 'state_space', 'dt': DT, 'a': [[0.5]], 'b': [1.0],
                         'c': {'force_N': [2.0], 'displacement_m': [0.0],
                               'velocity_m_s': [0.0], 'acceleration_m_s2': [0.0]}}, dt=DT)
    f = np.array([0.0, 10.0, 100.0])
    z = np.exp(2j * np.pi * f * DT)
    np.testing.assert_allclose(plant.frequency_response(f), 2.0 / (z - 0.5), rtol=1e-14)


def test_hold_factor_is_the_step_average_of_a_sinusoid():
    f, dt = 37.0, 0.002
    w = 2 * np.pi * f
    t = np.linspace(0.0, dt, 20001)
    avg = np.trapezoid(np.exp(1j * w * t), t) / dt
    assert hold_factor([f], dt)[0] == pytest.approx(avg, rel=1e-8)
    assert hold_factor([0.0], dt)[0] == 1.0
    # the step average of a sampled sinusoid
    y = np.sin(2 * np.pi * 10.0 * np.arange(4096) * dt)
    want = (np.cos(2 * np.pi * 10.0 * np.arange(4096) * dt)
            - np.cos(2 * np.pi * 10.0 * (np.arange(4096) + 1) * dt)) / (2 * np.pi * 10.0 * dt)
    np.testing.assert_allclose(step_average_of(y, dt)[500:3500], want[500:3500], atol=2e-3)


def test_the_held_force_is_the_force_of_a_plant_that_holds_its_force():
    """A specimen driven by a held force delayed two steps: the held force the model
    computes from its motion is that force, exactly (the measured force, the spring's and
    the damper's here, plays no part)."""
    from scipy.signal import cont2discrete
    sa = np.array([[0.0, 1.0], [-K / M, -C / M]])
    sb = np.array([[0.0], [1.0 / M]])
    phi, gam, *_ = cont2discrete((sa, sb, np.eye(2), np.zeros((2, 1))), DT, 'zoh')
    plant = parse_plant({'form': 'state_space', 'dt': DT, 'io_delay_s': 2 * DT,
                         'a': phi.tolist(), 'b': gam[:, 0].tolist(),
                         'c': {'force_N': [K, C], 'displacement_m': [1.0, 0.0],
                               'velocity_m_s': [0.0, 1.0], 'acceleration_m_s2': [0.0, 0.0]},
                         'specimen': {'mass_kg': M, 'damping_N_s_per_m': C,
                                      'stiffness_N_per_m': K}}, dt=DT)
    u = np.random.default_rng(1).standard_normal(30)
    out = simulate(plant, np.concatenate([u, [0.0]]))
    held = plant.held_force(out[:, 1:3])
    np.testing.assert_allclose(held[2:], u[:-2], rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize('doc, message', [
    ('nonsense', r'^plant_model: not JSON'),
    ({'form': 'zpk'}, r"^plant_model.form='zpk': expected one of 'state_space', "
                      r"'transfer_function'$"),
    ({'form': 'state_space', 'a': [[1.0]], 'b': [1.0], 'c': {'displacement_m': [1.0]}},
     r'^plant_model.c: expected the force_N output'),
    ({'form': 'state_space', 'a': [[1.0]], 'b': [1.0], 'c': {'force': [1.0]}},
     r"^plant_model.c: unknown output 'force'"),
    ({'form': 'state_space', 'a': [[1.0]], 'b': [1.0, 2.0], 'c': {'force_N': [1.0]}},
     r'^plant_model.b: expected 1 numbers'),
    ({'form': 'state_space', 'a': [[1.0]], 'b': [1.0], 'c': {'force_N': [1.0]}, 'd': 0.5},
     r'^plant_model.d: expected zero \(no feedthrough'),
    ({'form': 'transfer_function', 'num': {'force_N': [1.0, 2.0]}, 'den': [1.0, 3.0]},
     r'^plant_model.num.force_N: expected a strictly proper transfer function'),
    ({'form': 'state_space', 'dt': 0.001, 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]}},
     r"^plant_model.dt=0.001: a discrete model must have the run's period dt=0.002 s"),
    ({'form': 'state_space', 'dt': DT, 'io_delay_s': 0.003, 'a': [[0.5]], 'b': [1.0],
      'c': {'force_N': [1.0]}, 'specimen': {'mass_kg': 1.0, 'damping_N_s_per_m': 1.0,
                                            'stiffness_N_per_m': 1.0}},
     r'^plant_model.io_delay_s=0.003: a discrete model takes whole steps'),
    ({'form': 'state_space', 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]}},
     r'^plant_model: outputs displacement_m, velocity_m_s, acceleration_m_s2 are missing'),
    ({'form': 'state_space', 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]},
      'specimen': {'mass_kg': -1.0}}, r'^plant_model.specimen.mass_kg=-1.0: expected a number '
                                      r'> 0$'),
    ({'form': 'state_space', 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]}, 'gain': 2},
     r'^plant_model: unknown field\(s\) gain; expected some of'),
    # a misspelt key of the specimen or the uncertainty is named, not read as missing
    ({'form': 'state_space', 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]},
      'specimen': {'mass_kg': 52.7, 'damping': 903.3, 'stiffness_N_per_m': 2.11e5}},
     r'^plant_model.specimen: unknown field\(s\) damping; expected some of '
     r'damping_N_s_per_m, mass_kg, stiffness_N_per_m$'),
    ({'form': 'state_space', 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]},
      'specimen': SPECIMEN, 'uncertainty': {'relativ': 0.5}},
     r'^plant_model.uncertainty: unknown field\(s\) relativ; expected some of band_hz, '
     r'frequency, note, peak_force_N, peak_velocity_m_s, relative$'),
    # a delay of 2 s (meant: 2 ms) would be 1000 states
    ({'form': 'state_space', 'io_delay_s': 2.0, 'a': [[-1.0]], 'b': [1.0],
      'c': {'force_N': [1.0]}, 'specimen': SPECIMEN},
     r"^plant_model.io_delay_s=2: expected at most 50 steps of the run's dt=0.002 s \(0.1 s; "
     r'each step is a state of the sampled model\)$'),
    # a force that does not depend on the valve command
    ({'form': 'transfer_function', 'num': {'force_N': [0.0]}, 'den': [1.0, 3.0],
      'specimen': SPECIMEN},
     r'^plant_model.num.force_N: all zero: the force does not depend on the valve command; '
     r'expected a non-zero numerator$'),
    ({'form': 'state_space', 'a': [[-1.0]], 'b': [1.0], 'c': {'force_N': [0.0]},
      'specimen': SPECIMEN},
     r'^plant_model.c.force_N: the force does not depend on the valve command'),
    ({'form': 'state_space', 'a': [[-1.0, 0.0], [0.0, -2.0]], 'b': [1.0, 0.0],
      'c': {'force_N': [0.0, 5.0]}, 'specimen': SPECIMEN},      # a state b never reaches
     r'^plant_model.c.force_N: the force does not depend on the valve command \(c.force_N '
     r'\(sI - a\)\^-1 b is zero\); expected the force row of the model$'),
    ({'form': 'state_space', 'a': [[-1.0]], 'b': [0.0], 'c': {'force_N': [1.0]},
      'specimen': SPECIMEN},
     r'^plant_model.b: all zero: the valve command drives nothing'),
])
def test_a_bad_model_is_refused_in_one_line_naming_the_field(doc, message):
    with pytest.raises(ParameterError, match=message):
        parse_plant(doc, dt=DT)


def test_the_io_delay_bound_is_the_longest_loop_delay_a_compensator_inverts():
    """50 steps of dt are accepted (the largest predictor_loop_delay_steps); one more is not."""
    from seft_msgs_py.parameters import spec
    from seft_msgs_py.plant import MAX_IO_DELAY_STEPS
    assert MAX_IO_DELAY_STEPS == spec('predictor_loop_delay_steps').maximum
    doc = {'form': 'state_space', 'dt': DT, 'a': [[0.5]], 'b': [1.0], 'c': {'force_N': [1.0]},
           'specimen': SPECIMEN, 'io_delay_s': MAX_IO_DELAY_STEPS * DT}
    assert parse_plant(doc, dt=DT).order == 1 + 2 + MAX_IO_DELAY_STEPS
    with pytest.raises(ParameterError, match=r'^plant_model.io_delay_s=0.102: expected at most '):
        parse_plant(dict(doc, io_delay_s=(MAX_IO_DELAY_STEPS + 1) * DT), dt=DT)


def test_schur_response_is_the_closed_form_at_many_points():
    """``schur_response`` against closed forms: a first-order lag ``1 / (z - 0.9)``, and a
    defective ``a`` (a two-step shift register: ``z^-2``, no modal sum), radius included."""
    z = np.exp(2j * np.pi * np.linspace(0.0, 0.49, 200))
    response, radius = schur_response(np.array([[0.9]]), [1.0], [1.0], z)
    np.testing.assert_allclose(response, 1.0 / (z - 0.9), rtol=1e-12)
    assert radius == pytest.approx(0.9, abs=1e-15)
    shift = np.array([[0.0, 1.0], [0.0, 0.0]])
    response, radius = schur_response(shift, [0.0, 1.0], [1.0, 0.0], z)
    np.testing.assert_allclose(response, z ** -2, rtol=1e-12)
    assert radius == 0.0


def test_a_declared_specimen_is_measured_against_the_plant_models_own():
    """``Specimen.mismatch``: the ratios m/m0 and k/k0 when either lies beyond the tolerance
    (a mass typed in grams is 1000 x), None within it."""
    own = Specimen(29.13, 73.6, 1.19e6)
    assert own.mismatch(29.13e3, 1.19e6, 0.1) == pytest.approx((1000.0, 1.0))
    assert own.mismatch(29.13, 1.19e6 * 1.25, 0.1) == pytest.approx((1.0, 1.25))
    assert own.mismatch(29.13 * 1.09, 1.19e6 * 0.91, 0.1) is None
    assert own.mismatch(29.13 * 1.09, 1.19e6, 0.01) == pytest.approx((1.09, 1.0))
