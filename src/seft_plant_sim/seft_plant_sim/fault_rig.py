"""seft's rig node with one wiring fault injected (``seft rig-check --inject FAULT``).

``python -m seft_plant_sim.fault_rig FAULT --ros-args --params-file FILE`` starts the rig
node of :mod:`seft_plant_sim.rig_node` with its rig wrapped in
:class:`~seft_plant_sim.faults.FaultyRig` (``FAULT``: one of
:data:`~seft_plant_sim.faults.FAULTS`): what it measures, how it stamps its samples, how fast
it ticks, whether it ramps its command on an abort. Its ready report says which fault it
carries (``injected_fault``), so a bag recorded with it says so too.

Nothing else changes: the same topics, status, timing and safe state as seft's rig node, so
that ``seft rig-check`` shows what the fault looks like to the rest of the graph. Not for a
test of a specimen.
"""

import sys

from seft_msgs_py.node_support import main_for
from seft_plant_sim.faults import FAULTS, Fault, FaultyRig, check_supported
from seft_plant_sim.rig_node import RigNode

__all__ = ['FaultRigNode', 'main']


class FaultRigNode(RigNode):
    """seft's rig node around a :class:`~seft_plant_sim.faults.FaultyRig`.

    Raises
    ------
    ParameterError
        The rig is a UDP bridge (the fault is its controller's: ``seft emulate-controller
        --inject``), or a parameter is out of range.
    """

    #: The fault (set by :func:`main` before the node is made).
    fault: Fault = FAULTS['force_reversed']

    def __init__(self):
        super().__init__()
        check_supported(self.fault, self.params)
        self.rig = FaultyRig(self.rig, self.fault, seed=int(self.params['noise_seed']))
        self.get_logger().warning(f'fault injected: {self.fault.name} '
                                  f'({self.fault.description})')

    def contract_values(self) -> dict:
        """The rig contract's ready values, and the fault injected."""
        return {**super().contract_values(), 'injected_fault': self.fault.name}

    def sample_stamp_ns(self, k: int) -> int:
        """The faulty stamp of sample `k` [ns]."""
        return self.rig.stamp_ns(k, self.dt_ns)

    def next_due(self):
        """As the rig node's; a slow clock ticks every ``tick_factor dt``."""
        due = super().next_due()
        factor = self.fault.tick_factor
        if (factor == 1.0 or due is None or not self.running or self.t0 is None
                or self.drain_until is not None):
            return due
        return self.t0 + (self.rig.step + 1) * self.rig.dt * factor

    def due_step(self, now: float) -> int:
        """As the rig node's, on the slow clock's ticks."""
        if self.fault.tick_factor != 1.0:
            return int((now - self.t0) / (self.rig.dt * self.fault.tick_factor))
        return super().due_step(now)


def main(args=None) -> int:
    """Entry point: ``fault_rig FAULT --ros-args ...`` (exit code 2 for an unknown fault)."""
    argv = list(sys.argv if args is None else args)
    name = argv[1] if len(argv) > 1 else ''
    if name not in FAULTS:
        print(f'fault_rig: error: fault {name!r}: expected one of {", ".join(FAULTS)}',
              file=sys.stderr)
        return 2
    FaultRigNode.fault = FAULTS[name]
    return main_for(FaultRigNode, 'rig', argv[:1] + argv[2:])


if __name__ == '__main__':
    sys.exit(main())
