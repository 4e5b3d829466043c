"""OpenSees models as the computational substructure (issue 32): the target table.

For each record (the embedded one and any PEER ``.AT2`` given with --record; use records that
no configuration names), runs ``simulate`` and prints the displacement NRMS per DOF against
each run's reference:

* ``config/two_story.yaml`` (matrices, against scipy's lsim) and
  ``config/opensees/two_story.yaml`` (the same building through OpenSees, against OpenSees'
  own analysis of the whole), ``model``: the difference per DOF (target: within 0.05
  percentage points);
* ``config/opensees/steel_frame.yaml`` with ``model`` at each --amplitude (target: <= 1 % per
  floor while elastic, <= 3 % where the computational frame yields), with the largest moment
  of column 111 over its first-yield moment in the reference (> 1: it yields) and the peak
  plastic rotation (the column's end rotation beyond its elastic rotation at that moment);
* each model's timed dry run (500 steps, ``seft_ros.opensees.part.dry_run``): p50 / p99 /
  max of the OpenSees step, with the machine's load average.

Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/opensees_models.py [--record default X.AT2 ...]
       [--amplitude 1000 1400 2600] [--duration 0]
"""

import argparse
import os
from pathlib import Path

import numpy as np

from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import run_reference
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate
from seft_ros.core.structure import test_setup
from seft_ros.opensees.part import dry_run

ROOT = Path(__file__).resolve().parents[1]
#: First-yield moment of the frame's 40 x 12 mm S690 column [N m].
COLUMN_MY_N_M = 690e6 * 0.012 * 0.040 ** 2 / 6.0


def _run(path, **overrides):
    params = expand_runs(dict(load_config(path), **overrides))[0]
    run = simulate(params)
    comparison = compare_run(run)
    return run, comparison, [d.displacement.nrms for d in comparison.dofs]


def _pct(values) -> str:
    return ' / '.join(f'{100 * v:.3f}' for v in values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--record', nargs='+', default=['default'])
    ap.add_argument('--amplitude', nargs='+', type=float, default=[1000.0, 1400.0, 2600.0])
    ap.add_argument('--duration', type=float, default=0.0, help='seconds of each record (0: all)')
    args = ap.parse_args()
    common = {'duration_s': args.duration}
    for record in args.record:
        name = Path(record).name
        _, _, matrix = _run(ROOT / 'config' / 'two_story.yaml', predictor='model', record=record,
                            **common)
        _, _, model = _run(ROOT / 'config' / 'opensees' / 'two_story.yaml', predictor='model',
                           record=record, **common)
        print(f'two_story, {name}: NRMS x per DOF [%] matrices {_pct(matrix)}, OpenSees '
              f'{_pct(model)}, difference {_pct(np.abs(np.subtract(model, matrix)))} pp')
        for amplitude in args.amplitude:
            run, comparison, nrms = _run(ROOT / 'config' / 'opensees' / 'steel_frame.yaml',
                                         record=record, amplitude_N=amplitude, **common)
            ref = run_reference(run)
            moment = np.asarray(ref.element_forces[111])
            rotation = np.asarray(ref.element_deformations[111])
            k = int(np.argmax(np.abs(rotation)))
            elastic = moment[k] / (moment[np.argmax(np.abs(moment))] / rotation[
                np.argmax(np.abs(moment))]) if np.max(np.abs(moment)) else 0.0
            st = run.computational['opensees/step_time_s']
            st = st[np.isfinite(st)]
            print(f'steel_frame, {name}, {amplitude:g} N: stable {run.stable}, NRMS x per floor '
                  f'[%] {_pct(nrms)}; column 111: max |M| / M_y = '
                  f'{np.max(np.abs(moment)) / COLUMN_MY_N_M:.2f}, peak rotation '
                  f'{abs(rotation[k]):.4f} rad ({abs(rotation[k] - elastic):.4f} beyond the '
                  f'secant); step p50/p99/max {1e3 * np.percentile(st, 50):.3f} / '
                  f'{1e3 * np.percentile(st, 99):.3f} / {1e3 * np.max(st):.3f} ms')
    for path in ('two_story.yaml', 'steel_frame.yaml'):
        params = expand_runs(load_config(ROOT / 'config' / 'opensees' / path))[0]
        r = dry_run(test_setup(params).substructures, float(params['dt']), steps=500)
        print(f'dry run {path}: p50 {1e3 * r.p50_s:.3f} / p99 {1e3 * r.p99_s:.3f} / max '
              f'{1e3 * r.max_s:.3f} ms per step (load average {os.getloadavg()[0]:.1f})')


if __name__ == '__main__':
    main()
