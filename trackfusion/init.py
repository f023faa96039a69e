"""``trackfusion init LOG --out pipeline.yaml``: a runnable, commented pipeline for a log
(docs/init.md).

What the log says goes in as found: every sensor (topic, count, rate, span as comments), the
IMU rate, the origin of ``n`` (the log's survey metadata record's when it has one, as ``run``
takes it; else the first good GNSS fix: RTK fixed, else float, else any),
the lever arms and vehicle geometry of the log's ``lever_arms`` metadata record when it has one
(docs/log_format.md). What only the user knows is written so that the file runs and the comment
says to fill it in: lever arms not in the log are zero (the GNSS antenna's never is: measure
it), the IMU's noise is the named grade's datasheet figures (``--imu-grade``; without it the
log's own ``sensors`` record, else ``navigation``). A trolley's wheelbase and a rail vehicle's
axle distance neither in the log nor given are a round placeholder to fill in, and the wheel
path, which needs the exact wheelbase, stays off.

Factors are switched on for the sensors present and supported by the vehicle's kind
(trackfusion/vehicles.py): the wheel path on a trolley with an odometer and GNSS (as the
simulator's pipelines), track geometry on rail kinds. ``--set KEY=VALUE`` takes the pipeline's
dotted keys, the value parsed as YAML; an unknown key is refused. The result is validated as
``trackfusion run`` would (:func:`~trackfusion.pipeline.parse_pipeline`) before it is written,
atomically; an existing file is kept unless ``force``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from .errors import ConfigError
from .sensors.imu import IMU_GRADES, ImuSpec
from .vehicles import VEHICLE_KINDS

#: NHC sigma [mm/s] written for each kind (lateral and vertical): a rigid trolley's library
#: default (docs/pipeline.md, "Choosing the NHC sigma"); a rail vehicle's wheelsets play and hunt
#: by centimetres at a hertz or two; a car's side slip and suspension: KF-GINS's 0.1 m/s
NHC_SIGMA_MM_PER_S = {"trolley": 1.0, "rail-vehicle": 50.0, "road-vehicle": 100.0}
#: wheelbase [m] written, to fill in, when neither the log nor ``--set`` gives it: a round figure
#: of the class (survey trolleys about 1 m, bogies about 2.5 m), so that the file runs; the odometer
#: hardly depends on it (a lever arm along the direction it measures), the wheel path does (off)
PLACEHOLDER_WHEELBASE_M = {"trolley": 1.0, "rail-vehicle": 2.5}
#: a road vehicle's GNSS correlated-error model: the baseline-dependent part of RTK datasheets
#: ("8 mm + 1 ppm H, 15 mm + 1 ppm V": 1 ppm at a 3 km baseline; residual atmosphere and orbit
#: error, changing over tens of minutes); a moving car's carrier multipath decorrelates within a
#: second (white: the rest of the stated std). The pipeline's own default (8 / 15 mm, 300 s) is a
#: railway's: masts, catenary and cuttings next to a slow trolley.
ROAD_GNSS_CORRELATED = {"correlated_sigma_h_mm": 3.0, "correlated_sigma_v_mm": 3.0, "correlation_time_s": 600.0}
#: keyframe spacing [s] by kind (every GNSS fix gets a keyframe besides): a road vehicle's loose
#: NHC needs no denser ones (57 min car survey, benchmarks/car_survey.py: the same error to 0.01 mm
#: at 0.1, 0.5 and 1 s; the run's CPU 42, 17 and 13 s)
KEYFRAME_SPACING_S = {"trolley": 0.1, "rail-vehicle": 0.1, "road-vehicle": 1.0}


@dataclass
class InitResult:
    """What ``init`` wrote: the file, the vehicle kind, the sensors found (topic -> summary
    line) and the keys left for the user to fill in."""

    path: Path
    kind: str
    sensors: dict[str, str]
    fill_in: list[str] = field(default_factory=list)

    def format(self) -> str:
        lines = [f"wrote {self.path} ({self.kind})"] + [f"  {t}: {s}" for t, s in self.sensors.items()]
        if self.fill_in:
            lines.append("  fill in (zero now, see the comments): " + ", ".join(self.fill_in))
        return "\n".join(lines)


# --- what the log holds ---------------------------------------------------------------------------

def _topics(log) -> dict[str, tuple[str, Any]]:
    """Topic -> (sensor name, data) of every sensor with records."""
    out = {}
    for name in ("imu", "odometer", "gnss", "inclinometer", "gauge"):
        data = getattr(log, name)
        if data is not None and data.t_s.size:
            out[f"/{name}"] = (name, data)
    for sid, data in sorted(log.total_stations.items()):
        if data.t_s.size:
            out[f"/total_station/{sid}"] = ("total_stations", data)
    return out


def _describe(t_s: np.ndarray) -> str:
    t = np.asarray(t_s, dtype=float)
    span = float(t[-1] - t[0]) if t.size > 1 else 0.0
    rate = (t.size - 1) / span if span > 0 else 0.0
    return f"{t.size} records at {rate:.4g} Hz over {span:.1f} s"


def _first_good_fix(gnss) -> tuple[int, str]:
    """Index of the first RTK-fixed fix (quality 4), else RTK float (5), else the first; and its name."""
    q = np.asarray(gnss.fix_quality)
    for quality, name in ((4, "RTK fixed"), (5, "RTK float")):
        hit = np.flatnonzero(q == quality)
        if hit.size:
            return int(hit[0]), name
    return 0, f"quality {int(q[0])}"


def _imu_spec(log, grade: str | None, rate_hz: float) -> tuple[dict, str]:
    """The IMU section (every ImuSpec key) and where its figures come from."""
    if grade is not None:
        spec, source = IMU_GRADES[grade], f"the datasheet figures of grade {grade} (sensors/imu.py)"
    else:
        record = log.metadata.get("sensors", {}).get("imu") if isinstance(log.metadata.get("sensors"), dict) else None
        try:
            spec, source = ImuSpec(**record), "the log's sensors metadata record"
        except (TypeError, ValueError):  # no record, or not an ImuSpec
            spec, source = IMU_GRADES["navigation"], ("grade navigation's datasheet figures (no --imu-grade, no "
                                                     "record in the log): replace with your IMU's")
    return {**spec.model_dump(), "rate_hz": float(f"{rate_hz:.6g}")}, source


# --- the pipeline -----------------------------------------------------------------------------------

class _Draft:
    """The pipeline mapping being written and a comment per dotted key (lines above the key)."""

    def __init__(self):
        self.data: dict[str, Any] = {}
        self.notes: dict[str, str] = {}
        self.fill_in: list[str] = []
        self.unused: list[str] = []  # topics of the log the pipeline does not use, with the reason
        self.topics: dict[str, str] = {}  # topic -> count, rate, span

    def put(self, key: str, value: Any, note: str | None = None, fill_in: bool = False) -> None:
        node = self.data
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
        if note:
            self.notes[key] = note
        if fill_in:
            self.fill_in.append(key)


def _vehicle(d: _Draft, kind: str, arms: dict, given: set[str]) -> None:
    """The vehicle section of ``kind`` from the log's ``lever_arms`` record ``arms`` (or zeros and
    placeholders to fill in); ``given``: the keys ``--set`` gives."""
    d.put("vehicle.kind", kind, "what carries the IMU (docs/pipeline.md, vehicle): trolley, rail-vehicle, road-vehicle")
    from_log = "from the log's lever_arms metadata record"
    if kind in ("trolley", "rail-vehicle"):
        key = "wheelbase_m" if kind == "trolley" else "axle_distance_m"
        what = ("reference-rail wheels, front to rear [m]" if kind == "trolley"
                else "the two axles of the IMU's bogie, or the two bogie centres (IMU on the body) [m]")
        if "wheelbase_m" in arms:
            d.put(f"vehicle.{key}", float(arms["wheelbase_m"]), f"{what}; {from_log}")
        elif f"vehicle.{key}" in given:
            d.put(f"vehicle.{key}", None, what)  # the --set value comes in after the draft
        else:
            d.put(f"vehicle.{key}", PLACEHOLDER_WHEELBASE_M[kind],
                  f"FILL IN: {what}; a placeholder (the wheel path stays off until it is measured)", True)
        d.put("vehicle.reference_rail", "left")
    origin = {"trolley": "v's origin: midway between the reference-rail wheel contacts",
              "rail-vehicle": "v's origin: midway between those axles, on the reference rail",
              "road-vehicle": "v's origin: the centre of the rear axle"}[kind]
    if "lever_arm_imu_v_m" in arms:
        d.put("vehicle.lever_arm_imu_v_m", [float(x) for x in arms["lever_arm_imu_v_m"]],
              f"IMU origin in v [m] ({origin}); {from_log}")
    else:
        d.put("vehicle.lever_arm_imu_v_m", [0.0, 0.0, 0.0],
              f"FILL IN: IMU origin in v [m], x forward, y left, z up ({origin}); zero = the IMU sits there", True)
    ypr = [float(x) for x in arms.get("mounting_ypr_deg", (0.0, 0.0, 0.0))]
    d.put("vehicle.mounting_ypr_deg", ypr, "b relative to v: yaw, pitch, roll [deg]"
          + (f"; {from_log}" if "mounting_ypr_deg" in arms else " (zero: IMU axes along the vehicle's)"))
    if kind == "trolley":
        d.put("vehicle.odometer_wheel", "rear", "the reference-rail wheel carrying the encoder: rear or front")
    elif kind == "rail-vehicle":
        d.put("vehicle.odometer_axle", "rear", "the axle carrying the odometer: rear or front")
    else:
        d.put("vehicle.odometer_lever_arm_v_m", None,
              "where the speed is measured in v [m]; null: the rear axle centre (the mean of the rear wheels)")


def _sensors_and_factors(d: _Draft, log, kind: str, topics: dict, grade: str | None, arms: dict) -> list[str]:
    """sensors:, factors:, keyframes: and geometry:; returns the unused topics' lines."""
    rate = 1.0 / float(np.median(np.diff(log.imu.t_s)))
    imu, source = _imu_spec(log, grade, rate)
    d.put("sensors.imu", imu, f"/imu: {_describe(log.imu.t_s)}; noise and biases: {source}; rate_hz: as measured")
    has = {name for name, _ in topics.values()}
    d.put("factors.imu", True)
    d.put("factors.zupt", True, "zero velocity on the static periods (found from the IMU; checked against GNSS)")
    sigma = NHC_SIGMA_MM_PER_S[kind]
    d.put("factors.nhc", {"sigma_lateral_mm_per_s": sigma, "sigma_vertical_mm_per_s": sigma},
          "no lateral or vertical velocity of v's origin; the sigma for a " + kind
          + " (docs/pipeline.md, Choosing the NHC sigma: calibrate on your vehicle)")
    unused = []
    if "odometer" in has:
        d.put("sensors.odometer", {"clock_offset_s": 0.0}, f"/odometer: {_describe(log.odometer.t_s)}; "
              "clock_offset_s: its clock minus the IMU's")
    d.put("factors.odometer", "odometer" in has)
    # the wheel path needs the exact wheelbase: not on a placeholder
    aided = bool({"gnss", "total_stations"} & has)  # measured with either (docs/wheel_path.md)
    wheel_path = kind == "trolley" and "odometer" in has and aided and "vehicle.wheelbase_m" not in d.fill_in
    d.put("factors.wheel_path", {"enabled": True, "keyframe_step": 1} if wheel_path else False,
          "the rear wheel runs where the front one ran (docs/wheel_path.md)" if wheel_path
          else "the wheel path: a trolley's, with an odometer and GNSS or total stations (docs/wheel_path.md)")
    if "gnss" in has:
        g = log.gnss
        if "gnss_antenna_b_m" in arms:
            d.put("sensors.gnss.lever_arm_b_m", [float(x) for x in arms["gnss_antenna_b_m"]],
                  f"/gnss: {_describe(g.t_s)}; antenna phase centre from the IMU origin in b [m]: from the log's "
                  "lever_arms metadata record")
        else:
            d.put("sensors.gnss.lever_arm_b_m", [0.0, 0.0, 0.0],
                  f"/gnss: {_describe(g.t_s)}; FILL IN: antenna phase centre from the IMU origin in b [m] (x "
                  "forward, y left, z up); measure it: it is never zero", True)
        d.put("sensors.gnss.clock_offset_s", 0.0)
    if "gnss" in has and kind == "road-vehicle":
        d.put("factors.gnss", dict(ROAD_GNSS_CORRELATED),
              "the fixes' slow error (Gauss-Markov): the RTK datasheet's baseline-dependent 1 ppm at 3 km; "
              "scale it to your base-station distance (docs/init.md); the white part: the stated std less "
              "this, its scale estimated from the residuals")
    else:
        d.put("factors.gnss", "gnss" in has)
    if "inclinometer" in has:
        d.put("sensors.inclinometer", {"clock_offset_s": 0.0}, f"/inclinometer: {_describe(log.inclinometer.t_s)}")
    d.put("factors.inclinometer", "inclinometer" in has)
    stations = [t for t, (name, _) in topics.items() if name == "total_stations"]
    d.put("factors.total_stations", False, ("the log has " + ", ".join(stations) + ": their set-ups and prism "
                                            "lever arm go in sensors.total_stations (docs/total_stations.md)")
          if stations else None)
    unused += [f"{t} (needs sensors.total_stations)" for t in stations]
    d.put("keyframes.spacing_s", 0.2 if wheel_path else KEYFRAME_SPACING_S[kind],
          "with the wheel path: 0.2 s keyframes keep the 0.1 s accuracy (docs/solver_speed.md)" if wheel_path else None)
    rail = kind in ("trolley", "rail-vehicle")
    d.put("geometry.enabled", rail, "track geometry (docs/geometry.md)" if rail else "no track geometry for a road vehicle")
    if "gauge" in has and not rail:
        unused.append("/gauge (no track geometry for a road vehicle)")
    elif "gauge" in has:
        d.notes["geometry.enabled"] += f"; /gauge: {_describe(log.gauge.t_s)}"
    d.put("outputs.trajectory_rate_hz", float(min(100.0, np.floor(rate))))
    return unused


def draft_pipeline(log, log_path: Path, out: Path, kind: str = "trolley", imu_grade: str | None = None,
                   given: set[str] = frozenset()) -> _Draft:
    """The pipeline for ``log`` (read from ``log_path``) to be written at ``out``; ``given``: the
    dotted keys ``--set`` will give."""
    if kind not in VEHICLE_KINDS:
        raise ConfigError(f"--vehicle: unknown kind {kind!r} (known: {', '.join(VEHICLE_KINDS)})")
    if imu_grade is not None and imu_grade not in IMU_GRADES:
        raise ConfigError(f"--imu-grade: unknown grade {imu_grade!r} (known: {', '.join(IMU_GRADES)})")
    if log.imu is None or log.imu.t_s.size < 2:
        raise ConfigError(f"{log_path}: the log has no /imu records")
    topics = _topics(log)
    arms = log.metadata.get("lever_arms") if isinstance(log.metadata.get("lever_arms"), dict) else {}
    d = _Draft()
    d.put("name", log_path.stem)
    d.put("inputs.log", os.path.relpath(log_path.resolve(), out.resolve().parent), "the raw log, relative to this file")
    survey = log.metadata.get("survey") if isinstance(log.metadata.get("survey"), dict) else {}
    meta_origin = survey.get("origin") if isinstance(survey.get("origin"), dict) else {}
    if {"lat_deg", "lon_deg", "h_m"} <= set(meta_origin):  # the survey's own datum point
        d.put("origin", {k: float(meta_origin[k]) for k in ("lat_deg", "lon_deg", "h_m")},
              "origin of n (ENU): the log's survey metadata record")
    elif log.gnss is not None and log.gnss.t_s.size:
        i, quality = _first_good_fix(log.gnss)
        d.put("origin", {"lat_deg": float(log.gnss.lat_deg[i]), "lon_deg": float(log.gnss.lon_deg[i]),
                         "h_m": float(log.gnss.h_m[i])},
              f"origin of n (ENU): the first {quality} fix, at t = {float(log.gnss.t_s[i]):.3f} s")
    _vehicle(d, kind, arms, given)
    d.unused = _sensors_and_factors(d, log, kind, topics, imu_grade, arms)
    d.topics = {t: _describe(data.t_s) for t, (_, data) in topics.items()}
    return d


# --- --set -----------------------------------------------------------------------------------------

def parse_set(item: str) -> tuple[str, Any]:
    """``KEY=VALUE`` -> (dotted key, value parsed as YAML)."""
    key, sep, text = item.partition("=")
    key = key.strip()
    if not sep or not key or any(not p for p in key.split(".")):
        raise ConfigError(f"--set {item}: expected KEY=VALUE with a dotted pipeline key")
    try:
        return key, yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {key}: value is not YAML ({str(exc).splitlines()[0]})") from None


def apply_set(data: dict, key: str, value: Any) -> None:
    """Put ``value`` at the dotted ``key`` of ``data``; a factor written as true/false becomes
    ``{enabled: ...}`` when a key below it is set."""
    node = data
    parts = key.split(".")
    for p in parts[:-1]:
        child = node.get(p)
        if isinstance(child, bool):
            child = {"enabled": child}
        elif not isinstance(child, dict):
            child = {}
        node[p] = child
        node = child
    node[parts[-1]] = value


def _unknown_key(exc_errors: list[dict], keys: list[str]) -> str | None:
    """The ``--set`` key an ``extra_forbidden`` validation error is at, if any."""
    for e in exc_errors:
        if e["type"] == "extra_forbidden":
            at = ".".join(str(p) for p in e["loc"])
            for k in keys:
                if k == at or k.startswith(at + ".") or at.startswith(k + "."):
                    return k
    return None


def _validate(data: dict, out: Path, set_keys: list[str]) -> None:
    """Validate as ``trackfusion run`` does; an unknown ``--set`` key is named as such."""
    from pydantic import ValidationError
    from .pipeline import PipelineConfig, _UserPaths, parse_pipeline
    from .vehicles import vehicle_section
    try:
        PipelineConfig.model_validate(vehicle_section(data))
    except ValidationError as exc:
        unknown = _unknown_key(_UserPaths(exc, False).errors(), set_keys)
        if unknown is not None:
            raise ConfigError(f"--set {unknown}: not a pipeline key (docs/pipeline.md)") from None
    except ValueError:
        pass  # parse_pipeline names it below
    parse_pipeline(data, str(out), out.resolve().parent)


# --- the YAML text ---------------------------------------------------------------------------------

def _scalar(value: Any) -> str:
    """A value as one line of YAML flow (a one-item flow list, brackets off: PyYAML reads
    JSON's ``1e-07`` as a string, its own ``1.0e-07`` as the number)."""
    return yaml.safe_dump([value], default_flow_style=True, width=10**9).strip()[1:-1]


def _render(node: dict, notes: dict[str, str], prefix: str = "", indent: int = 0) -> list[str]:
    lines = []
    pad = "  " * indent
    for key, value in node.items():
        path = prefix + key
        if notes.get(path):
            lines += [f"{pad}# {line}" for line in notes[path].splitlines()]
        if isinstance(value, dict) and value:
            lines.append(f"{pad}{key}:")
            lines += _render(value, notes, path + ".", indent + 1)
        else:
            lines.append(f"{pad}{key}: {_scalar(value)}")
    return lines


def render(d: _Draft, log_path: Path, header: list[str]) -> str:
    """The commented YAML text of the draft."""
    top = [f"# trackfusion pipeline for {log_path.name}, written by 'trackfusion init' (docs/init.md, docs/pipeline.md)"]
    top += [f"# {line}" for line in header]
    return "\n".join(top + _render(d.data, d.notes)) + "\n"


def init_pipeline(log_path: str | os.PathLike, out: str | os.PathLike, kind: str = "trolley",
                  imu_grade: str | None = None, sets: list[str] | None = None, force: bool = False,
                  progress: Callable[[str], None] | None = None) -> InitResult:
    """Write the pipeline for the log at ``log_path`` to ``out`` (module docstring)."""
    from .sensors.fileio import write_text_atomic
    from .sensors.mcap_log import read_log
    say = progress or (lambda _m: None)
    log_path, out = Path(log_path), Path(out)
    if out.exists() and not force:
        raise ConfigError(f"{out}: exists; pass --force to overwrite it")
    parsed = [parse_set(s) for s in sets or []]
    from .sensors.ros2 import is_bag, read_bag
    bag = is_bag(log_path)  # a ROS 2 bag (docs/log_format.md): its topics found as run finds them
    if not (log_path.is_file() or bag):
        raise ConfigError(f"{log_path}: log not found")
    say(f"reading {log_path}")
    log = read_bag(log_path)[0] if bag else read_log(log_path)
    d = draft_pipeline(log, log_path, out, kind, imu_grade, {k for k, _ in parsed})
    for key, value in parsed:
        apply_set(d.data, key, value)
        d.notes[key] = (d.notes.get(key, "").replace("FILL IN: ", "") + "; " if d.notes.get(key) else "") + "set by --set"
        if key in d.fill_in:
            d.fill_in.remove(key)
    _validate(d.data, out, [k for k, _ in parsed])
    header = ["sensors in the log: " + "; ".join(f"{t} {s}" for t, s in d.topics.items())]
    if d.unused:
        header.append("in the log, not used: " + ", ".join(d.unused))
    if d.fill_in:
        header.append("FILL IN before trusting the results: " + ", ".join(d.fill_in) + " (zero now)")
    text = render(d, log_path, header)
    if yaml.safe_load(text) != d.data:  # the text must say what was validated
        raise AssertionError("init: the rendered pipeline does not read back as drafted")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, text)
    return InitResult(out, d.data["vehicle"]["kind"], d.topics, list(d.fill_in))
