"""Sensor arrays kept on disk instead of in memory during a long run (out-of-core IMU).

A run smoothed in chunks (fusion/chunks.py) reads its IMU samples one chunk at a time. After
preprocessing, :class:`SpilledImu` copies the IMU arrays into an anonymous temporary file (never
visible, gone when the run ends; beside the run's output folder, on disk) and maps it read-only: numpy reads the pages a
chunk touches from the file, and :meth:`SpilledImu.release` hands the resident pages back to the
kernel when the chunk is done (they are clean, the file holds them). The process then holds
about one chunk of IMU data, not the run's (56 bytes a sample: 144 MB for 20 km at 500 Hz).
The values are bit for bit the same. :class:`SpillArrays` does the same for arrays a run fills
as it goes (the output rows the geometry needs at the end). :func:`release_free_memory` and
:func:`trim_heap` hand freed heap pages back to the system between stages.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import mmap
import os
import tempfile
from typing import Any

import numpy as np

from .types import ImuData


class SpilledImu:
    """An :class:`ImuData` whose arrays live in a mapped temporary file (``imu``) in ``folder``."""

    def __init__(self, imu: ImuData, folder: str | os.PathLike | None = None):
        arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (imu.t_s, imu.gyro_radps, imu.accel_mps2)]
        offsets = np.cumsum([0] + [-(-a.nbytes // mmap.PAGESIZE) * mmap.PAGESIZE for a in arrays])
        with tempfile.TemporaryFile(prefix=".trackfusion-imu-", dir=folder) as fh:
            for a, at in zip(arrays, offsets):
                fh.seek(int(at))
                fh.write(memoryview(a).cast("B"))
            fh.truncate(int(offsets[-1]))
            fh.flush()
            self._map = mmap.mmap(fh.fileno(), int(offsets[-1]), access=mmap.ACCESS_READ)  # the map keeps the file
        t, g, f = (np.frombuffer(self._map, np.float64, a.size, int(at)).reshape(a.shape)
                   for a, at in zip(arrays, offsets))
        self.imu = ImuData(t, g, f)

    def release(self) -> None:
        """Drop the resident pages (read again from the file when next touched)."""
        _dont_need(self._map)



class SpillArrays:
    """Writable float arrays in anonymous temporary files in ``folder`` (sparse, zero-filled):
    filled once, read at the end of a run; :meth:`release` hands their resident pages back (the
    written values stay in the file and are read again when next touched)."""

    def __init__(self, folder: str | os.PathLike | None = None):
        self.folder = folder
        self._maps: list[mmap.mmap] = []

    def empty(self, shape: tuple[int, ...]) -> np.ndarray:
        """A float64 array of ``shape`` (zeros until written)."""
        count = int(np.prod(shape))
        nbytes = max(8 * count, 1)
        with tempfile.TemporaryFile(prefix=".trackfusion-rows-", dir=self.folder) as fh:
            fh.truncate(nbytes)
            m = mmap.mmap(fh.fileno(), nbytes)  # shared: the file holds what is written
        self._maps.append(m)
        return np.frombuffer(m, np.float64, count).reshape(shape)

    def release(self) -> None:
        for m in self._maps:
            _dont_need(m)


def _dont_need(m: mmap.mmap) -> None:
    if hasattr(m, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        m.madvise(mmap.MADV_DONTNEED)


def trim_heap() -> None:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim``; elsewhere
    nothing). Arrays of a few MB freed in the middle of the heap (a log's decoded batches once
    joined, a chunk's factor graph) otherwise keep their pages resident, under the next stage's."""
    global _malloc_trim
    if _malloc_trim is None:
        try:
            _malloc_trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _malloc_trim = False
    if _malloc_trim:
        _malloc_trim(0)


_malloc_trim: Any = None


def release_free_memory() -> None:
    """Collect garbage, then :func:`trim_heap`. Freed small objects (a log's decoded messages, a
    chunk's factor graph) otherwise keep their pages resident, and each chunk of a long run would
    start from the previous one's high-water mark (measured: 15 MB a chunk)."""
    gc.collect()
    trim_heap()
