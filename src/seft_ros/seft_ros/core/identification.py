"""Online identification for the adaptive compensators (no rclpy).

* :class:`RecursiveLeastSquares`: RLS with exponential forgetting and a bounded covariance,
  used by the ``adaptive`` compensator on the specimen's equation of motion
  ``f = m x'' + c x' + k x``;
* :class:`ExcitationGate`: running RMS of a signal against a threshold (the estimates are held
  while the input is quiet);
* :class:`GuardedValue`: an estimate kept in a range and rate limited;
* :class:`ArxLoopIdentifier`: an ARX model of a sampled loop (the servohydraulic rig's closed
  force loop, reference force to measured force) by RLS, its impulse response kept within a
  band-limited distance of the prior and rate limited (:class:`GuardedResponse`);
* :func:`ats_coefficients`: the least-squares fit of the adaptive time-series (ATS)
  compensator of Chae, Kazemibidokhti and Ricles (2013).
"""

import math

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['RecursiveLeastSquares', 'ExcitationGate', 'GuardedValue', 'ats_coefficients',
           'backward_differences', 'forgetting_factor', 'GuardedResponse', 'ArxLoopIdentifier',
           'arx_from_impulse_response', 'fir_band_basis']


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


def fir_band_basis(n_taps: int, dt: float, band_hz: float, points: int = 41,
                   first_lag: int = 1) -> np.ndarray:
    """Frequency-response rows of FIR taps on a grid of a band.

    Parameters
    ----------
    n_taps : int >= 1
        Number of taps n.
    dt : float > 0
        Sample period [s].
    band_hz : float > 0
        Upper end of the band [Hz] (the grid is ``linspace(0, band_hz, points)``).
    points : int >= 2
        Grid size.
    first_lag : int >= 0
        Lag of the first tap (1: ``y[j] = sum_i h_i u[j - i]``, i = 1..n).

    Returns
    -------
    ndarray of complex, shape (points, n_taps)
        ``B[f, i] = exp(-2j pi f (first_lag + i) dt)``: ``B @ h`` is the FIR's frequency
        response on the grid [-].
    """
    freq = np.linspace(0.0, float(band_hz), int(points))
    lags = np.arange(int(n_taps)) + int(first_lag)
    return np.exp(-2j * np.pi * np.outer(freq, lags) * float(dt))


class GuardedResponse:
    """A response that follows its target within a bound and a rate limit, in a max norm.

    The response is either FIR taps, whose change ``d`` has the size ``|d|_B = max_f |(B
    d)_f|``, its largest frequency-response magnitude on a band grid (``basis`` B,
    :func:`fir_band_basis`), or a frequency response itself (``basis`` None, complex values,
    ``|d| = max_f |d_f|``). Each :meth:`follow` moves toward the target along the straight
    line by at most ``max_step`` in that norm, then scales the deviation from the prior back
    to ``max_deviation`` if it is larger: the vector analogue of :class:`GuardedValue`.

    Parameters
    ----------
    initial : array_like, shape (n,)
        Prior response (taps or frequency response) [its unit].
    basis : ndarray of complex, shape (nf, n), or None
        B, or None for a frequency response.
    max_deviation : float > 0
        Largest ``|h - h0|_B`` [the unit of the FIR's gain].
    max_step : float >= 0
        Largest ``|h_k - h_k-1|_B`` per call.

    Attributes
    ----------
    value : ndarray, shape (n,)
        The guarded taps.
    deviation : float
        ``|value - initial|_B``.

    Raises
    ------
    ParameterError
        If the shapes disagree or a bound is negative.
    """

    def __init__(self, initial, basis, max_deviation: float, max_step: float):
        self.basis = None if basis is None else np.asarray(basis)
        self.initial = np.array(initial, dtype=float if basis is not None else complex).ravel()
        if basis is not None and (self.basis.ndim != 2
                                  or self.basis.shape[1] != self.initial.shape[0]):
            raise ParameterError(f'guarded response: basis of shape {self.basis.shape} does '
                                 f'not fit {self.initial.shape[0]} taps')
        if not (max_deviation > 0 and max_step >= 0):
            raise ParameterError(f'guarded response: expected max_deviation > 0 and max_step '
                                 f'>= 0, got {max_deviation!r}, {max_step!r}')
        self.max_deviation, self.max_step = float(max_deviation), float(max_step)
        self.value = self.initial.copy()
        self.deviation = 0.0

    def norm(self, change) -> float:
        """``|change|_B`` (or ``max |change|`` without a basis) [-]."""
        if self.basis is None:
            return float(np.max(np.abs(change)))
        return float(np.max(np.abs(self.basis @ change)))

    def follow(self, target) -> np.ndarray:
        """Move toward `target` (shape (n,)) within the limits; return the taps.

        A target with a non-finite entry is ignored (the taps are held).
        """
        target = np.asarray(target, dtype=self.initial.dtype)
        if not np.all(np.isfinite(target)):
            return self.value
        change = target - self.value
        size = self.norm(change)
        if size > self.max_step:
            change = change * (self.max_step / size)
        value = self.value + change
        offset = value - self.initial
        deviation = self.norm(offset)
        if deviation > self.max_deviation:
            offset = offset * (self.max_deviation / deviation)
            value = self.initial + offset
            deviation = self.max_deviation
        self.value = value
        self.deviation = deviation
        return self.value


def arx_from_impulse_response(response, na: int, nb: int) -> np.ndarray:
    """ARX coefficients that reproduce an impulse response (least squares).

    Parameters
    ----------
    response : array_like, shape (N,), N >= na + nb
        Impulse response ``h[0..N-1]`` of a causal system (any unit).
    na, nb : int >= 0
        Orders of ``A(z) = 1 + a_1 z^-1 + ... + a_na z^-na`` and
        ``B(z) = b_1 z^-1 + ... + b_nb z^-nb``.

    Returns
    -------
    ndarray, shape (na + nb,)
        ``theta = [a_1..a_na, b_1..b_nb]`` minimising ``sum_j (h[j] + sum_i a_i h[j-i] -
        sum_i b_i delta[j-i])^2`` (zeros before j = 0): exact when ``B/A`` has these orders.
    """
    h = np.asarray(response, dtype=float)
    n = h.shape[0]
    rows = np.zeros((n, na + nb))
    for i in range(1, na + 1):
        rows[i:, i - 1] = -h[:n - i]
    for i in range(1, nb + 1):
        if i < n:
            rows[i, na + i - 1] = 1.0
    return np.linalg.lstsq(rows, h, rcond=None)[0]


class ArxLoopIdentifier:
    """An ARX model of a sampled loop, identified by RLS; its frequency response guarded.

    The model is ``A(q) y[j] = B(q) u[j] + e[j]``, i.e. ::

        y[j] = -a_1 y[j-1] - ... - a_na y[j-na] + b_1 u[j-1] + ... + b_nb u[j-nb] + e[j]

    (``b_0 = 0``: ``u[j]`` is computed from ``y[j]``), with ``theta = [a, b]`` by
    :class:`RecursiveLeastSquares` (forgetting, prior covariance ``p0 I``, trace bounded by
    its start) from the prior's exact fit (:func:`arx_from_impulse_response`). What is used is
    the frequency response ``B/A`` on a grid ``freq_hz`` (the band the loop is inverted in):
    :meth:`follow` moves the response in use toward the estimate's within the limits of
    :class:`GuardedResponse` (max norm over the grid). The estimate need not be stable: while
    RLS converges, a high-order ARX estimate passes through models with poles outside the
    unit circle whose frequency response already fits the excited band (measured: within
    1 % up to 12 Hz after 0.5 s of strong motion, with a pole of modulus 1.1), and only that
    response is used. The caller decides when the input is excited enough to update (the
    hold).

    Parameters
    ----------
    prior : array_like, shape (N,)
        Prior impulse response ``h[0..N-1]`` (the configured model's loop) [y/u].
    na, nb : int >= 1
        Model orders.
    dt : float > 0
        Sample period [s].
    freq_hz : array_like, shape (nf,)
        Grid of the response in use [Hz].
    forgetting : float in (0, 1]
        RLS forgetting factor lambda.
    p0 : float > 0
        Prior covariance [1/u^2]: the prior weighs as much as ``1 / (p0 u^2)`` samples of
        signals of size u.
    max_deviation : float > 0
        Largest ``max_f |T_f - T_prior,f|`` [y/u].
    max_step : float >= 0
        Largest change of the response in use per :meth:`follow`, same norm [y/u].

    Attributes
    ----------
    rls : RecursiveLeastSquares
    guard : GuardedResponse
        Its ``initial`` is the prior fit's response, its ``value`` the response in use
        (complex, shape (nf,)).

    Raises
    ------
    ParameterError
        If a value is out of range.

    Notes
    -----
    With output noise, the equation error of an ARX model is coloured and its least-squares
    estimate biased (Ljung 1999, Sec. 7.3); at the model's full order and a signal-to-noise
    ratio of 40 dB the bias measured here is 0.1-0.3 % of the response up to 12 Hz and about
    1 % to 40 Hz. An instrumental-variable estimate would remove it but was ill conditioned
    on this band-limited input.

    References
    ----------
    L. Ljung, System Identification: Theory for the User, 2nd ed., Prentice Hall 1999,
    Sec. 4.2 (ARX), 7.3 and 11.2 (RLS with forgetting).
    """

    def __init__(self, prior, na: int, nb: int, dt: float, freq_hz, forgetting: float,
                 p0: float, max_deviation: float, max_step: float):
        prior = np.array(prior, dtype=float).ravel()
        na, nb = int(na), int(nb)
        if not (na >= 1 and nb >= 1 and prior.shape[0] >= na + nb + 1
                and np.all(np.isfinite(prior))):
            raise ParameterError(f'ARX loop model: expected orders >= 1 and a finite prior '
                                 f'longer than na + nb, got na={na}, nb={nb}, '
                                 f'{prior.shape[0]} samples')
        if not (p0 > 0 and math.isfinite(p0)):
            raise ParameterError(f'ARX loop prior covariance p0={p0!r}: expected > 0')
        self.na, self.nb = na, nb
        self.dt = float(dt)
        self.freq_hz = np.asarray(freq_hz, dtype=float)
        # z^-i on the grid, i = 0..max(na, nb)
        self._powers = np.exp(-2j * np.pi * np.outer(self.freq_hz, np.arange(max(na, nb) + 1))
                              * self.dt)
        theta0 = arx_from_impulse_response(prior, na, nb)
        self.rls = RecursiveLeastSquares(theta0, p0, forgetting)
        self.guard = GuardedResponse(self.frequency_response(theta0), None, max_deviation,
                                     max_step)

    @property
    def response(self) -> np.ndarray:
        """The guarded frequency response in use, complex, shape (nf,) [y/u]."""
        return self.guard.value

    @property
    def deviation(self) -> float:
        """``max_f |response - prior fit|`` [y/u]."""
        return self.guard.deviation

    def frequency_response(self, theta=None) -> np.ndarray:
        """``B/A`` on the grid (default: of the RLS estimate), complex, shape (nf,) [y/u]."""
        theta = self.rls.theta if theta is None else np.asarray(theta, dtype=float)
        z = self._powers
        a = z[:, 0] + z[:, 1:self.na + 1] @ theta[:self.na]
        return (z[:, 1:self.nb + 1] @ theta[self.na:]) / a

    def update(self, past_outputs, past_inputs, y: float) -> float:
        """Take one sample; return the a-priori error [y].

        Parameters
        ----------
        past_outputs : sequence of float, length na
            ``y[j-1], ..., y[j-na]`` (newest first) [y].
        past_inputs : sequence of float, length nb
            ``u[j-1], ..., u[j-nb]`` (newest first) [u].
        y : float
            ``y[j]`` [y].
        """
        phi = np.concatenate([np.negative(past_outputs, dtype=float),
                              np.asarray(past_inputs, dtype=float)])
        return self.rls.update(phi, y)

    def follow(self) -> np.ndarray:
        """Move the response in use toward the estimate's (guarded); return it.

        A non-finite estimate (``A`` zero on the grid) is ignored.
        """
        return self.guard.follow(self.frequency_response())


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
