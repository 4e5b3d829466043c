"""The ``model`` compensator's gains tuned on the model of the whole sampled loop.

The pole-matching law of :class:`~seft_ros.core.predictors.ModelPredictor` places the sampled
poles of the specimen under a *held* force delayed by ``d`` steps at those of the reference
structure (paper Eq. 2.1): exact on the delay rig. On a valve-driven rig the force-loop
inverse makes the step average of a *smooth* force follow the desired one; the specimen
integrates the force inside the step, and what a held force and the actual one do to it
differ by about ``(omega dt)^2``. With the study's 10 Hz, 13.5 %-damped specimen that is a few
tenths of a percent of the reference structure's damping; with a stiff, lightly damped one
(32 Hz, 1 %: ``omega dt = 0.4``) it is most of it, and the test's error is tens of percent.

:func:`pole_calibration` closes the gap on the model of the loop the test will run
(:class:`~seft_ros.core.stability.LoopModel`: the rig's plant, its force controller, the
inverse and the law): it finds the offset of the law's two gains ``K`` (on the predicted
displacement and velocity) that puts the closed loop's eigenvalue nearest the reference
structure's sampled pole exactly on it, by Newton's method on the two real equations (the
closed-loop matrix is affine in ``K``, the law's output is, so three identifications of the
compensator give it for every ``K``); then the factor on the ground force's gain that makes the
test's response to the ground force the reference's in the least squares over the response
band (:func:`ground_gain_scale`; before, at the pole's frequency alone, which a well-damped
reference pays for over the rest of its band).

In a structure the same gap is in the coupling: each rig's compensator sees the interface
force of the computational springs and dashpots on its DOF, averaged over the interval where
its new force acts (:class:`~seft_ros.core.substructure.InterfacePredictor`), and what that
force does through the rig's loop is off by a few microseconds of timing, which across a
stiff computational story is a damping of the structure's modes: on ``two_story`` with a
32 Hz, 0.5 % first story on the ``valve_2nd_order`` actuator, 0.36 / 0.60 % of critical for
the reference's 0.38 / 0.73 %, and 3.0 / 2.7 % NRMS per story. :func:`structure_calibration`
closes it on the model of the whole test (:class:`~seft_ros.core.stability.TestLoop`): per
coupled rig, four corrections of the interface force its compensator sees (its dashpots'
force scaled, an inerter along its springs, a dashpot and a mass on the rig's own DOF:
none acts on a static deflection, so the test's static response stays exact; a spring
instead of the mass cost ``two_piers`` 0.2-0.5 % of static error), found by Gauss-Newton
steps on the loop's eigenvalues nearest the reference structure's sampled modes (the
loop's matrix is affine in them: five loop models per rig give it for all).

References
----------
K. J. Astrom and B. Wittenmark, Computer-Controlled Systems, 3rd ed., 1997, Sec. 4.5 (pole
placement) and Ch. 7 (sampling of a continuous signal between samples).
J. E. Carrion and B. F. Spencer Jr., Model-based strategies for real-time hybrid testing,
NSEL Report 006, 2007 (the model-based compensation the law comes from).
"""

import json
import math
from typing import Mapping

import numpy as np
from scipy.sparse.linalg import eigs

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.sampling import single_blas_thread

__all__ = ['ground_gain_scale', 'pole_calibration', 'reference_pole', 'structure_calibration']

#: Newton iterations at most, and the step of the finite differences (relative to K).
_ITERATIONS, _STEP = 8, 1e-4
#: The largest correction accepted, relative to each gain: beyond it the law's model is too
#: far from the loop for a gain correction to be the answer. A gain smaller than
#: ``GAIN_FLOOR`` of the specimen's own scale (its stiffness for ``K_x``, its critical damping
#: ``2 sqrt(k m)`` for ``K_v``) is taken at that floor: the velocity gain of a lightly
#: damped 2 Hz specimen is 0.4 % of critical damping, and a correction of 0.3 % of it is no
#: sign of a wrong model.
MAX_CORRECTION = 0.5
GAIN_FLOOR = 0.05
#: A refused calibration names the declared specimen when its mass or stiffness is more
#: than this from the loop model's specimen (relative): the law's reference pole is the
#: declared specimen's, the loop's the model's (a prior 20 % off, session 24) [-].
SPECIMEN_TOLERANCE = 0.01
#: Beyond this many times :data:`MAX_CORRECTION` the search's offsets are no correction but
#: a diverged Newton iteration (1e16 N/m on a 2.5e5 N/m specimen), and are not printed [-].
_DIVERGED = 10.0

_CACHE: dict = {}


def reference_pole(mass_kg: float, damping_N_s_per_m: float, stiffness_N_per_m: float,
                   alpha: float, dt: float) -> complex:
    """The reference structure's sampled pole ``exp(lambda dt)`` (upper half plane) of
    ``(1 + alpha) m x'' + c x' + k x = 0`` (paper Eq. 2.1)."""
    lam = np.roots([(1.0 + alpha) * mass_kg, damping_N_s_per_m, stiffness_N_per_m])
    lam = max(lam, key=lambda x: x.imag)
    return complex(np.exp(lam * dt))


class _Fixed:
    """A compensator of one fixed linear form (what :class:`LoopModel` takes)."""

    alpha_dependent = False

    def __init__(self, form):
        self._form = form

    def form(self, alpha):
        return self._form


def _misfit_clause(rig_params: Mapping[str, Mapping]) -> str:
    """The rigs whose ``plant_model`` misses its measured force by more than
    :data:`~seft_ros.core.stability.MAX_PLANT_MISFIT` (its stated ``uncertainty.relative``),
    as a clause of a calibration's refusal ('' when none): the loop calibrated is that
    model's, which is not the rig's."""
    from seft_ros.core import stability
    poor = [(rig, stability._plant_misfit(p)) for rig, p in rig_params.items()]
    poor = [(rig, m) for rig, m in poor if m > stability.MAX_PLANT_MISFIT]
    if not poor:
        return ''
    which = ', '.join(f"{f'rig {rig}' if rig else 'the rig'}'s plant_model misses its force by "
                      f'{100 * m:.2g} % NRMS' for rig, m in poor)
    return (f'; {which} (above {100 * stability.MAX_PLANT_MISFIT:g} %, MAX_PLANT_MISFIT: a '
            'nonlinear actuator, friction or valve flow), and the force controller and '
            "inverse designed on it are not the rig's: identify it again (seft identify) or "
            "enter the lab's own controller")


def _pole_text(z: complex, dt: float) -> str:
    """A sampled pole ``z = exp(lambda dt)`` as its frequency [Hz] and damping ratio [%]."""
    lam = np.log(complex(z)) / dt
    return (f'{abs(lam) / (2.0 * math.pi):.2f} Hz, '
            f'{-100.0 * lam.real / max(abs(lam), 1e-300):.2g} % damped')


def _specimen_clause(params: Mapping, declared: Mapping) -> str | None:
    """The declared specimen (the law's, ``model_parameters``) against the loop model's
    (:func:`~seft_ros.core.force_loop.force_loop_plant`), as a clause of a refused
    calibration, when its mass or stiffness differs by more than
    :data:`SPECIMEN_TOLERANCE`; None when they agree or the loop has no specimen."""
    from seft_ros.core.force_loop import force_loop_plant
    try:
        spec = force_loop_plant(params).specimen
    except ParameterError:
        return None
    if spec is None:
        return None
    m, k = float(declared['mass_kg']), float(declared['stiffness_N_per_m'])
    ratios = spec.mismatch(m, k, SPECIMEN_TOLERANCE)
    if ratios is None:
        return None
    return (f'the declared specimen ({m:.4g} kg, {k:.4g} N/m, '
            f"{math.sqrt(k / m) / (2.0 * math.pi):.2f} Hz: predictor_* or the rig's) is "
            f"{ratios[0]:.3g} x the loop model's mass and "
            f'{ratios[1]:.3g} x its stiffness ({spec.mass_kg:.4g} kg, '
            f'{spec.stiffness_N_per_m:.4g} N/m, {spec.natural_frequency_hz:.2f} Hz), and the '
            "pole sought is the declared specimen's reference structure's: declare the "
            "specimen the loop has (a plant_model's specimen, as seft identify wrote it), "
            "or use predictor_calibration none; adaptive identifies the specimen from the run")


def pole_calibration(params: Mapping) -> np.ndarray:
    """The offset of the ``model`` law's gains ``K`` that gives the run's closed loop the
    reference structure's pole (module notes).

    Parameters
    ----------
    params : mapping
        A rig's resolved parameters (``predictor`` 'model' on a valve-driven rig, ``alpha``).

    Returns
    -------
    ndarray, shape (3,)
        ``(dK_x [N/m], dK_v [N s/m], beta_scale [-])``: the gains' offset and the factor on
        the ground force's gain ``beta`` that makes the closed loop's response to the
        ground force the reference's in the least squares over the response band (with the
        step average of the ground; :func:`ground_gain_scale`); ``(0, 0, 1)`` at
        ``alpha = 0`` (no feedback).

    Raises
    ------
    ParameterError
        The loop has no linear model, or the correction the pole needs is beyond
        ``MAX_CORRECTION`` of the gains (each at least ``GAIN_FLOOR`` of the specimen's
        scale) or does not converge (the message says which).
    """
    # eigenvalue problems of ~200 states: on one BLAS thread 2.4 s, on two 20 s (a loaded
    # 2-core host: the threads spin against the other work)
    with single_blas_thread():
        return _pole_calibration(params)


def _pole_calibration(params: Mapping) -> np.ndarray:
    from seft_ros.core import stability
    from seft_ros.core.predictors import ModelPredictor, model_parameters
    base = dict(params, predictor_calibration='none')
    alpha = float(base['alpha'])
    if alpha == 0.0:
        return np.array([0.0, 0.0, 1.0])
    key = tuple(sorted((k, v) for k, v in base.items() if k != 'structure'))
    if key in _CACHE:
        return _CACHE[key].copy()
    dt = float(base['dt'])
    mp = model_parameters(base)
    target = reference_pole(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'],
                            alpha, dt)
    pred0 = ModelPredictor.from_parameters(base)
    k0 = np.array(pred0._gain, dtype=float)
    steps = _STEP * np.maximum(np.abs(k0), 1.0)

    mass = float(base['mass_kg'])

    def matrix(offset):
        """The closed loop at `offset`: its matrix, the input vector of the ground force
        (``X[k+1] = M X[k] + b G[k+1]``) and the displacement's output row."""
        pred = ModelPredictor.from_parameters(base, gain_offset=offset)
        window = max(stability._WINDOW, (3 * pred.loop_inverse.taps.shape[0]) // 2 + 64)
        taps, cmd = stability._identify(pred, 'model', dt, False, window)
        form = stability.PredictorForm.fir(taps, cmd, source='identified')
        try:
            loop = stability.LoopModel(base, _Fixed(form))
        except stability.NoLinearModelError as exc:
            raise ParameterError(f'predictor_calibration poles: {exc}') from None
        lay = loop.layout(form)
        ground = np.zeros(lay['size'])
        ground[lay['w']] = form.b[:, 5]                  # F = G - alpha m a_hat(..., G)
        ground[lay['F']] = 1.0 - alpha * mass * form.d[5]
        x_row = np.zeros(lay['size'])
        x_row[lay['z']] = lay['outputs'][0]
        return loop.matrix(alpha), ground, x_row

    m0, ground0, x_row = matrix(np.zeros(2))
    dm, dg = [], []
    for i in range(2):
        mi, gi, _ = matrix(np.eye(2)[i] * steps[i])
        dm.append((mi - m0) / steps[i])
        dg.append((gi - ground0) / steps[i])

    start = np.ones(m0.shape[0], dtype=complex)        # ARPACK's start: reproducible
    poles = {}

    def pole(offset):
        """The closed loop's eigenvalue nearest the target, by shift-invert (3x faster than
        all of them at 213 states); kept by the offset (the converged one is asked again)."""
        key = offset.tobytes()
        if key not in poles:
            mm = (m0 + offset[0] * dm[0] + offset[1] * dm[1]).astype(complex)
            poles[key] = complex(eigs(mm, k=1, sigma=target, v0=start,
                                      return_eigenvectors=False)[0])
        return poles[key]

    offset = np.zeros(2)
    for _ in range(_ITERATIONS):
        e = pole(offset)
        err = np.array([e.real - target.real, e.imag - target.imag])
        if np.max(np.abs(err)) < 1e-12:
            break
        jac = np.zeros((2, 2))
        for i in range(2):
            h = steps[i]
            e2 = pole(offset + np.eye(2)[i] * h)
            jac[:, i] = [(e2.real - e.real) / h, (e2.imag - e.imag) / h]
        try:
            offset = offset - np.linalg.solve(jac, err)
        except np.linalg.LinAlgError:         # the pole does not move with the gains
            break
    e = pole(offset)
    gain_scale = np.maximum(np.abs(k0), GAIN_FLOOR * np.array([
        mp['stiffness_N_per_m'], 2.0 * math.sqrt(mp['stiffness_N_per_m'] * mp['mass_kg'])]))
    if abs(e - target) > 1e-8 or np.any(np.abs(offset) > MAX_CORRECTION * gain_scale):
        shift = (f"{offset[0]:.4g} N/m, {offset[1]:.4g} N s/m of the law's {k0[0]:.4g}, "
                 f'{k0[1]:.4g}')
        if abs(e - target) <= 1e-8:
            found = (f"the loop's model reaches the reference structure's pole "
                     f"({_pole_text(target, dt)}) only with the law's gains offset by "
                     f'{shift} (beyond {100 * MAX_CORRECTION:g} % of them)')
        elif (np.all(np.isfinite(offset))
                and np.all(np.abs(offset) <= _DIVERGED * MAX_CORRECTION * gain_scale)):
            found = (f"the loop's model does not reach the reference structure's pole "
                     f"({_pole_text(target, dt)}) with the law's gains (offset {shift}: pole "
                     f'{_pole_text(e, dt)})')
        else:           # a diverged iteration: its offsets and pole say nothing
            found = ("the search for the law's gains that give the loop the reference "
                     f"structure's pole ({_pole_text(target, dt)}) diverged (the loop's pole "
                     f"nearest it at the law's own gains: {_pole_text(pole(np.zeros(2)), dt)})")
        why = _specimen_clause(base, mp) or ('check the force-loop inverse (predictor_loop_*) '
                                             'or use predictor_calibration none')
        raise ParameterError(f'predictor_calibration poles: {found}: {why}'
                             + _misfit_clause({'': base}))
    # the ground force's gain: the test's response to the ground force, the pole exact, as
    # the reference's in the least squares over the response band (module notes)
    scale = ground_gain_scale(m0 + offset[0] * dm[0] + offset[1] * dm[1],
                              ground0 + offset[0] * dg[0] + offset[1] * dg[1], x_row,
                              mp, alpha, dt, target)
    if not (math.isfinite(scale) and abs(scale - 1.0) < MAX_CORRECTION):
        raise ParameterError(f'predictor_calibration poles: the ground force would need a gain '
                             f'of {scale:.4g}: check the force-loop inverse (predictor_loop_*) '
                             'or use predictor_calibration none' + _misfit_clause({'': base}))
    result = np.array([offset[0], offset[1], scale])
    if len(_CACHE) >= 16:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = result.copy()
    return result


#: The size of the logarithmic grid the ground force's gain is fitted on
#: (:func:`ground_gain_scale`, :func:`~seft_ros.core.stability.response_grid`).
GROUND_GRID_POINTS = 400


def ground_gain_scale(mat: np.ndarray, ground: np.ndarray, x_row: np.ndarray, specimen,
                      alpha: float, dt: float, target: complex) -> float:
    """The factor on the ground force's gain that makes the closed loop's displacement response
    to the ground force the reference structure's, in the least squares over its band.

    With ``H_t`` the loop's response (``X[k+1] = M X[k] + b G[k+1]``, ``x = c X``, times the
    step average of the ground, the hold factor) and ``H_r = 1 / (k - (1 + alpha) m w^2 +
    i w c)`` the reference's (paper Eq. 2.1), on a grid weighted by the firm-ground
    Kanai-Tajimi spectrum ``S`` (:func:`~seft_ros.core.stability.kanai_tajimi`)::

        s = sum(S |H_t| |H_r| dw) / sum(S |H_t|^2 dw)

    (magnitudes: the test's lag is removed as the comparison removes it). A lightly damped
    reference weighs its resonance, where the match of one frequency did the same; a well
    damped one its whole band: on the family's 50 Hz, 5 % specimen (``valve_2nd_order``,
    dt 1 ms, the pole placed exactly) the loop's response was 0.995 of the reference's below
    20 Hz and 1.027 at the 35 Hz resonance (alpha 1), and the resonance's factor, 0.978, cost
    the rest of the band: 2.41 % NRMS x against 1.71 % with no factor.

    Parameters
    ----------
    mat : ndarray, shape (n, n)
        The closed loop's matrix.
    ground, x_row : ndarray, shape (n,)
        The ground force's input vector and the displacement's output row.
    specimen : mapping
        ``mass_kg``, ``damping_N_s_per_m``, ``stiffness_N_per_m`` of the law's model.
    alpha, dt : float
        Mass ratio [-], sample period [s].
    target : complex
        The reference structure's sampled pole (its frequency refines the grid).

    Returns
    -------
    float
        The factor [-]; ``inf`` where the loop has a pole on the unit circle.
    """
    from seft_ros.core.stability import response_grid
    m, c, k = (float(specimen[key]) for key in
               ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'))
    lam = np.log(target) / dt
    f0 = abs(lam.imag) / (2.0 * math.pi)
    f, weight = response_grid(f0, max(-lam.real, 1e-3 * abs(lam)) / (2.0 * math.pi), dt,
                              GROUND_GRID_POINTS)
    w = 2.0 * math.pi * f
    z = np.exp(1j * w * dt)
    # the modal sum over M's eigenvalues; the loop's FIR delay chains make M defective (its
    # eigenvectors near parallel), so it is checked against a direct solve at the resonance
    # and replaced by one solve per frequency where it is off (measured on the 32 Hz column
    # and the family's 50 Hz, 5 % specimen: within 6e-8 of the solves at 600 frequencies; a
    # complex Schur form with triangular solves was 0.4 % off the solves on the column)
    eig, vec = np.linalg.eig(mat)
    if np.any(np.abs(np.abs(eig) - 1.0) < 1e-12):
        return math.inf
    left = x_row @ vec
    right = np.linalg.solve(vec, ground)
    h_test = np.abs(((left * right)[None, :] / (z[:, None] - eig[None, :])).sum(axis=1))
    eye = np.eye(mat.shape[0])
    i0 = int(np.argmin(np.abs(f - f0)))
    if not abs(h_test[i0] / abs(x_row @ np.linalg.solve(z[i0] * eye - mat, ground))
               - 1.0) < 1e-6:
        h_test = np.abs([x_row @ np.linalg.solve(zi * eye - mat, ground) for zi in z])
    hold = np.abs(np.sinc(w * dt / (2.0 * math.pi)))     # |(e^{iwdt} - 1) / (iwdt)|
    h_test = h_test * hold
    h_ref = 1.0 / np.abs(k - (1.0 + alpha) * m * w * w + 1j * w * c)
    return float((weight * h_test * h_ref).sum() / (weight * h_test * h_test).sum())


#: The coupled loop's calibrations made last (:func:`structure_calibration`), by the run's
#: parameters.
_STRUCTURE_CACHE: dict = {}


def structure_calibration(params: Mapping) -> dict:
    """The corrections of the interface force each calibrated rig's compensator sees that
    give the whole test's sampled loop the reference structure's modes (module notes).

    Applies to the rigs of a structure with ``predictor: model`` or ``adaptive`` and
    ``predictor_calibration: poles`` whose DOF carries computational springs or dashpots
    (the lab path writes ``poles`` for a rig it identified). An ``adaptive`` rig's loop is
    calibrated as the ``model`` law it identifies toward, at the specimen of its plant model
    of data (:func:`~seft_ros.core.predictors.calibrated_law_of_adaptive`, as its one-DOF
    law's calibration), and its interface prediction keeps these corrections while its
    identification moves its specimen model (a lab plant seft did not write, a 19.5 Hz
    first story under a 17.6 Hz computational one: 7.5 % NRMS x uncalibrated, 0.43 % with
    the prior 20 % off). With ``n_r`` such rigs the ``min(n_modes, 2 n_r)``
    lowest underdamped modes of the declared structure (Eq. 1) are placed: their sampled
    poles ``exp(lambda dt)`` become eigenvalues of the loop's matrix, to 1e-8.

    Parameters
    ----------
    params : mapping
        The run's resolved parameters.

    Returns
    -------
    dict
        ``{rig: (s_c, b_i [s^2], c_r [N s/m], m_r [kg])}``, the `corrections` of
        :class:`~seft_ros.core.substructure.InterfacePredictor`; empty when no rig asks
        for it (the study's test, a structure without such a rig).

    Raises
    ------
    ParameterError
        The loop has no linear model, or the modes are not reached within
        ``MAX_CORRECTION`` (relative to 1 for the dashpots' scale, to ``1/omega^2`` of the
        highest mode placed for the inerter, to the rig's specimen model's critical damping
        and mass for the dashpot and the mass).
    """
    with single_blas_thread():
        return _structure_calibration(params)


def _structure_calibration(params: Mapping) -> dict:
    from seft_ros.core.structure import test_setup
    setup = test_setup(params)
    if setup.is_study:
        return {}
    sub = setup.substructures
    s = sub.structure
    rigs = [r for r in sub.coupled_rigs
            if setup.rig_params[r].get('predictor') in ('model', 'adaptive')
            and setup.rig_params[r].get('predictor_calibration', 'none') == 'poles']
    if not rigs:
        return {}
    key = json.dumps(dict(params), sort_keys=True, default=repr)
    if key in _STRUCTURE_CACHE:
        return dict(_STRUCTURE_CACHE[key])
    # an adaptive rig's loop is calibrated as the model law it identifies toward (as its
    # one-DOF calibration, predictors._adaptive_law_correction): its interface prediction
    # keeps these corrections as the identification moves its specimen model
    from seft_ros.core.predictors import calibrated_law_of_adaptive
    from seft_ros.core.structure_design import with_rig_values
    adaptive = [r for r in rigs if setup.rig_params[r].get('predictor') == 'adaptive']
    for r in adaptive:
        params = with_rig_values(params, r, calibrated_law_of_adaptive(setup.rig_params[r]))
    if adaptive:
        setup = test_setup(params)
        sub = setup.substructures
        s = sub.structure
    # the loop models (seft_plant_sim) only for a test that asks: a controller-side install
    # without the plant simulation builds the others
    from seft_ros.core import stability
    from seft_ros.core.predictors import model_parameters
    from seft_ros.core.substructure import _rows, structure_matrices
    dt = float(params['dt'])
    n = s.n
    ax, av, _ = _rows(structure_matrices(sub), range(n))      # the rows of Eq. 1
    a = np.block([[np.zeros((n, n)), np.eye(n)], [ax, av]])
    lam = np.linalg.eigvals(a)
    lam = sorted(lam[lam.imag > 0], key=lambda x: x.imag)[:2 * len(rigs)]
    if not lam:                     # no mode that vibrates: nothing to place
        return {}
    target = np.exp(np.array(lam) * dt)
    scales = []
    omega_max = max(abs(x.imag) for x in lam)
    for r in rigs:
        mp = model_parameters(setup.rig_params[r])
        k, m = float(mp['stiffness_N_per_m']), float(mp['mass_kg'])
        scales.append((1.0, 1.0 / omega_max ** 2, 2.0 * math.sqrt(k * m), m))
    identity = {r: (1.0, 0.0, 0.0, 0.0) for r in rigs}

    def loop(corrections):
        try:
            return stability.TestLoop(params, interface_corrections=corrections).matrix
        except stability.NoLinearModelError as exc:
            raise ParameterError(f'predictor_calibration poles: {exc}') from None
    m0 = loop(identity)
    basis = []
    for r, scale in zip(rigs, scales):
        for i in range(4):
            c = list(identity[r])
            c[i] += scale[i]
            basis.append(loop(dict(identity, **{r: tuple(c)})) - m0)

    def residual(v):
        mm = m0 + sum(vi * bi for vi, bi in zip(v, basis))
        ev = np.linalg.eigvals(mm)
        nearest = np.array([ev[np.argmin(np.abs(ev - z))] for z in target])
        d = nearest - target
        return np.concatenate([d.real, d.imag])

    v = np.zeros(len(basis))
    h = 1e-6
    res = residual(v)
    for _ in range(_ITERATIONS):
        if np.max(np.abs(res)) < 1e-12:
            break
        jac = np.column_stack([(residual(v + h * np.eye(v.size)[i]) - res) / h
                               for i in range(v.size)])
        v = v + np.linalg.lstsq(jac, -res, rcond=None)[0]
        res = residual(v)
    if not np.max(np.abs(res)) <= 1e-8 or np.any(np.abs(v) > MAX_CORRECTION):
        freqs = ', '.join(f'{abs(x.imag) / (2 * math.pi):.3g}' for x in lam)
        raise ParameterError(
            "predictor_calibration poles: the test's loop does not reach the reference "
            f"structure's modes ({freqs} Hz) with the interface corrections of "
            f'{", ".join(rigs)} (pole error {np.max(np.abs(res)):.2g}, largest correction '
            f'{np.max(np.abs(v)):.3g} of {MAX_CORRECTION}): check the force-loop inverse '
            '(predictor_loop_*) or use predictor_calibration none'
            + _misfit_clause({r: setup.rig_params[r] for r in setup.rig_names}))
    out = {}
    for j, (r, scale) in enumerate(zip(rigs, scales)):
        vv = v[4 * j:4 * j + 4]
        out[r] = (1.0 + float(vv[0] * scale[0]), float(vv[1] * scale[1]),
                  float(vv[2] * scale[2]), float(vv[3] * scale[3]))
    if len(_STRUCTURE_CACHE) >= 16:
        _STRUCTURE_CACHE.pop(next(iter(_STRUCTURE_CACHE)))
    _STRUCTURE_CACHE[key] = dict(out)
    return out
