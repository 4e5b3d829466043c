"""Real-time scheduling of a seft process: SCHED_FIFO for every thread (no rclpy).

The nodes of a real-time run, the checker of ``seft rig-check``, the link emulator's hub and
the UDP controller emulator each run under SCHED_FIFO at their own priority where the system
allows it (root, CAP_SYS_NICE or an RT budget); each says in its own words what it does when
refused. This is the one call they share.
"""

import os

__all__ = ['set_fifo']


def set_fifo(priority: int, *, reset_on_fork: bool = False) -> int:
    """Run every thread of this process under SCHED_FIFO `priority`.

    Every thread, not only the calling one: the middleware's receive threads exist already
    (they deliver the samples; at the normal priority they would delay them), and threads
    created later inherit the policy.

    Parameters
    ----------
    priority : int
        SCHED_FIFO priority, clipped to 1-99.
    reset_on_fork : bool
        Children started later do not inherit it (``SCHED_RESET_ON_FORK``: a process that
        starts nodes which take their own priorities).

    Returns
    -------
    int
        The priority set (1-99).

    Raises
    ------
    OSError
        The system refused (no privilege, no RT budget).
    AttributeError
        The platform has no ``os.sched_setscheduler``.

    References
    ----------
    sched(7), the Linux manual page: SCHED_FIFO, SCHED_RESET_ON_FORK.
    """
    priority = max(1, min(99, int(priority)))
    policy = os.SCHED_FIFO | (os.SCHED_RESET_ON_FORK if reset_on_fork else 0)
    for tid in os.listdir('/proc/self/task'):
        os.sched_setscheduler(int(tid), policy, os.sched_param(priority))
    return priority
