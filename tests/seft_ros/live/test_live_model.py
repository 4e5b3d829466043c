"""The live view without ROS: which channels a run has, how record batches become shown
samples (decimation, timing totals, a structure's DOFs), the run's state from status
reports, what a page receives, and the access rules (address, token, TLS files)."""

import json

import numpy as np
import pytest

from seft_msgs_py.errors import InputError
from seft_msgs_py.signals import TIMING_FIELDS
from seft_ros.live import channels as ch
from seft_ros.live.access import LiveOptions, listen_error, parse_address, token_matches
from seft_ros.live.view import LiveView, RunStatus


class Recorder:
    """A sink that keeps what it is given."""

    def __init__(self):
        self.fields, self.logged, self.events = {}, [], []

    def new_run(self, fields):
        self.fields = {k: list(v) for k, v in fields.items()}

    def log(self, channel, message, log_time_ns):
        self.logged.append((channel, dict(message), log_time_ns))

    def event(self, level, node, message, log_time_ns):
        self.events.append((level, node, message))


def rows(steps, *columns):
    """Row-major batch data: step then the columns."""
    out = []
    for i, k in enumerate(steps):
        out += [float(k)] + [float(c[i]) for c in columns]
    return out


@pytest.fixture
def study(reference_params):
    return dict(reference_params, bag_path='/tmp/run/bag', mode='realtime')


def test_decimation_is_the_display_rate_in_whole_steps():
    assert ch.decimation(0.002) == 10
    assert ch.decimation(0.001) == 20
    assert ch.decimation(0.002, rate_hz=500.0) == 1
    assert ch.decimation(0.05) == 1                   # slower than the display: every sample


def test_study_channels_and_plots(study):
    run = ch.RunChannels(study)
    assert run.fields['/seft/live/measurement'] == ['measured_force_N', 'displacement_m',
                                                    'velocity_m_s', 'acceleration_m_s2']
    assert run.fields['/seft/live/timing/rig'] == list(TIMING_FIELDS) + list(ch.TIMING_TOTALS)
    assert '/seft/live/timing/force_servo_controller' in run.fields
    # the compensator's estimates are not shown
    assert not any('estimates' in s.stream.name for s in run.sources)
    titles = [p.title for p in run.plots()]
    assert titles == ['Force', 'Displacement', 'Acceleration', 'Valve command', 'Loop latency']
    lockstep = ch.RunChannels(dict(study, mode='lockstep'))
    assert not any('/timing/' in c for c in lockstep.fields)    # no node times its steps


def test_structure_channels_per_rig_and_dof(reference_params):
    structure = {'dofs': ['pier_a', 'pier_b', 'deck'],
                 'physical': {'pier_a': 'pier_a', 'pier_b': 'pier_b'}}
    params = dict(reference_params, structure=json.dumps(structure), mode='lockstep',
                  structure_builders='central')
    run = ch.RunChannels(params)
    assert '/pier_a/seft/live/measurement' in run.fields
    assert '/pier_b/seft/live/valve_command' in run.fields
    assert run.fields['/seft/live/dof/pier_a'] == ['displacement_m']
    assert run.fields['/seft/live/dof/deck'] == ['displacement_m']
    view = LiveView(sinks=[Recorder()])
    view.new_run(params)
    # the rig's displacement goes to its rig's channel and to its DOF's
    view.on_batch('/pier_a/seft/record/rig', ('f', 'x', 'v', 'a'),
                  rows([0, 1, 10], [1, 2, 3], [0.1, 0.2, 0.3], [0, 0, 0], [0, 0, 0]))
    assert view.series['/seft/live/dof/pier_a.displacement_m'] == ([0, 10], [0.1, 0.3])
    assert view.series['/pier_a/seft/live/measurement.measured_force_N'] == ([0, 10], [1, 3])
    # a computational DOF from the builder's structure state (the columns the batch names)
    view.on_batch('/seft/record/reference_force_builder/structure',
                  ('deck/displacement_m', 'deck/velocity_m_s'), rows([10, 20], [5e-3, 6e-3],
                                                                     [1, 2]))
    assert view.series['/seft/live/dof/deck.displacement_m'] == ([10, 20], [5e-3, 6e-3])
    assert [p.title for p in run.plots()][-1] == 'Displacement of each DOF'


def test_batches_become_shown_samples_at_the_display_steps(study):
    sink = Recorder()
    view = LiveView(sinks=[sink])
    assert view.new_run(study) and not view.new_run(study)          # the same run once
    steps = list(range(0, 20))
    force = [100.0 + k for k in steps]
    view.on_batch('/seft/record/rig', ('a', 'b', 'c', 'd'),
                  rows(steps, force, [k * 1e-4 for k in steps], steps, steps))
    shown = [(c, m) for c, m, _ in sink.logged if c == '/seft/live/measurement']
    assert [m['step'] for _, m in shown] == [0, 10]
    assert shown[1][1] == {'step': 10, 't_s': 0.02, 'measured_force_N': 110.0,
                           'displacement_m': 10e-4, 'velocity_m_s': 10.0,
                           'acceleration_m_s2': 10.0}
    # the log time: the run's start plus the sample time
    times = [t for c, _, t in sink.logged if c == '/seft/live/measurement']
    assert times[1] - times[0] == 20_000_000
    # a value that is not finite is shown as null (JSON has no NaN)
    view.on_batch('/seft/record/reference_force_builder', ('f',), rows([30], [np.nan]))
    assert view.series['/seft/live/reference_force.reference_force_N'] == ([30], [None])


def test_timing_totals_count_every_sample(study):
    sink = Recorder()
    view = LiveView(sinks=[sink])
    view.new_run(study)
    n = len(TIMING_FIELDS)
    missed, stale, latency = (TIMING_FIELDS.index(f) for f in
                              ('missed_deadline', 'stale', 'loop_latency_s'))
    data = []
    for k in range(0, 21):
        row = [0.0] * n
        row[missed] = 1.0 if k in (3, 7, 15) else 0.0
        row[stale] = 1.0 if k == 4 else 0.0
        row[latency] = 0.009 if k == 5 else 0.001
        data += [float(k)] + row
    view.on_batch('/seft/record/rig/timing', TIMING_FIELDS, data)
    shown = [m for c, m, _ in sink.logged if c == '/seft/live/timing/rig']
    assert [m['step'] for m in shown] == [0, 10, 20]
    assert [m['missed_deadlines'] for m in shown] == [0, 2, 3]
    assert [m['stale_inputs'] for m in shown] == [0, 1, 1]
    assert [m['loop_latency_max_s'] for m in shown] == [0.001, 0.009, 0.001]
    assert shown[1]['loop_latency_s'] == 0.001


def test_the_run_state_from_status_reports():
    status = RunStatus(('rig',), 'realtime')
    assert status.state == 'starting'
    status.update('rig', '', {'state': 'running', 'step': '0', 'n_steps': '5000'})
    assert status.state == 'running' and status.n_steps == 5000
    events = status.update('reference_force_builder', 'instability monitor: ...',
                           {'state': 'aborted', 'step': '900'})
    assert events[0]['level'] == 'error' and status.state == 'running'   # the rig ramps
    events = status.update('rig', 'reference_force_builder: instability monitor: ...',
                           {'state': 'aborted', 'step': '950', 'time_s': '1.9',
                            'missed_deadlines': '4'})
    assert status.state == 'aborted'
    assert status.reason == 'reference_force_builder: instability monitor: ...'
    assert status.missed == {'rig': 4} and status.time_s == 1.9
    status.update('recorder', 'bag closed', {'state': 'closed', 'lost': '0'})
    assert status.closed and status.lost == 0
    # a rig cut off: its final report never comes; the bag's closing ends the run
    cut = RunStatus(('a/rig', 'b/rig'), 'realtime')
    cut.update('a/rig', 'watchdog: no command for 100 ms', {'state': 'aborted'})
    assert cut.state == 'starting'
    cut.update('recorder', 'bag closed', {'state': 'closed', 'lost': '0'})
    assert cut.state == 'aborted' and cut.reason == 'watchdog: no command for 100 ms'
    lost = RunStatus(('a/rig',), 'realtime')
    lost.update('recorder', 'bag closed', {'state': 'closed'})
    assert lost.state == 'aborted'
    assert lost.reason == 'the bag closed without the final report of a/rig'
    done = RunStatus(('a/rig', 'b/rig'), 'lockstep')
    done.update('a/rig', 'completed', {'state': 'done'})
    assert done.state == 'starting'                        # every rig's end is needed
    done.update('b/rig', 'completed', {'state': 'done'})
    assert done.state == 'done' and done.reason == ''


def test_a_page_gets_a_snapshot_then_what_is_new(study):
    view = LiveView(reference=lambda p: {f: np.arange(100.0) for f in ch.ANALYTICAL_FIELDS})
    view.new_run(study)
    assert view.add_reference()
    hello, cursor = view.snapshot()
    assert hello['type'] == 'hello' and hello['run']['decimation'] == 10
    assert hello['reference']['/seft/live/analytical.force_N'] == [float(k) for k in
                                                                    range(0, 100, 10)]
    assert hello['status']['n_steps'] == 100
    assert [s['key'] for s in hello['plots'][0]['series']] == [
        '/seft/live/reference_force.reference_force_N',
        '/seft/live/measurement.measured_force_N', '/seft/live/analytical.force_N']
    assert view.delta(cursor)[0] is None                    # nothing new
    view.on_batch('/seft/record/rig', ('a', 'b', 'c', 'd'), rows([0, 10], [1, 2], [0, 0],
                                                                 [0, 0], [0, 0]))
    msg, cursor = view.delta(cursor)
    assert msg['series']['/seft/live/measurement.measured_force_N'] == [[0, 10], [1.0, 2.0]]
    view.on_status('rig', '', {'state': 'running', 'step': '0'})
    msg, cursor = view.delta(cursor)
    assert msg['status']['state'] == 'running' and msg['series'] == {}
    # the next run of a sweep: a new hello
    view.new_run(dict(study, bag_path='/tmp/run2/bag'))
    msg, _ = view.delta(cursor)
    assert msg['type'] == 'hello' and msg['series']['/seft/live/measurement.displacement_m'] \
        == [[], []]


def test_link_figures(study):
    sink = Recorder()
    view = LiveView(sinks=[sink])
    view.new_run(study)
    view.on_link({'reference': 'compute', 'links': {'lab': {
        'round_trip_ms': {'p50': 10.2, 'p99': 12.5, 'max': 14.0}, 'offset_ms': -0.3}}})
    assert view.status.link == {'lab': {'round_trip_p50_ms': 10.2, 'round_trip_p99_ms': 12.5,
                                        'round_trip_max_ms': 14.0, 'offset_ms': -0.3}}
    assert ('/seft/live/link', {'host': 'lab', 'reference': 'compute',
                                'round_trip_p50_ms': 10.2, 'round_trip_p99_ms': 12.5,
                                'round_trip_max_ms': 14.0, 'offset_ms': -0.3}) in \
        [(c, m) for c, m, _ in sink.logged]


@pytest.mark.parametrize('text,expected', [
    (None, ('127.0.0.1', 8765)), ('', ('127.0.0.1', 8765)), ('0.0.0.0', ('0.0.0.0', 8765)),
    (':9000', ('127.0.0.1', 9000)), ('10.1.2.3:9000', ('10.1.2.3', 9000)),
    ('[::1]:9000', ('::1', 9000)), ('lab-pc', ('lab-pc', 8765))])
def test_addresses(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize('text', ['host:', 'host:0', 'host:65535', 'a:b:c', 'host:x',
                                  'http://host', '[::1]x'])
def test_bad_addresses(text):
    with pytest.raises(InputError, match=r'--live .*expected \[HOST\]\[:PORT\]'):
        parse_address(text)


def test_a_token_for_other_sites(tmp_path):
    local = LiveOptions.from_command_line('', environ={})
    assert local.token == '' and local.urls() == ('http://127.0.0.1:8766/',
                                                  'ws://127.0.0.1:8765')
    remote = LiveOptions.from_command_line('0.0.0.0:9000', environ={})
    assert len(remote.token) >= 20                             # made when none is set
    assert remote.urls()[0] == f'http://0.0.0.0:9001/?token={remote.token}'
    given = LiveOptions.from_command_line('', environ={'SEFT_LIVE_TOKEN': 'abc'})
    assert given.token == 'abc' and given.urls()[1] == 'ws://127.0.0.1:8765/?token=abc'
    assert token_matches('abc', 'abc') and not token_matches('abc', 'abd')
    assert not token_matches('abc', None) and token_matches('', None)
    (tmp_path / 'c.pem').write_text('not a certificate')
    (tmp_path / 'k.pem').write_text('not a key')
    with pytest.raises(InputError, match='--live-tls .*c.pem .*k.pem: not a PEM'):
        LiveOptions.from_command_line('', tls=(tmp_path / 'c.pem', tmp_path / 'k.pem'),
                                      environ={})
    with pytest.raises(InputError, match='--live-tls: .*missing.pem: no such certificate'):
        LiveOptions.from_command_line('', tls=(tmp_path / 'missing.pem', tmp_path / 'k.pem'),
                                      environ={})


def test_listen_errors_are_one_line():
    busy = OSError(98, 'Address already in use')
    assert listen_error('Foxglove', '127.0.0.1', 8765, busy) == (
        'live view: Foxglove cannot listen on 127.0.0.1:8765: port 8765 is in use (another '
        'live view or program?)')
    sdk = RuntimeError('FoxgloveError: Failed to bind port: Cannot assign requested address '
                       '(os error 99)')
    assert listen_error('Foxglove', '192.0.2.1', 8765, sdk).endswith(
        '192.0.2.1 is not an address of this host')
    assert listen_error('the web page', 'x', 80, OSError(13, 'Permission denied')).endswith(
        'port 80 needs privileges (choose one above 1023)')


def test_samples_at_a_sensor_range_are_counted_in_the_run_state(study, reference_params):
    """Every row of the rig's batches, shown or not, against the rig's ranges (issue 39): the
    count per rig and channel is in the run's state (the page's line, /seft/live/run), and a
    builder's warning is an event."""
    sink = Recorder()
    view = LiveView(sinks=[sink])
    view.new_run(dict(study, accelerometer_range_m_s2=39.2, force_range_N=1000.0))
    steps = list(range(0, 20))
    a = [39.2 if k in (3, 4, 11) else -39.2 if k == 12 else 1.0 for k in steps]
    f = [1000.0 if k == 5 else 10.0 for k in steps]
    view.on_batch('/seft/record/rig', ('f', 'x', 'v', 'a'),
                  rows(steps, f, [0.0] * 20, [0.0] * 20, a))
    assert view.status.as_dict()['at_range'] == {'': {'acceleration': 4, 'force': 1}}
    state = [m for c, m, _ in sink.logged if c == '/seft/live/run'][-1]
    assert state['at_range'] == {'': {'acceleration': 4, 'force': 1}}
    view.on_status('reference_force_builder', 'acceleration at its sensor range ...',
                   {'state': 'running', 'warning': 'acceleration at its sensor range ...'})
    assert sink.events[-1] == ('warning', 'reference_force_builder',
                               'acceleration at its sensor range ...')
    # a structure's rig: its own ranges, counted under its name
    structure = {'dofs': ['pier_a', 'deck'], 'physical': {'pier_a': 'pier_a'},
                 'mass_matrix_kg': [[52.7, 0], [0, 52.7]],
                 'stiffness_matrix_N_per_m': [[4.22e5, -2.11e5], [-2.11e5, 2.11e5]],
                 'damping_matrix_N_s_per_m': [[1036.678, -133.4], [-133.4, 133.4]],
                 'influence': [1.0, 1.0],
                 'rigs': {'pier_a': {'velocity_range_m_s': 0.5}}}
    view = LiveView(sinks=[Recorder()])
    view.new_run(dict(reference_params, structure=json.dumps(structure), mode='lockstep',
                      structure_builders='central', bag_path='/tmp/s/bag'))
    view.on_batch('/pier_a/seft/record/rig', ('f', 'x', 'v', 'a'),
                  rows([0, 1, 2], [0, 0, 0], [0, 0, 0], [0.1, 0.6, -0.5], [0, 0, 0]))
    assert view.status.as_dict()['at_range'] == {'pier_a': {'velocity': 2}}
