"""Simulated surveys: from a scenario config to a raw log, truth files and a pipeline.

``simulate(config, seed, ideal)`` builds the track (design + irregularities),
drives the trolley along it, samples every sensor from the truth and returns
a :class:`Simulation` in memory; :func:`simulate_to_dir` writes ``log.mcap``,
``truth.csv`` (+ ``truth.json``), ``geometry_truth.csv`` (+ sidecar) and
``pipeline.yaml``. The same seed gives byte-identical files: each sensor draws
from its own random stream (``numpy.random.SeedSequence(seed).spawn``), so
switching one sensor off does not change the others' errors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml
from pydantic import ValidationError

from .. import geodesy
from ..errors import ConfigError, config_error_from_validation
from ..rotations import quat_from_R, ypr_from_R
from ..sensors.imu import IMU_GRADES, ImuSpec
from ..sensors.types import SensorLog
from ..track.design import DesignAlignment
from ..track.rails import TrackModel
from . import aiding
from .config import ScenarioConfig, load_scenario
from .imu import simulate_imu
from .irregularity import IrregularitySpec, synthesize
from .motion import Hold, MotionProfile, Move, compile_plan
from .trolley import TrolleyGeometry, TrolleyKinematics

#: Random streams, in a fixed order (append new ones at the end to keep old seeds' draws).
_STREAMS = ("irregularities", "imu", "odometer", "gnss", "total_stations", "inclinometer", "gauge", "station_setups")

TRUTH_COLUMNS = {
    "t_s": "s", "e_m": "m", "n_m": "m", "u_m": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
    "ve_mps": "m/s", "vn_mps": "m/s", "vu_mps": "m/s", "chainage_m": "m",
}
GEOMETRY_COLUMNS = {
    "chainage_m": "m", "left_e_m": "m", "left_n_m": "m", "left_u_m": "m",
    "right_e_m": "m", "right_n_m": "m", "right_u_m": "m",
}


@dataclass
class Simulation:
    """A simulated survey in memory.

    ``log``: the raw sensor log; ``truth``: column name -> (N,) array (``TRUTH_COLUMNS``);
    ``geometry_truth``: column name -> (M,) array (``GEOMETRY_COLUMNS`` plus design and
    irregularity columns); ``truth_info``: JSON-able dict (origin, seed, drawn errors, ...);
    ``kinematics``/``motion``/``track``: the truth models, for tests.
    """

    config: ScenarioConfig
    seed: int
    ideal: bool
    origin: geodesy.Origin
    log: SensorLog
    truth: dict[str, np.ndarray]
    geometry_truth: dict[str, np.ndarray]
    geometry_units: dict[str, str]
    truth_info: dict[str, Any]
    kinematics: TrolleyKinematics
    motion: MotionProfile
    track: TrackModel
    timings_s: dict[str, float] = field(default_factory=dict)


def _rngs(seed: int) -> dict[str, np.random.Generator]:
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return {name: np.random.default_rng(child) for name, child in zip(_STREAMS, children)}


def _motion_plan(cfg: ScenarioConfig) -> MotionProfile:
    segments: list[Hold | Move] = []
    for _ in range(cfg.motion.passes):
        for seg in cfg.motion.segments:
            if seg.hold_s is not None:
                segments.append(Hold(seg.hold_s))
            else:
                segments.append(Move(seg.move_to_m, seg.speed_mps, seg.accel_mps2))
    return compile_plan(cfg.motion.start_m, segments)


def _imu_spec(section: dict) -> ImuSpec:
    section = dict(section)
    grade = section.pop("grade", None)
    base = IMU_GRADES[grade].model_dump() if grade else {}
    if grade is not None and grade not in IMU_GRADES:
        raise ConfigError(f"imu.grade: unknown grade {grade!r} (known: {', '.join(IMU_GRADES)})")
    try:
        return ImuSpec.model_validate({**base, **section})
    except ValidationError as exc:
        raise config_error_from_validation(exc, "imu") from None


def _trolley_geometry(cfg: ScenarioConfig) -> TrolleyGeometry:
    t = cfg.trolley
    return TrolleyGeometry(wheelbase_m=t.wheelbase_m, reference_rail=t.reference_rail,
                           lever_arm_imu_v=tuple(t.lever_arm_imu_v_m),
                           mounting_ypr_rad=tuple(np.radians(t.mounting_ypr_deg)),
                           odometer_wheel=t.odometer_wheel)


def simulate(config: ScenarioConfig | str, seed: int = 0, ideal: bool = False,
             overrides: list[str] | None = None,
             progress: Callable[[str], None] | None = None) -> Simulation:
    """Simulate a survey: a :class:`ScenarioConfig` (or a scenario name/path) -> :class:`Simulation`."""
    say = progress or (lambda _msg: None)
    cfg = config if isinstance(config, ScenarioConfig) else load_scenario(config, overrides)
    timings: dict[str, float] = {}
    tic = time.perf_counter()
    scene = _scene(cfg, seed, say)
    spec, motion, kin, track, origin, rngs = (scene.imu_spec, scene.motion, scene.kin, scene.track, scene.origin,
                                              scene.rngs)
    s_lo, s_hi = motion.chainage_range_m
    timings["track_s"] = time.perf_counter() - tic

    tic = time.perf_counter()
    dt = 1.0 / spec.rate_hz
    n_imu = int(np.floor(motion.end_s * spec.rate_hz + 1e-9))
    t_imu = dt * np.arange(1, n_imu + 1)
    say(f"[{cfg.name}] IMU: {n_imu} samples at {spec.rate_hz:g} Hz ({motion.end_s / 60:.1f} min)")
    gyro_true, accel_true = kin.imu_interval_means(t_imu, dt, motion)
    imu, drawn_imu = simulate_imu(t_imu, gyro_true, accel_true, spec, rngs["imu"], ideal)
    timings["imu_s"] = time.perf_counter() - tic

    tic = time.perf_counter()
    log = SensorLog(imu=imu)
    drawn: dict[str, Any] = {"imu": drawn_imu}
    lever_arms: dict[str, list[float]] = {}
    _simulate_aiding(scene, ideal, log, drawn, lever_arms)
    timings["aiding_s"] = time.perf_counter() - tic

    tic = time.perf_counter()
    truth = _truth_table(kin, motion, cfg.truth.rate_hz)
    geometry_truth, geometry_units = _geometry_truth(track, s_lo, s_hi, cfg.truth.geometry_step_m)
    timings["truth_s"] = time.perf_counter() - tic

    truth_info = {
        "scenario": cfg.name, "description": cfg.description, "seed": seed, "ideal": ideal,
        "origin": origin.to_dict(), "duration_s": motion.end_s,
        "chainage_range_m": [s_lo, s_hi], "static_intervals_s": motion.static_intervals(),
        "imu_rate_hz": spec.rate_hz, "lever_arms_b_m": lever_arms,
        "trolley": cfg.trolley.model_dump(mode="json"),
        "errors": drawn,
        "total_stations": drawn.get("total_stations", {}).get("stations", {}),
        "config": cfg.model_dump(mode="json"),
    }
    log.metadata = _log_metadata(cfg, spec, lever_arms, drawn)
    return Simulation(cfg, seed, ideal, origin, log, truth, geometry_truth, geometry_units, truth_info,
                      kin, motion, track, timings)


@dataclass
class _Scene:
    """What a simulation draws before the IMU: sensor specs, motion, track and trolley kinematics."""

    imu_spec: ImuSpec
    aiding_specs: dict
    motion: MotionProfile
    kin: TrolleyKinematics
    track: TrackModel
    origin: geodesy.Origin
    rngs: dict[str, np.random.Generator]


def _scene(cfg: ScenarioConfig, seed: int, say: Callable[[str], None]) -> _Scene:
    """Validate everything before any work or output, then build the track and the trolley's motion."""
    rngs = _rngs(seed)
    origin = geodesy.Origin(cfg.origin.lat_deg, cfg.origin.lon_deg, cfg.origin.h_m)
    spec = _imu_spec(cfg.imu)
    aiding_specs = _aiding_specs(cfg)
    design = DesignAlignment.from_dict(cfg.alignment)
    irr_spec = IrregularitySpec.from_dict(cfg.irregularities)
    motion = _motion_plan(cfg)
    geometry = _trolley_geometry(cfg)
    s_lo, s_hi = motion.chainage_range_m
    reach = geometry.wheelbase_m
    if s_lo - reach < 0 or s_hi + reach > design.length_m:
        raise ConfigError(f"motion: chainage range [{s_lo}, {s_hi}] m needs the track to extend "
                          f"{reach} m beyond it (alignment length {design.length_m} m)")
    say(f"[{cfg.name}] building track and trolley motion")
    irr = synthesize(irr_spec, design.length_m, rngs["irregularities"])
    track = TrackModel(design, irr)
    kin = TrolleyKinematics.build(track, geometry, origin, s_lo - reach / 2, s_hi + reach / 2)
    return _Scene(spec, aiding_specs, motion, kin, track, origin, rngs)


def simulate_aiding(config: ScenarioConfig | str, seed: int = 0, ideal: bool = False) -> SensorLog:
    """The aiding sensors' records of a simulation (everything but the IMU), the same draws as
    :func:`simulate` of the same seed: a fast check of their clocks and times."""
    cfg = config if isinstance(config, ScenarioConfig) else load_scenario(config)
    scene = _scene(cfg, seed, lambda _m: None)
    log = SensorLog()
    _simulate_aiding(scene, ideal, log, {}, {})
    return log


def _truth_table(kin: TrolleyKinematics, motion: MotionProfile, rate_hz: float) -> dict[str, np.ndarray]:
    """Truth trajectory of the IMU origin at ``rate_hz`` over the whole run (``TRUTH_COLUMNS``)."""
    n = int(np.floor(motion.end_s * rate_hz + 1e-9)) + 1
    t = np.arange(n) / rate_hz
    cols: dict[str, list[np.ndarray]] = {k: [] for k in TRUTH_COLUMNS}
    for a in range(0, n, 200_000):
        st = kin.state(t[a:a + 200_000], motion)
        q = quat_from_R(st["R_nb"])
        parts = [t[a:a + 200_000], *st["pos_n"].T, *q.T, *st["vel_n"].T, st["s_m"]]
        for k, v in zip(TRUTH_COLUMNS, parts):
            cols[k].append(v)
    return {k: np.concatenate(v) for k, v in cols.items()}


def _geometry_truth(track: TrackModel, s_lo: float, s_hi: float, step_m: float
                    ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Rail reference points (and their irregularities) every ``step_m`` over the surveyed range."""
    s = step_m * np.arange(np.ceil(s_lo / step_m), np.floor(s_hi / step_m) + 1)
    left = track.rail_points_n(s, "left")
    right = track.rail_points_n(s, "right")
    cols = {"chainage_m": s, "left_e_m": left[:, 0], "left_n_m": left[:, 1], "left_u_m": left[:, 2],
            "right_e_m": right[:, 0], "right_n_m": right[:, 1], "right_u_m": right[:, 2]}
    units = dict(GEOMETRY_COLUMNS)
    design = track.design.evaluate(s)
    cols["gauge_m"] = track.gauge_m(s)
    cols["design_cant_m"] = design.cant_m
    units.update(gauge_m="m", design_cant_m="m")
    for name, values in track.irregularities.evaluate(s).items():
        cols[f"irr_{name}"] = values
        units[f"irr_{name}"] = "m"
    return cols, units


def _spec(model, section: dict, name: str):
    try:
        return model.model_validate(section)
    except ValidationError as exc:
        raise config_error_from_validation(exc, name) from None


def _pop_lever_arm(section: dict, key: str) -> np.ndarray:
    return np.asarray(section.pop(key, (0.0, 0.0, 0.0)), dtype=float)


def _epochs(motion: MotionProfile, rate_hz: float) -> np.ndarray:
    return np.arange(int(np.floor(motion.end_s * rate_hz + 1e-9)) + 1) / rate_hz


def _aiding_specs(cfg: ScenarioConfig) -> dict[str, tuple[Any, np.ndarray | None]]:
    """Validated specs of the configured aiding sensors: name -> (spec, lever arm in b or None)."""
    out: dict[str, tuple[Any, np.ndarray | None]] = {}
    for name, model, lever_key in (("odometer", aiding.OdometerSpec, None),
                                   ("gnss", aiding.GnssSpec, "lever_arm_b_m"),
                                   ("total_stations", aiding.TotalStationSpec, "prism_lever_arm_b_m"),
                                   ("inclinometer", aiding.InclinometerSpec, None),
                                   ("gauge", aiding.GaugeSpec, None)):
        section = getattr(cfg, name)
        if section is None:
            continue
        section = dict(section)
        lever = _pop_lever_arm(section, lever_key) if lever_key else None
        out[name] = (_spec(model, section, name), lever)
    return out


def _simulate_aiding(scene: _Scene, ideal: bool, log: SensorLog, drawn: dict, lever_arms: dict) -> None:
    """Simulate every configured aiding sensor of ``scene`` into ``log`` (each from its own random
    stream); fill ``drawn`` and ``lever_arms``."""
    specs, kin, track, motion, origin, rngs = (scene.aiding_specs, scene.kin, scene.track, scene.motion,
                                               scene.origin, scene.rngs)
    if "odometer" in specs:
        spec, _ = specs["odometer"]
        t = _epochs(motion, spec.rate_hz)
        s = motion.evaluate(t)[0]
        log.odometer, drawn["odometer"] = aiding.simulate_odometer(t, kin.wheel_distance_m(s), spec,
                                                                   rngs["odometer"], ideal)
    if "gnss" in specs:
        spec, lever = specs["gnss"]
        lever_arms["gnss_antenna"] = lever.tolist()
        t = _epochs(motion, spec.rate_hz)
        st = kin.state(t, motion)
        antenna = st["pos_n"] + st["R_nb"] @ lever
        log.gnss, drawn["gnss"] = aiding.simulate_gnss(t, antenna, origin, spec, rngs["gnss"], ideal)
    if "total_stations" in specs:
        spec, lever = specs["total_stations"]
        lever_arms["prism"] = lever.tolist()
        t = _epochs(motion, 20.0)

        def prism_at(t_imu: np.ndarray) -> np.ndarray:
            st = kin.state(t_imu, motion)
            return st["pos_n"] + st["R_nb"] @ lever

        log.total_stations, drawn["total_stations"] = aiding.simulate_total_stations(
            t, motion.evaluate(t)[0], prism_at, origin, spec, rngs["total_stations"], ideal,
            setup_rng=rngs["station_setups"])
    if "inclinometer" in specs:
        spec, _ = specs["inclinometer"]
        t = _epochs(motion, spec.rate_hz)
        st = kin.state(t, motion)
        # roll and pitch against the local plumb line at each point, not n's z axis
        R_lb = np.swapaxes(geodesy.R_n_local(st["pos_n"], origin), -1, -2) @ st["R_nb"]
        _, pitch, roll = ypr_from_R(R_lb)
        log.inclinometer, drawn["inclinometer"] = aiding.simulate_inclinometer(
            t, roll, pitch, spec, rngs["inclinometer"], ideal)
    if "gauge" in specs:
        spec, _ = specs["gauge"]
        t = _epochs(motion, spec.rate_hz)
        log.gauge, drawn["gauge"] = aiding.simulate_gauge(t, track.gauge_m(motion.evaluate(t)[0]), spec,
                                                          rngs["gauge"], ideal)


#: UTC time at which a simulated survey's IMU clock reads 0 (``survey.epoch_utc``: fused.mcap's absolute clock)
SIMULATED_EPOCH_UTC = "2024-06-03T08:00:00Z"


def _log_metadata(cfg: ScenarioConfig, spec: ImuSpec, lever_arms: dict, drawn: dict) -> dict[str, Any]:
    """Run metadata for the log: survey description, sensor specifications, lever arms, station set-ups."""
    meta: dict[str, Any] = {
        "survey": {"scenario": cfg.name, "description": cfg.description, "simulated": True,
                   "origin": cfg.origin.model_dump(), "epoch_utc": SIMULATED_EPOCH_UTC},
        "sensors": {"imu": spec.model_dump(), "odometer": cfg.odometer, "gnss": cfg.gnss,
                    "inclinometer": cfg.inclinometer, "gauge": cfg.gauge},
        "lever_arms": {"lever_arm_imu_v_m": list(cfg.trolley.lever_arm_imu_v_m),
                       "mounting_ypr_deg": list(cfg.trolley.mounting_ypr_deg),
                       "wheelbase_m": cfg.trolley.wheelbase_m, **{f"{k}_b_m": v for k, v in lever_arms.items()}},
    }
    if cfg.total_stations is not None:
        # the set-up a surveyor knows: nominal positions and orientations, not the drawn errors
        meta["total_stations"] = {s["id"]: {"pos_n_m": s["pos_n_m"], "orientation_deg": s.get("orientation_deg", 0.0)}
                                  for s in cfg.total_stations["stations"]}
    return meta


@dataclass
class SimulationReport:
    """What :func:`simulate_to_dir` wrote: the folder, file names, and a few figures."""

    out_dir: Path
    files: list[str]
    scenario: str
    seed: int
    ideal: bool
    duration_s: float
    imu_samples: int
    counts: dict[str, int]
    timings_s: dict[str, float]

    def format(self) -> str:
        """A short human-readable summary."""
        lines = [f"simulated {self.scenario!r} (seed {self.seed}{', ideal' if self.ideal else ''}): "
                 f"{self.duration_s / 60:.1f} min, {self.imu_samples} IMU samples",
                 "  " + ", ".join(f"{k}: {v}" for k, v in self.counts.items()),
                 f"  wrote {', '.join(self.files)} in {self.out_dir}/"]
        return "\n".join(lines)


#: keyframe spacing [s] of the surveys with the wheel-path factor (on every keyframe): with the
#: rear wheel tied to the front wheel's path, 0.2 s keyframes give the 0.1 s ones' relative
#: accuracy (open-track-gnss seeds 1-3, 5 m vertical MSE mean 0.043 against 0.040 mm, lateral
#: 0.032 against 0.032 mm) for about 73 % of the smoothing's CPU time (docs/solver_speed.md)
WHEEL_PATH_KEYFRAME_SPACING_S = 0.2


def pipeline_for(sim: Simulation) -> dict[str, Any]:
    """The pipeline a simulated run should be processed with (paths relative to its folder;
    schema: :class:`trackfusion.pipeline.PipelineConfig`, docs/pipeline.md). Datasheet values
    only: the scenario's IMU section (grade and stated figures), the library's NHC, odometer and
    wheel-path sigmas (a trolley's documented tolerances; each group's noise is estimated from the
    residuals, fusion/noise_components.py), nothing derived from the simulated track or the drawn
    errors. The wheel-path factor (and with it 0.2 s keyframes) is on in the surveys with an
    odometer and GNSS or total stations (not yet measured without either: docs/wheel_path.md)."""
    cfg = sim.config
    imu_spec = _imu_spec(cfg.imu)
    # the rigid trolley's rear wheel runs where its front wheel ran (fusion/wheel_path.py)
    wheel_path = cfg.odometer is not None and (cfg.gnss is not None or cfg.total_stations is not None)
    factors = {"imu": True, "zupt": True,
               "nhc": True,
               "odometer": cfg.odometer is not None,
               "wheel_path": {"enabled": True, "keyframe_step": 1} if wheel_path else False,
               "gnss": cfg.gnss is not None, "inclinometer": cfg.inclinometer is not None,
               "total_stations": cfg.total_stations is not None}
    sensors: dict[str, Any] = {"imu": imu_spec.model_dump()}
    arms = sim.truth_info["lever_arms_b_m"]
    if cfg.odometer is not None:
        sensors["odometer"] = {"clock_offset_s": 0.0}
    if "gnss_antenna" in arms:
        sensors["gnss"] = {"lever_arm_b_m": arms["gnss_antenna"], "clock_offset_s": 0.0}
    if cfg.inclinometer is not None:
        sensors["inclinometer"] = {"clock_offset_s": 0.0}
    if "prism" in arms:
        sensors["total_stations"] = {"prism_lever_arm_b_m": arms["prism"],
                                     "stations": sim.log.metadata.get("total_stations", {})}
    return {
        "name": cfg.name,
        "inputs": {"log": "log.mcap", "reference": "truth.csv"},
        "origin": sim.origin.to_dict(),
        "vehicle": {"kind": "trolley", "wheelbase_m": cfg.trolley.wheelbase_m, "reference_rail": cfg.trolley.reference_rail,
                    "lever_arm_imu_v_m": list(cfg.trolley.lever_arm_imu_v_m),
                    "mounting_ypr_deg": list(cfg.trolley.mounting_ypr_deg),
                    "odometer_wheel": cfg.trolley.odometer_wheel},
        "sensors": sensors,
        "factors": factors,
        "keyframes": {"spacing_s": WHEEL_PATH_KEYFRAME_SPACING_S}
        if wheel_path else {"spacing_s": 0.1},
        "outputs": {"trajectory_rate_hz": cfg.truth.rate_hz, "geometry_step_m": cfg.truth.geometry_step_m},
    }


def simulate_to_dir(scenario: str, out_dir: str | Path, seed: int = 0, ideal: bool = False,
                    overrides: list[str] | None = None,
                    progress: Callable[[str], None] | None = None, force: bool = False) -> SimulationReport:
    """Simulate ``scenario`` and write its files into ``out_dir``: checked and locked before the
    simulation, staged and renamed (:class:`~trackfusion.outdir.OutputFolder`; ``force``: write
    beside files trackfusion did not write)."""
    from ..outdir import OutputFolder

    folder = OutputFolder(out_dir, force, command=f"trackfusion simulate {scenario}")
    with folder.locked():
        say = progress or (lambda _msg: None)
        sim = simulate(scenario, seed=seed, ideal=ideal, overrides=overrides, progress=say)
        tic = time.perf_counter()
        say(f"[{sim.config.name}] writing {folder.path}/")
        with folder.staging() as stage:
            _write_simulation(sim, stage, seed)
    return _simulation_report(sim, folder.path, seed, ideal, time.perf_counter() - tic)


def _write_simulation(sim: Simulation, out: Path, seed: int) -> None:
    from ..sensors.fileio import write_csv_table, write_text_atomic
    from ..sensors.mcap_log import write_log

    origin = sim.origin.to_dict()
    write_log(out / "log.mcap", sim.log)
    write_csv_table(out / "truth.csv", sim.truth, TRUTH_COLUMNS, "n", origin, fmt="%.12g",
                    extra={"description": "truth of the IMU origin (simulated)", **sim.truth_info})
    write_csv_table(out / "geometry_truth.csv", sim.geometry_truth, sim.geometry_units, "n", origin, fmt="%.12g",
                    extra={"description": "rail reference points (top of rail, running edge) and irregularities"})
    header = f"# trackfusion pipeline for the simulated survey {sim.config.name!r} (seed {seed})\n"
    write_text_atomic(out / "pipeline.yaml", header + yaml.safe_dump(pipeline_for(sim), sort_keys=False))


def _simulation_report(sim: Simulation, out: Path, seed: int, ideal: bool, write_s: float) -> SimulationReport:
    sim.timings_s["write_s"] = write_s
    counts = {"imu": sim.log.imu.t_s.size}
    for name in ("odometer", "gnss", "inclinometer", "gauge"):
        data = getattr(sim.log, name)
        if data is not None:
            counts[name] = data.t_s.size
    for sid, data in sim.log.total_stations.items():
        counts[f"total_station/{sid}"] = data.t_s.size
    return SimulationReport(out, ["log.mcap", "truth.csv", "truth.json", "geometry_truth.csv",
                                  "geometry_truth.json", "pipeline.yaml"], sim.config.name, seed, ideal,
                            sim.motion.end_s, sim.log.imu.t_s.size, counts, sim.timings_s)
