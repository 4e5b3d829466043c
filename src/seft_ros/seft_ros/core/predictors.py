"""Delay compensators of substructure EFT: estimates of the fed-back specimen acceleration.

Every compensator implements the ``Predictor`` protocol of
:mod:`seft_ros.core.reference_force` and is chosen by the ``predictor`` parameter:

``none``
    The measured acceleration of the previous step (paper Eq. 5.3).
``polynomial``
    Extrapolation of the measured acceleration over the loop delay (Horiuchi et al. 1996).
``model``
    Model-based compensation after Carrion and Spencer (2007), made consistent with the
    zero-order hold of the reference force ("impulse matching"), with the force loop of the
    servo-hydraulic rig inverted by a model-based feedforward filter.
``adaptive``
    The ``model`` compensator with the actuator delay and amplitude identified online.

Timing (see :mod:`seft_ros.core.experiment`): the reference force ``f_r[k]`` is built after
the measurement of step ``k-1``; on the pure-delay rig (``tau = n dt + delta``) it acts on
the specimen over ``[t_k + tau, t_k+1 + tau)``.

Sampled-data consistency: the actuator holds each force for a whole step while the specimen
accelerates inside it, so matching the acceleration only at sample instants leaves an error
that grows with alpha and acts as added damping. The hold-consistent compensators instead
make the held force equal to the step average of the desired force (paper Eq. 2.5)::

    F_j = -(1 + alpha) m gbar_j - alpha m (v_j+1 - v_j) / dt                    (*)

with ``gbar_j`` the step average of the ground acceleration (the record is linear between
samples, as in the reference analysis) and ``(v_j+1 - v_j)/dt`` the step-average
acceleration: integrated over the step, (*) is exactly the reference equation of motion
``(1 + alpha) m x'' + c x' + k x = -(1 + alpha) m xg''``.
"""

from collections import deque
import math

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sampling import linear_map as _linear_map
from seft_msgs_py.sampling import single_blas_thread as _single_blas_thread
from seft_msgs_py.sampling import split_delay as _split_delay
from seft_msgs_py.sampling import zoh as _zoh

__all__ = [
    'NoPredictor', 'PolynomialPredictor', 'ModelPredictor', 'AdaptivePredictor',
    'DelayImpulseModel', 'ForceLoopInverse', 'lagrange_extrapolation_weights',
    'foh_step_average', 'model_parameters',
]


# -- helpers --------------------------------------------------------------------------------





def lagrange_extrapolation_weights(order: int, horizon_steps: float) -> np.ndarray:
    """Weights of the polynomial through ``order + 1`` equally spaced samples, evaluated ahead.

    Parameters
    ----------
    order : int >= 0
        Polynomial order p.
    horizon_steps : float
        Evaluation point h in steps after the newest sample.

    Returns
    -------
    ndarray, shape (order + 1,)
        ``w`` with ``y(t_newest + h dt) = sum_i w[i] y[newest - i]`` for every polynomial of
        degree <= p.

    Notes
    -----
    Lagrange basis on the nodes ``0, -1, ..., -p``: ``w_i = prod_{j != i} (h + j)/(j - i)``.
    """
    nodes = -np.arange(order + 1, dtype=float)
    w = np.ones(order + 1)
    for i in range(order + 1):
        for j in range(order + 1):
            if j != i:
                w[i] *= (horizon_steps - nodes[j]) / (nodes[i] - nodes[j])
    return w


def foh_step_average(window, offset_steps: float) -> float:
    """Average of a linearly interpolated record over one step starting `offset_steps` ahead.

    Parameters
    ----------
    window : sequence of float, shape (L + 1,)
        Samples ``y[k], y[k+1], ..., y[k+L]`` (any unit).
    offset_steps : float >= 0
        Start of the interval in steps after ``t_k``; ``offset_steps + 1 <= L``.

    Returns
    -------
    float
        ``(1/dt) int_{t_k + s dt}^{t_k + (s+1) dt} y(t) dt`` with y linear between samples
        (first-order hold, the interpolation of the reference analysis); for a whole s this is
        ``(y[k+s] + y[k+s+1]) / 2``.
    """
    i = int(math.floor(offset_steps + 1e-12))
    f = offset_steps - i
    if f < 1e-12:
        return 0.5 * (window[i] + window[i + 1])
    y0, y1, y2 = window[i], window[i + 1], window[i + 2]
    # int_f^1 of the first segment + int_0^f of the second one
    first = (1.0 - f) * (y0 + (y1 - y0) * 0.5 * (1.0 + f))
    second = f * (y1 + (y2 - y1) * 0.5 * f)
    return first + second


def _number(params, name: str, fallback: str | None = None) -> float:
    """``params[name]``, or ``params[fallback]`` when it is 0 (the "use the true value")."""
    value = float(params[name])
    if value == 0.0 and fallback is not None:
        value = float(params[fallback])
    return value


def model_parameters(params) -> dict:
    """The predictor's specimen model and delay (``predictor_*``; 0 = the true value).

    Returns
    -------
    dict
        ``mass_kg, damping_N_s_per_m, stiffness_N_per_m, tau_s`` [kg, N s/m, N/m, s].
    """
    return {
        'mass_kg': _number(params, 'predictor_mass_kg', 'mass_kg'),
        'damping_N_s_per_m': _number(params, 'predictor_damping_N_s_per_m',
                                     'damping_N_s_per_m'),
        'stiffness_N_per_m': _number(params, 'predictor_stiffness_N_per_m',
                                     'stiffness_N_per_m'),
        'tau_s': _number(params, 'predictor_tau_s', 'tau_s'),
    }


# -- none -----------------------------------------------------------------------------------

class NoPredictor:
    """No compensation: the measured acceleration of the previous step (paper Eq. 5.3).

    ``a_hat[k] = a_m[k-1]``; zero before the first measurement. The ground term is the
    sample ``xg''[k]`` (``step_average = False``), as in the reference study.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 5.3.
    """

    name = 'none'
    step_average = False
    delay_s = 0.0

    @classmethod
    def from_parameters(cls, params) -> 'NoPredictor':
        """No parameters."""
        return cls()

    def predict(self, latest: Measurement | None, commanded_N, ground_force_N: float = 0.0
                ) -> float:
        """Return the previous step's measured acceleration [m/s^2]."""
        return 0.0 if latest is None else latest.acceleration_m_s2

    def command(self, force_N: float) -> float:
        """The reference force is sent as it is."""
        return force_N


# -- polynomial -----------------------------------------------------------------------------

class PolynomialPredictor:
    """Polynomial extrapolation of the measured acceleration over the loop delay.

    ``a_hat[k] = sum_{i=0}^{p} w_i a_m[k-1-i]``, the polynomial of order p through the last
    ``p + 1`` measured accelerations evaluated ``h = tau + 1.5 dt`` after the newest one
    (:func:`lagrange_extrapolation_weights`): the force of step k reaches the specimen over
    ``[t_k + tau, t_k+1 + tau)``, whose middle is ``tau + 1.5 dt`` after ``t_k-1`` (the
    hold-consistent point; Horiuchi et al. use ``tau``). Missing samples at the start are 0.

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    tau_s : float >= 0
        Loop delay to compensate [s].
    order : int in 1..3
        Polynomial order p.

    Raises
    ------
    ParameterError
        If the order is outside 1..3 or ``tau_s < 0``.

    Notes
    -----
    For order 1, ``a_hat = a[k-1] + h/dt (a[k-1] - a[k-2])``. High orders amplify noise by
    ``sqrt(sum w_i^2)`` (order 3, tau = 10 ms, dt = 2 ms: about 600).

    References
    ----------
    T. Horiuchi, M. Nakagawa, M. Sugano and T. Konno (1996), Development of a real-time hybrid
    experimental system with actuator delay compensation, Proc. 11th WCEE, Paper 660.
    """

    name = 'polynomial'
    step_average = True

    def __init__(self, dt: float, tau_s: float, order: int = 2):
        if order not in (1, 2, 3):
            raise ParameterError(f'parameter polynomial_order={order!r}: expected 1, 2 or 3')
        if not tau_s >= 0:
            raise ParameterError(f'parameter predictor_tau_s={tau_s!r}: expected >= 0')
        self.delay_s = float(tau_s)
        self.order = int(order)
        self.weights = lagrange_extrapolation_weights(order, tau_s / dt + 1.5)
        self._history = deque([0.0] * (order + 1), maxlen=order + 1)   # newest first
        self._extrapolate = _linear_map(self.weights, name='extrapolate')

    @classmethod
    def from_parameters(cls, params) -> 'PolynomialPredictor':
        """Build from ``dt``, ``predictor_tau_s`` (0: ``tau_s``) and ``polynomial_order``."""
        return cls(float(params['dt']), model_parameters(params)['tau_s'],
                   int(params['polynomial_order']))

    def predict(self, latest: Measurement | None, commanded_N, ground_force_N: float = 0.0
                ) -> float:
        """Return the extrapolated acceleration [m/s^2]."""
        if latest is not None:
            self._history.appendleft(latest.acceleration_m_s2)
        return self._extrapolate(self._history)

    def command(self, force_N: float) -> float:
        """The reference force is sent as it is."""
        return force_N


# -- model ----------------------------------------------------------------------------------

class DelayImpulseModel:
    """The specimen driven by a delayed, held force, sampled exactly (ZOH).

    The force ``f[i]`` acts on the specimen ``m x'' + c x' + k x = f`` over
    ``[t_i + tau, t_i+1 + tau)`` (paper Eqs. 5.1-5.2, ``tau = n dt + delta``). From the state
    at ``t_k-1``, driven by the forces ``f[k-2-n..k-1]`` already sent, the state at the start
    of the interval of the new force ``f[k]`` is (matrix exponential over the split first
    step ``delta`` and ``n + 1`` whole steps, ``scipy.signal.cont2discrete``)::

        s_hat = [x, v](t_k + tau) = E [x, v](t_k-1) + H f[k-2-n..k-1]

    and over that interval ``s(t_k+1 + tau) = Phi s_hat + Gamma f[k]``.

    Parameters
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float
        Specimen model m [kg], c [N s/m], k [N/m].
    dt : float > 0
        Control period [s].
    tau_s : float >= 0
        Delay [s].

    Attributes
    ----------
    E : ndarray, shape (2, 2)
    H : ndarray, shape (2, n + 2)
        [m/N, m/s/N].
    phi : ndarray, shape (2, 2)
    gamma : ndarray, shape (2,)
        One step of the specimen under a held force [m/N, m/s/N].
    q : float
        ``gamma[1]``, velocity change per unit held force over a step [m/s/N].

    Raises
    ------
    ParameterError
        If a model value is out of range.
    """

    def __init__(self, mass_kg: float, damping_N_s_per_m: float, stiffness_N_per_m: float,
                 dt: float, tau_s: float):
        m, c, k = float(mass_kg), float(damping_N_s_per_m), float(stiffness_N_per_m)
        if not (m > 0 and c >= 0 and k > 0 and dt > 0 and tau_s >= 0):
            raise ParameterError('predictor model: expected m > 0, c >= 0, k > 0, dt > 0 and '
                                 f'tau >= 0, got {m!r}, {c!r}, {k!r}, {dt!r}, {tau_s!r}')
        self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m = m, c, k
        self.dt = float(dt)
        self.n, self.delta = _split_delay(tau_s, dt)
        self.tau_s = float(tau_s)
        a = np.array([[0.0, 1.0], [-k / m, -c / m]])
        b = np.array([[0.0], [1.0 / m]])
        phi, gam = _zoh(a, b, dt)
        phi_d, gam_d = _zoh(a, b, self.delta)
        n = self.n
        powers = [np.eye(2)]
        for _ in range(n + 1):
            powers.append(phi @ powers[-1])
        self.phi = phi
        self.gamma = gam[:, 0]
        self.q = float(gam[1, 0])
        self.E = powers[n + 1] @ phi_d
        self.H = np.column_stack([powers[n + 1] @ gam_d[:, 0]]
                                 + [powers[n - i] @ gam[:, 0] for i in range(n + 1)])
        self._gains = {}

    def state_ahead(self, x_m: float, v_m_s: float, forces_N) -> np.ndarray:
        """``s_hat`` [m, m/s] from the state at t_k-1 and ``f[k-2-n..k-1]`` (n + 2 values)."""
        return self.E @ np.array([x_m, v_m_s]) + self.H @ np.asarray(forces_N, dtype=float)

    def matching_gains(self, alpha: float):
        """Gains ``(K, beta)`` of the held force ``f = beta G - K s_hat`` (pole matching).

        Parameters
        ----------
        alpha : float >= 0
            Mass ratio.

        Returns
        -------
        K : ndarray, shape (2,)
            [N/m, N s/m].
        beta : float
            Gain on the ground force ``G = -(1 + alpha) m gbar`` [-].

        Notes
        -----
        ``K`` places the eigenvalues of ``Phi - Gamma K`` at ``exp(lambda dt)``, the sampled
        poles of the reference structure ``(1 + alpha) m x'' + c x' + k x = 0`` (Ackermann's
        formula ``K = [0 1] [Gamma, Phi Gamma]^-1 p(Phi)``); ``beta`` makes the static gain
        from G to x equal to the reference's ``1/k``.
        """
        key = float(alpha)
        if key not in self._gains:
            m, c, k = self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m
            total = (1.0 + key) * m
            lam = np.roots([total, c, k])
            z = np.exp(lam * self.dt)
            coeff = np.real(np.poly(z))                   # z^2 + a1 z + a0
            phi, g = self.phi, self.gamma
            p_phi = phi @ phi + coeff[1] * phi + coeff[2] * np.eye(2)
            ctrb = np.column_stack([g, phi @ g])
            gain = np.linalg.solve(ctrb.T, np.array([0.0, 1.0])) @ p_phi
            closed = phi - np.outer(g, gain)
            static = np.linalg.solve(np.eye(2) - closed, g)[0]
            self._gains[key] = (gain, (1.0 / k) / static)
        return self._gains[key]


def _past(history, count: int) -> np.ndarray:
    """The last `count` entries of `history`, zero-padded at the front (rest before t = 0)."""
    tail = list(history[-count:]) if count else []
    return np.array([0.0] * (count - len(tail)) + tail)


class ModelPredictor:
    """Model-based compensation consistent with the hold (after Carrion and Spencer 2007).

    Takes the latest measured state ``x, v`` (step k-1) as the initial condition and
    integrates the specimen model exactly (ZOH) over the loop delay plus the one-step
    measurement lag, driven by the forces already sent (they reach the specimen in that
    window), to the start of the interval ``[t_k + tau, t_k+1 + tau)`` where the new force
    acts (:class:`DelayImpulseModel`, state ``s_hat``). Over that interval the step-average
    acceleration is ``a_hat = (r s_hat + q F) / dt`` (``r`` = velocity row of ``Phi - I``):
    the new force F enters its own prediction, an algebraic loop solved exactly.

    ``matching='impulse'``: F is the step average of paper Eq. 2.5,
    ``F = G - alpha m a_hat`` with ``G = -(1 + alpha) m gbar``, i.e.
    ``F = (G dt - alpha m r s_hat) / (dt + alpha m q)``: integrated over the step the
    reference equation of motion holds exactly, but the sampled closed loop's poles are off by
    ``O((omega dt)^2)`` (0.02-0.05 % in frequency), which lightly damped specimens amplify.

    ``matching='poles'`` (default): the same law with the exact gains,
    ``F = beta G - K s_hat`` (:meth:`DelayImpulseModel.matching_gains`), so that the sampled
    closed loop has exactly the sampled poles and static gain of the reference structure; the
    returned estimate is the acceleration that Eq. 2.5 needs to give F,
    ``a_hat = (G - F) / (alpha m)``.

    On the servo-hydraulic rig the actuator is a force loop, not a delay: a feedforward FIR
    ``W(z)`` (:class:`ForceLoopInverse`) makes the step-average actuator force follow F
    delayed by a whole number of steps, and the prediction uses that delay.

    Parameters
    ----------
    model : DelayImpulseModel
    alpha : float >= 0
        Mass ratio.
    mass_kg : float > 0
        Specimen mass m of the reference force [kg].
    loop_inverse : ForceLoopInverse, optional
        Feedforward force-loop inverse (servo-hydraulic rig); None on the delay rig.
    matching : {'poles', 'impulse'}

    References
    ----------
    J. E. Carrion and B. F. Spencer Jr. (2007), Model-based strategies for real-time hybrid
    testing, NSEL Report 006, University of Illinois. N. Nakata and S. Combs, Substructure
    Effective Force Testing, Sec. 6 and Eqs. 2.5, 5.1-5.3. K. J. Astrom and B. Wittenmark,
    Computer-Controlled Systems, 3rd ed., Sec. 4.5 (Ackermann's formula).
    """

    name = 'model'
    step_average = True

    def __init__(self, model: DelayImpulseModel, alpha: float, mass_kg: float,
                 loop_inverse: 'ForceLoopInverse | None' = None, matching: str = 'poles'):
        if matching not in ('poles', 'impulse'):
            raise ParameterError(f"matching={matching!r}: expected one of 'poles', "
                                 "'impulse'")
        self.model = model
        self.alpha = float(alpha)
        self.mass_kg = float(mass_kg)
        self.loop_inverse = loop_inverse
        self.matching = matching
        self.delay_s = model.tau_s
        self.dt = model.dt
        self._r = (model.phi - np.eye(2))[1]
        self._n_past = model.n + 2
        self._zeros = [0.0] * self._n_past
        self._feedback = None
        if matching == 'poles':
            # K s_hat = K E [x, v] + K H f[k-2-n..k-1], one row of n + 4 numbers per step
            gain, beta = model.matching_gains(self.alpha)
            row = gain @ np.hstack([model.E, model.H])
            self._beta = float(beta)
            self._kx, self._kv = float(row[0]), float(row[1])
            self._feedback = _linear_map(row[2:], name='feedback')

    @classmethod
    def from_parameters(cls, params) -> 'ModelPredictor':
        """Build from the specimen, ``predictor_*``, ``dt`` and the rig parameters.

        On the ``delay`` rig the delay is ``predictor_tau_s`` (0: ``tau_s``); on the
        ``servohydraulic`` rig the force loop is modelled from the rig parameters and the
        discrete force controller (:class:`ForceLoopInverse`).
        """
        mp = model_parameters(params)
        dt = float(params['dt'])
        inverse = None
        tau = mp['tau_s']
        if params.get('rig_model') == 'servohydraulic':
            inverse = ForceLoopInverse.from_parameters(params)
            tau = inverse.delay_steps * dt
        model = DelayImpulseModel(mp['mass_kg'], mp['damping_N_s_per_m'],
                                  mp['stiffness_N_per_m'], dt, tau)
        return cls(model, float(params['alpha']), float(params['mass_kg']), inverse)

    def force(self, s_hat, ground_force_N: float) -> float:
        """The held force F [N] for the predicted state `s_hat` and ground force G [N]."""
        alpha, m = self.alpha, self.mass_kg
        if self.matching == 'impulse':
            p = float(self._r @ s_hat)
            return (ground_force_N * self.dt - alpha * m * p) / (self.dt + alpha * m
                                                                  * self.model.q)
        gain, beta = self.model.matching_gains(alpha)
        return beta * ground_force_N - float(gain @ s_hat)

    def predict(self, latest: Measurement | None, commanded_N, ground_force_N: float = 0.0
                ) -> float:
        """Return the fed-back acceleration [m/s^2] (see class notes).

        `commanded_N` are the desired forces ``F[0..k-1]`` (before the loop inverse).
        With pole matching, ``K s_hat = K E [x, v] + K H f`` is one precomputed row (the
        same numbers within rounding).
        """
        x, v = (0.0, 0.0) if latest is None else (latest.displacement_m, latest.velocity_m_s)
        if self._feedback is None:
            s_hat = self.model.state_ahead(x, v, _past(commanded_N, self.model.n + 2))
            force = self.force(s_hat, ground_force_N)
        else:
            count = self._n_past
            past = commanded_N[-count:]
            if len(past) < count:                   # rest before t = 0
                past = self._zeros[len(past):] + list(past)
            force = self._beta * ground_force_N - (self._kx * x + self._kv * v
                                                   + self._feedback(past))
        if self.alpha == 0.0:
            return 0.0
        return (ground_force_N - force) / (self.alpha * self.mass_kg)

    def command(self, force_N: float) -> float:
        """The command for the actuator: `force_N` through the loop inverse, if any."""
        return force_N if self.loop_inverse is None else self.loop_inverse.step(force_N)


class ForceLoopInverse:
    """Feedforward FIR ``W(z)`` so that the servo-hydraulic force loop acts as a pure delay.

    The closed force loop ``T(z)`` (rig sampled exactly with its I/O latency,
    :func:`seft_plant_sim.servohydraulic.sample`, and the discrete loop-shaping controller
    :class:`~seft_ros.core.controller.ForceServoController`) maps the reference force to the
    actuator force; its output here is the step-average actuator force
    ``(1/dt) int_{t_j}^{t_j+1} A p_L dt`` (:func:`step_average_force_impulse_response`).
    ``W`` is the FIR of ``n_taps`` taps minimizing, on a grid of frequencies ``f`` up to
    Nyquist (``z = exp(2j pi f dt)``)::

        sum_{f <= band_hz} |W T - z^-d|^2 + mu sum_{f > band_hz} |W|^2

    (linear least squares, ``numpy.linalg.lstsq``): ``W T ~ z^-d`` in the band of the
    response, and a bounded ``|W|`` above it, where the loop cannot push (|T| falls to 0.36
    at 50 Hz and 0.007 at 150 Hz) and an exact inverse would amplify noise a hundredfold.

    Parameters
    ----------
    impulse_response : ndarray, shape (N,)
        Impulse response of ``T`` [N/N].
    dt : float > 0
        Control period [s].
    delay_steps : int >= 1
        d.
    n_taps : int >= 1
    band_hz : float > 0
    hf_weight : float >= 0
        mu.

    Attributes
    ----------
    taps : ndarray, shape (n_taps,)
    band_error : float
        ``max |W T - z^-d|`` up to 25 Hz [-].
    max_gain : float
        ``max |W|`` [-].
    """

    def __init__(self, impulse_response, dt: float, delay_steps: int, n_taps: int = 48,
                 band_hz: float = 40.0, hf_weight: float = 1e-3):
        y = np.asarray(impulse_response, dtype=float)
        nfft = max(4096, 2 * y.shape[0])
        freq = np.fft.rfftfreq(nfft, dt)
        t = np.fft.rfft(y, n=nfft)
        basis = np.exp(-2j * np.pi * np.outer(freq, np.arange(n_taps)) * dt)
        band = freq <= band_hz
        target = np.exp(-2j * np.pi * freq * delay_steps * dt)
        fit = basis[band] * t[band, None]
        reg = basis[~band] * math.sqrt(hf_weight)
        a = np.vstack([fit.real, fit.imag, reg.real, reg.imag])
        rhs = np.concatenate([target[band].real, target[band].imag,
                              np.zeros(2 * reg.shape[0])])
        with _single_blas_thread():               # the same taps on every machine
            self.taps = np.linalg.lstsq(a, rhs, rcond=None)[0]
        w_f = basis @ self.taps
        low = freq <= 25.0
        self.band_error = float(np.max(np.abs(w_f[low] * t[low] - target[low])))
        self.max_gain = float(np.max(np.abs(w_f)))
        self.delay_steps = int(delay_steps)
        self._x = [0.0] * n_taps                    # newest first
        self._fir = _linear_map(self.taps, name='fir')

    @classmethod
    def from_parameters(cls, params) -> 'ForceLoopInverse':
        """Model the loop from the rig parameters, the specimen model and the controller.

        ``predictor_loop_delay_steps`` (d) and ``predictor_loop_taps`` set the fit; the
        specimen model is that of the predictor (``predictor_*``).
        """
        try:  # the plant models are optional on a lab's controller host
            from seft_plant_sim.servohydraulic import ServoHydraulicParams
            from seft_plant_sim.specimen import LinearSpecimen
        except ImportError as exc:
            raise ParameterError(
                'predictor model on rig_model servohydraulic: the force-loop model comes from '
                f'seft_plant_sim, which cannot be imported here ({exc}); install it') from None
        from seft_ros.core.controller import ForceServoController
        mp = model_parameters(params)
        spec = LinearSpecimen(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'])
        ctrl = ForceServoController.from_parameters(params)
        resp = step_average_force_impulse_response(
            ServoHydraulicParams.from_parameters(params), spec, ctrl, 1000)
        return cls(resp, ctrl.dt, int(params['predictor_loop_delay_steps']),
                   int(params['predictor_loop_taps']))

    def step(self, force_N: float) -> float:
        """Filter one sample of the desired force [N]; return the command [N]."""
        x = self._x
        x.insert(0, force_N)
        x.pop()
        return self._fir(x)


def step_average_force_impulse_response(rig_params, specimen, controller, n: int
                                        ) -> np.ndarray:
    """Impulse response of the closed force loop to the step-average actuator force.

    Parameters
    ----------
    rig_params : ServoHydraulicParams
    specimen : LinearSpecimen
    controller : ForceServoController
    n : int
        Number of samples.

    Returns
    -------
    ndarray, shape (n,)
        ``y[j] = (1/dt) int_{t_j}^{t_j+1} A p_L dt`` for ``f_r = delta[j]`` [N/N], linear
        (no valve saturation), from rest.

    Notes
    -----
    The continuous rig (:func:`seft_plant_sim.servohydraulic.continuous_model`) is augmented
    with the integral of the actuator force and sampled with the split I/O latency as
    :func:`seft_plant_sim.servohydraulic.sample`; the loop is closed with the measured force
    sample ``f_m[j]`` and the discrete controller, as in the one-process simulator.
    """
    from seft_plant_sim.servohydraulic import continuous_model
    dt = float(controller.dt)
    sys = continuous_model(rig_params, specimen)
    ns = sys.A.shape[0]
    true_force = np.asarray(sys.C)[4]
    a = np.zeros((ns + 1, ns + 1))
    a[:ns, :ns] = sys.A
    a[ns, :ns] = true_force
    b = np.vstack([sys.B, [[0.0]]])
    nd, delta = _split_delay(rig_params.io_latency_s, dt)
    phi, _ = _zoh(a, b, dt)
    phi_rest, g_late = _zoh(a, b, dt - delta)
    _, g_early = _zoh(a, b, delta)
    g_early = (phi_rest @ g_early)[:, 0]
    g_late = g_late[:, 0]
    measured_force = _linear_map(np.asarray(sys.C)[0], name='measured_force')
    advance = _linear_map(np.hstack([phi, g_early[:, None], g_late[:, None]]), name='advance')
    bz, az = np.ravel(controller.bz), np.ravel(controller.az)
    bz, az = bz / az[0], az / az[0]
    nc = max(len(bz), len(az)) - 1
    bz = np.concatenate([bz, np.zeros(nc + 1 - len(bz))])
    az = np.concatenate([az, np.zeros(nc + 1 - len(az))])
    bz, az = bz.tolist(), az.tolist()
    zc = [0.0] * nc
    s = [0.0] * (ns + 1)
    u_hist = deque([0.0] * (nd + 1), maxlen=nd + 1)
    out = np.zeros(n)
    for j in range(n):
        fr = 1.0 if j == 0 else 0.0
        e = fr - measured_force(s)
        u = bz[0] * e + (zc[0] if nc else 0.0)
        for i in range(nc):
            nxt = zc[i + 1] if i + 1 < nc else 0.0
            zc[i] = bz[i + 1] * e - az[i + 1] * u + nxt
        early = u_hist[0]
        late = u_hist[1] if nd >= 1 else u
        w_before = s[ns]
        s = list(advance(s + [early, late]))
        u_hist.append(u)
        out[j] = (s[ns] - w_before) / dt
    return out


# -- adaptive -------------------------------------------------------------------------------

class AdaptivePredictor:
    """The hold-consistent model predictor with the actuator delay and gain identified online.

    The actuator is modelled as ``f(t) = A f_r(t - tau)`` with unknown A and tau. Over a
    sliding window of ``window_s``, for each whole-step candidate ``n`` the measured velocity
    increments are regressed on the two reference forces that can act in a step (exact ZOH
    specimen model, the predictor's m, c, k)::

        v[j+1] - v[j] - (Phi - I)_v [x, v][j] = g_e f_r[j-n-1] + g_l f_r[j-n]

    (least squares, recursive sums). The candidate with the smallest residual gives ``n``;
    ``g_e / (g_e + g_l)`` gives the fractional part ``delta`` (through the exact hold
    integrals, tabulated) and ``(g_e + g_l) / Gamma_v(dt)`` the gain A. The estimate
    (``tau = n dt + delta``, A) is refreshed every ``update_steps`` and drives
    :class:`ModelPredictor` (the forces it predicts with and the command are scaled by A).
    Until the window is full and excited the prior (``predictor_tau_s``, A = 1) is used.

    This plays the role of the adaptive time-series compensator of Chae et al. (2013): the
    user need not know tau and the compensation follows a drifting delay; unlike the ATS
    compensator it identifies delay and gain of a force actuator from the specimen response.

    Parameters
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float
        Predictor's specimen model.
    dt : float > 0
        Control period [s].
    tau0_s : float >= 0
        Prior delay [s].
    alpha : float
        Mass ratio; ``mass_ref_kg`` the specimen mass of the reference force [kg].
    window_s : float > 0
        Identification window [s].
    max_delay_s : float > 0
        Largest delay searched [s].

    References
    ----------
    Y. Chae, K. Kazemibidokhti and J. M. Ricles (2013), Adaptive time series compensator for
    delay compensation of servo-hydraulic actuator systems for real-time hybrid simulation,
    Earthquake Eng. Struct. Dyn. 42(11), 1697-1715. Carrion and Spencer (2007).
    """

    name = 'adaptive'
    step_average = True

    def __init__(self, mass_kg, damping_N_s_per_m, stiffness_N_per_m, dt, tau0_s, alpha,
                 mass_ref_kg, window_s=0.5, max_delay_s=0.03, update_steps=10):
        self._model_args = (float(mass_kg), float(damping_N_s_per_m),
                            float(stiffness_N_per_m), float(dt))
        self.dt = float(dt)
        self.alpha = float(alpha)
        self.mass_ref_kg = float(mass_ref_kg)
        self.max_n = int(math.ceil(max_delay_s / dt))
        self.max_delay_s = self.max_n * float(dt)
        self.window = max(8, int(round(window_s / dt)))
        self.update_steps = int(update_steps)
        self.gain = 1.0
        self.tau_s = float(tau0_s)
        self._cache = {}
        self._set_model(self.tau_s)
        m, c, k, _ = self._model_args
        a = np.array([[0.0, 1.0], [-k / m, -c / m]])
        b = np.array([[0.0], [1.0 / m]])
        phi, gam = _zoh(a, b, dt)
        self._r = (phi - np.eye(2))[1]
        self._gv = float(gam[1, 0])
        # fraction table: delta -> g_e / (g_e + g_l) for a unit force
        grid = np.linspace(0.0, dt, 41)
        frac = []
        for d in grid:
            phi_rest, g_late = _zoh(a, b, dt - d)
            _, g_e = _zoh(a, b, d)
            ge = float((phi_rest @ g_e)[1, 0])
            frac.append(ge / (ge + float(g_late[1, 0])))
        self._frac_grid, self._frac_delta = np.array(frac), grid
        self._rows = deque(maxlen=self.window)      # (y, f_r[j-max_n-1 .. j])
        self._prev = None
        self._sent = []
        self._count = 0
        self.history_tau_s = []

    @classmethod
    def from_parameters(cls, params) -> 'AdaptivePredictor':
        """Build from the predictor model, ``dt``, ``alpha``, ``adaptive_*``."""
        mp = model_parameters(params)
        return cls(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'],
                   float(params['dt']), mp['tau_s'], float(params['alpha']),
                   float(params['mass_kg']), float(params['adaptive_window_s']),
                   float(params['adaptive_max_delay_s']))

    @property
    def delay_s(self) -> float:
        """Current delay estimate [s]."""
        return self.tau_s

    def _set_model(self, tau_s: float) -> None:
        key = round(tau_s / self.dt * 64)
        if key not in self._cache:
            self._cache[key] = DelayImpulseModel(*self._model_args, key * self.dt / 64)
        self.model = self._cache[key]

    def _identify(self) -> None:
        rows = np.array([r[1] for r in self._rows])
        y = np.array([r[0] for r in self._rows])
        if not np.any(rows):
            return
        best = None
        width = rows.shape[1]
        for n in range(0, self.max_n):
            cols = rows[:, [width - 2 - n, width - 1 - n]]
            sol, res, rank, _ = np.linalg.lstsq(cols, y, rcond=None)
            if rank < 2:
                continue
            err = float(np.sum((cols @ sol - y) ** 2))
            if best is None or err < best[0]:
                best = (err, n, sol)
        if best is None:
            return
        _, n, (ge, gl) = best
        total = ge + gl
        if not total > 0:
            return
        frac = min(max(ge / total, 0.0), self._frac_grid[-1])
        delta = float(np.interp(frac, self._frac_grid, self._frac_delta))
        self.tau_s = n * self.dt + delta
        self.gain = max(total / self._gv, 0.1)
        self._set_model(self.tau_s)

    def predict(self, latest: Measurement | None, commanded_N, ground_force_N: float = 0.0
                ) -> float:
        """Update the identification with the newest measurement; return a_hat [m/s^2]."""
        if latest is not None:
            x, v = latest.displacement_m, latest.velocity_m_s
            if self._prev is not None:
                px, pv, j = self._prev
                y = v - pv - (self._r[0] * px + self._r[1] * pv)
                count = self.max_n + 2            # _past(self._sent[:j + 1], count)
                self._rows.append((y, _past(self._sent[max(0, j + 1 - count):j + 1], count)))
                self._count += 1
                if (len(self._rows) == self.window
                        and self._count % self.update_steps == 0):
                    self._identify()
                    self.history_tau_s.append((j, self.tau_s, self.gain))
            self._prev = (x, v, latest.step)
        else:
            x, v = 0.0, 0.0
        # the forces already sent act as A f_sent; the new one is sent as F / A
        s_hat = self.model.state_ahead(x, v, self.gain * _past(self._sent, self.model.n + 2))
        gain, beta = self.model.matching_gains(self.alpha)
        force = beta * ground_force_N - float(gain @ s_hat)
        if self.alpha == 0.0:
            return 0.0
        return (ground_force_N - force) / (self.alpha * self.mass_ref_kg)

    def command(self, force_N: float) -> float:
        """The command ``F / A`` (so that the actuator applies F)."""
        sent = force_N / self.gain
        self._sent.append(sent)
        return sent
