"""The densification of a run smoothed in one batch in forked workers: the keyframe intervals are independent
(fusion/trajectory.py), so they are cut into ``workers`` parts at a multiple of
:func:`~.trajectory.densify`'s block, each densified in its own forked child
(:class:`trackfusion.forked.ForkedTasks`); the parts' rows are the same arrays, bit for bit,
as one :func:`~.trajectory.densify` call (tests/test_densify_forked.py). On the 54 min bridge
this halves the 6-7 s of the densification; the rows (about 100 MB a part) come back through
a pipe in a fraction of a second. :func:`start_densify_forked` starts the children and returns
at once (:meth:`Densifying.result` waits for them); the pipeline starts them once the smoother,
marginals included, is done (pipeline._smooth_and_densify).
"""

from __future__ import annotations

import numpy as np

from ..forked import ForkedTask, ForkedTasks, can_fork
from ..sensors.types import ImuData
from .trajectory import DenseTrajectory, KeyframeStates, densify

#: intervals per block of :func:`densify` (its default); the parts are cut at multiples of it
BLOCK = 2000
#: fewer intervals than this: not worth a worker (one densify call here)
MIN_INTERVALS_PER_WORKER = 2 * BLOCK

_JOB: tuple | None = None  # the arguments, read by the forked children


def part_bounds(n_intervals: int, workers: int) -> list[tuple[int, int]]:
    """Keyframe index ranges ``(a, b)`` (inclusive ends, ``b`` of one part the ``a`` of the next)
    of at most ``workers`` parts of ``n_intervals`` intervals, cut at multiples of :data:`BLOCK`."""
    n = max(1, min(workers, n_intervals // MIN_INTERVALS_PER_WORKER))
    cuts = sorted({int(round(n_intervals * i / n / BLOCK)) * BLOCK for i in range(1, n)} - {0, n_intervals})
    edges = [0] + [c for c in cuts if 0 < c < n_intervals] + [n_intervals]
    return list(zip(edges[:-1], edges[1:]))


def _part(i: int) -> DenseTrajectory:
    (imu, keys, omega_ie_n), bounds = _JOB
    a, b = bounds[i]
    d = densify(imu, keys.select(slice(a, b + 1)), omega_ie_n, block=BLOCK)
    return d if b == keys.key_idx.size - 1 else d.select(slice(None, -1))  # the next part starts there


class Densifying:
    """A densification started by :func:`start_densify_forked`: :meth:`result` waits for its parts."""

    def __init__(self, parts: list[ForkedTask] | None = None, dense: DenseTrajectory | None = None):
        self._parts, self._dense = parts, dense

    def result(self) -> DenseTrajectory:
        """The rows, as one :func:`~.trajectory.densify` call gives them (raises a part's failure)."""
        if self._dense is None:
            self._dense = DenseTrajectory.concatenate([part.result() for part in self._parts])
            self._parts = None
        return self._dense


def start_densify_forked(tasks: ForkedTasks, imu: ImuData, keys: KeyframeStates, omega_ie_n: np.ndarray,
                         workers: int) -> Densifying:
    """Start :func:`~.trajectory.densify` of these keyframes (same arguments; ``omega_ie_n`` the
    Earth rate) in up to ``workers`` children forked by ``tasks`` (made with ``always_fork=True``;
    leaving its ``with`` block on an error kills them) and return at once; ``workers`` 1: one
    child does it all, beside this process. In this process, before returning, when forking is
    not possible here (:func:`trackfusion.forked.can_fork`) or the run is too short to be worth it."""
    global _JOB
    n_intervals = keys.key_idx.size - 1
    if n_intervals < MIN_INTERVALS_PER_WORKER or not can_fork(2):  # (a child needs a CPU beside this one)
        return Densifying(dense=densify(imu, keys, omega_ie_n, block=BLOCK))
    bounds = part_bounds(n_intervals, workers)
    _JOB = ((imu, keys, omega_ie_n), bounds)
    try:  # each child sees _JOB as it was at its fork
        return Densifying([tasks.submit(f"densification, part {i + 1} of {len(bounds)}", _part, i)
                           for i in range(len(bounds))])
    finally:
        _JOB = None

