"""Forked worker processes: when the toolkit may start them (the log reader's decode workers,
sensors/mcap_log.py; the smoother's parallel segments, fusion/segments.py).

Workers are forked, never spawned: a spawned worker would import the caller's main script again
and every module anew, and forking lets a worker read the parent's arrays without copying them.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import signal
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


def run_forked(task: Callable[[int], Any], n: int) -> list[Any]:
    """``[task(0), ..., task(n - 1)]``, each call in its own forked process, all at once.

    ``task`` runs in the child with the parent's memory as it was at the fork (nothing of the
    parent is pickled); only its return value travels back, pickled through a pipe (keep it to
    numpy arrays and plain data). An exception raised in a child is raised here, the same
    class with the same message (a :class:`~trackfusion.errors.TrackfusionError` stays one);
    the first one to arrive wins, and the other children are then terminated. A child that dies
    without an answer (killed, out of memory) raises :class:`RuntimeError`. Every child has
    exited when this returns or raises.
    """
    ctx = fork_context()
    procs, conns = [], []
    try:
        for i in range(n):
            reader, writer = ctx.Pipe(duplex=False)
            p = ctx.Process(target=_child, args=(task, i, writer, os.getpid()), name=f"trackfusion-worker-{i}", daemon=True)
            p.start()
            writer.close()  # the child's end: EOF here once the child is gone
            procs.append(p)
            conns.append(reader)
        results: dict[int, Any] = {}
        waiting = dict(zip(conns, range(n)))
        while waiting:
            for conn in multiprocessing.connection.wait(list(waiting)):
                i = waiting.pop(conn)
                try:
                    ok, value = conn.recv()
                except EOFError:
                    procs[i].join()
                    raise RuntimeError(f"worker process {i} died without a result "
                                       f"(exit code {procs[i].exitcode})") from None
                if not ok:
                    raise value
                results[i] = value
        return [results[i] for i in range(n)]
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join()
        for conn in conns:
            conn.close()


def _die_with_parent(parent_pid: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux ``PR_SET_PDEATHSIG``): a
    parent killed by a signal runs no clean-up, and its workers would be left running."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:  # the parent died before the call
        os._exit(1)


def _child(task: Callable[[int], Any], i: int, conn, parent_pid: int) -> None:
    _die_with_parent(parent_pid)
    try:
        answer = (True, task(i))
    except BaseException as exc:  # noqa: BLE001 -- every failure goes to the parent
        answer = (False, exc)
    try:
        conn.send(answer)
    except Exception as exc:  # noqa: BLE001 -- an answer that does not pickle
        conn.send((False, RuntimeError(f"worker process {i}: {type(exc).__name__}: {exc}")))
    conn.close()
