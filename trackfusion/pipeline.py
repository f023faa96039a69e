"""Pipeline: the YAML a survey is processed with, and ``run`` (``trackfusion run``).

A pipeline YAML (docs/pipeline.md) names the raw log, the origin of ``n``, the trolley
geometry, the sensor specifications and lever arms, the factors and their noise, the
keyframe spacing and the outputs. Every section refuses unknown keys, and every error
names the file and the field path. Paths are relative to the YAML file's folder.

:func:`run` reads the log, preprocesses (static intervals, odometer gross errors, GNSS to
``n``, sensor clocks), smooths (:mod:`trackfusion.fusion.smoother`), densifies the
trajectory to the output rate, evaluates against a reference when one is given, and
writes ``trajectory.csv`` (+ sidecar), ``metrics.json`` and ``fused.mcap``. Nothing is
written to the output directory unless the whole run succeeds.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from . import geodesy
from .errors import ConfigError, FusionError, config_error_from_validation
from .fusion import preprocess
from .fusion.preintegration import ImuNoise
from .fusion.problem import FusionProblem, GnssFixes, TrolleyFrame
from .fusion.settings import FactorSettings, KeyframeSettings, SmootherSettings, StaticSettings
from .fusion.smoother import SmootherResult, smooth
from .fusion.trajectory import DenseTrajectory, densify
from .rotations import quat_from_R
from .sensors.imu import IMU_GRADES, ImuSpec
from .sensors.types import InclinometerData, OdometerData, SensorLog

Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class InputsConfig(_Strict):
    """``log``: the raw MCAP log; ``reference``: optional truth/reference trajectory CSV to
    evaluate against; ``allow_truncated``: run on the readable part of a damaged log."""

    log: str
    reference: str | None = None
    allow_truncated: bool = False


class OriginConfig(_Strict):
    lat_deg: float = Field(ge=-90, le=90)
    lon_deg: float = Field(ge=-180, le=360)
    h_m: float = 0.0


class TrolleyConfig(_Strict):
    """Trolley geometry: wheelbase of the reference-rail wheels, IMU origin in ``v`` and the
    mounting angles of ``b`` in ``v`` (yaw, pitch, roll)."""

    wheelbase_m: float = Field(gt=0)
    reference_rail: Literal["left", "right"] = "left"
    lever_arm_imu_v_m: Vec3
    mounting_ypr_deg: Vec3 = (0.0, 0.0, 0.0)
    odometer_wheel: Literal["rear", "front"] = "rear"


class ImuConfig(ImuSpec):
    """IMU specification; ``grade: <name>`` starts from a named grade
    (``navigation``, ``navigation-500``, ``fog``, ``mems-tactical``) and other keys override it."""

    @model_validator(mode="before")
    @classmethod
    def _grade(cls, data: Any) -> Any:
        if isinstance(data, dict) and "grade" in data:
            data = dict(data)
            grade = data.pop("grade")
            if grade not in IMU_GRADES:
                raise ValueError(f"unknown grade {grade!r} (known: {', '.join(IMU_GRADES)})")
            data = {**IMU_GRADES[grade].model_dump(), **data}
        return data


class ClockConfig(_Strict):
    """``clock_offset_s``: the sensor's clock minus the IMU clock (t_sensor = t_imu + offset)."""

    clock_offset_s: float = 0.0


class GnssConfig(ClockConfig):
    lever_arm_b_m: Vec3


class TotalStationsConfig(_Strict):
    """Prism lever arm and station set-ups (fused by the total-station issue; accepted here)."""

    prism_lever_arm_b_m: Vec3
    stations: dict[str, dict[str, Any]] = {}


class SensorsConfig(_Strict):
    imu: ImuConfig
    odometer: ClockConfig | None = None
    gnss: GnssConfig | None = None
    inclinometer: ClockConfig | None = None
    total_stations: TotalStationsConfig | None = None


class OutputsConfig(_Strict):
    """``trajectory_rate_hz``: rows per second of trajectory.csv (at most the IMU rate; the
    nearest whole divisor of it is used); ``fused_mcap``: write the Foxglove-viewable log."""

    trajectory_rate_hz: float = Field(100.0, gt=0)
    geometry_step_m: float = Field(0.25, gt=0)
    fused_mcap: bool = True


class PipelineConfig(_Strict):
    name: str = "survey"
    description: str = ""
    inputs: InputsConfig
    origin: OriginConfig | None = None
    trolley: TrolleyConfig
    sensors: SensorsConfig
    factors: FactorSettings = FactorSettings()
    keyframes: KeyframeSettings = KeyframeSettings()
    static: StaticSettings = StaticSettings()
    smoother: SmootherSettings = SmootherSettings()
    outputs: OutputsConfig = OutputsConfig()


@dataclass
class Pipeline:
    """A validated pipeline and the folder its relative paths start from."""

    config: PipelineConfig
    base_dir: Path
    source: str

    def path(self, p: str) -> Path:
        q = Path(p)
        return q if q.is_absolute() else self.base_dir / q


def parse_pipeline(data: Any, source: str, base_dir: Path) -> Pipeline:
    """Validate a pipeline mapping; raises :class:`ConfigError` naming ``source`` and the field."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a pipeline must be a mapping of sections")
    try:
        config = PipelineConfig.model_validate(data)
    except ValidationError as exc:
        raise config_error_from_validation(exc, source) from None
    pipeline = Pipeline(config, base_dir, source)
    _check_inputs(pipeline)
    return pipeline


def load_pipeline(path: str | os.PathLike) -> Pipeline:
    """Read and validate a pipeline YAML (see :func:`parse_pipeline`)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: pipeline file not found")
    try:
        data = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse_pipeline(data, str(p), p.resolve().parent)


def _check_inputs(pipeline: Pipeline) -> None:
    cfg, src = pipeline.config, pipeline.source
    for field_name in ("log", "reference"):
        value = getattr(cfg.inputs, field_name)
        if value is not None and not pipeline.path(value).is_file():
            raise ConfigError(f"{src}: inputs.{field_name}: file not found: {pipeline.path(value)}")
    if cfg.factors.total_stations.enabled:
        raise ConfigError(f"{src}: factors.total_stations: total-station fusion is not available yet "
                          "(set it to false)")
    if cfg.factors.gnss.enabled and cfg.sensors.gnss is None:
        raise ConfigError(f"{src}: sensors.gnss: missing (needed by factors.gnss; or set factors.gnss: false)")


# --- running -------------------------------------------------------------------------------------

@dataclass
class RunResult:
    """What a run produced: the output folder, file names, the metrics and the trajectory."""

    out_dir: Path
    files: list[str]
    metrics: dict[str, Any]
    trajectory: dict[str, np.ndarray]
    smoother: SmootherResult


TRAJECTORY_UNITS = {
    "t_s": "s", "e_m": "m", "n_m": "m", "u_m": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
    "ve_mps": "m/s", "vn_mps": "m/s", "vu_mps": "m/s", "chainage_m": "m",
    "sigma_e_m": "m", "sigma_n_m": "m", "sigma_u_m": "m",
    "sigma_roll_rad": "rad", "sigma_pitch_rad": "rad", "sigma_yaw_rad": "rad",
}


def _read(pipeline: Pipeline) -> SensorLog:
    from .sensors.mcap_log import read_log
    cfg = pipeline.config
    topics = ["/imu", "/odometer", "/gnss", "/inclinometer"]
    log = read_log(pipeline.path(cfg.inputs.log), topics=topics, allow_truncated=cfg.inputs.allow_truncated)
    if log.imu is None:
        raise FusionError(f"{pipeline.path(cfg.inputs.log)}: the log has no /imu topic")
    return log


def _origin(pipeline: Pipeline, log: SensorLog) -> geodesy.Origin:
    cfg = pipeline.config
    if cfg.origin is not None:
        return geodesy.Origin(cfg.origin.lat_deg, cfg.origin.lon_deg, cfg.origin.h_m)
    meta = log.metadata.get("survey", {}).get("origin") if isinstance(log.metadata.get("survey"), dict) else None
    if isinstance(meta, dict) and {"lat_deg", "lon_deg", "h_m"} <= set(meta):
        return geodesy.Origin(float(meta["lat_deg"]), float(meta["lon_deg"]), float(meta["h_m"]))
    if log.gnss is not None and log.gnss.t_s.size:
        return geodesy.Origin(float(log.gnss.lat_deg[0]), float(log.gnss.lon_deg[0]), float(log.gnss.h_m[0]))
    raise ConfigError(f"{pipeline.source}: origin: not given, and the log has neither an origin nor GNSS fixes")


def build_problem(pipeline: Pipeline, log: SensorLog, say: Callable[[str], None]) -> tuple[FusionProblem, dict]:
    """Preprocess a log into a :class:`FusionProblem`; returns it and the preprocessing metrics."""
    cfg = pipeline.config
    sensors, fs = cfg.sensors, cfg.factors
    origin = _origin(pipeline, log)
    odometer = None
    info: dict[str, Any] = {}
    if log.odometer is not None and sensors.odometer is not None and fs.odometer.enabled:
        odo = log.odometer
        t = preprocess.sensor_times_to_imu_clock(odo.t_s, sensors.odometer.clock_offset_s)
        odometer, repaired = preprocess.repair_odometer(OdometerData(t, odo.distance_m, odo.ticks),
                                                        window=fs.odometer.gross_error_window,
                                                        threshold_m=fs.odometer.gross_error_threshold_m)
        info["odometer_gross_errors"] = repaired
        say(f"odometer: {odo.t_s.size} records, {len(repaired)} gross errors repaired")
    st = cfg.static
    imu_spec = ImuSpec(**sensors.imu.model_dump())
    imu_rate_hz = 1.0 / float(np.median(np.diff(log.imu.t_s)))
    gyro_thr, accel_thr = st.thresholds(imu_spec.gyro_arw_deg_per_sqrt_h, imu_spec.accel_vrw_mps_per_sqrt_h,
                                        imu_rate_hz)
    static = preprocess.detect_static_intervals(
        log.imu, odometer, window_s=st.window_s, gyro_std_radps=np.radians(gyro_thr),
        accel_std_mps2=accel_thr, max_odometer_speed_mps=st.max_odometer_speed_mps,
        min_duration_s=st.min_duration_s)
    gnss = None
    if log.gnss is not None and sensors.gnss is not None and fs.gnss.enabled:
        gnss = GnssFixes.from_data(log.gnss, origin, sensors.gnss.lever_arm_b_m, sensors.gnss.clock_offset_s)
        sigma_m = np.sqrt(np.diagonal(gnss.cov_n, axis1=1, axis2=2))
        moving = preprocess.moving_intervals_by_gnss(static, gnss.t_s, gnss.pos_n, sigma_m)
        info["static_intervals_moving_by_gnss_s"] = [[float(a), float(b)] for a, b in (static[i] for i in moving)]
        static = [iv for i, iv in enumerate(static) if i not in moving]
    info["static_intervals_s"] = [[float(a), float(b)] for a, b in static]
    say(f"static intervals: {len(static)} ({sum(b - a for a, b in static):.0f} s)")
    inclinometer = None
    if log.inclinometer is not None and sensors.inclinometer is not None and fs.inclinometer.enabled:
        inc = log.inclinometer
        t = preprocess.sensor_times_to_imu_clock(inc.t_s, sensors.inclinometer.clock_offset_s)
        inclinometer = InclinometerData(t, inc.roll_rad, inc.pitch_rad)
    tr = cfg.trolley
    problem = FusionProblem(
        imu=log.imu, imu_noise=ImuNoise.from_spec(imu_spec), imu_gyro_bias_deg_per_h=imu_spec.gyro_bias_deg_per_h,
        origin=origin, trolley=TrolleyFrame.from_angles(tr.mounting_ypr_deg, tr.lever_arm_imu_v_m, tr.wheelbase_m,
                                                        tr.odometer_wheel),
        static_intervals_s=static, factors=fs, keyframes=cfg.keyframes, smoother=cfg.smoother,
        odometer=odometer, gnss=gnss, inclinometer=inclinometer)
    return problem, info


def _decimation(imu_rate_hz: float, rate_hz: float) -> int:
    return max(1, int(round(imu_rate_hz / rate_hz)))


def chainage_along(dense: DenseTrajectory, res: SmootherResult, odometer: OdometerData | None,
                   axis_b: np.ndarray) -> np.ndarray:
    """Chainage [m] at the dense times, 0 at the start: the odometer distance with the smoothed
    scale removed (``d_true = d_meas / (1 + scale)`` per interval), else the signed path length."""
    if odometer is not None and res.odometer_scale is not None:
        d_key = np.interp(res.t_s, odometer.t_s, odometer.distance_m)
        true_key = np.r_[0.0, np.cumsum(np.diff(d_key) / (1.0 + res.odometer_scale[:-1]))]
        corr = (d_key - d_key[0]) - true_key
        d = np.interp(dense.t_s, odometer.t_s, odometer.distance_m) - d_key[0]
        return d - np.interp(dense.t_s, res.t_s, corr)
    step = np.diff(dense.pos_n, axis=0)
    forward = np.einsum("kij,j,ki->k", dense.R_nb[:-1], axis_b, step)
    return np.r_[0.0, np.cumsum(np.sign(forward) * np.linalg.norm(step, axis=1))]


def trajectory_table(dense: DenseTrajectory, res: SmootherResult, chainage_m: np.ndarray, every: int
                     ) -> dict[str, np.ndarray]:
    """trajectory.csv columns (DESIGN.md section 4) at every ``every``-th dense sample."""
    sel = np.arange(0, dense.t_s.size, every)
    t = dense.t_s[sel]
    q = quat_from_R(dense.R_nb[sel])
    sp = np.column_stack([np.interp(t, res.sigma_t_s, res.sigma_pos_n_m[:, i]) for i in range(3)])
    sa = np.column_stack([np.interp(t, res.sigma_t_s, res.sigma_att_rad[:, i]) for i in range(3)])
    p, v = dense.pos_n[sel], dense.vel_n[sel]
    return {"t_s": t, "e_m": p[:, 0], "n_m": p[:, 1], "u_m": p[:, 2], "qw": q[:, 0], "qx": q[:, 1],
            "qy": q[:, 2], "qz": q[:, 3], "ve_mps": v[:, 0], "vn_mps": v[:, 1], "vu_mps": v[:, 2],
            "chainage_m": chainage_m[sel], "sigma_e_m": sp[:, 0], "sigma_n_m": sp[:, 1], "sigma_u_m": sp[:, 2],
            "sigma_roll_rad": sa[:, 0], "sigma_pitch_rad": sa[:, 1], "sigma_yaw_rad": sa[:, 2]}


def _smoother_metrics(res: SmootherResult, info: dict) -> dict[str, Any]:
    deg_h = np.degrees(res.gyro_bias_radps) * 3600.0
    ug = res.accel_bias_mps2 / 9.80665e-6
    m = {
        "keyframes": int(res.t_s.size), "factors": res.factor_counts, "iterations": res.iterations,
        "initial_cost": res.initial_cost, "final_cost": res.final_cost, "alignment": res.alignment.to_json(),
        "gyro_bias_deg_per_h": {"mean": deg_h.mean(axis=0).tolist(), "first": deg_h[0].tolist(),
                                "last": deg_h[-1].tolist()},
        "accel_bias_ug": {"mean": ug.mean(axis=0).tolist(), "first": ug[0].tolist(), "last": ug[-1].tolist()},
        "rejected_gnss": res.rejected_gnss,
        **info,
    }
    if res.odometer_scale is not None:
        m["odometer_scale_ppm"] = {"mean": float(res.odometer_scale.mean() * 1e6),
                                   "first": float(res.odometer_scale[0] * 1e6),
                                   "last": float(res.odometer_scale[-1] * 1e6)}
    return m


def run(pipeline: Pipeline, out_dir: str | os.PathLike | None = None,
        progress: Callable[[str], None] | None = None) -> RunResult:
    """Process a survey (module docstring). ``out_dir`` defaults to ``out/`` beside the YAML."""
    say = progress or (lambda _m: None)
    cfg = pipeline.config
    out = Path(out_dir) if out_dir is not None else pipeline.base_dir / "out"
    wall = time.perf_counter()
    timings: dict[str, float] = {}
    tic = time.perf_counter()
    say(f"[{cfg.name}] reading {pipeline.path(cfg.inputs.log)}")
    log = _read(pipeline)
    timings["read_s"] = time.perf_counter() - tic
    tic = time.perf_counter()
    problem, info = build_problem(pipeline, log, say)
    timings["preprocess_s"] = time.perf_counter() - tic
    imu_rate = 1.0 / np.median(np.diff(problem.imu.t_s))
    every = _decimation(imu_rate, cfg.outputs.trajectory_rate_hz)
    sm = cfg.smoother
    if sm.chunk_s is not None and problem.imu.t_s[-1] - problem.imu.t_s[0] > sm.chunk_s + sm.overlap_s:
        from .fusion.chunks import smooth_in_chunks  # long runs: memory bounded by the chunk
        res, dense = smooth_in_chunks(problem, sm.chunk_s, sm.overlap_s, every, say)
        tic, table_every = time.perf_counter(), 1  # dense is already at the output rate
    else:
        res = smooth(problem, say)
        tic, table_every = time.perf_counter(), every
        dense = densify(problem.imu, res.key_idx, res.R_nb, res.pos_n, res.vel_n, res.gyro_bias_radps,
                        res.accel_bias_mps2, geodesy.gravity_n(res.pos_n, problem.origin),
                        geodesy.earth_rate_n(problem.origin) if cfg.factors.imu.earth_rate else np.zeros(3))
    timings.update(res.timings_s)
    say("writing the trajectory at the output rate")
    chainage = chainage_along(dense, res, problem.odometer, problem.trolley.axis_b)
    table = trajectory_table(dense, res, chainage, table_every)
    metrics: dict[str, Any] = {"name": cfg.name, "origin": problem.origin.to_dict(),
                               "imu_samples": int(problem.imu.t_s.size),
                               "duration_s": float(problem.imu.t_s[-1] - problem.imu.t_s[0]),
                               "trajectory_rate_hz": float(imu_rate / every),
                               **_smoother_metrics(res, info)}
    if cfg.inputs.reference is not None:
        from .evaluation.reference import compare_with_reference
        metrics.update(compare_with_reference(table, pipeline.path(cfg.inputs.reference), problem.origin.to_dict()))
    timings["output_s"] = time.perf_counter() - tic
    timings["total_s"] = time.perf_counter() - wall
    metrics["timings_s"] = timings
    metrics["run_time_s"] = timings["total_s"]
    files = write_outputs(out, table, metrics, problem.origin, cfg, dense, every)
    say(f"[{cfg.name}] done in {timings['total_s']:.1f} s: {out}/")
    return RunResult(out, files, metrics, table, res)


def write_outputs(out: Path, table: dict[str, np.ndarray], metrics: dict, origin: geodesy.Origin,
                  cfg: PipelineConfig, dense: DenseTrajectory, every: int) -> list[str]:
    """Write every output into a staging folder beside ``out``, then move each file in."""
    from .sensors.fileio import write_csv_table, write_json_atomic
    from .sensors.fused import write_fused_mcap
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        write_csv_table(stage / "trajectory.csv", table, TRAJECTORY_UNITS, "n", origin.to_dict(), fmt="%.12g",
                        extra={"description": "smoothed trajectory of the IMU origin",
                               "config": cfg.model_dump(mode="json")})
        write_json_atomic(stage / "metrics.json", metrics)
        if cfg.outputs.fused_mcap:
            write_fused_mcap(stage / "fused.mcap", table, origin)
        files = sorted(p.name for p in stage.iterdir())
        out.mkdir(parents=True, exist_ok=True)
        for name in files:
            os.replace(stage / name, out / name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return files


def format_summary(result: RunResult) -> str:
    """A few lines for the terminal: files, sizes, timings and, with a reference, accuracy."""
    m = result.metrics
    t = m["timings_s"]
    lines = [f"wrote {', '.join(result.files)} to {result.out_dir}/",
             f"  {m['imu_samples']} IMU samples, {m['duration_s']:.0f} s, {m['keyframes']} keyframes, "
             f"{sum(m['factors'].values())} factors, {m['iterations']} iterations",
             "  time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in t.items())]
    if m.get("rejected_gnss"):
        lines.append(f"  rejected GNSS fixes: {len(m['rejected_gnss'])}")
    if "relative_accuracy" in m:
        for c in ("vertical", "lateral"):
            ra = m["relative_accuracy"][c]
            lines.append(f"  {c:<9} at 5 m: MSE {ra['mse_at_threshold_mm']:.3f} mm, ADEV {ra['adev_at_threshold_mm']:.3f} mm;"
                         f" absolute RMS {m['absolute_error'][c]['rms_mm']:.2f} mm")
    return "\n".join(lines)
