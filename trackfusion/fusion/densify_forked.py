"""The densification of a run smoothed in one batch on every CPU: the keyframe intervals are
independent (fusion/trajectory.py), so they are cut into ``workers`` parts at a multiple of
:func:`~.trajectory.densify`'s block; this process densifies the first part and a forked child
(:class:`trackfusion.forked.ForkedTasks`) each other one. The rows are the same arrays, bit for
bit, as one :func:`~.trajectory.densify` call (tests/test_densify_forked.py).

The children write their rows straight into the output arrays, which live in a shared anonymous
mapping made before the fork; nothing goes back through a pipe. Sending them back pickled cost
about 1 s per 200 MB (the 53 min bridge at 500 Hz: one child 3.3-3.8 s against 2.2-2.5 s in this
process alone). The rows are copied into private memory once the children are done, so that a
later forked child (the outputs) cannot write into this process's arrays.
"""

from __future__ import annotations

import mmap
from dataclasses import fields

import numpy as np

from ..forked import ForkedTasks, can_fork
from ..sensors.types import ImuData
from .trajectory import DenseTrajectory, KeyframeStates, densify

#: intervals per block of :func:`densify` (its default); the parts are cut at multiples of it
BLOCK = 2000
#: fewer intervals than this: not worth a worker (one densify call here)
MIN_INTERVALS_PER_WORKER = 2 * BLOCK


def part_bounds(n_intervals: int, workers: int) -> list[tuple[int, int]]:
    """Keyframe index ranges ``(a, b)`` (inclusive ends, ``b`` of one part the ``a`` of the next)
    of at most ``workers`` parts of ``n_intervals`` intervals, cut at multiples of :data:`BLOCK`."""
    n = max(1, min(workers, n_intervals // MIN_INTERVALS_PER_WORKER))
    cuts = sorted({int(round(n_intervals * i / n / BLOCK)) * BLOCK for i in range(1, n)} - {0, n_intervals})
    edges = [0] + [c for c in cuts if 0 < c < n_intervals] + [n_intervals]
    return list(zip(edges[:-1], edges[1:]))


def _shared_rows(n: int) -> tuple[mmap.mmap, DenseTrajectory]:
    """A shared anonymous mapping and (N = ``n``) rows of :class:`DenseTrajectory` in it (the
    mapping lives as long as any of the arrays)."""
    shapes = {"t_s": (n,), "R_nb": (n, 3, 3), "pos_n": (n, 3), "vel_n": (n, 3)}
    size = 8 * sum(int(np.prod(s)) for s in shapes.values())
    buf = mmap.mmap(-1, max(size, 1), flags=mmap.MAP_SHARED | mmap.MAP_ANONYMOUS)
    arrays, offset = {}, 0
    for name, shape in shapes.items():
        arrays[name] = np.frombuffer(buf, np.float64, int(np.prod(shape)), offset).reshape(shape)
        offset += arrays[name].nbytes
    return buf, DenseTrajectory(**arrays)


def _part_into(out: DenseTrajectory, imu: ImuData, keys: KeyframeStates, omega_ie_n: np.ndarray,
               bounds: tuple[int, int]) -> None:
    """Densify the keyframes ``bounds`` (a part of :func:`part_bounds`) into their rows of ``out``
    (the part's rows up to and without its last keyframe, but for the run's last part)."""
    a, b = bounds
    d = densify(imu, keys.select(slice(a, b + 1)), omega_ie_n, block=BLOCK)
    if b < keys.key_idx.size - 1:
        d = d.select(slice(None, -1))  # the next part starts there
    first = int(keys.key_idx[a] - keys.key_idx[0])
    for f in fields(DenseTrajectory):
        getattr(out, f.name)[first:first + d.t_s.size] = getattr(d, f.name)


def densify_forked(imu: ImuData, keys: KeyframeStates, omega_ie_n: np.ndarray, workers: int) -> DenseTrajectory:
    """:func:`~.trajectory.densify` of these keyframes (same arguments; ``omega_ie_n`` the Earth
    rate) in up to ``workers`` parts, this process one of them (module docstring). One densify
    call here when forking is not possible (:func:`trackfusion.forked.can_fork`) or the run is too
    short to be worth it. A child's failure is raised here, after every child is waited for or killed."""
    n_intervals = keys.key_idx.size - 1
    bounds = part_bounds(n_intervals, workers)
    if len(bounds) < 2 or not can_fork(2):
        return densify(imu, keys, omega_ie_n, block=BLOCK)
    _buf, out = _shared_rows(int(keys.key_idx[-1] - keys.key_idx[0]) + 1)  # (freed with its last array)
    with ForkedTasks(always_fork=True) as tasks:
        for i in range(1, len(bounds)):
            tasks.submit(f"densification, part {i + 1} of {len(bounds)}", _part_into, out, imu, keys,
                         omega_ie_n, bounds[i])
        _part_into(out, imu, keys, omega_ie_n, bounds[0])
        tasks.wait()
    return DenseTrajectory(*(np.array(getattr(out, f.name)) for f in fields(out)))
