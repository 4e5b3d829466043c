"""What late valve commands cost a test: the rig holding them or predicting them.

In real time the rig never waits: a command that has not arrived when it is due (the
controller's host stalled) is held (``realtime_late_command: hold``, a DAQ's zero-order hold)
or predicted from the commands received until it arrives (``predict``; the rig contract's
"A late command", :class:`seft_plant_sim.realtime.WallClockRig`). This replays late commands
in process on the real-time rig (``command_latency_s`` of
:func:`seft_ros.core.experiment.simulate`) with either rule and prints the worst NRMS of
displacement, the rigs' acceleration and the interface force, beside the run with every
command in time:

- given real-time bags (``seft run CONFIG --mode realtime``), each bag's own timing (its
  rigs' command arrivals, its controllers' stale steps as far behind as they were:
  :func:`seft_ros.analysis.timing_replay.replay_timing`), and the bag's own NRMS;
- without bags, a synthetic pattern on `--config` (``model``): on each rig one command every
  ``--every`` steps late by 1.5 sample periods, and every ``--burst-every`` steps a host
  stall of ``--burst`` commands that arrive together (the rigs offset by a third of
  ``--every``).

No ROS; deterministic (it times nothing). Asserts nothing.

Usage: .venv/bin/python benchmarks/late_commands.py [--config config/two_piers.yaml]
       [--alpha A] [--every 37] [--burst 5] [--burst-every 1000] [BAG ...]
"""

import argparse
from pathlib import Path
import sys

from seft_msgs_py.errors import SeftError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.findings import replay_cell
from seft_ros.analysis.timing_replay import replay_timing, worst_nrms
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate

ROOT = Path(__file__).resolve().parents[1]


def synthetic_latency(names, n: int, dt: float, every: int, burst: int,
                      burst_every: int) -> dict:
    """Rig -> step -> loop latency [s]: in time (0.5 ms) but for the pattern (module
    notes)."""
    out = {}
    for i, rig in enumerate(names):
        lat = {}
        offset = 20 + i * max(1, every // 3)
        for k in range(offset, n, every):
            lat[k] = 2.5 * dt                       # misses its tick by 1.5 periods
        for start in range(burst_every // 2 + i * 7, n - burst, burst_every):
            for j in range(burst):                  # a stall: they arrive together
                lat[start + j] = (burst - j) * dt + 0.5 * dt
        out[rig] = lat
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bags', nargs='*', type=Path, help='real-time bags')
    parser.add_argument('--config', type=Path, default=ROOT / 'config' / 'two_piers.yaml')
    parser.add_argument('--every', type=int, default=37,
                        help='one late command every this many steps per rig (synthetic)')
    parser.add_argument('--burst', type=int, default=5,
                        help='commands late together in a stall (synthetic)')
    parser.add_argument('--burst-every', type=int, default=1000,
                        help='a stall every this many steps (synthetic)')
    parser.add_argument('--alpha', type=float, default=None,
                        help="the configuration's run of this alpha (synthetic; default: "
                             'its first model run)')
    args = parser.parse_args(argv)
    print('worst NRMS x / a / f [%]')
    try:
        if args.bags:
            for bag in args.bags:
                run = read_run(bag)
                # replayed holding, the replay also gives the run with the rig predicting
                run.params['realtime_late_command'] = 'hold'
                r = replay_timing(run)
                if r is None:
                    print(f"{bag}: not a real-time run of seft's simulated rigs")
                    continue
                print(f"{bag}: {sum(r['late_commands'].values())} late commands, "
                      f"{sum(r['stale_steps'].values())} stale steps")
                print(f"  recorded         {replay_cell(r['recorded'])}")
                print(f"  replayed, hold   {replay_cell(r['as_run'])}")
                print(f"  replayed, predict {replay_cell(r.get('predicting', r['as_run']))}")
                print(f"  in time          {replay_cell(r['in_time'])}")
            return 0
        runs = [p for p in expand_runs(load_config(args.config))
                if p.get('predictor') == 'model'
                and (args.alpha is None or p.get('alpha') == args.alpha)]
        if not runs:
            raise SeftError(f'{args.config}: no model run'
                            + (f' of alpha {args.alpha:g}' if args.alpha is not None else ''))
        params = runs[0]
        in_time = simulate(params)
        names = in_time.rig_names
        latency = synthetic_latency(names, in_time.n_steps, float(params['dt']), args.every,
                                    args.burst, args.burst_every)
        late = sum(len(v) for v in latency.values())
        print(f'{args.config.name}, model, {in_time.n_steps} steps, rigs '
              f"{', '.join(n or 'the study' for n in names)}: {late} late commands")
        print(f'  in time (lockstep) {replay_cell(worst_nrms(in_time))}')
        for rule in ('hold', 'predict'):
            run = simulate(dict(params, realtime_late_command=rule), command_latency_s=latency)
            print(f'  {rule:7s}            {replay_cell(worst_nrms(run))}')
    except SeftError as exc:
        print(f'late_commands: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
