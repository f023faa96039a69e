"""The toolkit's forked child processes: when they may be started (:func:`can_fork`, for every
user: the log reader's decode workers, sensors/mcap_log.py; the smoother's parts,
trackfusion/parallel.py; the densification, fusion/densify_forked.py; the outputs, report/outputs.py;
vision), and work done in forked children while this process goes on (a run's outputs on the
second core).

Children are forked, never spawned: a spawned one would import the caller's main script again
and every module anew, and forking lets a child read the parent's arrays without copying them.

:class:`ForkedTasks` runs functions in children forked from this process (they see its memory as it
was at the fork, copy-on-write, and send their return value back through a pipe); :meth:`wait`
takes the results in the order submitted and raises the first failure in this process: the
child's exception itself (a :class:`~trackfusion.errors.TrackfusionError` stays one, so the
command line still exits with code 2 and its one line), or :class:`ForkedTaskError` when a child
died without an answer (killed, out of memory). Leaving the ``with`` block on an exception kills
and reaps the children still running, so no child outlives a failed run.

Without ``fork``, with fewer than 2 CPUs, inside a forked child or a worker process (e.g. of
``trackfusion batch``, which runs surveys side by side already), or with :data:`ENABLED` False,
every function runs at once in this process (the same results and errors, in turn).
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import pickle
import signal
import traceback
from typing import Any, Callable

from .errors import TrackfusionError

#: False: run every task in this process, in turn (e.g. to compare timings)
ENABLED = True
_IN_CHILD = False


class ForkedTaskError(TrackfusionError):
    """A forked child died without handing back its result."""


def usable_cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0))


def can_fork(workers: int = 2) -> bool:
    """True when ``workers`` (>= 2) forked processes (this one among them) are worth starting
    here: :data:`ENABLED`, two CPUs or more, ``fork`` available, and not inside a forked child
    or a worker process already (e.g. ``trackfusion batch``'s, or a pool's daemonic worker,
    which may not have children)."""
    return (ENABLED and not _IN_CHILD and workers >= 2 and usable_cpus() >= 2
            and multiprocessing.parent_process() is None and "fork" in multiprocessing.get_all_start_methods())


def fork_context():
    """The ``fork`` multiprocessing context."""
    return multiprocessing.get_context("fork")


class ForkedTask:
    """One submitted function: its result once :meth:`result` has waited for it."""

    def __init__(self, what: str):
        self.what = what
        self.pid: int | None = None
        self._fd: int | None = None
        self._done = False
        self._value: Any = None
        self._error: BaseException | None = None
        self._then: list[Callable[[Any], None]] = []

    def then(self, callback: Callable[[Any], None], otherwise: Callable[[], None] | None = None) -> None:
        """Call ``callback(result)`` in this process once the task has succeeded, or ``otherwise()``
        once it has failed or been stopped (at once when it is already done)."""
        if self._done:
            callback(self._value) if self._error is None else (otherwise and otherwise())
        else:
            self._then.append((callback, otherwise))

    def result(self) -> Any:
        """The function's return value (waits for the child); raises its exception."""
        if not self._done:
            self._collect()
        if self._error is not None:
            raise self._error
        return self._value

    def _settle(self, value: Any = None, error: BaseException | None = None) -> None:
        self._done, self._value, self._error = True, value, error
        callbacks, self._then = self._then, []
        for callback, otherwise in callbacks:
            if error is None:
                callback(value)
            elif otherwise is not None:
                otherwise()

    def _collect(self) -> None:
        chunks = []
        while True:  # the whole answer before waitpid: a child blocked on a full pipe never exits
            data = os.read(self._fd, 1 << 20)
            if not data:
                break
            chunks.append(data)
        os.close(self._fd)
        _, status = os.waitpid(self.pid, 0)
        self.pid = None
        if not chunks or os.WIFSIGNALED(status) or os.WEXITSTATUS(status) != 0:
            how = (f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status)
                   else f"exit code {os.WEXITSTATUS(status)}")
            self._settle(error=ForkedTaskError(f"{self.what}: the forked child process died ({how})"))
            return
        try:
            ok, payload = pickle.loads(b"".join(chunks))
        except Exception as exc:  # noqa: BLE001 (e.g. an exception class that does not unpickle)
            self._settle(error=ForkedTaskError(f"{self.what}: unreadable answer of the child ({exc})"))
            return
        self._settle(value=payload) if ok else self._settle(error=payload)

    def _kill(self) -> None:
        if self.pid is not None:
            os.kill(self.pid, signal.SIGKILL)
            os.close(self._fd)
            os.waitpid(self.pid, 0)
            self.pid = None
            self._settle(error=ForkedTaskError(f"{self.what}: stopped"))


class ForkedTasks:
    """Functions run in forked children (module docstring); use as a context manager."""

    def __init__(self, always_fork: bool = False):
        """``always_fork``: fork even where :func:`can_fork` says no (the caller has decided)."""
        self.tasks: list[ForkedTask] = []
        self.always_fork = always_fork

    def submit(self, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> ForkedTask:
        """Run ``fn(*args, **kwargs)`` in a forked child (here when :func:`can_fork` is False);
        ``what`` names the work in error messages (e.g. ``"writing fused.mcap"``)."""
        task = ForkedTask(what)
        self.tasks.append(task)
        if not (self.always_fork or can_fork()):
            try:
                task._settle(value=fn(*args, **kwargs))
            except Exception as exc:  # noqa: BLE001 (raised by result(), as from a child)
                task._settle(error=exc)
            return task
        read_fd, write_fd = os.pipe()
        gc.freeze()  # the child's collector leaves this process's objects (and their pages) alone
        parent_pid = os.getpid()
        pid = os.fork()
        if pid == 0:  # pragma: no cover (runs in the child; covered through its answers)
            _die_with_parent(parent_pid)
            _child(read_fd, write_fd, fn, args, kwargs)
        gc.unfreeze()
        os.close(write_fd)
        task.pid, task._fd = pid, read_fd
        return task

    def wait(self) -> None:
        """Wait for every task; raises the first failure (in the order submitted)."""
        first = None
        for task in self.tasks:
            try:
                task.result()
            except BaseException as exc:  # noqa: BLE001 (the others are still waited for)
                first = first or exc
        self.tasks = []
        if first is not None:
            raise first

    def kill(self) -> None:
        """Stop and reap every child still running."""
        for task in self.tasks:
            task._kill()
        self.tasks = []

    def __enter__(self) -> "ForkedTasks":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.kill()
        else:
            self.wait()


def _die_with_parent(parent_pid: int) -> None:
    """Have the kernel kill this (child) process when its parent dies (Linux ``PR_SET_PDEATHSIG``):
    a parent killed by a signal runs no clean-up, and its children would be left running."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:  # the parent died before the call
        os._exit(1)


def _child(read_fd: int, write_fd: int, fn: Callable, args: tuple, kwargs: dict) -> None:
    """The forked child: run ``fn``, send (ok, value or exception) and leave without any clean-up
    of the parent's state (no atexit handlers, no buffered output of the parent flushed twice)."""
    global _IN_CHILD
    _IN_CHILD = True
    code = 0
    try:
        os.close(read_fd)
        try:
            answer = (True, fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 (handed to the parent)
            if not isinstance(exc, TrackfusionError):  # an internal error: where it happened
                exc.add_note("in a forked child:\n" + traceback.format_exc().rstrip())
            answer = (False, exc)
        try:
            data = pickle.dumps(answer, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 (an exception that does not pickle: its type and message)
            err = answer[1] if not answer[0] else TypeError("unpicklable result")
            data = pickle.dumps((False, RuntimeError(f"{type(err).__name__}: {err}")))
        view = memoryview(data)
        while view:
            view = view[os.write(write_fd, view):]
        os.close(write_fd)
    except BaseException:  # noqa: BLE001
        code = 1
    finally:
        os._exit(code)
