"""ground_motion_publisher node: the prepared ground acceleration, ahead of the clock.

Loads the record (``record``: 'default', a PEER .AT2 or a CSV path), scales it (amplitude_N or
scale_factor), time-scales it and resamples it to ``dt`` (``seft_ros.core.ground_motion``),
reports its length on ``/seft/status`` and publishes ``xg''[k]`` (step k) in record batches
on ``/seft/record/ground_motion_publisher``: the first ``preview_steps`` at once, then, at
every ``/clock`` (published every ``CLOCK_EVERY`` steps), up to ``preview_steps + CLOCK_EVERY
- 1`` ahead, one batch each time, so that the reference-force builder always has the samples
it needs (and a preview of the record, which is known before the test). The builder reads
the batches; the recorder writes them to the bag as ``/seft/ground_acceleration``, one
stamped message per sample. Measured at 1 kHz: one message per ten samples instead of one per
sample saved the builder and this node about 0.1 of a core each.

In real-time mode it also records one timing record per sample (the bag's
``/seft/timing/ground_motion_publisher``; a sample is late, a missed deadline, when it is
published after the sample before it was due).

Run by hand: ``ros2 run seft_ros ground_motion_publisher --ros-args --params-file ...``.
"""

import json
import math
import sys
import time

from seft_msgs_py import clock
from seft_msgs_py.convert import STATE_READY, clock_ns_from_raw
from seft_msgs_py.node_support import SeftNode, StepTiming, main_for
from seft_msgs_py.topics import CLOCK, CLOCK_EVERY
from seft_ros.core.ground_motion import prepared_record

__all__ = ['GroundMotionPublisher', 'main']


class GroundMotionPublisher(SeftNode):
    """Publishes the prepared record, ``preview_steps`` ahead of the simulated clock."""

    def __init__(self):
        super().__init__('ground_motion_publisher')
        p = self.params
        self.record = prepared_record(p)
        self.values = self.record.acceleration_m_s2
        self.n_steps = int(self.values.shape[0])
        self.preview = int(p['preview_steps'])
        self.next_step = 0
        # the samples go out as record batches only: the builder reads them there, and the
        # recorder writes them to the bag's /seft/ground_acceleration
        self.batch = self.record_stream()
        clock = self.create_subscription(CLOCK.msg_type, CLOCK.name,
                                         self.guard(self._on_clock), CLOCK.qos, raw=True)
        if self.realtime:
            self.watch_inputs([clock], [self.batch.pub])
            self.timing = StepTiming(self)
        self.publish_parameters()
        self.get_logger().info(
            f'record {self.record.name}: {self.n_steps} steps of {p["dt"]} s, '
            f'peak {abs(self.values).max():.4g} m/s^2')
        # a run cut short of its record previews the ground motion that goes on there
        # (GroundMotion.following_m_s2; repr floats: the builder reads the same numbers)
        self.report(STATE_READY, f'record {self.record.name}', n_steps=self.n_steps,
                    record=self.record.name,
                    following=json.dumps(list(self.record.following_m_s2)))
        self._publish_until(self.preview)

    def _publish_until(self, last: int, clock_step: int | None = None) -> None:
        last = min(last, self.n_steps - 1)
        start, jitter = (self.timing.start() if self.timing is not None and self.next_step <= last
                         else (0.0, math.nan))
        while self.next_step <= last:
            k = self.next_step
            self.batch.add(k, float(self.values[k]))
            self.next_step += 1
            if self.timing is not None:
                now_ns = clock.now_ns()
                age = (math.nan if clock_step is None
                       else (now_ns - self.sample_time_ns(clock_step)) * 1e-9)
                self.timing.publish(k * self.dt_ns, jitter, time.monotonic() - start, age,
                                    now_ns > self.sample_time_ns(k - 1), False)
                jitter = math.nan
        self.batch.flush()      # every sample published so far is out (the builder needs them)

    def _on_clock(self, raw) -> None:
        k = int(round(clock_ns_from_raw(raw) / self.dt_ns))
        # the next /clock comes CLOCK_EVERY steps later: stay preview_steps ahead until then
        self._publish_until(k + self.preview + CLOCK_EVERY - 1, k)


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros ground_motion_publisher``."""
    return main_for(GroundMotionPublisher, 'ground_motion_publisher', args)


if __name__ == '__main__':
    sys.exit(main())
