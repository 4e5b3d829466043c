"""A substructure EFT experiment in one process, from the same classes the nodes use.

This is ``seft simulate`` and the independent check of the node graph: the lockstep graph and
:func:`simulate` execute the same calls in the same order, so they give the same samples.

One step k (the node that does it in the graph in brackets)::

    [rig]                     stop if rig.limit_violation(); m_k = rig.measure()
    [force_servo_controller]  u_k = C_f(f_r[k] - f_m[k]); stop if the interlock trips
    [rig]                     rig.apply(u_k)            (delay rig: rig.apply(f_r[k]))
    [reference_force_builder] stop if the instability monitor trips on m_k (k+1 < N);
                              f_r[k+1] = -(1+alpha) m g[k+1] - alpha m a_hat(m_k, ...)
                              from xg''[k+1 .. k+1+L] (the record is known ahead)

``f_r[0]`` is built from ``xg''[0]`` with the specimen at rest.
"""

from dataclasses import dataclass
import time
from typing import Callable

import numpy as np

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.interface import COMMAND_VALVE
from seft_plant_sim.rigs import make_rig
from seft_ros.analysis.rundata import RunData
from seft_ros.core.controller import ForceServoController, SaturationInterlock
from seft_ros.core.ground_motion import GroundMotion, load_record, prepare
from seft_ros.core.monitor import InstabilityMonitor
from seft_ros.core.reference_force import ReferenceForceBuilder, ground_window

__all__ = ['prepared_record', 'simulate', 'StepRecord']


def prepared_record(params) -> GroundMotion:
    """Load and prepare the run's ground motion (scaling, time scale, resampling, duration).

    Raises
    ------
    InputError, ParameterError
        Bad record file or parameter.
    """
    record = load_record(params['record'])
    gm = prepare(record, dt=float(params['dt']), mass_kg=float(params['mass_kg']),
                 amplitude_N=float(params['amplitude_N']),
                 scale_factor=float(params['scale_factor']),
                 time_scale=float(params['time_scale']),
                 duration_s=float(params['duration_s']))
    n = int(params.get('n_steps', 0) or 0)
    if n:
        if n > gm.acceleration_m_s2.shape[0]:
            raise ParameterError(
                f'parameter n_steps={n}: expected <= {gm.acceleration_m_s2.shape[0]} '
                '(the prepared record length)')
        gm = GroundMotion(gm.dt, gm.acceleration_m_s2[:n], gm.name, gm.source)
    return gm


@dataclass
class StepRecord:
    """Preallocated per-step arrays of a run, shape (N,)."""

    fr: np.ndarray
    fm: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u: np.ndarray


def simulate(params, *, progress: Callable[[int, int], None] | None = None,
             record: GroundMotion | None = None) -> RunData:
    """Run one experiment without ROS and return its signals.

    Parameters
    ----------
    params : mapping
        Parameter values (validated against ``seft_msgs_py.parameters``).
    progress : callable(step, n_steps), optional
        Called about every 0.5 s of wall time.
    record : GroundMotion, optional
        Already prepared ground motion (default: :func:`prepared_record`).

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
    rig = make_rig(params)
    builder = ReferenceForceBuilder.from_parameters(params)
    valve = rig.command_kind == COMMAND_VALVE
    ctrl = ForceServoController.from_parameters(params) if valve else None
    interlock = SaturationInterlock.from_parameters(params) if valve else None
    monitor = InstabilityMonitor.from_parameters(params)
    rec = StepRecord(*(np.full(n_total, np.nan) for _ in range(6)))
    reason = None
    n_done = n_total
    look = builder.lookahead_steps

    def ground(j):
        return ground_window(ag.__getitem__, j, look, n_total)

    fr = builder.step(ground(0), None)
    t_last = time.monotonic()
    for k in range(n_total):
        reason = rig.limit_violation()
        if reason:
            n_done = k
            break
        meas = rig.measure()
        if valve:
            u = ctrl.step(fr, meas.force_N)
            reason = interlock.update(ctrl.saturated, meas.time_s)
            if reason:
                n_done = k
                break
        else:
            u = fr
        rec.fr[k], rec.fm[k], rec.u[k] = fr, meas.force_N, u
        rec.x[k], rec.v[k], rec.a[k] = (meas.displacement_m, meas.velocity_m_s,
                                        meas.acceleration_m_s2)
        rig.apply(u)
        if k + 1 < n_total:
            reason = monitor.update(meas.force_N, builder.last_ground_force_N, meas.time_s)
            if reason:
                n_done = k + 1
                break
            fr = builder.step(ground(k + 1), meas)
        if progress is not None and time.monotonic() - t_last > 0.5:
            t_last = time.monotonic()
            progress(k + 1, n_total)
    n = n_done
    dt = float(params['dt'])
    return RunData(
        params=dict(params), time_s=np.arange(n) * dt,
        ground_acceleration_m_s2=np.array(ag[:n]), reference_force_N=rec.fr[:n],
        measured_force_N=rec.fm[:n], displacement_m=rec.x[:n], velocity_m_s=rec.v[:n],
        acceleration_m_s2=rec.a[:n], valve_command_V=rec.u[:n] if valve else None,
        stable=reason is None, unstable_at_s=None if reason is None else n * dt,
        abort_reason=reason, record_name=gm.name, source='simulate')
