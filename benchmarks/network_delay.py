"""Issue 23's tables: real-time tests across emulated networks (``tools/hosts.sh``), against
the same test on one host.

Three studies, each printing a Markdown table:

``--study sdof`` (default)
    The study's single-degree-of-freedom test (servohydraulic rig, ``--predictor``, default
    ``model``) over one link of each one-way delay (default 0, 5, 20, 50 and 100 ms, jitter
    +/- 20 %) for each mass ratio (default 0.5, 1 and 1.5), in the default partition
    (``loop_local``: the acceleration feedback and its compensator on the lab host, the
    ground motion sent ahead from the compute host), no hand-set delay. Each row is compared
    with the one-host real-time run of the same alpha (``seft run --mode realtime``): the
    difference of the NRMS errors in percentage points.
``--study remote``
    The earlier split (``--partition builder_remote``: the builder on the compute host, the
    loop across the link), ``network_delay_s`` left at ``auto``: what the runners measured and
    chose, whether the guard let the run go, and its NRMS.
``--study bridge``
    The two-pier bridge of ``config/two_piers.yaml``, each pier in its own lab, the deck on
    the compute host: both links at each delay (default 5, 20 and 50 ms), then pier a at
    5 ms and pier b at 20 ms (issue 20's case), ``none`` and ``model``, against one host.

Every run states whether it completed and the messages its bag lost; the load average is
printed before and after (this machine is a shared 2-core one: quote the tables with it).
Needs root (network namespaces).

Usage: .venv/bin/python benchmarks/network_delay.py [--study sdof|remote|bridge]
       [--delays-ms 0 5 20 50 100] [--alphas 0.5 1 1.5] [--duration 20] [--jitter 0.2]
       [--repeats 1] [-- extra seft run options]
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[1]
SEFT = ROOT / '.venv' / 'bin' / 'seft'
TWO_PIERS = ROOT / 'config' / 'two_piers.yaml'


def watchdog_s(delay_ms: float) -> float:
    """The watchdog limit of a run [s]: above a stall of this shared machine and, for an
    input that crosses the link, the link's jitter (the loop does not cross it by default)."""
    return 0.1 + 2e-3 * delay_ms


def one_host(out: Path, seft_args: list) -> dict:
    """One real-time run on this host; its summary entry (``exit``: the command's code)."""
    proc = subprocess.run([str(SEFT), 'run', '--mode', 'realtime', '--out', str(out),
                           *seft_args], capture_output=True, text=True, timeout=1800)
    return _entry(out / 'summary.json', proc)


def over_hosts(out: Path, links: dict, seft_args: list, partition: str | None = None) -> dict:
    """One run of ``tools/hosts.sh`` with the given one-way links ``{site: (delay_ms,
    jitter_ms)}``; its compute host's summary entry."""
    cmd = ['bash', str(ROOT / 'tools' / 'hosts.sh'), '--out', str(out)]
    if partition:
        cmd += ['--partition', partition]
    for site, (d, j) in links.items():
        cmd += ['--link', f'{site}={d:g},{j:g}']
    proc = subprocess.run([*cmd, '--', *seft_args], capture_output=True, text=True,
                          timeout=1800)
    return _entry(out / 'compute' / 'summary.json', proc)


def _entry(summary: Path, proc) -> dict:
    entry = json.loads(summary.read_text())['runs'][0] if summary.exists() else {}
    entry['exit'] = proc.returncode
    if 'nrms' not in entry:
        entry['stderr'] = proc.stderr[-3000:]
    return entry


def state(e: dict) -> str:
    """'completed', 'refused: ...', 'aborted at ...' or 'failed (exit N)'."""
    if 'nrms' not in e:
        refused = [ln for ln in e.get('stderr', '').splitlines() if 'unstable' in ln.lower()]
        return (f'refused: {refused[-1].split("error: ")[-1][:80]}' if refused
                else f'failed (exit {e["exit"]})')
    if e['stable'] and e['exit'] == 0:
        return 'completed'
    return f'aborted at {e["unstable_at_s"]:.2f} s ({(e.get("abort_reason") or "")[:60]})'


def lost(e: dict) -> str:
    """The bag's lost messages over its steps."""
    rec = e.get('recording') or {}
    return f'{e.get("bag_lost_messages", "?")} / {rec.get("steps", e.get("n_steps", "?"))}'


def rtt(e: dict) -> str:
    """The measured round trip p50 / p99 [ms] of every link of the run."""
    hosts = (e.get('link') or {}).get('hosts') or {}
    return ', '.join(f'{h} {v["round_trip_ms"]["p50"]:.1f}/{v["round_trip_ms"]["p99"]:.1f}'
                     for h, v in sorted(hosts.items())) or '-'


def pct(e: dict, key: str) -> float:
    return 100.0 * e['nrms'][key] if 'nrms' in e else float('nan')


def sdof(a, tmp: Path) -> None:
    print('| link one way ms | alpha | run | bag lost / steps | NRMS x / a / f % | one host '
          'x / a / f % | difference pp (x / a / f) | round trip p50/p99 ms | playout |')
    print('|---|---|---|---|---|---|---|---|---|')
    for alpha in a.alphas:
        args = ['--alpha', f'{alpha:g}', '--duration', f'{a.duration:g}', '--predictor',
                a.predictor, *a.extra]
        base = one_host(tmp / f'one_{alpha:g}', [*args, '--set',
                                                 f'watchdog_timeout_s={watchdog_s(0):.3f}'])
        for d in a.delays_ms:
            e = over_hosts(tmp / f'sdof_{alpha:g}_{d:g}', {'lab': (d, a.jitter * d)},
                           [*args, '--set', f'watchdog_timeout_s={watchdog_s(d):.3f}'])
            keys = ('displacement', 'acceleration', 'force')
            diff = ' / '.join(f'{pct(e, k) - pct(base, k):+.2f}' for k in keys)
            print(f'| {d:g} | {alpha:g} | {state(e)} | {lost(e)} | '
                  + ' / '.join(f'{pct(e, k):.2f}' for k in keys) + ' | '
                  + ' / '.join(f'{pct(base, k):.2f}' for k in keys)
                  + f' | {diff} | {rtt(e)} | {(e.get("link") or {}).get("playout", "-")} |',
                  flush=True)
            _stderr(e)
        _stderr(base)


def remote(a, tmp: Path) -> None:
    print('| link one way ms | alpha | run | bag lost / steps | network_delay_s chosen ms | '
          'round trip p50/p99 ms | NRMS x / a / f % | playout missed % |')
    print('|---|---|---|---|---|---|---|---|')
    for d in a.delays_ms:
        for alpha in a.alphas:
            args = ['--alpha', f'{alpha:g}', '--duration', f'{a.duration:g}', '--predictor',
                    a.predictor, '--set', f'watchdog_timeout_s={watchdog_s(4 * d):.3f}',
                    *a.extra]
            e = over_hosts(tmp / f'remote_{alpha:g}_{d:g}', {'lab': (d, a.jitter * d)}, args,
                           partition='builder_remote')
            link = e.get('link') or {}
            chosen = link.get('network_delay_s')
            missed = link.get('playout_missed_fraction')
            nrms = (' / '.join(f'{pct(e, k):.2f}' for k in ('displacement', 'acceleration',
                                                             'force'))
                    if 'nrms' in e else '-')
            print(f'| {d:g} | {alpha:g} | {state(e)} | {lost(e) if "nrms" in e else "-"} | '
                  f'{"-" if chosen is None else f"{1e3 * chosen:.0f}"} | {rtt(e)} | {nrms} | '
                  f'{"-" if missed is None else f"{100 * missed:.2f}"} |', flush=True)
            _stderr(e)


def bridge(a, tmp: Path) -> None:
    print('| links (pier a / pier b) ms | predictor | run | bag lost / steps | displacement '
          'NRMS pier a / pier b / deck % | one host % | round trip p50/p99 ms |')
    print('|---|---|---|---|---|---|---|')
    for predictor in ('none', 'model'):
        args = [str(TWO_PIERS), '--duration', f'{a.duration:g}', '--predictor', predictor,
                *a.extra]
        base = one_host(tmp / f'bridge_one_{predictor}', [*args, '--set',
                                                          f'watchdog_timeout_s={watchdog_s(0):.3f}'])
        for da, db in [(d, d) for d in a.delays_ms] + [(5.0, 20.0)]:
            links = {'pier_a': (da, a.jitter * da), 'pier_b': (db, a.jitter * db)}
            d = max(da, db)
            e = over_hosts(tmp / f'bridge_{predictor}_{da:g}_{db:g}', links,
                           [*args, '--set', f'watchdog_timeout_s={watchdog_s(2 * d):.3f}'])
            print(f'| {da:g} / {db:g} | {predictor} | {state(e)} | {lost(e)} | '
                  f'{_dofs(e)} | {_dofs(base)} | {rtt(e)} |', flush=True)
            _stderr(e)
        _stderr(base)


def _dofs(e: dict) -> str:
    if 'dofs' not in e:
        return '-'
    return ' / '.join(f'{100 * e["dofs"][n]["displacement"]["nrms"]:.2f}'
                      for n in ('pier_a', 'pier_b', 'deck') if n in e['dofs'])


def _stderr(e: dict) -> None:
    if 'stderr' in e:
        print(e['stderr'], file=sys.stderr)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--study', choices=('sdof', 'remote', 'bridge'), default='sdof')
    p.add_argument('--delays-ms', type=float, nargs='+', default=None,
                   help='one-way delays [ms] (default 0 5 20 50 100; bridge: 5 20 50, '
                        'both links)')
    p.add_argument('--alphas', type=float, nargs='+', default=[0.5, 1.0, 1.5])
    p.add_argument('--predictor', default='model')
    p.add_argument('--duration', type=float, default=20.0)
    p.add_argument('--jitter', type=float, default=0.2,
                   help='jitter as a fraction of the delay (default 0.2: +/- 20 %%)')
    p.add_argument('extra', nargs='*', help='more seft run options (after --)')
    a = p.parse_args()
    if os.geteuid() != 0:
        print('network_delay.py: error: needs root (network namespaces)', file=sys.stderr)
        return 2
    if a.delays_ms is None:
        a.delays_ms = [5, 20, 50] if a.study == 'bridge' else [0, 5, 20, 50, 100]
    print(f'load average before: {os.getloadavg()}', flush=True)
    with tempfile.TemporaryDirectory(prefix='seft-netdelay-') as tmp:
        {'sdof': sdof, 'remote': remote, 'bridge': bridge}[a.study](a, Path(tmp))
    print(f'load average after: {os.getloadavg()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
