"""The runner names when a node died: from the rig's reports, or, when none reached it (a
process killed before this runner had discovered it), from the last sample in the closed bag."""

from seft_msgs_py import parameters
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
