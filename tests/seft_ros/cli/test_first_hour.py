"""The first hour of a lab engineer (issue 22): the commands as a user first writes them.

Each command runs the installed ``seft`` as a subprocess in a fresh directory, as a user
would; a failure is one line naming the parameter or file and what was expected, exit code 2,
no traceback, and nothing left behind (no empty output folder, no ``runs/``).
"""

from concurrent.futures import ThreadPoolExecutor
import re

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.cli.api import output_dir, remove_empty_dirs
from seft_ros.core.monitor import InstabilityMonitor, open_loop_identification

#: id -> (arguments after 'seft', expected error line as a regex)
FAILURES = {
    # the sample period too long for the servohydraulic force loop: said in those words
    'dt_force_loop': (['simulate', '--set', 'dt=0.5', '--out', 'out'], re.escape(
        'parameter dt=0.5: the force loop alone (alpha = 0, no mass fed back) is predicted '
        'unstable on the servohydraulic rig: the sample period is too long for the force '
        'loop; expected dt <= ') + r'0\.007\d+ s; use --force to run it anyway'),
    # on the delay rig (no force loop) the monitor's band split is what a long period breaks
    'dt_monitor': (['simulate', '--rig', 'delay', '--set', 'dt=0.5', '--out', 'out'],
                   re.escape('parameter dt=0.5: the sample period is too long for the '
                             'instability monitor, whose band split monitor_cutoff_hz=25 Hz '
                             'must lie below the Nyquist frequency 1/(2 dt) = 1 Hz; expected '
                             'dt < 0.02 s')),
    # read as the float the schema says, not as YAML 1.1's string '1e-12'
    'set_float_exponent': (['simulate', '--rig', 'delay', '--set', 'tau_s=1e-12', '--out',
                            'a/b'], re.escape('parameter tau_s=1e-12: expected float > 0 (at '
                                              'least 1e-09 dt = 2e-12 s: shorter rounds to no '
                                              'delay)')),
    'set_not_a_number': (['simulate', '--set', 'tau_s=abc'], re.escape(
        "command line: parameter tau_s='abc': expected float > 0 <= 1")),
    'set_bool': (['simulate', '--set', 'ground_preview=yes'], re.escape(
        "command line: parameter ground_preview='yes': expected bool")),
    'set_int': (['simulate', '--set', 'n_steps=1.5'], re.escape(
        "command line: parameter n_steps='1.5': expected int >= 0")),
    'set_unknown': (['simulate', '--set', 'stifness_N_per_m=1e5'], re.escape(
        "command line: --set stifness_N_per_m=1e5: unknown parameter 'stifness_N_per_m' (did "
        "you mean 'stiffness_N_per_m'?)")),
    'set_unknown_far': (['simulate', '--set', 'xyz=1'], re.escape(
        "command line: --set xyz=1: unknown parameter 'xyz' (the parameter reference lists "
        'them)')),
    # a bad domain: nothing created, whether --out is given or not
    'run_bad_domain_out': (['run', '--domain-id', '999', '--out', 'out'],
                           re.escape('--domain-id=999: expected an integer 0-232')),
    'run_bad_domain': (['run', '--domain-id', '999'],
                       re.escape('--domain-id=999: expected an integer 0-232')),
    # a lab's model in z cannot be sub-stepped by the real-time rig: refused before any node
    'run_realtime_discrete_model': (
        ['run', '--mode', 'realtime', '--rig', 'state_space', '--out', 'out', '--set',
         'plant_model={"form": "transfer_function", "dt": 0.002, "num": {"force_N": [0, 1]}, '
         '"den": [1, -0.5], "specimen": {"mass_kg": 52.7, "stiffness_N_per_m": 211000, '
         '"damping_N_s_per_m": 903.3}}'],
        re.escape('rig_model state_space in real time: the plant_model is discrete at dt '
                  '(2 ms) and the real-time rig steps on a 0.1 ms grid') + '.*'),
    'identify_missing': (['identify', 'no_such_bag'],
                         re.escape('no_such_bag: no such bag or run directory')),
    # the map of a loop that is unstable without any mass fed back: said at once
    'stability_dt': (['stability', '--set', 'dt=0.5'], re.escape(
        'parameter dt=0.5: the force loop alone (alpha = 0, no mass fed back) is predicted '
        'unstable on the servohydraulic rig: the sample period is too long for the force '
        'loop; expected dt <= ') + r'0\.007\d+ s'),
    'stability_bad_points': (['stability', '--points', '1'],
                             re.escape('--points 1: expected >= 2')),
}


def error_line(proc):
    """The one error line of a failed command: exit code 2, no traceback."""
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr + proc.stdout
    lines = proc.stderr.splitlines()
    assert lines and lines[-1].startswith('seft: error: '), proc.stderr
    assert all(ln.startswith('[seft] ') for ln in lines[:-1]), proc.stderr
    return lines[-1][len('seft: error: '):]


@pytest.fixture(scope='module')
def failures(tmp_path_factory, seft_exe, run_process):
    def one(item):
        key, (args, _) = item
        cwd = tmp_path_factory.mktemp(key)
        return key, (cwd, run_process([seft_exe, *args], cwd=cwd, timeout=120))

    with ThreadPoolExecutor(max_workers=3) as pool:
        return dict(pool.map(one, FAILURES.items()))


@pytest.mark.parametrize('case', sorted(FAILURES))
def test_failure_is_one_line_and_leaves_nothing(failures, case):
    cwd, proc = failures[case]
    message = error_line(proc)
    assert re.fullmatch(FAILURES[case][1], message), message
    assert list(cwd.iterdir()) == [], 'left behind: ' + ', '.join(p.name for p in cwd.iterdir())


@pytest.fixture(scope='module')
def identification(tmp_path_factory, seft_exe, run_process):
    """The identification run as a user first writes it (4 s instead of 60), and its bag
    identified with the defaults."""
    cwd = tmp_path_factory.mktemp('identification')
    sim = run_process([seft_exe, 'simulate', '--duration', '4', '--set', 'excitation=noise',
                       '--set', 'excitation_input=valve_command', '--bag'], cwd=cwd,
                      timeout=180)
    ident = run_process([seft_exe, 'identify', 'runs/run'], cwd=cwd, timeout=180)
    return cwd, sim, ident


def test_open_loop_identification_run_completes(identification):
    """Broadband noise on the valve puts force above the monitor's 25 Hz split by design; the
    monitor, disarmed in an open-loop run, no longer stops the healthy rig at 0.14 s."""
    _, sim, _ = identification
    assert sim.returncode == 0, sim.stderr
    assert 'ABORTED' not in sim.stderr
    row = next(ln for ln in sim.stdout.splitlines() if 'servohydraulic' in ln)
    assert row.split()[3] == 'True', row                 # the 'stable' column


def test_identify_on_the_completed_run(identification):
    """The oil column of the default rig (90.22 Hz in its model) is found from 4 s."""
    _, _, ident = identification
    assert ident.returncode == 0, ident.stderr
    figures = dict(ln.split()[:2] for ln in ident.stdout.splitlines() if ln.endswith(')'))
    assert float(figures['resonance_hz']) == pytest.approx(90.22, rel=0.02)


def test_identify_on_an_aborted_run_says_when_and_why(tmp_path, seft_exe, run_process):
    """An unstable closed loop (alpha 1.5, no compensation) is stopped by the monitor; its
    bag is refused with the time and the reason, and no output folder is left."""
    sim = run_process([seft_exe, 'simulate', '--alpha', '1.5', '--duration', '4', '--set',
                       'excitation=noise', '--bag', '--force', '--out', 'aborted'],
                      cwd=tmp_path, timeout=180)
    assert sim.returncode == 0, sim.stderr
    assert 'ABORTED' in sim.stderr
    proc = run_process([seft_exe, 'identify', 'aborted'], cwd=tmp_path, timeout=180)
    message = error_line(proc)
    assert re.fullmatch(
        r'aborted/alpha_1\.5_servohydraulic_none/bag: the run was aborted at (\d\.\d{3}) s of '
        r'4 s \(reference_force_builder: unstable at t=\d\.\d{3} s: high-frequency '
        r'oscillation of the measured force, .+\); identification needs a run that '
        r'completed: fix the cause and record it again', message), message
    at = float(re.search(r'aborted at (\d\.\d{3}) s', message).group(1))
    assert 0.1 < at < 2.5
    assert sorted(p.name for p in tmp_path.iterdir()) == ['aborted']


def test_monitor_disarmed_only_in_open_loop_identification():
    base = parameters.resolve({})
    assert InstabilityMonitor.from_parameters(base).threshold == 1.0
    closed = parameters.resolve({'excitation': 'noise'})
    assert not open_loop_identification(closed)
    assert InstabilityMonitor.from_parameters(closed).threshold == 1.0
    opened = parameters.resolve({'excitation': 'chirp', 'excitation_input': 'valve_command'})
    assert open_loop_identification(opened)
    monitor = InstabilityMonitor.from_parameters(opened)
    assert monitor.threshold == 0.0
    # disarmed: a force far above the cut-off never trips it
    for k in range(500):
        assert monitor.update(1e4 * (-1) ** k, 0.0, k * 0.002) is None
    assert monitor.ratio > 100.0


def test_from_text_reads_by_the_schema_type():
    assert parameters.from_text('tau_s', '1e-2') == pytest.approx(0.01)
    assert isinstance(parameters.from_text('stiffness_N_per_m', '2e5'), float)
    assert parameters.from_text('n_steps', '100') == 100
    assert parameters.from_text('ground_preview', 'False') is False
    assert parameters.from_text('record', 'on') == 'on'           # text stays text
    assert parameters.from_text('predictor', '[none, model]') == ['none', 'model']
    with pytest.raises(ParameterError, match=r'^x: parameter dt=1e-12: expected float '
                                             r'> 1e-05 <= 1$'):
        parameters.from_text('dt', '1e-12', where='x')
    with pytest.raises(ParameterError, match=r"parameter n_steps='2.0': expected int >= 0"):
        parameters.from_text('n_steps', '2.0')


def test_output_dir_removed_on_failure_only_when_empty(tmp_path):
    made = []
    out = output_dir(out=str(tmp_path / 'a' / 'b'), name='x', created=made)
    assert made == [tmp_path / 'a', tmp_path / 'a' / 'b'] and out.is_dir()
    (out / 'run' / 'bag').mkdir(parents=True)
    remove_empty_dirs(made)
    assert not (tmp_path / 'a').exists()
    made = []
    out = output_dir(out=str(tmp_path / 'c'), name='x', created=made)
    (out / 'node.log').write_text('kept: a failed run tells why\n')
    remove_empty_dirs(made)
    assert (out / 'node.log').is_file()


@pytest.mark.parametrize('args, expected', [
    (['--params', 'runs'], '--params runs: is a directory; expected the name of the parameter '
                           'file to write'),
    (['--window', 'foo'], "runs/run/alpha_0_servohydraulic_none/bag: option window='foo': "
                          "expected a window of scipy.signal.get_window, e.g. 'hann', "
                          "'hamming', 'boxcar' (Invalid window name 'foo' in parameter "
                          "window='foo')"),
])
def test_identify_bad_option_is_one_line(identification, seft_exe, run_process, args,
                                         expected):
    cwd, _, _ = identification
    before = sorted(p.relative_to(cwd) for p in cwd.rglob('*'))
    proc = run_process([seft_exe, 'identify', 'runs/run', '--out', 'bad', *args], cwd=cwd,
                       timeout=180)
    assert error_line(proc) == expected
    assert sorted(p.relative_to(cwd) for p in cwd.rglob('*')) == before
