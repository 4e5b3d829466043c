"""Bad input to the ``seft`` command and to a node started by hand: exit code 2 and one line.

The table of one-line errors (:data:`CASES`) runs ``seft``'s entry point in this process
(cwd in tmp, stdout and stderr captured), one case after another: as a subprocess each case
cost about a second of imports, 52-67 s of one worker for the table. The cases of
:data:`AS_PROCESS` run the installed ``seft`` as a subprocess too (isolated ROS env), so
that the console script's exit code and streams are checked for each verb.
"""

from concurrent.futures import ThreadPoolExecutor
import contextlib
import io
import json
import os
from pathlib import Path
import re
import subprocess
import sys

import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from seft_ros.cli import main

AT2_HEAD = 'PEER NGA STRONG MOTION DATABASE RECORD\nTest, 1/1/2000, STA, 0\n' \
    'ACCELERATION TIME SERIES IN UNITS OF G\n'
#: A lab's plant model of the force alone (the motion from its specimen).
PLANT = ('form: transfer_function\nnum: {{force_N: {num}}}\nden: [1.0, 100.0]\n'
         'io_delay_s: {delay}\nspecimen: {specimen}\n')
SPECIMEN = '{mass_kg: 52.7, damping_N_s_per_m: 903.3, stiffness_N_per_m: 211000.0}'
FILES = {
    'npts.AT2': AT2_HEAD + 'NPTS= abc, DT= 0.01 SEC\n0.1 0.2 0.3 0.4 0.5\n',
    'short.AT2': AT2_HEAD + 'NPTS= 12, DT= 0.01 SEC\n0.1 0.2 0.3 0.4 0.5\n0.1 0.2 0.3 0.4 0.5\n',
    'token.AT2': AT2_HEAD + 'NPTS= 10, DT= 0.01 SEC\n0.1 0.2 0.3 0.4 0.5\n0.1 0.2 0.3x 0.4 0.5\n',
    'bad.csv': 'time,acceleration\n0.0,0.1\n0.01,0.2\n0.02,abc\n',
    'cm.AT2': AT2_HEAD.replace('TIME SERIES IN UNITS OF G', 'IN CM/SEC/SEC')
    + 'NPTS= 5, DT= 0.01 SEC\n98.1 196.1 -50.0 0.0 12.0\n',
    'msec.AT2': AT2_HEAD + 'NPTS= 5, DT= 10 MSEC\n0.1 0.2 -0.05 0.0 0.012\n',
    'zeros.AT2': AT2_HEAD + 'NPTS= 5, DT= 0.01 SEC\n0.0 0.0 0.0 0.0 0.0\n',
    'mass0.yaml': 'mass_kg: 0\n',
    'alpha.yaml': 'alpha: [0.5, -1]\n',
    'dt0.yaml': 'dt: 0\n',
    'unknown.yaml': 'alpha: 0.5\nstiffnes_N_per_m: 2.0e5\n',
    'invalid.yaml': 'alpha: 0.5\nrig_model: [delay\n',
    'ros.yaml': '/**:\n  ros__parameters:\n    use_sim_time: true\n    tau_s: 2.0\n',
    'binary_plant.yaml': 'rig_model: state_space\nplant_model: binary.yaml\n',
    'zero_force.yaml': PLANT.format(num='[0.0]', delay=0.003, specimen=SPECIMEN),
    'zero_force_run.yaml': 'rig_model: state_space\nplant_model: zero_force.yaml\n',
    'long_delay.yaml': PLANT.format(num='[1.0e6]', delay=2.0, specimen=SPECIMEN),
    'long_delay_run.yaml': 'rig_model: state_space\nplant_model: long_delay.yaml\n',
    'specimen_typo.yaml': PLANT.format(num='[1.0e6]', delay=0.003, specimen=SPECIMEN.replace(
        'damping_N_s_per_m', 'damping')),
    'specimen_typo_run.yaml': 'rig_model: state_space\nplant_model: specimen_typo.yaml\n',
    'alpha_twice.yaml': 'alpha: [0.5, 1, 0.50]\n',
    'plant.yaml': PLANT.format(num='[1.0e6]', delay=0.003, specimen=SPECIMEN),
    'plant_run.yaml': 'rig_model: state_space\nplant_model: plant.yaml\n',
    # the two-pier bridge with an alpha, which its structure's masses make meaningless
    'structure_alpha.yaml': (Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml')
    .read_text().replace('predictor: [none, model]', 'predictor: model') + 'alpha: 0.5\n',
}
#: A file that is not UTF-8 text (the bytes 0-255: 0x80 is the first that is not).
BINARY = bytes(range(256))


def given_too(setting, option):
    """The refusal of ``--set NAME=VALUE`` with the parameter's own option."""
    return re.escape(f'--set {setting}: {option} is given too; expected the value once')


#: id -> (arguments after 'seft', expected error line as a regex, stderr is only that line)
CASES = {
    'set_scale_factor_with_amplitude': (['simulate', '--set', 'scale_factor=2'], re.escape(
        'command line: parameter scale_factor=2.0: used only with amplitude_N 0 '
        '(amplitude_N=1000 scales the record to that peak force); set amplitude_N to 0, or '
        'leave scale_factor at 1')),
    'stability_plant_model': (['stability', 'plant_run.yaml', '--predictor', 'none'],
                              re.escape(
        "parameter rig_model='state_space': seft stability maps the delay of seft's own rig "
        "models ('delay', 'servohydraulic'); a plant model carries its delay: seft simulate "
        'or run checks its loop before the test and refuses one predicted unstable')),
    'structure_alpha': (['simulate', 'structure_alpha.yaml'], re.escape(
        "structure_alpha.yaml: parameter alpha=0.5: with a structure the computational masses "
        "are the structure's; leave alpha at 0")),
    'at2_npts_line': (['simulate', '--record', 'npts.AT2'], re.escape(
        "npts.AT2: line 4: expected 'NPTS=<int>, DT=<float> SEC', got 'NPTS= abc, DT= 0.01 "
        "SEC'")),
    'at2_truncated': (['simulate', '--record', 'short.AT2'],
                      r'short\.AT2: line \d+: truncated: expected NPTS=12 values, found 10'),
    'at2_token': (['simulate', '--record', 'token.AT2'],
                  re.escape("token.AT2: line 6: expected a number, got '0.3x'")),
    'record_missing': (['simulate', '--record', 'nothing.AT2'], r'nothing\.AT2: no such file'),
    'at2_units_not_g': (['simulate', '--record', 'cm.AT2'], re.escape(
        "cm.AT2: line 3: expected units of G, got 'CM/SEC/SEC' (seft reads .AT2 values in g: "
        'convert them, or write a CSV in m/s^2)')),
    'at2_dt_msec': (['simulate', '--record', 'msec.AT2'], re.escape(
        "msec.AT2: line 4: expected 'NPTS=<int>, DT=<float> SEC', got DT in 'MSEC' (seft "
        'reads DT in seconds)')),
    'at2_zeros_scaled': (['simulate', '--record', 'zeros.AT2', '--amplitude', '0', '--scale',
                          '1'], re.escape("zeros.AT2: record 'zeros' is all zeros in its first "
                                          '1 s; expected a record with a non-zero sample')),
    'csv_token': (['simulate', '--record', 'bad.csv'],
                  re.escape("bad.csv: line 4: expected a number, got 'abc'")),
    'yaml_mass_0': (['simulate', 'mass0.yaml'],
                    re.escape('mass0.yaml: parameter mass_kg=0: expected float > 0')),
    'yaml_alpha_negative': (['simulate', 'alpha.yaml'], re.escape(
        'alpha.yaml: parameter alpha=-1: expected float >= 0 <= 100')),
    'arg_alpha_negative': (['simulate', '--alpha', '0.5', '-1'], re.escape(
        'command line: parameter alpha=-1.0: expected float >= 0 <= 100')),
    'yaml_dt_0': (['simulate', 'dt0.yaml'],
                  re.escape('dt0.yaml: parameter dt=0: expected float > 1e-05 <= 1')),
    'set_rig_model': (['simulate', '--set', 'rig_model=foo'], re.escape(
        "command line: parameter rig_model='foo': expected one of 'delay', 'servohydraulic', "
        "'state_space', 'actuator'")),
    'set_alpha': (['simulate', '--set', 'alpha=1'], re.escape('--set alpha: use --alpha')),
    'simulate_realtime': (['simulate', '--set', 'mode=realtime'], re.escape(
        'parameter mode=realtime: seft simulate has no wall clock (it is the lockstep graph '
        'in one process); use seft run --mode realtime')),
    'set_mode': (['simulate', '--set', 'mode=fast'], re.escape(
        "command line: parameter mode='fast': expected one of 'lockstep', 'realtime'")),
    'yaml_unknown': (['simulate', 'unknown.yaml'],
                     re.escape("unknown.yaml: unknown parameter 'stiffnes_N_per_m' (did you "
                               "mean 'stiffness_N_per_m'?)")),
    'yaml_invalid': (['simulate', 'invalid.yaml'],
                     r'invalid\.yaml: line \d+: invalid YAML \(.+\)'),
    'yaml_ros_format': (['simulate', 'ros.yaml'],
                        re.escape('ros.yaml: parameter tau_s=2.0: expected float > 0 <= 1')),
    'yaml_not_utf8': (['simulate', 'binary.yaml'], re.escape(
        'binary.yaml: not UTF-8 text (byte 128); expected a YAML file')),
    'params_not_utf8': (['simulate', '--params', 'binary.yaml'], re.escape(
        'binary.yaml: not UTF-8 text (byte 128); expected a YAML file')),
    'plant_model_not_utf8': (['simulate', 'binary_plant.yaml'], re.escape(
        'binary.yaml: not UTF-8 text (byte 128); expected a YAML file')),
    # a model in a file of its own is named by that file (it was by the configuration that
    # points to it; a new user, session 38)
    'plant_zero_force': (['simulate', 'zero_force_run.yaml', '--predictor', 'none'], re.escape(
        'zero_force.yaml: plant_model.num.force_N: all zero: the force does not '
        'depend on the valve command; expected a non-zero numerator')),
    'plant_long_delay': (['simulate', 'long_delay_run.yaml'], re.escape(
        'long_delay.yaml: plant_model.io_delay_s=2: expected at most 50 steps of '
        "the run's dt=0.002 s (0.1 s; each step is a state of the sampled model)")),
    'plant_specimen_typo': (['simulate', 'specimen_typo_run.yaml'], re.escape(
        'specimen_typo.yaml: plant_model.specimen: unknown field(s) damping; '
        'expected some of damping_N_s_per_m, mass_kg, stiffness_N_per_m')),
    'yaml_missing': (['simulate', 'nope.yaml'],
                     re.escape('nope.yaml: no such configuration file')),
    'out_not_empty': (['simulate', '--out', 'full'], re.escape(
        'full: output directory exists and is not empty; expected a new directory')),
    'n_steps_too_long': (['simulate', '--set', 'duration_s=1', '--set', 'n_steps=100000'],
                         re.escape(
        'parameter n_steps=100000: expected <= 500 (the prepared record length)')),
    # the same run twice, or two values of one parameter on one command line: refused
    'alpha_twice': (['simulate', '--alpha', '0.5', '1', '0.50'], re.escape(
        '--alpha 0.5 1.0 0.5: the same run twice; expected each value once')),
    'predictor_twice': (['simulate', '--predictor', 'model', 'none', 'model'], re.escape(
        '--predictor model none model: the same run twice; expected each value once')),
    'record_twice': (['simulate', '--record', 'short.AT2', './short.AT2'], re.escape(
        '--record short.AT2 ./short.AT2: the same run twice; expected each value once')),
    'yaml_alpha_twice': (['simulate', 'alpha_twice.yaml'], re.escape(
        'alpha_twice.yaml: parameter alpha: 0.5 twice: the same run twice; expected each '
        'value once')),
    'set_with_time_scale': (['simulate', '--set', 'time_scale=0.25', '--time-scale', '0.8'],
                            given_too('time_scale=0.25', '--time-scale')),
    'set_after_time_scale': (['simulate', '--time-scale', '0.8', '--set', 'time_scale=0.25'],
                             given_too('time_scale=0.25', '--time-scale')),
    'set_with_amplitude': (['simulate', '--set', 'amplitude_N=300', '--amplitude', '700'],
                           given_too('amplitude_N=300', '--amplitude')),
    'set_with_predictor': (['simulate', '--set', 'predictor=model', '--predictor',
                            'polynomial'], given_too('predictor=model', '--predictor')),
    'set_with_record': (['simulate', '--set', 'record=short.AT2', '--record', 'default'],
                        given_too('record=short.AT2', '--record')),
    'set_with_duration': (['simulate', '--set', 'duration_s=1', '--duration', '0.5'],
                          given_too('duration_s=1', '--duration')),
    'n_steps_with_duration': (['simulate', '--set', 'n_steps=10'],
                              given_too('n_steps=10', '--duration')),
    'record_given_twice': (['simulate', '--record', 'short.AT2', '--record', 'default'],
                           re.escape('--record: given twice; expected it once (--record A B: '
                                     'one run per value)')),
    'amplitude_given_twice': (['simulate', '--amplitude', '500', '--amplitude', '700'],
                              re.escape('--amplitude: given twice; expected it once')),
    'amplitude_and_scale': (['simulate', '--amplitude', '500', '--scale', '2'], re.escape(
        '--scale 2: an amplitude of 500 N is given too; expected one of them (--scale with '
        'no amplitude or --amplitude 0)')),
    'name_is_a_path': (['simulate', '--name', '../../x'], re.escape(
        "--name '../../x': expected a run name, not a path (no '/', not '.' or '..')")),
    'out_under_a_file': (['simulate', '--out', 'plain_dir/notes.txt/x'], re.escape(
        '--out plain_dir/notes.txt/x: cannot create the output directory (Not a directory); '
        'expected a directory that can be made')),
    'out_in_proc': (['simulate', '--out', '/proc/seft_nope'], re.escape(
        '--out /proc/seft_nope: cannot create the output directory (No such file or '
        'directory); expected a directory that can be made')),
    'compare_not_a_bag': (['compare', 'plain_dir'],
                          re.escape('plain_dir: not a bag, a run directory (with bag/) '
                                    'or a folder of run directories') + '; .+'),
    'compare_missing': (['compare', 'no_such_bag'],
                        re.escape('no_such_bag: no such bag or run directory')),
    # a real-time watchdog shorter than 3 sample periods ends the run at its first lost or
    # late sample (before: accepted; every node tripped at the first step, 'limit 0 ms')
    'run_watchdog_below_dt': (['run', '--mode', 'realtime', '--set', 'watchdog_timeout_s=0.0005',
                               '--duration', '0.1'], re.escape(
        'command line: parameter watchdog_timeout_s=0.0005: expected at least 3 sample '
        'periods, 0.006 s at dt=0.002 s (an input is due every dt: a shorter watchdog ends '
        'the run at the first lost or late sample)')),
    'run_watchdog_3_dt_at_1khz': (['run', '--mode', 'realtime', '--set', 'dt=0.001', '--set',
                                   'watchdog_timeout_s=0.0025', '--duration', '0.1'],
                                  re.escape(
        'command line: parameter watchdog_timeout_s=0.0025: expected at least 3 sample '
        'periods, 0.003 s at dt=0.001 s (an input is due every dt: a shorter watchdog ends '
        'the run at the first lost or late sample)')),
    # a UDP bridge's controller address is checked before anything starts (before: by the
    # rig node 7-8 s into the start)
    'run_udp_address_no_port': (['run', '--mode', 'realtime', '--set',
                                 'rig_interface=udp_bridge', '--set',
                                 'udp_controller_address=127.0.0.1:99999', '--duration', '0.1'],
                                re.escape("command line: parameter udp_controller_address="
                                          "'127.0.0.1:99999': expected host:port with a port "
                                          '1-65535')),
    'run_udp_address_unknown_host': (['run', '--mode', 'realtime', '--set',
                                      'rig_interface=udp_bridge', '--set',
                                      'udp_controller_address=no-such-lab-pxi.invalid:47001',
                                      '--duration', '0.1'],
                                     re.escape("command line: parameter udp_controller_address="
                                               "'no-such-lab-pxi.invalid:47001': cannot resolve "
                                               "'no-such-lab-pxi.invalid' (") + '.+'),
    'run_domain_out_of_range': (['run', '--domain-id', '233', '--duration', '0.1'],
                                re.escape('--domain-id=233: expected an integer 0-232')),
    'compare_foreign_bag': (['compare', 'foreign_bag'], re.escape(
        'foreign_bag: not a seft bag (no /seft/run_parameters message)')),
}

def make_inputs(cwd):
    for name, text in FILES.items():
        (cwd / name).write_text(text)
    (cwd / 'binary.yaml').write_bytes(BINARY)
    (cwd / 'plain_dir').mkdir()
    (cwd / 'plain_dir' / 'notes.txt').write_text('not a bag\n')
    (cwd / 'full').mkdir()
    (cwd / 'full' / 'keep.txt').write_text('x\n')
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(cwd / 'foreign_bag', version=9) as writer:
        conn = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=store)
        msg = store.types['std_msgs/msg/String'](data='hello')
        writer.write(conn, 1, store.serialize_cdr(msg, 'std_msgs/msg/String'))


#: Cases also run as the installed ``seft`` in a subprocess (one per verb and input kind).
AS_PROCESS = ('yaml_mass_0', 'at2_token', 'compare_missing', 'run_domain_out_of_range')


def case_argv(key: str) -> list[str]:
    """The arguments after ``seft`` of case `key`: a short run in its own output directory."""
    args = CASES[key][0]
    if args[0] == 'simulate':
        # a case that gives the length by --set gets no --duration (refused with it)
        length = [] if any(a.startswith('duration_s=') for a in args) else ['--duration', '1']
        return [*args, *length, *([] if '--out' in args else ['--out', f'out_{key}'])]
    return [*args, '--out', f'out_{key}']


def run_in_process(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``seft argv`` through its entry point in this process, in `cwd`: the exit code and
    what it wrote to stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    previous = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main.main(argv)
            except SystemExit as exc:       # argparse's errors
                code = exc.code
    finally:
        os.chdir(previous)
    return subprocess.CompletedProcess(argv, code, out.getvalue(), err.getvalue())


@pytest.fixture(scope='module')
def inputs(tmp_path_factory):
    cwd = tmp_path_factory.mktemp('cli_errors')
    make_inputs(cwd)
    return cwd


@pytest.fixture(scope='module')
def results(inputs):
    return {key: run_in_process(case_argv(key), inputs) for key in CASES}


@pytest.fixture(scope='module')
def process_results(inputs, seft_exe, run_process, tmp_path_factory):
    cwd = tmp_path_factory.mktemp('cli_errors_process')
    make_inputs(cwd)

    def one(key):
        return key, run_process([seft_exe, *case_argv(key)], cwd=cwd, timeout=60)

    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(pool.map(one, AS_PROCESS))


def error_line(proc, prefix='seft: error: '):
    """The one error line of a failed command (exit code 2, no traceback, nothing else but
    '[seft]' progress lines)."""
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr + proc.stdout
    lines = proc.stderr.splitlines()
    errors = [ln for ln in lines if ln.startswith(prefix)]
    assert len(errors) == 1, proc.stderr
    assert lines[-1] == errors[0], proc.stderr
    assert all(ln.startswith('[seft] ') for ln in lines[:-1]), proc.stderr
    assert proc.stdout == ''
    return errors[0][len(prefix):]


@pytest.mark.parametrize('case', sorted(CASES))
def test_bad_input_is_one_error_line(results, case):
    proc = results[case]
    message = error_line(proc)
    assert re.fullmatch(CASES[case][1], message), message
    # found before anything runs: the error is all there is on stderr
    assert len(proc.stderr.splitlines()) == 1, proc.stderr


@pytest.mark.parametrize('case', AS_PROCESS)
def test_the_installed_command_gives_the_same_line(process_results, results, case):
    # the console script: exit code 2, the one line, nothing on stdout, no output left
    proc = process_results[case]
    assert error_line(proc) == error_line(results[case])
    assert proc.stderr == results[case].stderr


def test_argparse_choice_error(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'simulate', '--rig', 'foo'], cwd=tmp_path)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    # one line, as every other input error (argparse's usage block is not printed)
    assert len(proc.stderr.splitlines()) == 1, proc.stderr
    assert re.fullmatch(r"seft: error: argument --rig: invalid choice: 'foo' \(choose from "
                        r"'?delay'?, '?servohydraulic'?, '?state_space'?, '?actuator'?\) "
                        r"\(see 'seft simulate --help'\)", proc.stderr.strip()), proc.stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize('argv, line', [
    (['simulate', '--bogus'],
     "seft: error: unrecognized arguments: --bogus (see 'seft simulate --help')"),
    (['run', '--mode', 'fast'],
     "seft: error: argument --mode: invalid choice: 'fast' (choose from 'lockstep', "
     "'realtime') (see 'seft run --help')"),
    (['compare'], "seft: error: the following arguments are required: BAG "
     "(see 'seft compare --help')"),
    # an option of the verb before it, and a configuration file swallowed by a list option
    # (each said in argparse's words alone to a new user, session 36)
    (['--force', 'simulate'],
     "seft: error: unrecognized arguments: --force (--force: an option of 'seft simulate', "
     "given before the verb: put it after the verb) (see 'seft simulate --help')"),
    (['simulate', '--alpha', '0.5', 'lab.yaml'],
     "seft: error: argument --alpha: invalid float value: 'lab.yaml' (lab.yaml taken as its "
     'value: an option of several values takes every word after it; give the configuration '
     "file first) (see 'seft simulate --help')"),
])
def test_argparse_errors_are_one_line_naming_the_command(argv, line, capsys):
    # an argument the subcommand does not know is reported against the subcommand, not
    # against 'seft' (argparse's top level finds it)
    with pytest.raises(SystemExit) as exit_info:
        main.main(argv)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == line + '\n'


@pytest.mark.parametrize('args, line', [
    (['main.yaml'], 'seft emulate-controller takes one run of one rig: the configuration gives 8 '
     'runs (alpha [0.0, 0.5, 1.0, 1.5], predictor [model, none]); give one of each, e.g. --set '
     'alpha=0.0 --set predictor=model'),
    # alpha given, the two predictors left: before, 'expected one alpha and no structure'
    (['main.yaml', '--set', 'alpha=0.5'], 'seft emulate-controller takes one run of one rig: '
     'the configuration gives 2 runs (predictor [model, none]); give one of each, e.g. --set '
     'predictor=model'),
    (['two_piers.yaml'], 'seft emulate-controller takes one rig: the configuration is a '
     "structure; give a one-rig configuration (a rig's own section)"),
])
def test_the_emulator_names_what_makes_more_than_one_run(args, line, capsys):
    """What a lab gets from ``seft emulate-controller`` on the shipped configurations (a
    new user followed the rig contract's page with config/main.yaml; session 39)."""
    config = Path(__file__).resolve().parents[3] / 'config'
    argv = ['emulate-controller', str(config / args[0]), *args[1:]]
    assert main.main(argv) == 2
    assert capsys.readouterr().err == f'seft: error: {line}\n'


@pytest.mark.parametrize('verb', ['run', 'simulate', 'sites'])
def test_predictor_help_names_every_registered_predictor(verb, capsys):
    # the help listed 'none', 'model', 'polynomial', 'adaptive' and left 'ats' out
    from seft_ros.core.reference_force import PREDICTORS
    with pytest.raises(SystemExit) as exit_info:
        main.main([verb, '--help'])
    assert exit_info.value.code == 0
    text = ' '.join(capsys.readouterr().out.split())
    assert ("delay compensation(s): 'none', 'polynomial', 'model', 'adaptive', 'ats' "
            "(several: one run per predictor and alpha; default: the configuration's, else "
            "'none')") in text
    assert set(PREDICTORS) == {'none', 'polynomial', 'model', 'adaptive', 'ats'}
    # the defaults a record is played with (a new user's CSV played twice as fast by the
    # study's time scale, which no help named, session 36), from the parameter schema
    assert ("--amplitude N peak of m*xg'' [N] (0: use --scale; default: the configuration's, "
            'else 1000)') in text
    assert ("record time scale: the record's time step times this (default: the "
            "configuration's, else 0.5, the study's: the record plays in half its time; 1: as "
            'recorded)') in text


def test_argparse_set_without_value(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'simulate', '--set', 'alpha'], cwd=tmp_path)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert proc.stderr == ("seft: error: argument --set: --set 'alpha': expected NAME=VALUE "
                           "(see 'seft simulate --help')\n")


def test_run_with_bad_record_fails_fast(seft_exe, run_process, tmp_path):
    (tmp_path / 'token.AT2').write_text(FILES['token.AT2'])
    proc = run_process([seft_exe, 'run', '--record', 'token.AT2', '--duration', '1', '--out',
                        'out'], cwd=tmp_path, timeout=60)
    message = error_line(proc)
    # the record is read before any node starts: the file's own one-line error
    assert message == "token.AT2: line 6: expected a number, got '0.3x'"
    assert len(proc.stderr.splitlines()) == 1, proc.stderr


def test_run_with_bad_parameter_starts_nothing(seft_exe, run_process, tmp_path):
    proc = run_process([seft_exe, 'run', '--alpha', '-1', '--out', 'out'], cwd=tmp_path)
    assert error_line(proc) == 'command line: parameter alpha=-1.0: expected float >= 0 <= 100'
    assert len(proc.stderr.splitlines()) == 1
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('args, message', [
    (['--alpha', '0.5', '0.5'], '--alpha 0.5 0.5: the same run twice; expected each value once'),
    (['--set', 'predictor=model', '--predictor', 'none'],
     '--set predictor=model: --predictor is given too; expected the value once')])
def test_run_refuses_a_conflict_before_anything_starts(seft_exe, run_process,
                                                         tmp_path, args, message):
    # before: the second run's recorder failed on the first's bag, no report, and the first
    # run's params.yaml and logs overwritten
    proc = run_process([seft_exe, 'run', *args, '--duration', '0.2', '--out', 'out'],
                       cwd=tmp_path)
    assert error_line(proc) == message
    assert len(proc.stderr.splitlines()) == 1
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('value, shown', [('-1.0', '-1.0'), ('abc', "'abc'"), ('200', '200')])
def test_node_started_by_hand_with_bad_parameter(run_process, tmp_path, value, shown):
    proc = run_process([sys.executable, '-m', 'seft_ros.nodes.reference_force_builder',
                        '--ros-args', '-p', f'alpha:={value}'], cwd=tmp_path, timeout=30)
    assert proc.returncode == 2
    assert proc.stdout == ''
    assert proc.stderr.splitlines() == [
        f'reference_force_builder: error: parameter alpha={shown}: expected float >= 0 <= 100']


def test_fail_on_abort_exits_3_for_an_abort_the_guard_did_not_foresee(tmp_path, capsys):
    """``--fail-on-abort``: a lab script can tell a safety abort from a good run by the exit
    code (before: 0 whatever the outcome). At 30 kN the valve saturates and the interlock
    stops the run the guard found stable (exit 3, one line naming it); the study's alpha 1.5
    without compensation, predicted unstable and run with --force, aborts as foreseen (0);
    without the option an abort stays a result (0)."""
    common = ['simulate', '--duration', '2', '--alpha']
    big = common + ['0.5', '--predictor', 'model', '--amplitude', '30000']
    assert main.main(big + ['--fail-on-abort', '--out', str(tmp_path / 'a')]) == 3
    err = capsys.readouterr().err.splitlines()
    assert re.fullmatch(r'seft: 1 run\(s\) aborted that the stability guard had not predicted '
                        r'unstable: run 1 \(model, alpha 0\.5\) at 0\.\d+ s: force control '
                        r'lost at t=0\.\d+ s: .* \(--fail-on-abort: exit code 3\)', err[-1]), err
    assert main.main(big + ['--out', str(tmp_path / 'b')]) == 0
    foreseen = common + ['1.5', '--predictor', 'none', '--force', '--fail-on-abort']
    assert main.main(foreseen + ['--out', str(tmp_path / 'c')]) == 0
    entry = json.loads((tmp_path / 'c' / 'summary.json').read_text())['runs'][0]
    assert entry['stable'] is False and entry['stability']['predicted_stable'] is False


def test_unforeseen_aborts_of_a_structure_and_of_runs_without_a_prediction():
    """A structure's summary entry has no alpha (None), a run may have no stability entry
    (a bag read by compare): named all the same (a three-host bridge's compute host ended
    in a TypeError here)."""
    summary = [{'stable': False, 'predictor': 'model', 'alpha': None, 'unstable_at_s': 0.596,
                'abort_reason': 'pier_a/reference_force_builder: watchdog: no pier_b/'
                'measurement for 100 ms', 'stability': {'predicted_stable': True}},
               {'stable': False, 'predictor': 'none', 'alpha': 1.5, 'unstable_at_s': 0.786,
                'abort_reason': 'unstable', 'stability': {'predicted_stable': False}},
               {'stable': True, 'predictor': 'model', 'alpha': 1.0},
               {'stable': False, 'predictor': 'ats', 'alpha': 0.5, 'unstable_at_s': None,
                'abort_reason': None}]
    assert main.unforeseen_aborts(summary) == [
        'run 1 (model) at 0.596 s: pier_a/reference_force_builder: watchdog: no '
        'pier_b/measurement for 100 ms', 'run 4 (ats, alpha 0.5): aborted']


def test_a_stop_as_seft_run_names_its_runs_says_nothing_was_run(inputs, monkeypatch):
    """SIGTERM while ``seft run`` writes its ``N run(s) -> DIR`` line (the CI of d0f7ed9: the
    signal came between the line and its newline): nothing was run, said on a line of its
    own, exit 143; not 'left at once while the run ended', as if nodes had started."""
    said = []

    def progress(text):
        said.append(text)
        if 'run(s) ->' in text:
            raise KeyboardInterrupt('SIGTERM')       # main._interrupt's exception
    monkeypatch.setattr(main, '_progress', progress)
    proc = run_in_process(['run', '--duration', '0.1', '--out', 'out_stopped'], inputs)
    assert said[-1].startswith('1 run(s) -> ') and said[-1].endswith('out_stopped')
    assert proc.returncode == 143, proc.stderr
    assert proc.stderr.splitlines()[-1] == (
        'seft: interrupted by SIGTERM: before any node started: nothing was run'), proc.stderr
    assert not (inputs / 'out_stopped').exists()


def test_a_real_time_run_a_watchdog_ended_names_the_parameter():
    """The note of a real-time run stopped by a watchdog names watchdog_timeout_s (4 of 5 of a
    new user's runs on a shared host were stopped by 21-31 ms stalls, and nothing named it;
    session 39); a lockstep run's, or another abort's, says nothing more."""
    from seft_ros.cli.api import WATCHDOG_HINT, _watchdog_hint
    reason = ('pier_b/force_servo_controller: watchdog: no measurement for 21 ms (limit 20 ms; '
              'node or link lost)')
    assert _watchdog_hint('realtime', reason) == WATCHDOG_HINT
    assert 'watchdog_timeout_s=0.2' in WATCHDOG_HINT
    assert _watchdog_hint('lockstep', reason) == ''
    assert _watchdog_hint('realtime', 'rig: unstable at t=1 s') == ''
