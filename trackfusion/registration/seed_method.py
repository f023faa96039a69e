"""Seed 003's registration of one station's point cloud onto another's (section 2.2.1).

Over the chainage the two stations share, the *target* curve (the later station) is

1. rotated in the X-Z plane (X along the track, Z up) about its station centre by the angle
   that minimises the variance of the elevation residuals to the *reference* curve (eq. 1),
2. translated vertically by the mean residual (eq. 2), and
3. translated across the track (the X-Y plane: translation only, no rotation).

Corresponding points are those of equal chainage (odometer distance): each curve is
interpolated linearly on a common chainage grid (:func:`trackfusion.evaluation.overlap.overlap_residuals`).
X is the horizontal direction of the reference curve's chord over the overlap, Y = Z x X is
across the track (left). The seed's bridge is straight; on a curved overlap the chord frame
is an approximation of this method, not of the fusion.

The rotation is solved exactly (Newton on the variance of ``M sin t + H cos t - H_ref``), so a
noise-free target made by rotating and translating the reference is recovered to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RegistrationError
from ..evaluation.overlap import overlap_residuals


@dataclass(frozen=True)
class SeedRegistration:
    """Rotation ``theta_rad`` in the X-Z plane about ``centre_n`` (positive lifts points ahead,
    +X), vertical translation ``dz_m`` and cross-track translation ``dy_m``, in the frame
    ``axes_n`` (3,3) rows X, Y, Z; ``overlap_m`` the chainage span used."""

    theta_rad: float
    dz_m: float
    dy_m: float
    centre_n: np.ndarray
    axes_n: np.ndarray
    overlap_m: tuple[float, float]

    def apply(self, points_n: np.ndarray) -> np.ndarray:
        """The registered points (N,3) [m] of target points (N,3) in ``n``."""
        local = (np.asarray(points_n, dtype=float) - self.centre_n) @ self.axes_n.T
        c, s = np.cos(self.theta_rad), np.sin(self.theta_rad)
        m, y, h = local.T
        out = np.column_stack([m * c - h * s, y + self.dy_m, m * s + h * c + self.dz_m])
        return self.centre_n + out @ self.axes_n

    def to_json(self) -> dict:
        return {"theta_arcsec": float(np.degrees(self.theta_rad) * 3600.0), "dz_mm": 1e3 * self.dz_m,
                "dy_mm": 1e3 * self.dy_m, "overlap_m": list(self.overlap_m)}


def overlap_axes(chainage_m: np.ndarray, points_n: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Rows X (horizontal chord direction of increasing chainage), Y = Z x X, Z = up (3,3)."""
    s = np.asarray(chainage_m, dtype=float)
    sel = (s >= lo) & (s <= hi)
    if np.count_nonzero(sel) < 2:
        raise RegistrationError(f"overlap {lo:.1f}..{hi:.1f} m holds fewer than 2 reference points")
    ends = [points_n[sel][np.argmin(s[sel])], points_n[sel][np.argmax(s[sel])]]
    x = np.array([ends[1][0] - ends[0][0], ends[1][1] - ends[0][1], 0.0])
    if np.linalg.norm(x) == 0:
        raise RegistrationError("overlap: the reference curve does not move horizontally")
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, 1.0])
    return np.vstack([x, np.cross(z, x), z])


def _xz_rotation(m: np.ndarray, h: np.ndarray, h_ref: np.ndarray) -> float:
    """Angle minimising var(m sin t + h cos t - h_ref) (Newton from the small-angle solution)."""
    def cov(a, b):
        return float(np.mean((a - a.mean()) * (b - b.mean())))
    theta = -cov(m, h - h_ref) / cov(m, m)
    for _ in range(50):
        c, s = np.cos(theta), np.sin(theta)
        f, df, d2f = m * s + h * c - h_ref, m * c - h * s, -m * s - h * c
        step = cov(f, df) / (cov(df, df) + cov(f, d2f))
        theta -= step
        if abs(step) < 1e-16:
            break
    return float(theta)


def register_seed(ref_chainage_m: np.ndarray, ref_n: np.ndarray, tgt_chainage_m: np.ndarray, tgt_n: np.ndarray,
                  centre_n: np.ndarray, step_m: float = 0.25) -> SeedRegistration:
    """Register target points (M,3) at chainages (M,) onto reference points (N,3) at (N,)
    (module docstring); ``centre_n`` (3,) the target station's instrument point."""
    grid, _ = overlap_residuals(ref_chainage_m, ref_n[:, 2], tgt_chainage_m, tgt_n[:, 2], step_m)
    if grid.size < 3:
        raise RegistrationError(f"the stations' point clouds share only {grid.size} chainage grid points")
    axes = overlap_axes(ref_chainage_m, ref_n, grid[0], grid[-1])
    centre = np.asarray(centre_n, dtype=float)
    ref_local = _on_grid(ref_chainage_m, (ref_n - centre) @ axes.T, grid)
    tgt_local = _on_grid(tgt_chainage_m, (tgt_n - centre) @ axes.T, grid)
    theta = _xz_rotation(tgt_local[:, 0], tgt_local[:, 2], ref_local[:, 2])
    h_rot = tgt_local[:, 0] * np.sin(theta) + tgt_local[:, 2] * np.cos(theta)
    dz = float(np.mean(ref_local[:, 2] - h_rot))
    dy = float(np.mean(ref_local[:, 1] - tgt_local[:, 1]))
    return SeedRegistration(theta, dz, dy, centre, axes, (float(grid[0]), float(grid[-1])))


def _on_grid(chainage_m: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Each column of values (N,3) interpolated linearly at grid (G,) (chainage sorted first)."""
    order = np.argsort(chainage_m, kind="stable")
    s = np.asarray(chainage_m)[order]
    return np.column_stack([np.interp(grid, s, values[order, i]) for i in range(values.shape[1])])
