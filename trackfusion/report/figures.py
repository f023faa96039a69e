"""Figures of the run report (matplotlib object API on the Agg canvas: no display needed).

Every function takes plain arrays / ``metrics.json`` dicts and returns a matplotlib ``Figure``;
:func:`png_bytes` renders one. Units on the axes: metres for positions and chainage, millimetres
for errors, sigmas and geometry values.
"""

from __future__ import annotations

import io

import numpy as np

#: Longest series drawn per line (the figures are decimated to this many points).
MAX_POINTS = 20000

#: Fixed margins around the panels [in]: room for tick labels, axis labels and a title. (A layout
#: engine would fit them per figure by drawing it twice more: most of the report's time.)
MARGINS_IN = {"left": 1.0, "right": 0.2, "bottom": 0.5, "top": 0.32}
#: Gaps between panels [in]: beside a panel with its own y labels, or with shared y / x axes.
GAP_IN, SHARED_GAP_IN = 0.9, 0.45


def preload() -> None:
    """Import matplotlib's Agg canvas now (about a second), e.g. once before forking children that draw."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401


def _figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    return fig


def _panels(fig, nrows: int = 1, ncols: int = 1, sharex: bool = False, sharey: bool = False):
    """``fig.subplots`` with the fixed margins and gaps (MARGINS_IN, GAP_IN, SHARED_GAP_IN)."""
    w_in, h_in = fig.get_size_inches()
    m = MARGINS_IN
    gap_w = SHARED_GAP_IN if sharey else GAP_IN
    gap_h = 0.12 if sharex else GAP_IN
    panel_w = (w_in - m["left"] - m["right"] - (ncols - 1) * gap_w) / ncols
    panel_h = (h_in - m["bottom"] - m["top"] - (nrows - 1) * gap_h) / nrows
    grid = {"left": m["left"] / w_in, "right": 1 - m["right"] / w_in, "bottom": m["bottom"] / h_in,
            "top": 1 - m["top"] / h_in, "wspace": gap_w / panel_w, "hspace": gap_h / panel_h}
    return fig.subplots(nrows, ncols, sharex=sharex, sharey=sharey, gridspec_kw=grid)


def png_bytes(fig, dpi: int = 100) -> bytes:
    """PNG bytes of a figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _every(n: int) -> slice:
    return slice(None, None, max(1, -(-n // MAX_POINTS)))


#: A plan whose short side is below this share of its long side is drawn on unequal scales
#: (on equal ones a straight would be a flat line).
EQUAL_PLAN_MIN_RATIO = 0.05


def offset_from_chord_m(e_m: np.ndarray, n_m: np.ndarray, chainage_m: np.ndarray) -> np.ndarray:
    """Signed horizontal distance [m] (N,) of each point from the straight line (the chord)
    through the points of lowest and highest chainage (so out-and-back surveys share one
    chord), positive to the left of increasing chainage; zero when the two coincide."""
    i0, i1 = int(np.nanargmin(chainage_m)), int(np.nanargmax(chainage_m))
    d = np.array([e_m[i1] - e_m[i0], n_m[i1] - n_m[i0]], dtype=float)
    norm = float(np.hypot(*d))
    if norm == 0.0:
        return np.zeros_like(np.asarray(e_m, dtype=float))
    return (d[0] * (n_m - n_m[i0]) - d[1] * (e_m - e_m[i0])) / norm


def plan_and_profile(traj: dict[str, np.ndarray]):
    """Plan (north against east [m], equal scales unless the path is nearly straight), the
    horizontal offset from the chord of lowest to highest chainage against chainage (what a
    straight's plan hides)
    and the profile (up against chainage [m])."""
    fig = _figure(11.0, 3.6)
    ax_plan, ax_off, ax_prof = _panels(fig, 1, 3)
    s = _every(traj["t_s"].size)
    e, n = traj["e_m"], traj["n_m"]
    ax_plan.plot(e[s], n[s], lw=1.0, color="C0")
    ax_plan.plot(e[0], n[0], "o", color="C2", label="start")
    ax_plan.plot(e[-1], n[-1], "s", color="C3", label="end")
    ax_plan.set_xlabel("east (m)")
    ax_plan.set_ylabel("north (m)")
    spans = sorted([float(np.ptp(e)), float(np.ptp(n))])
    if spans[1] > 0 and spans[0] / spans[1] >= EQUAL_PLAN_MIN_RATIO:
        ax_plan.set_aspect("equal", adjustable="datalim")
        ax_plan.set_title("plan (frame n, equal scales)", fontsize=9)
    else:
        ax_plan.set_title("plan (n; scales NOT equal: nearly straight)", fontsize=8)
    ax_plan.legend(fontsize=7)
    ax_plan.grid(True, alpha=0.3)
    off_m = offset_from_chord_m(e, n, traj["chainage_m"])
    big = float(np.nanmax(np.abs(off_m))) >= 1.0 if off_m.size else False
    ax_off.plot(traj["chainage_m"][s], off_m[s] * (1.0 if big else 1e3), ".", ms=1.0, color="C0")
    ax_off.set_xlabel("chainage (m)")
    ax_off.set_ylabel(f"offset, left positive ({'m' if big else 'mm'})")
    ax_off.set_title("offset from the chord, lowest to highest chainage", fontsize=8)
    ax_off.grid(True, alpha=0.3)
    ax_prof.plot(traj["chainage_m"][s], traj["u_m"][s], ".", ms=1.0, color="C0")
    ax_prof.set_xlabel("chainage (m)")
    ax_prof.set_ylabel("height up (m)")
    ax_prof.set_title("profile (IMU origin height)", fontsize=9)
    ax_prof.grid(True, alpha=0.3)
    for ax in (ax_plan, ax_off, ax_prof):
        ax.ticklabel_format(useOffset=False, style="plain")
    return fig


def sigmas_along_chainage(traj: dict[str, np.ndarray]):
    """Smoothed 1-sigma position uncertainty (e, n, u) [mm] against chainage and time."""
    fig = _figure(11.0, 3.4)
    ax_s, ax_t = _panels(fig, 1, 2, sharey=True)
    s = _every(traj["t_s"].size)
    for i, axis in enumerate("enu"):
        sigma_mm = traj[f"sigma_{axis}_m"][s] * 1e3
        ax_s.plot(traj["chainage_m"][s], sigma_mm, ".", ms=1.0, color=f"C{i}", label=f"sigma {axis}")
        ax_t.plot(traj["t_s"][s], sigma_mm, lw=0.8, color=f"C{i}", label=f"sigma {axis}")
    ax_s.set_xlabel("chainage (m)")
    ax_t.set_xlabel("time t (s)")
    ax_s.set_ylabel("1-sigma (mm)")
    ax_s.set_title("position sigma along chainage", fontsize=9)
    ax_t.set_title("position sigma along time", fontsize=9)
    ax_t.legend(fontsize=7, markerscale=6)
    for ax in (ax_s, ax_t):
        ax.grid(True, alpha=0.3)
    return fig


def relative_accuracy(ra: dict, thresholds: dict):
    """MSE and ADEV [mm] against distance scale [m] per component (metrics ``relative_accuracy``),
    the MSE / ADEV limits as horizontal lines and the threshold scale as a vertical line."""
    comps = list(ra)
    fig = _figure(11.0, 3.6)
    axes = np.atleast_1d(_panels(fig, 1, len(comps), sharey=True))
    for ax, comp in zip(axes, comps):
        entry = ra[comp]
        scales = np.asarray(entry["scales_m"], float)
        for key, style, label in (("mse_mm", "o-", "MSE"), ("adev_mm", "s-", "ADEV"),
                                  ("oadev_mm", ":", "overlapping ADEV")):
            y = np.array([np.nan if v is None else v for v in entry.get(key, [])], float)
            ok = np.isfinite(y) & (y > 0)
            if ok.any():
                ax.loglog(scales[ok], y[ok], style, color="C0" if key == "mse_mm" else "C1", label=label)
        ax.axhline(thresholds["mse_mm"], color="C0", ls="--", lw=1, label=f"MSE limit {thresholds['mse_mm']:g} mm")
        ax.axhline(thresholds["adev_mm"], color="C1", ls="--", lw=1,
                   label=f"ADEV limit {thresholds['adev_mm']:g} mm")
        ax.axvline(thresholds["scale_m"], color="0.5", lw=0.8)
        ax.set_title(comp, fontsize=9)
        ax.set_xlabel("distance scale L (m)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative error (mm)")
    axes[0].legend(fontsize=7, loc="upper left")
    return fig


#: Line colours of the tolerance levels (a single ``limit`` is drawn as the intervention level).
LEVEL_COLOURS = {"alert": "#c99700", "limit": "#d9480f", "intervention": "#d9480f", "immediate_action": "#8b0000"}
LEVEL_WORDS = {"alert": "alert", "limit": "limit", "intervention": "intervention",
               "immediate_action": "immediate action"}


def series_with_bands(chainage_m: np.ndarray, series: dict[str, np.ndarray], levels_mm: dict[str, dict[str, float]],
                      title: str, exceedances: list[dict] | None = None, labels: dict[str, str] | None = None):
    """One panel per series [mm] against chainage [m], each labelled ``labels[name]`` (default the
    name); ``levels_mm[name]`` (level -> limit, e.g. ``{"alert": 6, "intervention": 10}``) draws
    each level as +-lines in its colour (LEVEL_COLOURS); ``exceedances`` (dicts with ``column``,
    ``from_m``, ``to_m``, ``chainage_m``, ``value_mm`` and ``label``, e.g. ``E3``) are shaded on
    the panel of their column, their peak marked and labelled.

    Returns ``(fig, spots)``: ``spots`` one ``(label, x0, y0, x1, y1)`` per drawn exceedance, its
    shaded box in pixels of the PNG (:func:`png_bytes` at the default dpi; origin top left), for
    an HTML image map linking each to its row of the exceedance list."""
    import textwrap

    names = list(series)
    labels = labels or {}
    fig = _figure(11.0, 1.7 * len(names) + 0.6)
    axes = np.atleast_1d(_panels(fig, len(names), 1, sharex=True))
    s = _every(chainage_m.size)
    marked: list[tuple] = []
    legend_of: dict | None = None
    for ax, name in zip(axes, names):
        ax.plot(chainage_m[s], series[name][s], lw=0.7, color="C0")
        for level, limit in (levels_mm.get(name) or {}).items():
            colour = LEVEL_COLOURS.get(level, "C3")
            ax.axhline(limit, color=colour, lw=0.9, ls="--", label=f"{LEVEL_WORDS.get(level, level)} ±{limit:g} mm")
            ax.axhline(-limit, color=colour, lw=0.9, ls="--")
        if levels_mm.get(name) and levels_mm[name] != legend_of:  # a legend where the levels change
            ax.legend(fontsize=7, loc="upper right", ncol=3)
            legend_of = levels_mm[name]
        for e in exceedances or []:
            if e.get("column") == name:
                ax.axvspan(e["from_m"], e["to_m"], color="C3", alpha=0.25, lw=0)
                ax.plot([e["chainage_m"]], [e["value_mm"]], "v", color="C3", ms=4)
                ax.annotate(e["label"], (e["chainage_m"], e["value_mm"]), xytext=(2, 2), textcoords="offset points",
                            fontsize=7, color="C3")
                marked.append((ax, e))
        ax.set_ylabel("\n".join(textwrap.wrap(labels.get(name, name), 22)), fontsize=7)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("chainage (m)")
    axes[0].set_title(title, fontsize=9)
    return fig, _spots(fig, marked)


def _spots(fig, marked: list[tuple]) -> list[tuple[str, int, int, int, int]]:
    """Pixel boxes (origin top left) of the exceedances drawn on their axes, at least 8 px wide."""
    height_px = fig.get_size_inches()[1] * fig.dpi
    out = []
    for ax, e in marked:
        y0, y1 = ax.get_ylim()
        (xa, ya), (xb, yb) = ax.transData.transform([(e["from_m"], y0), (e["to_m"], y1)])
        xa, xb = min(xa, xb), max(xa, xb)
        if xb - xa < 8:
            xa, xb = 0.5 * (xa + xb) - 4, 0.5 * (xa + xb) + 4
        out.append((e["label"], int(xa), int(height_px - max(ya, yb)), int(np.ceil(xb)),
                    int(np.ceil(height_px - min(ya, yb)))))
    return out


def time_sync_curves(time_sync: dict):
    """Pearson correlation r against trial clock offset [s] per station, the chosen offset marked."""
    fig = _figure(11.0, 3.2)
    ax = _panels(fig)
    for i, (sid, entry) in enumerate(sorted(time_sync.items())):
        lags = np.asarray(entry.get("lags_s", []), float)
        r = np.asarray(entry.get("r", []), float)
        if lags.size and lags.size == r.size:
            ax.plot(lags, r, lw=1.0, color=f"C{i}", label=f"station {sid}")
        if entry.get("offset_s") is not None:
            ax.axvline(entry["offset_s"], color=f"C{i}", ls="--", lw=0.8)
    ax.set_xlabel("station clock minus IMU clock (s)")
    ax.set_ylabel("correlation r")
    ax.set_title("time synchronisation: velocity correlation", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return fig
