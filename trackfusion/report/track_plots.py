"""Figures of the track geometry for the report (matplotlib object API, Agg canvas, no pyplot).

Each function takes the geometry table (``geometry.csv`` columns: name -> (N,) array) and/or
the ``geometry`` metrics, and returns a ``matplotlib.figure.Figure``; :func:`figure_png`
renders one to PNG bytes (the report writes the files).
"""

from __future__ import annotations

import io
import re

import numpy as np

_IRREGULARITY = re.compile(r"^(left|right)_(vertical|lateral)(?:_(D[123]))?_mm$")
_VERSINE = re.compile(r"^(left|right)_(vertical|lateral)_versine_([0-9.eE+-]+)m_mm$")
_TWIST = re.compile(r"^twist_([0-9.eE+-]+)m_mm$")
_WORDS = {"vertical": "longitudinal level", "lateral": "alignment"}
_OTHER = {"cross_level_mm": "cross-level", "gauge_variation_mm": "gauge deviation from nominal",
          "gauge_m": "gauge", "di_deg_per_m": "deformation index"}


def column_label(name: str) -> str:
    """A geometry column's quantity in words, without its unit (``left_vertical_mm`` -> ``left
    longitudinal level``, ``twist_3m_mm`` -> ``twist, 3 m base``); unknown names are returned
    with underscores as spaces and the unit suffix dropped."""
    if m := _IRREGULARITY.match(name):
        return f"{m[1]} {_WORDS[m[2]]}" + (f" {m[3]}" if m[3] else "")
    if m := _VERSINE.match(name):
        return f"{m[1]} {m[2]} versine, {m[3]} m chord"
    if m := _TWIST.match(name):
        return f"twist, {m[1]} m base"
    if name in _OTHER:
        return _OTHER[name]
    return re.sub(r"_(mm|m|s|deg_per_m)$", "", name).replace("_", " ")


def column_unit(name: str) -> str:
    """The unit of a geometry column from its name's suffix (``mm``, ``m``, ``deg/m``, ``s``)."""
    for suffix, unit in (("_deg_per_m", "deg/m"), ("_mm", "mm"), ("_m", "m"), ("_s", "s")):
        if name.endswith(suffix):
            return unit
    return ""


def measured(table: dict, names) -> list[str]:
    """The columns of ``names`` the table holds with at least one finite value (all-NaN columns are
    not measured and are not drawn)."""
    return [c for c in names if c in table and np.isfinite(np.asarray(table[c], dtype=float)).any()]


def _figure(rows: int, height: float = 2.4):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.0, height * rows), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _band(ax, limit_mm: float | None) -> None:
    if limit_mm:
        ax.axhspan(-limit_mm, limit_mm, color="tab:green", alpha=0.08, lw=0)
        for y in (-limit_mm, limit_mm):
            ax.axhline(y, color="tab:red", lw=0.8, ls="--")


def irregularities_figure(table: dict, limits_mm: dict[str, float] | None = None, title: str = ""):
    """Vertical and lateral irregularity of both rails, cross-level and the first twist column
    against chainage; ``limits_mm`` maps a quantity (``vertical``, ``lateral``, ``cross_level``,
    ``twist``) to a tolerance band drawn as +/- limit."""
    limits = limits_mm or {}
    s = table["chainage_m"]
    twist_cols = [c for c in table if c.startswith("twist_")]
    rows = [("vertical", [f"{r}_vertical_mm" for r in ("left", "right")]),
            ("lateral", [f"{r}_lateral_mm" for r in ("left", "right")]),
            ("cross_level", ["cross_level_mm"])] + ([("twist", twist_cols[:1])] if twist_cols else [])
    fig, axes = _figure(len(rows))
    for ax, (qty, cols) in zip(axes, rows):
        for c in measured(table, cols):
            ax.plot(s, table[c], lw=0.7, label=column_label(c))
        _band(ax, limits.get(qty))
        ax.set_ylabel(f"{qty.replace('_', '-')} (mm)")
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("chainage (m)")
    if title:
        fig.suptitle(title)
    return fig


def versines_figure(table: dict, chord_m: float, limit_mm: float | None = None, title: str = ""):
    """Vertical and lateral mid-chord versines of both rails for one chord, tolerance band +/- limit."""
    s = table["chainage_m"]
    fig, axes = _figure(2)
    for ax, comp in zip(axes, ("vertical", "lateral")):
        for col in measured(table, [f"{r}_{comp}_versine_{chord_m:g}m_mm" for r in ("left", "right")]):
            ax.plot(s, table[col], lw=0.7, label=column_label(col))
        _band(ax, limit_mm)
        ax.set_ylabel(f"{comp} versine (mm)")
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("chainage (m)")
    fig.suptitle(title or f"{chord_m:g} m chord versines")
    return fig


def deformation_index_figure(table: dict, di_metrics: dict, title: str = "Deformation index"):
    """DI along chainage with the threshold and the detected defects marked (seed 000 fig. 19)."""
    s = table["chainage_m"]
    fig, (ax,) = _figure(1, 3.0)
    ax.plot(s, table["di_deg_per_m"], lw=0.6, color="tab:blue", label="DI (mean over passes)")
    _band(ax, di_metrics["threshold_deg_per_m"])
    for d in di_metrics["defects"]:
        ax.axvline(d["chainage_m"], color="tab:red", alpha=0.5, lw=1)
        ax.annotate(f"{d['peak_di_deg_per_m']:.1f}", (d["chainage_m"], d["peak_di_deg_per_m"]), fontsize=7,
                    color="tab:red")
    ax.set_xlabel("chainage (m)")
    ax.set_ylabel("deformation index (deg/m)")
    ax.legend(loc="upper right", fontsize=7)
    ax.grid(alpha=0.3)
    fig.suptitle(title)
    return fig


def spectrum_figure(spectra: dict, title: str = "Spatial spectrum"):
    """Spectra on a wavelength axis (log-log) with their dominant wavelengths marked;
    ``spectra`` maps a label to a :class:`~trackfusion.track.shortwave.Spectrum`."""
    fig, (ax,) = _figure(1, 3.4)
    for label, sp in spectra.items():
        line, = ax.loglog(sp.wavelength_m, sp.psd, lw=0.8, label=label)
        for lam in sp.dominant_m[:3]:
            ax.axvline(lam, color=line.get_color(), lw=0.6, ls=":")
    ax.set_xlabel("wavelength (m)")
    ax.set_ylabel("power spectral density (unit² m)")
    ax.invert_xaxis()
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    fig.suptitle(title)
    return fig


def figure_png(fig, dpi: int = 110) -> bytes:
    """PNG bytes of a figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()

