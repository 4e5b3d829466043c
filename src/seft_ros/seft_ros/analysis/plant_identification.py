"""The force loop's plant identified from an open-loop run, its order chosen by the data.

``seft identify`` fits seft's physical rig model to a lab's actuator only when it is seft's
actuator: a two-stage valve, a leaky seal or an orifice is not in that model. This module fits
the plant as data instead (:class:`~seft_msgs_py.plant.PlantModel`): a discrete model from the
valve command ``u`` [V] to the four measured outputs (force, displacement, velocity,
acceleration), with one denominator (one plant, one set of poles) and a numerator per
output::

    y_i[k] = B_i(q) / A(q) u[k - n_k]      A = 1 + a_1 q^-1 + ... + a_n q^-n
                                           B_i = b_i0 + ... + b_in q^-n

- the whole-step delay ``n_k``: one less than the longest whose equation-error fit of the
  force is as good as the best (within :data:`DELAY_TOLERANCE`);
- for each order ``n`` from 1 to ``max_order``: an equation-error (ARX) fit, its unstable
  poles reflected into the unit circle, refined by the output-error fit
  (``scipy.optimize.least_squares``, its trust-region reflective method, by variable
  projection: the numerators are linear in the outputs once the denominator is fixed; its
  Levenberg-Marquardt method, MINPACK's, chose other trial points from the same residuals
  and Jacobians when the process shared its core, so that one record gave two models) of
  the simulated
  outputs to the measured ones, each output scaled by its standard deviation;
- the order by the Bayesian information criterion ``N log V + p log N`` (Schwarz 1978),
  with ``V`` the mean squared relative output error floored at :data:`ERROR_FLOOR` squared
  (a noise-free record would otherwise buy orders for rounding);
- then each output weighed by its own residual (maximum likelihood for independent sensor
  noise, Ljung 1999, Sec. 7.4: the displacement of a stiff specimen is mostly its sensor's
  noise) and the orders around the first choice fitted again;
- its uncertainty: the force output's relative simulation error (NRMS), and the relative
  standard error of the specimen's natural frequency from its fit.

The record must start at rest (an identification run does), so the simulation starts from
zero.

References
----------
G. Golub and V. Pereyra, Separable nonlinear least squares: the variable projection method
and its applications, Inverse Problems 19(2), 2003, R1-R26.
L. Ljung, System Identification: Theory for the User, 2nd ed., Prentice Hall, 1999, Sec. 4.2
(output-error model), 7.3 and 10.1 (prediction-error fit), 16.4 (model order).
G. Schwarz, Estimating the dimension of a model, Ann. Statist. 6(2), 1978, 461-464.
"""

from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from scipy import linalg, optimize, signal

from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.plant import OUTPUTS, PlantModel, PlantUncertainty, Specimen, parse_plant
from seft_msgs_py.sampling import single_blas_thread

__all__ = ['PlantFit', 'identify_plant', 'DELAY_TOLERANCE', 'ERROR_FLOOR', 'FORCE_CHOICE_FLOOR',
           'MAX_ORDER']

#: A longer whole-step delay is taken while its equation-error fit leaves at most this
#: fraction more of the force unexplained than the best delay's.
DELAY_TOLERANCE = 0.05
#: The relative output error below which a higher order gains nothing [-].
ERROR_FLOOR = 1e-4
#: The relative equation error below which two delays fit equally (rounding) [-]: far below
#: :data:`ERROR_FLOOR`, since an eighth-order fit with a delay one step too long misses an
#: integrating actuator's force by only ~1e-4 of its (drifting) level.
DELAY_FLOOR = 1e-6
#: The error of the force response near the specimen's frequency (relative to the
#: specimen's force there) below which the fit keeps the force's own numerator
#: (:meth:`PlantFit.with_specimen_force`) [-].
FORCE_CHOICE_FLOOR = 1e-3
#: The highest order tried.
MAX_ORDER = 10
#: Evaluations of the output-error fit at most (per order): a noise-free record converges in
#: a handful, a noisy one is within 1e-4 of its minimum in a few tens.
MAX_EVALUATIONS = 60


@dataclass
class PlantFit:
    """A plant identified by :func:`identify_plant`.

    Attributes
    ----------
    model : PlantModel
    order : int
        n (the denominator's).
    delay_steps : int
        n_k.
    a : ndarray, shape (n + 1,)
        Denominator in powers of ``q^-1``.
    b : ndarray, shape (4, n + 1)
        Numerators of :data:`~seft_msgs_py.plant.OUTPUTS` in powers of ``q^-1``, from
        ``q^-n_k`` [output unit / V].
    nrms : dict
        Output -> relative RMS error of the simulated output [-].
    orders : list of dict
        Every order tried: ``order``, ``loss`` (mean squared relative error), ``bic``,
        ``stable``.
    dt : float
        [s].
    source : str
    free_force_nrms : float or None
        The force's NRMS error with its own numerator, when the model's force is the
        specimen's on its motion (:meth:`with_specimen_force`) [-]; else None.
    force_errors : dict
        :meth:`with_specimen_force`'s errors of the two forces near the specimen's
        frequency (``own``, ``specimen``) [-]; empty before it.
    """

    model: PlantModel
    order: int
    delay_steps: int
    a: np.ndarray
    b: np.ndarray
    nrms: dict
    orders: list = field(default_factory=list)
    dt: float = 0.0
    source: str = ''
    free_force_nrms: float | None = None
    force_errors: dict = field(default_factory=dict)

    def mapping(self) -> dict[str, Any]:
        """The model as a ``plant_model`` mapping: a discrete transfer function (polynomials
        in z, descending powers), with its specimen, uncertainty and fit figures."""
        n, nk = self.order, self.delay_steps
        length = max(n, nk + n) + 1
        den = np.concatenate([self.a, np.zeros(length - self.a.size)])
        nums = {}
        for i, name in enumerate(OUTPUTS):
            num = np.concatenate([np.zeros(nk), self.b[i]])
            nums[name] = np.concatenate([num, np.zeros(length - num.size)]).tolist()
        doc = {'form': 'transfer_function', 'dt': self.dt, 'den': den.tolist(), 'num': nums,
               'source': self.source,
               'info': {'identified': 'output-error fit, order by BIC', 'order': n,
                        'delay_steps': nk,
                        'nrms': {k: float(v) for k, v in self.nrms.items()}}}
        if self.free_force_nrms is not None:
            doc['info'].update(force="the specimen's on the motion",
                               free_force_nrms=float(self.free_force_nrms))
        if self.model is not None:
            if self.model.specimen is not None:
                doc['specimen'] = self.model.specimen.to_mapping()
            doc['uncertainty'] = self.model.uncertainty.to_mapping()
        return doc

    def with_specimen(self, specimen: Specimen, frequency_uncertainty: float) -> None:
        """Put `specimen` (and the relative standard error of its natural frequency) with
        the model in place of the one it was identified with (the same transfer functions:
        a fit of the specimen made after the plant's, :meth:`residuals`)."""
        doc = self.mapping()
        doc['specimen'] = specimen.to_mapping()
        doc['uncertainty'] = dict(doc['uncertainty'], frequency=float(frequency_uncertainty),
                                  note=_uncertainty_note(self.nrms['force_N'], self.order,
                                                         frequency_uncertainty,
                                                         self.free_force_nrms))
        self.model = parse_plant(doc, dt=self.dt, where=self.source)

    def with_specimen_force(self, u, outputs, standard_errors=(0.0, 0.0, 0.0)) -> bool:
        """Make the model's force the force of its specimen on its own motion,
        ``B_f = m B_a + c B_v + k B_x`` (paper Eq. 5.1 on the load cell's side), in place of
        the force's own numerator, where the record says that force is the better known
        near the specimen's frequency; then its force NRMS is that model's on the record.

        The control-structure-interaction zeros of the force response are the specimen's poles.
        A force numerator fitted on its own places them from the force alone, where a lightly
        damped specimen takes almost none: with a load cell's noise of 0.1 N on an actuator
        with a 2 Hz, 0.5 % specimen (40 kg, 238 N RMS), its zero at 2.0040 Hz, damping 0.0023,
        where the specimen fit (errors in variables) gives 2.0008 Hz, 0.0050 (true 2.0000,
        0.0050); the study's test that inverted that model erred by 20 % NRMS x at alpha 1, 1.9
        % with the specimen's force. With the motion sensors noisy too the acceleration's
        numerator can be the worse known (0.9 % off at 2 Hz with 1e-3 m/s^2 of noise), and the
        specimen's force worse than the force's own. So the two are compared on the record's
        halves: each output's numerators fitted again on each half (the model's denominator,
        the regressor of the whole record), and the force response of each kind on the
        specimen's band (5 half-power bandwidths around its frequency) differs between the
        halves by its error (half the difference, relative to the specimen's force); the
        specimen's standard errors add theirs to the specimen's force. Its force is taken where
        its error is below half the other's and above :data:`FORCE_CHOICE_FLOOR` (a noise-free
        record keeps its own fit: both are exact).

        Parameters
        ----------
        u : array_like, shape (n,)
            The valve command the model was identified from [V].
        outputs : array_like, shape (n, 4)
            The measured outputs (:meth:`residuals`).
        standard_errors : (float, float, float)
            The specimen fit's standard errors of m [kg], c [N s/m] and k [N/m].

        Returns
        -------
        bool
            Whether the force is now the specimen's. Either way ``force_errors`` holds the
            two errors (``own``, ``specimen``) [-].

        Raises
        ------
        ParameterError
            The model has no specimen.
        """
        spec = self.model.specimen if self.model is not None else None
        if spec is None:
            raise ParameterError("plant fit: the force from the specimen needs the model's "
                                 'specimen; expected a fit with one (identify_plant(..., '
                                 'specimen=...))')
        u = np.asarray(u, dtype=float)
        y = np.asarray(outputs, dtype=float)
        y = y - y[0]
        coef = np.array([spec.mass_kg, spec.damping_N_s_per_m, spec.stiffness_N_per_m])
        freqs = _csi_band(spec)
        zq = np.exp(-2j * np.pi * freqs * self.dt)
        powers = zq[:, None] ** np.arange(self.delay_steps, self.delay_steps + self.b.shape[1])
        den = sum(self.a[j] * zq ** j for j in range(self.a.size))

        def responses(b):                  # (4, f): each output's numerator over A
            return (b @ powers.T) / den

        g = signal.lfilter([1.0], self.a, u)
        phi = np.column_stack([_shift(g, self.delay_steps + j) for j in range(self.b.shape[1])])
        half = u.size // 2
        h = [responses(np.linalg.lstsq(phi[part], y[part], rcond=None)[0].T)
             for part in (slice(0, half), slice(half, None))]
        full = responses(self.b)
        scale = np.abs(coef @ full[[3, 2, 1]])                 # the specimen's force
        own = np.abs(h[0][0] - h[1][0]) / 2
        derived = np.abs(coef @ (h[0][[3, 2, 1]] - h[1][[3, 2, 1]])) / 2
        se = np.abs(np.asarray(standard_errors, dtype=float))
        derived = np.sqrt(derived ** 2 + ((se[:, None] * np.abs(full[[3, 2, 1]])).sum(0)) ** 2)
        errors = {'own': float(np.sqrt(np.mean((own / scale) ** 2))),
                  'specimen': float(np.sqrt(np.mean((derived / scale) ** 2)))}
        self.force_errors = errors
        if not (errors['own'] > FORCE_CHOICE_FLOOR and errors['specimen'] < 0.5 * errors['own']):
            return False
        if self.free_force_nrms is None:
            self.free_force_nrms = float(self.nrms['force_N'])
        self.b = self.b.copy()
        self.b[0] = coef @ self.b[[3, 2, 1]]
        res = self.residuals(u, y)[:, 0]
        nrms = float(np.sqrt(np.mean(res ** 2)) / np.std(y[:, 0]))
        self.nrms = dict(self.nrms, force_N=nrms)
        doc = self.mapping()
        unc = self.model.uncertainty.to_mapping()
        unc['relative'] = max(nrms, ERROR_FLOOR)
        unc['note'] = _uncertainty_note(nrms, self.order, float(unc.get('frequency', 0.0)),
                                        self.free_force_nrms)
        doc['uncertainty'] = unc
        self.model = parse_plant(doc, dt=self.dt, where=self.source)
        return True

    def residuals(self, u, outputs) -> np.ndarray:
        """The measured outputs less the model's simulation from rest: with an exact command
        (the valve command an open-loop run sent), the sensors' noise and the model's error.

        Parameters
        ----------
        u : array_like, shape (n,)
            The valve command the model was identified from [V].
        outputs : array_like, shape (n, 4)
            The measured outputs of :data:`~seft_msgs_py.plant.OUTPUTS` (their first sample
            taken as the offset, as :func:`identify_plant` does).

        Returns
        -------
        ndarray, shape (n, 4)
            [output units].
        """
        u = np.asarray(u, dtype=float)
        y = np.asarray(outputs, dtype=float)
        sim = np.column_stack([signal.lfilter(np.concatenate([np.zeros(self.delay_steps), b]),
                                              self.a, u) for b in self.b])
        return (y - y[0]) - sim

    def to_json(self) -> dict[str, Any]:
        """The figures of the fit (order, delay, errors, the orders tried)."""
        return {'order': self.order, 'delay_steps': self.delay_steps,
                'nrms': {k: float(v) for k, v in self.nrms.items()},
                'orders': self.orders,
                'uncertainty': self.model.uncertainty.to_mapping()}


def _uncertainty_note(force_nrms: float, order: int, frequency_uncertainty: float,
                      free_force_nrms: float | None = None) -> str:
    """The identified model's uncertainty note."""
    free = ('' if free_force_nrms is None else
            f", the specimen's force on the motion (its own fit {100 * free_force_nrms:.2g} %)")
    return (f'identified: force NRMS {100 * force_nrms:.2g} % (order {order}{free}); '
            f'specimen frequency +-{100 * frequency_uncertainty:.2g} %')


def _csi_band(specimen: Specimen, points: int = 41) -> np.ndarray:
    """The frequencies [Hz] within 5 half-power bandwidths (at least +-1 %) of the
    specimen's natural frequency: where the force response has its
    control-structure-interaction zeros."""
    f_n = specimen.natural_frequency_hz
    width = 5.0 * max(specimen.damping_ratio, 0.002)
    return f_n * np.linspace(1.0 - width, 1.0 + width, points)


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    """`x` delayed by k samples (zeros before)."""
    if k <= 0:
        return x.copy()
    return np.concatenate([np.zeros(k), x[:-k]]) if k < x.size else np.zeros_like(x)


def _delay_steps(u: np.ndarray, y: np.ndarray, order: int = 8, longest: int = 10) -> int:
    """The whole-step delay of `y` behind `u` (module notes), at least 1: one step less than
    the longest ``n_k`` whose equation-error (ARX) fit of order `order` leaves at most
    :data:`DELAY_TOLERANCE` more of `y` unexplained than the best ``n_k`` (a shorter one
    fits as well with a leading zero: the longest such is the delay)."""
    losses = []
    for nk in range(1, longest + 1):
        lhs = np.column_stack([-_shift(y, j + 1) for j in range(order)]
                              + [_shift(u, nk + j) for j in range(order + 1)])
        theta, res, *_ = np.linalg.lstsq(lhs, y, rcond=None)
        r = y - lhs @ theta
        losses.append(float(r @ r))
    floor = (DELAY_FLOOR ** 2) * float(y @ y)
    best = min(losses)
    ok = [nk for nk, loss in zip(range(1, longest + 1), losses)
          if loss <= (1.0 + DELAY_TOLERANCE) * best + floor]
    # one step less: a delay too short costs a numerator coefficient, one too long the
    # response's first sample (with sensor noise the two fit about equally well)
    return max(1, max(ok) - 1)


def _stable_poly(a: np.ndarray) -> np.ndarray:
    """`a` with its roots outside the unit circle reflected inside (at 0.98 of 1/|z|)."""
    roots = np.roots(a)
    if roots.size and np.any(np.abs(roots) >= 1.0):
        roots = np.where(np.abs(roots) >= 1.0, 0.98 / np.conj(roots), roots)
        return np.real(np.poly(roots))
    return a


class _OutputError:
    """The output-error fit of one order (module notes) by variable projection: for a
    denominator ``A`` the numerators are the linear least squares of the outputs on the
    delayed, filtered command ``u / A`` (one regressor for all outputs), so the nonlinear fit
    is over the ``n`` coefficients of ``A`` alone, with Kaufman's Jacobian (Golub and Pereyra
    2003, Sec. 3): ten unknowns instead of fifty-five, the same minimum."""

    def __init__(self, u, y, na, nb, nk):
        self.u, self.y = u, y
        self.na, self.nb, self.nk = na, nb, nk
        self.n, self.p = y.shape

    def unpack(self, theta):
        a = np.concatenate([[1.0], theta[:self.na]])
        b = theta[self.na:].reshape(self.p, self.nb + 1)
        return a, b

    def _regressor(self, g):
        return np.column_stack([_shift(g, self.nk + j) for j in range(self.nb + 1)])

    def _project(self, a_tail):
        """``(phi, b, r)``: the regressor, the numerators (p, nb + 1) and the residuals
        (n, p) of the denominator ``[1, *a_tail]``."""
        with np.errstate(all='ignore'):
            g = signal.lfilter([1.0], np.concatenate([[1.0], a_tail]), self.u)
        if not np.all(np.isfinite(g)) or np.max(np.abs(g)) > 1e150:
            return None, None, None
        phi = self._regressor(g)
        q, rr = np.linalg.qr(phi)
        b = linalg.solve_triangular(rr, q.T @ self.y, check_finite=False).T \
            if np.all(np.abs(np.diag(rr)) > 1e-12 * np.abs(rr).max()) \
            else np.linalg.lstsq(phi, self.y, rcond=None)[0].T
        self._q = q
        return phi, b, self.y - phi @ b.T

    def full(self, a_tail):
        """The full parameter vector (denominator and numerators) of a denominator."""
        _, b, _ = self._project(a_tail)
        if b is None:
            b = np.zeros((self.p, self.nb + 1))
        return np.concatenate([a_tail, b.ravel()])

    def simulate(self, theta):
        a, b = self.unpack(theta)
        g = signal.lfilter([1.0], a, self.u)
        return self._regressor(g) @ b.T

    def _residuals(self, a_tail):
        _, _, r = self._project(a_tail)
        if r is None:
            return np.full(self.n * self.p, 1e10)
        return r.ravel(order='F')

    def _jacobian(self, a_tail):
        phi, b, r = self._project(a_tail)
        if phi is None:
            return np.zeros((self.n * self.p, self.na))
        a = np.concatenate([[1.0], a_tail])
        g = signal.lfilter([1.0], a, self.u)
        jac = np.zeros((self.n * self.p, self.na))
        for j in range(self.na):
            # d(u/A)/da_j = -q^-j (u/A)/A; r = (I - P) y: dr = -(I - P) dphi b (Kaufman)
            dphi = self._regressor(-signal.lfilter([1.0], a, _shift(g, j + 1)))
            d = dphi @ b.T
            d -= self._q @ (self._q.T @ d)
            jac[:, j] = -d.ravel(order='F')
        return np.where(np.isfinite(jac), jac, 0.0)

    def initial(self):
        """The denominator of the equation-error (ARX) least squares of all outputs, its
        poles made stable."""
        na, nb, nk, n = self.na, self.nb, self.nk, self.n
        rows, rhs = [], []
        for i in range(self.p):
            y = self.y[:, i]
            lhs = np.zeros((n, na + self.p * (nb + 1)))
            for j in range(na):
                lhs[:, j] = -_shift(y, j + 1)
            for j in range(nb + 1):
                lhs[:, na + i * (nb + 1) + j] = _shift(self.u, nk + j)
            rows.append(lhs)
            rhs.append(y)
        theta = linalg.lstsq(np.vstack(rows), np.concatenate(rhs), lapack_driver='gelsy')[0]
        return _stable_poly(np.concatenate([[1.0], theta[:na]]))[1:]

    def _refine(self, a0):
        sol = optimize.least_squares(self._residuals, a0, jac=self._jacobian, method='trf',
                                     max_nfev=MAX_EVALUATIONS)
        a_tail = sol.x
        loss = float(np.mean(sol.fun ** 2))
        loss0 = float(np.mean(self._residuals(a0) ** 2))
        if not np.all(np.isfinite(a_tail)) or not loss < loss0 + 1e-300:
            a_tail, loss = a0, loss0
        return self.full(a_tail), loss

    def stable(self, theta) -> bool:
        return bool(np.all(np.abs(np.roots(self.unpack(theta)[0])) < 1.0))

    def fit(self, start=None):
        """``(theta, loss)`` of the refined fit from the equation-error start, and from the
        denominator of `start` too if given (a fit of the same order with other weights):
        the stable one of lower loss."""
        fits = [self._refine(self.initial())]
        if start is not None:
            fits.append(self._refine(np.asarray(start[:self.na], dtype=float)))
        fits.sort(key=lambda f: (not self.stable(f[0]), f[1]))
        return fits[0]


def _search(u, y, scale, nk, orders, starts=None):
    """Fit every order of `orders` with the outputs divided by `scale`, from `starts`
    (order -> theta, fits of other weights) too: ``(tried, best, thetas)``, best
    ``(bic, order, theta, fit)`` of the stable ones (None if none), thetas every order's."""
    yn = y / scale
    n_obs = yn.size
    tried, best, thetas = [], None, {}
    for na in orders:
        oe = _OutputError(u, yn, na, na, nk)
        theta, loss = oe.fit(starts.get(na) if starts else None)
        thetas[na] = theta
        stable = oe.stable(theta)
        bic = n_obs * math.log(max(loss, ERROR_FLOOR ** 2)) + theta.size * math.log(n_obs)
        tried.append({'order': na, 'loss': loss, 'bic': bic, 'stable': stable})
        if stable and (best is None or bic < best[0]):
            best = (bic, na, theta, oe)
    return tried, best, thetas


def identify_plant(u, outputs, dt: float, *, specimen: Specimen | None = None,
                   frequency_uncertainty: float = 0.0, max_order: int = MAX_ORDER,
                   source: str = '') -> PlantFit:
    """Identify the plant from the valve command and the measured outputs (module notes).

    Parameters
    ----------
    u : array_like, shape (n,)
        The valve command [V] of an open-loop run from rest.
    outputs : array_like, shape (n, 4)
        The measured force [N], displacement [m], velocity [m/s] and acceleration [m/s^2].
    dt : float > 0
        Sample period [s].
    specimen : Specimen, optional
        The specimen in the loop (its fit, ``seft identify``'s): it goes with the model.
    frequency_uncertainty : float >= 0
        The relative standard error of the specimen's natural frequency (from its fit).
    max_order : int >= 1
        The highest order tried.
    source : str
        Where the data come from (a bag), for the model's ``source``.

    Returns
    -------
    PlantFit
        Its model's uncertainty states the force fit's NRMS and the record's largest force
        and velocity (from rest: the level the linear model was identified at).

    Raises
    ------
    InputError
        A record too short (fewer than 20 samples per parameter of the highest order), no
        excitation, or no stable fit.
    ParameterError
        Bad `dt` or `max_order`.
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(outputs, dtype=float)
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ParameterError(f'dt={dt!r}: expected a period > 0 [s]')
    if not (isinstance(max_order, int) and max_order >= 1):
        raise ParameterError(f'max_order={max_order!r}: expected an integer >= 1')
    where = source or 'the record'
    if u.ndim != 1 or y.shape != (u.size, len(OUTPUTS)):
        raise InputError(f'{where}: expected the command (n,) and the four outputs (n, 4), got '
                         f'{u.shape} and {y.shape}')
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise InputError(f'{where}: non-finite samples')
    y = y - y[0]                                  # from rest: the sensors' offsets out
    scale = np.std(y, axis=0)
    if not (np.std(u) > 0 and np.all(scale > 0)):
        raise InputError(f'{where}: the valve command or an output does not move: '
                         'identification needs an excitation (excitation_input valve_command)')
    n_params = max_order + len(OUTPUTS) * (max_order + 1)
    if u.size < 20 * n_params:
        raise InputError(f'{where}: {u.size} samples; expected at least {20 * n_params} to '
                         f'identify up to order {max_order}')
    with single_blas_thread():                    # small products: threads only slow them
        return _identify(u, y, dt, scale, specimen, frequency_uncertainty, max_order, source,
                         where)


def _identify(u, y, dt, scale, specimen, frequency_uncertainty, max_order, source, where):
    nk = _delay_steps(u, y[:, 0] / scale[0])
    tried, best, thetas = _search(u, y, scale, nk, range(1, max_order + 1))
    if best is None:
        raise InputError(f'{where}: no stable model of order 1 to {max_order} fits the record')
    # maximum likelihood: each output weighed by its own residual (a noisy sensor, the
    # displacement of a stiff specimen, must not pull the fit), the orders around the first
    # choice searched again
    _, na, theta, oe = best
    res = (oe.y - oe.simulate(theta)) * scale
    noise = np.maximum(np.sqrt(np.mean(res ** 2, axis=0)), ERROR_FLOOR * scale)
    around = range(max(1, na - 2), min(max_order, na + 2) + 1)
    again, best2, _ = _search(u, y, noise, nk, around, starts=thetas)
    if best2 is not None:
        scale = noise
        tried = [dict(o, weighted=True) for o in again] + tried
        best = best2
    _, na, theta, oe = best
    a, b_scaled = oe.unpack(theta)
    spread = np.std(y, axis=0)
    b = b_scaled * scale[:, None]
    sim = oe.simulate(theta) * scale
    nrms = {name: float(np.sqrt(np.mean((y[:, i] - sim[:, i]) ** 2)) / spread[i])
            for i, name in enumerate(OUTPUTS)}
    unc = PlantUncertainty(max(nrms['force_N'], ERROR_FLOOR), (0.0, 0.5 / dt),
                           _uncertainty_note(nrms['force_N'], na, frequency_uncertainty),
                           float(frequency_uncertainty),
                           peak_force_N=float(np.max(np.abs(y[:, 0]))),
                           peak_velocity_m_s=float(np.max(np.abs(y[:, 2]))))
    fit = PlantFit(None, na, nk, a, b, nrms, tried, float(dt), source or 'identified')
    doc = fit.mapping()
    doc['uncertainty'] = unc.to_mapping()
    if specimen is not None:
        doc['specimen'] = specimen.to_mapping()
    fit.model = parse_plant(doc, dt=float(dt), where=where)
    return fit
