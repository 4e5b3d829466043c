"""The pure-delay rig of the reference study's numerical model (Nakata and Combs, Sec. 5.2)."""

from collections import deque

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_FORCE, Measurement
from seft_msgs_py.sampling import linear_map as _linear_map
from seft_msgs_py.sampling import split_delay
from seft_msgs_py.sampling import zoh as _zoh
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import (
    BoucWenSpecimen,
    LinearSpecimen,
    SafetyLimits,
    make_specimen,
    rk4_hysteretic,
    substeps,
)

__all__ = ['DelayRig', 'delay_split']


def delay_split(tau_s: float, dt: float) -> tuple[int, float]:
    """The actuator delay as whole steps and a remainder, ``tau = n dt + delta``
    (:func:`~seft_msgs_py.sampling.split_delay`), for a delay that is one.

    Raises
    ------
    ParameterError
        `tau_s` is so short (under 1e-9 `dt`) that it rounds to no delay at all: the force
        of step k would act at t_k+, before the command of step k is known.
    """
    n, delta = split_delay(tau_s, dt)
    if n == 0 and delta == 0.0:
        raise ParameterError(f'parameter tau_s={tau_s!r}: expected float > 0 (at least 1e-09 '
                             f'dt = {1e-9 * dt:g} s: shorter rounds to no delay)')
    return n, delta


class DelayRig:
    """Specimen driven by the reference force delayed by ``tau``: ``f_m(t) = f_r(t - tau)``.

    The reference force is held over each step (zero-order hold) and reaches the specimen
    ``tau`` seconds later (paper Eq. 5.2); the servo controller is bypassed. The specimen
    state is propagated exactly (matrix exponential) for any ``tau > 0``, also when ``tau`` is
    not a multiple of ``dt``: with ``tau = n*dt + delta`` the force over ``[t_k, t_k+delta)``
    is ``f_r[k-n-1]`` and over ``[t_k+delta, t_k+1)`` it is ``f_r[k-n]``.

    Sensor readings are taken at ``t_k+`` (after the delayed force of step k took effect):
    ``f_m[k] = f_r(t_k - tau)``, ``a[k] = (f_m[k] - c v[k] - k x[k]) / m`` (paper Eq. 5.1).

    A hysteretic specimen (:class:`~seft_plant_sim.specimen.BoucWenSpecimen`) has no exact
    discretization: its state ``[x, x', z]`` is integrated with `rk4_substeps` classical
    Runge-Kutta substeps per step, with the same held, delayed force (a substep boundary at
    ``delta``), and ``a[k] = (f_m[k] - c v[k] - f_s(x[k], z[k])) / m``. With the default 10
    substeps (0.2 ms) halving the substep changes the response to the default record by less
    than 3e-8 (relative), and one ``apply()`` costs about 15 us.

    Parameters
    ----------
    specimen : LinearSpecimen or BoucWenSpecimen
    dt : float > 0
        Control period [s].
    tau_s : float > 0
        Actuator time delay [s] (reference study: 0.01 s).
    sensors : Sensors, optional
    limits : SafetyLimits, optional
    rk4_substeps : int >= 1
        Runge-Kutta substeps per control step (hysteretic specimen only).

    Raises
    ------
    ParameterError
        If ``dt <= 0``, ``tau_s <= 0`` (or under 1e-9 ``dt``, :func:`delay_split`) or
        ``rk4_substeps < 1``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 5.1-5.2, Eqs. 5.1-5.2.
    """

    command_kind = COMMAND_FORCE

    def __init__(self, specimen: LinearSpecimen | BoucWenSpecimen, dt: float, tau_s: float,
                 sensors: Sensors | None = None, limits: SafetyLimits | None = None,
                 rk4_substeps: int = 10):
        if not (dt > 0 and np.isfinite(dt)):
            raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
        if not (tau_s > 0 and np.isfinite(tau_s)):
            raise ParameterError(f'parameter tau_s={tau_s!r}: expected float > 0')
        self.specimen = specimen
        self.dt = float(dt)
        self.tau_s = float(tau_s)
        self.sensors = sensors or Sensors()
        self.limits = limits or SafetyLimits()
        n, delta = delay_split(tau_s, dt)
        self._n, self._delta = n, delta
        # past reference forces, newest last: f_r[k-n-1], ..., f_r[k-1]
        self._history = deque([0.0] * (n + 1), maxlen=n + 1)
        self.step = 0
        self._hysteretic = isinstance(specimen, BoucWenSpecimen)
        if self._hysteretic:
            if not (isinstance(rk4_substeps, int) and rk4_substeps >= 1):
                raise ParameterError(
                    f'parameter rk4_substeps={rk4_substeps!r}: expected int >= 1')
            self._substeps = substeps(self.dt, delta, rk4_substeps)
            self._rk4 = _hysteretic_step(specimen)
            self._state = [0.0, 0.0, 0.0]                  # [x, x', z]
            return
        a, b = specimen.state_space()
        phi, _ = _zoh(a, b, self.dt)
        phi_rest, gamma_late = _zoh(a, b, self.dt - delta)
        _, gamma_early = _zoh(a, b, delta)
        # [x, v](t_k+1) = [phi, gamma_early, gamma_late] [x, v, f_early, f_late](t_k)
        self._advance = _linear_map(np.hstack([phi, phi_rest @ gamma_early, gamma_late]),
                                    name='advance')
        self._state = (0.0, 0.0)                           # [x, x']
        self._coef = (specimen.damping_N_s_per_m, specimen.stiffness_N_per_m,
                      specimen.mass_kg)

    @classmethod
    def from_parameters(cls, params, *, rk4_substeps: int = 10) -> 'DelayRig':
        """Build from the parameter schema (``dt``, ``tau_s``, specimen, noise, the sensors'
        ranges, limits).

        The specimen is chosen by ``specimen_model`` (absent: 'linear'); `rk4_substeps` as in
        the constructor.
        """
        rng = float(params.get('accelerometer_range_m_s2', 0.0) or 0.0)
        return cls(make_specimen(params), float(params['dt']),
                   float(params['tau_s']), Sensors.from_parameters(params,
                                                                   rng if rng > 0 else None),
                   SafetyLimits.from_parameters(params), rk4_substeps=rk4_substeps)

    def _forces(self, newest: float):
        """(force over the early part, force over the late part) of the current step."""
        hist = self._history                            # f_r[k-n-1] ... f_r[k-1]
        return hist[0], (hist[1] if self._n >= 1 else newest)   # f_r[k-n-1], f_r[k-n]

    def _force_now(self) -> float:
        """Actuator force at t_k+ = f_r(t_k - tau)."""
        # a delay of whole steps has n >= 1 (delay_split): f_r[k-n]; else f_r[k-n-1]
        return self._history[1] if self._delta == 0.0 else self._history[0]

    @property
    def time_s(self) -> float:
        """Time of the current sample [s]."""
        return self.step * self.dt

    def true_force(self) -> float:
        """Actuator force acting on the specimen at the current sample [N]."""
        return self._force_now()

    @property
    def hysteretic_z(self) -> float | None:
        """Bouc-Wen variable z of the specimen at the current sample (None: linear)."""
        return self._state[2] if self._hysteretic else None

    def measure(self) -> Measurement:
        """Sensor readings at the current sample (see class notes)."""
        f = self._force_now()
        if self._hysteretic:
            x, v, z = self._state
            a = self.specimen.acceleration(x, v, z, f)
        else:
            s = self._state
            x, v = s[0], s[1]
            c, k, m = self._coef
            a = (f - c * v - k * x) / m             # LinearSpecimen.acceleration (Eq. 5.1)
        step = self.step
        return self.sensors.read(step, step * self.dt, x, v, a, f)

    def apply(self, command: float) -> None:
        """Hold the reference force `command` [N] over the current step and advance."""
        f = float(command)
        f_early, f_late = self._forces(f)
        if self._hysteretic:
            n_early, h_early, n_late, h_late = self._substeps
            s = rk4_hysteretic(self._rk4, self._state, f_early, h_early, n_early)
            self._state = rk4_hysteretic(self._rk4, s, f_late, h_late, n_late)
        else:
            s = self._state
            self._state = self._advance((s[0], s[1], f_early, f_late))
        self._history.append(f)
        self.step += 1

    def limit_violation(self) -> str | None:
        """Stroke/force limit check on the true state at the current sample."""
        return self.limits.violation(self.step * self.dt, self._state[0], self._force_now())


def _hysteretic_step(specimen: BoucWenSpecimen):
    """One RK4 step ``(s, f, h, sgn x') -> s`` of ``[x, x', z]`` under the actuator force f [N].

    ``m x'' = f - c x' - f_s(x, z)`` and ``z' = (x'/D_y)(1 - beta sgn(x') |z|^(n-1) z -
    gamma |z|^n)``, the Bouc-Wen rate of :meth:`~seft_plant_sim.specimen.BoucWenSpecimen.
    hysteretic_rate` with the direction of motion held (see
    :func:`~seft_plant_sim.specimen.rk4_hysteretic`); unrolled for speed.
    """
    inv_m, c, ak, bk, inv_dy, n, beta, gamma = specimen.coefficients()
    n1 = n - 1.0

    def zdot(v, z, bd):
        az = abs(z)
        return v * inv_dy * (1.0 - az ** n1 * (bd * z + gamma * az))

    def step(s, f, h, direction):
        bd = beta * direction
        x, v, z = s
        h2 = 0.5 * h
        a1, b1 = (f - c * v - ak * x - bk * z) * inv_m, zdot(v, z, bd)
        x2, v2, z2 = x + h2 * v, v + h2 * a1, z + h2 * b1
        a2, b2 = (f - c * v2 - ak * x2 - bk * z2) * inv_m, zdot(v2, z2, bd)
        x3, v3, z3 = x + h2 * v2, v + h2 * a2, z + h2 * b2
        a3, b3 = (f - c * v3 - ak * x3 - bk * z3) * inv_m, zdot(v3, z3, bd)
        x4, v4, z4 = x + h * v3, v + h * a3, z + h * b3
        a4, b4 = (f - c * v4 - ak * x4 - bk * z4) * inv_m, zdot(v4, z4, bd)
        h6 = h / 6.0
        return [x + h6 * (v + 2.0 * (v2 + v3) + v4), v + h6 * (a1 + 2.0 * (a2 + a3) + a4),
                z + h6 * (b1 + 2.0 * (b2 + b3) + b4)]

    return step
