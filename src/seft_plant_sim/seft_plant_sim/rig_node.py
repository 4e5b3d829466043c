"""rig node: the simulated actuator + specimen, master of the simulated clock (lockstep mode).

At each step k the rig checks its safety limits, publishes ``/clock`` = t_k and the sensor
readings stamped t_k, then waits for the command of step k (the valve command of the force
servo controller, or the reference force for the 'delay' rig), applies it over the step and
moves to k+1. The run ends after ``n_steps`` (or the length the ground-motion publisher
reports), on a limit violation, or when another node reports 'aborted'; the rig then
reports 'done' or 'aborted' and exits.

Run by hand: ``ros2 run seft_plant_sim rig --ros-args --params-file config/default.yaml``
(here: ``.venv/lib/seft_plant_sim/rig --ros-args ...``).
"""

import sys

from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RUNNING,
    clock_msg,
    dt_to_ns,
    scalar_msg,
    scalar_value,
    status_values,
    step_of,
)
from seft_msgs_py.node_support import SeftNode, main_for
from seft_msgs_py.topics import (
    ACCELERATION,
    CLOCK,
    DISPLACEMENT,
    MEASURED_FORCE,
    REFERENCE_FORCE,
    STATUS,
    VALVE_COMMAND,
    VELOCITY,
)
from seft_plant_sim.interface import COMMAND_VALVE
from seft_plant_sim.rigs import make_rig

__all__ = ['RigNode', 'main']

#: Sim-time interval of progress reports [steps].
PROGRESS_EVERY = 250


class RigNode(SeftNode):
    """Lockstep rig node around a :class:`seft_plant_sim.interface.Rig`."""

    def __init__(self):
        super().__init__('rig')
        p = self.params
        self.rig = make_rig(p)
        self.dt_ns = dt_to_ns(p['dt'])
        self.n_steps = int(p['n_steps'])
        self.command_topic = (VALVE_COMMAND if self.rig.command_kind == COMMAND_VALVE
                              else REFERENCE_FORCE)
        self.clock_pub = self.create_publisher(CLOCK.msg_type, CLOCK.name, CLOCK.qos)
        self.pubs = {t.name: self.create_publisher(t.msg_type, t.name, t.qos)
                     for t in (MEASURED_FORCE, DISPLACEMENT, VELOCITY, ACCELERATION)}
        self.command_sub = self.create_subscription(
            self.command_topic.msg_type, self.command_topic.name,
            self.guard(self._on_command), self.command_topic.qos)
        self.pending = {}
        self.window = int(p['recorder_window_steps'])
        self.recorded = 0
        self.waiting_for_recorder = False
        self.published = 0
        self.running = False
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status),
                                 STATUS.qos)
        self.start_timer = self.wall_timer(0.05, self._try_start)
        self.report(STATE_READY, 'waiting for the command publisher and the record length',
                    n_steps=self.n_steps)

    def _try_start(self) -> None:
        if self.running or self.n_steps <= 0:
            return
        if self.command_sub.get_publisher_count() < 1:
            return
        if self.params['wait_for_recorder'] and not self._recorder_subscribed():
            return
        self.start_timer.cancel()
        self.running = True
        self.get_logger().info(f'starting: {self.n_steps} steps of {self.rig.dt} s, '
                               f'command {self.command_topic.name}')
        self._publish_step()

    def _recorder_subscribed(self) -> bool:
        """The recorder's subscriptions to every rig topic are discovered."""
        for name in self.pubs:
            nodes = {i.node_name for i in self.get_subscriptions_info_by_topic(name)}
            if 'recorder' not in nodes:
                return False
        return True

    def _on_status(self, msg) -> None:
        values = status_values(msg)
        state = values.get('state')
        if msg.name == 'recorder':
            self.recorder_ready = True   # also set by SeftNode; this callback may run first
            if 'recorded' in values:
                self.recorded = int(values['recorded'])
                if self.waiting_for_recorder and self._recorder_keeps_up():
                    self.waiting_for_recorder = False
                    self._publish_step()
        if msg.name == 'ground_motion_publisher' and self.n_steps <= 0 and 'n_steps' in values:
            self.n_steps = int(values['n_steps'])
        if msg.name != self.seft_name and state in (STATE_ABORTED, STATE_FAILED):
            self._end(STATE_ABORTED, f'{msg.name}: {msg.message}')

    def _recorder_keeps_up(self) -> bool:
        return (not self.recorder_ready or self.window <= 0
                or self.rig.step - self.recorded < self.window)

    def _publish_step(self) -> None:
        """Limit check, then clock and sensor readings of the current step.

        In lockstep mode with a recorder, the rig holds the step until the recorder has
        recorded all but ``recorder_window_steps`` of the past steps: the simulated test waits
        rather than the bag losing samples.
        """
        if not self._recorder_keeps_up():
            self.waiting_for_recorder = True
            return
        reason = self.rig.limit_violation()
        if reason:
            self._end(STATE_ABORTED, reason)
            return
        k = self.rig.step
        stamp = k * self.dt_ns
        m = self.rig.measure()
        self.clock_pub.publish(clock_msg(stamp))
        self.pubs[MEASURED_FORCE.name].publish(scalar_msg(MEASURED_FORCE, stamp, m.force_N))
        self.pubs[DISPLACEMENT.name].publish(scalar_msg(DISPLACEMENT, stamp, m.displacement_m))
        self.pubs[VELOCITY.name].publish(scalar_msg(VELOCITY, stamp, m.velocity_m_s))
        self.pubs[ACCELERATION.name].publish(
            scalar_msg(ACCELERATION, stamp, m.acceleration_m_s2))
        self.published = k + 1
        if k % PROGRESS_EVERY == 0:
            self.report(STATE_RUNNING, step=k, n_steps=self.n_steps, time_s=f'{m.time_s:.3f}')

    def _on_command(self, msg) -> None:
        k = step_of(msg.header.stamp, self.dt_ns)
        self.pending[k] = scalar_value(self.command_topic, msg)
        while self.running and self.rig.step in self.pending:
            self.rig.apply(self.pending.pop(self.rig.step))
            if self.rig.step >= self.n_steps:
                self._end(STATE_DONE, f'completed {self.n_steps} steps')
                return
            self._publish_step()

    def _end(self, state: str, message: str) -> None:
        if self.done:
            return
        k = self.rig.step
        self.running = False
        if state == STATE_ABORTED:
            self.get_logger().error(f'run aborted at step {k}: {message}')
        else:
            self.get_logger().info(message)
        self.report(state, message, step=k, n_steps=self.n_steps,
                    time_s=f'{k * self.rig.dt:.6f}', published=self.published)
        self.finish(0)


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_plant_sim rig``."""
    return main_for(RigNode, 'rig', args)


if __name__ == '__main__':
    sys.exit(main())
