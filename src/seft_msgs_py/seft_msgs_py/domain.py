"""Which ROS domain a seft process uses: claimed, so that concurrent runs never meet.

The rule (tests and ``seft run`` alike): a process that starts ROS nodes claims its domain
with an exclusive, non-blocking ``flock`` on ``<LOCK_DIR>/<id>.lock`` and holds it until it
exits. The kernel releases the lock when the process dies, also on SIGKILL, so no claim
outlives its owner. A process tries the ids of its range from a start it chooses (the test
session's pid, a random one for ``seft run``) and takes the first it can lock, so two
concurrent processes can never share a domain. Tests use 200-232, ``seft run`` 100-199 (or
the id the user gives, refused while another process holds it). A claim covers the
holder's child processes: a test session's ``seft run`` uses the session's domain
(:func:`held_by_ancestor`).
"""

import fcntl
import os
from pathlib import Path

__all__ = ['LOCK_DIR', 'claim_domain', 'held_by_ancestor']

#: The claims: one lock file per domain, shared by every user of the machine (DDS discovery
#: on localhost crosses users).
LOCK_DIR = Path('/tmp/seft-ros-domains')


def claim_domain(ids, lock_dir: Path = LOCK_DIR, start: int | None = None):
    """Claim a ROS domain for as long as this process lives; return ``(domain_id, file)``.

    Tries the ids of `ids` from index ``start % len(ids)`` (default: this process's pid) and
    takes the first one it can lock (module notes); a pid-derived id alone could be shared
    (30 ids: 1 in 30 pairs of pids). Keep the returned file open: closing it releases the
    claim.

    Parameters
    ----------
    ids : iterable of int
        Candidate domain ids (0-232).
    lock_dir : Path
        Directory of the lock files (created world-writable if missing).
    start : int, optional
        Where to start in `ids`.

    Raises
    ------
    RuntimeError
        Every id of the range is claimed.
    """
    ids = list(ids)
    if not lock_dir.is_dir():
        lock_dir.mkdir(parents=True, exist_ok=True)
        try:            # every user's runs claim here (the umask would take the write bits)
            os.chmod(lock_dir, 0o1777)
        except OSError:
            pass
    first = (os.getpid() if start is None else start) % len(ids)
    for domain in ids[first:] + ids[:first]:
        path = lock_dir / f'{domain}.lock'
        try:
            f = open(path, 'a+')
        except OSError:             # another user's lock file: that domain is theirs
            continue
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        f.seek(0)
        f.truncate()
        f.write(f'{os.getpid()}\n')
        f.flush()
        return domain, f
    raise RuntimeError(f'no free ROS domain in {ids[0]}-{ids[-1]}: every one is claimed '
                       f'(lock files in {lock_dir})')


def _parent_pid(pid: int) -> int:
    """The parent of `pid` (0 when unknown), from ``/proc/<pid>/stat``."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return 0
    return int(stat.rsplit(')', 1)[1].split()[1])


def held_by_ancestor(domain: int, lock_dir: Path = LOCK_DIR) -> bool:
    """Whether `domain`'s claim is held by this process's parent, grandparent, ...

    The holder writes its pid into the lock file (:func:`claim_domain`); a process started by
    the holder (a test session's ``seft run``) may use the domain under that claim.
    """
    try:
        holder = int((lock_dir / f'{domain}.lock').read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return False
    pid = os.getppid()
    while pid > 1:
        if pid == holder:
            return True
        pid = _parent_pid(pid)
    return False
