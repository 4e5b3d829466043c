"""A real-time run replayed in one process: what its late steps cost it (``seft compare
--replay-timing``; ``seft run`` by itself where a rehearsal erred with late steps).

Each rig's commands arrive at their recorded loop latency
(:class:`~seft_plant_sim.realtime.ReplayRig`, the rig's timing records of
:mod:`seft_ros.analysis.timing`) and its controller's stale steps take the reference force
it then had; the same run with every step in time is the method's own error. The report's
line and flag are :func:`~seft_ros.analysis.findings.timing_replay_line` and
:func:`~seft_ros.analysis.findings.timing_cost_flag`.
"""

import dataclasses
import math

import numpy as np

from seft_ros.analysis.findings import REPLAY_SIGNALS
from seft_ros.analysis.timing import timing_until
from seft_ros.core.structure import is_study, structure_of, test_setup

__all__ = ['replay_timing', 'replay_due', 'steps_behind', 'worst_nrms', 'REPLAY_ABOVE_NRMS']

#: ``seft run`` replays a real-time run's timing (:func:`replay_due`) when its worst NRMS
#: of a signal passes this [-] and it had a late command or stale step.
REPLAY_ABOVE_NRMS = 0.01


def replay_timing(run, recorded: dict | None = None) -> dict | None:
    """What a real-time run's late steps cost it: the run replayed in one process on the
    real-time rig, as it ran and with every step in time.

    Each rig's commands arrive at their recorded loop latency
    (:class:`~seft_plant_sim.realtime.ReplayRig`) and its controller's stale steps take the
    reference force it then had (``stale_steps`` of :func:`~seft_ros.core.experiment.simulate`):
    the replay *as run* should match the recorded run (it checks the replay); *in time*,
    every command and reference force arrives in time. Their difference is the error the
    host's timing cost the run, not the method. A stale step is replayed as far behind its
    reference forces as the controller was (:func:`steps_behind`). Measured (2026-11-29):
    the yielding steel frame at 1 kHz, its builder up to 16 steps behind, replayed as run
    to the digit (8.36 / 34.92 / 29.98 % x / a / f; in time 1.49 / 8.63 / 5.79 %); a 32 Hz,
    0.5 % specimen at alpha 1 on a family plant, runs of 1.95-42.2 % x replayed as run to
    1.91-22.2 % (in time 1.32 %): the 42.2 % run had a 40 ms stall in which the rig's own
    tick was late, which the replay does not model.

    Parameters
    ----------
    run : RunData
        A real-time run read from its bag (``extra['timing_data']``) with seft's simulated
        rigs (``rig_interface: simulated``).
    recorded : dict, optional
        The run's own worst NRMS per signal (the summary's ``worst_nrms``, fractions), where
        the caller has it; else compared here.

    Returns
    -------
    dict or None
        None for a lockstep run or a rig that is not simulated (a lab's hardware cannot be
        replayed); else ``late_commands`` (arrived after their sample period),
        ``lost_commands`` (never arrived) and ``stale_steps`` (per rig, counts) and
        ``recorded``, ``as_run``, ``in_time``: the worst NRMS per signal
        (:data:`~seft_ros.analysis.findings.REPLAY_SIGNALS`, fractions; an unstable replay
        ``{'unstable_at_s': t}``); where a rig held its late commands
        (``realtime_late_command: hold``, the run's or its rig section's) and some came
        late, ``predicting``: the same as run with every rig predicting them (what
        ``predict`` would have given).

    Raises
    ------
    ParameterError
        The run's parameters cannot be simulated here (the message says why).
    """
    from seft_ros.core.experiment import simulate
    timing = run.extra.get('timing_data') or {}
    p = run.params
    if not timing or p.get('mode') != 'realtime' or p.get('rig_interface',
                                                            'simulated') != 'simulated':
        return None
    latency, stale = {}, {}
    for rig in run.rig_names:
        prefix = f'{rig}/' if rig else ''
        rig_t = timing.get(f'{prefix}rig')
        if rig_t is None:
            return None
        # the run's analysed steps: not an aborted run's safe-state ramp (no commands)
        rig_t = timing_until(rig_t, run.n_steps)
        latency[rig] = dict(zip(rig_t.step.tolist(), rig_t.loop_latency_s.tolist()))
        ctrl = timing.get(f'{prefix}force_servo_controller')
        stale[rig] = {} if ctrl is None else steps_behind(timing_until(ctrl, run.n_steps),
                                                          rig_t, float(p['dt']))
    params = {k: v for k, v in p.items() if k != 'bag_path'}
    params.update(mode='lockstep', n_steps=run.n_steps)

    as_run = simulate(params, stale_steps=stale, command_latency_s=latency)
    in_time = simulate(params, command_latency_s={rig: {} for rig in run.rig_names})
    late = {rig: sum(1 for v in lat.values() if math.isfinite(v) and v > float(p['dt']))
            for rig, lat in latency.items()}
    lost = {rig: sum(1 for v in lat.values() if not math.isfinite(v))
            for rig, lat in latency.items()}
    extra = {}
    holding = {rig: rp.get('realtime_late_command', 'hold') == 'hold'
               for rig, rp in test_setup(params).rig_params.items()}
    if any((late[rig] or lost[rig]) and holding[rig] for rig in late):
        # what rigs that predict a late command would have made of the same timing
        extra['predicting'] = worst_nrms(simulate(_predicting(params), stale_steps=stale,
                                                  command_latency_s=latency))
    return {'late_commands': late, 'lost_commands': lost,
            'stale_steps': {rig: len(s) for rig, s in stale.items()},
            'steps_behind': {rig: max(s.values(), default=0) for rig, s in stale.items()},
            'recorded': ({s: recorded.get(s) for s in REPLAY_SIGNALS} if recorded is not None
                         else worst_nrms(run)),
            'as_run': worst_nrms(as_run), 'in_time': worst_nrms(in_time), **extra}


def _predicting(params: dict) -> dict:
    """`params` with every rig predicting its late commands (``realtime_late_command:
    predict``): the run's parameter, and a structure's rig sections that set their own."""
    out = dict(params, realtime_late_command='predict')
    if not is_study(params):
        structure = structure_of(params)
        rigs = {rig: dict(section, realtime_late_command='predict')
                if 'realtime_late_command' in section else dict(section)
                for rig, section in structure.rigs.items()}
        out['structure'] = dataclasses.replace(structure, rigs=rigs).to_json()
    return out


def worst_nrms(run) -> dict:
    """A run's worst NRMS per signal (:data:`~seft_ros.analysis.findings.REPLAY_SIGNALS`,
    fractions, the summary's ``worst_nrms``), or ``{'unstable_at_s': t}`` for an unstable
    run (with ``'watchdog': True`` and its NRMS to then for one a watchdog stopped): what a
    replay reports of each run. A run the operator interrupted
    (``extra['interrupted']``) is not unstable: its NRMS over the steps it ran."""
    from seft_ros.analysis.metrics import compare_run, summary_entry
    stopped = not run.stable and not run.extra.get('interrupted')
    # a watchdog's stop is the host's timing, which no replay models (a replay runs to the
    # same step and completes): its NRMS to then, which the replay's are judged against (a
    # new user's replay matched them within 0.3 points and was said not to reproduce the
    # run; session 39)
    watchdog = stopped and 'watchdog:' in str(run.abort_reason or '')
    if stopped and not watchdog:
        return {'unstable_at_s': run.unstable_at_s}
    entry = summary_entry(run, compare_run(run))
    worst = {s: entry['worst_nrms'].get(s) for s in REPLAY_SIGNALS}
    return dict(worst, unstable_at_s=run.unstable_at_s, watchdog=True) if watchdog else worst


def steps_behind(controller, rig, dt: float) -> dict[int, int]:
    """How far behind its reference forces a real-time force servo controller was at each
    stale step: step k -> ``d`` (it held the forces up to ``k - d``), from its timing
    records and its rig's.

    The controller's input age at a stale step runs from the sample of the newest force it
    held to its command (``ReferencePlayout.due``'s source step), and the rig's loop latency
    from the step's sample to that command's arrival; their difference is ``d`` sample
    periods less the command's transit (0.1 ms on one host), rounded. Where the rig has no
    latency for the step (the command never arrived), ``d`` is 1. A builder that falls
    behind in a host stall leaves the controller several steps behind (the yielding steel
    frame at 1 kHz: up to 7), each step predicted over at most
    ``reference_extrapolation_steps``: a replay that took every stale step as 1 behind
    gave 1.4 % where the run erred 8.4 %.

    Parameters
    ----------
    controller, rig : TimingRecords
        The controller's and its rig's timing records (:mod:`seft_ros.analysis.timing`).
    dt : float
        Sample period [s].

    Returns
    -------
    dict of int to int
        Each stale step and its ``d`` (>= 1).
    """
    latency = dict(zip(rig.step.tolist(), rig.loop_latency_s.tolist()))
    out = {}
    for k, age in zip(controller.step[controller.stale].tolist(),
                      controller.input_age_s[controller.stale].tolist()):
        lat = latency.get(int(k), math.nan)
        d = round((age - lat) / dt) if math.isfinite(age) and math.isfinite(lat) else 1
        out[int(k)] = max(1, int(d))
    return out


def replay_due(run, worst_nrms) -> bool:
    """Whether ``seft run`` replays this run's timing by itself (:func:`replay_timing`): a
    real-time run of seft's simulated rigs with a late command or a stale step (up to its
    abort, if it was aborted) that either was aborted (not by the operator: did the host's
    timing stop it?) or completed with a worst NRMS above :data:`REPLAY_ABOVE_NRMS` in some
    signal (`worst_nrms`: the summary's, fractions, or a callable that returns them: called
    only once the timing says a replay could be due). Its cost is two runs in process (a few
    seconds), paid where the run erred."""
    p = run.params
    timing = run.extra.get('timing_data') or {}
    if not (timing and p.get('mode') == 'realtime'
            and p.get('rig_interface', 'simulated') == 'simulated'):
        return False
    if not run.stable and run.extra.get('interrupted'):
        return False                   # the operator's stop: nothing to explain
    dt = float(p['dt'])
    if not any((node.endswith('rig') and np.any(~(t.loop_latency_s <= dt)))
               or (node.endswith('force_servo_controller') and np.any(t.stale))
               for node, t in ((node, timing_until(t, run.n_steps))
                               for node, t in timing.items())):
        return False
    if not run.stable:
        return True
    if callable(worst_nrms):
        worst_nrms = worst_nrms()
    return any(v is not None and v > REPLAY_ABOVE_NRMS for v in worst_nrms.values())
