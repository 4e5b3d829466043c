"""Stability of a structure test: its closed sampled loop, from its eigenvalues (no rclpy).

The counterpart of :mod:`seft_ros.core.stability` for a structure
(:mod:`seft_ros.core.structure`): every rig's sampled linear model (the servohydraulic rig
with its I/O latency, or the delay rig), its force servo controller and, with ``model``, its
force-loop inverse, and the builders' law
(:class:`~seft_ros.core.substructure.StructureBuilder`: the computational degrees of freedom
advanced by the exact Hermite step
from the measured motion, the forces from ``model``'s law or Eq. 2 for ``none``), closed in
the lockstep order of one step (the rigs sample, the controllers act, the builders build the
next forces). The homogeneous loop (no ground motion) is ``S[k+1] = A S[k]``; the test is
stable when the spectral radius of ``A`` is below 1. Valve saturation and the
accelerometer's range are left out (small signal), as for one rig.

**Coupling scale.** A structure's computational part is scaled by ``s``:
``M(s) = diag_P(m) + s M_c``, ``C(s) = diag_P(c) + s C_c``, ``K(s) = diag_P(k) + s K_c`` (the
specimens stay as they are). For the study's test, whose computational part is the rigid mass
``alpha m``, ``s alpha`` is the mass ratio: the largest stable scale is the study's largest
stable alpha divided by the configured alpha. :func:`largest_stable_scale` finds where the
spectral radius first reaches 1.
"""

from dataclasses import dataclass
import json
import math
from typing import Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.graph import Graph
from seft_msgs_py.sampling import single_blas_thread
from seft_ros.core.stability import (
    NoLinearModelError,
    StabilityCheck,
    _delay_rig,
    _servohydraulic_rig,
)

__all__ = ['StructureLoop', 'largest_stable_scale', 'check_structure', 'scaled_parameters',
           'structure_stability_map']


def scaled_parameters(params: Mapping, scale: float) -> dict:
    """The run's parameters with its structure's computational part scaled by `scale`
    (module notes).

    Raises
    ------
    ParameterError
        `scale` not > 0, or no structure.
    """
    from seft_ros.core.substructure import structure_setup
    if not scale > 0:
        raise ParameterError(f'coupling scale {scale!r}: expected > 0')
    setup = structure_setup(params)
    sub = setup.substructures
    s = sub.structure
    idx = list(s.physical_index)
    doc = json.loads(s.to_json())
    for key, spec, part in (('mass_matrix_kg', sub.specimen_mass_kg, sub.mass_c_kg),
                            ('damping_matrix_N_s_per_m', sub.specimen_damping_N_s_per_m,
                             sub.damping_c_N_s_per_m),
                            ('stiffness_matrix_N_per_m', sub.specimen_stiffness_N_per_m,
                             sub.stiffness_c_N_per_m)):
        whole = float(scale) * np.asarray(part, dtype=float)
        for j, i in enumerate(idx):
            whole[i, i] += spec[j]
        doc[key] = whole.tolist()
    return dict(params, structure=json.dumps(doc, sort_keys=True, separators=(',', ':')))


@dataclass
class _Block:
    """Positions of one part of the loop state."""

    start: int
    size: int

    @property
    def slice(self) -> slice:
        return slice(self.start, self.start + self.size)


class StructureLoop:
    """The closed sampled loop of a structure test at one coupling scale (module notes).

    Parameters
    ----------
    params : mapping
        The run's resolved parameters (with a ``structure``; ``predictor`` 'none' or
        'model'; ``structure_builders`` as the run).
    scale : float > 0
        Coupling scale of the computational part.

    Attributes
    ----------
    matrix : ndarray, shape (N, N)
        ``A`` of ``S[k+1] = A S[k]``.

    Raises
    ------
    NoLinearModelError
        A rig without a linear model (a yielding member).
    ParameterError
        As the builder.
    """

    def __init__(self, params: Mapping, scale: float = 1.0):
        from seft_ros.core.controller import ForceServoController
        from seft_ros.core.predictors import ForceLoopInverse
        from seft_ros.core.substructure import StructureBuilder, hermite_step, structure_setup
        p = scaled_parameters(params, scale) if scale != 1.0 else dict(params)
        setup = structure_setup(p)
        sub = setup.substructures
        s = sub.structure
        graph = Graph.from_parameters(p)
        rigs = list(setup.rig_names)
        pi, qi = list(s.physical_index), list(s.computational_index)
        n_p, n_c = len(pi), len(qi)
        predictor = p['predictor']
        dt = float(p['dt'])
        with single_blas_thread():
            builders = [StructureBuilder.from_parameters(p, local=graph.local_rigs(b))
                        for b in graph.builder_nodes()]
        # each rig: its sampled model, its controller, its force-loop inverse
        models = []
        for r in rigs:
            rp = setup.rig_params[r]
            if rp.get('specimen_model', 'linear') != 'linear':
                raise NoLinearModelError(f'rig {r}: specimen {rp["specimen_model"]!r} is '
                                         'nonlinear')
            if rp['rig_model'] == 'servohydraulic':
                a, b, cy = _servohydraulic_rig(rp)
                ac, bc, cc, dc = ForceServoController.from_parameters(rp).state_space()
                taps = (ForceLoopInverse.from_parameters(rp).taps if predictor == 'model'
                        else np.ones(1))
            elif rp['rig_model'] == 'delay':
                a, b, cy = _delay_rig(rp)
                ac = bc = cc = dc = None
                taps = np.ones(1)
            else:
                raise NoLinearModelError(f'rig {r}: rig model {rp["rig_model"]!r} has no '
                                         'linear model')
            models.append((a, b, cy, ac, bc, cc, dc, np.asarray(taps, dtype=float)))
        hist = max([b._n_hist if predictor == 'model' else 1 for b in builders]
                   + [len(m[7]) for m in models])
        # the state: per rig z, x_c, F[k .. k-hist+1]; the computational state and the
        # physical DOFs' measured x, v of the previous sample
        blocks, pos = [], 0
        for a, b, cy, ac, *_ in models:
            z = _Block(pos, a.shape[0])
            pos += z.size
            c = _Block(pos, 0 if ac is None else ac.shape[0])
            pos += c.size
            f = _Block(pos, hist)
            pos += hist
            blocks.append((z, c, f))
        zq = _Block(pos, 2 * n_c)
        pos += zq.size
        xp = _Block(pos, 2 * n_p)
        pos += xp.size
        size = pos
        m = np.zeros((size, size))
        # measured outputs of sample k, rows on S[k]: y[r] = (x, v, a, f)
        outputs = []
        for (z, _, _), (_, _, cy, *_) in zip(blocks, models):
            y = np.zeros((4, size))
            y[:, z.slice] = cy
            outputs.append(y)
        for (z, c, f), (a, b, cy, ac, bc, cc, dc, taps), y in zip(blocks, models, outputs):
            cmd = np.zeros(size)
            cmd[f.start:f.start + len(taps)] = taps            # sum_i w_i F[k - i]
            if ac is None:
                u = cmd
            else:
                w_in = np.vstack([cmd - y[3], y[1], y[2]])
                u = dc[0] @ w_in
                u[c.slice] += cc[0]
                m[c.slice, c.slice] = ac
                m[c.slice] += bc @ w_in
            m[z.slice, z.slice] = a
            m[z.slice] += np.outer(b[:, 0], u)
        # the computational DOFs: z_Q[k] = S [z_Q[k-1], x_P[k-1], v_P[k-1], x_P[k], v_P[k], 0]
        x_now = np.vstack([y[0] for y in outputs])
        v_now = np.vstack([y[1] for y in outputs])
        zq_now = np.zeros((2 * n_c, size))
        if n_c:
            step = hermite_step(sub, pi, dt)
            inputs = np.zeros((step.shape[1], size))
            inputs[:2 * n_c, zq.slice] = np.eye(2 * n_c)
            o = 2 * n_c
            inputs[o:o + 2 * n_p, xp.slice] = np.eye(2 * n_p)
            inputs[o + 2 * n_p:o + 3 * n_p] = x_now
            inputs[o + 3 * n_p:o + 4 * n_p] = v_now
            zq_now = step @ inputs
            m[zq.slice] = zq_now
        m[xp.start:xp.start + n_p] = x_now
        m[xp.start + n_p:xp.start + xp.size] = v_now
        # every DOF's displacement and velocity at sample k, rows on S[k]
        x_all = np.zeros((s.n, size))
        v_all = np.zeros((s.n, size))
        for j, i in enumerate(pi):
            x_all[i], v_all[i] = x_now[j], v_now[j]
        for j, i in enumerate(qi):
            x_all[i], v_all[i] = zq_now[j], zq_now[n_c + j]
        # the new forces F[k+1] of each builder's rigs, and the histories' shift
        for builder in builders:
            local = [rigs.index(r) for r in builder.local_rigs]
            if predictor == 'model':
                order = builder._law_order
                n_l, nh = len(local), builder._n_hist
                law = builder.law_matrix
                new = np.zeros((n_l, size))
                ns = len(order)
                q_rows = np.vstack([x_all[order], v_all[order]])       # x_L, x_U; v_L, v_U
                q_rows = np.vstack([q_rows[:n_l], q_rows[ns:ns + n_l], q_rows[n_l:ns],
                                    q_rows[ns + n_l:]])
                new += law[:, :2 * ns] @ q_rows
                for jj, r in enumerate(local):
                    f = blocks[r][2]
                    cols = law[:, 2 * ns + jj * nh:2 * ns + (jj + 1) * nh]   # F[k+1-nh .. k]
                    for col in range(nh):
                        new[:, f.start + (nh - 1 - col)] += cols[:, col]
            else:
                kc = sub.stiffness_c_N_per_m[[pi[r] for r in local], :]
                cc = sub.damping_c_N_s_per_m[[pi[r] for r in local], :]
                new = -(kc @ x_all + cc @ v_all)
                for jj, r in enumerate(local):
                    new[jj] -= sub.rigid_mass_kg[r] * outputs[r][2]
            for jj, r in enumerate(local):
                f = blocks[r][2]
                m[f.start] = new[jj]
                for i in range(1, hist):
                    m[f.start + i, f.start + i - 1] = 1.0
        self.matrix = m
        self.scale = float(scale)

    @property
    def spectral_radius(self) -> float:
        """The largest eigenvalue modulus of ``matrix`` (< 1: stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.matrix))))


def largest_stable_scale(params: Mapping, predictor: str | None = None, *,
                         scale_max: float = 3.0, step: float = 0.1,
                         tol: float = 2e-3) -> float:
    """The coupling scale up to which the structure test is stable (module notes).

    Parameters
    ----------
    params : mapping
        The run's parameters.
    predictor : str, optional
        Default ``params['predictor']``.
    scale_max : float > 0
        Upper end of the search.
    step, tol : float > 0
        Grid step of the scan and bisection tolerance on the boundary.

    Returns
    -------
    float
        The first scale where the spectral radius reaches 1; ``inf`` if stable up to
        `scale_max`; ``0`` if unstable at the smallest scale of the grid (`step`).
    """
    if predictor is not None:
        params = dict(params, predictor=predictor)

    def stable(s):
        return StructureLoop(params, s).spectral_radius < 1.0
    grid = np.arange(step, scale_max + 0.5 * step, step)
    previous = None
    for s in grid:
        ok = stable(s)
        if not ok:
            if previous is None:
                return 0.0
            lo, hi = previous, s
            while hi - lo > tol:
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if stable(mid) else (lo, mid)
            return 0.5 * (lo + hi)
        previous = s
    return math.inf


def check_structure(params: Mapping) -> StabilityCheck:
    """Predicted stability of a structure run as configured (coupling scale 1).

    Returns
    -------
    StabilityCheck
        ``boundary_alpha`` holds the largest stable coupling scale (the study's alpha over
        the configured one); ``stable`` None where there is no linear model.
    """
    predictor = params['predictor']
    try:
        radius = StructureLoop(params).spectral_radius
    except NoLinearModelError as exc:
        return StabilityCheck(None, math.nan, math.nan,
                              f'structure with predictor {predictor}: no stability '
                              f'prediction ({exc})')
    # a coarse search (each point is an eigenvalue problem of a few hundred states)
    step = 0.1 if radius >= 1.0 else 0.25
    boundary = largest_stable_scale(params, step=step, tol=0.02)
    stable = radius < 1.0
    limit = ('stable up to at least 3 times its computational part' if math.isinf(boundary)
             else f'unstable already at {step:g} times its computational part'
             if boundary == 0.0 else
             f'largest stable coupling {boundary:.3g} times its computational part')
    message = (f'structure with predictor {predictor} is predicted '
               f'{"stable" if stable else "UNSTABLE"} (spectral radius {radius:.4f}; '
               f'{limit})')
    return StabilityCheck(stable, radius, boundary, message)


def structure_stability_map(params: Mapping, taus, predictors, *, scale_max: float = 3.0,
                            step: float = 0.25, tol: float = 0.01):
    """The largest stable coupling scale over the rigs' delay, one curve per predictor.

    Parameters
    ----------
    params : mapping
        A structure run's parameters; the delay varied is the run's ``io_latency_s``
        (servohydraulic) or ``tau_s`` (delay rig), of ``params['rig_model']``, for every rig
        whose section does not set its own.
    taus : array_like, shape (nt,)
        The delays [s].
    predictors : sequence of str
        'none' and/or 'model'.
    scale_max, step, tol
        As :func:`largest_stable_scale`.

    Returns
    -------
    StabilityMap
        Its ``boundary_alpha`` holds the largest stable coupling scale (``inf``: stable up to
        `scale_max`; ``0``: unstable at the smallest scale); ``alpha_max`` is `scale_max`.

    Raises
    ------
    NoLinearModelError
        A rig without a linear model.
    """
    from seft_ros.core.stability import DELAY_PARAMETER, StabilityMap
    rig = params['rig_model']
    knob = DELAY_PARAMETER[rig]
    taus = np.asarray(taus, dtype=float)
    predictors = tuple(predictors)
    bound = np.full((len(predictors), taus.size), math.nan)
    for i, name in enumerate(predictors):
        for j, tau in enumerate(taus):
            p = dict(params, predictor=name, **{knob: float(tau)})
            bound[i, j] = largest_stable_scale(p, scale_max=scale_max, step=step, tol=tol)
    intervals = [[[(0.0, float(b))] for b in row] for row in bound]
    return StabilityMap(rig, knob, taus, predictors, bound, intervals, {}, scale_max,
                        dict(params))
