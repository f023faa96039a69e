"""Evaluate an estimated trajectory against a reference: seed-002 relative accuracy, pass/fail, overlaps.

``evaluate_files(estimate.csv, reference.csv)`` reads both trajectory CSVs
(the only file I/O here, through :mod:`trackfusion.sensors.fileio`) and calls
:func:`evaluate_trajectories`, which is pure maths:

1. error series along / lateral / vertical over the moving part, resampled on
   a uniform chainage grid (:mod:`.errors_series`);
2. seed-002 statistics per component at every distance scale (:mod:`.relative`);
3. pass/fail at ``threshold_scale_m`` (5 m): MSE (eq. 10) <= 0.67 mm and
   ADEV (eq. 16) <= 0.16 mm for each checked component (vertical and lateral
   by default, as the seed evaluates them);
4. seed-003 overlap statistics between consecutive passes over their common
   chainage (the residual is the difference of the two passes' errors, i.e.
   of their estimated positions where the reference passes coincide).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import EvaluationError
from ..sensors.fileio import read_csv_table, read_sidecar
from .errors_series import COMPONENTS, DistanceSeries, ErrorSeries, Trajectory, error_series, resample_on_distance
from .overlap import OverlapStatistics, overlap_statistics
from .relative import DEFAULT_SCALES_M, RelativeAccuracy, relative_accuracy

#: Columns ``evaluate`` needs in both files.
REQUIRED_COLUMNS: tuple[str, ...] = ("t_s", "e_m", "n_m", "u_m", "ve_mps", "vn_mps", "vu_mps", "chainage_m")


@dataclass(frozen=True)
class EvaluationConfig:
    """Settings of an evaluation.

    scales_m: distance scales L (m), whole multiples of grid_step_m.
    grid_step_m: chainage grid spacing (m). min_speed_mps: horizontal speed
    below which a sample is static. max_gap_s: time gap that splits a pass.
    threshold_scale_m, mse_threshold_mm, adev_threshold_mm: seed 002 eqs. 10
    and 16. checked_components: components that must pass.
    overlap_min_length_m: shortest common chainage of two passes reported.
    """

    scales_m: tuple[float, ...] = DEFAULT_SCALES_M
    grid_step_m: float = 0.05
    min_speed_mps: float = 0.1
    max_gap_s: float = 1.0
    threshold_scale_m: float = 5.0
    mse_threshold_mm: float = 0.67
    adev_threshold_mm: float = 0.16
    checked_components: tuple[str, ...] = ("vertical", "lateral")
    overlap_min_length_m: float = 1.0

    def __post_init__(self) -> None:
        unknown = [c for c in self.checked_components if c not in COMPONENTS]
        if unknown:
            raise EvaluationError(f"checked_components: unknown component {unknown[0]!r} (use {', '.join(COMPONENTS)})")
        for name in ("grid_step_m", "min_speed_mps", "max_gap_s", "threshold_scale_m",
                     "mse_threshold_mm", "adev_threshold_mm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0) or (name in ("grid_step_m", "threshold_scale_m") and v == 0):
                raise EvaluationError(f"{name}: must be a positive number, got {v!r}")


@dataclass(frozen=True)
class ThresholdCheck:
    """Pass/fail of one component at the threshold scale (mm; NaN when the run is too short)."""

    mse_mm: float
    adev_mm: float
    mse_pass: bool
    adev_pass: bool

    @property
    def passed(self) -> bool:
        return self.mse_pass and self.adev_pass


@dataclass(frozen=True)
class PassOverlap:
    """Seed-003 statistics of pass ``pass_b`` minus pass ``pass_a`` over their common chainage, per component."""

    pass_a: int
    pass_b: int
    statistics: dict[str, OverlapStatistics]

    def to_json(self) -> dict:
        return {"passes": [self.pass_a, self.pass_b],
                **{c: s.to_json() for c, s in self.statistics.items()}}


@dataclass(frozen=True)
class EvaluationResult:
    """Everything ``trackfusion evaluate`` reports.

    relative_accuracy: component -> :class:`RelativeAccuracy`; checks:
    component -> :class:`ThresholdCheck`; overlaps: consecutive-pass
    residual statistics; series/distance: the error series behind them.
    """

    estimate: str
    reference: str
    match: str
    config: EvaluationConfig
    series: ErrorSeries
    distance: DistanceSeries
    relative_accuracy: dict[str, RelativeAccuracy]
    checks: dict[str, ThresholdCheck]
    overlaps: list[PassOverlap] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every checked component meets both thresholds."""
        return all(self.checks[c].passed for c in self.config.checked_components)

    def to_json(self) -> dict:
        """JSON-able dict; ``relative_accuracy`` follows DESIGN.md section 4 (NaN -> null)."""
        cfg = self.config
        ra = {}
        for c in COMPONENTS:
            entry = self.relative_accuracy[c].to_json()
            chk = self.checks[c]
            entry.update({"threshold_scale_m": cfg.threshold_scale_m, "mse_at_threshold_mm": _jf(chk.mse_mm),
                          "adev_at_threshold_mm": _jf(chk.adev_mm), "mse_pass": chk.mse_pass,
                          "adev_pass": chk.adev_pass})
            ra[c] = entry
        return {
            "estimate": self.estimate, "reference": self.reference, "match": self.match,
            "relative_accuracy": ra,
            "thresholds": {"scale_m": cfg.threshold_scale_m, "mse_mm": cfg.mse_threshold_mm,
                           "adev_mm": cfg.adev_threshold_mm, "components": list(cfg.checked_components)},
            "passed": self.passed,
            "samples": {"matched": self.series.n_matched, "static_excluded": self.series.n_static,
                        "moving": int(self.series.t_s.size), "passes": self.distance_passes,
                        "grid_step_m": cfg.grid_step_m, "grid_points": self.distance.n_points,
                        "length_m": self.distance.length_m, "min_speed_mps": cfg.min_speed_mps},
            "overlaps": [o.to_json() for o in self.overlaps],
        }

    @property
    def distance_passes(self) -> int:
        return len(self.distance.passes)

    def format_table(self) -> str:
        """A readable multi-line table of the figures."""
        cfg = self.config
        scales = self.relative_accuracy[COMPONENTS[0]].scales_m
        head = "".join(f"{s:>8g}" for s in scales)
        lines = [f"evaluate {self.estimate} against {self.reference} (matched by {self.match})",
                 f"  {self.series.t_s.size} moving samples of {self.series.n_matched} matched "
                 f"({self.series.n_static} static, speed < {cfg.min_speed_mps:g} m/s), {self.distance_passes} "
                 f"pass(es), {self.distance.length_m:.1f} m on a {cfg.grid_step_m:g} m grid",
                 "",
                 f"relative accuracy (mm)    L (m) ={head}"]
        for c in COMPONENTS:
            r = self.relative_accuracy[c]
            lines.append(f"{c:<9} sigma (eq. 1) {r.sigma_mm:8.3f}")
            for label, values in (("MSE sigma1 (eq. 2)", r.mse_mm), ("sigma2 (eq. 3)", r.sigma2_mm),
                                  ("ADEV (eqs. 5-6)", r.adev_mm), ("overlapping ADEV", r.oadev_mm)):
                lines.append(f"  {label:<23} " + "".join(_cell(v) for v in values))
        lines += ["", f"thresholds at L = {cfg.threshold_scale_m:g} m: MSE <= {cfg.mse_threshold_mm:g} mm (eq. 10), "
                      f"ADEV <= {cfg.adev_threshold_mm:g} mm (eq. 16)"]
        for c in COMPONENTS:
            chk = self.checks[c]
            note = "" if c in cfg.checked_components else "  (not checked)"
            lines.append(f"  {c:<9} MSE {_cell(chk.mse_mm)} {_verdict(chk.mse_pass)}   "
                         f"ADEV {_cell(chk.adev_mm)} {_verdict(chk.adev_pass)}{note}")
        for o in self.overlaps:
            lines.append("")
            lines.append(f"overlap of passes {o.pass_a} and {o.pass_b} "
                         f"({next(iter(o.statistics.values())).length_m:.1f} m): "
                         "max|r|, mean, std (mm), trend slope, relative accuracy (ppm)")
            for c, s in o.statistics.items():
                lines.append(f"  {c:<9} {s.max_abs_signed_mm:8.3f} {s.mean_mm:8.3f} {s.std_mm:8.3f} "
                             f"{s.trend_slope:11.3e} {s.relative_accuracy_ppm:8.2f}")
        lines += ["", f"result: {'PASS' if self.passed else 'FAIL'} ({', '.join(cfg.checked_components)})"]
        return "\n".join(lines)


def _jf(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _cell(v: float) -> str:
    return f"{v:8.3f}" if np.isfinite(v) else f"{'-':>8}"


def _verdict(ok: bool) -> str:
    return "pass" if ok else "FAIL"


def _threshold_check(x_m: Sequence[np.ndarray], ra: RelativeAccuracy, cfg: EvaluationConfig) -> ThresholdCheck:
    try:
        i = ra.index_of(cfg.threshold_scale_m)
        mse, adev = float(ra.mse_mm[i]), float(ra.adev_mm[i])
    except EvaluationError:
        at = relative_accuracy(x_m, cfg.grid_step_m, [cfg.threshold_scale_m])
        mse, adev = float(at.mse_mm[0]), float(at.adev_mm[0])
    return ThresholdCheck(mse_mm=mse, adev_mm=adev,
                          mse_pass=bool(np.isfinite(mse) and mse <= cfg.mse_threshold_mm),
                          adev_pass=bool(np.isfinite(adev) and adev <= cfg.adev_threshold_mm))


def pass_overlaps(distance: DistanceSeries, min_length_m: float = 1.0) -> list[PassOverlap]:
    """Seed-003 statistics of consecutive passes (i, i+1) over the grid points they share (>= min_length_m)."""
    out = []
    for i in range(len(distance.passes) - 1):
        a, b = distance.passes[i], distance.passes[i + 1]
        lo = max(a.start_index, b.start_index)
        hi = min(a.start_index + a.error_m.shape[0], b.start_index + b.error_m.shape[0])
        if (hi - lo - 1) * distance.step_m < max(min_length_m, 2 * distance.step_m):
            continue
        ea = a.error_m[lo - a.start_index: hi - a.start_index]
        eb = b.error_m[lo - b.start_index: hi - b.start_index]
        s = np.arange(lo, hi) * distance.step_m
        out.append(PassOverlap(pass_a=i, pass_b=i + 1, statistics={
            c: overlap_statistics(s, eb[:, k] - ea[:, k]) for k, c in enumerate(COMPONENTS)}))
    return out


def evaluate_trajectories(estimate: Trajectory, reference: Trajectory, match: str = "time",
                          config: EvaluationConfig | None = None) -> EvaluationResult:
    """Seed-002 relative accuracy (and pass overlaps) of ``estimate`` against ``reference``."""
    cfg = config or EvaluationConfig()
    series = error_series(estimate, reference, match=match, min_speed_mps=cfg.min_speed_mps,
                          max_gap_s=cfg.max_gap_s)
    distance = resample_on_distance(series, cfg.grid_step_m)
    ra, checks = {}, {}
    for c in COMPONENTS:
        x = distance.component(c)
        ra[c] = relative_accuracy(x, cfg.grid_step_m, cfg.scales_m)
        checks[c] = _threshold_check(x, ra[c], cfg)
    return EvaluationResult(estimate=estimate.source, reference=reference.source, match=match, config=cfg,
                            series=series, distance=distance, relative_accuracy=ra, checks=checks,
                            overlaps=pass_overlaps(distance, cfg.overlap_min_length_m))


def read_trajectory(path: str | Path) -> tuple[Trajectory, dict]:
    """Read a trajectory CSV and its JSON sidecar -> (:class:`Trajectory`, sidecar dict).

    Raises :class:`SensorDataError`/:class:`EvaluationError` naming the file
    (missing or empty file, missing column, non-finite value, positions not in ``n``).
    """
    with warnings.catch_warnings():
        # numpy warns "input contained no data" on a header-only file; read_csv_table raises
        # SensorDataError for it, which must stay the one line the command prints
        warnings.simplefilter("ignore", UserWarning)
        table = read_csv_table(path, required=REQUIRED_COLUMNS)
    sidecar = read_sidecar(path)
    if not isinstance(sidecar, dict):
        raise EvaluationError(f"{path}: sidecar is not a JSON object")
    frame = sidecar.get("frame")
    if frame is not None and frame != "n":
        raise EvaluationError(f"{path}: positions are in frame {frame!r}, expected 'n'")
    return Trajectory.from_columns(table, source=str(path)), sidecar


def evaluate_files(estimate_path: str | Path, reference_path: str | Path, match: str = "time",
                   config: EvaluationConfig | None = None) -> EvaluationResult:
    """Read two trajectory CSVs (estimate, reference) and evaluate them (see :func:`evaluate_trajectories`).

    Both must be in the same ``n`` frame: when both sidecars give an origin, they must agree.
    """
    est, est_meta = read_trajectory(estimate_path)
    ref, ref_meta = read_trajectory(reference_path)
    check_same_origin(estimate_path, est_meta.get("origin"), reference_path, ref_meta.get("origin"))
    return evaluate_trajectories(est, ref, match=match, config=config)


def check_same_origin(estimate_path, oe, reference_path, orf) -> None:
    if not (isinstance(oe, dict) and isinstance(orf, dict)):
        return
    try:
        same = (math.isclose(float(oe["lat_deg"]), float(orf["lat_deg"]), rel_tol=0, abs_tol=1e-9)
                and math.isclose(float(oe["lon_deg"]), float(orf["lon_deg"]), rel_tol=0, abs_tol=1e-9)
                and math.isclose(float(oe["h_m"]), float(orf["h_m"]), rel_tol=0, abs_tol=1e-6))
    except (KeyError, TypeError, ValueError):
        return
    if not same:
        raise EvaluationError(f"{estimate_path}: origin {oe} differs from the reference's origin {orf} "
                              f"({reference_path}); both must be in the same n frame")
