"""A yielding computational part (issue 40): the accuracy targets, on records no configuration
names.

* **The three-story shear frame** (``config/opensees/shear_frame.yaml``: story 1 the specimen,
  story 2 ``Steel01`` with post-yield ratio 0.02, story 3 elastic): for each --record and each
  --ductility, the yield force of story 2 that gives that drift ductility (peak drift over
  yield drift) in OpenSees' analysis of the whole frame (bisection on the reference alone),
  then the test with each --predictor; printed: the yield force, the ductility reached, the
  displacement NRMS per floor (target: <= 3 % to ductility 2.5, <= 5 % to 6), the acceleration
  NRMS per floor; with --initial also each run predicted with the initial linearization
  (``prediction: initial``, what the compensators did before issue 40). For each case also
  how far the reference itself moves with the record scaled by 1 +- 1 % (NRMS x per floor):
  the case's sensitivity, by which a yielding frame amplifies any error of the test.
* **The steel frame** (``config/opensees/steel_frame.yaml``) at each --amplitude, or with
  --moment-ratio at the amplitude whose reference reaches each ratio on each record
  (bisection on the reference alone, 14 steps): the largest moment of column 111 over its
  first-yield moment in the reference and the displacement NRMS per floor (target: <= 3 % at
  M/My 1.28-1.35).

Prints figures; asserts nothing. Records: PEER .AT2 paths (the development records of
/work/shared/data/ground_motions, never committed) or 'default'.

Usage: .venv/bin/python benchmarks/opensees_yielding.py --record default X.AT2 ...
       [--ductility 2.5 6] [--predictor model adaptive] [--amplitude 2000 2600]
       [--moment-ratio 1.28 1.35] [--initial] [--skip-shear] [--skip-steel]
       [--step deferred] [--duration-s 20]
"""

import argparse
import os
from pathlib import Path
import tempfile
import time

import numpy as np
import yaml

from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import run_reference
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import prepared_record
from seft_ros.core.models import model_plugin
from seft_ros.core.structure import test_setup

ROOT = Path(__file__).resolve().parents[1]
SHEAR = ROOT / 'config' / 'opensees' / 'shear_frame.yaml'
STEEL = ROOT / 'config' / 'opensees' / 'steel_frame.yaml'
#: Story 2's initial stiffness in shear_frame.py [N/m].
STORY_STIFFNESS_N_PER_M = 2.11e5
#: First-yield moment of the steel frame's 40 x 12 mm S690 column [N m].
COLUMN_MY_N_M = 690e6 * 0.012 * 0.040 ** 2 / 6.0


#: More arguments of the shear frame's model (``--gradual``: story 2 ``Steel02``).
SHEAR_ARGUMENTS: dict = {}
#: The models' ``step`` (``--step``; None: the configuration's) and the runs' duration
#: (``--duration-s``; None: the record's).
RUN_OPTIONS = {'step': None, 'duration_s': None}


def _params(path: Path, directory: Path, *, arguments=None, prediction=None, **overrides):
    """A run's parameters from `path` with the model's arguments and prediction changed
    (and :data:`RUN_OPTIONS`)."""
    doc = yaml.safe_load(path.read_text())
    model = doc['structure']['opensees']
    model['model'] = str(path.parent / model['model'])
    if RUN_OPTIONS['step']:
        model['step'] = RUN_OPTIONS['step']
    if RUN_OPTIONS['duration_s']:
        overrides.setdefault('duration_s', RUN_OPTIONS['duration_s'])
    if arguments:
        model['arguments'] = dict(model.get('arguments') or {}, **arguments)
    if prediction:
        model['prediction'] = prediction
    out = directory / f'{path.stem}.yaml'
    out.write_text(yaml.safe_dump(doc))
    return expand_runs(dict(load_config(out), **overrides))[0]


def _ductility(params) -> float:
    """Story 2's peak drift over its yield drift in OpenSees' analysis of the whole frame."""
    setup = test_setup(params)
    ag = prepared_record(params).acceleration_m_s2
    ref = model_plugin('opensees').reference(setup.substructures, float(params['dt']), ag)
    drift = ref.displacement_m[:, 1] - ref.displacement_m[:, 0]
    fy = float(yaml.safe_load(params['structure'])['opensees']['arguments']['fy2_N'])
    return float(np.max(np.abs(drift))) / (fy / STORY_STIFFNESS_N_PER_M)


def _yield_force_for(record: str, ductility: float, directory: Path) -> tuple[float, float]:
    """Story 2's yield force [N] that gives `ductility` on `record` (bisection, 1e-3)."""
    low, high = 100.0, 50_000.0                     # ductility falls as fy grows
    for _ in range(20):
        mid = (low * high) ** 0.5
        mu = _ductility(_params(SHEAR, directory, arguments={'fy2_N': mid, **SHEAR_ARGUMENTS},
                                record=record))
        if mu > ductility:
            low = mid
        else:
            high = mid
    fy = (low * high) ** 0.5
    return fy, _ductility(_params(SHEAR, directory, arguments={'fy2_N': fy, **SHEAR_ARGUMENTS},
                                  record=record))


def _pct(values) -> str:
    return ' / '.join(f'{100 * v:5.2f}' for v in values)


def _run(params):
    t0 = time.monotonic()
    run = simulate(params)
    comparison = compare_run(run)
    return run, comparison, time.monotonic() - t0


def _sensitivity(params, change: float = 0.01) -> np.ndarray:
    """How much OpenSees' analysis of the whole frame moves when the record is scaled by
    ``1 +- change``: each floor's NRMS x between the scaled and the unscaled analysis, the
    mean of the two [-] (n,). 1 % per 1 % for a linear frame; a yielding one's residual
    drifts can move several times more: the test's own errors (its floor-1 tracking, about
    1 % NRMS) are amplified as much."""
    setup = test_setup(params)
    ag = prepared_record(params).acceleration_m_s2
    plugin, dt = model_plugin('opensees'), float(params['dt'])
    base = plugin.reference(setup.substructures, dt, ag).displacement_m
    moved = []
    for scale in (1.0 + change, 1.0 - change):
        x = plugin.reference(setup.substructures, dt, scale * ag).displacement_m
        moved.append(np.sqrt(np.mean((x - base) ** 2, axis=0) / np.mean(base ** 2, axis=0)))
    return 0.5 * (moved[0] + moved[1])


def shear_frame(records, ductilities, predictors, initial: bool, directory: Path,
                yield_forces=()) -> None:
    for record in records:
        name = Path(record).name
        cases = ([(fy, _ductility(_params(SHEAR, directory, record=record,
                                          arguments={'fy2_N': fy, **SHEAR_ARGUMENTS})))
                  for fy in yield_forces] if yield_forces else
                 [_yield_force_for(record, ductility, directory) for ductility in ductilities])
        for fy, reached in cases:
            arguments = {'fy2_N': fy, **SHEAR_ARGUMENTS}
            moved = _sensitivity(_params(SHEAR, directory, arguments=arguments, record=record))
            print(f'shear_frame {name} ductility {reached:4.2f} (fy2 {fy:7.1f} N): the '
                  f'reference with the record scaled by 1 +- 1 % moves by NRMS x per floor '
                  f'[%] {_pct(moved)}', flush=True)
            for predictor in predictors:
                for prediction in ('tangent',) + (('initial',) if initial else ()):
                    params = _params(SHEAR, directory, arguments=arguments,
                                     prediction=prediction, record=record, predictor=predictor)
                    run, c, wall = _run(params)
                    print(f'shear_frame {name} ductility {reached:4.2f} (fy2 {fy:7.1f} N) '
                          f'{predictor:8s} {prediction:7s}: stable {run.stable}, NRMS x per floor '
                          f'[%] {_pct([d.displacement.nrms for d in c.dofs])}, a '
                          f'{_pct([d.acceleration.nrms for d in c.dofs])} ({wall:.0f} s)',
                          flush=True)


def _column_ratio(ref) -> float:
    """Column 111's largest end moment over its first-yield moment in a reference of the
    steel frame (its ``element_forces``)."""
    return float(np.max(np.abs(ref.element_forces[111]))) / COLUMN_MY_N_M


def _moment_ratio(params) -> float:
    """:func:`_column_ratio` of OpenSees' analysis of the whole steel frame."""
    setup = test_setup(params)
    ag = prepared_record(params).acceleration_m_s2
    return _column_ratio(model_plugin('opensees').reference(setup.substructures,
                                                            float(params['dt']), ag))


def _amplitude_for(record: str, ratio: float, directory: Path) -> float:
    """The amplitude [N] whose reference reaches column 111's M/My `ratio` on `record`
    (bisection of log amplitude over 500-20000 N, 14 steps: within 0.02 %)."""
    low, high = 500.0, 20_000.0                      # the ratio grows with the amplitude
    for _ in range(14):
        mid = (low * high) ** 0.5
        if _moment_ratio(_params(STEEL, directory, record=record, amplitude_N=mid)) < ratio:
            low = mid
        else:
            high = mid
    return (low * high) ** 0.5


def steel_frame(records, amplitudes, predictors, directory: Path, ratios=()) -> None:
    for record in records:
        name = Path(record).name
        for amplitude in list(amplitudes) + [_amplitude_for(record, r, directory)
                                             for r in ratios]:
            for predictor in predictors:
                params = _params(STEEL, directory, record=record, amplitude_N=amplitude,
                                 predictor=predictor)
                run, c, wall = _run(params)
                ref = run_reference(run)
                ratio = _column_ratio(ref)
                print(f'steel_frame {name} {amplitude:.0f} N {predictor:8s}: column M/My '
                      f'{ratio:.2f}, stable {run.stable}, NRMS x per floor [%] '
                      f'{_pct([d.displacement.nrms for d in c.dofs])}, a '
                      f'{_pct([d.acceleration.nrms for d in c.dofs])} ({wall:.0f} s)', flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--record', nargs='+', default=['default'])
    ap.add_argument('--ductility', nargs='+', type=float, default=[2.5, 6.0])
    ap.add_argument('--predictor', nargs='+', default=['model', 'adaptive'])
    ap.add_argument('--amplitude', nargs='*', type=float, default=[2000.0, 2600.0])
    ap.add_argument('--moment-ratio', nargs='*', type=float, default=[],
                    help='steel frame: also at the amplitudes whose reference reaches these '
                         'column M/My on each record (e.g. 1.28 1.35)')
    ap.add_argument('--initial', action='store_true',
                    help="also predict with the initial linearization ('prediction: initial')")
    ap.add_argument('--yield-force', nargs='*', type=float, default=[],
                    help="shear frame: story 2's yield forces [N] in place of the "
                         "ductilities'")
    ap.add_argument('--gradual', action='store_true',
                    help='shear frame: story 2 Steel02 (yields gradually) in place of Steel01')
    ap.add_argument('--skip-shear', action='store_true')
    ap.add_argument('--skip-steel', action='store_true')
    ap.add_argument('--step', choices=('immediate', 'deferred'),
                    help="the models' step (structure.opensees.step; default: the config's)")
    ap.add_argument('--duration-s', type=float, help="the runs' duration (default: the record)")
    args = ap.parse_args()
    RUN_OPTIONS.update(step=args.step, duration_s=args.duration_s)
    if args.gradual:
        SHEAR_ARGUMENTS['gradual'] = True
    print(f'load average {os.getloadavg()[0]:.1f}', flush=True)
    with tempfile.TemporaryDirectory(prefix='seft-yielding-') as tmp:
        if not args.skip_shear:
            shear_frame(args.record, args.ductility, args.predictor, args.initial, Path(tmp),
                        args.yield_force)
        if not args.skip_steel:
            steel_frame(args.record, args.amplitude, args.predictor, Path(tmp),
                        args.moment_ratio)
    print(f'load average {os.getloadavg()[0]:.1f}', flush=True)


if __name__ == '__main__':
    main()
