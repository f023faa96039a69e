"""Repeatability across repeated runs of the same track (seed 000, tables 2 and 3).

Seed 000 measures one rail five times, computes "the repeatability of each
point by using its corresponding five irregularities" and tabulates the
number of points, the number and share of points whose repeatability exceeds
a limit (0.1 mm for the 1 m chord, 1 mm for the 10 m chord) and the mean,
maximum and minimum repeatability (the mean being "the repeatability" of the
instrument). The seed does not spell out the per-point spread; here it is the
sample standard deviation across runs (``ddof = 1``, the default) or, with
``spread="range"``, max - min across runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import EvaluationError


@dataclass(frozen=True)
class RepeatabilityResult:
    """Seed-000 table 2/3 figures.

    chainage_m (N,) point chainage (or index when none was given); spread_mm (N,)
    per-point spread across the R runs; limit_mm: the limit; n_points,
    n_above (spread > limit), share_above_pct; mean/max/min of spread_mm;
    n_runs; spread: "std" or "range".
    """

    chainage_m: np.ndarray
    spread_mm: np.ndarray
    limit_mm: float
    n_runs: int
    spread: str

    @property
    def n_points(self) -> int:
        return int(self.spread_mm.size)

    @property
    def n_above(self) -> int:
        return int(np.count_nonzero(self.spread_mm > self.limit_mm))

    @property
    def share_above_pct(self) -> float:
        return 100.0 * self.n_above / self.n_points

    @property
    def mean_mm(self) -> float:
        return float(self.spread_mm.mean())

    @property
    def max_mm(self) -> float:
        return float(self.spread_mm.max())

    @property
    def min_mm(self) -> float:
        return float(self.spread_mm.min())

    def to_json(self) -> dict:
        return {"n_runs": self.n_runs, "spread": self.spread, "n_points": self.n_points,
                "limit_mm": float(self.limit_mm), "n_above_limit": self.n_above,
                "share_above_limit_pct": self.share_above_pct, "mean_repeatability_mm": self.mean_mm,
                "max_repeatability_mm": self.max_mm, "min_repeatability_mm": self.min_mm}

    def format_table(self) -> str:
        return (f"points {self.n_points}  > {self.limit_mm:g} mm: {self.n_above} ({self.share_above_pct:.1f} %)  "
                f"repeatability mean {self.mean_mm:.3f} mm, max {self.max_mm:.3f} mm, min {self.min_mm:.3f} mm "
                f"({self.spread} over {self.n_runs} runs)")


def repeatability(values_m: np.ndarray, limit_mm: float = 0.1, chainage_m: np.ndarray | None = None,
                  spread: str = "std") -> RepeatabilityResult:
    """Per-point spread of R runs of one quantity sampled at the same N points.

    values_m: (R, N) values (m), one row per run; columns with a NaN in any
    run are skipped. limit_mm: the per-point limit (seed 000: 0.1 mm for the
    1 m chord, 1 mm for the 10 m chord). chainage_m: (N,) point chainage.
    spread: ``"std"`` (sample standard deviation across runs) or ``"range"``.
    """
    v = np.asarray(values_m, dtype=float)
    if v.ndim != 2 or v.shape[0] < 2:
        raise EvaluationError(f"repeatability needs at least two runs as an (R, N) array, got shape {v.shape}")
    s = np.arange(v.shape[1], dtype=float) if chainage_m is None else np.asarray(chainage_m, dtype=float)
    ok = np.isfinite(v).all(axis=0)
    if not ok.any():
        raise EvaluationError("repeatability: no point is covered by every run")
    v, s = v[:, ok], s[ok]
    if spread == "std":
        per_point = v.std(axis=0, ddof=1)
    elif spread == "range":
        per_point = v.max(axis=0) - v.min(axis=0)
    else:
        raise EvaluationError(f"spread must be 'std' or 'range', got {spread!r}")
    return RepeatabilityResult(chainage_m=s, spread_mm=1e3 * per_point, limit_mm=float(limit_mm),
                               n_runs=int(v.shape[0]), spread=spread)


def runs_on_common_grid(runs: Sequence[tuple[np.ndarray, np.ndarray]], step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Put runs ``[(chainage_m (N_r,), values (N_r,)), ...]`` on the chainage grid ``k * step_m``
    they all cover (linear interpolation). Returns (grid_m (N,), values (R, N)).

    Each run's chainage may increase or decrease (it is sorted first).
    Raises :class:`EvaluationError` when the runs share no grid point.
    """
    if len(runs) < 2:
        raise EvaluationError("repeatability needs at least two runs")
    lo = max(float(np.min(s)) for s, _ in runs)
    hi = min(float(np.max(s)) for s, _ in runs)
    k0, k1 = int(np.ceil(lo / step_m - 1e-9)), int(np.floor(hi / step_m + 1e-9))
    if k1 < k0:
        raise EvaluationError(f"the runs share no chainage (common span {lo:.3f}..{hi:.3f} m)")
    grid = np.arange(k0, k1 + 1) * step_m
    rows = []
    for s, v in runs:
        order = np.argsort(np.asarray(s, dtype=float), kind="stable")
        rows.append(np.interp(grid, np.asarray(s, dtype=float)[order], np.asarray(v, dtype=float)[order]))
    return grid, np.vstack(rows)
