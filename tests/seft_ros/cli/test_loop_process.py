"""``--processes loop``: which nodes share a process, and the loop program's own arguments.

The runs themselves (bags equal to ``seft simulate`` with the loop processes, the study's and
the bridge's) are in test_node_graph_integration.py and test_structure_graph.py.
"""

import re
import subprocess
import sys

import pytest

from seft_msgs_py.errors import InputError, SeftError
from seft_ros.cli import api
from seft_ros.cli.runner import loop_groups, loop_log_name
from seft_ros.nodes.loop import parse_nodes


def test_the_study_loop_is_its_three_nodes_and_the_rest_runs_alone():
    nodes = ['recorder', 'ground_motion_publisher', 'reference_force_builder',
             'force_servo_controller', 'rig']
    assert loop_groups(nodes) == [['reference_force_builder', 'force_servo_controller', 'rig']]
    assert loop_log_name('rig') == 'loop.log'
    # the delay rig has no controller: builder and rig; a host with the rig alone: no group
    assert loop_groups(['reference_force_builder', 'rig']) == [['reference_force_builder',
                                                                'rig']]
    assert loop_groups(['rig', 'recorder']) == []
    # a node with a command of its own (seft rig-check --rig-command) is started alone
    assert loop_groups(nodes, exclude=('rig',)) == [['reference_force_builder',
                                                     'force_servo_controller']]


def test_each_rig_namespace_is_one_loop():
    # one host, one builder for both rigs (root namespace): each rig's controller and rig
    central = ['recorder', 'ground_motion_publisher', 'reference_force_builder',
               'pier_a/force_servo_controller', 'pier_a/rig', 'pier_b/rig',
               'pier_b/force_servo_controller']
    assert loop_groups(central) == [['pier_a/force_servo_controller', 'pier_a/rig'],
                                    ['pier_b/force_servo_controller', 'pier_b/rig']]
    # a lab of the bridge over three hosts: its builder, controller and rig
    lab = ['pier_a/rig', 'pier_a/reference_force_builder', 'pier_a/force_servo_controller']
    assert loop_groups(lab) == [['pier_a/reference_force_builder',
                                 'pier_a/force_servo_controller', 'pier_a/rig']]
    assert loop_log_name('pier_a/rig') == 'pier_a.loop.log'


def test_the_loop_arguments_split_per_node():
    argv = ['--node', 'rig', '--ros-args', '--params-file', 'r.yaml', '-r', '__ns:=/a',
            '--node', 'force_servo_controller', '--ros-args', '--params-file', 'c.yaml']
    assert parse_nodes(argv) == [
        ('rig', ['--ros-args', '--params-file', 'r.yaml', '-r', '__ns:=/a']),
        ('force_servo_controller', ['--ros-args', '--params-file', 'c.yaml'])]


@pytest.mark.parametrize('argv,message', [
    ([], 'expected --node NAME [--ros-args ...] for each node (NAME one of '
         'reference_force_builder, force_servo_controller, rig)'),
    (['--ros-args', '--node', 'rig'], 'expected --node NAME'),
    (['--node', 'recorder'], '--node recorder: expected one of reference_force_builder, '
                             'force_servo_controller, rig'),
    (['--node', 'rig', '--node', 'rig'], '--node rig given twice'),
    (['--node', 'rig', '--node'], '--node without a name'),
])
def test_bad_loop_arguments_are_one_line(argv, message):
    with pytest.raises(SeftError, match='^' + re.escape(message)):
        parse_nodes(argv)


def test_the_loop_program_refuses_bad_arguments_in_one_line():
    proc = subprocess.run([sys.executable, '-m', 'seft_ros.nodes.loop', '--node', 'recorder'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        'loop: error: --node recorder: expected one of reference_force_builder, '
        'force_servo_controller, rig']


def test_an_unknown_process_layout_is_refused_before_anything_runs(tmp_path):
    with pytest.raises(InputError, match=r'^--processes one: expected node or loop$'):
        api.run_experiments(runs=[{}], out_dir=tmp_path / 'out', processes='one')
    assert not (tmp_path / 'out').exists()
