"""ground_motion_publisher node: the prepared ground acceleration, ahead of the clock.

Loads the record (``record``: 'default', a PEER .AT2 or a CSV path), scales it (amplitude_N or
scale_factor), time-scales it and resamples it to ``dt`` (``seft_ros.core.ground_motion``),
reports its length on ``/seft/status`` and publishes ``xg''[k]`` stamped ``t_k`` on
``/seft/ground_acceleration``: the first ``preview_steps`` at once, then one more for every
``/clock`` tick, so the reference-force builder always has the samples it needs (and a
preview of the record, which is known before the test).

Run by hand: ``ros2 run seft_ros ground_motion_publisher --ros-args --params-file ...``.
"""

import sys

from seft_msgs_py.convert import (
    STATE_READY,
    dt_to_ns,
    scalar_msg,
    step_of,
)
from seft_msgs_py.node_support import SeftNode, main_for
from seft_msgs_py.topics import CLOCK, GROUND_ACCELERATION
from seft_ros.core.experiment import prepared_record

__all__ = ['GroundMotionPublisher', 'main']


class GroundMotionPublisher(SeftNode):
    """Publishes the prepared record, ``preview_steps`` ahead of the simulated clock."""

    def __init__(self):
        super().__init__('ground_motion_publisher')
        p = self.params
        self.record = prepared_record(p)
        self.values = self.record.acceleration_m_s2
        self.n_steps = int(self.values.shape[0])
        self.dt_ns = dt_to_ns(p['dt'])
        self.preview = int(p['preview_steps'])
        self.next_step = 0
        self.pub = self.create_publisher(GROUND_ACCELERATION.msg_type, GROUND_ACCELERATION.name,
                                         GROUND_ACCELERATION.qos)
        self.create_subscription(CLOCK.msg_type, CLOCK.name, self.guard(self._on_clock),
                                 CLOCK.qos)
        self.get_logger().info(
            f'record {self.record.name}: {self.n_steps} steps of {p["dt"]} s, '
            f'peak {abs(self.values).max():.4g} m/s^2')
        self.report(STATE_READY, f'record {self.record.name}', n_steps=self.n_steps,
                    record=self.record.name)
        self._publish_until(self.preview)

    def _publish_until(self, last: int) -> None:
        last = min(last, self.n_steps - 1)
        while self.next_step <= last:
            k = self.next_step
            self.pub.publish(scalar_msg(GROUND_ACCELERATION, k * self.dt_ns,
                                        float(self.values[k])))
            self.next_step += 1

    def _on_clock(self, msg) -> None:
        self._publish_until(step_of(msg.clock, self.dt_ns) + self.preview)


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros ground_motion_publisher``."""
    return main_for(GroundMotionPublisher, 'ground_motion_publisher', args)


if __name__ == '__main__':
    sys.exit(main())
