"""The real-time force servo controller waits for a late reference force until its deadline
(``reference_deadline_fraction``), then predicts it: the node's own methods, driven without
DDS on a controlled clock (the node's state set as its ``__init__`` sets it in real time;
the controller a pass-through, so the valve command is the force it acted on)."""

import time

import pytest

from seft_ros.core.controller import ReferencePlayout
from seft_ros.nodes import force_servo_controller as fsc

DT_NS = 2_000_000
T0_NS = 10_000_000_000


class _Clock:
    now_ns = T0_NS

    def __call__(self):
        return self.now_ns


class _PassThrough:
    saturated = False

    def step(self, fr, fm, v, a, x):
        return fr


class _Timing:
    def __init__(self):
        self.rows = []

    def start(self):
        return 0.0, 0.0

    def publish(self, stamp_ns, jitter, compute, age, missed, stale):
        self.rows.append((stamp_ns // DT_NS, stale))


class _Quiet:
    def feed(self, *args):
        pass

    def arm(self):
        pass

    def update(self, saturated, time_s):
        return None


@pytest.fixture
def node(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(fsc.clock, 'now_ns', clock)
    n = object.__new__(fsc.ForceServoControllerNode)
    published = []
    n.__dict__.update(
        controller=_PassThrough(), interlock=_Quiet(), watchdog=_Quiet(), timing=_Timing(),
        playout=ReferencePlayout(0, 2), dt=DT_NS * 1e-9, dt_ns=DT_NS, t0_ns=T0_NS,
        wait_ns=0.5 * DT_NS, pending=None, next_step=0, valve_topic='/seft/valve_command',
        out_msg=lambda topic, stamp, values: (stamp // DT_NS, values[0]),
        batch=type('Batch', (), {'add': lambda self, k, u: None})(),
        pub=type('Pub', (), {'publish': lambda self, msg: published.append(msg)})(),
        guard=lambda callback: callback, done=False)
    n.clock, n.published = clock, published
    return n


def _at(node, step, after_ms):
    node.clock.now_ns = T0_NS + step * DT_NS + int(after_ms * 1e6)


def test_a_force_late_by_less_than_the_deadline_is_waited_for_and_used(node):
    for k in (0, 1):
        node._on_reference_realtime(k, 10.0 * (k + 1))
        _at(node, k, 0.5)
        node._on_measured_realtime(k, 0.0)
    assert node.published == [(0, 10.0), (1, 20.0)] and node.next_due() is None
    _at(node, 2, 0.5)
    node._on_measured_realtime(2, 0.0)            # f_r[2] not there: wait for it
    assert node.published == [(0, 10.0), (1, 20.0)]
    assert node.next_due() is not None
    _at(node, 2, 0.8)
    node._on_reference_realtime(2, 35.0)          # in before t_2 + 1 ms: acted on as sent
    assert node.published[-1] == (2, 35.0) and node.next_due() is None
    assert node.timing.rows[-1] == (2, False)


def test_at_the_deadline_the_force_is_predicted_and_the_step_counted_stale(node):
    for k in (0, 1):
        node._on_reference_realtime(k, 10.0 * (k + 1))
        _at(node, k, 0.5)
        node._on_measured_realtime(k, 0.0)
    _at(node, 2, 0.5)
    node._on_measured_realtime(2, 0.0)
    node.run_due()                                # the deadline: extrapolated 20 + 10
    assert node.published[-1] == (2, 30.0) and node.timing.rows[-1] == (2, True)
    node._on_reference_realtime(2, 35.0)          # too late: not acted on again
    assert len(node.published) == 3


def test_past_the_deadline_or_with_no_wait_the_controller_acts_at_once(node):
    node._on_reference_realtime(0, 10.0)
    _at(node, 0, 0.5)
    node._on_measured_realtime(0, 0.0)
    _at(node, 1, 1.2)                             # measurement of 1 after t_1 + 1 ms
    node._on_measured_realtime(1, 0.0)
    assert node.published[-1] == (1, 10.0) and node.next_due() is None
    node.wait_ns = 0.0                            # reference_deadline_fraction 0
    _at(node, 2, 0.1)
    node._on_measured_realtime(2, 0.0)
    assert node.published[-1] == (2, 10.0) and node.timing.rows[-1] == (2, True)


def test_a_newer_measurement_releases_the_step_that_waits(node):
    node._on_reference_realtime(0, 10.0)
    _at(node, 0, 0.5)
    node._on_measured_realtime(0, 0.0)
    _at(node, 1, 0.5)
    node._on_measured_realtime(1, 0.0)            # waits for f_r[1]
    node._on_reference_realtime(2, 30.0)          # f_r[1] lost; f_r[2] in
    _at(node, 2, 0.5)
    node._on_measured_realtime(2, 0.0)            # step 1 goes first, then 2 on f_r[2]
    assert node.published == [(0, 10.0), (1, 30.0), (2, 30.0)]
    assert [stale for _, stale in node.timing.rows] == [False, True, False]


def test_the_wait_is_never_longer_than_its_fraction_of_dt(node):
    """A measurement that arrives before its own sample instant on this host's clock (a lab
    controller's clock ahead of it): the step waits at most 0.5 dt from now."""
    node._on_reference_realtime(0, 10.0)
    _at(node, 0, 0.5)
    node._on_measured_realtime(0, 0.0)
    _at(node, 1, -3.0)                            # 3 ms before t_1 here
    before = time.monotonic()
    node._on_measured_realtime(1, 0.0)
    assert node.next_due() - before <= 1e-3 + 1e-4
