"""The pure-delay rig of the reference study's numerical model (Nakata and Combs, Sec. 5.2)."""

from collections import deque

import numpy as np
from scipy.signal import cont2discrete

from seft_msgs_py.errors import ParameterError
from seft_plant_sim.interface import COMMAND_FORCE, Measurement
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import LinearSpecimen, SafetyLimits

__all__ = ['DelayRig']


def _zoh(a, b, h):
    """Return (Phi(h), Gamma(h)) of ``x' = a x + b u`` under a hold of length h [s]."""
    if h <= 0.0:
        return np.eye(a.shape[0]), np.zeros_like(b)
    phi, gamma, *_ = cont2discrete((a, b, np.eye(a.shape[0]), np.zeros_like(b)), h, 'zoh')
    return phi, gamma


class DelayRig:
    """Specimen driven by the reference force delayed by ``tau``: ``f_m(t) = f_r(t - tau)``.

    The reference force is held over each step (zero-order hold) and reaches the specimen
    ``tau`` seconds later (paper Eq. 5.2); the servo controller is bypassed. The specimen
    state is propagated exactly (matrix exponential) for any ``tau > 0``, also when ``tau`` is
    not a multiple of ``dt``: with ``tau = n*dt + delta`` the force over ``[t_k, t_k+delta)``
    is ``f_r[k-n-1]`` and over ``[t_k+delta, t_k+1)`` it is ``f_r[k-n]``.

    Sensor readings are taken at ``t_k+`` (after the delayed force of step k took effect):
    ``f_m[k] = f_r(t_k - tau)``, ``a[k] = (f_m[k] - c v[k] - k x[k]) / m`` (paper Eq. 5.1).

    Parameters
    ----------
    specimen : LinearSpecimen
    dt : float > 0
        Control period [s].
    tau_s : float > 0
        Actuator time delay [s] (reference study: 0.01 s).
    sensors : Sensors, optional
    limits : SafetyLimits, optional

    Raises
    ------
    ParameterError
        If ``dt <= 0`` or ``tau_s <= 0``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 5.1-5.2, Eqs. 5.1-5.2.
    """

    command_kind = COMMAND_FORCE

    def __init__(self, specimen: LinearSpecimen, dt: float, tau_s: float,
                 sensors: Sensors | None = None, limits: SafetyLimits | None = None):
        if not (dt > 0 and np.isfinite(dt)):
            raise ParameterError(f'parameter dt={dt!r}: expected finite float > 0')
        if not (tau_s > 0 and np.isfinite(tau_s)):
            raise ParameterError(f'parameter tau_s={tau_s!r}: expected finite float > 0')
        self.specimen = specimen
        self.dt = float(dt)
        self.tau_s = float(tau_s)
        self.sensors = sensors or Sensors()
        self.limits = limits or SafetyLimits()
        n = int(np.floor(tau_s / dt + 1e-9))
        delta = tau_s - n * dt
        if abs(delta) < 1e-9 * dt:
            delta = 0.0
        self._n, self._delta = n, delta
        a, b = specimen.state_space()
        self._phi, _ = _zoh(a, b, self.dt)
        phi_rest, self._gamma_late = _zoh(a, b, self.dt - delta)
        _, gamma_early = _zoh(a, b, delta)
        self._gamma_early = phi_rest @ gamma_early
        # past reference forces, newest last: f_r[k-n-1], ..., f_r[k-1]
        self._history = deque([0.0] * (n + 1), maxlen=n + 1)
        self._state = np.zeros(2)
        self.step = 0

    @classmethod
    def from_parameters(cls, params) -> 'DelayRig':
        """Build from the parameter schema (``dt``, ``tau_s``, specimen, noise, limits)."""
        return cls(LinearSpecimen.from_parameters(params), float(params['dt']),
                   float(params['tau_s']), Sensors.from_parameters(params),
                   SafetyLimits.from_parameters(params))

    def _forces(self, newest: float):
        """(force over the early part, force over the late part) of the current step."""
        hist = list(self._history) + [newest]          # f_r[k-n-1] ... f_r[k]
        return hist[0], hist[1]                         # f_r[k-n-1], f_r[k-n]

    def _force_now(self) -> float:
        """Actuator force at t_k+ = f_r(t_k - tau)."""
        hist = list(self._history)                      # f_r[k-n-1] ... f_r[k-1]
        if self._delta == 0.0:
            return hist[1] if self._n >= 1 else float('nan')
        return hist[0]

    @property
    def time_s(self) -> float:
        """Time of the current sample [s]."""
        return self.step * self.dt

    def true_force(self) -> float:
        """Actuator force acting on the specimen at the current sample [N]."""
        return self._force_now()

    def measure(self) -> Measurement:
        """Sensor readings at the current sample (see class notes)."""
        x, v = self._state
        f = self._force_now()
        a = self.specimen.acceleration(x, v, f)
        return self.sensors.read(self.step, self.time_s, x, v, a, f)

    def apply(self, command: float) -> None:
        """Hold the reference force `command` [N] over the current step and advance."""
        f_early, f_late = self._forces(float(command))
        self._state = (self._phi @ self._state + self._gamma_early[:, 0] * f_early
                       + self._gamma_late[:, 0] * f_late)
        self._history.append(float(command))
        self.step += 1

    def limit_violation(self) -> str | None:
        """Stroke/force limit check on the true state at the current sample."""
        return self.limits.violation(self.time_s, float(self._state[0]), self._force_now())
