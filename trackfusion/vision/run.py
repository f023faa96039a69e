"""``trackfusion run`` of a vision survey: a pipeline with a ``vision:`` section (docs/vision.md,
"Simulating and running a survey").

The log's images (``foxglove.CompressedImage`` PNG, :mod:`.image_log`) are measured frame by
frame with the calibrated camera-laser units (:func:`~trackfusion.vision.measure.measure_run`);
the roll of the measuring frame relative to the track comes from its IMU, the encoder's
chainage matched onto the design (:mod:`.relative_motion`), less the run's constant roll offset
estimated from the cross-level's mean about the design (``cross_level_reference: design``,
:mod:`.cross_level_reference`); the centreline's alignment and
vertical profile (D1 band) are the fitted profile origins plus eq. 46's relative trajectory.
Writes ``geometry.csv`` (+ ``geometry.json``), ``metrics.json`` and ``report.html`` (cross-sections
at a few chainages, gauge and wear against chainage). Faulty frames are NaN in the table and
listed in ``metrics.json``; nothing a simulator knows is read.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
from pydantic import Field, ValidationError

from ..errors import ConfigError, SensorDataError
from ..strict import StrictModel
from ..yamlio import ConfigFile

RUN_FILES = ("geometry.csv", "geometry.json", "metrics.json", "report.html")


class VisionSection(StrictModel):
    """``log``: the raw log (IMU, encoder, both cameras); ``calibration``: the file
    ``trackfusion calibrate-vision`` wrote; ``design``: curvature and cant against chainage
    (:mod:`.design_table`); the rail profile and nominal gauge of the drawing; ``workers``:
    forked processes for the per-frame measurement (the result does not depend on it);
    ``cross_level_reference``: ``design`` takes the run's constant roll offset (the
    accelerometer's lateral bias, :mod:`.cross_level_reference`) off the roll, weighted against
    ``accel_bias_mg``, the IMU datasheet's accelerometer bias (1 sigma, in-run and turn-on; null:
    the offset is taken off whole); ``none`` only reports it."""

    log: str
    calibration: str
    design: str
    rail_profile: str = "60E1"
    gauge_nominal_m: float = Field(1.435, gt=0.5, lt=2.5)
    workers: int = Field(2, ge=1)
    cross_level_reference: Literal["design", "none"] = "design"
    accel_bias_mg: float | None = Field(None, gt=0)


class VisionOutputs(StrictModel):
    report: bool = True


class VisionPipelineConfig(StrictModel):
    name: str = "vision survey"
    description: str = ""
    vision: VisionSection
    outputs: VisionOutputs = VisionOutputs()


@dataclass
class VisionPipeline(ConfigFile):
    """A validated vision pipeline and the folder its relative paths start from."""

    config: VisionPipelineConfig = field(kw_only=True)

    def inputs(self) -> list[Path]:
        v = self.config.vision
        return [Path(self.source)] + [self.path(p) for p in (v.log, v.calibration, v.design)]


def is_vision_pipeline(data: Any) -> bool:
    return isinstance(data, dict) and "vision" in data


def parse_vision_pipeline(data: dict, source: str, base_dir: Path) -> VisionPipeline:
    """Validate; :class:`ConfigError` naming the file and field, or a missing input."""
    from ..track.rail_profile import rail_head
    try:
        cfg = VisionPipelineConfig.model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        raise ConfigError(f"{source}: {'.'.join(str(x) for x in e['loc'])}: {e['msg']}") from None
    p = VisionPipeline(base_dir, source, config=cfg)
    for key in ("log", "design", "calibration"):
        f = p.path(getattr(cfg.vision, key))
        if not f.is_file():
            hint = " (write it with 'trackfusion calibrate-vision FOLDER --out FILE')" if key == "calibration" else ""
            raise ConfigError(f"{source}: vision.{key}: file not found: {f}{hint}")
    try:
        rail_head(cfg.vision.rail_profile)
    except (KeyError, ValueError):
        raise ConfigError(f"{source}: vision.rail_profile: unknown profile {cfg.vision.rail_profile!r}") from None
    return p


def read_inputs(p: VisionPipeline) -> dict:
    """Log, calibrated units and design, checked against each other before any computing."""
    from .calibration import load_calibration
    from .design_table import read_design_csv
    from .image_log import read_vision_log
    v = p.config.vision
    units = load_calibration(p.path(v.calibration))
    missing = {"left", "right"} - set(units)
    if missing:
        raise ConfigError(f"{p.path(v.calibration)}: no unit for the {' and '.join(sorted(missing))} rail")
    log = read_vision_log(p.path(v.log))
    for side, unit in units.items():
        shape = log["images"][side].shape[1:]
        if shape != (unit.camera.height_px, unit.camera.width_px):
            raise SensorDataError(f"{p.path(v.log)}: /camera/{side}/image: {shape[1]}x{shape[0]} px, "
                                  f"the calibration's camera has {unit.camera.width_px}x{unit.camera.height_px}")
    if np.any(np.diff(log["t_imu_s"]) <= 0):
        raise SensorDataError(f"{p.path(v.log)}: /imu: times not strictly increasing")
    t_f = log["t_frame_s"]
    if t_f[0] < log["t_imu_s"][0] or t_f[-1] > log["t_imu_s"][-1]:
        raise SensorDataError(f"{p.path(v.log)}: /camera/left/image: frames outside the IMU's record")
    return {"log": log, "units": units, "design": read_design_csv(p.path(v.design))}


def motion(log: dict, design) -> dict:
    """Design chainage, roll relative to the track and relative trajectory at the IMU's times,
    then at the frames' times (linear interpolation)."""
    from .relative_motion import design_along, design_chainage_m, relative_trajectory, zero_phase_roll
    t, gyro, accel = log["t_imu_s"], log["gyro_b"], log["accel_b"]
    s = design_chainage_m(t, log["encoder_m"], gyro, accel, design.at)
    rho, cant = design.at(s)
    d = design_along(s, t, rho, cant)
    roll = zero_phase_roll(t, gyro, accel, d["speed_mps"], rho) - cant
    r_t = relative_trajectory(t, accel, roll, d)
    tf = log["t_frame_s"]
    return {"s_m": s, "r_t": r_t, "offset_m": float(s[0] - log["encoder_m"][0]),
            "frame_s_m": np.interp(tf, t, s), "frame_roll_rad": np.interp(tf, t, roll)}


def reference_cross_level(mo: dict, m, reference: str, accel_bias_mg: float | None = None) -> tuple[dict, Any]:
    """The run's constant roll offset estimated from the measured cross-level
    (:func:`~trackfusion.vision.cross_level_reference.estimate_roll_offset`), in
    ``mo["cross_level_reference"]``; with ``reference == "design"`` taken off the frames' roll
    (weighted against the datasheet's bias ``accel_bias_mg``, :func:`~trackfusion.vision.
    cross_level_reference.prior_weight`),
    and the cross-level (eq. 37 from the fitted poses) and the centreline's trace (eq. 40,
    :func:`d1_traces`) follow. Eq. 46's relative trajectory stays: it sees ``a_y - g phi``, in
    which a lateral accelerometer bias and the roll offset it causes cancel (taking the offset
    off the roll alone would leave the bias there, a drift of ``b_y t^2 / 2``). The gauge keeps
    the first roll (a constant roll moves both gauge points alike; measuring the frames again
    with the offset moved it by 0.6-9.5 um rms, at most 48 um in a frame where a window edge
    moved, ``benchmarks/vision.py``). Returns the motion and the measurements."""
    from dataclasses import replace
    from .cross_level_reference import estimate_roll_offset, prior_weight
    from .measure import cross_level_of_poses
    est = estimate_roll_offset(m.cross_level_m, m.pose["left"], m.pose["right"], mo["frame_roll_rad"])
    weight = prior_weight(est.sd_rad, accel_bias_mg)
    if reference == "design":
        mo = {**mo, "frame_roll_rad": mo["frame_roll_rad"] - weight * est.offset_rad}
        m = replace(m, cross_level_m=cross_level_of_poses(m.pose["left"], m.pose["right"], mo["frame_roll_rad"]))
    return {**mo, "cross_level_reference": est.as_metrics(reference, weight)}, m


def d1_traces(m, mo: dict) -> dict[str, np.ndarray]:
    """Centreline alignment and vertical profile (F,) [m], D1 band: eq. 46's ``r`` band-passed over
    the whole IMU record plus the fitted origins' mean over the filmed stretch (eq. 40)."""
    from .relative_motion import band_trace, rail_centre_trace
    centre = rail_centre_trace(m.pose["left"][:, :2], m.pose["right"][:, :2], mo["frame_roll_rad"])
    out = {}
    for k, name in enumerate(("alignment", "vertical_profile")):
        r_band = np.interp(mo["frame_s_m"], mo["s_m"], band_trace(mo["s_m"], mo["r_t"][:, k]))
        out[name] = r_band + band_trace(mo["frame_s_m"], centre[:, k])
    return out


GEOMETRY_UNITS = {"t_s": "s", "chainage_m": "m", "gauge_m": "m", "cross_level_mm": "mm",
                  "wear_vertical_left_mm": "mm", "wear_vertical_right_mm": "mm", "wear_side_left_mm": "mm",
                  "wear_side_right_mm": "mm", "alignment_d1_mm": "mm", "vertical_profile_d1_mm": "mm",
                  "roll_rel_deg": "deg", "fault": "1"}


def geometry_table(log: dict, mo: dict, m, d1: dict) -> dict[str, np.ndarray]:
    """geometry.csv's columns, one row per frame (NaN where the frame is a fault)."""
    F = len(log["t_frame_s"])
    fault = np.zeros(F)
    fault[m.fault_frames] = 1.0
    cols = {"t_s": log["t_frame_s"], "chainage_m": mo["frame_s_m"], "gauge_m": m.gauge_m,
            "cross_level_mm": m.cross_level_m * 1e3}
    for side in ("left", "right"):
        cols[f"wear_vertical_{side}_mm"] = m.vertical_wear_mm[side]
    for side in ("left", "right"):
        cols[f"wear_side_{side}_mm"] = m.side_wear_mm[side]
    cols.update({"alignment_d1_mm": d1["alignment"] * 1e3, "vertical_profile_d1_mm": d1["vertical_profile"] * 1e3,
                 "roll_rel_deg": np.degrees(mo["frame_roll_rad"]), "fault": fault})
    return cols


def _stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"mean": None, "min": None, "max": None, "sd": None}
    return {"mean": float(x.mean()), "min": float(x.min()), "max": float(x.max()), "sd": float(x.std())}


def vision_metrics(cfg: VisionPipelineConfig, log: dict, mo: dict, m, table: dict, timings: dict) -> dict:
    """metrics.json: counts, the fault list (frame, time, chainage, rail, reason), the chainage
    shift, statistics of each geometry column."""
    F = len(log["t_frame_s"])
    faults = [{"frame": int(f), "t_s": float(log["t_frame_s"][f]), "chainage_m": float(mo["frame_s_m"][f]),
               "rail": side, "reason": reason} for f, side, reason in m.faults]
    return {"name": cfg.name, "vision": {
        "frames": F, "imu_samples": int(log["t_imu_s"].size),
        "duration_s": float(log["t_imu_s"][-1] - log["t_imu_s"][0]),
        "chainage_m": [float(mo["frame_s_m"][0]), float(mo["frame_s_m"][-1])],
        "encoder_to_design_shift_m": mo["offset_m"],
        "cross_level_reference": mo["cross_level_reference"],
        "frames_per_cpu_s": timings.get("frames_per_cpu_s"),
        "faults": {"frames": int(m.fault_frames.size), "rail_frames": len(faults),
                   "by_reason": dict(sorted(Counter(f["reason"] for f in faults).items())), "list": faults},
        "columns": {k: _stats(v) for k, v in table.items() if k not in ("t_s", "chainage_m", "fault")}},
        "timings_s": timings}


def cpu_s() -> float:
    """CPU seconds [s] of this process and of its children that have ended (the forked workers,
    reaped by then): user and system time."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def process(inputs: dict, cfg: VisionPipelineConfig, say: Callable[[str], None]) -> tuple[dict, dict, Any, dict]:
    """The run's computing: table, metrics, the measurements and the motion."""
    from ..track.rail_profile import rail_head
    from .measure import measure_run
    v, log = cfg.vision, inputs["log"]
    head = rail_head(v.rail_profile)
    timings: dict[str, float] = {}
    tic = time.perf_counter()
    say(f"[{cfg.name}] roll and relative motion from {log['t_imu_s'].size} IMU samples")
    mo = motion(log, inputs["design"])
    timings["motion_s"] = time.perf_counter() - tic
    F = len(log["t_frame_s"])
    say(f"[{cfg.name}] measuring {F} frames of both cameras")
    tic, cpu = time.perf_counter(), cpu_s()
    m = measure_run(inputs["units"], head, log["images"], mo["frame_roll_rad"], gauge_nominal_m=v.gauge_nominal_m,
                    workers=v.workers)
    timings["frames_s"] = time.perf_counter() - tic
    timings["frames_cpu_s"] = cpu_s() - cpu
    timings["frames_per_s"] = F / max(timings["frames_s"], 1e-9)
    timings["frames_per_cpu_s"] = F / max(timings["frames_cpu_s"], 1e-9)
    tic = time.perf_counter()
    mo, m = reference_cross_level(mo, m, v.cross_level_reference, v.accel_bias_mg)
    timings["cross_level_reference_s"] = time.perf_counter() - tic
    table = geometry_table(log, mo, m, d1_traces(m, mo))
    return table, vision_metrics(cfg, log, mo, m, table, timings), m, mo


@dataclass
class VisionRunResult:
    """What a vision run produced, as :class:`trackfusion.pipeline.RunResult` names it (the
    geometry table stands for the trajectory; there is no smoother)."""

    out_dir: Path
    files: list[str]
    metrics: dict[str, Any]
    trajectory: dict[str, np.ndarray]
    smoother: None = None


def run_vision(p: VisionPipeline, out_dir: str | Path | None = None,
               progress: Callable[[str], None] | None = None, force: bool = False):
    """Run the vision pipeline ``p`` into ``out_dir`` (default ``out/`` beside the YAML):
    checked and locked first, inputs read and checked before computing, outputs staged."""
    from ..outdir import OutputFolder
    from ..sensors.fileio import write_csv_table, write_json_atomic
    say = progress or (lambda _m: None)
    out = Path(out_dir) if out_dir is not None else p.base_dir / "out"
    folder = OutputFolder(out, force, inputs=p.inputs(), command="trackfusion run", writes=RUN_FILES)
    wall, cpu = time.perf_counter(), cpu_s()
    with folder.locked():
        say(f"[{p.config.name}] reading {p.path(p.config.vision.log)}")
        inputs = read_inputs(p)
        read_s = time.perf_counter() - wall
        table, metrics, m, _mo = process(inputs, p.config, say)
        metrics["timings_s"].update(read_s=read_s, total_s=time.perf_counter() - wall, total_cpu_s=cpu_s() - cpu)
        with folder.staging() as stage:
            write_csv_table(stage / "geometry.csv", table, GEOMETRY_UNITS, "track (design chainage)", {},
                            extra={"description": "vision-inertial track geometry per camera frame; "
                                                  "NaN where the frame is a fault (metrics.json vision.faults)"})
            write_json_atomic(stage / "metrics.json", metrics)
            if p.config.outputs.report:
                from ..report.vision_plots import write_vision_report
                from ..track.rail_profile import rail_head
                write_vision_report(stage / "report.html", p.config.name, table, metrics, inputs, m,
                                    rail_head(p.config.vision.rail_profile))
            files = sorted(x.name for x in stage.iterdir())
    say(f"[{p.config.name}] done: {folder.path}/")
    return VisionRunResult(folder.path, files, metrics, table)


def format_vision_summary(result) -> str:
    """The terminal lines of a vision run."""
    from .cross_level_reference import describe_reference
    v = result.metrics["vision"]
    cols = v["columns"]
    f = v["faults"]
    gauge = cols["gauge_m"]
    lines = [f"wrote {', '.join(result.files)} to {result.out_dir}/",
             f"  {v['frames']} frames per camera over {v['chainage_m'][0]:.1f}-{v['chainage_m'][1]:.1f} m, "
             f"{v['imu_samples']} IMU samples; encoder shifted {v['encoder_to_design_shift_m']:+.3f} m onto the design",
             f"  faults: {f['frames']} frames ({', '.join(f'{k} {n}' for k, n in f['by_reason'].items()) or 'none'})"]
    if gauge["mean"] is not None:
        lines.append(f"  gauge {gauge['min'] * 1e3:.1f}-{gauge['max'] * 1e3:.1f} mm, cross-level "
                     f"{cols['cross_level_mm']['min']:.1f} to {cols['cross_level_mm']['max']:.1f} mm")
    lines.append(f"  {describe_reference(v['cross_level_reference'])}")
    return "\n".join(lines)
