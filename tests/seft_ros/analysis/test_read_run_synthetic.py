"""read_run on small synthetic bags: a gap, a duplicate, a missing topic, another node's abort.

Each bag starts as the bag ``seft simulate --bag`` writes for a 40-step servohydraulic run
(``write_run_bag``), copied message by message with rosbags while the test drops, repeats or
changes records (:func:`rewrite`). What read_run returns is checked against what the test
wrote: the simulated run's arrays, cut where the test cut them.
"""

import json
import re

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, rig_contract, signals
from seft_msgs_py.errors import InputError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.bagwrite import write_run_bag
from seft_ros.core.experiment import simulate

STORE = get_typestore(Stores.ROS2_JAZZY)
DT = 0.002
DT_NS = 2_000_000
N = 40
GROUND, REFERENCE, VALVE = (signals.GROUND_ACCELERATION.name, signals.REFERENCE_FORCE.name,
                            signals.VALVE_COMMAND.name)
MEASURED, DISPLACEMENT = signals.MEASURED_FORCE.name, signals.DISPLACEMENT.name
#: RunData attribute of each scalar topic.
ATTR = {GROUND: 'ground_acceleration_m_s2', REFERENCE: 'reference_force_N',
        VALVE: 'valve_command_V', MEASURED: 'measured_force_N', DISPLACEMENT: 'displacement_m',
        signals.VELOCITY.name: 'velocity_m_s', signals.ACCELERATION.name: 'acceleration_m_s2'}
FIELD = {s.name: s.field for s in signals.SCALAR_SIGNALS}
MONITOR = ('unstable at t=0.050 s: high-frequency oscillation of the measured force, RMS '
           'above the cut-off 1.20 x the response band (threshold 1)')


@pytest.fixture(scope='module')
def run():
    rd = simulate(parameters.resolve({'duration_s': N * DT, 'dt': DT}))
    assert rd.n_steps == N and rd.stable and rd.params['rig_model'] == 'servohydraulic'
    for attr in ATTR.values():        # distinct values, or a wrong step would go unnoticed
        assert len(set(getattr(rd, attr)[2:].tolist())) == N - 2, attr
    return rd


@pytest.fixture(scope='module')
def source(run, tmp_path_factory):
    return write_run_bag(run, tmp_path_factory.mktemp('source') / 'bag')


def rewrite(src, dst, edit, added=None):
    """Copy bag `src` to `dst`, each message through ``edit(topic, ns, msg)``: the list of
    ``(ns, msg)`` to write instead (``msg`` a fresh copy, free to change); then `added`
    (``{topic: (msgtype, [(ns, msg), ...])}``)."""
    with Reader(src) as reader, Writer(dst, version=9,
                                       storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=STORE)
                 for c in reader.connections}
        for conn, ns, raw in reader.messages():
            for out_ns, msg in edit(conn.topic, ns, STORE.deserialize_cdr(raw, conn.msgtype)):
                writer.write(conns[conn.topic], out_ns, STORE.serialize_cdr(msg, conn.msgtype))
        for topic, (msgtype, messages) in (added or {}).items():
            conn = writer.add_connection(topic, msgtype, typestore=STORE)
            for ns, msg in messages:
                writer.write(conn, ns, STORE.serialize_cdr(msg, msgtype))
    return dst


def set_value(topic, msg, value):
    *path, last = FIELD[topic].split('.')
    for p in path:
        msg = getattr(msg, p)
    setattr(msg, last, value)


def status(node, state, message, **values):
    kv = STORE.types['diagnostic_msgs/msg/KeyValue']
    return STORE.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=2 if state == 'aborted' else 0, name=node, message=message, hardware_id='seft',
        values=[kv(key='state', value=state)] + [kv(key=k, value=str(v))
                                                 for k, v in values.items()])


def drop(steps_of):
    """An edit that drops the steps ``steps_of[topic]`` (a set) of each topic."""
    def edit(topic, ns, msg):
        return [] if ns // DT_NS in steps_of.get(topic, ()) else [(ns, msg)]
    return edit


def check_values(rd, run, n):
    assert rd.n_steps == n
    np.testing.assert_array_equal(rd.time_s, np.arange(n) * DT)
    for attr in ATTR.values():
        np.testing.assert_array_equal(getattr(rd, attr), getattr(run, attr)[:n], err_msg=attr)


def test_the_intact_bag_reads_every_step(source, run):
    rd = read_run(source)
    check_values(rd, run, N)
    assert rd.stable and rd.unstable_at_s is None
    assert rd.extra['gaps'] is None and rd.extra['duplicates'] == {}
    assert rd.extra['recording']['end'] == 'closed'
    assert 'gap' not in rd.extra['recording']['note']
    # the rig's final status says which rig contract it followed
    assert rd.extra['rig_contract'] == rig_contract.CONTRACT == 'seft-rig/3.0'


def test_a_bag_without_the_contract_reads_with_none(source, tmp_path):
    """A bag recorded before the rig contract: its rig reported none."""
    def edit(topic, ns, msg):
        if topic == signals.STATUS.name:
            msg.values = [v for v in msg.values if v.key != rig_contract.CONTRACT_KEY]
        return [(ns, msg)]
    rd = read_run(rewrite(source, tmp_path / 'old', edit))
    assert rd.extra['rig_contract'] is None and rd.stable


def test_a_gap_ends_the_analysis_and_is_reported(source, run, tmp_path):
    """Steps 12-14 of the measured force and step 13 of the displacement lost: the run is
    analysed up to step 12, and the report says what was missing and what was not read."""
    bag = rewrite(source, tmp_path / 'bag',
                  drop({MEASURED: {12, 13, 14}, DISPLACEMENT: {13}}))
    rd = read_run(bag)
    check_values(rd, run, 12)
    assert rd.stable and rd.unstable_at_s is None        # the rig completed the run
    gaps = rd.extra['gaps']
    assert gaps['missing'] == {MEASURED: [12, 13, 14], DISPLACEMENT: [13]}
    assert (gaps['at_step'], gaps['last_step']) == (12, N - 1)
    assert gaps['at_s'] == pytest.approx(12 * DT, abs=1e-15)
    assert gaps['steps_after_gap'] == N - 15                 # 15..39: complete, not analysed
    rec = rd.extra['recording']
    assert (rec['gap_at_step'], rec['steps_not_analysed']) == (12, 25)
    assert rec['note'].endswith(
        f'; gap at step 12 (t = 0.024 s): {MEASURED} misses steps 12-14; {DISPLACEMENT} '
        'misses steps 13; 25 complete steps after it (to step 39) were not analysed')
    assert rd.extra['counts'][MEASURED] == N - 3 and rd.extra['counts'][DISPLACEMENT] == N - 1


def test_steps_lost_at_the_end_of_a_completed_run_are_reported(source, run, tmp_path):
    """The rig completed 40 steps; the bag lost the last five valve commands (and step 30,
    scattered): no complete step after the gap, but the steps the run had are named."""
    lost = {30, 35, 36, 37, 38, 39}
    rd = read_run(rewrite(source, tmp_path / 'bag', drop({VALVE: lost})))
    check_values(rd, run, 30)
    gaps = rd.extra['gaps']
    assert gaps['missing'] == {VALVE: sorted(lost)}
    assert (gaps['at_step'], gaps['steps_after_gap'], gaps['last_step']) == (30, 4, 39)
    assert f'{VALVE} misses steps 30, 35-39; 4 complete steps after it' in gaps['note']


def test_a_missing_step_0_is_refused_with_what_follows(source, tmp_path):
    bag = rewrite(source, tmp_path / 'bag', drop({GROUND: {0}}))
    with pytest.raises(InputError) as err:
        read_run(bag)
    assert str(err.value) == (f'{bag}: the bag holds no complete step: step 0 missing on '
                              f'{GROUND} ({N - 1} complete steps after it)')


def test_an_identical_duplicate_reads_as_one(source, run, tmp_path):
    """Step 7 of the reference force recorded twice, and every displacement twice: the same
    values, read once each; the duplicates are listed."""
    def edit(topic, ns, msg):
        if topic == DISPLACEMENT or (topic == REFERENCE and ns == 7 * DT_NS):
            return [(ns, msg), (ns, msg)]
        return [(ns, msg)]

    rd = read_run(rewrite(source, tmp_path / 'bag', edit))
    check_values(rd, run, N)
    assert rd.extra['gaps'] is None
    assert rd.extra['duplicates'] == {REFERENCE: [7], DISPLACEMENT: list(range(N))}
    assert rd.extra['counts'][REFERENCE] == N + 1 and rd.extra['counts'][DISPLACEMENT] == 2 * N


def test_a_duplicate_with_another_value_is_refused(source, run, tmp_path):
    """Step 7 of the measured force recorded twice, the second 1 N higher: which one the test
    saw cannot be known; the error names the bag, the topic, the step and both values."""
    first = float(run.measured_force_N[7])

    def edit(topic, ns, msg):
        if topic == MEASURED and ns == 7 * DT_NS:
            other = STORE.deserialize_cdr(STORE.serialize_cdr(msg, msg.__msgtype__),
                                          msg.__msgtype__)
            set_value(topic, other, first + 1.0)
            return [(ns, msg), (ns, other)]
        return [(ns, msg)]

    bag = rewrite(source, tmp_path / 'bag', edit)
    with pytest.raises(InputError, match=re.escape(
            f'{bag}: {MEASURED}: step 7 (t = 0.014000 s) recorded more than once with '
            f'different values ({first!r} and {first + 1.0!r})')):
        read_run(bag)


def test_two_differing_duplicates_are_counted(source, run, tmp_path):
    def edit(topic, ns, msg):
        if topic == VALVE and ns in (3 * DT_NS, 9 * DT_NS):
            other = STORE.deserialize_cdr(STORE.serialize_cdr(msg, msg.__msgtype__),
                                          msg.__msgtype__)
            set_value(topic, other, -99.0)
            return [(ns, msg), (ns, other)]
        return [(ns, msg)]

    bag = rewrite(source, tmp_path / 'bag', edit)
    with pytest.raises(InputError, match=re.escape(
            f'{VALVE}: step 3 (t = 0.006000 s) recorded more than once with different values '
            f'({float(run.valve_command_V[3])!r} and -99.0); 1 more such sample')):
        read_run(bag)


@pytest.mark.parametrize('connection', [True, False])
def test_a_missing_topic_is_named(source, tmp_path, connection):
    """The valve command of a servohydraulic run absent: no messages on its connection, or
    no connection at all."""
    bag = rewrite(source, tmp_path / 'bag', drop({VALVE: set(range(N))}))
    if not connection:
        with Reader(source) as reader:
            assert VALVE in {c.topic for c in reader.connections}
        bag = tmp_path / 'no_connection'
        with Reader(source) as reader, Writer(bag, version=9) as writer:
            conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=STORE)
                     for c in reader.connections if c.topic != VALVE}
            for conn, ns, raw in reader.messages():
                if conn.topic != VALVE:
                    writer.write(conns[conn.topic], ns, raw)
    with pytest.raises(InputError) as err:
        read_run(bag)
    assert str(err.value) == f'{bag}: the bag holds no complete step: no samples on {VALVE}'


def builder_abort(k_abort, *, ground_ahead=5, lost=None):
    """An edit that turns the completed run into one the builder's instability monitor
    aborted at step `k_abort`, as the graph records it: the reference forces and valve
    commands of steps 0..k_abort-1, the rig's samples up to step k_abort (the one it published
    before hearing the abort), the ground acceleration `ground_ahead` steps past it; the
    builder's 'aborted' report, then the rig's; `lost` ({topic: steps}) dropped as well."""
    last = {REFERENCE: k_abort - 1, VALVE: k_abort - 1, GROUND: k_abort - 1 + ground_ahead}
    lost = lost or {}
    t_abort = f'{k_abort * DT:.6f}'

    def edit(topic, ns, msg):
        k = ns // DT_NS
        if topic in FIELD:
            if k > last.get(topic, k_abort) or k in lost.get(topic, ()):
                return []
            return [(ns, msg)]
        if topic != signals.STATUS.name:
            return [(ns, msg)]
        state = next(kv.value for kv in msg.values if kv.key == 'state')
        if msg.name == 'reference_force_builder' and state == 'done':
            return [(k_abort * DT_NS, status('reference_force_builder', 'aborted', MONITOR,
                                             step=k_abort, time_s=t_abort,
                                             published=k_abort))]
        if msg.name == 'rig' and state == 'done':
            return [(k_abort * DT_NS, status('rig', 'aborted',
                                             f'reference_force_builder: {MONITOR}',
                                             step=k_abort, n_steps=N, time_s=t_abort,
                                             published=k_abort + 1, mode='lockstep'))]
        return [(ns, msg)]
    return edit


def test_an_abort_by_the_builder_names_it(source, run, tmp_path):
    """The monitor of the reference-force builder trips at step 25: not stable, the reason
    names the builder, the run ends at t = 25 dt; the samples past the abort (the rig's
    step 25, the ground motion's preview) are not a gap."""
    rd = read_run(rewrite(source, tmp_path / 'bag', builder_abort(25)))
    check_values(rd, run, 25)
    assert rd.stable is False
    assert rd.abort_reason == f'reference_force_builder: {MONITOR}'
    assert rd.unstable_at_s == 25 * DT
    assert rd.extra['gaps'] is None
    assert rd.extra['rig_final']['state'] == 'aborted'
    assert rd.extra['recording']['end'] == 'closed'


def test_an_abort_after_a_gap_keeps_its_time(source, run, tmp_path):
    """The builder aborts at step 30; the bag lost the reference forces of steps 10 and 11:
    analysed up to step 10, the abort still at t = 30 dt (the rig's final report), the gap
    and the 18 complete steps 12..29 after it reported."""
    rd = read_run(rewrite(source, tmp_path / 'bag',
                          builder_abort(30, lost={REFERENCE: {10, 11}})))
    check_values(rd, run, 10)
    assert rd.stable is False and rd.abort_reason.startswith('reference_force_builder: ')
    assert rd.unstable_at_s == 30 * DT
    gaps = rd.extra['gaps']
    assert gaps['missing'] == {REFERENCE: [10, 11]}
    assert (gaps['at_step'], gaps['steps_after_gap'], gaps['last_step']) == (10, 18, 29)


# -- an interrupted real-time run ------------------------------------------------------------

def interrupted(k_abort, *, runner=True):
    """An edit that turns the completed run into a real-time run the operator interrupted
    with Ctrl-C at step `k_abort` (session 23's D6, as the graph records it): every node
    stopped by SIGINT, the force servo controller reporting first, then (`runner`) the
    runner's interrupt, then the rig, which sampled its safe ramp to the end of the bag
    (``abort_at_s``); the reference forces and commands end at the abort."""
    stopped = {'ground_motion_publisher', 'reference_force_builder', 'force_servo_controller'}
    t_abort = f'{k_abort * DT:.6f}'

    def edit(topic, ns, msg):
        k = ns // DT_NS
        if topic in (signals.RUN_PARAMETERS.name, signals.NODE_PARAMETERS.name):
            doc = json.loads(msg.data)
            (doc['parameters'] if 'parameters' in doc else doc)['mode'] = 'realtime'
            msg.data = json.dumps(doc)
            return [(ns, msg)]
        if topic in (REFERENCE, VALVE, GROUND):
            return [] if k >= k_abort else [(ns, msg)]
        if topic != signals.STATUS.name:
            return [(ns, msg)]
        state = next(kv.value for kv in msg.values if kv.key == 'state')
        if state != 'done' or msg.name not in stopped | {'rig'}:
            return [(ns, msg)]
        if msg.name != 'rig':
            return []
        out = [(ns, status('force_servo_controller', 'aborted',
                           'force_servo_controller stopped by SIGINT', step=k_abort,
                           time_s=t_abort, published=k_abort, signal='SIGINT'))]
        if runner:
            out.append((ns, status('seft_runner', 'aborted', rig_contract.INTERRUPT_REASON)))
        out += [(ns, status(node, 'aborted', f'{node} stopped by SIGINT', step=k_abort,
                            time_s=t_abort, published=k_abort, signal='SIGINT'))
                for node in sorted(stopped - {'force_servo_controller'})]
        out.append((ns, status('rig', 'aborted', 'rig stopped by SIGINT', step=N, n_steps=N,
                               time_s=f'{N * DT:.6f}', published=N, mode='realtime',
                               abort_at_s=t_abort, signal='SIGINT',
                               **{rig_contract.CONTRACT_KEY: rig_contract.CONTRACT})))
        return out
    return edit


def rig_timing(k_abort):
    """The rig's timing records of every sample: 0.4 ms loop latency up to the abort, then
    (its safe ramp, the controller stopped) no command: lost, and stale."""
    joint_state = STORE.types['sensor_msgs/msg/JointState']
    header = STORE.types['std_msgs/msg/Header']
    stamp = STORE.types['builtin_interfaces/msg/Time']
    out = []
    for k in range(N):
        ramp = k >= k_abort
        values = [1e-5, 1e-4, 1e-3, 0.0, float(ramp and k > k_abort),
                  float('nan') if ramp else 4e-4]
        sec, nanosec = divmod(k * DT_NS, 10**9)
        out.append((k * DT_NS, joint_state(
            header=header(stamp=stamp(sec=sec, nanosec=nanosec), frame_id=''),
            name=list(signals.TIMING_FIELDS), position=np.array(values),
            velocity=np.array([], float), effort=np.array([], float))))
    return {'/seft/timing/rig': (signals.TIMING_TYPE, out)}


@pytest.mark.parametrize('runner', [True, False])
def test_an_interrupted_run_is_the_operators_not_unstable_and_its_ramp_not_timed(
        source, run, tmp_path, runner):
    """Ctrl-C at step 30 of 40: the reason names the operator's interrupt (before: the first
    node to report, 'force_servo_controller: force_servo_controller stopped by SIGINT'); the
    timing statistics stop at the abort (before: the 10 ramp ticks counted as 10 lost
    commands and 9 of 39 stale, 23 %); the timing replay reports the run's NRMS (before:
    'recorded unstable at 0.06 s')."""
    from seft_ros.analysis.findings import timing_replay_line
    from seft_ros.analysis.timing_replay import replay_timing
    rd = read_run(rewrite(source, tmp_path / 'bag', interrupted(30, runner=runner),
                          rig_timing(30)))
    check_values(rd, run, 30)
    assert rd.stable is False and rd.unstable_at_s == 30 * DT
    assert rd.extra['interrupted'] is True
    assert rd.abort_reason == ('seft_runner: interrupted (Ctrl-C or SIGTERM at the runner)'
                               if runner else 'interrupted (SIGINT): force_servo_controller: '
                               'force_servo_controller stopped by SIGINT')
    timing = rd.extra['timing']
    assert timing['lost_commands'] == 0 and timing['stale_command_fraction'] == 0.0
    assert timing['nodes']['rig']['records'] == 30
    assert timing['loop_latency_ms'] == {'p50': 0.4, 'p99': 0.4, 'max': 0.4}
    replay = replay_timing(rd)
    assert replay['late_commands'] == {'': 0}
    assert replay['recorded']['displacement'] == pytest.approx(
        replay['in_time']['displacement'], rel=1e-3)
    assert 'unstable' not in timing_replay_line(replay)


def test_an_abort_of_the_run_is_not_an_interrupt(source, tmp_path):
    """The builder's monitor aborts (no signal), and then the operator presses Ctrl-C:
    the monitor's reason stays the run's."""
    abort = builder_abort(25)

    def edit(topic, ns, msg):
        out = abort(topic, ns, msg)
        if (topic == signals.STATUS.name and msg.name == 'reference_force_builder'
                and out[0][1].level == 2):          # its abort, then the operator's Ctrl-C
            out.append((ns, status('seft_runner', 'aborted', rig_contract.INTERRUPT_REASON)))
        return out
    rd = read_run(rewrite(source, tmp_path / 'bag', edit))
    assert rd.extra['interrupted'] is False
    assert rd.abort_reason == f'reference_force_builder: {MONITOR}'


# -- a rig behind the UDP bridge -------------------------------------------------------------

#: The wire counts of a bridge's final status (UdpBridgeRig.wire_counts): every datagram to
#: the PC came twice (session 23's bridge tester: 1004 duplicates on a run read 'stable').
WIRE = {'udp_late': 3, 'udp_bad': 0, 'udp_other_session': 0, 'udp_foreign': 0, 'udp_lost': 0,
        'udp_duplicate': 1004, 'udp_reordered': 0, 'controller_late': 0, 'controller_lost': 1,
        'controller_duplicate': 0, 'controller_reordered': 0, 'controller_bad': 0,
        'controller_start_refused': 0}
SILENT = ('udp_bridge: no datagram from the controller for 203.5 ms (limit 200 ms) after '
          't = 0.050 s')
UNCONFIRMED = ('the safe state was NOT confirmed by the controller at 127.0.0.1:47001: no '
               'state 3 (safe) from it 0.462 s after the request (bound 0.462 s: latency, '
               'safe ramp, hold and watchdog; its last state: running); check the rig')


def bridge_run(k_abort=None, **final):
    """An edit that gives the rig's final status a UDP bridge's counts (and `final`); with
    `k_abort`, the controller fell silent at step `k_abort`: the force servo controller's
    watchdog reports first, then the rig its own view (as the graph records it)."""
    t_abort = f'{(k_abort or 0) * DT:.6f}'

    def edit(topic, ns, msg):
        k = ns // DT_NS
        if k_abort is not None and topic in FIELD and k > k_abort:
            return []
        if topic != signals.STATUS.name:
            return [(ns, msg)]
        state = next(kv.value for kv in msg.values if kv.key == 'state')
        if state != 'done' or msg.name not in ('rig', 'force_servo_controller'):
            return [(ns, msg)]
        if msg.name == 'force_servo_controller':
            return [] if k_abort is not None else [(ns, msg)]
        if k_abort is None:
            return [(ns, status('rig', 'done', 'completed 40 steps', step=N, n_steps=N,
                                time_s=f'{N * DT:.6f}', published=N, **WIRE, **final))]
        return [(ns, status('force_servo_controller', 'aborted', 'watchdog: no '
                            '/seft/reference_force for 201 ms (limit 200 ms; node or link '
                            'lost)', step=k_abort, time_s=t_abort)),
                (ns, status('rig', 'aborted', SILENT, step=k_abort, n_steps=N, time_s=t_abort,
                            published=k_abort + 1, ended_by='force_servo_controller',
                            **WIRE, **final))]
    return edit


def test_a_silent_controller_is_the_runs_reason_not_the_watchdog_it_tripped(source, tmp_path):
    """Session 23: the run's reason was 'force_servo_controller: watchdog: no
    /seft/reference_force for 201 ms ...', the bridge's own view second. Now the rig's view
    of its controller is the reason."""
    rd = read_run(rewrite(source, tmp_path / 'bag', bridge_run(25)))
    assert rd.stable is False
    assert rd.abort_reason == SILENT
    assert rd.extra['abort_node'] == 'rig'


def test_the_bridges_wire_counts_and_an_unconfirmed_safe_state_are_reported(
        source, tmp_path):
    """The counts were in the bag's final status only: now in the summary, the report and
    the console's notes, with a warning for the duplicates (and the lost command, 1 of 40:
    above 1 %; 3 late samples of 40 too), and the safe state NOT confirmed said plainly."""
    from seft_ros.analysis.findings import bridge_entry, bridge_lines
    from seft_ros.analysis.metrics import compare_run, summary_entry
    from seft_ros.analysis.report import _run_markdown
    from seft_ros.cli.api import _accuracy_notes
    rd = read_run(rewrite(source, tmp_path / 'bag', bridge_run(
        safe_confirmed=0, safe_unconfirmed=UNCONFIRMED)))
    entry = summary_entry(rd, compare_run(rd))
    bridge = entry['udp_bridge']['rig']
    assert bridge == bridge_entry(rd)['rig']
    assert bridge['counts']['to_pc']['duplicate'] == 1004
    assert bridge['counts']['to_controller']['lost'] == 1
    assert bridge['safe_confirmed'] is False and bridge['safe_unconfirmed'] == UNCONFIRMED
    assert bridge['warnings'] == [
        'rig: the UDP link to the PC was not clean: 3 late (7.5 % of 40 samples; applied '
        'late), 1004 duplicate (2510.0 % of 40 samples; dropped): check the network and the '
        'controller',
        'rig: the UDP link to the controller was not clean: 1 lost (2.5 % of 40 samples; not '
        'applied): check the network and the controller']
    lines = bridge_lines(entry['udp_bridge'])
    assert lines[0] == ('counts', 'rig: UDP bridge datagrams over 40 samples: to the PC 0 '
                        'lost, 3 late, 1004 duplicate, 0 reordered, 0 bad, 0 foreign, 0 other '
                        'session; to the controller 1 lost, 0 late, 0 duplicate, 0 reordered, '
                        '0 bad')
    assert lines[-1] == ('safe state', f'rig: {UNCONFIRMED}')
    markdown = _run_markdown(1, rd, compare_run(rd))
    assert f'- {lines[0][1]}' in markdown
    assert f'- **warning**: {bridge["warnings"][0]}' in markdown
    assert f'- **safe state NOT confirmed**: rig: {UNCONFIRMED}' in markdown
    notes = _accuracy_notes('run 1 (model)', entry)
    assert f'note: run 1 (model): WARNING: {bridge["warnings"][1]}' in notes
    assert f'note: run 1 (model): WARNING: rig: {UNCONFIRMED}' in notes
    # a clean link: the counts, no warning
    rd = read_run(rewrite(source, tmp_path / 'clean', bridge_run(safe_confirmed=1)))
    clean = dict(WIRE, udp_duplicate=0, udp_late=0, controller_lost=0)
    assert bridge_entry(rd)['rig']['warnings'] != []          # WIRE's counts
    rd.extra['rig_finals']['rig'].update({k: str(v) for k, v in clean.items()})
    assert bridge_entry(rd)['rig']['warnings'] == []
    assert bridge_entry(rd)['rig']['safe_confirmed'] is True


def test_the_first_abort_reads_a_runners_report_beside_a_watchdog():
    """A run whose first abort is a watchdog and whose reports include the runner's (a lab
    host lost: 'seft_runner', no graph node): the watchdog stays the reason. Before, the
    bridge rule looked the runner's name up as a graph node and raised "node 'seft_runner':
    expected one of ...": the two- and three-host cut-link runs ended in that error (CI of
    0d0c0ed)."""
    from seft_ros.analysis.bag import _first_abort
    watchdog = {'name': 'reference_force_builder', 'state': 'aborted',
                'message': 'watchdog: no measurement for 41 ms (limit 40 ms; node or link lost)'}
    runner = {'name': 'seft_runner', 'state': 'aborted',
              'message': 'lab host lab lost: no word from it for 5.0 s (link cut or host down)'}
    assert _first_abort([watchdog, runner]) is watchdog
    bridge = {'name': 'pier_a/rig', 'state': 'aborted',
              'message': 'udp_bridge: no datagram from the controller for 203.5 ms'}
    assert _first_abort([watchdog, runner, bridge]) is bridge
