"""Sensor models of the rig: additive Gaussian noise (seeded) and range clipping
(the ranges of the rig contract, :mod:`seft_msgs_py.sensor_range`)."""

from dataclasses import dataclass, fields
import math

import numpy as np

from seft_msgs_py.interface import Measurement
from seft_msgs_py.sensor_range import SensorRanges

__all__ = ['Sensors']

_FIELDS = ('step', 'time_s', 'displacement_m', 'velocity_m_s', 'acceleration_m_s2', 'force_N')


def _plain_measurement() -> bool:
    """Whether :class:`Measurement` can be built by filling its ``__dict__`` (see read)."""
    return ('__slots__' not in Measurement.__dict__
            and not hasattr(Measurement, '__post_init__')
            and tuple(f.name for f in fields(Measurement)) == _FIELDS)


#: Build readings without the frozen dataclass ``__init__`` (see :meth:`Sensors.read`).
_FILL_DICT = _plain_measurement()
_new = object.__new__


@dataclass
class Sensors:
    """Load cell, displacement, velocity and acceleration sensors.

    Each reading is ``clip(true + N(0, sigma^2), -range, +range)`` (a sensor saturates at its
    full scale); the noise comes from one ``numpy.random.Generator(PCG64(seed))`` drawn in a
    fixed order (force, displacement, velocity, acceleration), so a run is reproducible sample
    for sample.

    Parameters
    ----------
    noise_force_N, noise_displacement_m, noise_velocity_m_s, noise_acceleration_m_s2 : float >= 0
        Noise standard deviations [N], [m], [m/s], [m/s^2].
    acceleration_range_m_s2 : float > 0 or None
        Full-scale range of the accelerometer [m/s^2] (a 4 g accelerometer: 39.2); readings
        saturate there. None: unlimited.
    seed : int >= 0
        Seed of the noise generator.
    force_range_N, displacement_range_m, velocity_range_m_s : float > 0 or None
        Full-scale ranges of the load cell [N], the displacement transducer [m] and the
        velocity sensor [m/s]. None: unlimited.
    """

    noise_force_N: float = 0.0
    noise_displacement_m: float = 0.0
    noise_velocity_m_s: float = 0.0
    noise_acceleration_m_s2: float = 0.0
    acceleration_range_m_s2: float | None = None
    seed: int = 1
    force_range_N: float | None = None
    displacement_range_m: float | None = None
    velocity_range_m_s: float | None = None

    def __post_init__(self):
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        self._sigma = np.array([self.noise_force_N, self.noise_displacement_m,
                                self.noise_velocity_m_s, self.noise_acceleration_m_s2])
        self._noisy = bool(np.any(self._sigma > 0))
        r = self.acceleration_range_m_s2
        self._range = None if r is None else float(r)
        others = (self.force_range_N, self.displacement_range_m, self.velocity_range_m_s)
        # the other three: (force, displacement, velocity) ranges, inf where unlimited; None
        # when all three are (the reading then costs what it did before they existed)
        ranges = tuple(math.inf if v is None else float(v) for v in others)
        self._ranges = None if all(math.isinf(v) for v in ranges) else ranges

    @property
    def ranges(self) -> SensorRanges:
        """The four ranges as :class:`~seft_msgs_py.sensor_range.SensorRanges`."""
        values = (self.force_range_N, self.displacement_range_m, self.velocity_range_m_s,
                  self.acceleration_range_m_s2)
        return SensorRanges(*(math.inf if v is None else float(v) for v in values))

    @classmethod
    def from_parameters(cls, params, acceleration_range_m_s2=None) -> 'Sensors':
        """Build from the ``noise_*`` and ``noise_seed`` parameters and the ranges
        (``force_range_N``, ``displacement_range_m``, ``velocity_range_m_s``; absent or 0:
        unlimited; the accelerometer's is `acceleration_range_m_s2`)."""
        def of(name):
            value = float(params.get(name, 0.0) or 0.0)
            return value if value > 0 else None
        return cls(float(params['noise_force_N']), float(params['noise_displacement_m']),
                   float(params['noise_velocity_m_s']), float(params['noise_acceleration_m_s2']),
                   acceleration_range_m_s2, int(params['noise_seed']), of('force_range_N'),
                   of('displacement_range_m'), of('velocity_range_m_s'))

    def read(self, step: int, time_s: float, displacement_m: float, velocity_m_s: float,
             acceleration_m_s2: float, force_N: float) -> Measurement:
        """Return the readings of the true values at one sample.

        The readings are Python floats if the true values are (the rigs pass floats).
        """
        if self._noisy:
            e = self._rng.standard_normal(4) * self._sigma
            force_N, displacement_m, velocity_m_s, acceleration_m_s2 = (
                float(force_N + e[0]), float(displacement_m + e[1]), float(velocity_m_s + e[2]),
                float(acceleration_m_s2 + e[3]))
        r = self._range
        if r is not None:
            if acceleration_m_s2 > r:           # min(max(a, -r), r); NaN passes through
                acceleration_m_s2 = r
            elif acceleration_m_s2 < -r:
                acceleration_m_s2 = -r
        if self._ranges is not None:
            rf, rx, rv = self._ranges
            if force_N > rf:
                force_N = rf
            elif force_N < -rf:
                force_N = -rf
            if displacement_m > rx:
                displacement_m = rx
            elif displacement_m < -rx:
                displacement_m = -rx
            if velocity_m_s > rv:
                velocity_m_s = rv
            elif velocity_m_s < -rv:
                velocity_m_s = -rv
        if not _FILL_DICT:
            return Measurement(step, time_s, displacement_m, velocity_m_s, acceleration_m_s2,
                               force_N)
        # A frozen dataclass sets each field through object.__setattr__: about 1.2 us for a
        # Measurement, a fifth of a simulated step. Filling the new instance's __dict__ gives
        # the same object (equal, hashable, dataclasses.replace works) in 0.45 us; only while
        # Measurement is a plain frozen dataclass of these fields without __post_init__.
        m = _new(Measurement)
        d = m.__dict__
        d['step'] = step
        d['time_s'] = time_s
        d['displacement_m'] = displacement_m
        d['velocity_m_s'] = velocity_m_s
        d['acceleration_m_s2'] = acceleration_m_s2
        d['force_N'] = force_N
        return m
