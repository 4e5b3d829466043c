"""Identify the rig from the bags of identification runs (``seft identify``; no rclpy).

Not the online identification of the ``adaptive`` compensator (``seft_ros.core.
identification``): this is what a test engineer measures before a test, from whole records.

- :func:`h1_estimate`: the H1 frequency-response estimate ``H1 = P_xy/P_xx`` with Welch
  averaging (``scipy.signal.csd``, ``welch``, ``coherence``), window, segment length and
  overlap as options.
- :func:`fit_rational`: a discrete rational transfer function ``B(z^-1)/A(z^-1)`` fitted to
  a measured response by linear least squares (Levy 1959) refined by Sanathanan-Koerner
  iterations; scipy has no ``invfreqz``.
- :func:`identify_run`: from an open-loop bag (the valve driven by the excitation) the
  valve-to-force response ``H_fu`` (paper Fig. 3a), its control-structure-interaction zero
  and oil-column resonance, and, with the configured force controller, the loop transfer
  function ``L = C H_fu`` with its crossover and margins (Fig. 3c); from a closed-loop bag
  the reference-to-measured-force response (Fig. 4) and the force loop's equivalent delay by
  phase slope and by cross-correlation. Each figure has the value of the rig's known model
  beside it (``seft_plant_sim``; the simulated rig's, or the model a lab configured).
- :func:`identified_parameters`: the identified delay and force-loop model as parameters
  the compensators load (``seft identify --params out.yaml``).
- Every rig's specimen, from its own measured force and motion
  (:func:`~seft_ros.analysis.specimen_identification.fit_specimen`, paper Eq. 5.1), beside
  its force loop. A structure's run is identified rig by rig (:func:`identify_rigs`), and
  :func:`identified_rig_parameters` gives each rig's section of the parameter file: its
  specimen (``predictor_mass_kg``, ``predictor_damping_N_s_per_m``,
  ``predictor_stiffness_N_per_m``) with its delay and force-loop model.
"""

from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from scipy import optimize, signal

from seft_msgs_py.errors import InputError, ParameterError, SeftError
from seft_msgs_py.parameters import identification_run, valve_commanded
from seft_msgs_py.plant import controller_response
from seft_msgs_py.sensor_range import SensorRanges
from seft_ros.analysis.rundata import RunData
from seft_ros.analysis.specimen_identification import (
    FIT_PARTS,
    MIN_PART_SAMPLES,
    SpecimenFit,
    fit_specimen,
)
from seft_ros.core.excitation import excitation_band_hz

__all__ = ['FrequencyResponse', 'RationalFit', 'RunIdentification',
           'h1_estimate', 'fit_rational', 'loop_figures', 'phase_slope_delay_s',
           'xcorr_delay_s', 'identify_run', 'applied_valve_command', 'identified_parameters',
           'identify_rigs', 'identified_rig_parameters', 'specimen_figures', 'fit_hydraulics',
           'HYDRAULIC_FIT',
           'SPECIMEN_PARAMETERS', 'MIN_SPECIMEN_SAMPLES', 'DEFAULT_NPERSEG',
           'DEFAULT_ORDERS_OPEN', 'DEFAULT_ORDERS_CLOSED', 'DELAY_BAND_HZ', 'MIN_COHERENCE']

#: Default Welch segment length [samples] (0.49 Hz resolution at dt = 2 ms).
DEFAULT_NPERSEG = 1024
#: Default orders (nb, na) of the fit of the valve-to-force response: the sampled rig has
#: four states (displacement, velocity, load pressure, spool) and a 1.5-step latency, so
#: ``A`` of order 4 and ``B`` up to z^-6.
DEFAULT_ORDERS_OPEN = (6, 4)
#: Default orders (nb, na) of the fit of the closed force loop (rig 4 + controller 2 states).
DEFAULT_ORDERS_CLOSED = (8, 6)
#: Band of the phase-slope delay [Hz] (as ``seft_plant_sim.servohydraulic.equivalent_delay_s``).
DELAY_BAND_HZ = (1.0, 5.0)
#: Frequencies whose coherence is below this are left out of fits and figures' values.
MIN_COHERENCE = 0.9
#: Fewer samples than this give no specimen fit.
MIN_SPECIMEN_SAMPLES = MIN_PART_SAMPLES * FIT_PARTS
#: The compensators' specimen parameters an identified specimen sets, per
#: :class:`~seft_ros.analysis.specimen_identification.SpecimenFit` attribute.
SPECIMEN_PARAMETERS = {'mass_kg': 'predictor_mass_kg',
                       'damping_N_s_per_m': 'predictor_damping_N_s_per_m',
                       'stiffness_N_per_m': 'predictor_stiffness_N_per_m'}


def _check_nperseg(nperseg, n):
    if isinstance(nperseg, bool) or not isinstance(nperseg, (int, np.integer)) or nperseg < 8:
        raise ParameterError(f'option nperseg={nperseg!r}: expected an integer >= 8')
    if nperseg > n:
        raise ParameterError(f'option nperseg={nperseg}: expected at most the record length '
                             f'({n} samples)')


@dataclass(frozen=True)
class FrequencyResponse:
    """A measured frequency response with its coherence.

    Attributes
    ----------
    freqs_hz : ndarray, shape (nf,)
        Frequencies [Hz], 0 to Nyquist.
    response : ndarray of complex, shape (nf,)
        ``H1(f) = P_xy(f)/P_xx(f)`` [output unit / input unit].
    coherence : ndarray, shape (nf,)
        Magnitude-squared coherence ``|P_xy|^2/(P_xx P_yy)`` in [0, 1].
    dt : float
        Sample period [s].
    window : str
    nperseg, noverlap : int
        The Welch settings used.
    n_segments : int
        Number of averaged segments.
    """

    freqs_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    dt: float
    window: str
    nperseg: int
    noverlap: int
    n_segments: int

    def settings(self) -> dict[str, Any]:
        """The estimator's settings, for the JSON."""
        return {'estimator': 'H1 (Welch)', 'window': self.window, 'nperseg': self.nperseg,
                'noverlap': self.noverlap, 'segments': self.n_segments,
                'resolution_hz': 1.0 / (self.nperseg * self.dt)}


def h1_estimate(x, y, dt: float, *, window: str = 'hann', nperseg: int = DEFAULT_NPERSEG,
                noverlap: int | None = None) -> FrequencyResponse:
    """H1 estimate of the response from `x` to `y`, with coherence (Welch averaging).

    Parameters
    ----------
    x, y : array_like, shape (n,)
        Input and output, sampled at ``k*dt``.
    dt : float > 0
        Sample period [s].
    window : str
        Window of each segment (any name ``scipy.signal.get_window`` takes).
    nperseg : int >= 8
        Segment length [samples], at most n.
    noverlap : int, optional
        Overlap of the segments [samples] (default ``nperseg // 2``).

    Returns
    -------
    FrequencyResponse

    Raises
    ------
    ParameterError
        Bad `dt`, window, segment length or overlap, or `x`, `y` of different shapes.

    Notes
    -----
    ``H1 = P_xy/P_xx`` (Bendat and Piersol 2010, Sec. 9.1): unbiased by noise on the output,
    biased low by noise on the input. ``scipy.signal.csd(x, y)`` is ``E[conj(X) Y]``, so the
    ratio is the response from x to y. The random error of ``|H1|`` is about
    ``sqrt(1 - coh)/(sqrt(coh) sqrt(2 n_d))`` with ``n_d`` segments (ibid., Eq. 9.90).

    References
    ----------
    J. S. Bendat and A. G. Piersol, Random Data, 4th ed., Wiley, 2010, Ch. 9.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        raise ParameterError(f'signals of shapes {x.shape} and {y.shape}: expected two 1-D '
                             'arrays of one length')
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
    _check_nperseg(nperseg, x.shape[0])
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if isinstance(noverlap, bool) or not isinstance(noverlap, (int, np.integer)) \
            or not 0 <= noverlap < nperseg:
        raise ParameterError(f'option noverlap={noverlap!r}: expected an integer in '
                             f'[0, nperseg={nperseg})')
    try:
        signal.get_window(window, nperseg)
    except (ValueError, TypeError) as exc:
        raise ParameterError(f'option window={window!r}: expected a window of '
                             f"scipy.signal.get_window, e.g. 'hann', 'hamming', 'boxcar' "
                             f'({str(exc).rstrip("!")})') from None
    fs = 1.0 / dt
    kw = dict(fs=fs, window=window, nperseg=nperseg, noverlap=noverlap, detrend='constant')
    f, pxy = signal.csd(x, y, **kw)
    _, pxx = signal.welch(x, **kw)
    _, coh = signal.coherence(x, y, **kw)
    with np.errstate(divide='ignore', invalid='ignore'):
        h = np.where(pxx > 0, pxy / pxx, np.nan + 0j)
    n_seg = 1 + (x.shape[0] - nperseg) // (nperseg - noverlap)
    return FrequencyResponse(f, h, np.nan_to_num(coh), float(dt), str(window), int(nperseg),
                             int(noverlap), int(n_seg))


@dataclass(frozen=True)
class RationalFit:
    """A discrete transfer function ``B(z^-1)/A(z^-1)`` fitted to a frequency response.

    Attributes
    ----------
    b : ndarray, shape (nb + 1,)
        Numerator in powers of ``z^-1`` (``b[0] z^0 + b[1] z^-1 + ...``).
    a : ndarray, shape (na + 1,)
        Denominator in powers of ``z^-1``, ``a[0] = 1``.
    dt : float
        Sample period [s].
    band_hz : (float, float)
        Band of the fit [Hz].
    error : float
        Relative fit error in the band, ``sqrt(sum w |H - H_fit|^2 / sum w |H|^2)`` with the
        fit's weights (the frequencies of coherence >= :data:`MIN_COHERENCE`).
    """

    b: np.ndarray
    a: np.ndarray
    dt: float
    band_hz: tuple
    error: float

    @property
    def orders(self) -> tuple[int, int]:
        """``(nb, na)``."""
        return len(self.b) - 1, len(self.a) - 1

    def response(self, freqs_hz) -> np.ndarray:
        """``B/A`` at ``z = exp(2j pi f dt)``; shape of `freqs_hz`, complex."""
        zinv = np.exp(-2j * np.pi * np.asarray(freqs_hz, dtype=float) * self.dt)
        return np.polyval(self.b[::-1], zinv) / np.polyval(self.a[::-1], zinv)

    def _modes(self, coefficients) -> list[tuple[float, float]]:
        """``(natural frequency [Hz], damping ratio)`` of the complex roots (upper half) of a
        polynomial in ``z^-1``, mapped to continuous time by ``s = ln(z)/dt``."""
        c = np.trim_zeros(np.asarray(coefficients, dtype=float), 'b')
        if len(c) < 2:
            return []
        roots = np.roots(c)                  # roots in z (the polynomial in z^-1, reversed)
        out = []
        for z in roots:
            if z.imag <= 1e-9 or abs(z) == 0:
                continue
            s = np.log(z) / self.dt
            wn = abs(s)
            out.append((wn / (2 * np.pi), -s.real / wn))
        return sorted(out)

    def pole_modes(self) -> list[tuple[float, float]]:
        """Lightly and heavily damped pole pairs: ``[(f_n [Hz], zeta), ...]`` by frequency."""
        return self._modes(self.a)

    def zero_modes(self) -> list[tuple[float, float]]:
        """Complex zero pairs: ``[(f_n [Hz], zeta), ...]`` by frequency."""
        return self._modes(self.b)

    def to_json(self) -> dict[str, Any]:
        """Coefficients, orders, band and error, for the JSON."""
        return {'b': [float(v) for v in self.b], 'a': [float(v) for v in self.a],
                'dt': self.dt, 'orders': list(self.orders),
                'band_hz': [float(v) for v in self.band_hz], 'fit_error': self.error}


def fit_rational(freqs_hz, response, dt: float, *, orders=DEFAULT_ORDERS_OPEN, weight=None,
                 band_hz=None, iterations: int = 20) -> RationalFit:
    """Fit ``H(z) = B(z^-1)/A(z^-1)`` to a frequency response (Levy, Sanathanan-Koerner).

    Parameters
    ----------
    freqs_hz : array_like, shape (nf,)
        Frequencies [Hz].
    response : array_like of complex, shape (nf,)
        Measured response.
    dt : float > 0
        Sample period [s].
    orders : (int, int)
        ``(nb, na)``: numerator and denominator orders in ``z^-1`` (nb >= 0, na >= 1).
    weight : array_like, shape (nf,), optional
        Non-negative weights (default 1); frequencies of weight 0 are left out.
    band_hz : (float, float), optional
        Only frequencies in this band (default: all but 0 Hz).
    iterations : int >= 0
        Sanathanan-Koerner iterations after the first (Levy) solution.

    Returns
    -------
    RationalFit

    Raises
    ------
    ParameterError
        Bad orders, or fewer weighted frequencies than unknowns.

    Notes
    -----
    Levy's linearisation minimises ``sum w |B(z_k) - H_k A(z_k)|^2`` over the coefficients
    (``a_0 = 1``), a linear least-squares problem in the real and imaginary parts. It weights
    the error by ``|A|``, which over-fits high frequencies; Sanathanan and Koerner divide the
    weights by ``|A_prev(z_k)|^2`` of the previous solution and iterate, which converges to
    the output-error fit ``sum w |H_k - B/A|^2`` for a good start. Poles and zeros map to
    continuous time by ``s = ln(z)/dt`` (exact for the poles of a sampled system).

    References
    ----------
    E. C. Levy, Complex-curve fitting, IRE Trans. Autom. Control AC-4, 1959, 37-43.
    C. K. Sanathanan and J. Koerner, Transfer function synthesis as a ratio of two complex
    polynomials, IEEE Trans. Autom. Control 8(1), 1963, 56-58.
    """
    try:
        nb, na = (int(v) for v in orders)
    except (TypeError, ValueError):
        raise ParameterError(f'option orders={orders!r}: expected two integers (nb, na)') \
            from None
    if nb < 0 or na < 1:
        raise ParameterError(f'option orders={orders!r}: expected nb >= 0 and na >= 1')
    f = np.asarray(freqs_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    w = np.ones_like(f) if weight is None else np.asarray(weight, dtype=float).copy()
    lo, hi = (0.0, np.inf) if band_hz is None else band_hz
    use = (f > 0) & (f >= lo) & (f <= hi) & (w > 0) & np.isfinite(h)
    if 2 * use.sum() < nb + 1 + na:
        raise ParameterError(f'fit of orders ({nb}, {na}): {int(use.sum())} usable frequencies '
                             f'in {lo:g}-{hi:g} Hz; expected at least {(nb + 1 + na + 1) // 2} '
                             '(coherent frequencies in the band)')
    f, h, w = f[use], h[use], w[use]
    zinv = np.exp(-2j * np.pi * f * dt)
    zb = zinv[:, None] ** np.arange(nb + 1)[None, :]
    za = zinv[:, None] ** np.arange(1, na + 1)[None, :]
    m = np.hstack([zb, -h[:, None] * za])
    sk = np.ones_like(f)
    theta = None
    for _ in range(iterations + 1):
        sw = np.sqrt(w * sk)[:, None]
        lhs = np.vstack([(m * sw).real, (m * sw).imag])
        rhs = np.concatenate([(h * sw[:, 0]).real, (h * sw[:, 0]).imag])
        theta = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        a_now = 1.0 + za @ theta[nb + 1:]
        sk = 1.0 / np.maximum(np.abs(a_now) ** 2, 1e-12)
    b = theta[:nb + 1]
    a = np.concatenate([[1.0], theta[nb + 1:]])
    fit = np.polyval(b[::-1], zinv) / np.polyval(a[::-1], zinv)
    err = float(np.sqrt(np.sum(w * np.abs(h - fit) ** 2) / np.sum(w * np.abs(h) ** 2)))
    return RationalFit(b, a, float(dt), (float(f.min()), float(f.max())), err)


def loop_figures(loop, f_min: float, f_max: float, points: int = 4000):
    """Crossover and margins of the loop ``loop(f)`` between `f_min` and `f_max` [Hz]
    (:func:`seft_ros.core.force_design.loop_margins`: a scan of `points` log-spaced
    frequencies refined by Brent's method).

    Parameters
    ----------
    loop : callable(ndarray of float) -> ndarray of complex
        ``L`` at frequencies [Hz].
    f_min, f_max : float > 0
        Scanned band [Hz].
    points : int

    Returns
    -------
    seft_ros.core.force_design.LoopMargins
    """
    from seft_ros.core.force_design import loop_margins
    return loop_margins(loop, f_min, f_max, points)


def phase_slope_delay_s(freqs_hz, response, band_hz=DELAY_BAND_HZ, weight=None) -> float:
    """Equivalent delay ``-d(arg H)/d(omega)`` [s] over a band, weighted least squares.

    Parameters
    ----------
    freqs_hz : array_like, shape (nf,)
    response : array_like of complex, shape (nf,)
    band_hz : (float, float)
        Band [Hz] (at least two frequencies in it).
    weight : array_like, shape (nf,), optional
        Weights (e.g. the coherence).

    Raises
    ------
    ParameterError
        Fewer than two frequencies of positive weight in the band.
    """
    f = np.asarray(freqs_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    w = np.ones_like(f) if weight is None else np.asarray(weight, dtype=float)
    use = (f >= band_hz[0]) & (f <= band_hz[1]) & (w > 0) & np.isfinite(h)
    if use.sum() < 2:
        raise ParameterError(f'delay band {band_hz[0]:g}-{band_hz[1]:g} Hz: expected at least '
                             'two coherent frequencies (longer record or longer segments)')
    phase = np.unwrap(np.angle(h[use]))
    slope = np.polyfit(2 * np.pi * f[use], phase, 1, w=np.sqrt(w[use]))[0]
    return float(-slope)


def xcorr_delay_s(x, y, dt: float, max_lag_s: float = 0.1) -> float:
    """Delay of `y` behind `x` at the peak of their cross-correlation [s].

    The means are removed; lags 0 .. `max_lag_s` (a causal loop does not lead); the peak is
    refined to a fraction of a sample by the parabola through it and its neighbours.
    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    y = np.asarray(y, dtype=float) - np.mean(y)
    n = x.shape[0]
    lags = np.arange(0, min(int(max_lag_s / dt), n - 2) + 1)
    r = np.array([np.dot(y[k:], x[:n - k]) for k in lags])
    i = int(np.argmax(r))
    frac = 0.0
    if 0 < i < len(r) - 1:
        den = r[i - 1] - 2 * r[i] + r[i + 1]
        frac = 0.5 * (r[i - 1] - r[i + 1]) / den if den != 0 else 0.0
    return float((lags[i] + frac) * dt)


def _controller_response(controller, freqs_hz) -> np.ndarray:
    """``C(e^{j w dt})`` [V/N] of a discrete controller with ``bz``, ``az`` (powers of
    ``z^-1``, the ``scipy.signal.lfilter`` convention) and ``dt``."""
    zinv = np.exp(-2j * np.pi * np.asarray(freqs_hz, dtype=float) * float(controller.dt))
    b = np.asarray(controller.bz, dtype=float)
    a = np.asarray(controller.az, dtype=float)
    return np.polyval(b[::-1], zinv) / np.polyval(a[::-1], zinv)


# -- the rig's known model ------------------------------------------------------------------

def _known_model(params):
    """The run's own model of its force loop
    (:func:`~seft_ros.core.force_loop.force_loop_plant`: its ``plant_model``, or seft's rig
    model with the run's specimen; a ``state_space`` rig's ``rig_plant_model`` where given,
    the plant the rig stepped) and its controller: ``(plant, controller)``, or None where the
    rig has none (an actuator seft has no model of, or seft_plant_sim missing)."""
    from seft_ros.core.controller import ForceServoController
    from seft_ros.core.force_loop import force_loop_plant, rig_plant
    try:
        stepped = rig_plant(params)
        if stepped is not None and stepped[0] == 'rig_plant_model':
            # named as the parameter it is (it read 'parameter plant_model'; session 38)
            plant = stepped[1]
            params = dict(params, plant_model=params['rig_plant_model'])
        else:
            plant = force_loop_plant(params)
        return plant, ForceServoController.from_parameters(params)
    except ParameterError:
        return None


def _model_modes(plant) -> tuple[float, float]:
    """``(zero_hz, resonance_hz)`` of a plant model's force response: its control-structure-
    interaction zero (the specimen's natural frequency, or the lightest zero pair) and its
    lightest pole pair above it (the oil column)."""
    from seft_ros.core.force_design import _csi_zero, _resonances
    csi = _csi_zero(plant, None)
    zero = plant.specimen.natural_frequency_hz if plant.specimen is not None else (
        csi[0] if csi else math.nan)
    res = _resonances(plant, (zero if math.isfinite(zero) else 0.0) * 1.15)
    return zero, (res[0][0] if res else math.nan)


def _coherent(fr: FrequencyResponse) -> np.ndarray:
    return np.where(fr.coherence >= MIN_COHERENCE, fr.coherence, 0.0)


def _lightest(modes, lo, hi):
    """The mode of least damping with frequency in [lo, hi] (nan, nan if none)."""
    inside = [m for m in modes if lo <= m[0] <= hi and 0 < m[1] < 0.5]
    return min(inside, key=lambda m: m[1]) if inside else (math.nan, math.nan)


@dataclass
class RunIdentification:
    """What one bag gives (:func:`identify_run`).

    Attributes
    ----------
    source : str
        The bag.
    kind : str
        'open_loop' (valve to force) or 'closed_loop' (reference to measured force).
    response : FrequencyResponse
        The H1 estimate (open loop: V -> N; closed loop: N -> N).
    fit : RationalFit
    model_response : ndarray of complex or None, shape (nf,)
        The rig's known model at ``response.freqs_hz`` (None without seft_plant_sim or for
        an unknown rig).
    loop : ndarray of complex or None, shape (nf,)
        Open loop: the measured ``L = C H1`` with the configured controller.
    loop_fit, loop_model : callable or None
        ``L(f)`` of the fit and of the known model.
    figures : dict
        The JSON figures (see :func:`identify_run`).
    params : dict
        The rig's parameters.
    rig : str
        The rig (``''``: the study's rig in the root namespace).
    specimen : SpecimenFit or None
        The rig's specimen fitted to its measured force and motion.
    plant : PlantFit or None
        Open loop on a valve-driven rig: the force loop's plant identified as data
        (:func:`~seft_ros.analysis.plant_identification.identify_plant`).
    design : ForceLoopDesign or None
        The force controller designed for it
        (:func:`~seft_ros.core.force_design.design_force_controller`).
    restoring : (ndarray, ndarray) or None, each shape (n,)
        The measured displacement [m] and restoring force ``f - m a - c v`` [N] with the
        fit's m and c (unfiltered), for the plot of the specimen.
    """

    source: str
    kind: str
    response: FrequencyResponse
    fit: RationalFit
    model_response: np.ndarray | None
    params: dict
    loop: np.ndarray | None = None
    figures: dict = field(default_factory=dict)
    loop_fit: Any = None
    loop_model: Any = None
    rig: str = ''
    specimen: SpecimenFit | None = None
    restoring: tuple | None = None
    plant: Any = None
    design: Any = None


def identify_run(run: RunData, *, window: str = 'hann', nperseg: int = DEFAULT_NPERSEG,
                 noverlap: int | None = None, orders=None,
                 delay_band_hz=DELAY_BAND_HZ, record_spectrum=None) -> RunIdentification:
    """Identify the rig from one run (a bag read by ``seft_ros.analysis.bag.read_run``).

    Parameters
    ----------
    run : RunData
        An open-loop run (``excitation_input: valve_command``): input the valve command
        [V], output the measured force [N]. Any other run is closed loop: input the
        reference force [N], output the measured force [N].
    window, nperseg, noverlap
        Welch settings (:func:`h1_estimate`).
    orders : (int, int), optional
        Fit orders (default :data:`DEFAULT_ORDERS_OPEN` or :data:`DEFAULT_ORDERS_CLOSED`).
    delay_band_hz : (float, float)
        Band of the phase-slope delay [Hz].
    record_spectrum : callable, optional
        ``params -> (GroundSpectrum or None, note)``, the spectrum of the record the test
        plays for the force-loop design of an open-loop run (default
        :func:`~seft_ros.core.force_design.played_record_spectrum`; :func:`identify_rigs`
        passes one that reads the record once for all the run's rigs).

    Returns
    -------
    RunIdentification
        ``figures``: open loop ``zero_hz``, ``resonance_hz`` (natural frequencies of the
        least-damped complex zero pair above 1 Hz and pole pair of the fit, by ``s =
        ln(z)/dt``), ``zero_damping``, ``resonance_damping`` and, with the configured force
        controller, ``crossover_hz``, ``phase_margin_deg``, ``gain_margin``,
        ``phase_crossover_hz`` of ``L = C(z) H_fit(z)``; closed loop ``delay_ms`` (phase
        slope of H1 over `delay_band_hz`, coherence-weighted) and ``delay_xcorr_ms``
        (cross-correlation peak of the reference and measured force), ``magnitude_min``,
        ``magnitude_max`` (``|H1|`` from 0.5 to 25 Hz, the band of Fig. 4). Every figure also
        under ``model`` from the rig's known model (``seft_plant_sim.servohydraulic``:
        ``valve_to_force``, ``loop_margins``, ``equivalent_delay_s``; the delay rig: tau_s).
        ``specimen``: the rig's specimen (:func:`specimen_figures`; none for a run of fewer
        than :data:`MIN_SPECIMEN_SAMPLES` samples).

    Raises
    ------
    InputError
        The run has several rigs (:func:`identify_rigs`), no valve command where one is
        needed, or is too short for `nperseg`.
    ParameterError
        Bad estimator options.
    """
    p = run.params
    dt = float(p['dt'])
    src = run.source
    if len(run.rigs) != 1:
        raise InputError(f'{src}: a run of {len(run.rigs)} rigs ({", ".join(run.rigs)}); '
                         'identify_rigs identifies each')
    rig = run.rig_names[0]
    open_loop = identification_run(p) and \
        p.get('excitation_input') == 'valve_command'
    servo = valve_commanded(p)
    if run.n_steps < 8:
        raise InputError(f'{src}: {run.n_steps} samples; expected a longer run to identify')
    late = 0
    if open_loop:
        if run.valve_command_V is None:
            raise InputError(f'{src}: open-loop run without /seft/valve_command')
        x, late = applied_valve_command(run)
        kind = 'open_loop'
    else:
        x, kind = run.reference_force_N, 'closed_loop'
    y = run.measured_force_N
    try:
        fr = h1_estimate(x, y, dt, window=window, nperseg=nperseg, noverlap=noverlap)
    except ParameterError as exc:
        raise ParameterError(f'{src}: {exc}') from None
    if orders is None:
        orders = DEFAULT_ORDERS_OPEN if open_loop else DEFAULT_ORDERS_CLOSED
    weight = _coherent(fr)
    nyq = 0.5 / dt
    band = (float(fr.freqs_hz[1]), 0.9 * nyq)
    lo_exc, hi_exc = (excitation_band_hz(p) if identification_run(p)
                      else (0.0, nyq))
    band = (max(band[0], lo_exc), min(band[1], hi_exc))
    try:
        fit = fit_rational(fr.freqs_hz, fr.response, dt, orders=orders, weight=weight,
                           band_hz=band)
    except ParameterError as exc:
        raise ParameterError(f'{src}: {exc}') from None
    known = _known_model(p) if servo else None
    ident = RunIdentification(src, kind, fr, fit, None, dict(p), rig=rig)
    if run.n_steps >= MIN_SPECIMEN_SAMPLES:         # else no specimen (a short H1 run)
        specimen = fit_specimen(run.measured_force_N, run.displacement_m, run.velocity_m_s,
                                run.acceleration_m_s2, dt, band_hz=_specimen_band(p),
                                where=f'{src}: rig {rig}' if rig else src,
                                ranges=SensorRanges.from_parameters(p))
        ident.specimen = specimen
        ident.restoring = (run.displacement_m, run.measured_force_N
                           - specimen.mass_kg * run.acceleration_m_s2
                           - specimen.damping_N_s_per_m * run.velocity_m_s)
    figs: dict[str, Any] = {'fit': fit.to_json(), 'estimator': fr.settings(),
                            'late_commands': late,
                            'coherence_mean_in_band': float(np.mean(fr.coherence[
                                (fr.freqs_hz >= band[0]) & (fr.freqs_hz <= band[1])]))}
    model: dict[str, Any] = {}
    f = fr.freqs_hz
    if open_loop:
        z = _lightest(fit.zero_modes(), max(1.0, band[0]), band[1])
        r = _lightest(fit.pole_modes(), max(1.0, band[0]), band[1])
        figs.update(zero_hz=z[0], zero_damping=z[1], resonance_hz=r[0], resonance_damping=r[1])
        from seft_ros.core.controller import ForceServoController
        ctrl = ForceServoController.from_parameters(p)
        ident.loop = _controller_response(ctrl, f) * fr.response
        ident.loop_fit = lambda ff: _controller_response(ctrl, ff) * fit.response(ff)
        lf = loop_figures(ident.loop_fit, max(0.1, band[0]), band[1])
        figs.update(lf.to_json())
        if known is not None:
            plant = known[0]
            ident.model_response = np.concatenate([[np.nan], plant.frequency_response(f[1:])])
            zm, rm = _model_modes(plant)
            ident.loop_model = (lambda ff, plant=plant: _controller_response(ctrl, ff)
                                * plant.frequency_response(ff))
            model.update(zero_hz=zm, resonance_hz=rm, source=plant.source,
                         **loop_figures(ident.loop_model, max(0.1, band[0]), band[1]).to_json())
        if servo and ident.specimen is not None and ident.specimen.linear:
            _identify_plant(ident, run, figs, record_spectrum, x)
    else:
        coh = weight
        figs['delay_ms'] = 1e3 * phase_slope_delay_s(f, fr.response, delay_band_hz, coh)
        figs['delay_xcorr_ms'] = 1e3 * xcorr_delay_s(x, y, dt)
        fig4 = (f >= 0.5) & (f <= 25.0) & (coh > 0)
        if fig4.any():
            figs['magnitude_min'] = float(np.min(np.abs(fr.response[fig4])))
            figs['magnitude_max'] = float(np.max(np.abs(fr.response[fig4])))
        if known is not None:
            plant, ctrl = known
            loop = controller_response(ctrl, f[1:]) * plant.frequency_response(f[1:])
            resp = np.concatenate([[np.nan], loop / (1.0 + loop)])
            ident.model_response = resp
            model['delay_ms'] = 1e3 * phase_slope_delay_s(f, resp, delay_band_hz)
            model['source'] = plant.source
        elif p.get('rig_model') == 'delay':
            tau = float(p['tau_s'])
            ident.model_response = np.exp(-2j * np.pi * f * tau)
            model['delay_ms'] = 1e3 * tau
    figs['model'] = model
    if ident.specimen is not None:
        figs['specimen'] = specimen_figures(ident.specimen, p)
    ident.figures = figs
    return ident


def applied_valve_command(run: RunData) -> tuple[np.ndarray, int]:
    """The valve command the rig applied over each step of a run of one rig, and how many
    commands reached it late (or never).

    In lockstep, in real time with every command in time, and with ``realtime_output:
    on_arrival`` (commands act as they arrive), it is the command sent
    (``run.valve_command_V``). A late command in real time held the previous one longer:
    the rig's timing records (``loop_latency_s`` of each sample) give when each arrived, and
    :func:`~seft_plant_sim.realtime.applied_commands` what acted over each step.

    Raises
    ------
    InputError
        The run has no valve command.
    """
    from seft_plant_sim.realtime import applied_commands, valve_latch_offset_s
    u = run.valve_command_V
    if u is None:
        raise InputError(f'{run.source}: no /seft/valve_command')
    rig = run.rig_names[0]
    timing = (run.extra.get('timing_data') or {}).get(f'{rig}/rig' if rig else 'rig')
    if (timing is None or timing.n == 0
            or run.params.get('realtime_output', 'latched') != 'latched'):
        # lockstep, or commands that act on arrival (no step they hold: the loop's delay is
        # the graph's latency itself, and the fit reads the commands sent)
        return np.asarray(u, dtype=float), 0
    offset = valve_latch_offset_s(run.params)
    dt = float(run.params['dt'])
    latency = np.full(u.size, offset)        # a step without a record: taken as in time
    inside = (timing.step >= 0) & (timing.step < u.size)
    latency[timing.step[inside]] = timing.loop_latency_s[inside]
    return applied_commands(u, latency, dt, offset)


def _identify_plant(ident: RunIdentification, run: RunData, figs: dict,
                    record_spectrum=None, command=None) -> None:
    """The plant as data and its designed controller, into `ident` and its figures
    (an open-loop run of a valve-driven rig with a linear specimen), from `command` (the
    valve command the rig applied, :func:`applied_valve_command`; default the one sent);
    the force-loop inverse ranked for the record the run's configuration names (the lab's
    path runs the test's configuration with an excitation)."""
    from seft_msgs_py.plant import Specimen
    from seft_ros.analysis.plant_identification import identify_plant
    from seft_ros.core.force_design import (
        design_force_controller,
        played_record_spectrum,
        valve_polarity,
    )
    def specimen_of(sf):
        se_m, _, se_k = sf.standard_errors
        return (Specimen(sf.mass_kg, sf.damping_N_s_per_m, sf.stiffness_N_per_m),
                0.5 * math.hypot(se_k / sf.stiffness_N_per_m, se_m / sf.mass_kg))

    spec, sigma_f = specimen_of(ident.specimen)
    y = np.column_stack([run.measured_force_N, run.displacement_m, run.velocity_m_s,
                         run.acceleration_m_s2])
    where = f'{run.source}: rig {ident.rig}' if ident.rig else run.source
    if command is None:
        command = run.valve_command_V
    ident.plant = identify_plant(command, y, float(run.params['dt']),
                                 specimen=spec, frequency_uncertainty=sigma_f, source=where)
    # the specimen again, the sensors' noise (the plant's output-error residuals: the
    # command is exact) out of its regressors (errors in variables: noise pulled k 0.7-0.9 %
    # low on a 15 Hz specimen, and adaptive's law calibrated there erred 16 % at alpha 1)
    noise = ident.plant.residuals(command, y)[:, [3, 2, 1]]
    sf = fit_specimen(run.measured_force_N, run.displacement_m, run.velocity_m_s,
                      run.acceleration_m_s2, float(run.params['dt']),
                      band_hz=_specimen_band(run.params), where=where,
                      ranges=SensorRanges.from_parameters(run.params), motion_noise=noise)
    if sf != ident.specimen and sf.linear:
        ident.specimen = sf
        ident.restoring = (run.displacement_m, run.measured_force_N
                           - sf.mass_kg * run.acceleration_m_s2
                           - sf.damping_N_s_per_m * run.velocity_m_s)
        ident.plant.with_specimen(*specimen_of(sf))
    ident.plant.with_specimen_force(command, y, _half_errors(run, noise, where)
                                    or ident.specimen.standard_errors)
    spectrum, note = (record_spectrum or played_record_spectrum)(run.params)
    ident.design = design_force_controller(ident.plant.model, ground_spectrum=spectrum,
                                           plant_gain_margin=True)
    if note:
        ident.design.notes.append(note)
    figs['plant'] = dict(ident.plant.to_json(), polarity=valve_polarity(ident.plant.model))
    figs['design'] = ident.design.to_json()


def _half_errors(run: RunData, motion_noise: np.ndarray, where: str) -> tuple | None:
    """The specimen fit's errors of m, c and k [kg, N s/m, N/m] read on the record's halves
    (half the difference of their fits): the fit's own standard errors overstated them
    4-17 times on an actuator with a noisy load cell (2 Hz, 0.5 % specimen, 0.1 N: k 5 N/m
    off, its standard error 21 N/m). None where a half gives no linear fit (a record too
    short for it: 10 s halves of that record were not)."""
    half = run.n_steps // 2
    fits = []
    for part in (slice(0, half), slice(half, None)):
        try:
            fits.append(fit_specimen(
                run.measured_force_N[part], run.displacement_m[part], run.velocity_m_s[part],
                run.acceleration_m_s2[part], float(run.params['dt']),
                band_hz=_specimen_band(run.params), where=where,
                ranges=SensorRanges.from_parameters(run.params),
                motion_noise=motion_noise[part]))
        except (InputError, ParameterError):
            return None
    if not all(f.linear for f in fits):
        return None
    return tuple(abs(getattr(fits[0], k) - getattr(fits[1], k)) / 2.0
                 for k in SPECIMEN_PARAMETERS)


def _specimen_band(params) -> tuple[float, float] | None:
    """The band of the specimen fit: the excitation's, or None (the fit's default)."""
    if not identification_run(params):
        return None
    return excitation_band_hz(params)


def specimen_figures(fit: SpecimenFit, params) -> dict[str, Any]:
    """The JSON of a rig's identified specimen beside what the run declared.

    Returns
    -------
    dict
        :meth:`~seft_ros.analysis.specimen_identification.SpecimenFit.to_json`, with
        ``model``: the rig's specimen as configured (``mass_kg``, ``damping_N_s_per_m``,
        ``stiffness_N_per_m``: on the simulated rig the true one), and ``declared``: the
        compensators' model of it (``predictor_*``, 0 meaning the rig's).
    """
    model = {k: float(params[k]) for k in SPECIMEN_PARAMETERS}
    declared = {k: float(params.get(name, 0.0)) or model[k]
                for k, name in SPECIMEN_PARAMETERS.items()}
    own = _plant_specimen(params)
    if own is not None:          # a state_space rig steps its plant's specimen, not these
        model = {'mass_kg': own.mass_kg, 'damping_N_s_per_m': own.damping_N_s_per_m,
                 'stiffness_N_per_m': own.stiffness_N_per_m}
    return dict(fit.to_json(), model=model, declared=declared)


def _plant_specimen(params):
    """The specimen inside the plant a ``state_space`` rig steps (its ``rig_plant_model``,
    else ``plant_model``), or None (another rig, a plant without one, one that does not
    parse: the run said why)."""
    from seft_ros.core.force_loop import rig_plant
    try:
        stepped = rig_plant(params)
    except (SeftError, ValueError):
        return None
    return stepped[1].specimen if stepped is not None else None


def identify_rigs(run: RunData, **options) -> list[RunIdentification]:
    """Identify every rig of a run from its own signals (:func:`identify_run` per rig).

    Parameters
    ----------
    run : RunData
        A run of one rig or of a structure (each rig's parameters and signals its own).
    **options
        As :func:`identify_run`.

    Returns
    -------
    list of RunIdentification
        One per rig, in the structure's order (``rig`` set).

    Raises
    ------
    InputError, ParameterError
        As :func:`identify_run` (the message names the bag and the rig).
    """
    if len(run.rigs) == 1:
        return [identify_run(run, **options)]
    once: dict[str, tuple] = {}         # one record, one test: read it once for all rigs

    def record_spectrum(params):
        if 'spectrum' not in once:
            from seft_ros.core.force_design import played_record_spectrum
            once['spectrum'] = played_record_spectrum(params)
        return once['spectrum']

    options.setdefault('record_spectrum', record_spectrum)
    out = []
    for name in run.rig_names:
        try:
            out.append(identify_run(run.rig_view(name), **options))
        except (InputError, ParameterError) as exc:
            text = str(exc)
            if not text.startswith(f'{run.source}: rig {name}'):
                text = text.replace(f'{run.source}: ', f'{run.source}: rig {name}: ', 1) \
                    if text.startswith(f'{run.source}: ') else f'rig {name}: {text}'
            raise type(exc)(text) from None
    return out


def identified_parameters(runs: list[RunIdentification], *,
                          specimen: tuple[float, float, float] | None = None) -> dict[str, Any]:
    """The identified delay and force-loop model as parameters the compensators load.

    Parameters
    ----------
    runs : list of RunIdentification
        One rig's.
    specimen : (float, float, float), optional
        The rig's identified specimen ``(m [kg], c [N s/m], k [N/m])``. Not used: the plant
        model is identified with each open-loop run's own specimen fit
        (``RunIdentification.specimen``, written as ``plant_model.specimen``); the grey-box
        fit of seft's rig parameters that took it is :func:`fit_hydraulics`, which this
        function no longer writes.

    Returns
    -------
    dict
        ``predictor_tau_s`` [s] (the closed-loop phase-slope delay, mean over the closed-loop
        runs): the actuator delay of every compensator on the delay rig, the delay of
        ``polynomial`` and ``ats`` and the prior of ``adaptive``. From an open-loop run of a
        valve-driven rig: the force loop's plant as data (``plant_model``,
        :func:`~seft_ros.analysis.plant_identification.identify_plant`) and the force
        controller designed for it with its compensators' settings
        (:meth:`~seft_ros.core.force_design.ForceLoopDesign.parameters`: ``force_controller``
        'transfer_function', ``force_controller_tf``, ``predictor_loop_*``,
        ``predictor_calibration``, and ``predictor_tau_s``, the designed loop's delay, which
        replaces the measured one of the old controller). Keys starting with '_' are notes:
        ``_plant`` (the plant's order, delay and fit; or, for an open-loop run of a
        valve-driven rig that gave none, ``'not identified ...'`` and why: its specimen fit's
        verdict, e.g. a sensor at its range), ``_design`` (the design's summary; ``'NOT
        written ...'`` and why when it closes no stable loop on the model, or when the model
        misses the measured force by more than ``MAX_PLANT_MISFIT``
        (:mod:`seft_ros.core.stability`) NRMS: the level above which the
        stability guard trusts no verdict of it, and a design on it is not the rig's).
        Empty if nothing was identified.
    """
    from seft_ros.core.stability import MAX_PLANT_MISFIT
    out: dict[str, Any] = {}
    delays = [r.figures['delay_ms'] for r in runs
              if r.kind == 'closed_loop' and math.isfinite(r.figures.get('delay_ms', math.nan))]
    if delays:
        out['predictor_tau_s'] = float(np.mean(delays)) * 1e-3
    for r in runs:
        if r.kind == 'open_loop' and r.plant is not None:
            out['plant_model'] = r.plant.mapping()
            misfit = r.plant.nrms['force_N']
            out['_plant'] = (f'order {r.plant.order}, delay {r.plant.delay_steps} steps, force '
                             f'NRMS {100 * misfit:.2g} %')
            free = r.plant.free_force_nrms
            if free is not None:
                err = r.plant.force_errors
                out['_plant'] += (f" (the specimen's force on the modelled motion: near its "
                                  f"frequency {100 * err['specimen']:.2g} % off on the "
                                  f"record's halves, the force's own fit {100 * err['own']:.2g} "
                                  f'%; its own fit NRMS {100 * free:.2g} %)')
            if not misfit <= MAX_PLANT_MISFIT:
                out['_design'] = (f'NOT written: the plant model misses the measured force by '
                                  f'{100 * misfit:.2g} % NRMS, above '
                                  f'{100 * MAX_PLANT_MISFIT:g} % (MAX_PLANT_MISFIT, the level '
                                  'above which the stability guard gives its runs no verdict): '
                                  'the actuator is not linear at this level (friction, valve '
                                  'flow), and a controller designed on this model is not '
                                  "the rig's; identify it again at the test's level, or enter "
                                  "the lab's own controller (force_controller_tf) and rehearse "
                                  'it on the rig at a low amplitude')
                break
            if not r.design.stable:
                out['_design'] = ("NOT written: no controller of seft's design closes a "
                                  'stable force loop on this model (' + '; '.join(r.design.notes)
                                  + "); enter the lab's own (force_controller_tf) and check it "
                                  'with seft design')
                break
            out.update(r.design.parameters())
            out['_design'] = r.design.summary() + ('' if r.design.met else ' (targets NOT met: '
                                                   + '; '.join(r.design.notes) + ')')
            break
        if (r.kind == 'open_loop' and r.plant is None and valve_commanded(r.params)
                and '_plant' not in out):
            why = (f'the specimen fit it needs is {r.specimen.verdict()}'
                   if r.specimen is not None
                   else f'the run is too short for the specimen fit the plant model needs '
                   f'({MIN_SPECIMEN_SAMPLES} samples at least)')
            out['_plant'] = f'not identified from {r.source}: {why}'
    return out


def identified_rig_parameters(runs: list[RunIdentification]) -> dict[str, dict[str, Any]]:
    """Each rig's identified specimen, delay and force-loop model: the ``rigs`` sections of
    a structure's parameter file.

    Parameters
    ----------
    runs : list of RunIdentification
        Any rigs' (:func:`identify_rigs` of each bag).

    Returns
    -------
    dict of str to dict
        Rig -> its parameters, in the order the rigs first appear: the specimen
        (:data:`SPECIMEN_PARAMETERS`: the mean of the rig's fits, if every one is linear;
        ``_specimen_residual``, the largest relative residual, as a note), then
        :func:`identified_parameters` with that specimen in the force-loop model. A rig
        whose specimen is not linear gets no m, c, k, and the reason under ``_specimen``.
        Keys starting with ``'_'`` are notes, not parameters.
    """
    by_rig: dict[str, list[RunIdentification]] = {}
    for r in runs:
        by_rig.setdefault(r.rig, []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for rig, own in by_rig.items():
        fits = [r.specimen for r in own if r.specimen is not None]
        values: dict[str, Any] = {}
        specimen = None
        if fits and all(f.linear for f in fits):
            specimen = tuple(float(np.mean([getattr(f, k) for f in fits]))
                             for k in SPECIMEN_PARAMETERS)
            values.update(zip(SPECIMEN_PARAMETERS.values(), specimen))
            values['_specimen_residual'] = max(f.residual for f in fits)
        elif fits:
            bad = next(f for f in fits if not f.linear)
            values['_specimen'] = f'm, c, k not written: {bad.verdict()}'
        values.update(identified_parameters(own, specimen=specimen))
        out[rig] = values
    return out


#: Parameters of the grey-box fit of ``fit_hydraulics``, in order.
HYDRAULIC_FIT = ('valve_flow_gain_m3_per_s_V', 'actuator_volume_m3',
                 'valve_pressure_coefficient_m3_per_s_Pa', 'valve_time_constant_s',
                 'io_latency_s')


def fit_hydraulics(run: RunIdentification, *,
                   specimen: tuple[float, float, float] | None = None) -> dict[str, float]:
    """Fit the servohydraulic rig's physical parameters to a measured ``H_fu``.

    The model is the sampled rig of ``seft_plant_sim.servohydraulic.sample`` (valve,
    compressible oil column, specimen, I/O latency, zero-order hold) with the run's specimen
    (m, c, k; or `specimen`, the identified ``(m [kg], c [N s/m], k [N/m])``: the zero of
    ``H_fu`` is the specimen's) and the configured piston area A (``H_fu`` depends on
    ``k_q/A``, ``C_h/A^2`` and ``K/A^2`` only, so A is not identifiable apart from them: the
    lab knows it); fitted (nonlinear least squares, ``scipy.optimize.least_squares`` on the
    log of each, from the configured values) are the valve flow gain k_q, the hydraulic
    capacitance ``C_h = V_t/(4 beta)`` (written as ``actuator_volume_m3`` at the
    configured bulk modulus: only their ratio is identifiable), the total flow-pressure
    coefficient ``K = K_c + C_l`` (written as ``valve_pressure_coefficient_m3_per_s_Pa`` at
    the configured leakage C_l, at least 0), the spool time constant and the I/O latency, on
    the coherent frequencies of the fit band, relative complex error.

    Returns
    -------
    dict
        :data:`HYDRAULIC_FIT` names with the fitted values, and ``'_fit_error'`` (relative
        RMS complex error); empty without seft_plant_sim.
    """
    try:
        from seft_plant_sim.servohydraulic import ServoHydraulicParams, sample
        from seft_plant_sim.specimen import LinearSpecimen
    except ImportError:
        return {}
    import dataclasses
    p = run.params
    fr = run.response
    dt = fr.dt
    spec = LinearSpecimen(*(specimen if specimen is not None else (
        float(p['mass_kg']), float(p['damping_N_s_per_m']), float(p['stiffness_N_per_m']))))
    base = ServoHydraulicParams.from_parameters(p)
    lo, hi = run.fit.band_hz
    use = (fr.freqs_hz >= lo) & (fr.freqs_hz <= hi) & (fr.coherence >= MIN_COHERENCE)
    f, h = fr.freqs_hz[use], fr.response[use]
    beta = base.oil_bulk_modulus_Pa
    leak = base.leakage_coefficient_m3_per_s_Pa
    area = base.piston_area_m2
    x0 = np.log([base.valve_flow_gain_m3_per_s_V,
                 base.hydraulic_capacitance_m3_per_Pa, base.total_flow_pressure_coefficient,
                 base.valve_time_constant_s, max(base.io_latency_s, 1e-4)])

    def model(theta):
        kq, ch, kk, tv, tio = np.exp(theta)
        hp = dataclasses.replace(base, piston_area_m2=area, valve_flow_gain_m3_per_s_V=kq,
                                 actuator_volume_m3=4 * beta * ch,
                                 valve_pressure_coefficient_m3_per_s_Pa=max(kk - leak, 0.0),
                                 leakage_coefficient_m3_per_s_Pa=min(leak, kk),
                                 valve_time_constant_s=tv, io_latency_s=tio)
        return hp, sample(hp, spec, dt).frequency_response(f, 0)

    def residual(theta):
        r = (model(theta)[1] - h) / np.abs(h)
        return np.concatenate([r.real, r.imag])

    sol = optimize.least_squares(residual, x0, method='lm', x_scale=1.0, max_nfev=400)
    hp, fit = model(sol.x)
    err = float(np.sqrt(np.mean(np.abs((fit - h) / h) ** 2)))
    return {'valve_flow_gain_m3_per_s_V': hp.valve_flow_gain_m3_per_s_V,
            'actuator_volume_m3': hp.actuator_volume_m3,
            'valve_pressure_coefficient_m3_per_s_Pa': hp.valve_pressure_coefficient_m3_per_s_Pa,
            'valve_time_constant_s': hp.valve_time_constant_s,
            'io_latency_s': hp.io_latency_s, '_fit_error': err}
