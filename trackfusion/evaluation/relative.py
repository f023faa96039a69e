"""Relative accuracy over distance scales (seed 002, eqs. 1-6, 10, 16).

The input is an error series sampled on a *uniform distance grid* of spacing
``step_m`` (one 1-D array per monotonic pass; see
:mod:`trackfusion.evaluation.errors_series`). A distance scale ``L`` is a
whole number ``m = L / step_m`` of grid steps. Every statistic returns the
unit of its input (the result object converts metres to millimetres).

Statistics (``x`` is the error, ``N`` grid points, all passes pooled: sums of
squares and term counts are added over the passes, no difference ever spans
two passes):

``sigma_eq1``
    eq. 1, ``sqrt(sum x_i^2 / (N - 1))`` -- the absolute error (no mean removed).
``sigma1``
    eqs. 2 and 10 (the paper's "MSE"): root mean square of the differences
    between points a distance ``L`` apart, ``x(l + L) - x(l)``, taken at every
    grid point ``l`` (every point is an ``A_i`` of eq. 10; the divisor is the
    number of differences, ``N1 - 1`` of eq. 2).
``sigma2``
    eq. 3: root mean square of the differences between the means of adjacent,
    non-overlapping clusters of length ``L`` (clusters start at the first grid
    point of each pass; a trailing partial cluster is dropped).
``allan_deviation``
    eqs. 5-6: ``sigma2 / sqrt(2)``, the classical (non-overlapping) Allan
    deviation of ``x`` treated as the averaged quantity (allantools' ``adev``
    with ``data_type="freq"``, ``rate = 1 / step_m``, ``taus = L``).
``overlapping_allan_deviation``
    the overlapping estimator of eq. 5: cluster means of length ``L`` starting
    at every grid point, differences at lag ``L`` (allantools' ``oadev``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import EvaluationError

#: Default distance scales L (m).
DEFAULT_SCALES_M: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)

Passes = np.ndarray | Sequence[np.ndarray]


def _as_passes(x: Passes) -> list[np.ndarray]:
    """One float array per pass: a 1-D array is one pass, a 2-D array one pass per row."""
    if isinstance(x, np.ndarray):
        if x.ndim == 1:
            return [x.astype(float, copy=False)]
        if x.ndim == 2:
            return [row.astype(float, copy=False) for row in x]
        raise ValueError(f"error series must be 1-D or 2-D, got shape {x.shape}")
    return [np.asarray(p, dtype=float).ravel() for p in x]


def _root_mean(sum_sq: float, count: int) -> float:
    return float(np.sqrt(sum_sq / count)) if count > 0 else float("nan")


def scale_samples(scale_m: float, step_m: float) -> int:
    """The number of grid steps ``m`` of the distance scale ``scale_m`` (m).

    Raises :class:`EvaluationError` unless ``scale_m`` is a whole multiple
    (to 1e-6 relative) of ``step_m`` and at least one step.
    """
    if not (step_m > 0 and np.isfinite(step_m)):
        raise EvaluationError(f"grid step must be positive, got {step_m!r} m")
    m = int(round(scale_m / step_m))
    if m < 1 or abs(m * step_m - scale_m) > 1e-6 * max(scale_m, step_m):
        raise EvaluationError(
            f"distance scale {scale_m!r} m is not a whole multiple of the grid step {step_m!r} m")
    return m


def lag_difference_sums(x: Passes, m: int) -> tuple[float, int]:
    """``(sum of (x[i+m] - x[i])^2, number of differences)`` pooled over passes (eq. 2 terms)."""
    ss, n = 0.0, 0
    for p in _as_passes(x):
        if p.size > m:
            d = p[m:] - p[:-m]
            ss += float(d @ d)
            n += d.size
    return ss, n


def cluster_difference_sums(x: Passes, m: int) -> tuple[float, int]:
    """``(sum of squared differences of adjacent non-overlapping m-means, count)`` (eq. 3 terms)."""
    ss, n = 0.0, 0
    for p in _as_passes(x):
        k = p.size // m
        if k >= 2:
            means = p[: k * m].reshape(k, m).mean(axis=1)
            d = np.diff(means)
            ss += float(d @ d)
            n += d.size
    return ss, n


def overlapping_cluster_difference_sums(x: Passes, m: int) -> tuple[float, int]:
    """``(sum of squared lag-m differences of the moving m-means, count)`` (overlapping eq. 5 terms)."""
    ss, n = 0.0, 0
    for p in _as_passes(x):
        if p.size >= 2 * m:
            q = p - p.mean()  # centred: keeps the running sum well conditioned
            c = np.concatenate(([0.0], np.cumsum(q)))
            means = (c[m:] - c[:-m]) / m  # (size - m + 1,) means of q[j : j + m]
            d = means[m:] - means[:-m]
            ss += float(d @ d)
            n += d.size
    return ss, n


def sigma_eq1(x: Passes) -> float:
    """Seed 002 eq. 1: ``sqrt(sum x^2 / (N - 1))`` over every point of every pass (unit of x)."""
    parts = _as_passes(x)
    n = sum(p.size for p in parts)
    if n < 2:
        return float("nan")
    return float(np.sqrt(sum(float(p @ p) for p in parts) / (n - 1)))


def sigma1(x: Passes, m: int) -> float:
    """Seed 002 eqs. 2/10 ("MSE"): RMS of differences between points m grid steps apart (unit of x)."""
    return _root_mean(*lag_difference_sums(x, m))


def sigma2(x: Passes, m: int) -> float:
    """Seed 002 eq. 3: RMS of differences between adjacent non-overlapping m-point cluster means."""
    return _root_mean(*cluster_difference_sums(x, m))


def allan_deviation(x: Passes, m: int) -> float:
    """Seed 002 eqs. 5-6: non-overlapping Allan deviation, ``sigma2(x, m) / sqrt(2)``."""
    return sigma2(x, m) / np.sqrt(2.0)


def overlapping_allan_deviation(x: Passes, m: int) -> float:
    """Overlapping Allan deviation at m grid steps (cluster means starting at every point)."""
    ss, n = overlapping_cluster_difference_sums(x, m)
    return _root_mean(ss / 2.0, n)


@dataclass(frozen=True)
class RelativeAccuracy:
    """Seed-002 statistics of one error component over distance scales.

    Arrays have shape (S,), one entry per scale in ``scales_m``; an entry is
    NaN (``null`` in JSON) where the series is too short for that scale.
    ``n_points``: grid points used; ``n_pairs``/``n_cluster_differences``/
    ``n_overlapping_differences``: number of terms in eqs. 2, 3 and the
    overlapping estimator at each scale.
    """

    scales_m: np.ndarray
    step_m: float
    sigma_mm: float
    mse_mm: np.ndarray
    sigma2_mm: np.ndarray
    adev_mm: np.ndarray
    oadev_mm: np.ndarray
    n_points: int
    n_pairs: np.ndarray
    n_cluster_differences: np.ndarray
    n_overlapping_differences: np.ndarray

    def index_of(self, scale_m: float) -> int:
        """Index of ``scale_m`` in ``scales_m``; :class:`EvaluationError` when absent."""
        hits = np.flatnonzero(np.isclose(self.scales_m, scale_m, rtol=1e-9, atol=1e-12))
        if hits.size == 0:
            raise EvaluationError(f"distance scale {scale_m} m was not evaluated")
        return int(hits[0])

    def to_json(self) -> dict:
        """JSON-able dict (DESIGN.md section 4 keys first; NaN becomes null)."""
        return {
            "scales_m": [float(s) for s in self.scales_m],
            "sigma_mm": _json_float(self.sigma_mm),
            "mse_mm": _json_list(self.mse_mm),
            "adev_mm": _json_list(self.adev_mm),
            "sigma2_mm": _json_list(self.sigma2_mm),
            "oadev_mm": _json_list(self.oadev_mm),
            "n_points": int(self.n_points),
            "n_pairs": [int(v) for v in self.n_pairs],
            "n_cluster_differences": [int(v) for v in self.n_cluster_differences],
            "grid_step_m": float(self.step_m),
        }


def _json_float(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _json_list(a: np.ndarray) -> list[float | None]:
    return [_json_float(v) for v in np.asarray(a, dtype=float)]


def relative_accuracy(x_m: Passes, step_m: float,
                      scales_m: Sequence[float] = DEFAULT_SCALES_M) -> RelativeAccuracy:
    """Every seed-002 statistic of an error series on a uniform distance grid.

    x_m: errors (m), one 1-D array per monotonic pass (or one (N,) array, or
    (P, N) for P passes of equal length), sampled every ``step_m`` metres of
    chainage. scales_m: distance scales L (m), each a whole multiple of
    ``step_m``. Returns the statistics in millimetres.
    """
    scales = np.asarray(scales_m, dtype=float).ravel()
    if scales.size == 0:
        raise EvaluationError("no distance scales given")
    parts = _as_passes(x_m)
    lags = [scale_samples(s, step_m) for s in scales]
    pair = np.array([lag_difference_sums(parts, m) for m in lags], dtype=float).reshape(-1, 2)
    clus = np.array([cluster_difference_sums(parts, m) for m in lags], dtype=float).reshape(-1, 2)
    over = np.array([overlapping_cluster_difference_sums(parts, m) for m in lags], dtype=float).reshape(-1, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mse = np.sqrt(pair[:, 0] / pair[:, 1])
        s2 = np.sqrt(clus[:, 0] / clus[:, 1])
        oadev = np.sqrt(over[:, 0] / (2.0 * over[:, 1]))
    return RelativeAccuracy(
        scales_m=scales, step_m=float(step_m), sigma_mm=1e3 * sigma_eq1(parts),
        mse_mm=1e3 * mse, sigma2_mm=1e3 * s2, adev_mm=1e3 * s2 / np.sqrt(2.0), oadev_mm=1e3 * oadev,
        n_points=sum(p.size for p in parts), n_pairs=pair[:, 1].astype(int),
        n_cluster_differences=clus[:, 1].astype(int), n_overlapping_differences=over[:, 1].astype(int))
