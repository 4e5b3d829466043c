"""Stability of the substructure EFT loop from its sampled-data state matrix (no simulation).

The loop of :func:`seft_ros.core.experiment.simulate` with zero ground input is linear for the
linear rig models (sensor noise, the accelerometer range and the valve saturation left out):
the rig sampled exactly with its (fractional) delay, the discrete force controller (on the
servohydraulic rig) and the reference-force builder with its delay compensator, paper
Eq. 5.3 with ``a_hat`` in place of the measured acceleration::

    z[k+1]     = A z[k] + B u[k],  y[k] = (x, v, a, f_m)[k] = C z[k]        rig
    u[k]       = C_e(z) (f_r[k] - f_m[k]) + g_v (v + T_v a)[k]  (delay: f_r[k])  controller
    a_hat[k+1] = P_alpha(z) q[k],  q[k] = (x, v, a, f_m, F)[k]              compensator
    F[k+1]     = -alpha m a_hat[k+1]                                        Eq. 5.3
    f_r[k+1]   = W(z) F[k+1]                                                command

``F`` is the desired force and ``f_r`` the command sent (``W = 1`` except for a force-loop
inverse). Hence ``X[k+1] = M(alpha) X[k]`` with ``X = [z, x_c, w, w_W, F]``, and
``M = M_0 + alpha M_1`` when the compensator does not depend on alpha; the loop is stable if
and only if the spectral radius of ``M`` is below 1.

Compensators enter through :class:`PredictorForm`. A predictor class may state it
(:class:`LinearPredictor`, ``linear_form()``); otherwise it is identified from the
compensator's own ``predict``/``command`` calls, driven as the builder drives them (impulse
responses of the compensator alone, checked by superposition on a random input): exact for
finite-memory linear compensators. Nonlinear (adaptive) ones have no form; the map marks
them n/a. A compensator that depends on alpha is identified at every alpha of the search.

With a pure delay and no compensation the loop is of neutral type (paper Eq. 5.4: the
delayed acceleration enters with the factor alpha), unstable for alpha > 1 at every delay;
with the specimen's stiffness the first chain of roots crosses earlier, near
``alpha = exp(-(omega_n T/pi)^2)``, ``T = tau + dt``.

References
----------
N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 5.1, Eqs. 5.1-5.4.
J. E. Carrion and B. F. Spencer Jr., Model-based strategies for real-time hybrid testing,
NSEL Report 006, University of Illinois, 2007 (delay compensation).
"""

import copy
from dataclasses import dataclass, field
import math
from typing import Any, Mapping, Protocol, runtime_checkable

import numpy as np

from seft_msgs_py.errors import SeftError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sampling import zoh as _zoh
from seft_plant_sim.delay_rig import delay_split
from seft_plant_sim.servohydraulic import OUTPUTS, ServoHydraulicParams, sample
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.core.controller import ForceServoController
from seft_ros.core.reference_force import PREDICTORS, make_predictor, network_delay_steps

__all__ = [
    'PREDICTOR_INPUTS', 'DELAY_PARAMETER', 'KNOWN_NONLINEAR', 'PredictorForm',
    'LinearPredictor', 'Compensator', 'compensator', 'NoLinearModelError',
    'PredictedUnstableError', 'LoopModel', 'loop_model', 'closed_loop_matrix',
    'spectral_radius', 'largest_stable_alpha', 'StabilityMap', 'stability_map',
    'StabilityCheck', 'check_run', 'largest_stable_dt',
]

#: Inputs of a compensator's linear form at step k, in this order (:class:`PredictorForm`).
PREDICTOR_INPUTS = ('displacement_m', 'velocity_m_s', 'acceleration_m_s2', 'force_N',
                    'commanded_N')

#: The delay knob of each linear rig model (the ``tau`` axis of the stability map).
DELAY_PARAMETER = {'delay': 'tau_s', 'servohydraulic': 'io_latency_s'}

#: Compensators known to be nonlinear (until their class says ``linear = False``).
KNOWN_NONLINEAR = ('adaptive',)

#: Probe lengths of the identification [steps]: warm-up, impulse window.
_WARM_UP, _WINDOW = 16, 192
_PROBE_SCALE = np.array([1e-3, 5e-2, 5.0, 500.0, 500.0])   # typical sizes of the inputs
#: alphas at which a compensator's dependence on alpha is tested.
_ALPHA_PROBES = (0.5, 1.5)


class NoLinearModelError(SeftError):
    """The rig or compensator has no linear time-invariant model (adaptive, hysteretic)."""


class PredictedUnstableError(SeftError):
    """A run's loop is predicted unstable at its configured alpha (see :func:`check_run`)."""


def _shift_register(taps: np.ndarray):
    """State space ``(a, b, c, d)`` of ``y[k] = sum_i sum_j taps[i, j] u_i[k-j]``."""
    taps = np.atleast_2d(np.asarray(taps, dtype=float))
    ni = taps.shape[0]
    lengths = []
    for row in taps:
        nz = np.nonzero(row)[0]
        lengths.append(int(nz[-1]) + 1 if nz.size else 1)
    nw = sum(n - 1 for n in lengths)
    a, b, c = np.zeros((nw, nw)), np.zeros((nw, ni)), np.zeros(nw)
    pos = 0
    for i, n in enumerate(lengths):
        # states pos .. pos+n-2 hold u_i[k-1], ..., u_i[k-n+1]
        if n > 1:
            b[pos, i] = 1.0
            for j in range(1, n - 1):
                a[pos + j, pos + j - 1] = 1.0
            c[pos:pos + n - 1] = taps[i, 1:n]
        pos += n - 1
    return a, b, c, taps[:, 0].copy()


@dataclass(frozen=True)
class PredictorForm:
    """Linear form of a delay compensator at one alpha (zero ground input), builder timing.

    Prediction, from the step-k inputs ``q[k] = (x, v, a, f_m, F)[k]``
    (:data:`PREDICTOR_INPUTS`: the measurement of step k and the newest desired force, the
    arguments of ``predict(latest, commanded_N, 0.0)`` that returns ``a_hat[k+1]``)::

        w[k+1] = a w[k] + b q[k],   a_hat[k+1] = c w[k] + d q[k]

    Command sent for a desired force (``command(F)``)::

        w_W[k+1] = cmd_a w_W[k] + cmd_b F[k],   f_r[k] = cmd_c w_W[k] + cmd_d F[k]

    Attributes
    ----------
    a : ndarray, shape (nw, nw)
    b : ndarray, shape (nw, 5)
    c : ndarray, shape (nw,)
    d : ndarray, shape (5,)
        Units: ``a_hat`` [m/s^2] over the input units (m, m/s, m/s^2, N, N).
    cmd_a : ndarray, shape (nv, nv)
    cmd_b, cmd_c : ndarray, shape (nv,)
    cmd_d : float
        The command filter [N/N] (default: the identity).
    source : str
        How the form was obtained ('analytic', 'linear_form', 'identified').
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    cmd_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cmd_b: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cmd_c: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cmd_d: float = 1.0
    source: str = 'analytic'

    @classmethod
    def fir(cls, taps, command_taps=(1.0,), source: str = 'analytic') -> 'PredictorForm':
        """Finite-memory compensator ``a_hat[k+1] = sum_i sum_j taps[i, j] q_i[k-j]``,
        ``f_r[k] = sum_j command_taps[j] F[k-j]``.

        Parameters
        ----------
        taps : array_like, shape (5, L)
            Weight of input i (:data:`PREDICTOR_INPUTS`) j steps back.
        command_taps : array_like, shape (Lc,)
        source : str

        Returns
        -------
        PredictorForm
            Shift-register realizations (``L_i - 1`` states per input, ``L_i`` its number of
            taps without trailing zeros).
        """
        taps = np.atleast_2d(np.asarray(taps, dtype=float))
        if taps.shape[0] != len(PREDICTOR_INPUTS):
            raise ValueError(f'taps: expected shape (5, L), got {taps.shape}')
        a, b, c, d = _shift_register(taps)
        ca, cb, cc, cd = _shift_register(np.atleast_2d(command_taps))
        return cls(a, b, c, d, ca, cb[:, 0], cc, float(cd[0]), source)

    @classmethod
    def none(cls) -> 'PredictorForm':
        """No compensation: ``a_hat[k+1] = a_m[k]`` (paper Eq. 5.3)."""
        return cls.fir([[0.0], [0.0], [1.0], [0.0], [0.0]])

    @property
    def order(self) -> int:
        """Number of prediction states nw."""
        return self.a.shape[0]

    @property
    def command_order(self) -> int:
        """Number of command-filter states nv."""
        return self.cmd_a.shape[0]


@runtime_checkable
class LinearPredictor(Protocol):
    """A delay compensator that states its own linear form (preferred over identification).

    ``linear_form()`` returns the :class:`PredictorForm` of the compensator as configured
    (at its alpha). A class with ``linear = False`` is nonlinear.
    """

    def linear_form(self) -> PredictorForm:
        """Return the compensator's linear form."""


def _drive(predictor, q: np.ndarray, dt: float):
    """Feed a copy of a compensator as the builder does; return ``(a_hat[1..N], f_r[0..N-1])``.

    ``q`` (N, 5): measurement of step k and desired force ``F[k]``; zero ground force.
    """
    pred = copy.deepcopy(predictor)
    commanded: list[float] = []
    n = q.shape[0]
    a_hat, cmd = np.empty(n), np.empty(n)
    pred.predict(None, commanded, 0.0)
    for k in range(n):
        commanded.append(float(q[k, 4]))
        cmd[k] = pred.command(float(q[k, 4]))
        meas = Measurement(k, k * dt, float(q[k, 0]), float(q[k, 1]), float(q[k, 2]),
                           float(q[k, 3]))
        a_hat[k] = pred.predict(meas, commanded, 0.0)
    return a_hat, cmd


def _trim(name: str, taps: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Zero negligible taps; refuse a response still alive in the last quarter (in the last
    16 steps of a shorter window)."""
    if not np.all(np.isfinite(taps)):
        raise NoLinearModelError(f'predictor {name!r}: impulse response not finite')
    weights = np.abs(taps) * scale[:, None]
    peak = float(np.max(weights)) or 1.0
    tail = taps.shape[1] // 4 if taps.shape[1] >= _WINDOW else 16
    if np.max(weights[:, -tail:]) > 1e-9 * peak:
        raise NoLinearModelError(f'predictor {name!r}: memory longer than '
                                 f'{taps.shape[1] - tail} steps')
    taps = taps.copy()
    taps[weights <= 1e-12 * peak] = 0.0
    return taps


def _identify(predictor, name: str, dt: float, check: bool, window: int = _WINDOW) -> tuple:
    """Taps ``(5, window)`` and command taps ``(window,)`` of a compensator (module notes)."""
    n = _WARM_UP + window
    base_a, base_c = _drive(predictor, np.zeros((n, 5)), dt)
    taps = np.zeros((5, window))
    cmd_taps = np.zeros(window)
    for i in range(5):
        q = np.zeros((n, 5))
        q[_WARM_UP, i] = _PROBE_SCALE[i]
        ah, cm = _drive(predictor, q, dt)
        taps[i] = (ah - base_a)[_WARM_UP:] / _PROBE_SCALE[i]
        resp = (cm - base_c)[_WARM_UP:]
        if i == 4:
            cmd_taps = resp / _PROBE_SCALE[i]
        elif np.any(resp != 0.0):
            raise NoLinearModelError(f'predictor {name!r}: the command depends on the '
                                     'measurements')
    taps = _trim(name, taps, _PROBE_SCALE)
    cmd_taps = _trim(name, cmd_taps[None], np.ones(1))[0]
    if check:
        # superposition on a random input after the warm-up
        n = _WARM_UP + 2 * window
        q = np.zeros((n, 5))
        q[_WARM_UP:] = (np.random.default_rng(1).standard_normal((n - _WARM_UP, 5))
                        * _PROBE_SCALE)
        base_a, base_c = _drive(predictor, np.zeros((n, 5)), dt)
        got_a, got_c = _drive(predictor, q, dt)
        u = q[_WARM_UP:]
        want_a = sum(np.convolve(u[:, i], taps[i])[:n - _WARM_UP] for i in range(5))
        want_c = np.convolve(u[:, 4], cmd_taps)[:n - _WARM_UP]
        err_a = float(np.max(np.abs((got_a - base_a)[_WARM_UP:] - want_a)))
        err_c = float(np.max(np.abs((got_c - base_c)[_WARM_UP:] - want_c)))
        if not (err_a <= 1e-6 * max(float(np.max(np.abs(want_a))), 1e-300)
                and err_c <= 1e-6 * max(float(np.max(np.abs(want_c))), 1e-300)):
            raise NoLinearModelError(f'predictor {name!r}: not linear time-invariant '
                                     f'(superposition error {err_a:.3g} m/s^2, {err_c:.3g} N)')
    return taps, cmd_taps


class Compensator:
    """The linear form of a configured delay compensator as a function of alpha.

    Parameters
    ----------
    params : mapping
        Run parameters (``predictor``, ``dt`` and the compensator's keys).

    Attributes
    ----------
    name : str
    alpha_dependent : bool
        The form changes with alpha (then :meth:`form` builds the compensator at each alpha).

    Raises
    ------
    NoLinearModelError
        Nonlinear compensator (``linear = False``, :data:`KNOWN_NONLINEAR`) or one that fails
        the identification checks.
    ParameterError
        Unknown predictor name.

    Notes
    -----
    Identification: after 16 zero steps one input at a time (x, v, a, f_m, F) is pulsed and
    ``a_hat`` and the command recorded over 192 steps; the responses must vanish over the
    last 48 (finite memory) and superpose to the response to a random input within 1e-6.
    The form is compared at alpha = 0.5 and 1.5 to tell whether it depends on alpha.
    """

    def __init__(self, params: Mapping):
        self.name = params['predictor']
        self._params = dict(params)
        self._dt = float(params['dt'])
        self._cache: dict[float, PredictorForm] = {}
        if self.name == 'none':
            self.alpha_dependent = False
            self._fixed = PredictorForm.none()
            return
        factory = PREDICTORS.get(self.name)
        cls = getattr(factory, '__self__', None)
        if self.name in KNOWN_NONLINEAR or getattr(cls, 'linear', True) is False:
            raise NoLinearModelError(f'predictor {self.name!r} is nonlinear (time-varying)')
        self._window = _WINDOW
        forms = [self._build(a, check=(i == 0)) for i, a in enumerate(_ALPHA_PROBES)]
        self.alpha_dependent = not _same_form(*forms)
        # the other alphas: a window just longer than the memory seen at the probes
        self._window = 16 + max(max(f.order, f.command_order) for f in forms) + 1
        self._fixed = None if self.alpha_dependent else forms[0]
        self._cache.update(zip(_ALPHA_PROBES, forms))

    def _build(self, alpha: float, check: bool = False) -> PredictorForm:
        pred = make_predictor(dict(self._params, alpha=float(alpha)))
        if getattr(pred, 'linear', True) is False:
            raise NoLinearModelError(f'predictor {self.name!r} is nonlinear')
        if isinstance(pred, LinearPredictor):
            f = pred.linear_form()
            return PredictorForm(*(np.asarray(x, dtype=float) for x in (f.a, f.b, f.c, f.d)),
                                 np.asarray(f.cmd_a, dtype=float),
                                 np.asarray(f.cmd_b, dtype=float),
                                 np.asarray(f.cmd_c, dtype=float), float(f.cmd_d),
                                 source='linear_form')
        taps, cmd_taps = _identify(pred, self.name, self._dt, check, self._window)
        return PredictorForm.fir(taps, cmd_taps, source='identified')

    def form(self, alpha: float) -> PredictorForm:
        """The form at `alpha` (the same for every alpha unless `alpha_dependent`)."""
        if self._fixed is not None:
            return self._fixed
        key = float(alpha)
        if key not in self._cache:
            self._cache[key] = self._build(key)
        return self._cache[key]


def _same_form(f: PredictorForm, g: PredictorForm) -> bool:
    parts = ('a', 'b', 'c', 'd', 'cmd_a', 'cmd_b', 'cmd_c')
    if any(np.shape(getattr(f, p)) != np.shape(getattr(g, p)) for p in parts):
        return False
    return all(np.allclose(getattr(f, p), getattr(g, p), rtol=1e-9, atol=0.0)
               for p in parts) and math.isclose(f.cmd_d, g.cmd_d, rel_tol=1e-9)


def compensator(params: Mapping) -> Compensator:
    """:class:`Compensator` of ``params['predictor']`` (see there)."""
    return Compensator(params)


# -- rig models -------------------------------------------------------------------------------



def _delay_rig(params: Mapping):
    """Augmented model of the delay rig: state ``[x, v, f_r[k-n-1..k-1]]``, input ``f_r[k]``.

    Returns (A, B, C) with C rows (x, v, a, f_m); the split of a fractional delay as
    :class:`~seft_plant_sim.delay_rig.DelayRig`.
    """
    spec = LinearSpecimen.from_parameters(params)
    dt = float(params['dt'])
    n, delta = delay_split(float(params['tau_s']), dt)
    a_s, b_s = spec.state_space()
    phi, _ = _zoh(a_s, b_s, dt)
    phi_rest, g_late = _zoh(a_s, b_s, dt - delta)
    _, g_early = _zoh(a_s, b_s, delta)
    g_early = phi_rest @ g_early
    nz = 2 + n + 1
    a, b = np.zeros((nz, nz)), np.zeros((nz, 1))
    a[:2, :2] = phi
    a[:2, 2] = g_early[:, 0]
    if n >= 1:
        a[:2, 3] = g_late[:, 0]
    else:
        b[:2, 0] = g_late[:, 0]
    for i in range(n):
        a[2 + i, 3 + i] = 1.0
    b[nz - 1, 0] = 1.0
    f_m = np.zeros(nz)
    f_m[3 if delta == 0.0 else 2] = 1.0          # f_r(t_k - tau) at t_k+
    m, c, k = spec.mass_kg, spec.damping_N_s_per_m, spec.stiffness_N_per_m
    acc = f_m / m
    acc[0] -= k / m
    acc[1] -= c / m
    x, v = np.zeros(nz), np.zeros(nz)
    x[0], v[1] = 1.0, 1.0
    return a, b, np.vstack([x, v, acc, f_m])


def _servohydraulic_rig(params: Mapping):
    """Augmented model of the servohydraulic rig (:meth:`SampledRig.augmented`), C rows
    (x, v, a, f_m)."""
    rig = sample(ServoHydraulicParams.from_parameters(params),
                 LinearSpecimen.from_parameters(params), float(params['dt']))
    a, b, c = rig.augmented()
    rows = [OUTPUTS.index(n) for n in ('displacement_m', 'velocity_m_s', 'acceleration_m_s2',
                                       'force_N')]
    return a, b, c[rows]


def _rig_name(params: Mapping, frozen: bool = False) -> str:
    name = params.get('rig_model')
    if name not in DELAY_PARAMETER:
        raise NoLinearModelError(f'rig {name!r}: no linear model')
    specimen = params.get('specimen_model', 'linear')
    if specimen != 'linear' and not (frozen and specimen == 'bouc_wen'):
        raise NoLinearModelError(f'specimen {specimen!r} is nonlinear')
    return name


def tangent_ratios(params: Mapping) -> tuple[float, ...]:
    """The tangent stiffnesses, as fractions of k, at which a run's loop is linearized.

    ``(1.0,)`` for the linear specimen; for the Bouc-Wen member ``(1.0, a)``: its elastic
    (initial) and post-yield stiffness (``post_yield_stiffness_ratio`` a, at least 1e-3), the
    two ends of the tangent stiffness under monotonic loading.
    """
    if params.get('specimen_model', 'linear') != 'bouc_wen':
        return (1.0,)
    return (1.0, max(float(params.get('post_yield_stiffness_ratio', 0.1)), 1e-3))


class LoopModel:
    """The closed loop ``X[k+1] = M(alpha) X[k]`` of one run configuration (any alpha).

    Parameters
    ----------
    params : mapping
        Run parameters: ``rig_model`` ('delay' or 'servohydraulic'), ``dt``, the specimen
        (``specimen_model`` 'linear'), the rig's keys and ``predictor`` with its keys.
    comp : Compensator, optional
        Default: :func:`compensator` of `params`.
    tangent_ratio : float, optional
        Linearize a yielding member (``specimen_model`` 'bouc_wen' allowed) at the frozen
        tangent stiffness ``tangent_ratio * k``: the rig's specimen has that stiffness, the
        ``tangent_loop_shaping`` controller is scheduled to it
        (:meth:`~seft_ros.core.controller.TangentLoopShaping.frozen`), and the compensator
        keeps its own model. A necessary condition only: the member's stiffness changes.

    Attributes
    ----------
    compensator : Compensator

    Raises
    ------
    NoLinearModelError
        The rig, specimen or compensator has no linear form.

    Notes
    -----
    State ``X = [z (rig, past commands), x_c (controller; servohydraulic rig only),
    w (prediction), w_W (command filter), d (the reference force's playout delay line),
    F]``. With ``network_delay_s`` (the builder on another host) the controller acts on
    ``f_r[k - m]``, ``m = round(network_delay_s / dt)``: ``d`` holds ``f_r[k-1 .. k-m]``
    (the delay the predictor compensates is then in the loop, as in the test); the controller of
    :class:`~seft_ros.core.controller.ForceServoController` (``force_controller``: its
    error path ``C_e(z)`` in controllable canonical form by ``scipy.signal.tf2ss`` and its
    velocity and acceleration feedback,
    :meth:`~seft_ros.core.controller.ForceServoController.state_space`); the
    valve saturation and the accelerometer range are left out
    (small signal).
    """

    def __init__(self, params: Mapping, comp: Compensator | None = None, *,
                 tangent_ratio: float | None = None):
        rig = _rig_name(params, frozen=tangent_ratio is not None)
        self.compensator = comp if comp is not None else compensator(params)
        self.mass_kg = float(params['mass_kg'])
        plant = params
        if tangent_ratio is not None:
            plant = dict(params, stiffness_N_per_m=float(params['stiffness_N_per_m'])
                         * float(tangent_ratio))
        if rig == 'delay':
            a, b, cy = _delay_rig(plant)
            ac = np.zeros((0, 0))
            bc, cc, dc = np.zeros((0, 3)), np.zeros((1, 0)), np.zeros((1, 3))
        else:
            a, b, cy = _servohydraulic_rig(plant)
            ctrl = ForceServoController.from_parameters(params)
            if tangent_ratio is not None and hasattr(ctrl, 'frozen'):
                ctrl = ctrl.frozen(tangent_ratio)
            ac, bc, cc, dc = ctrl.state_space()
        self._rig = (rig, a, b, cy, ac, bc, cc, dc)
        #: the playout delay of the reference force before the controller [steps]
        self.playout_steps = network_delay_steps(params) if rig != 'delay' else 0
        self._affine = None
        if not self.compensator.alpha_dependent:
            self._affine = self.matrices(self.compensator.form(0.0))

    def matrices(self, form: PredictorForm):
        """``(M_0, M_1)`` with ``M = M_0 + alpha M_1`` for a compensator form.

        Returns
        -------
        m0, m1 : ndarray, shape (N, N)
            Only the last row (``F``) of ``m1`` is nonzero.
        """
        rig, a, b, cy, ac, bc, cc, dc = self._rig
        nz, nc, nw, nv = a.shape[0], ac.shape[0], form.order, form.command_order
        nd = self.playout_steps
        n = nz + nc + nw + nv + nd + 1
        iz = slice(0, nz)
        ic = slice(nz, nz + nc)
        iw = slice(nz + nc, nz + nc + nw)
        iv = slice(nz + nc + nw, nz + nc + nw + nv)
        i_d = nz + nc + nw + nv                            # first of the delay line
        i_f = n - 1
        q = np.zeros((5, n))                               # q[k] = Q X[k]
        q[:4, iz] = cy
        q[4, i_f] = 1.0
        f_r = np.zeros(n)                                  # command sent, f_r[k]
        f_r[iv] = form.cmd_c
        f_r[i_f] = form.cmd_d
        applied = f_r                                      # what the controller acts on
        if nd:                                             # f_r[k - m], the playout delay
            applied = np.zeros(n)
            applied[i_d + nd - 1] = 1.0
        e = applied.copy()                                 # force error f_r - f_m
        e[iz] -= cy[3]
        # controller inputs (e, v, a) and output u = cc x_c + dc (e, v, a)
        w_in = np.vstack([e, np.zeros(n), np.zeros(n)])
        w_in[1, iz] = cy[1]
        w_in[2, iz] = cy[2]
        if rig == 'delay':
            u = f_r
        else:
            u = dc[0] @ w_in
            u[ic] += cc[0]
        m0 = np.zeros((n, n))
        m0[iz, iz] = a
        m0[iz] += np.outer(b[:, 0], u)
        m0[ic, ic] = ac
        m0[ic] += bc @ w_in
        m0[iw, iw] = form.a
        m0[iw] += form.b @ q
        m0[iv, iv] = form.cmd_a
        m0[iv, i_f] = form.cmd_b
        if nd:                                             # d[k+1] = [f_r[k], d_1..d_m-1]
            m0[i_d] = f_r
            for j in range(1, nd):
                m0[i_d + j, i_d + j - 1] = 1.0
        m1 = np.zeros((n, n))                              # F[k+1] = -alpha m a_hat[k+1]
        m1[i_f, iw] = -self.mass_kg * form.c
        m1[i_f] -= self.mass_kg * (form.d @ q)
        return m0, m1

    def matrix(self, alpha: float) -> np.ndarray:
        """Closed-loop state matrix at `alpha`, shape (N, N)."""
        m0, m1 = self._affine or self.matrices(self.compensator.form(alpha))
        return m0 + float(alpha) * m1

    def radii(self, alphas) -> np.ndarray:
        """Spectral radii at `alphas`, shape (na,)."""
        alphas = np.atleast_1d(np.asarray(alphas, dtype=float))
        if self._affine is not None:
            m0, m1 = self._affine
            mats = m0[None] + alphas[:, None, None] * m1[None]
            return np.max(np.abs(np.linalg.eigvals(mats)), axis=-1)
        return np.array([np.max(np.abs(np.linalg.eigvals(self.matrix(a)))) for a in alphas])


def loop_model(params: Mapping) -> LoopModel:
    """:class:`LoopModel` of a run configuration (see there)."""
    return LoopModel(params)


def closed_loop_matrix(params: Mapping, alpha: float | None = None) -> np.ndarray:
    """Closed-loop state matrix at `alpha` (default ``params['alpha']``), see
    :class:`LoopModel`."""
    return loop_model(params).matrix(params['alpha'] if alpha is None else alpha)


def spectral_radius(params: Mapping, alpha: float | None = None) -> float:
    """Largest eigenvalue modulus of :func:`closed_loop_matrix` (< 1: stable)."""
    return float(loop_model(params).radii(params['alpha'] if alpha is None else alpha)[0])


def _scan(loop: LoopModel, alpha_max: float, step: float, tol: float):
    """(first boundary, stable intervals) over ``[0, alpha_max]``."""
    if loop.compensator.alpha_dependent:
        step, tol = max(step, 0.25), max(tol, 5e-3)      # one identification per alpha
    grid = np.linspace(0.0, alpha_max, int(math.ceil(alpha_max / step)) + 1)
    stable = loop.radii(grid) < 1.0

    def edge(lo, hi, lo_stable):
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            if (loop.radii(mid)[0] < 1.0) == lo_stable:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    intervals, start = [], 0.0 if stable[0] else None
    for i in range(1, grid.size):
        if stable[i] and not stable[i - 1]:
            start = edge(grid[i - 1], grid[i], False)
        elif stable[i - 1] and not stable[i]:
            intervals.append((float(start), float(edge(grid[i - 1], grid[i], True))))
            start = None
    if start is not None:
        intervals.append((float(start), math.inf))
    if not stable[0]:
        return math.nan, intervals
    return intervals[0][1], intervals


def largest_stable_alpha(params: Mapping, predictor: str | None = None, *,
                         alpha_max: float = 3.0, step: float = 0.01,
                         tol: float = 1e-4) -> float:
    """Stability boundary in alpha: the loop is stable for ``0 <= alpha < boundary``.

    Parameters
    ----------
    params : mapping
        Run parameters (see :class:`LoopModel`).
    predictor : str, optional
        Predictor name (default ``params['predictor']``).
    alpha_max : float > 0
        Upper end of the search.
    step : float > 0
        Grid step of the scan over alpha (stability need not be monotonic in alpha); at
        least 0.25 for a compensator that depends on alpha.
    tol : float > 0
        Bisection tolerance on the boundary (at least 5e-3 for such a compensator).

    Returns
    -------
    float
        The first alpha where the spectral radius reaches 1; ``inf`` if stable up to
        `alpha_max`; ``nan`` if already unstable at alpha = 0 (the force loop alone).

    Raises
    ------
    NoLinearModelError
        The rig or compensator has no linear form.
    """
    if predictor is not None:
        params = dict(params, predictor=predictor)
    return _scan(loop_model(params), alpha_max, step, tol)[0]


@dataclass
class StabilityMap:
    """Stability boundary in alpha over the rig's delay, one curve per predictor.

    Attributes
    ----------
    rig : str
        ``rig_model``.
    delay_parameter : str
        The varied parameter (:data:`DELAY_PARAMETER`: 'tau_s' or 'io_latency_s').
    taus_s : ndarray, shape (nt,)
        Its values [s].
    predictors : tuple of str, length np
    boundary_alpha : ndarray, shape (np, nt)
        :func:`largest_stable_alpha` per predictor and delay; ``inf``: stable up to
        `alpha_max`; ``nan``: unstable at alpha = 0, or no linear form (see `notes`).
    stable_intervals : list (np) of list (nt) of list of (float, float)
        Every stable interval of alpha in ``[0, alpha_max]`` (more than one where stability
        is not monotonic in alpha).
    notes : dict
        Predictor name -> why it has no curve (e.g. 'n/a (nonlinear)').
    alpha_max : float
        Upper end of the search.
    params : dict
        The other parameters of the map.
    """

    rig: str
    delay_parameter: str
    taus_s: np.ndarray
    predictors: tuple
    boundary_alpha: np.ndarray
    stable_intervals: list
    notes: dict = field(default_factory=dict)
    alpha_max: float = 3.0
    params: dict = field(default_factory=dict)

    def boundary(self, predictor: str) -> np.ndarray:
        """The boundary curve of one predictor, shape (nt,)."""
        return self.boundary_alpha[self.predictors.index(predictor)]

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict (``inf`` as the string 'inf', ``nan`` as null)."""
        def num(v):
            return None if math.isnan(v) else ('inf' if math.isinf(v) else float(v))

        return {
            'rig': self.rig, 'delay_parameter': self.delay_parameter,
            'taus_s': [float(t) for t in self.taus_s], 'alpha_max': self.alpha_max,
            'neutral_alpha': 1.0,
            'predictors': {
                p: {'boundary_alpha': [num(v) for v in self.boundary_alpha[i]],
                    'stable_intervals': [[[num(lo), num(hi)] for lo, hi in iv]
                                         for iv in self.stable_intervals[i]],
                    'note': self.notes.get(p)}
                for i, p in enumerate(self.predictors)},
            'params': {k: v for k, v in self.params.items()
                       if isinstance(v, (bool, int, float, str))},
        }


def stability_map(params: Mapping, taus, predictors, *, alpha_max: float = 3.0,
                  step: float = 0.01, tol: float = 1e-4) -> StabilityMap:
    """Largest stable alpha over the rig's delay for each predictor (eigenvalues only).

    Parameters
    ----------
    params : mapping
        Run parameters; ``rig_model`` 'delay' (varies ``tau_s``) or 'servohydraulic'
        (varies ``io_latency_s``).
    taus : array_like, shape (nt,)
        Delays [s] (> 0 for the delay rig, >= 0 for the servohydraulic rig).
    predictors : sequence of str
        Predictor names (registry ``PREDICTORS``).
    alpha_max, step, tol
        As :func:`largest_stable_alpha`.

    Returns
    -------
    StabilityMap

    Raises
    ------
    NoLinearModelError
        The rig has no linear model.
    ParameterError
        Unknown predictor or bad parameter.

    References
    ----------
    Nakata and Combs, Eqs. 5.1-5.4 (neutral type for alpha > 1 without compensation).
    """
    rig = _rig_name(params)
    knob = DELAY_PARAMETER[rig]
    taus = np.asarray(taus, dtype=float)
    predictors = tuple(predictors)
    bound = np.full((len(predictors), taus.size), math.nan)
    intervals = [[[] for _ in taus] for _ in predictors]
    notes = {}
    for i, name in enumerate(predictors):
        for j, tau in enumerate(taus):
            p = dict(params, predictor=name, **{knob: float(tau)})
            try:
                loop = loop_model(p)
            except NoLinearModelError as exc:
                notes[name] = f'n/a: {exc}'
                break
            bound[i, j], intervals[i][j] = _scan(loop, alpha_max, step, tol)
    return StabilityMap(rig, knob, taus, predictors, bound, intervals, notes, alpha_max,
                        dict(params))


@dataclass(frozen=True)
class StabilityCheck:
    """Predicted stability of one run at its configured alpha (:func:`check_run`).

    Attributes
    ----------
    stable : bool or None
        None if not predictable (nonlinear rig or predictor; see `note`).
    spectral_radius : float
        Of the closed-loop matrix at the configured alpha (nan if not predictable).
    boundary_alpha : float
        :func:`largest_stable_alpha` (nan if not predictable).
    message : str
        One line for the user.
    """

    stable: bool | None
    spectral_radius: float
    boundary_alpha: float
    message: str


def check_run(params: Mapping) -> StabilityCheck:
    """Predict whether a run's loop is stable at its configured alpha and predictor.

    Parameters
    ----------
    params : mapping
        Resolved run parameters.

    Returns
    -------
    StabilityCheck
        ``stable`` False when the spectral radius at ``params['alpha']`` is >= 1.
    """
    alpha, pred, rig = float(params['alpha']), params['predictor'], params.get('rig_model')
    where = f'alpha={alpha:g} with predictor {pred} on the {rig} rig'
    ratios = tangent_ratios(params)
    try:
        comp = compensator(params)
        loops = [LoopModel(params, comp, tangent_ratio=None if len(ratios) == 1 else r)
                 for r in ratios]
    except NoLinearModelError as exc:
        return StabilityCheck(None, math.nan, math.nan,
                              f'{where}: stability not predicted, {exc}')
    rho = max(float(loop.radii(alpha)[0]) for loop in loops)
    bounds = [_scan(loop, max(3.0, 2.0 * alpha), 0.02, 1e-4)[0] for loop in loops]
    bound = math.nan if any(math.isnan(b) for b in bounds) else min(bounds)
    frozen = ('' if len(ratios) == 1 else ' at the elastic and the post-yield stiffness of '
              f'the yielding member, frozen (k and {ratios[1]:g} k)')
    if rho < 1.0:
        return StabilityCheck(True, rho, bound, f'{where} is predicted stable{frozen} '
                              f'(spectral radius {rho:.4f}, largest stable alpha {bound:.3g})')
    if math.isnan(bound) and max(float(loop.radii(0.0)[0]) for loop in loops) >= 1.0:
        dt = float(params['dt'])
        limit = largest_stable_dt(params)
        hint = (f'; expected dt <= {limit:.3g} s' if math.isfinite(limit)
                else '; no sample period makes it stable: check the rig and controller')
        return StabilityCheck(False, rho, bound, f'parameter dt={dt:g}: the force loop alone '
                              f'(alpha = 0, no mass fed back) is predicted unstable on the {rig} '
                              f'rig: the sample period is too long for the force loop{hint}')
    return StabilityCheck(False, rho, bound, f'{where} is predicted unstable{frozen} '
                          f'(largest stable alpha {bound:.3g})')


def largest_stable_dt(params: Mapping, *, dt_min: float = 1e-4, rtol: float = 0.01) -> float:
    """The longest sample period at which the force loop alone (alpha = 0) is stable.

    Bisection on a log scale between `dt_min` and ``params['dt']`` on the spectral radius of
    the sampled loop at alpha = 0 (:class:`LoopModel`, the run's rig, controller and
    predictor, rebuilt at each period).

    Parameters
    ----------
    params : mapping
        Resolved run parameters; ``dt`` [s] is the upper end of the search.
    dt_min : float > 0
        Lower end of the search [s].
    rtol : float > 0
        Relative width at which the bisection stops.

    Returns
    -------
    float
        The period [s] (the stable end of the last bracket); ``inf`` if the loop is stable at
        ``params['dt']``, ``nan`` if it is unstable even at `dt_min` or has no linear form.
    """
    def stable(dt: float) -> bool:
        p = dict(params, dt=dt, alpha=0.0)
        try:
            comp = compensator(p)
            loops = [LoopModel(p, comp, tangent_ratio=None if len(r) == 1 else x)
                     for r in (tangent_ratios(p),) for x in r]
        except (NoLinearModelError, SeftError):
            return False
        return all(float(loop.radii(0.0)[0]) < 1.0 for loop in loops)

    hi = float(params['dt'])
    if stable(hi):
        return math.inf
    lo = dt_min
    if not stable(lo):
        return math.nan
    while hi / lo > 1.0 + rtol:
        mid = math.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return lo
