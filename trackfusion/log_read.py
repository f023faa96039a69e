"""The log a run reads (:class:`LogRequest`), and reading it ahead of the rest.

``trackfusion run`` spends about a second importing the toolkit (GTSAM, SciPy, allantools,
matplotlib) before it can validate the pipeline, and reading the log takes about as long again
on one core (the hour of ``benchmarks/speed.py``: 1.4-1.6 s). :func:`read_ahead` therefore reads
the pipeline YAML's ``inputs`` section as it is written and, where a forked child may run
(trackfusion/forked.py ``can_fork``), starts reading that log in one while this process imports
and validates. The run takes the child's log (:meth:`ReadAhead.take`) only when the validated
pipeline asks for the same file read the same way; otherwise it stops the child and reads the
log itself. Either way the log is the same arrays: the child runs the same reader.

Nothing read is used before the pipeline is validated and the output folder locked, so a bad
pipeline or output folder still fails first, with its own one line; a bad log's error is the
child's, raised where the run reads. The child is stopped (and reaped) whenever the run ends
without its log. Where no child may be forked (one CPU, no ``fork``, inside a worker process),
nothing is read ahead.

This module imports only what the command line has already loaded; the readers (and numpy with
them) are imported where they are used.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

from .errors import TrackfusionError
from .forked import ForkedTask, ForkedTasks, as_leading_child, can_fork

if TYPE_CHECKING:
    from .sensors.types import SensorLog

@dataclass(frozen=True)
class LogRequest:
    """How a run reads its log: the file or bag ``path``, ``topics`` (the roles' topics, sorted
    (role, topic or None) pairs; None: not a bag read by topics), ``allow_truncated`` and the
    pipeline ``source`` that errors name."""

    path: Path
    topics: tuple[tuple[str, str | None], ...] | None
    allow_truncated: bool
    source: str

    @classmethod
    def of(cls, pipeline: Any) -> "LogRequest":
        """The request of a validated pipeline (trackfusion/pipeline.py ``Pipeline``)."""
        inputs = pipeline.config.inputs
        topics = None if inputs.topics is None else tuple(sorted(inputs.topics.model_dump().items()))
        return cls(pipeline.path(inputs.log), topics, inputs.allow_truncated, str(pipeline.source))


def read_requested(request: LogRequest) -> tuple["SensorLog", dict | None]:
    """The log of ``request`` and, for a damaged file kept with ``allow_truncated``, what was lost
    (as :func:`~trackfusion.sensors.mcap_log.read_log_with_damage`). A bag (``topics`` given, or a
    ROS 2 bag by its form) is read by :func:`~trackfusion.sensors.ros2.read_bag`, every topic of
    any other log by trackfusion's MCAP reader."""
    from .sensors import ros2
    from .sensors.mcap_log import read_log_with_damage
    if request.topics is not None or ros2.is_bag(request.path):
        topics = dict(request.topics) if request.topics is not None else None
        return ros2.read_bag(request.path, topics, request.source, request.allow_truncated)
    return read_log_with_damage(request.path, allow_truncated=request.allow_truncated)


def written_request(pipeline_path: str) -> LogRequest | None:
    """The :class:`LogRequest` the pipeline YAML at ``pipeline_path`` makes if it validates, from
    its ``inputs`` section as written (paths as trackfusion/yamlio.py ``ConfigFile.path`` joins
    them); None when that section is not plain enough to tell (the run then reads as usual). The
    roles of ``topics`` are the bag reader's (trackfusion/sensors/ros2.py ``ROLES``, which the child
    imports anyway)."""
    from .sensors.ros2 import ROLES
    from .yamlio import ConfigFile, load_yaml
    p = Path(pipeline_path)
    try:
        data = load_yaml(p, "pipeline file")
    except TrackfusionError:
        return None
    inputs = data.get("inputs") if isinstance(data, dict) and "vision" not in data else None
    if not isinstance(inputs, dict) or not isinstance(inputs.get("log"), str):
        return None
    allow_truncated = inputs.get("allow_truncated", False)
    topics = inputs.get("topics")
    if not isinstance(allow_truncated, bool) or not (topics is None or isinstance(topics, dict)):
        return None
    if topics is not None:
        topics = tuple(sorted({role: topics.get(role) for role in ROLES}.items()))
    as_loaded = ConfigFile(p.resolve().parent, str(p))  # as load_pipeline takes the YAML's folder
    return LogRequest(as_loaded.path(inputs["log"]), topics, allow_truncated, str(p))


def _read_as_leader(request: LogRequest) -> tuple["SensorLog", dict | None]:
    """:func:`read_requested` in the read-ahead child, which may start the reader's decode workers
    as the run's own process would (a JSON log's; CDR is decoded in the reading process)."""
    with as_leading_child():
        return read_requested(request)


class ReadAhead:
    """A log being read in a forked child (:func:`read_ahead`) for ``request``."""

    def __init__(self, request: LogRequest, task: ForkedTask, tasks: ForkedTasks):
        self.request = request
        self._task: ForkedTask | None = task
        self._tasks = tasks

    def take(self, request: LogRequest, meanwhile: Callable[[], None] | None = None
             ) -> tuple["SensorLog", dict | None]:
        """:func:`read_requested` of ``request``: the child's answer (its log, or its error raised
        here) when it was asked the same, else read here (the child stopped). ``meanwhile``: work
        this process does before it waits for the child (not when it reads here)."""
        task, self._task = self._task, None
        if task is not None and request == self.request:
            if meanwhile is not None:
                meanwhile()
            return task.result()
        self._tasks.kill()
        return read_requested(request)


@contextlib.contextmanager
def read_ahead(pipeline_path: str) -> Iterator[ReadAhead | None]:
    """Start reading the log of the pipeline YAML at ``pipeline_path`` in a forked child (module
    docstring); yields its :class:`ReadAhead`, or None where nothing is read ahead. On leaving,
    a child whose log was not taken is stopped."""
    request = written_request(pipeline_path) if can_fork() else None
    if request is None:
        yield None
        return
    tasks = ForkedTasks(always_fork=True)
    try:
        yield ReadAhead(request, tasks.submit("reading the log", _read_as_leader, request), tasks)
    finally:
        tasks.kill()
