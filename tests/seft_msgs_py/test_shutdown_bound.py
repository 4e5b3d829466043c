"""A node process's ROS shutdown after its run is bounded (node_support.shut_down): past
SHUTDOWN_TIMEOUT_S the process exits with its code and one line, instead of hanging."""

import time

from seft_msgs_py import node_support


class _Node:
    def __init__(self, seconds):
        self.seconds, self.destroyed = seconds, False

    def destroy_node(self):
        time.sleep(self.seconds)
        self.destroyed = True


def test_a_hanging_teardown_exits_with_the_run_code_and_one_line(monkeypatch, capsys):
    exits = []
    monkeypatch.setattr(node_support, 'SHUTDOWN_TIMEOUT_S', 0.2)
    monkeypatch.setattr(node_support.os, '_exit', exits.append)
    monkeypatch.setattr(node_support.rclpy, 'try_shutdown', lambda: None)
    node_support.shut_down([_Node(1.0)], 'rig', 3)           # hangs past the bound
    assert exits == [3]
    err = capsys.readouterr().err
    assert err == 'rig: its ROS shutdown did not finish within 0.2 s; exiting\n'


def test_a_prompt_teardown_exits_normally(monkeypatch, capsys):
    exits = []
    monkeypatch.setattr(node_support, 'SHUTDOWN_TIMEOUT_S', 0.5)
    monkeypatch.setattr(node_support.os, '_exit', exits.append)
    monkeypatch.setattr(node_support.rclpy, 'try_shutdown', lambda: None)
    node = _Node(0.0)
    node_support.shut_down([node], 'rig', 0)
    time.sleep(0.7)                                           # the bound would have fired
    assert node.destroyed and exits == []
    assert capsys.readouterr().err == ''


def test_outputs_are_closed_before_the_bound_runs(monkeypatch):
    """A bag's close is not cut short: close_outputs runs first, unbounded (1 s here against a
    0.2 s bound), and only the teardown after it is bounded."""
    exits, order = [], []
    monkeypatch.setattr(node_support, 'SHUTDOWN_TIMEOUT_S', 0.2)
    monkeypatch.setattr(node_support.os, '_exit', exits.append)
    monkeypatch.setattr(node_support.rclpy, 'try_shutdown', lambda: order.append('shutdown'))

    class Writer(_Node):
        def close_outputs(self):
            time.sleep(1.0)
            order.append('closed')

    node_support.shut_down([Writer(0.0)], 'recorder', 0)
    time.sleep(0.3)
    assert order == ['closed', 'shutdown'] and exits == []
