"""Figure of seed-002 relative accuracy: MSE and ADEV against distance scale, thresholds drawn.

Uses matplotlib's object API with the Agg canvas (no pyplot, no display, safe
in worker processes). The figure is returned as PNG bytes and optionally
written atomically.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..evaluation.errors_series import COMPONENTS


def relative_accuracy_figure(result, title: str | None = None):
    """A matplotlib ``Figure``: one panel per component, MSE (eq. 2) and ADEV (eqs. 5-6) in mm
    against the distance scale L (m, log-log), overlapping ADEV dashed, thresholds as horizontal
    lines and the threshold scale as a vertical line.

    result: an :class:`~trackfusion.evaluation.api.EvaluationResult`.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    cfg = result.config
    fig = Figure(figsize=(11.0, 3.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(COMPONENTS), sharey=True)
    for ax, comp in zip(axes, COMPONENTS):
        ra = result.relative_accuracy[comp]
        ok = np.isfinite(ra.mse_mm) & (ra.mse_mm > 0)
        ax.loglog(ra.scales_m[ok], ra.mse_mm[ok], "o-", color="C0", label="MSE sigma1 (eq. 2)")
        ok = np.isfinite(ra.adev_mm) & (ra.adev_mm > 0)
        ax.loglog(ra.scales_m[ok], ra.adev_mm[ok], "s-", color="C1", label="ADEV (eqs. 5-6)")
        ok = np.isfinite(ra.oadev_mm) & (ra.oadev_mm > 0)
        ax.loglog(ra.scales_m[ok], ra.oadev_mm[ok], ":", color="C1", label="overlapping ADEV")
        ax.axhline(cfg.mse_threshold_mm, color="C0", ls="--", lw=1, label=f"MSE limit {cfg.mse_threshold_mm:g} mm")
        ax.axhline(cfg.adev_threshold_mm, color="C1", ls="--", lw=1,
                   label=f"ADEV limit {cfg.adev_threshold_mm:g} mm")
        ax.axvline(cfg.threshold_scale_m, color="0.5", lw=0.8)
        chk = result.checks[comp]
        verdict = "pass" if chk.passed else "fail"
        ax.set_title(f"{comp} (sigma {ra.sigma_mm:.2f} mm, {verdict} at {cfg.threshold_scale_m:g} m)", fontsize=9)
        ax.set_xlabel("distance scale L (m)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative error (mm)")
    axes[0].legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def relative_accuracy_png(result, path: str | Path | None = None, title: str | None = None, dpi: int = 110) -> bytes:
    """PNG bytes of :func:`relative_accuracy_figure`; also written (atomically) to ``path`` when given."""
    fig = relative_accuracy_figure(result, title=title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    png = buf.getvalue()
    if path is not None:
        from ..sensors.fileio import atomic_path

        with atomic_path(path) as tmp:
            tmp.write_bytes(png)
    return png
