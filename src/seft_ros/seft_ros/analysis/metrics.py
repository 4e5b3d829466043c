"""Error metrics of a substructure EFT run against the analytical reference.

Imports no rclpy. Every test is a structure (:mod:`seft_ros.core.structure`; the reference
study's test is its one-DOF case), and a run is compared with the whole structure's reference
(:func:`~seft_ros.analysis.reference.run_reference`) two ways (:func:`compare_run`):

- **per rig** (:class:`RigComparison`): the rig's displacement, load-cell force and
  acceleration against the reference at its degree of freedom (DOF). The test lags the
  reference by the actuator's loop delay (paper Eq. 5.2), so each signal is compared after
  removing its lag: the lag is estimated from the cross-correlation peak, the test is advanced
  by it, and the normalized RMS error is computed over the samples both signals share. Each
  signal's NRMS is also given unshifted and after removing one common lag (the
  displacement's) from every signal: a lag of its own can hide a signal's phase error. The
  RTHS benchmark's criteria J1-J5 come from ``seft_ros.analysis.criteria``. For a yielding
  (nonlinear) member the displacement is also compared after removing each signal's slowly
  varying permanent offset (:func:`drift`), with the residual (permanent) displacement
  (:func:`residual_displacement`) and the member's restoring force (:func:`restoring_force`)
  for its hysteresis loops;
- **per DOF** (:class:`DofComparison`): displacement, relative and floor (absolute)
  acceleration of every DOF — a physical DOF's from its rig's sensors (the rig's comparison),
  a computational DOF's from the state the builder integrated — and at a physical DOF the
  interface force (the load cell against ``m_p x'' + c_p x' + k_p x``, paper Eq. 2.4 per
  rig); per link of the structure (a story, a bearing) its deformation
  (:class:`LinkComparison`, the story drift).

A run of one rig reads as its rig's comparison (``comparison.displacement.nrms``), as the run
reads as its rig. :func:`summary_entry` gives every run one layout in ``summary.json``.
"""

from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from scipy import interpolate, signal

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.criteria import J1_MAX_LAG_S, Criteria, evaluation_criteria
from seft_ros.analysis.criteria import as_1d as _as_1d
from seft_ros.analysis.criteria import check_dt as _check_dt
from seft_ros.analysis.reference import ReferenceResponse, StructureReference, run_reference
from seft_ros.analysis.rundata import SIGNALS, RigData, RunData, only_rig, rig_label
from seft_ros.analysis.timing import link_summary
from seft_ros.core.models import model_plugin
from seft_ros.core.structure import STUDY_DOF, Link, structure_of

__all__ = [
    'SignalComparison', 'RigComparison', 'RunComparison', 'DofComparison', 'LinkComparison',
    'estimate_lag', 'shift', 'nrms_error', 'peak', 'peak_ratio', 'high_frequency_fraction',
    'compare_run', 'summary_entry', 'dof_signals', 'DOF_SIGNALS', 'json_safe', 'best_runs',
    'UNCOMPENSATED', 'residual_displacement', 'drift', 'restoring_force',
    'ResidualComparison', 'is_nonlinear', 'DRIFT_CUTOFF_HZ', 'RESIDUAL_WINDOW_S',
]

#: Default bound of the lag search [s] (ten times the reference rig's 10 ms delay).
MAX_LAG_S = 0.1
#: Default cutoff of :func:`high_frequency_fraction` [Hz] (the controller works up to 25 Hz).
HIGH_FREQUENCY_CUTOFF_HZ = 20.0
#: Name of the predictor that leaves the fed-back acceleration uncompensated.
UNCOMPENSATED = 'none'
#: Cut-off of the zero-phase low-pass that gives a displacement's drift [Hz] (:func:`drift`):
#: 8 to 13 times below the slowest oscillation of the default yielding member (its post-yield
#: tangent frequency, 3.2 Hz at alpha = 0, 2.0 Hz at alpha = 1.5) and a quarter of the lower
#: band edge of the default record at time scale 0.5 (1 Hz).
DRIFT_CUTOFF_HZ = 0.25
#: Order of the Butterworth low-pass of :func:`drift` (applied forward and backward).
DRIFT_FILTER_ORDER = 4
#: Length of the Hann window of :func:`residual_displacement` [s].
RESIDUAL_WINDOW_S = 2.0


def estimate_lag(test, reference, dt: float, max_lag_s: float = MAX_LAG_S) -> float:
    """Estimate how much the test lags the reference, from their cross-correlation peak.

    Parameters
    ----------
    test, reference : array_like (n,), (n_ref,)
        Test and reference signals sampled at the same instants ``k*dt`` (any unit, the
        same for both). Only the first ``min(n, n_ref)`` samples are used; samples that are
        not finite in either signal are set to zero in both.
    dt : float > 0
        Sample period [s].
    max_lag_s : float >= 0
        Bound of the search [s]: the peak is searched for lags in ``[-max_lag_s, max_lag_s]``.

    Returns
    -------
    float
        Lag L [s], positive when the test lags the reference (``test(t) ~ reference(t - L)``),
        within ``[-max_lag_s, max_lag_s]``. 0.0 when the lag is undefined (fewer than two
        common samples, or a signal that is identically zero).

    Raises
    ------
    ParameterError
        If `dt` or `max_lag_s` is out of range or a signal is not 1-D.

    Notes
    -----
    Both signals have their mean removed; the cross-correlation
    ``r[l] = sum_k test[k+l] reference[k]`` is computed with ``scipy.signal.correlate`` and
    its lags with ``scipy.signal.correlation_lags``. The integer peak l0 is refined to
    sub-sample precision by fitting a parabola through ``r[l0-1], r[l0], r[l0+1]``:
    ``l = l0 + (r[l0-1] - r[l0+1]) / (2 (r[l0-1] - 2 r[l0] + r[l0+1]))``.

    For a diverging (unstable) run the correlation is dominated by the growing oscillation
    and the estimate may be meaningless; when the peak lies at the edge of the search window
    the result is clamped to ``+/-max_lag_s``, so a lag equal to the bound flags an estimate
    that should not be trusted.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 5.2 (delay tau).
    """
    dt = _check_dt(dt)
    if isinstance(max_lag_s, bool) or not (isinstance(max_lag_s, (int, float, np.integer,
                                                                   np.floating))
                                          and math.isfinite(max_lag_s) and max_lag_s >= 0):
        raise ParameterError(f'parameter max_lag_s={max_lag_s!r}: expected a finite float >= 0')
    test = _as_1d('test', test)
    reference = _as_1d('reference', reference)
    n = min(test.shape[0], reference.shape[0])
    if n < 2:
        return 0.0
    x = test[:n].copy()
    y = reference[:n].copy()
    good = np.isfinite(x) & np.isfinite(y)
    if not np.any(good):
        return 0.0
    x = np.where(good, x - np.mean(x[good]), 0.0)
    y = np.where(good, y - np.mean(y[good]), 0.0)
    if not (np.any(x) and np.any(y)):
        return 0.0
    max_lag = min(int(math.floor(max_lag_s / dt + 1e-9)), n - 1)
    r = signal.correlate(x, y, mode='full')
    lags = signal.correlation_lags(n, n, mode='full')
    window = np.abs(lags) <= max_lag
    r = r[window]
    lags = lags[window]
    i = int(np.argmax(r))
    if r[i] <= 0:
        return 0.0
    if i == 0 or i == r.shape[0] - 1:
        return float(np.clip(lags[i] * dt, -max_lag_s, max_lag_s))
    r_minus, r_0, r_plus = r[i - 1], r[i], r[i + 1]
    denominator = r_minus - 2.0 * r_0 + r_plus
    delta = 0.5 * (r_minus - r_plus) / denominator if denominator < 0 else 0.0
    return float(np.clip((lags[i] + delta) * dt, -max_lag_s, max_lag_s))


def shift(signal, lag_s: float, dt: float) -> np.ndarray:
    """Advance a signal by `lag_s` with sub-sample accuracy (remove a lag of the test).

    Parameters
    ----------
    signal : array_like (n,)
        Samples at ``k*dt`` (any unit).
    lag_s : float
        Time advance [s]; the result is ``y[k] = signal(k*dt + lag_s)`` (a negative value
        delays).
    dt : float > 0
        Sample period [s].

    Returns
    -------
    ndarray (n,)
        The shifted signal, same unit. Samples whose instant falls outside the record (the
        last ``lag_s/dt`` samples for a positive lag) or next to a non-finite input sample are
        NaN, so that metrics exclude them.

    Raises
    ------
    ParameterError
        If `dt` is not > 0, `lag_s` is not finite or the signal is not 1-D.

    Notes
    -----
    A whole number of samples is an exact index shift. Otherwise the signal is interpolated
    by a not-a-knot cubic spline (``scipy.interpolate.CubicSpline``), whose error for a
    signal band-limited well below the Nyquist frequency is of order ``(omega dt)^4``.
    """
    dt = _check_dt(dt)
    if isinstance(lag_s, bool) or not isinstance(lag_s, (int, float, np.integer, np.floating)) \
            or not math.isfinite(lag_s):
        raise ParameterError(f'parameter lag_s={lag_s!r}: expected a finite float')
    x = _as_1d('signal', signal)
    n = x.shape[0]
    out = np.full(n, np.nan)
    steps = lag_s / dt
    whole = round(steps)
    if abs(steps - whole) < 1e-9:
        if abs(whole) >= n:                  # shifted past the record: nothing left
            return out
        if whole >= 0:
            out[:n - whole] = x[whole:]
        else:
            out[-whole:] = x[:n + whole]
        return out
    if n < 2:
        return out
    bad = ~np.isfinite(x)
    k = np.arange(n, dtype=float)
    query = k + steps
    inside = (query >= 0) & (query <= n - 1)
    spline = interpolate.CubicSpline(k, np.where(bad, 0.0, x))
    out[inside] = spline(query[inside])
    if np.any(bad):
        # Poison the output within two samples of a non-finite input (the spline's support).
        bad_near = np.convolve(bad.astype(float), np.ones(5), mode='same') > 0
        lo = np.clip(np.floor(query).astype(int), 0, n - 1)
        hi = np.clip(lo + 1, 0, n - 1)
        out[bad_near[lo] | bad_near[hi]] = np.nan
    return out


def nrms_error(test, reference) -> float:
    """Normalized RMS error of a test signal against the reference, as a fraction.

    Parameters
    ----------
    test, reference : array_like (n,)
        Signals at the same instants, same unit (already aligned, see :func:`shift`).

    Returns
    -------
    float
        ``rms(test - reference) / rms(reference)`` over the samples finite in both
        (0.1 means 10 %). NaN if no sample is common or the reference is zero there.

    Raises
    ------
    ParameterError
        If the signals are not 1-D arrays of the same shape.

    Notes
    -----
    With the N common finite samples k::

        nrms = sqrt(sum_k (test[k] - reference[k])^2) / sqrt(sum_k reference[k]^2)

    which is the normalized RMS error of the RTHS benchmark evaluation criteria
    (Silva et al. 2020, J2): scale-free, 0 for a perfect test, 1 for a test that is
    identically zero.

    References
    ----------
    C. E. Silva, D. Gomez, A. Maghareh, S. J. Dyke and B. F. Spencer Jr. (2020), Benchmark
    control problem for real-time hybrid simulation, Mech. Syst. Signal Process. 135, 106381.
    """
    test = _as_1d('test', test)
    reference = _as_1d('reference', reference)
    if test.shape != reference.shape:
        raise ParameterError(
            f'nrms_error: test and reference have shapes {test.shape} and {reference.shape}; '
            'expected the same')
    good = np.isfinite(test) & np.isfinite(reference)
    if not np.any(good):
        return math.nan
    denominator = float(np.sqrt(np.sum(reference[good] ** 2)))
    if denominator == 0:
        return math.nan
    return float(np.sqrt(np.sum((test[good] - reference[good]) ** 2))) / denominator


def peak(x) -> float:
    """Peak magnitude ``max |x|`` ignoring NaN (inf if the signal diverged; NaN if empty)."""
    x = _as_1d('x', x)
    x = np.abs(x[~np.isnan(x)])
    return float(np.max(x)) if x.size else math.nan


def peak_ratio(test, reference) -> float:
    """``peak(test) / peak(reference)`` (NaN if the reference peak is zero or undefined)."""
    p_ref = peak(reference)
    if not p_ref > 0:
        return math.nan
    return peak(test) / p_ref


def _check_cutoff(cutoff_hz, dt: float) -> None:
    """ParameterError naming cutoff_hz unless it is a float in (0, 1/(2 dt)) Hz."""
    nyquist = 0.5 / dt
    if isinstance(cutoff_hz, bool) or not isinstance(cutoff_hz, (int, float, np.integer,
                                                                  np.floating)) \
            or not (0 < cutoff_hz < nyquist):
        raise ParameterError(
            f'parameter cutoff_hz={cutoff_hz!r}: expected a float in (0, {nyquist:g}) Hz')


def high_frequency_fraction(x, dt: float, cutoff_hz: float = HIGH_FREQUENCY_CUTOFF_HZ) -> float:
    """Fraction of a signal's power above a cutoff frequency.

    Quantifies the "undesirable high frequency vibration" that acceleration feedback induces
    in the test (paper Sec. 4).

    Parameters
    ----------
    x : array_like (n,)
        Signal sampled at ``k*dt`` (any unit). Only the samples before the first non-finite
        one are used.
    dt : float > 0
        Sample period [s].
    cutoff_hz : float > 0
        Cutoff frequency [Hz], below the Nyquist frequency ``1/(2 dt)``.

    Returns
    -------
    float
        ``sum_{f > cutoff} P(f) / sum_f P(f)`` in [0, 1], with P the Welch power spectral
        density (``scipy.signal.welch``, Hann window, segments of up to 512 samples, mean
        removed). NaN for fewer than 8 samples or a constant signal.

    Raises
    ------
    ParameterError
        If `dt` is not > 0 or `cutoff_hz` is not in ``(0, 1/(2 dt))``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 4 (Figure 6 f, i).
    """
    dt = _check_dt(dt)
    _check_cutoff(cutoff_hz, dt)
    x = _as_1d('x', x)
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        x = x[:bad[0]]
    if x.shape[0] < 8:
        return math.nan
    freq, power = signal.welch(x, fs=1.0 / dt, window='hann', nperseg=min(x.shape[0], 512),
                               detrend='constant')
    total = float(np.sum(power))
    if not total > 0:
        return math.nan
    return float(np.sum(power[freq > cutoff_hz])) / total


def _finite_prefix(x: np.ndarray) -> np.ndarray:
    """The samples of `x` before its first non-finite one."""
    bad = np.flatnonzero(~np.isfinite(x))
    return x[:bad[0]] if bad.size else x


def _check_positive(name: str, value) -> float:
    """`value` as a finite float > 0, or ParameterError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and value > 0):
        raise ParameterError(f'parameter {name}={value!r}: expected a finite float > 0')
    return float(value)


def residual_displacement(x, dt: float, window_s: float = RESIDUAL_WINDOW_S) -> float:
    """Residual (permanent) displacement: the Hann-weighted mean over the record's last seconds.

    Parameters
    ----------
    x : array_like (n,)
        Displacement at ``k*dt`` [m] (any unit; the result has the same). Only the samples
        before the first non-finite one are used.
    dt : float > 0
        Sample period [s].
    window_s : float > 0
        Length T of the window at the end of the record [s]; a record shorter than T is
        used whole.

    Returns
    -------
    float
        ``sum_k w[k] x[k] / sum_k w[k]`` over the last ``N = round(T/dt)`` samples, with w
        the Hann window of N samples without its zero end points
        (``scipy.signal.windows.hann(N + 2)[1:-1]``); same unit as `x`. NaN if no sample is
        finite.

    Raises
    ------
    ParameterError
        If `dt` or `window_s` is not a finite float > 0 or `x` is not 1-D.

    Notes
    -----
    The permanent set of a yielding member is the displacement it comes to rest at once the
    shaking has ended. This definition gives it also when the record ends while the
    structure still oscillates: a sinusoid ``A sin(2 pi f t + phi)`` adds at most
    ``A / (pi f T ((f T)^2 - 1))`` for ``f T > 1`` (the magnitude of the Hann window's
    transform relative to its value at 0, Harris 1978), i.e. 0.4 % of A at 2.2 Hz (the
    post-yield tangent frequency of the default member at alpha = 1) and 1.2e-4 A at 7 Hz
    with the default 2 s. The mean lies on a linear trend's value at the window's centre
    (T/2 before the end): a member still drifting at the end of the record is credited with
    its offset about a second earlier.

    References
    ----------
    F. J. Harris, On the use of windows for harmonic analysis with the discrete Fourier
    transform, Proc. IEEE 66(1), 1978, 51-83 (the Hann window and its transform).
    """
    dt = _check_dt(dt)
    window_s = _check_positive('window_s', window_s)
    x = _finite_prefix(_as_1d('x', x))
    n = x.shape[0]
    if n == 0:
        return math.nan
    count = min(n, max(1, int(round(window_s / dt))))
    weights = signal.windows.hann(count + 2)[1:-1]
    return float(np.dot(weights, x[n - count:]) / np.sum(weights))


def drift(x, dt: float, cutoff_hz: float = DRIFT_CUTOFF_HZ) -> np.ndarray:
    """The slowly varying permanent offset of a displacement: a zero-phase low-pass of it.

    Parameters
    ----------
    x : array_like (n,)
        Displacement at ``k*dt`` [m] (any unit; the result has the same).
    dt : float > 0
        Sample period [s].
    cutoff_hz : float > 0
        Cut-off frequency [Hz], below the Nyquist frequency ``1/(2 dt)``.

    Returns
    -------
    ndarray (n,)
        The low-passed displacement, same unit. Samples from the first non-finite one of
        `x` on are NaN; a single sample is returned as it is.

    Raises
    ------
    ParameterError
        If `dt` is not > 0, `cutoff_hz` is not in ``(0, 1/(2 dt))`` or `x` is not 1-D.

    Notes
    -----
    A Butterworth low-pass of order ``DRIFT_FILTER_ORDER`` (4), applied forward and backward
    (``scipy.signal.sosfiltfilt``): zero phase, magnitude ``1 / (1 + (f/f_c)^8)``, so a
    step of the permanent offset stays where it happened and the oscillation is removed
    (with the default 0.25 Hz: 1.5e-5 of it passes at 1 Hz, 6e-8 at 2 Hz). The record is
    extended at both ends by its even reflection of ``n - 1`` samples (``padtype='even'``),
    which keeps the mean of an oscillation that is cut off at the end and passes a constant
    (to rounding, 1e-11 relative): ``x - drift(x)`` of ``x + d`` is that of x for any
    constant d. The default cut-off (``DRIFT_CUTOFF_HZ``) lies 8 to 13 times below the
    slowest oscillation of the default yielding member (its post-yield tangent frequency
    ``sqrt(a k / ((1 + alpha) m)) / (2 pi)``: 3.2 Hz at alpha = 0, 2.0 Hz at alpha = 1.5)
    and at a quarter of the default record's lower band edge at time scale 0.5 (1 Hz).

    References
    ----------
    D. M. Boore and J. J. Bommer (2005), Processing of strong-motion accelerograms: needs,
    options and consequences, Soil Dyn. Earthquake Eng. 25(2), 93-115 (acausal Butterworth
    filtering of records, padded).
    """
    dt = _check_dt(dt)
    _check_cutoff(cutoff_hz, dt)
    x = _as_1d('x', x)
    out = np.full(x.shape[0], np.nan)
    head = _finite_prefix(x)
    m = head.shape[0]
    if m < 2:
        out[:m] = head
        return out
    sos = signal.butter(DRIFT_FILTER_ORDER, float(cutoff_hz), fs=1.0 / dt, output='sos')
    out[:m] = signal.sosfiltfilt(sos, head, padtype='even', padlen=m - 1)
    return out


def is_nonlinear(params) -> bool:
    """Whether a run's specimen is nonlinear: ``params['specimen_model']`` other than 'linear'
    (absent: 'linear', the runs recorded before the hysteretic member)."""
    return params.get('specimen_model', 'linear') != 'linear'


def restoring_force(run: RunData) -> np.ndarray:
    """The member's restoring force in a test, from the load cell, accelerometer and velocity.

    Parameters
    ----------
    run : RunData
        The run; uses ``measured_force_N``, ``acceleration_m_s2``, ``velocity_m_s`` (n,) and
        ``params['mass_kg']``, ``params['damping_N_s_per_m']``.

    Returns
    -------
    ndarray (n,)
        ``f_s = f_m - m a - c v`` [N] at every sample; plotted against the displacement it is
        the member's hysteresis loop.

    Raises
    ------
    ParameterError
        If mass_kg or damping_N_s_per_m is missing, not finite or out of range (m > 0,
        c >= 0).

    Notes
    -----
    The load cell measures the actuator force f_m on the specimen, and the specimen obeys
    ``m x'' + c x' + f_s(x, z) = f_m`` (paper Eq. 5.1, ``k x`` replaced by the member's
    restoring force). Both simulated rigs read their sensors from that equation at the
    same instant t_k (``ServoHydraulicRig.measure``: ``f_m = A p_L``,
    ``a = (A p_L - c x' - f_s)/m``; ``DelayRig.measure``: ``f_m = f_r(t_k - tau)``,
    ``a = (f_m - c v - f_s)/m``), so the reconstruction is exact for noise-free sensors, an
    acceleration inside the accelerometer's range (4 g by default) and no anti-alias filter
    (``anti_alias_cutoff_hz = 0``, the default; with it the force and the acceleration are
    filtered alike and only ``c v`` is not). Sensor noise enters as
    ``sigma_f + m sigma_a + c sigma_v``. The viscous damping is the nominal c: damping of a
    real member beyond it shows in the loops.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 5.1.
    """
    params = run.params
    values = {}
    for name, allow_zero in (('mass_kg', False), ('damping_N_s_per_m', True)):
        if name not in params:
            raise ParameterError(f'run parameters: missing {name}')
        value = params[name]
        ok = isinstance(value, (int, float, np.integer, np.floating)) \
            and not isinstance(value, bool) and math.isfinite(value) \
            and (value >= 0 if allow_zero else value > 0)
        if not ok:
            raise ParameterError(f'parameter {name}={value!r}: expected a finite float '
                                 + ('>= 0' if allow_zero else '> 0'))
        values[name] = float(value)
    n = run.n_steps
    f = np.asarray(run.measured_force_N, dtype=float)[:n]
    a = np.asarray(run.acceleration_m_s2, dtype=float)[:n]
    v = np.asarray(run.velocity_m_s, dtype=float)[:n]
    return f - values['mass_kg'] * a - values['damping_N_s_per_m'] * v


@dataclass(frozen=True)
class SignalComparison:
    """Comparison of one test signal with its reference counterpart.

    Attributes
    ----------
    peak_test, peak_reference : float
        Peak magnitudes ``max |x|`` of the test and the reference over the run's samples
        (SI unit of the signal: m, N or m/s^2).
    lag_s : float
        Estimated lag of the test behind the reference [s] (:func:`estimate_lag`).
    nrms : float
        Normalized RMS error after removing the signal's own lag `lag_s`, as a fraction
        (:func:`nrms_error`).
    peak_ratio : float
        ``peak_test / peak_reference`` [-].
    nrms_unshifted : float
        Normalized RMS error of the signals as recorded (no lag removed), as a fraction.
    nrms_common_lag : float
        Normalized RMS error after removing the common lag, the displacement's of its rig
        or DOF, from this signal, as a fraction; equals `nrms` for a displacement and a
        link's drift.
    """

    peak_test: float
    peak_reference: float
    lag_s: float
    nrms: float
    peak_ratio: float
    nrms_unshifted: float = math.nan
    nrms_common_lag: float = math.nan


@dataclass(frozen=True)
class ResidualComparison:
    """The displacement of a test and its reference with and without the permanent offset.

    Attributes
    ----------
    peak_test_m, peak_reference_m : float
        Peak displacements ``max |x|`` of the test and the reference [m].
    residual_test_m, residual_reference_m : float
        Residual (permanent) displacements [m] (:func:`residual_displacement`).
    lag_s : float
        The displacement's lag behind the reference [s], removed in both NRMS.
    nrms : float
        Displacement NRMS after removing the lag, as a fraction (the displacement's `nrms`).
    nrms_residual_removed : float
        The same NRMS after subtracting from the test and from the reference each its own
        drift (:func:`drift`): ``nrms(x - drift(x), x_ref - drift(x_ref))``, as a fraction.
    drift_cutoff_hz : float
        Cut-off of the drift low-pass [Hz].
    residual_window_s : float
        Window of the residual displacement [s].
    """

    peak_test_m: float
    peak_reference_m: float
    residual_test_m: float
    residual_reference_m: float
    lag_s: float
    nrms: float
    nrms_residual_removed: float
    drift_cutoff_hz: float = DRIFT_CUTOFF_HZ
    residual_window_s: float = RESIDUAL_WINDOW_S


@dataclass(frozen=True)
class RigComparison:
    """Comparison of one rig's signals with the reference at its DOF, one
    :class:`SignalComparison` per signal.

    Attributes
    ----------
    displacement, force, acceleration : SignalComparison
        Displacement [m], load-cell force versus the member (interface) force [N],
        acceleration [m/s^2].
    reference : ReferenceResponse
        The reference at the rig's DOF over the run's n samples.
    high_frequency_force_fraction : float
        Fraction of the test force's power above `high_frequency_cutoff_hz`
        (:func:`high_frequency_fraction`).
    high_frequency_force_fraction_reference : float
        The same for the reference force.
    high_frequency_cutoff_hz : float
        Cutoff of the two fractions [Hz] (default ``HIGH_FREQUENCY_CUTOFF_HZ``, 20 Hz).
    criteria : Criteria or None
        The RTHS benchmark's criteria J1-J5 (``criteria.evaluation_criteria``).
    residual : ResidualComparison or None
        Peak and residual displacements and the displacement NRMS with the permanent offsets
        removed (computed for every rig; reported for a nonlinear specimen).
    """

    displacement: SignalComparison
    force: SignalComparison
    acceleration: SignalComparison
    reference: ReferenceResponse
    high_frequency_force_fraction: float
    high_frequency_force_fraction_reference: float
    high_frequency_cutoff_hz: float = HIGH_FREQUENCY_CUTOFF_HZ
    criteria: Criteria | None = None
    residual: ResidualComparison | None = None

    def signal(self, name: str) -> SignalComparison:
        """Return the comparison of 'displacement', 'force' or 'acceleration'."""
        if name not in SIGNALS:
            raise ParameterError(f'signal {name!r}: expected one of {", ".join(SIGNALS)}')
        return getattr(self, name)


#: The compared signals of a DOF, in report order (``interface_force`` at physical DOFs).
DOF_SIGNALS = ('displacement', 'acceleration', 'floor_acceleration', 'interface_force')


@dataclass(frozen=True)
class DofComparison:
    """One degree of freedom of a run against the reference.

    Attributes
    ----------
    dof : str
        Its name.
    rig : str or None
        The rig that tests it (None: computational; ``''``: the study's rig).
    displacement, acceleration, floor_acceleration : SignalComparison
        Displacement relative to the ground [m], relative and absolute acceleration [m/s^2]
        (a physical DOF's displacement and acceleration are its rig's comparisons).
    interface_force : SignalComparison or None
        Physical DOF: the rig's load-cell force against the reference specimen's force [N]
        (its rig's force comparison).
    """

    dof: str
    rig: str | None
    displacement: SignalComparison
    acceleration: SignalComparison
    floor_acceleration: SignalComparison
    interface_force: SignalComparison | None = None

    def signal(self, name: str) -> SignalComparison | None:
        """The comparison of one of :data:`DOF_SIGNALS`."""
        if name not in DOF_SIGNALS:
            raise ParameterError(f'signal {name!r}: expected one of {", ".join(DOF_SIGNALS)}')
        return getattr(self, name)


@dataclass(frozen=True)
class LinkComparison:
    """The deformation of one link (a story, a bearing) against the reference.

    Attributes
    ----------
    name : str
        ``story_<i>`` of a shear building, ``<dof>-<dof>`` or ``<dof>-ground``.
    drift : SignalComparison
        Its deformation [m] (the story drift: the relative displacement of its ends).
    """

    name: str
    drift: SignalComparison


def _one_rig(name: str):
    """A property of a one-rig comparison that reads its rig's attribute `name`."""
    def get(self):
        return getattr(self.rig, name)
    return property(get, doc=f"The rig's ``{name}`` (a run of one rig only; "
                    '``comparison.rigs[name]`` otherwise).')


@dataclass(frozen=True)
class RunComparison:
    """A run against the whole structure's reference: per rig and per DOF (module notes).

    A comparison of a run of one rig reads as that rig's (``comparison.displacement``,
    ``.force``, ``.acceleration``, ``.reference``, ``.criteria``, ``.residual``,
    ``.high_frequency_*``, ``.signal(name)`` are its :class:`RigComparison`'s); with several
    rigs they raise ``AttributeError`` naming the rigs.

    Attributes
    ----------
    rigs : dict of str to RigComparison
        Per rig, in the structure's order.
    dofs : tuple of DofComparison
        In the structure's DOF order.
    links : tuple of LinkComparison
        The structure's links (story drifts).
    structure_reference : StructureReference or None
        The whole structure's reference over the run's samples.
    n_steps : int
        The samples compared.
    """

    rigs: dict
    dofs: tuple = ()
    links: tuple = ()
    structure_reference: StructureReference | None = None
    n_steps: int = 0

    @property
    def rig(self) -> RigComparison:
        """The comparison of the run's only rig.

        Raises
        ------
        AttributeError
            The run has several rigs (the message names them).
        """
        return only_rig(self.rigs, 'comparison', 'use comparison.rigs[name]')

    displacement = _one_rig('displacement')
    force = _one_rig('force')
    acceleration = _one_rig('acceleration')
    reference = _one_rig('reference')
    high_frequency_force_fraction = _one_rig('high_frequency_force_fraction')
    high_frequency_force_fraction_reference = _one_rig('high_frequency_force_fraction_reference')
    high_frequency_cutoff_hz = _one_rig('high_frequency_cutoff_hz')
    criteria = _one_rig('criteria')
    residual = _one_rig('residual')

    def signal(self, name: str) -> SignalComparison:
        """The only rig's comparison of 'displacement', 'force' or 'acceleration'."""
        return self.rig.signal(name)

    def dof(self, name: str) -> DofComparison:
        """The comparison of DOF `name` (KeyError if none)."""
        for d in self.dofs:
            if d.dof == name:
                return d
        raise KeyError(name)

    def worst_dof(self, name: str = 'displacement') -> tuple[float, str]:
        """The largest NRMS over the DOFs of one of :data:`DOF_SIGNALS` and the DOF it is
        at: (a fraction, the DOF's name); (NaN, '') if none is finite (the first DOF of a
        tie)."""
        worst, where = math.nan, ''
        for d in self.dofs:
            c = d.signal(name)
            if c is not None and math.isfinite(c.nrms) and (not where or c.nrms > worst):
                worst, where = c.nrms, d.dof
        return worst, where

    def worst_nrms(self, name: str = 'displacement') -> float:
        """The largest NRMS over the DOFs of one of :data:`DOF_SIGNALS` (a fraction; NaN if
        none is finite; :meth:`worst_dof` names the DOF)."""
        return self.worst_dof(name)[0]


def _compare_rig(rig: RigData, reference: ReferenceResponse, dt: float, n: int, *,
                 max_lag_s: float, high_frequency_cutoff_hz: float, j1_max_lag_s: float,
                 drift_cutoff_hz: float, residual_window_s: float) -> RigComparison:
    """One rig's signals against the reference at its DOF (:func:`compare_run`)."""
    pairs = {name: (np.asarray(rig.signal(name), dtype=float)[:n],
                    np.asarray(reference.signal(name), dtype=float)[:n]) for name in SIGNALS}
    common_lag = estimate_lag(*pairs['displacement'], dt, max_lag_s)
    results = {}
    for name, (test, ref) in pairs.items():
        lag = estimate_lag(test, ref, dt, max_lag_s)
        results[name] = SignalComparison(
            peak_test=peak(test), peak_reference=peak(ref), lag_s=lag,
            nrms=nrms_error(shift(test, lag, dt), ref), peak_ratio=peak_ratio(test, ref),
            nrms_unshifted=nrms_error(test, ref),
            nrms_common_lag=nrms_error(shift(test, common_lag, dt), ref))
    x_test, x_ref = pairs['displacement']
    lag_x = results['displacement'].lag_s
    residual = ResidualComparison(
        peak_test_m=peak(x_test), peak_reference_m=peak(x_ref),
        residual_test_m=residual_displacement(x_test, dt, residual_window_s),
        residual_reference_m=residual_displacement(x_ref, dt, residual_window_s),
        lag_s=lag_x, nrms=results['displacement'].nrms,
        nrms_residual_removed=nrms_error(
            shift(x_test - drift(x_test, dt, drift_cutoff_hz), lag_x, dt),
            x_ref - drift(x_ref, dt, drift_cutoff_hz)),
        drift_cutoff_hz=float(drift_cutoff_hz), residual_window_s=float(residual_window_s))
    criteria = evaluation_criteria(
        target_force=np.asarray(rig.reference_force_N, dtype=float)[:n],
        measured_force=np.asarray(rig.measured_force_N, dtype=float)[:n],
        displacement=pairs['displacement'][0], reference_displacement=pairs['displacement'][1],
        dt=dt, j1_max_lag_s=j1_max_lag_s)
    return RigComparison(
        **results, reference=reference, criteria=criteria,
        high_frequency_force_fraction=high_frequency_fraction(
            np.asarray(rig.measured_force_N, dtype=float)[:n], dt, high_frequency_cutoff_hz),
        high_frequency_force_fraction_reference=high_frequency_fraction(
            reference.force_N[:n], dt, high_frequency_cutoff_hz),
        high_frequency_cutoff_hz=float(high_frequency_cutoff_hz), residual=residual)


def _signal_comparison(test, reference, dt: float, max_lag_s: float,
                       common_lag_s: float | None = None) -> SignalComparison:
    """:class:`SignalComparison` of two signals over the samples finite in both; its common-lag
    NRMS after removing `common_lag_s` (its DOF's displacement lag), or its own lag's for
    None (a displacement or a link's drift, whose lag is the common one)."""
    test = np.asarray(test, dtype=float)
    reference = np.asarray(reference, dtype=float)
    good = np.isfinite(test) & np.isfinite(reference)
    n = int(np.argmin(good)) if not np.all(good) else test.shape[0]
    test, reference = test[:n], reference[:n]
    if n < 2:
        return SignalComparison(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan,
                                math.nan)
    lag = estimate_lag(test, reference, dt, max_lag_s)
    nrms = nrms_error(shift(test, lag, dt), reference)
    common = (nrms if common_lag_s is None or common_lag_s == lag else
              nrms_error(shift(test, common_lag_s, dt), reference)
              if math.isfinite(common_lag_s) else math.nan)
    return SignalComparison(
        peak_test=peak(test), peak_reference=peak(reference), lag_s=lag, nrms=nrms,
        peak_ratio=peak_ratio(test, reference), nrms_unshifted=nrms_error(test, reference),
        nrms_common_lag=common)


def _dof_signals(run: RunData, dofs, rigs, physical_index, influence) -> dict:
    """:func:`dof_signals` of a structure given by its DOFs, rigs, their DOFs and iota."""
    ag = np.asarray(run.ground_acceleration_m_s2, dtype=float)
    physical = {physical_index[j]: r for j, r in enumerate(rigs)}
    out = {}
    for i, dof in enumerate(dofs):
        if i in physical:
            rig = run.rigs.get(physical[i])
            if rig is None:
                raise ParameterError(f'rig {rig_label(physical[i])}: its signals are not in '
                                     f'the run (rigs: {", ".join(map(rig_label, run.rigs))})')
            x, v, a = rig.displacement_m, rig.velocity_m_s, rig.acceleration_m_s2
            extra = {'interface_force': np.asarray(rig.measured_force_N, dtype=float)}
        else:
            try:
                x, v, a = (run.computational[f'{dof}/{q}'] for q in (
                    'displacement_m', 'velocity_m_s', 'acceleration_m_s2'))
            except KeyError:
                raise ParameterError(f'computational dof {dof!r}: its state is not in the '
                                     'run') from None
            extra = {}
        a = np.asarray(a, dtype=float)
        out[dof] = {'displacement': np.asarray(x, dtype=float),
                    'velocity': np.asarray(v, dtype=float), 'acceleration': a,
                    'floor_acceleration': a + float(influence[i]) * ag, **extra}
    return out


def dof_signals(run: RunData) -> dict[str, dict[str, np.ndarray]]:
    """The test's signals per DOF: ``{dof: {'displacement', 'velocity', 'acceleration',
    'floor_acceleration', ['interface_force']}}``, arrays of shape (n,) [m, m/s, m/s^2, N]
    (a physical DOF's from its rig's sensors and load cell; a computational DOF's as the
    builder integrated it, its last sample NaN: the builder's state of sample k comes with
    the force of k+1).

    Raises
    ------
    ParameterError
        The run's structure is invalid, or a DOF's signals are missing.
    """
    s = structure_of(run.params)
    rigs = s.rig_names
    return _dof_signals(run, s.dofs, rigs, s.physical_index, s.influence)


def _one_dof_reference(reference: ReferenceResponse, run: RunData) -> StructureReference:
    """The one-DOF structure reference of a run of one rig whose rig's reference is
    `reference` (its absolute acceleration from the run's record; NaN past it)."""
    if len(run.rigs) != 1 or not run.is_study:
        raise ParameterError("reference: a ReferenceResponse is the reference of the study's "
                             'one-DOF test; give a structure test its StructureReference '
                             '(run_reference)')
    rig = next(iter(run.rigs))
    n = reference.n_steps
    ground = np.full(n, np.nan)
    ag = np.asarray(run.ground_acceleration_m_s2, dtype=float)[:n]
    ground[:ag.shape[0]] = ag

    def column(values):
        return np.asarray(values, dtype=float)[:, None]
    restoring = (reference.restoring_force_N if reference.restoring_force_N is not None
                 else np.full(n, np.nan))
    return StructureReference(
        time_s=reference.time_s, dofs=(STUDY_DOF,), rigs=(rig,), physical_index=(0,),
        influence=np.ones(1), links=(Link(0, None, f'{STUDY_DOF}-ground'),),
        displacement_m=column(reference.displacement_m),
        velocity_m_s=column(reference.velocity_m_s),
        acceleration_m_s2=column(reference.acceleration_m_s2),
        absolute_acceleration_m_s2=column(reference.acceleration_m_s2) + ground[:, None],
        interface_force_N=column(reference.force_N), restoring_force_N=column(restoring),
        hysteretic_z={} if reference.hysteretic_z is None else {rig: reference.hysteretic_z})


def compare_run(run: RunData, reference: StructureReference | ReferenceResponse | None = None,
                *, max_lag_s: float = MAX_LAG_S,
                high_frequency_cutoff_hz: float = HIGH_FREQUENCY_CUTOFF_HZ,
                j1_max_lag_s: float = J1_MAX_LAG_S,
                drift_cutoff_hz: float = DRIFT_CUTOFF_HZ,
                residual_window_s: float = RESIDUAL_WINDOW_S) -> RunComparison:
    """Compare a run with the whole structure's reference, per rig and per DOF.

    **Per rig** (:class:`RigComparison`), the rig's displacement, force and acceleration
    against the reference at its DOF: for each signal the lag of the test behind the
    reference is estimated (:func:`estimate_lag`), the test is advanced by that lag
    (:func:`shift`), and the normalized RMS error (:func:`nrms_error`) is computed over the
    samples both share; the peaks are those of the unshifted signals. Each signal is aligned
    by its own lag (all three share the loop delay in a well-behaved test; a different force
    or acceleration lag reveals the phase error of acceleration feedback). The NRMS is also
    computed unshifted and after advancing every signal by the displacement's lag (the common
    lag), and the RTHS benchmark's criteria J1-J5 (``criteria.evaluation_criteria``: the
    reference force commanded versus the load-cell force, and the displacement versus the
    reference, as recorded). The displacement is also compared without the permanent offsets
    (:class:`ResidualComparison`): peaks, residual displacements
    (:func:`residual_displacement`) and the NRMS, after removing the displacement's lag, of
    ``x - drift(x)`` against ``x_ref - drift(x_ref)`` (:func:`drift`).

    **Per DOF** (:class:`DofComparison`): a physical DOF's displacement, acceleration and
    interface force are its rig's comparisons; its floor acceleration ``x'' + iota xg''``
    and a computational DOF's signals (:func:`dof_signals`) are compared the same way over
    the samples finite in both, their common lag the DOF's displacement lag (a physical DOF's:
    its rig's). **Per link** (:class:`LinkComparison`): the relative displacement of its
    ends.

    Parameters
    ----------
    run : RunData
        The run (n samples; an aborted run is compared over the samples it has).
    reference : StructureReference, ReferenceResponse or None
        The reference; :func:`~seft_ros.analysis.reference.run_reference` of the run if None;
        for the study's one-DOF test also its rig's ReferenceResponse. Only its first n
        samples are used.
    max_lag_s : float >= 0
        Bound of the lag search [s].
    high_frequency_cutoff_hz : float > 0
        Cutoff of the high-frequency content of the force [Hz], below the Nyquist frequency
        ``1/(2 dt)`` (:func:`high_frequency_fraction`).
    j1_max_lag_s : float >= 0
        Bound of the search of criterion J1 [s] (``criteria.J1_MAX_LAG_S``).
    drift_cutoff_hz : float > 0
        Cut-off of the drift low-pass [Hz], below the Nyquist frequency (:func:`drift`).
    residual_window_s : float > 0
        Window of the residual displacement [s] (:func:`residual_displacement`).

    Returns
    -------
    RunComparison

    Raises
    ------
    ParameterError
        If a run parameter is missing or out of range, a cutoff is not below the Nyquist
        frequency, `residual_window_s` is not > 0, the reference has fewer samples than the
        run, or a rig's or computational DOF's signals are missing from the run.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 4 (Figure 6) and
    Eq. 5.2.
    """
    if reference is None:
        reference = run_reference(run)
    elif isinstance(reference, ReferenceResponse):
        reference = _one_dof_reference(reference, run)
    n = run.n_steps
    if reference.n_steps < n:
        raise ParameterError(f'reference has {reference.n_steps} samples, the run {n}; '
                             'expected at least as many as the run')
    dt = _check_dt(run.params.get('dt'))
    test = _dof_signals(run, reference.dofs, reference.rigs, reference.physical_index,
                        reference.influence)
    rigs = {r: _compare_rig(run.rigs[r], reference.rig(r), dt, n, max_lag_s=max_lag_s,
                            high_frequency_cutoff_hz=high_frequency_cutoff_hz,
                            j1_max_lag_s=j1_max_lag_s, drift_cutoff_hz=drift_cutoff_hz,
                            residual_window_s=residual_window_s)
            for r in reference.rigs}
    physical = {i: r for r, i in zip(reference.rigs, reference.physical_index)}
    refs = {'displacement': reference.displacement_m,
            'acceleration': reference.acceleration_m_s2}
    dofs = []
    for i, dof in enumerate(reference.dofs):
        c = rigs[physical[i]] if i in physical else None
        x = c.displacement if c is not None else _signal_comparison(
            test[dof]['displacement'][:n], refs['displacement'][:n, i], dt, max_lag_s)
        # every signal of a DOF also with its displacement's lag removed (the common lag)
        floor = _signal_comparison(test[dof]['floor_acceleration'][:n],
                                   reference.absolute_acceleration_m_s2[:n, i], dt, max_lag_s,
                                   x.lag_s)
        if c is not None:
            dofs.append(DofComparison(dof, physical[i], c.displacement, c.acceleration, floor,
                                      c.force))
            continue
        a = _signal_comparison(test[dof]['acceleration'][:n], refs['acceleration'][:n, i], dt,
                               max_lag_s, x.lag_s)
        dofs.append(DofComparison(dof, None, x, a, floor))
    links = []
    for link in reference.links:
        x_i, r_i = test[reference.dofs[link.i]]['displacement'][:n], \
            reference.displacement_m[:n, link.i]
        if link.j is None:
            x_j, r_j = np.zeros(n), np.zeros(n)
        else:
            x_j, r_j = test[reference.dofs[link.j]]['displacement'][:n], \
                reference.displacement_m[:n, link.j]
        links.append(LinkComparison(link.name, _signal_comparison(x_i - x_j, r_i - r_j, dt,
                                                                  max_lag_s)))
    return RunComparison(rigs, tuple(dofs), tuple(links), reference, n)


def _finite_or_none(value) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def json_safe(value: Any) -> Any:
    """Return `value` with every non-finite float (and NumPy scalar) made JSON-safe.

    NaN and +/-inf become None (JSON null), NumPy scalars become Python scalars; dicts, lists
    and tuples are converted recursively.
    """
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _finite_or_none(value)
    return value


#: The signals of a rig's entry, in summary order.
_ENTRY_SIGNALS = ('displacement', 'acceleration', 'force')
#: The criteria of a rig's entry.
_CRITERIA = ('J1', 'J2', 'J3', 'J4', 'J5')


def _rig_entry(params, comparison: RigComparison | None) -> dict[str, Any]:
    """The one-rig keys of a summary entry of one rig (its parameters `params`), or every
    value None (`comparison` None: a run of several rigs)."""
    if comparison is None:
        nothing = {name: None for name in _ENTRY_SIGNALS}
        return {'alpha': None, 'rig': None, 'lag_s': None, 'nrms': dict(nothing),
                'nrms_common_lag': dict(nothing), 'nrms_unshifted': dict(nothing),
                'criteria': {key: None for key in _CRITERIA}, 'peak_ratio': dict(nothing),
                'high_frequency_force_fraction': None,
                'high_frequency_force_fraction_reference': None,
                'high_frequency_cutoff_hz': None}
    c = comparison
    return {
        'alpha': _finite_or_none(params.get('alpha')),
        'rig': params.get('rig_model'),
        'lag_s': c.displacement.lag_s,
        'nrms': {name: c.signal(name).nrms for name in _ENTRY_SIGNALS},
        'nrms_common_lag': {name: c.signal(name).nrms_common_lag for name in _ENTRY_SIGNALS},
        'nrms_unshifted': {name: c.signal(name).nrms_unshifted for name in _ENTRY_SIGNALS},
        'criteria': (c.criteria.as_dict() if c.criteria is not None
                     else {key: None for key in _CRITERIA}),
        'peak_ratio': {name: c.signal(name).peak_ratio for name in _ENTRY_SIGNALS},
        'high_frequency_force_fraction': c.high_frequency_force_fraction,
        'high_frequency_force_fraction_reference': c.high_frequency_force_fraction_reference,
        'high_frequency_cutoff_hz': c.high_frequency_cutoff_hz,
    }


def _nonlinear_entry(params, comparison: RigComparison) -> dict[str, Any] | None:
    """The ``'nonlinear'`` block of a rig with a nonlinear specimen (None otherwise)."""
    residual = comparison.residual
    if not is_nonlinear(params) or residual is None:
        return None
    return {
        'specimen_model': params.get('specimen_model'),
        'nrms_displacement': residual.nrms,
        'nrms_displacement_residual_removed': residual.nrms_residual_removed,
        'peak_displacement_m': {'test': residual.peak_test_m,
                                'reference': residual.peak_reference_m},
        'residual_displacement_m': {'test': residual.residual_test_m,
                                    'reference': residual.residual_reference_m},
        'drift_cutoff_hz': residual.drift_cutoff_hz,
        'residual_window_s': residual.residual_window_s,
    }


def _signal_entry(c: SignalComparison | None) -> dict[str, Any] | None:
    if c is None:
        return None
    return {'nrms': c.nrms, 'peak_ratio': c.peak_ratio, 'lag_s': c.lag_s,
            'peak_test': c.peak_test, 'peak_reference': c.peak_reference,
            'nrms_common_lag': c.nrms_common_lag, 'nrms_unshifted': c.nrms_unshifted}


def summary_entry(run: RunData, comparison: RunComparison) -> dict[str, Any]:
    """Summarize a run and its comparison as a JSON-safe dict: one layout for every run.

    Parameters
    ----------
    run : RunData
        The run.
    comparison : RunComparison
        Its comparison (:func:`compare_run`).

    Returns
    -------
    dict
        **The run's rig** (the keys of the study's test, for any run of one rig):
        ``{'alpha', 'rig', 'predictor', 'record', 'stable', 'unstable_at_s', 'lag_s',
        'nrms': {'displacement', 'acceleration', 'force'},
        'nrms_common_lag': {...}, 'nrms_unshifted': {...},
        'peak_ratio': {'displacement', 'acceleration', 'force'},
        'criteria': {'J1', 'J2', 'J3', 'J4', 'J5'},
        'high_frequency_force_fraction', 'high_frequency_force_fraction_reference',
        'high_frequency_cutoff_hz', 'abort_reason', 'mode', 'wall_s', 'rig_contract'}``
        (and ``'timing'``, the :func:`seft_ros.analysis.timing.timing_summary` of a
        real-time run, from ``run.extra['timing']``, ``'link'``, ``'bag_lost_messages'``,
        what the nodes published and the bag does not hold, and ``'recording'``, how the
        recording ended (``seft_ros.analysis.bag.recording_end``: closed, stopped, or crashed
        and recovered), ``'stability'``, the pre-run guard's prediction with its robustness
        margin (``cli.api.stability_entry``), ``'warnings'``, what the builders reported
        during the run (a specimen that is not the declared one), and
        ``'specimen_stiffness_ratios'``, each rig's identified specimen stiffness over the
        declared one, from ``run.extra``; ``'range_check'``, the pre-run range check
        (:meth:`seft_ros.analysis.range_check.RangeCheck.as_dict`, from ``run.extra``),
        ``'record_read'``, what the run read from its record file and how it scaled it
        (:func:`seft_ros.core.ground_motion.record_read`, from ``run.extra``; a run on the
        embedded default or an excitation has none),
        ``'sensor_range'``, each rig's samples at a sensor's range
        (:func:`seft_ros.analysis.findings.sensor_range_entry`), for a rig behind the UDP
        bridge ``'udp_bridge'``, its link's datagram counts, warnings and whether the
        controller confirmed its safe state
        (:func:`seft_ros.analysis.findings.bridge_entry`), ``'flags'``, why the run may
        have lost accuracy as a lab sees it (:func:`seft_ros.analysis.findings.run_flags`), and
        ``'verdict'``, ``'stable'``, ``'stable, flagged'``, ``'aborted'`` or ``'recording cut
        short'``; ``wall_s`` [s],
        the wall time of the stepping, from ``run.extra['wall_s']``; ``rig_contract``, the rig
        contract its rig reported, ``'seft-rig/1.1'``, None for a bag before it, from
        ``run.extra``) where alpha and rig are the rig's ``alpha`` and ``rig_model``, predictor
        is ``params['predictor']``, record is ``run.record_name`` (``params['record']`` if
        empty), ``lag_s`` [s] is the displacement lag, ``nrms`` is after removing each signal's
        own lag, ``nrms_common_lag`` after removing ``lag_s`` from every signal,
        ``nrms_unshifted`` as recorded, ``criteria`` are the RTHS benchmark's J1 [ms] and J2-J5
        [%] (``criteria.CRITERIA``), nrms values and the high-frequency fractions (of the
        measured and of the reference force's power above the cutoff [Hz]) are fractions.
        A rig with a nonlinear specimen (:func:`is_nonlinear`) has in addition
        ``'nonlinear'``: ``{'specimen_model', 'nrms_displacement',
        'nrms_displacement_residual_removed', 'peak_displacement_m': {'test', 'reference'},
        'residual_displacement_m': {'test', 'reference'}, 'drift_cutoff_hz',
        'residual_window_s'}`` from its :class:`ResidualComparison`: the displacement NRMS
        after removing the lag as it is and with each signal's drift removed (fractions),
        peaks and residual (permanent) displacements [m], the drift's cut-off [Hz] and the
        residual's window [s]. A run of several rigs has these keys with every value None
        (``nrms`` ``{'displacement': None, ...}``; each rig's are in ``'rigs'``).

        **Every run** in addition: ``'abort_node'`` (the node that ended the run, or None),
        ``'n_steps'`` (the samples compared), ``'structure': {'dofs', 'physical',
        'builders'}`` (the DOFs, ``{dof: rig}`` of the physical ones, the builders' layout;
        the study's ``{'dofs': ['specimen'], 'physical': {'specimen': ''}}``),
        ``'worst_nrms': {'displacement', 'acceleration', 'floor_acceleration',
        'interface_force'}`` (the largest NRMS over the DOFs),
        ``'dofs': {dof: {'rig', 'displacement', 'acceleration', 'floor_acceleration',
        'interface_force'}}``, ``'links': {name: {...}}`` (each signal ``{'nrms',
        'peak_ratio', 'lag_s', 'peak_test', 'peak_reference', 'nrms_common_lag',
        'nrms_unshifted'}``, SI; ``nrms`` after removing the signal's own lag,
        ``nrms_common_lag`` after removing its DOF's displacement lag, None for a link;
        ``interface_force`` None at a computational DOF; ``rig`` None there, ``''`` for the
        study's rig), ``'rigs': {rig: {...}}`` (each rig's one-rig keys above, with
        ``'rig_contract'`` and ``'nonlinear'``, and ``'dof'``, ``'specimen_model'``) and,
        when the nodes disagreed, ``'parameter_mismatches'``.

        Every NaN or inf is None, so that ``json.dumps(entry, allow_nan=False)`` succeeds.
    """
    params = run.params
    single = len(comparison.rigs) == 1
    only = next(iter(comparison.rigs)) if single else None
    rig_params = run.rigs[only].params if single and only in run.rigs else params
    entry = _rig_entry(rig_params, comparison.rigs[only] if single else None)
    entry = {
        'alpha': entry['alpha'], 'rig': entry['rig'], 'predictor': params.get('predictor'),
        'record': run.record_name or params.get('record', ''), 'stable': bool(run.stable),
        'unstable_at_s': _finite_or_none(run.unstable_at_s),
        **{k: v for k, v in entry.items() if k not in ('alpha', 'rig')},
        'abort_reason': run.abort_reason,
        'mode': params.get('mode', 'lockstep'),
        'wall_s': _finite_or_none(run.extra.get('wall_s')),
        'rig_contract': run.extra.get('rig_contract'),
    }
    if single:
        block = _nonlinear_entry(rig_params, comparison.rigs[only])
        if block is not None:
            entry['nonlinear'] = block
    if run.extra.get('timing') is not None:
        entry['timing'] = run.extra['timing']
    link = link_summary(run.extra.get('link'), run.extra.get('timing'))
    if link is not None:
        entry['link'] = link
    if run.extra.get('bag_lost_messages') is not None:
        entry['bag_lost_messages'] = int(run.extra['bag_lost_messages'])
    if run.extra.get('recording') is not None:
        entry['recording'] = dict(run.extra['recording'])
    # the pre-run guard's prediction (its robustness margin), and what the builder found
    # during the run (a specimen not the declared one)
    if run.extra.get('stability') is not None:
        entry['stability'] = dict(run.extra['stability'])
    entry['warnings'] = list(run.extra.get('warnings') or [])
    if run.extra.get('specimen_ratios'):
        entry['specimen_stiffness_ratios'] = dict(run.extra['specimen_ratios'])
    # what says the run may have lost accuracy (issue 39): the pre-run range check, the
    # samples at a sensor's range, and the flags a lab sees without the reference
    from seft_ros.analysis.findings import (
        bridge_entry,
        run_flags,
        sensor_range_entry,
        valve_saturation_entry,
        verdict,
    )
    if run.extra.get('range_check') is not None:
        entry['range_check'] = dict(run.extra['range_check'])
    if run.extra.get('record_read') is not None:
        from seft_ros.core.ground_motion import record_warnings
        entry['record_read'] = dict(run.extra['record_read'])
        entry['record_warnings'] = record_warnings(run.extra['record_read'])
    if run.extra.get('timing_replay') is not None:
        entry['timing_replay'] = dict(run.extra['timing_replay'])
    entry['sensor_range'] = sensor_range_entry(run)
    entry['valve_saturation'] = valve_saturation_entry(run)
    bridge = bridge_entry(run)
    if bridge:
        entry['udp_bridge'] = bridge
    entry['flags'] = run_flags(run, comparison)
    entry['verdict'] = verdict(bool(run.stable), entry['flags'], run.recording_cut_short)
    entry.update(_structure_entries(run, comparison))
    return json_safe(entry)


def _structure_entries(run: RunData, comparison: RunComparison) -> dict[str, Any]:
    """The per-DOF, per-link and per-rig sections of :func:`summary_entry`."""
    rigs = {}
    dof_of = {d.rig: d.dof for d in comparison.dofs if d.rig is not None}
    for name, c in comparison.rigs.items():
        data = run.rigs.get(name)
        p = data.params if data is not None else run.params
        own = _rig_entry(p, c)
        rig = {'dof': dof_of.get(name), 'rig_model': own.pop('rig'), **own,
               'specimen_model': p.get('specimen_model', 'linear'),
               'rig_contract': (data.extra.get('rig_contract') if data is not None else None)
               or run.extra.get('rig_contract')}
        block = _nonlinear_entry(p, c)
        if block is not None:
            rig['nonlinear'] = block
        rigs[name] = rig
    out = {
        'abort_node': run.extra.get('abort_node'),
        'n_steps': comparison.n_steps,
        'structure': {'dofs': [d.dof for d in comparison.dofs],
                      'physical': {d.dof: d.rig for d in comparison.dofs if d.rig is not None},
                      'builders': run.params.get('structure_builders', 'central')},
        'worst_nrms': {name: comparison.worst_nrms(name) for name in DOF_SIGNALS},
        'dofs': {d.dof: {'rig': d.rig, **{name: _signal_entry(d.signal(name))
                                           for name in DOF_SIGNALS}}
                 for d in comparison.dofs},
        'links': {lk.name: _signal_entry(lk.drift) for lk in comparison.links},
        'rigs': rigs,
    }
    kind = None if run.is_study else structure_of(run.params).model_kind
    summary = None if kind is None else getattr(model_plugin(kind), 'summary', None)
    if summary is not None:
        # a plug-in model's own entry (OpenSees: its step times and overruns), by its name
        out[kind] = summary(run)
    if run.extra.get('parameter_mismatches'):
        out['parameter_mismatches'] = list(run.extra['parameter_mismatches'])
    return out


def best_runs(summary_entries) -> dict[tuple[Any, Any], dict[str, Any]]:
    """Pick the best compensated run per alpha and rig: stable, smallest displacement NRMS.

    Parameters
    ----------
    summary_entries : iterable of dict
        Summary entries (:func:`summary_entry`, or the ``runs`` of a ``summary.json``).

    Returns
    -------
    dict
        ``{(alpha, rig): entry}`` in order of first appearance. Candidates are the stable
        entries whose predictor is neither ``UNCOMPENSATED`` ('none') nor missing and whose
        displacement NRMS is a finite number; among them the smallest displacement NRMS wins
        (the first one on a tie). An (alpha, rig) without a candidate is absent.

    Raises
    ------
    ParameterError
        If an entry is not a dict.
    """
    best: dict[tuple[Any, Any], dict[str, Any]] = {}
    for entry in summary_entries:
        if not isinstance(entry, dict):
            raise ParameterError(f'summary entry {entry!r}: expected a dict')
        predictor = entry.get('predictor')
        if predictor in (None, UNCOMPENSATED) or not entry.get('stable'):
            continue
        error = (entry.get('nrms') or {}).get('displacement')
        if isinstance(error, bool) or not isinstance(error, (int, float)) \
                or not math.isfinite(error):
            continue
        key = (entry.get('alpha'), entry.get('rig'))
        if key not in best or error < best[key]['nrms']['displacement']:
            best[key] = entry
    return best

