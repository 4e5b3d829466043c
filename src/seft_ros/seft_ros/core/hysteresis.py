"""The yielding member as the controller side models it: a Bouc-Wen restoring force
anchored on the measured restoring force and identified online.

Two parts of the loop need to know where a yielding member is going, a few milliseconds ahead:

* the ``tangent_loop_shaping`` force controller (:mod:`seft_ros.core.controller`), whose
  control-structure-interaction cancellation follows the member's tangent stiffness at the
  moment its valve command takes effect;
* the ``model`` compensator with ``predictor_restoring_force: hysteretic``
  (:mod:`seft_ros.core.predictors`), which integrates the member over the loop delay.

Both use :class:`HystereticMember`: the measured restoring force ``r = f_m - m a - c v``
(load cell, accelerometer, velocity sensor, the nominal m and c) fixes the member's state
(the Bouc-Wen variable z) at every sample, so the model only has to carry it over the next
milliseconds; and the model's parameters (initial stiffness, post-yield ratio, yield
displacement, sharpness) are identified online from the same measurements
(:class:`HystereticIdentifier`), starting from the configured ``hysteresis_*`` guesses.

The model (normalized Bouc-Wen, Ismail, Ikhouane and Rodellar 2009, ``A = 1``)::

    r  = a k x + (1 - a) k D_y z
    dz/dx = (1 - |z|^n (beta sgn(x' z) + gamma)) / D_y

is rate independent, so z is carried along a displacement path, not a time; ``beta = gamma``
(fixed, ``HYSTERESIS_BETA``) makes unloading elastic (at the initial stiffness), as in a
yielding steel or reinforced-concrete member.

Stepping uses plain Python floats (a few microseconds per call), as the nodes step at 500 Hz
and more. ROS-free.

References
----------
R. Bouc (1967); Y.-K. Wen, Method for random vibration of hysteretic systems, J. Eng. Mech.
Div. ASCE 102(2), 1976, 249-263. M. Ismail, F. Ikhouane and J. Rodellar, The hysteresis
Bouc-Wen model, a survey, Arch. Comput. Methods Eng. 16, 2009, 161-188.
E. N. Chatzi and A. W. Smyth, The unscented Kalman filter and particle filter methods for
nonlinear structural system identification with non-collocated heterogeneous sensing,
Struct. Control Health Monit. 16(1), 2009, 99-123 (online identification of Bouc-Wen
parameters). B. Wu and T. Wang, Model updating with constrained unscented Kalman filter for
hybrid testing, Smart Struct. Syst. 14(6), 2014, 1105-1129 (online model updating in hybrid
simulation). L. Ljung and T. Soderstrom, Theory and Practice of Recursive Identification,
MIT Press, 1983, Ch. 3 (the recursive prediction-error / Gauss-Newton update).
"""

from dataclasses import dataclass
import math

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement

__all__ = ['BoucWenModel', 'HystereticIdentifier', 'HystereticMember', 'HYSTERESIS_BETA',
           'HYSTERESIS_ESTIMATES', 'MemberGuess']

#: beta = gamma of the model: unloading at the initial stiffness (z_max = 1).
HYSTERESIS_BETA = 0.5
#: Names of :meth:`HystereticMember.estimates` (recorded on ``/seft/estimates``).
HYSTERESIS_ESTIMATES = ('tangent_stiffness_N_per_m', 'hysteresis_stiffness_N_per_m',
                        'hysteresis_post_yield_ratio', 'hysteresis_yield_displacement_m',
                        'hysteresis_n', 'hysteresis_unloading_shape')


class BoucWenModel:
    """Bouc-Wen restoring force of the member, carried along a displacement path.

    Parameters
    ----------
    stiffness_N_per_m : float > 0
        Initial (elastic) stiffness k [N/m].
    post_yield_ratio : float in [0, 1)
        a = post-yield / initial stiffness [-].
    yield_displacement_m : float > 0
        D_y [m].
    n : float >= 1
        Sharpness of the elastic-plastic transition [-].
    beta, gamma : float
        Shape (``beta + gamma > 0``); default ``beta = gamma = 0.5``.

    Raises
    ------
    ParameterError
        A value out of range.

    Notes
    -----
    ``r = a k x + (1 - a) k D_y z`` and ``dz/dx = (1 - |z|^n (beta sgn(dx z) + gamma))/D_y``
    (module notes): z saturates at ``z_max = (beta + gamma)^(-1/n)``, the tangent stiffness
    ``dr/dx = a k + (1 - a) k D_y dz/dx`` falls from k to ``a k`` under monotonic loading
    and is k again on unloading (``beta = gamma``).
    """

    def __init__(self, stiffness_N_per_m: float, post_yield_ratio: float,
                 yield_displacement_m: float, n: float, beta: float = HYSTERESIS_BETA,
                 gamma: float = HYSTERESIS_BETA):
        self.beta, self.gamma = float(beta), float(gamma)
        if not self.beta + self.gamma > 0:
            raise ParameterError(f'hysteresis: expected beta + gamma > 0, got {beta!r}, '
                                 f'{gamma!r}')
        self.set(stiffness_N_per_m, post_yield_ratio, yield_displacement_m, n)

    def set(self, stiffness_N_per_m: float, post_yield_ratio: float,
            yield_displacement_m: float, n: float, beta: float | None = None,
            gamma: float | None = None) -> None:
        """Change the parameters (the identifier's estimates); same checks as the class."""
        if beta is not None:
            self.beta, self.gamma = float(beta), float(gamma)
        k, a, dy, n = (float(stiffness_N_per_m), float(post_yield_ratio),
                       float(yield_displacement_m), float(n))
        if not (k > 0 and 0.0 <= a < 1.0 and dy > 0 and n >= 1.0
                and math.isfinite(k * dy * n)):
            raise ParameterError('hysteresis model: expected k > 0, 0 <= a < 1, D_y > 0 and '
                                 f'n >= 1, got {k!r}, {a!r}, {dy!r}, {n!r}')
        self.stiffness_N_per_m, self.post_yield_ratio = k, a
        self.yield_displacement_m, self.n = dy, n
        self._ak = a * k                          # post-yield stiffness [N/m]
        self._hk = (1.0 - a) * k * dy             # hysteretic strength [N]
        self._inv_dy = 1.0 / dy
        self.z_max = (self.beta + self.gamma) ** (-1.0 / n)

    def z_of(self, displacement_m: float, restoring_force_N: float) -> float:
        """The z that gives `restoring_force_N` at `displacement_m`, within ``+-z_max``."""
        z = (restoring_force_N - self._ak * displacement_m) / self._hk
        zm = self.z_max
        return zm if z > zm else (-zm if z < -zm else z)

    def restoring_force(self, displacement_m: float, z: float) -> float:
        """``r = a k x + (1 - a) k D_y z`` [N]."""
        return self._ak * displacement_m + self._hk * z

    def dz_dx(self, z: float, direction: float) -> float:
        """``dz/dx`` [1/m] moving in `direction` (+1.0 or -1.0)."""
        beta = self.beta if direction * z > 0.0 else -self.beta
        return (1.0 - abs(z) ** self.n * (beta + self.gamma)) * self._inv_dy

    def tangent(self, z: float, direction: float) -> float:
        """Tangent stiffness ``dr/dx`` [N/m] at z moving in `direction`."""
        return self._ak + self._hk * self.dz_dx(z, direction)

    def advance(self, z: float, dx_m: float, direction: float | None = None) -> float:
        """Carry z over a displacement increment `dx_m` [m] (classical RK4 in x).

        `direction` (+1.0 or -1.0) is the direction of motion that selects the loading or
        unloading branch; default ``sgn(dx_m)``. Given the measured velocity's sign while
        `dx_m` comes from a noisy displacement, a back-and-forth of the noise is carried
        along one branch and back (reversibly), not as a tiny unloading-reloading cycle
        that would walk z off the loading curve. Substeps of at most ``D_y/8``.
        """
        if dx_m == 0.0:
            return z
        if direction is None:
            direction = 1.0 if dx_m > 0.0 else -1.0
        steps = int(abs(dx_m) * self._inv_dy * 8.0) + 1
        h = dx_m / steps
        beta, gamma, n, inv = self.beta, self.gamma, self.n, self._inv_dy
        bp, bm = beta + gamma, gamma - beta
        for _ in range(steps):
            # dz_dx written out (4 calls a substep)
            k1 = (1.0 - abs(z) ** n * (bp if direction * z > 0.0 else bm)) * inv
            z2 = z + 0.5 * h * k1
            k2 = (1.0 - abs(z2) ** n * (bp if direction * z2 > 0.0 else bm)) * inv
            z3 = z + 0.5 * h * k2
            k3 = (1.0 - abs(z3) ** n * (bp if direction * z3 > 0.0 else bm)) * inv
            z4 = z + h * k3
            k4 = (1.0 - abs(z4) ** n * (bp if direction * z4 > 0.0 else bm)) * inv
            z += h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        return z


@dataclass(frozen=True)
class MemberGuess:
    """The configured (initial) model of the member: where identification starts.

    Attributes
    ----------
    mass_kg, damping_N_s_per_m : float
        Nominal m [kg] and c [N s/m] of the restoring force ``r = f_m - m a - c v``.
    stiffness_N_per_m : float
        Initial stiffness k [N/m].
    post_yield_ratio, yield_displacement_m, n : float
        ``hysteresis_post_yield_ratio``, ``hysteresis_yield_displacement_m``,
        ``hysteresis_n``.
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float
    post_yield_ratio: float
    yield_displacement_m: float
    n: float

    @classmethod
    def from_parameters(cls, params, *, predictor: bool = True) -> 'MemberGuess':
        """From ``mass_kg``, ``damping_N_s_per_m``, ``stiffness_N_per_m`` (with `predictor`,
        the compensator's ``predictor_*`` values where set; the force controller, which does
        not declare those, passes False) and the ``hysteresis_*`` parameters (absent: the
        schema's defaults).

        Raises
        ------
        ParameterError
            A value out of range.
        """
        from seft_msgs_py.parameters import spec

        def get(name, fallback=None):
            if fallback is not None and not predictor:
                name, fallback = fallback, None
            value = float(params[name] if name in params else spec(name).default)
            if value == 0.0 and fallback is not None:
                value = float(params[fallback])
            return value

        guess = cls(get('predictor_mass_kg', 'mass_kg'),
                    get('predictor_damping_N_s_per_m', 'damping_N_s_per_m'),
                    get('predictor_stiffness_N_per_m', 'stiffness_N_per_m'),
                    get('hysteresis_post_yield_ratio'), get('hysteresis_yield_displacement_m'),
                    get('hysteresis_n'))
        checks = (('hysteresis_post_yield_ratio', guess.post_yield_ratio,
                   0.0 < guess.post_yield_ratio < 1.0, 'float in (0, 1)'),
                  ('hysteresis_yield_displacement_m', guess.yield_displacement_m,
                   guess.yield_displacement_m > 0, 'float > 0'),
                  ('hysteresis_n', guess.n, guess.n > 1.0, 'float > 1'),
                  ('mass_kg', guess.mass_kg, guess.mass_kg > 0, 'float > 0'),
                  ('stiffness_N_per_m', guess.stiffness_N_per_m, guess.stiffness_N_per_m > 0,
                   'float > 0'))
        for name, value, ok, expected in checks:
            if not (ok and math.isfinite(value)):
                raise ParameterError(f'parameter {name}={value!r}: expected {expected}')
        return guess


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class HystereticIdentifier:
    """Online identification of the Bouc-Wen parameters from the measured restoring force.

    A recursive Gauss-Newton (prediction-error) update with exponential forgetting, the
    extended Kalman filter of constant parameters (Ljung and Soderstrom 1983, Ch. 3): the
    model anchored at a sample's restoring force ``r[i]`` (z from :meth:`BoucWenModel.z_of`)
    predicts ``r[j]`` of a later sample after the displacement increment in between,
    integrated from the measured velocity, on the branch of its direction; the prediction
    error updates the parameters along its gradient (finite differences)::

        theta = (ln k, logit a, ln D_y, ln(n - 1), s),   e = r[j] - r_hat(theta)
        K = P J / (lambda R + J' P J),  theta += K e,  P = (P - K J' P) / lambda

    An update waits (the anchor stays) until the member has moved at least
    ``min_increment_m`` and three standard deviations of the sensors' noise over k (the
    force it moved must stand out of the noise), and restarts its anchor at a reversal of
    the measured velocity. ``R`` is the running mean of ``e^2`` (time constant
    ``memory_s``) with a floor, so the gain adapts to the residual; the sensors' noise
    ``sensor_var_N2`` is the same mean over the samples far from yield (``|z| < 0.3``),
    where the residual is noise and not the yield parameters' error;
    ``lambda = exp(-dt/memory_s)`` per update; P is bounded (no
    wind-up while a parameter is not excited, e.g. the yield parameters of a member that
    stays elastic); theta stays within ``bounds`` of the guess. Only the initial stiffness
    is visible while the member is elastic; the others are learnt from its yield
    excursions. ``s = beta - gamma`` with ``beta + gamma = 1`` is the shape of unloading
    (0: elastic, at k; towards 1: stiffer than k), which any ``beta >= gamma`` reduces to
    (z and D_y rescaled by ``(beta + gamma)^(1/n)``); it is learnt from unloadings after
    yield and starts at 0.

    Parameters
    ----------
    guess : MemberGuess
        Starting values.
    dt : float > 0
        Sample period [s] (forgetting per sample).
    memory_s : float > 0
        Memory of the forgetting and of the noise estimate [s].
    min_increment_m : float >= 0
        Samples that moved less than this since the last update are skipped (the anchor
        stays), so that sensor noise at rest does not drive the estimates.

    Attributes
    ----------
    model : BoucWenModel
        The model at the current estimates (updated in place).
    updates : int
        Parameter updates so far.
    noise_var_N2, sensor_var_N2 : float
        Running mean of the squared prediction error [N^2]: over all updates (the gain's R)
        and over those far from yield (the sensors' noise).

    Raises
    ------
    ParameterError
        Bad `dt` or `memory_s`.
    """

    #: Prior variance of each transformed parameter and its bound: narrow for k (22 % one
    #: sigma: the elastic stiffness is the configured one within that, and it is identified
    #: from every motion), wide for a, D_y and n (a factor of 4: the yield behaviour may be
    #: far from the guess), narrow for s (0.22: it is seen only in unloadings after yield,
    #: and an elastic unloading is the usual case).
    P0 = (0.05, 2.0, 2.0, 2.0, 0.05)
    #: Range of each parameter: k within 0.5..2 of the guess, a within 0.001..0.95,
    #: D_y within 0.2..20 of the guess, n within 1.05..20, s within -0.5..0.98 (below 0,
    #: unloading softer than k: not a member's, but no bound at the elastic value 0, which
    #: would bias the estimate of an elastic unloading upwards).
    BOUNDS = ((math.log(0.5), math.log(2.0)), (_logit(0.001), _logit(0.95)),
              (math.log(0.2), math.log(20.0)), (math.log(0.05), math.log(19.0)), (-0.5, 0.98))
    #: Number of identified parameters.
    N_PARAMETERS = 5
    #: Floor of the residual variance [N^2].
    NOISE_FLOOR_N2 = 1.0
    #: Below this ``|z|`` the member is far from yield: the one-step residual there is the
    #: sensors' noise (``sensor_var_N2``), not the model's error in the yield parameters.
    ELASTIC_Z = 0.3
    #: Weight of a residual in the running estimate of the sensors' noise (about the last
    #: 100 updates).
    SENSOR_WEIGHT = 0.01

    @classmethod
    def estimate_bounds(cls, guess: MemberGuess) -> dict:
        """The range of each identified parameter, ``{estimate name: (lower, upper)}``
        (names of :data:`HYSTERESIS_ESTIMATES`, SI units): :data:`BOUNDS` about `guess`."""
        (lk, hk), (la, ha), (ld, hd), (ln_, hn), (ls, hs) = cls.BOUNDS
        k, dy = guess.stiffness_N_per_m, guess.yield_displacement_m

        def expit(x):
            return 1.0 / (1.0 + math.exp(-x))
        return {'hysteresis_stiffness_N_per_m': (k * math.exp(lk), k * math.exp(hk)),
                'hysteresis_post_yield_ratio': (expit(la), expit(ha)),
                'hysteresis_yield_displacement_m': (dy * math.exp(ld), dy * math.exp(hd)),
                'hysteresis_n': (1.0 + math.exp(ln_), 1.0 + math.exp(hn)),
                'hysteresis_unloading_shape': (ls, hs)}

    def __init__(self, guess: MemberGuess, dt: float, *, memory_s: float = 2.0,
                 min_increment_m: float = 2e-6):
        if not (dt > 0 and memory_s > 0 and min_increment_m >= 0):
            raise ParameterError(f'hysteresis identifier: expected dt > 0, memory_s > 0, '
                                 f'got {dt!r}, {memory_s!r}')
        self.guess = guess
        self._k0, self._dy0 = guess.stiffness_N_per_m, guess.yield_displacement_m
        self.theta = [0.0, _logit(guess.post_yield_ratio), 0.0, math.log(guess.n - 1.0), 0.0]
        self.theta = [min(max(t, lo), hi) for t, (lo, hi) in zip(self.theta, self.BOUNDS)]
        npar = self.N_PARAMETERS
        self.P = [[self.P0[i] if i == j else 0.0 for j in range(npar)] for i in range(npar)]
        self._lam = math.exp(-dt / memory_s)
        self._noise_w = 1.0 - math.exp(-dt / memory_s)
        self.noise_var_N2 = 100.0
        self.sensor_var_N2 = 0.0
        self.min_increment_m = float(min_increment_m)
        self.model = BoucWenModel(*self.parameters())
        self._probe = BoucWenModel(*self.parameters())
        self._last = None                     # (x, r) of the anchor
        self._v = 0.0                         # velocity of the previous sample
        self._dx = 0.0                        # displacement since the anchor (from v)
        self._dt = float(dt)
        self.updates = 0

    def parameters(self, theta=None) -> tuple[float, ...]:
        """``(k [N/m], a, D_y [m], n, beta, gamma)`` of `theta` (default: the current
        estimates)."""
        t = self.theta if theta is None else theta
        return (self._k0 * math.exp(t[0]), 1.0 / (1.0 + math.exp(-t[1])),
                self._dy0 * math.exp(t[2]), 1.0 + math.exp(t[3]), 0.5 * (1.0 + t[4]),
                0.5 * (1.0 - t[4]))

    def _predict(self, model: BoucWenModel, x0, r0, x1, direction) -> float:
        z = model.advance(model.z_of(x0, r0), x1 - x0, direction)
        return model.restoring_force(x1, z)

    def observe(self, displacement_m: float, restoring_force_N: float,
                velocity_m_s: float) -> None:
        """Take one sample: displacement [m], restoring force [N], velocity [m/s].

        The displacement increment since the anchor is the measured velocity integrated
        (trapezoidal rule), not the difference of two displacement readings: a displacement
        sensor's noise (10 um here) is of the order of a step's motion in the quiet parts of
        a record, and a regressor that noisy biases the stiffness towards zero (errors in
        variables); the velocity's noise integrates to a fraction of a micrometre a step.
        """
        x, r, v = displacement_m, restoring_force_N, velocity_m_s
        if not (math.isfinite(x) and math.isfinite(r) and math.isfinite(v)):
            return
        last = self._last
        if last is None:
            self._last, self._v, self._dx = (x, r), v, 0.0
            return
        if v * self._v < 0.0:                   # a reversal: a new anchor, no update
            self._last, self._v, self._dx = (x, r), v, 0.0
            return
        self._dx += 0.5 * (self._v + v) * self._dt
        self._v = v
        dx = self._dx
        # enough motion for the force it moves to stand out of the sensors' noise
        least = max(self.min_increment_m,
                    3.0 * math.sqrt(self.sensor_var_N2) / self.model.stiffness_N_per_m)
        if abs(dx) < least:
            return                                      # the anchor stays
        x0, r0 = last
        x = x0 + dx
        self._last, self._dx = (displacement_m, r), 0.0
        direction = 1.0 if dx > 0.0 else -1.0
        theta = self.theta
        r_hat = self._predict(self.model, x0, r0, x, direction)
        eps = 1e-4
        jac = []
        probe = self._probe
        npar = self.N_PARAMETERS
        for i in range(npar):
            t = list(theta)
            t[i] += eps
            probe.set(*self.parameters(t))
            jac.append((self._predict(probe, x0, r0, x, direction) - r_hat) / eps)
        e = r - r_hat
        self.noise_var_N2 += self._noise_w * (e * e - self.noise_var_N2)
        if abs(self.model.z_of(x0, r0)) < self.ELASTIC_Z:   # far from yield: e is noise
            self.sensor_var_N2 += self.SENSOR_WEIGHT * (e * e - self.sensor_var_N2)
        noise = max(self.noise_var_N2, self.NOISE_FLOOR_N2)
        P = self.P
        pj = [sum(P[i][j] * jac[j] for j in range(npar)) for i in range(npar)]
        s = self._lam * noise + sum(jac[i] * pj[i] for i in range(npar))
        if not (s > 0 and math.isfinite(s) and math.isfinite(e)):
            return
        gain = [p / s for p in pj]
        self.theta = [min(max(t + g * e, lo), hi)
                      for t, g, (lo, hi) in zip(theta, gain, self.BOUNDS)]
        lam = self._lam
        P = [[(P[i][j] - gain[i] * pj[j]) / lam for j in range(npar)] for i in range(npar)]
        p0 = self.P0
        if any(P[i][i] > p0[i] for i in range(npar)):     # bounded covariance: no wind-up
            scale = [math.sqrt(min(1.0, p0[i] / max(P[i][i], 1e-300))) for i in range(npar)]
            P = [[P[i][j] * scale[i] * scale[j] for j in range(npar)] for i in range(npar)]
        self.P = P
        self.model.set(*self.parameters())
        self.updates += 1


class HystereticMember:
    """The member's state and model, from the measurements: what the tangent controller and
    the hysteretic compensator share.

    Parameters
    ----------
    guess : MemberGuess
    dt : float > 0
        Sample period [s].
    identify : bool
        Identify the parameters online (:class:`HystereticIdentifier`); False keeps the guess.

    Attributes
    ----------
    model : BoucWenModel
        The current model.
    displacement_m, velocity_m_s, acceleration_m_s2, restoring_force_N, z : float
        Of the latest sample (zero before the first); ``z`` anchored on the measured
        restoring force.
    """

    #: The member has shown that it yields once its restoring force left the elastic line
    #: from a reversal by this fraction of the model's hysteretic strength ``(1 - a) k D_y``
    #: (plus twice the sensors' noise); until then it is taken as elastic.
    YIELD_EVIDENCE = 0.05

    def __init__(self, guess: MemberGuess, dt: float, *, identify: bool = True):
        self.guess = guess
        self.mass_kg, self.damping_N_s_per_m = guess.mass_kg, guess.damping_N_s_per_m
        self.identifier = HystereticIdentifier(guess, dt) if identify else None
        self.model = (self.identifier.model if identify else
                      BoucWenModel(guess.stiffness_N_per_m, guess.post_yield_ratio,
                                   guess.yield_displacement_m, guess.n))
        self.displacement_m = self.velocity_m_s = self.acceleration_m_s2 = 0.0
        self.restoring_force_N = self.z = 0.0
        self.confidence = 1.0
        self.has_yielded = False
        self._held: set[int] = set()      # samples the identifier does not take (hold)

        self._direction = 1.0
        self._reversal = None             # (x, r) where the motion last reversed
        self._z_path = self._x_path = 0.0

    def hold(self, step: int) -> None:
        """Keep sample `step` out of the identification (a reading at its sensor's range, or
        an acceleration estimated in its place): :meth:`observe_measurement` of that sample
        anchors the state but does not update the parameters."""
        self._held.add(int(step))
        if len(self._held) > 64:             # samples never observed (a run's end)
            self._held.discard(min(self._held))

    def restoring_force_at(self, displacement_m: float, velocity_m_s: float) -> float:
        """The model's restoring force [N] at `displacement_m` [m], its state carried from
        the latest anchored sample along the displacement increment in the direction of
        `velocity_m_s` [m/s] (what the member model says where the measurement cannot:
        an accelerometer at its range)."""
        model = self.model
        z = model.advance(self.z, displacement_m - self.displacement_m,
                          1.0 if velocity_m_s >= 0.0 else -1.0)
        return model.restoring_force(displacement_m, z)

    def observe(self, displacement_m: float, velocity_m_s: float, acceleration_m_s2: float,
                force_N: float, identify: bool = True) -> None:
        """Take the sensor readings of one sample (x [m], v [m/s], a [m/s^2], f_m [N]);
        `identify` False: anchor the state, leave the parameters (:meth:`hold`)."""
        r = force_N - self.mass_kg * acceleration_m_s2 - self.damping_N_s_per_m * velocity_m_s
        if self.identifier is not None and identify:
            self.identifier.observe(displacement_m, r, velocity_m_s)
        self.displacement_m, self.velocity_m_s = displacement_m, velocity_m_s
        self.acceleration_m_s2, self.restoring_force_N = acceleration_m_s2, r
        if not (math.isfinite(displacement_m) and math.isfinite(r)):
            return
        model = self.model
        self.z = model.z_of(displacement_m, r)
        # since the last reversal of the motion: how far the member has left the elastic
        # line, measured and as the model has it (z carried along the measured path)
        direction = 1.0 if velocity_m_s >= 0.0 else -1.0
        if direction != self._direction or self._reversal is None:
            self._direction = direction
            self._reversal = (displacement_m, r)
            self._z_path, self._x_path = self.z, displacement_m
            self.confidence = 1.0 if self.has_yielded else 0.0
            return
        x0, r0 = self._reversal
        self._z_path = model.advance(self._z_path, displacement_m - self._x_path, direction)
        self._x_path = displacement_m
        elastic = r0 + model.stiffness_N_per_m * (displacement_m - x0)
        predicted = abs(model.restoring_force(displacement_m, self._z_path) - elastic)
        measured = abs(r - elastic)
        noise = 2.0 * math.sqrt(self.identifier.sensor_var_N2) if self.identifier else 0.0
        if not self.has_yielded:
            self.has_yielded = measured > self.YIELD_EVIDENCE * model._hk + noise
        self.confidence = (0.0 if not self.has_yielded else 1.0 if predicted <= measured else
                           (measured + noise) / (predicted + noise))

    def observe_measurement(self, latest: Measurement) -> None:
        """:meth:`observe` with a :class:`~seft_msgs_py.interface.Measurement`."""
        held = self._held
        identify = not held or latest.step not in held
        if not identify:
            held.discard(latest.step)
        self.observe(latest.displacement_m, latest.velocity_m_s, latest.acceleration_m_s2,
                     latest.force_N, identify)

    def tangent_ahead(self, horizon_s: float) -> float:
        """Tangent stiffness [N/m] `horizon_s` after the latest sample.

        The displacement path over the horizon is the one of the latest velocity and
        acceleration (``x + v t + a t^2/2``), through its reversal if the velocity changes
        sign on the way (then the member unloads); the tangent is that of the model at the
        end of the path, in the direction of the velocity there.
        """
        model, z = self.model, self.z
        v, a, h = self.velocity_m_s, self.acceleration_m_s2, horizon_s
        v_end = v + a * h
        if v * v_end < 0.0:                          # reversal at t_r = -v/a inside
            t_r = -v / a
            peak = v * t_r + 0.5 * a * t_r * t_r
            z = model.advance(z, peak, 1.0 if v > 0.0 else -1.0)
            z = model.advance(z, v * h + 0.5 * a * h * h - peak, 1.0 if v_end > 0.0 else -1.0)
        else:
            z = model.advance(z, v * h + 0.5 * a * h * h)
        k = model.stiffness_N_per_m
        return k - self.confidence * (k - model.tangent(z, 1.0 if v_end >= 0.0 else -1.0))

    def estimates(self) -> dict[str, float]:
        """The tangent stiffness now and the model's parameters (names
        :data:`HYSTERESIS_ESTIMATES`)."""
        m = self.model
        return {'tangent_stiffness_N_per_m': m.tangent(self.z, 1.0 if self.velocity_m_s >= 0
                                                       else -1.0),
                'hysteresis_stiffness_N_per_m': m.stiffness_N_per_m,
                'hysteresis_post_yield_ratio': m.post_yield_ratio,
                'hysteresis_yield_displacement_m': m.yield_displacement_m,
                'hysteresis_n': m.n,
                'hysteresis_unloading_shape': (m.beta - m.gamma) / (m.beta + m.gamma)}
