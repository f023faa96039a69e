"""Rail traces from the smoothed pose, the trolley geometry and the gauge reading.

The trolley frame ``v`` is fixed by its three wheel contacts (``simulation/trolley.py``): origin
midway between the two reference-rail contacts, x from the rear to the front contact, z
normal to the contact plane. With ``R_nv = R_nb R_vb^T`` and the IMU at ``lever_arm_imu_v``:

- the two reference-rail contacts ``origin +/- R_nv [l/2, 0, 0]`` are points *on* the rail, at
  chainages ``s -/+ l/2`` (``s`` the trolley's chainage). Both wheels trace the same rail; the
  trace is their mean where both cover it, which also cancels a pitch error to first order.
- the single wheel's contact lies in the contact plane on the transverse axis,
  ``origin + w u`` with ``u = -y_v`` (reference rail left) or ``+y_v``. ``w`` is the gauge
  reading ``G`` corrected for the offset of ``v``'s origin from the reference rail at ``s``
  (the sagitta of the wheelbase chord): ``w = G + (P_ref(s) - origin) . u``. Without a gauge
  sensor ``G`` is the nominal gauge and the other rail's alignment carries the gauge
  irregularity (say so in the outputs). The point is filed under the chainage where the
  track's cross-section through it meets the reference rail (its offset along a 10 m chord
  of the reference rail), as the truth files both rails under one design chainage.

Each pass (a run in one direction between stops) is resampled on the chainage grid
``k * step_m`` (linear interpolation of the IMU-rate samples), so repeated passes line up.
The gauge readings of each pass are smoothed along chainage by the Wiener smoother of
:mod:`.gauge` (or averaged over a window, ``GaugeSmoothing(filter="box")``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d

from ..errors import TrackGeometryError
from ..sensors.types import GaugeData
from .gauge import MIN_READINGS, fit_gauge_spectrum, smooth_gauge


@dataclass(frozen=True)
class TrolleyGeometry:
    """What the traces need of the trolley: ``R_vb`` (3, 3) mounting rotation b -> v,
    ``lever_arm_imu_v`` (3,) [m], ``wheelbase_m`` [m], ``reference_rail`` "left"/"right"."""

    R_vb: np.ndarray
    lever_arm_imu_v: np.ndarray
    wheelbase_m: float
    reference_rail: str = "left"

    @property
    def other_rail(self) -> str:
        return "right" if self.reference_rail == "left" else "left"


@dataclass(frozen=True)
class TrajectoryOnTrack:
    """The dense smoothed trajectory with its chainage: ``t_s`` (N,) [s], ``R_nb`` (N, 3, 3),
    ``pos_n`` (N, 3) [m], ``chainage_m`` (N,) [m] of the trolley frame ``v``'s origin.
    ``absolute_positions``: the positions are georeferenced (GNSS), so they can be projected
    onto a design alignment (``geometry.chainage: auto``)."""

    t_s: np.ndarray
    R_nb: np.ndarray
    pos_n: np.ndarray
    chainage_m: np.ndarray
    absolute_positions: bool = True

    def select(self, sel) -> "TrajectoryOnTrack":
        """The samples ``sel`` (a slice over the N samples)."""
        return TrajectoryOnTrack(self.t_s[sel], self.R_nb[sel], self.pos_n[sel], self.chainage_m[sel],
                                 self.absolute_positions)


@dataclass(frozen=True)
class GaugeSmoothing:
    """How each pass's gauge readings become its gauge (:func:`gauge_along_pass`): ``filter``
    ``"wiener"`` or ``"box"``, the reading noise ``sigma_m`` [m] (None: fitted), the box width
    ``window_m`` [m] (None: one grid step); ``nominal_gauge_m`` [m] without gauge readings."""

    nominal_gauge_m: float = 1.435
    filter: str = "wiener"
    window_m: float | None = None
    sigma_m: float | None = None


@dataclass(frozen=True)
class Pass:
    """One pass: sample index range [start, stop) of the dense trajectory and its direction (+1/-1)."""

    start: int
    stop: int
    direction: int


@dataclass
class RailTraces:
    """Rail traces of one pass on the chainage grid: ``chainage_m`` (N,), ``left_n``, ``right_n``
    (N, 3) [m] in ``n``, ``gauge_m`` (N,) [m], ``t_s`` (N,) the time the trolley's origin was at
    each chainage, ``direction`` (+1 increasing chainage), ``gauge_filter`` how the gauge
    readings were smoothed (empty: nominal gauge)."""

    chainage_m: np.ndarray
    left_n: np.ndarray
    right_n: np.ndarray
    gauge_m: np.ndarray
    t_s: np.ndarray
    direction: int
    gauge_filter: dict = field(default_factory=dict)

    def rail(self, side: str) -> np.ndarray:
        return self.left_n if side == "left" else self.right_n


def split_passes(t_s: np.ndarray, chainage_m: np.ndarray, min_speed_mps: float = 0.05,
                 min_length_m: float = 1.0) -> list[Pass]:
    """Runs of motion in one direction (speed above ``min_speed_mps``) at least ``min_length_m`` long."""
    dt = float(np.median(np.diff(t_s)))
    v = uniform_filter1d(np.gradient(chainage_m, t_s), max(1, int(round(0.2 / dt))))  # 0.2 s mean
    moving = np.abs(v) > min_speed_mps
    direction = np.where(moving, np.sign(v), 0).astype(int)
    edges = np.flatnonzero(np.diff(direction)) + 1
    bounds = np.r_[0, edges, direction.size]
    passes = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        if direction[a] != 0 and abs(chainage_m[b - 1] - chainage_m[a]) >= min_length_m:
            passes.append(Pass(int(a), int(b), int(direction[a])))
    return passes


def box_mean(x: np.ndarray, y: np.ndarray, x_query: np.ndarray, width: float) -> np.ndarray:
    """Mean of the samples ``y`` (K,) with ``|x - x_q| <= width / 2`` at each ``x_query`` (M,)
    (nearest sample where the box holds none): averages a noisy reading over one grid step."""
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    c = np.r_[0.0, np.cumsum(y)]
    lo = np.searchsorted(x, x_query - width / 2, side="left")
    hi = np.searchsorted(x, x_query + width / 2, side="right")
    nearest = np.clip(np.searchsorted(x, x_query), 0, x.size - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (c[hi] - c[lo]) / (hi - lo)
    return np.where(hi > lo, mean, y[nearest])


def refine_with_attitude(grid: np.ndarray, ref_n: np.ndarray, s_origin: np.ndarray, x_n: np.ndarray,
                         wheelbase_m: float, crossover_m: float) -> np.ndarray:
    """The reference-rail trace (N, 3) on the uniform ``grid`` (N,) combined with the trolley's
    attitude: least squares of the two-wheel differences ``P(s + l/2) - P(s - l/2) = l x_n(s)``
    (x_n (M, 3) the trolley's x axis at the origin chainages s_origin (M,), interpolated to the
    grid) and the positions ``P = ref_n`` weighted ``w = 2 sin(pi l / crossover_m)``: at
    wavelengths below ``crossover_m`` the gyro-derived attitude shapes the trace, above it the
    fused positions (their weights are equal there). The differences alone leave the
    wavelengths ``l / k`` to the positions (the two-point instrument's zeros).
    """
    from scipy.sparse import coo_matrix, identity
    from scipy.sparse.linalg import spsolve

    step = grid[1] - grid[0]
    h = 0.5 * wheelbase_m
    inside = (grid - h >= grid[0]) & (grid + h <= grid[-1]) & (grid >= s_origin.min()) & (grid <= s_origin.max())
    k = np.flatnonzero(inside)
    x_grid = _on_grid(s_origin, x_n, grid[k])
    rows, cols, vals = [], [], []
    for sign, offset in ((1.0, h), (-1.0, -h)):
        f = (grid[k] + offset - grid[0]) / step
        i = np.clip(np.floor(f).astype(int), 0, grid.size - 2)
        frac = f - i
        r = np.arange(k.size)
        rows += [r, r]
        cols += [i, i + 1]
        vals += [sign * (1 - frac), sign * frac]
    D = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(k.size, grid.size)).tocsc()
    w2 = (2 * np.sin(np.pi * wheelbase_m / crossover_m)) ** 2
    A = (D.T @ D + w2 * identity(grid.size, format="csc")).tocsc()
    b = D.T @ (wheelbase_m * x_grid) + w2 * ref_n
    return np.asarray(spsolve(A, b)).reshape(ref_n.shape)


def _on_grid(s: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Linear interpolation of values (M, k) at chainages s (M,) onto grid (N,); NaN outside."""
    order = np.argsort(s, kind="stable")
    s, values = s[order], values[order]
    s = np.maximum.accumulate(s)
    out = np.column_stack([np.interp(grid, s, values[:, i], left=np.nan, right=np.nan)
                           for i in range(values.shape[1])])
    return out


def pass_traces(traj: TrajectoryOnTrack, trolley: TrolleyGeometry, gauge_m: np.ndarray, step_m: float,
                direction: int = 1, crossover_m: float | None = None) -> RailTraces:
    """Rail traces of one pass (module docstring).

    traj: the pass's M samples (:class:`TrajectoryOnTrack`), gauge_m (M,) [m] gauge at each
    sample (reading or nominal), step_m [m] grid step; crossover_m: combine with the attitude
    (:func:`refine_with_attitude`), or None.
    """
    t_s, R_nb, pos_n, chainage_m = traj.t_s, traj.R_nb, traj.pos_n, traj.chainage_m
    R_nv = R_nb @ trolley.R_vb.T
    origin = pos_n - R_nv @ np.asarray(trolley.lever_arm_imu_v, dtype=float)
    half = 0.5 * trolley.wheelbase_m
    x_n, y_n = R_nv[:, :, 0], R_nv[:, :, 1]
    lo = np.min(chainage_m) - half
    hi = np.max(chainage_m) + half
    # work on a grid fine enough for linear interpolation at the wheels (<= 5 cm, <= l/8),
    # whose every m-th point is an output point
    m = int(np.ceil(step_m / min(step_m, 0.05, trolley.wheelbase_m / 8) - 1e-9))
    fine = step_m / m
    grid = fine * np.arange(np.ceil(lo / step_m - 1e-9) * m, np.floor(hi / step_m + 1e-9) * m + 1)
    front = _on_grid(chainage_m + half, origin + half * x_n, grid)
    rear = _on_grid(chainage_m - half, origin - half * x_n, grid)
    ref = np.where(np.isnan(front), rear, np.where(np.isnan(rear), front, 0.5 * (front + rear)))
    ok = np.isfinite(ref[:, 0])
    if crossover_m is not None:
        ref[ok] = refine_with_attitude(grid[ok], ref[ok], chainage_m, x_n, trolley.wheelbase_m, crossover_m)
        origin = 0.5 * (np.column_stack([np.interp(chainage_m + half, grid[ok], ref[ok, i]) for i in range(3)])
                        + np.column_stack([np.interp(chainage_m - half, grid[ok], ref[ok, i]) for i in range(3)]))
    u = -y_n if trolley.reference_rail == "left" else y_n
    ref_at_origin = np.column_stack([np.interp(chainage_m, grid[ok], ref[ok, i]) for i in range(3)])
    w = gauge_m + np.sum((ref_at_origin - origin) * u, axis=1)
    other_n = origin + w[:, None] * u
    # the other rail's point belongs to the chainage where the track's cross-section through it
    # meets the reference rail: shift by its offset along the track direction (a 10 m chord of
    # the reference rail, which averages out the irregularities' slopes)
    ahead = np.column_stack([np.interp(chainage_m + 5.0, grid[ok], ref[ok, i]) for i in range(3)])
    behind = np.column_stack([np.interp(chainage_m - 5.0, grid[ok], ref[ok, i]) for i in range(3)])
    along = ahead - behind
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    s_other = chainage_m + np.sum((other_n - ref_at_origin) * along, axis=1)
    other = _on_grid(s_other, other_n, grid)
    extra = _on_grid(chainage_m, np.column_stack([gauge_m, t_s]), grid)
    on_output = np.abs(grid / step_m - np.round(grid / step_m)) < 1e-6
    keep = ok & np.isfinite(other[:, 0]) & on_output
    if np.count_nonzero(keep) < 4:
        raise TrackGeometryError("a pass covers fewer than 4 chainage steps; lower outputs.geometry_step_m")
    left, right = (ref, other) if trolley.reference_rail == "left" else (other, ref)
    return RailTraces(np.round(grid[keep] / step_m) * step_m, left[keep], right[keep], extra[keep, 0],
                      extra[keep, 1], direction)


def gauge_along_pass(s_reading_m: np.ndarray, reading_m: np.ndarray, s_query_m: np.ndarray, method: str,
                     window_m: float, sigma_m: float | None = None) -> tuple[np.ndarray, dict]:
    """One pass's gauge readings (K,) at chainages s_reading_m (K,) [m], at s_query_m (M,) [m]:
    the Wiener smoother (``method="wiener"``, :mod:`.gauge`; noise ``sigma_m`` from the spec or,
    None, fitted) or the mean over ``window_m`` (``"box"``, :func:`box_mean`; also when the pass
    has fewer than ``MIN_READINGS`` readings). Returns the values and what was done."""
    if method == "wiener" and s_reading_m.size >= MIN_READINGS:
        fit = fit_gauge_spectrum(s_reading_m, reading_m, sigma_m)
        return smooth_gauge(s_reading_m, reading_m, s_query_m, fit), fit.to_json()
    info = {"filter": "box", "window_m": float(window_m), "readings": int(s_reading_m.size)}
    return box_mean(s_reading_m, reading_m, s_query_m, window_m), info


def rail_traces(traj: TrajectoryOnTrack, trolley: TrolleyGeometry, step_m: float, gauge: GaugeData | None = None,
                smoothing: GaugeSmoothing = GaugeSmoothing(), min_speed_mps: float = 0.05, min_length_m: float = 1.0,
                crossover_m: float | None = None) -> list[RailTraces]:
    """Rail traces of every pass of a dense trajectory (module docstring); ``traj`` as in
    :func:`pass_traces` over the whole run; the gauge readings ``gauge`` (K,) are smoothed per
    pass by :func:`gauge_along_pass` (``smoothing``), or ``smoothing.nominal_gauge_m`` without
    them; ``crossover_m``: see :func:`refine_with_attitude`."""
    t_s, chainage_m = traj.t_s, traj.chainage_m
    passes = split_passes(t_s, chainage_m, min_speed_mps, min_length_m)
    if not passes:
        raise TrackGeometryError(f"the trajectory has no pass of at least {min_length_m:g} m in motion")
    gauge_m = np.full(t_s.shape, float(smoothing.nominal_gauge_m))
    filters: list[dict] = [{} for _ in passes]
    if gauge is not None and gauge.t_s.size >= 2:
        s_reading = np.interp(gauge.t_s, t_s, chainage_m)
        for k, p in enumerate(passes):
            inside = (gauge.t_s >= t_s[p.start]) & (gauge.t_s <= t_s[p.stop - 1])
            if np.count_nonzero(inside) < 2:
                raise TrackGeometryError(f"no gauge readings between t = {t_s[p.start]:.1f} and {t_s[p.stop - 1]:.1f} s")
            gauge_m[p.start:p.stop], filters[k] = gauge_along_pass(
                s_reading[inside], gauge.gauge_m[inside], chainage_m[p.start:p.stop], smoothing.filter,
                smoothing.window_m or step_m, smoothing.sigma_m)
    out = []
    for p, info in zip(passes, filters):
        tr = pass_traces(traj.select(slice(p.start, p.stop)), trolley, gauge_m[p.start:p.stop], step_m, p.direction,
                         crossover_m)
        tr.gauge_filter = info
        out.append(tr)
    return out
