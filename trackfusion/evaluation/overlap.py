"""Overlap residuals between passes or stations (seed 003, tables 1-4).

Seed 003 compares two curves over their common chainage (two total stations'
point clouds, or the two halves of a repeated pass) through the residuals
``r`` at corresponding points and tabulates: the maximum absolute value (the
seed prints it with its sign, e.g. -4.5 mm), the average, the standard
deviation, the slope of the least-squares trend line of ``r`` against
chainage (how parallel the curves are) and the relative accuracy
``std / overlap length`` in ppm (6.1 mm / 191 m = 31.9 ppm).
Here the standard deviation uses ``ddof = 1`` and the slope is dimensionless
(metres of residual per metre of chainage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import EvaluationError


@dataclass(frozen=True)
class OverlapStatistics:
    """Seed-003 residual statistics over one overlap.

    n_points; length_m: chainage span of the overlap; max_abs_mm = max |r|;
    max_abs_signed_mm: r at that point (with its sign, as seed 003 prints it);
    mean_mm; std_mm (ddof 1); trend_slope: slope of the fitted line r(s) (m/m);
    relative_accuracy_ppm = std / length * 1e6.
    """

    n_points: int
    length_m: float
    max_abs_mm: float
    max_abs_signed_mm: float
    mean_mm: float
    std_mm: float
    trend_slope: float

    @property
    def relative_accuracy_ppm(self) -> float:
        return self.std_mm * 1e-3 / self.length_m * 1e6

    def to_json(self) -> dict:
        return {"n_points": self.n_points, "length_m": self.length_m, "max_abs_mm": self.max_abs_mm,
                "max_abs_signed_mm": self.max_abs_signed_mm, "mean_mm": self.mean_mm, "std_mm": self.std_mm,
                "trend_slope": self.trend_slope, "relative_accuracy_ppm": self.relative_accuracy_ppm}


def overlap_statistics(chainage_m: np.ndarray, residual_m: np.ndarray) -> OverlapStatistics:
    """Seed-003 statistics of residuals residual_m (N,) m at chainage_m (N,) m; N >= 3 with a non-zero span."""
    s = np.asarray(chainage_m, dtype=float).ravel()
    r = np.asarray(residual_m, dtype=float).ravel()
    if s.size != r.size:
        raise EvaluationError(f"overlap: {s.size} chainages but {r.size} residuals")
    ok = np.isfinite(s) & np.isfinite(r)
    s, r = s[ok], r[ok]
    length = float(s.max() - s.min()) if s.size else 0.0
    if s.size < 3 or length <= 0:
        raise EvaluationError(f"overlap too short for statistics ({s.size} points over {length:.3f} m)")
    i = int(np.argmax(np.abs(r)))
    slope = float(np.polyfit(s - s.mean(), r, 1)[0])
    return OverlapStatistics(n_points=int(s.size), length_m=length, max_abs_mm=float(1e3 * abs(r[i])),
                             max_abs_signed_mm=float(1e3 * r[i]), mean_mm=float(1e3 * r.mean()),
                             std_mm=float(1e3 * r.std(ddof=1)), trend_slope=slope)


def overlap_residuals(chainage_a_m: np.ndarray, values_a_m: np.ndarray, chainage_b_m: np.ndarray,
                      values_b_m: np.ndarray, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``b - a`` at common chainage: both curves interpolated linearly on ``k * step_m``
    over the span they share. Returns (chainage_m (N,), residual_m (N,)).

    Each curve's chainage may increase or decrease. Raises :class:`EvaluationError` when they share no grid point.
    """
    sa, va = _sorted(chainage_a_m, values_a_m)
    sb, vb = _sorted(chainage_b_m, values_b_m)
    lo, hi = max(sa[0], sb[0]), min(sa[-1], sb[-1])
    k0, k1 = int(np.ceil(lo / step_m - 1e-9)), int(np.floor(hi / step_m + 1e-9))
    if k1 < k0:
        raise EvaluationError(f"the curves do not overlap (a: {sa[0]:.3f}..{sa[-1]:.3f} m, "
                              f"b: {sb[0]:.3f}..{sb[-1]:.3f} m)")
    grid = np.arange(k0, k1 + 1) * step_m
    return grid, np.interp(grid, sb, vb) - np.interp(grid, sa, va)


def _sorted(s, v) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(s, dtype=float).ravel()
    v = np.asarray(v, dtype=float).ravel()
    if s.size == 0 or s.size != v.size:
        raise EvaluationError(f"overlap: a curve needs matching, non-empty chainage and values ({s.size}, {v.size})")
    order = np.argsort(s, kind="stable")
    return s[order], v[order]
