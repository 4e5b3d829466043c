"""Issue 31's targets: structure tests whose specimens are not known exactly, or yield.

Run: ``.venv/bin/python benchmarks/robust_structures.py [RECORD ...] [--quick]
[--parts 1 3 4] [--duration 15] [--noise] [--network-runs 3] [--md FILE]``

Each RECORD is a PEER ``.AT2`` (or CSV) path, or ``default`` (the embedded record, the
fallback when none is given); every record runs at time scale 0.5 (the configurations' and
the study's), ``--duration`` seconds at most. Nothing here is tuned to a record. Each part
prints its Markdown tables as it goes and the load average before and after; ``--md`` writes
them all to a file.

1. ``config/two_piers.yaml`` and ``config/two_story.yaml`` at 1000 N, every rig's predictor
   ``k``, ``c``, ``m`` and loop delay off by +-10 % and +-20 %, one at a time and all four
   together (same sign), with the compensators of :data:`PREDICTORS` (``adaptive``, the one
   meant for an unknown specimen, with its force loop refitted from the rig model with the
   identified specimen and I/O latency, or with the declared latency, and ``model`` for
   contrast): the displacement NRMS per DOF
   (targets: every run stable, <= 2 % at +-10 %, <= 3 % at +-20 %). The loop delay is off
   by x when ``predictor_io_latency_s`` (the I/O latency the compensators model the
   servohydraulic force loop with) is the rig's ``io_latency_s`` plus x times the loop's
   equivalent delay (``seft_plant_sim.servohydraulic.equivalent_delay_s`` of the rig, its
   specimen and its force controller); the modelled loop's equivalent delay is printed as a check.
2. (``--network-runs N``, as root) The bridge with each pier in its own lab
   (``tools/hosts.sh`` through ``benchmarks/network_delay.py``: 20 ms one-way links, +-20 %
   jitter, ``structure_builders: per_rig``, loop processes), every pier's model (m, c, k;
   ``--network-errors`` may add the loop delay) +10 % off, ``adaptive``, N runs on the
   first record, each beside the same test in lockstep in one process (target: <= 2 % per
   pier, nothing lost).
3. ``config/two_piers_yielding.yaml`` (pier_a Bouc-Wen) and ``config/two_story_yielding.yaml``
   (story 1 Bouc-Wen) at 700 N, ``model`` and ``adaptive``, against the nonlinear reference
   (solve_ivp; target: stable, <= 5 % per DOF), and the yielding pier's force-loop inverse of
   5, 10 and 14 steps on the first record.
4. The study's one-rig test on the servohydraulic rig at 1000 N, alpha 0.5 / 1 / 1.5, the
   predictor's m, c, k and loop delay +-10 % one at a time and all together, ``model``,
   ``adaptive`` and ``adaptive`` with the loop from data, noise-free and with the sensor noise
   of ``benchmarks/robust_compensation.py`` (target <= 2 %).

``--quick``: the first record only; the exact model, k, the loop delay and all four off
(parts 1 and 4); part 3 without the inverse-delay sweep. Prints figures; asserts nothing.
"""

import argparse
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import sys
import tempfile
import time

import yaml

from seft_msgs_py.errors import InputError, ParameterError
from seft_plant_sim.servohydraulic import ServoHydraulicParams, equivalent_delay_s
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.analysis.metrics import compare_run
from seft_ros.cli.api import build_runs
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.controller import ForceServoController
from seft_ros.core.experiment import simulate
from seft_ros.core.structure import test_setup

sys.path.insert(0, str(Path(__file__).resolve().parent))
import network_delay  # noqa: E402  (tools/hosts.sh runs and their summaries)
from robust_compensation import NOISE  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / 'config'
#: Error name -> (the rig's predictor parameter, the rig's true parameter).
ERRORS = {'m': ('predictor_mass_kg', 'mass_kg'),
          'c': ('predictor_damping_N_s_per_m', 'damping_N_s_per_m'),
          'k': ('predictor_stiffness_N_per_m', 'stiffness_N_per_m'),
          'delay': ('predictor_io_latency_s', 'io_latency_s')}
ALPHAS = (0.5, 1.0, 1.5)
#: The compensators compared: label -> parameters (``adaptive`` refits the force-loop
#: inverse from the rig model with its identified specimen and, with ``adaptive_loop:
#: model_latency``, its identified I/O latency; with ``adaptive_loop: data`` it identifies the
#: loop from what it sends and measures).
PREDICTORS = {'adaptive': {'predictor': 'adaptive', 'adaptive_loop': 'model_latency'},
              'adaptive, latency declared': {'predictor': 'adaptive', 'adaptive_loop': 'model'},
              'model': {'predictor': 'model'}}
#: Targets of part 1: largest error -> worst NRMS x per DOF allowed [%].
TARGETS = {0.1: 2.0, 0.2: 3.0}


@dataclass
class Outcome:
    """One run: its worst displacement NRMS over the DOFs [%] (NaN if refused), per DOF [%],
    whether it stayed stable, why it was refused, and the final estimates."""

    worst: float
    per_dof: tuple = ()
    stable: bool = True
    refused: str = ''
    estimates: str = ''
    #: worst NRMS over the DOFs of acceleration / floor acceleration / interface force [%]
    signals: tuple = ()

    def cell(self) -> str:
        if self.refused:
            return 'refused'
        text = ' / '.join(f'{v:.2f}' for v in self.per_dof)
        return text if self.stable else f'{text} (unstable)'

    def bad(self) -> float:
        """The worst NRMS, inf if unstable or refused."""
        return self.worst if self.stable and not self.refused else math.inf


class Tables:
    """Markdown lines, printed as they come and kept for ``--md``."""

    def __init__(self):
        self.lines = []

    def __call__(self, line: str = '') -> None:
        print(line, flush=True)
        self.lines.append(line)

    def table(self, header: list[str]) -> None:
        self('| ' + ' | '.join(header) + ' |')
        self('|' + '---|' * len(header))

    def row(self, cells: list) -> None:
        self('| ' + ' | '.join(str(c) for c in cells) + ' |')

    def load(self, when: str) -> None:
        self(f'Load average {when}: ' + ' / '.join(f'{v:.1f}' for v in os.getloadavg())
             + ' (1 / 5 / 15 min, 2 cores).')
        self()

    def finish(self, t0: float, md: str | None) -> int:
        """The wall time since `t0` (``time.monotonic``); the tables to `md` if given; 0."""
        self(f'Wall time {time.monotonic() - t0:.0f} s.')
        if md:
            Path(md).write_text('\n'.join(self.lines) + '\n')
        return 0


def record_runs(records: list[str], duration_s: float) -> list[tuple[str, dict]]:
    """(label, run parameters) of each record: the embedded one or a file, time scale 0.5,
    at most `duration_s`."""
    out = []
    for rec in records:
        if rec == 'default':
            out.append(('embedded default', {'record': 'default', 'time_scale': 0.5}))
        else:
            path = Path(rec).resolve()
            out.append((path.stem, {'record': str(path), 'time_scale': 0.5,
                                    'duration_s': duration_s}))
    return out


def config_params(name: str | Path, **run) -> dict:
    """The first run of ``config/<name>.yaml`` (or of a configuration file) with `run` set."""
    path = name if isinstance(name, Path) else CONFIG / f'{name}.yaml'
    return expand_runs(dict(load_config(path), **run))[0]


def with_rig_sections(params: dict, sections: dict) -> dict:
    """`params` with each rig's parameters updated by ``sections[rig]`` (a structure's rig
    sections, or the study's own parameters for its rig ``''``)."""
    if params.get('structure', 'none') in ('none', '', None):
        return dict(params, **sections.get('', {}))
    doc = json.loads(params['structure'])
    for rig, values in sections.items():
        doc['rigs'].setdefault(rig, {}).update(values)
    return dict(params, structure=json.dumps(doc))


def loop_delay_s(rig: dict, io_latency_s: float | None = None,
                 band_hz: tuple = (1.0, 5.0)) -> float:
    """The equivalent delay [s] of a servohydraulic rig's force loop with its specimen and
    force controller (with another I/O latency if given): the phase slope over `band_hz`."""
    if io_latency_s is not None:
        rig = dict(rig, io_latency_s=io_latency_s)
    return equivalent_delay_s(ServoHydraulicParams.from_parameters(rig),
                              LinearSpecimen(rig['mass_kg'], rig['damping_N_s_per_m'],
                                             rig['stiffness_N_per_m']),
                              ForceServoController.from_parameters(rig), band_hz)


def error_sections(params: dict, errors: dict) -> dict:
    """Every rig's predictor parameters off by ``errors[name]`` (a fraction; names of
    :data:`ERRORS`) relative to the rig's true values; the loop delay as the module notes
    define it."""
    sections = {}
    for rig, rp in test_setup(params).rig_params.items():
        section = {}
        for name, x in errors.items():
            key, truth = ERRORS[name]
            if name == 'delay':
                section[key] = float(rp[truth]) + x * loop_delay_s(rp)
            else:
                section[key] = (1.0 + x) * float(rp[truth])
        sections[rig] = section
    return sections


def error_cases(quick: bool, sizes=(0.1, 0.2)) -> list[tuple[str, float, dict]]:
    """(label, size, errors) of the cases: exact, each error +-x, all four +-x."""
    names = ('k', 'delay') if quick else ('m', 'c', 'k', 'delay')
    out = [('exact', 0.0, {})]
    for x in sizes:
        for sign in (+1, -1):
            for name in names:
                out.append((f'{name} {sign * 100 * x:+.0f} %', x, {name: sign * x}))
            out.append((f'all {sign * 100 * x:+.0f} %', x,
                        {name: sign * x for name in ERRORS}))
    return out


def run(params: dict) -> Outcome:
    """Simulate one test and compare it with the whole structure's reference."""
    try:
        rd = simulate(params)
    except ParameterError as exc:
        return Outcome(math.nan, refused=str(exc))
    comparison = compare_run(rd)
    per_dof = tuple(100.0 * d.displacement.nrms for d in comparison.dofs)
    notes = []
    for rig, data in rd.rigs.items():
        est = data.estimates
        if est and 'stiffness_N_per_m' in est:
            k = float(est['stiffness_N_per_m'][-1]) / float(data.params['stiffness_N_per_m'])
            m = float(est['mass_kg'][-1]) / float(data.params['mass_kg'])
            note = f'{rig or "rig"} k {k:.3f} m {m:.3f}'
            if 'loop_latency_s' in est:
                latency = float(est['loop_latency_s'][-1])
                note += f', I/O latency {latency / float(data.params["io_latency_s"]):.3f}'
            notes.append(note)
    signals = tuple(100.0 * comparison.worst_nrms(name) for name in
                    ('acceleration', 'floor_acceleration', 'interface_force'))
    return Outcome(100.0 * comparison.worst_nrms('displacement'), per_dof, bool(rd.stable),
                   estimates=', '.join(notes), signals=signals)


def delay_check(out: Tables, name: str) -> None:
    """The modelled force loop's equivalent delay against the rig's, per rig, for a loop
    delay off by -20 / -10 / +10 / +20 %: the phase slope over 1-5 Hz (the definition's) and
    over 5-20 Hz (the structures' modes)."""
    params = config_params(name)
    for rig, rp in test_setup(params).rig_params.items():
        got = {}
        for band in ((1.0, 5.0), (5.0, 20.0)):
            true = loop_delay_s(rp, band_hz=band)
            got[band] = (true, [])
            for x in (-0.2, -0.1, 0.1, 0.2):
                latency = error_sections(params, {'delay': x})[rig]['predictor_io_latency_s']
                got[band][1].append(
                    f'{100 * (loop_delay_s(rp, latency, band) / true - 1):+.1f} %')
        (t1, low), (t2, high) = got.values()
        out(f"{name}, {rig}: the force loop's equivalent delay {1e3 * t1:.2f} ms over 1-5 Hz, "
            f'{1e3 * t2:.2f} ms over 5-20 Hz (I/O latency {1e3 * float(rp["io_latency_s"]):.1f}'
            ' ms); modelled with the loop delay off by -20 / -10 / +10 / +20 %: '
            f'{" / ".join(low)} over 1-5 Hz, {" / ".join(high)} over 5-20 Hz.')
    out()


def part1(out: Tables, records, quick: bool, noise: dict) -> None:
    """Every rig's model off: the compensators of :data:`PREDICTORS` on both structures."""
    out("## 1. Structures at 1000 N, every rig's predictor off")
    out()
    out.load('before')
    for name in ('two_piers', 'two_story'):
        delay_check(out, name)
    worst, refusals = {}, []
    for name in ('two_piers', 'two_story'):
        for label, rec in records:
            base = config_params(name, amplitude_N=1000.0, **rec, **noise)
            dofs = json.loads(base['structure'])['dofs']
            out(f'**{name}, {label}**: displacement NRMS per DOF ({" / ".join(dofs)}), %')
            out()
            out.table(['case'] + [f'`{p}`' for p in PREDICTORS] + ['worst'] +
                      ['`adaptive`: identified / true at the end'])
            for case, size, errors in error_cases(quick):
                params = with_rig_sections(base, error_sections(base, errors))
                outcomes = {}
                for pred, opts in PREDICTORS.items():
                    o = outcomes[pred] = run(dict(params, **opts))
                    key = (name, pred, size)
                    worst[key] = max(worst.get(key, -math.inf), o.bad())
                    if o.refused:
                        refusals.append(f'{name}, {label}, {case}, {pred}: {o.refused}')
                out.row([case] + [o.cell() for o in outcomes.values()]
                        + [' / '.join('-' if o.refused else f'{o.worst:.2f}'
                                      for o in outcomes.values()),
                           outcomes['adaptive'].estimates])
            out()
    for line in refusals:
        out(f'Refused before the run: {line}')
        out()
    out('**Worst displacement NRMS per DOF over every case and record**, % (inf: a run '
        'unstable or refused):')
    out()
    out.table(['structure', 'compensator', 'exact', 'up to +-10 %', 'up to +-20 %',
               'target (<= 2 % / <= 3 %)'])
    for name in ('two_piers', 'two_story'):
        for pred in PREDICTORS:
            w = [worst[name, pred, s] for s in (0.0, 0.1, 0.2)]
            met = [w[1] <= TARGETS[0.1], w[2] <= TARGETS[0.2]]
            out.row([name, f'`{pred}`'] + [f'{v:.2f}' for v in w]
                    + [' / '.join('met' if m else 'missed' for m in met)])
    out()
    out.load('after')


def part2(out: Tables, records, runs: int, duration_s: float, keep: str | None,
          names: tuple) -> None:
    """The bridge over three emulated hosts, every pier's `names` (of :data:`ERRORS`) +10 %
    off, adaptive."""
    out('## 2. The bridge with each pier in its own lab')
    out()
    if os.geteuid() != 0:
        out('Not run: needs root (network namespaces).')
        return
    label, rec = records[0]
    values = yaml.safe_load((CONFIG / 'two_piers.yaml').read_text())
    base = config_params('two_piers', amplitude_N=1000.0, **rec)
    for rig, section in error_sections(base, {n: 0.1 for n in names}).items():
        values['rigs'].setdefault(rig, {}).update(section)
    values.update(predictor='adaptive', structure_builders='per_rig', amplitude_N=1000.0,
                  **rec)
    delay_ms = 20.0
    with tempfile.TemporaryDirectory(prefix='seft-robust-') as tmp:
        if keep:
            tmp = Path(keep)
            tmp.mkdir(parents=True, exist_ok=True)
        config = Path(tmp) / 'two_piers_off.yaml'
        config.write_text(yaml.safe_dump(values, sort_keys=False))
        lockstep = run(config_params(config))
        out(f"{label}, {duration_s:g} s at most; every pier's {', '.join(names)} +10 %, "
            f'`adaptive`, `structure_builders: per_rig`; links {delay_ms:g} ms one way '
            f'+-{0.2 * delay_ms:g} ms. Lockstep in one process: {lockstep.cell()} % '
            f'({lockstep.estimates}); worst acceleration / floor acceleration / interface '
            f"force {' / '.join(f'{v:.2f}' for v in lockstep.signals)} %.")
        out()
        out.load('before')
        out.table(['run', 'outcome', 'bag lost / steps', 'NRMS x pier a / pier b / deck %',
                   'worst NRMS acceleration / floor acceleration / interface force %',
                   'identified k / declared', 'round trip p50/p99 ms',
                   "controllers' stale steps %", 'rig period jitter max ms', 'load before'])
        for i in range(runs):
            load = os.getloadavg()[0]
            e = network_delay.over_hosts(
                Path(tmp) / f'run{i}', {r: (delay_ms, 0.2 * delay_ms)
                                        for r in ('pier_a', 'pier_b')},
                [str(config), '--set', 'watchdog_timeout_s='
                 f'{network_delay.watchdog_s(2 * delay_ms):.3f}'])
            ratios = ', '.join(f'{r} {v:.3f}' for r, v in
                               sorted((e.get('specimen_stiffness_ratios') or {}).items()))
            out.row([i + 1, network_delay.state(e), network_delay.lost(e),
                     network_delay._dofs(e), _worst(e), ratios or '-', network_delay.rtt(e),
                     _stale(e), _jitter(e), f'{load:.1f}'])
            network_delay._stderr(e)
    out()
    out.load('after')


def _worst(e: dict) -> str:
    """The run's worst NRMS over the DOFs of the acceleration, the floor acceleration and
    the interface force [%] (summary.json's ``worst_nrms``)."""
    worst = e.get('worst_nrms') or {}
    cells = [worst.get(name) for name in ('acceleration', 'floor_acceleration',
                                          'interface_force')]
    return ' / '.join('-' if v is None else f'{100 * v:.2f}' for v in cells)


def _stale(e: dict) -> str:
    """Each controller's fraction of steps without its reference force in time [%]."""
    nodes = ((e.get('timing') or {}).get('nodes') or {})
    cells = [f'{n.split("/")[0]} {100 * v["stale_fraction"]:.2f}'
             for n, v in sorted(nodes.items())
             if n.endswith('force_servo_controller') and v.get('stale_fraction') is not None]
    return ', '.join(cells) or '-'


def _jitter(e: dict) -> str:
    """The largest deviation of a rig's period [ms]: a stall of the host shows here."""
    jitter = ((e.get('timing') or {}).get('period_jitter_ms') or {}).get('max')
    return '-' if jitter is None else f'{jitter:.1f}'


def part3(out: Tables, records, quick: bool, noise: dict) -> None:
    """A yielding member on each structure, against the nonlinear reference."""
    out('## 3. A yielding member at 700 N')
    out()
    out.load('before')
    out.table(['structure (yielding DOF)', 'record', 'compensator', 'NRMS x per DOF %',
               'worst %', 'peak / yield displacement', 'target <= 5 %'])
    for name, dof in (('two_piers_yielding', 'pier_a'), ('two_story_yielding', 'story_1')):
        for label, rec in records:
            for predictor in ('model', 'adaptive'):
                params = config_params(name, predictor=predictor, **rec, **noise)
                o, ductility = _yielding(params, dof)
                out.row([f'{name} ({dof})', label, f'`{predictor}`', o.cell(),
                         f'{o.worst:.2f}', f'{ductility:.1f}',
                         'met' if o.bad() <= 5.0 else 'missed'])
    out()
    if not quick:
        label, rec = records[0]
        out(f"two_piers_yielding, `model`, {label}: pier_a's force-loop inverse delay "
            '(`predictor_loop_delay_steps`)')
        out()
        out.table(['inverse delay, steps', 'NRMS x pier a / pier b / deck %', 'worst %'])
        for steps in (5, 10, 14):
            params = with_rig_sections(
                config_params('two_piers_yielding', predictor='model', **rec, **noise),
                {'pier_a': {'predictor_loop_delay_steps': steps,
                            'predictor_loop_taps': 48 if steps == 5 else 96}})
            o, _ = _yielding(params, 'pier_a')
            out.row([steps, o.cell(), f'{o.worst:.2f}'])
        out()
    out.load('after')


def _yielding(params: dict, dof: str) -> tuple[Outcome, float]:
    """A run with a yielding member: its outcome and the member's peak displacement over its
    yield displacement in the nonlinear reference."""
    rd = simulate(params)
    comparison = compare_run(rd)
    ref = comparison.structure_reference
    i = list(json.loads(params['structure'])['dofs']).index(dof)
    rig = json.loads(params['structure'])['physical'][dof]
    peak = float(abs(ref.displacement_m[:, i]).max())
    per_dof = tuple(100.0 * d.displacement.nrms for d in comparison.dofs)
    return (Outcome(100.0 * comparison.worst_nrms('displacement'), per_dof, bool(rd.stable)),
            peak / float(rd.rigs[rig].params['yield_displacement_m']))


def part4(out: Tables, records, quick: bool) -> None:
    """The study's one-rig test, servohydraulic, its predictor's model +-10 % off."""
    out("## 4. The study's one-rig test, servohydraulic rig, 1000 N")
    out()
    out.load('before')
    cases = error_cases(quick, sizes=(0.1,))
    summary = {}
    for label, rec in records:
        for noisy in (False, True):
            extra = NOISE if noisy else {}
            out(f'**{label}, sensor noise {"on" if noisy else "off"}**: displacement NRMS %, '
                'alpha ' + ' / '.join(f'{a:g}' for a in ALPHAS))
            out()
            out.table(['case'] + [f'`{p}`' for p in PREDICTORS])
            for case, _, errors in cases:
                cells = [case]
                for pred, opts in PREDICTORS.items():
                    row = []
                    for alpha in ALPHAS:
                        params = expand_runs(dict(rec, amplitude_N=1000.0, alpha=alpha,
                                                  rig_model='servohydraulic', **opts,
                                                  **extra))[0]
                        o = run(with_rig_sections(params, error_sections(params, errors)))
                        row.append(o)
                        key = (label, noisy, pred, case == 'exact')
                        summary[key] = max(summary.get(key, -math.inf), o.bad())
                    cells.append(' / '.join(o.cell() for o in row))
                out.row(cells)
            out()
    out('**Worst over alpha 0.5-1.5 and the cases** (displacement NRMS %; target <= 2 %):')
    out()
    out.table(['record', 'noise'] + [f'`{p}` exact / off by 10 %' for p in PREDICTORS])
    for label, _ in records:
        for noisy in (False, True):
            out.row([label, 'on' if noisy else 'off'] + [
                f'{summary[label, noisy, p, True]:.2f} / {summary[label, noisy, p, False]:.2f}'
                for p in PREDICTORS])
    out()
    out.load('after')


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('records', nargs='*', default=['default'],
                   help="ground-motion records (.AT2 or CSV paths; 'default': the embedded "
                        'one, the fallback)')
    p.add_argument('--parts', type=int, nargs='+', default=None, choices=(1, 2, 3, 4),
                   help='parts to run (default 1 3 4, and 2 with --network-runs)')
    p.add_argument('--quick', action='store_true',
                   help='the first record, fewer cases (module notes)')
    p.add_argument('--duration', type=float, default=15.0,
                   help='run length after time scaling [s] (default 15)')
    p.add_argument('--noise', action='store_true',
                   help='sensor noise in parts 1 and 3 too (part 4 runs with and without)')
    p.add_argument('--network-runs', type=int, default=0,
                   help='part 2: this many runs over three emulated hosts (root)')
    p.add_argument('--network-errors', nargs='+', choices=tuple(ERRORS), default=['m', 'c', 'k'],
                   help="part 2: the pier model's parameters +10 %% off (default m c k)")
    p.add_argument('--keep', metavar='DIR',
                   help="part 2: keep each run's outputs (tools/hosts.sh --out) in DIR")
    p.add_argument('--md', help='write the tables to this Markdown file')
    a = p.parse_args()
    parts = a.parts or ([1, 3, 4] + ([2] if a.network_runs else []))
    records = record_runs(a.records[:1] if a.quick else a.records, a.duration)
    noise = NOISE if a.noise else {}
    out = Tables()
    t0 = time.monotonic()
    try:
        build_runs(overrides={'record': [r['record'] for _, r in records]})  # read them now
        for part in sorted(parts):
            if part == 1:
                part1(out, records, a.quick, noise)
            elif part == 2:
                part2(out, records, max(a.network_runs, 1), a.duration, a.keep,
                      tuple(a.network_errors))
            elif part == 3:
                part3(out, records, a.quick, noise)
            else:
                part4(out, records, a.quick)
    except (InputError, ParameterError) as exc:
        print(f'robust_structures.py: error: {exc}', file=sys.stderr)
        return 2
    return out.finish(t0, a.md)


if __name__ == '__main__':
    sys.exit(main())
