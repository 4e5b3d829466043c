"""The specimen (load-resisting member): a linear or a hysteretic (Bouc-Wen) SDOF system."""

from dataclasses import dataclass
import math

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['LinearSpecimen', 'BoucWenSpecimen', 'SPECIMEN_MODELS', 'make_specimen', 'rk4_step',
           'rk4_hysteretic', 'substeps', 'SafetyLimits']


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
class BoucWenSpecimen:
    """Hysteretic SDOF specimen: ``m x'' + c x' + f_s(x, z) = f`` with a Bouc-Wen spring.

    The restoring force and the dimensionless hysteretic variable z follow the normalized
    Bouc-Wen model (Ismail, Ikhouane and Rodellar 2009, with ``A = 1``)::

        f_s = a k x + (1 - a) k D_y z
        z'  = (x' / D_y) (1 - |z|^n (beta sgn(x' z) + gamma))

    The initial (pre-yield) stiffness is ``k``, so small motions are those of
    :class:`LinearSpecimen` with the same m, c, k (10.1 Hz with the defaults). Under monotonic
    loading z rises to its saturation ``z_max = (beta + gamma)^(-1/n)``, so the hysteretic
    spring's strength is ``(1 - a) k D_y z_max`` and the tangent stiffness falls to the
    post-yield ``a k``. With ``beta = gamma`` unloading (``x' z < 0``) is at the initial
    stiffness, as in an elastic-plastic member; with ``n = 2`` and ``beta + gamma = 1`` the
    virgin loading curve of the hysteretic part is ``(1 - a) k D_y tanh(x / D_y)``.

    Parameters
    ----------
    mass_kg : float > 0
        Mass m [kg].
    damping_N_s_per_m : float >= 0
        Viscous damping c [N s/m].
    stiffness_N_per_m : float > 0
        Initial (pre-yield) stiffness k [N/m].
    post_yield_stiffness_ratio : float in [0, 1]
        a = post-yield / pre-yield stiffness [-] (1: the linear specimen).
    yield_displacement_m : float > 0
        Yield displacement D_y [m].
    bouc_wen_n : float >= 1
        Sharpness n of the elastic-plastic transition [-].
    bouc_wen_beta, bouc_wen_gamma : float
        Shape parameters beta, gamma [-]; ``beta + gamma > 0`` and ``beta >= gamma`` (the
        bounded, passive class of the model, Ismail et al. 2009).

    Raises
    ------
    ParameterError
        If a value is out of range.

    Notes
    -----
    The defaults: ``D_y = 4 mm`` (nominal yield force ``k D_y = 844 N``): the default input
    (record 'default', 1000 N amplitude, time scale 0.5) drives the linear specimen to 8.5 mm at
    alpha = 0 and about 20 mm at alpha = 1, i.e. 2 to 5 times ``D_y``, so the member yields
    in every test of the study's alpha range, while the actuator force (at most about
    ``(1 + alpha) 1000 N``) stays far below the 24.5 kN limit. ``a = 0.1`` (post-yield
    stiffness 21.1 kN/m, a typical hardening ratio), ``n = 2`` (smooth but distinct
    knee), ``beta = gamma = 0.5`` (``z_max = 1``; elastic unloading).

    References
    ----------
    R. Bouc, Forced vibration of mechanical systems with hysteresis, Proc. 4th Conf. on
    Nonlinear Oscillations, Prague, 1967.
    Y.-K. Wen, Method for random vibration of hysteretic systems, J. Eng. Mech. Div. ASCE
    102(2), 1976, 249-263.
    M. Ismail, F. Ikhouane and J. Rodellar, The hysteresis Bouc-Wen model, a survey, Arch.
    Comput. Methods Eng. 16, 2009, 161-188.
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float
    post_yield_stiffness_ratio: float = 0.1
    yield_displacement_m: float = 0.004
    bouc_wen_n: float = 2.0
    bouc_wen_beta: float = 0.5
    bouc_wen_gamma: float = 0.5

    def __post_init__(self):
        LinearSpecimen(self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m)
        a, dy, n = self.post_yield_stiffness_ratio, self.yield_displacement_m, self.bouc_wen_n
        beta, gamma = self.bouc_wen_beta, self.bouc_wen_gamma
        checks = (
            ('post_yield_stiffness_ratio', a, 0.0 <= a <= 1.0, 'float in [0, 1]'),
            ('yield_displacement_m', dy, math.isfinite(dy) and dy > 0, 'finite float > 0'),
            ('bouc_wen_n', n, math.isfinite(n) and n >= 1, 'finite float >= 1'),
            ('bouc_wen_gamma', gamma, math.isfinite(gamma), 'finite float'),
            ('bouc_wen_beta', beta, math.isfinite(beta) and beta + gamma > 0 and beta >= gamma,
             'finite float with bouc_wen_beta + bouc_wen_gamma > 0 and '
             'bouc_wen_beta >= bouc_wen_gamma'),
        )
        for name, value, ok, expected in checks:
            if not ok:
                raise ParameterError(f'parameter {name}={value!r}: expected {expected}')

    @classmethod
    def from_parameters(cls, params) -> 'BoucWenSpecimen':
        """Build from a parameter mapping; absent Bouc-Wen keys take the defaults."""
        names = ('post_yield_stiffness_ratio', 'yield_displacement_m', 'bouc_wen_n',
                 'bouc_wen_beta', 'bouc_wen_gamma')
        extra = {name: float(params[name]) for name in names if name in params}
        return cls(float(params['mass_kg']), float(params['damping_N_s_per_m']),
                   float(params['stiffness_N_per_m']), **extra)

    @property
    def natural_frequency_hz(self) -> float:
        """Small-amplitude natural frequency ``sqrt(k/m)/(2*pi)`` [Hz]."""
        return self.linearized().natural_frequency_hz

    @property
    def z_max(self) -> float:
        """Saturation of the hysteretic variable ``(beta + gamma)^(-1/n)`` [-]."""
        return float((self.bouc_wen_beta + self.bouc_wen_gamma) ** (-1.0 / self.bouc_wen_n))

    @property
    def yield_force_N(self) -> float:
        """Nominal yield force ``k D_y`` [N] (the knee of the virgin loading curve)."""
        return self.stiffness_N_per_m * self.yield_displacement_m

    def linearized(self) -> LinearSpecimen:
        """The linear specimen with the initial stiffness (small-amplitude behaviour)."""
        return LinearSpecimen(self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m)

    def restoring_force(self, displacement_m, z):
        """``f_s = a k x + (1 - a) k D_y z`` [N] (scalars or arrays)."""
        k, a = self.stiffness_N_per_m, self.post_yield_stiffness_ratio
        return a * k * displacement_m + (1.0 - a) * k * self.yield_displacement_m * z

    def hysteretic_rate(self, velocity_m_s: float, z: float) -> float:
        """``z' = (x'/D_y)(1 - |z|^n (beta sgn(x' z) + gamma))`` [1/s]."""
        vz = velocity_m_s * z
        beta = self.bouc_wen_beta if vz > 0 else -self.bouc_wen_beta
        return (velocity_m_s / self.yield_displacement_m
                * (1.0 - abs(z) ** self.bouc_wen_n * (beta + self.bouc_wen_gamma)))

    def acceleration(self, displacement_m: float, velocity_m_s: float, z: float,
                     force_N: float) -> float:
        """Acceleration ``(f - c v - f_s(x, z))/m`` [m/s^2]."""
        return (force_N - self.damping_N_s_per_m * velocity_m_s
                - self.restoring_force(displacement_m, z)) / self.mass_kg

    def coefficients(self):
        """Constants of the fast integrators of the rigs.

        Returns
        -------
        tuple of float
            ``(1/m, c, a k, (1 - a) k D_y, 1/D_y, n, beta, gamma)``.
        """
        k, a = self.stiffness_N_per_m, self.post_yield_stiffness_ratio
        return (1.0 / self.mass_kg, self.damping_N_s_per_m, a * k,
                (1.0 - a) * k * self.yield_displacement_m, 1.0 / self.yield_displacement_m,
                float(self.bouc_wen_n), self.bouc_wen_beta, self.bouc_wen_gamma)


#: ``specimen_model`` name -> factory taking the flat parameter mapping.
SPECIMEN_MODELS = {
    'linear': LinearSpecimen.from_parameters,
    'bouc_wen': BoucWenSpecimen.from_parameters,
}


def make_specimen(params):
    """Build the specimen named by ``params['specimen_model']`` (absent: 'linear').

    Raises
    ------
    ParameterError
        If the name is not registered or a value is out of range.
    """
    name = params.get('specimen_model', 'linear')
    try:
        factory = SPECIMEN_MODELS[name]
    except (KeyError, TypeError):
        expected = ', '.join(repr(n) for n in SPECIMEN_MODELS)
        raise ParameterError(
            f'parameter specimen_model={name!r}: expected one of {expected}') from None
    return factory(params)


def rk4_step(rates):
    """One classical Runge-Kutta step built from a right-hand side.

    Parameters
    ----------
    rates : callable(list, float, float) -> list
        ``rates(s, u, direction)``: the state derivative with the input u and the direction
        of motion ``sgn(x')`` (+1.0 or -1.0) held.

    Returns
    -------
    callable(list, float, float, float) -> list
        ``step(s, u, h, direction)``: the state after one RK4 step of length h.
    """
    def step(s, u, h, direction):
        h2 = 0.5 * h
        k1 = rates(s, u, direction)
        k2 = rates([a + h2 * b for a, b in zip(s, k1)], u, direction)
        k3 = rates([a + h2 * b for a, b in zip(s, k2)], u, direction)
        k4 = rates([a + h * b for a, b in zip(s, k3)], u, direction)
        h6 = h / 6.0
        return [a + h6 * (b1 + 2.0 * (b2 + b3) + b4)
                for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]

    return step


def rk4_hysteretic(step, state, u: float, h: float, n: int, velocity_index: int = 1):
    """Advance a hysteretic system by n classical Runge-Kutta steps of length h.

    The Bouc-Wen rate depends on ``sgn(x')``: its derivative jumps at a velocity reversal
    (the tangent stiffness goes from the post-yield to the unloading value), which would cut
    RK4 to about first order. Each substep therefore holds the direction of motion, and a
    substep in which the velocity changes sign is split at the reversal, located by the
    Illinois (modified regula falsi) method on the velocity after a partial RK4 step.

    Parameters
    ----------
    step : callable(list, float, float, float) -> list
        One RK4 step ``step(s, u, h, direction)`` with the direction of motion ``sgn(x')``
        (+1.0 or -1.0) held (:func:`rk4_step`, or an unrolled equivalent).
    state : sequence of float
    u : float
        Input held over the interval.
    h : float > 0
        Substep [s].
    n : int >= 0
        Number of substeps.
    velocity_index : int
        Index of the velocity ``x'`` in the state.

    Returns
    -------
    list of float
        The state after ``n h`` seconds.

    References
    ----------
    L. F. Shampine and S. Thompson, Event location for ordinary differential equations,
    Comput. Math. Appl. 39, 2000, 43-54 (locating a switch and restarting there).
    """
    s = list(state)
    iv = velocity_index
    for _ in range(n):
        v0 = s[iv]
        if v0 == 0.0:                       # at rest: the direction the step moves to
            s1 = step(s, u, h, 1.0)
            direction = 1.0
            if s1[iv] < 0.0:
                s1 = step(s, u, h, -1.0)
                direction = -1.0
        else:
            direction = 1.0 if v0 > 0.0 else -1.0
            s1 = step(s, u, h, direction)
        if s1[iv] * direction >= 0.0:
            s = s1
            continue
        # velocity reversal inside the substep: Illinois on g(t) = direction * v(t)
        lo, g_lo, hi, g_hi = 0.0, abs(v0), h, s1[iv] * direction
        side = 0
        for _ in range(8):
            t = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
            g = step(s, u, t, direction)[iv] * direction
            if g > 0.0:
                lo, g_lo = t, g
                if side == 1:
                    g_hi *= 0.5
                side = 1
            else:
                hi, g_hi = t, g
                if side == -1:
                    g_lo *= 0.5
                side = -1
            if abs(g) <= 1e-13 * abs(v0):
                break
        mid = step(s, u, t, direction)
        s = step(mid, u, h - t, -direction)
    return s


def substeps(dt: float, delta: float, per_step: int):
    """Split a step ``[0, dt)`` at ``delta`` into RK4 substeps of at most ``dt/per_step``.

    Returns
    -------
    (n_early, h_early, n_late, h_late)
        Substeps over ``[0, delta)`` (0 if ``delta == 0``) and over ``[delta, dt)``.
    """
    n_early = int(math.ceil(per_step * delta / dt - 1e-9)) if delta > 0 else 0
    n_late = max(1, int(math.ceil(per_step * (dt - delta) / dt - 1e-9)))
    return (n_early, delta / n_early if n_early else 0.0, n_late, (dt - delta) / n_late)


@dataclass(frozen=True)
class SafetyLimits:
    """The actuator's safe envelope: stroke and force limits (symmetric).

    Parameters
    ----------
    stroke_limit_m : float > 0
        Largest allowed ``abs(displacement)`` [m] (911D actuator: 152 mm total stroke, +/-76 mm).
    force_limit_N : float > 0
        Largest allowed ``abs(actuator force)`` [N] (911D: 24.5 kN dynamic).
    """

    stroke_limit_m: float = 0.076
    force_limit_N: float = 24.5e3

    @classmethod
    def from_parameters(cls, params) -> 'SafetyLimits':
        """Build from ``stroke_limit_m`` and ``force_limit_N``."""
        return cls(float(params['stroke_limit_m']), float(params['force_limit_N']))

    def violation(self, time_s: float, displacement_m: float, force_N: float) -> str | None:
        """Return a one-line reason if a limit is exceeded, else None."""
        stroke, force = self.stroke_limit_m, self.force_limit_N
        if -stroke <= displacement_m <= stroke and -force <= force_N <= force:
            return None                 # the common case (false for NaN)
        if not (math.isfinite(displacement_m) and math.isfinite(force_N)):
            return f'non-finite rig state at t={time_s:.3f} s'
        if abs(displacement_m) > self.stroke_limit_m:
            return (f'stroke limit exceeded at t={time_s:.3f} s: |x|={abs(displacement_m):.4g} m'
                    f' > {self.stroke_limit_m:g} m')
        if abs(force_N) > self.force_limit_N:
            return (f'force limit exceeded at t={time_s:.3f} s: |f|={abs(force_N):.4g} N'
                    f' > {self.force_limit_N:g} N')
        return None
