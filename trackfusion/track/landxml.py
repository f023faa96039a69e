"""LandXML 1.2 design alignments -> :class:`~.design.AlignmentConfig` (the model a YAML design gives).

Read (docs/geometry.md, "LandXML designs"): the one ``Alignment`` of the file, its ``CoordGeom``
(``Line``, ``Curve``: circular arc, ``Spiral``: clothoid), its one ``ProfAlign`` (``PVI``,
``ParaCurve``: symmetric parabola of ``length``) and its ``Cant`` (``CantStation``). Anything
else that changes the geometry (other spiral types, ``IrregularLine``, ``Chain``, unsymmetric or
circular vertical curves, station equations, a rotation point other than the inside rail, a
projected coordinate system) is refused with a :class:`ConfigError` naming the file, the line
and the element.

Conventions of LandXML taken care of here:

- point text is ``northing easting [elevation]``; the model is in ``n`` (east, north): the
  file's grid is taken to *be* the survey's local frame ``n`` (metres east and north of the
  pipeline's origin, elevations as ``u``); a declared EPSG / WKT coordinate system, or an
  alignment more than 100 km from ``n``'s origin, is refused;
- ``rot="ccw"`` curves left (positive curvature in ``n``), ``"cw"`` right; a radius ``INF``
  is a straight end;
- stations: design chainage ``s = station - staStart`` (the model's chainage starts at 0);
- ``Units``: ``Metric`` or ``Imperial`` ``linearUnit`` scales coordinates, lengths, radii,
  stations and elevations; cant values are millimetres (metric) or inches (imperial), as
  the schema says; ``Cant@gauge`` is in the linear unit.

The model is rebuilt from the elements' lengths and radii (the points over-determine it). Each
element's End, Center and PI must lie within :data:`POINT_TOLERANCE_M` of where its own Start,
start tangent, length and radii put them, each Start on the previous End (no gap) and each
start tangent on the previous end tangent (no kink): the first element at fault is named. The
model's start point and heading are then the rigid 2-D fit of its element points to the file's,
and every file point must lie within the same tolerance of the fitted model (small errors that
add up). A wrong ``rot``, radius or length is refused, not smoothed over.

Parsed with the standard library's expat (namespace-aware, any LandXML namespace) rather than
``xml.etree`` alone, because ElementTree's C parser does not report element line numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from xml.etree.ElementTree import Element, TreeBuilder
from xml.parsers import expat

import numpy as np
from pydantic import ValidationError

from ..errors import ConfigError, config_error_from_validation
from .design import AlignmentConfig, DesignAlignment

POINT_TOLERANCE_M = 0.005
"""Largest distance [m] allowed between a point of the file and the model rebuilt from the
elements' lengths and radii (coordinates printed to 1 mm over a few km stay inside it)."""

MAX_DISTANCE_FROM_ORIGIN_M = 100_000.0
"""A design further than this from ``n``'s origin is in a projected grid, not in ``n``."""

RAIL_HEAD_M = 0.065
"""Cant base = ``Cant@gauge`` + this (1.5 m for the 1.435 m standard gauge)."""

_MAX_COORD_M, _MAX_LENGTH_M, _MIN_RADIUS_M, _MAX_ELEVATION_M, _MAX_GRADE, _MAX_CANT_M = 1e7, 1e6, 1.0, 1e5, 1.0, 0.5
"""Bounds beyond which a value is a malformed file, not a track (and would overflow the model)."""

_LINEAR_M = {"millimeter": 1e-3, "centimeter": 1e-2, "meter": 1.0, "kilometer": 1e3,
             "foot": 0.3048, "USSurveyFoot": 1200.0 / 3937.0, "inch": 0.0254, "mile": 1609.344}
_CANT_M = {"Metric": 1e-3, "Imperial": 0.0254}  # CantStation values: mm or inches
_REFUSED_GEOM = {"IrregularLine": "an irregular line", "Chain": "a chain of points",
                 "CurveSpiral": "a curve-spiral"}


@dataclass
class _Doc:
    """A parsed file: root element, line of each element, file name for messages."""

    root: Element
    lines: dict[int, int]
    path: Path

    def where(self, el: Element) -> str:
        return f"{self.path}:{self.lines.get(id(el), '?')}: {_local(el.tag)}"

    def error(self, el: Element, msg: str) -> ConfigError:
        name = el.get("name")
        return ConfigError(f"{self.where(el)}{f' {name!r}' if name else ''}: {msg}")


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _parse(data: bytes, path: Path) -> _Doc:
    """Elements of the file's bytes with their line numbers (namespaces reduced to ``{uri}local``
    tags); ``path`` names the file in messages."""
    builder, lines = TreeBuilder(), {}
    parser = expat.ParserCreate(namespace_separator="}")

    def start(tag, attrs):
        el = builder.start("{" + tag if "}" in tag else tag, {_local(k): v for k, v in attrs.items()})
        lines[id(el)] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: builder.end("{" + tag if "}" in tag else tag)
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise ConfigError(f"{path}:{exc.lineno}: not well-formed XML ({expat.ErrorString(exc.code)})") from None
    except LookupError as exc:  # the XML declaration names an encoding Python does not know
        raise ConfigError(f"{path}:1: not readable XML ({exc})") from None
    root = builder.close()
    if _local(root.tag) != "LandXML":
        raise ConfigError(f"{path}:1: not a LandXML file (root element {_local(root.tag)!r})")
    return _Doc(root, lines, path)


def _children(el: Element, name: str) -> list[Element]:
    return [c for c in el if _local(c.tag) == name]


def _descendants(el: Element, name: str) -> list[Element]:
    return [c for c in el.iter() if _local(c.tag) == name]


def _one(doc: _Doc, parent: Element, name: str, required: bool = True) -> Element | None:
    found = _children(parent, name)
    if len(found) > 1:
        raise doc.error(found[1], f"more than one {name} in {_local(parent.tag)} (trackfusion reads one)")
    if not found and required:
        raise doc.error(parent, f"no {name} element")
    return found[0] if found else None


def _number(doc: _Doc, el: Element, attr: str, default: float | None = None, inf: bool = False) -> float:
    text = el.get(attr)
    if text is None:
        if default is None:
            raise doc.error(el, f"missing attribute {attr}")
        return default
    try:
        value = float(text.strip())
    except ValueError:
        raise doc.error(el, f"{attr}={text!r} is not a number") from None
    if math.isnan(value) or (math.isinf(value) and not inf):
        raise doc.error(el, f"{attr}={text!r} must be finite")
    return value


def _choice(doc: _Doc, el: Element, attr: str, allowed: tuple[str, ...], default: str | None = None) -> str:
    value = el.get(attr, default)
    if value not in allowed:
        raise doc.error(el, f"{attr}={value!r} must be one of {', '.join(allowed)}"
                        if value is not None else f"missing attribute {attr}")
    return value


# --- units and frame -----------------------------------------------------------------------------

def _units(doc: _Doc) -> tuple[float, float]:
    """(metres per linear unit, metres per cant unit) from the ``Units`` element."""
    units = _one(doc, doc.root, "Units")
    system = [c for c in units if _local(c.tag) in ("Metric", "Imperial")]
    if len(system) != 1:
        raise doc.error(units, "needs exactly one Metric or Imperial element")
    kind = _local(system[0].tag)
    allowed = ("millimeter", "centimeter", "meter", "kilometer") if kind == "Metric" else \
        ("foot", "USSurveyFoot", "inch", "mile")
    return _LINEAR_M[_choice(doc, system[0], "linearUnit", allowed)], _CANT_M[kind]


def _check_frame(doc: _Doc) -> None:
    """Refuse a design declared in a geodetic or projected coordinate reference system."""
    for cs in _descendants(doc.root, "CoordinateSystem"):
        crs = next((f"{a}={cs.get(a)!r}" for a in ("epsgCode", "ogcWktCode") if cs.get(a)), None)
        if crs:
            raise doc.error(cs, f"the design is in a projected coordinate system ({crs}); trackfusion takes "
                            "the design's coordinates in the survey's local frame n (metres east/north of "
                            "the pipeline's origin): transform them first")


# --- horizontal ----------------------------------------------------------------------------------

def _point(doc: _Doc, parent: Element, name: str, scale: float, points: dict[str, str],
           required: bool = True) -> np.ndarray | None:
    """(east, north) [m] of a point child (text ``N E [Z]`` or ``pntRef`` to a ``CgPoint``)."""
    el = _one(doc, parent, name, required)
    if el is None:
        return None
    text = (el.text or "").strip()
    if not text and el.get("pntRef"):
        if el.get("pntRef") not in points:
            raise doc.error(el, f"pntRef={el.get('pntRef')!r} names no CgPoint")
        text = points[el.get("pntRef")]
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        raise doc.error(el, f"point {text!r} is not 'northing easting [elevation]'") from None
    if len(values) not in (2, 3) or not all(map(math.isfinite, values)):
        raise doc.error(el, f"point {text!r} is not 'northing easting [elevation]'")
    if max(abs(v) for v in values) * scale > _MAX_COORD_M:
        raise doc.error(el, f"point {text!r} lies beyond {_MAX_COORD_M / 1000:g} km")
    return scale * np.array([values[1], values[0]])


def _check_length(doc: _Doc, el: Element, length_m: float) -> float:
    if not 0 < length_m <= _MAX_LENGTH_M:
        raise doc.error(el, f"length {length_m:g} m must be positive and at most {_MAX_LENGTH_M:g} m")
    return length_m


def _check_radius(doc: _Doc, el: Element, radius_m: float) -> float:
    if not radius_m >= _MIN_RADIUS_M:
        raise doc.error(el, f"radius {radius_m:g} m must be at least {_MIN_RADIUS_M:g} m (INF: straight; the side "
                        "is rot)")
    return radius_m


@dataclass
class _Element:
    """One CoordGeom element read: the model element dict, its XML element, its points (east,
    north) [m] and the start heading its points give [rad, from east towards north]."""

    model: dict
    el: Element
    points: dict[str, np.ndarray]
    start_heading_rad: float


def _signed(rot: str) -> float:
    return 1.0 if rot == "ccw" else -1.0


def _line(doc: _Doc, el: Element, f: float, pts: dict) -> _Element:
    p = {"Start": _point(doc, el, "Start", f, pts), "End": _point(doc, el, "End", f, pts)}
    chord = p["End"] - p["Start"]
    length = _check_length(doc, el, f * _number(doc, el, "length", float(np.hypot(*chord)) / f))
    return _Element({"type": "tangent", "length_m": length}, el, p, math.atan2(chord[1], chord[0]))


def _curve(doc: _Doc, el: Element, f: float, pts: dict) -> _Element:
    p = {k: _point(doc, el, k, f, pts) for k in ("Start", "Center", "End")}
    pi = _point(doc, el, "PI", f, pts, required=False)
    if pi is not None:
        p["PI"] = pi
    sign = _signed(_choice(doc, el, "rot", ("cw", "ccw")))
    r_points = float(np.hypot(*(p["Start"] - p["Center"])))
    radius = _check_radius(doc, el, f * _number(doc, el, "radius", r_points / f))
    a0, a1 = (math.atan2(*(p[k] - p["Center"])[::-1]) for k in ("Start", "End"))
    swept = ((a1 - a0) * sign) % (2 * math.pi)  # angle turned in the rot sense
    length = _check_length(doc, el, f * _number(doc, el, "length", radius * swept / f))
    r_vec = p["Start"] - p["Center"]
    return _Element({"type": "arc", "length_m": length, "radius_m": sign * radius}, el, p,
                    math.atan2(r_vec[1], r_vec[0]) + sign * math.pi / 2)


def _spiral(doc: _Doc, el: Element, f: float, pts: dict) -> _Element:
    spi = el.get("spiType")
    if spi != "clothoid":
        raise doc.error(el, f"spiType={spi!r} is not supported (clothoid only)")
    p = {k: _point(doc, el, k, f, pts) for k in ("Start", "End")}
    pi = _point(doc, el, "PI", f, pts, required=False)  # required by the schema, left out by some writers
    if pi is not None:
        p["PI"] = pi
    sign = _signed(_choice(doc, el, "rot", ("cw", "ccw")))
    length = _check_length(doc, el, f * _number(doc, el, "length"))
    r0, r1 = (math.inf if el.get(a, "").strip() in ("INF", "-INF") else _check_radius(doc, el, f * _number(doc, el, a))
              for a in ("radiusStart", "radiusEnd"))
    if r0 == r1:
        raise doc.error(el, "radiusStart equals radiusEnd: not a spiral")
    if el.get("constant") is not None:  # clothoid parameter A, A^2 = L / |k1 - k0|
        a_file = f * _number(doc, el, "constant")
        a_model = math.sqrt(length / abs(1 / r1 - 1 / r0))
        if abs(a_file - a_model) > 1e-4 * a_model:
            raise doc.error(el, f"constant {a_file:.4f} m disagrees with length and radii (A = {a_model:.4f} m)")
    tangent = p["PI"] - p["Start"] if pi is not None else None  # no PI: the previous element's end tangent
    return _Element({"type": "clothoid", "length_m": length, "start_radius_m": sign * r0, "end_radius_m": sign * r1},
                    el, p, math.nan if tangent is None else math.atan2(tangent[1], tangent[0]))


_READERS = {"Line": _line, "Curve": _curve, "Spiral": _spiral}


def _coord_geom(doc: _Doc, alignment: Element, f: float) -> list[_Element]:
    cg = _one(doc, alignment, "CoordGeom")
    points = {p.get("name"): (p.text or "") for p in _descendants(doc.root, "CgPoint") if p.get("name")}
    out = []
    for child in cg:
        name = _local(child.tag)
        if name in _READERS:
            out.append(_READERS[name](doc, child, f, points))
        elif name != "Feature":
            raise doc.error(child, f"{_REFUSED_GEOM.get(name, 'this element')} is not supported in CoordGeom "
                            "(Line, Curve, Spiral)")
    if not out:
        raise doc.error(cg, "holds no Line, Curve or Spiral")
    return out


def _tangent_intersection(p0: np.ndarray, h0: np.ndarray, p1: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """Where the tangents at p0 (heading h0) and p1 (heading h1) meet, (M, 2); NaN if parallel."""
    d0 = np.column_stack([np.cos(h0), np.sin(h0)])
    d1 = np.column_stack([np.cos(h1), np.sin(h1)])
    cross = d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0]
    dp = p1 - p0
    t = (dp[:, 0] * d1[:, 1] - dp[:, 1] * d1[:, 0]) / np.where(np.abs(cross) > 1e-9, cross, np.nan)
    return p0 + t[:, None] * d0


def _model_points(elements: list[_Element]) -> dict[str, np.ndarray]:
    """Start, End, Center and PI (M, 2) of every element and its start and end heading (M,) [rad]
    of the model started at (0, 0) heading east."""
    cfg = AlignmentConfig.model_validate({"horizontal": {"elements": [e.model for e in elements]}})
    design = DesignAlignment(cfg)
    s0 = design.s_start
    s1 = s0 + np.array([e.model["length_m"] for e in elements])
    a, b = design.evaluate(s0), design.evaluate(np.minimum(s1, design.length_m))
    radius = np.array([e.model.get("radius_m", 0.0) for e in elements])  # signed, positive left
    normal = np.column_stack([-np.sin(a.heading_rad), np.cos(a.heading_rad)])
    return {"Start": a.pos_n[:, :2], "End": b.pos_n[:, :2], "Center": a.pos_n[:, :2] + radius[:, None] * normal,
            "PI": _tangent_intersection(a.pos_n[:, :2], a.heading_rad, b.pos_n[:, :2], b.heading_rad),
            "start_heading": a.heading_rad, "end_heading": b.heading_rad}


def _rotate(xy: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Points (M, 2) each rotated by its angle (M,) [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]])


def _check_elements(doc: _Doc, elements: list[_Element], model: dict[str, np.ndarray]) -> None:
    """Each element on its own (its End, Center, PI where its Start, start tangent, length and
    radii put them), then each joint (no gap, no kink): the first element at fault is named."""
    start = np.array([e.points["Start"] for e in elements])
    heading = np.array([e.start_heading_rad for e in elements])
    turned = model["end_heading"] - model["start_heading"]
    if np.isnan(heading[0]):
        raise doc.error(elements[0].el, "the first element needs a PI (its start tangent)")
    for i in np.flatnonzero(np.isnan(heading)):  # a spiral without PI starts on the previous end tangent
        heading[i] = heading[i - 1] + turned[i - 1]
    for k in ("End", "Center", "PI"):
        has = np.array([k in e.points and bool(np.all(np.isfinite(model[k][i]))) for i, e in enumerate(elements)])
        if not has.any():
            continue
        local = _rotate(model[k][has] - model["Start"][has], -model["start_heading"][has])
        misfit = np.hypot(*(np.array([e.points[k] for e, h in zip(elements, has) if h])
                            - start[has] - _rotate(local, heading[has])).T)
        bad = np.flatnonzero(misfit > POINT_TOLERANCE_M)
        if bad.size:
            i, j = int(np.flatnonzero(has)[bad[0]]), bad[0]
            raise doc.error(elements[i].el, f"its {k} point is {misfit[j]:.4f} m from where its Start, start tangent, "
                            f"length and radii put it (tolerance {POINT_TOLERANCE_M} m): a wrong rot, radius or "
                            "length, or points not written 'northing easting'?")
    end = np.array([e.points["End"] for e in elements])
    gap = np.hypot(*(start[1:] - end[:-1]).T)
    kink = np.angle(np.exp(1j * (heading[1:] - heading[:-1] - turned[:-1])))
    lengths = np.array([e.model["length_m"] for e in elements])
    offset = np.abs(kink) * np.minimum(lengths[1:], lengths[:-1])  # sideways error the kink makes
    for i in range(1, len(elements)):
        if gap[i - 1] > POINT_TOLERANCE_M:
            raise doc.error(elements[i].el, f"its Start is {gap[i - 1]:.4f} m from the previous element's End (a gap)")
        if offset[i - 1] > POINT_TOLERANCE_M:
            raise doc.error(elements[i].el, f"its start tangent turns {1e3 * kink[i - 1]:.3f} mrad from the previous "
                            "element's end tangent (a kink)")


def _rigid_fit(model_xy: np.ndarray, file_xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Translation (2,) and rotation [rad] taking model points (M, 2) onto file points (M, 2),
    least squares (2-D Kabsch)."""
    pm, pf = model_xy.mean(axis=0), file_xy.mean(axis=0)
    a, b = model_xy - pm, file_xy - pf
    angle = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])), float(np.sum(a * b)))
    c, s = math.cos(angle), math.sin(angle)
    return pf - np.array([[c, -s], [s, c]]) @ pm, angle


def _horizontal(doc: _Doc, elements: list[_Element]) -> dict:
    """The ``horizontal`` section: elements, and the start pose fitted to the file's points."""
    model = _model_points(elements)
    _check_elements(doc, elements, model)
    pairs = [(i, k) for i, e in enumerate(elements) for k in e.points if np.all(np.isfinite(model[k][i]))]
    mxy = np.array([model[k][i] for i, k in pairs])
    fxy = np.array([elements[i].points[k] for i, k in pairs])
    t, angle = _rigid_fit(mxy, fxy)
    c, s = math.cos(angle), math.sin(angle)
    misfit = np.hypot(*(fxy - (mxy @ np.array([[c, s], [-s, c]]) + t)).T)
    worst = int(np.argmax(misfit))
    if misfit[worst] > POINT_TOLERANCE_M:
        i, k = pairs[worst]
        raise doc.error(elements[i].el, f"its {k} point is {misfit[worst]:.4f} m off the alignment rebuilt from "
                        f"the elements' lengths and radii (tolerance {POINT_TOLERANCE_M} m; the elements' small "
                        "errors add up)")
    if np.hypot(*t) > MAX_DISTANCE_FROM_ORIGIN_M:
        raise doc.error(elements[0].el, f"starts {np.hypot(*t) / 1000:.0f} km from the origin of n: the design looks "
                        "like projected-grid coordinates; trackfusion takes them in the survey's local frame n "
                        "(metres east/north of the pipeline's origin)")
    return {"start_e_m": float(t[0]), "start_n_m": float(t[1]), "heading_deg": math.degrees(angle),
            "elements": [e.model for e in elements]}


def _check_stations(doc: _Doc, alignment: Element, elements: list[_Element], f: float, sta0: float) -> None:
    """Element ``staStart`` and the alignment's ``length``, where given, agree with the lengths."""
    s = 0.0
    for e in elements:
        if e.el.get("staStart") is not None:
            given = f * (_number(doc, e.el, "staStart") - sta0)
            if abs(given - s) > POINT_TOLERANCE_M:
                raise doc.error(e.el, f"staStart is {given:.4f} m from the alignment start, the lengths before it "
                                f"sum to {s:.4f} m")
        s += e.model["length_m"]
    if alignment.get("length") is not None and abs(f * _number(doc, alignment, "length") - s) > POINT_TOLERANCE_M:
        raise doc.error(alignment, f"length {f * _number(doc, alignment, 'length'):.4f} m differs from the sum of "
                        f"its elements' lengths {s:.4f} m")


# --- vertical and cant ---------------------------------------------------------------------------

def _station_value(doc: _Doc, el: Element, f: float, sta0: float) -> tuple[float, float]:
    """(chainage [m], elevation [m]) of a PVI / ParaCurve text ``station elevation``."""
    try:
        sta, z = (float(v) for v in (el.text or "").split())
    except ValueError:
        raise doc.error(el, f"text {(el.text or '').strip()!r} is not 'station elevation'") from None
    if not (math.isfinite(sta) and math.isfinite(z)) or abs(f * z) > _MAX_ELEVATION_M \
            or abs(f * (sta - sta0)) > _MAX_COORD_M:
        raise doc.error(el, f"station {sta:g} or elevation {z:g} is not plausible")
    return f * (sta - sta0), f * z


def _vertical(doc: _Doc, alignment: Element, f: float, sta0: float) -> dict:
    prof = [p for profile in _children(alignment, "Profile") for p in _children(profile, "ProfAlign")]
    if len(prof) != 1:
        where = prof[1] if prof else alignment
        raise doc.error(where, "needs exactly one Profile/ProfAlign (the vertical design), "
                        f"found {len(prof)}")
    pvis, els = [], []
    for child in prof[0]:
        name = _local(child.tag)
        if name in ("UnsymParaCurve", "CircCurve"):
            raise doc.error(child, "is not supported (PVI and ParaCurve: symmetric parabolas only)")
        if name not in ("PVI", "ParaCurve"):
            continue
        s, z = _station_value(doc, child, f, sta0)
        pvi = {"chainage_m": s, "u_m": z}
        if name == "ParaCurve":
            pvi["curve_length_m"] = _check_length(doc, child, f * _number(doc, child, "length"))
        if els and s <= pvis[-1]["chainage_m"]:
            raise doc.error(child, f"station {s / f + sta0:g} does not follow the previous one")
        if els and abs(z - pvis[-1]["u_m"]) > _MAX_GRADE * (s - pvis[-1]["chainage_m"]):
            raise doc.error(child, f"the grade from the previous PVI exceeds {100 * _MAX_GRADE:g} %")
        pvis.append(pvi)
        els.append(child)
    if not pvis:
        raise doc.error(prof[0], "holds no PVI")
    for k in (0, len(pvis) - 1):
        if pvis[k].get("curve_length_m"):
            raise doc.error(els[k], "the first and last vertical points take no vertical curve")
    for k in range(1, len(pvis) - 1):
        room = min(pvis[k]["chainage_m"] - pvis[k - 1]["chainage_m"], pvis[k + 1]["chainage_m"] - pvis[k]["chainage_m"])
        if pvis[k].get("curve_length_m", 0.0) / 2 > room:
            raise doc.error(els[k], f"vertical curve of {pvis[k]['curve_length_m']:.1f} m overlaps a neighbouring PVI")
    return {"pvis": pvis}


def _cant(doc: _Doc, alignment: Element, f: float, f_cant: float, sta0: float, length_m: float) -> dict:
    """``cant_stations`` and ``cant_base_m`` from the ``Cant`` element (empty without one); the
    stations must lie on the alignment (``length_m`` long)."""
    cant = _one(doc, alignment, "Cant", required=False)
    if cant is None:
        return {}
    rotation = cant.get("rotationPoint", "insideRail")
    if rotation != "insideRail":
        raise doc.error(cant, f"rotationPoint={rotation!r} is not supported (insideRail: the low rail stays on "
                        "the gradeline)")
    out: dict = {}
    if cant.get("gauge") is not None:
        gauge = f * _number(doc, cant, "gauge")
        if not 0.5 <= gauge <= 2.0:
            raise doc.error(cant, f"gauge {gauge:g} m is not a track gauge (0.5-2 m)")
        out["cant_base_m"] = gauge + RAIL_HEAD_M
    stations = []
    for st in _children(cant, "CantStation"):
        applied = f_cant * _number(doc, st, "appliedCant")
        if not 0 <= applied <= _MAX_CANT_M:
            raise doc.error(st, f"appliedCant {applied * 1e3:g} mm must lie in 0-{_MAX_CANT_M * 1e3:g} mm (the raised "
                            "rail follows curvature and adverse)")
        curve = _choice(doc, st, "curvature", ("cw", "ccw"), None if applied else "cw")  # no side without cant
        adverse = _choice(doc, st, "adverse", ("true", "false", "1", "0"), "false") in ("true", "1")
        # the outer rail of a right-hand (cw) curve is the left one; adverse cant raises the inner rail
        raised = "left" if (curve == "cw") != adverse else "right"
        s = f * (_number(doc, st, "station") - sta0)
        if stations and s <= stations[-1]["chainage_m"]:
            raise doc.error(st, "station does not follow the previous CantStation")
        if not -POINT_TOLERANCE_M <= s <= length_m + POINT_TOLERANCE_M:
            raise doc.error(st, f"station {s / f + sta0:g} lies off the alignment "
                            f"({sta0:g} to {sta0 + length_m / f:g})")
        stations.append({"chainage_m": s, "cant_mm": 1000.0 * applied, "raised_rail": raised})
    if not stations:
        raise doc.error(cant, "holds no CantStation")
    out["cant_stations"] = stations
    return out


# --- the file ------------------------------------------------------------------------------------

def parse_landxml(data: bytes, path: str | Path) -> AlignmentConfig:
    """The design alignment of a LandXML 1.2 file's bytes (module docstring) as an
    :class:`AlignmentConfig`; ``path`` names the file in messages. Raises :class:`ConfigError`
    (one line: file, line, element) on anything it cannot read. The file is read at the I/O
    boundary (:func:`trackfusion.geometry_inputs.read_landxml`)."""
    doc = _parse(data, Path(path))
    f, f_cant = _units(doc)
    _check_frame(doc)
    alignments = _descendants(doc.root, "Alignment")
    if len(alignments) != 1:
        names = ", ".join(repr(a.get("name")) for a in alignments)
        raise ConfigError(f"{doc.path}: holds {len(alignments)} Alignment elements{f' ({names})' if names else ''}; "
                          "trackfusion reads a file with exactly one")
    al = alignments[0]
    equation = _children(al, "StaEquation")
    if equation:
        raise doc.error(equation[0], "station equations are not supported")
    sta0 = _number(doc, al, "staStart", 0.0)
    elements = _coord_geom(doc, al, f)
    _check_stations(doc, al, elements, f, sta0)
    length_m = sum(e.model["length_m"] for e in elements)
    data = {"horizontal": _horizontal(doc, elements), "vertical": _vertical(doc, al, f, sta0),
            **_cant(doc, al, f, f_cant, sta0, length_m)}
    try:
        return AlignmentConfig.model_validate(data)
    except ValidationError as exc:
        raise config_error_from_validation(exc, f"{doc.path}: Alignment {al.get('name')!r}") from None
