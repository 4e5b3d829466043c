"""How a test is split over hosts: named partitions and their sites (no rclpy).

A distributed test runs the rig(s) in one or several labs and the rest on a compute host.
Which node runs where is a named choice (``seft run --partition NAME --site SITE``), not a
node list to get right by hand (``--nodes`` remains for any other split).

``loop_local`` (the default, and :data:`DEFAULT_PARTITION`)
    Everything that closes the loop at the sample rate runs on the lab host beside the rig:
    the force servo controller **and** the reference-force builder with its compensator
    (the acceleration feedback needs only the rig's own measurement). The compute host runs
    the ground-motion publisher and the recorder: the record is known before the test, so its
    samples reach the lab ahead of their use (``preview_steps``), stamped with their step, and
    the network is not inside the loop. A structure on several rigs runs one builder per rig
    (``structure_builders: per_rig``): each lab integrates a replica of the computational
    part from every rig's measurements and predicts the other rigs' motion over the link's
    delay with the whole structure's model (
    :class:`~seft_ros.core.reference_force.ReferenceForceBuilder`).
``builder_remote``
    The split of earlier releases: the lab host runs the rig and its controller, the compute
    host the ground-motion publisher, the builder (one for every rig) and the recorder. The
    measurement travels to the builder and the reference force back before it acts: the loop
    crosses the network, which the playout delay ``network_delay_s`` and the ``model``
    compensator's longer horizon must cover.

Sites: ``compute``, and ``lab`` for the study's single rig, or one site per rig of a
structure, named after the rig.
"""

from typing import Any, Mapping

from seft_msgs_py.errors import InputError
from seft_msgs_py.graph import CENTRAL, PER_RIG, Graph, qualified

__all__ = ['PARTITIONS', 'DEFAULT_PARTITION', 'COMPUTE', 'LAB', 'PROCESSES',
           'partition_parameters', 'sites', 'site_nodes', 'loop_crosses_hosts']

#: The named partitions.
PARTITIONS = ('loop_local', 'builder_remote')
#: How a runner starts the nodes of its host (``seft run --processes``): ``node``, one
#: process each (``ros2 run``'s way: a node can be stopped or killed alone); ``loop``, the
#: nodes that close each rig's loop (the rig, its force servo controller and the builder of
#: the rig's namespace; for the study's single rig, the three of the root namespace) in one
#: process each (ROS 2 composition, :mod:`seft_ros.nodes.loop`: less CPU and no transport
#: between them; measured in docs/network.md). The recorder and the ground-motion publisher
#: always run alone. The first is the default.
PROCESSES = ('node', 'loop')
#: The partition of ``seft run --site`` and ``tools/two_hosts.sh`` unless told otherwise.
DEFAULT_PARTITION = 'loop_local'
#: The compute host's site.
COMPUTE = 'compute'
#: The lab host's site of the study's single rig.
LAB = 'lab'


def _check(partition: str) -> None:
    if partition not in PARTITIONS:
        raise InputError(f'--partition {partition}: expected one of {", ".join(PARTITIONS)}')


def partition_parameters(params: Mapping[str, Any], partition: str) -> dict[str, Any]:
    """The run's parameters under `partition`: a structure's builders per rig with
    ``loop_local``, one central builder with ``builder_remote``.

    Raises
    ------
    InputError
        An unknown partition.
    """
    _check(partition)
    out = dict(params)
    if Graph.from_parameters(out).is_structure:
        out['structure_builders'] = PER_RIG if partition == 'loop_local' else CENTRAL
    return out


def sites(params: Mapping[str, Any], partition: str) -> dict[str, tuple[str, ...]]:
    """``{site: its nodes (qualified names)}`` of a run under `partition` (after
    :func:`partition_parameters`), the compute site first.

    Raises
    ------
    InputError
        An unknown partition.
    """
    _check(partition)
    graph = Graph.from_parameters(partition_parameters(params, partition))
    local_builder = partition == 'loop_local'
    compute = ['recorder', 'ground_motion_publisher']
    if not local_builder:
        compute += list(graph.builder_nodes())
    out = {COMPUTE: tuple(compute)}
    for rig in graph.rigs:
        nodes = [qualified('rig', rig)]
        if graph.has_controller(rig):
            nodes.insert(0, qualified('force_servo_controller', rig))
        if local_builder:
            nodes.insert(0, graph.builder_of(rig))
        out[rig or LAB] = tuple(nodes)
    return out


def site_nodes(params: Mapping[str, Any], partition: str, site: str) -> list[str]:
    """The nodes of `site` under `partition`.

    Raises
    ------
    InputError
        An unknown partition or site (the message lists the sites).
    """
    table = sites(params, partition)
    if site not in table:
        raise InputError(f'--site {site}: not a site of partition {partition}; expected one '
                         f'of {", ".join(table)}')
    return list(table[site])


def loop_crosses_hosts(params: Mapping[str, Any], partition: str) -> bool:
    """Whether the sample-rate loop (measurement to builder, reference force to controller)
    crosses hosts under `partition`: then the reference force needs a playout delay
    (``network_delay_s``)."""
    _check(partition)
    return partition == 'builder_remote'
