"""Benchmark: the cross-level's design reference (``vision.cross_level_reference``) against the run's
length, without rendering (docs/vision.md, "The cross-level's reference").

Usage: python benchmarks/cross_level_reference.py [--seeds 1 ... 10] [--lengths-m 200 1000 3000]

Per seed and filmed length: the tgms-vehicle scenario (``trackfusion simulate tgms-vehicle``'s
track, bogie, IMU with the datasheet's errors and encoder, same random streams), the vision
run's motion (``trackfusion.vision.run.motion``: chainage onto the design, zero-phase roll), and
in place of the images the true profile origins in the measuring frame plus white noise of
0.057 mm on the cross-level (the vision alone's cross-level error with the true roll,
``benchmarks/vision.py``): the cross-level error is then the roll's error times the rail-head
baseline plus that noise. The run's offset is estimated as the run does
(:func:`~trackfusion.vision.cross_level_reference.estimate_roll_offset`) and taken off. Figures:
cross-level RMS error with ``none`` and with the whole offset taken off (``design``), the offset and its standard deviation,
the true constant roll error (the filmed frames' mean), the truth's own mean cross-level over
the run, and with the offset weighted against the datasheet's 0.2 mg bias (``weighted``: the
run's default, :func:`~trackfusion.vision.cross_level_reference.prior_weight`); per length the worst seed, the rms over the seeds and the seeds within 0.3 mm. At
200 m it reproduces the rendered end-to-end benchmark (``benchmarks/tgms_vehicle.py``, seeds
1-10). Writes benchmarks/results/cross_level_reference.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from trackfusion.simulation.camera_laser import simulate_run
from trackfusion.simulation.tgms_vehicle import TgmsScenario, design_of
from trackfusion.simulation.vision_imu import ImuSpec, encoder_chainage_m, imu_signals
from trackfusion.track.rail_profile import rail_head
from trackfusion.vision.cross_level_reference import estimate_roll_offset, prior_weight
from trackfusion.vision.measure import cross_level_of_poses
from trackfusion.vision.run import motion

HEAD = rail_head("60E1")
VISION_NOISE_M = 0.057e-3


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def one_run(seed: int, length_m: float) -> dict:
    """One seed's run of ``length_m`` filmed: the errors without and with the reference."""
    sc = TgmsScenario(length_m=length_m)
    lead, film = int(round(sc.lead_s * sc.rate_hz)), int(round(sc.length_m / sc.speed_mps * sc.rate_hz))
    n = lead + film + int(round(sc.tail_s * sc.rate_hz))
    run = simulate_run(HEAD, n_frames=n, speed_mps=sc.speed_mps, rate_hz=sc.rate_hz, seed=seed + 1,
                       truth_frames=slice(0, 0))
    design = design_of(sc, sc.speed_mps * lead / sc.rate_hz)
    gyro, accel = imu_signals(run.t_s, run.s_m, run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m,
                              run.roll_rel_rad, design, ImuSpec(), np.random.default_rng(7 + seed))
    f = slice(lead, lead + film)
    log = {"t_imu_s": run.t_s, "gyro_b": gyro, "accel_b": accel, "t_frame_s": run.t_s[f],
           "encoder_m": encoder_chainage_m(run.s_m, np.random.default_rng(11 + seed))}
    roll = motion(log, design)["frame_roll_rad"]
    pose = {k: np.column_stack([run.origin_v_m[k][f] * 1e3, run.roll_v_rad[k][f]]) for k in ("left", "right")}
    noise = np.random.default_rng(100 + seed).normal(0.0, VISION_NOISE_M, film)
    cl = cross_level_of_poses(pose["left"], pose["right"], roll) + noise
    est = estimate_roll_offset(cl, pose["left"], pose["right"], roll)
    referenced = cross_level_of_poses(pose["left"], pose["right"], roll - est.offset_rad) + noise
    w = prior_weight(est.sd_rad, ImuSpec().accel_bias_mg)
    weighted = cross_level_of_poses(pose["left"], pose["right"], roll - w * est.offset_rad) + noise
    truth = run.cross_level_m[f]
    return {"seed": seed, "cross_level_rms_error_mm_none": rms((cl - truth) * 1e3),
            "cross_level_rms_error_mm_design": rms((referenced - truth) * 1e3),
            "cross_level_rms_error_mm_weighted": rms((weighted - truth) * 1e3), "weight": w,
            "roll_offset_urad": est.offset_rad * 1e6, "roll_offset_sd_urad": est.sd_rad * 1e6,
            "true_roll_error_mean_urad": float(np.mean(roll - run.roll_rel_rad[f]) * 1e6),
            "truth_cross_level_mean_mm": float(np.mean(truth) * 1e3)}


def summary(runs: list[dict]) -> dict:
    """Worst seed, rms over the seeds and seeds within 0.3 mm, for ``none``, ``design`` (the
    whole offset taken off) and ``weighted`` (weighted against the datasheet's bias: the default)."""
    out = {}
    for ref in ("none", "design", "weighted"):
        e = np.array([r[f"cross_level_rms_error_mm_{ref}"] for r in runs])
        out[ref] = {"worst_mm": float(e.max()), "rms_over_seeds_mm": rms(e),
                    "seeds_within_0p3_mm": int((e <= 0.3).sum())}
    out["truth_mean_rms_over_seeds_mm"] = rms(np.array([r["truth_cross_level_mean_mm"] for r in runs]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--lengths-m", type=float, nargs="+", default=[200.0, 1000.0, 3000.0])
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "cross_level_reference.json"))
    args = ap.parse_args()
    doc = {"seeds": args.seeds, "vision_noise_mm": VISION_NOISE_M * 1e3, "lengths": {}}
    for length in args.lengths_m:
        runs = [one_run(s, length) for s in args.seeds]
        doc["lengths"][f"{length:g}"] = {**summary(runs), "runs": runs}
        print(json.dumps({"length_m": length, **summary(runs)}))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
