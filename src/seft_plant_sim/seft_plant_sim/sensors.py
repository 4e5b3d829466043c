"""Sensor models of the rig: additive Gaussian noise (seeded) and range clipping."""

from dataclasses import dataclass

import numpy as np

from seft_plant_sim.interface import Measurement

__all__ = ['Sensors']


@dataclass
class Sensors:
    """Load cell, displacement, velocity and acceleration sensors.

    Each reading is ``clip(true + N(0, sigma^2), -range, +range)``; the noise comes from one
    ``numpy.random.Generator(PCG64(seed))`` drawn in a fixed order (force, displacement,
    velocity, acceleration), so a run is reproducible sample for sample.

    Parameters
    ----------
    noise_force_N, noise_displacement_m, noise_velocity_m_s, noise_acceleration_m_s2 : float >= 0
        Noise standard deviations [N], [m], [m/s], [m/s^2].
    acceleration_range_m_s2 : float > 0 or None
        Full-scale range of the accelerometer [m/s^2] (a 4 g accelerometer: 39.2); readings
        saturate there. None: unlimited.
    seed : int >= 0
        Seed of the noise generator.
    """

    noise_force_N: float = 0.0
    noise_displacement_m: float = 0.0
    noise_velocity_m_s: float = 0.0
    noise_acceleration_m_s2: float = 0.0
    acceleration_range_m_s2: float | None = None
    seed: int = 1

    def __post_init__(self):
        self._rng = np.random.Generator(np.random.PCG64(self.seed))
        self._sigma = np.array([self.noise_force_N, self.noise_displacement_m,
                                self.noise_velocity_m_s, self.noise_acceleration_m_s2])
        self._noisy = bool(np.any(self._sigma > 0))

    @classmethod
    def from_parameters(cls, params, acceleration_range_m_s2=None) -> 'Sensors':
        """Build from the ``noise_*`` and ``noise_seed`` parameters."""
        return cls(float(params['noise_force_N']), float(params['noise_displacement_m']),
                   float(params['noise_velocity_m_s']), float(params['noise_acceleration_m_s2']),
                   acceleration_range_m_s2, int(params['noise_seed']))

    def read(self, step: int, time_s: float, displacement_m: float, velocity_m_s: float,
             acceleration_m_s2: float, force_N: float) -> Measurement:
        """Return the readings of the true values at one sample."""
        f, x, v, a = force_N, displacement_m, velocity_m_s, acceleration_m_s2
        if self._noisy:
            e = self._rng.standard_normal(4) * self._sigma
            f, x, v, a = f + e[0], x + e[1], v + e[2], a + e[3]
        if self.acceleration_range_m_s2 is not None:
            r = self.acceleration_range_m_s2
            a = min(max(a, -r), r)
        return Measurement(step, time_s, float(x), float(v), float(a), float(f))
