"""Throughput of the lockstep node graph and of the one-process simulation.

Runs ``seft run`` (five node processes over DDS, recorder included) on the default record for
a few seconds of simulated time, several times, and ``simulate()`` likewise, and prints the
median steps per second and the ratio to real time (500 steps/s at dt = 2 ms), and the
recorder's CPU time per step (user + system of its process, read from ``/proc`` every 0.1 s
while it runs, so its last 0.1 s are missing). The machine is shared and noisy: quote
medians. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/graph_throughput.py [--repeat 3] [--duration 10]
"""

import argparse
import json
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

from seft_ros.core.experiment import simulate


def _cpu_s(marker: str) -> float | None:
    """User + system CPU time [s] of the running recorder whose command line holds
    `marker` (None: not running)."""
    for pid in os.listdir('/proc'):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
            if 'seft_ros.nodes.recorder' not in cmd or marker not in cmd:
                continue
            stat = Path(f'/proc/{pid}/stat').read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(')') + 2:].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    return None


def graph_once(duration: float, out: Path) -> tuple[float, float, float]:
    """Return (stepping rate [steps/s], whole command wall time [s], recorder CPU per step
    [s])."""
    seft = Path(sys.executable).parent / 'seft'
    # no ROS_DOMAIN_ID of its own: seft run claims a free domain (seft_msgs_py.domain), the
    # rule of the tests and of every run, so that concurrent runs never meet
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    t0 = time.monotonic()
    proc = subprocess.Popen([str(seft), 'run', '--alpha', '0.5', '--duration', str(duration),
                             '--out', str(out)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    recorder_cpu = 0.0
    while proc.poll() is None:
        time.sleep(0.1)
        cpu = _cpu_s(str(out))
        recorder_cpu = cpu if cpu is not None else recorder_cpu
    _, stderr = proc.communicate()
    proc.stderr = stderr
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    steps = json.loads((out / 'summary.json').read_text())['runs'][0]
    n = int(round(duration / 0.002))
    # the rig's progress: 'N steps in W s wall' includes start-up; use the log line
    line = [ln for ln in proc.stderr.splitlines() if 'steps in' in ln][-1]
    run_wall = float(line.split('steps in ')[1].split(' s wall')[0])
    graph_up = [ln for ln in proc.stderr.splitlines() if 'graph up in' in ln][-1]
    startup = float(graph_up.split('graph up in ')[1].split(' s')[0])
    assert steps['stable']
    return n / max(run_wall - startup, 1e-9), wall, recorder_cpu / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--duration', type=float, default=10.0)
    args = ap.parse_args()
    rates, walls, cpus = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            rate, wall, cpu = graph_once(args.duration, Path(tmp) / f'r{i}')
            rates.append(rate)
            cpus.append(cpu)
            walls.append(wall)
    sim = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        run = simulate({'alpha': 0.5, 'duration_s': args.duration})
        sim.append(run.n_steps / (time.perf_counter() - t0))
    med = statistics.median(rates)
    print(f'node graph (lockstep, 5 processes + recorder): median {med:.0f} steps/s '
          f'({med / 500:.2f}x real time at dt = 2 ms), runs {[round(r) for r in rates]}')
    print(f'recorder CPU: median {1e6 * statistics.median(cpus):.0f} us/step, runs '
          f'{[round(1e6 * c) for c in cpus]}')
    print(f'seft run wall time for {args.duration:g} s of record: median '
          f'{statistics.median(walls):.1f} s (start-up, stepping, bag read-back, report)')
    ms = statistics.median(sim)
    print(f'simulate (one process): median {ms:.0f} steps/s ({1e6 / ms:.1f} us/step), '
          f'{ms / med:.0f}x the node graph')


if __name__ == '__main__':
    main()
