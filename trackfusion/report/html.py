"""``report.html``: a self-contained run report (figures as base64 PNG, inline CSS, no script,
no external asset), readable offline; optionally the same figures as a PDF.

Inputs are the files of a run folder (``trackfusion run``): ``metrics.json``, ``trajectory.csv``
and its sidecar (which holds the pipeline configuration), and ``geometry.csv`` + sidecar when
the run derived track geometry. Sections appear when their data is there (docs/report.md):

summary, trajectory plan and profile, position sigmas, relative accuracy (with a reference),
track geometry (irregularities, versines, cross-level / twist / gauge, exceedances), time
synchronisation, registration, rejected measurements, detected faults.
"""

from __future__ import annotations

import base64
import html
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SensorDataError
from ..sensors.fileio import atomic_path, read_csv_table, read_json, read_sidecar, write_text_atomic
from . import figures

IRREGULARITY_COLUMNS = ("left_vertical_mm", "right_vertical_mm", "left_lateral_mm", "right_lateral_mm")
_VERSINE = re.compile(r"^(left|right)_(vertical|lateral)_versine_[0-9.eE+-]+m_mm$")
_TWIST = re.compile(r"^twist_[0-9.eE+-]+m_mm$")
NOMINAL_GAUGE_M = 1.435


@dataclass
class RunFiles:
    """What a run folder holds: metrics dict, trajectory columns, trajectory sidecar and, when
    present, geometry columns and sidecar (``None`` otherwise)."""

    run_dir: Path
    metrics: dict[str, Any]
    trajectory: dict[str, np.ndarray]
    trajectory_meta: dict[str, Any]
    geometry: dict[str, np.ndarray] | None
    geometry_meta: dict[str, Any] | None
    shown_dir: Path | None = None
    #: ``<img>`` tags already rendered (alt text -> tag, :func:`table_images`), used instead of drawing again
    images: dict[str, str] = field(default_factory=dict)


TRAJECTORY_REQUIRED = ("t_s", "e_m", "n_m", "u_m", "chainage_m", "sigma_e_m", "sigma_n_m", "sigma_u_m")


def load_run(run_dir: str | Path, tables: dict[str, dict[str, np.ndarray]] | None = None) -> RunFiles:
    """Read a run folder; raises :class:`SensorDataError` naming the missing or bad file.

    tables: CSV tables of the folder already in memory (file name, e.g. ``"trajectory.csv"`` ->
    columns, as written), used instead of parsing the files again (the pipeline passes its own)."""
    d = Path(run_dir)
    if not d.is_dir():
        raise SensorDataError(f"{d}: run folder not found")
    tables = tables or {}

    def table(name: str, required: tuple[str, ...]) -> dict[str, np.ndarray]:
        if name not in tables:
            return read_csv_table(d / name, required=required)
        missing = [c for c in required if c not in tables[name]]
        if missing:
            raise SensorDataError(f"{d / name}: missing column {missing[0]!r}")
        return tables[name]

    metrics = read_json(d / "metrics.json", f"not found (is {d} the output folder of 'trackfusion run'?)")
    traj = table("trajectory.csv", TRAJECTORY_REQUIRED)
    geometry = geometry_meta = None
    if (d / "geometry.csv").is_file():
        geometry = table("geometry.csv", ("chainage_m",))
        geometry_meta = read_sidecar(d / "geometry.csv") if (d / "geometry.json").is_file() else {}
    return RunFiles(d, metrics, traj, read_sidecar(d / "trajectory.csv"), geometry, geometry_meta)


# --- small HTML helpers ----------------------------------------------------------------------------

def _e(x: Any) -> str:
    return html.escape(str(x))


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return {True: "yes", False: "no", None: "–"}[v]
    if isinstance(v, float):
        return "–" if not math.isfinite(v) else f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v) if len(v) <= 12 else f"[{len(v)} values]"
    if isinstance(v, dict):
        return "; ".join(f"{k}: {_fmt(x)}" for k, x in v.items())
    return str(v)


def _table(rows: list[dict], columns: list[str] | None = None, limit: int = 200) -> str:
    """An HTML table of dict rows (columns: the union of keys in first-seen order)."""
    cols = columns or list(dict.fromkeys(k for r in rows for k in r))
    head = "".join(f"<th>{_e(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{_e(_fmt(r.get(c)))}</td>" for c in cols) + "</tr>"
                   for r in rows[:limit])
    more = f"<p class='note'>{len(rows) - limit} more rows in metrics.json.</p>" if len(rows) > limit else ""
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>{more}"


def _kv(pairs: list[tuple[str, Any]]) -> str:
    return "<table class='kv'>" + "".join(f"<tr><th>{_e(k)}</th><td>{_e(_fmt(v))}</td></tr>" for k, v in pairs) \
        + "</table>"


def _img(fig, alt: str) -> str:
    data = base64.b64encode(figures.png_bytes(fig)).decode("ascii")
    return f"<img alt='{_e(alt)}' src='data:image/png;base64,{data}'>"


def _run_img(run: RunFiles, alt: str, make_figure) -> str:
    """The ``<img>`` of ``make_figure()``, or the one drawn before (kept in ``run.images``)."""
    if alt not in run.images:
        run.images[alt] = _img(make_figure(), alt)
    return run.images[alt]


def _section(sid: str, title: str, body: str) -> str:
    return f"<section id='{sid}'><h2>{_e(title)}</h2>{body}</section>"


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.extend(_flatten(v, key + "."))
        else:
            out.append((key, v))
    return out


# --- sections ------------------------------------------------------------------------------------------

def _sensors(config: dict, metrics: dict) -> list[str]:
    sensors = config.get("sensors", {})
    factors = config.get("factors", {})
    out = []
    for name, spec in sensors.items():
        if spec is None:
            continue
        used = factors.get(name, factors.get("imu") if name == "imu" else None)
        enabled = used.get("enabled", True) if isinstance(used, dict) else used
        label = name.replace("_", " ")
        if name == "imu" and isinstance(spec, dict) and "rate_hz" in spec:
            label += f" ({spec['rate_hz']:g} Hz, gyro bias {spec.get('gyro_bias_deg_per_h', float('nan')):g} deg/h)"
        if name == "total_stations" and isinstance(spec, dict):
            label += f" ({', '.join(sorted(spec.get('stations', {}))) or 'no set-up given'})"
        out.append(label + ("" if enabled in (None, True) else " — not fused"))
    return out


def summary_section(run: RunFiles) -> str:
    m, traj = run.metrics, run.trajectory
    config = run.trajectory_meta.get("config", {})
    chainage = traj["chainage_m"]
    travelled_m = float(np.sum(np.abs(np.diff(chainage)))) if chainage.size > 1 else 0.0
    rows: list[tuple[str, Any]] = [
        ("survey", m.get("name", config.get("name", "?"))),
        ("sensors", ", ".join(_sensors(config, m)) or "?"),
        ("duration", f"{m.get('duration_s', float(traj['t_s'][-1] - traj['t_s'][0])):.1f} s"),
        ("distance travelled", f"{travelled_m:.1f} m"),
        ("chainage covered", f"{chainage.min():.2f} m to {chainage.max():.2f} m"),
        ("origin of n", m.get("origin")),
        ("IMU samples", m.get("imu_samples")),
        ("keyframes / factors / iterations",
         f"{m.get('keyframes', '?')} / {sum(m.get('factors', {}).values())} / {m.get('iterations', '?')}"),
        ("run time", f"{m['run_time_s']:.1f} s" if "run_time_s" in m else None),
        ("output folder", str((run.shown_dir or run.run_dir).resolve())),
    ]
    if "odometer_scale_ppm" in m:
        rows.append(("odometer scale (mean)", f"{m['odometer_scale_ppm']['mean']:.1f} ppm"))
    verdict = ""
    ev = m.get("evaluation")
    if ev:
        thr = ev["thresholds"]
        ok = ev.get("passed")
        verdict = (f"<p class='verdict {'pass' if ok else 'fail'}'>The survey {'MEETS' if ok else 'DOES NOT MEET'} "
                   f"the thresholds at {thr['scale_m']:g} m (MSE &le; {thr['mse_mm']:g} mm, ADEV &le; "
                   f"{thr['adev_mm']:g} mm, {_e(' and '.join(thr['components']))}) against the reference "
                   f"{_e(m.get('reference', ''))}.</p>")
    settings = ""
    if config:
        keep = {k: config[k] for k in ("factors", "keyframes", "static", "smoother", "outputs", "trolley")
                if k in config}
        settings = f"<details><summary>settings (pipeline configuration)</summary>{_kv(_flatten(keep))}</details>"
    return _section("summary", "Run summary", verdict + _kv(rows) + settings)


def metrics_images(m: dict) -> dict[str, str]:
    """The ``<img>`` tags (alt text -> tag) of the figures drawn from ``metrics.json`` (``m``, as
    read back from the file): the relative accuracy against the reference, when evaluated. The
    pipeline draws them while its forked child still draws the table figures."""
    ra, ev = m.get("relative_accuracy"), m.get("evaluation")
    if not ra or not ev:
        return {}
    return {"relative accuracy": _img(figures.relative_accuracy(ra, ev["thresholds"]), "relative accuracy")}


def accuracy_section(m: dict, images: dict[str, str] | None = None) -> str:
    """The relative-accuracy section; its figure from ``images`` (:func:`metrics_images`) when
    drawn before."""
    ra, ev = m.get("relative_accuracy"), m.get("evaluation")
    if not ra or not ev:
        return ""
    thr = ev["thresholds"]
    rows = []
    for comp, entry in ra.items():
        rows.append({"component": comp, "sigma (mm)": entry.get("sigma_mm"),
                     f"MSE at {thr['scale_m']:g} m (mm)": entry.get("mse_at_threshold_mm"),
                     "MSE limit (mm)": thr["mse_mm"], "MSE pass": entry.get("mse_pass"),
                     f"ADEV at {thr['scale_m']:g} m (mm)": entry.get("adev_at_threshold_mm"),
                     "ADEV limit (mm)": thr["adev_mm"], "ADEV pass": entry.get("adev_pass"),
                     "checked": comp in thr["components"],
                     "absolute RMS (mm)": m.get("absolute_error", {}).get(comp, {}).get("rms_mm")})
    image = (images or {}).get("relative accuracy") or metrics_images(m)["relative accuracy"]
    body = image + _table(rows)
    return _section("relative-accuracy", "Relative accuracy against the reference", body)


def _geometry_limits(geo_metrics: dict) -> dict[str, float]:
    """Tolerance per geometry column [mm]: ``geometry.limits_mm`` when given, else the limits
    the exceedances were checked against (their ``check`` names the column)."""
    limits = {k: float(v) for k, v in (geo_metrics.get("limits_mm") or {}).items()}
    for e in geo_metrics.get("exceedances", []):
        limits.setdefault(e.get("check"), abs(float(e["limit_mm"])))
    return limits


def geometry_section(run: RunFiles) -> str:
    g = run.geometry
    if g is None:
        return ""
    gm = run.metrics.get("geometry", {})
    limits = _geometry_limits(gm)
    exceedances = gm.get("exceedances", [])
    s = g["chainage_m"]
    parts = []
    unmeasured: list[str] = []
    irr = _measured({c: g[c] for c in IRREGULARITY_COLUMNS if c in g}, unmeasured)
    if irr:
        parts.append(_run_img(run, "irregularities", lambda: figures.series_with_bands(
            s, irr, limits, "irregularities (mm)", exceedances)))
    versines = _measured({c: g[c] for c in g if _VERSINE.match(c)}, unmeasured)
    if versines:
        parts.append(_run_img(run, "versines", lambda: figures.series_with_bands(
            s, versines, limits, "chord versines (mm)", exceedances)))
    level = {c: g[c] for c in g if c == "cross_level_mm" or _TWIST.match(c)}
    if "gauge_m" in g:
        nominal = float((run.geometry_meta or {}).get("nominal_gauge_m", NOMINAL_GAUGE_M))
        level[f"gauge_minus_{nominal * 1e3:g}_mm"] = (g["gauge_m"] - nominal) * 1e3
    level = _measured(level, unmeasured)
    if unmeasured:  # said, not drawn: an empty or copied curve would look like data
        why = sorted(set((gm.get("not_measured") or {}).values())) or ["no finite value"]
        parts.append(f"<p class=\"not-measured\">Not measured ({_e('; '.join(why))}): "
                     f"{_e(', '.join(sorted(set(unmeasured))))}.</p>")
    if level:
        parts.append(_run_img(run, "cross-level", lambda: figures.series_with_bands(
            s, level, limits, "cross-level, twist and gauge (mm)", exceedances)))
    facts = [("chainage", f"{s.min():.2f} m to {s.max():.2f} m"), ("step", gm.get("step_m")),
             ("length", gm.get("length_m")),
             ("tolerances (mm)", {k: v for k, v in limits.items()} or "none given")]
    parts.append(_kv(facts))
    if exceedances:
        parts.append(f"<h3>Exceedances ({len(exceedances)})</h3>"
                     + _table(exceedances, ["check", "chainage_m", "value_mm", "limit_mm"]))
    else:
        parts.append("<p>No tolerance exceedance.</p>")
    return _section("geometry", "Track geometry", "".join(parts))


def _measured(columns: dict[str, np.ndarray], unmeasured: list[str]) -> dict[str, np.ndarray]:
    """The columns holding any finite value; the names of the others are appended to ``unmeasured``."""
    kept = {}
    for name, values in columns.items():
        if np.isfinite(np.asarray(values, dtype=float)).any():
            kept[name] = values
        else:
            unmeasured.append(name)
    return kept


def time_sync_section(m: dict) -> str:
    ts = m.get("time_sync")
    if not ts:
        return ""
    rows = [{"station": sid, "offset_s (station minus IMU clock)": e.get("offset_s"), "r_max": e.get("r_max")}
            for sid, e in sorted(ts.items())]
    return _section("time-sync", "Time synchronisation of the total stations",
                    _img(figures.time_sync_curves(ts), "time synchronisation") + _table(rows))


def registration_section(m: dict) -> str:
    reg = m.get("registration")
    if not reg:
        return ""
    parts = [_kv([("method", reg.get("method"))])]
    stations = reg.get("stations") or {}
    if stations:
        parts.append("<h3>Stations</h3>" + _table([{"station": sid, **(v if isinstance(v, dict) else {"value": v})}
                                                   for sid, v in sorted(stations.items())]))
    rows = [{"stage": stage, "component": comp, **stats}
            for stage, comps in (reg.get("residuals") or {}).items() for comp, stats in comps.items()]
    if rows:
        parts.append("<h3>Residuals before and after registration</h3>"
                     + _table(rows, ["stage", "component", "max_abs_mm", "mean_mm", "std_mm", "slope_mm_per_m"]))
    return _section("registration", "Registration of the total stations", "".join(parts))


def rejected_section(m: dict) -> str:
    parts = []
    gnss = m.get("rejected_gnss")
    if gnss is not None:
        parts.append(f"<h3>GNSS fixes ({len(gnss)})</h3>" + (_table(gnss) if gnss else "<p>None rejected.</p>"))
    prism = m.get("rejected_prism")
    if prism is not None:
        parts.append(f"<h3>Prism observations ({len(prism)})</h3>"
                     + (_table(prism, ["station", "t_s", "reason"]) if prism else "<p>None rejected.</p>"))
    odo = m.get("odometer_gross_errors")
    if odo:
        parts.append(f"<h3>Odometer gross errors repaired ({len(odo)})</h3>"
                     + _table(odo if isinstance(odo[0], dict) else [{"record": x} for x in odo]))
    return _section("rejected", "Rejected measurements", "".join(parts)) if parts else ""


def faults_section(m: dict) -> str:
    faults = m.get("faults")
    if faults is None:
        return ""
    if not faults:
        return _section("faults", "Detected data faults", "<p>No data fault detected.</p>")
    parts = []  # issue 8: one table per fault kind, one row per event (times on the IMU clock)
    for name, v in faults.items():
        if isinstance(v, dict) and isinstance(v.get("events"), list):
            extra = {k: x for k, x in v.items() if k not in ("count", "events")}
            parts.append(f"<h3>{_e(name)} ({v['count']})" + (f" – {_e(_fmt(extra))}" if extra else "") + "</h3>"
                         + _table(v["events"]))
        else:
            parts.append(f"<h3>{_e(name)}</h3>" + _kv(_flatten(v) if isinstance(v, dict) else [("detail", v)]))
    return _section("faults", "Detected data faults", "".join(parts))


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:24px auto;max-width:1150px;
color:#1b1f24;background:#fff;padding:0 16px}
h1{font-size:1.6em;margin-bottom:0.2em}h2{border-bottom:2px solid #d0d7de;padding-bottom:4px;margin-top:1.6em}
table{border-collapse:collapse;margin:8px 0;font-size:0.85em}th,td{border:1px solid #d0d7de;padding:3px 8px;
text-align:left}thead th{background:#f6f8fa}table.kv th{background:#f6f8fa;width:16em}
img{max-width:100%;height:auto;display:block;margin:8px 0}.note{color:#57606a;font-size:0.85em}
.verdict{font-weight:bold;padding:8px 12px;border-radius:6px}.pass{background:#dafbe1;color:#116329}
.fail{background:#ffebe9;color:#a40e26}nav a{margin-right:12px}
"""


def trajectory_sections(run: RunFiles) -> list[str]:
    """The trajectory plan and profile and the position sigmas."""
    return [_section("trajectory", "Trajectory plan and profile",
                     _run_img(run, "plan and profile", lambda: figures.plan_and_profile(run.trajectory))),
            _section("sigmas", "Position sigmas along chainage",
                     _run_img(run, "position sigmas", lambda: figures.sigmas_along_chainage(run.trajectory)))]


def render_report(run: RunFiles) -> str:
    """The whole HTML document of a run (a string)."""
    m = run.metrics
    sections = [summary_section(run), *trajectory_sections(run), accuracy_section(m, run.images), geometry_section(run), time_sync_section(m), registration_section(m),
                rejected_section(m), faults_section(m)]
    sections = [s for s in sections if s]
    nav = "".join(f"<a href='#{sid}'>{_e(title)}</a>" for sid, title in
                  re.findall(r"<section id='([^']+)'><h2>([^<]+)</h2>", "".join(sections)))
    name = _e(m.get("name", "survey"))
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>trackfusion report: {name}</title><style>{_CSS}</style></head><body>"
            f"<h1>trackfusion report: {name}</h1><p class='note'>{_e(m.get('description', ''))}</p>"
            f"<nav>{nav}</nav>{''.join(sections)}</body></html>\n")


def table_images(trajectory: dict[str, np.ndarray], geometry: dict[str, np.ndarray] | None = None,
                 geometry_metrics: dict | None = None, geometry_meta: dict | None = None) -> dict[str, str]:
    """The ``<img>`` tags (alt text -> tag) of the figures drawn from the trajectory and geometry
    tables alone (plan and profile, sigmas, the geometry section's; not those of the metrics): the
    pipeline draws them in a forked child while it evaluates, and :func:`write_report` takes
    them (``images``). ``geometry_metrics``: ``metrics["geometry"]`` as in metrics.json;
    ``geometry_meta``: the geometry.csv sidecar."""
    run = RunFiles(Path("."), {"geometry": geometry_metrics or {}}, trajectory, {}, geometry, geometry_meta)
    trajectory_sections(run)  # these draw their figures into run.images
    geometry_section(run)
    return run.images


def write_report(run_dir: str | Path, path: str | Path | None = None, shown_dir: str | Path | None = None,
                 tables: dict[str, dict[str, np.ndarray]] | None = None,
                 images: dict[str, str] | None = None) -> Path:
    """Write ``report.html`` of the run in ``run_dir`` (default: inside it); returns its path.
    ``shown_dir``: the output folder named in the report (default ``run_dir``; the pipeline
    writes from a staging folder). ``tables``: the folder's CSV tables already in memory
    (:func:`load_run`); ``images``: figures already drawn from them (:func:`table_images`)."""
    run = load_run(run_dir, tables)
    if shown_dir is not None:
        run.shown_dir = Path(shown_dir)
    run.images = dict(images or {})
    out = Path(path) if path is not None else Path(run_dir) / "report.html"
    write_text_atomic(out, render_report(run))
    return out


def write_report_pdf(run_dir: str | Path, path: str | Path | None = None) -> Path:
    """Print ``report.html`` of ``run_dir`` (written first when missing) to ``report.pdf`` with
    headless Chromium; raises :class:`ReportError` when Chromium is not installed."""
    from .chromium import print_pdf

    run_dir = Path(run_dir)
    html_path = run_dir / "report.html"
    if not html_path.is_file():
        write_report(run_dir, html_path)
    out = Path(path) if path is not None else run_dir / "report.pdf"
    with atomic_path(out) as tmp:
        print_pdf(html_path, tmp)
    return out
