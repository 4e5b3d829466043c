"""A lab's reference-force builder: its compute time per step, without ROS (issue 41 target 4).

Runs ``config/two_piers.yaml`` with each lab's own builder (``structure_builders:
per_rig``), ``adaptive``, every pier's predictor m, c and k 10 % off, in one process
(``seft_ros.core.experiment.simulate``, lockstep), and times every builder's
``ReferenceForceBuilder.step`` with ``time.perf_counter_ns``: the work a builder node does
per control period once its inputs are there (the node adds its messages; the work it does
after its command is out, ``ReferenceForceBuilder.advance``, is not timed). Prints, per
builder, the compute time's p50, p99, p99.9 and max over the run's steps, the steps over the
budget (``--budget-ms``, 0.5 ms by default: the issue's target), and the load average before
and after; ``--profile`` adds the functions that take the most time inside the steps over
the budget (``cProfile`` on every step, the slow steps' statistics kept).

    .venv/bin/python benchmarks/builder_step.py [--record A.AT2] [--duration-s 15]
        [--amplitude-N 700] [--repeats 3] [--profile]
    .venv/bin/python benchmarks/builder_step.py --config LAB.yaml [--params RIG.yaml]
        [--set KEY=VALUE ...]          # a lab's own test instead

The figures are CPU time of one core under whatever else the host runs: quote the load with
them, and medians over repeats.
"""

import argparse
import cProfile
import os
from pathlib import Path
import pstats
import sys
import tempfile
import time

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
#: Predictor parameter -> the rig's true parameter (every pier's model 10 % off).
ERRORS = {'predictor_mass_kg': 'mass_kg', 'predictor_damping_N_s_per_m': 'damping_N_s_per_m',
          'predictor_stiffness_N_per_m': 'stiffness_N_per_m'}


def _config(tmp: Path, args) -> Path:
    """two_piers.yaml with per-rig builders, ``adaptive`` and each pier's model +10 %."""
    from seft_ros.cli.api import build_runs
    from seft_ros.core.structure import test_setup
    values = yaml.safe_load((ROOT / 'config' / 'two_piers.yaml').read_text())
    base = build_runs(config=str(ROOT / 'config' / 'two_piers.yaml'),
                      overrides={'predictor': 'model'})[0]
    rig_params = test_setup(base).rig_params
    for rig, section in values['rigs'].items():
        for key, source in ERRORS.items():
            section[key] = float(1.1 * float(rig_params[rig][source]))
    values.update(predictor='adaptive', structure_builders='per_rig',
                  amplitude_N=float(args.amplitude_N), duration_s=float(args.duration_s),
                  record=args.record)
    path = tmp / 'two_piers_builder_step.yaml'
    path.write_text(yaml.safe_dump(values, sort_keys=False))
    return path


def _timed_run(params: dict, budget_s: float, profile: bool, background: bool):
    """One lockstep run; per builder the step times [s] and, with `profile`, the statistics
    of its steps over the budget. With `background`, the compensators' refits run on a
    worker process as in a real-time builder node (``BackgroundFits``, the node's switch
    interval) and the steps are paced at ``dt`` (the fits take wall time): the figures are
    then the node's, and the run's numbers not reproducible."""
    from seft_ros.core import reference_force
    from seft_ros.core.experiment import simulate
    from seft_ros.core.predictors import BackgroundFits
    from seft_ros.nodes.reference_force_builder import FIT_SWITCH_INTERVAL_S
    original_init = reference_force.ReferenceForceBuilder.__init__
    fits = BackgroundFits() if background else None
    if fits is not None:
        fits.start()

    def init(self, *a, **kw):
        original_init(self, *a, **kw)
        self.run_fits_in_background(fits)
    switch = sys.getswitchinterval()
    if background:
        sys.setswitchinterval(FIT_SWITCH_INTERVAL_S)
        reference_force.ReferenceForceBuilder.__init__ = init
    times: dict[int, list] = {}
    names: dict[int, str] = {}
    slow_profiles = []
    original = reference_force.ReferenceForceBuilder.step

    period_s = float(params['dt'])
    clock = {'first': None, 'next': None}

    def timed(self, *a, **kw):
        key = id(self)
        names.setdefault(key, ','.join(getattr(self, 'local_rigs', ()) or ('all',)))
        if background:                  # the real-time pace: the worker's fits take wall time
            if clock['first'] is None:
                clock['first'] = key
            if key == clock['first']:
                now = time.perf_counter()
                clock['next'] = (now if clock['next'] is None else clock['next']) + period_s
                if clock['next'] > now:
                    time.sleep(clock['next'] - now)
        self.advance()                  # untimed, as the node does it after the command
        if profile:
            prof = cProfile.Profile()
            t0 = time.perf_counter_ns()
            prof.enable()
            out = original(self, *a, **kw)
            prof.disable()
            dt = (time.perf_counter_ns() - t0) * 1e-9
            if dt > budget_s:
                slow_profiles.append(prof)
        else:
            t0 = time.perf_counter_ns()
            out = original(self, *a, **kw)
            dt = (time.perf_counter_ns() - t0) * 1e-9
        times.setdefault(key, []).append(dt)
        return out

    reference_force.ReferenceForceBuilder.step = timed
    try:
        run = simulate(params)
    finally:
        reference_force.ReferenceForceBuilder.step = original
        reference_force.ReferenceForceBuilder.__init__ = original_init
        sys.setswitchinterval(switch)
    slow = None
    if slow_profiles:
        slow = pstats.Stats(slow_profiles[0])
        for p in slow_profiles[1:]:
            slow.add(p)
    return run, {names[k]: np.array(v) for k, v in times.items()}, slow


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--record', default='default', help="a PEER .AT2 path, or 'default'")
    ap.add_argument('--duration-s', type=float, default=15.0)
    ap.add_argument('--amplitude-N', type=float, default=700.0)
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--budget-ms', type=float, default=0.5)
    ap.add_argument('--profile', action='store_true',
                    help='the functions that take the time of the steps over the budget')
    ap.add_argument('--in-step', action='store_true',
                    help='the refits in the step, as seft simulate runs them (default: on a '
                         'worker process, as the real-time node)')
    ap.add_argument('--config', help="a lab's own configuration instead of the two piers "
                                     '(its first run; --record, --duration-s and '
                                     '--amplitude-N then as --set gives them)')
    ap.add_argument('--params', nargs='*', default=[], help='parameter files over --config')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help='parameter values over --config and --params')
    args = ap.parse_args(argv)
    budget = args.budget_ms * 1e-3
    from seft_ros.cli.api import build_runs
    where = ('in the step' if args.in_step else 'in a worker process (as in real time)')
    load = f'load {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores'
    rows: dict[str, list] = {}
    with tempfile.TemporaryDirectory(prefix='seft-builder-step-') as tmp:
        if args.config:
            sets = dict(item.split('=', 1) for item in args.set)
            params = build_runs(config=args.config, params_files=args.params,
                                overrides={k: yaml.safe_load(v) for k, v in sets.items()})[0]
            print(f'{args.config} ' + ' '.join(args.params + args.set)
                  + f' (its first run); refits {where}; {load}', flush=True)
        else:
            params = build_runs(config=str(_config(Path(tmp), args)))[0]
            print(f'two_piers, per-rig builders, adaptive, every pier m, c, k +10 %, '
                  f'{args.amplitude_N:g} N, {args.duration_s:g} s of {args.record}; refits '
                  f'{where}; {load}', flush=True)
        for i in range(args.repeats):
            run, times, slow = _timed_run(params, budget, args.profile and i == 0,
                                          not args.in_step)
            from seft_ros.analysis.metrics import compare_run
            dofs = compare_run(run).dofs
            print(f'run {i + 1}: NRMS x per DOF '
                  + ' / '.join(f'{100 * d.displacement.nrms:.2f}' for d in dofs)
                  + ' %, acceleration per DOF '
                  + ' / '.join(f'{100 * d.acceleration.nrms:.2f}' for d in dofs) + ' %',
                  flush=True)
            for name, t in times.items():
                ms = 1e3 * t
                row = (np.percentile(ms, 50), np.percentile(ms, 99), np.percentile(ms, 99.9),
                       float(np.max(ms)), 100.0 * float(np.mean(t > budget)), len(t))
                rows.setdefault(name, []).append(row)
                print(f'run {i + 1}: builder {name}: p50 {row[0]:.3f} ms, p99 {row[1]:.3f} '
                      f'ms, p99.9 {row[2]:.3f} ms, max {row[3]:.2f} ms; {row[4]:.2f} % of '
                      f'{row[5]} steps over {args.budget_ms:g} ms'
                      + ('' if run.stable else f' (run stopped: {run.abort_reason})'),
                      flush=True)
            if slow is not None:
                print(f'\nthe steps over {args.budget_ms:g} ms, by internal time:')
                slow.sort_stats('tottime').print_stats(15)
    print(f'\nmedians over {args.repeats} runs (load {os.getloadavg()[0]:.2f} after):')
    print('| builder | p50 [ms] | p99 [ms] | p99.9 [ms] | max [ms] | steps over budget [%] |')
    print('|---|---|---|---|---|---|')
    for name, rs in rows.items():
        med = np.median(np.array(rs)[:, :5], axis=0)
        print(f'| {name} | {med[0]:.3f} | {med[1]:.3f} | {med[2]:.3f} | {med[3]:.2f} | '
              f'{med[4]:.2f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
