"""A bag whose recorder was killed: flushed chunks survive, the cut file reads back (issue 8).

Bags are written in ``tmp_path`` with rosbags as the recorder writes them (run parameters,
the recorder's 'ready' status, one message per step on every scalar topic, a
:func:`~seft_ros.analysis.bag_recovery.flush_bag` every ``FLUSH`` steps). A copy of the bag
directory taken while the writer is open is what a SIGKILL leaves: no ``metadata.yaml``, an
MCAP file without summary and footer (which rosbags refuses), or an sqlite3 file with an open
transaction. Cutting that file at any byte must never yield a short message.
"""

import json
from pathlib import Path
import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import parameters, signals
from seft_msgs_py.errors import InputError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.bag_recovery import flush_bag, is_unclosed_bag, recover_bag

STORE = get_typestore(Stores.ROS2_JAZZY)
DT = 0.002
DT_NS = 2_000_000
N = 1000
FLUSH = 100          # steps between flushes
SNAPSHOT_AT = 650    # the 'kill': after this many steps, flushed at 600
SCALARS = (signals.GROUND_ACCELERATION, signals.REFERENCE_FORCE, signals.VALVE_COMMAND,
           signals.MEASURED_FORCE, signals.DISPLACEMENT, signals.VELOCITY, signals.ACCELERATION)


def value(j, k):
    """Sample k of signal number j: distinct, exactly representable."""
    return (j + 1) * 1000.0 + 0.25 * k


def scalar_raw(sig, k, v):
    msg = STORE.types[sig.type_name]
    fields = {'geometry_msgs/msg/AccelStamped': 'accel', 'geometry_msgs/msg/WrenchStamped':
              'wrench', 'geometry_msgs/msg/Vector3Stamped': 'vector',
              'geometry_msgs/msg/PointStamped': 'point', 'geometry_msgs/msg/TwistStamped':
              'twist'}
    header = STORE.types['std_msgs/msg/Header'](
        stamp=STORE.types['builtin_interfaces/msg/Time'](*divmod(k * DT_NS, 10**9)),
        frame_id='seft')
    v3 = STORE.types['geometry_msgs/msg/Vector3']
    zero = v3(0.0, 0.0, 0.0)
    body = {
        'accel': lambda: STORE.types['geometry_msgs/msg/Accel'](v3(v, 0.0, 0.0), zero),
        'wrench': lambda: STORE.types['geometry_msgs/msg/Wrench'](v3(v, 0.0, 0.0), zero),
        'vector': lambda: v3(v, 0.0, 0.0),
        'point': lambda: STORE.types['geometry_msgs/msg/Point'](v, 0.0, 0.0),
        'twist': lambda: STORE.types['geometry_msgs/msg/Twist'](v3(v, 0.0, 0.0), zero),
    }[fields[sig.type_name]]()
    return STORE.serialize_cdr(msg(header, body), sig.type_name)


def status_raw(node, state, **values):
    kv = STORE.types['diagnostic_msgs/msg/KeyValue']
    msg = STORE.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name=node, message='', hardware_id='seft',
        values=[kv(key='state', value=state)] + [kv(key=k, value=str(v))
                                                 for k, v in values.items()])
    return STORE.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticStatus')


def record(path: Path, storage=StoragePlugin.MCAP, *, snapshot: Path | None = None,
           rig_final: bool = True):
    """Write a bag as the recorder does; copy the directory to `snapshot` after
    ``SNAPSHOT_AT`` steps (the state a SIGKILL leaves). Without `rig_final`, the recorder
    closes the bag without the rig's final status (stopped by a signal)."""
    params = parameters.resolve({'rig_model': 'servohydraulic', 'dt': DT, 'alpha': 0.5})
    writer = Writer(path, version=9, storage_plugin=storage)
    writer.open()
    conns = {t.name: writer.add_connection(t.name, t.type_name, typestore=STORE)
             for t in (signals.RUN_PARAMETERS, signals.STATUS) + SCALARS}
    text = STORE.types['std_msgs/msg/String'](data=json.dumps(params))
    writer.write(conns[signals.RUN_PARAMETERS.name], 0,
                 STORE.serialize_cdr(text, 'std_msgs/msg/String'))
    writer.write(conns[signals.STATUS.name], 0,
                 status_raw('recorder', 'ready', flush_every_s=FLUSH * DT))
    flush_bag(writer)
    for k in range(N):
        if k == SNAPSHOT_AT and snapshot is not None:
            shutil.copytree(path, snapshot)
        for j, sig in enumerate(SCALARS):
            writer.write(conns[sig.name], k * DT_NS, scalar_raw(sig, k, value(j, k)))
        if (k + 1) % FLUSH == 0:
            flush_bag(writer)
    if rig_final:
        writer.write(conns[signals.STATUS.name], (N - 1) * DT_NS, status_raw('rig', 'done'))
    writer.write(conns[signals.STATUS.name], (N - 1) * DT_NS, status_raw('recorder', 'closed'))
    writer.close()


@pytest.fixture(scope='module')
def mcap_bags(tmp_path_factory):
    """(closed bag, the snapshot a SIGKILL at step 650 leaves)."""
    tmp = tmp_path_factory.mktemp('mcap')
    record(tmp / 'bag', snapshot=tmp / 'killed')
    return tmp / 'bag', tmp / 'killed'


def check_values(run, n):
    assert run.n_steps == n
    k = np.arange(n)
    for j, attr in enumerate(('ground_acceleration_m_s2', 'reference_force_N',
                              'valve_command_V', 'measured_force_N', 'displacement_m',
                              'velocity_m_s', 'acceleration_m_s2')):
        np.testing.assert_array_equal(getattr(run, attr), value(j, k), err_msg=attr)


def test_a_closed_bag_reads_as_before_and_says_closed(mcap_bags):
    bag, _ = mcap_bags
    assert not is_unclosed_bag(bag)
    run = read_run(bag)
    check_values(run, N)
    assert run.stable
    assert run.extra['recording']['end'] == 'closed'
    # rosbags reads it as one bag, one file; the flushes only made more chunks
    assert sorted(p.name for p in bag.iterdir()) == ['bag.mcap', 'metadata.yaml']
    with Reader(bag) as reader:
        assert reader.message_count == 2 + 2 + N * len(SCALARS)


def test_a_bag_closed_before_the_run_ended_says_stopped(tmp_path):
    """A recorder stopped by SIGINT/SIGTERM closes its bag: it reads, cut short."""
    record(tmp_path / 'bag', rig_final=False)
    run = read_run(tmp_path / 'bag')
    check_values(run, N)
    assert run.extra['recording']['end'] == 'stopped'
    assert not run.stable and run.unstable_at_s == pytest.approx(N * DT)
    assert run.abort_reason == 'recorder: the recording was stopped before the run ended'


def test_recovery_reads_a_closed_file_as_rosbags_does(mcap_bags):
    bag, _ = mcap_bags
    with Reader(bag) as reader:
        expected = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]
    got = recover_bag(next(bag.glob('*.mcap')))
    assert got.file_complete and got.end == ''
    assert got.messages == expected


def test_a_killed_recorders_bag_reads_up_to_the_last_flush(mcap_bags, tmp_path):
    bag, killed = mcap_bags
    assert not (killed / 'metadata.yaml').exists()
    with pytest.raises(FileNotFoundError, match='metadata'):
        Reader(killed)
    # even given the metadata, rosbags refuses the file: no summary, no footer
    with_meta = tmp_path / 'with_meta'
    shutil.copytree(killed, with_meta)
    shutil.copy(bag / 'metadata.yaml', with_meta)
    with pytest.raises(ReaderError, match='File end magic is invalid'):
        Reader(with_meta).open()
    assert is_unclosed_bag(killed)
    run = read_run(killed)
    check_values(run, 600)          # every flushed step, nothing of the pending chunk
    rec = run.extra['recording']
    assert rec['end'] == 'crashed' and rec['steps'] == 600
    assert rec['flush_every_s'] == pytest.approx(FLUSH * DT)
    assert rec['file_complete'] is False
    assert not run.stable and run.unstable_at_s == pytest.approx(600 * DT)
    assert run.abort_reason == ('recorder: the recording was not closed (recorder killed, or '
                                'still recording)')
    assert rec['note'].startswith('the recording was not closed (recorder killed, or still '
                                  'recording): recovered 1.200 s (600 steps')
    # a cut, not an abort (a new user's recovered cut recording read 'aborted'; session 36)
    from seft_ros.analysis.metrics import compare_run, summary_entry
    from seft_ros.analysis.report import _entry_status
    assert run.recording_cut_short
    entry = summary_entry(run, compare_run(run))
    assert entry['verdict'] == 'recording cut short'
    assert _entry_status(entry) == 'recording cut short at 1.200 s'


def test_a_closed_bags_file_cut_afterwards_reads_as_recovered_and_says_so(mcap_bags,
                                                                           tmp_path):
    """A bag whose metadata.yaml says it was closed but whose file the reader refuses (a copy
    cut short): its complete records are read as of a bag never closed, and the recording
    says 'damaged' with the reader's error (before: 'cannot read the bag: File end magic is
    invalid', while the same file without its metadata read back; a new user, session 36)."""
    bag, killed = mcap_bags
    cut = tmp_path / 'cut'
    shutil.copytree(killed, cut)
    shutil.copy(bag / 'metadata.yaml', cut)
    run = read_run(cut)
    check_values(run, 600)
    rec = run.extra['recording']
    assert rec['end'] == 'damaged' and rec['steps'] == 600
    assert 'File end magic is invalid' in rec['reader_error'] and 'flush_every_s' not in rec
    assert rec['note'].startswith(
        'its metadata.yaml says the recorder closed this bag, but the reader refuses it '
        f"({rec['reader_error']}); its file was cut or damaged after the recording: "
        'recovered 1.200 s (600 steps'), rec['note']
    assert not run.stable and run.abort_reason.startswith(
        'the bag: its file was cut or damaged after the recording')
    # a whole file the reader refuses for its metadata (another version): read, not 'cut'
    meta = tmp_path / 'meta'
    shutil.copytree(bag, meta)
    text = (meta / 'metadata.yaml').read_text()
    (meta / 'metadata.yaml').write_text(text.replace('version: ', 'version: 99 #', 1))
    rec = read_run(meta).extra['recording']
    assert rec['end'] == 'damaged' and rec['steps'] == N and rec['note'].startswith(
        'its metadata.yaml says the recorder closed this bag, but the reader refuses it ('), rec
    assert '; its file is whole: read from it 2.000 s (1000 steps' in rec['note'], rec['note']
    # a file that holds nothing whole: the reader's error, in one line
    empty = tmp_path / 'empty'
    empty.mkdir()
    shutil.copy(bag / 'metadata.yaml', empty)
    (empty / next(bag.glob('*.mcap')).name).write_bytes(b'not an mcap file')
    with pytest.raises(InputError, match=r'empty: the reader refuses its file \(.+\), cut or '
                       r'damaged after the recording, and holds no run parameters in its '
                       r'complete records \(bag.mcap: not a valid MCAP file'):
        read_run(empty)


def test_a_file_cut_anywhere_yields_only_whole_messages(mcap_bags, tmp_path):
    """Cut the killed recorder's file at 30 places: what is recovered is whole messages of
    whole flushes (a cut record is never parsed short), growing with the cut; a few of the
    cuts read as runs with exact values."""
    _, killed = mcap_bags
    data = next(killed.glob('*.mcap')).read_bytes()
    whole = set(recover_bag(killed).messages)
    previous, steps = 0, 0
    for i, cut in enumerate(np.linspace(0, len(data), 30).astype(int)):
        bag = tmp_path / f'cut{i}'
        bag.mkdir()
        (bag / 'bag.mcap').write_bytes(data[:cut])
        got = recover_bag(bag)
        assert set(got.messages) <= whole, cut
        scalars = [m for m in got.messages if m[0] != signals.STATUS.name
                   and m[0] != signals.RUN_PARAMETERS.name]
        assert len(scalars) % (FLUSH * len(SCALARS)) == 0, (cut, len(scalars))
        assert len(got.messages) >= previous, cut
        assert got.file_complete is False and (got.end or cut == len(data)), cut
        previous = len(got.messages)
        if i % 10 == 9:
            try:
                run = read_run(bag)
            except InputError as exc:
                assert 'no complete step' in str(exc), (cut, exc)
                continue
            check_values(run, run.n_steps)
            assert run.n_steps >= steps and run.n_steps % FLUSH == 0
            steps = run.n_steps
    assert previous == 2 + 600 * len(SCALARS)


def test_sqlite3_commits_survive_a_kill(tmp_path):
    bag, killed = tmp_path / 'bag', tmp_path / 'killed'
    record(bag, StoragePlugin.SQLITE3, snapshot=killed)
    assert is_unclosed_bag(killed)
    run = read_run(killed)
    check_values(run, 600)
    assert run.extra['recording']['end'] == 'crashed'
    assert run.extra['recording']['storage'] == 'sqlite3'
    # the crashed file is left as it was (the recovery reads a copy)
    db = next(killed.glob('*.db3'))
    before = db.read_bytes()
    read_run(killed)
    assert db.read_bytes() == before
    check_values(read_run(bag), N)


def test_a_bag_killed_before_its_first_flush_says_so(tmp_path):
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag.mcap').write_bytes(b'\x89MCAP0\r\n\x01')       # magic, a cut header
    with pytest.raises(InputError, match='not closed .* no run parameters'):
        read_run(bag)
    (bag / 'bag.mcap').write_bytes(b'not an mcap file')
    with pytest.raises(InputError, match='not closed'):
        read_run(bag)
    other = tmp_path / 'other'
    other.mkdir()
    (other / 'bag.db3').write_bytes(b'not sqlite')
    with pytest.raises(InputError, match='cannot read the bag'):
        read_run(other)


def test_flush_bag_refuses_an_unknown_storage():
    class Fake:
        storage = object()
    with pytest.raises(TypeError, match='no flush for this bag storage'):
        flush_bag(Fake())
