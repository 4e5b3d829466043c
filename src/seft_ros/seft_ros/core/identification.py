"""Online identification for the adaptive compensators (no rclpy).

* :class:`RecursiveLeastSquares`: RLS with exponential forgetting and a bounded covariance,
  used by the ``adaptive`` compensator on the specimen's equation of motion
  ``f = m x'' + c x' + k x``;
* :class:`ExcitationGate`: running RMS of a signal against a threshold (the estimates are held
  while the input is quiet);
* :class:`GuardedValue`: an estimate kept in a range and rate limited;
* :func:`ats_coefficients`: the least-squares fit of the adaptive time-series (ATS)
  compensator of Chae, Kazemibidokhti and Ricles (2013).
"""

import math

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['RecursiveLeastSquares', 'ExcitationGate', 'GuardedValue', 'ats_coefficients',
           'backward_differences', 'forgetting_factor']


def forgetting_factor(dt: float, memory_s: float) -> float:
    """Forgetting factor ``lambda = exp(-dt / T)`` of an exponential memory ``T``.

    Parameters
    ----------
    dt : float > 0
        Sample period [s].
    memory_s : float > 0
        Memory time constant T [s] (the weight of a sample falls to 1/e after T).

    Returns
    -------
    float in (0, 1)

    Raises
    ------
    ParameterError
        If ``memory_s <= 0`` (names ``adaptive_memory_s``).
    """
    if not (memory_s > 0 and math.isfinite(memory_s)):
        raise ParameterError(f'parameter adaptive_memory_s={memory_s!r}: expected float > 0')
    return math.exp(-float(dt) / float(memory_s))


class RecursiveLeastSquares:
    """Recursive least squares with exponential forgetting and a covariance bound.

    Minimises ``sum_j lambda^(k-j) (y_j - phi_j^T theta)^2 + lambda^k (theta - theta_0)^T
    P_0^-1 (theta - theta_0)`` recursively::

        K_k     = P_k-1 phi_k / (lambda + phi_k^T P_k-1 phi_k)
        theta_k = theta_k-1 + K_k (y_k - phi_k^T theta_k-1)
        P_k     = (P_k-1 - K_k phi_k^T P_k-1) / lambda

    When the trace of P exceeds ``max_trace`` it is scaled back to it (covariance limiting: a
    regressor that excites only some directions no longer winds P up in the others).

    Parameters
    ----------
    theta0 : array_like, shape (n,)
        Prior estimate (any unit; the regressor's unit times theta is y's unit).
    p0 : float > 0 or ndarray, shape (n, n)
        Prior covariance ``P_0`` (``p0 I`` for a float).
    forgetting : float in (0, 1]
        lambda.
    max_trace : float > 0, optional
        Bound on ``trace(P)`` (default: ``trace(P_0)``).

    Attributes
    ----------
    theta : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    updates : int
        Number of updates so far.

    Raises
    ------
    ParameterError
        If ``forgetting`` is outside (0, 1] or ``p0`` is not positive.

    References
    ----------
    L. Ljung, System Identification: Theory for the User, 2nd ed., Prentice Hall 1999,
    Sec. 11.2, Eqs. 11.12-11.13 (RLS with forgetting). K. J. Astrom and B. Wittenmark,
    Adaptive Control, 2nd ed., Addison-Wesley 1995, Sec. 2.2 and 11.2 (covariance limiting).
    """

    def __init__(self, theta0, p0, forgetting: float = 1.0, max_trace: float | None = None):
        self.theta = np.array(theta0, dtype=float).ravel()
        n = self.theta.shape[0]
        p = np.asarray(p0, dtype=float)
        self.P = p * np.eye(n) if p.ndim == 0 else p.copy()
        if not (0.0 < forgetting <= 1.0):
            raise ParameterError(f'forgetting={forgetting!r}: expected 0 < lambda <= 1')
        if not (self.P.shape == (n, n) and np.all(np.linalg.eigvalsh(self.P) > 0)):
            raise ParameterError(f'p0={p0!r}: expected a positive definite covariance')
        self.forgetting = float(forgetting)
        self.max_trace = float(np.trace(self.P) if max_trace is None else max_trace)
        self.updates = 0

    def update(self, phi, y: float) -> float:
        """Take one sample ``y = phi^T theta + e``; return the a-priori error ``e``."""
        phi = np.asarray(phi, dtype=float)
        p_phi = self.P @ phi
        gain = p_phi / (self.forgetting + phi @ p_phi)
        err = float(y - phi @ self.theta)
        self.theta = self.theta + gain * err
        p = (self.P - np.outer(gain, p_phi)) / self.forgetting
        p = 0.5 * (p + p.T)
        trace = p[0, 0] + p[1, 1] + p[2, 2] if p.shape[0] == 3 else np.trace(p)
        if trace > self.max_trace:
            p *= self.max_trace / trace
        self.P = p
        self.updates += 1
        return err


class ExcitationGate:
    """Is the input strong enough to identify from? A running RMS against a threshold.

    ``ms_k = ms_k-1 + (dt / T) (u_k^2 - ms_k-1)`` (first-order running mean square, time
    constant T); excited when ``sqrt(ms_k) > threshold``.

    Parameters
    ----------
    dt : float > 0
        Sample period [s].
    window_s : float > 0
        T [s].
    threshold : float >= 0
        RMS level (the unit of u).
    """

    def __init__(self, dt: float, window_s: float, threshold: float):
        self._w = min(1.0, float(dt) / float(window_s))
        self._limit = float(threshold) ** 2
        self.mean_square = 0.0

    def update(self, u: float) -> bool:
        """Take one sample; return whether the input is excited."""
        self.mean_square += self._w * (u * u - self.mean_square)
        return self.mean_square > self._limit

    @property
    def excited(self) -> bool:
        """Whether the running RMS is above the threshold."""
        return self.mean_square > self._limit


class GuardedValue:
    """An estimate that follows its target within ``[low, high]`` and a rate limit.

    ``value_k = clip(value_k-1 + clip(target - value_k-1, -max_step, max_step), low, high)``.

    Parameters
    ----------
    initial : float
        Start value (the configured model), clipped into the range.
    low, high : float
        Range (``low <= high``).
    max_step : float >= 0
        Largest change per call.
    """

    def __init__(self, initial: float, low: float, high: float, max_step: float):
        if not low <= high:
            raise ParameterError(f'estimate range [{low!r}, {high!r}]: expected low <= high')
        self.low, self.high, self.max_step = float(low), float(high), float(max_step)
        self.value = min(max(float(initial), self.low), self.high)

    def follow(self, target: float) -> float:
        """Move toward `target` by at most ``max_step``, stay in range; return the value."""
        if not math.isfinite(target):
            return self.value
        step = min(max(target - self.value, -self.max_step), self.max_step)
        self.value = min(max(self.value + step, self.low), self.high)
        return self.value


def backward_differences(y, dt: float) -> np.ndarray:
    """``[y, y', y'']`` of a sequence by backward differences.

    Parameters
    ----------
    y : array_like, shape (n,), n >= 3
        Samples (any unit).
    dt : float > 0
        Sample period [s].

    Returns
    -------
    ndarray, shape (n - 2, 3)
        Rows ``[y_j, (y_j - y_j-1)/dt, (y_j - 2 y_j-1 + y_j-2)/dt^2]`` for j = 2..n-1.
    """
    y = np.asarray(y, dtype=float)
    d1 = (y[2:] - y[1:-1]) / dt
    d2 = (y[2:] - 2.0 * y[1:-1] + y[:-2]) / (dt * dt)
    return np.column_stack([y[2:], d1, d2])


def ats_coefficients(command, measured, dt: float) -> np.ndarray:
    """Least-squares ATS coefficients from a window of command and measured response.

    Parameters
    ----------
    command : array_like, shape (n,), n >= 6
        Commands u_j sent to the actuator (any unit).
    measured : array_like, shape (n,)
        Measured responses r_j of the same steps (the unit of u).
    dt : float > 0
        Sample period [s].

    Returns
    -------
    ndarray, shape (3,)
        ``[a0, a1, a2]`` [-, s, s^2] minimising ``sum_j (u_j - a0 r_j - a1 r'_j - a2 r''_j)^2``
        over j = 2..n-1 (derivatives by :func:`backward_differences`); NaNs if the window is
        rank deficient.

    Raises
    ------
    ParameterError
        If the arrays differ in length or are shorter than 6 samples.

    Notes
    -----
    Chae et al. (2013), Eqs. 9-13: the actuator's inverse is ``u = a0 r + a1 r' + a2 r''``;
    with ``X = [r, r', r'']`` the coefficients are ``A = (X^T X)^-1 X^T U``
    (``numpy.linalg.lstsq``).

    References
    ----------
    Y. Chae, K. Kazemibidokhti and J. M. Ricles (2013), Adaptive time series compensator for
    delay compensation of servo-hydraulic actuator systems for real-time hybrid simulation,
    Earthquake Engng Struct. Dyn. 42(11), 1697-1715.
    """
    u = np.asarray(command, dtype=float)
    r = np.asarray(measured, dtype=float)
    if u.shape != r.shape or u.ndim != 1 or u.shape[0] < 6:
        raise ParameterError(f'ATS window: expected two equal 1-D arrays of >= 6 samples, got '
                             f'shapes {u.shape} and {r.shape}')
    x = backward_differences(r, dt)
    sol, _, rank, _ = np.linalg.lstsq(x, u[2:], rcond=None)
    if rank < 3:
        return np.full(3, np.nan)
    return sol
