"""A run's trajectory against a reference trajectory file (for ``metrics.json``).

Relative accuracy (seed 002, :func:`evaluate_trajectories`), absolute error RMS and maximum
along / lateral / vertical over the moving samples, and statistical consistency: the RMS
of error / sigma per ``n`` axis over all samples (about 1 when the sigmas are honest), with the
run's effective number of independent samples and the interval an honest RMS falls in
(:mod:`.consistency`: one run of a slowly varying error is nearly one sample).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .api import check_same_origin, evaluate_trajectories, read_trajectory
from .consistency import consistency_of
from .errors_series import COMPONENTS, Trajectory, hermite_interpolate


def normalised_errors(table: dict[str, np.ndarray], reference: Trajectory) -> dict[str, np.ndarray]:
    """(estimate - reference) / sigma for e, n, u over the samples inside the reference span, each (N,)."""
    t = table["t_s"]
    inside = (t >= reference.t_s[0]) & (t <= reference.t_s[-1])
    ref = hermite_interpolate(reference.t_s, reference.pos_n_m, reference.vel_n_mps, t[inside])
    return {axis: (table[f"{axis}_m"][inside] - ref[:, i]) / table[f"sigma_{axis}_m"][inside]
            for i, axis in enumerate("enu")}


def consistency(table: dict[str, np.ndarray], reference: Trajectory) -> dict[str, float]:
    """RMS of (estimate - reference) / sigma for e, n, u over the samples inside the reference span."""
    return _rms_by_axis(normalised_errors(table, reference))


def consistency_detail(table: dict[str, np.ndarray], reference: Trajectory) -> dict[str, dict]:
    """Per axis: RMS(z), effective independent samples, the 95 % interval of RMS(z) for honest
    sigmas, and the sample count (evaluation/consistency.py)."""
    return _detail_by_axis(normalised_errors(table, reference))


def _rms_by_axis(z_by_axis: dict[str, np.ndarray]) -> dict[str, float]:
    return {axis: float(np.sqrt(np.mean(z**2))) for axis, z in z_by_axis.items()}


def _detail_by_axis(z_by_axis: dict[str, np.ndarray]) -> dict[str, dict]:
    return {axis: {**consistency_of(z), "samples": int(z.size)} for axis, z in z_by_axis.items()}


def compare_with_reference(table: dict[str, np.ndarray], reference_path: str | Path,
                           origin: dict | None = None, read: tuple[Trajectory, dict] | None = None) -> dict:
    """Metrics of a trajectory table (trajectory.csv columns) against a reference CSV; ``read``:
    the reference as :func:`~.api.read_trajectory` of ``reference_path`` returned it, when read before."""
    reference, meta = read if read is not None else read_trajectory(reference_path)
    if origin is not None:
        check_same_origin("trajectory", origin, reference_path, meta.get("origin"))
    estimate = Trajectory.from_columns(table, source="trajectory")
    result = evaluate_trajectories(estimate, reference)
    evaluation = result.to_json()
    err = result.series.error_m
    absolute = {c: {"rms_mm": float(np.sqrt(np.mean(err[:, i] ** 2)) * 1e3),
                    "max_abs_mm": float(np.max(np.abs(err[:, i])) * 1e3)} for i, c in enumerate(COMPONENTS)}
    z = normalised_errors(table, reference)  # once for both consistency entries
    return {"reference": str(reference_path), "relative_accuracy": evaluation["relative_accuracy"],
            "evaluation": {k: v for k, v in evaluation.items() if k != "relative_accuracy"},
            "absolute_error": absolute, "consistency_rms_error_over_sigma": _rms_by_axis(z),
            "consistency": _detail_by_axis(z)}
