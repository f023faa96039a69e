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

from ..errors import ReportError, SensorDataError
from ..sensors.fileio import atomic_path, read_csv_table, read_json, read_sidecar, write_text_atomic
from . import figures
from .track_plots import column_label, column_unit, measured

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
    if "vision" in metrics:  # its figures are drawn from the log's frames and the calibration, not kept in the folder
        raise ReportError(f"{d / 'metrics.json'}: the folder of a vision run, whose report.html 'trackfusion run' "
                          "writes; re-rendering it from the folder alone is not supported")
    traj = table("trajectory.csv", TRAJECTORY_REQUIRED)
    geometry = geometry_meta = None
    if (d / "geometry.csv").is_file():
        geometry = table("geometry.csv", ("chainage_m",))
        geometry_meta = read_sidecar(d / "geometry.csv") if (d / "geometry.json").is_file() else {}
    return RunFiles(d, metrics, traj, read_sidecar(d / "trajectory.csv"), geometry, geometry_meta)


# --- small HTML helpers ----------------------------------------------------------------------------

def _e(x: Any) -> str:
    return html.escape(str(x))


def num(v: float, decimals: int) -> str:
    """``v`` with ``decimals`` decimals, never ``-0.00`` (a value that rounds to zero is unsigned)."""
    s = f"{v:.{decimals}f}"
    return s.lstrip("-") if float(s) == 0.0 else s


#: Decimals of a table cell by the unit suffix of its column (what the measurements resolve:
#: 1 um and 1 ms in mm / m / s columns, 0.1 ms for clock offsets, 0.1 mm for latitude and
#: longitude, 0.04" for other angles in degrees); other floats get 4 significant digits.
_DECIMALS = (("offset_s", 4), ("clock (s)", 4), ("_mm", 3), ("(mm)", 3), ("_m", 3), ("(m)", 3), ("_s", 3), ("(s)", 3),
             ("_ppm", 1), ("_arcsec", 2), ("lat_deg", 9), ("lon_deg", 9), ("_deg", 5), ("_mrad", 3))


def _decimals(column: str | None) -> int | None:
    col = (column or "").strip()
    for suffix, d in _DECIMALS:
        if col.endswith(suffix):
            return d
    return None


def _fmt(v: Any, column: str | None = None) -> str:
    """A value for a table cell; floats rounded by their column's unit (:data:`_DECIMALS`)."""
    if isinstance(v, bool) or v is None:
        return {True: "yes", False: "no", None: "–"}[v]
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        d = _decimals(column)
        return num(v, d) if d is not None else num(v, 0) if v == 0 else f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x, column) for x in v) if len(v) <= 12 else f"[{len(v)} values]"
    if isinstance(v, dict):
        return "; ".join(f"{k}: {_fmt(x, k)}" for k, x in v.items())
    return str(v)


def _table(rows: list[dict], columns: list[str] | None = None, limit: int = 200) -> str:
    """An HTML table of dict rows (columns: the union of keys in first-seen order). A row's
    ``_id`` becomes the row's anchor id; a value of :class:`Raw` is inserted as HTML."""
    cols = columns or list(dict.fromkeys(k for r in rows for k in r if k != "_id"))
    head = "".join(f"<th>{_e(c)}</th>" for c in cols)

    def cell(r: dict, c: str) -> str:
        v = r.get(c)
        return f"<td>{v}</td>" if isinstance(v, Raw) else f"<td>{_e(_fmt(v, c))}</td>"

    body = "".join((f"<tr id='{_e(r['_id'])}'>" if "_id" in r else "<tr>") + "".join(cell(r, c) for c in cols)
                   + "</tr>" for r in rows[:limit])
    more = f"<p class='note'>{len(rows) - limit} more rows in metrics.json.</p>" if len(rows) > limit else ""
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>{more}"


class Raw(str):
    """A table cell holding HTML (already escaped)."""


def _kv(pairs: list[tuple[str, Any]]) -> str:
    return "<table class='kv'>" + "".join(f"<tr><th>{_e(k)}</th><td>{_e(_fmt(v, k))}</td></tr>" for k, v in pairs) \
        + "</table>"


def _img(fig, alt: str, spots: list[tuple[str, int, int, int, int]] | None = None) -> str:
    """The ``<img>`` of a figure; ``spots`` (label, x0, y0, x1, y1 in pixels) add an image map
    whose areas link to the anchors ``exc-<label>`` of the exceedance list."""
    data = base64.b64encode(figures.png_bytes(fig)).decode("ascii")
    if not spots:
        return f"<img alt='{_e(alt)}' src='data:image/png;base64,{data}'>"
    name = "map-" + re.sub(r"[^a-z0-9]+", "-", alt.lower())
    areas = "".join(f"<area shape='rect' coords='{x0},{y0},{x1},{y1}' href='#exc-{_e(label)}' alt='{_e(label)}' "
                    f"title='exceedance {_e(label)}'>" for label, x0, y0, x1, y1 in spots)
    return (f"<img id='fig-{name[4:]}' alt='{_e(alt)}' usemap='#{name}' src='data:image/png;base64,{data}'>"
            f"<map name='{name}'>{areas}</map>")


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

def _smoothed(smoothing: dict | None) -> str | None:
    """The summary's line of metrics.json ``smoothing``: one batch, or the chunks and their joins
    [min after the first IMU sample]; None for a run written before it."""
    if not smoothing:
        return None
    limit = smoothing.get("one_batch_up_to_s")
    if smoothing["one_batch"]:
        return "one batch" + (f" (up to {limit:.0f} s: smoother.chunk_s)" if limit is not None else "")
    joins = smoothing["joins_s"]
    return (f"in {len(joins) + 1} chunks of {smoothing['chunk_length_s']:.0f} s with {smoothing['overlap_s']:.0f} s "
            f"overlap (longer than {limit:.0f} s: smoother.chunk_s), joined "
            + ", ".join(f"{(t - smoothing['start_s']) / 60.0:.1f}" for t in joins) + " min after the start")


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
        ("chainage covered", f"{num(float(chainage.min()), 2)} m to {num(float(chainage.max()), 2)} m"),
        ("origin of n", m.get("origin")),
        ("IMU samples", m.get("imu_samples")),
        ("keyframes / factors / iterations",
         f"{m.get('keyframes', '?')} / {sum(m.get('factors', {}).values())} / {m.get('iterations', '?')}"),
        ("smoothed", _smoothed(m.get("smoothing"))),
        ("run time", f"{m['run_time_s']:.1f} s" if "run_time_s" in m else None),
        ("output folder", str((run.shown_dir or run.run_dir).resolve())),
    ]
    if "odometer_scale_ppm" in m:
        sc = m["odometer_scale_ppm"]
        rows.append(("odometer scale (mean; drift)",
                     f"{sc['mean']:.1f} ppm; {sc.get('drift_ppm_per_h', 0.0):+.0f} ppm/h"))
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
        keep = {k: config[k] for k in ("factors", "keyframes", "static", "smoother", "outputs", "vehicle", "trolley")
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


def _levels_by_column(gm: dict) -> dict[str, dict[str, float]]:
    """Tolerance levels per geometry column (level -> limit [mm]): the ``tolerance_checks`` of
    metrics ``geometry``; runs written before them: ``limits_mm`` or the exceedances' limits."""
    out: dict[str, dict[str, float]] = {}
    for c in gm.get("tolerance_checks") or []:
        for col in c.get("columns", []):
            out.setdefault(col, {}).update({k: float(v) for k, v in (c.get("levels_mm") or {}).items()})
    for col, v in (gm.get("limits_mm") or {}).items():
        out.setdefault(col, {"limit": float(v)})
    for e in gm.get("exceedances", []):
        out.setdefault(_column(e), {"limit": abs(float(e["limit_mm"]))})
    return out


def _column(e: dict) -> str:
    """The geometry column an exceedance is on (``check`` is ``<check name>:<column>``)."""
    return e.get("column") or str(e.get("check", "")).split(":")[-1]


def _exceedances(gm: dict) -> list[dict]:
    """The exceedances in chainage order, each with ``column``, ``from_m`` / ``to_m`` (the peak's
    chainage for runs that did not write them) and its list label ``E1``, ``E2``, ..."""
    rows = [dict(e, column=_column(e), from_m=e.get("from_m", e["chainage_m"]), to_m=e.get("to_m", e["chainage_m"]))
            for e in gm.get("exceedances", [])]
    rows.sort(key=lambda e: (e["from_m"], e["column"]))
    return [dict(e, label=f"E{k}") for k, e in enumerate(rows, 1)]


def _tolerance_verdict(gm: dict, n_exceedances: int) -> str:
    """What the tolerance check found, in words: no table given; checks skipped (and why);
    exceedances or none."""
    table = gm.get("tolerance_table")
    skipped = gm.get("skipped_checks") or []
    checks = gm.get("tolerance_checks")
    if table is None and not n_exceedances and not gm.get("limits_mm"):
        return ("<p class='verdict none'>No tolerance table given (<code>geometry.tolerances</code>): "
                "the geometry was not checked against limits.</p>")
    parts = []
    name = f"table <b>{_e(table)}</b>" if table else "the given limits"
    n_checks = len(checks) if checks is not None else None
    skipped_names = {s.get("check") for s in skipped}
    if n_checks is not None and skipped and len(skipped_names) >= n_checks and not n_exceedances:
        parts.append(f"<p class='verdict none'>Not checked: every check of {name} was skipped.</p>")
    elif n_exceedances:
        parts.append(f"<p class='verdict fail'>{n_exceedances} exceedance{'s' if n_exceedances > 1 else ''} of "
                     f"{name} (list below).</p>")
    else:
        done = "" if n_checks is None else f" ({n_checks - len(skipped_names & {c['name'] for c in checks})} of {n_checks} checks made)"
        parts.append(f"<p class='verdict pass'>No exceedance of {name}{done}.</p>")
    if skipped:
        parts.append("<p>Skipped checks:</p><ul>" + "".join(
            f"<li><b>{_e(s.get('check'))}</b>: {_e(s.get('reason', 'no reason given'))}</li>" for s in skipped)
            + "</ul>")
    return "".join(parts)


def _exceedance_table(rows: list[dict], figure_of: dict[str, str]) -> str:
    out = []
    for e in rows:
        fig = figure_of.get(e["column"])
        label = _e(e["label"])
        link = Raw(f"<a href='#fig-{fig}'>{label}</a>" if fig else label)
        length = e.get("length_m")
        level = str(e.get("level", "limit")).replace("_", " ")
        out.append({"_id": f"exc-{e['label']}", "#": link, "check": str(e.get("check", "")).split(":")[0],
                    "quantity": column_label(e["column"]) if e["column"] in figure_of else e["column"].replace("_", " "),
                    "from (m)": num(e["from_m"], 2), "to (m)": num(e["to_m"], 2),
                    "length (m)": "–" if length is None else num(length, 2),
                    "peak (mm)": num(e["value_mm"], 2), "at (m)": num(e["chainage_m"], 2), "level": level,
                    "limit (mm)": num(abs(float(e["limit_mm"])), 2),
                    **({"pass": str(e["pass_index"])} if "pass_index" in e else {})})
    return _table(rows=out)


def _quality_table(gm: dict) -> str:
    qi = gm.get("quality_index")
    if not qi:
        return ""
    head = (f"<h3 id='quality-index'>Track quality index: standard deviation per {qi.get('section_m', 200):g} m "
            "section (EN 13848-6 style, D1)</h3>")
    if not qi.get("sections"):
        return head + f"<p>Not computed: {_e(qi.get('not_computed', 'no measured D1 column'))}.</p>"
    names = list(qi.get("columns", {}))
    rows = [{"section (m)": f"{s['from_m']:g} – {s['to_m']:g}",
             **{f"{q} (mm)": "–" if s.get(q) is None else num(s[q], 2) for q in names}} for s in qi["sections"]]
    note = ("<p class='note'>A section gets a value when at least half of it was measured. "
            + (f"Not measured: {_e(', '.join(qi['not_measured']))}. " if qi.get("not_measured") else "")
            + "</p>")
    return head + _table(rows) + note


def _gauge_deviation_mm(run: RunFiles) -> np.ndarray | None:
    """The gauge minus nominal [mm] when a gauge was measured (None: no gauge sensor, a
    constant nominal gauge, or an all-NaN column)."""
    g = run.geometry
    gm = run.metrics.get("geometry", {})
    if str(gm.get("gauge", "")).startswith("nominal"):
        return None
    if "gauge_variation_mm" in g:
        dev = np.asarray(g["gauge_variation_mm"], float)
    elif "gauge_m" in g:
        nominal = float((run.geometry_meta or {}).get("nominal_gauge_m", NOMINAL_GAUGE_M))
        dev = (np.asarray(g["gauge_m"], float) - nominal) * 1e3
    else:
        return None
    ok = np.isfinite(dev)
    return dev if ok.any() and np.ptp(dev[ok]) > 0 else None


#: The geometry figures: alt text (and anchor) -> title.
GEOMETRY_FIGURES = {"irregularities": "irregularities: longitudinal level and alignment (mm)",
                    "versines": "chord versines (mm)", "cross-level": "cross-level, twist and gauge (mm)"}


def _geometry_panels(run: RunFiles) -> dict[str, list[str]]:
    """The columns drawn in each geometry figure (measured ones only), by figure alt text."""
    g = run.geometry
    cols = {"irregularities": [c for c in IRREGULARITY_COLUMNS if c in g],
            "versines": [c for c in g if _VERSINE.match(c)],
            "cross-level": [c for c in g if c == "cross_level_mm" or _TWIST.match(c)]}
    return {k: measured(g, v) for k, v in cols.items()}


def geometry_section(run: RunFiles) -> str:
    g = run.geometry
    if g is None:
        return ""
    gm = run.metrics.get("geometry", {})
    levels = _levels_by_column(gm)
    exceedances = _exceedances(gm)
    s = g["chainage_m"]
    panels = _geometry_panels(run)
    gauge = _gauge_deviation_mm(run)
    candidates = [c for c in IRREGULARITY_COLUMNS if c in g] + [c for c in g if _VERSINE.match(c)]
    not_measured = [c for c in candidates if c not in panels["irregularities"] + panels["versines"]]
    figure_of = {c: alt for alt, cols in panels.items() for c in cols}
    if gauge is not None:
        figure_of["gauge_variation_mm"] = "cross-level"
    parts = [_tolerance_verdict(gm, len(exceedances))]
    for alt, title in GEOMETRY_FIGURES.items():
        series = {c: np.asarray(g[c], float) for c in panels[alt]}
        if alt == "cross-level" and gauge is not None:
            series["gauge_variation_mm"] = gauge
        if not series:
            continue
        labels = {c: f"{column_label(c)} ({column_unit(c) or 'mm'})" for c in series}
        if "gauge_variation_mm" in series:
            nominal = float((run.geometry_meta or {}).get("nominal_gauge_m", NOMINAL_GAUGE_M))
            labels["gauge_variation_mm"] = f"gauge minus {nominal * 1e3:g} mm (mm)"

        def draw(series=series, labels=labels, title=title, alt=alt):
            fig, spots = figures.series_with_bands(s, series, levels, title, exceedances, labels)
            return _img(fig, alt, spots)

        if alt not in run.images:
            run.images[alt] = draw()
        parts.append(run.images[alt])
    if not_measured or gauge is None:
        gauge_note = ["gauge (no gauge sensor: nominal gauge used)"] if gauge is None else []
        parts.append("<p class='note'>Not measured (not drawn): "
                     + _e(", ".join([column_label(c) for c in not_measured] + gauge_note)) + ".</p>")
    facts = [("chainage", f"{num(float(np.nanmin(s)), 2)} m to {num(float(np.nanmax(s)), 2)} m"),
             ("grid step", f"{gm['step_m']:g} m" if "step_m" in gm else None),
             ("chainage from", gm.get("chainage")), ("irregularities against", gm.get("irregularity_reference")),
             ("gauge from", gm.get("gauge")), ("passes", gm.get("passes")),
             ("tolerance table", gm.get("tolerance_table") or "none given")]
    parts.append(_kv([(k, v) for k, v in facts if v is not None]))
    if exceedances:
        parts.append(f"<h3 id='exceedances'>Exceedances ({len(exceedances)})</h3>"
                     "<p class='note'>Each shaded stretch on the plots links to its row; # links back to the plot. "
                     "From / to: the first and last sample beyond the mildest level; level: the highest the "
                     "peak reaches.</p>" + _exceedance_table(exceedances, figure_of))
    parts.append(_quality_table(gm))
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
    rows = [{"station": sid, "offset, station minus IMU clock (s)": e.get("offset_s"), "r_max": e.get("r_max")}
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


def _noise_rows(ne: dict) -> list[dict]:
    """One row per estimated noise component of ``metrics["noise_estimates"]``: the configured
    (datasheet) and estimated sigma and the factor the smoother applied."""
    rows = []
    for group, comps in ne.items():
        if group in ("imu", "gnss", "components", "gnss_time_constant") or not isinstance(comps, dict):
            continue
        for comp, e in comps.items():
            unit = next((k[len("configured_sigma_"):] for k in e if k.startswith("configured_sigma_")), None)
            rows.append({"group": group, "component": comp,
                         "configured sigma": e.get(f"configured_sigma_{unit}") if unit else None,
                         "estimated sigma": e.get(f"estimated_sigma_{unit}") if unit else None,
                         "unit": (unit or "").replace("_per_", "/"), "sigma scale": e["sigma_scale"],
                         "its 1-sigma": e["sigma_scale_sigma"],
                         "applied sigma scale": e["applied_variance_factor"] ** 0.5,
                         "redundancy": e["redundancy"], "rows": e["rows"]})
    gnss = ne.get("gnss")
    if gnss:
        for i, axis in enumerate(("horizontal", "vertical")):
            rows.append({"group": "gnss (white)", "component": axis,
                         "configured sigma": gnss["stated_white_sigma_mm"][2 * i],
                         "estimated sigma": gnss["estimated_white_sigma_mm"][2 * i], "unit": "mm",
                         "sigma scale": gnss["sigma_scale"][axis], "its 1-sigma": gnss["sigma_scale_sigma"][axis],
                         "applied sigma scale": gnss["applied_variance_factor"][axis] ** 0.5,
                         "redundancy": gnss["mean_redundancy"][axis], "rows": gnss["fixes"]})
    return rows


def noise_section(m: dict) -> str:
    """Each measurement group's noise estimated from the data beside its datasheet value
    (docs/noise_estimation.md)."""
    ne = m.get("noise_estimates") or {}
    rows = _noise_rows(ne)
    if not rows:
        return ""
    return _section("noise", "Sensor noise estimated from the data",
                    "<p class='note'>Configured (datasheet) and estimated sigma of each measurement group; the "
                    "smoother applies an estimate that differs significantly (applied sigma scale).</p>"
                    + _table(rows) + _time_constant_part(ne.get("gnss_time_constant")))


def _time_constant_part(tc: dict | None) -> str:
    """The GNSS correlated error's time constant estimated (fusion/gnss_time_constant.py), if it was."""
    if not tc:
        return ""
    lo, hi = tc["interval_95_s"]
    profile = [{"time constant": f"{t:.1f} s", "log-likelihood below the peak": f"{abs(v):.2f}"}
               for t, v in zip(tc.get("profile_tau_s", []), tc.get("profile_log_likelihood", []))]
    return ("<h3>GNSS correlated error: time constant</h3>"
            + _kv([("configured", f"{tc['configured_s']:g} s"), ("estimated", f"{tc['estimate_s']:.0f} s"),
                   ("95 % interval", f"{lo:.0f} s to " + (f"{hi:.0f} s" if hi is not None else "unbounded")),
                   ("applied", "yes: the survey solved again with it" if tc["applied"] else "no")])
            + ("<p class='note'>The survey's likelihood at each time constant tried; the 95 % interval spans "
               "those less than 1.92 below the peak, and the configured one is replaced only when it lies "
               "further below (a flat profile resolves nothing).</p>" + _table(profile) if profile else ""))


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
    parts = []  # the data faults: one table per fault kind, one row per event (times on the IMU clock)
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
.fail{background:#ffebe9;color:#a40e26}.none{background:#fff8c5;color:#633c01}nav a{margin-right:12px}
tr:target{background:#fff8c5}code{font-size:0.9em}
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
                noise_section(m), rejected_section(m), faults_section(m)]
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
