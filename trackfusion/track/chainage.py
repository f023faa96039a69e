"""Chainage of measured points: projection onto a design alignment, and regridding a pass.

Projection: the design chainage of a point is where the design centreline's normal plane
through the point meets the centreline (horizontal). Start from the nearest of the
centreline sampled every metre, then Newton steps ``s <- s + (p - c(s)) . t(s)`` (``t`` the
horizontal unit tangent); the steps converge to sub-micrometre in three iterations on
curves of radius above ~50 m.

Not implemented: seed 001's odometry by curvature matching (for runs with neither
positioning nor a reliable odometer); see docs/geometry.md.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import TrackGeometryError
from .design import DesignAlignment
from .traces import RailTraces


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

    return RailTraces(grid, at(tr.left_n), at(tr.right_n), at(tr.gauge_m), at(tr.t_s), tr.direction)
