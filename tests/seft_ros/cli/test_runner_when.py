"""The runner names when a node died: from the rig's reports, or, when none reached it (a
process killed before this runner had discovered it), from the last sample in the closed bag;
and a rig that refused the run before its first sample, saying why, is not a node's death."""

import time

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import SeftError
from seft_msgs_py.graph import Graph
from seft_ros.analysis.bagwrite import write_run_bag
from seft_ros.cli.runner import GraphRunner
from seft_ros.core.experiment import simulate


def test_when_without_a_rig_report_is_the_last_sample_in_the_bag(tmp_path):
    params = parameters.resolve({'duration_s': 0.5})
    run = simulate(params)
    runner = GraphRunner.__new__(GraphRunner)      # no ROS context: only what _when reads
    runner.graph, runner._bag_path = Graph.from_parameters(params), tmp_path / 'bag'
    # no bag (yet, or not on this host): the runner cannot tell
    assert runner._when_from_bag() == 'before the rig started'
    write_run_bag(run, tmp_path / 'bag')
    last = len(run.time_s) - 1
    assert last == 249
    assert runner._when_from_bag() == (
        f'at t = {last * 0.002:.3f} s (step {last}, the last in the bag; no report of the rig '
        'reached this runner)')


def test_an_interrupted_bridge_run_says_its_safe_state_was_not_confirmed(tmp_path):
    """Session 23: a Ctrl-C'd run through the UDP bridge whose controller never reported its
    safe state ended 'the rig ramped to its safe state from t = 2.552 s'. The line now says
    what the rig's final status says: NOT confirmed."""
    params = parameters.resolve({'duration_s': 0.5})
    runner = GraphRunner.__new__(GraphRunner)      # no ROS context: what the line reads
    runner.graph, runner._bag_path = Graph.from_parameters(params), tmp_path / 'bag'
    runner._bag_closed = lambda: True
    unconfirmed = ('the safe state was NOT confirmed by the controller at 127.0.0.1:47001: '
                   'no state 3 (safe) from it 0.463 s after the request (bound 0.462 s: '
                   'latency, safe ramp, hold and watchdog; its last state: running); check '
                   'the rig')
    final = {'name': 'rig', 'state': 'aborted', 'step': '1400', 'abort_at_s': '2.552000',
             'safe_confirmed': '0', 'safe_unconfirmed': unconfirmed}
    runner._rig_final = lambda heard_only=False: final
    assert runner._interrupted_state({'rig': None}) == (
        f'the rig was asked for its safe state from t = 2.552 s, but {unconfirmed}; bag '
        f'closed: {tmp_path / "bag"}')
    final.update(safe_confirmed='1')
    del final['safe_unconfirmed']
    assert runner._interrupted_state({'rig': None}).startswith(
        'the rig ramped to its safe state from t = 2.552 s; bag closed')


class _Exited:
    """A node's process that exited with `code`."""

    def __init__(self, code):
        self.code = code

    def poll(self):
        return self.code


def _runner_with_reports(later: list[dict]):
    """A runner without ROS whose spin hears the reports of `later`, one per spin."""
    runner = GraphRunner.__new__(GraphRunner)
    runner.graph = Graph.from_parameters(parameters.resolve({'duration_s': 0.5}))
    runner.statuses, spins = [], []

    def spin(seconds):
        spins.append(seconds)
        if later:
            runner.statuses.append(later.pop(0))
    runner._spin = spin
    return runner, spins


REFUSAL = {'name': 'rig', 'state': 'failed', 'published': '0',
           'message': 'udp_bridge: no datagram from the controller at 127.0.0.1:9 for 10 s'}


def test_a_rig_that_refused_the_run_is_not_a_node_death(tmp_path):
    """The CI of 08955b2: a UDP bridge whose controller was not at its address reported
    'failed' and exited with code 2; the runner saw the exit before the report and named a
    node's death ('node rig exited with code 2 at t = 0.000 s (step ?)') where the run is the
    rig's refusal ('the rig failed before its first sample: ...; nothing was run', which the
    watch then says). The report is waited for (REPORT_GRACE_S): heard on the third spin."""
    runner, spins = _runner_with_reports([{'name': 'recorder', 'state': 'ready'},
                                          {'name': 'controller', 'state': 'ready'},
                                          REFUSAL])
    runner._check_procs({'rig': _Exited(2), 'recorder': _Exited(None)}, tmp_path)
    assert len(spins) == 3 and runner._latest('rig')['state'] == 'failed'
    runner._check_procs({'rig': _Exited(2)}, tmp_path)           # heard: no wait again
    assert len(spins) == 3
    loop = _Exited(2)               # --processes loop: the rig's process holds other nodes
    runner._check_procs({'force_servo_controller': loop, 'rig': loop}, tmp_path)
    assert len(spins) == 3

    # no report within the grace, a rig that had stepped, a node that is not a rig, a
    # signal: each is a death, named as before (the reports heard before, those on the way)
    stepped = {'name': 'rig', 'state': 'running', 'step': '12', 'published': '12'}
    ended = []
    for procs, heard, later in (({'rig': _Exited(2)}, [], []),
                                ({'rig': _Exited(2)}, [stepped], [REFUSAL]),
                                ({'controller': _Exited(2)}, [], [REFUSAL]),
                                ({'controller': _Exited(2), 'rig': _Exited(None)}, [],
                                 [REFUSAL]),
                                ({'rig': _Exited(-9)}, [], [REFUSAL])):
        runner, _ = _runner_with_reports(list(later))
        runner.statuses.extend(heard)
        runner._end_run = lambda reason, procs, **values: ended.append(reason)
        runner._when = lambda: 'at t = 0.024 s (step 12)'
        with pytest.raises(SeftError, match=r'^node (rig|controller) (exited with code 2|was '
                           r'killed by SIGKILL) at t = 0.024 s'):
            runner._check_procs(procs, tmp_path)
    assert ended == ['node rig exited with code 2', 'node rig exited with code 2',
                     'node controller exited with code 2', 'node controller exited with code 2',
                     'node rig was killed by SIGKILL']


def test_parameters_that_differ_wait_for_the_rigs_word_before_nothing_was_run(monkeypatch):
    """The CI of 43ca88f: a node's differing parameters reached the runner at the rig's step
    300 before any report of the rig had (another topic; the rig not discovered yet), and the
    runner said 'nothing was run' (exit 2) while the nodes stopped the run. Now a rig's word
    is waited for: its 'running' report, heard on the third spin, makes it a stop of a run in
    progress; a rig heard 'ready' only, after the grace, a refusal of a run not begun."""
    monkeypatch.setattr('seft_ros.cli.runner.REPORT_GRACE_S', 0.2)
    monkeypatch.setattr('seft_ros.cli.runner.DISCOVERY_SETTLE_S', 0.4)
    differ = {'reference_force_builder': {'alpha': 0.5}, 'recorder': {'alpha': 0.0}}

    def runner_for(later):
        runner, spins = _runner_with_reports(later)
        runner.mismatch_stopped, runner.node_params = False, differ
        runner.progress, aborts = (lambda line: None), []
        runner._publish_abort = aborts.append
        return runner, spins, aborts

    runner, spins, aborts = runner_for([{'name': 'recorder', 'state': 'ready'},
                                        {'name': 'controller', 'state': 'ready'},
                                        {'name': 'rig', 'state': 'running', 'step': '250'}])
    runner._check_parameters()
    assert len(spins) == 3 and runner.mismatch_stopped
    assert aborts == ['parameters differ between nodes after the start: parameter alpha '
                      'differs: reference_force_builder=0.5, recorder=0.0; the run is stopped '
                      'safely']
    for later, unheard in (([{'name': 'rig', 'state': 'ready'}], False), ([], True)):
        runner, spins, aborts = runner_for(list(later))
        runner.statuses.append({'name': 'recorder', 'state': 'ready'})
        start = time.monotonic()
        with pytest.raises(SeftError, match=r'^1 shared parameter\(s\) differ between the '
                           r'nodes \(listed above\); nothing was run$'):
            runner._check_parameters()
        # spun for the grace; longer while the rig was never heard
        assert aborts == [] and len(spins) >= 2
        assert time.monotonic() - start >= (0.4 if unheard else 0.2)


def test_a_stop_signal_inside_rclpys_message_conversion_is_the_interrupt():
    """CI of session 34: a SIGHUP arrived while rclpy's ``take_message`` converted a message
    with Python code; raised there, pybind11 dropped the ``KeyboardInterrupt`` for
    ``RuntimeError: Unable to convert call argument '0' ...``, and the runner exited 1 with a
    traceback instead of ending the run safely. A stop signal inside the executor is now
    left to ``_spin``, which raises it once ``spin_once`` returns; outside it the handler
    raises at once, and an executor's own RuntimeError is raised as itself."""
    from seft_msgs_py.stopping import raise_stop

    class Executor:
        def __init__(self, signame):
            self.signame = signame
            self.returned = False

        def spin_once(self, timeout_sec):
            if self.signame is None:
                raise RuntimeError("Unable to convert call argument '0' to Python object")
            raise_stop(self.signame)            # the handler, as seft's main installs it
            self.returned = True                # (it did not raise in here)

    runner = GraphRunner.__new__(GraphRunner)      # no ROS context: what _spin reads
    runner.executor = Executor('SIGHUP')
    with pytest.raises(KeyboardInterrupt) as info:
        runner._spin(1.0)
    assert info.value.args == ('SIGHUP',) and runner.executor.returned
    with pytest.raises(KeyboardInterrupt) as info:
        raise_stop('SIGTERM')                   # not in the executor: at once
    assert info.value.args == ('SIGTERM',)
    runner.executor = Executor(None)
    with pytest.raises(RuntimeError, match='Unable to convert'):
        runner._spin(1.0)
