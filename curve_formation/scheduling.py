"""A node process's scheduling, declared once: the SCHED_FIFO priority it may take (NORMAL:
normal scheduling, up to Linux's HIGHEST), the defaults of the controllers' processes and of
a robot bridge's writing thread, and taking it. No ROS here: the command line reads it too.
"""

import os
from pathlib import Path
from typing import Any


PARAMETER = 'realtime_priority'   # the parameter of a node that gives its priority
NORMAL = 0          # normal scheduling
HIGHEST = 99        # Linux's highest SCHED_FIFO priority (os.sched_get_priority_max)
# The controllers' processes (run --realtime-priority, their parameter): SCHED_FIFO, as
# ros2_control's controller manager takes it by default, so that a busy PC cannot hold their
# ticks up (docs/performance.md: 50 robots beside a busy program); below a bridge, whose
# writing thread comes first. Without the permission a process notes it and runs normally.
CONTROLLERS = 10
BRIDGE = 20         # a robot_bridge's thread that takes cmd_vel and writes the robot's lines


def priority_problem(value: Any) -> str | None:
    """What is wrong with `value` as a priority, or None."""
    if isinstance(value, bool) or not isinstance(value, int) or not NORMAL <= value <= HIGHEST:
        return (f'expected an integer from {NORMAL} (normal scheduling) to {HIGHEST}, '
                f'got {value!r}')
    return None


def realtime_priority(priority: int, thread: int = 0) -> str | None:
    """Schedule a thread of this process (its id; 0: the calling one) SCHED_FIFO at
    `priority` (1-99), so that processes woken around it (a busy PC's other nodes, the
    kernel's tty work) cannot delay what it does next; threads it starts later inherit it.
    Returns None, or why not (it needs root, CAP_SYS_NICE or an rtprio limit); priority 0
    leaves the thread as it is.
    """
    if priority <= NORMAL:
        return None
    try:
        os.sched_setscheduler(thread, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def realtime_process(priority: int) -> str | None:
    """realtime_priority for every thread this process has (e.g. the BLAS threads numpy's
    import starts) and so for every thread started from them later; None, or why not.
    """
    for thread in os.listdir('/proc/self/task'):
        why_not = realtime_priority(priority, int(thread))
        if why_not and Path(f'/proc/self/task/{thread}').exists():   # not one that ended
            return why_not
    return None
