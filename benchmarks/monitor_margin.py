"""Margin of the online instability monitor: stable runs vs unstable runs.

For each record (the synthetic default and, when present, the PEER records in
../shared/data/ground_motions/) and each linear rig, runs ``seft simulate`` with the monitor
in observe-only mode (threshold 0, interlock and limits off) and prints the largest monitor
ratio ``r_hf / (r_lf + 0.05 F_g + floor)`` reached. The uncompensated stability boundary is
alpha = 1 on the delay rig (neutral-type loop) and 1.317 on the servohydraulic rig, so
alpha <= 0.5 / <= 1.2 are stable and alpha >= 1.5 unstable. The default threshold (1.0) must
lie between the two groups. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/monitor_margin.py
"""

from pathlib import Path

import numpy as np

from seft_ros.core.experiment import simulate
from seft_ros.core.monitor import InstabilityMonitor

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'ground_motions'
STABLE = {'delay': (0.0, 0.5, 0.9), 'servohydraulic': (0.0, 0.5, 1.0, 1.2)}
UNSTABLE = {'delay': (1.5, 2.0), 'servohydraulic': (1.5, 2.0)}
OBSERVE = {'monitor_threshold': 0.0, 'saturation_abort_fraction': 1.0, 'force_limit_N': 1e12,
           'stroke_limit_m': 1e6, 'duration_s': 20.0}


def max_ratio(params) -> float:
    run = simulate(params)
    mon = InstabilityMonitor(run.params['dt'])
    m, alpha = run.params['mass_kg'], run.params['alpha']
    ratios = []
    for f, g, t in zip(run.measured_force_N, run.ground_acceleration_m_s2, run.time_s):
        if not np.isfinite(f):
            break
        mon.update(f, -(1 + alpha) * m * g, t)
        ratios.append(mon.ratio)
    return float(np.max(ratios))


def main() -> None:
    records = {'default': 'default'}
    if SHARED.is_dir():
        records.update({p.stem: str(p) for p in sorted(SHARED.glob('*.AT2'))})
    worst_stable, best_unstable = 0.0, np.inf
    print(f'{"record":32s} {"rig":15s} {"alpha":>5s} {"max ratio":>10s}')
    for name, rec in records.items():
        for rig in ('delay', 'servohydraulic'):
            for alpha in STABLE[rig] + UNSTABLE[rig]:
                r = max_ratio(dict(OBSERVE, record=rec, rig_model=rig, alpha=alpha))
                if alpha in STABLE[rig]:
                    worst_stable = max(worst_stable, r)
                else:
                    best_unstable = min(best_unstable, r)
                print(f'{name:32s} {rig:15s} {alpha:5.2f} {r:10.3f}')
    print(f'largest ratio of a stable run: {worst_stable:.3f}; smallest of an unstable run: '
          f'{best_unstable:.3f}; default threshold 1.0')


if __name__ == '__main__':
    main()
