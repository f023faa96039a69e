"""Error series of an estimated trajectory against a reference, in track components.

Pipeline (pure maths, no file I/O):

1. **Match** each estimate sample to the reference.

   * ``match="time"`` (default): the reference position is interpolated at the
     estimate's ``t_s`` by cubic Hermite interpolation between the two
     bracketing reference samples, using the reference velocities as end
     slopes (interpolation error O(dt^4): far below 1 micrometre for a
     50 Hz reference of a pushed trolley). The reference velocity and
     chainage are interpolated linearly. Estimate samples outside the
     reference's time span are dropped (no extrapolation).
   * ``match="chainage"``: the reference is taken as a single-valued curve of
     chainage: its samples are sorted by ``chainage_m`` (positions at a
     repeated chainage averaged) and interpolated linearly at the estimate's
     ``chainage_m``. Estimate samples outside the reference's chainage span are
     dropped. Use it for references without a common clock (levelling
     surveys, design curves); it assumes every pass of the reference lies on
     the same curve.

2. **Split** the error ``e = p_est - p_ref`` (frame ``n``) into

   * ``along``: horizontal unit tangent ``a`` in the direction of *increasing
     chainage* (not of travel, so a return pass keeps the same axes);
   * ``lateral``: ``l = up x a``, horizontal, positive to the left of increasing
     chainage (the ``t`` frame's y);
   * ``vertical``: the ``n`` frame's up axis.

   In time mode ``a`` is the reference's horizontal velocity times the sign of
   its chainage rate; in chainage mode the horizontal direction of the
   reference chord from ``s - 0.25 m`` to ``s + 0.25 m`` (parallel to the
   tangent at ``s`` on a circle, and insensitive to nearly repeated chainages).

3. **Keep the moving part**: a sample is moving when the horizontal speed
   (reference velocity in time mode, estimate velocity in chainage mode) is
   at least ``min_speed_mps`` (default 0.1 m/s). Static intervals (ZUPT
   stands, the stop at a reversal) are excluded.

4. **Passes**: consecutive moving samples with the same sign of chainage rate
   and no time gap above ``max_gap_s`` form one monotonic pass.

5. **Resample onto distance**: each pass is linearly interpolated in chainage
   onto the global grid ``chainage = k * step_m`` (default ``step_m`` 0.05 m;
   the grid is anchored at chainage 0 so passes share grid points), covering
   only the chainage the pass spans.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import EvaluationError

#: Component names, in the column order of ``error_m`` arrays.
COMPONENTS: tuple[str, ...] = ("along", "lateral", "vertical")

_UP_N = np.array([0.0, 0.0, 1.0])

#: Half chord (m) of the reference used for the tangent in chainage mode (robust to repeated chainages).
_TANGENT_HALF_CHORD_M = 0.25


@dataclass(frozen=True)
class Trajectory:
    """A trajectory in the ``n`` frame.

    t_s (N,) s; pos_n_m (N, 3) m (e, n, u); vel_n_mps (N, 3) m/s; chainage_m (N,) m;
    source: file name or label used in error messages.
    """

    t_s: np.ndarray
    pos_n_m: np.ndarray
    vel_n_mps: np.ndarray
    chainage_m: np.ndarray
    source: str = "trajectory"

    @classmethod
    def from_columns(cls, table: dict[str, np.ndarray], source: str = "trajectory") -> "Trajectory":
        """Build from trajectory-CSV columns (``t_s, e_m, n_m, u_m, ve_mps, vn_mps, vu_mps, chainage_m``).

        Raises :class:`EvaluationError` naming ``source`` and the column on a
        non-finite value, and when fewer than two rows are given.
        """
        for name in ("t_s", "e_m", "n_m", "u_m", "ve_mps", "vn_mps", "vu_mps", "chainage_m"):
            if name not in table:
                raise EvaluationError(f"{source}: missing column {name!r}")
            bad = np.flatnonzero(~np.isfinite(table[name]))
            if bad.size:
                raise EvaluationError(f"{source}: column {name!r} has a non-finite value in data row {bad[0] + 1}")
        if table["t_s"].size < 2:
            raise EvaluationError(f"{source}: needs at least two data rows, got {table['t_s'].size}")
        return cls(t_s=np.asarray(table["t_s"], dtype=float),
                   pos_n_m=np.column_stack([table["e_m"], table["n_m"], table["u_m"]]).astype(float),
                   vel_n_mps=np.column_stack([table["ve_mps"], table["vn_mps"], table["vu_mps"]]).astype(float),
                   chainage_m=np.asarray(table["chainage_m"], dtype=float), source=source)


@dataclass(frozen=True)
class ErrorSeries:
    """Matched, moving samples of the estimate error.

    t_s (M,) estimate time; chainage_m (M,) chainage used for the distance
    grid (reference chainage in time mode, estimate chainage in chainage mode);
    error_m (M, 3) errors est - ref along ``COMPONENTS`` (m); pass_index (M,)
    0-based monotonic pass; pass_direction (P,) +1 increasing / -1 decreasing
    chainage. n_matched: estimate samples inside the reference span;
    n_static: of those, excluded as static.
    """

    t_s: np.ndarray
    chainage_m: np.ndarray
    error_m: np.ndarray
    pass_index: np.ndarray
    pass_direction: np.ndarray
    n_matched: int
    n_static: int

    @property
    def n_passes(self) -> int:
        return int(self.pass_direction.size)

    def component(self, name: str) -> np.ndarray:
        """(M,) error of one component (m)."""
        return self.error_m[:, COMPONENTS.index(name)]


@dataclass(frozen=True)
class GriddedPass:
    """One monotonic pass on the distance grid: chainage ``(start_index + arange(n)) * step_m``.

    error_m (n, 3) m along ``COMPONENTS``, ordered by increasing chainage; direction +1/-1.
    """

    start_index: int
    step_m: float
    error_m: np.ndarray
    direction: int

    @property
    def chainage_m(self) -> np.ndarray:
        return (self.start_index + np.arange(self.error_m.shape[0])) * self.step_m


@dataclass(frozen=True)
class DistanceSeries:
    """The error series resampled on a uniform chainage grid, one :class:`GriddedPass` per pass."""

    step_m: float
    passes: tuple[GriddedPass, ...]

    def component(self, name: str) -> list[np.ndarray]:
        """One (n_p,) array (m) per pass for component ``name``."""
        k = COMPONENTS.index(name)
        return [p.error_m[:, k] for p in self.passes]

    @property
    def n_points(self) -> int:
        return sum(p.error_m.shape[0] for p in self.passes)

    @property
    def length_m(self) -> float:
        """Total gridded length over all passes (m)."""
        return sum(max(p.error_m.shape[0] - 1, 0) for p in self.passes) * self.step_m


def hermite_interpolate(t_s: np.ndarray, pos: np.ndarray, vel: np.ndarray, t_query_s: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of positions (N, 3) with velocities (N, 3) at t_query_s (M,) -> (M, 3).

    t_s must be strictly increasing and t_query_s inside [t_s[0], t_s[-1]].
    """
    i = np.clip(np.searchsorted(t_s, t_query_s, side="right") - 1, 0, t_s.size - 2)
    h = (t_s[i + 1] - t_s[i])[:, None]
    u = (t_query_s - t_s[i])[:, None] / h
    u2, u3 = u * u, u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    return h00 * pos[i] + h10 * h * vel[i] + h01 * pos[i + 1] + h11 * h * vel[i + 1]


def _interp_columns(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp of each column of fp (N, k) at x (M,) -> (M, k)."""
    return np.column_stack([np.interp(x, xp, fp[:, j]) for j in range(fp.shape[1])])


def _unit_horizontal(vec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) horizontal unit vectors of vec (M, 3) and their horizontal norms (M,)."""
    h = vec.copy()
    h[:, 2] = 0.0
    norm = np.linalg.norm(h, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return h / norm[:, None], norm


def project_components(error_n_m: np.ndarray, along_unit_n: np.ndarray) -> np.ndarray:
    """Errors (M, 3) in ``n`` -> (M, 3) along / lateral (left) / vertical, given horizontal unit tangents (M, 3)."""
    lateral_unit = np.cross(_UP_N, along_unit_n)
    return np.column_stack([np.einsum("ij,ij->i", error_n_m, along_unit_n),
                            np.einsum("ij,ij->i", error_n_m, lateral_unit),
                            error_n_m[:, 2]])


def _check_increasing_time(traj: Trajectory) -> None:
    bad = np.flatnonzero(np.diff(traj.t_s) <= 0)
    if bad.size:
        raise EvaluationError(f"{traj.source}: t_s is not strictly increasing at data row {bad[0] + 2}")


def _match_time(est: Trajectory, ref: Trajectory):
    _check_increasing_time(ref)
    _check_increasing_time(est)  # passes are cut at time gaps and reversals: the order must be time order
    t0, t1 = ref.t_s[0], ref.t_s[-1]
    keep = (est.t_s >= t0) & (est.t_s <= t1)
    if not keep.any():
        raise EvaluationError(
            f"{est.source}: no overlap in time with {ref.source} (estimate {est.t_s.min():.3f}..{est.t_s.max():.3f} s, "
            f"reference {t0:.3f}..{t1:.3f} s)")
    t = est.t_s[keep]
    p_ref = hermite_interpolate(ref.t_s, ref.pos_n_m, ref.vel_n_mps, t)
    v_ref = _interp_columns(t, ref.t_s, ref.vel_n_mps)
    s_ref = np.interp(t, ref.t_s, ref.chainage_m)
    s_rate = np.interp(t, ref.t_s, np.gradient(ref.chainage_m, ref.t_s))
    along, speed = _unit_horizontal(v_ref)
    sign = np.sign(s_rate)
    return keep, p_ref, along * sign[:, None], speed, s_ref, sign


def _match_chainage(est: Trajectory, ref: Trajectory):
    s_u, inverse = np.unique(ref.chainage_m, return_inverse=True)
    if s_u.size < 2:
        raise EvaluationError(f"{ref.source}: chainage_m spans no distance (a single value)")
    counts = np.bincount(inverse)
    pos_u = np.column_stack([np.bincount(inverse, weights=ref.pos_n_m[:, j]) / counts for j in range(3)])
    keep = (est.chainage_m >= s_u[0]) & (est.chainage_m <= s_u[-1])
    if not keep.any():
        raise EvaluationError(
            f"{est.source}: no overlap in chainage with {ref.source} (estimate {est.chainage_m.min():.3f}.."
            f"{est.chainage_m.max():.3f} m, reference {s_u[0]:.3f}..{s_u[-1]:.3f} m)")
    s = est.chainage_m[keep]
    p_ref = _interp_columns(s, s_u, pos_u)
    ahead = np.minimum(s + _TANGENT_HALF_CHORD_M, s_u[-1])
    behind = np.maximum(s - _TANGENT_HALF_CHORD_M, s_u[0])
    tangent = _interp_columns(ahead, s_u, pos_u) - _interp_columns(behind, s_u, pos_u)
    along, _ = _unit_horizontal(tangent)
    _, speed = _unit_horizontal(est.vel_n_mps[keep])
    _check_increasing_time(est)
    sign = np.sign(np.gradient(est.chainage_m, est.t_s)[keep])
    return keep, p_ref, along, speed, s, sign


def _pass_index(t_s: np.ndarray, sign: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(M,) pass index of consecutive samples with one chainage-rate sign and no gap > max_gap_s; (P,) signs."""
    new = np.ones(t_s.size, dtype=bool)
    new[1:] = (sign[1:] != sign[:-1]) | (np.diff(t_s) > max_gap_s)
    idx = np.cumsum(new) - 1
    return idx, sign[new].astype(int)


def error_series(est: Trajectory, ref: Trajectory, match: str = "time", min_speed_mps: float = 0.1,
                 max_gap_s: float = 1.0) -> ErrorSeries:
    """Errors of ``est`` against ``ref`` over the moving part of the run (see the module docstring).

    match: ``"time"`` or ``"chainage"``. min_speed_mps: horizontal speed below
    which a sample counts as static. max_gap_s: a larger time step between
    moving samples starts a new pass. Raises :class:`EvaluationError` (naming
    the file) on no overlap or no moving sample.
    """
    if match == "time":
        keep, p_ref, along, speed, s, sign = _match_time(est, ref)
    elif match == "chainage":
        keep, p_ref, along, speed, s, sign = _match_chainage(est, ref)
    else:
        raise EvaluationError(f"match must be 'time' or 'chainage', got {match!r}")
    moving = (speed >= min_speed_mps) & (sign != 0) & np.isfinite(along).all(axis=1)
    n_matched = int(keep.sum())
    if not moving.any():
        raise EvaluationError(
            f"{est.source}: no moving sample in the overlap with {ref.source} (speed below {min_speed_mps} m/s)")
    t = est.t_s[keep][moving]
    err_n = est.pos_n_m[keep][moving] - p_ref[moving]
    comps = project_components(err_n, along[moving])
    pass_index, directions = _pass_index(t, sign[moving], max_gap_s)
    return ErrorSeries(t_s=t, chainage_m=s[moving], error_m=comps, pass_index=pass_index,
                       pass_direction=directions, n_matched=n_matched, n_static=n_matched - int(moving.sum()))


def resample_on_distance(series: ErrorSeries, step_m: float = 0.05) -> DistanceSeries:
    """Resample each pass of ``series`` linearly onto the chainage grid ``k * step_m`` (see module docstring).

    Passes spanning no grid point are dropped. Raises :class:`EvaluationError`
    when no pass spans at least two grid points.
    """
    if not (step_m > 0 and np.isfinite(step_m)):
        raise EvaluationError(f"grid step must be positive, got {step_m!r} m")
    bounds = np.flatnonzero(np.diff(series.pass_index)) + 1
    starts = np.concatenate(([0], bounds))
    stops = np.concatenate((bounds, [series.pass_index.size]))
    passes = []
    for a, b in zip(starts, stops):
        s = series.chainage_m[a:b]
        order = np.argsort(s, kind="stable")
        s_sorted = s[order]
        k0, k1 = int(np.ceil(s_sorted[0] / step_m - 1e-9)), int(np.floor(s_sorted[-1] / step_m + 1e-9))
        if k1 - k0 < 1 or s_sorted[-1] <= s_sorted[0]:
            continue
        grid = np.arange(k0, k1 + 1) * step_m
        values = _interp_columns(grid, s_sorted, series.error_m[a:b][order])
        passes.append(GriddedPass(start_index=k0, step_m=float(step_m), error_m=values,
                                  direction=int(series.pass_direction[series.pass_index[a]])))
    if not passes:
        raise EvaluationError(f"the moving part spans less than two grid steps of {step_m} m")
    return DistanceSeries(step_m=float(step_m), passes=tuple(passes))
