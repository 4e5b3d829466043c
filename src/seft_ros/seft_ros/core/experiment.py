"""A substructure EFT test in one process, from the same classes the nodes use.

This is ``seft simulate`` and the independent check of the node graph: the lockstep graph and
:func:`simulate` execute the same calls in the same order, so they give the same samples.
Every test is a structure (:mod:`seft_ros.core.structure`); the reference study's test is its
one-rig case.

One step k (the node that does it in the graph in brackets), each rig in the structure's
order of its physical DOFs::

    for each rig r:
      [rig]                     stop if rig.limit_violation(); m_r = rig.measure()
      [force_servo_controller]  u_r = C_e(f_r[k] - f_m,r[k]) + g_v (v + T_v a) (m_r's
                                velocity and acceleration; g_v = 0 for loop shaping; the
                                tangent design schedules C_e on m_r), or u_r = e[k] in an
                                open-loop identification run; stop if the interlock trips
      [rig]                     rig.apply(u_r)            (delay rig: rig.apply(f_r[k]))
    [reference_force_builder]   stop if a rig's instability monitor trips on m_r (k+1 < N);
                                builder.observe(r, m_r) for every rig r (every builder);
                                f[k+1] = builder.step(xg''[k+1 .. k+1+L]) (each builder: its
                                rigs' forces; the study: -(1+alpha) m g[k+1] - alpha m a_hat)

``f[0]`` is built from ``xg''[0..]`` with the structure at rest.
"""

import time
from typing import Callable, Collection, Mapping

import numpy as np

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.graph import Graph, qualified
from seft_msgs_py.interface import COMMAND_VALVE
from seft_msgs_py.sampling import single_blas_thread
from seft_plant_sim.realtime import ReplayRig
from seft_plant_sim.rigs import make_rig
from seft_ros.analysis.rundata import RigData, RunData
from seft_ros.core.controller import (
    ReferencePlayout,
    SaturationInterlock,
    prediction_window_steps,
)
from seft_ros.core.excitation import make_valve_controller
from seft_ros.core.ground_motion import GroundMotion, prepared_record
from seft_ros.core.monitor import (
    SPECIMEN_UNJUDGED,
    DivergenceGuard,
    InstabilityMonitor,
    SpecimenCheck,
)
from seft_ros.core.reference_force import ReferenceForceBuilder

__all__ = ['simulate']


def simulate(params, *, progress: Callable[[int, int], None] | None = None,
             record: GroundMotion | None = None,
             stale_steps: Mapping[str, Collection[int]] | Collection[int] | None = None,
             command_latency_s: Mapping[str, Mapping[int, float]] | None = None
             ) -> RunData:
    """Run one test without ROS and return its signals.

    Parameters
    ----------
    params : mapping
        Parameter values (validated against ``seft_msgs_py.parameters``), with a
        ``structure`` or the study's ``alpha``.
    progress : callable(step, n_steps), optional
        Called about every 0.5 s of wall time.
    record : GroundMotion, optional
        Already prepared ground motion (default:
        :func:`~seft_ros.core.ground_motion.prepared_record`).
    stale_steps : mapping of str to collection of int, or collection of int, optional
        Rig name -> the steps at which its force servo controller acts before the reference
        force of the step has arrived (a real-time run's stale steps, from its bag's timing
        records, replayed in process); a plain collection for a test of one rig. At those
        steps the controller acts as in real time
        (:class:`~seft_ros.core.controller.ReferencePlayout` with the rig's
        ``reference_extrapolation_steps``) and the force arrives just after; a mapping of
        step -> ``d`` (int >= 1) in place of a collection: the controller held the forces
        up to step ``k - d`` (the builder ``d`` steps behind;
        :meth:`~seft_ros.core.controller.ReferencePlayout.replay`).
        Servohydraulic rigs only (ignored on the delay rig, which has no controller);
        default none (lockstep).
    command_latency_s : mapping of str to (mapping of int to float), optional
        Rig name (``''``: the study's) -> step -> the loop latency of its command [s] (a
        real-time run's, its rig's timing records): that rig is the real-time rig, each
        command arriving at its recorded time (:class:`~seft_plant_sim.realtime.ReplayRig`;
        a real-time run of a simulated rig replayed, with `stale_steps`). Default: the
        lockstep rig.

    Returns
    -------
    RunData
        n samples of every rig and of the computational DOFs (fewer than the record if the
        run was aborted).

    Raises
    ------
    InputError, ParameterError
        Bad record, parameter or structure; `stale_steps` of a rig the test has not.

    Notes
    -----
    The whole run keeps numpy's and scipy's BLAS at one thread
    (:func:`~seft_msgs_py.sampling.single_blas_thread`), as a real-time node does: an
    ``adaptive`` compensator refits its model and loop inverse during the run (small
    matrix exponentials), and a pool of two BLAS threads made each refit about 100 times
    slower on a loaded 2-core host (24 ms against 0.2 ms per ``expm``).
    """
    with single_blas_thread():
        return _simulate(params, progress=progress, record=record, stale_steps=stale_steps,
                         command_latency_s=command_latency_s)


def _steps_behind(steps) -> dict[int, int]:
    """Stale steps as step -> how many steps behind the controller's newest force was (a
    mapping as given; a collection: 1 each)."""
    if isinstance(steps, Mapping):
        return {int(k): max(1, int(d)) for k, d in steps.items()}
    return dict.fromkeys((int(k) for k in steps), 1)


def _simulate(params, *, progress, record, stale_steps, command_latency_s) -> RunData:
    """:func:`simulate`'s run, BLAS at one thread."""
    params = parameters.resolve(params)
    gm = record if record is not None else prepared_record(params)
    ag = gm.acceleration_m_s2
    n_total = ag.shape[0]
    # one builder for every rig, or (structure_builders per_rig) one per rig, as the graph
    graph = Graph.from_parameters(params)
    local_sets = [[r] for r in graph.rigs] if graph.per_rig_builders else [None]
    builders = [ReferenceForceBuilder.from_parameters(params, local=lr)
                for lr in local_sets]
    builder = builders[0]           # its computational state is the one recorded
    names = builder.rig_names
    rig_params = builder.setup.rig_params
    latencies = command_latency_s or {}
    unknown = sorted(set(latencies) - set(names))
    if unknown:
        raise ParameterError(f'command latencies of rig(s) {", ".join(unknown)}: the test '
                             f'has the rigs {", ".join(names)}')
    rigs = [ReplayRig(rig_params[r], latencies[r]) if r in latencies else make_rig(rig_params[r])
            for r in names]
    valve = [rig.command_kind == COMMAND_VALVE for rig in rigs]
    # the force controller, or the excitation itself in an open-loop identification run
    ctrls = [make_valve_controller(rig_params[r]) if v else None
             for r, v in zip(names, valve)]
    locks = [SaturationInterlock.from_parameters(rig_params[r]) if v else None
             for r, v in zip(names, valve)]
    monitors = [InstabilityMonitor.from_parameters(rig_params[r]) for r in names]
    # each rig's measured displacement and force against the pre-run prediction of their
    # peaks (divergence_factor); the range check's reference analysis of the record as run
    predicted = None
    if float(params.get('divergence_factor', 0.0) or 0.0) > 0:
        from seft_ros.analysis.range_check import range_check  # analysis imports the core
        predicted = range_check(params, ag, valve=False, program_reference=False)
    guards = [DivergenceGuard.from_parameters(rig_params[r], predicted, rig=r) for r in names]
    # each rig's specimen against its compensator's model (specimen_check)
    local_params = {r: p for b in builders for r, p in zip(b.local_rigs, b.rig_params)}
    checks = [SpecimenCheck.from_parameters(local_params[r], rig=r) for r in names]
    check_abort = [local_params[r].get('specimen_check', 'warn') == 'abort'
                   for r in names]
    if stale_steps is not None and not isinstance(stale_steps, Mapping):
        if len(names) != 1:
            raise ParameterError(f'stale steps of a test of {len(names)} rigs: expected '
                                 'them per rig (a mapping of rig names to steps)')
        stale_steps = {names[0]: stale_steps}
    stale = stale_steps or {}
    unknown = sorted(set(stale) - set(names))
    if unknown:
        raise ParameterError(f'stale steps of rig(s) {", ".join(unknown)}: the test '
                             f'has the rigs {", ".join(names)}')
    playouts = [ReferencePlayout(0, int(rig_params[r]['reference_extrapolation_steps']),
                                 prediction_window_steps(rig_params[r]))
                if v and r in stale else None for r, v in zip(names, valve)]
    stale = [_steps_behind(stale.get(r, ())) for r in names]
    look = max(b.lookahead_steps for b in builders)
    # the ground window xg''[j..j+L] of every step as a slice (the numbers of
    # reference_force.ground_window: the record as Python floats, then the samples that
    # follow a record cut short, zeros after its end)
    padded = ag.tolist() + list(gm.following_m_s2) + [0.0] * (look + 1)
    # the compensators' online estimates (if they have any), in effect for each f_r[k]
    estimators = [getattr(law.predictor, 'estimates', None) for b in builders for law in b.laws]
    estimated = [r for r, fn in enumerate(estimators) if fn is not None]

    # the builders act as one: each rig's command in rig order (per_rig: one builder a rig)
    builder_set = builder if len(builders) == 1 else _Builders(builders)
    width = 1 + builder_set.lookahead_steps
    build = builder_set.step

    def estimates():
        return [None if fn is None else fn() for fn in estimators]

    n_r = len(rigs)
    # per-step signals as Python lists (a list store is a few times cheaper than an array's):
    # each rig's samples as one row (f_r, f_m, u, x, v, a) a step, its estimates apart
    rows = [[] for _ in names]
    est_rows = [[] for _ in names]
    # each rig's calls of a step, looked up once (a step costs what the test uses: a rig
    # without controller, playout or estimates skips them)
    lanes = [(r, rig.limit_violation, rig.measure, rig.apply,
              ctrls[r].step if valve[r] else None, locks[r].update if valve[r] else None,
              ctrls[r], playouts[r], stale[r], rows[r].append)
             for r, rig in enumerate(rigs)]
    # each rig's watches in the builder: its instability monitor, its specimen check (None:
    # none; its finding a warning, or with specimen_check: abort a reason to stop; its note
    # that it cannot judge, SPECIMEN_UNJUDGED, a warning) and its
    # divergence guard (None: none)
    watches = [(r, monitors[r].update, None if checks[r] is None else checks[r].update,
                check_abort[r], names[r], None if guards[r] is None else guards[r].update)
               for r in range(n_r)]
    # each builder's rig observations, and its rigs' range guards (a warning to say)
    observations = [(b.observe, r) for b in builders for r in range(n_r)]
    guarded = [(b, g) for b in builders for g in b.range_guards if g is not None]
    # the computational state of each sample a force was built from (a structure's)
    state_rec = []
    record_state = bool(builder.state_names)
    state_lag = builder.state_lag_steps     # the state of sample k - lag (an OpenSees part
                                            # that steps after the command)
    warnings = []
    commands = build(padded[0:width])
    est = estimates() if estimated else None
    t_start = time.monotonic()
    if n_r == 1 and len(builders) == 1:
        # the study's test and every test of one rig: the same step with the loops over
        # rigs and builders taken apart
        reason, abort_node, n_done, meas = _one_rig_steps(
            n_total, commands[0], est, lanes[0], watches[0], builder, estimates, padded,
            width, warnings, state_rec, record_state, state_lag, est_rows[0], progress)
    else:
        reason, abort_node, n_done, meas = _rig_steps(
            n_total, commands, est, lanes, watches, builder_set, estimates, padded, width,
            warnings, state_rec, record_state, state_lag, est_rows, progress, names,
            observations, guarded, builder, estimated)
    # the samples of the last step that no force was built from (the record's end, or an
    # abort there): the graph's builder node received them, and counts those at a sensor's
    # range; so does this
    built = builders[0].next_step - 1       # the samples a force was built from
    if n_total and (reason is not None or n_done == n_total):
        for b in builders:
            for r in range(n_r):
                if meas[r] is not None and meas[r].step >= built:
                    b.count_at_range(r, meas[r])
            warnings.extend(b.range_warnings())
    wall_s = time.monotonic() - t_start
    n = n_done
    dt = float(params['dt'])
    t = np.arange(n) * dt

    rig_data = {}
    for r, name in enumerate(names):
        # the rig's samples (n, 6) as six contiguous signals
        fr, fm, u, x, v, a = (np.ascontiguousarray(column) for column in
                              np.array(rows[r][:n], dtype=float).reshape(-1, 6).T)
        estimate_signals = None
        if est_rows[r]:
            estimate_signals = {key: np.array([e[key] for e in est_rows[r][:n]], dtype=float)
                                for key in est_rows[r][0]}
        p = rig_params[name]
        if not builder.setup.is_study:
            p = dict(p, alpha=float(builder.setup.substructures.alpha[r]))
        rig_data[name] = RigData(
            params=dict(p), reference_force_N=fr, measured_force_N=fm, displacement_m=x,
            velocity_m_s=v, acceleration_m_s2=a, valve_command_V=u if valve[r] else None,
            estimates=estimate_signals)
    # the computational state of sample k is recorded by the step of k+1 (k+2: a state lag):
    # the last sample's is not (the run ends there); it is NaN
    computational = {}
    if builder.state_names:
        states = np.array(state_rec[:n], dtype=float).reshape(len(state_rec[:n]),
                                                              len(builder.state_names))
        for i, name in enumerate(builder.state_names):
            column = np.full(n, np.nan)
            column[:states.shape[0]] = states[:n, i]
            computational[name] = column
    return RunData(
        params=dict(params), time_s=t, ground_acceleration_m_s2=np.array(ag[:n]),
        rigs=rig_data, computational=computational, stable=reason is None,
        unstable_at_s=None if reason is None else n * dt, abort_reason=reason,
        record_name=gm.name, source='simulate',
        extra={'wall_s': wall_s, 'abort_node': abort_node, 'warnings': warnings,
               'specimen_ratios': {r: c.stiffness_ratio for r, c in zip(names, checks)
                                   if c is not None},
               'sensor_range': {r: v for b in builders for r, v in b.range_counts().items()},
               'part_findings': builder.part_findings()})


def _rig_steps(n_total, commands, est, lanes, watches, builder_set, estimates, padded, width,
               warnings, state_rec, record_state, state_lag, est_rows, progress, names,
               observations, guarded, builder, estimated):
    """:func:`simulate`'s steps of a test of any rigs and builders; returns ``(reason,
    abort_node, n_done, meas)``: the reason the run stopped (None: completed), the node
    that stopped it, the samples done and each rig's last measurement (None: not taken)."""
    n_r = len(lanes)
    reason = abort_node = None
    n_done = n_total
    meas = [None] * n_r
    build = builder_set.step
    t_last = time.monotonic()
    for k in range(n_total):
        meas = [None] * n_r
        for (r, limit_violation, measure, apply, control, lock, ctrl, playout, stale_r,
             store) in lanes:
            reason = limit_violation()
            if reason:
                abort_node = qualified('rig', names[r])
                break
            m = measure()
            meas[r] = m
            fr = commands[r]
            if control is not None:
                reference = fr if playout is None else playout.replay(k, fr, stale_r.get(k, 0))
                u = control(reference, m.force_N, m.velocity_m_s, m.acceleration_m_s2,
                            m.displacement_m)
                reason = lock(ctrl.saturated, m.time_s)
                if reason:
                    abort_node = qualified('force_servo_controller', names[r])
                    break
            else:
                u = fr
            store((fr, m.force_N, u, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
            if est is not None and est[r] is not None:
                est_rows[r].append(est[r])
            apply(u)
        if reason:
            n_done = k
            break
        if k + 1 < n_total:
            scale = builder_set.last_ground_forces_N
            for r, watch, check, abort, name, diverging in watches:
                m = meas[r]
                reason = watch(m.force_N, scale[r], m.time_s)
                if not reason and diverging is not None:
                    reason = diverging(m)
                if not reason and check is not None:
                    reason = check(m)
                    if reason and (not abort or reason.startswith(SPECIMEN_UNJUDGED)):
                        warnings.append(reason)
                        reason = None
                if reason:
                    reason = f'{name}: {reason}' if name else reason
                    abort_node = 'reference_force_builder'
                    break
            if reason:
                n_done = k + 1
                break
            for observe, r in observations:
                observe(r, meas[r])
            for b, g in guarded:
                if g.news:                  # (b says every guard's news, and empties them)
                    warnings.extend(b.range_warnings())
            commands = build(padded[k + 1:k + 1 + width])
            if estimated:
                est = estimates()
            if record_state and k >= state_lag:
                state_rec.append(builder.computational_state)
        if progress is not None and not k & 255 and time.monotonic() - t_last > 0.5:
            t_last = time.monotonic()
            progress(k + 1, n_total)
    return reason, abort_node, n_done, meas


def _one_rig_steps(n_total, fr, est, lane, watch_of, builder, estimates, padded, width,
                   warnings, state_rec, record_state, state_lag, est_row, progress):
    """:func:`_rig_steps` for a test of one rig and one builder (the study's test), the
    same operations in the same order with the lists of one element taken apart."""
    (_, limit_violation, measure, apply, control, lock, ctrl, playout, stale_r,
     store) = lane
    _, watch, check, abort, name, diverging = watch_of
    step_after = builder.observe_and_step   # (observe, then step; no warning in between)
    scale = builder.last_ground_forces_N            # (updated in place by every step)
    guards = [g for g in builder.range_guards if g is not None]
    estimated = est is not None
    reason = abort_node = m = None
    n_done = n_total
    t_last = time.monotonic()
    for k in range(n_total):
        m = None
        reason = limit_violation()
        if reason:
            abort_node = qualified('rig', name)
            n_done = k
            break
        m = measure()
        if control is not None:
            reference = fr if playout is None else playout.replay(k, fr, stale_r.get(k, 0))
            u = control(reference, m.force_N, m.velocity_m_s, m.acceleration_m_s2,
                        m.displacement_m)
            reason = lock(ctrl.saturated, m.time_s)
            if reason:
                abort_node = qualified('force_servo_controller', name)
                n_done = k
                break
        else:
            u = fr
        store((fr, m.force_N, u, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
        if estimated and est[0] is not None:
            est_row.append(est[0])
        apply(u)
        if k + 1 < n_total:
            reason = watch(m.force_N, scale[0], m.time_s)
            if not reason and diverging is not None:
                reason = diverging(m)
            if not reason and check is not None:
                reason = check(m)
                if reason and (not abort or reason.startswith(SPECIMEN_UNJUDGED)):
                    warnings.append(reason)
                    reason = None
            if reason:
                reason = f'{name}: {reason}' if name else reason
                abort_node = 'reference_force_builder'
                n_done = k + 1
                break
            fr = step_after(m, padded[k + 1:k + 1 + width])
            for g in guards:
                if g.news:
                    warnings.extend(builder.range_warnings())
            if estimated:
                est = estimates()
            if record_state and k >= state_lag:
                state_rec.append(builder.computational_state)
        if progress is not None and not k & 255 and time.monotonic() - t_last > 0.5:
            t_last = time.monotonic()
            progress(k + 1, n_total)
    return reason, abort_node, n_done, [m]


class _Builders:
    """The reference-force builders of one test (``structure_builders: per_rig``, one a rig)
    stepped as one :class:`~seft_ros.core.reference_force.ReferenceForceBuilder`: each
    builder's commands in rig order, and the specimen models they send exchanged as the
    graph's builders exchange them.

    Parameters
    ----------
    builders : list of ReferenceForceBuilder
        In rig order (each commands its own rigs).
    """

    def __init__(self, builders):
        self.builders = builders
        self.lookahead_steps = max(b.lookahead_steps for b in builders)

    @property
    def last_ground_forces_N(self) -> list:
        """Each rig's effective force of its latest command [N], in rig order."""
        return [g for b in self.builders for g in b.last_ground_forces_N]

    def step(self, window) -> list:
        """The commands of step j of every rig [N], in rig order, from ``window =
        xg''[j .. j + lookahead_steps]`` [m/s^2] (each builder reads its own part)."""
        builders = self.builders
        j = builders[0].next_step
        out = [c for b in builders for c in b.step(window[:1 + b.lookahead_steps])]
        for b in builders:
            if b.outbox is not None and b.outbox[0] == j:
                for other in builders:
                    if other is not b:
                        for rig, model in b.outbox[1].items():
                            other.receive_models(j, rig, model)
        return out
