"""The specimen (load-resisting member) as a linear single-degree-of-freedom system."""

from dataclasses import dataclass

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['LinearSpecimen', 'SafetyLimits']


@dataclass(frozen=True)
class LinearSpecimen:
    """Linear SDOF specimen ``m*x'' + c*x' + k*x = f`` (paper Eq. 5.1).

    Parameters
    ----------
    mass_kg : float > 0
        Mass m [kg].
    damping_N_s_per_m : float >= 0
        Viscous damping c [N s/m].
    stiffness_N_per_m : float > 0
        Stiffness k [N/m].

    Raises
    ------
    ParameterError
        If a value is out of range.
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float

    def __post_init__(self):
        if not self.mass_kg > 0:
            raise ParameterError(f'parameter mass_kg={self.mass_kg!r}: expected float > 0')
        if not self.damping_N_s_per_m >= 0:
            raise ParameterError(
                f'parameter damping_N_s_per_m={self.damping_N_s_per_m!r}: expected float >= 0')
        if not self.stiffness_N_per_m > 0:
            raise ParameterError(
                f'parameter stiffness_N_per_m={self.stiffness_N_per_m!r}: expected float > 0')

    @classmethod
    def from_parameters(cls, params) -> 'LinearSpecimen':
        """Build from a parameter mapping (``mass_kg``, ``damping_N_s_per_m``, ...)."""
        return cls(float(params['mass_kg']), float(params['damping_N_s_per_m']),
                   float(params['stiffness_N_per_m']))

    @property
    def natural_frequency_hz(self) -> float:
        """Undamped natural frequency ``sqrt(k/m)/(2*pi)`` [Hz]."""
        return float(np.sqrt(self.stiffness_N_per_m / self.mass_kg) / (2 * np.pi))

    def state_space(self):
        """Continuous state space of the specimen driven by the actuator force.

        Returns
        -------
        a : ndarray, shape (2, 2)
        b : ndarray, shape (2, 1)
            State ``[x [m], x' [m/s]]``, input ``f [N]``.
        """
        m, c, k = self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m
        a = np.array([[0.0, 1.0], [-k / m, -c / m]])
        b = np.array([[0.0], [1.0 / m]])
        return a, b

    def acceleration(self, displacement_m: float, velocity_m_s: float, force_N: float) -> float:
        """Acceleration ``(f - c*v - k*x)/m`` [m/s^2] (paper Eq. 5.1)."""
        return (force_N - self.damping_N_s_per_m * velocity_m_s
                - self.stiffness_N_per_m * displacement_m) / self.mass_kg


@dataclass(frozen=True)
class SafetyLimits:
    """The actuator's safe envelope: stroke and force limits (symmetric).

    Parameters
    ----------
    stroke_limit_m : float > 0
        Largest allowed |displacement| [m] (911D actuator: 152 mm total stroke, +/-76 mm).
    force_limit_N : float > 0
        Largest allowed |actuator force| [N] (911D: 24.5 kN dynamic).
    """

    stroke_limit_m: float = 0.076
    force_limit_N: float = 24.5e3

    @classmethod
    def from_parameters(cls, params) -> 'SafetyLimits':
        """Build from ``stroke_limit_m`` and ``force_limit_N``."""
        return cls(float(params['stroke_limit_m']), float(params['force_limit_N']))

    def violation(self, time_s: float, displacement_m: float, force_N: float) -> str | None:
        """Return a one-line reason if a limit is exceeded, else None."""
        if not (np.isfinite(displacement_m) and np.isfinite(force_N)):
            return f'non-finite rig state at t={time_s:.3f} s'
        if abs(displacement_m) > self.stroke_limit_m:
            return (f'stroke limit exceeded at t={time_s:.3f} s: |x|={abs(displacement_m):.4g} m'
                    f' > {self.stroke_limit_m:g} m')
        if abs(force_N) > self.force_limit_N:
            return (f'force limit exceeded at t={time_s:.3f} s: |f|={abs(force_N):.4g} N'
                    f' > {self.force_limit_N:g} N')
        return None
