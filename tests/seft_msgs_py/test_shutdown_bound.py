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
    assert err == ('rig: its ROS shutdown did not finish within 0.2 s of the end of the run; '
                   'exiting\n')


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
