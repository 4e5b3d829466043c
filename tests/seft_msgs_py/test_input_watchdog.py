"""The real-time input watchdog (``node_support.InputWatchdog``) on a clock of its own."""

import pytest

from seft_msgs_py import node_support
from seft_msgs_py.node_support import WATCHDOG_START_S, InputWatchdog


class FakeNode:
    """What the watchdog uses of a node: parameters, a timer, the run's steps, abort_run."""

    def __init__(self, timeout_s):
        self.params = {'watchdog_timeout_s': timeout_s}
        self.done = False
        self.run_steps = None
        self.next_step = 0
        self.aborts = []

    def wall_timer(self, period_s, callback):
        self.period_s = period_s

    def abort_run(self, reason, step):
        self.aborts.append(reason)
        self.done = True


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(node_support.time, 'monotonic', lambda: now[0])
    return now


@pytest.mark.parametrize('limit_s, quiet_s, line', [
    (0.02, 0.019, 'watchdog: no measurement for 21 ms (limit 20 ms'),
    # before: 'limit 0 ms' (a node started by hand; seft run refuses a limit below 3 dt)
    (0.0005, 0.0004, 'watchdog: no measurement for 1 ms (limit 0.5 ms;')])
def test_a_silent_input_ends_the_run_after_the_limit(clock, limit_s, quiet_s, line):
    node = FakeNode(limit_s)
    dog = InputWatchdog(node, ('measurement',))
    dog.arm()
    dog.feed('measurement', 0)
    clock[0] += quiet_s
    dog.check()
    assert node.aborts == []
    clock[0] += 0.002 if limit_s > 0.001 else 0.0002
    dog.check()
    assert len(node.aborts) == 1
    assert node.aborts[0].startswith(line)


def test_an_input_not_heard_since_the_start_gets_the_start_limit(clock):
    node = FakeNode(0.02)
    dog = InputWatchdog(node, ('/seft/reference_force', 'measurement'))
    dog.arm()
    dog.feed('measurement', 0)
    clock[0] += WATCHDOG_START_S - 0.001      # the reference force's first sample is late:
    dog.feed('measurement', 1)                # it has not come over the link yet
    dog.check()
    assert node.aborts == []
    clock[0] += 0.002
    dog.check()
    silent_ms = round(1e3 * (WATCHDOG_START_S + 0.001))
    assert node.aborts and f'no /seft/reference_force for {silent_ms} ms' in node.aborts[0]


def test_the_last_steps_measurement_ends_the_watch(clock):
    node = FakeNode(0.02)
    node.run_steps = 10
    dog = InputWatchdog(node, ('measurement',))
    dog.arm()
    dog.feed('measurement', 8)
    dog.feed('measurement', 9)                # the run's last step: nothing more is due
    clock[0] += 1.0
    dog.check()
    assert node.aborts == []


def test_a_check_held_up_by_the_nodes_own_stall_reads_the_queue_first(clock):
    """The node was stopped 1 s (its timer too): the first check after it judges nothing, the
    measurements that waited in the queue are read, and the next check finds them in time;
    a second held-up check in a row judges."""
    node = FakeNode(0.2)
    dog = InputWatchdog(node, ('measurement',))
    dog.arm()
    dog.feed('measurement', 0)
    dog.check()
    clock[0] += 1.0                           # SIGSTOP ... SIGCONT
    dog.check()
    assert node.aborts == []
    dog.feed('measurement', 1)                # the queue, read after the held-up check
    clock[0] += 0.01
    dog.check()
    assert node.aborts == []
    clock[0] += 1.0                           # silent again, and the check held up again:
    dog.check()                               # deferred once only
    clock[0] += 0.25
    dog.check()
    assert len(node.aborts) == 1 and 'no measurement for 1260 ms' in node.aborts[0]


def test_an_input_lost_while_the_node_stalled_is_caught_one_period_later(clock):
    node = FakeNode(0.02)
    dog = InputWatchdog(node, ('measurement',))
    dog.arm()
    dog.feed('measurement', 0)
    dog.check()
    clock[0] += 0.5                           # the node stalled, and nothing is queued
    dog.check()
    assert node.aborts == []
    clock[0] += node.period_s
    dog.check()
    assert len(node.aborts) == 1 and 'no measurement for 510 ms (limit 20 ms' in node.aborts[0]
