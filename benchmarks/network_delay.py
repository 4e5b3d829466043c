"""Issue 8's delay table: a real-time test across an emulated network between two hosts.

For each one-way network delay (default 0, 2, 5, 10 and 20 ms, jitter +/- 20 %) runs
``tools/two_hosts.sh`` (two network namespaces; the link emulator where the kernel has no
netem) twice: uncompensated (``predictor none``) and compensated (``predictor model`` with
``network_delay_s`` = the longest round trip, 2 x delay x (1 + jitter), plus 1 ms of
processing, in whole steps: the reference force built on the compute host from sample k
reaches the controller on the lab host about a round trip later, and the controller applies
it that fixed delay later). Prints, per run:
whether it completed, the messages the bag lost, its steps, the displacement, acceleration
and force NRMS errors, the J2 peak error, the rig's loop latency and the controller's
reference-force age (p50), and what the link emulator forwarded.

Needs root (network namespaces). The load average is printed before and after: on this
shared 2-core machine quote the table with it.

Usage: .venv/bin/python benchmarks/network_delay.py [--delays-ms 0 2 5 10 20] [--alpha 0.5]
       [--duration 20] [--jitter 0.2] [-- extra seft run options]
"""

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[1]


def run(out: Path, delay_ms: float, jitter: float, seft_args: list) -> dict:
    """One two-host run; return its summary entry plus the script's own lines."""
    cmd = ['bash', str(ROOT / 'tools' / 'two_hosts.sh'), '--delay-ms', f'{delay_ms:g}',
           '--jitter-ms', f'{jitter * delay_ms:g}', '--out', str(out), '--', *seft_args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    summary = out / 'compute' / 'summary.json'
    entry = json.loads(summary.read_text())['runs'][0] if summary.exists() else {}
    entry['exit'] = proc.returncode
    entry['link'] = next((ln for ln in proc.stderr.splitlines()
                          if ln.startswith('link emulator: first')), '')
    if not entry.get('timing'):
        entry['stderr'] = proc.stderr[-2000:]
    return entry


def watchdog_s(delay_ms: float) -> float:
    """The watchdog limit of a run [s]: above a stall of this machine and the round trip."""
    return 0.1 + 4e-3 * delay_ms


def row(delay_ms: float, name: str, e: dict) -> str:
    if 'nrms' not in e:
        return f'| {delay_ms:g} | {name} | failed (exit {e["exit"]}) | | | | | | | |'
    t = e['timing']
    ctrl_age = t['nodes'].get('force_servo_controller', {}).get('input_age_ms', {}).get('p50')
    rec = e.get('recording') or {}
    state = 'completed' if e['stable'] and e['exit'] == 0 else (
        f'aborted at {e["unstable_at_s"]:.2f} s: {e.get("abort_reason")}')
    return (f'| {delay_ms:g} | {name} | {state} | {e.get("bag_lost_messages")} / '
            f'{rec.get("steps", "?")} | {100 * e["nrms"]["displacement"]:.1f} | '
            f'{100 * e["nrms"]["acceleration"]:.1f} | {100 * e["nrms"]["force"]:.1f} | '
            f'{e["criteria"]["J2"]:.1f} | {t["loop_latency_ms"]["p50"]:.2f} | '
            f'{ctrl_age:.2f} |')


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--delays-ms', type=float, nargs='+', default=[0, 2, 5, 10, 20])
    p.add_argument('--alpha', type=float, default=0.5)
    p.add_argument('--duration', type=float, default=20.0)
    p.add_argument('--jitter', type=float, default=0.2,
                   help='jitter as a fraction of the delay (default 0.2: +/- 20 %%)')
    p.add_argument('extra', nargs='*', help='more seft run options (after --)')
    a = p.parse_args()
    if os.geteuid() != 0:
        print('network_delay.py: error: needs root (network namespaces)', file=sys.stderr)
        return 2
    base = ['--alpha', f'{a.alpha:g}', '--duration', f'{a.duration:g}', *a.extra]
    print(f'load average before: {os.getloadavg()}', flush=True)
    print('| delay ms | compensation | run | bag lost / steps | NRMS x % | NRMS a % | '
          'NRMS f % | J2 % | rig loop latency p50 ms | controller f_r age p50 ms |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    links = []
    with tempfile.TemporaryDirectory(prefix='seft-netdelay-') as tmp:
        for d in a.delays_ms:
            # the controller's watchdog on the reference force must outlast the round trip
            base_d = [*base, '--set', f'watchdog_timeout_s={watchdog_s(d):.3f}']
            plain = run(Path(tmp) / f'none_{d:g}', d, a.jitter,
                        [*base_d, '--predictor', 'none'])
            print(row(d, 'none', plain), flush=True)
            # the playout delay: the longest round trip (2 x delay x (1 + jitter)) plus 1 ms
            # of processing, in whole steps
            network_s = 0.0 if d == 0 else 0.002 * math.ceil(
                (2e-3 * d * (1 + a.jitter) + 0.001) / 0.002)
            comp = run(Path(tmp) / f'model_{d:g}', d, a.jitter,
                       [*base_d, '--predictor', 'model',
                        '--set', f'network_delay_s={network_s:.4f}'])
            print(row(d, f'model, N = {1e3 * network_s:.1f} ms', comp), flush=True)
            links += [(d, 'none', plain['link']), (d, 'model', comp['link'])]
            for e in (plain, comp):
                if 'stderr' in e:
                    print(e['stderr'], file=sys.stderr)
    for d, name, link in links:
        print(f'{d:g} ms {name}: {link}')
    print(f'load average after: {os.getloadavg()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
