"""Non-interference of the live view: real time at 500 Hz with and without it watched.

Runs ``seft run --mode realtime`` (servohydraulic rig, alpha 0, the default record at 400 N
stretched to DURATION, the instability monitor off and a 0.5 s watchdog, so that a stall of
this shared machine does not end a run; as benchmarks/realtime_graph.py) PAIRS
times without the live view and PAIRS times with ``--live`` and, connected for the whole
run, a Foxglove client (subscribed to every channel, tests/seft_ros/foxglove_client.py) and
the web page in headless Chromium (Debian's, driven by Playwright), alternating so that the
machine's load drifts over both alike. Per run: the rig's loop latency p50 / p99 / max,
missed deadlines (every node's, and the rig's), messages lost by the bag, what the Foxglove
client received, and the CPU of the live view's process and of the browser; then per
condition the median and the run-to-run spread (min-max) of each figure, and whether the
runs with the live view fall within the spread of those without.

Usage: .venv/bin/python benchmarks/live_view.py [--pairs 4] [--duration 20]
Prints figures; asserts nothing (target: missed deadlines and loop latency p99 with the live
view within the run-to-run spread without it; nothing lost in the bag).
"""

import argparse
import json
import os
from pathlib import Path
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEFT = Path(sys.executable).parent / 'seft'
sys.path.insert(0, str(ROOT / 'tests' / 'seft_ros'))
TICKS = os.sysconf('SC_CLK_TCK')
CHROMIUM = '/usr/bin/chromium'
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update',
                 '--disable-sync']


def free_port() -> int:
    """A port P with P and P+1 free on 127.0.0.1."""
    while True:
        with socket.socket() as s:
            s.bind(('127.0.0.1', 0))
            port = s.getsockname()[1]
        try:
            with socket.socket() as a, socket.socket() as b:
                a.bind(('127.0.0.1', port))
                b.bind(('127.0.0.1', port + 1))
            return port
        except OSError:
            continue


def cpu_seconds(pattern: str) -> float:
    """CPU time [s] of the processes whose command line matches `pattern`."""
    total = 0.0
    for pid in os.listdir('/proc'):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
            stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        if re.search(pattern, cmd):
            total += (int(stat[11]) + int(stat[12]) + int(stat[13]) + int(stat[14])) / TICKS
    return total


def run_once(duration_s: float, out: Path, live: bool, browser) -> dict:
    cmd = [str(SEFT), 'run', '--mode', 'realtime', '--alpha', '0', '--amplitude', '400',
           '--time-scale', f'{max(0.5, duration_s / 20.0):g}', '--duration', str(duration_s),
           '--set', 'monitor_threshold=0', '--set', 'watchdog_timeout_s=0.5', '--out',
           str(out)]
    port = free_port()
    if live:
        cmd += ['--live', f'127.0.0.1:{port}']
    load0 = os.getloadavg()[0]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    client = page = None
    live_cpu = chromium_cpu = 0.0
    if live:
        from foxglove_client import FoxgloveClient
        deadline = time.monotonic() + 60
        while not any('live view: Foxglove' in ln for ln in lines):
            if time.monotonic() > deadline or proc.poll() is not None:
                raise SystemExit('the live view did not start:\n' + ''.join(lines))
            time.sleep(0.05)
        client = FoxgloveClient(f'ws://127.0.0.1:{port}')
        chromium0 = cpu_seconds(r'chromium')
        page = browser.new_context(viewport={'width': 1500, 'height': 1150}).new_page()
        page.goto(f'http://127.0.0.1:{port + 1}/')
        while proc.poll() is None:
            # the live view's CPU while it runs (its process ends with the command)
            live_cpu = max(live_cpu, cpu_seconds(r'seft_ros\.live\.node'))
            page.wait_for_timeout(500)
        chromium_cpu = cpu_seconds(r'chromium') - chromium0
    proc.wait()
    reader.join(5)
    if proc.returncode != 0:
        raise SystemExit(f'seft run failed (exit {proc.returncode}):\n' + ''.join(lines[-20:]))
    received = {}
    if client is not None:
        client.close()
        received = {t: len(m) for t, m in client.messages.items()}
        page.context.close()
    entry = json.loads((out / 'summary.json').read_text())['runs'][0]
    t = entry.get('timing') or {}
    lat = t.get('loop_latency_ms', {})
    rig = (t.get('nodes') or {}).get('rig', {})
    nodes = t.get('nodes') or {}
    ticks = duration_s * 500
    missed = sum(round(n.get('missed_deadline_fraction', 0.0) * ticks)
                 for n in nodes.values())
    return {'live': live, 'stable': entry['stable'],
            'reason': '' if entry['stable'] else f'aborted at {entry["unstable_at_s"]:.2f} '
                                                 f's: {entry.get("abort_reason")}',
            'p50': lat.get('p50'),
            'p99': lat.get('p99'), 'max': lat.get('max'),
            'missed_rig': round(rig.get('missed_deadline_fraction', 0.0) * ticks),
            'missed_all': missed, 'lost': entry.get('bag_lost_messages'),
            'received': received, 'live_cpu_s': live_cpu, 'chromium_cpu_s': chromium_cpu,
            'load_before': load0, 'load_after': os.getloadavg()[0]}


def spread(values) -> str:
    v = np.array([x for x in values if x is not None], dtype=float)
    if not len(v):
        return '-'
    return f'{np.median(v):.3g} [{v.min():.3g}-{v.max():.3g}]'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--pairs', type=int, default=4)
    ap.add_argument('--duration', type=float, default=20.0)
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright
    print(f'machine: {os.cpu_count()} cores, load average {os.getloadavg()}; 500 Hz, '
          f'{args.duration:g} s per run, {args.pairs} pairs (without, with the live view)')
    results = []
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for i in range(args.pairs):
            for live in (False, True):
                r = run_once(args.duration, Path(tmp) / f'{i}_{int(live)}', live, browser)
                results.append(r)
                extra = ''
                if live:
                    extra = (f'; live view CPU {r["live_cpu_s"]:.1f} s, chromium '
                             f'{r["chromium_cpu_s"]:.1f} s; Foxglove received '
                             f'{sum(r["received"].values())} messages on '
                             f'{len(r["received"])} channels')
                print(f'{"with   " if live else "without"} loop latency ms p50 {r["p50"]} '
                      f'p99 {r["p99"]} max {r["max"]}; missed deadlines rig {r["missed_rig"]}'
                      f', all nodes {r["missed_all"]}; lost {r["lost"]}; stable '
                      f'{r["stable"]} {r["reason"]}; load {r["load_before"]:.2f} -> '
                      f'{r["load_after"]:.2f}'
                      + extra, flush=True)
        browser.close()
    print('\nmedian [min-max] over the runs:')
    results = [r for r in results if r['stable']] or results
    print(f'(over the {len(results)} runs that completed)')
    for key, label in (('p50', 'loop latency p50 ms'), ('p99', 'loop latency p99 ms'),
                       ('max', 'loop latency max ms'), ('missed_rig', 'missed deadlines, rig'),
                       ('missed_all', 'missed deadlines, all nodes'), ('lost', 'lost in bag')):
        off = [r[key] for r in results if not r['live']]
        on = [r[key] for r in results if r['live']]
        within = (min(off) <= float(np.median(on)) <= max(off)) if off and on and \
            None not in off + on else None
        print(f'  {label:28s} without {spread(off):>22s}   with {spread(on):>22s}   '
              f'median with within spread without: {within}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
