"""loop: the nodes that close a rig's loop, in one process (ROS 2 composition).

A rig, its force servo controller and the reference-force builder of its namespace exchange
a message each way every sample. As separate processes each message crosses DDS's transport
and wakes another process; in one process (one ``EventsExecutor`` spinning the nodes,
:func:`~seft_msgs_py.node_support.main_for_nodes`) Fast DDS delivers them within the
participant and one thread does the work of all of them. Each node is the same node as
alone: its own name, namespace, parameter file, status reports, records and timing, so the
graph, the bag and the report do not change (lockstep runs equal ``seft simulate`` bit for
bit either way). It is ``rclcpp_components``' container for seft's Python nodes; ``seft run
--processes loop`` starts one per rig namespace (and one for the study's single rig).

Usage (each ``--node`` is followed by that node's own ROS arguments)::

    ros2 run seft_ros loop --node rig --ros-args --params-file rig.yaml -r __ns:=/pier_a \\
                           --node force_servo_controller --ros-args --params-file rig.yaml \\
                           -r __ns:=/pier_a

A node that fails reports it on ``/seft/status`` as it would alone, and the others end
the run as they would; a process that dies takes all its nodes with it (as a lab PC that
stops), and the runner then names every node of the process.
"""

import importlib
import os
import sys
from typing import Sequence

from seft_msgs_py.errors import SeftError
from seft_msgs_py.node_support import main_for_nodes

__all__ = ['LOOP_NODES', 'parse_nodes', 'main']

#: The nodes a loop process may hold: node name -> (module, class).
LOOP_NODES = {
    'reference_force_builder': ('seft_ros.nodes.reference_force_builder',
                                'ReferenceForceBuilderNode'),
    'force_servo_controller': ('seft_ros.nodes.force_servo_controller',
                               'ForceServoControllerNode'),
    'rig': ('seft_plant_sim.rig_node', 'RigNode'),
}


def parse_nodes(argv: Sequence[str]) -> list[tuple[str, list[str]]]:
    """Split ``--node NAME [ROS arguments] --node NAME ...`` into ``[(name, ros_args)]``.

    Raises
    ------
    SeftError
        No ``--node``, something before the first one, a name that is not one of
        :data:`LOOP_NODES`, or a node given twice (the message names it).
    """
    argv = list(argv)
    if not argv or argv[0] != '--node':
        raise SeftError('expected --node NAME [--ros-args ...] for each node '
                        f'(NAME one of {", ".join(LOOP_NODES)})')
    nodes: list[tuple[str, list[str]]] = []
    for arg in argv:
        if arg == '--node':
            nodes.append(('', []))
        elif not nodes[-1][0]:
            if arg not in LOOP_NODES:
                raise SeftError(f'--node {arg}: expected one of {", ".join(LOOP_NODES)}')
            if any(name == arg for name, _ in nodes):
                raise SeftError(f'--node {arg} given twice (one process holds one of '
                                'each node)')
            nodes[-1] = (arg, [])
        else:
            nodes[-1][1].append(arg)
    if not nodes[-1][0]:
        raise SeftError('--node without a name')
    return nodes


def _factory(name: str):
    module, cls = LOOP_NODES[name]
    return getattr(importlib.import_module(module), cls)


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros loop``; `args`: the arguments after the program."""
    argv = sys.argv[1:] if args is None else list(args)
    try:
        nodes = parse_nodes(argv)
    except SeftError as exc:
        print(f'loop: error: {exc}', file=sys.stderr)
        return 2
    print(f'loop: {", ".join(name for name, _ in nodes)} in one process (pid {os.getpid()})',
          flush=True)
    return main_for_nodes([(_factory(name), name, ros_args) for name, ros_args in nodes],
                          args=[])


if __name__ == '__main__':
    sys.exit(main())
