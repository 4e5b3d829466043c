"""The reference-force builder of substructure EFT and its delay-compensation plug-in point."""

from typing import Callable, Protocol, runtime_checkable

from seft_msgs_py.errors import ParameterError
from seft_plant_sim.interface import Measurement

__all__ = ['Predictor', 'NoPredictor', 'PREDICTORS', 'make_predictor', 'ReferenceForceBuilder']


@runtime_checkable
class Predictor(Protocol):
    """Estimate of the specimen acceleration fed back into the reference force.

    Called once per step k with the latest measurement, that of step k-1 (None before the
    first sample: the specimen is at rest), and the reference forces already commanded
    (``f_r[0..k-1]``); returns ``a_hat[k]`` [m/s^2] for the reference force of step k.
    """

    name: str

    def predict(self, latest: Measurement | None, commanded_N: list[float]) -> float:
        """Return the fed-back acceleration estimate [m/s^2]."""


class NoPredictor:
    """No compensation: the measured acceleration of the previous step (paper Eq. 5.3).

    ``a_hat[k] = a_m[k-1]``; zero before the first measurement.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 5.3.
    """

    name = 'none'

    @classmethod
    def from_parameters(cls, params) -> 'NoPredictor':
        """No parameters."""
        return cls()

    def predict(self, latest: Measurement | None, commanded_N: list[float]) -> float:
        """Return the previous step's measured acceleration [m/s^2]."""
        return 0.0 if latest is None else latest.acceleration_m_s2


#: Delay compensators by name (parameter ``predictor``).
PREDICTORS: dict[str, Callable] = {'none': NoPredictor.from_parameters}


def make_predictor(params) -> Predictor:
    """Build the predictor named by ``params['predictor']``.

    Raises
    ------
    ParameterError
        If the name is not registered.
    """
    name = params['predictor']
    try:
        factory = PREDICTORS[name]
    except KeyError:
        choices = ', '.join(repr(n) for n in PREDICTORS)
        raise ParameterError(f'parameter predictor={name!r}: expected one of {choices}') from None
    return factory(params)


class ReferenceForceBuilder:
    """Reference force of substructure EFT from the ground motion and fed-back acceleration.

    ``f_r[k] = -(1 + alpha) m xg''[k] - alpha m a_hat[k]`` (paper Eq. 2.5 with the measured
    acceleration, Eq. 5.3), where ``a_hat[k]`` is the predictor's estimate (``none``: the
    measured acceleration of step k-1).

    Parameters
    ----------
    alpha : float >= 0
        Mass ratio (computational mass / specimen mass).
    mass_kg : float > 0
        Specimen mass m [kg].
    predictor : Predictor

    Raises
    ------
    ParameterError
        If ``alpha < 0`` or ``mass_kg <= 0``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.4-2.5 and 5.3.
    """

    def __init__(self, alpha: float, mass_kg: float, predictor: Predictor):
        if not alpha >= 0:
            raise ParameterError(f'parameter alpha={alpha!r}: expected float >= 0')
        if not mass_kg > 0:
            raise ParameterError(f'parameter mass_kg={mass_kg!r}: expected float > 0')
        self.alpha = float(alpha)
        self.mass_kg = float(mass_kg)
        self.predictor = predictor
        self.commanded_N: list[float] = []
        self.last_ground_force_N = 0.0

    @classmethod
    def from_parameters(cls, params) -> 'ReferenceForceBuilder':
        """Build from ``alpha``, ``mass_kg`` and ``predictor``."""
        return cls(float(params['alpha']), float(params['mass_kg']), make_predictor(params))

    def step(self, ground_acceleration_m_s2: float, latest: Measurement | None) -> float:
        """Return ``f_r[k]`` [N] from ``xg''[k]`` and the measurement of step k-1."""
        a_hat = self.predictor.predict(latest, self.commanded_N)
        m, alpha = self.mass_kg, self.alpha
        self.last_ground_force_N = -(1.0 + alpha) * m * ground_acceleration_m_s2
        force = self.last_ground_force_N - alpha * m * a_hat
        self.commanded_N.append(force)
        return force
