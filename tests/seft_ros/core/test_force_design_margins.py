"""The design's criteria beyond the force loop's margins: the compensated test's plant-gain
margin and the crossover (session 24's explorer, problems 1 and 5), warned beside "targets
met", which keeps the loop's targets (session 25)."""

import copy
import json
import math

import numpy as np
import pytest

from seft_msgs_py.parameters import resolve
from seft_ros.core import force_design
from seft_ros.core.force_design import design_force_controller
from seft_ros.core.force_loop import force_loop_plant


def _leaky_plant():
    """Case H: a 54 Hz, damping 0.9 valve, 3 ms I/O delay, heavy leakage (the loaded pole
    at 2 Hz), a 2 Hz, 5 % specimen of 500 kg; dt 2 ms."""
    m, fs, zeta = 500.0, 2.0, 0.05
    k = m * (2 * math.pi * fs) ** 2
    c = 2 * zeta * math.sqrt(k * m)
    area, kq, w_v = 2e-3, 1.2e-4, 2 * math.pi * 54.0
    ch = area ** 2 / (m * (2 * math.pi * 60.0) ** 2 - k)
    leak = 2 * math.pi * 2.0 * (area ** 2 + ch * k) / k
    a = [[0, 1, 0, 0, 0], [-k / m, -c / m, area / m, 0, 0],
         [0, -area / ch, -leak / ch, kq / ch, 0], [0, 0, 0, 0, 1],
         [0, 0, 0, -w_v ** 2, -2 * 0.9 * w_v]]
    doc = {'form': 'state_space', 'io_delay_s': 0.003, 'a': a, 'b': [0, 0, 0, 0, w_v ** 2],
           'c': {'force_N': [0, 0, area, 0, 0], 'displacement_m': [1, 0, 0, 0, 0],
                 'velocity_m_s': [0, 1, 0, 0, 0], 'acceleration_m_s2': a[1]},
           'specimen': {'mass_kg': m, 'damping_N_s_per_m': c, 'stiffness_N_per_m': k}}
    return force_loop_plant(resolve({'rig_model': 'state_space', 'dt': 0.002,
                                     'plant_model': json.dumps(doc), 'mass_kg': m,
                                     'damping_N_s_per_m': c, 'stiffness_N_per_m': k}))


def test_the_leaky_loops_predicted_errors_do_not_ride_on_rounding():
    """The test loop on this plant (221 states in physical units: a norm of 3.2e6, and
    ``zI - M`` a condition number of 2.6e17 at 0.5-2 Hz): its frequency response unbalanced
    was 0.6-1 % off a direct solve, and the predicted errors that choose the inverse moved
    by up to 10 x with the plant's gain off by 1e-13 (3 to 11 steps: 0.04-10 %, another
    inverse on each host). Balanced, they are 0.002-0.02 % and the same to 1e-5 (cond 2e7)."""
    plant = _leaky_plant()
    d = design_force_controller(plant)
    nudged = copy.copy(plant)
    nudged.b = plant.b * (1 + 1e-13)
    for steps in (3, 4, 10):
        errors = force_design._predicted_errors(plant, d, steps)
        again = force_design._predicted_errors(nudged, d, steps)
        assert max(errors) < 0.001, (steps, errors)
        np.testing.assert_allclose(again, errors, rtol=1e-4)


def test_a_leaky_actuator_flat_above_its_specimen_is_designed_above_10_hz(monkeypatch):
    """Before: 2.9 Hz, inverse 30 steps within 1.4 %, no inverse stable up to alpha 2, and
    'targets met'. The plant's pole pair at 2.0 Hz (damping 0.55) is now replaced by an
    integral action: 14 Hz, a 4-step inverse within 0.24 %."""
    plant = _leaky_plant()
    d = design_force_controller(plant)
    assert 13.0 < d.margins.crossover_hz < 15.0 and d.margins.phase_margin_deg > 47.0
    assert d.structure['integral_damping'] > 0.5 and d.met and d.warnings == []
    assert d.inverse_band_error < 0.005 and d.loop_delay_steps <= 6
    # the pair left alone (as before): the slow loop, with its line and its misses
    monkeypatch.setattr(force_design, 'SLOW_PAIR_DAMPING', 1.1)
    slow = design_force_controller(plant)
    # its loop's targets are met (as before); what else falls short is warned, each line
    # with its figure
    assert 2.5 < slow.margins.crossover_hz < 3.5 and slow.met and slow.notes == []
    assert slow.inverse_band_error > 0.005
    no_inverse, band, crossover = slow.warnings
    assert no_inverse.startswith('no force-loop inverse of 2-30 steps makes the study')
    assert 'stable up to alpha = 2' in no_inverse
    assert band.startswith(f'the force-loop inverse ({slow.loop_delay_steps} steps) misses the '
                           f'closed loop by {100 * slow.inverse_band_error:.2g} % up to 25 Hz')
    assert crossover.startswith('the designed crossover 2.9 Hz is below the 10 Hz')
    assert 'crossing there, the loop would have a phase margin of' in crossover
    assert slow.to_json()['warnings'] == slow.warnings


def test_a_test_on_its_stability_boundary_is_warned():
    """Case J: seft's servohydraulic rig with a lab's valve (1.99 ms) and latency (3 ms), a
    45 Hz, 0.5 % specimen at dt 1 ms, designed as a plant model of data: 20.1 Hz, 58 deg,
    2.38, its loop's targets met (as before), but the compensated test is stable for a plant
    gain <0.1-1.0x at alpha 1 (a valve gain 1 % up after the identification ran to 5894 %
    NRMS x). Before session 25 the design said nothing of it; now a warning line gives the
    test's margin and what to do."""
    params = resolve({'rig_model': 'servohydraulic', 'dt': 0.001, 'mass_kg': 60.0,
                      'stiffness_N_per_m': 4796627.7, 'damping_N_s_per_m': 169.646,
                      'valve_time_constant_s': 0.00199, 'io_latency_s': 0.003})
    d = design_force_controller(force_loop_plant(params), plant_gain_margin=True)
    assert d.met and d.notes == [] and 19.5 < d.margins.crossover_hz < 20.7
    assert d.gain_robust is False
    assert [m.low <= 0.1 for m in d.test_margin.values()] == [True] * 3
    assert max(m.high for m in d.test_margin.values()) < 1.03
    (warning,) = d.warnings
    assert warning.startswith("the study's test with `model` on this design is stable for a "
                              'plant gain <0.1-1.01 x / <0.1-1 x / <0.1-1 x the model')
    assert 'short of the +-5 %' in warning and 'adaptive_loop_fit fit' in warning
    assert d.to_json()['warnings'] == [warning]


def _fast_oil_column_plant(dt: float):
    """A lab plant the family does not hold (session 32): an 86 Hz, damping 0.74 valve, a
    4 ms I/O delay, leakage 1.19e-11 m^3/(s Pa), its oil column at 215 Hz (near the Nyquist
    frequency of dt 2 ms), a 8.17 Hz, 1.53 % specimen of 21.6 kg."""
    m, k, c = 21.595, 56921.0, 33.866
    area, kq, leak, ch = 2.1303e-3, 3.015e-4, 1.1861e-11, 1.15543e-13
    w_v, z_v = 2 * math.pi * 86.2, 0.74
    a = [[0, 1, 0, 0, 0], [-w_v ** 2, -2 * z_v * w_v, 0, 0, 0], [0, 0, 0, 1, 0],
         [0, 0, -k / m, -c / m, 1 / m], [area * kq / ch, 0, 0, -area ** 2 / ch, -leak / ch]]
    doc = {'form': 'state_space', 'io_delay_s': 0.004, 'a': a, 'b': [0, w_v ** 2, 0, 0, 0],
           'c': {'force_N': [0, 0, 0, 0, 1], 'displacement_m': [0, 0, 1, 0, 0],
                 'velocity_m_s': [0, 0, 0, 1, 0], 'acceleration_m_s2': a[3]},
           'specimen': {'mass_kg': m, 'damping_N_s_per_m': c, 'stiffness_N_per_m': k}}
    return force_loop_plant(resolve({'rig_model': 'state_space', 'dt': dt,
                                     'plant_model': json.dumps(doc), 'mass_kg': m,
                                     'damping_N_s_per_m': c, 'stiffness_N_per_m': k}))


def test_a_sampled_zero_off_the_specimens_mode_is_warned_with_a_shorter_dt():
    """In continuous time the force of this plant vanishes at the specimen's poles; sampled
    at dt 2 ms its zero lies 0.67 % off them (8.116 against 8.171 Hz), at dt 1 ms 0.04 %
    (Astrom et al. 1984: sampled zeros near their continuous ones as dt shrinks). Identified
    at 2 ms, its test erred 1.37 % NRMS x at alpha 0.5 (every inverse 4.6 % off the loop),
    at 1 ms 0.04 %; seft identify said neither why nor what to do. The design now warns at
    2 ms, with the estimated part and the remedy, and not at 1 ms, nor on the study's rig."""
    offset, f_zero, part = force_design.sampled_zero_offset(_fast_oil_column_plant(0.002))
    assert 0.006 < offset < 0.0075 and abs(f_zero - 8.116) < 0.005
    assert part == offset / (1 - 1 / math.sqrt(1.5)) and part > force_design.SAMPLED_ZERO_BOUND
    fine, _, fine_part = force_design.sampled_zero_offset(_fast_oil_column_plant(0.001))
    assert fine < 0.0005 and fine_part < 0.15 * force_design.SAMPLED_ZERO_BOUND
    coarse = _fast_oil_column_plant(0.002)
    note = force_design._sampled_zero_note(coarse, None, force_design._csi_zero(coarse, None))
    # the distance is the s-plane's: both dampings shown beside the frequencies (0.68 %
    # beside 8.116 and 8.171 Hz alone misread, session 35), and a sample period named
    assert note.startswith("the measured force's control-structure-interaction zero, sampled "
                           "at dt 2 ms, lies 0.68 % of the mode's |s| from the specimen's "
                           'mode in the s-plane (8.116 Hz, 1.4 % damped, against 8.171 Hz, '
                           '1.5 % damped)'), note
    assert 'identify and test at a shorter sample period, dt 1 ms or less' in note
    fine_plant = _fast_oil_column_plant(0.001)
    assert force_design._sampled_zero_note(
        fine_plant, None, force_design._csi_zero(fine_plant, None)) is None
    study = force_loop_plant(resolve({}))
    assert force_design.sampled_zero_offset(study)[2] < 0.25 * force_design.SAMPLED_ZERO_BOUND
    assert force_design._sampled_zero_note(
        study, None, force_design._csi_zero(study, None)) is None


def test_the_phase_margin_names_its_crossover():
    """An integrator over a 10 Hz, 2 % resonance crosses 0 dB three times: at 2.09 Hz
    (|2/(j 2 pi f / 2 pi)| = 1 below the resonance, the crossover) and on either side of the
    resonance; its smallest phase margin is at the third (10.86 Hz, -76.4 deg), not at the
    crossover printed beside it (a new user read the two as one; session 38)."""
    from seft_ros.core.force_design import loop_margins

    def loop(f):
        f = np.asarray(f, dtype=float)
        return (2.0 / (1j * f)) / (1.0 - (f / 10.0) ** 2 + 2j * 0.02 * (f / 10.0))
    m = loop_margins(loop, 0.1, 100.0)
    assert m.crossovers == 3
    assert m.crossover_hz == pytest.approx(2.0914, abs=1e-4)
    assert m.phase_margin_hz == pytest.approx(10.858, abs=1e-3)
    at = loop(np.array([m.phase_margin_hz]))[0]
    assert abs(at) == pytest.approx(1.0, abs=1e-9)
    assert m.phase_margin_deg == pytest.approx(math.degrees(np.angle(at)) + 180.0 - 360.0)
    assert m.to_json()['phase_margin_hz'] == m.phase_margin_hz


@pytest.mark.parametrize('member', ['valve_2nd_order', 'valve_3_stage', 'leaky',
                                    'orifice_flow', 'coulomb_friction', 'pure_delay'])
def test_a_reversed_valve_is_told_by_its_step(member):
    """Every plant of the family, and seft's rig, with specimens from 2 to 50 Hz answers a
    positive valve step with a positive force (+1); the same plant with its valve's sign
    reversed with a negative one (-1: a new user's reversed valve was identified with healthy
    margins on the run's loop; session 38)."""
    from seft_msgs_py.plant import PlantModel
    from seft_plant_sim.actuator import _member
    from seft_plant_sim.specimen import LinearSpecimen
    from seft_ros.core.force_design import valve_polarity
    for hz in (2.0, 10.0, 50.0):
        for zeta in (0.005, 0.05):
            m = 50.0
            k = m * (2 * math.pi * hz) ** 2
            spec = LinearSpecimen(m, 2 * zeta * math.sqrt(k * m), k)
            plant = _member(member, spec).linear_plant(spec, 0.002)
            assert valve_polarity(plant) == 1, (hz, zeta)
            assert valve_polarity(PlantModel(plant.a, -plant.b, plant.c, plant.dt)) == -1
    rig = force_loop_plant(resolve({'stiffness_N_per_m': 1.19e6, 'mass_kg': 29.13}))
    assert valve_polarity(rig) == 1
    assert valve_polarity(PlantModel(rig.a, rig.b, -rig.c, rig.dt)) == -1
