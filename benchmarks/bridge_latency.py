"""Loop latency through the UDP bridge next to the simulated rig's, at 500 Hz (issue 21).

Runs ``seft run --mode realtime`` on the servohydraulic rig twice per repeat: the simulated
rig in the rig node, and the same rig behind the UDP bridge (``rig_interface: udp_bridge``)
with ``seft emulate-controller`` as the lab's real-time target. Prints, per case and repeat,
the loop latency (sample k to its command at the rig: for the bridge, at the target, on its
clock) p50 / p99 / max, stale commands and missed deadlines (fractions of the samples), the
bridge's late, lost and reordered datagrams, and the displacement NRMS against ``seft
simulate`` (the lockstep run every command-in-time real-time run equals). alpha 0.5, no
compensation, the default record, the instability monitor off and a 0.2 s watchdog, so that
a stall of this shared machine cannot end a run.

Usage: .venv/bin/python benchmarks/bridge_latency.py [--duration 20] [--repeats 2]
       [--set NAME=VALUE ...]
Prints figures; asserts nothing.
"""

import argparse
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import tempfile

import numpy as np

SEFT = Path(sys.executable).parent / 'seft'


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _run(out: Path, sets: list[str], duration: float, bridge: bool) -> dict:
    """One real-time run (through the bridge: with an emulator process); its figures."""
    from seft_ros.analysis.bag import read_run
    from seft_ros.core.experiment import simulate
    common = ['--set', 'monitor_threshold=0', '--set', 'watchdog_timeout_s=0.2', *sets]
    emulator = None
    if bridge:
        common += ['--set', 'rig_interface=udp_bridge', '--set',
                   f'udp_controller_address=127.0.0.1:{_free_port()}']
        emulator = subprocess.Popen([str(SEFT), 'emulate-controller', '--runs', '1', *common],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                    text=True, start_new_session=True)
        for line in emulator.stderr:
            if 'emulating' in line:
                break
    try:
        proc = subprocess.run([str(SEFT), 'run', '--mode', 'realtime', '--alpha', '0.5',
                               '--duration', str(duration), '--out', str(out), *common],
                              capture_output=True, text=True)
    finally:
        if emulator is not None and emulator.poll() is None:
            os.killpg(emulator.pid, signal.SIGINT)
            emulator.wait(timeout=10)
    if proc.returncode != 0:
        return {'error': proc.stderr.strip().splitlines()[-1]}
    run = read_run(next(out.glob('*/bag')))
    sim = simulate(dict(run.params, rig_interface='simulated', mode='lockstep'))
    n = min(run.n_steps, sim.n_steps)
    a, b = run.displacement_m[:n], sim.displacement_m[:n]
    rig = run.extra['timing_data']['rig']
    latency = np.asarray(rig.loop_latency_s)
    final = run.extra['rig_final']
    return {'p50': np.nanpercentile(latency, 50), 'p99': np.nanpercentile(latency, 99),
            'max': np.nanmax(latency), 'stale': float(np.mean(rig.stale[1:])),
            'missed': float(np.mean(rig.missed_deadline)),
            'nrms': float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b ** 2))),
            'late': int(final.get('udp_late', 0)) + int(final.get('controller_late', 0)),
            'lost': int(final.get('udp_lost', 0)) + int(final.get('controller_lost', 0)),
            'reordered': (int(final.get('udp_reordered', 0))
                          + int(final.get('controller_reordered', 0)))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=20.0, help='run length [s]')
    parser.add_argument('--repeats', type=int, default=2)
    parser.add_argument('--set', dest='sets', action='append', default=[],
                        metavar='NAME=VALUE', help='any other parameter of both runs')
    args = parser.parse_args()
    sets = [x for s in args.sets for x in ('--set', s)]
    print(f'load average before: {os.getloadavg()[0]:.2f}; {args.duration:g} s at 500 Hz, '
          f'alpha 0.5, servohydraulic rig')
    print(f'{"rig":24s} {"p50 ms":>7s} {"p99 ms":>7s} {"max ms":>7s} {"stale %":>8s} '
          f'{"missed %":>9s} {"late":>5s} {"lost":>5s} {"reord":>5s} {"NRMS x %":>9s}')
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for bridge in (False, True):
                name = 'UDP bridge + emulator' if bridge else 'simulated (rig node)'
                r = _run(Path(tmp) / f'{repeat}_{int(bridge)}', sets, args.duration, bridge)
                if 'error' in r:
                    print(f'{name:24s} failed: {r["error"]}')
                    continue
                print(f'{name:24s} {1e3 * r["p50"]:7.2f} {1e3 * r["p99"]:7.2f} '
                      f'{1e3 * r["max"]:7.2f} {100 * r["stale"]:8.2f} {100 * r["missed"]:9.2f} '
                      f'{r["late"]:5d} {r["lost"]:5d} {r["reordered"]:5d} '
                      f'{100 * r["nrms"]:9.3f}')
    print(f'load average after: {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
