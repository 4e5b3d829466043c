"""OpenSees in real time (issue 40): the step's cost, and whole graphs on the wall clock.

For each --config (default: the steel frame at 500 Hz and at 1 kHz, the 63-DOF ten-story frame
at 500 Hz):

* a **dry run** in this process (``seft_ros.opensees.part.dry_run``, --steps steps, the
  interfaces moving 1 mm at 2 Hz): the OpenSees step's p50 / p99 / max;
* --repeats **real-time runs** of the node graph (``seft run CONFIG --mode realtime
  --duration D``, one host): whether it completed (or why it stopped), the OpenSees step's
  p50 / p99 / max as recorded with each sample and the steps over the budget (half the
  period; 0.8 of it with ``step: deferred``) and over the period, the stale and the missed
  fractions of the rig's periods, the loop latency, the builder's compute time, and the
  displacement NRMS per DOF.

The machine's load average is printed before and after each run: on a shared 2-core host the
slowest steps are the scheduler's; quote medians over repeats.

With ``--binding PYTHON`` the same per-step loop (the interface moved by a single-point
constraint, one transient step, the reactions and every floor's displacement read back) is
timed under another interpreter whose ``opensees.openseespy`` is another binding of OpenSees
(xara's: ``pip install xara`` into a Python 3.11 venv), and under this one's OpenSeesPy, on
the steel frame and on config/opensees/two_story.py, elastic and yielding.

Prints figures; asserts nothing (targets: the steel frame's step p99 <= 0.5 ms at 500 Hz; the
ten-story frame completes with <= 0.5 % stale steps; the steel frame completes at 1 kHz).

With ``--record`` and ``--amplitude`` the real-time runs are on that record at that amplitude
(the steel frame yields from about 1400 N on El Centro 180: its tangent is then read and
predicted with, and its system is a full one).

Usage: .venv/bin/python benchmarks/opensees_realtime.py [--config A.yaml ...] [--duration 10]
       [--repeats 2] [--steps 1000] [--binding /path/to/python] [--record X.AT2]
       [--amplitude N] [--step deferred]
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile

import yaml

from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.structure import test_setup
from seft_ros.opensees.part import dry_run

ROOT = Path(__file__).resolve().parents[1]
SEFT = Path(sys.executable).parent / 'seft'
CONFIGS = ('config/opensees/steel_frame.yaml', 'config/opensees/steel_frame_1khz.yaml',
           'config/opensees/ten_story.yaml')

#: The per-step loop of --binding, run under either interpreter: argv[1] 'xara' or
#: 'openseespy'; prints one line per case.
BINDING_LOOP = r"""
import math, sys, time, types
binding = sys.argv[1]
if binding == 'xara':
    import opensees.openseespy as ops
    package = types.ModuleType('openseespy'); package.opensees = ops
    sys.modules['openseespy'] = package; sys.modules['openseespy.opensees'] = ops
else:
    from seft_ros.opensees.loader import opensees
    ops = opensees()
sys.path.insert(0, sys.argv[2])
import steel_frame, two_story
def case(build, interface, floors, amplitude, steps=600, dt=0.002):
    build()
    ops.timeSeries('Constant', 1)
    ops.constraints('Penalty', 1e14, 1e14); ops.numberer('RCM'); ops.system('BandGeneral')
    ops.test('NormDispIncr', 1e-12, 25); ops.algorithm('Newton')
    ops.integrator('Newmark', 0.5, 0.25); ops.analysis('Transient')
    whole, analyze = [], []
    for k in range(1, steps):
        t0 = time.perf_counter()
        try:
            ops.remove('loadPattern', 5)
        except Exception:
            pass
        ops.pattern('Plain', 5, 1)
        ops.sp(interface, 1, amplitude * math.sin(2 * math.pi * 2.0 * k * dt))
        t1 = time.perf_counter()
        ops.analyze(1, dt)
        t2 = time.perf_counter()
        ops.reactions('-dynamic')
        ops.nodeReaction(interface, 1)
        [(ops.nodeDisp(n, 1), ops.nodeVel(n, 1), ops.nodeAccel(n, 1)) for n in floors]
        whole.append(time.perf_counter() - t0)
        analyze.append(t2 - t1)
    whole.sort(); analyze.sort()
    return whole[len(whole) // 2], analyze[len(analyze) // 2], ops.nodeDisp(floors[-1], 1)
for name, build, interface, floors in (
        ('steel_frame', steel_frame.build, 11, (11, 21, 31)),
        ('two_story', two_story.build, 1, (1, 2))):
    for amplitude in (1e-3, 2e-2):
        step, analyze, x = case(build, interface, floors, amplitude)
        print(f'{binding:10s} {name} {1e3 * amplitude:g} mm: step p50 {1e6 * step:.0f} us, '
              f'analyze p50 {1e6 * analyze:.0f} us (top floor {x:.6g} m)', flush=True)
"""


def _load() -> str:
    return '/'.join(f'{v:.1f}' for v in os.getloadavg())


def _ms(d, key) -> str:
    return '/'.join(f'{d[key][q]:.3f}' for q in ('p50', 'p99', 'max'))


def realtime_run(config: str, duration_s: float, out: Path, extra=()) -> str:
    """One real-time run of the node graph (`extra`: more ``seft run`` arguments); its
    figures in one line."""
    cmd = [str(SEFT), 'run', config, '--mode', 'realtime', '--duration', str(duration_s),
           '--out', str(out), *extra]
    before = _load()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    after = _load()
    summary = out / 'summary.json'
    if not summary.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ['?']
        return f'no summary (exit {proc.returncode}: {tail[0]}); load {before} -> {after}'
    entry = json.loads(summary.read_text())['runs'][0]
    st = entry.get('opensees', {}).get('step_time', {})
    timing = entry.get('timing') or {}
    builder = (timing.get('nodes') or {}).get('reference_force_builder', {})
    nrms = [entry['dofs'][d]['displacement']['nrms'] for d in entry['dofs']]
    done = 'completed' if entry.get('stable') and not entry.get('abort_reason') else \
        f'stopped: {entry.get("abort_reason")}'
    return (f'{done}; OpenSees step p50/p99/max {1e3 * st.get("p50_s", float("nan")):.3f}/'
            f'{1e3 * st.get("p99_s", float("nan")):.3f}/{1e3 * st.get("max_s", float("nan")):.3f}'
            f' ms, over budget {st.get("over_budget")}, over dt {st.get("over_period")} of '
            f'{st.get("steps")}; stale {100 * timing.get("stale_command_fraction", 0):.2f} %, '
            f'missed {100 * timing.get("missed_deadline_fraction", 0):.2f} %, loop latency '
            f'{_ms(timing, "loop_latency_ms") if "loop_latency_ms" in timing else "-"} ms, '
            f'builder compute {_ms(builder, "compute_ms") if builder else "-"} ms; NRMS x [%] '
            + ' / '.join(f'{100 * v:.2f}' for v in nrms) + f'; load {before} -> {after}')


def _with_step(config: str, step: str | None, directory: Path) -> str:
    """`config`, or with `step` a copy of it in `directory` with ``structure.opensees.step``
    set (its model's path made absolute)."""
    if step is None:
        return config
    path = ROOT / config
    doc = yaml.safe_load(path.read_text())
    model = doc['structure']['opensees']
    model.update(step=step, model=str(path.parent / model['model']))
    out = directory / f'{path.stem}_{step}.yaml'
    out.write_text(yaml.safe_dump(doc))
    return str(out)


def _config_runs(config: str, args, extra) -> None:
    """The dry run and the real-time runs of one configuration (module notes)."""
    params = expand_runs(load_config(ROOT / config))[0]
    r = dry_run(test_setup(params).substructures, float(params['dt']), steps=args.steps)
    print(f'{config}: dry run of {args.steps} steps: p50/p99/max {1e3 * r.p50_s:.3f}/'
          f'{1e3 * r.p99_s:.3f}/{1e3 * r.max_s:.3f} ms per step at dt = '
          f'{1e3 * float(params["dt"]):g} ms (load {_load()})', flush=True)
    with tempfile.TemporaryDirectory(prefix='seft-osrt-') as tmp:
        for i in range(args.repeats):
            line = realtime_run(config, args.duration, Path(tmp) / f'run{i}', extra)
            print(f'{config}: real time, run {i + 1}: {line}', flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--config', nargs='*', default=list(CONFIGS))
    ap.add_argument('--duration', type=float, default=10.0)
    ap.add_argument('--repeats', type=int, default=2)
    ap.add_argument('--steps', type=int, default=1000)
    ap.add_argument('--binding', help='a Python whose opensees.openseespy is another binding')
    ap.add_argument('--record', help='the real-time runs on this record (a PEER .AT2 path)')
    ap.add_argument('--amplitude', type=float,
                    help='the real-time runs at this amplitude [N] (a frame that yields)')
    ap.add_argument('--step', choices=('immediate', 'deferred'),
                    help="the models' step (structure.opensees.step; default: the config's)")
    args = ap.parse_args()
    extra = (['--record', args.record] if args.record else []) + (
        ['--amplitude', str(args.amplitude)] if args.amplitude else [])
    with tempfile.TemporaryDirectory(prefix='seft-osrt-config-') as configs:
        for config in args.config:
            _config_runs(_with_step(config, args.step, Path(configs)), args, extra)
    if args.binding:

        models = str(ROOT / 'config' / 'opensees')
        for python, name in ((args.binding, 'xara'), (sys.executable, 'openseespy')):
            proc = subprocess.run([python, '-c', BINDING_LOOP, name, models],
                                  capture_output=True, text=True)
            lines = [ln for ln in proc.stdout.splitlines() if ' us' in ln]
            print('\n'.join(lines) or f'{name}: failed ({proc.stderr.strip()[-300:]})',
                  flush=True)


if __name__ == '__main__':
    main()
