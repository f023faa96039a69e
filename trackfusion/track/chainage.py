"""Chainage of measured points: projection onto a design alignment, and regridding a pass.

Projection: the design chainage of a point is where the design centreline's normal plane
through the point meets the centreline (horizontal). Start from the nearest of the
centreline sampled every metre, then Newton steps ``s <- s + (p - c(s)) . t(s)`` (``t`` the
horizontal unit tangent); the steps converge to sub-micrometre in three iterations on
curves of radius above ~50 m.

Odometry by curvature matching (seed 001 section 8), for runs with neither positioning nor a
reliable odometer: the measured horizontal curvature ``rho_exp = omega_z / V`` (here the
derivative of the trolley's heading along the approximate chainage ``s_app``) is compared with
each curvature function of the design (a curve from the start of its entry transition to the
end of its exit transition, width ``ds``): the normalised squared error (eqs. 49-51)
``ne2(s) = int_{s-ds}^{s} [rho_exp(u) - rho_ideal(u - s + s_exit)]^2 du / int rho_ideal^2`` is
about 1 on straight track and 0 where the two match; its minimum locates the curve's exit
(and so its entry) in ``s_app``. Between the matched entries and exits ``s_app`` is mapped
linearly onto the design chainage (seed 001 fig. 17); before the first and after the last
matched point the nearest correction is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import TrackGeometryError
from .design import DesignAlignment
from .traces import RailTraces, split_passes


def project_onto_design(points_n: np.ndarray, design: DesignAlignment, iterations: int = 4) -> np.ndarray:
    """Design chainage [m] (N,) of points (N, 3) in the design's ``n`` (module docstring)."""
    p = np.asarray(points_n, dtype=float)
    s_coarse = np.linspace(0.0, design.length_m, max(2, int(np.ceil(design.length_m)) + 1))
    c = design.evaluate(s_coarse).pos_n
    _, k = cKDTree(c[:, :2]).query(p[:, :2])
    s = s_coarse[k]
    for _ in range(iterations):
        d = design.evaluate(np.clip(s, 0.0, design.length_m))
        t = np.column_stack([np.cos(d.heading_rad), np.sin(d.heading_rad)])
        s = s + np.sum((p[:, :2] - d.pos_n[:, :2]) * t, axis=1)
    if np.any(s < -1.0) or np.any(s > design.length_m + 1.0):
        raise TrackGeometryError(f"measured points project outside the design alignment "
                                 f"[0, {design.length_m:g}] m (is the design in the survey's frame n?)")
    return np.clip(s, 0.0, design.length_m)


def regrid(tr: RailTraces, new_chainage_m: np.ndarray, step_m: float) -> RailTraces:
    """The pass ``tr`` with its chainage replaced by ``new_chainage_m`` (N,) (e.g. the design
    chainage) and resampled on the grid ``k * step_m`` it covers (linear interpolation)."""
    s = np.asarray(new_chainage_m, dtype=float)
    o = np.argsort(s, kind="stable")
    s = s[o]
    if np.any(np.diff(s) <= 0):
        raise TrackGeometryError("the projected chainage does not increase along the pass")
    grid = step_m * np.arange(np.ceil(s[0] / step_m - 1e-9), np.floor(s[-1] / step_m + 1e-9) + 1)

    def at(v: np.ndarray) -> np.ndarray:
        v = v[o]
        return np.column_stack([np.interp(grid, s, v[:, i]) for i in range(v.shape[1])]) if v.ndim == 2 \
            else np.interp(grid, s, v)

    return RailTraces(grid, at(tr.left_n), at(tr.right_n), at(tr.gauge_m), at(tr.t_s), tr.direction,
                      tr.gauge_filter)


def curvature_functions(design: DesignAlignment, step_m: float = 0.5) -> list[tuple[float, float]]:
    """(start, end) design chainage [m] of each curvature function: a run of non-zero curvature."""
    s = np.arange(0.0, design.length_m + 1e-9, step_m)
    curved = np.abs(design.evaluate(s).curvature_h_1pm) > 1e-9
    edges = np.flatnonzero(np.diff(curved.astype(int)))
    starts = [s[i + 1] if not curved[i] else s[i] for i in edges if not curved[i]]
    ends = [s[i] for i in edges if curved[i]]
    if curved[0]:
        starts = [0.0] + starts
    if curved[-1]:
        ends = ends + [s[-1]]
    return [(float(a) - step_m, float(b) + step_m) for a, b in zip(starts, ends)]


def _best_end(grid: np.ndarray, k_grid: np.ndarray, design: DesignAlignment, a: float, b: float,
              expected_end: float, search_m: float, step_m: float) -> tuple[float, float]:
    """s_app where the window of the design curvature over [a, b] ends best (eq. 49), and its ne2."""
    n_t = max(2, int(round((b - a) / step_m)))
    template = design.evaluate(np.clip(b - step_m * np.arange(n_t)[::-1], 0, design.length_m)).curvature_h_1pm
    i2 = np.sum(template ** 2) * step_m
    ends = np.flatnonzero((grid >= expected_end - search_m) & (grid <= expected_end + search_m)
                          & (np.arange(grid.size) >= n_t - 1))
    if ends.size == 0 or i2 == 0:
        return np.nan, np.inf
    windows = k_grid[ends[:, None] - n_t + 1 + np.arange(n_t)[None, :]]
    ne2 = np.sum((windows - template[None, :]) ** 2, axis=1) * step_m / i2
    j = int(np.argmin(ne2))
    return float(grid[ends[j]]), float(ne2[j])


def match_curves(s_app_m: np.ndarray, curvature_1pm: np.ndarray, design: DesignAlignment,
                 search_m: float = 50.0, step_m: float = 0.5, max_ne2: float = 0.5) -> list[tuple[float, float]]:
    """Anchor pairs (s_app, s_design) [m] at the entry and exit of each design curve that the
    measured curvature (N,) against ``s_app_m`` (N,) matches (module docstring). The entry and
    the exit half of each curvature function are matched separately, so an odometer scale error
    does not stretch one into the other: the minimum of ``ne2`` within ``search_m`` of where
    ``s_app`` expects it, accepted below ``max_ne2``."""
    order = np.argsort(s_app_m, kind="stable")
    sa, k = s_app_m[order], curvature_1pm[order]
    grid = np.arange(sa[0], sa[-1], step_m)
    k_grid = np.interp(grid, sa, k)
    anchors = []
    for a, b in curvature_functions(design, step_m):
        mid = 0.5 * (a + b)
        entry_end, ne2_entry = _best_end(grid, k_grid, design, a, mid, mid, search_m, step_m)
        exit_end, ne2_exit = _best_end(grid, k_grid, design, mid, b, b, search_m, step_m)
        if ne2_entry <= max_ne2:
            anchors.append((entry_end - (mid - a), a))
        if ne2_exit <= max_ne2:
            anchors.append((exit_end, b))
    return anchors


@dataclass(frozen=True)
class CurvatureMatching:
    """Settings of :func:`curvature_matched_chainage`: the first match's search window
    ``search_m`` [m] (10 m on the re-matches), the speed ``min_speed_mps`` [m/s] splitting the
    run into passes, the number of matchings ``iterations``, the matching grid's ``step_m`` [m]."""

    search_m: float = 50.0
    min_speed_mps: float = 0.05
    iterations: int = 3
    step_m: float = 0.2


def curvature_matched_chainage(t_s: np.ndarray, R_nv: np.ndarray, chainage_m: np.ndarray,
                               design: DesignAlignment, start_chainage_m: float,
                               settings: CurvatureMatching = CurvatureMatching()) -> tuple[np.ndarray, list]:
    """Design chainage (N,) of a run from its approximate chainage (N,) (odometer or integrated
    speed, 0 at the start, placed at ``start_chainage_m``) by curvature matching, pass by pass.
    The heading of the trolley's x axis (``R_nv`` (N, 3, 3)) gives the curvature. Returns the
    chainage and the anchors ``(s_app, s_design)`` of each pass; a pass without a matched curve
    keeps ``s_app``. The matching is repeated ``settings.iterations`` times on the corrected
    chainage."""
    search_m, step_m = settings.search_m, settings.step_m
    s_app = start_chainage_m + np.asarray(chainage_m, dtype=float)
    heading = np.unwrap(np.arctan2(R_nv[:, 1, 0], R_nv[:, 0, 0]))
    out = s_app.copy()
    all_anchors = []
    for p in split_passes(t_s, s_app, settings.min_speed_mps, 5.0):
        sl = slice(p.start, p.stop)
        s_p = s_app[sl]
        order = np.argsort(s_p, kind="stable")
        grid = np.arange(s_p.min(), s_p.max(), step_m)
        h_grid = np.interp(grid, s_p[order], heading[sl][order])
        mapped = grid.copy()
        anchors: list = []
        for _ in range(settings.iterations):  # re-match on the corrected chainage: removes the scale's stretch
            found = match_curves(mapped, np.gradient(h_grid, mapped), design, search_m, step_m)
            if not found:
                break
            xa, xd = np.array(found).T
            o = np.argsort(xa)
            mapped = mapped + np.interp(mapped, xa[o], (xd - xa)[o])
            anchors = found
            search_m = min(search_m, 10.0)
        all_anchors.append([(float(g), float(m)) for g, m in zip(*_anchor_points(grid, mapped, anchors))])
        if anchors:
            out[sl] = np.interp(s_p, grid, mapped)
    return out, all_anchors


def _anchor_points(grid: np.ndarray, mapped: np.ndarray, anchors: list) -> tuple[np.ndarray, np.ndarray]:
    """The approximate chainage of each anchor's design chainage under the final mapping."""
    if not anchors:
        return np.zeros(0), np.zeros(0)
    design_s = np.array([d for _, d in anchors])
    return np.interp(design_s, mapped, grid), design_s
