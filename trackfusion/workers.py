"""Forked worker processes: when the toolkit may start them (the log reader's decode workers,
sensors/mcap_log.py; :func:`run_forked` for work beside an idle CPU, trackfusion/output_prefetch.py).

Workers are forked, never spawned: a spawned worker would import the caller's main script again
and every module anew, and forking lets a worker read the parent's arrays without copying them.
"""

from __future__ import annotations

import multiprocessing
import os
from typing import Any, Callable


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


def run_forked(task: Callable[[int], Any], n: int, while_waiting: Callable[[], None] | None = None) -> list[Any]:
    """``[task(0), ..., task(n - 1)]``, each call in its own forked child, all at once
    (:class:`trackfusion.forked.ForkedTasks`: the parent's memory as it was at the fork, nothing
    of it pickled; only the return value travels back through a pipe, so keep it to numpy arrays
    and plain data). The first failure in the order of ``i`` is raised here, the child's own
    exception (a :class:`~trackfusion.errors.TrackfusionError` stays one; a child that died
    without an answer: :class:`~trackfusion.forked.ForkedTaskError`), and the children still
    running are then killed. Every child has exited when this returns or raises.
    ``while_waiting()``: called here once the first child has finished, while the others still
    run (work for the CPU that child leaves idle; it must not raise).
    """
    from .forked import ForkedTasks, wait_first
    with ForkedTasks(always_fork=True) as tasks:
        handles = [tasks.submit(f"worker process {i}", task, i) for i in range(n)]
        if while_waiting is not None:
            wait_first(handles)
            while_waiting()
        return [h.result() for h in handles]
