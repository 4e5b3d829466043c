"""Rig nodes broken on purpose, for the tests of ``seft rig-check`` only.

``python broken_rig.py MODE --ros-args --params-file FILE`` starts seft's real-time rig node
with one fault (:data:`MODES`):

``wrong_sign``
    the load cell's sign is inverted (the measured force is minus the true one);
``unit_error``
    the displacement is published in millimetres instead of metres;
``no_safe_state``
    on an abort the rig holds its last command instead of ramping it to zero;
``late_clock``
    the rig ticks every 1.25 dt on the wall clock (its stamps still say k dt).
"""

from dataclasses import replace
import sys

from seft_msgs_py.node_support import main_for
from seft_plant_sim.realtime import WallClockRig
from seft_plant_sim.rig_node import RigNode

#: Factor of the late clock's tick period.
LATE = 1.25


class _BrokenRig(WallClockRig):
    """The simulated rig with one fault."""

    def __init__(self, params, mode: str):
        super().__init__(params)
        self.mode = mode

    def measure(self):
        m = super().measure()
        if self.mode == 'wrong_sign':
            return replace(m, force_N=-m.force_N)
        if self.mode == 'unit_error':
            return replace(m, displacement_m=1e3 * m.displacement_m)
        return m

    def _safe_command(self, sub: int) -> float:
        if self.mode == 'no_safe_state':
            return self._safe_from_value        # held, never ramped
        return super()._safe_command(sub)


class BrokenRigNode(RigNode):
    """seft's rig node around :class:`_BrokenRig`; the late clock ticks slow."""

    mode = ''

    def __init__(self):
        super().__init__()
        self.rig = _BrokenRig(self.params, self.mode)

    def next_due(self):
        due = super().next_due()
        if self.mode != 'late_clock' or due is None or not self.running or self.t0 is None \
                or self.drain_until is not None:
            return due
        return self.t0 + (self.rig.step + 1) * self.rig.dt * LATE

    def due_step(self, now: float) -> int:
        if self.mode == 'late_clock':
            return int((now - self.t0) / (self.rig.dt * LATE))
        return super().due_step(now)


MODES = ('wrong_sign', 'unit_error', 'no_safe_state', 'late_clock')


def main() -> int:
    mode = sys.argv[1]
    if mode not in MODES:
        print(f'broken_rig: mode {mode!r}: expected one of {", ".join(MODES)}', file=sys.stderr)
        return 2
    BrokenRigNode.mode = mode
    return main_for(BrokenRigNode, 'rig', sys.argv[:1] + sys.argv[2:])


if __name__ == '__main__':
    sys.exit(main())
