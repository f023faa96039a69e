"""``trackfusion simulate tgms-vehicle``: an in-service vehicle with seed 001's vision-inertial
track geometry measuring system (docs/vision.md, "Simulating and running a survey").

The measuring frame on the bogie moves relative to the track (:func:`~trackfusion.simulation.
camera_laser.simulate_run`); its IMU and encoder (:mod:`~trackfusion.simulation.vision_imu`)
record from ``lead_s`` before the filmed stretch to ``tail_s`` after it (the zero-phase roll
filter needs both sides), the two camera-laser units film the stretch at the IMU's 250 Hz. The
line: straight, a clothoid transition with a linear cant ramp into a left-hand arc, a transition
out and a straight, all within the filmed stretch; a worn stretch in the arc (vertical wear on
both rails, side wear on the left one, 5 m ramps).

Written into the output folder: ``log.mcap`` (IMU, encoder, ``foxglove.CompressedImage`` PNG
frames of both cameras), ``calibration/left|right`` (calibration sets: board and laser-line
images), ``design.csv``, ``truth.csv`` (per filmed frame) and ``pipeline.yaml`` (datasheet
values only; its calibration file is written by ``trackfusion calibrate-vision``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import ConfigError

NAME = "tgms-vehicle"
DESCRIPTION = ("in-service vehicle, seed 001's camera-laser rail profiles + IMU + encoder at 250 frames/s "
               "on a curve with transitions, cant and a worn stretch (vision run; --set length_m=...)")


@dataclass(frozen=True)
class TgmsScenario:
    """The scenario's parameters (``--set NAME=VALUE``): filmed length [m], speed [m/s], IMU
    lead-in and tail [s], frame rate [Hz], arc radius [m] and cant [mm], wear [mm], board poses
    per calibration set, rail profile, and how the log holds the images (``png``:
    ``foxglove.CompressedImage``; ``raw``: ``sensor_msgs/msg/Image``, nothing to decode)."""

    length_m: float = 200.0
    speed_mps: float = 30.0
    lead_s: float = 60.0
    tail_s: float = 10.0
    rate_hz: float = 250.0
    radius_m: float = 800.0
    cant_mm: float = 100.0
    vertical_wear_mm: float = 1.0
    side_wear_mm: float = 2.0
    calibration_poses: int = 30
    rail_profile: str = "60E1"
    image_encoding: str = "png"


def scenario_from_overrides(overrides: list[str]) -> TgmsScenario:
    """The default scenario with ``NAME=VALUE`` overrides; :class:`ConfigError` for unknown names
    or values out of range (before anything is computed)."""
    known = {f.name: f.type for f in fields(TgmsScenario)}
    values: dict = {}
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or key not in known:
            raise ConfigError(f"--set {item}: {NAME} takes {', '.join(known)}")
        try:
            values[key] = raw if known[key] == "str" else (int(raw) if known[key] == "int" else float(raw))
        except ValueError:
            raise ConfigError(f"--set {item}: not a number") from None
    sc = replace(TgmsScenario(), **values)
    if not 20.0 <= sc.speed_mps <= 40.0:
        raise ConfigError(f"--set speed_mps={sc.speed_mps:g}: an in-service vehicle here runs at 20-40 m/s")
    if sc.length_m < 20.0 or sc.lead_s < 5.0 or sc.tail_s < 2.0 or sc.calibration_poses < 8 or sc.rate_hz <= 0:
        raise ConfigError("--set: needs length_m >= 20, lead_s >= 5, tail_s >= 2, calibration_poses >= 8")
    from ..vision.image_log import IMAGE_ENCODINGS
    if sc.image_encoding not in IMAGE_ENCODINGS:
        raise ConfigError(f"--set image_encoding={sc.image_encoding}: one of {', '.join(IMAGE_ENCODINGS)}")
    return sc


def design_of(sc: TgmsScenario, start_m: float):
    """The line's design table: transitions over 15-35 % and 65-85 % of the filmed stretch
    starting at ``start_m``, the arc between."""
    from ..vision.design_table import DesignTable
    L = sc.length_m
    s = start_m + L * np.array([0.15, 0.35, 0.65, 0.85])
    k, c = 1.0 / sc.radius_m, sc.cant_mm
    return DesignTable(np.concatenate([[0.0], s, [start_m + L + sc.speed_mps * sc.tail_s + 100.0]]),
                       np.array([0.0, 0.0, k, k, 0.0, 0.0]), np.array([0.0, 0.0, c, c, 0.0, 0.0]))


def simulate_tgms(sc: TgmsScenario, seed: int, say: Callable[[str], None]) -> dict:
    """Everything the folder holds, in memory: IMU, encoder, frames, truth, design, units."""
    from ..track.rail_profile import rail_head
    from .camera_laser import StripeLook, default_units, frame_images, simulate_run
    from .vision_imu import ImuSpec, encoder_chainage_m, imu_signals
    head = rail_head(sc.rail_profile)
    lead, film = int(round(sc.lead_s * sc.rate_hz)), int(round(sc.length_m / sc.speed_mps * sc.rate_hz))
    n = lead + film + int(round(sc.tail_s * sc.rate_hz))
    start = sc.speed_mps * lead / sc.rate_hz
    wear = {"start_m": start + 0.4 * sc.length_m, "end_m": start + 0.6 * sc.length_m,
            "vertical_mm": sc.vertical_wear_mm, "side_mm": sc.side_wear_mm, "side_rail": "left"}
    say(f"[{NAME}] {n} IMU samples, {film} frames per camera")
    filmed = slice(lead, lead + film)
    run = simulate_run(head, n_frames=n, speed_mps=sc.speed_mps, rate_hz=sc.rate_hz, wear=wear, seed=seed + 1,
                       truth_frames=filmed)
    design = design_of(sc, start)
    gyro, accel = imu_signals(run.t_s, run.s_m, run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m,
                              run.roll_rel_rad, design, ImuSpec(), np.random.default_rng(7 + seed))
    enc = encoder_chainage_m(run.s_m, np.random.default_rng(11 + seed))
    sims = default_units(1.435 / 2 + head.gauge_point_mm()[0] / 1000)
    shot = run.frames(lead, lead + film)
    images, flags = {}, {}
    for i, side in enumerate(("left", "right")):
        say(f"[{NAME}] rendering the {side} camera's frames")
        images[side], flags[side] = frame_images(sims[side], head, shot, StripeLook(), seed=1000 * seed + i + 1)
    return {"run": run, "shot": shot, "filmed": filmed, "gyro": gyro, "accel": accel, "encoder_m": enc,
            "images": images, "flags": flags, "design": design, "sims": sims}


def truth_columns(sim: dict) -> dict[str, np.ndarray]:
    """Per filmed frame: time, true chainage, gauge, cross-level, wear, relative motion, the
    centreline's alignment and vertical profile, and what the renderer did (0 ok, 1 no stripe, 2 glare)."""
    r = sim["shot"]
    out = {"t_s": r.t_s, "chainage_m": r.s_m, "gauge_m": r.gauge_m, "cross_level_mm": r.cross_level_m * 1e3}
    for side in ("left", "right"):
        out[f"wear_vertical_{side}_mm"] = r.vertical_wear_mm[side]
        out[f"wear_side_{side}_mm"] = r.side_wear_mm[side]
    out.update({"roll_rel_deg": np.degrees(r.roll_rel_rad), "y_rel_mm": r.y_rel_m * 1e3, "z_rel_mm": r.z_rel_m * 1e3,
                "alignment_mm": r.alignment_m * 1e3, "vertical_profile_mm": r.vertical_profile_m * 1e3,
                "rendered_left": sim["flags"]["left"], "rendered_right": sim["flags"]["right"]})
    return out


def pipeline_yaml(sc: TgmsScenario, seed: int) -> str:
    """The survey's pipeline: file names and datasheet/drawing values only (the IMU's nominal
    accelerometer bias, not the drawn one)."""
    import yaml

    from .vision_imu import ImuSpec
    doc = {"name": NAME, "description": f"simulated {NAME} survey (seed {seed})",
           "vision": {"log": "log.mcap", "calibration": "calibration.yaml", "design": "design.csv",
                      "rail_profile": sc.rail_profile, "gauge_nominal_m": 1.435,
                      "workers": 2, "cross_level_reference": "design", "accel_bias_mg": ImuSpec().accel_bias_mg},
           "outputs": {"report": True}}
    return (f"# trackfusion pipeline for the simulated survey {NAME!r} (seed {seed}).\n"
            "# First calibrate the cameras: trackfusion calibrate-vision calibration --out calibration.yaml\n"
            + yaml.safe_dump(doc, sort_keys=False))


def write_tgms(sim: dict, sc: TgmsScenario, seed: int, out: Path) -> list[str]:
    """Write the folder's files into ``out`` (a staging folder); returns their names."""
    from ..sensors.fileio import write_text_atomic
    from ..vision.design_table import write_design_csv
    from ..vision.image_log import ImuEncoderSamples, write_vision_log
    from .vision_calibration import write_calibration_set
    run, f = sim["run"], sim["filmed"]
    motion = ImuEncoderSamples(run.t_s, sim["gyro"], sim["accel"], sim["encoder_m"], 1e-3)
    write_vision_log(out / "log.mcap", motion, run.t_s[f], sim["images"], metadata={"scenario": NAME, "seed": seed, "simulated": True},
                     image_encoding=sc.image_encoding)
    for i, side in enumerate(("left", "right")):
        write_calibration_set(sim["sims"][side], out / "calibration" / side, n_poses=sc.calibration_poses,
                              seed=100 * seed + i + 1)
    write_design_csv(out / "design.csv", sim["design"])
    cols = truth_columns(sim)
    lines = [",".join(cols)] + [",".join(f"{v:.9g}" for v in row) for row in np.column_stack(list(cols.values()))]
    write_text_atomic(out / "truth.csv", "\n".join(lines) + "\n")
    write_text_atomic(out / "pipeline.yaml", pipeline_yaml(sc, seed))
    return ["log.mcap", "calibration/", "design.csv", "truth.csv", "pipeline.yaml"]


def simulate_tgms_to_dir(out_dir: str | Path, seed: int = 0, overrides: list[str] | None = None,
                         progress: Callable[[str], None] | None = None, force: bool = False) -> str:
    """Simulate the scenario into ``out_dir`` (checked and locked first, staged, renamed); returns
    the lines the command prints."""
    from ..outdir import OutputFolder
    sc = scenario_from_overrides(overrides or [])
    say = progress or (lambda _m: None)
    folder = OutputFolder(out_dir, force, command=f"trackfusion simulate {NAME}")
    with folder.locked():
        sim = simulate_tgms(sc, seed, say)
        say(f"[{NAME}] writing {folder.path}/")
        with folder.staging() as stage:
            names = write_tgms(sim, sc, seed, stage)
    frames = len(sim["shot"].t_s)
    return (f"wrote {', '.join(names)} to {folder.path}/\n"
            f"  {NAME} (seed {seed}): {sc.length_m:g} m filmed at {sc.speed_mps:g} m/s, {frames} frames per camera, "
            f"{len(sim['run'].t_s)} IMU samples\n"
            f"  next: trackfusion calibrate-vision {folder.path}/calibration --out {folder.path}/calibration.yaml; "
            f"trackfusion run {folder.path}/pipeline.yaml")
