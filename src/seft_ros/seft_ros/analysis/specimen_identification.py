"""A rig's specimen identified from its own measured force and motion (no rclpy).

Not the online identification of the ``adaptive`` compensator
(:mod:`seft_ros.core.identification`, recursive least squares during the test): this is the
pre-test fit a lab makes on the record of a low-amplitude identification run (``seft
identify``), over the whole record, with its quality stated.

:func:`fit_specimen` fits the specimen of paper Eq. 5.1, ``f = m x'' + c x' + k x``, by linear
least squares on the rig's measured force, acceleration, velocity and displacement, and
says how well the model holds: the residual, the standard errors, and whether the stiffness
depends on the amplitude (a member that yields has no single ``k``: it is reported as not
linear, and ``seft identify`` writes no ``m, c, k`` for it). A record in which a sensor read
its range (a clipped accelerometer, :mod:`seft_msgs_py.sensor_range`) is not fitted as the
specimen either: the clipped readings bend the fit (a 25 Hz pier whose accelerometer clipped
in a third of its samples was fitted 32 % heavy and 13 % soft, and looked like a member that
yields), and the verdict names the sensor. A few such samples (at most
:data:`MAX_AT_RANGE_SHARE` of the record) are taken, and said.
"""

from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from scipy import signal

from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.sensor_range import CHANNEL_UNITS, CHANNELS, RANGE_PARAMETERS, SensorRanges

__all__ = ['SpecimenFit', 'fit_specimen', 'NONLINEAR_TOLERANCE', 'FIT_PARTS', 'FILTER_ORDER',
           'SMALL_QUANTILE', 'LARGE_QUANTILE', 'MIN_PART_SAMPLES', 'MAX_AT_RANGE_SHARE',
           'SENSOR_NAMES', 'NOISE_FLOOR', 'SIGN_RESIDUAL']

#: Largest relative difference between the stiffness over the largest displacements and over
#: the smallest ones for a linear specimen [-]. Measured on the simulated rig (20 s of noise,
#: 0.5-50 Hz, ``config/two_story.yaml``'s rig): a linear specimen 0 without sensor noise,
#: 0.0014 with the noise set of ``benchmarks/robust_compensation.py`` at 100 N of excitation
#: and 0.0038 at 30 N; the study's Bouc-Wen member (yield force 844 N) 0.013 at 100 N (the
#: linear fit's k 1.1 % below the elastic one, c 3.9 % above: the loops' dissipation), 0.059
#: at 200 N (k 5.6 % low) and 0.15 at 300 N (k 15 % low).
NONLINEAR_TOLERANCE = 0.03
#: Largest share of a record's samples at a sensor's range with which the fit is still taken
#: as the specimen's [-]. Measured on a 25 Hz, 2 % pier (30 kg, 7.4e5 N/m) on
#: ``valve_3_stage``, 8 s of valve noise, its 39.2 m/s^2 accelerometer clipping: in 0.1 % of
#: the samples the fit's m, c, k were 0.07, -0.8 and 0.01 % off (within the noisy fits'
#: 0.5 % for m and k and 1.5 % for c), in 0.28 % c was 1.9 % off, in 1 % m 0.75 %, in 4 %
#: 2.6, -5.2 and -1.3 %, in 35 % m 34 % and k -11 % (read as a member that yields).
MAX_AT_RANGE_SHARE = 0.001
#: A fit whose m, c and k are all negative and which leaves less than this share of the
#: force unexplained [-] reads a sign reversed between the force and the motion, not a lack
#: of motion: a new user's load cell reversed gave m, c, k exactly negated (session 38); a
#: record with too little motion leaves most of the force unexplained.
SIGN_RESIDUAL = 0.1
#: Consecutive parts of the record fitted apart for the standard errors.
FIT_PARTS = 4
#: Fewest samples of each part.
MIN_PART_SAMPLES = 64
#: Order of the zero-phase Butterworth band-pass applied to every signal alike.
FILTER_ORDER = 4
#: The samples whose displacement magnitude is below this quantile are the "small" ones and
#: those above :data:`LARGE_QUANTILE` the "large" ones of the amplitude check.
SMALL_QUANTILE = 0.5
#: See :data:`SMALL_QUANTILE`.
LARGE_QUANTILE = 0.9


#: What the verdict calls each sensor (:data:`~seft_msgs_py.sensor_range.CHANNELS`).
SENSOR_NAMES = {'force': 'a load cell', 'displacement': 'a displacement transducer',
                'velocity': 'a velocity sensor', 'acceleration': 'an accelerometer'}


@dataclass(frozen=True)
class SpecimenFit:
    """A specimen identified by :func:`fit_specimen`.

    Attributes
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float
        The fitted m [kg], c [N s/m], k [N/m].
    standard_errors : tuple of float, length 3
        Standard errors of m, c, k (their units): the spread of the fits on
        :data:`FIT_PARTS` consecutive parts of the record over ``sqrt(parts)``.
    residual : float
        ``rms(f - m a - c v - k x) / rms(f)`` over the filtered record [-].
    band_hz : (float, float)
        Band of the zero-phase band-pass applied to every signal [Hz].
    n_samples : int
        Samples fitted.
    stiffness_small_N_per_m, stiffness_large_N_per_m : float
        The stiffness of the restoring force ``f - m a - c v`` over the samples of the
        smallest displacements (below the :data:`SMALL_QUANTILE` of ``|x|``) and over the
        largest ones (above :data:`LARGE_QUANTILE`) [N/m].
    peak_displacement_m, peak_force_N : float
        Largest ``|x|`` [m] and ``|f|`` [N] of the record (unfiltered).
    at_range : tuple of (str, int, float)
        ``(channel, samples, range)`` of each sensor that read its range in the record
        (:data:`~seft_msgs_py.sensor_range.CHANNELS`, the range in the channel's SI unit);
        empty when none did. The fit then reads clipped readings: beyond
        :data:`MAX_AT_RANGE_SHARE` of the samples (:attr:`clipped`) it is not the specimen's.
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float
    standard_errors: tuple
    residual: float
    band_hz: tuple
    n_samples: int
    stiffness_small_N_per_m: float
    stiffness_large_N_per_m: float
    peak_displacement_m: float
    peak_force_N: float
    at_range: tuple = ()

    @property
    def amplitude_dependence(self) -> float:
        """``|k_large / k_small - 1|`` [-]: 0 for a linear specimen (nan without motion)."""
        small, large = self.stiffness_small_N_per_m, self.stiffness_large_N_per_m
        if not (math.isfinite(small) and math.isfinite(large)) or small == 0:
            return math.nan
        return abs(large / small - 1.0)

    @property
    def clipped(self) -> bool:
        """Whether a sensor read its range in more than :data:`MAX_AT_RANGE_SHARE` of the
        samples: the fit is then not the specimen's."""
        return any(n > MAX_AT_RANGE_SHARE * self.n_samples for _, n, _ in self.at_range)

    @property
    def linear(self) -> bool:
        """Whether the specimen follows ``f = m a + c v + k x`` with one stiffness
        (:attr:`amplitude_dependence` within :data:`NONLINEAR_TOLERANCE`) and positive
        ``m`` and ``k``, read on a record with no more than :data:`MAX_AT_RANGE_SHARE` of
        its samples at a sensor's range (not :attr:`clipped`)."""
        return (not self.clipped and self.amplitude_dependence <= NONLINEAR_TOLERANCE
                and self.mass_kg > 0 and self.stiffness_N_per_m > 0)

    def verdict(self) -> str:
        """One sentence on the fit: linear, or why its m, c, k are not the specimen's (a
        sensor at its range first: it is the cause of whatever else the fit shows)."""
        if self.clipped:
            clipped = ', '.join(f'its {channel} was at its sensor range ({value:g} '
                                f'{CHANNEL_UNITS[channel]}) in {n} of {self.n_samples} samples'
                                for channel, n, value in self.at_range)
            larger = ' or '.join(f'{SENSOR_NAMES[channel]} of a larger range '
                                 f'({RANGE_PARAMETERS[channel]})'
                                 for channel, _, _ in self.at_range)
            return (f'not the specimen: {clipped}, and the fit reads the clipped readings '
                    f'(m = {self.mass_kg:.4g} kg, c = {self.damping_N_s_per_m:.4g} N s/m, '
                    f"k = {self.stiffness_N_per_m:.4g} N/m are not the specimen's): "
                    f'identify again with a lower excitation_amplitude or {larger}')
        if (self.mass_kg < 0 and self.stiffness_N_per_m < 0 and self.damping_N_s_per_m <= 0
                and self.residual < SIGN_RESIDUAL):
            # m, c and k all negated, and the equation of motion holds: a sign, not a lack of
            # motion (a new user's reversed load cell read 'too little motion'; session 38)
            return (f'not a specimen: the fit gives m = {self.mass_kg:.4g} kg, c = '
                    f'{self.damping_N_s_per_m:.4g} N s/m, k = {self.stiffness_N_per_m:.4g} '
                    f'N/m, all negative, and explains the force within '
                    f'{100 * self.residual:.2g} %: the measured force and the motion have '
                    "opposite signs (the load cell's or a motion sensor's polarity reversed, "
                    'or a sign in its plant model); fix the sign, then identify again')
        if (self.mass_kg <= 0 or self.stiffness_N_per_m <= 0
                or not math.isfinite(self.amplitude_dependence)):
            return (f'not a specimen: the fit gives m = {self.mass_kg:.4g} kg, k = '
                    f'{self.stiffness_N_per_m:.4g} N/m (too little motion in the record?)')
        if not self.linear:
            return (f'not linear: the stiffness is {self.stiffness_small_N_per_m:.4g} N/m over '
                    f'the smallest displacements and {self.stiffness_large_N_per_m:.4g} N/m '
                    f'over the largest (peak {1e3 * self.peak_displacement_m:.3g} mm), '
                    f'{100 * self.amplitude_dependence:.0f} % apart: a member that yields '
                    'has no single m, c, k (identify it at a lower amplitude for its elastic '
                    'stiffness, or use predictor adaptive, which identifies it online)')
        few = ''.join(f'; its {channel} at its sensor range in {n} of {self.n_samples} '
                      f'samples (at most {100 * MAX_AT_RANGE_SHARE:g} % are taken)'
                      for channel, n, _ in self.at_range)
        return (f'linear: f = m a + c v + k x leaves {100 * self.residual:.2g} % of the force '
                f'unexplained; the stiffness is the same over small and large displacements '
                f'(within {100 * self.amplitude_dependence:.2g} %){few}')

    def to_json(self) -> dict[str, Any]:
        """The figures, for ``identification.json``."""
        return {'mass_kg': self.mass_kg, 'damping_N_s_per_m': self.damping_N_s_per_m,
                'stiffness_N_per_m': self.stiffness_N_per_m,
                'standard_errors': {'mass_kg': self.standard_errors[0],
                                    'damping_N_s_per_m': self.standard_errors[1],
                                    'stiffness_N_per_m': self.standard_errors[2]},
                'residual': self.residual, 'band_hz': list(self.band_hz),
                'n_samples': self.n_samples,
                'stiffness_small_N_per_m': self.stiffness_small_N_per_m,
                'stiffness_large_N_per_m': self.stiffness_large_N_per_m,
                'amplitude_dependence': self.amplitude_dependence,
                'peak_displacement_m': self.peak_displacement_m,
                'peak_force_N': self.peak_force_N, 'linear': self.linear,
                'clipped': self.clipped,
                'at_range': {channel: {'samples': n, 'range': value}
                             for channel, n, value in self.at_range},
                'verdict': self.verdict()}


def _least_squares(force, columns, noise_ms=None):
    """``theta`` of ``force ~ columns @ theta`` (columns scaled to unit RMS first); with
    `noise_ms` (each column's noise mean square, shape (3,)) the normal equations less the
    noise's share, ``(X^T X - n diag(noise_ms)) theta = X^T f`` (errors in variables)."""
    scale = np.sqrt(np.mean(columns ** 2, axis=0))
    scale[scale == 0] = 1.0
    xs = columns / scale
    if noise_ms is None:
        theta = np.linalg.lstsq(xs, force, rcond=None)[0]
    else:
        gram = xs.T @ xs - xs.shape[0] * np.diag(np.asarray(noise_ms) / scale ** 2)
        theta = np.linalg.solve(gram, xs.T @ force)
    return theta / scale


#: A column's noise mean square below this fraction of its own is a noise-free record's
#: rounding (:func:`fit_specimen`'s ``motion_noise``) [-].
NOISE_FLOOR = 1e-8


def _band_noise(sos, motion_noise, columns, n: int, pre: str):
    """The band-passed `motion_noise` (shape (n, 3)), its columns below :data:`NOISE_FLOOR`
    of `columns`' mean squares zeroed; None without noise or when every column is below."""
    if motion_noise is None:
        return None
    noise = np.asarray(motion_noise, dtype=float)
    if noise.shape != (n, 3) or not np.all(np.isfinite(noise)):
        raise InputError(f'{pre}motion noise of shape {noise.shape}; expected ({n}, 3) finite '
                         'samples (acceleration, velocity, displacement)')
    noise = np.column_stack([signal.sosfiltfilt(sos, noise[:, j]) for j in range(3)])
    material = np.mean(noise ** 2, axis=0) > NOISE_FLOOR * np.mean(columns ** 2, axis=0)
    if not material.any():
        return None
    return noise * material


def fit_specimen(force_N, displacement_m, velocity_m_s, acceleration_m_s2, dt: float, *,
                 band_hz=None, parts: int = FIT_PARTS, where: str = '',
                 ranges: SensorRanges | None = None,
                 motion_noise=None) -> SpecimenFit:
    """Fit ``f = m a + c v + k x`` (paper Eq. 5.1) to a rig's measured force and motion.

    Parameters
    ----------
    force_N, displacement_m, velocity_m_s, acceleration_m_s2 : array_like, shape (n,)
        The rig's measured force f [N] and the specimen's displacement x [m], velocity v
        [m/s] and acceleration a [m/s^2] relative to the ground, sampled at ``k*dt``.
    dt : float > 0
        Sample period [s].
    band_hz : (float, float), optional
        Band of the band-pass [Hz] (an identification run: its excitation band). Default
        0.2 Hz to 0.8 times the Nyquist frequency.
    parts : int >= 2
        Consecutive parts of the record fitted apart for the standard errors.
    where : str
        Prefix of the error messages (the bag and rig).
    ranges : SensorRanges, optional
        The rig's sensor ranges (``SensorRanges.from_parameters`` of its parameters): the
        samples whose reading is at a range (``|y| >= AT_RANGE_FRACTION * range``) are
        counted into ``SpecimenFit.at_range``, and such a fit is not
        :attr:`~SpecimenFit.linear`. Default: none counted.
    motion_noise : array_like, shape (n, 3), optional
        The noise of the measured acceleration [m/s^2], velocity [m/s] and displacement [m]
        (a record of it: the output-error residuals of the plant identified from the same
        run, ``seft identify``): its band-passed mean squares are taken out of the normal
        equations (Notes). Default: none (the plain least squares).

    Returns
    -------
    SpecimenFit

    Raises
    ------
    InputError
        Signals of different lengths, not finite, or too short (fewer than
        :data:`MIN_PART_SAMPLES` samples per part).
    ParameterError
        A band not within (0, Nyquist).

    Notes
    -----
    Every signal is filtered by one zero-phase Butterworth band-pass of order
    :data:`FILTER_ORDER` (``scipy.signal.butter``, ``sosfiltfilt``): a linear
    time-invariant filter applied alike keeps ``f = m a + c v + k x`` exact (its padding and
    initial conditions are linear in each signal too), and it takes the sensors' offsets and
    their noise outside the excitation's band out of the fit. Then ``[a, v, x] theta = f``
    by linear least squares (``numpy.linalg.lstsq``, the columns scaled to unit RMS).

    The standard errors are the spread of the fits on `parts` consecutive parts over
    ``sqrt(parts)``: unlike ``sigma^2 (X^T X)^-1`` they do not take the filtered, hence
    correlated, residual as white. Neither covers the bias of noise on the regressors
    (errors in variables: noise on x, v, a pulls k, c, m towards 0 by about the noise's
    share of each signal's variance in the band; measured with the noise set of
    ``benchmarks/robust_compensation.py`` at 100 N of excitation: k 0.2 % low, c 0.4 %,
    m 0.2 %). With `motion_noise` that bias is taken out: the noise's band-passed mean
    square ``s_j`` of each column leaves the normal equations,
    ``(X^T X - n diag(s)) theta = X^T f`` (the bias-compensated least squares of errors in
    variables, sensors' noises independent of each other and of the motion: Fuller 1987,
    Sec. 1.2; Soderstrom 2007, Sec. 5). On the servohydraulic rig of 200 kg, 1.78e6 N/m
    (15 Hz, 3 %) with 10 um, 0.1 mm/s and 0.05 m/s^2 of sensor noise, 20 s of valve noise
    (three noise seeds): k 0.7-0.9 % low and the natural frequency 0.24-0.35 % low without
    it. A column whose noise is below 1e-8 of its mean square (a noise-free record's
    rounding) is taken as noise-free.

    The amplitude check refits the stiffness alone on the restoring force ``f - m a - c v``
    over the samples of the smallest and of the largest displacements: a linear specimen has
    one k, a member that yields is stiffer near ``x = 0`` (its loops) than at its peaks.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 5.1.
    W. A. Fuller, Measurement Error Models, Wiley, 1987, Sec. 1.2.
    T. Soderstrom, Errors-in-variables methods in system identification, Automatica 43(6),
    2007, 939-958.
    S. F. Masri and T. K. Caughey (1979), A nonparametric identification technique for
    nonlinear dynamic problems, J. Appl. Mech. 46(2), 433-447 (the restoring force as the
    measured force less the inertial and damping forces).
    """
    pre = f'{where}: ' if where else ''
    signals = [np.asarray(s, dtype=float) for s in (force_N, acceleration_m_s2, velocity_m_s,
                                                     displacement_m)]
    n = signals[0].shape[0]
    if any(s.ndim != 1 or s.shape[0] != n for s in signals):
        raise InputError(f'{pre}force and motion of different shapes '
                         f'{[s.shape for s in signals]}; expected one length')
    if not all(np.all(np.isfinite(s)) for s in signals):
        raise InputError(f'{pre}the force or motion is not finite (NaN or inf samples)')
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
    parts = int(parts)
    if parts < 2:
        raise ParameterError(f'parts={parts!r}: expected an integer >= 2')
    if n < MIN_PART_SAMPLES * parts:
        raise InputError(f'{pre}{n} samples; expected at least {MIN_PART_SAMPLES * parts} to '
                         'fit the specimen')
    nyquist = 0.5 / dt
    lo, hi = (0.2, 0.8 * nyquist) if band_hz is None else (float(b) for b in band_hz)
    if not 0 < lo < hi < nyquist:
        raise ParameterError(f'band {lo:g}-{hi:g} Hz: expected 0 < low < high < the Nyquist '
                             f'frequency {nyquist:g} Hz')
    sos = signal.butter(FILTER_ORDER, [lo, hi], 'bandpass', fs=1.0 / dt, output='sos')
    f, a, v, x = (signal.sosfiltfilt(sos, s) for s in signals)
    columns = np.column_stack([a, v, x])
    noise = _band_noise(sos, motion_noise, columns, n, pre)
    theta = _least_squares(f, columns, None if noise is None else np.mean(noise ** 2, axis=0))
    rms_f = float(np.sqrt(np.mean(f ** 2)))
    residual = float(np.sqrt(np.mean((f - columns @ theta) ** 2)) / rms_f) if rms_f > 0 \
        else math.nan
    size = n // parts
    estimates = np.array([_least_squares(
        f[i * size:(i + 1) * size], columns[i * size:(i + 1) * size],
        None if noise is None else np.mean(noise[i * size:(i + 1) * size] ** 2, axis=0))
        for i in range(parts)])
    errors = tuple(float(e) for e in np.std(estimates, axis=0, ddof=1) / math.sqrt(parts))
    restoring = f - theta[0] * a - theta[1] * v
    magnitude = np.abs(x)
    small = magnitude <= np.quantile(magnitude, SMALL_QUANTILE)
    large = magnitude >= np.quantile(magnitude, LARGE_QUANTILE)

    def stiffness(mask):
        xs = x[mask]
        den = float(np.dot(xs, xs))
        return float(np.dot(restoring[mask], xs)) / den if den > 0 else math.nan

    at_range = []
    if ranges is not None:
        recorded = dict(zip(('force', 'acceleration', 'velocity', 'displacement'), signals))
        for channel, threshold in zip(CHANNELS, ranges.thresholds):
            count = int(np.count_nonzero(np.abs(recorded[channel]) >= threshold))
            if count:
                at_range.append((channel, count, float(ranges.range_of(channel))))
    return SpecimenFit(float(theta[0]), float(theta[1]), float(theta[2]), errors, residual,
                       (lo, hi), int(n), stiffness(small), stiffness(large),
                       float(np.max(np.abs(signals[3]))), float(np.max(np.abs(signals[0]))),
                       tuple(at_range))
