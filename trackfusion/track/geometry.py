"""Track geometry of a survey: the ``geometry:`` pipeline section and :func:`compute_geometry`.

From the dense smoothed trajectory, its chainage and the gauge readings: rail traces per pass
(:mod:`.traces`), then per pass and on the chainage grid the gauge, cross-level, twist,
irregularities (against the design when given, else EN 13848 bands), versines, the
deformation index; tolerance checks from a table in ``trackfusion/data/tolerances``; repeated
passes averaged into one table and their repeatability (seed 000 tables 2-3). Column names
follow the geometry.csv contract (docs/geometry.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from pydantic import Field, ValidationError

from ..errors import ConfigError, EvaluationError, TrackGeometryError, config_error_from_validation
from ..evaluation.repeatability import repeatability
from ..sensors.types import GaugeData
from ..strict import StrictModel
from . import irregularities as irr
from .chainage import curvature_matched_chainage, project_onto_design, regrid
from .design import DesignAlignment
from .quality import SECTION_M, quality_index
from .shortwave import deformation_index, detect_defects, merge_defects, spatial_spectrum
from .traces import GaugeSmoothing, RailTraces, TrajectoryOnTrack, TrolleyGeometry, rail_traces
from .versines import chord_indicator, chord_offsets

RAILS = ("left", "right")


class AsymmetricChord(StrictModel):
    """A chord from ``before_m`` behind the point to ``after_m`` ahead of it [m]."""

    before_m: float = Field(ge=0)
    after_m: float = Field(ge=0)


class DeformationIndexConfig(StrictModel):
    """Seed 000's DI: standing below ``v_min_mps``; defect where |DI| > ``threshold_deg_per_m``;
    detections closer than ``merge_m`` are one defect."""

    enabled: bool = True
    v_min_mps: float = Field(0.1, gt=0)
    threshold_deg_per_m: float = Field(25.0, gt=0)
    merge_m: float = Field(0.5, gt=0)


class GeometryConfig(StrictModel):
    """The ``geometry:`` pipeline section (docs/geometry.md)."""

    enabled: bool = True
    chainage: Literal["auto", "odometer", "projection", "curvature_matching"] = "auto"
    start_chainage_m: float = 0.0
    chords_m: list[float] = Field(default_factory=lambda: [10.0])
    asymmetric_chords: list[AsymmetricChord] = []
    twist_bases_m: list[float] = Field(default_factory=lambda: [3.0])
    irregularity_band: Literal["D1", "D2", "D3"] = "D1"
    extra_bands: list[Literal["D1", "D2", "D3"]] = []
    tolerances: str | None = None
    nominal_gauge_m: float = Field(1.435, gt=0)
    min_speed_mps: float = Field(0.05, gt=0)
    attitude_crossover_m: float | None = Field(100.0, gt=0)
    gauge_filter: Literal["wiener", "box"] = "wiener"
    gauge_sigma_mm: float | None = Field(None, ge=0)
    gauge_window_m: float = Field(0.25, gt=0)
    repeatability_chords_m: list[float] = Field(default_factory=lambda: [1.0, 10.0])
    repeatability_limits_mm: list[float] = Field(default_factory=lambda: [0.1, 1.0])
    deformation_index: DeformationIndexConfig = DeformationIndexConfig()

    def gauge_smoothing(self, step_m: float) -> GaugeSmoothing:
        """How the gauge readings are smoothed on a chainage grid of ``step_m`` [m] (the box is at
        least one step wide)."""
        return GaugeSmoothing(self.nominal_gauge_m, self.gauge_filter, max(self.gauge_window_m, step_m),
                              None if self.gauge_sigma_mm is None else 1e-3 * self.gauge_sigma_mm)


#: EN 13848-5 style levels of a check, mildest first: alert (plan maintenance), intervention
#: (correct within a set time), immediate action (restrict or stop traffic).
LEVELS = ("alert", "intervention", "immediate_action")

#: Geometry columns of a ``kind: limit`` check's quantity (``L``: its ``length_m`` as ``%g``).
LIMIT_COLUMNS = {
    "vertical_versine": lambda L: [f"{r}_vertical_versine_{L}m_mm" for r in RAILS],
    "lateral_versine": lambda L: [f"{r}_lateral_versine_{L}m_mm" for r in RAILS],
    "longitudinal_level": lambda L: [f"{r}_vertical_mm" for r in RAILS],
    "alignment": lambda L: [f"{r}_lateral_mm" for r in RAILS],
    "twist": lambda L: [f"twist_{L}m_mm"],
    "cross_level": lambda L: ["cross_level_mm"],
    "gauge_variation": lambda L: ["gauge_variation_mm"],
}


@dataclass(frozen=True)
class ToleranceCheck:
    """One check of a tolerance table (see the YAML files in ``trackfusion/data/tolerances``).

    A check gives one ``limit_mm``, or EN 13848-5 style levels ``alert_mm``, ``intervention_mm``,
    ``immediate_action_mm`` (any of them, increasing; ``limit_mm`` then defaults to the mildest)."""

    name: str
    kind: str
    limit_mm: float | None = None
    quantity: str | None = None
    length_m: float | None = None
    chord_m: float | None = None
    spacing_m: float | None = None
    alert_mm: float | None = None
    intervention_mm: float | None = None
    immediate_action_mm: float | None = None

    def levels(self) -> list[tuple[str, float]]:
        """(level name, limit [mm]) mildest first: the EN 13848-5 style levels given, else
        ``[("limit", limit_mm)]``."""
        given = [(lv, float(getattr(self, f"{lv}_mm"))) for lv in LEVELS if getattr(self, f"{lv}_mm") is not None]
        return given or [("limit", float(self.limit_mm))]

    def threshold_mm(self) -> float:
        """The value beyond which a stretch is an exceedance [mm]: the mildest level."""
        return self.levels()[0][1]

    def columns(self) -> list[str]:
        """The geometry columns a ``kind: limit`` check applies to."""
        L = fmt_length(self.length_m) if self.length_m is not None else ""
        return LIMIT_COLUMNS[self.quantity](L)


def _check_tolerance(c: ToleranceCheck, source: str) -> None:
    if c.kind not in ("limit", "chord_indicator"):
        raise ConfigError(f"{source}: check {c.name}: unknown kind {c.kind!r}")
    if c.kind == "limit" and c.quantity not in LIMIT_COLUMNS:
        raise ConfigError(f"{source}: check {c.name}: unknown quantity {c.quantity!r} "
                          f"(one of {', '.join(LIMIT_COLUMNS)})")
    levels = [getattr(c, f"{lv}_mm") for lv in LEVELS if getattr(c, f"{lv}_mm") is not None]
    if c.limit_mm is None and not levels:
        raise ConfigError(f"{source}: check {c.name}: needs limit_mm or alert_mm / intervention_mm / "
                          "immediate_action_mm")
    values = ([c.limit_mm] if c.limit_mm is not None else []) + levels
    if any(not isinstance(v, (int, float)) or not v > 0 for v in values):
        raise ConfigError(f"{source}: check {c.name}: limits must be positive numbers of mm")
    if any(b <= a for a, b in zip(levels, levels[1:])):
        raise ConfigError(f"{source}: check {c.name}: alert_mm < intervention_mm < immediate_action_mm must increase")


def parse_tolerances(data: Any, source: str, default_name: str) -> tuple[str, list[ToleranceCheck]]:
    """A tolerance table from its parsed YAML mapping (``name``, ``checks``); ``source`` names it
    in messages, ``default_name`` is its name when the table gives none. The file is read at the
    I/O boundary (:func:`trackfusion.geometry_inputs.load_tolerances`)."""
    try:
        checks = [ToleranceCheck(**c) for c in data["checks"]]
    except (KeyError, TypeError) as exc:
        raise ConfigError(f"{source}: invalid tolerance table ({exc})") from None
    for c in checks:
        _check_tolerance(c, source)
    checks = [c if c.limit_mm is not None else replace(c, limit_mm=c.threshold_mm()) for c in checks]
    return str(data.get("name", default_name)), checks


def parse_geometry_config(data: Any, source: str) -> GeometryConfig:
    try:
        return GeometryConfig.model_validate(data or {})
    except ValidationError as exc:
        raise config_error_from_validation(exc, f"{source}: geometry") from None


def fmt_length(x: float) -> str:
    """``%g`` of a length, as in the column names (3, 10, 1.5, 18.8976)."""
    return f"{x:g}"


@dataclass
class GeometryResult:
    """``table`` column -> (N,) on the chainage grid (mean over passes), ``units``,
    ``metrics`` (the metrics.json ``geometry`` section), ``passes`` the per-pass tables,
    ``traces`` the per-pass rail traces, ``di`` per pass (chainage (M,), DI (M,) [deg/m])."""

    table: dict[str, np.ndarray]
    units: dict[str, str]
    metrics: dict[str, Any]
    passes: list[dict[str, np.ndarray]] = field(default_factory=list)
    traces: list[RailTraces] = field(default_factory=list)
    di: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    def sidecar(self) -> dict[str, Any]:
        """Extra keys of geometry.json: what the columns rest on and their sign conventions."""
        return {"description": "track geometry per chainage step: rail reference points (top of rail / running "
                               "edge) in n and the quantities derived from them (docs/geometry.md)",
                "chainage": self.metrics["chainage"], "irregularity_reference": self.metrics["irregularity_reference"],
                "gauge": self.metrics["gauge"], "passes": self.metrics["passes"],
                "not_measured": self.metrics.get("not_measured", {}),
                "sign_conventions": {"cross_level_mm": "left rail height minus right rail height",
                                     "vertical": "positive up", "lateral": "positive to the left of increasing chainage",
                                     "twist": "cross_level(s + B/2) - cross_level(s - B/2)"}}


def pitch_rate_v(R_nb: np.ndarray, gyro_b: np.ndarray, gyro_bias_b: np.ndarray, omega_ie_n: np.ndarray,
                 R_vb: np.ndarray) -> np.ndarray:
    """Pitch rate [rad/s] (N,) of the trolley (nose up positive: minus the rate about ``y_v``)
    from the gyro (N, 3) [rad/s], its bias (N, 3) and the Earth rate in ``n`` (3,)."""
    w_nb_b = gyro_b - gyro_bias_b - np.einsum("nji,j->ni", R_nb, omega_ie_n)
    return -(w_nb_b @ R_vb.T)[:, 1]


def _pass_table(tr: RailTraces, cfg: GeometryConfig, chords: list[tuple[float, float]], bases: list[float],
                step_m: float, design_track, design_s: np.ndarray | None) -> dict[str, np.ndarray]:
    s = tr.chainage_m
    cols: dict[str, np.ndarray] = {"chainage_m": s}
    for side in RAILS:
        p = tr.rail(side)
        cols.update({f"{side}_e_m": p[:, 0], f"{side}_n_m": p[:, 1], f"{side}_u_m": p[:, 2]})
    cols["gauge_m"] = tr.gauge_m
    cl = irr.cross_level(tr.left_n, tr.right_n)
    cols["cross_level_mm"] = 1e3 * cl
    for b in bases:
        cols[f"twist_{fmt_length(b)}m_mm"] = 1e3 * irr.twist(s, cl, b)
    bands = [cfg.irregularity_band, *[b for b in cfg.extra_bands if b != cfg.irregularity_band]]
    for side in RAILS:
        p = tr.rail(side)
        if design_track is not None:
            v, l = irr.against_design(p, design_s, design_track, side)
        else:
            v, l = irr.banded(p, step_m, irr.EN13848_BANDS[bands[0]])
        cols[f"{side}_vertical_mm"], cols[f"{side}_lateral_mm"] = 1e3 * v, 1e3 * l
    for band in bands[1:] if design_track is None else bands:
        for side in RAILS:
            v, l = irr.banded(tr.rail(side), step_m, irr.EN13848_BANDS[band])
            cols[f"{side}_vertical_{band}_mm"], cols[f"{side}_lateral_{band}_mm"] = 1e3 * v, 1e3 * l
    cols["gauge_variation_mm"] = 1e3 * (tr.gauge_m - cfg.nominal_gauge_m)
    for a, b in chords:
        name = fmt_length(a + b) if a == b else f"{fmt_length(a)}+{fmt_length(b)}"
        for side in RAILS:
            v, l = chord_offsets(s, tr.rail(side), a, b)
            cols[f"{side}_vertical_versine_{name}m_mm"] = 1e3 * v
            cols[f"{side}_lateral_versine_{name}m_mm"] = 1e3 * l
    cols["t_s"] = tr.t_s
    return cols


def _units(names) -> dict[str, str]:
    def unit(n: str) -> str:
        return "mm" if n.endswith("_mm") else "s" if n.endswith("_s") else "deg/m" if n.endswith("_deg_per_m") else "m"
    return {n: unit(n) for n in names}


def _mean_over_passes(tables: list[dict[str, np.ndarray]], step_m: float) -> dict[str, np.ndarray]:
    """Mean of the pass tables on the union of their chainage grids (NaN where none covers)."""
    idx = [np.round(t["chainage_m"] / step_m).astype(int) for t in tables]
    k0 = min(i.min() for i in idx)
    k1 = max(i.max() for i in idx)
    out: dict[str, np.ndarray] = {}
    for name in tables[0]:
        if name == "chainage_m":
            continue
        acc = np.zeros(k1 - k0 + 1)
        cnt = np.zeros(k1 - k0 + 1)
        for t, i in zip(tables, idx):
            v = t[name]
            ok = np.isfinite(v)
            np.add.at(acc, i[ok] - k0, v[ok])
            np.add.at(cnt, i[ok] - k0, 1)
        with np.errstate(invalid="ignore"):
            out[name] = acc / cnt
    out = {"chainage_m": step_m * np.arange(k0, k1 + 1), **out}
    covered = np.isfinite(out["left_e_m"])
    return {k: v[covered] for k, v in out.items()}


#: why a column is not measured without a gauge sensor
NO_GAUGE = ("no gauge sensor: the other rail's lateral position is the reference rail's plus the nominal gauge, "
            "so its lateral irregularities and versines and the gauge would be copies, not measurements")


def not_measured_without_gauge(table: dict[str, np.ndarray], other_rail: str) -> dict[str, str]:
    """The columns of a geometry table a survey without a gauge sensor does not measure, with why:
    the gauge and its variation, and every lateral quantity of the rail opposite the reference
    rail (``other_rail``). Its vertical quantities are measured (the trolley's cross-level)."""
    return {c: NO_GAUGE for c in table
            if c in ("gauge_m", "gauge_variation_mm") or c.startswith(f"{other_rail}_lateral")}


def limit_exceedances(table: dict[str, np.ndarray], check: ToleranceCheck, step_m: float) -> list[dict]:
    """Exceedances of a ``kind: limit`` check on the columns it applies to that were measured."""
    out = []
    for col in check.columns():
        if col in table and np.isfinite(table[col]).any():
            out += _stretches(table["chainage_m"], table[col], check, col, step_m)
    return out


def _unmeasured(table: dict[str, np.ndarray], check: ToleranceCheck) -> list[str]:
    """Columns of a ``kind: limit`` check the table lacks or holds no finite value of."""
    return [c for c in check.columns() if c not in table or not np.isfinite(table[c]).any()]


def _stretches(s: np.ndarray, value_mm: np.ndarray, check: ToleranceCheck, column: str, step_m: float,
               merge_m: float = 1.0) -> list[dict]:
    """One exceedance per stretch of ``|value|`` beyond the check's mildest level (stretches closer
    than ``merge_m`` are one): ``check`` (``<check name>:<column>``), ``column``, ``from_m`` /
    ``to_m`` (first and last sample beyond it), ``length_m`` (their distance plus one sample
    step), the peak's ``chainage_m`` and signed ``value_mm``, and the ``level`` its peak reaches
    with that level's ``limit_mm``."""
    levels = check.levels()
    limits = np.array([lim for _, lim in levels])
    out = []
    for d in detect_defects(s, value_mm, levels[0][1], merge_m):
        k = int(np.searchsorted(limits, abs(d.peak_di_deg_per_m), side="left")) - 1
        out.append({"check": f"{check.name}:{column}", "column": column, "from_m": d.start_m, "to_m": d.end_m,
                    "length_m": float(d.end_m - d.start_m + step_m), "chainage_m": d.chainage_m,
                    "value_mm": d.peak_di_deg_per_m, "level": levels[k][0], "limit_mm": float(limits[k])})
    return out


def _indicator_exceedances(tr: RailTraces, design_track, design_s, check: ToleranceCheck) -> list[dict]:
    out = []
    for side in RAILS:
        ref = design_track.rail_points_n(design_s, side)
        for comp in ("vertical", "lateral"):
            ind = chord_indicator(tr.chainage_m, tr.rail(side), ref, check.chord_m, check.spacing_m, comp)
            dv = 1e3 * ind.delta_v_m.ravel()
            sc = ind.pair_chainage_m.ravel()
            out += _stretches(sc, dv, check, f"{side}_{comp}", check.spacing_m, check.spacing_m)
    return out


def compute_geometry(traj: TrajectoryOnTrack, trolley: TrolleyGeometry, cfg: GeometryConfig, step_m: float,
                     gauge: GaugeData | None = None, pitch_rate_radps: np.ndarray | None = None,
                     design: DesignAlignment | None = None,
                     tolerances: tuple[str, list[ToleranceCheck]] | None = None) -> GeometryResult:
    """Track geometry of a survey (module docstring).

    traj: the dense trajectory, t_s (N,) [s], R_nb (N, 3, 3), pos_n (N, 3) [m], and chainage_m
    (N,) [m] of the trolley origin; gauge: the gauge readings (K,) or None (nominal gauge);
    pitch_rate_radps (N,) for the DI (or None: no DI); design: reference the irregularities and
    seed-002 checks to it. Chainage (``cfg.chainage``): ``projection`` onto the design
    (positions in the design's ``n``), ``odometer`` (``start_chainage_m`` + chainage_m),
    ``curvature_matching`` (seed 001, :func:`.chainage.curvature_matched_chainage`), or
    ``auto``: projection with a design and ``traj.absolute_positions``, else the odometer.
    """
    method = _chainage_method(cfg, design, traj.absolute_positions)
    traj, anchors = _survey_chainage(traj, trolley, cfg, design, method)
    checks = tolerances[1] if tolerances else []
    chords, bases = _chords_and_twist_bases(cfg, checks)
    traces = rail_traces(traj, trolley, step_m, gauge, cfg.gauge_smoothing(step_m), cfg.min_speed_mps,
                         min_length_m=max(1.0, 4 * step_m), crossover_m=cfg.attitude_crossover_m)
    design_track = irr.design_track(design, cfg.nominal_gauge_m) if design is not None else None
    passes = _Passes([], [], [])
    for tr in traces:
        tr, ds = _on_design_chainage(tr, design, method, step_m)
        passes.tables.append(_pass_table(tr, cfg, chords, bases, step_m, design_track, ds))
        passes.traces.append(tr)
        passes.design_s.append(ds)
    table = _mean_over_passes(passes.tables, step_m)
    has_gauge = gauge is not None and gauge.t_s.size >= 2
    not_measured = {} if has_gauge else not_measured_without_gauge(table, trolley.other_rail)
    for t in passes.tables + [table]:  # NaN, never the copy of the reference rail or the nominal gauge
        t.update({c: np.full(t[c].shape, np.nan) for c in not_measured})
    exceedances, skipped = _tolerance_results(checks, table, passes, design_track,
                                              trolley.other_rail if not_measured else None, step_m)
    di_series, di_metrics = [], None
    if pitch_rate_radps is not None and cfg.deformation_index.enabled:
        di_series, table["di_deg_per_m"], di_metrics = _deformation_index(pitch_rate_radps, traj, passes,
                                                                          cfg.deformation_index, step_m)
    metrics: dict[str, Any] = {
        "step_m": float(step_m),
        "length_m": float(table["chainage_m"][-1] - table["chainage_m"][0]),
        "passes": len(passes.traces),
        "chainage": {"projection": "design (projection)", "odometer": "odometer",
                     "curvature_matching": "odometer corrected by curvature matching (seed 001)"}[method],
        "irregularity_reference": "design" if design is not None else f"EN 13848 band {cfg.irregularity_band}",
        "gauge": "gauge sensor" if has_gauge else
                 f"nominal {cfg.nominal_gauge_m} m (no gauge sensor: the other rail's alignment includes the gauge irregularity)",
        "gauge_filter_per_pass": [tr.gauge_filter for tr in passes.traces],
        "not_measured": not_measured,
        "tolerance_table": tolerances[0] if tolerances else None,
        "tolerance_checks": [_check_description(c) for c in checks],
        "exceedances": exceedances,
        "skipped_checks": skipped,
    }
    metrics["quality_index"] = _quality_index(table, cfg, design is not None, step_m)
    if method == "curvature_matching":
        metrics["curvature_matching_anchors"] = [[{"s_app_m": a, "chainage_m": d} for a, d in p] for p in anchors]
    if di_metrics is not None:
        metrics["deformation_index"] = di_metrics
    metrics["dominant_wavelengths_m"] = {
        col: spatial_spectrum(table[col], step_m).dominant_m
        for col in ("left_vertical_mm", "right_vertical_mm", "di_deg_per_m") if col in table and table[col].size >= 64}
    if len(passes.tables) >= 2:
        metrics["repeatability"] = _repeatability(passes.tables, cfg, step_m)
    table.pop("t_s", None)
    units = _units(table)
    return GeometryResult(table, units, metrics, passes.tables, passes.traces, di_series)


@dataclass(frozen=True)
class _Passes:
    """The passes a geometry is computed from: their rail ``traces`` (on the chainage used), their
    ``tables`` (:func:`_pass_table`) and their design chainage ``design_s`` (N,) [m] (None
    without a design)."""

    traces: list[RailTraces]
    tables: list[dict[str, np.ndarray]]
    design_s: list[np.ndarray | None]


def _survey_chainage(traj: TrajectoryOnTrack, trolley: TrolleyGeometry, cfg: GeometryConfig,
                     design: DesignAlignment | None, method: str) -> tuple[TrajectoryOnTrack, list]:
    """The trajectory on the chainage of ``method`` (curvature matching, else the odometer's
    plus ``start_chainage_m``; projection onto the design is done per pass later), and the
    curvature matching's anchors (none for the other methods)."""
    if method == "curvature_matching":
        chainage_m, anchors = curvature_matched_chainage(traj.t_s, traj.R_nb @ trolley.R_vb.T, traj.chainage_m,
                                                         design, cfg.start_chainage_m)
        return replace(traj, chainage_m=chainage_m), anchors
    return replace(traj, chainage_m=cfg.start_chainage_m + np.asarray(traj.chainage_m, dtype=float)), []


def _chords_and_twist_bases(cfg: GeometryConfig, checks: list[ToleranceCheck]
                            ) -> tuple[list[tuple[float, float]], list[float]]:
    """The versine chords (before, after) [m] and twist bases [m] to compute: the configured ones
    and those the tolerance checks need, sorted."""
    chords = sorted({(0.5 * c, 0.5 * c) for c in cfg.chords_m}
                    | {(0.5 * r, 0.5 * r) for r in cfg.repeatability_chords_m}
                    | {(c.before_m, c.after_m) for c in cfg.asymmetric_chords}
                    | {(0.5 * c.length_m, 0.5 * c.length_m) for c in checks
                       if c.kind == "limit" and c.quantity.endswith("versine")})
    bases = sorted(set(cfg.twist_bases_m) | {c.length_m for c in checks if c.kind == "limit" and c.quantity == "twist"})
    return chords, bases


def _on_design_chainage(tr: RailTraces, design: DesignAlignment | None, method: str,
                        step_m: float) -> tuple[RailTraces, np.ndarray | None]:
    """A pass's traces regridded on the design chainage (``method == "projection"``), and their
    design chainage (N,) [m] (None without a design), checked to lie on the design."""
    if method == "projection":
        tr = regrid(tr, project_onto_design(0.5 * (tr.left_n + tr.right_n), design), step_m)
    if design is None:
        return tr, None
    ds = tr.chainage_m
    if ds.min() < 0 or ds.max() > design.length_m:
        raise TrackGeometryError(f"chainage {ds.min():.1f}..{ds.max():.1f} m leaves the design alignment "
                                 f"[0, {design.length_m:g}] m (set geometry.start_chainage_m)")
    return tr, ds


def _tolerance_results(checks: list[ToleranceCheck], table: dict[str, np.ndarray], passes: _Passes, design_track,
                       unmeasured_rail: str | None, step_m: float) -> tuple[list[dict], list[dict]]:
    """The exceedances of the tolerance checks and the checks skipped (with why): ``limit``
    checks on the mean ``table``, chord indicators per pass against ``design_track`` (None: no
    design). ``unmeasured_rail``: the rail whose lateral position was not measured (no gauge
    sensor), or None."""
    exceedances: list[dict] = []
    skipped: list[dict] = []
    for c in checks:
        if c.kind == "limit":
            missing = _unmeasured(table, c)
            if missing:
                skipped.append({"check": c.name, "columns": missing,
                                "reason": f"not measured ({', '.join(missing)})"})
            exceedances += limit_exceedances(table, c, step_m)
        elif design_track is None:
            skipped.append({"check": c.name, "reason": "needs a design alignment (inputs.design)"})
        elif not any(np.ptp(tr.chainage_m) >= c.chord_m for tr in passes.traces):
            skipped.append({"check": c.name, "reason": f"no pass is as long as the {c.chord_m:g} m chord"})
        else:
            exceedances += [dict(e, pass_index=k) for k, (tr, ds) in enumerate(zip(passes.traces, passes.design_s))
                            if np.ptp(tr.chainage_m) >= c.chord_m
                            for e in _indicator_exceedances(tr, design_track, ds, c)
                            if not (unmeasured_rail and e["check"] == f"{c.name}:{unmeasured_rail}_lateral")]
            if unmeasured_rail:
                skipped.append({"check": c.name, "columns": [f"{unmeasured_rail}_lateral"],
                                "reason": f"not measured ({unmeasured_rail}_lateral: {NO_GAUGE})"})
    return exceedances, skipped


def _check_description(c: ToleranceCheck) -> dict:
    """A tolerance check in metrics.json: its name, kind, the columns it applies to, its levels [mm]."""
    return {"name": c.name, "kind": c.kind,
            "columns": c.columns() if c.kind == "limit" else [f"{r}_{comp}" for r in RAILS
                                                               for comp in ("vertical", "lateral")],
            "levels_mm": dict(c.levels())}


def _deformation_index(pitch_rate_radps: np.ndarray, traj: TrajectoryOnTrack, passes: _Passes,
                       dcfg: DeformationIndexConfig, step_m: float
                       ) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, dict]:
    """Seed 000's deformation index from the pitch rate (N,) [rad/s]: per pass its chainage (M,)
    [m] and DI (M,) [deg/m], the mean over passes on the geometry table's grid (the table's
    ``di_deg_per_m``), and the metrics.json ``deformation_index`` section (defects)."""
    t_s = traj.t_s
    speed = np.gradient(traj.chainage_m, t_s)
    di = deformation_index(pitch_rate_radps, speed, dcfg.v_min_mps)
    di_series, di_defects = [], []
    for tr in passes.traces:
        m = (t_s >= tr.t_s.min()) & (t_s <= tr.t_s.max())
        s_di = np.interp(t_s[m], tr.t_s[np.argsort(tr.t_s)], tr.chainage_m[np.argsort(tr.t_s)])
        di_series.append((s_di, di[m]))
        di_defects.append(detect_defects(s_di, di[m], dcfg.threshold_deg_per_m, dcfg.merge_m))
    column = _mean_over_passes(
        [{"chainage_m": t["chainage_m"], "left_e_m": t["left_e_m"],
          "di_deg_per_m": np.interp(t["chainage_m"], *_sorted(*ser))} for t, ser in zip(passes.tables, di_series)],
        step_m)["di_deg_per_m"]
    metrics = {"threshold_deg_per_m": dcfg.threshold_deg_per_m, "v_min_mps": dcfg.v_min_mps,
               "defects": merge_defects(di_defects, dcfg.merge_m),
               "defects_per_pass": [[d.to_json() for d in ds] for ds in di_defects]}
    return di_series, column, metrics


def _quality_index(table: dict[str, np.ndarray], cfg: GeometryConfig, with_design: bool, step_m: float) -> dict:
    """EN 13848-6 style quality index (:func:`.quality.quality_index`) of the D1 longitudinal level
    and alignment of both rails: the D1 columns (``<rail>_<vertical|lateral>_D1_mm``), or the main
    irregularity columns when they are the D1 band; none when no D1 column was computed."""
    columns = {}
    for side in RAILS:
        for comp, qty in (("vertical", "longitudinal level"), ("lateral", "alignment")):
            d1 = f"{side}_{comp}_D1_mm"
            main = f"{side}_{comp}_mm"
            col = d1 if d1 in table else main if not with_design and cfg.irregularity_band == "D1" else None
            if col is not None:
                columns[f"{side} {qty}"] = col
    if not columns:
        return {"section_m": SECTION_M, "columns": {}, "sections": [],
                "not_computed": "no D1 irregularity column (add D1 to geometry.extra_bands)"}
    return quality_index(table, step_m, columns)


def _chainage_method(cfg: GeometryConfig, design: DesignAlignment | None, absolute_positions: bool) -> str:
    if cfg.chainage == "auto":
        return "projection" if design is not None and absolute_positions else "odometer"
    if cfg.chainage in ("projection", "curvature_matching") and design is None:
        raise ConfigError(f"geometry.chainage: {cfg.chainage} needs a design alignment (inputs.design)")
    return cfg.chainage


def _sorted(s: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    o = np.argsort(s, kind="stable")
    return s[o], v[o]


def _repeatability(tables: list[dict[str, np.ndarray]], cfg: GeometryConfig, step_m: float) -> dict:
    """Seed 000 tables 2-3 per repeatability chord, rail and direction (vertical, lateral)."""
    out: dict[str, Any] = {}
    idx = [np.round(t["chainage_m"] / step_m).astype(int) for t in tables]
    k0, k1 = max(i.min() for i in idx), min(i.max() for i in idx)
    if k1 <= k0:
        return {"error": "the passes share no chainage"}
    for chord, limit in zip(cfg.repeatability_chords_m, cfg.repeatability_limits_mm):
        for side in RAILS:
            for comp in ("vertical", "lateral"):
                col = f"{side}_{comp}_versine_{fmt_length(chord)}m_mm"
                rows = np.vstack([t[col][(i >= k0) & (i <= k1)] for t, i in zip(tables, idx)])
                if not np.isfinite(rows).any():  # a column the sensors do not measure (not_measured_without_gauge)
                    out[col] = {"not_measured": True}
                    continue
                try:
                    r = repeatability(rows / 1e3, limit, step_m * np.arange(k0, k1 + 1))
                except EvaluationError as exc:  # reported, not raised: passes may share no point
                    out[col] = {"error": str(exc)}
                    continue
                out[col] = r.to_json()
    return out
