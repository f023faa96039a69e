"""The trajectory at the output rate: its chainage and the trajectory.csv columns (DESIGN.md
section 4), for the whole run at once or, for a long run smoothed in chunks, chunk by chunk.

:class:`StreamedTrajectory` turns each chunk's densified core (fusion/chunks.py) into its
trajectory.csv rows as soon as the chunk is done and hands them to a sink (the CSV writer):
the same rows, to the last bit, as :func:`trajectory_table` of the whole run's trajectory
(the chainage's cumulative sums go on from the previous chunk's last sample; the sigmas and
the odometer-scale correction are interpolated between the same keyframes). Of the rows it
keeps only what the rest of the run needs: the pose and chainage for the track geometry, the
columns the reference evaluation reads (when there is a reference) and every row at the
Foxglove rate (for fused.mcap).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..rotations import quat_from_R
from ..sensors.types import ImuData, OdometerData
from .smoother import SmootherResult
from .trajectory import DenseTrajectory

#: columns of the reference evaluation (evaluation/reference.py)
EVALUATION_COLUMNS = ("t_s", "e_m", "n_m", "u_m", "ve_mps", "vn_mps", "vu_mps", "chainage_m",
                      "sigma_e_m", "sigma_n_m", "sigma_u_m")


def chainage_along(dense: DenseTrajectory, res: SmootherResult, odometer: OdometerData | None,
                   axis_b: np.ndarray, before: tuple[np.ndarray, np.ndarray, float] | None = None) -> np.ndarray:
    """Chainage [m] at the dense times, 0 at the start: the odometer distance with the smoothed
    scale removed (``d_true = d_meas / (1 + scale)`` per interval), else the signed path length.
    ``before``: (pos_n (3,) [m], R_nb (3, 3), chainage [m]) of the sample just before ``dense``
    when it continues an earlier piece of the run; the path length goes on from it."""
    if odometer is not None and res.odometer_scale is not None:
        d_key = np.interp(res.t_s, odometer.t_s, odometer.distance_m)
        true_key = np.r_[0.0, np.cumsum(np.diff(d_key) / (1.0 + res.odometer_scale[:-1]))]
        corr = (d_key - d_key[0]) - true_key
        d = np.interp(dense.t_s, odometer.t_s, odometer.distance_m) - d_key[0]
        return d - np.interp(dense.t_s, res.t_s, corr)
    pos, R, start = dense.pos_n, dense.R_nb, 0.0
    if before is not None:
        pos, R, start = np.concatenate([before[0][None], pos]), np.concatenate([before[1][None], R]), before[2]
    step = np.diff(pos, axis=0)
    forward = np.einsum("kij,j,ki->k", R[:-1], axis_b, step)
    s = np.cumsum(np.r_[start, np.sign(forward) * np.linalg.norm(step, axis=1)])  # sequential: chunks add up
    return s if before is None else s[1:]


def trajectory_table(dense: DenseTrajectory, res: SmootherResult, chainage_m: np.ndarray, every: int
                     ) -> dict[str, np.ndarray]:
    """trajectory.csv columns (DESIGN.md section 4) at every ``every``-th dense sample."""
    sel = np.arange(0, dense.t_s.size, every)
    t = dense.t_s[sel]
    q = quat_from_R(dense.R_nb[sel])
    sp = np.column_stack([np.interp(t, res.sigma_t_s, res.sigma_pos_n_m[:, i]) for i in range(3)])
    sa = np.column_stack([np.interp(t, res.sigma_t_s, res.sigma_att_rad[:, i]) for i in range(3)])
    p, v = dense.pos_n[sel], dense.vel_n[sel]
    return {"t_s": t, "e_m": p[:, 0], "n_m": p[:, 1], "u_m": p[:, 2], "qw": q[:, 0], "qx": q[:, 1],
            "qy": q[:, 2], "qz": q[:, 3], "ve_mps": v[:, 0], "vn_mps": v[:, 1], "vu_mps": v[:, 2],
            "chainage_m": chainage_m[sel], "sigma_e_m": sp[:, 0], "sigma_n_m": sp[:, 1], "sigma_u_m": sp[:, 2],
            "sigma_roll_rad": sa[:, 0], "sigma_pitch_rad": sa[:, 1], "sigma_yaw_rad": sa[:, 2]}


class _Rows:
    """Columns filled block by block into arrays allocated once for ``rows_max`` rows (the
    pages of the unused tail are never touched, so they cost no memory)."""

    def __init__(self, rows_max: int, empty: Callable[[tuple], np.ndarray] = np.empty):
        self.rows_max, self.n, self.arrays, self.empty = rows_max, 0, {}, empty

    def append(self, columns: dict[str, np.ndarray]) -> None:
        k = len(next(iter(columns.values())))
        if self.n + k > self.rows_max:
            raise ValueError(f"more than the {self.rows_max} rows allocated")
        for name, v in columns.items():
            if name not in self.arrays:
                self.arrays[name] = self.empty((self.rows_max,) + v.shape[1:])
            self.arrays[name][self.n:self.n + k] = v
        self.n += k

    def columns(self) -> dict[str, np.ndarray]:
        return {name: a[:self.n] for name, a in self.arrays.items()}


class StreamedTrajectory:
    """trajectory.csv rows of a run smoothed in chunks, made chunk by chunk (module docstring).

    ``sink(columns)`` receives the rows block by block in time order (trajectory.csv columns);
    ``rows_max``: an upper bound of the run's rows; ``thin_every``: keep every that-many-th row
    (all columns, for fused.mcap; None: none); ``keep_evaluation``: keep
    :data:`EVALUATION_COLUMNS` of every row; ``imu``: the run's IMU samples, given to keep for the
    geometry the time, attitude, position, chainage and gyro sample of every row (in arrays
    from ``empty(shape)``, e.g. :meth:`~trackfusion.sensors.spill.SpillArrays.empty`). Call :meth:`add` once per chunk with its decimated dense core and
    the keyframe result of the chunks so far (``last`` for the final chunk).
    """

    def __init__(self, odometer: OdometerData | None, axis_b: np.ndarray, sink: Callable[[dict], None],
                 rows_max: int, thin_every: int | None = None, keep_evaluation: bool = False,
                 imu: ImuData | None = None, empty: Callable[[tuple], np.ndarray] = np.empty):
        self.odometer, self.axis_b, self.sink, self.imu = odometer, axis_b, sink, imu
        self.thin_every, self.rows = thin_every, 0
        self.thinned = _Rows(rows_max // thin_every + 1) if thin_every else None
        self.evaluation = _Rows(rows_max) if keep_evaluation else None
        self.geometry = _Rows(rows_max, empty) if imu is not None else None
        self._pending: DenseTrajectory | None = None
        self._before: tuple[np.ndarray, np.ndarray, float] | None = None

    def add(self, dense: DenseTrajectory, so_far: SmootherResult, last: bool) -> None:
        """Rows of ``dense`` up to the last marginal of ``so_far`` (all of them when ``last``);
        the rest waits for the next chunk, whose first marginal its sigmas interpolate towards."""
        if self._pending is not None:
            dense = DenseTrajectory.concatenate([self._pending, dense])
        n_ready = dense.t_s.size if last else int(np.searchsorted(dense.t_s, so_far.sigma_t_s[-1], "right"))
        self._pending = dense.select(slice(n_ready, None)) if n_ready < dense.t_s.size else None
        if n_ready == 0:
            return
        ready = dense.select(slice(0, n_ready))
        chainage = chainage_along(ready, so_far, self.odometer, self.axis_b, self._before)
        self._before = (ready.pos_n[-1].copy(), ready.R_nb[-1].copy(), float(chainage[-1]))
        table = trajectory_table(ready, so_far, chainage, 1)
        self.sink(table)
        if self.thinned is not None:
            keep = (self.rows + np.arange(n_ready)) % self.thin_every == 0
            self.thinned.append({k: v[keep] for k, v in table.items()})
        if self.evaluation is not None:
            self.evaluation.append({k: table[k] for k in EVALUATION_COLUMNS})
        if self.geometry is not None:
            gyro = self.imu.gyro_radps[np.searchsorted(self.imu.t_s, ready.t_s)]
            self.geometry.append({"t_s": ready.t_s, "R_nb": ready.R_nb, "pos_n": ready.pos_n, "chainage_m": chainage,
                                  "gyro_radps": gyro})
        self.rows += n_ready

    def geometry_input(self) -> tuple[DenseTrajectory, np.ndarray, ImuData]:
        """The kept pose at every row (velocity left out: the geometry does not use it), its
        chainage, and the IMU samples at the rows' times (gyro only)."""
        g = self.geometry.columns()
        empty = np.empty((0, 3))
        return (DenseTrajectory(g["t_s"], g["R_nb"], g["pos_n"], empty), g["chainage_m"],
                ImuData(g["t_s"], g["gyro_radps"], empty))
