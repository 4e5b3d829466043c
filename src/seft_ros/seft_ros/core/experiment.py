"""A substructure EFT experiment in one process, from the same classes the nodes use.

This is ``seft simulate`` and the independent check of the node graph: the lockstep graph and
:func:`simulate` execute the same calls in the same order, so they give the same samples.

One step k (the node that does it in the graph in brackets)::

    [rig]                     stop if rig.limit_violation(); m_k = rig.measure()
    [force_servo_controller]  u_k = C_e(f_r[k] - f_m[k]) + g_v (v_k + T_v a_k) (m_k's velocity
                              and acceleration; g_v = 0 for loop shaping; the tangent design
                              schedules C_e on m_k), or u_k = e[k] in an open-loop
                              identification run; stop if the interlock trips
    [rig]                     rig.apply(u_k)            (delay rig: rig.apply(f_r[k]))
    [reference_force_builder] stop if the instability monitor trips on m_k (k+1 < N);
                              f_r[k+1] = -(1+alpha) m g[k+1] - alpha m a_hat(m_k, ...)
                              from xg''[k+1 .. k+1+L] (the record is known ahead)

``f_r[0]`` is built from ``xg''[0]`` with the specimen at rest.
"""

import time
from typing import Callable, Collection

import numpy as np

from seft_msgs_py import parameters
from seft_msgs_py.interface import COMMAND_VALVE
from seft_msgs_py.sampling import single_blas_thread
from seft_plant_sim.rigs import make_rig
from seft_ros.analysis.rundata import RunData
from seft_ros.core.controller import ReferencePlayout, SaturationInterlock
from seft_ros.core.excitation import make_valve_controller
from seft_ros.core.ground_motion import GroundMotion, prepared_record
from seft_ros.core.monitor import InstabilityMonitor
from seft_ros.core.reference_force import ReferenceForceBuilder

__all__ = ['simulate']


def simulate(params, *, progress: Callable[[int, int], None] | None = None,
             record: GroundMotion | None = None,
             stale_steps: Collection[int] | None = None) -> RunData:
    """Run one experiment without ROS and return its signals.

    Parameters
    ----------
    params : mapping
        Parameter values (validated against ``seft_msgs_py.parameters``).
    progress : callable(step, n_steps), optional
        Called about every 0.5 s of wall time.
    record : GroundMotion, optional
        Already prepared ground motion (default:
        :func:`~seft_ros.core.ground_motion.prepared_record`).
    stale_steps : collection of int, optional
        The steps at which the force servo controller acts before the reference force of the
        step has arrived (a real-time run's stale steps, from its bag's timing records,
        replayed in process): it then acts as in real time
        (:class:`~seft_ros.core.controller.ReferencePlayout` with
        ``reference_extrapolation_steps``) and the force arrives just after. Servohydraulic
        rig only (ignored on the delay rig, which has no controller); default none
        (lockstep).

    Returns
    -------
    RunData
        n samples (fewer than the record if the run was aborted).

    Raises
    ------
    InputError, ParameterError
        Bad record or parameter.
    """
    params = parameters.resolve(params)
    gm = record if record is not None else prepared_record(params)
    ag = gm.acceleration_m_s2
    n_total = ag.shape[0]
    with single_blas_thread():                 # see there: faster set-up, no spinning threads
        rig = make_rig(params)
        builder = ReferenceForceBuilder.from_parameters(params)
        valve = rig.command_kind == COMMAND_VALVE
        # the force controller, or the excitation itself in an open-loop identification run
        ctrl = make_valve_controller(params) if valve else None
        interlock = SaturationInterlock.from_parameters(params) if valve else None
        monitor = InstabilityMonitor.from_parameters(params)
        reason = abort_node = None
        n_done = n_total
        look = builder.lookahead_steps
        # the ground window xg''[j..j+look] of every step as a slice (the numbers of
        # reference_force.ground_window: the record as Python floats, zeros after its end)
        padded = ag.tolist() + [0.0] * (look + 1)
        # per-step signals as Python lists (a list store is a few times cheaper than an array's)
        fr_rec, fm_rec, u_rec, x_rec, v_rec, a_rec = ([] for _ in range(6))
        # bound methods and attributes looked up once (the per-step calls are the nodes' calls)
        limit_violation, measure, apply = rig.limit_violation, rig.measure, rig.apply
        build = builder.step
        watch = monitor.update
        if valve:
            control, interlock_update = ctrl.step, interlock.update
        stale = frozenset(stale_steps or ())
        playout = (ReferencePlayout(0, int(params['reference_extrapolation_steps']))
                   if valve and stale_steps is not None else None)
        # the compensator's online estimates (if it has any), in effect for each f_r[k]
        estimates = getattr(builder.predictor, 'estimates', None)
        est_rec = []

        fr = build(padded[0:1 + look], None)
        est = estimates() if estimates is not None else None
        t_last = t_start = time.monotonic()
        for k in range(n_total):
            reason = limit_violation()
            if reason:
                n_done, abort_node = k, 'rig'
                break
            meas = measure()
            fm = meas.force_N
            if valve:
                acted = fr if playout is None else playout.replay(k, fr, k in stale)
                u = control(acted, fm, meas.velocity_m_s, meas.acceleration_m_s2,
                            meas.displacement_m)
                reason = interlock_update(ctrl.saturated, meas.time_s)
                if reason:
                    n_done, abort_node = k, 'force_servo_controller'
                    break
            else:
                u = fr
            fr_rec.append(fr)
            if estimates is not None:
                est_rec.append(est)
            fm_rec.append(fm)
            u_rec.append(u)
            x_rec.append(meas.displacement_m)
            v_rec.append(meas.velocity_m_s)
            a_rec.append(meas.acceleration_m_s2)
            apply(u)
            if k + 1 < n_total:
                reason = watch(fm, builder.last_ground_force_N, meas.time_s)
                if reason:
                    n_done, abort_node = k + 1, 'reference_force_builder'
                    break
                fr = build(padded[k + 1:k + 2 + look], meas)
                if estimates is not None:
                    est = estimates()
            if progress is not None and not k & 255 and time.monotonic() - t_last > 0.5:
                t_last = time.monotonic()
                progress(k + 1, n_total)
    wall_s = time.monotonic() - t_start
    n = n_done
    dt = float(params['dt'])

    def signal(values):
        return np.array(values[:n], dtype=float)

    estimate_signals = None
    if estimates is not None and est_rec:
        estimate_signals = {name: np.array([e[name] for e in est_rec[:n]], dtype=float)
                            for name in est_rec[0]}

    return RunData.one_rig(
        params=dict(params), time_s=np.arange(n) * dt,
        ground_acceleration_m_s2=np.array(ag[:n]), reference_force_N=signal(fr_rec),
        measured_force_N=signal(fm_rec), displacement_m=signal(x_rec),
        velocity_m_s=signal(v_rec), acceleration_m_s2=signal(a_rec),
        valve_command_V=signal(u_rec) if valve else None,
        stable=reason is None, unstable_at_s=None if reason is None else n * dt,
        abort_reason=reason, record_name=gm.name, source='simulate',
        extra={'wall_s': wall_s, 'abort_node': abort_node}, estimates=estimate_signals)
