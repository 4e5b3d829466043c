"""Who publishes what in a run's graph (issue 42): the topics that command a rig and each
topic's publishers (``seft_msgs_py.graph.Graph``), and how a foreign publisher is named from
what the middleware knows (``Graph.foreign_publishers``), for the study's test and a
structure with a builder per rig."""

from pathlib import Path

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.graph import UNKNOWN_NODE, Graph
from seft_ros.cli.api import build_runs

CONFIG = Path(__file__).resolve().parents[3] / 'config'


@pytest.fixture(scope='module')
def study():
    return Graph.from_parameters(parameters.resolve({}))


@pytest.fixture(scope='module')
def piers():
    params = build_runs(config=str(CONFIG / 'two_piers.yaml'),
                        overrides={'structure_builders': 'per_rig'})[0]
    return Graph.from_parameters(params)


def test_the_study_commands_its_rig_through_four_topics(study):
    assert study.command_topics() == ('/seft/record/ground_motion_publisher',
                                      '/seft/measurement', '/seft/reference_force',
                                      '/seft/valve_command')
    assert study.publishers_of('/seft/reference_force') == ('reference_force_builder',)
    assert study.publishers_of('/seft/valve_command') == ('force_servo_controller',)
    assert study.publishers_of('/seft/measurement') == ('rig',)
    assert study.publishers_of('/seft/record/rig/timing') == ('rig',)
    assert study.publishers_of('/clock') == ('rig',)
    assert study.publishers_of('/seft/run_parameters') == ('recorder',)
    assert set(study.publishers_of('/seft/status')) == {
        'ground_motion_publisher', 'reference_force_builder', 'force_servo_controller', 'rig',
        'recorder'}
    assert study.publishers_of('/not/seft') == ()
    delay = Graph.from_parameters(parameters.resolve({'rig_model': 'delay'}))
    assert '/seft/valve_command' not in delay.command_topics()
    assert delay.publishers_of('/seft/valve_command') == ()


def test_a_structure_with_a_builder_per_rig(piers):
    topics = piers.command_topics()
    for rig in ('pier_a', 'pier_b'):
        for topic in ('measurement', 'reference_force', 'valve_command', 'specimen_model'):
            assert f'/{rig}/seft/{topic}' in topics
    assert piers.publishers_of('/pier_b/seft/reference_force') == (
        'pier_b/reference_force_builder',)
    assert piers.publishers_of('/pier_b/seft/specimen_model') == (
        'pier_b/reference_force_builder',)
    assert piers.publishers_of('/pier_a/seft/measurement') == ('pier_a/rig',)


def test_foreign_publishers_are_named(study, piers):
    own = ('reference_force_builder', '/', b'\x01\x0f\xaa')
    intruder = ('intruder', '/', bytes(range(16)))
    topic = '/seft/reference_force'
    assert study.foreign_publishers(topic, [own]) == []
    assert study.foreign_publishers(topic, [own, intruder]) == [
        "'intruder' (gid 000102030405060708090a0b)"]
    # a sender that took the builder's name: no telling which is the run's, both named
    twin = ('reference_force_builder', '/', b'\x02')
    assert study.foreign_publishers(topic, [own, twin]) == [
        "2 publishers named 'reference_force_builder' (gid 010faa, 02; the run has 1)"]
    # a node not named yet: the run's own while the run's is not seen by name, else foreign
    unnamed = (UNKNOWN_NODE, '/', b'\x03')
    assert study.foreign_publishers(topic, [unnamed]) == []
    assert study.foreign_publishers(topic, [own, unnamed]) == [
        'a node not named yet (gid 03: a process outside the run)']
    # the rig of another namespace on this rig's topic
    assert piers.foreign_publishers('/pier_a/seft/measurement', [
        ('rig', '/pier_a', b'\x04'), ('rig', '/pier_b', b'\x05')]) == ["'pier_b/rig' (gid 05)"]
    # the status: seft's tools, any number of them, are not foreign
    status = [('rig', '/', b'\x06'), ('seft_runner', '/', b'\x07'),
              ('seft_runner', '/', b'\x08'), ('seft_live', '/', b'\x09'),
              ('stranger', '/', b'\x0a')]
    assert study.foreign_publishers('/seft/status', status) == ["'stranger' (gid 0a)"]
