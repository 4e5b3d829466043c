"""force_servo_controller node: u[k] = sat(C_f(z) (f_r[k] - f_m[k])), paper Eq. 3.1.

When the reference force and the measured force of step k have both arrived it publishes the
valve command of step k. Its loss-of-control interlock (``seft_ros.core.controller.
SaturationInterlock``) aborts the run when the valve stays saturated: it then publishes
'aborted' on ``/seft/status`` instead of the command, and the rig stops.

Run by hand: ``ros2 run seft_ros force_servo_controller --ros-args --params-file ...``.
"""

import sys

from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_READY,
    dt_to_ns,
    scalar_msg,
    scalar_value,
    step_of,
)
from seft_msgs_py.node_support import SeftNode, main_for
from seft_msgs_py.sync import StepSync
from seft_msgs_py.topics import MEASURED_FORCE, REFERENCE_FORCE, VALVE_COMMAND
from seft_ros.core.controller import ForceServoController, SaturationInterlock

__all__ = ['ForceServoControllerNode', 'main']


class ForceServoControllerNode(SeftNode):
    """Lockstep shell around :class:`ForceServoController`."""

    def __init__(self):
        super().__init__('force_servo_controller')
        p = self.params
        self.controller = ForceServoController.from_parameters(p)
        self.interlock = SaturationInterlock.from_parameters(p)
        self.dt = float(p['dt'])
        self.dt_ns = dt_to_ns(self.dt)
        self.sync = StepSync((REFERENCE_FORCE.name, MEASURED_FORCE.name))
        self.ready = {}
        self.next_step = 0
        self.pub = self.create_publisher(VALVE_COMMAND.msg_type, VALVE_COMMAND.name,
                                         VALVE_COMMAND.qos)
        for spec in (REFERENCE_FORCE, MEASURED_FORCE):
            self.create_subscription(spec.msg_type, spec.name,
                                     self.guard(lambda msg, s=spec: self._on_force(s, msg)),
                                     spec.qos)
        self.report(STATE_READY, f'controller discretized: {self.controller.design.method}')

    def _on_force(self, spec, msg) -> None:
        k = step_of(msg.header.stamp, self.dt_ns)
        done = self.sync.add(k, spec.name, scalar_value(spec, msg))
        if done is None:
            return
        self.ready[k] = done
        while self.next_step in self.ready and not self.done:
            k = self.next_step
            forces = self.ready.pop(k)
            u = self.controller.step(forces[REFERENCE_FORCE.name], forces[MEASURED_FORCE.name])
            reason = self.interlock.update(self.controller.saturated, k * self.dt)
            if reason:
                self.get_logger().error(reason)
                self.report(STATE_ABORTED, reason, step=k, time_s=f'{k * self.dt:.6f}')
                self.finish(0)
                return
            self.pub.publish(scalar_msg(VALVE_COMMAND, k * self.dt_ns, u))
            self.next_step += 1


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros force_servo_controller``."""
    return main_for(ForceServoControllerNode, 'force_servo_controller', args)


if __name__ == '__main__':
    sys.exit(main())
