"""Robust delay compensation: `model` against `adaptive` and `ats` with a wrong model.

Run: ``.venv/bin/python benchmarks/robust_compensation.py [--quick] [--plot PNG]``
(about 6 minutes; ``--quick``: the delay rig only).

Prints, for the embedded record (amplitude and time scale as configured by default), with
sensor noise on (the noise set of ``benchmarks/compensation_targets.py``; the parameters'
defaults are noise-free), the displacement NRMS after removing the lag for every
predictor x error case x alpha x rig. The error cases are the predictor's m, c, k and tau
(delay rig only; on the servohydraulic rig the loop delay is the inverse's) each +/-10 %,
and all of them +/-10 % together; on the servohydraulic rig also `adaptive` with the force
loop identified from data (``adaptive_loop: data``). Then the convergence of the `adaptive`
estimates (all +10 % wrong at the start) on both rigs and on Kobe KJM000 when present, and with
``--plot`` a figure of the estimates over a run.
"""

import argparse
from pathlib import Path
import time

import numpy as np

from seft_ros.analysis.metrics import compare_run
from seft_ros.analysis.report import plot_estimates
from seft_ros.core.experiment import simulate

KOBE = Path(__file__).resolve().parents[1] / '..' / 'shared' / 'data' / 'ground_motions' \
    / 'RSN1106_KOBE_KJM000.AT2'
NOISE = {'noise_force_N': 5.0, 'noise_displacement_m': 1e-5, 'noise_velocity_m_s': 1e-4,
         'noise_acceleration_m_s2': 0.05}
M, C, K, TAU = 52.7, 17.14 * 52.7, 2.11e5, 0.01
TRUTH = {'mass_kg': M, 'damping_N_s_per_m': C, 'stiffness_N_per_m': K}
KEYS = {'m': 'predictor_mass_kg', 'c': 'predictor_damping_N_s_per_m',
        'k': 'predictor_stiffness_N_per_m', 'tau': 'predictor_tau_s'}
ALPHAS = (0.5, 1.0, 1.5, 2.0)
PREDICTORS = ('model', 'adaptive', 'ats')
#: Extra rows of the servohydraulic rig: `adaptive` with the force loop identified from data.
VARIANTS = {'adaptive/data': ('adaptive', {'adaptive_loop': 'data'})}


def cases(rig: str) -> list[tuple[str, dict]]:
    """(label, predictor_* overrides) of the error cases."""
    names = ('m', 'c', 'k', 'tau') if rig == 'delay' else ('m', 'c', 'k')
    truth = {'m': M, 'c': C, 'k': K, 'tau': TAU}
    out = [('exact', {})]
    for name in names:
        for sign in (+1, -1):
            out.append((f'{name} {sign * 10:+d} %', {KEYS[name]: truth[name] * (1 + 0.1 * sign)}))
    for sign in (+1, -1):
        out.append((f'all {sign * 10:+d} %', {KEYS[n]: truth[n] * (1 + 0.1 * sign)
                                               for n in names}))
    return out


def nrms(params) -> tuple[float, bool]:
    """Displacement NRMS [%] after removing the lag, and whether the run stayed stable."""
    rd = simulate(params)
    return 100.0 * compare_run(rd).displacement.nrms, rd.stable


def table(rig: str, base: dict) -> dict:
    """Print and return ``{(predictor, case): [nrms per alpha]}``."""
    print(f'\n== {rig} rig, sensor noise on (displacement NRMS %, U = aborted)')
    print('predictor case'.ljust(24) + ''.join(f'a={a:<7g}' for a in ALPHAS) + 'worst')
    out = {}
    rows = [(p, p, {}) for p in PREDICTORS]
    if rig == 'servohydraulic':
        rows += [(name, p, opts) for name, (p, opts) in VARIANTS.items()]
    for pred, predictor, opts in rows:
        for label, extra in cases(rig):
            row = [nrms(dict(base, rig_model=rig, predictor=predictor, alpha=a, **NOISE,
                             **opts, **extra)) for a in ALPHAS]
            out[pred, label] = row
            cells = ''.join(f'{e:6.2f}{"U" if not s else " "} ' for e, s in row)
            worst = max(e if s else float('inf') for e, s in row)
            print(f'{pred:14s}{label:10s}' + cells + f'{worst:6.2f}', flush=True)
    return out


def convergence(rig: str, base: dict, label: str) -> None:
    """Error of the `adaptive` estimates over time, all +10 % wrong at the start."""
    wrong = {KEYS['m']: 1.1 * M, KEYS['c']: 1.1 * C, KEYS['k']: 1.1 * K}
    if rig == 'delay':
        wrong[KEYS['tau']] = 1.1 * TAU
    rd = simulate(dict(base, rig_model=rig, predictor='adaptive', alpha=1.0, **NOISE, **wrong))
    f = rd.measured_force_N
    window = max(1, int(round(0.5 / float(rd.params['dt']))))
    rms = np.sqrt(np.convolve(f * f, np.ones(window) / window, mode='same'))
    strong = float(rd.time_s[np.argmax(rms > 100.0)])
    truth = dict(TRUTH, tau_s=TAU)
    print(f'\n== adaptive estimates, {label} (alpha = 1, all +10 % at the start; '
          f'strong motion from {strong:.2f} s)')
    for t in (0.5, 1.0, 2.0, 3.0, 5.0, rd.time_s[-1]):
        i = min(int(round(t / float(rd.params['dt']))), rd.n_steps - 1)
        errs = '  '.join(f'{name} {100 * (rd.estimates[name][i] / truth[name] - 1):+6.2f} %'
                         for name in ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m')
                         + (('tau_s',) if rig == 'delay' else ()))
        print(f't = {t:5.2f} s  {errs}')
    after = strong + 2.0
    i = int(round(after / float(rd.params['dt'])))
    if i < rd.n_steps:
        worst = max(abs(rd.estimates[n][i:] / truth[n] - 1).max()
                    for n in ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'))
        print(f'largest m, c, k error after {after:.2f} s (2 s of strong motion): '
              f'{100 * worst:.2f} %')
    return rd


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='delay rig only')
    parser.add_argument('--plot', help='write the estimates of the delay-rig run to this PNG')
    args = parser.parse_args()
    t0 = time.monotonic()
    table('delay', {})
    rd = convergence('delay', {}, 'delay rig, default record')
    if args.plot:
        plot_estimates(rd, args.plot, title="'adaptive' on the delay rig, alpha = 1, "
                       'model +10 % wrong, sensor noise')
    if not args.quick:
        table('servohydraulic', {})
        convergence('servohydraulic', {}, 'servohydraulic rig, default record')
        if KOBE.exists():
            kobe = {'record': str(KOBE.resolve()), 'amplitude_N': 1000.0, 'time_scale': 0.5,
                    'duration_s': 20.0}
            convergence('delay', kobe, 'delay rig, Kobe KJM000')
    print(f'\n{time.monotonic() - t0:.0f} s')


if __name__ == '__main__':
    main()
