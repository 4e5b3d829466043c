"""What late reference forces cost a test: held, extrapolated linearly, or predicted.

In real time the force servo controller never waits long: when the builder's force of a
step has not arrived by its deadline (a *stale* step: the builder's host was late), it held
the newest force; then extrapolated it linearly; it now predicts it
(``reference_extrapolation``, ``reference_extrapolation_steps``,
:class:`seft_ros.core.controller.ReferencePlayout`). This replays stale steps in process
(``stale_steps`` of :func:`seft_ros.core.experiment.simulate`, any test) with the force
held (``reference_extrapolation_steps`` 0), extrapolated linearly and predicted (over the
configured steps, or ``--extrapolate``) and prints the NRMS errors against the run without
stale steps (displacement per DOF for a structure; displacement / acceleration / force for
the study's test), predictor ``model``:

- given real-time bags (``seft run CONFIG --mode realtime``), their controllers' stale steps
  (the timing records) are replayed, and the bag's own NRMS is printed beside them: it shows
  how much of a real-time run's error the late forces explain;
- without bags, a synthetic pattern: one stale step every ``--every`` steps on each rig (the
  rigs offset by a third of it).

No ROS; deterministic (it times nothing). Asserts nothing.

Usage: .venv/bin/python benchmarks/stale_reference.py [--config config/two_piers.yaml]
       [--alpha A] [--every 37] [--extrapolate 2] [BAG ...]
"""

import argparse
from pathlib import Path
import sys

from seft_msgs_py.errors import SeftError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.api import has_structure
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate

ROOT = Path(__file__).resolve().parents[1]


def _nrms(run) -> dict:
    """NRMS [%]: displacement per DOF (a structure), else displacement / acceleration / force."""
    c = compare_run(run)
    if not run.is_study:
        return {d.dof: 100.0 * d.displacement.nrms for d in c.dofs}
    return {name: 100.0 * getattr(c, name).nrms
            for name in ('displacement', 'acceleration', 'force')}


def _run(params: dict, stale: dict | None):
    """Simulate `params` with the stale steps of each rig (None: none; the study's rig is
    ``''``)."""
    return simulate(params, stale_steps=stale)


def _stale_of_bag(bag: Path) -> tuple:
    """The real-time run of `bag` and its controllers' stale steps (rig name -> steps)."""
    run = read_run(bag)
    nodes = ({'': 'force_servo_controller'} if run.is_study else
             {rig: f'{rig}/force_servo_controller' for rig in run.rigs})
    timing = run.extra['timing_data']
    missing = [n for n in nodes.values() if n not in timing]
    if missing:
        raise SeftError(f'{bag}: no timing records of {", ".join(missing)} (a real-time run '
                        'of the servohydraulic rig is needed)')
    return run, {rig: set(timing[n].step[timing[n].stale].tolist())
                 for rig, n in nodes.items()}


def _row(label: str, stable: bool, nrms: dict, stale_fraction: float | None) -> str:
    stale = '' if stale_fraction is None else f'{100 * stale_fraction:.2f}'
    cells = ' | '.join(f'{v:.3f}' for v in nrms.values())
    return f'| {label} | {stale} | {"yes" if stable else "NO"} | {cells} |'


def replay(params: dict, stale: dict, extrapolate: int) -> list[tuple]:
    """(label, stable, NRMS [%]) held, extrapolated linearly and predicted."""
    out = []
    for label, steps, how in (('held', 0, 'linear'),
                              (f'extrapolated linearly ({extrapolate})', extrapolate, 'linear'),
                              (f'predicted ({extrapolate})', extrapolate, 'prediction')):
        run = _run(dict(params, reference_extrapolation_steps=steps,
                        reference_extrapolation=how), stale)
        out.append((label, run.stable, _nrms(run)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='*', type=Path, help='real-time structure bags')
    parser.add_argument('--config', type=Path, default=ROOT / 'config' / 'two_piers.yaml')
    parser.add_argument('--alpha', type=float, default=None,
                        help="the study's test: its mass ratio (default the config's first)")
    parser.add_argument('--every', type=int, default=37,
                        help='synthetic pattern: one stale step every this many steps')
    parser.add_argument('--extrapolate', type=int, default=None,
                        help='reference_extrapolation_steps of the extrapolated replay '
                             "(default: the configuration's)")
    args = parser.parse_args(argv)
    try:
        runs = [p for p in expand_runs(load_config(args.config)) if p['predictor'] == 'model']
        if args.alpha is not None:
            runs = [dict(p, alpha=args.alpha) for p in runs]
        if not runs:
            raise SeftError(f'{args.config}: no run with predictor model')
        params = runs[0]
        if params.get('rig_model') != 'servohydraulic' and not has_structure(params):
            raise SeftError(f'{args.config}: rig_model {params.get("rig_model")!r}: the '
                            'servohydraulic rig is needed (the delay rig has no controller)')
        extrapolate = (int(params['reference_extrapolation_steps']) if args.extrapolate is None
                       else args.extrapolate)
        clean = _run(params, None)
        columns = list(_nrms(clean))
        what = ('displacement NRMS per DOF' if hasattr(clean, 'rigs') else
                f'alpha {params["alpha"]:g}, NRMS')
        print(f'{args.config.name}, predictor model: {what} [%]')
        print(f'| replay | stale steps [%] | stable | {" | ".join(columns)} |')
        print('|---|---|---|' + '---|' * len(columns))
        print(_row('no stale step (lockstep)', clean.stable, _nrms(clean), 0.0))
        n = clean.time_s.shape[0]
        rigs = list(clean.rigs)
        if not args.bags:
            offset = max(1, args.every // 3)
            stale = {r: set(range(args.every + i * offset, n, args.every))
                     for i, r in enumerate(rigs)}
            fraction = sum(len(s) for s in stale.values()) / (n * len(stale))
            for label, stable, nrms in replay(params, stale, extrapolate):
                print(_row(f'every {args.every} steps, {label}', stable, nrms, fraction))
        for bag in args.bags:
            measured, stale = _stale_of_bag(bag)
            if sorted(stale) != sorted(rigs):
                raise SeftError(f'{bag}: its rigs {", ".join(sorted(stale))} are not those of '
                                f'{args.config} ({", ".join(rigs)})')
            fraction = sum(len(s) for s in stale.values()) / (n * len(stale))
            name = '/'.join(bag.resolve().parts[-3:-1])     # <out>/<run>
            print(_row(f'{name}: the real-time run itself', measured.stable, _nrms(measured),
                       fraction))
            for label, stable, nrms in replay(params, stale, extrapolate):
                print(_row(f'{name}: its stale steps, {label}', stable, nrms, fraction))
    except SeftError as exc:
        print(f'stale_reference: error: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
