"""What late reference forces cost a structure test, held or extrapolated.

In real time the force servo controller never waits: when the builder's force of a step has
not arrived as the controller acts (a *stale* step: the builder's host was late), it held the
newest force; it now extrapolates it (``reference_extrapolation_steps``,
:class:`seft_ros.core.controller.ReferencePlayout`). This replays stale steps in process
(:func:`seft_ros.core.structure_experiment.simulate_structure`, ``stale_steps``) with the
force held (``reference_extrapolation_steps`` 0) and extrapolated (the configured value, or
``--extrapolate``) and prints the NRMS of displacement per DOF against the run without stale
steps:

- given real-time bags (``seft run CONFIG --mode realtime``; the bag is under the output
  folder), their controllers' stale steps (the timing records) are replayed, and the bag's
  own NRMS is printed beside them: it shows how much of a real-time run's error the late
  forces explain;
- without bags, a synthetic pattern: one stale step every ``--every`` steps on each rig (the
  rigs offset by a third of it).

No ROS; deterministic (it times nothing). Asserts nothing.

Usage: .venv/bin/python benchmarks/stale_reference.py [--config config/two_piers.yaml]
       [--every 37] [--extrapolate 2] [BAG ...]
"""

import argparse
from pathlib import Path
import sys

from seft_msgs_py.errors import SeftError
from seft_ros.analysis.structure_bag import read_structure_run
from seft_ros.analysis.structure_metrics import compare_structure
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.structure_experiment import simulate_structure

ROOT = Path(__file__).resolve().parents[1]


def _nrms(run) -> dict:
    return {d.dof: 100.0 * d.displacement.nrms for d in compare_structure(run).dofs}


def _row(label: str, stable: bool, nrms: dict, stale_fraction: float | None) -> str:
    stale = '' if stale_fraction is None else f'{100 * stale_fraction:.2f}'
    cells = ' | '.join(f'{v:.3f}' for v in nrms.values())
    return f'| {label} | {stale} | {"yes" if stable else "NO"} | {cells} |'


def replay(params: dict, stale: dict, n_steps: int, extrapolate: int) -> list[tuple]:
    """(label, stable, nrms per DOF [%]) held and extrapolated."""
    out = []
    for label, steps in (('held', 0), (f'extrapolated ({extrapolate})', extrapolate)):
        run = simulate_structure(dict(params, reference_extrapolation_steps=steps),
                                 stale_steps=stale)
        out.append((label, run.stable, _nrms(run)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='*', type=Path, help='real-time structure bags')
    parser.add_argument('--config', type=Path, default=ROOT / 'config' / 'two_piers.yaml')
    parser.add_argument('--every', type=int, default=37,
                        help='synthetic pattern: one stale step every this many steps')
    parser.add_argument('--extrapolate', type=int, default=None,
                        help='reference_extrapolation_steps of the extrapolated replay '
                             "(default: the configuration's)")
    args = parser.parse_args(argv)
    try:
        runs = [p for p in expand_runs(load_config(args.config)) if p['predictor'] == 'model']
        if not runs:
            raise SeftError(f'{args.config}: no run with predictor model')
        params = runs[0]
        extrapolate = (int(params['reference_extrapolation_steps']) if args.extrapolate is None
                       else args.extrapolate)
        clean = simulate_structure(params)
        dofs = list(_nrms(clean))
        print(f'{args.config.name}, predictor model: displacement NRMS per DOF [%]')
        print(f'| replay | stale steps [%] | stable | {" | ".join(dofs)} |')
        print('|---|---|---|' + '---|' * len(dofs))
        print(_row('no stale step (lockstep)', clean.stable, _nrms(clean), 0.0))
        n = clean.time_s.shape[0]
        if not args.bags:
            offset = max(1, args.every // 3)
            stale = {r: set(range(args.every + i * offset, n, args.every))
                     for i, r in enumerate(clean.rigs)}
            fraction = sum(len(s) for s in stale.values()) / (n * len(stale))
            for label, stable, nrms in replay(params, stale, n, extrapolate):
                print(_row(f'every {args.every} steps, {label}', stable, nrms, fraction))
        for bag in args.bags:
            measured = read_structure_run(bag)
            timing = measured.extra['timing_data']
            stale = {}
            for rig in measured.rigs:
                t = timing[f'{rig}/force_servo_controller']
                stale[rig] = set(t.step[t.stale].tolist())
            fraction = sum(len(s) for s in stale.values()) / (n * len(stale))
            name = bag.resolve().parent.parent.name
            print(_row(f'{name}: the real-time run itself', measured.stable, _nrms(measured),
                       fraction))
            for label, stable, nrms in replay(params, stale, n, extrapolate):
                print(_row(f'{name}: its stale steps, {label}', stable, nrms, fraction))
    except SeftError as exc:
        print(f'stale_reference: error: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
