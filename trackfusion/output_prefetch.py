"""The run's reference trajectory read while a CPU would be idle.

A run smoothed in one batch leaves the second CPU idle all through its solve (GTSAM runs on
one): :meth:`OutputPrefetch.read_in_child` reads the reference trajectory (``inputs.reference``)
there, in a forked child. Its result is the same as when read later, errors included: a
reference that cannot be read raises its error when the evaluation asks for it
(:meth:`OutputPrefetch.reference`), at the point of the run where it always did
(docs/solver_speed.md).
"""

from __future__ import annotations

from pathlib import Path


class OutputPrefetch:
    """``reference_path``: the run's reference trajectory CSV, or None."""

    def __init__(self, reference_path: Path | None):
        self.reference_path = reference_path
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

    def reference(self):
        """The reference as :func:`~trackfusion.evaluation.api.read_trajectory` returned it, or
        None when it was not read in a child (the evaluation then reads it); raises the error
        reading it raised. Handed over once."""
        if self._task is None:
            return None
        task, self._task = self._task, None
        return task.result()
