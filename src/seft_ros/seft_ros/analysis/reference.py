"""The analytical reference: the whole structure simulated from the recorded ground motion.

Imports no rclpy. The reference study validates each substructure EFT test against the response
of the whole structure (load-resisting member plus computational mass) computed from the same
ground motion (paper Sec. 4, Figure 6). Every test is a structure
(:mod:`seft_ros.core.structure`): the study's test is its one-DOF case, a physical DOF carrying
the rigid computational mass ``alpha m``. This module computes the response of the whole
structure, physical and computational DOFs together, for any run:

- **linear** (every rig's specimen linear): ``M x'' + C x' + K x = -M iota xg''`` with
  the first-order-hold discretization (``scipy.signal.cont2discrete``) of the state
  ``[x, x']`` stepped by SLICOT's TF01MD, the record linear between samples (for which the
  discrete solution is exact: Nigam and Jennings 1969);
- **nonlinear** (a rig's specimen hysteretic, ``specimen_model: bouc_wen``): the same
  structure with that member's spring replaced by its Bouc-Wen restoring force, integrated by
  ``scipy.integrate.solve_ivp`` (LSODA) with tight tolerances, independently of the test's own
  discretization (:func:`structure_reference`, Notes: the method and its measured error).

:func:`run_reference` gives the whole structure's response of a run
(:class:`StructureReference`); :meth:`StructureReference.rig` one rig's DOF as a
:class:`ReferenceResponse`, the counterpart of that rig's signals. :func:`reference_response`
is the study's one-DOF case from its parameters.
"""

from dataclasses import dataclass, field
import hashlib
import math
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import integrate, signal

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.sampling import single_blas_thread
from seft_plant_sim.specimen import BoucWenSpecimen, LinearSpecimen, make_specimen
from seft_ros.core.models import model_plugin
from seft_ros.core.structure import (
    STUDY_RIG,
    Structure,
    is_study,
    study_structure,
    test_setup,
)

__all__ = ['ReferenceResponse', 'StructureReference', 'structure_reference', 'run_reference',
           'reference_response', 'hysteretic_reference_response', 'reference_from_run',
           'planned_reference',
           'LINEAR_METHOD', 'NONLINEAR_METHOD']

#: How the reference of a linear structure is computed (:func:`structure_reference`).
LINEAR_METHOD = ('first-order hold (scipy.signal.cont2discrete, exact for a record linear between '
                 'samples), stepped by SLICOT TF01MD')
#: How the reference of a structure with a hysteretic member is computed.
NONLINEAR_METHOD = 'scipy.integrate.solve_ivp, LSODA, rtol {rtol:g}, atol {atol:g} (scaled)'


@dataclass(frozen=True)
class ReferenceResponse:
    """Response of one rig's degree of freedom of the whole structure, one sample per step.

    All arrays have shape ``(n,)``; sample k is at ``time_s[k] = k*dt``. The counterpart of
    one rig's signals (the study's test: of the run).

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
        Force on the load-resisting member ``m x'' + c x' + k x`` [N] (hysteretic member:
        ``m x'' + c x' + f_s(x, z)``), the counterpart of the load-cell force of a test (paper
        Eq. 2.4); in the study's test it equals ``-(1+alpha) m xg'' - alpha m x''`` (paper
        Eq. 2.5).
    hysteretic_z : ndarray (n,) or None
        Bouc-Wen variable z of a hysteretic member [-] (None: linear member).
    restoring_force_N : ndarray (n,) or None
        Restoring force of the member [N]: ``k x`` (linear) or the Bouc-Wen
        ``f_s = a k x + (1 - a) k D_y z`` (hysteretic), i.e. `force_N` without the member's
        inertia and damping, ``force_N - m x'' - c x'``; plotted against `displacement_m` it
        is the member's hysteresis loop. None only for a response built without it.
    """

    time_s: np.ndarray
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    force_N: np.ndarray
    hysteretic_z: np.ndarray | None = None
    restoring_force_N: np.ndarray | None = None

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


@dataclass(frozen=True)
class StructureReference:
    """Response of the whole structure, one sample per step, SI units, relative to the ground.

    Attributes
    ----------
    time_s : ndarray (n,)
        Sample times [s].
    dofs : tuple of str, length n_dof
        The DOFs, in the structure's order.
    rigs : tuple of str, length n_p
        The rig of each physical DOF, in the structure's order (``('',)``: the study's).
    physical_index : tuple of int, length n_p
        The DOF index of each rig.
    influence : ndarray (n_dof,)
        The structure's influence vector iota [-].
    links : tuple of Link
        The structure's links (springs between DOFs or to the ground) whose deformation a
        comparison gives (:class:`~seft_ros.core.structure.Link`: story drifts).
    displacement_m, velocity_m_s, acceleration_m_s2 : ndarray (n, n_dof)
        Per DOF, in the structure's DOF order.
    absolute_acceleration_m_s2 : ndarray (n, n_dof)
        ``x'' + iota xg''`` (floor accelerations).
    interface_force_N : ndarray (n, n_p)
        At each physical DOF (structure order), the force its specimen carries,
        ``m_p x_p'' + c_p x_p' + k_p x_p`` (hysteretic: ``... + f_s(x_p, z_p)``): what the
        rig's load cell should read (Eq. 2 of :mod:`seft_ros.core.structure`).
    restoring_force_N : ndarray (n, n_p)
        Each specimen's restoring force ``k_p x_p`` or ``f_s(x_p, z_p)`` [N].
    hysteretic_z : dict of str to ndarray (n,)
        The Bouc-Wen variable of each hysteretic rig's member [-] (empty: all linear).
    method : str
        How it was computed (:data:`LINEAR_METHOD`, :data:`NONLINEAR_METHOD`, or a model
        plug-in's own analysis, e.g. OpenSees': :mod:`seft_ros.core.models`).
    element_forces, element_deformations : dict of int to ndarray (n,)
        A plug-in model's elements asked for (OpenSees): a member's force and deformation
        (empty otherwise).
    """

    time_s: np.ndarray
    dofs: tuple
    rigs: tuple
    physical_index: tuple
    influence: np.ndarray
    links: tuple
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    absolute_acceleration_m_s2: np.ndarray
    interface_force_N: np.ndarray
    restoring_force_N: np.ndarray
    hysteretic_z: dict = field(default_factory=dict)
    method: str = LINEAR_METHOD
    element_forces: dict = field(default_factory=dict)
    element_deformations: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    def dof_index(self, name: str) -> int:
        """The index of DOF `name` (KeyError if none)."""
        try:
            return self.dofs.index(name)
        except ValueError:
            raise KeyError(name) from None

    def rig(self, name: str) -> ReferenceResponse:
        """The response at rig `name`'s DOF: its displacement, velocity, acceleration,
        interface force (``force_N``), restoring force and Bouc-Wen variable, each a
        contiguous array of shape (n,).

        Raises
        ------
        KeyError
            No such rig.
        """
        try:
            j = self.rigs.index(name)
        except ValueError:
            raise KeyError(name) from None
        i = self.physical_index[j]

        def column(values):
            return np.ascontiguousarray(values[:, i])
        z = self.hysteretic_z.get(name)
        return ReferenceResponse(
            time_s=self.time_s, displacement_m=column(self.displacement_m),
            velocity_m_s=column(self.velocity_m_s),
            acceleration_m_s2=column(self.acceleration_m_s2),
            force_N=np.ascontiguousarray(self.interface_force_N[:, j]),
            hysteretic_z=None if z is None else np.ascontiguousarray(z),
            restoring_force_N=np.ascontiguousarray(self.restoring_force_N[:, j]))


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


def _finite(name: str, value: Any) -> float:
    """Return `value` as a finite float, or raise ParameterError naming `name`."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (ok and math.isfinite(float(value))):
        raise ParameterError(f'parameter {name}={value!r}: expected a finite float')
    return float(value)


def _record(ground_acceleration_m_s2) -> np.ndarray:
    """The record as a finite 1-D float array, or ParameterError."""
    try:
        ag = np.asarray(ground_acceleration_m_s2, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError('ground_acceleration_m_s2: expected a 1-D array of floats') from None
    if ag.ndim != 1 or not np.all(np.isfinite(ag)):
        raise ParameterError(
            f'ground_acceleration_m_s2: expected a finite 1-D array, got shape {ag.shape}'
            + ('' if ag.ndim != 1 else ' with non-finite values'))
    return ag


def _mass_solve(mass: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``M^-1 values`` (values of shape (n_dof, ...)): a division by the lumped masses when
    ``M`` is diagonal (exact for the study's one DOF, ``k / ((1 + alpha) m)``), else a
    solve."""
    diagonal = np.diag(mass)
    if np.count_nonzero(mass - np.diag(diagonal)) == 0:
        return values / diagonal.reshape((-1,) + (1,) * (values.ndim - 1))
    return np.linalg.solve(mass, values)


def _member_forces(structure: Structure, specimens, x: np.ndarray, z: np.ndarray,
                   hysteretic: list) -> np.ndarray:
    """The specimens' restoring forces ``k_p x_p`` or ``f_s(x_p, z_p)``, shape (n, n_p)."""
    out = np.empty((x.shape[0], len(specimens)))
    for j, (i, spec) in enumerate(zip(structure.physical_index, specimens)):
        if j in hysteretic:
            out[:, j] = spec.restoring_force(x[:, i], z[:, hysteretic.index(j)])
        else:
            out[:, j] = spec.stiffness_N_per_m * x[:, i]
    return out


def structure_reference(structure: Structure, specimens: Sequence, dt: float,
                        ground_acceleration_m_s2, *, rtol: float = 1e-9,
                        atol: float = 1e-9) -> StructureReference:
    """Simulate the whole structure from rest under a sampled ground acceleration.

    Solves (Eq. 1 of :mod:`seft_ros.core.structure`, each hysteretic specimen's spring
    replaced by its restoring force)::

        M x'' + C x' + K_l x + sum_h e_h f_s,h(x_h, z_h) = -M iota xg''
        z_h' = (x_h'/D_y,h)(1 - |z_h|^n (beta sgn(x_h' z_h) + gamma))

    where ``K_l = K - sum_h k_h e_h e_h^T`` (``k_h`` the hysteretic specimen's initial
    stiffness, ``e_h`` its DOF), with the record linearly interpolated between samples.

    Parameters
    ----------
    structure : Structure
        The whole structure (the study's test: :func:`~seft_ros.core.structure.study_structure`).
    specimens : sequence of LinearSpecimen or BoucWenSpecimen, length n_p
        The specimen of each physical DOF, in the structure's order
        (``structure.physical_index``): its ``m, c, k`` give the interface force, a
        BoucWenSpecimen makes its spring hysteretic.
    dt : float > 0
        Sample period [s].
    ground_acceleration_m_s2 : array_like (n,)
        xg'' at ``k dt`` [m/s^2], finite.
    rtol, atol : float > 0
        Tolerances of the nonlinear integrator (atol applies to ``x/D_y``,
        ``x'/(D_y w_0)`` and z, all scaled to order one; ``D_y`` the smallest yield
        displacement of the hysteretic members, ``w_0`` the highest of their initial natural
        circular frequencies ``sqrt(k/m)``). Unused for a linear structure.

    Returns
    -------
    StructureReference

    Raises
    ------
    ParameterError
        A bad dt, record, tolerance or specimen list, or the nonlinear integration failed.

    Notes
    -----
    **Linear** (no hysteretic specimen): the first-order-hold discretization
    (``scipy.signal.cont2discrete``, stepped by SLICOT's TF01MD: ``lsim``'s recurrence,
    compiled) of the state
    ``[x, x']`` with ``A = [[0, I], [-M^-1 K, -M^-1 C]]``, ``B = [0; -iota]``; with the
    record linear between samples (first-order hold) the discrete solution is exact
    (piecewise-linear excitation, Nigam and Jennings 1969). Then
    ``x'' = -M^-1 (C x' + K x) - iota xg''`` at each sample.

    **Nonlinear**: ``scipy.integrate.solve_ivp`` with LSODA (Adams / BDF switching, adaptive;
    Petzold 1983) on ``[x, x', z]``, steps capped at ``dt`` so that no sample of the record is
    stepped over, and the samples taken at ``t_eval`` (the integrator's own interpolant of its
    order, within the tolerance). The test's discretization (its rig's substeps, the
    builder's hold) plays no part. Measured error of the default ``rtol = atol = 1e-9``
    against the same integration at ``1e-12`` on the default record (5000 samples, the
    members yielding to 3-7 times ``D_y``), largest difference over the peak: the study's
    member 2.5e-8 to 2.8e-8 (displacement), 2.5e-8 to 3.5e-8 (acceleration) at alpha 0 and
    1; the two-pier bridge with pier a yielding 1.5e-8 to 1.9e-8 (displacement), 3e-8 to
    6e-8 (floor acceleration), 1.5e-8 to 2e-8 (interface force) per DOF; the two-story
    building with its first story yielding 1.7e-8 to 1.8e-8, 5e-8 to 6.5e-8, 3.5e-8. A Bouc-Wen
    member with ``post_yield_stiffness_ratio = 1`` (a linear spring) agrees with the exact
    linear solution to 1e-7 of the peaks, and the study's member with a classical RK4 at 40
    steps per sample to 1e-5 (``tests/seft_ros/analysis/test_nonlinear_reference.py`` checks
    each bound). 5000 samples take about 1.2 s (the study's member) to 1.5 s (the bridge)
    on this project's 2-core machine.

    With one DOF and ``M = (1 + alpha) m`` this is the study's reference: the lumped masses
    divide (``x'' = -(c x' + k x) / ((1 + alpha) m) - xg''``), so the one-DOF case is the
    computation of the study's reference bit for bit.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing: A Force-Based Real-Time
    Hybrid Simulation, Eqs. 2.1, 2.4, 2.5 and Sec. 4 (Figure 6).
    N. C. Nigam and P. C. Jennings (1969), Calculation of response spectra from strong-motion
    earthquake records, Bull. Seismol. Soc. Am. 59(2), 909-922.
    M. Ismail, F. Ikhouane and J. Rodellar, The hysteresis Bouc-Wen model, a survey, Arch.
    Comput. Methods Eng. 16, 2009, 161-188.
    L. Petzold, Automatic selection of methods for solving stiff and nonstiff systems of
    ordinary differential equations, SIAM J. Sci. Stat. Comput. 4(1), 1983, 136-148 (LSODA).
    """
    dt = _positive('dt', dt)
    rtol = _positive('rtol', rtol)
    atol = _positive('atol', atol)
    ag = _record(ground_acceleration_m_s2)
    specimens = list(specimens)
    idx = structure.physical_index
    if len(specimens) != len(idx) or not all(
            isinstance(s, (LinearSpecimen, BoucWenSpecimen)) for s in specimens):
        raise ParameterError(f'specimens: expected {len(idx)} LinearSpecimen or BoucWenSpecimen '
                             f'(one per physical dof), got {specimens!r}')
    hysteretic = [j for j, s in enumerate(specimens) if isinstance(s, BoucWenSpecimen)]
    n = ag.shape[0]
    mass, damping = structure.mass_kg, structure.damping_N_s_per_m
    stiff = structure.stiffness_N_per_m.copy()
    for j in hysteretic:
        stiff[idx[j], idx[j]] -= specimens[j].stiffness_N_per_m
    iota = structure.influence
    t = np.arange(n) * dt
    if hysteretic:
        x, v, z = _nonlinear(structure, specimens, hysteretic, stiff, dt, ag, rtol, atol)
        method = NONLINEAR_METHOD.format(rtol=rtol, atol=atol)
    else:
        x, v = _linear(structure, t, ag)
        z = np.zeros((n, 0))
        method = LINEAR_METHOD
    members = _member_forces(structure, specimens, x, z, hysteretic)
    forces = v @ damping.T
    if np.any(stiff):
        forces = forces + x @ stiff.T
    for j in hysteretic:
        forces[:, idx[j]] += members[:, j]
    acc = -_mass_solve(mass, forces.T).T - ag[:, None] * iota[None, :]
    absolute = acc + ag[:, None] * iota[None, :]
    interface = np.empty((n, len(idx)))
    for j, (i, spec) in enumerate(zip(idx, specimens)):
        interface[:, j] = (spec.mass_kg * acc[:, i] + spec.damping_N_s_per_m * v[:, i]
                           + members[:, j])
    return StructureReference(
        time_s=t, dofs=tuple(structure.dofs), rigs=tuple(structure.rig_names),
        physical_index=tuple(idx), influence=np.array(iota, dtype=float),
        links=tuple(structure.links), displacement_m=x, velocity_m_s=v, acceleration_m_s2=acc,
        absolute_acceleration_m_s2=absolute, interface_force_N=interface,
        restoring_force_N=members,
        hysteretic_z={structure.rig_names[j]: z[:, q] for q, j in enumerate(hysteretic)},
        method=method)


def _linear(structure: Structure, t: np.ndarray, ag: np.ndarray):
    """``(x, x')`` of the linear structure, each (n, n_dof): the first-order-hold
    discretization of ``scipy.signal.cont2discrete`` stepped by SLICOT's TF01MD (slycot).

    The same recurrence as ``scipy.signal.lsim(..., interp=True)`` (the same matrix
    exponential; lsim steps it in a Python loop, about 4 us a sample, here compiled): the two
    agree to about 1e-13 of the peak (``tests/seft_ros/analysis/test_reference.py``).
    ``cont2discrete``'s state is ``x - D u`` (its ``D`` the input's share of the hold, with
    ``C = I``), so it starts from ``-D xg''[0]`` for ``x[0] = 0``.
    """
    from slycot import tf01md  # (imported here: about 50 ms)
    n_dof, n = structure.n, ag.shape[0]
    mass = structure.mass_kg
    a = np.block([[np.zeros((n_dof, n_dof)), np.eye(n_dof)],
                  [-_mass_solve(mass, structure.stiffness_N_per_m),
                   -_mass_solve(mass, structure.damping_N_s_per_m)]])
    b = np.concatenate([np.zeros(n_dof), -structure.influence])[:, None]
    if n < 2:
        states = np.zeros((n, 2 * n_dof))
        return states[:, :n_dof], states[:, n_dof:]
    size = 2 * n_dof
    dt = float(t[1] - t[0])
    with single_blas_thread():
        ad, bd, cd, dd, _ = signal.cont2discrete((a, b, np.eye(size), np.zeros((size, 1))),
                                                 dt, method='foh')
        u = np.asarray(ag, dtype=float)[None, :]
        _, y = tf01md(size, 1, size, n, ad, bd, cd, dd, u, -(dd[:, 0] * u[0, 0]))
    states = np.ascontiguousarray(y.T)
    return states[:, :n_dof], states[:, n_dof:]


#: The latest nonlinear references by what they are computed from (:func:`_nonlinear`): a
#: run's divergence guard asks for its reference before the run and its comparison after it,
#: the same integration twice (measured: 12 integrations, 43 of the 72 s of three tests of
#: a yielding member, each one twice).
_NONLINEAR: dict = {}
_NONLINEAR_KEPT = 4


def _nonlinear(structure: Structure, specimens: list, hysteretic: list, stiff: np.ndarray,
               dt: float, ag: np.ndarray, rtol: float, atol: float):
    """``(x, x', z)`` of the structure with hysteretic members, by ``solve_ivp`` (LSODA);
    kept by the structure, the specimens, ``dt``, the record and the tolerances
    (``_NONLINEAR``: the same integration is made once)."""
    key = hashlib.sha1(repr((structure.to_json(), specimens, hysteretic, float(dt),
                             float(rtol), float(atol), ag.shape)).encode()
                       + np.ascontiguousarray(stiff, dtype=float).tobytes()
                       + np.ascontiguousarray(ag, dtype=float).tobytes()).digest()
    if key not in _NONLINEAR:
        if len(_NONLINEAR) >= _NONLINEAR_KEPT:
            _NONLINEAR.pop(next(iter(_NONLINEAR)))
        _NONLINEAR[key] = _integrate_nonlinear(structure, specimens, hysteretic, stiff, dt, ag,
                                               rtol, atol)
    return tuple(a.copy() for a in _NONLINEAR[key])


def _integrate_nonlinear(structure: Structure, specimens: list, hysteretic: list,
                         stiff: np.ndarray, dt: float, ag: np.ndarray, rtol: float,
                         atol: float):
    """:func:`_nonlinear`'s integration."""
    n_dof, n, n_h = structure.n, ag.shape[0], len(hysteretic)
    if n < 2:
        return np.zeros((n, n_dof)), np.zeros((n, n_dof)), np.zeros((n, n_h))
    idx = structure.physical_index
    members = [(idx[j], specimens[j].restoring_force, specimens[j].hysteretic_rate)
               for j in hysteretic]
    # the rows of C and K_l as their nonzero terms, for a right-hand side in plain floats
    # (small structures: a few terms a row; numpy's per-call overhead would dominate)
    rows = [[(j, float(c)) for j, c in enumerate(structure.damping_N_s_per_m[i]) if c != 0.0]
            + [(n_dof + j, float(k)) for j, k in enumerate(stiff[i]) if k != 0.0]
            for i in range(n_dof)]
    iota = structure.influence.tolist()
    diagonal = np.diag(structure.mass_kg)
    lumped = np.count_nonzero(structure.mass_kg - np.diag(diagonal)) == 0
    masses, mass = diagonal.tolist(), structure.mass_kg
    samples = ag.tolist()
    last = n - 2

    def rhs(time, y):
        values = y.tolist()          # [x (n_dof), v (n_dof), z (n_h)]
        x, v = values[:n_dof], values[n_dof:2 * n_dof]
        z = values[2 * n_dof:]
        pos = time / dt
        i = min(max(int(pos), 0), last)
        xg = samples[i] + (pos - i) * (samples[i + 1] - samples[i])
        state = v + x                # C acts on v (columns 0..n-1), K_l on x (n..2n-1)
        force = []
        for terms in rows:
            f = 0.0
            for j, coefficient in terms:
                f += coefficient * state[j]
            force.append(f)
        rates = []
        for q, (dof, restoring, rate) in enumerate(members):
            force[dof] += restoring(x[dof], z[q])
            rates.append(rate(v[dof], z[q]))
        if lumped:
            acc = [-f / m - g * xg for f, m, g in zip(force, masses, iota)]
        else:
            acc = (-np.linalg.solve(mass, force) - np.array(iota) * xg).tolist()
        return v + acc + rates

    dy = min(specimens[j].yield_displacement_m for j in hysteretic)
    w0 = max(2.0 * np.pi * specimens[j].natural_frequency_hz for j in hysteretic)
    scale = np.concatenate([np.full(n_dof, dy), np.full(n_dof, dy * w0), np.ones(n_h)])
    t = np.arange(n) * dt
    sol = integrate.solve_ivp(rhs, (0.0, t[-1]), np.zeros(2 * n_dof + n_h), method='LSODA',
                              t_eval=t, rtol=rtol, atol=atol * scale, max_step=dt)
    if not sol.success:
        raise ParameterError(f'hysteretic reference: integration failed ({sol.message})')
    y = sol.y.T
    return y[:, :n_dof], y[:, n_dof:2 * n_dof], y[:, 2 * n_dof:]


_PARAMS = ('alpha', 'mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m', 'dt')
_BOUC_WEN = ('post_yield_stiffness_ratio', 'yield_displacement_m', 'bouc_wen_n',
             'bouc_wen_beta', 'bouc_wen_gamma')
_MODELS = ('linear', 'bouc_wen')


def _study(alpha, mass_kg, damping_N_s_per_m, stiffness_N_per_m, specimen_model: str,
           bouc_wen: Mapping[str, Any]) -> tuple[Structure, object]:
    """The study's one-DOF structure and its specimen from checked parameters."""
    alpha = _positive('alpha', alpha, allow_zero=True)
    m = _positive('mass_kg', mass_kg)
    c = _positive('damping_N_s_per_m', damping_N_s_per_m, allow_zero=True)
    k = _positive('stiffness_N_per_m', stiffness_N_per_m)
    unknown = sorted(set(bouc_wen) - set(_BOUC_WEN))
    if unknown:
        raise ParameterError(f'unknown parameter {unknown[0]!r} of the Bouc-Wen member')
    if specimen_model not in _MODELS:
        raise ParameterError(f"parameter specimen_model={specimen_model!r}: expected one of "
                             "'linear', 'bouc_wen'")
    if specimen_model == 'bouc_wen':
        specimen = BoucWenSpecimen(m, c, k, **{name: _finite(name, value)
                                               for name, value in bouc_wen.items()})
    else:
        specimen = LinearSpecimen(m, c, k)
    structure = study_structure({'alpha': alpha, 'mass_kg': m, 'damping_N_s_per_m': c,
                                 'stiffness_N_per_m': k})
    return structure, specimen


def reference_response(*, alpha: float, mass_kg: float, damping_N_s_per_m: float,
                       stiffness_N_per_m: float, dt: float, ground_acceleration_m_s2,
                       specimen_model: str = 'linear', **bouc_wen) -> ReferenceResponse:
    """Simulate the study's whole structure from rest under a sampled ground acceleration.

    The one-DOF case of :func:`structure_reference`: the load-resisting member plus the
    computational mass ``alpha*m``::

        (1+alpha) m x'' + c x' + k x = -(1+alpha) m xg''

    with the first-order hold of :func:`structure_reference` on the state ``[x, x']``.
    The record is linearly interpolated
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
    specimen_model : {'linear', 'bouc_wen'}
        The load-resisting member: linear, or hysteretic (see
        :func:`hysteretic_reference_response`), with initial stiffness ``stiffness_N_per_m``.
    **bouc_wen
        ``post_yield_stiffness_ratio``, ``yield_displacement_m``, ``bouc_wen_n``,
        ``bouc_wen_beta``, ``bouc_wen_gamma`` of the 'bouc_wen' member (absent: the defaults of
        :class:`~seft_plant_sim.specimen.BoucWenSpecimen`).

    Returns
    -------
    ReferenceResponse
        Displacement, velocity, acceleration (relative to the ground), member force and the
        member's restoring force (``k x``; hysteretic: ``f_s``), each of shape ``(n,)``.

    Raises
    ------
    ParameterError
        If a parameter is out of range, not finite or of the wrong type, the specimen model is
        unknown, or the ground acceleration is not a finite 1-D array; the message names the
        parameter.

    Notes
    -----
    With ``M = (1+alpha) m`` the relative acceleration is ``x'' = -(c x' + k x)/M - xg''`` and
    the member force is ``f = m x'' + c x' + k x = -(1+alpha) m xg'' - alpha m x''``
    (paper Eqs. 2.4-2.5).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.1, 2.4, 2.5 and
    Sec. 4 (Figure 6); Nigam and Jennings (1969), as :func:`structure_reference`.
    """
    structure, specimen = _study(alpha, mass_kg, damping_N_s_per_m, stiffness_N_per_m,
                                 specimen_model, bouc_wen)
    dt = _positive('dt', dt)
    ag = _record(ground_acceleration_m_s2)
    return structure_reference(structure, [specimen], dt, ag).rig(STUDY_RIG)


def hysteretic_reference_response(*, alpha: float, specimen: BoucWenSpecimen, dt: float,
                                  ground_acceleration_m_s2, rtol: float = 1e-9,
                                  atol: float = 1e-9) -> ReferenceResponse:
    """Simulate the study's whole structure with a hysteretic (Bouc-Wen) member from rest.

    Solves::

        (1+alpha) m x'' + c x' + f_s(x, z) = -(1+alpha) m xg''
        f_s = a k x + (1 - a) k D_y z,   z' = (x'/D_y)(1 - |z|^n (beta sgn(x' z) + gamma))

    on the state ``[x, x', z]``: the one-DOF case of :func:`structure_reference` (its Notes:
    ``scipy.integrate.solve_ivp``, LSODA, steps capped at ``dt``, the record linear between
    samples). With the default tolerances the result agrees with a classical RK4 solution at
    80 steps per sample to 5e-7 (relative to the peaks) on the default record; 5000 samples
    take about 1.2 s.

    Parameters
    ----------
    alpha : float >= 0
        Mass ratio [-].
    specimen : BoucWenSpecimen
        The member: m, c, initial stiffness k and the Bouc-Wen parameters.
    dt : float > 0
        Sample period of the record [s].
    ground_acceleration_m_s2 : array_like (n,)
        Ground acceleration xg'' at ``k*dt`` [m/s^2]; finite values.
    rtol, atol : float > 0
        Tolerances of the integrator (atol applies to ``x/D_y``, ``x'/(D_y w_0)`` and z, all
        scaled to order one; w_0 is the initial natural circular frequency).

    Returns
    -------
    ReferenceResponse
        Displacement, velocity, acceleration, member force ``m x'' + c x' + f_s``, z and the
        restoring force ``f_s``, each of shape ``(n,)``.

    Raises
    ------
    ParameterError
        If a parameter is out of range or the integration fails.

    Notes
    -----
    The member force equals ``-(1+alpha) m xg'' - alpha m x''`` (paper Eq. 2.5), as for the
    linear member: the equation of motion does not depend on the member's constitutive law.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.1, 2.4, 2.5.
    M. Ismail, F. Ikhouane and J. Rodellar, The hysteresis Bouc-Wen model, a survey, Arch.
    Comput. Methods Eng. 16, 2009, 161-188.
    L. Petzold, Automatic selection of methods for solving stiff and nonstiff systems of
    ordinary differential equations, SIAM J. Sci. Stat. Comput. 4(1), 1983, 136-148 (LSODA).
    """
    if not isinstance(specimen, BoucWenSpecimen):
        raise ParameterError(f'specimen={specimen!r}: expected a BoucWenSpecimen')
    alpha = _positive('alpha', alpha, allow_zero=True)
    structure = study_structure({'alpha': alpha, 'mass_kg': specimen.mass_kg,
                                 'damping_N_s_per_m': specimen.damping_N_s_per_m,
                                 'stiffness_N_per_m': specimen.stiffness_N_per_m})
    return structure_reference(structure, [specimen], dt, ground_acceleration_m_s2, rtol=rtol,
                               atol=atol).rig(STUDY_RIG)


def run_reference(run) -> StructureReference:
    """The whole structure's reference of a run, from its parameters and its record.

    Parameters
    ----------
    run : RunData
        The run; uses ``run.params`` (the study's: ``alpha``, ``mass_kg``,
        ``damping_N_s_per_m``, ``stiffness_N_per_m``, ``dt``, ``specimen_model`` and the
        Bouc-Wen parameters, absent: linear and their defaults; a structure's: its
        ``structure`` and each rig's section) and ``run.ground_acceleration_m_s2`` (n,)
        [m/s^2].

    Returns
    -------
    StructureReference
        Over the same n samples as the run (an aborted run gives a shorter reference); the
        specimens are those the parameters declare (:func:`~seft_ros.core.structure.test_setup`),
        hysteretic where a rig's ``specimen_model`` is ``bouc_wen``.

    Raises
    ------
    ParameterError
        A parameter is missing or out of range (the message names it), the structure is
        invalid or disagrees with a rig's specimen.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 2.1 and Sec. 4.
    """
    params = run.params
    if is_study(params):
        missing = [name for name in _PARAMS if name not in params]
        if missing:
            raise ParameterError(f'run parameters: missing {", ".join(missing)}')
        model = params.get('specimen_model', 'linear')
        structure, specimen = _study(
            params['alpha'], params['mass_kg'], params['damping_N_s_per_m'],
            params['stiffness_N_per_m'], model,
            {n: params[n] for n in _BOUC_WEN if n in params} if model != 'linear' else {})
        specimens = [specimen]
    else:
        setup = test_setup(params)
        structure = setup.structure
        reference = None if structure.model_kind is None else getattr(
            model_plugin(structure.model_kind), 'reference', None)
        if reference is not None:
            # a plug-in model's reference is its program's own analysis of it (OpenSees')
            return reference(setup.substructures, _positive('dt', params.get('dt')),
                             run.ground_acceleration_m_s2)
        specimens = [make_specimen(setup.rig_params[r]) for r in setup.rig_names]
    return structure_reference(structure, specimens, _positive('dt', params.get('dt')),
                               run.ground_acceleration_m_s2)


def reference_from_run(run) -> ReferenceResponse:
    """The reference of a run of one rig at its rig's DOF (the study's test: of the run).

    Parameters
    ----------
    run : RunData
        A run of one rig (:func:`run_reference`).

    Returns
    -------
    ReferenceResponse
        Over the same n samples as the run (an aborted run gives a shorter reference).

    Raises
    ------
    ParameterError
        If a parameter is missing or out of range (see :func:`reference_response`), or the
        run has several rigs (``run_reference(run).rig(name)`` gives each).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 2.1 and Sec. 4.
    """
    reference = run_reference(run)
    if len(reference.rigs) != 1:
        raise ParameterError(f'a run of {len(reference.rigs)} rigs has no single rig '
                             'reference: use run_reference(run).rig(name)')
    return reference.rig(reference.rigs[0])


def planned_reference(params: Mapping[str, Any]) -> ReferenceResponse:
    """The linear one-DOF reference of a test before it runs: its specimen (``mass_kg``,
    ``damping_N_s_per_m``, ``stiffness_N_per_m``) and mass ratio on its prepared ground
    motion (``seft_ros.core.ground_motion.prepared_record``, scaled by ``amplitude_N``).

    Parameters
    ----------
    params : mapping
        Resolved parameters of one run.

    Returns
    -------
    ReferenceResponse

    Raises
    ------
    ParameterError, InputError
        As :func:`reference_response` and the record's reader.
    """
    from seft_ros.core.ground_motion import prepared_record
    gm = prepared_record(params)
    return reference_response(alpha=params['alpha'], mass_kg=params['mass_kg'],
                              damping_N_s_per_m=params['damping_N_s_per_m'],
                              stiffness_N_per_m=params['stiffness_N_per_m'], dt=params['dt'],
                              ground_acceleration_m_s2=gm.acceleration_m_s2)
