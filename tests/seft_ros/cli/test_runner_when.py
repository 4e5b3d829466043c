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
