"""Work spread over worker processes: the smoother's time parts (fusion/partitioned.py) in
forked children or on Dask, and ``trackfusion batch``'s surveys (batch.py) in a pool of spawned
processes or on Dask. With trackfusion/forked.py (this process's forked children, its forked
pool and threads) the only module that forks, starts pools or threads, or imports
``multiprocessing``, ``concurrent.futures``, ``threading``, ``dask`` or ``distributed``
(tests/test_layout.py).

The smoother's time parts on local workers: in one Gauss-Newton step with ``W`` workers, the
parts are dealt into ``W`` contiguous groups; group 0 is worked on in this process, each other
group in a child forked after the linearisation (it reads the linearised graph from the parent's
memory as it was at the fork, nothing of it pickled). A child reduces its parts and sends back
only their reduced factors on the separator, waits for the separator's solution, back-
substitutes its parts and sends back their steps, and exits. The numbers do not depend on ``W``:
each part is reduced and back-substituted the same way wherever it runs.

A child that dies (killed, out of memory) ends the step with :class:`PartWorkerDied` naming
its parts; every child has exited when a step returns or raises.

With ``smoother.engine: dask`` (:func:`run_step_dask`) each group goes to an actor on a worker
of a Dask cluster (:func:`dask_client`) instead: the same two halves, the parts' factors sent
to it, the actor keeping its eliminations in between.

A batch's surveys: :func:`completed_in_spawned_pool` runs them in spawned processes (a survey
imports the toolkit afresh, nothing of this process inherited), :func:`completed_on_dask` as
tasks of a client of :func:`open_dask`; both yield each outcome as soon as it is done.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import threading
from typing import Any, Callable, Iterator, Sequence

from .errors import WorkerDied
from .forked import can_fork, fork_context


class PartWorkerDied(WorkerDied):
    """A worker process of the smoother's parts ended without its answer (exit code 1 on the
    command line: not a fault of the input)."""


def groups_of(n_parts: int, workers: int) -> list[list[int]]:
    """The parts ``0 .. n_parts - 1`` in ``min(workers, n_parts)`` contiguous groups."""
    w = max(1, min(workers, n_parts))
    bounds = [round(i * n_parts / w) for i in range(w + 1)]
    return [list(range(bounds[i], bounds[i + 1])) for i in range(w)]


def _child(conn, reduce: Callable[[], Any], back_substitute: Callable[[Any], Any]) -> None:
    """A child's step: its answers as ``(True, value)``, or its exception as ``(False, exc)``."""
    try:
        try:
            conn.send_bytes(pickle.dumps((True, reduce())))
            given = pickle.loads(conn.recv_bytes())
            conn.send_bytes(pickle.dumps((True, back_substitute(given))))
        except Exception as exc:  # noqa: BLE001 (raised in the parent)
            conn.send_bytes(pickle.dumps((False, exc)))
    finally:
        conn.close()
        os._exit(0)


def _name(parts: list[int]) -> str:
    return f"part {parts[0] + 1}" if len(parts) == 1 else f"parts {parts[0] + 1}-{parts[-1] + 1}"


def run_step(groups: list[list[int]], reduce: Callable[[list[int]], Any],
             solve: Callable[[list[Any]], Any], back_substitute: Callable[[list[int], Any], Any]
             ) -> tuple[Any, list[Any], list[Any]]:
    """One step over ``groups`` of parts: ``reduce(group)`` per group (children for groups 1..),
    ``given = solve([reduced per group])`` here, ``back_substitute(group, given)`` per group.
    Returns ``(given, reduced per group, back-substituted per group)``. Without forking (one
    group, or :func:`~trackfusion.forked.can_fork` false) everything runs here in turn."""
    if len(groups) < 2 or not can_fork(len(groups)):
        reduced = [reduce(g) for g in groups]
        given = solve(reduced)
        return given, reduced, [back_substitute(g, given) for g in groups]
    ctx = fork_context()
    children = []
    try:
        with _sigint_deferred():  # a Ctrl-C while forking must not leave a child unknown to the finally
            for g in groups[1:]:
                parent_end, child_end = ctx.Pipe()
                proc = ctx.Process(target=_child, args=(child_end, lambda g=g: reduce(g),
                                                        lambda given, g=g: back_substitute(g, given)), daemon=True)
                proc.start()
                child_end.close()
                children.append((g, proc, parent_end))
        reduced = [reduce(groups[0])] + [_receive(g, proc, conn) for g, proc, conn in children]
        given = solve(reduced)
        payload = pickle.dumps(given)
        for g, proc, conn in children:
            _send(g, proc, conn, payload)
        done = [back_substitute(groups[0], given)] + [_receive(g, proc, conn) for g, proc, conn in children]
        return given, reduced, done
    finally:
        for _, proc, conn in children:
            conn.close()
            if proc.is_alive():
                proc.kill()
            proc.join()


class PartQueue:
    """The indices ``0 .. n - 1``, each handed out once to whichever process asks next: this
    process and the children forked after the queue was made (a counter in shared memory under
    its lock). For work whose parts cost unequal time (the sigma parts' trees): each process takes
    the next part when it is done with its last, instead of a fixed group. What a part gives does
    not depend on which process computed it, so the numbers are the same."""

    def __init__(self, n: int):
        self.n = n
        self._next = fork_context().Value("l", 0)

    def __iter__(self) -> Iterator[int]:
        while True:
            with self._next.get_lock():
                i = self._next.value
                self._next.value = i + 1
            if i >= self.n:
                return
            yield i


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """SIGINT held back while the block runs (only in the main thread, where Python runs signal
    handlers), then handed to the handler that was in place: a KeyboardInterrupt raised in the
    middle of ``Process.start`` would leave a forked child that no one kills."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pending and callable(previous):
        previous(signal.SIGINT, None)


def _died(group: list[int], proc) -> PartWorkerDied:
    proc.join(timeout=5.0)
    code = proc.exitcode
    how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
    return PartWorkerDied(f"the smoother's worker process of {_name(group)} died ({how})")


#: how often [s] a wait for a child's answer returns to Python, so that a Ctrl-C (SIGINT) the
#: kernel delivered to another thread of this process (GTSAM's, a library's) is acted on at once
POLL_S = 0.1
#: how long [s] a Dask client tries to reach ``smoother.address`` before the run ends with exit 2
SCHEDULER_TIMEOUT_S = 30.0


def _receive(group: list[int], proc, conn) -> Any:
    try:
        while not conn.poll(POLL_S):  # (a closed pipe polls ready: recv_bytes raises EOFError)
            pass
        ok, value = pickle.loads(conn.recv_bytes())
    except (EOFError, OSError):
        raise _died(group, proc) from None
    if not ok:
        raise value
    return value


def _send(group: list[int], proc, conn, payload: bytes) -> None:
    try:
        conn.send_bytes(payload)
    except (BrokenPipeError, OSError):
        raise _died(group, proc) from None


_CLIENTS: dict = {}


def open_dask_client(address: str | None, workers: int, engine_key: str, address_key: str):
    """A new Dask ``(client, cluster)``: of the scheduler at ``address`` (``cluster`` None), else of
    a ``distributed.LocalCluster`` of ``workers`` single-threaded processes. Raises
    :class:`~trackfusion.errors.ConfigError` (exit 2) naming ``engine_key`` when Dask is missing,
    ``address_key`` when the scheduler cannot be reached; shared by ``smoother.engine: dask`` and
    ``trackfusion batch --engine dask``."""
    from .errors import ConfigError
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError(f"{engine_key}: Dask is not installed (pip install 'trackfusion[distributed]')") from None
    cluster = None
    try:
        if address is None:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                                   scheduler_kwargs={"dashboard": False})  # its HTTP server on a free port
            return Client(cluster), cluster
        return Client(address, timeout=SCHEDULER_TIMEOUT_S), None
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise ConfigError(f"{address_key} {address}: cannot reach the Dask scheduler ({exc})") from None


def dask_client(address: str | None, workers: int):
    """The Dask client of ``smoother.engine: dask`` (:func:`open_dask_client`): one per process and
    configuration, closed at exit."""
    import atexit
    if (address, workers) in _CLIENTS:
        return _CLIENTS[(address, workers)][0]
    client, cluster = open_dask_client(address, workers, "smoother.engine: dask", "smoother.address")
    _CLIENTS[(address, workers)] = (client, cluster)
    if len(_CLIENTS) == 1:
        atexit.register(close_dask_clients)
    return client


def close_dask_clients() -> None:
    """Close every client (and local cluster) :func:`dask_client` opened."""
    while _CLIENTS:
        _, (client, cluster) = _CLIENTS.popitem()
        _close(client, cluster)


def _close(client, cluster) -> None:
    client.close()
    if cluster is not None:
        cluster.close()


@contextlib.contextmanager
def open_dask(address: str | None, workers: int, engine_key: str, address_key: str) -> Iterator[Any]:
    """The client of :func:`open_dask_client` for the ``with`` block, closed (and its local
    cluster) when the block ends."""
    client, cluster = open_dask_client(address, workers, engine_key, address_key)
    try:
        yield client
    finally:
        _close(client, cluster)


#: one call's end: (its index among the calls, its value or None, the exception it raised or None)
Completed = tuple[int, Any, "Exception | None"]


def _outcome(index: int, future) -> Completed:
    try:
        return index, future.result(), None
    except Exception as exc:  # noqa: BLE001 (handed to the caller: a worker died, a task was lost)
        return index, None, exc


def completed_in_spawned_pool(fn: Callable[..., Any], calls: Sequence[tuple], workers: int) -> Iterator[Completed]:
    """``fn(*args)`` for every ``args`` of ``calls`` in a pool of ``workers`` spawned processes
    (``fn`` and ``args`` picklable); yields each call's :data:`Completed` as it ends, in the order
    they end (a worker that died: ``BrokenProcessPool`` as the exception). The pool is shut down
    (waiting for its workers) when the loop ends."""
    from concurrent.futures import ProcessPoolExecutor, as_completed
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(fn, *args): i for i, args in enumerate(calls)}
        for future in as_completed(futures):
            yield _outcome(futures[future], future)


def completed_on_dask(client, fn: Callable[..., Any], calls: Sequence[tuple], keys: Sequence[str]
                      ) -> Iterator[Completed]:
    """``fn(*args)`` for every ``args`` of ``calls`` as tasks of the Dask ``client`` named
    ``keys`` (not pure: each runs); yields each call's :data:`Completed` as it ends, in the order
    they end (a lost worker or task: its exception)."""
    from distributed import as_completed as dask_as_completed
    futures = [client.submit(fn, *args, pure=False, key=key) for args, key in zip(calls, keys)]
    index = {f.key: i for i, f in enumerate(futures)}
    for future in dask_as_completed(futures):
        yield _outcome(index[future.key], future)


def run_step_dask(client, groups: list[list[int]], worker_cls: type, payloads: list[Any],
                  solve: Callable[[list[Any]], Any], pack_given: Callable[[Any], Any]
                  ) -> tuple[Any, list[Any], list[Any]]:
    """:func:`run_step` on the workers of a Dask ``client``: per group one actor of
    ``worker_cls`` (it keeps its parts' eliminations between the step's two halves, as Bayes
    trees do not pickle); ``actor.reduce(payload)``, ``given = solve([reduced per group])`` here,
    ``actor.back_substitute(pack_given(given))``. A worker lost ends the step with
    :class:`PartWorkerDied` naming its parts."""
    actors = _gather(groups, [client.submit(worker_cls, actor=True, pure=False) for _ in groups])
    reduced = _gather(groups, [a.reduce(p) for a, p in zip(actors, payloads)])
    given = solve(reduced)
    packed = pack_given(given)
    return given, reduced, _gather(groups, [a.back_substitute(packed) for a in actors])


def _gather(groups: list[list[int]], futures: list) -> list[Any]:
    out = []
    for g, fut in zip(groups, futures):
        try:
            out.append(fut.result())
        except Exception as exc:  # noqa: BLE001 (a lost worker or actor: distributed's own exceptions)
            if type(exc).__module__.startswith("distributed") or isinstance(exc, (OSError, TimeoutError)):
                raise PartWorkerDied(f"the smoother's Dask worker of {_name(g)} failed ({type(exc).__name__})") from None
            raise
    return out
