"""Sampled-data helpers, the sensors' readings and the safety limits (the per-step code)."""

import dataclasses
import dis
import math
import re

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sampling import (
    COMPILE_AFTER_CALLS,
    LazyLinearMap,
    chained_linear_map,
    linear_map,
    single_blas_thread,
    split_delay,
)
from seft_msgs_py.sensor_range import SensorRanges
from seft_plant_sim.rigs import make_rig
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import SafetyLimits


def test_linear_map_equals_the_matrix_product():
    rng = np.random.default_rng(3)
    m = rng.standard_normal((5, 7)) * 10.0 ** rng.integers(-6, 6, (5, 7))
    m[1, 2] = 0.0
    m[2, :] = 0.0                                  # an all-zero row
    m[3, 4] = 1.0
    f = linear_map(m, name='product')
    assert f.__name__ == 'product'
    for _ in range(20):
        x = rng.standard_normal(7) * 100.0
        y = f(x.tolist())
        assert isinstance(y, tuple) and len(y) == 5
        assert all(isinstance(v, float) for v in y)
        np.testing.assert_allclose(y, m @ x, rtol=1e-13, atol=1e-13 * np.max(np.abs(m @ x)))
        # left to right: exactly the Python sum of the products
        assert y[0] == sum(c * v for c, v in zip(m[0].tolist(), x.tolist()))
    assert f([0.0] * 7)[2] == 0.0
    assert f(list(range(7)) + [99.0])[4] == pytest.approx(m[4] @ np.arange(7.0), rel=1e-14)


def test_linear_map_compiles_the_same_coefficients_once():
    """A copy of a compensator (the stability guard drives hundreds per design) gets the
    function compiled for its coefficients back; other coefficients or another name, a new
    one."""
    rng = np.random.default_rng(5)
    m = rng.standard_normal((3, 40))
    f = linear_map(m, name='fir')
    assert linear_map(m.copy(), name='fir') is f
    assert linear_map(m, name='other') is not f
    m2 = m.copy()
    m2[1, 7] = np.nextafter(m2[1, 7], np.inf)        # one ulp: another map
    assert linear_map(m2, name='fir') is not f
    m2[1, 7] += 1.0
    g = linear_map(m2, name='fir')
    x = rng.standard_normal(40).tolist()
    assert g(x)[0] == f(x)[0] and g(x)[1] != f(x)[1]


def test_linear_map_of_a_row_returns_a_float():
    w = [0.5, -0.25, 0.0, 2.0]
    f = linear_map(w)
    assert f([1.0, 2.0, 3.0, 4.0]) == 0.5 - 0.5 + 8.0
    assert linear_map([0.0, 0.0])([1.0, 2.0]) == 0.0


def test_lazy_linear_map_gives_the_compiled_maps_floats_before_and_after_it_compiles():
    """LazyLinearMap sums the same products in the same order as linear_map's code: every
    result the same float (its bits), before the compile and after it (at call
    COMPILE_AFTER_CALLS + 1); zero and unit coefficients, a zero row, -0.0 and a 1-d map."""
    rng = np.random.default_rng(7)
    m = rng.standard_normal((4, 50)) * 10.0 ** rng.integers(-8, 8, (4, 50))
    m[0, :3] = (0.0, 1.0, -0.0)
    m[2, :] = 0.0
    compiled, lazy = linear_map(m, name='rows'), LazyLinearMap(m, name='rows')
    for call in range(COMPILE_AFTER_CALLS + 4):
        x = (rng.standard_normal(50) * 10.0 ** rng.integers(-3, 3, 50)).tolist()
        if call == 2:
            x[1] = -0.0                       # a unit coefficient's operand, not multiplied
        got, want = lazy(x), compiled(x)
        assert isinstance(got, tuple) and len(got) == 4
        assert [v.hex() for v in got] == [v.hex() for v in want]
        assert lazy.compiled == (call >= COMPILE_AFTER_CALLS)
    row = LazyLinearMap(m[1])
    assert row(x) == linear_map(m[1])(x) and isinstance(row(x), float)
    assert LazyLinearMap([0.0, 0.0])([1.0, 2.0]) == 0.0
    with pytest.raises(ValueError, match=r'^linear_map: expected finite coefficients$'):
        LazyLinearMap([1.0, math.nan])


@pytest.mark.parametrize('matrix, name, message', [
    ([[1.0, math.inf]], 'f', r'^linear_map: expected finite coefficients$'),
    ([[1.0, math.nan]], 'f', r'^linear_map: expected finite coefficients$'),
    (np.zeros((2, 2, 2)), 'f', r'^linear_map: expected a 1-d or 2-d matrix, got shape '
     r'\(2, 2, 2\)$'),
    ([1.0], 'not a name', r"^linear_map: name 'not a name' is not an identifier$"),
])
def test_linear_map_errors(matrix, name, message):
    with pytest.raises(ValueError, match=message):
        linear_map(matrix, name=name)


def test_chained_linear_map_is_the_two_maps_bit_for_bit():
    """A rig's step and readings in one function: the same floats as the two linear maps."""
    rng = np.random.default_rng(5)
    m = rng.standard_normal((4, 6)) * 10.0 ** rng.integers(-6, 6, (4, 6))
    m[0, 1] = 0.0
    m[2, 5] = 1.0
    n = rng.standard_normal((5, 4))
    n[1, :] = 0.0                                  # a reading of nothing
    n[3, 2] = 1.0
    f = chained_linear_map(m, n, name='advance')
    first, then = linear_map(m), linear_map(n)
    assert f.__name__ == 'advance'
    for _ in range(50):
        x = (rng.standard_normal(6) * 100.0).tolist()
        y, z = f(x)
        assert y == first(x) and z == then(first(x))
        assert all(isinstance(v, float) for v in y + z)
    y, z = f([0.0] * 6)
    assert y == (0.0,) * 4 and z[1] == 0.0



def test_unpacked_maps_are_the_indexed_maps_bit_for_bit():
    """``unpack``: the argument read into locals once (a 48-tap FIR, a rig's step): the same
    floats as the indexed code, in fewer instructions; a wrong length is refused."""
    rng = np.random.default_rng(11)
    taps = rng.standard_normal(48) * 10.0 ** rng.integers(-6, 6, 48)
    taps[[3, 30]] = 0.0
    taps[7] = 1.0
    m = rng.standard_normal((4, 6))
    m[1, 3] = 0.0
    n = rng.standard_normal((5, 4))
    fir, fir_unpacked = linear_map(taps, name='fir'), linear_map(taps, name='fir', unpack=True)
    assert fir_unpacked is not fir                 # compiled apart, kept apart
    assert linear_map(taps, name='fir', unpack=True) is fir_unpacked
    step, step_unpacked = chained_linear_map(m, n), chained_linear_map(m, n, unpack=True)
    rows = linear_map(m, unpack=True)
    for _ in range(50):
        x = (rng.standard_normal(48) * 1e3).tolist()
        assert fir_unpacked(x) == fir(x)
        w = (rng.standard_normal(6) * 1e2).tolist()
        assert step_unpacked(w) == step(w)
        assert rows(w) == linear_map(m)(w)
    def subscripts(fn):
        return sum(i.opname.startswith('BINARY_SUBSCR') for i in dis.get_instructions(fn))
    assert subscripts(fir) == 46 and subscripts(fir_unpacked) == 0
    with pytest.raises(ValueError):
        fir_unpacked(x + [0.0])                    # exactly n floats
    with pytest.raises(ValueError):
        step_unpacked(w[:5])

@pytest.mark.parametrize('matrix, then, message', [
    ([[1.0, 2.0]], [[1.0, 2.0]], r'^chained_linear_map: expected matrices \(m, n\) and '
     r'\(p, m\), got shapes \(1, 2\) and \(1, 2\)$'),
    ([1.0, 2.0], [[1.0]], r'^chained_linear_map: expected matrices \(m, n\) and \(p, m\), '
     r'got shapes \(2,\) and \(1, 1\)$'),
    ([[1.0]], [[math.nan]], r'^chained_linear_map: expected finite coefficients$'),
])
def test_chained_linear_map_errors(matrix, then, message):
    with pytest.raises(ValueError, match=message):
        chained_linear_map(matrix, then)


def test_split_delay_snaps_to_whole_steps():
    assert split_delay(0.01, 0.002) == (5, 0.0)
    n, delta = split_delay(0.003, 0.002)
    assert n == 1 and delta == pytest.approx(0.001, abs=1e-15)


def test_sensor_readings_are_measurements():
    m = Sensors().read(3, 0.006, 1e-3, -0.2, 4.5, 120.0)
    ref = Measurement(3, 0.006, 1e-3, -0.2, 4.5, 120.0)
    assert type(m) is Measurement and m == ref and hash(m) == hash(ref)
    assert dataclasses.replace(m, step=4) == Measurement(4, 0.006, 1e-3, -0.2, 4.5, 120.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.force_N = 0.0


def test_every_sensor_clips_at_its_range_on_both_rigs():
    """Issue 39: the load cell, displacement transducer and velocity sensor saturate at
    their ranges as the accelerometer does, after the noise; the rigs take the ranges of the
    parameters, the delay rig too."""
    s = Sensors(force_range_N=1000.0, displacement_range_m=0.05, velocity_range_m_s=1.0,
                acceleration_range_m_s2=39.2, noise_force_N=50.0, seed=2)
    m = s.read(0, 0.0, -0.2, 3.0, 50.0, 5000.0)
    assert (m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2) == (
        1000.0, -0.05, 1.0, 39.2)
    assert s.ranges == SensorRanges(1000.0, 0.05, 1.0, 39.2)
    inside = s.read(1, 0.002, 0.01, 0.5, 1.0, 0.0)
    assert (inside.displacement_m, inside.velocity_m_s) == (0.01, 0.5)
    assert abs(inside.force_N) < 300.0                      # noise only, not clipped
    params = parameters.resolve({'force_range_N': 500.0, 'displacement_range_m': 0.002})
    for model in ('delay', 'servohydraulic'):
        rig = make_rig(dict(params, rig_model=model))
        assert rig.sensors.ranges == SensorRanges(500.0, 0.002, 2.5, 39.2), model


def test_accelerometer_range_clips_and_noise_is_seeded():
    s = Sensors(acceleration_range_m_s2=39.2)
    assert s.read(0, 0.0, 0.0, 0.0, 50.0, 0.0).acceleration_m_s2 == 39.2
    assert s.read(0, 0.0, 0.0, 0.0, -50.0, 0.0).acceleration_m_s2 == -39.2
    assert s.read(0, 0.0, 0.0, 0.0, -3.0, 0.0).acceleration_m_s2 == -3.0
    assert math.isnan(s.read(0, 0.0, 0.0, 0.0, math.nan, 0.0).acceleration_m_s2)
    a = [Sensors(noise_force_N=5.0, seed=9).read(0, 0.0, 0.0, 0.0, 0.0, 100.0)
         for _ in range(2)]
    b = Sensors(noise_force_N=5.0, seed=9)
    e = np.random.Generator(np.random.PCG64(9)).standard_normal(4) * [5.0, 0.0, 0.0, 0.0]
    assert a[0] == a[1] == b.read(0, 0.0, 0.0, 0.0, 0.0, 100.0)
    assert a[0].force_N == 100.0 + e[0] and type(a[0].force_N) is float
    assert a[0].displacement_m == 0.0


@pytest.mark.parametrize('x, f, reason', [
    (0.076, 24.5e3, None),                          # on the limits: inside
    (-0.076, -24.5e3, None),
    (0.0761, 0.0, r'^stroke limit exceeded at t=1\.250 s: \|x\|=0\.0761 m > 0\.076 m$'),
    (0.0, -24.6e3, r'^force limit exceeded at t=1\.250 s: \|f\|=2\.46e\+04 N > 24500 N$'),
    (math.nan, 0.0, r'^non-finite rig state at t=1\.250 s$'),
    (0.0, math.inf, r'^non-finite rig state at t=1\.250 s$'),
])
def test_safety_limits(x, f, reason):
    got = SafetyLimits().violation(1.25, x, f)
    if reason is None:
        assert got is None
    else:
        assert got is not None and re.match(reason, got), got


def test_single_blas_thread_limits_and_restores():
    from threadpoolctl import threadpool_info
    before = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']
    assert before
    with single_blas_thread():
        assert all(i['num_threads'] == 1 for i in threadpool_info() if i['user_api'] == 'blas')
    assert [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'] == before


def test_single_blas_thread_limits_a_blas_imported_after_its_first_use():
    """python-control brings slycot's own OpenBLAS: imported after single_blas_thread was
    first used, it is limited too (a fresh interpreter: the suite's other modules may have
    imported it already). Before, the controller made at the first use kept its libraries,
    and this failed in a CI run whose worker had first used it without python-control."""
    import subprocess
    import sys
    code = (
        'from threadpoolctl import threadpool_info\n'
        'from seft_msgs_py.sampling import single_blas_thread\n'
        'blas = lambda: [i for i in threadpool_info() if i["user_api"] == "blas"]\n'
        'with single_blas_thread():\n'
        '    before = len(blas())\n'
        'import control  # noqa: F401\n'
        'assert len(blas()) > before, "python-control brought no BLAS of its own"\n'
        'with single_blas_thread():\n'
        '    assert all(i["num_threads"] == 1 for i in blas()), blas()\n'
        'print("ok")\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == 'ok', proc.stderr


def test_sensor_readings_without_the_dict_shortcut(monkeypatch):
    from seft_plant_sim import sensors
    assert sensors._FILL_DICT                      # Measurement is a plain frozen dataclass
    fast = Sensors().read(1, 0.002, 1.0, 2.0, 3.0, 4.0)
    monkeypatch.setattr(sensors, '_FILL_DICT', False)
    assert Sensors().read(1, 0.002, 1.0, 2.0, 3.0, 4.0) == fast
