"""Where an OpenSees computational part first yields: a pushover of the model before the test
(no rclpy).

Over the loop delay the compensators predict the interface force with the part's own tangent
and its yielding mechanisms (:mod:`seft_ros.core.tangent`); a mechanism seen yielding before
is anticipated, but a **first yield** is not: the part knows a member's strength only once
the member has yielded. :func:`probe_yield` finds it before the test, on the model itself:

* the computational model (the test's: :func:`~seft_ros.opensees.model.build_model` with the
  specimens removed) is built afresh for each push, its own loads (gravity) held;
* each of seft's DOFs is **pushed** alone, in each sense, every other DOF of seft's held at 0
  (single-point constraints, OpenSees' ``Penalty`` handler, a static ``Newton`` solve per
  increment; the model's other DOFs are free): the displacement doubles from
  :data:`FIRST_INCREMENT_M` until the restoring forces leave the linearization or the push
  reaches ``limit_m``, then the last doubling is pushed again from a fresh model in
  :data:`FINE_STEPS` increments;
* the restoring forces' **deficit** ``d = K_0 x - (R(x) - R(0))`` (``R``: the reactions at
  seft's DOFs, summed over the nodes an ``equalDOF`` ties to each) of one yielding member
  lies along its direction ``u`` (its deformation's gradient) and grows as
  ``lambda (z - z_y)`` with ``z = u . x``: two increments past the onset give the
  mechanism's direction ``u``, deficit stiffness ``lambda`` and onset ``z_y``; a third tells
  whether it stays bilinear (:data:`~seft_ros.core.tangent.BILINEAR_SPREAD`);
* the pushes of one mechanism (directions within
  :data:`~seft_ros.core.tangent.SAME_DIRECTION`) give its onsets in the two senses: its
  **virgin elastic range** ``[z_low, z_high]``.

Exact for members that yield sharply (a bilinear ``Steel01``) whose deformation is linear in
seft's DOFs (a ``zeroLength`` story, a truss); a member that yields gradually (``Steel02``
fibres) is found but marked not bilinear, and is predicted as before (its tangent followed
from sample to sample). Only the first member to yield on each push is found: one whose
every push yields another member first stays unknown (anticipated from its first yield on,
as before).

References
----------
A. K. Chopra and R. K. Goel (2002), A modal pushover analysis procedure for estimating
seismic demands for buildings, Earthquake Engineering and Structural Dynamics 31(3), 561-582
(a pushover under imposed displacements); J. C. Simo and T. J. R. Hughes (1998),
Computational Inelasticity, Springer, Sec. 1.2 (the elastic range of a bilinear member).
"""

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from seft_ros.core.tangent import BILINEAR_SPREAD, SAME_DIRECTION, VirginMechanism
from seft_ros.opensees.loader import captured, last_message, opensees
from seft_ros.opensees.model import ModelError, ModelSpec, build_model, interface_group

__all__ = ['probe_yield', 'Push', 'FIRST_INCREMENT_M', 'FINE_STEPS', 'DEFICIT_TOLERANCE',
           'describe_mechanisms', 'pushover_skipped']

#: The first increment of a push [m]; it doubles to the push's limit.
FIRST_INCREMENT_M = 1e-5
#: Increments over the doubling that first left the linearization.
FINE_STEPS = 64
#: The restoring forces have left the linearization where their deficit exceeds this part
#: of the linearization's force ``|K_0 x|`` (a static solve's round-off is about 1e-12 of it).
DEFICIT_TOLERANCE = 1e-6
#: Tags of the probe's pattern and time series (far from a model's, and from the test's).
_PATTERN, _SERIES = 2_000_000_021, 2_000_000_022
#: Two increments' deficit directions within this (cosine) are one member's.
_ONE_MEMBER = 1.0 - 1e-4
#: A DOF whose part of a mechanism's direction is below this part of the largest is left out
#: of its coordinate's description (:func:`describe_mechanisms`).
_COORDINATE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Push:
    """One push's first yielding member (None fields: the push stayed linear to its limit).

    Attributes
    ----------
    dof : int
        The pushed DOF (seft's order).
    sense : float
        +1 or -1.
    direction : ndarray (n,) or None
        ``u`` (unit; its sign: ``z`` grows with the push).
    deficit_N_per_m : float
        ``lambda``.
    onset_m : float
        ``z_y``: ``z`` where the member starts to yield.
    bilinear : bool
        Whether its deficit stiffness stayed within ``BILINEAR_SPREAD`` over the increments
        that followed the onset.
    """

    dof: int
    sense: float
    direction: np.ndarray | None = None
    deficit_N_per_m: float = 0.0
    onset_m: float = 0.0
    bilinear: bool = False


def probe_yield(spec: ModelSpec, stiffness_N_per_m, limit_m: Sequence[float]
                ) -> tuple[list[VirginMechanism], list[Push]]:
    """Push the computational model along each of seft's DOFs in each sense (module notes).

    Parameters
    ----------
    spec : ModelSpec
        The model (built anew for each push; the model in OpenSees afterwards is the last
        push's: build the test's again).
    stiffness_N_per_m : ndarray (n, n)
        ``K_0``: the computational part's linearization condensed to seft's DOFs [N/m].
    limit_m : sequence of float (n,)
        How far each DOF is pushed, at most [m].

    Returns
    -------
    mechanisms : list of VirginMechanism
        Each mechanism found, with the onsets found in either sense (None: not found).
    pushes : list of Push
        Each push's finding (``2 n``).

    Raises
    ------
    ModelError
        The model does not build, or its static analysis cannot be set up (OpenSees'
        message). A push whose increment does not converge ends there (what it found so
        far kept).
    ValueError
        `limit_m` is not one value per DOF.
    """
    k0 = np.asarray(stiffness_N_per_m, dtype=float)
    n = k0.shape[0]
    limits = [float(v) for v in limit_m]
    if len(limits) != n:
        raise ValueError(f'probe_yield: {len(limits)} limits for {n} DOFs')
    pushes = []
    for i in range(n):
        for sense in (1.0, -1.0):
            pushes.append(_push(spec, k0, i, sense, limits[i]))
    return _mechanisms(pushes), pushes


def _push(spec: ModelSpec, k0: np.ndarray, i: int, sense: float, limit: float) -> Push:
    """One push (module notes)."""
    # coarse: doubling until the deficit shows
    state = _Model(spec, k0)
    s, before = 0.0, 0.0
    step = FIRST_INCREMENT_M
    found = False
    while s < limit:
        before, s = s, min(s + step, limit)
        step *= 2.0
        if not state.to(i, sense * s):
            break
        if state.yielded():
            found = True
            break
    if not found:
        return Push(i, sense)
    # fine: the last doubling again, from a fresh model
    state = _Model(spec, k0)
    if before > 0.0 and not state.to(i, sense * before):
        return Push(i, sense)
    samples = []
    for m in range(1, FINE_STEPS + 1):
        x = sense * (before + (s - before) * m / FINE_STEPS)
        if not state.to(i, x):
            break
        if state.yielded():
            samples.append(state.deficit())
            if len(samples) == 3:
                break
    # a few more past the doubling if the onset fell at its end
    extra = (s - before) / FINE_STEPS
    while len(samples) < 3 and state.x_i * sense < limit + 3 * extra:
        if not state.to(i, state.x_i + sense * extra):
            break
        samples.append(state.deficit())
    return _finding(i, sense, samples)


def _finding(i: int, sense: float, samples: list) -> Push:
    """The push's first member from the first (x, d) samples past its onset: its direction
    the second deficit's, its line ``lambda (z - z_y)`` through the first two deficits'
    projections on it (the first can be small, its direction round-off's); bilinear if a
    third sample keeps both (no other member yielded by then)."""
    if len(samples) < 2:
        return Push(i, sense)
    (x1, d1), (x2, d2) = samples[0], samples[1]
    u = d2 / float(np.linalg.norm(d2))
    if float(u @ (x2 - x1)) < 0.0:
        u = -u                                # z grows with the push
    z1, z2 = float(u @ x1), float(u @ x2)
    lam = float(u @ (d2 - d1)) / (z2 - z1)
    if not lam > 0.0:
        return Push(i, sense)
    onset = z1 - float(u @ d1) / lam
    bilinear = False
    if len(samples) >= 3:
        x3, d3 = samples[2]
        along = abs(float(u @ d3)) >= _ONE_MEMBER * float(np.linalg.norm(d3))
        lam3 = float(u @ (d3 - d2)) / (float(u @ x3) - z2)
        bilinear = along and abs(lam3 - lam) <= BILINEAR_SPREAD * max(abs(lam3), lam)
    return Push(i, sense, u, lam, onset, bilinear)


def _mechanisms(pushes: list[Push]) -> list[VirginMechanism]:
    """The pushes' members merged by direction, each with its onsets in both senses."""
    found: list[VirginMechanism] = []
    for p in pushes:
        if p.direction is None:
            continue
        match = None
        for j, m in enumerate(found):
            if abs(float(m.direction @ p.direction)) > SAME_DIRECTION:
                match = j
                break
        sign = 1.0
        if match is None:
            found.append(VirginMechanism(p.direction, p.deficit_N_per_m, None, None,
                                         p.bilinear))
            match = len(found) - 1
        else:
            sign = 1.0 if float(found[match].direction @ p.direction) > 0.0 else -1.0
        m = found[match]
        onset = sign * p.onset_m              # along m's direction
        low, high = m.low_m, m.high_m
        if sign > 0.0:
            high = onset if high is None else min(high, onset)
        else:
            low = onset if low is None else max(low, onset)
        found[match] = VirginMechanism(m.direction, max(m.deficit_N_per_m, p.deficit_N_per_m),
                                       low, high, m.bilinear and p.bilinear)
    return found


class _Model:
    """The computational model built for one push, with its static analysis."""

    def __init__(self, spec: ModelSpec, k0: np.ndarray):
        build_model(spec, test=True)
        ops = opensees()
        self.spec, self.k0 = spec, k0
        self.nodes = [(node, dof) for _, node, dof in spec.dofs]
        self.groups = [interface_group(node, dof) for node, dof in self.nodes]
        penalty = 1e6 * float(np.max(np.abs(k0)))
        with captured() as log:
            try:
                ops.loadConst('-time', 0.0)
                ops.timeSeries('Constant', _SERIES)
                ops.wipeAnalysis()
                ops.constraints('Penalty', penalty, penalty)
                ops.numberer('RCM')
                ops.system('BandGeneral')
                ops.test('NormDispIncr', 1e-12, 50, 0, 2)
                ops.algorithm('Newton')
                ops.integrator('LoadControl', 0.0)
                ops.analysis('Static')
                error = None
            except Exception as exc:
                error = exc
        if error is not None:
            raise ModelError(f'{spec.where}: the pushover could not be set up: OpenSees: '
                             f'{last_message(log.text) or error}')
        self.n = len(self.nodes)
        self.x_i = 0.0
        self.r0 = self._restoring()
        self.x = np.zeros(self.n)

    def _restoring(self) -> np.ndarray:
        ops = opensees()
        ops.reactions()
        return np.array([sum(float(ops.nodeReaction(n, dof)) for n in group)
                         for (_, dof), group in zip(self.nodes, self.groups)])

    def to(self, i: int, value: float) -> bool:
        """Hold DOF i at `value` [m], every other at 0, and solve; False: no convergence."""
        ops = opensees()
        try:
            ops.remove('loadPattern', _PATTERN)
        except Exception:
            pass
        ops.pattern('Plain', _PATTERN, _SERIES)
        for j, (node, dof) in enumerate(self.nodes):
            ops.sp(node, dof, value if j == i else 0.0)
        with captured():
            ok = ops.analyze(1) == 0
        # the penalty holds each DOF within 1e-6 of its value: the displacement it reached
        self.x = np.array([float(ops.nodeDisp(node, dof)) for node, dof in self.nodes])
        self.x_i = value
        return ok

    def deficit(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, d): seft's DOFs' displacement [m] and the restoring forces' deficit [N]."""
        r = self._restoring() - self.r0
        return self.x.copy(), self.k0 @ self.x - r

    def yielded(self) -> bool:
        x, d = self.deficit()
        scale = float(np.linalg.norm(self.k0 @ x))
        return float(np.linalg.norm(d)) > DEFICIT_TOLERANCE * scale and scale > 0.0


def pushover_skipped(spec: ModelSpec) -> str | None:
    """Why a model section has no pushover before the test (``'prediction: initial'``,
    ``'pushover: false'``), or None: it has one (``prediction: tangent`` with ``pushover``
    true)."""
    if spec.prediction != 'tangent':
        return f'prediction: {spec.prediction}'
    if not spec.pushover:
        return 'pushover: false'
    return None


def describe_mechanisms(mechanisms: Sequence[VirginMechanism], dofs: Sequence[str]) -> list[dict]:
    """The pushover's mechanisms as a run's summary gives them (JSON-able).

    Each mechanism is given along a coordinate scaled so that its largest DOF weight is 1
    (a story between two floors: the drift ``x_i - x_j``; the last DOF's of several equal
    weights): the weights per DOF, where it first yields in the negative and the positive
    sense [m] (None: not found) and the stiffness it loses once it yields [N/m] (``lambda``
    of the unit direction times the largest weight's square: ``(1 - b) k`` for a bilinear
    story).

    Parameters
    ----------
    mechanisms : sequence of VirginMechanism
        :func:`probe_yield`'s mechanisms.
    dofs : sequence of str
        The structure's DOF names, in seft's order (the directions' length).

    Returns
    -------
    list of dict
        ``{'coordinate': {dof: weight}, 'first_yield_m': [low, high],
        'lost_stiffness_N_per_m': float, 'bilinear': bool}`` per mechanism.
    """
    found = []
    for m in mechanisms:
        u = np.asarray(m.direction, dtype=float)
        i = int(np.nonzero(np.abs(u) >= (1.0 - 1e-9) * np.max(np.abs(u)))[0][-1])
        scale = u[i]
        weights = u / scale
        low, high = m.low_m, m.high_m
        if scale < 0.0:
            low, high = high, low
        found.append({
            'coordinate': {dofs[j]: float(w) for j, w in enumerate(weights)
                           if abs(w) > _COORDINATE_TOLERANCE},
            'first_yield_m': [None if low is None else float(low / scale),
                              None if high is None else float(high / scale)],
            'lost_stiffness_N_per_m': float(m.deficit_N_per_m * scale ** 2),
            'bilinear': bool(m.bilinear)})
    return found
