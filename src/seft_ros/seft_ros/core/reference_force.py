"""The reference-force builder of substructure EFT and its delay-compensation plug-in point."""

import math
from typing import Callable, Protocol, runtime_checkable

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_ros.core.predictors import (
    AdaptivePredictor,
    AtsPredictor,
    NoPredictor,
    PolynomialPredictor,
    foh_step_average,
    model_predictor,
    network_delay_steps,
)

__all__ = ['Predictor', 'NoPredictor', 'PREDICTORS', 'make_predictor', 'ReferenceForceBuilder',
           'ground_window', 'with_loop_latency', 'network_delay_steps']


@runtime_checkable
class Predictor(Protocol):
    """Delay compensator: estimate of the specimen acceleration fed back into the reference force.

    Called once per step k with the latest measurement, that of step k-1 (None before the
    first sample: the specimen is at rest), the desired forces already built
    (``F[0..k-1]``) and the ground-motion part ``G[k] = -(1 + alpha) m gbar[k]`` [N] of the
    new force (the compensator may solve the algebraic loop through it); returns
    ``a_hat[k]`` [m/s^2]. The builder forms ``F[k] = G[k] - alpha m a_hat[k]`` and sends
    ``command(F[k])`` (the identity, except for a force-loop inverse).

    Attributes
    ----------
    name : str
        Registry name (parameter ``predictor``).
    step_average : bool
        The ground term is the step average of the (linearly interpolated) record over the
        step in which the force acts (hold-consistent compensators), not the sample
        ``xg''[k]`` (paper Eq. 5.3).
    delay_s : float
        Loop delay the compensator assumes [s] (the shift of the ground-motion preview).
    """

    name: str
    step_average: bool
    delay_s: float

    def predict(self, latest: Measurement | None, commanded_N: list[float],
                ground_force_N: float = 0.0) -> float:
        """Return the fed-back acceleration estimate [m/s^2]."""

    def command(self, force_N: float) -> float:
        """Return the command sent to the actuator for the desired force [N]."""


#: Delay compensators by name (parameter ``predictor``).
PREDICTORS: dict[str, Callable] = {
    'none': NoPredictor.from_parameters,
    'polynomial': PolynomialPredictor.from_parameters,
    'model': model_predictor,
    'adaptive': AdaptivePredictor.from_parameters,
    'ats': AtsPredictor.from_parameters,
}


def with_loop_latency(params) -> dict:
    """The parameters a predictor models, with the measured loop latency added.

    In real time with ``realtime_output: on_arrival`` a command acts when it arrives, so the
    loop's delay differs from the lockstep one by ``L - dt``, where ``L`` is the loop latency
    (sample to command at the rig) and ``dt`` the control period that lockstep assumes.
    With ``predictor_loop_latency_s = L > 0`` the predictor models the actuator delay
    ``tau + L - dt`` on the delay rig (``predictor_tau_s``, 0: ``tau_s``) and the I/O latency
    ``io_latency_s + L - dt`` on the servohydraulic rig, so that compensation covers the
    actuator and the communication together. ``L = 0`` (the default) changes nothing.

    With ``network_delay_s > 0`` (the builder on another host) the force servo controller
    applies each reference force ``N = round(network_delay_s / dt) dt`` later
    (:func:`network_delay_steps`): a pure delay in series with the actuator, outside the force
    loop. The predictor then predicts N beyond the force loop's inverted delay
    (:meth:`~seft_ros.core.predictors.ModelPredictor.from_parameters`); the force loop's own
    model is unchanged.

    Parameters
    ----------
    params : mapping
        The resolved parameters.

    Returns
    -------
    dict
        A copy with ``predictor_tau_s`` and ``io_latency_s`` adjusted (never below 0; the
        delay stays above 0).

    Raises
    ------
    ParameterError
        ``predictor_loop_latency_s > 0`` with ``realtime_output: latched`` (the default):
        there a command acts at the next tick whatever its latency, so the latency is no
        delay of the loop, and a predictor told it predicts too far (told the 3.6 ms loop
        latency of a builder on another host, ``model`` missed by about 4 % instead of
        0.4 %; the network's delay is ``network_delay_s``'s to cover).
    """
    out = dict(params)
    latency = float(params.get('predictor_loop_latency_s', 0.0) or 0.0)
    if latency > 0.0 and params.get('realtime_output', 'on_arrival') != 'on_arrival':
        raise ParameterError(
            f'parameter predictor_loop_latency_s={latency:g}: applies with realtime_output '
            "'on_arrival' only; with 'latched' output a command acts at the next tick "
            'whatever its latency, and a predictor told it would predict too far (set it to 0; '
            'a builder on another host: network_delay_s)')
    steps = network_delay_steps(params)
    network = steps * float(params['dt']) if steps else 0.0
    if latency <= 0.0 and network <= 0.0:
        return out
    extra = latency - float(params['dt']) if latency > 0.0 else 0.0
    tau = float(params.get('predictor_tau_s') or params.get('tau_s') or 0.0)
    out['predictor_tau_s'] = max(tau + extra + network, 1e-6)
    if 'io_latency_s' in params and latency > 0.0:
        out['io_latency_s'] = max(float(params['io_latency_s']) + extra, 0.0)
    return out


def make_predictor(params) -> Predictor:
    """Build the predictor named by ``params['predictor']`` (:func:`with_loop_latency`).

    Raises
    ------
    ParameterError
        If the name is not registered.
    """
    params = with_loop_latency(params)
    name = params['predictor']
    try:
        factory = PREDICTORS[name]
    except KeyError:
        choices = ', '.join(repr(n) for n in PREDICTORS)
        raise ParameterError(f'parameter predictor={name!r}: expected one of {choices}') from None
    return factory(params)


class ReferenceForceBuilder:
    """Reference force of substructure EFT from the ground motion and fed-back acceleration.

    ``F[k] = -(1 + alpha) m g[k] - alpha m a_hat[k]`` (paper Eq. 2.5 with the measured
    acceleration, Eq. 5.3), where ``a_hat[k]`` is the predictor's estimate (``none``: the
    measured acceleration of step k-1) and ``g[k]`` is the ground acceleration: the sample
    ``xg''[k]`` for ``none``, the step average of the linearly interpolated record over
    ``[t_k + s, t_k+1 + s]`` for the hold-consistent predictors, with ``s = 0`` or, with the
    ground-motion preview, ``s`` = the predictor's loop delay: the record is known before the
    test, so its part of the force is commanded ahead by the delay and the response no longer
    lags the reference. The command sent is ``predictor.command(F[k])``.

    Parameters
    ----------
    alpha : float >= 0
        Mass ratio (computational mass / specimen mass).
    mass_kg : float > 0
        Specimen mass m [kg].
    predictor : Predictor
    dt : float > 0, optional
        Control period [s]; needed by the preview.
    ground_preview : bool
        Shift the ground term ahead by the predictor's delay.

    Attributes
    ----------
    lookahead_steps : int
        How many samples after ``xg''[k]`` :meth:`step` reads (the window length - 1).

    Raises
    ------
    ParameterError
        If ``alpha < 0`` or ``mass_kg <= 0``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.4-2.5 and 5.3.
    """

    def __init__(self, alpha: float, mass_kg: float, predictor: Predictor, *,
                 dt: float = 0.0, ground_preview: bool = False):
        if not alpha >= 0:
            raise ParameterError(f'parameter alpha={alpha!r}: expected float >= 0')
        if not mass_kg > 0:
            raise ParameterError(f'parameter mass_kg={mass_kg!r}: expected float > 0')
        self.alpha = float(alpha)
        self.mass_kg = float(mass_kg)
        self.predictor = predictor
        self.dt = float(dt)
        self.ground_preview = bool(ground_preview) and self.dt > 0
        self.commanded_N: list[float] = []
        self.last_ground_force_N = 0.0
        self._ground_gain = -(1.0 + self.alpha) * self.mass_kg    # G = ground_gain g
        self._alpha_m = self.alpha * self.mass_kg
        self.lookahead_steps = 0
        if getattr(predictor, 'step_average', False):
            self.lookahead_steps = 1
            if self.ground_preview:
                most = getattr(predictor, 'max_delay_s', predictor.delay_s)
                self.lookahead_steps = 1 + int(math.ceil(most / self.dt - 1e-9))

    @classmethod
    def from_parameters(cls, params) -> 'ReferenceForceBuilder':
        """Build from ``alpha``, ``mass_kg``, ``dt``, ``ground_preview`` and ``predictor``."""
        return cls(float(params['alpha']), float(params['mass_kg']), make_predictor(params),
                   dt=float(params['dt']), ground_preview=bool(params['ground_preview']))

    def ground(self, window) -> float:
        """The ground acceleration g[k] [m/s^2] of the new force from ``xg''[k..k+L]``."""
        if not self.predictor.step_average:
            return float(window[0])
        shift = self.predictor.delay_s / self.dt if self.ground_preview else 0.0
        return foh_step_average(window, shift)

    def step(self, ground, latest: Measurement | None) -> float:
        """Return the command ``f_r[k]`` [N] from the ground motion and the measurement of k-1.

        Parameters
        ----------
        ground : float or sequence of float, shape (lookahead_steps + 1,)
            ``xg''[k]`` [m/s^2], or the window ``xg''[k], ..., xg''[k + lookahead_steps]``
            (zeros after the end of the record); a float is enough when
            ``lookahead_steps == 0``.
        latest : Measurement or None
            The measurement of step k-1 (None for k = 0).
        """
        window = (ground,) if isinstance(ground, (int, float)) else ground
        if len(window) <= self.lookahead_steps:
            raise ParameterError(f'ground window of {len(window)} samples: expected '
                                 f'{self.lookahead_steps + 1} (xg[k..k+{self.lookahead_steps}])')
        predictor = self.predictor
        if not predictor.step_average:             # self.ground(window), written out
            g = float(window[0])
        elif self.ground_preview:
            g = foh_step_average(window, predictor.delay_s / self.dt)
        else:
            g = 0.5 * (window[0] + window[1])      # foh_step_average(window, 0.0)
        ground_force = self.last_ground_force_N = self._ground_gain * g
        a_hat = predictor.predict(latest, self.commanded_N, ground_force)
        force = ground_force - self._alpha_m * a_hat
        self.commanded_N.append(force)
        return predictor.command(force)


def ground_window(lookup: Callable[[int], float], k: int, lookahead_steps: int,
                  n_total: int) -> list[float]:
    """``[xg''[k], ..., xg''[k + lookahead_steps]]`` with zeros after the record.

    Parameters
    ----------
    lookup : callable(int) -> float
        Ground acceleration of a step [m/s^2].
    k : int
        Step of the new force.
    lookahead_steps : int >= 0
    n_total : int
        Record length (steps at and after it are 0).
    """
    end = k + lookahead_steps + 1
    if end <= n_total:
        return [float(lookup(j)) for j in range(k, end)]
    return [float(lookup(j)) if j < n_total else 0.0 for j in range(k, end)]
