"""report.html of a vision run: rail cross-sections (the measured stripe points in the fitted
profile frame and the unworn profile) at a few chainages, gauge, cross-level and wear against
chainage, and the fault list (figures as in :mod:`.figures`: matplotlib on the Agg canvas,
embedded as base64 PNG)."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import numpy as np

from . import figures

#: frames shown as cross-sections: the first good frame, the most worn one, the last good one
SECTIONS = 3


def section_frames(table: dict[str, np.ndarray]) -> list[int]:
    """Frames without a fault: the first, the one of most vertical wear (left rail), the last."""
    good = np.nonzero((table["fault"] == 0) & np.isfinite(table["wear_vertical_left_mm"]))[0]
    if not good.size:
        return []
    worn = int(good[np.argmax(table["wear_vertical_left_mm"][good])])
    return sorted({int(good[0]), worn, int(good[-1])})


def cross_section_figure(frames: list[int], chainage_m: np.ndarray, inputs: dict, m, head):
    """One column per frame, a row per rail: measured points (profile frame, mm) and the unworn
    profile they were fitted to."""
    from ..track.rail_profile import sample_unworn_mm
    from ..vision.measure import rail_points_mm
    from ..vision.profile_fit import to_profile_frame
    from ..vision.stripe import StripeSettings
    unworn = sample_unworn_mm(head, 0.2)
    fig = figures._figure(3.4 * len(frames) + 1.2, 6.0)
    axes = np.atleast_2d(figures._panels(fig, 2, len(frames), sharey=True)).reshape(2, len(frames))
    for j, f in enumerate(frames):
        for i, side in enumerate(("left", "right")):
            ax = axes[i, j]
            y, z, ok, _ = rail_points_mm(inputs["units"][side], inputs["log"]["images"][side][f:f + 1], StripeSettings())
            q, zz = to_profile_frame(y, z, m.pose[side][f:f + 1], side)
            ax.plot(unworn[:, 0], unworn[:, 1], "-", color="0.4", lw=1.0, label="unworn profile (fitted)")
            ax.plot(q[ok], zz[ok], ".", ms=2.0, color="C3", label="measured points")
            ax.set_title(f"{side} rail, {chainage_m[f]:.1f} m", fontsize=9)
            ax.set_xlabel("q towards gauge side [mm]", fontsize=8)
            if j == 0:
                ax.set_ylabel("z [mm]")
            ax.set_xlim(-40, 40)
            ax.set_ylim(-32, 3)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    return fig


def chainage_figure(table: dict[str, np.ndarray]):
    """Gauge, cross-level, vertical and side wear, alignment / vertical profile (D1) against chainage."""
    s = table["chainage_m"]
    fig = figures._figure(9.0, 8.0)
    axes = figures._panels(fig, 4, 1, sharex=True)
    axes[0].plot(s, table["gauge_m"] * 1e3, lw=0.8)
    axes[0].set_ylabel("gauge [mm]")
    axes[1].plot(s, table["cross_level_mm"], lw=0.8)
    axes[1].set_ylabel("cross-level [mm]")
    for side, c in (("left", "C0"), ("right", "C1")):
        axes[2].plot(s, table[f"wear_vertical_{side}_mm"], lw=0.8, color=c, label=f"vertical, {side}")
        axes[2].plot(s, table[f"wear_side_{side}_mm"], lw=0.8, color=c, ls="--", label=f"side, {side}")
    axes[2].set_ylabel("wear [mm]")
    axes[2].legend(fontsize=7, ncol=4)
    axes[3].plot(s, table["alignment_d1_mm"], lw=0.8, label="alignment D1")
    axes[3].plot(s, table["vertical_profile_d1_mm"], lw=0.8, label="vertical profile D1")
    axes[3].set_ylabel("D1 [mm]")
    axes[3].legend(fontsize=7)
    axes[3].set_xlabel("chainage [m]")
    return fig


def _img(fig, alt: str) -> str:
    data = base64.b64encode(figures.png_bytes(fig)).decode("ascii")
    return f"<img alt='{html.escape(alt)}' src='data:image/png;base64,{data}'>"


def write_vision_report(path: Path, name: str, table: dict, metrics: dict, inputs: dict, m, head) -> None:
    """Write the self-contained report.html of a vision run: ``table`` geometry.csv's columns,
    ``inputs`` the log and units read, ``m`` the frame measurements, ``head`` the rail profile."""
    from ..sensors.fileio import write_text_atomic
    from ..vision.cross_level_reference import describe_reference
    v = metrics["vision"]
    frames = section_frames(table)
    rows = "".join(f"<tr><td>{f['frame']}</td><td>{f['chainage_m']:.2f}</td><td>{f['rail']}</td>"
                   f"<td>{html.escape(f['reason'])}</td></tr>" for f in v["faults"]["list"])
    parts = [f"<h1>{html.escape(name)}: vision-inertial track geometry</h1>",
             f"<p>{v['frames']} frames per camera, chainage {v['chainage_m'][0]:.1f}-{v['chainage_m'][1]:.1f} m; "
             f"{v['faults']['frames']} frames with faults (NaN in geometry.csv).</p>",
             f"<p>{html.escape(describe_reference(v['cross_level_reference']))} (docs/vision.md, "
             "\"The cross-level's reference\").</p>",
             "<h2>Rail cross-sections</h2>",
             _img(cross_section_figure(frames, table["chainage_m"], inputs, m, head), "cross-sections")
             if frames else "<p>no frame without a fault</p>",
             "<h2>Gauge, cross-level, wear and D1 against chainage</h2>",
             _img(chainage_figure(table), "geometry against chainage"),
             "<h2>Faults</h2>",
             f"<table><tr><th>frame</th><th>chainage [m]</th><th>rail</th><th>reason</th></tr>{rows}</table>"]
    write_text_atomic(path, "<!doctype html><html><head><meta charset='utf-8'><title>"
                      f"{html.escape(name)}</title></head><body>{''.join(parts)}</body></html>\n")
