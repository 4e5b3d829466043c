"""seft simulate --bag: the bag of a one-process run reads back as the run (bag round trip), the
study's test and structure tests (each rig in its namespace)."""

import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.bagwrite import write_run_bag
from seft_ros.core.experiment import simulate

_SIGNALS = ('ground_acceleration_m_s2', 'reference_force_N', 'measured_force_N',
            'displacement_m', 'velocity_m_s', 'acceleration_m_s2', 'valve_command_V')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_round_trip_bit_for_bit(tmp_path, storage):
    rd = simulate(parameters.resolve({'excitation': 'chirp', 'duration_s': 1.0,
                                      'excitation_band_low_hz': 2.0,
                                      'excitation_band_hz': 40.0, 'monitor_threshold': 0.0,
                                      'excitation_input': 'valve_command'}))
    path = write_run_bag(rd, tmp_path / 'bag', storage=storage)
    back = read_run(path)
    for name in _SIGNALS:
        assert np.array_equal(getattr(rd, name), getattr(back, name)), name
    assert back.params == rd.params
    assert back.stable and back.record_name == rd.record_name
    assert back.extra['param_sources']['excitation'] == 'ground_motion_publisher'
    assert back.extra['parameter_mismatches'] == []
    with Reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    expected = {s.name: s.type_name for s in signals.BAG_SIGNALS
                if not s.name.startswith('/seft/timing/')}
    assert types == expected
    with pytest.raises(InputError, match='the bag exists already'):
        write_run_bag(rd, path)


def test_aborted_run_and_estimates(tmp_path):
    rd = simulate(parameters.resolve({'alpha': 1.5, 'duration_s': 4.0}))
    assert not rd.stable and rd.extra['abort_node'] == 'reference_force_builder'
    back = read_run(write_run_bag(rd, tmp_path / 'bag'))
    assert not back.stable and back.unstable_at_s == rd.unstable_at_s
    assert back.abort_reason == f'reference_force_builder: {rd.abort_reason}'
    # the builder's count of the samples at a sensor's range is in its abort status
    assert back.extra['sensor_range'] == rd.extra['sensor_range']
    rd = simulate(parameters.resolve({'predictor': 'adaptive', 'rig_model': 'delay',
                                      'duration_s': 0.5}))
    back = read_run(write_run_bag(rd, tmp_path / 'bag2'))
    assert set(back.estimates) == set(rd.estimates)
    for name, values in rd.estimates.items():
        assert np.array_equal(back.estimates[name], values)
    with Reader(tmp_path / 'bag2') as reader:
        conn = [c for c in reader.connections if c.topic == signals.RUN_PARAMETERS.name]
        raw = next(reader.messages(connections=conn))[2]
    assert b'"predictor": "adaptive"' in raw or json.dumps('adaptive').encode() in raw


# -- structure tests: each rig in its namespace ----------------------------------------------

ROOT = Path(__file__).resolve().parents[3]
_RIG_SIGNALS = ('reference_force_N', 'measured_force_N', 'displacement_m', 'velocity_m_s',
                'acceleration_m_s2', 'valve_command_V')


def _structure_run(config, **over):
    from seft_ros.cli.config import load_config
    from seft_ros.core.experiment import simulate as simulate_structure
    return simulate_structure(parameters.resolve(dict(load_config(ROOT / 'config' / config),
                                                      **over)))


def _same_structure_run(back, rd):
    """Every rig's parameters and signals and the computational state, bit for bit."""
    assert back.params == rd.params and back.n_steps == rd.n_steps
    assert list(back.rigs) == list(rd.rigs)
    np.testing.assert_array_equal(back.ground_acceleration_m_s2, rd.ground_acceleration_m_s2)
    for name, rig in rd.rigs.items():
        assert back.rigs[name].params == rig.params, name
        for attr in _RIG_SIGNALS:
            want, got = getattr(rig, attr), getattr(back.rigs[name], attr)
            assert (got is None) if want is None else np.array_equal(got, want), (name, attr)
    assert set(back.computational) == set(rd.computational) != set()
    for key, values in rd.computational.items():
        np.testing.assert_array_equal(back.computational[key], values, err_msg=key)


def test_structure_round_trip_bit_for_bit(tmp_path):
    """The two-pier bridge (each pier's rig in its namespace, the deck computational): the
    bag holds the graph's topics, each rig node its own rig's parameters, and reads back as
    the run."""
    from seft_msgs_py.graph import Graph
    rd = _structure_run('two_piers.yaml', predictor='model', duration_s=0.5)
    path = write_run_bag(rd, tmp_path / 'bag')
    back = read_run(path)
    _same_structure_run(back, rd)
    assert back.stable and back.abort_reason is None and back.extra['gaps'] is None
    assert back.extra['recording']['end'] == 'closed'
    assert back.rigs['pier_b'].params['stiffness_N_per_m'] == 3.376e5
    assert back.rigs['pier_a'].params['force_controller'] == 'specimen_loop_shaping'
    assert back.rigs['pier_a'].params['predictor'] == 'model'   # the run's, not a default
    assert set(back.extra['rig_finals']) == {'pier_a/rig', 'pier_b/rig'}
    assert back.extra['parameter_mismatches'] == []
    assert back.extra['rig_contract'] == 'seft-rig/3.0'
    with Reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    graph = Graph.from_parameters(rd.params)
    timing = {graph.timing_topic(s) for s in graph.record_streams() if s.timing}
    assert types == {s.name: s.type_name for s in graph.bag_signals() if s.name not in timing}
    assert '/pier_b/seft/measured_force' in types and '/seft/structure_state' in types
    # the last sample's computational state is not recorded (NaN): one message fewer
    with Reader(path) as reader:
        count = {c.topic: c.msgcount for c in reader.connections}
    assert count['/seft/structure_state'] == rd.n_steps - 1


def test_a_clipped_run_round_trip(tmp_path):
    """Without the monitor (and the divergence guard) the unstable loop takes the
    accelerometer to its range and runs to the force limit: the builder's count of the
    samples at the range and its warning are in the bag (issue 39)."""
    rd = simulate(parameters.resolve({'alpha': 1.5, 'duration_s': 3.0,
                                      'monitor_threshold': 0.0, 'divergence_factor': 0.0}))
    assert not rd.stable and rd.extra['abort_node'] == 'rig'
    assert rd.extra['sensor_range']['']['samples']['acceleration'] > 100
    back = read_run(write_run_bag(rd, tmp_path / 'bag'))
    assert back.extra['sensor_range'] == rd.extra['sensor_range']
    assert back.extra['specimen_ratios'] == rd.extra['specimen_ratios']
    assert rd.extra['specimen_ratios'][''] == pytest.approx(1.0, abs=1e-9)
    assert back.extra['warnings'] == rd.extra['warnings']
    assert rd.extra['warnings'][0].startswith('acceleration at its sensor range (39.2 m/s^2) '
                                              'at t=')


def test_structure_abort_round_trip(tmp_path):
    """Uncompensated, the builder's monitor stops the bridge: every rig ended on its abort
    (ended_by), the reason names the builder as the graph's bag does."""
    rd = _structure_run('two_piers.yaml', predictor='none', duration_s=3.0)
    assert not rd.stable and rd.extra['abort_node'] == 'reference_force_builder'
    back = read_run(write_run_bag(rd, tmp_path / 'bag'))
    _same_structure_run(back, rd)
    assert not back.stable and back.unstable_at_s == rd.unstable_at_s
    assert back.abort_reason == f'reference_force_builder: {rd.abort_reason}'
    # the builder's count of the samples at a sensor's range is in its abort status
    assert back.extra['sensor_range'] == rd.extra['sensor_range']
    assert back.extra['abort_node'] == 'reference_force_builder'
    finals = back.extra['rig_finals']
    assert {f['ended_by'] for f in finals.values()} == {'reference_force_builder'}


def test_a_gap_in_one_rig_of_a_structure_ends_the_analysed_run_there(tmp_path):
    """A step of pier b's load cell lost: the run is read up to it, and the gap names the
    rig's topic and the steps after it that were not analysed."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    rd = _structure_run('two_piers.yaml', predictor='model', duration_s=0.2)
    src = write_run_bag(rd, tmp_path / 'bag')
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(src) as reader, Writer(tmp_path / 'cut', version=9) as writer:
        conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections}
        for conn, ns, raw in reader.messages():
            if conn.topic == '/pier_b/seft/measured_force' and ns == 40 * 2_000_000:
                continue
            writer.write(conns[conn.topic], ns, raw)
    back = read_run(tmp_path / 'cut')
    assert back.n_steps == 40 and back.stable
    gaps = back.extra['gaps']
    assert gaps['missing'] == {'/pier_b/seft/measured_force': [40]}
    assert gaps['steps_after_gap'] == rd.n_steps - 41 and gaps['last_step'] == rd.n_steps - 1
    assert 'gap at step 40 (t = 0.080 s): /pier_b/seft/measured_force misses steps 40' in \
        back.extra['recording']['note']
    np.testing.assert_array_equal(back.rigs['pier_a'].displacement_m,
                                  rd.rigs['pier_a'].displacement_m[:40])
