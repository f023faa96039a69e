"""Pipeline: the YAML a survey is processed with, and ``run`` (``trackfusion run``).

A pipeline YAML (docs/pipeline.md) names the raw log, the origin of ``n``, the vehicle
(trackfusion/vehicles.py), the sensor specifications and lever arms, the factors and their noise, the
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
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Literal, Mapping

import numpy as np
from pydantic import Field, ValidationError, field_validator, model_validator

from . import geodesy
from .errors import ConfigError, FusionError, TrackfusionError, config_error_from_validation
from .yamlio import ConfigFile
from .fusion import faults, input_checks, preprocess
from .fusion.imu_noise import estimate_imu_noise
from .fusion.preintegration import ImuNoise
from .fusion.problem import FusionProblem, GnssFixes, TrolleyFrame  # noqa: F401 (TrolleyFrame: trackfusion.pipeline's)
from .fusion.settings import FactorSettings, KeyframeSettings, SmootherSettings, StaticSettings
from .fusion.densify_forked import densify_forked
from .fusion.trajectory import KeyframeStates
from .fusion.smoother import Preintegrated, SmootherResult, preintegrate_problem, smooth
from .fusion.output_rate import chainage_along, trajectory_table  # noqa: F401 (also trackfusion.pipeline's)
from .geometry_inputs import check_geometry_inputs, geometry_for_run
from .log_read import LogRequest, ReadAhead, read_requested
from .forked import ForkedTasks, can_fork as can_fork_tasks, usable_cpus
from .output_prefetch import OutputPrefetch
from .registration.stations import SETUP_POSITION_SIGMA_MM, StationSetupConfig
from .report.outputs import start_raw_copy, start_table_outputs
from .rotations import quat_from_R
from .sensors.fileio import CsvTableOnDisk
from .sensors.imu import IMU_GRADES, ImuSpec
from .sensors.spill import release_free_memory
from .sensor_use import ClockConfig, decide_sensor_use, summary_lines as sensor_summary_lines
from .sensors.types import InclinometerData, OdometerData, SensorLog
from .strict import StrictModel
from .track.geometry import GeometryConfig
from .vehicles import MAX_SPEED_MPS, TrolleyVehicle, VehicleConfig, error_location, frame_of, vehicle_section

Vec3 = tuple[float, float, float]


class TopicsConfig(StrictModel):
    """The ROS 2 bag topic of each role (docs/log_format.md, "ROS 2 bags"); a role not named
    is found as the bag's only topic of a supported type."""

    imu: str | None = None
    gnss: str | None = None
    odometer: str | None = None


class InputsConfig(StrictModel):
    """``log``: the raw MCAP log or a ROS 2 bag (MCAP, ``.db3``, rosbag2 folder);
    ``reference``: optional truth/reference trajectory CSV to evaluate against;
    ``allow_truncated``: run on the readable part of a damaged log; ``design``: optional design
    alignment (docs/geometry.md); ``topics``: a bag's topics (read as a bag when given);
    ``imu_axes``: where the log's IMU x, y, z point (``flu``, ``frd``, ... or a signed
    permutation matrix; docs/import.md)."""

    log: str
    reference: str | None = None
    allow_truncated: bool = False
    design: str | None = None  # design alignment: YAML (``alignment:``) or LandXML 1.2 (.xml), for geometry
    topics: TopicsConfig | None = None
    imu_axes: str | tuple[tuple[int, int, int], tuple[int, int, int], tuple[int, int, int]] = "flu"

    @field_validator("imu_axes")
    @classmethod
    def _axes(cls, value):
        from .sensors.imu_axes import axes_matrix
        axes_matrix(value)  # raises ValueError: a one-line config error naming inputs.imu_axes
        return value


class OriginConfig(StrictModel):
    lat_deg: float = Field(ge=-90, le=90)
    lon_deg: float = Field(ge=-180, le=360)
    h_m: float = 0.0


#: the older ``trolley:`` section's model (``vehicle: {kind: trolley}``, trackfusion/vehicles.py)
TrolleyConfig = TrolleyVehicle


class ImuConfig(ImuSpec):
    """IMU specification; ``grade: <name>`` starts from a named grade
    (``navigation``, ``navigation-500``, ``fog``, ``mems-tactical``) and other keys override it.
    ``white_noise_tolerance``: the factor within which the datasheet's ARW / VRW are trusted;
    where the static periods' estimate lies outside it, the smoother uses the estimate
    (docs/noise_estimation.md)."""

    white_noise_tolerance: float = Field(1.5, ge=1.0)

    def spec(self) -> ImuSpec:
        """The datasheet part, as :class:`ImuSpec`."""
        return ImuSpec(**self.model_dump(exclude={"white_noise_tolerance"}))

    @model_validator(mode="before")
    @classmethod
    def _grade(cls, data: Any) -> Any:
        if isinstance(data, dict) and "grade" in data:
            data = dict(data)
            grade = data.pop("grade")
            if not isinstance(grade, str) or grade not in IMU_GRADES:
                raise ValueError(f"unknown grade {grade!r} (known: {', '.join(IMU_GRADES)})")
            data = {**IMU_GRADES[grade].model_dump(), **data}
        return data


class GnssConfig(ClockConfig):
    lever_arm_b_m: Vec3


class TotalStationsConfig(StrictModel):
    """Robotic total stations (docs/total_stations.md): the prism lever arm in ``b``; each
    station's set-up (given, or resected from ``control_points`` in ``n``); the instrument's
    precision (angles, distance ``sigma + ppm``) and refraction coefficient; and the priors of
    each station's correction in the fusion: tilt of the vertical axis (the electronic level's
    set-up accuracy), orientation, position of the instrument point, clock drift."""

    prism_lever_arm_b_m: Vec3
    stations: dict[str, StationSetupConfig] = Field(min_length=1)
    control_points: dict[str, Vec3] = {}
    angle_sigma_arcsec: float = Field(0.5, gt=0)
    distance_sigma_mm: float = Field(3.0, gt=0)
    distance_ppm: float = Field(1.5, ge=0)
    refraction_k: float = 0.13
    tilt_sigma_arcsec: float = Field(2.0, gt=0)
    orientation_sigma_arcsec: float = Field(2.0, gt=0)
    position_sigma_mm: float = Field(SETUP_POSITION_SIGMA_MM, gt=0)
    clock_drift_sigma_ppm: float = Field(5.0, gt=0)


class SensorsConfig(StrictModel):
    imu: ImuConfig
    odometer: ClockConfig | None = None
    gnss: GnssConfig | None = None
    inclinometer: ClockConfig | None = None
    total_stations: TotalStationsConfig | None = None


class OutputsConfig(StrictModel):
    """``trajectory_rate_hz``: rows per second of trajectory.csv (at most the IMU rate; the
    nearest whole divisor of it is used); ``fused_mcap``: write the Foxglove-viewable log;
    ``report``: write report.html (docs/report.md)."""

    trajectory_rate_hz: float = Field(100.0, gt=0)
    geometry_step_m: float = Field(0.25, gt=0)
    fused_mcap: bool = True
    report: bool = True


class PipelineConfig(StrictModel):
    name: str = "survey"
    description: str = ""
    inputs: InputsConfig
    origin: OriginConfig | None = None
    vehicle: VehicleConfig  # the older trolley: reads as vehicle: {kind: trolley, ...}
    sensors: SensorsConfig
    factors: FactorSettings = FactorSettings()
    keyframes: KeyframeSettings = KeyframeSettings()
    static: StaticSettings = StaticSettings()
    smoother: SmootherSettings = SmootherSettings()
    outputs: OutputsConfig = OutputsConfig()
    geometry: GeometryConfig = GeometryConfig()

    @model_validator(mode="before")
    @classmethod
    def _vehicle(cls, data: Any) -> Any:
        return vehicle_section(data)


@dataclass
class Pipeline(ConfigFile):
    """A validated pipeline and the folder its relative paths start from."""

    config: PipelineConfig = field(kw_only=True)


def parse_pipeline(data: Any, source: str, base_dir: Path) -> Pipeline:
    """Validate a pipeline mapping; raises :class:`ConfigError` naming ``source`` and the field."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a pipeline must be a mapping of sections")
    _refuse_removed_keys(data, source)
    try:
        config = PipelineConfig.model_validate(data)
    except ValidationError as exc:
        raise config_error_from_validation(_UserPaths(exc, "trolley" in data), source) from None
    pipeline = Pipeline(base_dir, source, config=config)
    _check_inputs(pipeline)
    return pipeline


@dataclass
class _UserPaths:
    """A validation error whose field paths are as written (trackfusion/vehicles.py: error_location)."""

    exc: ValidationError
    wrote_trolley: bool

    def errors(self) -> list[dict]:
        return [{**e, "loc": error_location(e["loc"], self.wrote_trolley)} for e in self.exc.errors()]


#: keys that went away, and what replaced them (docs/pipeline.md "Removed keys")
REMOVED_KEYS = {("smoother", "slow_priors"): "the parallel segments it gave priors to are gone: "
                                            "smoother.part_s solves the run in exact time parts",
                ("factors", "total_stations", "solve"): "the joint solve replaced the two-stage one: "
                                                        "the stations are estimated with the whole trajectory",
                ("keyframes", "spacing_without_wheel_path_s"): "runs in chunks keep the wheel-path factor now, "
                                                               "on keyframes.spacing_s"}


def _refuse_removed_keys(data: dict, source: str) -> None:
    for path, why in REMOVED_KEYS.items():
        node = data
        for key in path[:-1]:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict) and path[-1] in node:
            raise ConfigError(f"{source}: {'.'.join(path)}: removed; {why}")


def load_pipeline(path: str | os.PathLike) -> Pipeline:
    """Read and validate a pipeline YAML (see :func:`parse_pipeline`)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: pipeline file not found")
    from .yamlio import load_yaml
    from .vision.run import is_vision_pipeline, parse_vision_pipeline
    data = load_yaml(p, "pipeline file")
    if is_vision_pipeline(data):  # a camera-laser survey (docs/vision.md): vision/run.py
        return parse_vision_pipeline(data, str(p), p.resolve().parent)
    return parse_pipeline(data, str(p), p.resolve().parent)



def _check_inputs(pipeline: Pipeline) -> None:
    cfg, src = pipeline.config, pipeline.source
    for field_name in ("log", "reference", "design"):
        value = getattr(cfg.inputs, field_name)
        bag_folder = field_name == "log" and (pipeline.path(value) / "metadata.yaml").is_file()  # a rosbag2 folder
        if value is not None and not pipeline.path(value).is_file() and not bag_folder:
            raise ConfigError(f"{src}: inputs.{field_name}: file not found: {pipeline.path(value)}")
    if cfg.factors.total_stations.enabled and cfg.sensors.total_stations is None:
        raise ConfigError(f"{src}: sensors.total_stations: missing (needed by factors.total_stations; "
                          "or set factors.total_stations: false)")
    from .vehicles import check_vehicle_support
    check_vehicle_support(cfg, src)  # factors and geometry the vehicle's kind supports
    check_geometry_inputs(pipeline)  # the design file and the tolerance table
    if cfg.factors.gnss.enabled and "gnss" in cfg.factors.model_fields_set and cfg.sensors.gnss is None:
        raise ConfigError(f"{src}: sensors.gnss: missing (needed by factors.gnss; or set factors.gnss: false)")


# --- running -------------------------------------------------------------------------------------

@dataclass
class RunResult:
    """What a run produced: the output folder, file names, the metrics and the trajectory
    (trajectory.csv columns; for a run smoothed in chunks, read from its trajectory.csv on first
    access, so that a long run's trajectory is never all in memory)."""

    out_dir: Path
    files: list[str]
    metrics: dict[str, Any]
    trajectory: Mapping[str, np.ndarray]
    smoother: SmootherResult


TRAJECTORY_UNITS = {
    "t_s": "s", "e_m": "m", "n_m": "m", "u_m": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
    "ve_mps": "m/s", "vn_mps": "m/s", "vu_mps": "m/s", "chainage_m": "m",
    "sigma_e_m": "m", "sigma_n_m": "m", "sigma_u_m": "m",
    "sigma_roll_rad": "rad", "sigma_pitch_rad": "rad", "sigma_yaw_rad": "rad",
}


def _read(pipeline: Pipeline, say: Callable[[str], None] = lambda _m: None, ahead: ReadAhead | None = None
          ) -> tuple[SensorLog, dict | None]:
    """The log (every topic: the fusion's, and fused.mcap carries them all) and, when
    ``inputs.allow_truncated`` kept the readable part of a damaged file, what was lost (reported
    and listed in ``faults.truncated_log``). ``ahead``: the log read ahead by ``trackfusion run``
    (trackfusion/log_read.py), taken when it was read as this pipeline asks."""
    from .sensors import imu_axes
    cfg = pipeline.config
    request = LogRequest.of(pipeline)
    path = request.path
    log, damage = ahead.take(request, lambda: _output_imports(cfg)) if ahead is not None else read_requested(request)
    if damage is not None:
        readable = ", ".join(f"{k} {v}" for k, v in damage["records_readable"].items()) or "no records"
        say(f"warning: {path} is damaged at byte {damage['byte']} ({damage['reason']}); running on the readable "
            f"part ({readable}) because inputs.allow_truncated is set")
    if log.imu is None or log.imu.t_s.size < 2:
        raise FusionError(f"{path}: the log has no /imu records" + (" before the damage" if damage else ""))
    c_b_s = imu_axes.axes_matrix(cfg.inputs.imu_axes)
    log.imu = imu_axes.to_body(log.imu, c_b_s)
    imu_axes.check_imu_frame(log.imu, str(path), c_b_s, "inputs.imu_axes")
    if cfg.outputs.fused_mcap:  # fused.mcap's clock: a bad survey.epoch_utc refused before the computing
        from .sensors.fused import survey_epoch_ns
        survey_epoch_ns(log.metadata, str(path))
    return log, damage


def _output_imports(cfg: PipelineConfig) -> None:
    """Import what the run's outputs need (the report's figures: matplotlib, about 0.25 s; the
    evaluation against a reference): done while this process waits for the log read ahead
    (trackfusion/log_read.py), not on the run's critical path after the smoothing."""
    if cfg.outputs.report:
        from .report import html  # noqa: F401
        from .report.figures import preload
        preload()
    if cfg.inputs.reference is not None:
        from .evaluation import reference  # noqa: F401


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
    info: dict[str, Any] = {}
    imu_spec = sensors.imu.spec()
    src = str(pipeline.path(cfg.inputs.log))
    used = _checked_sensor_use(pipeline, log, origin, imu_spec, info, say)
    gnss = _gnss_on_imu_clock(log, used, origin, src, info)
    odometer = _odometer_on_imu_clock(log, used, fs, src, info, say) if used.use["odometer"] else None
    static = _static_intervals(cfg, log, odometer, gnss, imu_spec, src, info, say)
    imu_spec = _imu_spec_with_noise_from_data(log, static, imu_spec, sensors.imu, info, say)
    inclinometer = _inclinometer_on_imu_clock(log, used, src, info) if used.use["inclinometer"] else None
    problem = FusionProblem(
        imu=log.imu, imu_noise=ImuNoise.from_spec(imu_spec), imu_gyro_bias_deg_per_h=imu_spec.gyro_bias_deg_per_h,
        origin=origin, trolley=frame_of(cfg.vehicle),
        static_intervals_s=static, factors=fs, keyframes=cfg.keyframes, smoother=cfg.smoother,
        odometer=odometer, gnss=gnss, inclinometer=inclinometer)
    return problem, info


def _checked_sensor_use(pipeline: Pipeline, log: SensorLog, origin: geodesy.Origin, imu_spec: ImuSpec,
                        info: dict, say: Callable[[str], None]):
    """The sensors fused (every switched-on factor's topic in the log, trackfusion/sensor_use.py;
    a :class:`~trackfusion.sensor_use.SensorUse`, said and put in ``info``) after the
    plausibility checks of the whole log (fusion/input_checks.py)."""
    cfg = pipeline.config
    src = str(pipeline.path(cfg.inputs.log))
    used = decide_sensor_use(cfg, log, pipeline.source, src)
    info.update(used.to_json())
    for line in used.defaulted + [f"{u['topic']} in the log, not used: {u['reason']}" for u in used.unused]:
        say(line)
    use = used.use
    aiding = input_checks.AidingSensors(gnss=log.gnss if use["gnss"] else None,
                                        odometer=log.odometer if use["odometer"] else None,
                                        inclinometer=log.inclinometer if use["inclinometer"] else None)
    input_checks.check_log(log.imu, imu_spec, origin, src, pipeline.source, aiding,
                           max_speed_mps=MAX_SPEED_MPS[cfg.vehicle.kind], vehicle=cfg.vehicle.kind)
    return used


def _gnss_on_imu_clock(log: SensorLog, used, origin: geodesy.Origin, src: str, info: dict) -> GnssFixes | None:
    """The used GNSS fixes in ``n`` on the IMU clock, clock jumps corrected (listed in
    ``info["clock_jumps"]``, which this starts); None when GNSS is not used."""
    info["clock_jumps"] = []
    if not used.use["gnss"]:
        return None
    clock = used.clocks["gnss"]
    gnss = GnssFixes.from_data(log.gnss, origin, clock.lever_arm_b_m, clock.clock_offset_s)
    gnss.t_s, jumps = faults.correct_clock_jumps(gnss.t_s, gnss.pos_n, "/gnss", src, noise=0.05)
    info["clock_jumps"] += jumps
    return gnss


def _odometer_on_imu_clock(log: SensorLog, used, fs: FactorSettings, src: str, info: dict,
                           say: Callable[[str], None]) -> OdometerData:
    """The odometer on the IMU clock, clock jumps corrected and gross errors repaired (both in ``info``)."""
    odo = log.odometer
    t = preprocess.sensor_times_to_imu_clock(odo.t_s, used.clocks["odometer"].clock_offset_s)
    t, jumps = faults.correct_clock_jumps(t, odo.distance_m, "/odometer", src, noise=1e-3)
    info["clock_jumps"] += jumps
    odometer, repaired = preprocess.repair_odometer(OdometerData(t, odo.distance_m, odo.ticks),
                                                    window=fs.odometer.gross_error_window,
                                                    threshold_m=fs.odometer.gross_error_threshold_m)
    info["odometer_gross_errors"] = repaired
    say(f"odometer: {odo.t_s.size} records, {len(repaired)} gross errors repaired")
    return odometer


def _static_intervals(cfg: PipelineConfig, log: SensorLog, odometer: OdometerData | None, gnss: GnssFixes | None,
                      imu_spec: ImuSpec, src: str, info: dict, say: Callable[[str], None]) -> list[tuple[float, float]]:
    """The static intervals [(start, end)] [s] from the IMU (and odometer), less those the GNSS
    fixes show moving; then the gyro's units checked on them (rad/s, not deg/s, at rest)."""
    st = cfg.static
    imu_rate_hz = 1.0 / float(np.median(np.diff(log.imu.t_s)))
    gyro_thr, accel_thr = st.thresholds(imu_spec.gyro_arw_deg_per_sqrt_h, imu_spec.accel_vrw_mps_per_sqrt_h,
                                        imu_rate_hz)
    static = preprocess.detect_static_intervals(
        log.imu, odometer, window_s=st.window_s, gyro_std_radps=np.radians(gyro_thr),
        accel_std_mps2=accel_thr, max_odometer_speed_mps=st.max_odometer_speed_mps,
        min_duration_s=st.min_duration_s)
    if gnss is not None:  # an IMU cannot tell constant speed from rest; the fixes can
        sigma_m = np.sqrt(np.diagonal(gnss.cov_n, axis1=1, axis2=2))
        moving = preprocess.moving_intervals_by_gnss(static, gnss.t_s, gnss.pos_n, sigma_m)
        info["static_intervals_moving_by_gnss_s"] = [[float(a), float(b)] for a, b in (static[i] for i in moving)]
        static = [iv for i, iv in enumerate(static) if i not in moving]
    info["static_intervals_s"] = [[float(a), float(b)] for a, b in static]
    input_checks.check_static_gyro_units(log.imu, imu_spec, static + input_checks.odometer_rest_intervals(odometer),
                                         src)
    say(f"static intervals: {len(static)} ({sum(b - a for a, b in static):.0f} s)")
    return static


def _imu_spec_with_noise_from_data(log: SensorLog, static: list[tuple[float, float]], imu_spec: ImuSpec,
                                   imu_cfg, info: dict, say: Callable[[str], None]) -> ImuSpec:
    """The IMU noise estimated from the static data (reported in ``info["noise_estimates"]``
    beside the datasheet's ``imu_cfg``) and the specification the smoother uses: the datasheet's,
    with the estimate where :func:`_imu_spec_from_data` says so."""
    imu_noise = estimate_imu_noise(log.imu, static, imu_spec)
    if imu_noise is None:
        return imu_spec
    info["noise_estimates"] = {"imu": imu_noise.to_json()}
    say(imu_noise.summary())
    imu_spec, replaced = _imu_spec_from_data(imu_spec, imu_noise, imu_cfg.white_noise_tolerance)
    info["noise_estimates"]["imu"]["used"] = replaced
    for key in replaced:
        say(f"sensors.imu.{key}: the static data give {getattr(imu_spec, key):.3g}, outside the datasheet's "
            f"{getattr(imu_cfg, key):.3g} x/ {imu_cfg.white_noise_tolerance:g} "
            "(sensors.imu.white_noise_tolerance): the smoother uses the estimate")
    return imu_spec


def _inclinometer_on_imu_clock(log: SensorLog, used, src: str, info: dict) -> InclinometerData:
    """The inclinometer on the IMU clock, clock jumps corrected (in ``info["clock_jumps"]``)."""
    inc = log.inclinometer
    t = preprocess.sensor_times_to_imu_clock(inc.t_s, used.clocks["inclinometer"].clock_offset_s)
    t, jumps = faults.correct_clock_jumps(t, np.zeros(t.size), "/inclinometer", src, noise=1.0)
    info["clock_jumps"] += jumps
    return InclinometerData(t, inc.roll_rad, inc.pitch_rad)


#: an IMU noise estimate below this fraction of the datasheet's is no sensor's but a noise-free log's
NOISE_FREE_RATIO = 1e-3


def _imu_spec_from_data(spec: ImuSpec, est, tolerance: float) -> tuple[ImuSpec, list[str]]:
    """``spec`` with the white-noise densities the static data estimate (``est``, an
    :class:`~trackfusion.fusion.imu_noise.ImuNoiseEstimate`) where they differ from the
    datasheet by more than the factor ``tolerance`` (not below :data:`NOISE_FREE_RATIO` of it);
    returns it and the keys replaced."""
    replaced = {}
    for key in ("gyro_arw_deg_per_sqrt_h", "accel_vrw_mps_per_sqrt_h"):
        term = est.terms()[key]
        ratio = term.ratio()
        if term.value is None or (ratio is not None and ratio < NOISE_FREE_RATIO):
            continue  # no noise in the static data (a noise-free, simulated log): the datasheet stays
        if ratio is None or not 1.0 / tolerance <= ratio <= tolerance:
            replaced[key] = term.value
    return (spec.model_copy(update=replaced) if replaced else spec), sorted(replaced)


# --- total stations --------------------------------------------------------------------------------

def _prepare_total_stations(pipeline: Pipeline, log: SensorLog, problem: FusionProblem,
                            say: Callable[[str], None]):
    """Set-ups, readings to ``n`` and time synchronisation; returns the problem with its prism
    readings and the :class:`~trackfusion.registration.survey.PrismSurvey` (None when off)."""
    if not pipeline.config.factors.total_stations.enabled:
        return problem, None
    return _with_survey(problem, _survey(pipeline, log, problem), say)


def _survey(pipeline: Pipeline, log: SensorLog, problem: FusionProblem):
    """:func:`~trackfusion.registration.survey.prepare_prisms` of the run (errors name the log)."""
    from .errors import RegistrationError
    from .registration.survey import prepare_prisms
    cfg = pipeline.config
    try:
        return prepare_prisms(log.total_stations, cfg.sensors.total_stations, cfg.factors.total_stations,
                              problem.origin, problem.odometer)
    except RegistrationError as exc:
        raise RegistrationError(f"{pipeline.path(cfg.inputs.log)}: {exc}") from None


def _with_survey(problem: FusionProblem, survey, say: Callable[[str], None]) -> tuple[FusionProblem, Any]:
    for sid, st in survey.stations.items():
        how = f"r_max {st.sync.r_max:.3f}" if st.sync is not None else "given"
        say(f"total station {sid}: {st.t_s.size} readings, clock offset {st.offset_s:+.4f} s ({how})")
    return replace(problem, prisms=survey.readings), survey


def _prepare_and_preintegrate(pipeline: Pipeline, log: SensorLog, problem: FusionProblem,
                              say: Callable[[str], None]) -> tuple[FusionProblem, Any, Preintegrated | None]:
    """:func:`_prepare_total_stations` in a forked child while this process preintegrates the IMU
    for the smoother (the two are independent; the survey's arrays come back through a pipe,
    GTSAM's preintegrated measurements could not). Returns (problem, survey, preintegrated);
    ``preintegrated`` is None without total stations or where forking is not possible, and the
    smoother then preintegrates itself. The stations' errors come first, as in turn."""
    if not pipeline.config.factors.total_stations.enabled or not can_fork_tasks():
        return (*_prepare_total_stations(pipeline, log, problem, say), None)
    with ForkedTasks(always_fork=True) as child:
        task = child.submit("preparing the total stations", _survey, pipeline, log, problem)
        say(f"preintegrating {problem.imu.t_s.size} IMU samples while the total stations are prepared")
        try:
            pre = preintegrate_problem(problem)
        except Exception:  # noqa: BLE001 (the smoother preintegrates again and raises it, after the stations')
            pre = None
        survey = task.result()
    return (*_with_survey(problem, survey, say), pre)


def _total_station_metrics(survey, res: SmootherResult, problem: FusionProblem, table: dict[str, np.ndarray],
                           cfg: PipelineConfig) -> dict[str, Any]:
    """``time_sync``, ``registration``, ``rejected_prism`` and ``round_trip`` of metrics.json."""
    from .registration.survey import corrected_points, registration_report, round_trip
    fs = cfg.factors.total_stations
    states = res.station_states if res.station_states is not None else np.zeros((len(survey.stations), 8))
    time_sync = {}
    for j, (sid, st) in enumerate(survey.stations.items()):
        q = states[j]
        entry = st.sync.to_json() if st.sync is not None else {"r_max": None, "lags_s": [], "r": []}
        entry.update(offset_s=st.offset_s + float(q[6]), drift_ppm=float(q[7]), offset_correlation_s=st.offset_s)
        time_sync[sid] = entry
    ids = list(survey.stations)
    rejected = []
    for r in res.rejected_prism:  # on the IMU clock with the refined clock offset and drift
        q = states[ids.index(r["station"])]
        rejected.append({**r, "t_s": r["t_s"] - float(q[6]) - 1e-6 * float(q[7]) * r["t_s"]})
    out: dict[str, Any] = {"time_sync": time_sync, "rejected_prism": rejected}
    odo = problem.odometer
    if odo is not None:
        out["registration"] = registration_report(survey, res.station_states, odo, fs.registration, problem.origin,
                                                  res.station_cov)
        before_t, before_p = [], []
        for j, st in enumerate(survey.stations.values()):
            t, p = corrected_points(st, states[j])
            before_t.append(t)
            before_p.append(p)
        t = np.concatenate(before_t)
        order = np.argsort(t)
        t = t[order]
        try:
            out["round_trip"] = {
                "before_fusion": round_trip(t, np.concatenate(before_p)[order], np.interp(t, odo.t_s, odo.distance_m)),
                "after_fusion": round_trip(table["t_s"], np.column_stack([table["e_m"], table["n_m"], table["u_m"]]),
                                           table["chainage_m"])}
        except TrackfusionError as exc:
            out["round_trip"] = {"error": str(exc)}
    return out


def _smooth_and_densify(problem: FusionProblem, cfg, say: Callable[[str], None],
                        preintegrated: Preintegrated | None = None):
    """One batch by :func:`smooth` (``preintegrated``: see there) and its rows at the IMU rate,
    densified once the smoother (with its marginals, which use every CPU) is done, in parts on
    the CPUs this process may use, this process one of them (fusion/densify_forked.py; the same
    rows as one densify call). Returns (result, dense); the result's
    ``timings_s["densify_wait_s"]``: the wall time of the densification.

    After the marginals, not beside them: three processes on two cores cost more than they
    overlapped (the 53 min bridge, back to back: marginals and densification 9.8 s in turn
    against 10.7-11.1 s beside each other; docs/solver_speed.md)."""
    earth_rate_n = geodesy.earth_rate_n(problem.origin) if cfg.factors.imu.earth_rate else np.zeros(3)
    res = smooth(problem, say, preintegrated=preintegrated)
    tic = time.perf_counter()
    dense = densify_forked(problem.imu, KeyframeStates.of(res, problem.origin), earth_rate_n, usable_cpus())
    res.timings_s["densify_wait_s"] = time.perf_counter() - tic
    return res, dense


def _decimation(imu_rate_hz: float, rate_hz: float) -> int:
    return max(1, int(round(imu_rate_hz / rate_hz)))


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
    if res.gnss_noise is not None:  # the GNSS white noise from the residuals (fusion/gnss_noise.py)
        m["noise_estimates"] = {**m.get("noise_estimates", {}), "gnss": res.gnss_noise.to_json()}
    if res.noise_components is not None:  # every other group's noise (fusion/noise_components.py)
        m["noise_estimates"] = {**m.get("noise_estimates", {}), **res.noise_components["groups"],
                                "components": {k: v for k, v in res.noise_components.items() if k != "groups"}}
    if res.gnss_time_constant is not None:  # the GNSS correlated time constant (fusion/gnss_time_constant.py)
        m["noise_estimates"] = {**m.get("noise_estimates", {}), "gnss_time_constant": res.gnss_time_constant}
    if res.odometer_scale is not None:
        m["odometer_scale_ppm"] = _odometer_scale_figures(res.t_s, res.odometer_scale)
    return m


def _odometer_scale_figures(t_s: np.ndarray, scale: np.ndarray) -> dict:
    """The odometer scale error over the keyframes (K,) at times ``t_s`` (K,) [s]: its mean, first
    and last [ppm], and its drift [ppm/h], the least-squares slope over the run."""
    hours = (t_s - t_s.mean()) / 3600.0
    span = float(hours @ hours)
    return {"mean": float(scale.mean() * 1e6), "first": float(scale[0] * 1e6), "last": float(scale[-1] * 1e6),
            "drift_ppm_per_h": float(hours @ (scale - scale.mean()) * 1e6 / span) if span > 0 else 0.0}


def run(pipeline: Pipeline, out_dir: str | os.PathLike | None = None,
        progress: Callable[[str], None] | None = None, force: bool = False,
        read_ahead: ReadAhead | None = None) -> RunResult:
    """Process a survey (module docstring). ``out_dir`` defaults to ``out/`` beside the YAML;
    it is checked and locked before anything read is used (:class:`~trackfusion.outdir.OutputFolder`;
    ``force``: write beside files trackfusion did not write). ``read_ahead``: the log as
    ``trackfusion run`` began reading it before the pipeline was validated (trackfusion/log_read.py;
    taken when it is the log this pipeline reads)."""
    from .outdir import OutputFolder
    from .vision.run import VisionPipeline, run_vision
    if isinstance(pipeline, VisionPipeline):
        return run_vision(pipeline, out_dir, progress, force)
    out = Path(out_dir) if out_dir is not None else pipeline.base_dir / "out"
    folder = OutputFolder(out, force, inputs=input_paths(pipeline), command="trackfusion run", writes=RUN_FILES)
    with folder.locked():
        return _run(pipeline, folder, progress, read_ahead)


#: the files a run may write into its output folder
RUN_FILES = ("trajectory.csv", "trajectory.json", "metrics.json", "geometry.csv", "geometry.json", "fused.mcap",
             "report.html")


def input_paths(pipeline: Pipeline) -> list[Path]:
    """The files a run reads: the YAML, the log, the reference, the design and the tolerance table."""
    cfg = pipeline.config
    paths = [Path(pipeline.source)] + [pipeline.path(v) for v in (cfg.inputs.log, cfg.inputs.reference,
                                                                   cfg.inputs.design) if v is not None]
    tolerances = getattr(cfg.geometry, "tolerances", None)
    if isinstance(tolerances, str):
        paths.append(pipeline.path(tolerances))
    return paths


def _run(pipeline: Pipeline, folder, progress: Callable[[str], None] | None = None,
         read_ahead: ReadAhead | None = None) -> RunResult:
    """:func:`run` in its locked output folder (an :class:`~trackfusion.outdir.OutputFolder`):
    read, preprocess, smooth (in chunks or one batch), metrics, track geometry, evaluation
    against the reference, outputs; each a step of its own."""
    say = progress or (lambda _m: None)
    cfg = pipeline.config
    out = folder.path
    wall = tic = time.perf_counter()
    timings: dict[str, float] = {}
    say(f"[{cfg.name}] reading {pipeline.path(cfg.inputs.log)}")
    log, damage = _read(pipeline, say, read_ahead)
    release_free_memory()  # the reader's garbage
    timings["read_s"] = time.perf_counter() - tic
    tic = time.perf_counter()
    problem, info = build_problem(pipeline, log, say)
    found = {"truncated_log": damage, "clock_jumps": info.pop("clock_jumps"),
             "odometer_gross_errors": info.get("odometer_gross_errors")}
    problem, survey, preintegrated = _prepare_and_preintegrate(pipeline, log, problem, say)
    if survey is not None:  # total-station clock jumps (registration/clock_jumps.py)
        found["clock_jumps"] += survey.info["clock_jumps"]
    timings["preprocess_s"] = time.perf_counter() - tic
    imu_rate = 1.0 / np.median(np.diff(problem.imu.t_s))
    every = _decimation(imu_rate, cfg.outputs.trajectory_rate_hz)
    duration_s = float(problem.imu.t_s[-1] - problem.imu.t_s[0])
    chunked = _in_chunks(pipeline, problem, duration_s, info)
    with folder.staging() as stage, ForkedTasks() as background:  # background: outputs written in forked children
        raw_copy = start_raw_copy(background, stage, log, cfg) if not chunked else None  # (report/outputs.py)
        with _trajectory_writer(stage / "trajectory.csv", problem.origin, cfg) as writer:
            prefetch = OutputPrefetch(pipeline.path(cfg.inputs.reference) if cfg.inputs.reference else None)
            if chunked:  # memory bounded by the chunk (docs/long_runs.md); rebound: no reference keeps the IMU read
                problem, spilled = _with_spilled_imu(problem, log, stage)
                smoothed = _smooth_chunked(problem, spilled, stage, every, imu_rate, writer, cfg, say)
            else:
                smoothed = _smooth_one_batch(problem, cfg, say, preintegrated, every, writer, prefetch, background)
        res, table = smoothed.res, smoothed.table
        timings.update(res.timings_s)
        metrics: dict[str, Any] = {"name": cfg.name, "origin": problem.origin.to_dict(),
                                   "imu_samples": int(problem.imu.t_s.size),
                                   "duration_s": duration_s, "trajectory_rate_hz": float(imu_rate / every),
                                   **_smoother_metrics(res, info),
                                   "faults": faults.detected_faults(problem, res, found)}
        if survey is not None:
            metrics.update(_total_station_metrics(survey, res, problem, table, cfg))
        geometry = _geometry_step(pipeline, problem, smoothed, log, metrics, timings, say)
        # --- outputs of the tables alone, in a forked child while the evaluation goes on (report/outputs.py) ---
        early = start_table_outputs(background, stage, table, problem.origin, cfg, geometry, log,
                                    raw_copy) if table is not None else None
        smoothed.release_geometry_rows()
        if cfg.inputs.reference is not None:
            say(f"evaluating against the reference {pipeline.path(cfg.inputs.reference)}")
            from .evaluation.reference import compare_with_reference
            metrics.update(compare_with_reference(smoothed.evaluation_table, pipeline.path(cfg.inputs.reference),
                                                  problem.origin.to_dict(), prefetch.reference()))
        timings["output_s"] = time.perf_counter() - smoothed.output_tic
        timings["total_s"] = time.perf_counter() - wall
        metrics["timings_s"] = timings
        metrics["run_time_s"] = timings["total_s"]
        say("writing the outputs" + ", fused.mcap" * cfg.outputs.fused_mcap + ", report.html" * cfg.outputs.report)
        files = write_outputs(stage, out, metrics, problem.origin, cfg,
                              OutputSources(table, geometry, log, smoothed.fused_table, early, background, raw_copy))
    say(f"[{cfg.name}] done in {timings['total_s']:.1f} s: {out}/")
    return RunResult(out, files, metrics, table if table is not None else CsvTableOnDisk(out / "trajectory.csv"), res)


@dataclass
class _Smoothed:
    """A run's smoothed trajectory and what the later steps read of it.

    res: the keyframe result; table: the whole trajectory.csv table, or None when it is only on
    disk (a run in chunks); evaluation_table: the rows compared with the reference (or None);
    fused_table: the rows fused.mcap shows when not ``table`` (a long run's, thinned);
    dense, chainage_m, geometry_imu: what the track geometry reads (the IMU-rate rows, their
    chainage [m] and, for a run in chunks, the IMU samples read back); kept: the spill arrays
    holding a long run's geometry rows; output_tic: ``time.perf_counter()`` at which the output
    step began (``timings_s.output_s``)."""

    res: SmootherResult
    table: dict[str, np.ndarray] | None
    evaluation_table: dict[str, np.ndarray] | None
    fused_table: dict[str, np.ndarray] | None
    dense: Any
    chainage_m: np.ndarray | None
    geometry_imu: Any
    kept: Any
    output_tic: float

    def release_geometry_rows(self) -> None:
        """Drop the rows only the track geometry reads (memory of a long run)."""
        self.dense = self.chainage_m = self.geometry_imu = None
        if self.kept is not None:
            self.kept.release()  # the geometry's rows, read back for it


def _in_chunks(pipeline: Pipeline, problem: FusionProblem, duration_s: float, info: dict | None = None) -> bool:
    """Whether the run is smoothed in chunks (``smoother.chunk_s``: longer than
    ``SmootherSettings.one_batch_up_to_s``), said in ``info["smoothing"]`` (metrics.json's,
    :func:`_smoothing_metrics`); a total-station run too long for one batch is refused."""
    cfg = pipeline.config
    limit_s = cfg.smoother.one_batch_up_to_s(cfg.keyframes.spacing_s)
    chunked = limit_s is not None and duration_s > limit_s
    if chunked and problem.prisms is not None:  # station correction states are not handed over between chunks
        raise ConfigError(f"{pipeline.source}: smoother.chunk_s: total-station runs are smoothed in one "
                          f"batch, and this run lasts {duration_s:.0f} s; set smoother.chunk_s to at least "
                          f"{np.ceil(duration_s):.0f} (or null)")
    if info is not None:
        info["smoothing"] = _smoothing_metrics(cfg.smoother, problem.imu.t_s, limit_s, chunked)
    return chunked


def _smoothing_metrics(sm: SmootherSettings, t_s: np.ndarray, limit_s: float | None, chunked: bool
                       ) -> dict[str, Any]:
    """metrics.json's ``smoothing``: whether the run of IMU times ``t_s`` (N,) [s] was one batch, the
    longest run that would be (``limit_s`` [s], ``one_batch_up_to_s``; None: any) and, in chunks, the
    chunk and overlap [s], the first IMU time ``start_s`` and the join times ``joins_s`` [s] (IMU clock)."""
    out: dict[str, Any] = {"one_batch": not chunked, "chunk_s": sm.chunk_s, "one_batch_up_to_s": limit_s}
    if chunked:
        from .fusion.chunks import join_times
        out.update(chunk_length_s=sm.chunk_length_s, overlap_s=sm.chunk_overlap_s, start_s=float(t_s[0]),
                   joins_s=join_times(float(t_s[0]), float(t_s[-1]), sm.chunk_length_s, sm.chunk_overlap_s).tolist())
    return out


def _with_spilled_imu(problem: FusionProblem, log: SensorLog, stage: Path):
    """The problem with its IMU spilled to ``stage`` and read back chunk by chunk (``log.imu`` too),
    and the :class:`~trackfusion.sensors.spill.SpilledImu` holding it. The caller must drop its
    own reference to ``problem``: the arrays in memory go with the last one (the caller's kept
    them alive through the whole smoothing before: 144 MB on a 20 km survey at 500 Hz)."""
    from .sensors.spill import SpilledImu
    spilled = SpilledImu(problem.imu, stage)
    log.imu = spilled.imu
    return replace(problem, imu=spilled.imu), spilled


def _smooth_chunked(problem: FusionProblem, spilled, stage: Path, every: int, imu_rate_hz: float, writer,
                    cfg: PipelineConfig, say: Callable[[str], None]) -> _Smoothed:
    """A long run smoothed in chunks with its memory bounded by the chunk (its IMU ``spilled`` to
    ``stage`` by :func:`_with_spilled_imu`), the rows written by ``writer`` as each chunk is done,
    the geometry's rows kept on disk."""
    from .sensors.spill import SpillArrays
    release_free_memory()  # the IMU arrays and preprocessing's temporaries
    kept = SpillArrays(stage)  # the rows the geometry reads at the end

    def after_chunk():
        spilled.release()
        kept.release()

    res, stream = _smooth_streamed(problem, every, imu_rate_hz, writer.write, cfg, say, after_chunk, kept.empty)
    tic = time.perf_counter()
    dense, chainage, geometry_imu = stream.geometry_input() if stream.geometry is not None else (None,) * 3
    fused_table = stream.thinned.columns() if stream.thinned is not None else None
    evaluation_table = stream.evaluation.columns() if stream.evaluation is not None else None
    return _Smoothed(res, None, evaluation_table, fused_table, dense, chainage, geometry_imu, kept, tic)


def _smooth_one_batch(problem: FusionProblem, cfg: PipelineConfig, say: Callable[[str], None],
                      preintegrated: Preintegrated | None, every: int, writer, prefetch: OutputPrefetch,
                      background: ForkedTasks) -> _Smoothed:
    """One batch (its steps in exact time parts with smoother.part_s, fusion/partitioned.py), the
    reference read meanwhile on the CPU the solve leaves idle (output_prefetch.py); the rows at
    the output rate handed to ``writer`` (formatted in a forked child of ``background``)."""
    prefetch.read_in_child(background)
    res, dense = _smooth_and_densify(problem, cfg, say, preintegrated)  # fusion/densify_forked.py
    tic = time.perf_counter()
    say("writing the trajectory at the output rate")
    chainage = chainage_along(dense, res, problem.odometer, problem.trolley.axis_b)
    table = trajectory_table(dense, res, chainage, every)
    writer.write(table, background)  # formatted in a forked child (trackfusion/forked.py)
    return _Smoothed(res, table, table, None, dense, chainage, None, None, tic)


def _geometry_step(pipeline: Pipeline, problem: FusionProblem, smoothed: _Smoothed, log: SensorLog, metrics: dict,
                   timings: dict, say: Callable[[str], None]):
    """The track geometry (geometry.csv's table and ``metrics["geometry"]``,
    :func:`~trackfusion.geometry_inputs.geometry_for_run`), or None when it is off."""
    tic_geometry = time.perf_counter()
    if pipeline.config.geometry.enabled:
        say("computing the track geometry")
    imu_problem = problem if smoothed.geometry_imu is None else replace(problem, imu=smoothed.geometry_imu)
    geometry = geometry_for_run(pipeline, imu_problem, smoothed.res, smoothed.dense, smoothed.chainage_m, log.gauge)
    if geometry is not None:
        metrics["geometry"] = geometry.metrics
        timings["geometry_s"] = time.perf_counter() - tic_geometry  # (also inside output_s)
    return geometry


def _smooth_streamed(problem: FusionProblem, every: int, imu_rate_hz: float, sink: Callable[[dict], None],
                     cfg: PipelineConfig, say: Callable[[str], None], after_chunk: Callable[[], None],
                     empty: Callable[[tuple], np.ndarray] = np.empty):
    """A long run smoothed in chunks (``smoother.chunk_s``, fusion/chunks.py), each chunk's
    trajectory.csv rows handed to ``sink`` as soon as it is done (then ``after_chunk()``; the kept
    rows in arrays from ``empty(shape)``); returns
    the keyframe result and the :class:`~trackfusion.fusion.output_rate.StreamedTrajectory`
    with what the geometry, the reference evaluation and fused.mcap need of the rows."""
    from .fusion.chunks import smooth_in_chunks
    from .fusion.output_rate import StreamedTrajectory
    from .sensors.fused import FUSED_POSE_RATE_HZ
    thin_every = max(1, int(round(imu_rate_hz / (FUSED_POSE_RATE_HZ * every))))
    stream = StreamedTrajectory(problem.odometer, problem.trolley.axis_b, sink, problem.imu.t_s.size // every + 1,
                                thin_every if cfg.outputs.fused_mcap else None,
                                keep_evaluation=cfg.inputs.reference is not None,
                                imu=problem.imu if cfg.geometry.enabled else None, empty=empty)

    def on_dense(piece, so_far, last):
        stream.add(piece, so_far, last)
        after_chunk()
        release_free_memory()  # the chunk's graph and temporaries

    say("writing the trajectory at the output rate as each chunk is done")
    sm = cfg.smoother
    res, _ = smooth_in_chunks(problem, sm.chunk_length_s, sm.chunk_overlap_s, every, say, on_dense=on_dense)
    return res, stream


def _trajectory_writer(path: Path, origin: geodesy.Origin, cfg: PipelineConfig):
    """trajectory.csv + sidecar, written block by block (:class:`~trackfusion.sensors.fileio.CsvTableWriter`)."""
    from .sensors.fileio import CsvTableWriter
    return CsvTableWriter(path, list(TRAJECTORY_UNITS), TRAJECTORY_UNITS, "n", origin.to_dict(), fmt="%.12g",
                          extra={"description": "smoothed trajectory of the IMU origin",
                                 "config": cfg.model_dump(mode="json")})


@dataclass
class OutputSources:
    """What :func:`write_outputs` writes from. ``table``: the whole trajectory.csv table, or
    None when it is only on disk (a run in chunks); ``geometry``: the track geometry or None;
    ``raw``: the input log as read, whose topics fused.mcap carries; ``fused_table``: the
    trajectory rows fused.mcap shows when not ``table`` (a long run's rows at
    :data:`~trackfusion.sensors.fused.FUSED_POSE_RATE_HZ`); ``early``: the forked task already
    writing geometry.csv and drawing the table figures, fused.mcap in another
    (:func:`~trackfusion.report.outputs.start_table_outputs`);
    ``background``: the run's forked tasks, all waited for (and their failures raised) before
    the files are listed; ``raw_copy``: the task that began fused.mcap's copy of ``raw``
    (:func:`~trackfusion.report.outputs.start_raw_copy`; None: none)."""

    table: dict[str, np.ndarray] | None
    geometry: Any = None
    raw: SensorLog | None = None
    fused_table: dict[str, np.ndarray] | None = None
    early: Any = None
    background: ForkedTasks | None = None
    raw_copy: Any = None


def write_outputs(stage: Path, out: Path, metrics: dict, origin: geodesy.Origin, cfg: PipelineConfig,
                  src: OutputSources) -> list[str]:
    """Write the outputs but trajectory.csv into the staging folder ``stage`` (:meth:`~trackfusion.outdir.OutputFolder.staging`;
    ``out`` is the folder they go to) from ``src``; returns the names of all staged files."""
    table, geometry, early = src.table, src.geometry, src.early
    from .report.outputs import write_table_outputs
    from .sensors.fileio import write_json_atomic
    tic_write = time.perf_counter()  # timings_s.write_s
    write_json_atomic(stage / "metrics.json", metrics)
    # --- geometry.csv, Foxglove log and report, from the staged files (report last) ---
    if early is None:
        images = write_table_outputs(stage, table if src.fused_table is None else src.fused_table, origin, cfg,
                                     geometry, src.raw, raw_copy=src.raw_copy)
    else:  # the metrics' figures drawn here while the child may still be drawing the tables'
        from .report.html import metrics_images
        from .sensors.fileio import read_json
        drawn = metrics_images(read_json(stage / "metrics.json")) if cfg.outputs.report else {}
        images = {**early.result(), **drawn}
    if cfg.outputs.report:
        from .report.html import write_report
        tables = {**({"trajectory.csv": table} if table is not None else {}),  # no re-parsing of these CSVs
                  **({"geometry.csv": geometry.table} if geometry is not None else {})}
        write_report(stage, stage / "report.html", shown_dir=out, tables=tables, images=images)
    if src.background is not None:
        src.background.wait()  # trajectory.csv's rows (renamed into the stage when written)
    # --- end of the staged outputs ---
    # metrics.json once more, last, with the time the writing took
    timings = metrics.setdefault("timings_s", {})
    timings["write_s"] = time.perf_counter() - tic_write
    timings["wall_s"] = timings.get("total_s", 0.0) + timings["write_s"]
    write_json_atomic(stage / "metrics.json", metrics)
    return sorted(p.name for p in stage.iterdir())


def format_summary(result: RunResult) -> str:
    """A few lines for the terminal: files, sizes, timings and, with a reference, accuracy."""
    m = result.metrics
    if "vision" in m:
        from .vision.run import format_vision_summary
        return format_vision_summary(result)
    t = m["timings_s"]
    lines = [f"wrote {', '.join(result.files)} to {result.out_dir}/",
             f"  {m['imu_samples']} IMU samples, {m['duration_s']:.0f} s, {m['keyframes']} keyframes, "
             f"{sum(m['factors'].values())} factors, {m['iterations']} iterations",
             "  time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in t.items())]
    lines += sensor_summary_lines(m)  # sensors used with defaults, sensors not used
    if m.get("rejected_gnss"):
        lines.append(f"  rejected GNSS fixes: {len(m['rejected_gnss'])}")
    gnss_noise = m.get("noise_estimates", {}).get("gnss")
    if gnss_noise:  # fusion/gnss_noise.py
        st, est = gnss_noise["stated_white_sigma_mm"], gnss_noise["estimated_white_sigma_mm"]
        applied = gnss_noise["applied_variance_factor"]
        lines.append(f"  GNSS white sigma: stated {st[0]:.1f}/{st[2]:.1f} mm, from the residuals "
                     f"{est[0]:.1f}/{est[2]:.1f} mm (horizontal/vertical; variance factor applied "
                     f"{applied['horizontal']:.2f}/{applied['vertical']:.2f})")
    if m.get("faults"):  # data faults: docs/robustness.md
        lines.append("  data faults: " + ", ".join(f"{k} {v['count']}" if "count" in v else k
                                                  for k, v in m["faults"].items()))
        lines += faults.summary_lines(m["faults"])
        if "missing_static_period" in m["faults"]:
            miss = m["faults"]["missing_static_period"]
            lines.append(f"  no static period at the {' and '.join(miss['at'])}: {miss['action']}")
    for sid, ts in m.get("time_sync", {}).items():  # total stations
        est = m.get("registration", {}).get("stations", {}).get(sid, {})
        r = f"r_max {ts['r_max']:.3f}" if ts.get("r_max") is not None else "offset given"
        lines.append(f"  station {sid}: clock offset {ts['offset_s']:+.4f} s ({r}), drift {ts['drift_ppm']:+.2f} ppm"
                     + (f", tilt {est['tilt_arcsec'][0]:+.2f}/{est['tilt_arcsec'][1]:+.2f}\"" if est else ""))
    if m.get("rejected_prism"):
        lines.append(f"  rejected prism readings: {len(m['rejected_prism'])}")
    if "relative_accuracy" in m:
        for c in ("vertical", "lateral"):
            ra = m["relative_accuracy"][c]
            lines.append(f"  {c:<9} at 5 m: MSE {ra['mse_at_threshold_mm']:.3f} mm, ADEV {ra['adev_at_threshold_mm']:.3f} mm;"
                         f" absolute RMS {m['absolute_error'][c]['rms_mm']:.2f} mm")
    return "\n".join(lines)
