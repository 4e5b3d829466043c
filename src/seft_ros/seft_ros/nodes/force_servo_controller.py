"""force_servo_controller node: u[k] = sat(C_f(z) (f_r[k] - f_m[k])), paper Eq. 3.1.

Lockstep mode: when the reference force and the measured force of step k have both arrived it
publishes the valve command of step k. Real-time mode: it acts on the arrival of each measured
force ``f_m[k]`` (in the rig's measurement) with the newest reference force it has
(normally ``f_r[k]``, built in parallel during step k-1; when it is late the step counts as
stale and the force is predicted from the newest ones, ``reference_extrapolation`` and
``reference_extrapolation_steps``), and records one timing record per step (the bag's
``/seft/timing/force_servo_controller``, through its record stream). When the reference
force of step k is late it waits for it, until ``reference_deadline_fraction`` of the period
after the sample instant ``t_k`` (then predicts it): a builder a fraction of a millisecond
late then costs the command that much time, not a predicted force (0: never wait).

Its loss-of-control interlock (``seft_ros.core.controller.SaturationInterlock``) aborts the
run when the valve stays saturated: it then publishes 'aborted' on ``/seft/status`` instead of
the command, and the rig stops.

Run by hand: ``ros2 run seft_ros force_servo_controller --ros-args --params-file ...``.
"""

import sys
import time

from seft_msgs_py import clock
from seft_msgs_py.convert import (
    STATE_READY,
    SerializedStamped,
)
from seft_msgs_py.node_support import InputWatchdog, SeftNode, StepTiming, main_for
from seft_msgs_py.sync import StepSync
from seft_msgs_py.topics import MEASURED_FORCE, REFERENCE_FORCE, VALVE_COMMAND
from seft_ros.core.controller import (
    ReferencePlayout,
    SaturationInterlock,
    prediction_window_steps,
)
from seft_ros.core.excitation import make_valve_controller
from seft_ros.core.reference_force import network_delay_steps

__all__ = ['ForceServoControllerNode', 'main']


class ForceServoControllerNode(SeftNode):
    """Lockstep shell around :class:`~seft_ros.core.controller.ForceServoController` (or, in
    an open-loop identification run, :class:`~seft_ros.core.excitation.OpenLoopValve`)."""

    def __init__(self):
        super().__init__('force_servo_controller')
        p = self.params
        # the force controller, or the excitation in an open-loop identification run
        self.controller = make_valve_controller(p)
        self.interlock = SaturationInterlock.from_parameters(p)
        self.dt = float(p['dt'])
        #: Real time, the builder on another host: f_r[k] is applied at step k + this
        #: (network_delay_s; 0 on one host). Raises ParameterError in lockstep.
        self.playout_steps = network_delay_steps(p)
        self.sync = StepSync((REFERENCE_FORCE.name, MEASURED_FORCE.name))
        self.ready = {}
        self.next_step = 0
        # the rig's topics: in its namespace for a rig of a structure
        reference = self.scoped_spec(REFERENCE_FORCE)
        valve = self.scoped_spec(VALVE_COMMAND)
        self.pub = self.create_publisher(valve.msg_type, valve.name, valve.qos)
        self.valve_topic = valve.name
        self.out_msg = self.sealed_writer(SerializedStamped.scalar(valve, self.seal.frame_id))
        self.batch = self.record_stream()
        #: real time, a step waiting for its reference force: (monotonic deadline [s], k,
        #: measured values, period jitter [s])
        self.pending = None
        if self.realtime:
            self.timing = StepTiming(self)
            #: f_r[k - m] of each step, or its extrapolation when it is late
            self.playout = ReferencePlayout(self.playout_steps,
                                            int(p['reference_extrapolation_steps']),
                                            prediction_window_steps(p))
            #: how long after t_k a late reference force is waited for [ns]
            self.wait_ns = float(p['reference_deadline_fraction']) * self.dt_ns
            self.watchdog = InputWatchdog(self, (REFERENCE_FORCE.name, 'measurement'))
            self.watch_inputs([
                self.scalar_subscription(reference, self._on_reference_realtime),
                self.measurement_subscription(
                    lambda k, values: self._on_measured_realtime(k, *values))], [self.pub])
        else:
            self.scalar_subscription(
                reference, lambda k, value: self._on_force(REFERENCE_FORCE.name, k, value))
            self.measurement_subscription(
                lambda k, values: self._on_force(MEASURED_FORCE.name, k, values))
        self.publish_parameters()
        self.report(STATE_READY, f'controller discretized: {self.controller.design.method}')

    def _on_reference_realtime(self, k: int, value: float) -> None:
        self.watchdog.feed(REFERENCE_FORCE.name)
        self.playout.receive(k, value)
        pending = self.pending
        if pending is not None and self.playout.has_due(pending[1]):
            self.pending = None
            if not self.done:
                self._act(*pending[1:])

    def next_due(self) -> float | None:
        """The deadline of a step waiting for its reference force (None: none waits)."""
        return None if self.pending is None else self.pending[0]

    def run_due(self) -> None:
        """The deadline came: act with the predicted force."""
        pending, self.pending = self.pending, None
        if pending is not None and not self.done:
            self.guard(self._act)(*pending[1:])

    def _on_measured_realtime(self, k: int, fm: float, x: float = 0.0, v: float = 0.0,
                              a: float = 0.0) -> None:
        """u[k] from the measurement of k (f_m, x, v, a) and the reference force of step k
        (``network_delay_s``: of step k - m); when that force is late, wait for it until
        the deadline (:meth:`next_due`), then use its prediction from the newest ones
        (:class:`~seft_ros.core.controller.ReferencePlayout`)."""
        _, jitter = self.timing.start()
        self.watchdog.feed('measurement', k)
        self.watchdog.arm()
        if k < self.next_step:
            return                          # a duplicate: each step is computed once
        if self.pending is not None:        # a newer measurement: the waiting step goes now
            pending, self.pending = self.pending, None
            self._act(*pending[1:])
            if self.done:
                return
        if self.wait_ns > 0 and not self.playout.has_due(k):
            # until t_k + the fraction of dt, and never longer than that fraction from now
            # (a lab controller's clock that drifts from this host's moves t_k here)
            wait_s = min(self.sample_time_ns(k) + self.wait_ns - clock.now_ns(),
                         self.wait_ns) * 1e-9
            if wait_s > 0:                  # (nan before t0: act at once)
                self.pending = (time.monotonic() + wait_s, k, (fm, x, v, a), jitter)
                return
        self._act(k, (fm, x, v, a), jitter)

    def _act(self, k: int, measured: tuple, jitter: float) -> None:
        """Compute and publish u[k] (the timing record's compute time is this call's; a
        wait for the reference force shows in its input age, from the sample instant)."""
        start = time.monotonic()
        fm, x, v, a = measured
        fr, stale, fr_step = self.playout.due(k)
        u = self.controller.step(fr, fm, v, a, x)
        reason = self.interlock.update(self.controller.saturated, k * self.dt)
        if reason:
            self.abort_run(reason, k)
            return
        self.pub.publish(self.out_msg(self.valve_topic, k * self.dt_ns, (u,)))
        self.batch.add(k, u)
        self.next_step = k + 1
        now_ns = clock.now_ns()
        oldest = min(k, fr_step) if fr_step >= 0 else k
        age = (now_ns - self.sample_time_ns(oldest)) * 1e-9
        missed = now_ns > self.sample_time_ns(k + 1)   # nan compares False before t0
        self.timing.publish(k * self.dt_ns, jitter, time.monotonic() - start, age, missed,
                            stale)

    def _on_force(self, name: str, k: int, value) -> None:
        """Lockstep: collect f_r[k] (a float) and the measurement of k (a tuple)."""
        done = self.sync.add(k, name, value)
        if done is None:
            return
        self.ready[k] = done
        while self.next_step in self.ready and not self.done:
            k = self.next_step
            forces = self.ready.pop(k)
            # the measurement: (force, displacement, velocity, acceleration), as simulate
            fm, x, v, a = forces[MEASURED_FORCE.name]
            u = self.controller.step(forces[REFERENCE_FORCE.name], fm, v, a, x)
            reason = self.interlock.update(self.controller.saturated, k * self.dt)
            if reason:
                self.abort_run(reason, k)
                return
            self.pub.publish(self.out_msg(self.valve_topic, k * self.dt_ns, (u,)))
            self.batch.add(k, u)
            self.next_step += 1


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros force_servo_controller``."""
    return main_for(ForceServoControllerNode, 'force_servo_controller', args)


if __name__ == '__main__':
    sys.exit(main())
