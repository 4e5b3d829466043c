"""The analytical reference: the whole structure simulated from the recorded ground motion.

Imports no rclpy. The reference study validates each substructure EFT test against the response
of the whole linear structure (load-resisting member plus computational mass) computed from the
same ground motion (paper Sec. 4, Figure 6); this module computes that response.
"""

from dataclasses import dataclass
import math
from typing import Any, Mapping

import numpy as np
from scipy import signal

from seft_msgs_py.errors import ParameterError

__all__ = ['ReferenceResponse', 'reference_response', 'reference_from_run']


@dataclass(frozen=True)
class ReferenceResponse:
    """Response of the whole structure to a ground-motion record, one sample per step, SI units.

    All arrays have shape ``(n,)``; sample k is at ``time_s[k] = k*dt``.

    Attributes
    ----------
    time_s : ndarray (n,)
        Sample times [s].
    displacement_m : ndarray (n,)
        Displacement x relative to the ground [m].
    velocity_m_s : ndarray (n,)
        Velocity x' relative to the ground [m/s].
    acceleration_m_s2 : ndarray (n,)
        Acceleration x'' relative to the ground [m/s^2].
    force_N : ndarray (n,)
        Force on the load-resisting member ``m x'' + c x' + k x`` [N], the counterpart of the
        load-cell force of a test (paper Eq. 2.4); it equals
        ``-(1+alpha) m xg'' - alpha m x''`` (paper Eq. 2.5).
    """

    time_s: np.ndarray
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    force_N: np.ndarray

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    def signal(self, name: str) -> np.ndarray:
        """Return 'displacement', 'force' or 'acceleration' (the names of ``RunData.signal``).

        Raises
        ------
        ParameterError
            If `name` is none of these.
        """
        signals = {'displacement': self.displacement_m, 'force': self.force_N,
                   'acceleration': self.acceleration_m_s2}
        try:
            return signals[name]
        except KeyError:
            raise ParameterError(
                f'signal {name!r}: expected one of {", ".join(map(repr, signals))}') from None


def _positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return `value` as a float, or raise ParameterError naming `name`."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if ok:
        value = float(value)
        ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ParameterError(
            f'parameter {name}={value!r}: expected a finite float {">=" if allow_zero else ">"} 0')
    return value


def reference_response(*, alpha: float, mass_kg: float, damping_N_s_per_m: float,
                       stiffness_N_per_m: float, dt: float,
                       ground_acceleration_m_s2) -> ReferenceResponse:
    """Simulate the whole linear structure from rest under a sampled ground acceleration.

    Solves the equation of motion of the structure (load-resisting member plus computational
    mass ``alpha*m``)::

        (1+alpha) m x'' + c x' + k x = -(1+alpha) m xg''

    with ``scipy.signal.lsim`` on the state ``[x, x']``. The record is linearly interpolated
    between samples (first-order hold), for which the discrete solution is exact: the
    piecewise-linear excitation method of Nigam & Jennings (1969). Acceleration and force then
    follow from the equation of motion at each sample.

    Parameters
    ----------
    alpha : float >= 0
        Mass ratio of the computational mass to the specimen mass [-].
    mass_kg : float > 0
        Specimen (load-resisting member) mass m [kg].
    damping_N_s_per_m : float >= 0
        Specimen viscous damping c [N s/m].
    stiffness_N_per_m : float > 0
        Specimen stiffness k [N/m].
    dt : float > 0
        Sample period of the record [s].
    ground_acceleration_m_s2 : array_like (n,)
        Ground acceleration xg'' at ``k*dt`` [m/s^2]; finite values.

    Returns
    -------
    ReferenceResponse
        Displacement, velocity, acceleration (relative to the ground) and member force, each
        of shape ``(n,)``.

    Raises
    ------
    ParameterError
        If a parameter is out of range, not finite or of the wrong type, or the ground
        acceleration is not a finite 1-D array; the message names the parameter.

    Notes
    -----
    With ``M = (1+alpha) m`` the relative acceleration is ``x'' = -(c x' + k x)/M - xg''`` and
    the member force is ``f = m x'' + c x' + k x = -(1+alpha) m xg'' - alpha m x''``
    (paper Eqs. 2.4-2.5).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing: A Force-Based Real-Time
    Hybrid Simulation, Eqs. 2.1, 2.4, 2.5 and Sec. 4 (Figure 6).
    N. C. Nigam and P. C. Jennings (1969), Calculation of response spectra from strong-motion
    earthquake records, Bull. Seismol. Soc. Am. 59(2), 909-922.
    """
    alpha = _positive('alpha', alpha, allow_zero=True)
    m = _positive('mass_kg', mass_kg)
    c = _positive('damping_N_s_per_m', damping_N_s_per_m, allow_zero=True)
    k = _positive('stiffness_N_per_m', stiffness_N_per_m)
    dt = _positive('dt', dt)
    try:
        ag = np.asarray(ground_acceleration_m_s2, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError('ground_acceleration_m_s2: expected a 1-D array of floats') from None
    if ag.ndim != 1 or not np.all(np.isfinite(ag)):
        raise ParameterError(
            f'ground_acceleration_m_s2: expected a finite 1-D array, got shape {ag.shape}'
            + ('' if ag.ndim != 1 else ' with non-finite values'))

    n = ag.shape[0]
    total_mass = (1.0 + alpha) * m
    t = np.arange(n) * dt
    if n >= 2:
        a_mat = np.array([[0.0, 1.0], [-k / total_mass, -c / total_mass]])
        b_mat = np.array([[0.0], [-1.0]])
        system = signal.StateSpace(a_mat, b_mat, np.eye(2), np.zeros((2, 1)))
        _, _, states = signal.lsim(system, ag, t, interp=True)
        x = np.ascontiguousarray(states[:, 0])
        v = np.ascontiguousarray(states[:, 1])
    else:
        x = np.zeros(n)
        v = np.zeros(n)
    a = -(c * v + k * x) / total_mass - ag
    force = m * a + c * v + k * x
    return ReferenceResponse(time_s=t, displacement_m=x, velocity_m_s=v, acceleration_m_s2=a,
                             force_N=force)


_PARAMS = ('alpha', 'mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m', 'dt')


def _reference_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """Pick the arguments of :func:`reference_response` from a run's parameters.

    Raises
    ------
    ParameterError
        If one of alpha, mass_kg, damping_N_s_per_m, stiffness_N_per_m, dt is missing.
    """
    missing = [name for name in _PARAMS if name not in params]
    if missing:
        raise ParameterError(f'run parameters: missing {", ".join(missing)}')
    return {name: params[name] for name in _PARAMS}


def reference_from_run(run) -> ReferenceResponse:
    """Compute the reference response of a run from its parameters and ground acceleration.

    Parameters
    ----------
    run : RunData
        The run; uses ``run.params`` (alpha, mass_kg, damping_N_s_per_m, stiffness_N_per_m,
        dt) and ``run.ground_acceleration_m_s2`` (n,) [m/s^2].

    Returns
    -------
    ReferenceResponse
        Over the same n samples as the run (an aborted run gives a shorter reference).

    Raises
    ------
    ParameterError
        If a parameter is missing or out of range (see :func:`reference_response`).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 2.1 and Sec. 4.
    """
    return reference_response(**_reference_params(run.params),
                              ground_acceleration_m_s2=run.ground_acceleration_m_s2)
