"""Throughput of ``seft simulate``: microseconds per step, one run, and a sweep on all cores.

For the predictors ``none`` and ``model`` on the servohydraulic rig with its force controller
(and on the delay rig), simulates a long run several times and prints the median and the
minimum of

* the whole :func:`~seft_ros.core.experiment.simulate` call per step (set-up included: the
  rig's sampling, the controller, the ``model`` predictor's force-loop inverse), and
* the step loop alone (the whole call less the set-up, timed on its own),

in microseconds per step and as a multiple of real time (``dt`` per step), and the whole call
in CPU time of the process (``time.process_time``: on a shared host the wall time also counts
the other jobs' turns on the cores, the CPU time much less so). Then the wall time
of a sweep of runs (the main job's 8: alpha 0, 0.5, 1, 1.5 with ``none`` and ``model``) one
after the other and in the process pool of ``seft simulate``
(:func:`seft_ros.cli.api.simulate_runs`), and, for scale, the stability guard and the report
that ``seft simulate`` adds around the runs. The machine is shared and noisy: quote medians
with the load printed. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/simulate_throughput.py [--repeat 5] [--time-scale 1]
"""

import argparse
import os
from pathlib import Path
import statistics
import tempfile
import time

from seft_msgs_py import parameters
from seft_msgs_py.sampling import single_blas_thread
from seft_plant_sim.rigs import make_rig
from seft_ros.analysis.report import write_report
from seft_ros.cli import api
from seft_ros.core.controller import ForceServoController, SaturationInterlock
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepared_record
from seft_ros.core.monitor import InstabilityMonitor
from seft_ros.core.reference_force import ReferenceForceBuilder


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f'load average {one:.2f} / {five:.2f} / {fifteen:.2f} on {os.cpu_count()} cores'


def setup_s(params) -> float:
    """Wall time of the objects simulate() builds before its first step [s] (built as there,
    on one BLAS thread)."""
    t0 = time.perf_counter()
    with single_blas_thread():
        rig = make_rig(params)
        ReferenceForceBuilder.from_parameters(params)
        InstabilityMonitor.from_parameters(params)
        if rig.command_kind == 'valve_command_V':
            ForceServoController.from_parameters(params)
            SaturationInterlock.from_parameters(params)
    return time.perf_counter() - t0


def one_run(params, repeat: int) -> str:
    gm = prepared_record(params)
    simulate(params, record=gm)                       # warm up (imports, caches)
    totals, loops, cpus, steps = [], [], [], None
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        run = simulate(params, record=gm)
        total = time.perf_counter() - t0
        cpus.append(time.process_time() - c0)
        steps = run.n_steps
        totals.append(total)
        loops.append(total - setup_s(params))
    dt = float(params['dt'])

    def fig(times):
        us = [1e6 * t / steps for t in times]
        med, best = statistics.median(us), min(us)
        return (f'{med:6.2f} / {best:6.2f} us/step = {dt / (med * 1e-6):4.0f}x / '
                f'{dt / (best * 1e-6):4.0f}x real time')

    stable = 'stable' if run.stable else f'ABORTED at {run.unstable_at_s:.2f} s'
    return (f'{params["rig_model"]:>14} {params["predictor"]:>5}  {steps} steps ({stable})\n'
            f'    whole simulate() median / min: {fig(totals)}\n'
            f'    step loop alone  median / min: {fig(loops)}\n'
            f'    whole call, CPU  median / min: {fig(cpus)}')


def sweep(runs, workers: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        api.simulate_runs(runs=runs, out_dir=Path(tmp), progress=lambda line: None,
                          workers=workers)
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--repeat', type=int, default=5, help='repeats per figure (default 5)')
    ap.add_argument('--record', default='default', help='record (default: the embedded one)')
    ap.add_argument('--time-scale', type=float, default=None,
                    help='time scale of the record (default: the schema default)')
    ap.add_argument('--alpha', type=float, default=0.5, help='mass ratio of the single runs')
    args = ap.parse_args()
    base = {'record': args.record, 'amplitude_N': 500.0, 'alpha': args.alpha}
    if args.time_scale is not None:
        base['time_scale'] = args.time_scale
    print(f'seft simulate throughput; {load()}')
    print(f'single runs, {args.repeat} repeats, alpha {args.alpha:g}, amplitude 500 N, '
          f'record {args.record!r}:')
    for rig in ('servohydraulic', 'delay'):
        for predictor in ('none', 'model'):
            params = parameters.resolve(dict(base, rig_model=rig, predictor=predictor))
            print(one_run(params, args.repeat), flush=True)
    runs = api.build_runs(overrides=dict(base, rig_model='servohydraulic',
                                         predictor=['none', 'model']),
                          alphas=[0.0, 0.5, 1.0, 1.5])
    n = len(runs)
    workers = min(n, os.cpu_count() or 1)
    serial = [sweep(runs, 1) for _ in range(max(1, args.repeat // 2))]
    pooled = [sweep(runs, workers) for _ in range(max(1, args.repeat // 2))]
    s, p = statistics.median(serial), statistics.median(pooled)
    print(f'sweep of {n} runs (servohydraulic, none/model x alpha 0-1.5), median of '
          f'{len(serial)}: one after the other {s:.2f} s, pool of {workers} workers '
          f'{p:.2f} s: {s / p:.2f}x; {load()}')
    t0 = time.perf_counter()
    api.check_stability(runs=runs, force=True, progress=lambda line: None)
    t1 = time.perf_counter()
    api.check_ranges(runs=runs, progress=lambda line: None)
    t2 = time.perf_counter()
    data = [simulate(r) for r in runs]
    with tempfile.TemporaryDirectory() as tmp:
        t3 = time.perf_counter()
        write_report(data, Path(tmp), title='benchmark')
        t4 = time.perf_counter()
    print(f'around the runs, seft simulate also spends: stability guard {t1 - t0:.2f} s, '
          f'range check {t2 - t1:.2f} s, report {t4 - t3:.2f} s')


if __name__ == '__main__':
    main()
