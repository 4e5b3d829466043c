"""Real-time mode benchmark: the whole graph (four nodes and the recorder) on the wall clock.

Runs ``seft run --mode realtime`` on the servohydraulic rig for DURATION seconds at 500 Hz and
at 1 kHz and prints, per rate, the figures below. alpha = 0 (no feedback) and the instability
monitor off, so that a timing glitch cannot end the run; the default record at 400 N,
time-scaled to last the run. Per rate:
loop latency and rig period jitter (p50 / p99 / max), missed deadlines and stale commands
(fractions of the rig's ticks), messages lost by the bag, and the CPU each node used (from
/proc, as a fraction of one core over the node's life). The machine's load average is printed
before and after, and before each run the scheduling latency of the bare machine: a
SCHED_FIFO sleep loop at the same rate for 5 s (what no node can do better than). On a shared
2-core machine, quote medians over repeats.

Usage: .venv/bin/python benchmarks/realtime_graph.py [--duration 60] [--rates 500 1000]
       [--repeats 1] [--set NAME=VALUE ...]
Prints figures; asserts nothing (targets: 500 Hz missed < 1 %, loop latency p50 < 1.5 ms and
p99 < 5 ms; 1 kHz missed < 5 %).
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEFT = Path(sys.executable).parent / 'seft'
NODES = ('recorder', 'ground_motion_publisher', 'reference_force_builder',
         'force_servo_controller', 'rig_node')
TICKS = os.sysconf('SC_CLK_TCK')


def _cpu_watch(marker: str, stop: threading.Event, cpu: dict) -> None:
    """Poll /proc for the run's node processes; keep each one's last (cpu s, life s)."""
    while not stop.is_set():
        for pid in os.listdir('/proc'):
            if not pid.isdigit():
                continue
            try:
                cmd = Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
                stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if marker not in cmd:
                continue
            node = next((n for n in NODES if n in cmd), None)
            if node is None:
                continue
            used = (int(stat[11]) + int(stat[12])) / TICKS        # utime + stime [s]
            entry = cpu.setdefault((node, pid), [used, time.monotonic(), time.monotonic()])
            entry[0], entry[2] = used, time.monotonic()
        stop.wait(0.25)


def machine_latency(rate_hz: int, seconds: float = 5.0) -> str:
    """Lateness of a SCHED_FIFO (where permitted) sleep loop at `rate_hz`: the floor."""
    try:
        old = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(60))
    except OSError:
        old = None
    period = 1.0 / rate_hz
    late, t0, k = [], time.monotonic(), 1
    while k < seconds * rate_hz:
        due, now = t0 + k * period, time.monotonic()
        if now < due:
            time.sleep(due - now)
            continue
        late.append(now - due)
        k += 1
    if old is not None:
        os.sched_setscheduler(0, old[0], old[1])
    v = np.array(late) * 1e3
    return (f'bare machine, sleep loop at {rate_hz} Hz: lateness ms p50 {np.median(v):.3f} '
            f'p99 {np.percentile(v, 99):.3f} max {v.max():.2f}; later than a period: '
            f'{100 * np.mean(v > period * 1e3):.2f} %')


def run_once(rate_hz: int, duration_s: float, sets: list[str], out: Path) -> dict:
    dt = 1.0 / rate_hz
    # the embedded record lasts 20 s at time scale 1: stretch it to the run's length
    floor = machine_latency(rate_hz)
    cmd = [str(SEFT), 'run', '--mode', 'realtime', '--alpha', '0', '--amplitude', '400',
           '--time-scale', f'{max(0.5, duration_s / 20.0):g}', '--duration', str(duration_s),
           '--set', f'dt={dt}', '--set', 'monitor_threshold=0', '--out', str(out)]
    for s in sets:
        cmd += ['--set', s]
    stop, cpu = threading.Event(), {}
    watcher = threading.Thread(target=_cpu_watch, args=(str(out), stop, cpu), daemon=True)
    load0 = os.getloadavg()[0]
    watcher.start()
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.monotonic() - t0
    stop.set()
    watcher.join()
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
        raise SystemExit(f'seft run failed at {rate_hz} Hz (exit {proc.returncode})')
    entry = json.loads((out / 'summary.json').read_text())['runs'][0]
    per_node = {}
    for (node, _), (used, first, last) in cpu.items():
        per_node[node] = per_node.get(node, 0.0) + used / max(last - first, 1e-9)
    return {'rate_hz': rate_hz, 'entry': entry, 'cpu': per_node, 'wall_s': wall,
            'load_before': load0, 'load_after': os.getloadavg()[0], 'floor': floor}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=60.0)
    ap.add_argument('--rates', type=int, nargs='+', default=[500, 1000])
    ap.add_argument('--repeats', type=int, default=1)
    ap.add_argument('--set', dest='sets', action='append', default=[])
    args = ap.parse_args()
    print(f'machine: {os.cpu_count()} cores, load average {os.getloadavg()}')
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rates:
            results = [run_once(rate, args.duration, args.sets, Path(tmp) / f'r{rate}_{i}')
                       for i in range(args.repeats)]
            for r in results:
                e, t = r['entry'], r['entry'].get('timing') or {}
                lat, jit = t.get('loop_latency_ms', {}), t.get('period_jitter_ms', {})
                aborted = ('' if e['stable'] else
                           f'aborted at {e["unstable_at_s"]:.2f} s: {e.get("abort_reason")}')
                print(f'\n{rate} Hz, {args.duration:g} s (load {r["load_before"]:.2f} -> '
                      f'{r["load_after"]:.2f}); stable={e["stable"]} {aborted}')
                print(f'  {r["floor"]}')
                print(f'  loop latency ms   p50 {lat.get("p50")}  p99 {lat.get("p99")}  '
                      f'max {lat.get("max")}')
                print(f'  period jitter ms  p50 {jit.get("p50")}  p99 {jit.get("p99")}  '
                      f'max {jit.get("max")}')
                print(f'  missed deadlines {100 * t.get("missed_deadline_fraction", np.nan):.2f}'
                      f' %, stale commands {100 * t.get("stale_command_fraction", np.nan):.2f}'
                      f' %, lost commands {t.get("lost_commands")}')
                for node, n in sorted((t.get('nodes') or {}).items()):
                    c = n['compute_ms']
                    print(f'  {node:>24}: compute ms p50 {c["p50"]} p99 {c["p99"]}; missed '
                          f'{100 * n["missed_deadline_fraction"]:.2f} %, stale '
                          f'{100 * n["stale_fraction"]:.2f} %')
                print('  CPU (fraction of one core): ' + ', '.join(
                    f'{k} {v:.2f}' for k, v in sorted(r['cpu'].items())))
                print(f'  displacement NRMS {100 * e["nrms"]["displacement"]:.2f} %; wall '
                      f'{r["wall_s"]:.0f} s incl. start-up; messages lost by the bag: '
                      f'{e.get("bag_lost_messages")}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
