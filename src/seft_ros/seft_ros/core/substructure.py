"""The reference-force builder of a structure: the computational substructure and its coupling.

The builder of a test with a structure (:mod:`seft_ros.core.structure`) integrates the
computational DOFs ``Q`` in real time, driven by the measured responses of the physical DOFs
``P`` and by the ground acceleration, and sends each rig ``p`` the force of Eq. 2 of that
module: the effective force plus the interface force of the computational part,

    f_p = -(m_p + mu_p) iota_p xg'' - mu_p x_p'' - [C_c x' + K_c x]_p            (2)

(``M_c`` is diagonal on ``P``: a rigid mass ``mu_p`` riding on each physical DOF, and
physical DOFs carry no mass coupling). The rigid limit, one rig with ``mu = alpha m`` and
nothing else, is paper Eq. 2.5.

**The computational DOFs** (``M_QP = 0``)::

    M_QQ x_Q'' + C_QQ x_Q' + K_QQ x_Q = -M_QQ iota_Q xg'' - K_QP x_P - C_QP x_P'     (3)

are advanced from sample ``k-2`` to ``k-1`` once the measurement of ``k-1`` has arrived,
with the physical motion over the step taken as the cubic Hermite interpolant of the measured
displacements and velocities at both ends and the ground acceleration as linear between
samples (the record's own interpolation, as in the analytical reference). For such inputs the
step is exact: :func:`seft_msgs_py.sampling.zoh` (``scipy.signal.cont2discrete``, method
'zoh') of (3) augmented with the input's polynomial generator. Order: the Hermite
interpolant's error is ``O(dt^4)`` per step (fourth order); the transition matrix is
``exp(A_QQ dt)``, so the scheme is unconditionally stable (its eigenvalues lie inside the unit
circle exactly when the computational part, held at the physical DOFs, is damped: no step
limit as with central differences or Newmark's explicit scheme).

**Compensators** (parameter ``predictor``):

``none``
    Eq. 2 with the measured ``x_P, x_P', x_P''`` of sample ``k-1``, the computational state of
    sample ``k-1`` and ``xg''[k]``: the study's timing (paper Eq. 5.3); the delay of the
    force loop then acts as negative damping on the coupling.
``model``
    The coupled model predicts the whole test over the loop delay: from the measured state of
    the physical DOFs and the computational state at ``t_k-1``, the specimens (``m_p, c_p,
    k_p`` of each rig's predictor model) are driven by the forces already sent, each held
    over its interval ``[t_j + tau, t_j+1 + tau)``, and the computational DOFs by the
    predicted physical motion and the record, all integrated exactly (the augmented
    continuous system with the held forces and the record's slope as zero-order-hold inputs,
    ``cont2discrete``). The new forces ``F[k]`` act over ``[t_k + tau, t_k+1 + tau)``;
    they are chosen so that over that interval the impulse of every rig's force equals the
    impulse of Eq. 2 (impulse matching, the hold-consistent generalisation of the study's
    ``model`` compensator; the new forces enter their own interval through the specimens'
    motion, an algebraic loop solved exactly as one linear system). The record is known
    ahead, so its part of the force is that of the interval where the force acts: the
    response does not lag the reference. On the servohydraulic rig each rig's force loop is
    inverted to a pure delay (:class:`~seft_ros.core.predictors.ForceLoopInverse`, as for one
    rig), which is the ``tau`` of that rig. Every rig's delay must be the same.

The whole law is linear, so each step is two fixed matrix-vector products (compiled once by
:func:`~seft_msgs_py.sampling.linear_map`).

References
----------
N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.4-2.5 and 5.3.
J. E. Carrion and B. F. Spencer Jr. (2007), Model-based strategies for real-time hybrid
testing, NSEL Report 006 (model-based delay compensation). A. K. Chopra, Dynamics of
Structures, Ch. 9-11 (multi-degree-of-freedom systems).
"""

from typing import Mapping, Sequence

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sampling import linear_map, single_blas_thread, split_delay, zoh
from seft_ros.core.structure import Substructures, TestSetup, test_setup

__all__ = ['StructureBuilder', 'STRUCTURE_PREDICTORS', 'Timeline', 'hermite_step',
           'CoupledModel', 'structure_setup', 'StructureSetup', 'loop_delay']

#: The compensators available with a structure.
STRUCTURE_PREDICTORS = ('none', 'model')


#: The setup of a test (:class:`~seft_ros.core.structure.TestSetup`).
StructureSetup = TestSetup


def structure_setup(params: Mapping) -> TestSetup:
    """The :class:`~seft_ros.core.structure.TestSetup` of a run with a ``structure``
    parameter (:func:`~seft_ros.core.structure.test_setup`).

    Raises
    ------
    ParameterError
        No structure, an invalid one, a rig whose parameters disagree with it, or a specimen
        that is not linear.
    """
    if params.get('structure', 'none') in (None, '', 'none'):
        raise ParameterError('parameter structure: this run has no structure')
    setup = test_setup(params)
    for rig, p in setup.rig_params.items():
        model = p.get('specimen_model', 'linear')
        if model != 'linear':
            raise ParameterError(f'rig {rig}: parameter specimen_model={model!r}: a structure '
                                 "needs a 'linear' specimen (its reference is linear)")
    return setup


def _rows(structure, unknown: Sequence[int]):
    """``x_U'' = -M_UU^-1 (K_U. x + C_U. v) - iota_U g``: the unknown DOFs' rows of Eq. 1.

    Returns ``(Ax, Av, iota_U)``: ``Ax``, ``Av`` of shape (n_u, n) on the displacements and
    velocities of every DOF (structure order), ``iota_U`` of shape (n_u,). Valid because no
    physical DOF has a mass coupling (:func:`~seft_ros.core.structure.split`), so
    ``(M iota)_U = M_UU iota_U``.
    """
    u = list(unknown)
    minv = np.linalg.inv(structure.mass_kg[np.ix_(u, u)])
    return (-minv @ structure.stiffness_N_per_m[u, :], -minv @ structure.damping_N_s_per_m[u, :],
            structure.influence[u])


def loop_delay(setup: StructureSetup, rigs: Sequence[str], predictor: str, dt: float) -> float:
    """The loop delay ``model`` predicts over for the `rigs` one builder commands [s].

    Each rig's: its force loop's inverted delay (``predictor_loop_delay_steps`` steps) on
    the servohydraulic rig, ``predictor_tau_s`` (0: ``tau_s``) on the delay rig, plus the
    reference force's network delay (``network_delay_s``). 0 for ``none``.

    Raises
    ------
    ParameterError
        The rigs' delays differ (one builder's law has one delay): the message lists them and
        says what to do.
    """
    from seft_ros.core.predictors import network_delay_steps
    if predictor != 'model':
        return 0.0
    taus = []
    for rig in rigs:
        p = setup.rig_params[rig]
        network = network_delay_steps(p) * dt
        if p['rig_model'] == 'servohydraulic':
            taus.append(int(p['predictor_loop_delay_steps']) * dt + network)
        else:
            taus.append(float(p.get('predictor_tau_s') or p['tau_s']) + network)
    if max(taus) - min(taus) > 1e-9 * dt:
        listed = ', '.join(f'{r} {1e3 * t:g} ms' for r, t in zip(rigs, taus))
        raise ParameterError(f'predictor model with a structure: the rigs of one builder need '
                             f'the same loop delay, got {listed} (set predictor_tau_s or '
                             'predictor_loop_delay_steps in the rigs sections to one delay, or '
                             'structure_builders: per_rig)')
    return taus[0]


class CoupledModel:
    """The continuous model of the test as one builder sees it.

    The **local** physical DOFs ``L`` (the rigs this builder commands) are their specimens
    (the predictor's model ``m, c, k``) under the held actuator forces ``F``; every other DOF
    ``U`` (the computational ones, and the physical ones of rigs commanded elsewhere) moves as
    in the whole structure (Eq. 1), driven by the local DOFs' motion and the record.

    State ``Y = [x_L, v_L, x_U, v_U, int x_L, int x_U, g, int g]`` (``n_l``, ``n_l``, ``n_u``,
    ``n_u``, ``n_l``, ``n_u``, 1, 1), inputs ``u = [F (n_l), g' (1)]`` held over a piece:
    ``Y' = A Y + B u``.

    Parameters
    ----------
    sub : Substructures
    local : sequence of int
        DOF indices of the local physical DOFs (each a physical DOF), in order.
    model_mass_kg, model_damping_N_s_per_m, model_stiffness_N_per_m : array_like (n_l,)
        The local specimens' model (the predictor's: ``predictor_*`` of each rig, 0: its
        specimen).

    Attributes
    ----------
    local, unknown : tuple of int
        DOF indices of ``L`` and ``U`` (structure order).
    n_l, n_u : int
    size : int
        ``3 (n_l + n_u) + 2``.
    a : ndarray (size, size)
    b : ndarray (size, n_l + 1)
    """

    def __init__(self, sub: Substructures, local: Sequence[int], model_mass_kg,
                 model_damping_N_s_per_m, model_stiffness_N_per_m):
        s = sub.structure
        self.local = tuple(local)
        self.unknown = tuple(i for i in range(s.n) if i not in self.local)
        li, ui = list(self.local), list(self.unknown)
        n_l, n_u = len(li), len(ui)
        self.n_l, self.n_u = n_l, n_u
        self.size = 3 * (n_l + n_u) + 2
        m = np.asarray(model_mass_kg, dtype=float)
        c = np.asarray(model_damping_N_s_per_m, dtype=float)
        k = np.asarray(model_stiffness_N_per_m, dtype=float)
        a = np.zeros((self.size, self.size))
        b = np.zeros((self.size, n_l + 1))
        sl = self.slices
        xl, vl, xu, vu = sl['x_L'], sl['v_L'], sl['x_U'], sl['v_U']
        a[xl, vl] = np.eye(n_l)
        a[vl, xl] = np.diag(-k / m)
        a[vl, vl] = np.diag(-c / m)
        b[vl, :n_l] = np.diag(1.0 / m)
        g, ig = sl['g'], sl['int_g']
        if n_u:
            ax, av, iota = _rows(s, ui)
            a[xu, vu] = np.eye(n_u)
            a[vu, xu] = ax[:, ui]
            a[vu, vu] = av[:, ui]
            a[vu, xl] = ax[:, li]
            a[vu, vl] = av[:, li]
            a[vu, g] = -iota[:, None]
        a[sl['int_x_L'], xl] = np.eye(n_l)
        a[sl['int_x_U'], xu] = np.eye(n_u)
        a[ig, g] = 1.0
        b[g, n_l] = 1.0
        self.a, self.b = a, b

    @property
    def slices(self) -> dict:
        """Name -> slice of the state ``Y``."""
        n_l, n_u = self.n_l, self.n_u
        sizes = (('x_L', n_l), ('v_L', n_l), ('x_U', n_u), ('v_U', n_u), ('int_x_L', n_l),
                 ('int_x_U', n_u), ('g', 1), ('int_g', 1))
        out, pos = {}, 0
        for name, size in sizes:
            out[name] = slice(pos, pos + size)
            pos += size
        return out

    def piece(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Gamma)`` of a piece of length `h` [s]: ``Y(h) = Phi Y(0) + Gamma u``."""
        return zoh(self.a, self.b, h)


class Timeline:
    """The pieces of the delayed, held forces and the linear record from ``t_start`` on.

    Step ``j`` (``[t_j, t_j+1)``) is split at ``t_j + delta`` (``tau = n dt + delta``,
    :func:`~seft_msgs_py.sampling.split_delay`): force ``F[j-n-1]`` acts on the early part,
    ``F[j-n]`` on the late part (the delay rig's timing,
    :class:`~seft_plant_sim.delay_rig.DelayRig`), and the record's slope is
    ``(g[j+1] - g[j]) / dt`` on both.

    Parameters
    ----------
    dt, tau_s : float
        Period and loop delay [s].
    """

    def __init__(self, dt: float, tau_s: float):
        self.dt = float(dt)
        self.n, self.delta = split_delay(float(tau_s), self.dt)

    def pieces(self, first_step: int, last_step: int, start_early: bool = True,
               end_early: bool = False):
        """Yield ``(step j, force index j - n - 1 or j - n, length h)`` over steps
        ``first_step .. last_step`` (the early part of `first_step` only with
        `start_early`; of `last_step` only the early part with `end_early`); zero-length
        parts left out."""
        n, delta, dt = self.n, self.delta, self.dt
        for j in range(first_step, last_step + 1):
            if (j > first_step or start_early) and delta > 0.0:
                yield j, j - n - 1, delta
            if j == last_step and end_early:
                return
            yield j, j - n, dt - delta


def hermite_step(sub: Substructures, known: Sequence[int], dt: float) -> np.ndarray:
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
    ax, av, iota = _rows(s, ui)
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


class StructureBuilder:
    """The reference forces of the rigs of a structure test, one step at a time.

    The generalisation of :class:`~seft_ros.core.reference_force.ReferenceForceBuilder` to a
    structure (module notes). Measurements are handed in as they come (:meth:`observe`, any
    rig, any order); :meth:`step` then returns the commands ``f_r[k]`` of the **local** rigs
    (those this builder commands: every rig on one host, its own rig for a lab's replica).

    The state it works from, at sample ``k-1``:

    * **settled**: every rig's measurement is in up to sample ``s``; the computational DOFs
      are advanced to ``s`` exactly from the measured motion (:func:`hermite_step` with
      every physical DOF known);
    * **window** ``s < j <= k-1``: the rigs whose measurement of ``k-1`` is not there (in real
      time, across a network) move as the whole structure would (Eq. 1), with the
      computational DOFs, driven by the measured motion of the others
      (:func:`hermite_step` with those known), from their settled state. With every
      measurement in (lockstep, one host) the window is empty.

    Parameters
    ----------
    setup : StructureSetup
    dt : float > 0
        Control period [s].
    predictor : {'none', 'model'}
    loop_inverses : sequence of ForceLoopInverse or None, length n_local
        Each local rig's force-loop inverse (servohydraulic rig with ``model``), or None.
    tau_s : float >= 0
        The loop delay ``model`` predicts over (every local rig's: the inverse's delay on the
        servohydraulic rig, ``predictor_tau_s`` or ``tau_s`` on the delay rig, plus the
        reference force's network delay).
    local : sequence of str, optional
        The rigs this builder commands (default: all, in structure order).

    Attributes
    ----------
    rig_names : tuple of str
        Every rig of the structure (the order of :meth:`observe`'s index).
    local_rigs : tuple of str
        The rigs :meth:`step` returns commands for, in structure order.
    next_step : int
        The step ``k`` of the next :meth:`step`.
    lookahead_steps : int
        How many samples after ``xg''[k]`` :meth:`step` reads.
    last_ground_forces_N : list of float
        The effective force ``-(m_p + mu_p) iota_p xg''`` of each local rig's latest command
        [N] (the instability monitor's scale).
    computational_state : tuple of float
        ``x_Q, v_Q, a_Q`` of sample ``k-1`` as the latest :meth:`step` used them
        [m, m/s, m/s^2], in the order of ``state_names``.
    state_names : tuple of str
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        per computational DOF.
    window_steps : int
        The window of the latest :meth:`step` (0: every measurement of ``k-1`` was in).

    Raises
    ------
    ParameterError
        An unknown predictor or local rig.
    """

    def __init__(self, setup: StructureSetup, dt: float, predictor: str,
                 loop_inverses: Sequence | None = None, tau_s: float = 0.0,
                 local: Sequence[str] | None = None):
        if predictor not in STRUCTURE_PREDICTORS:
            raise ParameterError(
                f'parameter predictor={predictor!r}: with a structure, expected one of '
                + ', '.join(repr(p) for p in STRUCTURE_PREDICTORS))
        self.setup = setup
        sub = setup.substructures
        s = sub.structure
        self.dt = float(dt)
        self.predictor = predictor
        self.rig_names = setup.rig_names
        names = self.rig_names
        local = names if local is None else tuple(local)
        unknown_rigs = [r for r in local if r not in names]
        if unknown_rigs or not local:
            raise ParameterError(f'local rigs {list(local)!r}: expected some of '
                                 f'{", ".join(names)}')
        self.local_rigs = tuple(r for r in names if r in local)
        pi, qi = list(s.physical_index), list(s.computational_index)
        self._pi, self._qi = pi, qi
        #: position in rig_names of each local rig, and its DOF
        self._local_pos = [names.index(r) for r in self.local_rigs]
        self._local_dof = [pi[j] for j in self._local_pos]
        n_l = len(self._local_pos)
        self.n_p, self.n_c, self.n_l = len(pi), len(qi), n_l
        self.loop_inverses = list(loop_inverses) if loop_inverses else [None] * n_l
        iota = s.influence
        self._ground_gain = [-(sub.specimen_mass_kg[j] + sub.rigid_mass_kg[j]) * iota[pi[j]]
                             for j in self._local_pos]
        self._mu = [float(sub.rigid_mass_kg[j]) for j in self._local_pos]
        self.last_ground_forces_N = [0.0] * n_l
        self.commanded_N: list[list[float]] = [[] for _ in range(n_l)]
        self.state_names = tuple(f'{s.dofs[i]}/{q}' for q in (
            'displacement_m', 'velocity_m_s', 'acceleration_m_s2') for i in qi)
        self.computational_state = tuple([0.0] * (3 * len(qi)))
        self.next_step = 0
        self.window_steps = 0
        # measurements: per rig, step -> (x, v, a); the settled sample and state
        self._meas: list[dict] = [{} for _ in names]
        self._ground: dict[int, float] = {}
        self._settled = 0               # every measurement in up to this sample (rest at 0)
        self._started = False           # the settled state holds sample 0's measurement
        self._x = [0.0] * s.n           # displacement and velocity of every DOF at _settled
        self._v = [0.0] * s.n
        self._maps: dict[tuple, object] = {}          # unknown DOFs -> compiled step
        with single_blas_thread():
            # a_Q of the computational DOFs from every DOF's x, v and the record
            if qi:
                ax, av, iota_q = _rows(s, qi)
                self._acc = linear_map(np.hstack([ax, av, -iota_q[:, None]]),
                                       name='acceleration')
            # the interface force of Eq. 2 on the local DOFs: -[C_c v + K_c x]_L
            kc = sub.stiffness_c_N_per_m[self._local_dof, :]
            cc = sub.damping_c_N_s_per_m[self._local_dof, :]
            self._interface = linear_map(np.hstack([-kc, -cc]), name='interface')
        self.lookahead_steps = 0
        self.tau_s = float(tau_s)
        if predictor == 'model':
            self._build_model()

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def from_parameters(cls, params, local: Sequence[str] | None = None
                        ) -> 'StructureBuilder':
        """Build from a run's parameters (``structure``, ``predictor``, ``dt`` and each
        rig's parameters).

        With ``model``, each local rig's delay is its force loop's inverted delay on the
        servohydraulic rig (:class:`~seft_ros.core.predictors.ForceLoopInverse` from that
        rig's parameters), ``predictor_tau_s`` (0: ``tau_s``) on the delay rig, plus the
        reference force's network delay (``network_delay_s``); they must be equal.

        Raises
        ------
        ParameterError
            As :func:`structure_setup`, a predictor other than 'none' and 'model', or rigs
            whose delays differ under 'model'.
        """
        from seft_ros.core.predictors import ForceLoopInverse
        setup = structure_setup(params)
        predictor = params['predictor']
        dt = float(params['dt'])
        if predictor not in STRUCTURE_PREDICTORS:
            raise ParameterError(
                f'parameter predictor={predictor!r}: with a structure, expected one of '
                + ', '.join(repr(p) for p in STRUCTURE_PREDICTORS))
        names = setup.rig_names if local is None else [r for r in setup.rig_names
                                                       if r in local]
        inverses, tau = [], loop_delay(setup, names, predictor, dt)
        if predictor == 'model':
            with single_blas_thread():
                inverses = [ForceLoopInverse.from_parameters(setup.rig_params[r])
                            if setup.rig_params[r]['rig_model'] == 'servohydraulic' else None
                            for r in names]
        return cls(setup, dt, predictor, inverses or None, tau, local=local)

    def _model_specimens(self):
        """The local specimens' model (``predictor_*`` of each rig, 0: the specimen's)."""
        from seft_ros.core.predictors import model_parameters
        out = [model_parameters(self.setup.rig_params[r]) for r in self.local_rigs]
        return ([o['mass_kg'] for o in out], [o['damping_N_s_per_m'] for o in out],
                [o['stiffness_N_per_m'] for o in out])

    def _build_model(self) -> None:
        """Compile the ``model`` law ``F[k] = L q[k]`` (module notes), and ``L_0`` for the
        first step (from rest at ``t_0``)."""
        with single_blas_thread():
            coupled = CoupledModel(self.setup.substructures, self._local_dof,
                                   *self._model_specimens())
            timeline = Timeline(self.dt, self.tau_s)
            self._timeline = timeline
            n = timeline.n
            #: forces F[k-n-2 .. k-1] per local rig, samples g[k-1 .. k+n+2]
            self._n_hist = n + 2
            self._n_ground = n + 4
            self.lookahead_steps = n + 2
            law = self._law(coupled, timeline, first=False)
            law0 = self._law(coupled, timeline, first=True)
        self._law_map = linear_map(law, name='model_law')
        self._law0_map = linear_map(law0, name='model_law_0')
        self._law_order = list(coupled.local) + list(coupled.unknown)
        self.law_matrix = law

    def _law(self, coupled: CoupledModel, timeline: Timeline, first: bool) -> np.ndarray:
        """The matrix ``L``: ``F[k] = L [x_L, v_L, x_U, v_U, F_hist, g]`` (module notes).

        ``q``: ``x_L, v_L`` (n_l each, sample k-1), ``x_U, v_U`` (n_u each, k-1), the forces
        ``F_r[k-n-2 .. k-1]`` of each local rig r (n + 2 each, rig after rig), the record
        ``g[k-1 .. k+n+2]`` (n + 4). With `first`, the test starts from rest at ``t_0``
        (``k = 0``): the prediction starts there, and the columns of sample k-1 are unused.
        """
        n_l, n_u = coupled.n_l, coupled.n_u
        sl = coupled.slices
        nh, ng = self._n_hist, self._n_ground
        n_state = 2 * (n_l + n_u)
        width = n_state + n_l * nh + ng
        col_hist = n_state
        col_g = col_hist + n_l * nh
        n, dt = timeline.n, self.dt
        k = 0                     # steps relative to k: sample k-1 is step -1
        # Y at the start (t_k-1, or t_0 for the first step), as a map of q
        y = np.zeros((coupled.size, width + n_l))          # last n_l columns: F[k]
        start = k if first else k - 1
        if not first:
            y[:n_state, :n_state] = np.eye(n_state)
        y[sl['g'], col_g + (start - (k - 1))] = 1.0
        cache = {}

        def advance(y, j, force, h):
            if h not in cache:
                cache[h] = coupled.piece(h)
            phi, gamma = cache[h]
            u = np.zeros((n_l + 1, width + n_l))
            # the forces of step index `force` (relative to k): history or the new F[k]
            rel = force - k                                 # -n-2 .. 0
            if rel == 0:
                u[:n_l, width:] = np.eye(n_l)
            elif rel >= -nh and not (first and force < 0):
                for r in range(n_l):
                    u[r, col_hist + r * nh + (nh + rel)] = 1.0
            # the record's slope on step j: (g[j+1] - g[j]) / dt
            gj = col_g + (j - (k - 1))
            u[n_l, gj + 1] += 1.0 / dt
            u[n_l, gj] -= 1.0 / dt
            return phi @ y + gamma @ u

        # prediction: up to t_k + tau = t_k+n + delta
        for j, force, h in timeline.pieces(start, k + n, start_early=True, end_early=True):
            y = advance(y, j, force, h)
        y_start = y
        # the new forces' interval [t_k+n + delta, t_k+n+1 + delta)
        last = k + n + 1 if timeline.delta > 0.0 else k + n
        for j, force, h in timeline.pieces(k + n, last, start_early=False,
                                           end_early=timeline.delta > 0.0):
            y = advance(y, j, force, h)
        diff = y - y_start
        # impulse of Eq. 2 over the interval, as rows on Y: G int g - mu dv_L - C_c dx - K_c Ix
        s = self.setup.substructures
        li, ui = list(coupled.local), list(coupled.unknown)
        kc = s.stiffness_c_N_per_m[li, :]
        cc = s.damping_c_N_s_per_m[li, :]
        rows = np.zeros((n_l, coupled.size))
        rows[:, sl['int_g']] = np.array(self._ground_gain)[:, None]
        rows[:, sl['v_L']] = -np.diag(self._mu)
        rows[:, sl['x_L']] -= cc[:, li]
        rows[:, sl['x_U']] -= cc[:, ui]
        rows[:, sl['int_x_L']] -= kc[:, li]
        rows[:, sl['int_x_U']] -= kc[:, ui]
        impulse = rows @ diff                                # (n_l, width + n_l)
        # F dt = impulse_known q + impulse_F F  ->  (dt I - impulse_F) F = impulse_known q
        lhs = dt * np.eye(n_l) - impulse[:, width:]
        return np.linalg.solve(lhs, impulse[:, :width])

    # -- the state --------------------------------------------------------------------------

    def observe(self, rig: int, measurement: Measurement) -> None:
        """Hand in one rig's measurement (any rig, any order; a repeat replaces it).

        Parameters
        ----------
        rig : int
            Index of the rig in ``rig_names``.
        measurement : Measurement
            Its sample (``measurement.step``).
        """
        self._meas[rig][measurement.step] = (measurement.displacement_m,
                                             measurement.velocity_m_s,
                                             measurement.acceleration_m_s2)

    def _step_map(self, unknown: tuple):
        """The compiled :func:`hermite_step` with the DOFs `unknown` not measured."""
        fn = self._maps.get(unknown)
        if fn is None:
            known = [i for i in self._pi if i not in unknown]
            with single_blas_thread():
                fn = linear_map(hermite_step(self.setup.substructures, known, self.dt),
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
        q += [self._ground.get(j, 0.0), self._ground.get(j + 1, 0.0)]
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
            self._ground.pop(j - 1, None)

    def _state_at(self, j: int) -> tuple[list, list, int]:
        """Displacements and velocities of every DOF at sample `j` (settled, then the
        window), and the window's length."""
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
                raise ParameterError(f'rig {self.rig_names[r]}: samples missing before '
                                     f'{j}; measurements of a rig must come in order')
        unknown = tuple(sorted(self._qi + [self._pi[r] for r in missing]))
        for i in range(s, j):
            self._advance(x, v, i, unknown, known)
        return x, v, j - s

    # -- stepping ---------------------------------------------------------------------------

    def step(self, window) -> list[float]:
        """The commands ``f_r[k]`` of the local rigs [N], from the record and what has been
        observed (``k`` = ``next_step``).

        Parameters
        ----------
        window : sequence of float, length lookahead_steps + 1
            ``xg''[k .. k + lookahead_steps]`` [m/s^2] (zeros after the record).

        Returns
        -------
        list of float, length n_l
            The command of each local rig: the desired force (through its force-loop
            inverse, if any) [N].

        Raises
        ------
        ParameterError
            A short window, or a local rig's measurement of ``k-1`` not observed.
        """
        if len(window) <= self.lookahead_steps:
            raise ParameterError(f'ground window of {len(window)} samples: expected '
                                 f'{self.lookahead_steps + 1}')
        k = self.next_step
        for j, g in enumerate(window[:self.lookahead_steps + 1]):
            self._ground[k + j] = float(g)
        n_l = self.n_l
        first = k == 0
        if first:
            x, v = self._x, self._v
            acc = [0.0] * n_l
            self.window_steps = 0
        else:
            for r in self._local_pos:
                if k - 1 not in self._meas[r]:
                    raise ParameterError(f'rig {self.rig_names[r]}: no measurement of '
                                         f'sample {k - 1} observed')
            acc = [self._meas[r][k - 1][2] for r in self._local_pos]
            x, v, self.window_steps = self._state_at(k - 1)
            if self._qi:
                g_prev = self._ground.get(k - 1, 0.0)
                a_q = self._acc(x + v + [g_prev])
                self.computational_state = (tuple(x[i] for i in self._qi)
                                            + tuple(v[i] for i in self._qi) + tuple(a_q))
        g_k = float(window[0])
        for r in range(n_l):
            self.last_ground_forces_N[r] = self._ground_gain[r] * g_k
        if self.predictor == 'none':
            interface = self._interface(x + v)
            forces = [self._ground_gain[r] * g_k - self._mu[r] * acc[r] + interface[r]
                      for r in range(n_l)]
        else:
            nh = self._n_hist
            local, unknown = self._law_order[:n_l], self._law_order[n_l:]
            q = ([x[i] for i in local] + [v[i] for i in local]
                 + [x[i] for i in unknown] + [v[i] for i in unknown])
            for r in range(n_l):
                past = self.commanded_N[r][-nh:]
                q.extend([0.0] * (nh - len(past)) + past)
            g_prev = 0.0 if first else self._ground.get(k - 1, 0.0)
            q += [g_prev] + list(window[:self._n_ground - 1])
            forces = list((self._law0_map if first else self._law_map)(q))
        self.next_step = k + 1
        out = []
        for r in range(n_l):
            self.commanded_N[r].append(forces[r])
            inverse = self.loop_inverses[r]
            out.append(forces[r] if inverse is None else inverse.step(forces[r]))
        return out
