"""How the delay compensators, all built on a linear model, fare on a yielding specimen.

For the Bouc-Wen specimen (``specimen_model='bouc_wen'``, defaults: k = 2.11e5 N/m initial,
D_y = 4 mm, post-yield ratio 0.1, n = 2, beta = gamma = 0.5) on the default record (1000 N,
time scale 0.5), runs ``simulate`` for each mass ratio, each registered predictor (read from
``seft_ros.core.reference_force.PREDICTORS`` at run time) and both rigs, and prints the NRMS
error (after removing the lag) and the peak ratio of displacement, force and acceleration
against the nonlinear reference, which is computed once per alpha. The same runs with the
linear specimen give the baseline: a compensator that works there and fails on the yielding
member is hurt by its linear model. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/nonlinear_specimen.py [--alpha 0 0.5 1] [--duration 0]
"""

import argparse
import math
import time

import numpy as np

from seft_msgs_py.errors import InputError, ParameterError
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import reference_from_run
from seft_ros.core.experiment import simulate
from seft_ros.core.reference_force import PREDICTORS

RIGS = ('delay', 'servohydraulic')
SIGNALS = ('displacement', 'force', 'acceleration')


def row(params, reference=None):
    """Simulate one run; return (cells, reference, seconds of simulate)."""
    t0 = time.monotonic()
    try:
        run = simulate(params)
    except (ParameterError, InputError) as exc:
        return [f'error: {exc}'], reference, 0.0
    wall = time.monotonic() - t0
    if reference is None or reference.n_steps < run.n_steps:
        reference = reference_from_run(run)
    if run.n_steps < 20:
        return [f'aborted at {run.unstable_at_s} s'], reference, wall
    cmp = compare_run(run, reference)
    cells = [f'{cmp.signal(s).nrms * 100:6.1f}% {cmp.signal(s).peak_ratio:5.2f}'
             for s in SIGNALS]
    cells.append(f'{np.max(np.abs(run.displacement_m)) * 1e3:6.1f}')
    cells.append('ok' if run.stable else f'aborted {run.unstable_at_s:.2f} s: '
                 f'{(run.abort_reason or "")[:40]}')
    return cells, reference, wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--alpha', type=float, nargs='+', default=[0.0, 0.5, 1.0])
    parser.add_argument('--duration', type=float, default=0.0,
                        help='run length [s] (0: the whole record)')
    args = parser.parse_args()
    predictors = list(PREDICTORS)
    print(f'predictors: {", ".join(predictors)}')
    print('cells: NRMS after lag removal, peak ratio test/reference; max|x| [mm]')
    header = (f'{"rig":15s} {"alpha":>5s} {"specimen":9s} {"predictor":11s} '
              + ' '.join(f'{s:>13s}' for s in SIGNALS) + f' {"max|x|":>6s}  run')
    print(header)
    print('-' * len(header))
    walls = []
    for alpha in args.alpha:
        refs = {}
        for rig in RIGS:
            for model in ('linear', 'bouc_wen'):
                for pred in predictors:
                    params = {'rig_model': rig, 'alpha': alpha, 'predictor': pred,
                              'specimen_model': model, 'duration_s': args.duration}
                    cells, refs[model], wall = row(params, refs.get(model))
                    walls.append(wall)
                    print(f'{rig:15s} {alpha:5.2f} {model:9s} {pred:11s} ' + ' '.join(cells))
        ref = refs.get('bouc_wen')
        if ref is not None and ref.hysteretic_z is not None:
            print(f'  reference (bouc_wen, alpha={alpha:g}): max|x| = '
                  f'{np.max(np.abs(ref.displacement_m)) * 1e3:.1f} mm '
                  f'(D_y = 4 mm), max|z| = {np.max(np.abs(ref.hysteretic_z)):.4f}, '
                  f'residual x = {ref.displacement_m[-1] * 1e3:+.2f} mm')
    walls = [w for w in walls if w > 0 and math.isfinite(w)]
    if walls:
        print(f'simulate wall time per run: median {np.median(walls):.2f} s, '
              f'max {max(walls):.2f} s')


if __name__ == '__main__':
    main()
