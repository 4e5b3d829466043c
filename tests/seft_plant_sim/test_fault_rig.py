"""The wiring faults of ``seft rig-check --inject``: one wrapper around seft's rigs changes
what they measure and nothing else, by name (issue 33)."""

import math
import subprocess
import sys

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.faults import FAULTS, SENSOR_FAULTS, FaultyRig, G, check_supported, fault
from seft_plant_sim.realtime import WallClockRig
from seft_plant_sim.rigs import make_rig
from seft_plant_sim.udp_emulator import ControllerEmulator

DT_NS = 2_000_000


def moving(model='delay', fault_name=None, n=300, **overrides):
    """Measurements (f, x, v, a) of `model`'s lockstep rig pushed by 100 N, with and
    without the fault."""
    p = parameters.resolve({'rig_model': model, **overrides})
    rigs = [make_rig(p), make_rig(p)]
    faulty = FaultyRig(rigs[1], FAULTS[fault_name]) if fault_name else rigs[1]
    rows = []
    for _ in range(n):
        pair = [r.measure() for r in (rigs[0], faulty)]
        rows.append([(m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2)
                     for m in pair])
        for r in rigs:
            r.apply(100.0 if model == 'delay' else 0.5)
    rows = np.array(rows)
    return rows[:, 0], rows[:, 1]


@pytest.mark.parametrize('name, gains', [
    ('force_reversed', (-1, 1, 1, 1)), ('force_kN', (1e-3, 1, 1, 1)),
    ('transducer_reversed', (1, -1, -1, -1)), ('displacement_mm', (1, 1e3, 1, 1)),
    ('velocity_mm_s', (1, 1, 1e3, 1)), ('acceleration_g', (1, 1, 1, 1 / G)),
])
def test_a_sign_or_unit_scales_its_field(name, gains):
    true, read = moving(fault_name=name)
    np.testing.assert_array_equal(read, true * np.array(gains))


def test_swapped_stuck_and_noisy_fields():
    true, read = moving(fault_name='swapped_velocity_acceleration')
    np.testing.assert_array_equal(read, true[:, [0, 1, 3, 2]])
    true, read = moving(fault_name='displacement_stuck')
    assert np.all(read[:, 1] == true[0, 1]) and np.ptp(true[:, 1]) > 0
    np.testing.assert_array_equal(read[:, [0, 2, 3]], true[:, [0, 2, 3]])
    true, read = moving(fault_name='force_noise', n=2000)
    noise = read[:, 0] - true[:, 0]
    assert np.std(noise) == pytest.approx(100.0, rel=0.05)
    np.testing.assert_array_equal(read[:, 1:], true[:, 1:])
    # the same noise every run (seeded)
    np.testing.assert_array_equal(moving(fault_name='force_noise', n=2000)[1], read)


def test_the_wrapper_passes_everything_else_through():
    p = parameters.resolve({'rig_model': 'servohydraulic'})
    inner = make_rig(p)
    rig = FaultyRig(inner, FAULTS['acceleration_reversed'])
    assert rig.command_kind == inner.command_kind and rig.dt == inner.dt
    rig.apply(1.0)
    assert rig.step == inner.step == 1 and rig.limit_violation() is None


def test_stamps():
    ahead = FaultyRig(None, FAULTS['stamps_ahead'])
    assert ahead.stamp_ns(0, DT_NS) == 2 * DT_NS and ahead.stamp_ns(7, DT_NS) == 9 * DT_NS
    off = FaultyRig(None, FAULTS['stamps_off_grid'])
    assert off.stamp_ns(3, DT_NS) == 3 * DT_NS + DT_NS // 4
    assert FaultyRig(None, FAULTS['force_kN']).stamp_ns(5, DT_NS) == 5 * DT_NS


def test_no_safe_state_holds_the_last_command():
    """The real-time rig ramps its command to zero on an abort; with the fault it holds it."""
    p = parameters.resolve({'rig_model': 'delay', 'mode': 'realtime'})
    ends = []
    for name in (None, 'no_safe_state'):
        rig = WallClockRig(p)
        rig = FaultyRig(rig, FAULTS[name]) if name else rig
        for k in range(100):
            rig.arrive(k + 1, 70.0, k * rig.dt)
            rig.advance()
        rig.enter_safe_state()
        for _ in range(200):
            rig.advance()
        ends.append(rig.measure().force_N)
    assert ends[0] == pytest.approx(0.0, abs=1e-9) and ends[1] == pytest.approx(70.0)


def test_every_fault_has_a_name_and_words():
    for name, f in FAULTS.items():
        assert f.name == name and f.description
    assert set(SENSOR_FAULTS) == set(FAULTS) - {'stamps_ahead', 'stamps_off_grid',
                                                'slow_clock', 'no_safe_state'}
    assert fault('force_kN') is FAULTS['force_kN']
    with pytest.raises(ParameterError, match=r"^--inject 'kN': expected one of "
                                             r'force_reversed, force_kN, '):
        fault('kN')
    assert not math.isnan(FAULTS['acceleration_g'].gains[3])


def test_where_a_fault_cannot_go():
    p = parameters.resolve({'rig_model': 'delay', 'rig_interface': 'udp_bridge'})
    with pytest.raises(ParameterError, match=r"^--inject force_kN: with "
                       r"rig_interface=udp_bridge the fault is the lab controller's: seft "
                       r'emulate-controller --inject force_kN$'):
        check_supported(FAULTS['force_kN'], p)
    with pytest.raises(ParameterError, match=r'^--inject slow_clock: the controller emulator '
                       r'injects what it measures only \(force_reversed, '):
        ControllerEmulator(parameters.resolve({'rig_model': 'delay'}),
                           bind=('127.0.0.1', 0), fault=FAULTS['slow_clock'])


def test_the_fault_rig_refuses_an_unknown_fault():
    proc = subprocess.run([sys.executable, '-m', 'seft_plant_sim.fault_rig', 'wrong_sign',
                           '--ros-args'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("fault_rig: error: fault 'wrong_sign': expected one of "
                                  'force_reversed, ')
