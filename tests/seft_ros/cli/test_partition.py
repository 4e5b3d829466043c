"""Named partitions of a test over hosts: which node runs on which site."""

import json

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError
from seft_ros.cli.partition import (
    loop_crosses_hosts,
    partition_parameters,
    site_nodes,
    sites,
)

BRIDGE = json.dumps({'dofs': ['a', 'b', 'deck'], 'physical': {'a': 'pier_a', 'b': 'pier_b'},
                     'rigs': {'pier_b': {'rig_model': 'delay'}}})


def test_the_study_split_two_ways():
    p = parameters.resolve()
    assert sites(p, 'loop_local') == {
        'compute': ('recorder', 'ground_motion_publisher'),
        'lab': ('reference_force_builder', 'force_servo_controller', 'rig')}
    assert sites(p, 'builder_remote') == {
        'compute': ('recorder', 'ground_motion_publisher', 'reference_force_builder'),
        'lab': ('force_servo_controller', 'rig')}
    assert not loop_crosses_hosts(p, 'loop_local')
    assert loop_crosses_hosts(p, 'builder_remote')
    assert partition_parameters(p, 'loop_local') == p      # the study has no builders to place


def test_a_structure_gets_one_site_per_rig_and_the_builders_follow_the_partition():
    p = parameters.resolve({'structure': BRIDGE})
    assert partition_parameters(p, 'loop_local')['structure_builders'] == 'per_rig'
    assert partition_parameters(p, 'builder_remote')['structure_builders'] == 'central'
    assert sites(p, 'loop_local') == {
        'compute': ('recorder', 'ground_motion_publisher'),
        'pier_a': ('pier_a/reference_force_builder', 'pier_a/force_servo_controller',
                   'pier_a/rig'),
        'pier_b': ('pier_b/reference_force_builder', 'pier_b/rig')}   # delay rig: no controller
    assert site_nodes(p, 'builder_remote', 'compute') == [
        'recorder', 'ground_motion_publisher', 'reference_force_builder']
    # every node of the graph is on exactly one site
    for name in ('loop_local', 'builder_remote'):
        from seft_msgs_py.graph import Graph
        graph = Graph.from_parameters(partition_parameters(p, name))
        placed = [n for nodes in sites(p, name).values() for n in nodes]
        assert sorted(placed) == sorted(('recorder',) + graph.nodes())


def test_unknown_partition_or_site_is_one_line():
    p = parameters.resolve()
    with pytest.raises(InputError, match='^--partition nope: expected one of loop_local, '
                                         'builder_remote$'):
        sites(p, 'nope')
    with pytest.raises(InputError, match='^--site pier_a: not a site of partition loop_local; '
                                         'expected one of compute, lab$'):
        site_nodes(p, 'loop_local', 'pier_a')
