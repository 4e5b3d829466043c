"""seft simulate --bag: the bag of a one-process run reads back as the run (bag round trip)."""

import json

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
