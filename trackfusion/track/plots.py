"""Figures of the track geometry for the report (matplotlib object API, Agg canvas, no pyplot).

Each function takes the geometry table (``geometry.csv`` columns: name -> (N,) array) and/or
the ``geometry`` metrics, and returns a ``matplotlib.figure.Figure``; :func:`figure_png`
renders one to PNG bytes (the report writes the files).
"""

from __future__ import annotations

import io


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
        for c in cols:
            ax.plot(s, table[c], lw=0.7, label=c)
        _band(ax, limits.get(qty))
        ax.set_ylabel("mm")
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("chainage [m]")
    if title:
        fig.suptitle(title)
    return fig


def versines_figure(table: dict, chord_m: float, limit_mm: float | None = None, title: str = ""):
    """Vertical and lateral mid-chord versines of both rails for one chord, tolerance band +/- limit."""
    s = table["chainage_m"]
    fig, axes = _figure(2)
    for ax, comp in zip(axes, ("vertical", "lateral")):
        for r in ("left", "right"):
            col = f"{r}_{comp}_versine_{chord_m:g}m_mm"
            ax.plot(s, table[col], lw=0.7, label=col)
        _band(ax, limit_mm)
        ax.set_ylabel(f"{comp} [mm]")
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("chainage [m]")
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
    ax.set_xlabel("chainage [m]")
    ax.set_ylabel("DI [deg/m]")
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
    ax.set_xlabel("wavelength [m]")
    ax.set_ylabel("PSD [unit^2 m]")
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

