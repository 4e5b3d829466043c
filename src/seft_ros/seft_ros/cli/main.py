"""The ``seft`` command line: run, simulate, compare, stability, identify (thin verbs over
``seft_ros.cli.api``).

Every :class:`~seft_msgs_py.errors.SeftError` (bad file, bad parameter, failed node) is printed as
one line
``seft: error: ...`` with exit code 2. Ctrl-C, SIGTERM and SIGHUP (the terminal closed, an SSH
session dropped) stop a run safely and print one line that says what was reached, with exit
code 128 + the signal's number: 130, 143, 129.
"""

import signal
import sys
import threading


def _interrupted_on_start(signum, frame):
    """A stop signal while ``seft`` imports its modules (seconds on a loaded host): one line,
    not a traceback through scipy's imports."""
    print(f'seft: interrupted by {_said(signal.Signals(signum).name)} while starting; nothing '
          'was run', file=sys.stderr, flush=True)
    raise SystemExit(128 + signum)


def _said(signame: str) -> str:
    """A signal's name as the last line says it."""
    return {'SIGINT': 'Ctrl-C (SIGINT)', 'SIGHUP': 'SIGHUP (hang-up)'}.get(signame, signame)


if (threading.current_thread() is threading.main_thread()
        and sys.argv[:1] and sys.argv[0].rsplit('/', 1)[-1] == 'seft'):
    # the `seft` command (its console script), not a test or a tool that imports this module
    for _signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(_signum, _interrupted_on_start)

import argparse  # noqa: E402  (after the start-up's signal handlers)
import contextlib  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402

from seft_msgs_py import parameters  # noqa: E402
from seft_msgs_py.errors import InputError, Interrupted, SeftError  # noqa: E402
from seft_msgs_py.stopping import STOP_SIGNALS, raise_stop, signal_name  # noqa: E402
from seft_plant_sim.faults import CONTROLLER_FAULTS, FAULTS, SENSOR_FAULTS  # noqa: E402
from seft_ros.cli import api, partition  # noqa: E402
from seft_ros.cli.arguments import OneLineParser  # noqa: E402
from seft_ros.cli.config import repeated  # noqa: E402
from seft_ros.cli.live import options_from_args  # noqa: E402
from seft_ros.cli.spawn import node_start  # noqa: E402
from seft_ros.core.reference_force import PREDICTORS  # noqa: E402

#: The rig models of --rig (the parameter rig_model's choices).
RIG_CHOICES = parameters.spec('rig_model').choices

__all__ = ['main', 'build_parser']


def _set_value(text: str):
    """``NAME=VALUE`` split; the value stays text until :func:`_typed` reads it by the
    schema's type."""
    if '=' not in text:
        raise argparse.ArgumentTypeError(f'--set {text!r}: expected NAME=VALUE')
    name, value = text.split('=', 1)
    return name.strip(), value


#: The parameters of the experiment options (``dest`` -> the option): ``--set NAME=...`` and
#: the option on one command line are refused, as is an option given twice.
OPTIONS = {'record': '--record', 'rig_model': '--rig', 'predictor': '--predictor',
           'amplitude_N': '--amplitude', 'scale_factor': '--scale', 'time_scale': '--time-scale',
           'duration_s': '--duration', 'mode': '--mode'}
#: Parameters that a given option sets too (``n_steps`` is the run's length, as --duration).
ALSO_SET_BY = {'n_steps': 'duration_s'}


class _Once(argparse.Action):
    """Store the value; an option given twice is noted in ``args.repeated`` (refused with a
    line of its own by :func:`_check_options`, not kept as the last)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest, None) is not None:
            namespace.repeated = [*getattr(namespace, 'repeated', []), option_string]
        setattr(namespace, self.dest, values)


def _typed(sets, *, alpha: bool = False, given: dict[str, str] | None = None):
    """``--set`` values read by each parameter's type in the schema (not by YAML's guessing:
    ``tau_s=1e-12`` is a float), checked against its range. `given`: the parameters whose
    option is on the command line (name -> option): their ``--set`` is refused."""
    out = []
    for name, text in sets:
        if name == 'alpha' and not alpha:
            raise InputError('--set alpha: use --alpha')
        option = (given or {}).get(name)
        if option is not None:
            raise InputError(f'--set {name}={text}: {option} is given too; expected the value '
                             'once')
        if name not in parameters.defaults():
            raise InputError(f'command line: --set {name}={text}: '
                             f'{parameters.unknown_parameter(name)}')
        out.append((name, parameters.from_text(name, text, where='command line')))
    return out


def _node_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(',') if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f'--nodes {text!r}: expected NAME[,NAME...]')
    return names


def _experiment_options(p: argparse.ArgumentParser) -> None:
    d = parameters.defaults()

    def default(name: str) -> str:
        """The help's default of an option: the configuration's, else the schema's (a new
        user's CSV played twice as fast by the study's time_scale 0.5, which no help named,
        session 36)."""
        value = d[name]
        return f"default: the configuration's, else {value:g}" if isinstance(
            value, float) else f"default: the configuration's, else {value!r}"
    p.add_argument('config', nargs='?', help='configuration YAML (ROS 2 parameter file; '
                   'alpha may be a list)')
    p.add_argument('--record', action=_Once, nargs='+', metavar='FILE',
                   help="ground motion(s): 'default', a PEER .AT2 or a CSV path (several: one "
                   "run per record, predictor and alpha, each run's directory named by the "
                   "record's file stem; records of the same stem by their folder too, "
                   f"rec2_dt001, else by their position, dt001-2; {default('record')}: the "
                   'embedded synthetic record)')
    p.add_argument('--alpha', action=_Once, type=float, nargs='+', metavar='A',
                   help="mass ratio(s) (a run's directory alpha_<A>_...: A to every digit "
                   f"that tells it from another; {default('alpha')})")
    p.add_argument('--rig', action=_Once, dest='rig_model', choices=RIG_CHOICES,
                   help="simulated rig model ('state_space': the rig_plant_model, else the "
                   "plant_model; 'actuator': "
                   f"the family of actuators, actuator_family; {default('rig_model')})")
    p.add_argument('--predictor', action=_Once, nargs='+', metavar='NAME',
                   help='delay compensation(s): ' + ', '.join(map(repr, PREDICTORS))
                   + f" (several: one run per predictor and alpha; {default('predictor')})")
    p.add_argument('--amplitude', action=_Once, dest='amplitude_N', type=float, metavar='N',
                   help=f"peak of m*xg'' [N] (0: use --scale; {default('amplitude_N')})")
    p.add_argument('--scale', action=_Once, dest='scale_factor', type=float,
                   help='plain amplitude factor (instead of --amplitude: amplitude_N is 0)')
    p.add_argument('--time-scale', action=_Once, dest='time_scale', type=float,
                   help="record time scale: the record's time step times this "
                   f"({default('time_scale')}, the study's: the record plays in half its "
                   'time; 1: as recorded)')
    p.add_argument('--duration', action=_Once, dest='duration_s', type=float, metavar='S',
                   help='run length after time scaling [s] (0: whole record)')
    p.add_argument('--params', dest='params_files', action='append', default=[],
                   metavar='FILE', help='parameter file layered over CONFIG (repeatable, '
                   'the first wins; e.g. the --params file of seft identify: its rigs '
                   "sections merge into CONFIG's); the options above and --set win")
    p.add_argument('--set', dest='sets', type=_set_value, action='append', default=[],
                   metavar='NAME=VALUE', help='any other parameter (repeatable)')
    p.add_argument('--out', action=_Once, help='output directory (default runs/<name>/)')
    p.add_argument('--name', action=_Once, help='run name, not a path (default: the config '
                   'file name, or "run")')
    p.add_argument('--force', action='store_true', help='run even when a run is predicted '
                   'unstable by the stability map, or a real-time run needs more than its '
                   "actuator's capacity (warn instead of refusing)")
    p.add_argument('--strict', action='store_true', help="refuse a run whose analytical "
                   "reference exceeds a rig's sensor range or actuator capacity (default: one "
                   'warning line per channel before the run)')
    p.add_argument('--fail-on-abort', action='store_true', help='exit code 3 when a run was '
                   "aborted (the monitor, the interlock, a watchdog, the operator's stop, a "
                   'lost host) that the stability guard had not predicted unstable (default: '
                   'an aborted run is a result, exit code 0; summary.json has each verdict)')


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``seft``."""
    parser = OneLineParser(prog='seft', description='Substructure effective force testing '
                     '(force-based real-time hybrid simulation) on ROS 2.')
    sub = parser.add_subparsers(dest='verb', required=True, parser_class=OneLineParser)
    parser.verbs = sub.choices
    run = sub.add_parser('run', help='run experiments as a node graph over DDS (bag + report)')
    _experiment_options(run)
    run.add_argument('--mode', choices=('lockstep', 'realtime'),
                     help="'lockstep' (default: every node waits for its inputs; equals "
                     "simulate bit for bit) or 'realtime' (the rig ticks on the wall clock "
                     'every dt, nobody waits; timing recorded and reported)')
    run.add_argument('--domain-id', type=int, help='ROS_DOMAIN_ID of the run (default: '
                     '$ROS_DOMAIN_ID, else a random one in 100-199)')
    run.add_argument('--nodes', type=_node_list, metavar='NAME[,NAME...]',
                     help='start only these nodes of the graph (recorder, '
                     'ground_motion_publisher, reference_force_builder, '
                     'force_servo_controller, rig; <rig>/<node> for a rig of a structure); '
                     'the others run on another host with the same ROS_DOMAIN_ID and '
                     'parameters. The host with the recorder writes the bag and the report')
    run.add_argument('--partition', choices=partition.PARTITIONS,
                     help="how the test is split over hosts: 'loop_local' (default with "
                     '--site: the builder beside each rig, the network out of the loop) or '
                     "'builder_remote' (the builder on the compute host)")
    run.add_argument('--site', metavar='SITE', help="start the nodes of this site of the "
                     "partition: 'compute', and 'lab' (the study's rig) or a structure's rig")
    run.add_argument('--processes', choices=partition.PROCESSES, default=partition.PROCESSES[0],
                     help="'node' (default): one process per node, as ros2 run starts them; "
                     "'loop': the nodes that close each rig's loop (its rig, force servo "
                     'controller and the builder of its namespace) in one process, ROS 2 '
                     'composition: less CPU, no transport between them (tools/hosts.sh '
                     'uses it)')
    run.add_argument('--live', nargs='?', const='', metavar='HOST[:PORT]',
                     help='watch the runs live: a Foxglove WebSocket server at HOST:PORT and a '
                     'web page at HOST:PORT+1 (default 127.0.0.1:8765, this machine only; '
                     'another address needs the token of $SEFT_LIVE_TOKEN, made and printed '
                     'if unset); the URLs are printed at start')
    run.add_argument('--live-tls', nargs=2, metavar=('CERT', 'KEY'),
                     help='serve the live view over TLS (https, wss) with this PEM '
                     'certificate and private key')
    run.add_argument('--live-stop', action='store_true',
                     help="put an operator's stop button on the live view's page (the rig "
                     'goes to its safe state; the bag names who stopped it)')
    sites = sub.add_parser('sites', help='which nodes each host starts when a run is split over '
                           'hosts (the options of seft run; one line per site)')
    _experiment_options(sites)
    sites.add_argument('--mode', choices=('lockstep', 'realtime'), help='as seft run')
    sites.add_argument('--partition', choices=partition.PARTITIONS,
                       default=partition.DEFAULT_PARTITION, help='the split (default: '
                       f'{partition.DEFAULT_PARTITION})')
    sim = sub.add_parser('simulate', help='the same experiments in one process, without ROS')
    _experiment_options(sim)
    sim.add_argument('--bag', action='store_true', help="also write each run's bag "
                     '(DIR/<run>/bag), the bag the node graph records')
    ident = sub.add_parser('identify', help='identify each rig from the bags of '
                           'identification runs (frequency responses, fits, delay, loop '
                           'margins, its specimen m, c, k)')
    ident.add_argument('bags', nargs='+', metavar='BAG', help='a bag, a run directory or a '
                       'folder of run directories')
    ident.add_argument('--out', help='output directory (default runs/identify/)')
    ident.add_argument('--window', default='hann', help="Welch window (default 'hann')")
    ident.add_argument('--nperseg', type=int, metavar='N', help='Welch segment length '
                       '[samples] (default 1024)')
    ident.add_argument('--noverlap', type=int, metavar='N', help='Welch overlap [samples] '
                       '(default nperseg/2)')
    ident.add_argument('--orders', type=int, nargs=2, metavar=('NB', 'NA'), help='orders of '
                       'the rational fit in z^-1 (default 6 4 open loop, 8 6 closed loop)')
    ident.add_argument('--params', dest='params_out', metavar='FILE', help='write a '
                       'parameter file (for seft run CONFIG --params FILE): the closed-loop '
                       'delay; with an open-loop bag, the identified plant model and a force '
                       'controller designed for it, which REPLACES the configured one, with '
                       "its compensators' settings; of a structure's bags, a rigs section "
                       'per rig with its specimen too')
    des = sub.add_parser('design', help="design each rig's force controller from the model "
                         "of its force loop (plant_model, or seft's rig model): crossover, "
                         'margins, control-structure interaction')
    des.add_argument('config', nargs='?', help='configuration YAML (the rig, its plant_model '
                     "or seft's rig parameters, the specimen)")
    des.add_argument('--params', dest='params_files', action='append', default=[],
                     metavar='FILE', help='parameter file layered over CONFIG (e.g. the one '
                     'seft identify --params wrote: its plant_model)')
    des.add_argument('--set', dest='sets', type=_set_value, action='append', default=[],
                     metavar='NAME=VALUE', help='any other parameter (repeatable)')
    des.add_argument('--phase-margin', type=float, default=45.0, metavar='DEG',
                     help='the least phase margin [deg] (default 45)')
    des.add_argument('--gain-margin', type=float, default=2.0, metavar='G',
                     help='the least gain margin [-] (default 2, 6 dB)')
    des.add_argument('--crossover-hz', type=float, default=0.0, metavar='HZ',
                     help='the crossover to aim at [Hz] (default 0: the highest the margins '
                     'allow)')
    des.add_argument('--uncertainty', type=float, default=0.05, metavar='U',
                     help="the plant model's relative error the margins must survive "
                     '(default 0.05)')
    des.add_argument('--out', metavar='FILE', help='write the controller and the '
                     "compensators' settings as a parameter file (for --params)")
    cmp_ = sub.add_parser('compare', help='compare recorded bags against the analytical '
                          'reference (figures, table, summary.json)')
    cmp_.add_argument('bags', nargs='+', metavar='BAG', help='a bag, a run directory '
                      '(with bag/) or a folder of run directories (one report of the sweep)')
    cmp_.add_argument('--out', help='output directory (default runs/compare/)')
    cmp_.add_argument('--replay-timing', action='store_true',
                      help="replay each real-time run of seft's simulated rigs in process, "
                      'as it ran and with every step in time: what its late commands and '
                      "stale steps cost it (the host's timing, not the method)")
    rcheck = sub.add_parser('rig-check', help='check a rig node against the rig contract: '
                            'short real-time runs of the rest of the graph at a small force, '
                            'one line per check (docs/rig_contract.md)')
    rcheck.add_argument('config', nargs='?', help='configuration YAML of the test (the rig, '
                        'the specimen, dt; a structure: each of its rigs in turn)')
    rcheck.add_argument('--rig', dest='rig_model', choices=RIG_CHOICES,
                        help='rig model (what the graph sends the rig: the reference force, '
                        'or the valve command of the force servo controller)')
    rcheck.add_argument('--rig-command', metavar='CMD', help='the command that starts the '
                        'rig node (any language; {params} is replaced by the parameter file, '
                        "else --ros-args --params-file FILE is appended); default seft's "
                        'simulated rig')
    rcheck.add_argument('--amplitude', type=float, default=100.0, metavar='N',
                        help="static force and sine amplitude [N] (default 100; the rig's "
                        'force limit becomes 5 times this during the check)')
    rcheck.add_argument('--sine-hz', type=float, default=2.0, metavar='HZ',
                        help="frequency of the safe-state runs' sine [Hz] (default 2)")
    rcheck.add_argument('--runs', type=_node_list, metavar='RUN[,RUN...]',
                        help='only these runs: step, abort, stopped_controller, watchdog '
                        '(default all; the checks of the others fail as not measured)')
    rcheck.add_argument('--params', dest='params_files', action='append', default=[],
                        metavar='FILE', help='parameter file layered over CONFIG')
    rcheck.add_argument('--set', dest='sets', type=_set_value, action='append', default=[],
                        metavar='NAME=VALUE', help='any other parameter (repeatable)')
    rcheck.add_argument('--rig-name', metavar='RIG', help='a structure test: check this rig '
                        '(in its namespace, with its own parameters) only; default every rig '
                        'in turn')
    rcheck.add_argument('--inject', metavar='FAULT', choices=FAULTS, help="wrap seft's "
                        'simulated rig with one wiring fault, to see what it looks like: '
                        + ', '.join(FAULTS) + ' (docs/rig_contract.md)')
    rcheck.add_argument('--out', help='output directory (default runs/rig-check/)')
    rcheck.add_argument('--domain-id', type=int, help='ROS_DOMAIN_ID (as seft run)')
    emu = sub.add_parser('emulate-controller', help="emulate a lab's real-time controller "
                         "at the far end of the UDP bridge: seft's simulated rig on its own "
                         'clock behind udp_controller_address (JSON lines of what happens)')
    emu.add_argument('config', nargs='?', help='configuration YAML (the rig, the specimen, '
                     'dt, udp_* parameters): the one the rig node takes')
    emu.add_argument('--rig', dest='rig_model', choices=RIG_CHOICES,
                     help="the plant: 'delay' takes the force reference, the others the valve "
                     'voltage')
    emu.add_argument('--runs', type=int, metavar='N', help='serve N runs, then exit (default: '
                     'until Ctrl-C)')
    emu.add_argument('--inject', metavar='FAULT', choices=SENSOR_FAULTS + tuple(
        CONTROLLER_FAULTS), help='send the measurement with one wiring fault (a lab '
        "controller's): " + ', '.join(SENSOR_FAULTS) + '; or break the session rules: '
        + ', '.join(CONTROLLER_FAULTS) + ' (a test fault: seft rig-check fails its second '
        'sender check)')
    emu.add_argument('--params', dest='params_files', action='append', default=[],
                     metavar='FILE', help='parameter file layered over CONFIG')
    emu.add_argument('--set', dest='sets', type=_set_value, action='append', default=[],
                     metavar='NAME=VALUE', help='any other parameter (repeatable)')
    stab = sub.add_parser('stability', help='largest stable alpha over the delay per predictor '
                          "from the sampled loop's eigenvalues (stability.png, .json, table)")
    stab.add_argument('config', nargs='?', help='configuration YAML (rig, specimen, dt; '
                      'its alpha(s) and delay are marked on stability.png; of a structure the '
                      'map is of the coupling scale, the configured test at 1)')
    stab.add_argument('--rig', dest='rig_model', choices=RIG_CHOICES,
                      help='simulated rig model')
    stab.add_argument('--predictor', dest='predictors', nargs='+', metavar='NAME',
                      help='predictors to map (default: all registered)')
    stab.add_argument('--tau-min', type=float, metavar='S', help='first delay [s] (tau_s of '
                      'the delay rig, io_latency_s of the servohydraulic rig)')
    stab.add_argument('--tau-max', type=float, metavar='S', help='last delay [s] (default '
                      '0.02 on the delay rig, 0.01 on the servohydraulic rig)')
    stab.add_argument('--points', type=int, metavar='N', help='number of delays (default: '
                      "0.5 ms spacing; a structure's map: 6)")
    stab.add_argument('--alpha-max', type=float, default=3.0, metavar='A',
                      help='upper end of the search in alpha (default 3)')
    stab.add_argument('--set', dest='sets', type=_set_value, action='append', default=[],
                      metavar='NAME=VALUE', help='any other parameter (repeatable)')
    stab.add_argument('--out', help='output directory (default runs/stability/)')
    return parser


def _interrupt(signum, frame):
    raise_stop(signal.Signals(signum).name)


def _say(text: str, stream=None) -> None:
    """Print a line (stderr by default); a terminal that is gone (a hang-up: writes fail
    with EIO) takes nothing more, and the command goes on ending the run safely."""
    try:
        out = stream or sys.stderr
        out.write(text + '\n')         # one write: a signal does not split the line from its end
        out.flush()
    except OSError:
        devnull = open(os.devnull, 'w')
        sys.stdout = sys.stderr = devnull


def _progress(text: str) -> None:
    _say(f'[seft] {text}')


def _check_options(args) -> dict[str, str]:
    """Refuse what the experiment options would otherwise lose: an option given twice, the
    same run twice in a list (``--alpha 0.5 0.5``), a run name that is a path. Returns the
    parameters an option on the command line sets (name -> option; :func:`_typed`)."""
    for option in getattr(args, 'repeated', ()):
        several = f' ({option} A B: one run per value)' if option in (
            '--record', '--alpha', '--predictor') else ''
        raise InputError(f'{option}: given twice; expected it once{several}')
    for name in ('record', 'alpha', 'predictor'):
        values = getattr(args, name)
        if values and repeated(name, values) is not None:
            raise InputError(f'--{name} {" ".join(map(str, values))}: the same run twice; '
                             'expected each value once')
    name = args.name
    if name is not None and (not name.strip() or name in ('.', '..') or '/' in name
                             or (os.altsep and os.altsep in name)):
        raise InputError(f"--name {name!r}: expected a run name, not a path (no '/', not "
                         "'.' or '..')")
    given = {p: opt for p, opt in OPTIONS.items() if getattr(args, p, None) is not None}
    given.update({p: OPTIONS[by] for p, by in ALSO_SET_BY.items() if by in given})
    return given


def _build(args):
    """The runs of an experiment's options (config, options, --params, --set)."""
    given = _check_options(args)
    overrides = {k: getattr(args, k) for k in ('record', 'rig_model', 'predictor',
                                               'amplitude_N', 'scale_factor', 'time_scale',
                                               'duration_s')}
    overrides['mode'] = getattr(args, 'mode', None)
    for name, value in _typed(args.sets, given=given):
        overrides[name] = value
    if args.scale_factor is not None:          # --scale is the amplitude: amplitude_N 0
        amplitude = overrides.get('amplitude_N')
        if amplitude is None:
            overrides['amplitude_N'] = 0.0
        elif amplitude != 0:
            raise InputError(f'--scale {args.scale_factor:g}: an amplitude of {amplitude:g} N '
                             'is given too; expected one of them (--scale with no amplitude '
                             'or --amplitude 0)')
    return api.build_runs(config=args.config, overrides=overrides, alphas=args.alpha,
                          params_files=args.params_files, progress=_progress)


def _experiments(args):
    runs = _build(args)
    if getattr(args, 'site', None) or getattr(args, 'partition', None):
        if args.nodes:
            raise InputError('--nodes: give either --nodes or --partition/--site, not both')
        chosen = args.partition or partition.DEFAULT_PARTITION
        runs = [partition.partition_parameters(p, chosen) for p in runs]
        if args.site:
            args.nodes = partition.site_nodes(runs[0], chosen, args.site)
            os.environ.setdefault('SEFT_SITE', args.site)    # this host in the link figures
    if args.verb == 'simulate' and any(p.get('mode') == 'realtime' for p in runs):
        raise InputError('parameter mode=realtime: seft simulate has no wall clock (it is the '
                         'lockstep graph in one process); use seft run --mode realtime')
    if args.verb == 'run':
        api.check_realtime_rigs(runs)
    api.run_labels(runs)                  # each run its own directory, before anything starts
    from pathlib import Path
    name = args.name or (Path(args.config).stem if args.config else 'run')
    return runs, api.output_dir(out=args.out, name=name, created=args.created), name


def _stability(args) -> int:
    overrides = {'rig_model': args.rig_model}
    given = {p: o for p, o, v in (('rig_model', '--rig', args.rig_model),
                                  ('predictor', '--predictor', args.predictors)) if v}
    for name, value in _typed(args.sets, alpha=True, given=given):
        overrides[name] = value
    out = api.output_dir(out=args.out, name='stability', created=args.created)
    result = api.stability_report(out_dir=out, config=args.config, overrides=overrides,
                                  predictors=args.predictors, tau_min=args.tau_min,
                                  tau_max=args.tau_max, points=args.points,
                                  alpha_max=args.alpha_max)
    print(api.stability_table(result))
    print(f'plot: {result.png_path}')
    print(f'map: {result.json_path}')
    return 0


def _identify(args) -> int:
    out = api.output_dir(out=args.out, name='identify', created=args.created)
    result = api.identify_bags(bags=args.bags, out_dir=out, window=args.window,
                               nperseg=args.nperseg, noverlap=args.noverlap,
                               orders=tuple(args.orders) if args.orders else None,
                               params_out=args.params_out)
    print(api.identification_table(result.document))
    print(f'report: {out / "identification.md"}')
    print(f'data: {out / "identification.json"}')
    print(f'figures: {out} ({", ".join(sorted(p.name for p in out.glob("*.png")))})')
    if result.params_path is not None:
        print(f'parameters: {result.params_path}')
    if result.kept is not None:
        print(f'the parameter file it replaced: kept as {result.kept}')
    return 0


def _design(args) -> int:
    result = api.design_controllers(config=args.config, overrides=dict(_typed(args.sets)),
                                    params_files=args.params_files, out=args.out,
                                    phase_margin_deg=args.phase_margin,
                                    gain_margin=args.gain_margin,
                                    crossover_hz=args.crossover_hz,
                                    uncertainty=args.uncertainty, progress=_progress)
    for rig, d in result.designs.items():
        label = f'rig {rig}: ' if rig else ''
        print(f'{label}{d.summary()}')
        print(f'{label}force-loop inverse {d.loop_delay_steps} steps, {d.loop_taps} taps (miss '
              f'{100 * d.inverse_band_error:.2g} % up to 25 Hz), closed-loop delay '
              f'{1e3 * d.equivalent_delay_s:.1f} ms; targets '
              + ('met' if d.met else 'NOT met: ' + '; '.join(d.notes)))
        for warning in [api.predicted_error_warning(d.to_json())] + d.warnings:
            if warning:
                print(f'{label}WARNING: {warning}')
    for choice in result.inverse_choices:
        print(choice.summary())
    if result.params_path is not None:
        print(f'parameters: {result.params_path}')
    return 0 if all(d.met for d in result.designs.values()) else 1


def _rig_runs(args) -> list[dict]:
    """The runs of a rig's options (config, --rig, --params, --set) for rig-check and
    emulate-controller."""
    overrides = {'rig_model': args.rig_model}
    given = {'rig_model': '--rig'} if args.rig_model else {}
    overrides.update(dict(_typed(args.sets, alpha=True, given=given)))
    return api.build_runs(config=args.config, overrides=overrides,
                          params_files=args.params_files, progress=_progress)


def _one_rig(args, verb: str) -> dict:
    """The parameters of one rig (:func:`_rig_runs`), for emulate-controller."""
    runs = _rig_runs(args)
    if runs[0].get('structure', 'none') != 'none':
        raise InputError(f'seft {verb} takes one rig: the configuration is a structure; give '
                         "a one-rig configuration (a rig's own section)")
    if len(runs) != 1:
        # name what makes several runs (it said 'expected one alpha' for config/main.yaml,
        # whose two predictors made two runs with alpha set; session 39)
        lists = {name: sorted({str(r.get(name)) for r in runs})
                 for name in parameters.LIST_PARAMETERS}
        several = ', '.join(f"{name} [{', '.join(values)}]"
                            for name, values in lists.items() if len(values) > 1)
        raise InputError(f'seft {verb} takes one run of one rig: the configuration gives '
                         f'{len(runs)} runs ({several}); give one of each, e.g. '
                         + ' '.join(f'--set {name}={values[0]}'
                                    for name, values in lists.items() if len(values) > 1))
    return runs[0]


def _emulate(args) -> int:
    from seft_plant_sim.udp_emulator import ControllerEmulator, serve_until_stopped
    params = _one_rig(args, 'emulate-controller')
    if args.runs is not None and args.runs < 1:
        raise InputError(f'--runs {args.runs}: expected a number of runs >= 1')
    controller_fault = args.inject if args.inject in CONTROLLER_FAULTS else None
    emulator = ControllerEmulator(
        params, fault=FAULTS[args.inject] if args.inject and not controller_fault else None,
        controller_fault=controller_fault)
    host, port = emulator.address
    serve_until_stopped(
        emulator, args.runs, int(params['realtime_priority']),
        announce=lambda: _progress(
            f"emulating the lab's controller at {host}:{port}: {params['rig_model']} rig, dt "
            f"{1e3 * params['dt']:g} ms, watchdog {1e3 * params['watchdog_timeout_s']:g} ms"
            + (f'; fault injected: {args.inject}' if args.inject else '') + ' (Ctrl-C ends)'))
    return 0


def _check_params(args) -> dict:
    """The test's parameters for rig-check (:func:`_rig_runs`): a sweep's first run, with its
    largest alpha (the check runs at alpha 0; its noise check weighs the fed-back
    acceleration by the test's alpha)."""
    runs = _rig_runs(args)
    return dict(runs[0], alpha=max(float(r.get('alpha', 0.0)) for r in runs))


def _rig_check(args) -> int:
    from seft_ros.cli import rig_check
    from seft_ros.core.rig_check import CheckProfile
    rigs = rig_check.structure_rigs(_check_params(args), args.rig_name)
    profile = CheckProfile(dt=float(rigs[0][1]['dt']), amplitude_N=args.amplitude,
                           sine_hz=args.sine_hz)
    for _, p in rigs:
        if args.inject:
            rig_check.fault_rig_command(args.inject, p)       # a fault it cannot take: now
    api.check_domain(args.domain_id)
    node_start()                                   # $SEFT_NODE_START, before anything runs
    out = api.output_dir(out=args.out, name='rig-check')
    passed = []
    for rig, params in rigs:
        if rig:
            print(f'rig {rig} (namespace /{rig}, its parameters from rigs.{rig}):', flush=True)
        report = rig_check.run_rig_check(params=params, out_dir=out / rig if rig else out,
                                         profile=profile, rig_command=args.rig_command,
                                         inject=args.inject, runs=args.runs or rig_check.RUNS,
                                         domain_id=args.domain_id, progress=_progress)
        for line in rig_check.main_lines(report, rig):
            print(line, flush=True)
        passed.append(report.passed)
    if len(rigs) > 1:
        failed = [r for (r, _), ok in zip(rigs, passed) if not ok]
        print(f'rig-check: {len(rigs) - len(failed)} of {len(rigs)} rigs passed'
              + (f'; failed: {", ".join(failed)}' if failed else ''))
    return 0 if all(passed) else 1


def main(argv=None) -> int:
    """Entry point of ``seft``; returns the exit code."""
    # SIGTERM and SIGHUP end a run as Ctrl-C does (rig to its safe state, bags closed), not
    # the runner alone with its nodes left running; each is named in the last line
    previous = {s: signal.signal(s, _interrupt) for s in STOP_SIGNALS}
    code, args = 1, None
    try:
        args = build_parser().parse_args(argv)
        args.created = []       # directories this command made: removed if it fails empty
        code = _main(args)
        return code
    except KeyboardInterrupt as exc:
        signame = signal_name(exc)
        code = 128 + signal.Signals[signame].value
        _say(f'seft: interrupted by {_said(signame)}: {_reached(exc, args)}')
        return code
    finally:
        if code != 0 and args is not None:
            api.remove_empty_dirs(args.created)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _reached(exc: KeyboardInterrupt, args) -> str:
    """What an interrupted command had reached (the end of its last line)."""
    if isinstance(exc, Interrupted):
        return exc.state
    if args is None:
        return 'nothing was run'
    if args.verb in ('run', 'rig-check'):
        # a further signal while the run ended (the runner's, after its line said so)
        return ('left at once while the run ended; its nodes stop the run by themselves '
                '(their logs say how)')
    if args.verb in ('simulate', 'compare'):
        return f'seft {args.verb} did not finish; no report written'
    return f'seft {args.verb} did not finish'


def _main(args) -> int:
    t0 = time.monotonic()
    try:
        if args.verb == 'stability':
            return _stability(args)
        if args.verb == 'sites':
            for site, nodes in partition.sites(_build(args)[0], args.partition).items():
                print(f'{site}: {",".join(nodes)}')
            return 0
        if args.verb == 'identify':
            return _identify(args)
        if args.verb == 'design':
            return _design(args)
        if args.verb == 'rig-check':
            return _rig_check(args)
        if args.verb == 'emulate-controller':
            return _emulate(args)
        if args.verb == 'compare':
            out = api.output_dir(out=args.out, name='compare', created=args.created)
            result = api.compare_bags(bags=args.bags, out_dir=out,
                                      replay_timing=args.replay_timing, progress=_progress)
        else:
            live = None
            # a stop before the runner starts: nothing was run (not 'left while the run ended')
            with (api.interrupted_as(lambda exc: api.NOTHING_RUN) if args.verb == 'run'
                  else contextlib.nullcontext()):
                if args.verb == 'run':
                    api.check_domain(args.domain_id)    # a bad domain before anything runs
                    node_start()                        # and a bad $SEFT_NODE_START
                    live = options_from_args(args)      # and a bad --live address or pair
                runs, out, name = _experiments(args)
                _progress(f'{len(runs)} run(s) -> {out}')
            if args.verb == 'run':
                result = api.run_experiments(runs=runs, out_dir=out, progress=_progress,
                                             title=f'seft run {name}', domain_id=args.domain_id,
                                             force=args.force, nodes=args.nodes,
                                             processes=args.processes, live=live,
                                             strict=args.strict)
                if result is None:
                    print(f'this host ran {", ".join(args.nodes)}; the bag and the report are '
                          'on the host that ran the recorder')
                    print(f'took {time.monotonic() - t0:.1f} s')
                    return 0
            else:
                result = api.simulate_experiments(runs=runs, out_dir=out, progress=_progress,
                                                  title=f'seft simulate {name}',
                                                  force=args.force, bag=args.bag,
                                                  strict=args.strict)
    except SeftError as exc:
        print(f'seft: error: {exc}', file=sys.stderr)
        return 2
    print(api.summary_table(result.summary))
    criteria = api.criteria_table(result.summary)
    if criteria:
        print(criteria)
    print(f'report: {result.out_dir / "report.md"} (self-contained page: '
          f'{result.out_dir / "report.html"})')
    print(f'summary: {result.out_dir / "summary.json"}')
    print(f'took {time.monotonic() - t0:.1f} s')
    unforeseen = (unforeseen_aborts(result.summary)
                  if getattr(args, 'fail_on_abort', False) else [])   # run and simulate
    if unforeseen:
        print(f'seft: {len(unforeseen)} run(s) aborted that the stability guard had not '
              f'predicted unstable: {"; ".join(unforeseen)} (--fail-on-abort: exit code 3)',
              file=sys.stderr)
        return 3
    return 0


def unforeseen_aborts(summary: list[dict]) -> list[str]:
    """The runs of `summary` (``summary.json``'s entries) that were aborted although the
    stability guard had not predicted them unstable, each as ``run N (<predictor>, alpha A)
    at T s: <reason>``. A run the guard predicted unstable and ``--force`` ran is expected
    to abort (the study's alpha 1.5 without compensation): not listed."""
    said = []
    for i, e in enumerate(summary, start=1):
        if e.get('stable') or (e.get('stability') or {}).get('predicted_stable') is False:
            continue
        at, alpha = e.get('unstable_at_s'), e.get('alpha')     # a structure's: None
        said.append(f'run {i} ({e.get("predictor")}'
                    + (f', alpha {alpha:g})' if isinstance(alpha, (int, float)) else ')')
                    + (f' at {at:.3f} s' if at is not None else '')
                    + f': {e.get("abort_reason") or "aborted"}')
    return said


if __name__ == '__main__':
    sys.exit(main())
