"""The runs of ``seft rig-check`` recorded in one process, for the tests of its checks.

:func:`recorded_runs` plays the four runs (step, abort, stopped controller, watchdog) as the
graph does in real time, with every command on time, against seft's real-time simulated rig
(:class:`~seft_plant_sim.realtime.WallClockRig`, wrapped in
:class:`~seft_plant_sim.faults.FaultyRig` for a fault), seft's force servo controller for a
valve rig, and the rig node's safe state, watchdog and limits; and returns what the checker
would have heard and the bag would hold (``seft_ros.cli.rig_check._Run``). No DDS, no wall
clock: the same numbers every time, a few hundred milliseconds a rig.
"""

import math
from types import SimpleNamespace

import numpy as np

from seft_msgs_py import parameters, rig_contract
from seft_msgs_py.interface import COMMAND_VALVE
from seft_msgs_py.signals import CLOCK_EVERY, MEASUREMENT_FIELDS
from seft_plant_sim.faults import FAULTS, FaultyRig
from seft_plant_sim.realtime import WallClockRig
from seft_ros.cli.rig_check import _SENSOR_TOPICS, RUNS, _Run, check_parameters
from seft_ros.core import rig_check as rc
from seft_ros.core.excitation import make_valve_controller

#: The system-clock time of the rig's sample 0 in these runs [ns].
T0_NS = 1_800_000_000_000_000_000
#: When the rig sends a sample after its instant, and a command arrives after the instant
#: of the sample it was computed from [s].
SEND_S, COMMAND_S = 1e-4, 5e-4


def check_params(model: str, **overrides) -> dict:
    """The resolved parameters of a check of seft's `model` rig in real time."""
    return parameters.resolve({'rig_model': model, 'mode': 'realtime',
                               'watchdog_timeout_s': 0.05, **overrides})


def _run(name, params, profile, fault, tmp_dir, chance=0):
    """One run, played sample by sample; the fault at its chance `chance`
    (``profile.fault_steps``)."""
    reference = profile.step_reference() if name == 'step' else profile.sine_reference()
    p = check_parameters(params, profile, tmp_dir / 'record.csv', reference.size)
    dt = profile.dt
    dt_ns = int(round(dt * 1e9))
    rig = WallClockRig(p)
    if fault is not None:
        rig = FaultyRig(rig, FAULTS[fault], seed=int(p['noise_seed']))
    valve = rig.command_kind == COMMAND_VALVE
    controller = make_valve_controller(p) if valve else None
    tick = FAULTS[fault].tick_factor if fault else 1.0
    watchdog_steps = math.ceil(float(p['watchdog_timeout_s']) / dt)
    stamps, sent, rows, clock_ns = [], [], [], []
    commands = {} if valve else {0: reference[0]}
    fault_ns = abort_at = reason = safe_since = None
    last_command = 0
    k = 0
    while True:
        m = rig.measure()
        values = (m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2)
        stamps.append(rig.stamp_ns(k, dt_ns) if fault else k * dt_ns)
        sent.append(T0_NS * 1e-9 + k * dt * tick + SEND_S)
        rows.append(values)
        if k % CLOCK_EVERY == 0:
            clock_ns.append(k * dt_ns)
        if k + 1 >= reference.size and abort_at is None:
            break
        if abort_at is None:
            why = rig.limit_violation()
            if why is None and name != 'step' and k == profile.fault_steps[chance]:
                fault_ns = T0_NS + int((k * dt + 3e-4) * 1e9)
                if name != 'watchdog':
                    why = {'abort': 'seft_runner: seft rig-check: abort',
                           'stopped_controller': 'stopped by SIGTERM'}[name]
            if why is None and k - last_command > watchdog_steps:
                why = (f'{rig_contract.WATCHDOG_REASON} no command for '
                       f'{1e3 * (k - last_command) * dt:.1f} ms')
            if why is not None:
                abort_at, reason = k * dt, why
                rig.enter_safe_state()
        elif rig.safe_ramp_done:
            safe_since = k * dt if safe_since is None else safe_since
            if k * dt - safe_since >= rig_contract.SAFE_HOLD_S - 1e-9:
                break
        silent = name == 'watchdog' and fault_ns is not None
        if abort_at is None and not silent:
            if valve:
                j, u = k, controller.step(reference[k], *values[:1], values[2], values[3],
                                          values[1])
            else:
                j, u = k + 1, reference[min(k + 1, reference.size - 1)]
            commands[j] = u
            rig.arrive(j, u, k * dt + COMMAND_S)
            last_command = k
        rig.advance()
        k += 1
    stamps = np.array(stamps, dtype=np.int64)
    steps = np.round(stamps / dt_ns).astype(np.int64)
    rows = np.array(rows)
    samples = {topic: dict(zip(steps.tolist(), rows[:, i].tolist()))
               for i, topic in enumerate(_SENSOR_TOPICS)}
    samples[rig_contract.command_signal(rig.command_kind).name] = commands
    published = len(rows)
    final = {'name': 'rig', 'state': 'done' if abort_at is None else 'aborted',
             'message': reason or f'completed {published} steps', 'published': str(published),
             rig_contract.CONTRACT_KEY: rig_contract.CONTRACT}
    if abort_at is not None:
        final['abort_at_s'] = f'{abort_at:.6f}'
    statuses = [{'name': 'rig', 'state': 'ready', rig_contract.CONTRACT_KEY:
                 rig_contract.CONTRACT, 'command_kind': rig.command_kind,
                 'command_latency_s': repr(rig_contract.command_latency_s(p))},
                {'name': 'rig', 'state': 'running', 't0_ns': str(T0_NS)}, final]
    bag = SimpleNamespace(samples=samples, statuses=statuses,
                          node_params={'rig': {n: p[n] for n in
                                               rig_contract.REQUIRED_PARAMETERS}})
    return _Run(name, p, steps=steps, stamps=stamps, arrivals=np.array(sent),
                names=MEASUREMENT_FIELDS, values=rows, fault_ns=fault_ns, clock_ns=clock_ns,
                statuses=statuses, bag=bag, bag_closed=True,
                fault_step=None if name == 'step' else profile.fault_steps[chance])


def recorded_runs(params, profile: rc.CheckProfile, tmp_dir, fault: str | None = None,
                  runs=RUNS, chance: int = 0) -> dict:
    """The runs of a rig check of `params`' rig with `fault` (a name of
    :data:`~seft_plant_sim.faults.FAULTS`, None: none), as ``seft_ros.cli.rig_check``
    collects them; the fault runs' fault at its chance `chance` (``profile.fault_steps``: a
    checker that heard the earlier chances late)."""
    return {name: _run(name, params, profile, fault, tmp_dir, chance) for name in runs}
