"""The system clock of a seft process, in the reference host's time (no rclpy).

Timing ages, deadlines and the rigs' common start compare instants taken on different hosts:
a sample stamped by the rig's host, its command received on the controller's host. Two lab
PCs without PTP disagree by milliseconds or more. seft therefore keeps every host in the
clock of one **reference host** (the one that runs the recorder): each other host's runner
measures its offset to it (NTP-style pings, :mod:`seft_ros.core.link_probe`) before its nodes
start and hands it to them in :data:`OFFSET_ENV`; :func:`now_ns` is the system clock less that
offset.

:data:`TEST_OFFSET_ENV` is **for tests only**: it shifts what :func:`system_ns` reads by a set
amount, so that two network namespaces of one machine (which share one clock) behave like two
hosts whose clocks differ.
"""

import math
import os
import time

__all__ = ['now_ns', 'system_ns', 'offset_ns', 'read_environment', 'OFFSET_ENV',
           'TEST_OFFSET_ENV']

#: This host's clock minus the reference host's [ns] (set by ``seft run`` for its nodes).
OFFSET_ENV = 'SEFT_CLOCK_OFFSET_NS'
#: Test only: add this [s] to the system clock this process reads (a host whose clock is off).
TEST_OFFSET_ENV = 'SEFT_TEST_CLOCK_OFFSET_S'


def _env_ns(name: str, scale: float) -> int:
    text = os.environ.get(name, '').strip()
    if not text:
        return 0
    try:
        value = float(text) * scale
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f'{name}={text!r}: expected a number')
    return int(round(value))


_TEST_NS = 0
_OFFSET_NS = 0


def read_environment() -> None:
    """Take this process's offsets from its environment (:data:`OFFSET_ENV`,
    :data:`TEST_OFFSET_ENV`): at import, and again when a node starts (a node forked from a
    process that imported this module earlier, ``seft_ros.cli.spawn``, has its own).

    Raises
    ------
    ValueError
        A variable is set to something else than a finite number.
    """
    global _TEST_NS, _OFFSET_NS
    _TEST_NS = _env_ns(TEST_OFFSET_ENV, 1e9)
    _OFFSET_NS = _env_ns(OFFSET_ENV, 1.0)


read_environment()


def system_ns() -> int:
    """This host's system clock [ns since the epoch] (``time.time_ns``; shifted by
    :data:`TEST_OFFSET_ENV` in a test)."""
    return time.time_ns() + _TEST_NS


def offset_ns() -> int:
    """This host's clock minus the reference host's [ns] (:data:`OFFSET_ENV`; 0 on the
    reference host and on one host)."""
    return _OFFSET_NS


def now_ns() -> int:
    """The reference host's clock [ns since the epoch], as this host estimates it."""
    return system_ns() - _OFFSET_NS
