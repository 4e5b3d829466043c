"""A lab's own actuator through seft's three commands: identify, design, test (issue 38).

For each plant (seft_plant_sim's family of actuators seft did not design its models for, or
seft's own rig with a stiff column) and specimen, as a lab does:

1. an open-loop identification run: 20 s of valve noise (``excitation: noise``,
   ``excitation_input: valve_command``), the plant recorded;
2. ``seft identify``: the plant as data (its order chosen by the data) and the force
   controller designed for it (``plant_model``, ``force_controller: transfer_function``,
   the compensators' settings), from that run alone;
3. the study's one-DOF test with them, ``model`` at alpha 0.5, 1.0 and 1.5 and ``adaptive``
   with the specimen's predictor model 20 % off, at an amplitude the rig can take (the
   analytical reference's peak acceleration at 70 % of the accelerometer's range, its peak
   velocity at half the valve's no-load velocity).

Each test is first checked by the guard as ``seft simulate`` checks it
(:func:`seft_ros.cli.api.check_stability`, with the robustness margin); its verdict is
compared with the run's outcome. The designed loop's crossover, phase and gain margins are
read on the *true* plant (the
actuator linearized at rest, ``ActuatorSpec.linear_plant``; seft's rig model), never on the
identified one. The test never sees the true plant: the same run in a lab would.

Usage::

    .venv/bin/python benchmarks/own_actuator.py                 # the family x specimens
    .venv/bin/python benchmarks/own_actuator.py --quick         # fewer specimens
    .venv/bin/python benchmarks/own_actuator.py --monte-carlo 20 --alphas 1 --no-adaptive
    #   20 spread plants per member (+-30 %), the 32 Hz 1 % specimen, model at alpha 1
    .venv/bin/python benchmarks/own_actuator.py --write docs/results/own-actuator.md
    .venv/bin/python benchmarks/own_actuator.py --noise 1 --members leaky --specimens 10
    #   the sensors' declared noise: 1 N on the load cell and the proportionate set
    .venv/bin/python benchmarks/own_actuator.py --noise force=0.1
    #   or each sensor's own (force [N], displacement [m], velocity [m/s], acceleration
    #   [m/s^2], seed), the others noise-free

Prints one line per plant and specimen, then the table; ``--write`` puts the table in the
docs page between its markers.
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import math
import os
import sys
import time

import numpy as np

FAMILY_MEMBERS = ('valve_2nd_order', 'valve_3_stage', 'leaky', 'orifice_flow',
                  'coulomb_friction', 'pure_delay')
SPECIMEN_HZ = (2.0, 5.0, 10.0, 20.0, 32.0, 50.0)
DAMPING = (0.005, 0.05)
ALPHAS = (0.5, 1.0, 1.5)
MASS_KG = 40.0
#: The sample period of the specimens above :data:`~seft_ros.core.predictors.LOOP_BAND_HZ`
#: (the default 2 ms elsewhere): as a lab runs a stiff specimen faster. A 50 Hz specimen at
#: 2 ms has 10 samples per period; measured on ``valve_2nd_order`` with the 0.5 % one: no
#: force-loop inverse makes the test stable up to alpha 2 on the model, 1.6-7.0 % NRMS x at
#: alpha 0.5-1.5; at 1 ms 0.3-1.3 % [s].
STIFF_DT_S = 0.001
STIFF_HZ = 40.0
#: The sensors' noise (standard deviations) per newton of the load cell's in the
#: proportionate set of ``--noise F``: a 40 kN load cell with 0.1 N (2.5e-6 of its range),
#: a 76 mm displacement sensor with 0.2 um, and so on (session 24's case K is ``--noise 5``
#: but for its velocity).
NOISE_PER_N = {'noise_force_N': 1.0, 'noise_displacement_m': 2e-6,
               'noise_velocity_m_s': 2e-5, 'noise_acceleration_m_s2': 0.01}
_NOISE_KEYS = {'force': 'noise_force_N', 'displacement': 'noise_displacement_m',
               'velocity': 'noise_velocity_m_s', 'acceleration': 'noise_acceleration_m_s2',
               'seed': 'noise_seed'}


def noise_parameters(text: str) -> dict:
    """The rig's noise parameters of ``--noise``: a number F (the load cell's noise [N]
    and :data:`NOISE_PER_N` times it for the other sensors) or ``key=value`` pairs
    separated by commas (keys ``force`` [N], ``displacement`` [m], ``velocity`` [m/s],
    ``acceleration`` [m/s^2], ``seed``).

    Raises
    ------
    argparse.ArgumentTypeError
        Another key, a value that is not a number >= 0.
    """
    try:
        level = float(text)
    except ValueError:
        pass
    else:
        if not (math.isfinite(level) and level >= 0):
            raise argparse.ArgumentTypeError(f'--noise {text}: expected a level >= 0 [N]')
        return {k: v * level for k, v in NOISE_PER_N.items()}
    out = {}
    for item in text.split(','):
        key, _, value = item.partition('=')
        if key.strip() not in _NOISE_KEYS:
            raise argparse.ArgumentTypeError(
                f'--noise {item!r}: expected a level [N] or key=value with a key of '
                f'{", ".join(_NOISE_KEYS)}')
        try:
            v = float(value)
        except ValueError:
            v = -1.0
        if not (math.isfinite(v) and v >= 0):
            raise argparse.ArgumentTypeError(f'--noise {item!r}: expected a number >= 0')
        name = _NOISE_KEYS[key.strip()]
        out[name] = int(v) if name == 'noise_seed' else v
    return out


def _specimen(f_hz: float, zeta: float, mass_kg: float = MASS_KG) -> dict:
    k = mass_kg * (2.0 * math.pi * f_hz) ** 2
    return {'mass_kg': mass_kg, 'stiffness_N_per_m': k,
            'damping_N_s_per_m': 2.0 * zeta * math.sqrt(k * mass_kg)}


def _amplitude(params: dict, v_max: float) -> float:
    """The amplitude at which the reference takes 70 % of the accelerometer's range and half
    of the valve's no-load velocity (at most 1000 N)."""
    from seft_ros.analysis.reference import planned_reference
    ref = planned_reference(dict(params, amplitude_N=1000.0))
    a_peak = float(np.max(np.abs(ref.acceleration_m_s2)))
    v_peak = float(np.max(np.abs(ref.velocity_m_s)))
    rng = float(params.get('accelerometer_range_m_s2', 39.2)) or math.inf
    return min(1000.0, 1000.0 * 0.7 * rng / a_peak, 1000.0 * 0.5 * v_max / v_peak)


def _true_margins(base: dict, design) -> dict:
    """The designed controller's loop on the true plant (linearized at rest)."""
    from seft_plant_sim.actuator import actuator_spec
    from seft_plant_sim.specimen import LinearSpecimen
    from seft_ros.core.force_design import _Discrete, plant_margins
    from seft_ros.core.force_loop import force_loop_plant
    if base['rig_model'] == 'actuator':
        true = actuator_spec(base).linear_plant(LinearSpecimen.from_parameters(base),
                                                float(base['dt']))
    else:
        true = force_loop_plant(base)
    m = plant_margins(true, _Discrete(np.array(design.num_z), np.array(design.den_z),
                                      design.dt))
    return {'crossover_hz': m.crossover_hz, 'phase_margin_deg': m.phase_margin_deg,
            'gain_margin': m.gain_margin, 'crossovers': m.crossovers}


def lab_path(case: dict) -> dict:
    """One plant and specimen through the three commands (module notes); an exception is
    the case's result (``error``), not the benchmark's end."""
    try:
        return _lab_path(case)
    except Exception as exc:                           # noqa: BLE001 - reported per case
        import traceback
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return {'case': case['name'], 'member': case['member'], 'f_hz': case['f_hz'],
                'zeta': case['zeta'], 'runs': [],
                'error': f'{type(exc).__name__}: {exc} ({where.filename.rsplit("/", 1)[-1]}:'
                         f'{where.lineno})'}


def _lab_path(case: dict) -> dict:
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.analysis.rig_identification import identified_parameters, identify_rigs
    from seft_ros.cli.api import build_runs, check_stability
    from seft_ros.cli.config import mapping_values
    from seft_ros.core import stability
    from seft_ros.core.experiment import simulate
    t0 = time.time()
    base = dict(case['params'])
    out = {'case': case['name'], 'member': case['member'], 'f_hz': case['f_hz'],
           'zeta': case['zeta'], 'runs': []}
    # 1. the open-loop identification run
    # (the test's configuration: the design ranks its force-loop inverses for its record)
    idp = build_runs(overrides=dict(base, predictor='none', excitation='noise',
                                    excitation_input='valve_command', duration_s=20.0,
                                    alpha=0.0, record=case.get('record', 'default')))[0]
    rd = simulate(idp)
    if not rd.stable:
        out['error'] = f'identification run aborted: {rd.abort_reason}'
        return out
    # 2. identify and design
    idents = identify_rigs(rd)
    ident = idents[0]
    if ident.design is None:
        out['error'] = 'no plant identified (specimen not linear?)'
        return out
    found = identified_parameters(idents)
    written = mapping_values({k: v for k, v in found.items() if not k.startswith('_')})
    design = ident.design
    out['plant_order'] = ident.plant.order
    out['plant_nrms'] = ident.plant.nrms['force_N']
    out['design_model'] = design.margins.to_json()
    out['design_met'] = design.met
    out['loop_delay_steps'] = design.loop_delay_steps
    out['true'] = _true_margins(idp, design)
    v_max = case.get('v_max', math.inf)
    # 3. the tests
    tests = [('model', a, {}) for a in case.get('alphas', ALPHAS)]
    if case.get('adaptive', True):
        tests.append(('adaptive', 1.0, {'predictor_stiffness_N_per_m':
                                        1.2 * base['stiffness_N_per_m'],
                                        'predictor_mass_kg': 0.8 * base['mass_kg']}))
    for predictor, alpha, extra in tests:
        p = build_runs(overrides=dict(base, **written, **extra, predictor=predictor,
                                      alpha=alpha, duration_s=case.get('duration_s', 15.0),
                                      record=case.get('record', 'default')))[0]
        p['amplitude_N'] = _amplitude(p, v_max)
        entry = {'predictor': predictor, 'alpha': alpha, 'amplitude_N': p['amplitude_N']}
        # the guard as `seft simulate` runs it (with the robustness margin: the margin's
        # error refused adaptive runs that `simulate` alone ran, fifteenth session); a run
        # the guard refuses is run all the same (--force) to compare verdict and outcome
        try:
            check = check_stability(runs=[p], progress=lambda line: None)[0]
            entry['guard'] = check.stable
        except stability.PredictedUnstableError as exc:
            entry['guard'], entry['guard_refused'] = False, str(exc)
        except Exception as exc:                       # a prediction the guard cannot make
            entry['guard'] = f'n/a: {exc}'
        try:
            run = simulate(p)
        except Exception as exc:
            entry['error'] = str(exc)
            out['runs'].append(entry)
            continue
        entry['stable'] = bool(run.stable)
        if run.stable:
            c = compare_run(run)
            entry.update(nrms_x=c.displacement.nrms, nrms_a=c.acceleration.nrms,
                         nrms_f=c.force.nrms,
                         valve_peak_V=float(np.max(np.abs(run.rigs[''].valve_command_V))))
        out['runs'].append(entry)
    out['seconds'] = time.time() - t0
    return out


def cases(members, specimens, damping, spread=0.0, seeds=(1,), stiff=True) -> list[dict]:
    """The plants and specimens to run."""
    out = []
    for f_hz in specimens:                   # the members inside: a stopped run covers them
        for zeta in damping:
            for member in members:
                for seed in seeds:
                    params = dict(_specimen(f_hz, zeta), rig_model='actuator',
                                  actuator_family=member, actuator_spread=spread,
                                  actuator_seed=seed)
                    if f_hz > STIFF_HZ:
                        params['dt'] = STIFF_DT_S
                    name = f'{member} {f_hz:g} Hz {100 * zeta:g} %' + (
                        f' seed {seed}' if spread else '')
                    out.append({'name': name, 'member': member, 'f_hz': f_hz, 'zeta': zeta,
                                'params': params, 'v_max': 0.6})
    if stiff:
        params = dict(rig_model='servohydraulic', mass_kg=29.13, stiffness_N_per_m=1.19e6,
                      damping_N_s_per_m=117.75)
        out.insert(0, {'name': "seft's rig, 32 Hz column 1 %", 'member': 'seft servohydraulic',
                       'f_hz': 32.2, 'zeta': 0.01, 'params': params, 'v_max': 2.0})
    return out


def _pct(v):
    return '–' if v is None or not math.isfinite(v) else f'{100 * v:.2f}'


def _worst(runs: list[dict]) -> str:
    """The largest acceleration and force NRMS of the stable ``model`` runs."""
    done = [x for x in runs if x['predictor'] == 'model' and x.get('stable')]
    if not done:
        return '–'
    return (f"{_pct(max(x['nrms_a'] for x in done))}, "
            f"{_pct(max(x['nrms_f'] for x in done))}")


def monte_carlo_table(results: list[dict]) -> str:
    """The Markdown table of a Monte-Carlo run (``--monte-carlo``): per member, the plants,
    how many runs were stable, the worst NRMS x (and a, f) of the stable ones, the guard's
    verdicts against the outcomes, and the weakest designed loop on the true plants."""
    head = ('| member | plants | stable | worst x % (a, f) | guard agrees / no verdict / '
            'disagrees | design: lowest crossover [Hz], PM [deg], GM |')
    lines = [head, '|' + '---|' * 6]
    members = sorted({r['member'] for r in results}, key=list(FAMILY_MEMBERS + (
        'seft servohydraulic',)).index)
    for member in members:
        rs = [r for r in results if r['member'] == member]
        runs = [x for r in rs for x in r.get('runs', [])]
        stable = [x for x in runs if x.get('stable')]
        verdicts = [(x.get('guard'), x.get('stable')) for x in runs]
        agree = sum(isinstance(g, bool) and g == o for g, o in verdicts)
        none = sum(not isinstance(g, bool) for g, _ in verdicts)
        designs = [r['true'] for r in rs if 'true' in r]
        worst = '–'
        if stable:
            peak = {k: _pct(max(x[k] for x in stable)) for k in ('nrms_x', 'nrms_a', 'nrms_f')}
            worst = f"{peak['nrms_x']} ({peak['nrms_a']}, {peak['nrms_f']})"
        design = (f"{min(d['crossover_hz'] for d in designs):.1f}, "
                  f"{min(d['phase_margin_deg'] for d in designs):.0f}, "
                  f"{min(d['gain_margin'] for d in designs):.2f}" if designs else '–')
        errors = sum('error' in r for r in rs)
        lines.append(f'| {member} | {len(rs)}' + (f' ({errors} not identified)' if errors else '')
                     + f' | {len(stable)} of {len(runs)} | {worst} | {agree} / {none} / '
                     f'{len(verdicts) - agree - none} | {design} |')
    return '\n'.join(lines)


def table(results: list[dict]) -> str:
    """The Markdown table of the results."""
    head = ('| plant | specimen | order | crossover [Hz] | PM [deg] | GM | d | '
            'x % alpha 0.5 | 1.0 | 1.5 | adaptive 20 % off, 1.0 | a, f % (worst model run) | '
            'guard agrees |')
    lines = [head, '|' + '---|' * 13]
    for r in results:
        if 'error' in r:
            lines.append(f"| {r['member']} | {r['f_hz']:g} Hz {100 * r['zeta']:g} % | "
                         f"{r['error']} |" + ' |' * 10)
            continue
        t = r['true']
        cells = []
        agree = True
        for run in r['runs']:
            if run.get('stable'):
                cells.append(_pct(run.get('nrms_x')))
            else:
                cells.append('**unstable**' if 'stable' in run and run['stable'] is False
                             else 'refused: ' + str(run.get('error', '?'))[:40] + '...')
            guard = run.get('guard')
            if isinstance(guard, bool) and isinstance(run.get('stable'), bool) \
                    and guard != run['stable']:
                agree = False
        lines.append(f"| {r['member']} | {r['f_hz']:g} Hz {100 * r['zeta']:g} % | "
                     f"{r['plant_order']} | {t['crossover_hz']:.1f} | "
                     f"{t['phase_margin_deg']:.0f} | {t['gain_margin']:.2f} | "
                     f"{r['loop_delay_steps']} | " + ' | '.join(cells)
                     + f" | {_worst(r['runs'])} | {'yes' if agree else '**no**'} |")
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='specimens 2, 10, 32, 50 Hz only')
    ap.add_argument('--members', nargs='+', default=list(FAMILY_MEMBERS))
    ap.add_argument('--specimens', nargs='+', type=float)
    ap.add_argument('--damping', nargs='+', type=float, default=list(DAMPING))
    ap.add_argument('--monte-carlo', type=int, default=0, metavar='N',
                    help='N spread plants per member (+-30 %%), the 32 Hz 1 %% specimen')
    ap.add_argument('--record', default='default', help="a record for the tests ('default')")
    ap.add_argument('--alphas', nargs='*', type=float, default=list(ALPHAS),
                    help='the mass ratios of the model runs (Monte Carlo: 1.0, as the '
                    "issue's target; none: the adaptive run alone)")
    ap.add_argument('--no-adaptive', action='store_true', help='skip the adaptive run')
    ap.add_argument('--no-rig', action='store_true', help="skip seft's rig with the column")
    ap.add_argument('--noise', type=noise_parameters, default={}, metavar='F|KEY=V,...',
                    help="the sensors' declared noise in every run: a load cell's noise F "
                    '[N] with the proportionate set (displacement 2e-6 m, velocity 2e-5 m/s, '
                    'acceleration 0.01 m/s^2 per N), or force=,displacement=,velocity=,'
                    'acceleration=,seed= (the others noise-free)')
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--json', help='write the results there')
    ap.add_argument('--write', help='a docs page to put the table in (between markers)')
    ap.add_argument('--from-json', metavar='FILE', help='no runs: the table of the results '
                    'a previous --json wrote (all of them, or those done when it was stopped)')
    args = ap.parse_args(argv)
    if args.from_json:
        with open(args.from_json) as fh:
            return _report(json.load(fh), args.write, args.monte_carlo)
    specimens = args.specimens or ((2.0, 10.0, 32.0, 50.0) if args.quick else SPECIMEN_HZ)
    if args.monte_carlo:
        todo = cases(args.members, (32.0,), (0.01,), spread=0.3,
                     seeds=range(1, args.monte_carlo + 1), stiff=False)
    else:
        todo = cases(args.members, specimens, args.damping, stiff=not args.no_rig)
    for c in todo:
        c.update(record=args.record, alphas=tuple(args.alphas), adaptive=not args.no_adaptive)
        c['params'].update(args.noise)
    print(f'{len(todo)} plants x specimens, {args.workers} workers; load: '
          f'{os.getloadavg()[0]:.2f}' + (f'; noise {args.noise}' if args.noise else ''),
          flush=True)
    results = []
    with ProcessPoolExecutor(args.workers) as pool:
        for r in pool.map(lab_path, todo):
            results.append(r)
            if args.json:                      # after each case: a stopped run keeps its results
                with open(args.json, 'w') as fh:
                    json.dump(results, fh, indent=1, default=float)
            if 'error' in r:
                print(f"{r['case']}: {r['error']}", flush=True)
                continue
            t = r['true']
            runs = ', '.join(f"{x['predictor']} {x['alpha']:g}: "
                             + (_pct(x.get('nrms_x')) + ' %' if x.get('stable') else
                                'UNSTABLE' if 'stable' in x else x.get('error', '?'))
                             for x in r['runs'])
            print(f"{r['case']}: order {r['plant_order']}, fc {t['crossover_hz']:.1f} Hz, PM "
                  f"{t['phase_margin_deg']:.0f}, GM {t['gain_margin']:.2f}, d "
                  f"{r['loop_delay_steps']}; {runs} ({r['seconds']:.0f} s)", flush=True)
    return _report(results, args.write, args.monte_carlo)


def _report(results: list[dict], write: str | None, monte_carlo: int = 0) -> int:
    """Print the table (the Monte-Carlo summary with `monte_carlo`); with `write`, put it in
    that docs page between its markers."""
    text = monte_carlo_table(results) if monte_carlo else table(results)
    print(text)
    if write:
        with open(write) as fh:
            page = fh.read()
        kind = 'monte carlo' if monte_carlo else 'table'
        start, end = f'<!-- own_actuator {kind} -->', f'<!-- end own_actuator {kind} -->'
        if start not in page or end not in page:
            print(f'{write}: no markers {start} ... {end}', file=sys.stderr)
            return 2
        page = page[:page.index(start) + len(start)] + '\n' + text + '\n' + page[page.index(end):]
        with open(write, 'w') as fh:
            fh.write(page)
    return 0


if __name__ == '__main__':
    sys.exit(main())
