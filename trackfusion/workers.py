"""Forked worker processes: when the toolkit may start them (the log reader's decode workers,
sensors/mcap_log.py; the smoother's parts, trackfusion/parallel.py).

Workers are forked, never spawned: a spawned worker would import the caller's main script again
and every module anew, and forking lets a worker read the parent's arrays without copying them.
"""

from __future__ import annotations

import multiprocessing
import os


def usable_cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0))


def can_fork(workers: int) -> bool:
    """True when ``workers`` (>= 2) forked worker processes are worth starting here: two CPUs or
    more, ``fork`` available, and not inside a worker process already (e.g. ``trackfusion batch``'s,
    or a pool's daemonic worker, which may not have children)."""
    return (workers >= 2 and usable_cpus() >= 2 and multiprocessing.parent_process() is None
            and "fork" in multiprocessing.get_all_start_methods())


def fork_context():
    """The ``fork`` multiprocessing context."""
    return multiprocessing.get_context("fork")

