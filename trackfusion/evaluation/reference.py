"""A run's trajectory against a reference trajectory file (for ``metrics.json``).

Relative accuracy (seed 002, :func:`evaluate_trajectories`), absolute error RMS and maximum
along / lateral / vertical over the moving samples, and statistical consistency: the RMS
of error / sigma per ``n`` axis over all samples (about 1 when the sigmas are honest).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .api import check_same_origin, evaluate_trajectories, read_trajectory
from .errors_series import COMPONENTS, Trajectory, hermite_interpolate


def consistency(table: dict[str, np.ndarray], reference: Trajectory) -> dict[str, float]:
    """RMS of (estimate - reference) / sigma for e, n, u over the samples inside the reference span."""
    t = table["t_s"]
    inside = (t >= reference.t_s[0]) & (t <= reference.t_s[-1])
    ref = hermite_interpolate(reference.t_s, reference.pos_n_m, reference.vel_n_mps, t[inside])
    out = {}
    for i, axis in enumerate("enu"):
        err = table[f"{axis}_m"][inside] - ref[:, i]
        out[axis] = float(np.sqrt(np.mean((err / table[f"sigma_{axis}_m"][inside]) ** 2)))
    return out


def compare_with_reference(table: dict[str, np.ndarray], reference_path: str | Path,
                           origin: dict | None = None) -> dict:
    """Metrics of a trajectory table (trajectory.csv columns) against a reference CSV."""
    reference, meta = read_trajectory(reference_path)
    if origin is not None:
        check_same_origin("trajectory", origin, reference_path, meta.get("origin"))
    estimate = Trajectory.from_columns(table, source="trajectory")
    result = evaluate_trajectories(estimate, reference)
    evaluation = result.to_json()
    err = result.series.error_m
    absolute = {c: {"rms_mm": float(np.sqrt(np.mean(err[:, i] ** 2)) * 1e3),
                    "max_abs_mm": float(np.max(np.abs(err[:, i])) * 1e3)} for i, c in enumerate(COMPONENTS)}
    return {"reference": str(reference_path), "relative_accuracy": evaluation["relative_accuracy"],
            "evaluation": {k: v for k, v in evaluation.items() if k != "relative_accuracy"},
            "absolute_error": absolute, "consistency_rms_error_over_sigma": consistency(table, reference)}
