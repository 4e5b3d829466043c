"""Force control and compensation of a yielding member (issue 10): the target table.

For the Bouc-Wen member (``specimen_model='bouc_wen'``; the rig's defaults: k = 2.11e5 N/m
initial, D_y = 4 mm, post-yield ratio 0.1, n = 2, beta = gamma = 0.5, or others with --set)
on the embedded record at 1000 N and on any PEER ``.AT2`` given with --record, runs
``simulate`` for each mass ratio and each configuration below and prints the displacement
NRMS against the nonlinear reference (scipy's solve_ivp of the whole structure, computed once
per record and alpha), after removing the lag and, second, with each signal's drift removed
too, the peak-displacement ratio test/reference, and whether the run was stable.

Configurations (force controller / compensator):

* servohydraulic rig: the study's ``loop_shaping`` uncompensated, with ``model`` (elastic) and
  with ``model`` + the measured restoring force; ``tangent_loop_shaping`` uncompensated and
  with ``model`` + the ``hysteretic`` member model (the recommendation);
* pure-delay rig: ``none``, ``model``, ``model`` + measured, ``model`` + hysteretic;
* the linear specimen, servohydraulic rig: ``loop_shaping`` against ``tangent_loop_shaping``
  with ``none`` and ``model`` (the recommended controller must not make it worse).

Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/nonlinear_specimen.py [--record default X.AT2 ...]
       [--alpha 0 0.5 1 1.5 2] [--duration 20] [--noise] [--set NAME=VALUE ...]
"""

import argparse
import time

from seft_msgs_py.errors import InputError, ParameterError
from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.reference import reference_from_run
from seft_ros.core.experiment import simulate

#: The benchmarks' sensor noise (benchmarks/robust_compensation.py).
NOISE = {'noise_force_N': 5.0, 'noise_displacement_m': 1e-5, 'noise_velocity_m_s': 1e-4,
         'noise_acceleration_m_s2': 0.05}
LOOP, TANGENT = {'force_controller': 'loop_shaping'}, {'force_controller': 'tangent_loop_shaping'}
MEASURED = {'predictor': 'model', 'predictor_restoring_force': 'measured'}
HYSTERETIC = {'predictor': 'model', 'predictor_restoring_force': 'hysteretic'}
#: (label, rig, specimen, options)
CONFIGURATIONS = (
    ('loop_shaping / none', 'servohydraulic', 'bouc_wen', dict(LOOP, predictor='none')),
    ('loop_shaping / model', 'servohydraulic', 'bouc_wen', dict(LOOP, predictor='model')),
    ('loop_shaping / model+measured', 'servohydraulic', 'bouc_wen', dict(LOOP, **MEASURED)),
    ('tangent / none', 'servohydraulic', 'bouc_wen', dict(TANGENT, predictor='none')),
    ('tangent / model+hysteretic', 'servohydraulic', 'bouc_wen', dict(TANGENT, **HYSTERETIC)),
    ('delay / none', 'delay', 'bouc_wen', {'predictor': 'none'}),
    ('delay / model', 'delay', 'bouc_wen', {'predictor': 'model'}),
    ('delay / model+measured', 'delay', 'bouc_wen', MEASURED),
    ('delay / model+hysteretic', 'delay', 'bouc_wen', HYSTERETIC),
    ('linear: loop_shaping / none', 'servohydraulic', 'linear', dict(LOOP, predictor='none')),
    ('linear: tangent / none', 'servohydraulic', 'linear', dict(TANGENT, predictor='none')),
    ('linear: loop_shaping / model', 'servohydraulic', 'linear', dict(LOOP, predictor='model')),
    ('linear: tangent / model', 'servohydraulic', 'linear', dict(TANGENT, predictor='model')),
)


def cell(params, references):
    """One run: its figures as text, the reference reused per (record, alpha, specimen)."""
    try:
        run = simulate(params)
    except (ParameterError, InputError) as exc:
        return f'error: {exc}'
    key = (params.get('record'), params['alpha'], params['specimen_model'])
    ref = references.get(key)
    if ref is None or ref.n_steps < run.n_steps:
        ref = references[key] = reference_from_run(run)
    if run.n_steps < 20:
        return f'aborted at {run.unstable_at_s:.2f} s'
    cmp = compare_run(run, ref)
    text = (f'{cmp.signal("displacement").nrms * 100:6.2f} '
            f'{cmp.residual.nrms_residual_removed * 100:6.2f} '
            f'{cmp.signal("displacement").peak_ratio:5.2f}')
    if not run.stable:
        text += f'  stopped at {run.unstable_at_s:.2f} s: {(run.abort_reason or "")[:40]}'
    return text


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--record', nargs='+', default=['default'],
                        help="'default' or PEER .AT2 paths")
    parser.add_argument('--alpha', type=float, nargs='+', default=[0.0, 0.5, 1.0, 1.5, 2.0])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='run length after time scaling [s] (0: the whole record)')
    parser.add_argument('--noise', action='store_true', help='with the sensor noise of '
                        'benchmarks/robust_compensation.py')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='another parameter (e.g. yield_displacement_m=0.006)')
    args = parser.parse_args()
    extra = {}
    for item in args.set:
        name, _, value = item.partition('=')
        extra[name] = float(value) if value.replace('.', '', 1).replace('e-', '', 1).isdigit() \
            else value
    print('cells: displacement NRMS [%] after removing the lag | the same with the drift '
          'removed [%] | peak ratio test/reference')
    t0 = time.monotonic()
    for record in args.record:
        references = {}
        print(f'\n== record {record}, 1000 N, time scale 0.5, {args.duration:g} s'
              + (', sensor noise' if args.noise else '')
              + ''.join(f', {k}={v}' for k, v in extra.items()))
        print(f'{"force controller / compensator":32s}' + ''.join(
            f'  alpha = {a:<18g}' for a in args.alpha))
        for label, rig, specimen, opts in CONFIGURATIONS:
            cells = []
            for alpha in args.alpha:
                params = {'rig_model': rig, 'specimen_model': specimen, 'alpha': alpha,
                          'amplitude_N': 1000.0, 'duration_s': args.duration, **opts,
                          **extra}
                if record != 'default':
                    params['record'] = record
                if args.noise:
                    params.update(NOISE)
                cells.append(cell(params, references))
            print(f'{label:32s}' + ''.join(f'  {c:27s}' for c in cells), flush=True)
    print(f'\n{time.monotonic() - t0:.0f} s')


if __name__ == '__main__':
    main()
