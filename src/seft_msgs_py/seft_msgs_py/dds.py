"""The DDS settings a seft process starts with (no rclpy).

Fast DDS (rmw_fastrtps, ROS 2 Jazzy's default middleware) reads its default profiles from the
XML file named by ``FASTRTPS_DEFAULT_PROFILES_FILE`` when the process creates its first
participant. seft ships one (``fastdds_profile.xml`` beside this module) that shortens a
reliable writer's heartbeat period from Fast DDS's 3 s to :data:`HEARTBEAT_PERIOD_S`: a
reader delivers a writer's samples in order, so a packet lost on the link holds back every
later sample of that writer until the next heartbeat makes the reader ask for it again
(RTPS 2.5, section 8.4.15.5: a reliable reader requests the missing sequence numbers only
when a HEARTBEAT says they exist). Over a 1 % lossy 5 ms link the default stopped three real-time
runs of three at 0.4-1.2 s (a builder's 20 ms watchdog), the 50 ms period completed all three.

The profile also gives every socket a participant listens on a receive buffer of
:data:`RECEIVE_BUFFER_BYTES` instead of the system's default (208 KiB on Linux: about 35 ms of
a busy host's traffic). A process that falls behind for longer loses what arrives meanwhile,
and DDS must resend it: on the three-host bridge on one 2-core machine the recorder's host
overflowed its buffers 500-560 times in a run and, when a link was cut, lost a lab's samples
from 0.1-0.2 s on for good (2 runs of 4); with 4 MiB none overflowed (4 runs of 4). The
kernel caps the size at ``net.core.rmem_max`` without an error. It applies where rmw_fastrtps
uses Fast DDS's own UDP transport (``ROS_AUTOMATIC_DISCOVERY_RANGE`` SUBNET, as between
hosts); with LOCALHOST it sets up a transport of its own that keeps the system's buffers (a
run on one host goes over shared memory).

A new participant announces itself :data:`INITIAL_ANNOUNCEMENTS` times, every
:data:`INITIAL_ANNOUNCEMENT_PERIOD_S` (2 s; Fast DDS's default is 5 every 0.1 s, then one
every 3 s). The processes of a graph start within a second or two of each other, and one that
opens its ports after another's initial announcements are over learns of it only at the next
periodic one: ``seft run`` heard its five nodes' first reports 3.2 s after starting them
(6.4 s at times), and 1.0-1.5 s with the longer announcements (5 runs of 5).

A file the user names in the environment is kept (theirs wins); other middlewares ignore the
variable.
"""

import os
from pathlib import Path

from seft_msgs_py.errors import SeftError

__all__ = ['PROFILE_ENV', 'HEARTBEAT_PERIOD_S', 'RECEIVE_BUFFER_BYTES',
           'INITIAL_ANNOUNCEMENTS', 'INITIAL_ANNOUNCEMENT_PERIOD_S', 'DISCOVERY_SETTLE_S',
           'profile_path',
           'use_seft_profile']

#: The variable Fast DDS 2.x reads its default XML profiles from.
PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
#: A reliable writer's periodic heartbeat in seft's profile [s] (Fast DDS's default: 3 s).
HEARTBEAT_PERIOD_S = 0.05
#: The receive buffer seft's profile asks for on every listening socket [bytes].
RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024
#: How many times a new participant announces itself before its periodic announcements.
INITIAL_ANNOUNCEMENTS = 10
#: The period of those initial announcements [s].
INITIAL_ANNOUNCEMENT_PERIOD_S = 0.2
#: How long after a node of the graph was first heard (its parameters, sent once its
#: participant exists) a real-time run waits before its sample 0: the participants' initial
#: announcements are over by then (:data:`INITIAL_ANNOUNCEMENTS` every
#: :data:`INITIAL_ANNOUNCEMENT_PERIOD_S`, and 0.2 s more) [s]. Measured: on one 2-core host
#: the study's graph in real time was stopped by a 20 ms input watchdog in its first 0.35 s
#: in 2 of 10, 3 of 12 and 3 of 15 runs, a node's real-time thread blocked for 21 to more
#: than 150 ms inside a publish: its writer's lock held by a Fast DDS receive thread that
#: was opening another process's shared-memory port (a named inter-process mutex,
#: ``SharedMemGlobal::open_port_internal``), while the processes still announced
#: themselves. With Fast DDS's own 5 announcements in 0.5 s (over before sample 0), 15 runs
#: of 15 completed; so did those started after this wait (each start 2.1 s later). A window
#: of 1 s (10 every 0.1 s, a 1.2 s wait) also gave 15 of 15, but under the test suite's load
#: ``seft run`` then heard a lockstep graph 6.2 s after its start (two periodic
#: announcements late), after the run was over: the 2 s stay.
DISCOVERY_SETTLE_S = INITIAL_ANNOUNCEMENTS * INITIAL_ANNOUNCEMENT_PERIOD_S + 0.2


def profile_path() -> Path:
    """The Fast DDS profile seft ships (an XML file beside this module)."""
    return Path(__file__).with_name('fastdds_profile.xml')


def use_seft_profile(environ=None) -> str:
    """Name seft's Fast DDS profile in `environ` unless a profile is named there already.

    Call it before the process creates its first DDS participant (``rclpy.init`` and the
    first node); processes started later with a copy of `environ` inherit it.

    Parameters
    ----------
    environ : MutableMapping[str, str], optional
        The environment to set (default ``os.environ``).

    Returns
    -------
    str
        The profile file in effect (the user's, or seft's).

    Raises
    ------
    SeftError
        seft's profile is to be used and its file is missing (a broken install).
    """
    env = os.environ if environ is None else environ
    if PROFILE_ENV not in env:
        path = profile_path()
        if not path.is_file():
            raise SeftError(f"{path}: seft's Fast DDS profile is missing (a broken install of "
                            'seft_msgs_py: install it again)')
        env[PROFILE_ENV] = str(path)
    return env[PROFILE_ENV]
