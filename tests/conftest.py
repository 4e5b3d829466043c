"""Fixtures shared by the tests: an isolated ROS environment, the ``seft`` executable and the
reference rig's parameters.

Test modules have unique basenames: pytest's default ``prepend`` import mode cannot hold two
``test_x.py`` from different folders without ``__init__.py`` files.
"""

import os
from pathlib import Path
import signal
import subprocess
import sys

import pytest
import rerun_reasons

from seft_msgs_py import parameters
from seft_msgs_py.domain import LOCK_DIR, claim_domain

#: Domains the test sessions claim from: outside 100-199, where ``seft run`` picks a random
#: domain when none is set, and within the valid 0-232.
DOMAIN_RANGE = range(200, 233)
#: Where the claims are (``seft_msgs_py.domain``), shared with ``seft run``.
DOMAIN_LOCK_DIR = LOCK_DIR


#: ROS_DOMAIN_ID of this test session, claimed for its lifetime (the lock file stays open).
DOMAIN_ID, _DOMAIN_CLAIM = claim_domain(DOMAIN_RANGE)


@pytest.fixture(scope='session')
def ros_env(tmp_path_factory):
    """Environment of the processes a test starts: own domain, localhost only, logs in tmp."""
    log_dir = tmp_path_factory.mktemp('ros_log')
    env = dict(os.environ)
    # SEFT_DISCOVERY_SETTLE_S: the session's domain is claimed by a lock and nothing is
    # started there by hand, so seft run's busy-domain check need not wait for periodic
    # announcements (3.5 s a run); the test of that check restores the default
    env.update(ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_LOG_DIR=str(log_dir), PYTHONUNBUFFERED='1', SEFT_DISCOVERY_SETTLE_S='0.5')
    env.pop('ROS_STATIC_PEERS', None)
    return env


@pytest.fixture(scope='session')
def seft_exe():
    """The ``seft`` console script of the interpreter running the tests."""
    path = Path(sys.executable).parent / 'seft'
    assert path.is_file(), f'{path}: seft is not installed in this environment'
    return path


class EmulatorProcess:
    """``seft emulate-controller`` in a process of its own; its JSON events as they come
    (each with ``at``, the monotonic time the test read it).

    Parameters
    ----------
    seft_exe, env, cwd
        The ``seft`` executable, the environment and the working directory.
    args : sequence of str
        Its options (``--set udp_controller_address=...``, ``--inject``, ``--runs``).
    """

    def __init__(self, seft_exe, env, cwd, args):
        import json
        import threading
        import time
        self._json, self._time = json, time
        self.proc = subprocess.Popen([str(seft_exe), 'emulate-controller', *map(str, args)],
                                     cwd=cwd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.events, self.stderr = [], []
        self.readers = [threading.Thread(target=self._read, args=(stream, events), daemon=True)
                        for stream, events in ((self.proc.stdout, True),
                                               (self.proc.stderr, False))]
        for r in self.readers:
            r.start()
        deadline = time.monotonic() + 30
        while not any('emulating' in line for line in self.stderr):
            assert time.monotonic() < deadline and self.proc.poll() is None, self.stderr
            time.sleep(0.05)

    def _read(self, stream, events):
        for line in stream:
            if events:
                self.events.append(self._json.loads(line) | {'at': self._time.monotonic()})
            else:
                self.stderr.append(line)

    def of(self, kind):
        """Its events of `kind` ('start', 'end', ...), in order."""
        return [e for e in self.events if e['event'] == kind]

    def wait_for(self, kind, timeout=3.0):
        """Its events of `kind` once there is one (fails after `timeout` [s])."""
        deadline = self._time.monotonic() + timeout
        while not self.of(kind):
            assert self._time.monotonic() < deadline, (kind, self.events)
            self._time.sleep(0.01)
        return self.of(kind)

    def stop(self):
        """Stop it (SIGCONT first: a test may have frozen it), then read what it said."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGCONT)
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        for r in self.readers:
            r.join(timeout=5)


@pytest.fixture
def emulator_process(seft_exe, ros_env, tmp_path):
    """Start ``seft emulate-controller ARGS`` (:class:`EmulatorProcess`); each is stopped
    after the test."""
    made = []

    def start(*args):
        made.append(EmulatorProcess(seft_exe, ros_env, tmp_path, args))
        return made[-1]
    yield start
    for e in made:
        e.stop()


@pytest.fixture(scope='session')
def run_process(ros_env):
    """Run a command in its own session; on timeout stop its whole process group, then fail.

    Returns a callable ``(argv, *, cwd, timeout=60) -> CompletedProcess`` (text output).
    """
    def run(argv, *, cwd, timeout=60.0, env=None):
        proc = subprocess.Popen([str(a) for a in argv], cwd=cwd, env=env or ros_env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            for sig, wait in ((signal.SIGINT, 10.0), (signal.SIGKILL, 5.0)):
                try:
                    os.killpg(proc.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    out, err = proc.communicate(timeout=wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
            pytest.fail(f'{argv} did not finish within {timeout} s')
        return subprocess.CompletedProcess(argv, proc.returncode, out, err)
    return run


def _drive(rig, commands):
    """Apply `commands` (reference forces [N] or valve commands [V]) one step each; return the
    readings before each step, shape (n, 4): force [N], displacement [m], velocity [m/s],
    acceleration [m/s^2]."""
    import numpy as np
    rows = []
    for c in commands:
        m = rig.measure()
        rows.append((m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
        rig.apply(c)
    return np.array(rows)


@pytest.fixture(scope='session')
def drive():
    """A rig driven open loop (:func:`_drive`), its readings."""
    return _drive


@pytest.fixture(scope='session')
def reference_params():
    """The reference rig (Nakata and Combs Sec. 3.1): the schema defaults, resolved."""
    p = parameters.resolve()
    assert p['mass_kg'] == 52.7 and p['stiffness_N_per_m'] == 2.11e5 and p['dt'] == 0.002
    return p


def pytest_configure(config):
    config.addinivalue_line(
        'markers', 'wall_clock: runs the node graph on the wall clock (real time, several '
        'hosts, rig-check); given by the module or the test name, not by hand. tools/test.sh '
        'runs these one at a time after the rest (-m wall_clock / -m "not wall_clock")')
    _count_samples_at_a_range()


#: The tests whose runs in this process took a sensor to its range: {test id: {channel:
#: samples}} (issue 39: no run clips a sensor silently, the suite's included).
SAMPLES_AT_A_RANGE: dict[str, dict[str, int]] = {}


def _count_samples_at_a_range():
    """Count, per test, the samples a builder of this process flagged at a sensor's range
    (``seft_msgs_py.sensor_range.RangeCount.add``, wrapped for the session); the session's
    summary lists them (:func:`pytest_terminal_summary`). The runs of a node process or of
    a forked ``seft simulate`` worker count where they run: their tests read the count from
    the bag or the summary."""
    from seft_msgs_py.sensor_range import RangeCount, channel_names
    add = RangeCount.add

    def counting(self, step, flags):
        add(self, step, flags)
        if flags:
            test = os.environ.get('PYTEST_CURRENT_TEST', '?').rsplit(' (', 1)[0]
            counts = SAMPLES_AT_A_RANGE.setdefault(test, {})
            for channel in channel_names(flags):
                counts[channel] = counts.get(channel, 0) + 1
    RangeCount.add = counting


def pytest_sessionfinish(session):
    """An xdist worker hands its tests' samples at a range to the controller."""
    if hasattr(session.config, 'workeroutput'):
        session.config.workeroutput['samples_at_a_range'] = dict(SAMPLES_AT_A_RANGE)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """The controller takes a worker's samples at a range (pytest-xdist)."""
    SAMPLES_AT_A_RANGE.update(getattr(node, 'workeroutput', {}).get('samples_at_a_range', {}))


def pytest_runtest_logreport(report):
    """Keep why a test that is run again failed its first time (:mod:`rerun_reasons`)."""
    rerun_reasons.record(report)


def pytest_terminal_summary(terminalreporter):
    """Why the reruns failed first (:mod:`rerun_reasons`); name the tests whose runs took a
    sensor to its range, with the samples per channel."""
    rerun_reasons.summary(terminalreporter)
    if not SAMPLES_AT_A_RANGE:
        return
    terminalreporter.section('runs at a sensor range (counted; issue 39)')
    for test, counts in sorted(SAMPLES_AT_A_RANGE.items()):
        terminalreporter.write_line(
            f'{test}: ' + ', '.join(f'{c} {n}' for c, n in counts.items()))


@pytest.hookimpl(tryfirst=True)       # before pytest's own -m selection reads the markers
def pytest_collection_modifyitems(config, items):
    """Mark the tests that run on the wall clock ``wall_clock`` (:func:`_on_the_wall_clock`)
    and give each a rerun (:data:`REALTIME_RERUNS`): those of the node graph (the modules
    directly under tests/seft_ros/) since 2026-11-23, the others (the UDP bridge at its
    socket) since the CI of 817774d, where test_udp_bridge's silent controller was noticed
    72.5 ms after its last datagram against a bound of 70 ms (50 ms watchdog, 20 ms of
    polling), and 72.1 ms in the same session's suite; it passed alone both times.

    ``tools/test.sh`` runs the rest (numerics, CLI, analysis, lockstep graphs: nothing in
    them depends on how fast the host is) on two pytest-xdist workers, then the
    ``wall_clock`` tests alone, one after the other: two real-time graphs, or one and another
    worker's load, on the two cores miss their deadlines. Under ``--dist loadgroup`` the
    node-graph tests also go to one worker together (``xdist_group``).
    """
    graph_dir = Path(__file__).resolve().parent / 'seft_ros'
    for item in items:
        in_graph = Path(str(item.fspath)).resolve().parent == graph_dir
        if in_graph:
            item.add_marker(pytest.mark.xdist_group('node_graph'))
        if _on_the_wall_clock(item, in_graph):
            item.add_marker(pytest.mark.wall_clock)
            item.add_marker(pytest.mark.flaky(reruns=REALTIME_RERUNS, reruns_delay=5))


#: The summary's ``nrms`` signals against the replay's (``worst_nrms``) names.
_REPLAY_NAMES = {'displacement': 'displacement', 'acceleration': 'acceleration',
                 'force': 'interface_force'}


def realtime_accuracy(entry: dict) -> tuple[dict, str]:
    """The NRMS by which a real-time run's method is judged: ``({'displacement',
    'acceleration', 'force': fraction}, which figures)``, from the run's summary.json entry.

    A run with its steps in time, or whose late ones cost it less than 1 % (no
    ``timing_replay``): its recorded figures (``'recorded'``), and it must be stable. A run
    whose late commands or stale steps cost it accuracy or stability (seft replays it, as run
    and with every step in time: :mod:`seft_ros.analysis.timing_replay`): its replay with
    every step in time (``'in time'``), provided the replay as run shows the host's timing
    costing the run: it reproduces what was recorded
    (:func:`~seft_ros.analysis.findings.replay_reproduces_run`), or is itself unstable, or
    its NRMS x is 3 times the one in time and 0.5 points above it (the replay models the late
    commands and stale steps, not every late input: over a lossy two-host link a run recorded
    9.1 % x, replayed as run 3.4 %, in time 0.39 %). Else, or when the run in time is itself
    unstable, the loss is not the host's timing and the test fails here.

    Why: on the 2-core VMs of 2026-11-29/30 (a Python loop of 1e7 additions 1.3-1.5 s, three
    to four times the hosts these tests were written on; CI's first phase 1096 s against
    488 s), the graph needs 1.3 of the 2 cores at 500 Hz: a one-host real-time run of `model`
    at alpha 0.5 had 2.5 % of its commands late and 1 % stale steps and recorded 0.53 / 11.2 /
    9.5 % x / a / f (0.39 / 0.90 / 0.77 % in time), and over two emulated hosts (stale steps
    up to 6 behind) went unstable at 0.90 s (replayed as run: at 0.88 s; in time 0.23 / 1.09
    / 1.15 %). What these tests check, the
    method and the transport, is what the replay in time measures; what the host can hold is
    the benchmarks' (benchmarks/realtime_graph.py).
    """
    from seft_ros.analysis.findings import replay_reproduces_run

    replay = entry.get('timing_replay')
    if not replay:
        assert entry['stable'], entry['abort_reason']
        return {s: entry['nrms'][s] for s in _REPLAY_NAMES}, 'recorded'
    in_time, as_run = replay['in_time'], replay['as_run']
    assert 'unstable_at_s' not in in_time, f'unstable with every step in time: {replay}'
    costs = ('unstable_at_s' in as_run or (
        as_run['displacement'] >= 3 * in_time['displacement']
        and as_run['displacement'] >= in_time['displacement'] + 0.005))
    assert replay_reproduces_run(replay) or costs, (
        f"the host's timing, replayed, does not explain the run ({entry['abort_reason']}): "
        f'{replay}')
    return {s: in_time[r] for s, r in _REPLAY_NAMES.items()}, 'in time'


#: A test that runs the graph in real time on this shared 2-core machine is run once more
#: when it fails (pytest-rerunfailures; the summary counts the reruns): a stall of the host
#: (other tenants; load averages of 2-6 measured while the suite ran alone) can miss a
#: deadline the test asserts. A test that fails twice fails. Measured in the serial suite
#: of 2026-11-23: 4 of about 60 real-time tests failed once (a 100 ms watchdog, a playout
#: 0.2 ms short of the round trip re-measured during the run, a rig-check watchdog reaction,
#: the two-pier bridge diverging at 0.84 s: see docs/network.md), each passing alone.
REALTIME_RERUNS = 1
#: The modules whose every test runs on the wall clock: real time, several hosts, and, at
#: the socket without ROS, the UDP bridge against its controller emulator ticking every 2 ms
#: and the link emulator's hold times (test_udp_bridge's clean run lost samples 27-28 when
#: it shared the host with the other xdist worker, in the CI of c7205ee).
REALTIME_MODULES = frozenset({'test_hosts', 'test_two_hosts', 'test_link_phase',
                              'test_udp_bridge_graph',
                              'test_realtime_integration', 'test_rig_check',
                              'test_runner_errors', 'test_udp_bridge', 'test_link_emulator',
                              'test_udp_sessions', 'test_intruder'})


#: Tests of those modules that start no real-time graph: a bad option's one error line, a
#: lockstep sweep, a unit test of a helper.
OFF_THE_WALL_CLOCK = frozenset({
    'test_rig_check_errors_are_one_line',
    'test_a_step_run_whose_clock_the_checker_missed_is_run_again',
    'test_a_bad_ros_domain_id_is_one_error_line',
    'test_an_unknown_node_start_method_is_one_error_line',
    'test_a_sweep_over_two_predictors_runs_both_graphs',
    'test_discovery_settle_time_from_the_environment',
    'test_emulator_and_bridge_errors_are_one_line',
    'test_the_emulator_ends_on_ctrl_c_even_started_as_a_background_job'})
# (test_intruder's two lockstep runs with another node's parameters went back on the wall
# clock: they hang on DDS discovery and on the order of two topics at the runner, which a
# loaded host upsets: 3 failures in 3 loaded phase-1 runs of session 38, none alone or
# beside one other module's graphs)


def _on_the_wall_clock(item, in_graph: bool) -> bool:
    """Whether a test runs in real time: its module says so, or, for a node-graph test
    (`in_graph`), its name."""
    name = item.name.lower()
    if item.originalname in OFF_THE_WALL_CLOCK:
        return False
    return (Path(str(item.fspath)).stem in REALTIME_MODULES
            or (in_graph and ('realtime' in name or 'real_time' in name)))
