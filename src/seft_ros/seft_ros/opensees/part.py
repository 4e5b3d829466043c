"""The computational part of a test stepped by OpenSees once per sample (no rclpy).

:class:`OpenSeesPart` is the :class:`~seft_ros.core.substructure.ComputationalPart` of a
structure from an OpenSeesPy model (:mod:`seft_ros.opensees.model`): the model without its
specimens, built in this process, stepped by OpenSees' own transient analysis as soon as every
rig's measurement of a sample is in:

* the **interface DOFs follow the measured motion**: a single-point constraint moved to the
  measured displacement at the step's end (``sp``, OpenSees' ``Penalty`` constraint handler,
  its factor ``PENALTY_FACTOR`` times the largest diagonal of the effective stiffness), the
  step starting from the measured displacement, velocity and acceleration (``setNodeDisp``,
  ``setNodeVel``, ``setNodeAccel``); with ``substeps > 1`` the motion inside a sample is the
  cubic Hermite interpolant of the measured displacements and velocities at its ends (as the
  matrix path's :func:`~seft_ros.core.substructure.hermite_step`);
* the **ground motion** loads every other DOF with mass as ``-m iota xg''`` (nodal forces; the
  record linear between samples);
* **one transient step** (``Newmark`` average acceleration, ``Newton`` iterations to
  ``NormDispOrUnbalance``: a correction below 1e-12 m or an unbalance below
  ``UNBALANCE_TOLERANCE``, at most 25; a banded system until the model first leaves its
  linearization, then a full one): nonlinear elements and materials are stepped as they
  are;
* the **interface force** of each rig is minus the reaction at its interface DOF less the
  inertia of the interface node's mass (``reactions('-dynamic')``: the elements' restoring
  and damping forces with their Rayleigh damping, and the node's; its mass is the specimen's
  and the rigid mass ``mu`` of seft's reference force, ``- mu a_hat``, so its inertia is
  seft's, not the model's), summed over the nodes an ``equalDOF`` ties to the interface node
  in that direction (a rigid floor: they move with it, and neither their ground-motion load
  nor their inertia is the model's).

Exact and approximate: for a linear model the step is Newmark's (second order; period error
about ``(omega dt)^2 / 12`` per mode, 0.35 % for a 16 Hz mode at 500 Hz, less with
``substeps``), where the matrix path integrates the computational DOFs exactly for the
interpolated motion. The compensators predict the interface force with a linear model
started from the model's state, its nonlinear restoring forces at the last sample held over
the prediction (:meth:`OpenSeesPart.prediction_state`): exact for a linear model. A yielding
model is predicted with its own tangent stiffness, read from the system Newton assembled on
the steps that changed it and condensed to seft's DOFs (:meth:`OpenSeesPart.tangent`;
``prediction: tangent``, the default), whose yielding mechanisms the builder follows over
the predicted motion (:mod:`seft_ros.core.tangent`); exact at the sample, approximate over
the loop delay (a first yield anticipated where a pushover before the test found it,
:mod:`seft_ros.opensees.probe`). With ``prediction: initial`` the change
is predicted with the linearization.

With ``step: deferred`` the state a builder gets for sample ``j`` is not OpenSees' but one
step of the part's linear model (the tangent, the restoring forces found from each DOF's
equilibrium) from OpenSees' state at ``j - 1`` (``OpenSeesPart._step_ahead``); OpenSees
steps to ``j`` afterwards (:meth:`OpenSeesPart.advance`: a real-time builder once its
command is out), and the state recorded is OpenSees' own, one sample later
(``recorded_lag_steps``). The OpenSees step leaves the command's critical path; the command
sees a yield one sample later.

Each step's wall time (``time.perf_counter``) is recorded as the state
``opensees/step_time_s``; :func:`dry_run` times the model before a real-time run.
"""

import math
import time
from typing import Sequence

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.core.reference_force import TANGENT_FLOOR, below_tangent_floor
from seft_ros.core.structure import Substructures
from seft_ros.core.substructure import structure_matrices
from seft_ros.opensees.loader import captured, last_message, opensees, rayleigh_calls
from seft_ros.opensees.model import KIND, ModelError, ModelSpec, build_model, interface_group
from seft_ros.opensees.probe import describe_mechanisms, probe_yield, pushover_skipped

__all__ = ['OpenSeesPart', 'STEP_TIME', 'dry_run', 'DryRun', 'BUDGET_FRACTION',
           'DEFERRED_BUDGET_FRACTION', 'budget_fraction', 'element_names',
           'element_response']

#: The recorded state of each step's OpenSees wall time [s].
STEP_TIME = 'opensees/step_time_s'
#: How far the pushover before the test pushes each of seft's DOFs [m]
#: (:func:`~seft_ros.opensees.probe.probe_yield`; a push stops earlier at its first yield,
#: or where OpenSees no longer converges).
PUSH_LIMIT_M = 1.0
#: Tags of seft's own pattern and time series (far from a model's).
_PATTERN, _SERIES = 2_000_000_011, 2_000_000_012
#: The interface's moving constraint is a penalty of this many times the largest diagonal of
#: the effective stiffness: its error is ``1/PENALTY_FACTOR`` of the interface force's own
#: displacement scale.
PENALTY_FACTOR = 1e6
#: A Newton iteration whose unbalance is below this part of the computational stiffness'
#: largest entry (times 1 m) [N] has converged: the one solve of a step that stays linear
#: (its correction would be the round-off's), else the correction below 1e-12 m.
UNBALANCE_TOLERANCE = 1e-7
#: A step that moved the restoring forces' offset from the linearization by more than this
#: part of the linearization's own force increment (a yielding member's: about its deficit,
#: whatever the increment) and than :data:`NOISE_TOLERANCE` of the largest restoring force
#: the linearization has given so far is off the linearization (``OpenSeesPart.tangent``).
NONLINEAR_TOLERANCE = 1e-4
#: An elastic model's offset moves by its integration's round-off and its massless DOFs'
#: damping (the condensed damping is exact for static massless DOFs only): 1e-5 of that force
#: on the steel frame, 5e-5 on the ten-story one (measured; a linear model is not tracked at
#: all: it never needs a second Newton iteration).
NOISE_TOLERANCE = 1.5e-5
#: A tangent within this part of the largest entry of the linearization's stiffness is the
#: linearization's (the assembled system's round-off, less Newmark's part and the penalty,
#: is about 1e-9 of it).
INITIAL_TOLERANCE = 1e-6
#: An interface DOF the model's own loads hold displaced by more than this at the start [m]
#: is refused: the rig's specimen starts unloaded at 0 (about the resolution of a rig's
#: displacement transducer; a symmetric frame under gravity is displaced by round-off, 1e-22 m).
STATIC_OFFSET_TOLERANCE_M = 1e-6
#: A real-time run is refused when the dry run's median step time exceeds this part of
#: ``dt`` (the other half is the builder's own work and the messages, done after the step).
BUDGET_FRACTION = 0.5
#: The same with ``step: deferred``: the step is done after the builder's command is out,
#: while the builder waits for the next sample; what is left of the period is the builder's
#: own work (its p99 0.47 ms for the steel frame yielding at 1 kHz, measured lockstep:
#: ``benchmarks/builder_step.py``).
DEFERRED_BUDGET_FRACTION = 0.8


def budget_fraction(step: str) -> float:
    """The part of the sample period an OpenSees step may take in real time, for the model
    section's ``step`` (:data:`BUDGET_FRACTION`, :data:`DEFERRED_BUDGET_FRACTION`)."""
    return DEFERRED_BUDGET_FRACTION if step == 'deferred' else BUDGET_FRACTION


class OpenSeesPart:
    """The computational part as an OpenSees model (module notes).

    Parameters
    ----------
    sub : Substructures
        A split structure from an OpenSees model (``sub.structure.model``).
    dt : float > 0
        Control period [s].
    pushover : bool
        With ``prediction: tangent`` and the model section's ``pushover`` (default true),
        find where the members first yield before the test
        (:func:`~seft_ros.opensees.probe.probe_yield`, by :meth:`prepare`; a dry run that
        only times the steps does without).

    Attributes
    ----------
    state_names : tuple of str
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        per computational DOF, then :data:`STEP_TIME`, then the recorded elements'
        (:func:`element_names`).
    matrices : Matrices
        The model's linearization (the structure's matrices).
    step_times_s : list of float
        Each OpenSees step's wall time [s].
    virgin_mechanisms : list of VirginMechanism or None
        The pushover's mechanisms (None: not pushed yet, or not pushed).
    pushes : list of Push or None
        Its pushes (the same).
    pushover_time_s : float
        Its wall time [s].

    Notes
    -----
    The model is built in OpenSees by :meth:`prepare` (or the first step), not here: one
    model per process, and a builder made for its linear model only never builds it.
    """

    def __init__(self, sub: Substructures, dt: float, *, pushover: bool = True):
        s = sub.structure
        if s.model_kind != KIND:
            raise ParameterError('OpenSees part: the structure has no OpenSees model')
        self.sub = sub
        self.dt = float(dt)
        self.spec = spec = ModelSpec.from_doc(s.model)
        self.rig_names = s.rig_names
        self._pi, self._qi = list(s.physical_index), list(s.computational_index)
        self.state_names = tuple(f'{s.dofs[i]}/{q}' for q in (
            'displacement_m', 'velocity_m_s', 'acceleration_m_s2') for i in self._qi) + (
            STEP_TIME,) + tuple(name for e in spec.elements for name in element_names(e))
        self._element_values = [0.0] * (2 * len(spec.elements))
        self._ndf: dict[int, int] = {}
        self.matrices = structure_matrices(sub)
        self.step_times_s: list[float] = []
        self._nodes = [(node, dof) for _, node, dof in spec.dofs]
        self._interface = [self._nodes[i] for i in self._pi]
        self._meas: list[dict] = [{} for _ in self.rig_names]
        self.ground: dict[int, float] = {}
        self._settled = -1
        self._x = [0.0] * s.n
        self._v = [0.0] * s.n
        self._a = [0.0] * s.n
        self._forces = [0.0] * len(self._pi)
        self._linear_forces = [0.0] * len(self._pi)
        self._substeps = max(1, int(spec.substeps))
        self._ready = False
        self._prediction_maps: dict = {}
        self._linear_maps()
        # the tangent (prediction 'tangent'): the restoring forces' offset from the
        # linearization at the latest sample, and whether it moved over the last step
        self._tangent_on = spec.prediction == 'tangent'
        self._read_next = False
        self._tangent_damping, self._damping_gain = (0.0, 0.0), 0.0
        self._model_loads = None
        self._k_t = None                  # the condensed tangent of the latest sample
        # the pushover's mechanisms (opensees.probe; prepare() finds them)
        self._pushover = pushover and pushover_skipped(spec) is None
        self.virgin_mechanisms = None
        self.pushes = None
        self.pushover_time_s = 0.0
        self._deficit = None              # deficit_forces' matrix
        self.tangent_steps = 0            # samples whose tangent was assembled
        # step: deferred: the sample ahead of OpenSees' (its linear step), and the
        # effective matrices of that step per stiffness
        self._deferred = spec.step == 'deferred'
        self.recorded_lag_steps = 1 if self._deferred else 0
        self._ahead = None                # (sample, x, v, a, forces)
        self._ahead_maps: dict = {}
        self._ahead_fixed = None

    def prepare(self) -> None:
        """Build the model in OpenSees and set up seft's analysis of it (done by the first
        step otherwise: a real-time builder calls it before the run; a builder made only
        for its linear model, as the pre-run guard's, never does).

        Raises
        ------
        ModelError
            The model does not build or its analysis cannot be set up (OpenSees' message).
        """
        if not self._ready:
            if self._pushover and self.virgin_mechanisms is None:
                # where the members first yield, on the model built for the pushes (then
                # built again for the test)
                t0 = time.perf_counter()
                self.virgin_mechanisms, self.pushes = probe_yield(
                    self.spec, self.sub.stiffness_c_N_per_m, [PUSH_LIMIT_M] * len(self._nodes))
                self.pushover_time_s = time.perf_counter() - t0
            build_model(self.spec, test=True)
            self._series = False
            self._setup()
            self._ready = True

    def findings(self) -> dict:
        """What the part found before the test, for the run's data (JSON-able; the builder
        hands it on: ``RunData.extra['part_findings']``, the builder's final status in a bag):
        ``{'pushover': entry}``, the entry ``{'ran': False, 'why': str}`` (``prediction``
        not ``tangent``, ``pushover: false``, or the model not built yet) or ``{'ran': True,
        'time_s': float, 'mechanisms': [...]}``
        (:func:`~seft_ros.opensees.probe.describe_mechanisms`)."""
        skipped = pushover_skipped(self.spec)
        if skipped is not None:
            entry = {'ran': False, 'why': skipped}
        elif not self._pushover:
            entry = {'ran': False, 'why': 'not run: a part made without it (a dry run)'}
        elif self.virgin_mechanisms is None:
            entry = {'ran': False, 'why': 'not run: the model was never built'}
        else:
            entry = {'ran': True, 'time_s': float(self.pushover_time_s),
                     'mechanisms': describe_mechanisms(self.virgin_mechanisms,
                                                       self.sub.structure.dofs)}
        return {'pushover': entry}

    # -- OpenSees ---------------------------------------------------------------------------

    def _setup(self) -> None:
        """seft's analysis of the computational model: loads, handler, integrator."""
        ops = opensees()
        spec = self.spec
        self._groups = [interface_group(node, dof) for node, dof in self._interface]
        interface = {(n, dof) for (node, dof), group in zip(self._interface, self._groups)
                     for n in group}
        loads = []
        for node in ops.getNodeTags():
            mass = ops.nodeMass(node)
            d = spec.excitation_dof
            if len(mass) >= d and mass[d - 1] > 0.0 and (node, d) not in interface:
                loads.append((node, len(mass), -float(mass[d - 1])))
        self._loads = loads
        self._interface_mass = [[float(ops.nodeMass(n)[dof - 1]) for n in group]
                                for (_, dof), group in zip(self._interface, self._groups)]
        m = np.diag(self.sub.structure.mass_kg)
        k = np.diag(self.sub.stiffness_c_N_per_m)
        c = np.diag(self.sub.damping_c_N_s_per_m)
        h = self.dt / self._substeps
        stiff = float(np.max(np.abs(k) + 4.0 * m / h ** 2 + 2.0 * np.abs(c) / h))
        self._penalty = PENALTY_FACTOR * stiff
        # a step converges when its last correction is below 1e-12 m, or (the one solve of
        # a step that stays linear) when the unbalance left is (module notes)
        unbalance = UNBALANCE_TOLERANCE * float(np.max(np.abs(self.sub.stiffness_c_N_per_m)))
        with captured() as log:
            try:
                ops.wipeAnalysis()
                if not self._series:
                    ops.timeSeries('Constant', _SERIES)
                    self._series = True
                ops.constraints('Penalty', self._penalty, self._penalty)
                ops.numberer('RCM')
                ops.test('NormDispOrUnbalance', 1e-12, unbalance, 25, 0, 2)
                if self._tangent_on:
                    # Newmark's M, C part of the system, from a full one (printA reads only
                    # those): the tangent is read from the system Newton assembles
                    ops.system('FullGeneral')
                    k0 = _assembled(ops, (0.0, 0.0, 1.0))
                    self._newmark_mc = _assembled(ops, (4.0 / h ** 2, 2.0 / h, 1.0)) - k0
                    self._tangent_damping = _stiffness_damping(ops, k0, spec.where)
                    self._k0_full = k0
                    self._damping_gain = 2.0 / h * sum(self._tangent_damping)
                ops.system('BandGeneral')
                self._full_system = False
                ops.algorithm('Newton')
                ops.integrator('Newmark', 0.5, 0.25)
                ops.analysis('Transient')
                error = None
            except ModelError as exc:         # the model's damping (_stiffness_damping)
                error = exc
            except Exception as exc:
                error = exc
        if isinstance(error, ModelError):
            raise error
        if error is not None:
            raise ModelError(f'{spec.where}: setting up the analysis failed: OpenSees: '
                             f'{last_message(log.text) or error}')
        if self._tangent_on:
            self._equations = _equations(ops)
        # the model's own load patterns (gravity), checked to be constant over the first step
        self._model_loads = {int(tag): float(ops.getLoadFactor(tag))
                             for tag in ops.getPatterns() if int(tag) != _PATTERN}
        self._check_static_offset(ops)

    def _check_static_offset(self, ops) -> None:
        """At rest, before the first step: no interface DOF is held displaced by the model's
        own loads (a lateral load held by ``loadConst``). The rig's specimen starts unloaded
        at 0; the model, imposed the measured 0 at the first step, would start the test with
        a step of its static force (the reference starts from the static state: a start-up
        transient of 7 % NRMS over 1 s, 1.3 % over 10 s, on a two-story building with 100 N
        at its roof).

        Raises
        ------
        ModelError
            An interface DOF displaced by more than :data:`STATIC_OFFSET_TOLERANCE_M` (the
            message names it, its displacement and the remedy).
        """
        names = [name for name, _, _ in self.spec.dofs]
        for i, (node, dof) in zip(self._pi, self._interface):
            x0 = float(ops.nodeDisp(node, dof))
            if abs(x0) > STATIC_OFFSET_TOLERANCE_M:
                raise ModelError(
                    f'{self.spec.where}.model: its own loads hold the interface DOF {names[i]} '
                    f'(node {node}, dof {dof}) at {1e3 * x0:.4g} mm at the start, where the '
                    "rig's specimen starts unloaded at 0 (a lateral load held by loadConst): "
                    'the test would start with a step; leave lateral loads out of build() '
                    '(gravity on a frame that does not sway may stay)')

    def _check_model_loads(self, ops) -> None:
        """After the first step: the model's own load patterns kept their factors. One on a
        time series that is not constant (an analysis in ``build()`` without ``loadConst``)
        would grow with the test's time, and the test and its reference would part.

        Raises
        ------
        ModelError
            A pattern's factor moved (the message names it and the remedy).
        """
        loads, self._model_loads = self._model_loads, None
        for tag, before in (loads or {}).items():
            after = float(ops.getLoadFactor(tag))
            if after != before:
                raise ModelError(f'{self.spec.where}.model: its load pattern {tag} is not '
                                 f'constant (its factor moved from {before:g} to {after:g} '
                                 'over the first step: an analysis in build() left it on its '
                                 "time series): call ops.loadConst('-time', 0.0) after the "
                                 'analysis, or remove the pattern')

    def _opensees_step(self, j: int) -> None:
        """Step the model from sample j to j+1 with every rig's measurements of both."""
        self.prepare()
        ops = opensees()
        t0 = time.perf_counter()
        n_sub = self._substeps
        h = self.dt / n_sub
        start = [self._meas[r][j] for r in range(len(self._pi))]
        end = [self._meas[r][j + 1] for r in range(len(self._pi))]
        g0, g1 = self.ground.get(j, 0.0), self.ground.get(j + 1, 0.0)
        iterations = 0
        for i in range(n_sub):
            s0, s1 = i / n_sub, (i + 1) / n_sub
            for (node, dof), m0, m1 in zip(self._interface, start, end):
                x, v, a = _hermite(m0, m1, self.dt, s0 * self.dt)
                if i == 0:
                    v, a = m0[1], m0[2]
                ops.setNodeDisp(node, dof, x, '-commit')
                ops.setNodeVel(node, dof, v, '-commit')
                ops.setNodeAccel(node, dof, a, '-commit')
            g = g0 + (g1 - g0) * s1
            try:
                ops.remove('loadPattern', _PATTERN)
            except Exception:          # pragma: no cover - the first step has none
                pass
            ops.pattern('Plain', _PATTERN, _SERIES)
            for (node, dof), m0, m1 in zip(self._interface, start, end):
                ops.sp(node, dof, m1[0] if i == n_sub - 1 else
                       _hermite(m0, m1, self.dt, s1 * self.dt)[0])
            d = self.spec.excitation_dof
            for node, ndf, minus_m in self._loads:
                values = [0.0] * ndf
                values[d - 1] = minus_m * g
                ops.load(node, *values)
            failed = ops.analyze(1, h) != 0
            iterations = max(iterations, ops.testIter())
            if failed:
                raise ModelError(f'{self.spec.where}: OpenSees failed to converge at sample '
                                 f'{j + 1} (t = {(j + 1) * self.dt:.4f} s): the computational '
                                 'model cannot follow the measured motion')
        ops.reactions('-dynamic')
        for r, (node, dof) in enumerate(self._interface):
            self._forces[r] = -sum(float(ops.nodeReaction(n, dof)) - m * float(ops.nodeAccel(
                n, dof)) for n, m in zip(self._groups[r], self._interface_mass[r]))
        for i, (node, dof) in enumerate(self._nodes):
            self._x[i] = float(ops.nodeDisp(node, dof))
            self._v[i] = float(ops.nodeVel(node, dof))
            self._a[i] = float(ops.nodeAccel(node, dof))
        for n, tag in enumerate(self.spec.elements):
            self._element_values[2 * n:2 * n + 2] = element_response(ops, tag, self._ndf)
        for r, p in enumerate(self._pi):       # the physical DOFs as measured
            self._x[p], self._v[p], self._a[p] = end[r][0], end[r][1], end[r][2]
        if self._tangent_on:
            self._follow_tangent(ops, iterations, g1)
        if self._model_loads is not None:
            self._check_model_loads(ops)
        self.step_times_s.append(time.perf_counter() - t0)

    def _follow_tangent(self, ops, iterations: int, g: float) -> None:
        """After a step: the tangent of its end (None: the linearization's).

        Newton needs more than its one solve only where the tangent changed within the step
        (a step on one tangent converges at its first solve, ``NormDispOrUnbalance``): until
        a step first needs two, the model is linear and nothing is done. From then on, the
        restoring forces' offset from the linearization, ``d = R - K_c x`` (``R`` from each
        DOF's equilibrium), moves over a step only where the model is off its linearization:
        a step that moved the offset by less than
        :data:`NONLINEAR_TOLERANCE` of the linear force increment (or than
        :data:`NOISE_TOLERANCE` of the largest force so far) is on the linearization; one
        that changed its tangent has it read (``printA``, :meth:`_condensed_tangent`); one
        that moved the offset on an unchanged tangent keeps the one read last. Until the
        model first leaves its linearization its system is a banded one, then a full one
        (``printA`` reads only those), from which the tangent is read from the next step on.
        """
        if iterations > 1:
            self._nonlinear = True
        if not self._nonlinear:
            return                                    # a linear model, so far
        z = np.array(self._inputs(g))
        offset = self._offset_map @ z
        x = z[:len(self._x)]
        # the largest magnitudes, read as Python floats (exact; numpy's max of a few
        # entries costs microseconds each, on every step once the model has yielded)
        moved = max(map(abs, (offset - self._offset).tolist()))
        self._force_scale = max(self._force_scale, max(map(abs, (self._k0 @ x).tolist())))
        increment = max(map(abs, (self._k0 @ (x - self._x_last)).tolist()))
        self._offset, self._x_last = offset, x
        off = moved > max(NONLINEAR_TOLERANCE * increment, NOISE_TOLERANCE * self._force_scale)
        if not (off or iterations > 1 or self._read_next):
            self._k_t = None                          # on the linearization
            return
        if not (iterations > 1 or self._read_next or self._k_t is None):
            return                                    # on the tangent read last
        if not self._full_system:
            ops.system('FullGeneral')
            self._full_system = self._read_next = True
            return
        k_t = self._condensed_tangent(ops)
        k0 = self._k0
        # back on the initial tangent (a member unloaded): the linearization's, exactly
        self._k_t = None if np.max(np.abs(k_t - k0)) <= INITIAL_TOLERANCE * np.max(
            np.abs(k0)) else k_t
        # damping on the committed stiffness: a step that changed the tangent is read with
        # the tangent committed before it; the next step's system has the new one committed
        self._read_next = iterations > 1 and self._tangent_damping[1] != 0.0
        self.tangent_steps += 1

    def _step_ahead(self, j: int) -> tuple:
        """``step: deferred``: the state of sample `j` from OpenSees' state of ``j - 1``
        (:attr:`_settled`) by one step of the part's linear model, as OpenSees would step
        it: the interfaces moved to the measured motion of `j` (the cubic Hermite
        interpolant at the substeps' ends), the ground linear between the samples, Newmark's
        average acceleration over each of the ``substeps``; the restoring forces those of
        the tangent (or the linearization) from their value at ``j - 1``, found from each
        DOF's equilibrium there (as :meth:`_linear_maps`' offset: exact for a linear model
        up to the condensation of its massless DOFs' damping, and for a yielding one up to
        the tangent's change over the step).

        Returns
        -------
        (x, v, a, forces) : lists
            Every DOF's displacement [m], velocity [m/s] and acceleration [m/s^2] (the
            interfaces' as measured) and each rig's interface force [N] at `j`.
        """
        qi, pi = self._qi, self._pi
        n_sub = self._substeps
        h = self.dt / n_sub
        key = None if self._k_t is None else self._k_t.tobytes()
        parts = self._ahead_maps.get(key)
        if parts is None:
            parts = _remember(self._ahead_maps, key,
                              self._ahead_parts(self._k0 if self._k_t is None else self._k_t, h))
        k, inv_eff, m_iota, c_uu, c_up, k_uu, k_up, c_p = parts
        s = self._settled
        g0, g1 = self.ground.get(s, 0.0), self.ground.get(j, 0.0)
        x = np.array(self._x)
        # the restoring forces at s from each DOF's equilibrium (R = K_c x + offset); the
        # model starts on its linearization (no interface force is read before a step)
        restoring = self._k0 @ x
        if s > 0:
            restoring = restoring + self._offset_map @ np.array(self._inputs(g0))
        v_u = np.array([self._v[i] for i in qi])
        a_u = np.array([self._a[i] for i in qi])
        x_p = np.array([self._x[p] for p in pi])
        start = [self._meas[r][s] for r in range(len(pi))]
        end = [self._meas[r][j] for r in range(len(pi))]
        dx = np.zeros(len(x))
        for i in range(n_sub):
            ends = (end if i == n_sub - 1 else
                    [_hermite(m0, m1, self.dt, (i + 1) * h) for m0, m1 in zip(start, end)])
            g = g0 + (g1 - g0) * (i + 1) / n_sub
            x_end = np.array([e[0] for e in ends])
            dx[pi] = x_end - x_p
            x_p = x_end
            if qi:
                a_new = inv_eff @ (-m_iota * g - c_uu @ (v_u + 0.5 * h * a_u)
                                   - c_up @ [e[1] for e in ends] - restoring[qi]
                                   - k_uu @ (h * v_u + 0.25 * h * h * a_u) - k_up @ dx[pi])
                dx[qi] = h * v_u + 0.25 * h * h * (a_u + a_new)
                v_u = v_u + 0.5 * h * (a_u + a_new)
                a_u = a_new
            restoring = restoring + k @ dx
            x = x + dx
        x_out, v_out, a_out = x.tolist(), list(self._v), list(self._a)
        for n_i, i in enumerate(qi):
            v_out[i], a_out[i] = float(v_u[n_i]), float(a_u[n_i])
        for r, p in enumerate(pi):
            x_out[p], v_out[p], a_out[p] = end[r][0], end[r][1], end[r][2]
        forces = (-(restoring[pi] + c_p @ np.array(v_out))).tolist()
        return x_out, v_out, a_out, forces

    def _ahead_parts(self, k: np.ndarray, h: float) -> tuple:
        """The matrices of :meth:`_step_ahead` for the stiffness `k` (n x n) [N/m] and the
        substep `h` [s]: ``k``, the inverse of Newmark's effective mass of the
        computational DOFs ``(M + h/2 C + h^2/4 K)_UU``, ``M_UU iota_U``, the blocks
        ``C_UU, C_UP, K_UU, K_UP`` and the interfaces' rows ``C_P.``."""
        qi, pi = self._qi, self._pi
        if self._ahead_fixed is None:          # what does not depend on the stiffness
            uu, up = np.ix_(qi, qi), np.ix_(qi, pi)
            c = self.sub.damping_c_N_s_per_m
            m_uu = self.matrices.mass_kg[uu]
            self._ahead_fixed = (uu, up, m_uu + 0.5 * h * c[uu],
                                 m_uu @ self.matrices.influence[qi], c[uu], c[up], c[pi])
        uu, up, mc_eff, m_iota, c_uu, c_up, c_p = self._ahead_fixed
        k_uu = k[uu]
        inv_eff = np.linalg.inv(mc_eff + 0.25 * h * h * k_uu) if qi else None
        return k, inv_eff, m_iota, c_uu, c_up, k_uu, k[up], c_p

    def _linear_maps(self) -> None:
        """The matrix on ``z`` (:meth:`_inputs`) of the restoring forces' offset from the
        linearization, ``d = R - K_c x`` with ``R`` from each DOF's equilibrium (a
        computational DOF: ``-M_UU (a_U + iota_U g) - C_U. v``; an interface: ``-I_p -
        C_p. v``)."""
        sub, m = self.sub, self.matrices
        n, qi, pi = len(self._x), self._qi, self._pi
        nu, npp = len(qi), len(pi)
        offset = np.zeros((n, 2 * n + nu + 1 + npp))
        offset[:, :n] = -sub.stiffness_c_N_per_m
        offset[:, n:2 * n] = -sub.damping_c_N_s_per_m
        if qi:
            m_uu = m.mass_kg[np.ix_(qi, qi)]
            offset[np.ix_(qi, range(2 * n, 2 * n + nu))] = -m_uu
            offset[qi, 2 * n + nu] = -m_uu @ m.influence[qi]
        for j, p in enumerate(pi):
            offset[p, 2 * n + nu + 1 + j] = -1.0
        self._offset_map = offset
        self._offset = np.zeros(n)
        self._nonlinear = False
        self._k0 = sub.stiffness_c_N_per_m
        self._force_scale = 0.0
        self._x_last = np.zeros(n)

    def _inputs(self, g: float, state=None) -> list:
        """``z = [x (n), v (n), a_U, g, I_P]`` of OpenSees' latest sample (or of `state`,
        ``(x, v, a, forces)``): what the prediction's starting state is linear in."""
        x, v, a, forces = state or (self._x, self._v, self._a, self._forces)
        return x + v + [a[i] for i in self._qi] + [g] + forces

    def _prediction_map(self, stiffness_c, dofs) -> np.ndarray:
        """The matrix on ``z`` of :meth:`prediction_state`'s shifted state and residuals
        at `dofs`, for the stiffness `stiffness_c` (None: the linearization's); kept for
        the few stiffnesses a run predicts with."""
        key = (None if stiffness_c is None else np.asarray(stiffness_c).tobytes(), tuple(dofs))
        out = self._prediction_maps.get(key)
        if out is not None:
            return out
        sub, m = self.sub, self.matrices
        n, qi, pi = len(self._x), self._qi, self._pi
        nu = len(qi)
        k_c = sub.stiffness_c_N_per_m if stiffness_c is None else np.asarray(stiffness_c,
                                                                             dtype=float)
        width = 2 * n + nu + 1 + len(pi)
        shifted = np.zeros((n, width))
        shifted[:, :n] = np.eye(n)
        if qi:
            # d_U = -M_UU (a_U + iota_U g) - C_U. v - K_U. x; x_U + K_UU^-1 d_U
            d_u = np.zeros((nu, width))
            d_u[:, :n] = -k_c[qi]
            d_u[:, n:2 * n] = -m.damping_N_s_per_m[qi]
            m_uu = m.mass_kg[np.ix_(qi, qi)]
            d_u[:, 2 * n:2 * n + nu] = -m_uu
            d_u[:, 2 * n + nu] = -m_uu @ m.influence[qi]
            shifted[qi] += np.linalg.solve(k_c[np.ix_(qi, qi)], d_u)
        residual = np.zeros((len(dofs), width))
        for row, i in enumerate(dofs):
            residual[row] = k_c[i] @ shifted
            residual[row, n:2 * n] += sub.damping_c_N_s_per_m[i]
            residual[row, 2 * n + nu + 1 + pi.index(i)] += 1.0
        out = np.vstack([shifted, residual])
        return _remember(self._prediction_maps, key, out)

    def _condensed_tangent(self, ops) -> np.ndarray:
        """The computational part's tangent stiffness condensed to the DOFs with mass, from
        the system Newton assembled last (``printA``: ``K_t + (2/h) C + (4/h^2) M`` and the
        penalties; less the Newmark part and the interfaces' moving constraint)."""
        a = np.asarray(ops.printA('-ret'), dtype=float)
        size = int(round(math.sqrt(a.size)))
        k = a.reshape(size, size) - self._newmark_mc
        keep, other, interface = self._equations_of()
        for eq in interface:
            k[eq, eq] -= self._penalty
        g = self._damping_gain
        if g:
            # Rayleigh damping on the current (beta_K) or committed (beta_K_comm) stiffness:
            # Newton's system holds (2/h) C_t, C_t = ... + beta_K K_t + beta_K_comm K_comm,
            # and the Newmark part above holds it at the initial stiffness; with K_comm
            # taken as K_t (exact on a step that kept its tangent, a weighted mean of the
            # two on one that changed it)
            k = (k + g * self._k0_full) / (1.0 + g)
        kk, ko, oo, ok = self._condensation_indices(keep, other)
        kr = k[kk]
        if other:
            kr = kr - k[ko] @ np.linalg.solve(self._floored(k[oo], oo), k[ok])
        return 0.5 * (kr + kr.T)

    def _floored(self, k_oo: np.ndarray, oo) -> np.ndarray:
        """The massless DOFs' tangent block `k_oo`, or ``k_oo + TANGENT_FLOOR * K_0,oo`` where
        it is below the floor (``seft_ros.core.reference_force.below_tangent_floor``, the
        prediction's): a massless node between two members that yield perfectly plastic has
        no stiffness, and its condensation no inverse."""
        k0_oo = self._k0_full[oo]
        return k_oo + TANGENT_FLOOR * k0_oo if below_tangent_floor(k_oo, k0_oo) else k_oo

    def _condensation_indices(self, keep, other) -> tuple:
        """``np.ix_`` of the kept and the other equations' four blocks (made once: each
        costs a few microseconds, and the tangent is read on most yielding steps)."""
        cached = getattr(self, '_cond_ix', None)
        if cached is None:
            cached = self._cond_ix = (np.ix_(keep, keep), np.ix_(keep, other),
                                      np.ix_(other, other), np.ix_(other, keep))
        return cached

    def _equations_of(self):
        """The equations of the DOFs with mass (seft's, in order), of the others that are
        not fixed, and of the interfaces, in the analysis' numbering."""
        cached = getattr(self, '_eq_split', None)
        if cached is None:
            eqs = self._equations
            keep = [eqs[nd] for nd in self._nodes]
            other = sorted(set(eqs.values()) - set(keep))
            cached = self._eq_split = (keep, other, [eqs[nd] for nd in self._interface])
        return cached

    def tangent(self) -> np.ndarray | None:
        """The computational part's tangent stiffness ``K_c,t`` at the latest sample [N/m]
        (n x n, condensed to seft's DOFs), or None while the model has not left its
        linearization (or with ``prediction: initial``)."""
        return self._k_t

    # -- the ComputationalPart protocol -----------------------------------------------------

    def observe(self, rig: int, measurement) -> None:
        """Hand in one rig's measurement (a repeat replaces it)."""
        self._meas[rig][measurement.step] = (measurement.displacement_m,
                                             measurement.velocity_m_s,
                                             measurement.acceleration_m_s2)

    def set_ground(self, step: int, acceleration_m_s2: float) -> None:
        """Hand in the ground acceleration of a sample [m/s^2]."""
        self.ground[step] = float(acceleration_m_s2)

    def _settle(self, until: int) -> None:
        meas = self._meas
        if self._settled < 0:
            if not all(0 in m for m in meas):
                return
            for r, p in enumerate(self._pi):
                x, v, a = meas[r][0]
                self._x[p], self._v[p], self._a[p] = x, v, a
            self._start()
            self._settled = 0
        while self._settled < until and all(self._settled + 1 in m for m in meas):
            j = self._settled
            self._opensees_step(j)
            self._settled = j + 1
            for m in meas:
                m.pop(j, None)
            self.ground.pop(j - 1, None)

    def _start(self) -> None:
        """The computational DOFs' accelerations at sample 0 consistent with the measured
        motion and the record (Eq. 3 of :mod:`seft_ros.core.substructure` with the
        linearization; Newmark's step needs them)."""
        qi = self._qi
        self.prepare()
        if not qi:
            return
        ops = opensees()
        m = self.matrices
        x, v = np.asarray(self._x), np.asarray(self._v)
        rhs = -(m.stiffness_N_per_m[qi] @ x + m.damping_N_s_per_m[qi] @ v)
        acc = np.linalg.solve(m.mass_kg[np.ix_(qi, qi)], rhs) - m.influence[qi] * self.ground.get(
            0, 0.0)
        for i, a in zip(qi, acc):
            node, dof = self._nodes[i]
            ops.setNodeAccel(node, dof, float(a), '-commit')
            self._a[i] = float(a)

    def state_at(self, j: int) -> tuple[list, list, int]:
        """Every DOF's displacement and velocity at sample `j` (the model stepped to it; with
        ``step: deferred`` to ``j - 1`` and the part's linear step from there, module notes).

        Raises
        ------
        ParameterError
            A rig's measurement of `j` is not in: an OpenSees model is stepped only on
            measured motion (it does not predict a rig commanded elsewhere).
        """
        deferred = self._deferred and j > 0
        need = j - 1 if deferred else j
        self._settle(need)
        if self._settled < need or deferred and not all(j in m for m in self._meas):
            missing = [self.rig_names[r] or 'rig' for r, m in enumerate(self._meas)
                       if j not in m]
            raise ParameterError(f'OpenSees computational part: the measurement of sample {j} '
                                 f'of {", ".join(missing)} is not in; an OpenSees model is '
                                 "stepped on every rig's measured motion (one builder that "
                                 'hears every rig)')
        if not deferred:
            self._ahead = None
            return list(self._x), list(self._v), 0
        if self._ahead is None or self._ahead[0] != j:
            self._ahead = (j,) + self._step_ahead(j)
        return list(self._ahead[1]), list(self._ahead[2]), 0

    def advance(self) -> None:
        """``step: deferred``: step OpenSees to the sample the latest :meth:`state_at` gave
        (a real-time builder calls it once its command is out; otherwise the next
        :meth:`state_at` does: the same steps either way)."""
        if self._ahead is not None:
            self._settle(self._ahead[0])

    def interface_forces(self, x, v, dofs) -> tuple:
        """The model's interface force [N] at each of `dofs` (physical DOFs) at the sample of
        the latest :meth:`state_at` (`x`, `v` are that state; the model has its own)."""
        forces = self._forces if self._ahead is None else self._ahead[4]
        return tuple(forces[self._pi.index(i)] for i in dofs)

    def prediction_state(self, x, v, dofs, stiffness_c_N_per_m=None) -> tuple[list, tuple]:
        """The state the compensators' linear prediction starts from, and what to add to
        its interface forces at `dofs` (module notes: the linearization, or the tangent
        `stiffness_c_N_per_m`, with the model's nonlinear restoring forces held over the
        prediction).

        The model's restoring forces at the computational DOFs ``U`` differ from the linear
        model's by ``d_U = -M_UU (a_U + iota_U g) - C_U. v - K_U. x`` (the model's own
        accelerations at the sample; ``K`` the linearization's or the tangent); held
        constant, they are the linear model's with ``x_U`` shifted by ``K_UU^-1 d_U``. At an
        interface DOF ``p`` the rest, ``r_p = I_p + C_c[p] v + K_c[p] x_s`` (``x_s`` the
        shifted state, ``I_p`` the model's interface force), is added to the prediction.
        For a linear model both are zero up to the integrators' difference.

        Returns
        -------
        shifted : list of float, length n
            Every DOF's displacement with ``x_U`` shifted [m].
        residual : tuple of float
            ``r_p`` per DOF of `dofs` [N].
        """
        n = len(self._x)
        ahead = self._ahead
        z = (self._inputs(self.ground.get(self._settled, 0.0)) if ahead is None
             else self._inputs(self.ground.get(ahead[0], 0.0), ahead[1:]))
        z[:n], z[n:2 * n] = x, v
        out = (self._prediction_map(stiffness_c_N_per_m, dofs) @ np.array(z)).tolist()
        return out[:n], tuple(out[n:])

    def deficit_forces(self, x, v) -> np.ndarray:
        """The computational part's restoring force short of its linearization's at the
        sample of the latest :meth:`state_at`, at every DOF [N] (n,): ``K_c,0 x - R(x)``.

        ``R`` is the model's restoring force less its damping: at a computational DOF
        ``-M_UU (a_U + iota_U g) - C_U. v`` (its equation of motion), at an interface DOF
        ``-I_p - C_c[p] v`` (``I_p`` the interface force). Zero while the model is linear
        (to its integrator's difference); along a yielding mechanism it grows by the
        mechanism's deficit stiffness times its travel beyond the onset
        (:class:`~seft_ros.core.tangent.YieldMechanisms` places the onset with it).

        Parameters
        ----------
        x, v : sequence of float (n,)
            Every DOF's displacement [m] and velocity [m/s] at that sample (``state_at``).
        """
        n = len(self._x)
        ahead = self._ahead
        z = (self._inputs(self.ground.get(self._settled, 0.0)) if ahead is None
             else self._inputs(self.ground.get(ahead[0], 0.0), ahead[1:]))
        z[:n], z[n:2 * n] = x, v
        return self._deficit_map() @ np.array(z)

    def _deficit_map(self) -> np.ndarray:
        """The matrix on ``z`` (:meth:`_inputs`) of :meth:`deficit_forces` (made once)."""
        if self._deficit is not None:
            return self._deficit
        sub, m = self.sub, self.matrices
        n, qi, pi = len(self._x), self._qi, self._pi
        nu = len(qi)
        out = np.zeros((n, 2 * n + nu + 1 + len(pi)))
        out[:, :n] = sub.stiffness_c_N_per_m
        for i in qi:
            out[i, n:2 * n] = m.damping_N_s_per_m[i]
        if qi:
            m_uu = m.mass_kg[np.ix_(qi, qi)]
            out[np.ix_(qi, range(2 * n, 2 * n + nu))] = m_uu
            out[qi, 2 * n + nu] = m_uu @ m.influence[qi]
        for p in pi:
            out[p, n:2 * n] = sub.damping_c_N_s_per_m[p]
            out[p, 2 * n + nu + 1 + pi.index(p)] = 1.0
        self._deficit = out
        return out

    def recorded_state(self, x, v, j: int) -> tuple:
        """The computational DOFs' ``x, v, a`` at sample ``j - recorded_lag_steps`` as
        OpenSees stepped them, the step's OpenSees time and the recorded elements' values
        (``state_names``; with ``step: deferred`` the sample before `j`: OpenSees steps to
        `j` after the command built from it)."""
        qi = self._qi
        step = self.step_times_s[-1] if self.step_times_s else math.nan
        return (tuple(self._x[i] for i in qi) + tuple(self._v[i] for i in qi)
                + tuple(self._a[i] for i in qi) + (step,) + tuple(self._element_values))

    def set_matrices(self, matrices) -> None:
        """Kept for the protocol: the model itself moves the DOFs; `matrices` only replace
        the linearization the compensators see."""
        self.matrices = matrices


def _assembled(ops, factors) -> np.ndarray:
    """The system ``f_m M + f_c C + f_k K`` of the model in OpenSees at its state, in the
    current analysis' numbering and constraints (``GimmeMCK``, ``printA``; a full system)."""
    ops.integrator('GimmeMCK', *factors)
    ops.analysis('Transient')
    ops.analyze(1, 0.0)
    a = np.asarray(ops.printA('-ret'), dtype=float)
    size = int(round(math.sqrt(a.size)))
    return a.reshape(size, size)


def _stiffness_damping(ops, k0: np.ndarray, where: str) -> tuple[float, float]:
    """``(beta_K, beta_K_comm)``: the model's Rayleigh damping on its current and committed
    stiffness (OpenSees' ``rayleigh(alpha_M, beta_K, beta_K_init, beta_K_comm)``), which
    Newton's system holds beside the tangent; ``(0, 0)`` when there is none or no element
    takes it (a ``zeroLength`` without ``-doRayleigh 1``).

    Read from the model's ``rayleigh`` commands (:func:`~seft_ros.opensees.loader.
    rayleigh_calls`); which elements take it is measured at rest: the damping assembled
    with those two factors doubled, less the model's own, is ``(beta_K + beta_K_comm)
    K_0,R`` with ``K_0,R`` the initial stiffness of the elements that take it (the factors
    are then set back, and the damping checked to be the model's again).

    Raises
    ------
    ModelError
        Damping on the current or committed stiffness that only some elements take, or set
        per region or per element: the tangent cannot be told from Newton's system.
    """
    calls = rayleigh_calls()
    moving = [(kind, f) for kind, f in calls if f[1] or f[3]]
    if not moving:
        return (0.0, 0.0)
    fix = 'put it on the initial stiffness (beta_K_init), or set prediction: initial'
    if any(kind != 'rayleigh' for kind, _ in moving) or any(
            not math.isfinite(v) for _, f in moving for v in f):
        raise ModelError(f'{where}.model: Rayleigh damping on the current or committed '
                         'stiffness set per region or per element: seft reads the tangent '
                         f'only with the global ops.rayleigh; {fix}')
    factors = [f for kind, f in calls if kind == 'rayleigh'][-1]
    alpha_m, beta_k, beta_k_init, beta_k_comm = factors
    damping = _assembled(ops, (0.0, 1.0, 0.0))
    ops.rayleigh(alpha_m, 2.0 * beta_k, beta_k_init, 2.0 * beta_k_comm)
    doubled = _assembled(ops, (0.0, 1.0, 0.0))
    ops.rayleigh(*factors)
    if not np.array_equal(_assembled(ops, (0.0, 1.0, 0.0)), damping):
        raise ModelError(f'{where}.model: Rayleigh damping on the current or committed '
                         'stiffness that not every element got from the last ops.rayleigh '
                         f'(elements made after it, or other factors per element); {fix}')
    keep = sorted(set(_equations(ops).values()))
    k0_r = ((doubled - damping) / (beta_k + beta_k_comm))[np.ix_(keep, keep)]
    k = k0[np.ix_(keep, keep)]
    tol = 1e-9 * float(np.max(np.abs(k)))
    if float(np.max(np.abs(k0_r))) <= tol:
        return (0.0, 0.0)                     # no element takes the damping
    if float(np.max(np.abs(k0_r - k))) <= tol:
        return (beta_k, beta_k_comm)
    raise ModelError(f'{where}.model: Rayleigh damping on the current or committed stiffness '
                     f'(ops.rayleigh({alpha_m:g}, {beta_k:g}, {beta_k_init:g}, '
                     f'{beta_k_comm:g})) that some elements take and others not (a zeroLength '
                     "takes it with '-doRayleigh', 1): seft cannot tell the tangent from it; "
                     f'give it to every element, {fix}')


def _equations(ops) -> dict:
    """``(node, dof) -> equation`` of the model's DOFs that are not fixed, in the current
    analysis' numbering."""
    fixed = {(int(node), int(dof)) for node in ops.getFixedNodes()
             for dof in ops.getFixedDOFs(node)}
    out = {}
    for node in ops.getNodeTags():
        for dof, eq in enumerate(ops.nodeDOFs(node), start=1):
            if eq >= 0 and (int(node), dof) not in fixed:
                out[(int(node), dof)] = int(eq)
    return out


def element_names(tag: int) -> tuple[str, str]:
    """The recorded states of element `tag`: its force (a 2-D beam-column's end moment at
    its first node [N m]; a link's basic force [N]) and its deformation (a beam-column's
    basic rotation at that end [rad]; a link's basic deformation [m])."""
    return f'opensees/ele{tag}/force', f'opensees/ele{tag}/deformation'


def element_response(ops, tag: int, ndf: dict | None = None) -> tuple[float, float]:
    """The values of :func:`element_names` of element `tag` in the model now (`ndf`: the
    elements' DOFs per node found so far, by tag; filled in)."""
    force = ops.eleForce(tag)
    per_node = None if ndf is None else ndf.get(tag)
    if per_node is None:
        per_node = len(force) // max(len(ops.eleNodes(tag)), 1)
        if ndf is not None:
            ndf[tag] = per_node
    basic = ops.eleResponse(tag, 'basicDeformation')
    if len(basic) >= 3:                 # a beam-column: its end moment, its rotation at i
        return float(force[per_node - 1]), float(basic[1])
    # a link (zeroLength, a truss): its basic force along its deformation (its first node's
    # last DOF was the vertical force of a story's zeroLength, 0: a flat hysteresis plot; a
    # new user's and the shipped shear frame's, session 38)
    link = ops.eleResponse(tag, 'basicForce') if basic else []
    if link:
        return float(link[0]), float(basic[0])
    return float(force[per_node - 1]), float(basic[0]) if basic else math.nan


#: Matrices kept per stiffness (the few a run predicts with; the oldest dropped first).
_KEPT_MATRICES = 64


def _remember(cache: dict, key, value):
    """Keep `value` under `key` in `cache` (at most :data:`_KEPT_MATRICES`, the oldest
    dropped first) and return it."""
    if len(cache) >= _KEPT_MATRICES:
        cache.pop(next(iter(cache)))
    cache[key] = value
    return value


def _hermite(m0, m1, dt: float, t: float) -> tuple[float, float, float]:
    """The cubic Hermite interpolant of ``(x0, v0)``, ``(x1, v1)`` over ``[0, dt]`` at `t`:
    displacement, velocity, acceleration (the coefficients of
    :func:`~seft_ros.core.substructure.hermite_step`)."""
    x0, v0 = m0[0], m0[1]
    x1, v1 = m1[0], m1[1]
    a2 = (3.0 * (x1 - x0) / dt - 2.0 * v0 - v1) / dt
    a3 = (2.0 * (x0 - x1) / dt + v0 + v1) / dt ** 2
    return (x0 + t * (v0 + t * (a2 + t * a3)), v0 + t * (2.0 * a2 + 3.0 * a3 * t),
            2.0 * a2 + 6.0 * a3 * t)


class DryRun:
    """A timed dry run of a model (:func:`dry_run`).

    Attributes
    ----------
    step_times_s : ndarray (n,)
        Each step's wall time [s].
    p50_s, p99_s, max_s : float
        Its percentiles [s].
    """

    def __init__(self, times: Sequence[float]):
        self.step_times_s = np.asarray(times, dtype=float)
        self.p50_s, self.p99_s = (float(np.percentile(self.step_times_s, q)) for q in (50, 99))
        self.max_s = float(np.max(self.step_times_s))


def dry_run(sub: Substructures, dt: float, *, steps: int = 500, amplitude_m: float = 1e-3,
            frequency_hz: float = 2.0) -> DryRun:
    """Step the computational model `steps` times with its interfaces moving as a sine and
    no ground motion, timed per step (the model is left as built: call before a run).

    Parameters
    ----------
    sub : Substructures
    dt : float > 0
        Control period [s].
    steps : int > 0
    amplitude_m : float
        The interfaces' displacement amplitude [m] (small: an elastic model stays elastic).
    frequency_hz : float > 0

    Returns
    -------
    DryRun
    """
    from seft_msgs_py.interface import Measurement
    part = OpenSeesPart(sub, dt, pushover=False)
    w = 2.0 * math.pi * frequency_hz
    for k in range(steps + 1):
        t = k * dt
        for r in range(len(part.rig_names)):
            part.observe(r, Measurement(step=k, time_s=t, force_N=0.0,
                                        displacement_m=amplitude_m * math.sin(w * t),
                                        velocity_m_s=amplitude_m * w * math.cos(w * t),
                                        acceleration_m_s2=-amplitude_m * w * w
                                        * math.sin(w * t)))
        part.set_ground(k, 0.0)
        part.state_at(k)
    return DryRun(part.step_times_s)
