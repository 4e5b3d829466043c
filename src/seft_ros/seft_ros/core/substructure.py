"""The computational substructure of a test and its coupling to the rigs (no rclpy).

Every test is a structure (:mod:`seft_ros.core.structure`): physical degrees of freedom
(DOFs) ``P``, each tested on a rig, and the computational part integrated by the
reference-force builder (:class:`~seft_ros.core.reference_force.ReferenceForceBuilder`).
The actuator of rig ``p`` applies Eq. 2 of :mod:`seft_ros.core.structure`::

    f_p = -(m_p + mu_p) iota_p xg'' - mu_p x_p'' + I_p,   I_p = -[C_c x' + K_c x]_p      (2)

the effective force, the rigid computational mass ``mu_p`` on the DOF (``alpha m`` of
paper Eq. 2.5) and the **interface force** ``I_p`` of the computational springs and dashpots
attached to it. The reference study's test is the case ``I = 0`` (one DOF, only a rigid
mass). This module holds what a structure adds to one rig's reference force:

**The computational DOFs** ``Q`` (``M_QP = 0``)::

    M_QQ x_Q'' + C_QQ x_Q' + K_QQ x_Q = -M_QQ iota_Q xg'' - K_QP x_P - C_QP x_P'     (3)

advanced from sample ``k-2`` to ``k-1`` once the measurement of ``k-1`` has arrived, with the
physical motion over the step taken as the cubic Hermite interpolant of the measured
displacements and velocities at both ends and the ground acceleration as linear between
samples (the record's own interpolation, as in the analytical reference). For such inputs the
step is exact: :func:`seft_msgs_py.sampling.zoh` (``scipy.signal.cont2discrete``, method
'zoh') of (3) augmented with the input's polynomial generator (:func:`hermite_step`).
Order: the Hermite interpolant's error is ``O(dt^4)`` per step (fourth order); the
transition matrix is ``exp(A_QQ dt)``, so the scheme is unconditionally stable (no step limit
as with central differences or Newmark's explicit scheme). :class:`StructureState` keeps
that state, and predicts the DOFs of rigs whose measurement has not arrived (a rig commanded
on another host) as the whole structure (1) would move them.

**The interface force** ``I_p`` each rig's compensator sees (its ``interface`` mode,
:mod:`seft_ros.core.predictors`): ``'sampled'`` (``none``: Eq. 2 at sample ``k-1``, the
study's timing, paper Eq. 5.3: the loop delay then acts as negative damping on the coupling,
about ``k_c tau`` across a computational spring ``k_c``), ``'extrapolated'``
(``polynomial``: the sampled interface forces extrapolated with the compensator's own
weights) or ``'predicted'`` (``model``, ``adaptive``, ``ats``: :class:`InterfacePredictor`,
its average over the interval where the new force acts, ``[t_k + tau_p, t_k+1 + tau_p)``,
from the coupled model of the test: every rig this builder commands as its specimen model
under the forces already sent, the other DOFs as the whole structure (1), the record linear).
The compensator then treats ``G_p + I_p`` as the external force on its DOF, exactly as it
treats the effective force ``G = -(1 + alpha) m xg''`` in the study's test.

References
----------
N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.4-2.5 and 5.3.
J. E. Carrion and B. F. Spencer Jr. (2007), Model-based strategies for real-time hybrid
testing, NSEL Report 006 (model-based delay compensation). A. K. Chopra, Dynamics of
Structures, Ch. 9-11 (multi-degree-of-freedom systems).
"""

from dataclasses import dataclass
import math
from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.sampling import LazyLinearMap, linear_map, single_blas_thread, split_delay, zoh
from seft_ros.core.models import model_plugin
from seft_ros.core.structure import Substructures

__all__ = ['Matrices', 'structure_matrices', 'hermite_step', 'InterfacePredictor',
           'StructureState', 'SpecimenModel', 'INTERFACE_MODES', 'ComputationalPart',
           'computational_part', 'tangent_matrices']

#: How a rig's compensator sees the interface force (module notes).
INTERFACE_MODES = ('sampled', 'extrapolated', 'predicted')


@dataclass(frozen=True)
class SpecimenModel:
    """A rig's specimen as a compensator models it: ``m x'' + c x' + k x = f``.

    Attributes
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float
        m [kg], c [N s/m], k [N/m].
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float

    def moved(self, other: 'SpecimenModel', tolerance: float) -> bool:
        """Whether any value differs from `other`'s by more than `tolerance` (relative)."""
        return any(abs(a - b) > tolerance * abs(b) for a, b in (
            (self.mass_kg, other.mass_kg), (self.damping_N_s_per_m, other.damping_N_s_per_m),
            (self.stiffness_N_per_m, other.stiffness_N_per_m)))


@dataclass(frozen=True)
class Matrices:
    """The whole structure's matrices as a builder models it (Eq. 1).

    Attributes
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : ndarray, shape (n, n)
    influence : ndarray, shape (n,)
    """

    mass_kg: np.ndarray
    damping_N_s_per_m: np.ndarray
    stiffness_N_per_m: np.ndarray
    influence: np.ndarray


def structure_matrices(sub: Substructures,
                       models: Mapping[int, SpecimenModel] | None = None) -> Matrices:
    """The whole structure with some rigs' specimens replaced by models.

    Parameters
    ----------
    sub : Substructures
    models : mapping of int to SpecimenModel, optional
        Position of a rig (in ``sub.structure.rig_names``) -> the model that replaces its
        specimen's ``m, c, k`` on its DOF's diagonal (an identified specimen). Default none:
        the declared structure itself.

    Returns
    -------
    Matrices
    """
    s = sub.structure
    if not models:
        return Matrices(s.mass_kg, s.damping_N_s_per_m, s.stiffness_N_per_m, s.influence)
    m, c, k = sub.mass_c_kg.copy(), sub.damping_c_N_s_per_m.copy(), sub.stiffness_c_N_per_m.copy()
    pi = s.physical_index
    for j, i in enumerate(pi):
        model = models.get(j)
        if model is None:
            m[i, i] += sub.specimen_mass_kg[j]
            c[i, i] += sub.specimen_damping_N_s_per_m[j]
            k[i, i] += sub.specimen_stiffness_N_per_m[j]
        else:
            m[i, i] += model.mass_kg
            c[i, i] += model.damping_N_s_per_m
            k[i, i] += model.stiffness_N_per_m
    return Matrices(m, c, k, s.influence)


def _rows(matrices: Matrices, unknown: Sequence[int]):
    """``x_U'' = -M_UU^-1 (K_U. x + C_U. v) - iota_U g``: the unknown DOFs' rows of Eq. 1.

    Returns ``(Ax, Av, iota_U)``: ``Ax``, ``Av`` of shape (n_u, n) on the displacements and
    velocities of every DOF (structure order), ``iota_U`` of shape (n_u,). Valid because no
    physical DOF has a mass coupling (:func:`~seft_ros.core.structure.split`), so
    ``(M iota)_U = M_UU iota_U``.
    """
    u = list(unknown)
    minv = np.linalg.inv(matrices.mass_kg[np.ix_(u, u)])
    return (-minv @ matrices.stiffness_N_per_m[u, :], -minv @ matrices.damping_N_s_per_m[u, :],
            matrices.influence[u])


def hermite_step(sub: Substructures, known: Sequence[int], dt: float,
                 matrices: 'Matrices | None' = None) -> np.ndarray:
    """The exact step of the DOFs whose motion is not measured, under Hermite-interpolated
    measured motion and a linear record.

    ``U`` are the DOFs not in `known` (the computational ones, and physical ones whose
    measurement is not there yet), moving as in the whole structure (Eq. 1) driven by the
    `known` physical DOFs' measured motion: ``z1 = S @ [x_U0, v_U0, x_K0, v_K0, x_K1, v_K1,
    g0, g1]`` (sample ``0`` at the start of the step, ``1`` at its end).

    Parameters
    ----------
    sub : Substructures
    known : sequence of int
        DOF indices of the measured (physical) DOFs ``K``, in order.
    dt : float > 0
        Step [s].
    matrices : Matrices, optional
        The whole structure the unknown DOFs move in (default the declared one,
        :func:`structure_matrices`).

    Returns
    -------
    S : ndarray, shape (2 n_u, 2 n_u + 4 n_k + 2)

    Notes
    -----
    The displacement of a known DOF over the step is the cubic
    ``x(t) = a0 + a1 t + a2 t^2 + a3 t^3`` with ``a0 = x0``, ``a1 = v0``,
    ``a2 = (3 (x1 - x0) / h - 2 v0 - v1) / h``, ``a3 = (2 (x0 - x1) / h + v0 + v1) / h^2``;
    its generator ``[x, x', x'', x''']`` (``x'''' = 0``) starts at ``[a0, a1, 2 a2, 6 a3]``.
    Augmented with it and with the record's ``[g]`` (slope held), Eq. 1's rows ``U`` form a
    linear system without other inputs, stepped exactly by ``scipy.signal.cont2discrete``
    (method 'zoh', :func:`~seft_msgs_py.sampling.zoh`). The interpolant's error is
    ``O(dt^4)`` per step; the transition matrix is ``exp(A_UU dt)``, so the scheme is
    unconditionally stable.
    """
    s = sub.structure
    ki = list(known)
    ui = [i for i in range(s.n) if i not in ki]
    n_k, n_u = len(ki), len(ui)
    h = float(dt)
    nz = 2 * n_u
    size = nz + 4 * n_k + 1
    a = np.zeros((size, size))
    b = np.zeros((size, 1))
    ax, av, iota = _rows(matrices or structure_matrices(sub), ui)
    xu, vu = slice(0, n_u), slice(n_u, nz)
    gen = [slice(nz + i * n_k, nz + (i + 1) * n_k) for i in range(4)]   # x, x', x'', x'''
    ig = size - 1
    a[xu, vu] = np.eye(n_u)
    a[vu, xu] = ax[:, ui]
    a[vu, vu] = av[:, ui]
    a[vu, gen[0]] = ax[:, ki]
    a[vu, gen[1]] = av[:, ki]
    a[vu, ig] = -iota
    for i in range(3):
        a[gen[i], gen[i + 1]] = np.eye(n_k)
    b[ig, 0] = 1.0
    phi, gamma = zoh(a, b, h)
    # initial state of the augmented system from [x_U0, v_U0, x_K0, v_K0, x_K1, v_K1, g0, g1]
    width = nz + 4 * n_k + 2
    init = np.zeros((size, width))
    init[:nz, :nz] = np.eye(nz)
    ix0, iv0 = slice(nz, nz + n_k), slice(nz + n_k, nz + 2 * n_k)
    ix1, iv1 = slice(nz + 2 * n_k, nz + 3 * n_k), slice(nz + 3 * n_k, nz + 4 * n_k)
    eye = np.eye(n_k)
    init[gen[0], ix0] = eye
    init[gen[1], iv0] = eye
    # x'' = 2 a2 = 2 (3 (x1 - x0) / h - 2 v0 - v1) / h
    init[gen[2], ix1] = 6.0 / h ** 2 * eye
    init[gen[2], ix0] = -6.0 / h ** 2 * eye
    init[gen[2], iv0] = -4.0 / h * eye
    init[gen[2], iv1] = -2.0 / h * eye
    # x''' = 6 a3 = 6 (2 (x0 - x1) / h + v0 + v1) / h^2
    init[gen[3], ix0] = 12.0 / h ** 3 * eye
    init[gen[3], ix1] = -12.0 / h ** 3 * eye
    init[gen[3], iv0] = 6.0 / h ** 2 * eye
    init[gen[3], iv1] = 6.0 / h ** 2 * eye
    init[ig, width - 2] = 1.0
    slope = np.zeros((1, width))
    slope[0, width - 2], slope[0, width - 1] = -1.0 / h, 1.0 / h
    return (phi @ init + gamma @ slope)[:nz]


class InterfacePredictor:
    """The interface forces of rigs over the intervals where their new forces act.

    From sample ``k-1`` on, the builder's model of the test (module notes): the DOFs ``L`` of
    the rigs it commands move as their specimen models (``m x'' + c x' + k x = F``) under the
    desired forces, rig ``o``'s force ``F_o[i]`` held over ``[t_i + tau_o, t_i+1 + tau_o)``
    (its force loop inverted to the pure delay ``tau_o``, or the delay rig's delay); every
    other DOF ``U`` moves as in the whole structure (the rows ``U`` of Eq. 1 with
    `matrices`); the record is linear between samples. The forces not built yet (``F_o[k]``,
    and for a rig of shorter delay those after it) are taken as the latest, ``F_o[k-1]``:
    their effect on an interface force inside one step is of order ``k_c dt^2 / m`` times
    their change (a few tenths of a percent of a step's force change for the study's rig).
    Everything is linear: the map from the state at ``k-1``, the forces sent and the record
    to the predicted interface forces is one matrix, summed in Python and compiled once it
    is used (:class:`~seft_msgs_py.sampling.LazyLinearMap`: a part that yields makes a new
    one at nearly every step), the pieces between the forces' switching
    instants and the samples integrated exactly (``scipy.signal.cont2discrete``, method
    'zoh', of the model augmented with ``int x`` and ``g``).

    Parameters
    ----------
    sub : Substructures
    local : sequence of int
        Positions (in ``sub.structure.rig_names``) of the rigs the builder commands.
    models : sequence of SpecimenModel
        Each local rig's specimen model, in the order of `local`.
    taus_s : sequence of float >= 0
        Each local rig's loop delay [s], in the order of `local`.
    targets : sequence of int
        Indices into `local` of the rigs whose interface force is predicted.
    dt : float > 0
        Control period [s].
    matrices : Matrices, optional
        The whole structure the other DOFs move in (default the declared one).
    offsets : sequence of bool, optional
        Per local rig: whether its model carries a restoring-force offset ``d`` (a member
        that yields: its model is the tangent stiffness, and ``d`` = the measured restoring
        force less the model's at ``t_k-1``, held over the prediction:
        ``m x'' + c x' + k_t x + d = F``).
    stiffness_c_N_per_m : ndarray (n, n), optional
        The computational part's stiffness the interface forces are predicted with (a
        tangent of a model that yields, :func:`tangent_matrices`; default
        ``sub.stiffness_c_N_per_m``, the linearization's); `matrices` must hold it too.
    corrections : sequence of (float, float, float, float) or None, optional
        Per target (in the order of `targets`), the coupled loop's calibration
        (:func:`~seft_ros.core.law_calibration.structure_calibration`), or None for none:
        ``(s_c, b_i, c_r, m_r)``, the interface force the compensator sees taken as
        ``-(1/dt) [s_c C_c[p, :] (x(b) - x(a)) + K_c[p, :] (X(b) - X(a)) + b_i K_c[p, :]
        (v(b) - v(a)) + c_r (x_p(b) - x_p(a)) + m_r (v_p(b) - v_p(a))]``: the computational
        dashpots' force scaled, an inerter along the computational springs (``b_i`` [s^2]),
        and a dashpot ``c_r`` [N s/m] and a mass ``m_r`` [kg] on the rig's own DOF, each
        over the same interval; none of them acts on a static deflection.

    Attributes
    ----------
    history_steps : int
        ``nh``: the forces ``F_o[k-nh .. k-1]`` of each local rig are read.
    ground_steps : int
        ``ng``: the record ``g[k-1 .. k+ng-2]`` is read.
    width : int
        Length of ``q``: ``2 n + n_l nh + ng + n_d`` (``n_d`` the rigs with an offset).
    matrix : ndarray, shape (n_targets, width)
        ``I = matrix q`` [N].
    displacement_matrix : ndarray, shape (n, width)
        Every DOF's displacement in the middle of the first target's interval,
        ``x((a + b) / 2) = displacement_matrix q`` [m] (:meth:`displacements`).

    Notes
    -----
    ``q = [x (n), v (n), F_0[k-nh .. k-1], ..., F_{n_l-1}[...], g[k-1 .. k+ng-2], d...]``,
    every DOF's displacement and velocity at ``t_k-1`` in structure order, then the offsets.
    The interface force of target rig ``r`` at DOF ``p`` is the average over its interval,
    ``I_r = -(1/dt) [C_c[p, :] (x(b) - x(a)) + K_c[p, :] (X(b) - X(a))]`` with ``X = int x``
    and ``[a, b) = [t_k + tau_r, t_k+1 + tau_r)``.
    """

    def __init__(self, sub: Substructures, local: Sequence[int], models: Sequence[SpecimenModel],
                 taus_s: Sequence[float], targets: Sequence[int], dt: float,
                 matrices: Matrices | None = None, offsets: Sequence[bool] | None = None,
                 stiffness_c_N_per_m: np.ndarray | None = None, corrections=None):
        s = sub.structure
        k_c = sub.stiffness_c_N_per_m if stiffness_c_N_per_m is None else np.asarray(
            stiffness_c_N_per_m, dtype=float)
        dt = float(dt)
        n = s.n
        pi = list(s.physical_index)
        li = [pi[j] for j in local]
        n_l = len(li)
        ui = [i for i in range(n) if i not in li]
        taus = [float(t) for t in taus_s]
        if len(models) != n_l or len(taus) != n_l:
            raise ParameterError('interface predictor: expected one model and one delay per '
                                 'local rig')
        if corrections is not None and len(corrections) != len(targets):
            raise ParameterError('interface predictor: expected one correction (or None) per '
                                 'target')
        if any(not (t >= 0.0 and math.isfinite(t)) for t in taus):
            raise ParameterError(f'interface predictor: loop delays {taus!r}: expected >= 0')
        matrices = matrices or structure_matrices(sub)
        with_offset = [r for r in range(n_l) if offsets is not None and offsets[r]]
        n_d = len(with_offset)
        size = 3 * n + 1
        a = np.zeros((size, size))
        b = np.zeros((size, n_l + 1 + n_d))
        xs, vs, ixs, ig = slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n), 3 * n
        a[xs, vs] = np.eye(n)
        for r, (i, mod) in enumerate(zip(li, models)):
            a[n + i, i] = -mod.stiffness_N_per_m / mod.mass_kg
            a[n + i, n + i] = -mod.damping_N_s_per_m / mod.mass_kg
            b[n + i, r] = 1.0 / mod.mass_kg
        if ui:
            ax, av, iota = _rows(matrices, ui)
            for row, i in enumerate(ui):
                a[n + i, :n] = ax[row]
                a[n + i, n:2 * n] = av[row]
                a[n + i, ig] = -iota[row]
        for col, r in enumerate(with_offset):
            b[n + li[r], n_l + 1 + col] = -1.0 / models[r].mass_kg
        a[ixs, xs] = np.eye(n)
        b[ig, n_l] = 1.0
        splits = [split_delay(t, dt) for t in taus]
        nh = max(nn for nn, _ in splits) + 2
        end = max(2.0 * dt + taus[t] for t in targets) if targets else 2.0 * dt
        eps = 1e-9 * dt
        points = {0.0, end}
        j = 1
        while j * dt < end - eps:
            points.add(j * dt)
            j += 1
        for tau in taus:
            t = dt + tau
            while t < end - eps:
                if t > eps:
                    points.add(t)
                t += dt
        times = []
        for t in sorted(points):
            if not times or t - times[-1] > eps:
                times.append(t)
        ng = int(math.floor((end - eps) / dt)) + 2
        width = 2 * n + n_l * nh + ng + n_d
        col_f = 2 * n
        col_g = col_f + n_l * nh
        col_d = col_g + ng
        y = np.zeros((size, width))
        y[:2 * n, :2 * n] = np.eye(2 * n)
        y[ig, col_g] = 1.0
        wanted = {}
        for t in targets:
            for edge in (dt + taus[t], 2.0 * dt + taus[t]):
                wanted.setdefault(round(edge / eps), None)
        snapshots = {}
        cache = {}
        for t0, t1 in zip(times[:-1], times[1:]):
            key0 = round(t0 / eps)
            for w in wanted:
                if abs(w - key0) <= 2 and w not in snapshots:
                    snapshots[w] = y
            h = t1 - t0
            hk = round(h / eps)
            if hk not in cache:
                cache[hk] = zoh(a, b, h)
            phi, gamma = cache[hk]
            mid = 0.5 * (t0 + t1)
            u = np.zeros((n_l + 1 + n_d, width))
            for col in range(n_d):
                u[n_l + 1 + col, col_d + col] = 1.0
            for r, tau in enumerate(taus):
                i = int(math.floor((mid - dt - tau) / dt))      # F_r[k + i] acts
                base = col_f + r * nh + nh
                if i <= -1:
                    u[r, base + i] = 1.0
                else:                   # not built yet: extrapolated from F_r[k-2], F_r[k-1]
                    u[r, base - 1] = i + 2.0
                    u[r, base - 2] = -(i + 1.0)
            step = int(math.floor(mid / dt))                     # step k-1+step of the record
            u[n_l, col_g + step + 1] += 1.0 / dt
            u[n_l, col_g + step] -= 1.0 / dt
            y = phi @ y + gamma @ u
        key_end = round(times[-1] / eps)
        for w in wanted:
            if w not in snapshots and abs(w - key_end) <= 2:
                snapshots[w] = y
        rows = np.zeros((len(targets), width))
        for row, t in enumerate(targets):
            p = li[t]
            ya = snapshots[round((dt + taus[t]) / eps)]
            yb = snapshots[round((2.0 * dt + taus[t]) / eps)]
            diff = yb - ya
            corr = None if corrections is None else corrections[row]
            if corr is None:
                rows[row] = -(sub.damping_c_N_s_per_m[p] @ diff[xs] + k_c[p] @ diff[ixs]) / dt
            else:
                s_c, b_i, c_r, m_r = (float(v) for v in corr)
                rows[row] = -(s_c * (sub.damping_c_N_s_per_m[p] @ diff[xs])
                              + k_c[p] @ diff[ixs] + b_i * (k_c[p] @ diff[vs])
                              + c_r * diff[p] + m_r * diff[n + p]) / dt
        self.history_steps, self.ground_steps, self.width = nh, ng, width
        self.displacement_matrix = np.zeros((n, width))
        if targets:
            t = targets[0]
            self.displacement_matrix = 0.5 * (snapshots[round((dt + taus[t]) / eps)][xs]
                                              + snapshots[round((2.0 * dt + taus[t]) / eps)][xs])
        self._displacements = None
        self.offset_rigs = tuple(with_offset)
        self.matrix = rows
        # made anew at each new tangent of a part that yields: compiled once it lives
        self._map = LazyLinearMap(rows, name='interface_prediction')

    def __call__(self, q) -> tuple:
        """The predicted interface forces [N] of the targets from ``q`` (class notes)."""
        return self._map(q)

    def displacements(self, q) -> tuple:
        """Every DOF's predicted displacement [m] in the middle of the first target's
        interval, from ``q`` (``displacement_matrix``; compiled on first use)."""
        if self._displacements is None:
            self._displacements = LazyLinearMap(self.displacement_matrix, name='displacements')
        return self._displacements(q)


def tangent_matrices(sub: Substructures, matrices: Matrices,
                     stiffness_c_N_per_m: np.ndarray) -> Matrices:
    """`matrices` with the computational part's stiffness replaced by a tangent one.

    ``K = matrices.K - K_c + K_c,t``: the rigs' specimens (declared or identified) stay as
    `matrices` has them.

    Parameters
    ----------
    sub : Substructures
    matrices : Matrices
        The whole structure as the builder models it.
    stiffness_c_N_per_m : ndarray (n, n)
        ``K_c,t`` [N/m].

    Returns
    -------
    Matrices
    """
    k = matrices.stiffness_N_per_m - sub.stiffness_c_N_per_m + np.asarray(stiffness_c_N_per_m,
                                                                          dtype=float)
    return Matrices(matrices.mass_kg, matrices.damping_N_s_per_m, k, matrices.influence)


@runtime_checkable
class ComputationalPart(Protocol):
    """The computational part of a test as a builder integrates it: the plug-in point of a
    computational substructure (matrices, :class:`StructureState`; or a model of another
    program stepped once per sample).

    Sample ``j`` of every DOF is known once every rig's measurement of ``j`` is in
    (:meth:`observe`); the interface forces at the physical DOFs are what the computational
    part exerts on them there (Eq. 2's ``I``); ``matrices`` is its linear model for the
    compensators' prediction (the ``predicted`` interface forces, the stability analysis).

    A part that is not its linearization (a model that yields) may add two methods, which
    the builder calls when they are there (:class:`StructureState` has neither: its
    prediction is exact):

    * ``tangent() -> ndarray (n, n) or None``: the computational part's tangent stiffness
      ``K_c,t`` [N/m] at the latest sample (None: its linearization's ``K_c`` holds);
    * ``prediction_state(x, v, dofs, stiffness_c_N_per_m=None) -> (shifted, residual)``: the
      state the linear prediction with that stiffness starts from (the model's own
      restoring forces held over the prediction: the computational DOFs' displacements
      shifted) and what to add to its interface forces at `dofs`.

    Any part may add ``findings() -> dict``: what it found before or during the test (JSON-able;
    an OpenSees part's pushover), which the run's data carry
    (``ReferenceForceBuilder.part_findings``).

    Attributes
    ----------
    state_names : tuple of str
        The names of :meth:`recorded_state`'s values (``'<dof>/displacement_m'``, ...).
    matrices : Matrices
        The whole structure as the builder models it (its linearization).
    """

    state_names: tuple
    matrices: Matrices

    def observe(self, rig: int, measurement) -> None:
        """Hand in one rig's measurement (any rig, any order)."""

    def set_ground(self, step: int, acceleration_m_s2: float) -> None:
        """Hand in the ground acceleration of a sample [m/s^2]."""

    def state_at(self, j: int) -> tuple[list, list, int]:
        """Every DOF's displacement and velocity at sample `j` [m, m/s], and how many
        samples of it were predicted (measurements not in yet)."""

    def interface_forces(self, x, v, dofs) -> tuple:
        """The interface force [N] at each of `dofs` for the state `x`, `v` (Eq. 2)."""

    def recorded_state(self, x, v, j: int) -> tuple:
        """The computational DOFs' values named ``state_names`` at sample `j`."""

    def set_matrices(self, matrices: Matrices) -> None:
        """Model the DOFs not measured with `matrices` (an identified specimen)."""


def computational_part(sub: Substructures, dt: float) -> 'ComputationalPart':
    """The computational part of a split structure: :class:`StructureState` (the matrices of
    Eq. 1), or for a structure from a model of another program its plug-in's part
    (:mod:`seft_ros.core.models`; OpenSees: :class:`~seft_ros.opensees.part.OpenSeesPart`,
    the model stepped once per sample)."""
    kind = sub.structure.model_kind
    if kind is not None:
        return model_plugin(kind).part(sub, dt)
    return StructureState(sub, dt)


class StructureState:
    """Every DOF's displacement and velocity as a builder knows them, sample by sample: the
    :class:`ComputationalPart` of a structure given by its matrices.

    Measurements are handed in as they come (:meth:`observe`, any rig, any order).

    * **settled**: every rig's measurement is in up to sample ``s``; the computational DOFs
      are advanced to ``s`` exactly from the measured motion (:func:`hermite_step` with every
      physical DOF known);
    * **window** ``s < j``: the rigs whose measurement of ``j`` is not there (in real time,
      across a network) move as the whole structure would (Eq. 1 with the builder's
      :class:`Matrices`), with the computational DOFs, driven by the measured motion of the
      others (:func:`hermite_step` with those known), from their settled state. With every
      measurement in (lockstep, one host) the window is empty.

    Parameters
    ----------
    sub : Substructures
    dt : float > 0
        Control period [s].

    Attributes
    ----------
    state_names : tuple of str
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        per computational DOF.
    """

    def __init__(self, sub: Substructures, dt: float):
        s = sub.structure
        self.sub = sub
        self.dt = float(dt)
        self.rig_names = s.rig_names
        self._pi, self._qi = list(s.physical_index), list(s.computational_index)
        self.state_names = tuple(f'{s.dofs[i]}/{q}' for q in (
            'displacement_m', 'velocity_m_s', 'acceleration_m_s2') for i in self._qi)
        self.matrices = structure_matrices(sub)
        # measurements: per rig, step -> (x, v, a); the settled sample and state
        self._meas: list[dict] = [{} for _ in self.rig_names]
        self.ground: dict[int, float] = {}
        self._settled = 0               # every measurement in up to this sample (rest at 0)
        self._started = False           # the settled state holds sample 0's measurement
        self._x = [0.0] * s.n           # displacement and velocity of every DOF at _settled
        self._v = [0.0] * s.n
        self._maps: dict[tuple, object] = {}          # unknown DOFs -> compiled step
        self._interface: dict[tuple, object] = {}     # DOFs -> compiled interface forces
        self._acc = None
        if self._qi:
            with single_blas_thread():
                ax, av, iota_q = _rows(self.matrices, self._qi)
                self._acc = linear_map(np.hstack([ax, av, -iota_q[:, None]]),
                                       name='acceleration')

    def set_matrices(self, matrices: Matrices) -> None:
        """Model the DOFs not measured with `matrices` from now on (an identified specimen
        of a rig commanded elsewhere); the settled computational state does not depend on
        it."""
        self.matrices = matrices
        self._maps = {k: v for k, v in self._maps.items()
                      if not set(k) & set(self._pi)}

    def set_ground(self, step: int, acceleration_m_s2: float) -> None:
        """Hand in the ground acceleration of a sample [m/s^2]."""
        self.ground[step] = float(acceleration_m_s2)

    def interface_forces(self, x, v, dofs) -> tuple:
        """``-[C_c v + K_c x]`` [N] at each of `dofs` (Eq. 2), from every DOF's x and v."""
        key = tuple(dofs)
        fn = self._interface.get(key)
        if fn is None:
            sub = self.sub
            rows = [[-c for c in sub.stiffness_c_N_per_m[i]]
                    + [-c for c in sub.damping_c_N_s_per_m[i]] for i in key]
            fn = self._interface[key] = linear_map(rows, name='interface')
        return fn(list(x) + list(v))

    def recorded_state(self, x, v, j: int) -> tuple:
        """``x_Q, v_Q, a_Q`` of sample `j` [m, m/s, m/s^2] (``state_names``)."""
        qi = self._qi
        if not qi:
            return ()
        a_q = self.computational_acceleration(x, v, self.ground.get(j, 0.0))
        return tuple(x[i] for i in qi) + tuple(v[i] for i in qi) + tuple(a_q)

    def observe(self, rig: int, measurement) -> None:
        """Hand in one rig's measurement (a :class:`~seft_msgs_py.interface.Measurement`;
        a repeat replaces it)."""
        self._meas[rig][measurement.step] = (measurement.displacement_m,
                                             measurement.velocity_m_s,
                                             measurement.acceleration_m_s2)

    def has(self, rig: int, step: int) -> bool:
        """Whether rig `rig`'s measurement of `step` is in (and not yet forgotten)."""
        return step in self._meas[rig]

    def computational_acceleration(self, x, v, g: float) -> tuple:
        """``x_Q''`` [m/s^2] from every DOF's x, v and the ground acceleration (Eq. 3)."""
        return self._acc(list(x) + list(v) + [g]) if self._acc is not None else ()

    def _step_map(self, unknown: tuple):
        """The compiled :func:`hermite_step` with the DOFs `unknown` not measured."""
        fn = self._maps.get(unknown)
        if fn is None:
            known = [i for i in self._pi if i not in unknown]
            matrices = self.matrices if set(unknown) & set(self._pi) else None
            with single_blas_thread():
                fn = linear_map(hermite_step(self.sub, known, self.dt, matrices),
                                name='hermite_step')
            self._maps[unknown] = fn
        return fn

    def _advance(self, x, v, j: int, unknown: tuple, known_rigs) -> None:
        """Move the state ``x, v`` (every DOF, in place) from sample j to j+1: the `unknown`
        DOFs by :func:`hermite_step`, the known rigs' DOFs to their measurement of j+1."""
        meas, pi = self._meas, self._pi
        q = [x[i] for i in unknown] + [v[i] for i in unknown]
        q += [x[pi[r]] for r in known_rigs] + [v[pi[r]] for r in known_rigs]
        nxt = [meas[r][j + 1] for r in known_rigs]
        q += [m[0] for m in nxt] + [m[1] for m in nxt]
        q += [self.ground.get(j, 0.0), self.ground.get(j + 1, 0.0)]
        z = self._step_map(unknown)(q)
        n_u = len(unknown)
        for i, dof in enumerate(unknown):
            x[dof], v[dof] = z[i], z[n_u + i]
        for r, m in zip(known_rigs, nxt):
            x[pi[r]], v[pi[r]] = m[0], m[1]

    def _settle(self, until: int) -> None:
        """Advance the settled state while every rig's next measurement is in (at most to
        `until`), and forget what is no longer needed."""
        meas = self._meas
        rigs = range(len(meas))
        qi = tuple(self._qi)
        if not self._started:
            # sample 0: the computational DOFs at rest, the physical ones as measured
            if not all(0 in m for m in meas):
                return
            for r in rigs:
                self._x[self._pi[r]], self._v[self._pi[r]] = meas[r][0][:2]
            self._started = True
        while self._settled < until and all(self._settled + 1 in m for m in meas):
            j = self._settled
            if qi:
                self._advance(self._x, self._v, j, qi, rigs)
            else:
                for r in rigs:
                    self._x[self._pi[r]], self._v[self._pi[r]] = meas[r][j + 1][:2]
            self._settled = j + 1
            for m in meas:
                m.pop(j, None)
            self.ground.pop(j - 1, None)

    def state_at(self, j: int) -> tuple[list, list, int]:
        """Displacements and velocities of every DOF at sample `j` (settled, then the
        window), and the window's length [steps].

        Raises
        ------
        ParameterError
            A measured rig's samples before `j` missing (they must come in order).
        """
        self._settle(j)
        s = self._settled
        x, v = list(self._x), list(self._v)
        if s >= j and self._started:
            return x, v, 0
        meas = self._meas
        missing = tuple(r for r in range(len(meas)) if j not in meas[r])
        if not self._started:            # sample 0 of a rig not in: it is at rest there
            for r in range(len(meas)):
                if 0 in meas[r]:
                    x[self._pi[r]], v[self._pi[r]] = meas[r][0][:2]
            if j == 0:
                return x, v, 0
        known = [r for r in range(len(meas)) if r not in missing]
        for r in known:
            if any(i not in meas[r] for i in range(s + 1, j + 1)):
                raise ParameterError(f'rig {self.rig_names[r] or "rig"}: samples missing '
                                     f'before {j}; measurements of a rig must come in order')
        unknown = tuple(sorted(self._qi + [self._pi[r] for r in missing]))
        for i in range(s, j):
            self._advance(x, v, i, unknown, known)
        return x, v, j - s
