"""Evaluation criteria J1-J5 of the RTHS benchmark control problem, for a one-storey SEFT.

Imports no rclpy and no SciPy. Silva et al. (2020) judge a real-time hybrid simulation by
nine criteria; the first three measure how well the transfer system tracks its command, the
others how well the test reproduces the reference structure. Here the transfer system is the
force loop (target: the reference force f_r commanded at each step; measured: the load-cell
force) and the response is the specimen's displacement against the analytical reference of
the whole structure:

- J1 [ms]: the lag, in whole samples, that maximises the cross-correlation of the measured
  and the target signal (the delay of the force loop);
- J2 = 100 std(measured - target) / std(target) [%] and
  J3 = 100 max|measured - target| / max|target| [%] (tracking of the force loop);
- J4 = 100 std(x_test - x_ref) / std(x_ref) [%] and
  J5 = 100 max|x_test - x_ref| / max|x_ref| [%] (the response against the reference).

The benchmark's J6-J9 are J4 and J5 for its other storeys; a one-degree-of-freedom SEFT has
none, so they do not apply. J2-J5 compare the signals as recorded, without removing any lag:
a delay is an error there, as in the benchmark.

References
----------
C. E. Silva, D. Gomez, A. Maghareh, S. J. Dyke and B. F. Spencer Jr. (2020), Benchmark
control problem for real-time hybrid simulation, Mech. Syst. Signal Process. 135, 106381,
Sec. "Evaluation criteria".
"""

from dataclasses import dataclass
import math

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['Criteria', 'tracking_delay', 'normalized_std_error', 'normalized_peak_error',
           'evaluation_criteria', 'CRITERIA', 'J1_MAX_LAG_S', 'BENCHMARK_J1_LAG_SAMPLES']

#: Largest lag the benchmark's evaluation code searches for J1, in samples (lags 0..49).
BENCHMARK_J1_LAG_SAMPLES = 49
#: Upper bound of our J1 search [s]: lags 0..floor(J1_MAX_LAG_S/dt) samples, 0..50 at the
#: default dt of 2 ms (the benchmark's 0..49 samples to one sample). A bound in seconds, not in
#: samples, so that the window does not change with dt; 100 ms is five times the largest
#: delay seen here (the 20 ms force-loop delay of ``model`` on the servohydraulic rig) and the
#: bound of the lag estimate ``metrics.MAX_LAG_S``.
J1_MAX_LAG_S = 0.1

#: Criteria of a summary entry: key -> (unit, meaning).
CRITERIA = {
    'J1': ('ms', 'delay of the force loop: the lag maximising the cross-correlation of the '
                 'load-cell force with the reference force'),
    'J2': ('%', 'force tracking: 100 std(f_m - f_r) / std(f_r)'),
    'J3': ('%', 'force tracking: 100 max|f_m - f_r| / max|f_r|'),
    'J4': ('%', 'displacement: 100 std(x_test - x_ref) / std(x_ref)'),
    'J5': ('%', 'displacement: 100 max|x_test - x_ref| / max|x_ref|'),
}


def as_1d(name: str, x) -> np.ndarray:
    """`x` as a 1-D float array, or ParameterError naming `name` (also used by ``metrics``)."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f'{name}: expected a 1-D array of floats') from None
    if arr.ndim != 1:
        raise ParameterError(f'{name}: expected a 1-D array, got shape {arr.shape}')
    return arr


def check_dt(dt) -> float:
    """`dt` as a float, or ParameterError unless it is a finite number > 0 (also used by
    ``metrics``)."""
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(dt) and dt > 0):
        raise ParameterError(f'parameter dt={dt!r}: expected a finite float > 0')
    return float(dt)


def _pair(name_a: str, a, name_b: str, b) -> tuple[np.ndarray, np.ndarray]:
    """Two 1-D float arrays of the same shape, or ParameterError."""
    out = [as_1d(name_a, a), as_1d(name_b, b)]
    if out[0].shape != out[1].shape:
        raise ParameterError(f'{name_a} and {name_b} have shapes {out[0].shape} and '
                             f'{out[1].shape}; expected the same')
    return out[0], out[1]


def _finite_common(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    good = np.isfinite(a) & np.isfinite(b)
    return a[good], b[good]


def tracking_delay(measured, target, dt: float, max_lag_s: float = J1_MAX_LAG_S) -> float:
    """J1: the delay of a measured signal behind its target, in whole samples [s].

    Parameters
    ----------
    measured, target : array_like (n,)
        Measured and target signal at the instants ``k*dt``, same unit. Only the samples
        before the first one that is not finite in either signal are used (an aborted run
        ends in NaN).
    dt : float > 0
        Sample period [s].
    max_lag_s : float >= 0
        Bound of the search [s]: lags ``l = 0, 1, ..., floor(max_lag_s/dt)`` samples (fewer
        when the signals are shorter).

    Returns
    -------
    float
        ``dt * l*`` [s], with l* the (first) lag that maximises the cross-correlation. NaN
        when no lag correlates positively (fewer than two usable samples, a signal that is
        zero, or every ``r[l] <= 0``).

    Raises
    ------
    ParameterError
        If `dt` is not a finite float > 0, `max_lag_s` not a finite float >= 0, or the
        signals are not 1-D arrays of the same shape.

    Notes
    -----
    With the N usable samples::

        r[l] = sum_{k=0}^{N-1-l} measured[k+l] * target[k],   l = 0 .. L
        J1 = dt * argmax_l r[l]

    The benchmark's evaluation code searches ``l = 0 .. 49`` samples
    (``BENCHMARK_J1_LAG_SAMPLES``); here the window is a time, ``J1_MAX_LAG_S`` (0..50
    samples at dt = 2 ms). Only non-negative lags: a measured signal of a causal loop does
    not lead its command. The means are not removed and the sum is not normalised. The
    result is a whole number of samples, as in the benchmark; ``metrics.estimate_lag``
    refines the correlation peak to a fraction of a sample.

    References
    ----------
    C. E. Silva, D. Gomez, A. Maghareh, S. J. Dyke and B. F. Spencer Jr. (2020), Benchmark
    control problem for real-time hybrid simulation, Mech. Syst. Signal Process. 135, 106381
    (evaluation criterion J1).
    """
    dt = check_dt(dt)
    if isinstance(max_lag_s, bool) \
            or not isinstance(max_lag_s, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(max_lag_s) and max_lag_s >= 0):
        raise ParameterError(f'parameter max_lag_s={max_lag_s!r}: expected a finite float >= 0')
    measured, target = _pair('measured', measured, 'target', target)
    bad = np.flatnonzero(~(np.isfinite(measured) & np.isfinite(target)))
    n = int(bad[0]) if bad.size else measured.shape[0]
    if n < 2:
        return math.nan
    m, t = measured[:n], target[:n]
    max_lag = min(int(math.floor(max_lag_s / dt + 1e-9)), n - 1)
    r = np.array([np.dot(m[lag:], t[:n - lag]) for lag in range(max_lag + 1)])
    best = int(np.argmax(r))
    if not r[best] > 0:
        return math.nan
    return best * float(dt)


def normalized_std_error(measured, target) -> float:
    """J2 / J4: the standard deviation of the error relative to that of the target [%].

    Parameters
    ----------
    measured, target : array_like (n,)
        Signals at the same instants, same unit (as recorded: no lag removed).

    Returns
    -------
    float
        ``100 * std(measured - target) / std(target)`` over the samples finite in both; NaN
        if there is none or the target is constant there.

    Raises
    ------
    ParameterError
        If the signals are not 1-D arrays of the same shape.

    Notes
    -----
    The standard deviation removes the mean, so unlike the normalised RMS error
    (``metrics.nrms_error``) a constant offset costs nothing. The ratio is the same with the
    1/N and the 1/(N-1) estimate of the standard deviation (both have the same N).

    References
    ----------
    Silva et al. (2020), Mech. Syst. Signal Process. 135, 106381 (criteria J2 and J4).
    """
    measured, target = _finite_common(*_pair('measured', measured, 'target', target))
    if measured.size == 0:
        return math.nan
    denominator = float(np.std(target))
    if not denominator > 0:
        return math.nan
    return 100.0 * float(np.std(measured - target)) / denominator


def normalized_peak_error(measured, target) -> float:
    """J3 / J5: the largest error relative to the target's peak [%].

    Parameters
    ----------
    measured, target : array_like (n,)
        Signals at the same instants, same unit (as recorded: no lag removed).

    Returns
    -------
    float
        ``100 * max|measured - target| / max|target|`` over the samples finite in both; NaN
        if there is none or the target is zero there.

    Raises
    ------
    ParameterError
        If the signals are not 1-D arrays of the same shape.

    References
    ----------
    Silva et al. (2020), Mech. Syst. Signal Process. 135, 106381 (criteria J3 and J5).
    """
    measured, target = _finite_common(*_pair('measured', measured, 'target', target))
    if measured.size == 0:
        return math.nan
    denominator = float(np.max(np.abs(target)))
    if not denominator > 0:
        return math.nan
    return 100.0 * float(np.max(np.abs(measured - target))) / denominator


@dataclass(frozen=True)
class Criteria:
    """The benchmark's criteria J1-J5 of one run.

    Attributes
    ----------
    j1_ms : float
        Delay of the force loop [ms] (:func:`tracking_delay`, whole samples).
    j2_pct, j3_pct : float
        Force tracking [%]: normalised standard deviation and peak of the error of the
        load-cell force against the reference force.
    j4_pct, j5_pct : float
        Response [%]: the same for the displacement against the analytical reference.
    j1_max_lag_s : float
        Bound of the J1 search [s].

    NaN marks a criterion that is undefined for the run (see the functions).
    """

    j1_ms: float
    j2_pct: float
    j3_pct: float
    j4_pct: float
    j5_pct: float
    j1_max_lag_s: float = J1_MAX_LAG_S

    def as_dict(self) -> dict[str, float]:
        """``{'J1': ms, 'J2': %, 'J3': %, 'J4': %, 'J5': %}`` (the keys of ``CRITERIA``)."""
        return {'J1': self.j1_ms, 'J2': self.j2_pct, 'J3': self.j3_pct, 'J4': self.j4_pct,
                'J5': self.j5_pct}


def evaluation_criteria(*, target_force, measured_force, displacement, reference_displacement,
                        dt: float, j1_max_lag_s: float = J1_MAX_LAG_S) -> Criteria:
    """The benchmark's criteria J1-J5 of a substructure EFT run.

    Parameters
    ----------
    target_force, measured_force : array_like (n,)
        Reference force f_r commanded at each step and load-cell force [N].
    displacement, reference_displacement : array_like (n,)
        Measured displacement and the analytical reference's [m].
    dt : float > 0
        Sample period [s].
    j1_max_lag_s : float >= 0
        Bound of the J1 search [s].

    Returns
    -------
    Criteria

    Raises
    ------
    ParameterError
        If `dt` or `j1_max_lag_s` is out of range, or a pair of signals are not 1-D arrays
        of the same shape.

    References
    ----------
    Silva et al. (2020), Mech. Syst. Signal Process. 135, 106381 (criteria J1-J5; J6-J9
    are J4-J5 of the benchmark's other storeys and do not apply to one degree of freedom).
    """
    return Criteria(
        j1_ms=1e3 * tracking_delay(measured_force, target_force, dt, j1_max_lag_s),
        j2_pct=normalized_std_error(measured_force, target_force),
        j3_pct=normalized_peak_error(measured_force, target_force),
        j4_pct=normalized_std_error(displacement, reference_displacement),
        j5_pct=normalized_peak_error(displacement, reference_displacement),
        j1_max_lag_s=float(j1_max_lag_s))
