"""How long ``seft rig-check`` takes on seft's rigs, and whether it passes them with no rerun
(issue 33).

Runs the whole check (four runs) as a user runs it, ``--repeats`` times per rig, the rigs
interleaved so that they share the host's load: the delay rig, the servohydraulic rig, the
servohydraulic rig through the UDP bridge with ``seft emulate-controller`` as the lab's
target, and the first pier of ``config/two_piers.yaml`` in its namespace. Prints, per run,
the wall time of the command, the checks passed and the runs the check ran again ("once
more": the checker heard the rig late, or a graph stalled), then per rig the median, min and
max. ``--src DIR`` runs the seft of another source tree (``git archive <commit> | tar -x -C
DIR``) the same way, for a baseline under the same load.

Usage: .venv/bin/python benchmarks/rig_check_time.py [--repeats 3] [--rigs delay,servo,...]
       [--src DIR] [--set NAME=VALUE ...]
Prints figures; asserts nothing.
"""

import argparse
import os
from pathlib import Path
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np

SEFT = Path(sys.executable).parent / 'seft'
ROOT = Path(__file__).resolve().parents[1]
RIGS = ('delay', 'servohydraulic', 'bridge', 'pier')


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _env(src: Path | None) -> dict:
    env = dict(os.environ)
    if src is not None:
        paths = [str(src / 'src' / p) for p in ('seft_ros', 'seft_plant_sim', 'seft_msgs_py')]
        env['PYTHONPATH'] = os.pathsep.join(paths + [env.get('PYTHONPATH', '')]).rstrip(':')
    return env


def _check(rig: str, out: Path, sets: list[str], env: dict) -> dict:
    """One rig-check of `rig`; its wall time, verdict line and reruns."""
    args = {'delay': ['--rig', 'delay'], 'servohydraulic': ['--rig', 'servohydraulic'],
            'pier': [str(ROOT / 'config' / 'two_piers.yaml'), '--rig-name', 'pier_a']}
    emulator = None
    if rig == 'bridge':
        bridge = ['--rig', 'servohydraulic', '--set', 'rig_interface=udp_bridge', '--set',
                  f'udp_controller_address=127.0.0.1:{_free_port()}']
        emulator = subprocess.Popen([str(SEFT), 'emulate-controller', *bridge, *sets],
                                    env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(2.0)           # it binds its socket (the PC waits for it anyway)
        argv = bridge
    else:
        argv = args[rig]
    start = time.monotonic()
    try:
        proc = subprocess.run([str(SEFT), 'rig-check', *argv, *sets, '--out', str(out)],
                              env=env, capture_output=True, text=True, timeout=600)
    finally:
        if emulator is not None:
            os.killpg(emulator.pid, signal.SIGINT)
            emulator.wait(timeout=20)
    wall = time.monotonic() - start
    verdict = next((line for line in proc.stdout.splitlines()
                    if re.match(r'rig-check( \w+)?: \d+ of \d+ checks', line)), '')
    failed = [line.split(':')[0][5:] for line in proc.stdout.splitlines()
              if line.startswith('FAIL ')]
    return {'wall_s': wall, 'verdict': verdict, 'failed': failed,
            'reruns': proc.stderr.count('; once more'), 'code': proc.returncode}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--rigs', default=','.join(RIGS),
                        help=f'some of {", ".join(RIGS)}')
    parser.add_argument('--src', type=Path, help="another source tree's seft (a baseline)")
    parser.add_argument('--set', dest='sets', action='append', default=[], metavar='N=V')
    args = parser.parse_args()
    rigs = [r for r in args.rigs.split(',') if r]
    sets = [w for s in args.sets for w in ('--set', s)]
    env = _env(args.src)
    print(f'load average {os.getloadavg()[0]:.2f} at the start; '
          f'{"seft of " + str(args.src) if args.src else "this tree"}')
    results = {r: [] for r in rigs}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for rig in rigs:
                r = _check(rig, Path(tmp) / f'{rig}-{i}', sets, env)
                results[rig].append(r)
                print(f'{rig:15s} run {i + 1}: {r["wall_s"]:5.1f} s, exit {r["code"]}, '
                      f'{r["reruns"]} reruns, failed: {", ".join(r["failed"]) or "none"}; '
                      f'load {os.getloadavg()[0]:.2f}', flush=True)
    print('rig              p50 [s]  min [s]  max [s]  passed  reruns')
    for rig, rs in results.items():
        w = np.array([r['wall_s'] for r in rs])
        print(f'{rig:15s}  {np.median(w):7.1f}  {w.min():7.1f}  {w.max():7.1f}  '
              f'{sum(r["code"] == 0 for r in rs)}/{len(rs)}  '
              f'{sum(r["reruns"] for r in rs)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
