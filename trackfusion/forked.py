"""This process's own concurrency: its forked children, its pool of forked workers and its
threads. With trackfusion/parallel.py (the smoother's part workers, ``trackfusion batch``'s
surveys, Dask) the only module that forks, starts pools or threads, or imports
``multiprocessing``, ``concurrent.futures`` or ``threading`` (tests/test_layout.py).

The toolkit's forked child processes: when they may be started (:func:`can_fork`, for every
user: the log read ahead by ``trackfusion run``, trackfusion/log_read.py; the log reader's decode
workers, sensors/mcap_log.py; the smoother's parts,
trackfusion/parallel.py; the densification, fusion/densify_forked.py; the outputs, report/outputs.py;
vision), and work done in forked children while this process goes on (a run's outputs on the
second core).

Children are forked, never spawned: a spawned one would import the caller's main script again
and every module anew, and forking lets a child read the parent's arrays without copying them.

:class:`ForkedTasks` runs functions in children forked from this process (they see its memory as it
was at the fork, copy-on-write, and send their return value back: its arrays through an in-memory
file that this process then maps, the rest through a pipe); :meth:`wait`
takes the results in the order submitted and raises the first failure in this process: the
child's exception itself (a :class:`~trackfusion.errors.TrackfusionError` stays one, so the
command line still exits with code 2 and its one line), or :class:`ForkedTaskError` when a child
died without an answer (killed, out of memory: exit code 1, not the input's fault). Leaving the
``with`` block on an exception kills and reaps the children still running, so no child outlives
a failed run.

Without ``fork``, with fewer than 2 CPUs, inside a forked child or a worker process (e.g. of
``trackfusion batch``, which runs surveys side by side already), or with :data:`ENABLED` False,
every function runs at once in this process (the same results and errors, in turn).

:class:`ForkedPool` keeps a pool of forked workers for batches handed out while this process goes
on (the log reader's decoding); :func:`thread_map` runs a function that releases the GIL (zstd
compression) on two threads, results in order; :func:`other_threads_running` tells whether an
exit must wait for threads; :func:`one_blas_thread` holds BLAS to one thread while the work is
one process per CPU.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import mmap
import multiprocessing
import os
import pickle
import signal
import threading
import traceback
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, TypeVar

if TYPE_CHECKING:  # (concurrent.futures is imported when a pool is used: not at the command line's start)
    from concurrent.futures import Future, ProcessPoolExecutor

from .errors import TrackfusionError, WorkerDied

#: False: run every task in this process, in turn (e.g. to compare timings)
ENABLED = True
_IN_CHILD = False


class ForkedTaskError(WorkerDied):
    """A forked child died without handing back its result (exit code 1 on the command line)."""


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
        self._buffers_fd: int | None = None  # the answer's arrays (:func:`_answer_buffers_fd`)
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
        try:
            if not chunks or os.WIFSIGNALED(status) or os.WEXITSTATUS(status) != 0:
                how = (f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status)
                       else f"exit code {os.WEXITSTATUS(status)}")
                self._settle(error=ForkedTaskError(f"{self.what}: the forked child process died ({how})"))
                return
            try:
                ok, payload = _answer(b"".join(chunks), self._buffers_fd)
            except Exception as exc:  # noqa: BLE001 (e.g. an exception class that does not unpickle)
                self._settle(error=ForkedTaskError(f"{self.what}: unreadable answer of the child ({exc})"))
                return
            self._settle(value=payload) if ok else self._settle(error=payload)
        finally:
            self._close_buffers()

    def _kill(self) -> None:
        if self.pid is not None:
            os.kill(self.pid, signal.SIGKILL)
            os.close(self._fd)
            os.waitpid(self.pid, 0)
            self.pid = None
            self._close_buffers()
            self._settle(error=ForkedTaskError(f"{self.what}: stopped"))

    def _close_buffers(self) -> None:
        if self._buffers_fd is not None:
            _ANSWER_FDS.discard(self._buffers_fd)
            os.close(self._buffers_fd)
            self._buffers_fd = None


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
        buffers_fd = _answer_buffers_fd()
        gc.freeze()  # the child's collector leaves this process's objects (and their pages) alone
        parent_pid = os.getpid()
        global _KEPT_ANSWER_FD
        _KEPT_ANSWER_FD = buffers_fd  # the one answer file the child keeps (:func:`_drop_answer_fds`)
        try:
            pid = os.fork()
        finally:
            _KEPT_ANSWER_FD = None
        if pid == 0:  # pragma: no cover (runs in the child; covered through its answers)
            _die_with_parent(parent_pid)
            _child(read_fd, write_fd, buffers_fd, (fn, args, kwargs))
        gc.unfreeze()
        os.close(write_fd)
        task.pid, task._fd, task._buffers_fd = pid, read_fd, buffers_fd
        return task

    def submit_idle(self, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> ForkedTask:
        """:meth:`submit` for work that should take only the CPU time the run leaves free: the
        child runs at the lowest priority (``nice`` 19); run here (no fork), at this process's."""
        return self.submit(what, _at_lowest_priority, os.getpid(), fn, *args, **kwargs)

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


@contextlib.contextmanager
def as_leading_child() -> Iterator[None]:
    """In a forked child that does its parent's main work while the parent only prepares (the log
    read ahead, trackfusion/log_read.py): :func:`can_fork` as in the main process for the block,
    so that the child may start its own workers (the reader's decode workers of a JSON log)."""
    global _IN_CHILD
    was, _IN_CHILD = _IN_CHILD, False
    try:
        yield
    finally:
        _IN_CHILD = was


def _at_lowest_priority(submitter_pid: int, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)``, in a child of the process ``submitter_pid`` at the lowest priority."""
    if os.getpid() != submitter_pid:
        os.nice(19)
    return fn(*args, **kwargs)


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


def _child(read_fd: int, write_fd: int, buffers_fd: int | None, call: tuple[Callable, tuple, dict]) -> None:
    """The forked child: run ``call`` (function, args, kwargs), send (ok, value or exception)
    (:func:`_pickled_answer`) and leave without any clean-up of the parent's state (no atexit
    handlers, no buffered output of the parent flushed twice)."""
    global _IN_CHILD
    _IN_CHILD = True
    code = 0
    try:
        os.close(read_fd)
        fn, args, kwargs = call
        try:
            answer = (True, fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 (handed to the parent)
            if not isinstance(exc, TrackfusionError):  # an internal error: where it happened
                exc.add_note("in a forked child:\n" + traceback.format_exc().rstrip())
            answer = (False, exc)
        _write_all(write_fd, _pickled_answer(answer, buffers_fd))
        os.close(write_fd)
    except BaseException:  # noqa: BLE001
        code = 1
    finally:
        os._exit(code)


#: the answer buffers' files of the tasks still running (closed in every other child)
_ANSWER_FDS: set[int] = set()
#: the answer file a task's child keeps across its fork (every other process forked drops them all)
_KEPT_ANSWER_FD: int | None = None


def _drop_answer_fds() -> None:
    """In every child forked from this process (a task's, a worker of the smoother's parts or of
    a :class:`ForkedPool`): close the running tasks' answer files but the child's own, so that no
    other process holds an answer's memory after this process has taken it."""
    for fd in _ANSWER_FDS - {_KEPT_ANSWER_FD}:
        try:
            os.close(fd)
        except OSError:
            pass
    _ANSWER_FDS.intersection_update({_KEPT_ANSWER_FD})


os.register_at_fork(after_in_child=_drop_answer_fds)
#: alignment [bytes] of each array in an answer's buffer file
_BUFFER_ALIGN = 64


def _answer_buffers_fd() -> int | None:
    """An anonymous in-memory file (``memfd_create``) for a child's answer's arrays, made before
    the fork so that both processes hold it; None where there is none (the answer then goes
    whole through the pipe). Why: 100 MB of arrays take 0.3-0.5 s through a pipe (the log read
    ahead, trackfusion/log_read.py), 0.05 s through the file, mapped with no copy."""
    try:
        fd = os.memfd_create("trackfusion-answer")
    except (AttributeError, OSError):
        return None
    _ANSWER_FDS.add(fd)
    return fd


def _write_all(fd: int, data: bytes | memoryview) -> None:
    view = memoryview(data).cast("B")
    while view:
        view = view[os.write(fd, view):]


def _pickled_answer(answer: tuple[bool, Any], buffers_fd: int | None) -> bytes:
    """What a child sends through its pipe: the pickle of (``answer``'s pickle, the layout
    [(offset, bytes)] of its out-of-band arrays written to ``buffers_fd``). Protocol 5's
    out-of-band buffers (numpy's contiguous arrays) go to ``buffers_fd``, each at an offset
    aligned to :data:`_BUFFER_ALIGN`; without the file, everything is in the pickle."""
    buffers: list[pickle.PickleBuffer] = []
    try:
        data = pickle.dumps(answer, protocol=5, buffer_callback=buffers.append if buffers_fd is not None else None)
    except Exception:  # noqa: BLE001 (an exception that does not pickle: its type and message)
        err = answer[1] if not answer[0] else TypeError("unpicklable result")
        data, buffers = pickle.dumps((False, RuntimeError(f"{type(err).__name__}: {err}"))), []
    layout, at = [], 0
    for buffer in buffers:
        raw = buffer.raw()
        pad = -at % _BUFFER_ALIGN
        if pad:
            _write_all(buffers_fd, bytes(pad))
        _write_all(buffers_fd, raw)
        layout.append((at + pad, raw.nbytes))
        at += pad + raw.nbytes
    return pickle.dumps((data, layout), protocol=5)


def _answer(sent: bytes, buffers_fd: int | None) -> tuple[bool, Any]:
    """The (ok, value or exception) a child sent (:func:`_pickled_answer`): its arrays map the
    buffer file (private, copy-on-write: writable, and the file is never changed)."""
    data, layout = pickle.loads(sent)
    if not layout:
        return pickle.loads(data)
    size = layout[-1][0] + layout[-1][1]
    view = memoryview(mmap.mmap(buffers_fd, size, flags=mmap.MAP_PRIVATE, prot=mmap.PROT_READ | mmap.PROT_WRITE)
                      if size else bytearray())
    return pickle.loads(data, buffers=[view[at:at + n] for at, n in layout])


def fork_map(what: str, fn: Callable[[_T], _R], items: list[_T]) -> list[_R]:
    """``[fn(x) for x in items]``: the items after the first each in a forked child while this
    process computes the first (in turn where :func:`can_fork` says no; the same values either
    way). ``what`` names the work in error messages; a child's exception is raised here."""
    if len(items) < 2 or not can_fork(len(items)):
        return [fn(x) for x in items]
    with ForkedTasks() as tasks:
        rest = [tasks.submit(what, fn, x) for x in items[1:]]
        first = fn(items[0])
        return [first, *(task.result() for task in rest)]


class ForkedPool:
    """``workers`` forked worker processes (a ``concurrent.futures`` pool, forked at the first
    :meth:`submit`: a spawned worker would import the caller's main script again, and every import
    anew) for work handed out while this process goes on; at most ``max_in_flight`` submitted
    calls are pending at once. Where :func:`can_fork` says no for ``workers``, where the pool
    cannot be started, or once a worker has died (e.g. out of memory), every call runs here, in
    turn. :meth:`close` ends the pool."""

    def __init__(self, workers: int, max_in_flight: int):
        self.workers = workers
        self.max_in_flight = max_in_flight
        self.pool: ProcessPoolExecutor | None = None
        self.in_flight: collections.deque[Future] = collections.deque()
        self.parallel = can_fork(workers)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        """A future of ``fn(*args)`` run in a worker (``fn`` and ``args`` picklable), or its value
        when run here (class docstring); :func:`result_of` takes either. Waits while more than
        ``max_in_flight`` futures are pending."""
        import concurrent.futures
        from concurrent.futures.process import BrokenProcessPool
        if self.parallel and self.pool is None:
            try:
                self.pool = concurrent.futures.ProcessPoolExecutor(max_workers=self.workers, mp_context=fork_context())
            except (OSError, ValueError):
                self.parallel = False
        future = None
        if self.pool is not None:
            try:
                future = self.pool.submit(fn, *args)
            except (BrokenProcessPool, RuntimeError):  # a worker died (e.g. out of memory): go on here
                self.close()
                self.parallel = False
        if future is None:
            return fn(*args)
        self.in_flight.append(future)
        while len(self.in_flight) > self.max_in_flight:
            concurrent.futures.wait([self.in_flight.popleft()])
        return future

    def close(self) -> None:
        """Shut the workers down (pending calls cancelled); later calls fork a new pool."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None


def result_of(submitted: Any) -> Any:
    """The value of a :meth:`ForkedPool.submit`: its future's result (waited for; raises the
    call's exception), or the value itself when it was run here."""
    from concurrent.futures import Future
    return submitted.result() if isinstance(submitted, Future) else submitted


_T = TypeVar("_T")
_R = TypeVar("_R")


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS (numpy's and scipy's OpenBLAS, as loaded now) on one thread in this process, and in
    the children it forks meanwhile, inside the ``with`` block; as before after it. For work done
    one process per CPU on small matrices, where BLAS's own threads only take CPU from the other
    processes: the sigma parts' pass down each tree (fusion/tree_marginals.py) took 3.3 s for a
    bridge part in two processes with BLAS's threads, against 0.56 s. (A whole run under
    ``OPENBLAS_NUM_THREADS=1`` measured 0-1 s faster on the bridge and the hour, within the
    machine's noise: not applied.)"""
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def thread_map(fn: Callable[[_T], _R], items: Iterable[_T], workers: int = 2) -> Iterator[tuple[_T, _R]]:
    """``(item, fn(item))`` for every item, in the order of ``items``, ``fn`` run on ``workers``
    threads (worth it for a function that releases the GIL, such as zstd compression). Every item
    is handed to the threads as it is drawn from ``items``, all of them before the first result is
    given; leaving the loop early waits for the calls already started."""
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = [(item, pool.submit(fn, item)) for item in items]
        for item, future in pending:
            yield item, future.result()


def other_threads_running() -> bool:
    """True while a thread other than this process's main one is alive."""
    return threading.active_count() > 1
