"""A lab's rig node written to rig contract 2.0, for ``seft rig-check --rig-command``.

seft's rig node as a rig of ``seft-rig/2.0`` was: it seals its measurement and takes only
sealed commands (2.0), but its status reports carry no seal (``hardware_id`` the plain
``'seft'``) and it acts on every report on ``/seft/status``, the run's or not (3.0 asks the
seal on both). ``python rig_contract2.py --ros-args --params-file FILE``.
"""

import sys

from seft_msgs_py import rig_contract
from seft_msgs_py.convert import status_msg
from seft_msgs_py.node_support import main_for
from seft_msgs_py.signals import STATE_ABORTED, STATE_DONE, STATE_FAILED
from seft_plant_sim.rig_node import RigNode

#: The contract such a rig reports.
CONTRACT_2 = 'seft-rig/2.0'


class Contract2RigNode(RigNode):
    """seft's rig node with the status reports of a rig of contract 2.0."""

    def contract_values(self) -> dict:
        """The ready values, the contract 2.0's."""
        return {**super().contract_values(), rig_contract.CONTRACT_KEY: CONTRACT_2}

    def report(self, state: str, message: str = '', **values) -> None:
        """A status report without the run's seal (``hardware_id`` 'seft')."""
        if state in (STATE_DONE, STATE_ABORTED, STATE_FAILED):
            for batch in self.records:
                batch.flush()
        if rig_contract.CONTRACT_KEY in values:
            values[rig_contract.CONTRACT_KEY] = CONTRACT_2
        self.status_pub.publish(status_msg(self.seft_name, state, message, **values))

    def status_of_run(self, msg) -> bool:
        """Contract 2.0: every report is acted on."""
        return True


if __name__ == '__main__':
    sys.exit(main_for(Contract2RigNode, 'rig', sys.argv))
