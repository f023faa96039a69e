"""What a run's outputs need, read and imported while a CPU would be idle.

Called (``OutputPrefetch()``) in the parent, it does what the run would do afterwards anyway: import the modules of
the evaluation and of the report figures (matplotlib) and read the reference trajectory
(``inputs.reference``). Its results are the same as when done later, errors included: a reference
that cannot be read raises its error when the evaluation asks for it (:meth:`reference`), at the
point of the run where it always did (docs/solver_speed.md). A run smoothed in one batch leaves the
second CPU idle all through its solve (GTSAM runs on one): :meth:`read_in_child` reads the
reference there, in a forked child.
"""

from __future__ import annotations

from pathlib import Path


class OutputPrefetch:
    """``reference_path``: the run's reference trajectory CSV, or None; ``figures``: the report
    is drawn (import matplotlib)."""

    def __init__(self, reference_path: Path | None, figures: bool):
        self.reference_path, self.figures = reference_path, figures
        self._read = None  # read_trajectory's (Trajectory, sidecar), once read
        self._error: Exception | None = None
        self._task = None  # the forked child reading it (read_in_child)

    def read_in_child(self, background) -> None:
        """Start reading the reference in a forked child of ``background`` (a
        :class:`~trackfusion.forked.ForkedTasks`), when children can be forked; :meth:`reference`
        takes its result (or raises its error)."""
        from .forked import can_fork
        if self.reference_path is not None and can_fork():
            from .evaluation.api import read_trajectory
            self._task = background.submit(f"reading the reference {self.reference_path}", read_trajectory,
                                           self.reference_path)

    def __call__(self) -> None:
        """Import and read (never raises: a failure is kept for :meth:`reference`)."""
        from .evaluation.api import read_trajectory
        from .evaluation import reference  # noqa: F401 (scipy.stats and the rest of the evaluation)
        if self.figures:
            from .report.figures import preload
            preload()
        if self.reference_path is not None:
            try:
                self._read = read_trajectory(self.reference_path)
            except Exception as exc:  # noqa: BLE001 (raised where the evaluation asks for it)
                self._error = exc

    def reference(self):
        """The reference as :func:`~trackfusion.evaluation.api.read_trajectory` returned it, or
        None when it was not read here; raises the error reading it raised."""
        if self._task is not None:
            task, self._task = self._task, None
            return task.result()
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        read, self._read = self._read, None  # (the run keeps no second reference in memory)
        return read
