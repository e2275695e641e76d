"""
Real-time scheduling for the fixed-rate (``free_run``) loop: SCHED_FIFO for a whole process.

A node on the critical path that runs as its own process in ``free_run`` moves every thread of its
process (the executor, the plant's clock thread, the middleware's receive threads) to the
``SCHED_FIFO`` class at ``priority`` (1-99): a runnable thread of that class preempts any ordinary
process, so a busy neighbour can no longer make the loop miss its deadlines (measured in
``docs/architecture.md``, "Real-time fixed rate"). Threads created later inherit the class from
their creator. The kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``,
95 % by default) keeps a runaway real-time thread from freezing the machine.

It needs the right to raise the scheduling class: root, ``CAP_SYS_NICE``, or an ``rtprio`` limit
(``ulimit -r``, ``/etc/security/limits.conf``: ``@realtime - rtprio 80``). Without it
:func:`enter` says so in one line and the loop runs with ordinary scheduling — reported, never
silent.
"""
from __future__ import annotations

import gc
import os
from typing import List, Optional, Tuple

#: The priority the critical nodes ask for in free_run (below the kernel's own threads at 99).
DEFAULT_PRIORITY = 50


def _threads() -> List[int]:
    try:
        return [int(t) for t in os.listdir('/proc/self/task')]
    except OSError:
        return [0]


def describe() -> str:
    """Return this thread's scheduling: ``fifo:50`` or ``normal``."""
    try:
        policy = os.sched_getscheduler(0)
        if policy == os.SCHED_FIFO:
            return f'fifo:{os.sched_getparam(0).sched_priority}'
    except (AttributeError, OSError):
        pass
    return 'normal'


def enter(priority: int = DEFAULT_PRIORITY) -> Tuple[bool, str]:
    """
    Move every thread of this process to SCHED_FIFO at ``priority``.

    Returns (True, 'fifo:P') or (False, reason) — the reason names what to grant.
    """
    if not 1 <= int(priority) <= 99:
        return False, f'real-time priority {priority} is outside 1..99'
    if not hasattr(os, 'sched_setscheduler'):
        return False, 'this platform has no SCHED_FIFO'
    param = os.sched_param(int(priority))
    failed: Optional[OSError] = None
    moved = 0
    for tid in _threads():
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            moved += 1
        except ProcessLookupError:          # a thread that just ended
            continue
        except OSError as exc:
            failed = exc
            break
    if failed is not None:
        leave()
        return False, (f'SCHED_FIFO priority {priority} refused ({failed.strerror}): grant it '
                       f'with CAP_SYS_NICE or an rtprio limit (ulimit -r {priority}; '
                       f'/etc/security/limits.conf "<user> - rtprio {priority}")')
    return True, f'fifo:{priority}'


def quiet_gc() -> None:
    """
    Shorter garbage-collection pauses in the loop.

    Everything allocated before the run (modules, the node, the middleware's objects) moves to
    the permanent generation, so a full collection during the run only walks what the run
    itself allocated. Collection stays on: memory stays bounded however long the run.
    """
    gc.collect()
    gc.freeze()


def leave() -> None:
    """Every thread of this process back to ordinary scheduling."""
    if not hasattr(os, 'sched_setscheduler'):
        return
    for tid in _threads():
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            continue
