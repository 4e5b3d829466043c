"""A bag whose writer died before closing it: keep it readable while it is written, and read
back what it saved.

rosbags writes a bag's index only on close: ``metadata.yaml`` then, the MCAP file's summary
and footer then (a cut file is refused with "File end magic is invalid"), and an sqlite3 bag
is one transaction until then. A recorder killed with SIGKILL would lose its whole bag.

Writer side, :func:`flush_bag`: put everything written so far into the file. For MCAP it
closes the pending chunk (a complete Chunk record, with its message indexes) and flushes the
file object; for sqlite3 it commits. The recorder calls it every :data:`FLUSH_EVERY_S`
(sample and wall time): what a SIGKILL loses is the pending chunk, at most that long. A
closed bag is unchanged for every reader (only its chunks are smaller).

Reader side, :func:`recover_bag`: every message of the complete records of the file(s) of a
bag without ``metadata.yaml``. MCAP through the ``mcap`` package's
:class:`~mcap.stream_reader.StreamReader` (it reads records in file order and needs no
summary), with reads of exactly the size asked, so that a record cut by the crash ends the
reading instead of being parsed short; sqlite3 from a copy of the database (sqlite rolls the
uncommitted transaction back in the copy, the crashed file stays as it was).

No rclpy here: the recorder (writer side) and the bag reader (:mod:`seft_ros.analysis.bag`)
both use it.
"""

from dataclasses import dataclass, field
from pathlib import Path
import shutil
import sqlite3
import tempfile

from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

__all__ = ['FLUSH_EVERY_S', 'flush_bag', 'is_unclosed_bag', 'storage_files', 'RecoveredBag',
           'recover_bag']

#: The recorder flushes its bag (:func:`flush_bag`) every this many seconds of sample time
#: and of wall time: a recorder killed with SIGKILL loses at most the last this many seconds
#: of what it had received [s].
FLUSH_EVERY_S = 0.25
#: Suffix of the storage file of each rosbag2 storage plugin.
STORAGE_SUFFIXES = {'.mcap': 'mcap', '.db3': 'sqlite3'}


def flush_bag(writer) -> None:
    """Put every message written so far into the bag's file, readable after a crash.

    Parameters
    ----------
    writer : rosbags.rosbag2.Writer
        An open writer (MCAP or sqlite3 storage); a closed one is left alone.

    Raises
    ------
    TypeError
        Another storage plugin (rosbags has only these two).

    Notes
    -----
    Uses the storage objects of rosbags 0.11 (``McapWriter.close_chunk``, ``.chunk``,
    ``.bio``; ``Sqlite3Writer.conn``), pinned in constraints.txt; the bag-recovery tests
    fail if a new version changes them. A flushed chunk is a normal MCAP chunk: at close,
    rosbags indexes it with the others. Without the flush, rosbags closes a chunk at 1 MiB.
    """
    storage = writer.storage
    if storage is None:
        return
    if isinstance(storage, McapWriter):
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()
    elif isinstance(storage, Sqlite3Writer):
        storage.conn.commit()
    else:
        raise TypeError(f'{type(storage).__name__}: no flush for this bag storage')


def storage_files(path) -> list[Path]:
    """The storage files of the bag at `path`: the file itself (``.mcap``, ``.db3``) or the
    directory's, in name order."""
    path = Path(path)
    if path.is_file():
        return [path] if path.suffix in STORAGE_SUFFIXES else []
    return sorted(p for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES and p.is_file())


def is_unclosed_bag(path) -> bool:
    """True if `path` is a storage file, or a directory holding storage files but no
    ``metadata.yaml``: its writer never closed it (or it is a bare file rosbags cannot
    open); :func:`recover_bag` reads it."""
    path = Path(path)
    if path.is_file():
        return path.suffix in STORAGE_SUFFIXES
    return path.is_dir() and not (path / 'metadata.yaml').exists() and bool(storage_files(path))


@dataclass
class RecoveredBag:
    """What :func:`recover_bag` read from a bag that was not closed.

    Attributes
    ----------
    files : list of Path
        The storage files read.
    storage : str
        ``'mcap'`` or ``'sqlite3'``.
    messages : list of (str, str, int, bytes)
        ``(topic, message type, log time [ns], CDR bytes)`` of every message of the complete
        records, in log-time order (file order among equal times), as rosbags yields them.
    file_complete : bool
        True if every file ended as a closed file does (the MCAP footer and end magic); an
        sqlite3 file counts as complete.
    end : str
        Why the reading of a file stopped before its end ('' if none): the cut record.
    damaged : str
        For a bag whose ``metadata.yaml`` says it was closed but whose file the reader
        refuses (cut or damaged after the recording: a copy cut short), the reader's error;
        '' for a bag that was never closed.
    """

    files: list[Path]
    storage: str
    messages: list[tuple[str, str, int, bytes]] = field(default_factory=list)
    file_complete: bool = True
    end: str = ''
    damaged: str = ''


class _ExactReads:
    """A binary file whose ``read(n)`` returns n bytes or raises EOFError.

    mcap's ``ReadDataStream`` takes a short read that is not empty as the data: a record cut
    by a crash (a chunk half written) would be parsed short, its last message cut.
    """

    def __init__(self, f):
        self._f = f
        self.pos = 0

    def read(self, n: int) -> bytes:
        data = self._f.read(n)
        self.pos += len(data)
        if len(data) < n:
            raise EOFError(f'the file ends at byte {self.pos} without its summary and footer'
                           + (' (a record cut)' if data else ''))
        return data


def _mcap_messages(path: Path, out: list) -> tuple[bool, str]:
    """Append the messages of the complete records of MCAP file `path` to `out` (file
    order); return (whether the file was complete, why reading stopped)."""
    # imported here: the recorder (flush_bag) does not need it at start-up (15 ms of CPU)
    from mcap.records import Channel, Footer, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    complete = False
    with path.open('rb') as f:
        try:
            for rec in StreamReader(_ExactReads(f)).records:
                if isinstance(rec, Message):
                    topic_type = channels.get(rec.channel_id)
                    if topic_type is not None:
                        out.append((*topic_type, rec.log_time, rec.data))
                elif isinstance(rec, Channel):
                    channels.setdefault(rec.id, (rec.topic, schemas.get(rec.schema_id, '')))
                elif isinstance(rec, Schema):
                    schemas.setdefault(rec.id, rec.name)
                elif isinstance(rec, Footer):
                    complete = True
        except Exception as exc:   # mcap raises several types for a cut or damaged file
            return False, f'{path.name}: {exc or type(exc).__name__}'
    return complete, ''


def _sqlite_messages(path: Path, out: list) -> None:
    """Append the committed messages of sqlite3 file `path` to `out` (timestamp order)."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / path.name
        for src in (path, *(path.with_name(path.name + s) for s in ('-journal', '-wal'))):
            if src.exists():
                shutil.copyfile(src, copy.with_name(src.name))
        conn = sqlite3.connect(copy)
        try:
            topics = {i: (name, msgtype) for i, name, msgtype
                      in conn.execute('SELECT id, name, type FROM topics')}
            for topic_id, stamp, data in conn.execute(
                    'SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id'):
                if topic_id in topics:
                    out.append((*topics[topic_id], int(stamp), bytes(data)))
        finally:
            conn.close()


def recover_bag(path) -> RecoveredBag:
    """Read every message a bag that was not closed holds in complete records.

    Parameters
    ----------
    path : str or Path
        A bag directory without ``metadata.yaml`` (or one storage file), written by rosbags;
        or one with it whose file the reader refuses (its metadata is then not read).

    Returns
    -------
    RecoveredBag

    Raises
    ------
    ValueError
        No storage file there, or an sqlite3 file that is not a rosbag2 database.
    """
    files = storage_files(path)
    if not files:
        raise ValueError(f'{path}: no .mcap or .db3 file')
    kinds = {STORAGE_SUFFIXES[f.suffix] for f in files}
    if len(kinds) > 1:
        raise ValueError(f'{path}: both .mcap and .db3 files')
    bag = RecoveredBag(files=files, storage=kinds.pop())
    for f in files:
        if bag.storage == 'mcap':
            complete, end = _mcap_messages(f, bag.messages)
            bag.file_complete = bag.file_complete and complete
            bag.end = bag.end or end
        else:
            try:
                _sqlite_messages(f, bag.messages)
            except sqlite3.Error as exc:
                raise ValueError(f'{f}: not a readable rosbag2 sqlite3 file ({exc})') from None
    bag.messages.sort(key=lambda m: m[2])       # stable: file order among equal times
    return bag
