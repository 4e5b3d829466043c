"""The pre-test identification of a structure's rigs (issue 31): identify, then test.

``config/two_piers.yaml`` with each pier's specimen 15 % stiffer than the configuration
declares to its compensator (``predictor_stiffness_N_per_m`` = k / 1.15 in each rig's
section; the simulated pier is the configured one, as ``benchmarks/robust_compensation.py``
emulates a wrong model). The path a lab takes, as ``seft`` runs it:

1. the identification run: ``seft simulate CONFIG --predictor none --set excitation=noise
   --set excitation_band_hz=50 --duration 20 --bag`` (each rig alone, 100 N of noise;
   ``--id-duration``), without and with the benchmarks' sensor noise;
2. ``seft identify BAG --params FILE``: each pier's m, c, k against the true ones;
3. the structure test with ``predictor: model`` on each record (15 s at 1000 N): the
   worst displacement NRMS per DOF with the exact model, with the wrong declaration and with
   ``--params FILE`` of step 2.

Prints figures; asserts nothing. About 20 s (two records; more with --record).

Usage: .venv/bin/python benchmarks/identify_structure.py [--record default X.AT2 ...]
       [--duration 15] [--id-duration 20] [--stiffer 1.15]
"""

import argparse
from pathlib import Path
import tempfile
import time

import yaml

from seft_ros.analysis import rig_identification as ri
from seft_ros.analysis.identification_report import write_rig_params_yaml
from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.api import build_runs
from seft_ros.cli.config import ConfigLoader
from seft_ros.core.experiment import simulate

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / 'config' / 'two_piers.yaml'
RECORDS = ROOT / '..' / 'shared' / 'data' / 'ground_motions'
#: The benchmarks' sensor noise (benchmarks/robust_compensation.py).
NOISE = {'noise_force_N': 5.0, 'noise_displacement_m': 1e-5, 'noise_velocity_m_s': 1e-4,
         'noise_acceleration_m_s2': 0.05}
IDENTIFICATION = {'predictor': 'none', 'excitation': 'noise', 'excitation_band_hz': 50.0,
                  'duration_s': 20.0}


def declared_config(stiffer: float, folder: Path) -> Path:
    """two_piers.yaml with each pier's declared stiffness the true one over `stiffer`."""
    doc = yaml.load(CONFIG.read_text(), Loader=ConfigLoader)
    truth = {'pier_a': 2.11e5, 'pier_b': doc['rigs']['pier_b']['stiffness_N_per_m']}
    for rig, k in truth.items():
        doc['rigs'][rig]['predictor_stiffness_N_per_m'] = k / stiffer
    path = folder / 'two_piers_declared.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def identify(config: Path, noise: dict, out: Path, duration: float) -> tuple[Path, dict]:
    """Steps 1-2: the identification run, each pier's fit, and the parameter file."""
    run, = build_runs(config=str(config),
                      overrides=dict(IDENTIFICATION, duration_s=duration, **noise))
    rd = simulate(run)
    idents = ri.identify_rigs(rd)
    per_rig = ri.identified_rig_parameters(idents)
    print(f'\n== identification ({"with" if noise else "without"} sensor noise): '
          f'{duration:g} s of 100 N noise, 0.5-50 Hz, each rig alone')
    print(f'{"rig":8s}{"":4s}{"identified":>12s}{"std err":>10s}{"true":>12s}{"error %":>9s}'
          f'{"declared":>12s}')
    for ident in idents:
        fit, p = ident.specimen, ident.params
        for key, label in (('mass_kg', 'm'), ('damping_N_s_per_m', 'c'),
                           ('stiffness_N_per_m', 'k')):
            value = getattr(fit, key)
            true = float(p[key])
            se = fit.standard_errors[('mass_kg', 'damping_N_s_per_m',
                                      'stiffness_N_per_m').index(key)]
            declared = float(p[ri.SPECIMEN_PARAMETERS[key]]) or true
            print(f'{ident.rig:8s}{label:4s}{value:12.6g}{se:10.2g}{true:12.6g}'
                  f'{100 * (value / true - 1):9.3f}{declared:12.6g}')
        print(f'{ident.rig:8s}    {fit.verdict()}; delay {ident.figures["delay_ms"]:.2f} ms')
    path = out / f'identified{"_noise" if noise else ""}.yaml'
    return write_rig_params_yaml(per_rig, path), per_rig


def worst_per_dof(config: Path, record: str, duration: float, params_files=()) -> str:
    """Step 3: the structure test with model; per-DOF displacement NRMS [%]."""
    try:
        run, = build_runs(config=str(config), params_files=[str(p) for p in params_files],
                          overrides={'predictor': 'model', 'record': record,
                                     'duration_s': duration, 'amplitude_N': 1000.0})
        rd = simulate(run)
    except Exception as exc:  # a refused force-loop inverse is a figure here
        return f'refused: {str(exc)[:90]}'
    cmp = compare_run(rd)
    cells = ' '.join(f'{d.dof} {100 * d.displacement.nrms:6.2f}' for d in cmp.dofs)
    return cells + ('' if rd.stable else f'  ABORTED at {rd.unstable_at_s:.2f} s')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default_records = ['default'] + [str(RECORDS / n) for n in ('RSN6_IMPVALL.I_I-ELC180.AT2',)
                                     if (RECORDS / n).is_file()]
    parser.add_argument('--record', nargs='+', default=default_records)
    parser.add_argument('--duration', type=float, default=15.0)
    parser.add_argument('--id-duration', type=float, default=20.0,
                        help='length of the identification run [s] (default 20)')
    parser.add_argument('--stiffer', type=float, default=1.15,
                        help='true stiffness over the declared one (default 1.15)')
    args = parser.parse_args()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        declared = declared_config(args.stiffer, folder)
        files = {}
        for noise in ({}, NOISE):
            files['noise' if noise else 'clean'] = identify(declared, noise, folder,
                                                            args.id_duration)[0]
        print(f'\n== structure test, predictor model, {args.duration:g} s at 1000 N: '
              'displacement NRMS % per DOF (after removing the lag)')
        cases = (('exact model', CONFIG, ()),
                 (f'declared k/{args.stiffer:g}', declared, ()),
                 ('identified', declared, (files['clean'],)),
                 ('identified, sensor noise', declared, (files['noise'],)))
        for record in args.record:
            print(f'record {Path(record).name}')
            for label, config, params in cases:
                print(f'  {label:26s} {worst_per_dof(config, record, args.duration, params)}',
                      flush=True)
    print(f'\ntook {time.monotonic() - t0:.0f} s')


if __name__ == '__main__':
    main()
