"""Benchmark: cross-level on the `track-level` scenario (seed 004) from the factor graph and from
seed 004's own fusion methods.

Usage: python benchmarks/track_level.py [--seeds 1 2 3]

Each seed's `track-level` survey (cant transition into a 600 m curve, MEMS IMU + inclinometer +
gauge + odometer; cached under ``$TMPDIR/trackfusion-bench-track-level``) gives the cross-level
``H = L sin(theta)`` (seed 004 eq. 22) of:

1. the factor graph with the inclinometer roll/pitch factor (the pipeline's geometry.csv
   ``cross_level_mm``, from the smoothed attitude and the gauge reading), and, for what the
   factor adds, the same graph without it;
2. seed 004's Kalman filter of the angle sensor and the gyro angle (eqs. 1-7, its Q and R);
3. seed 004's weighted fusion (eqs. 8-18), weights from the data (its section III) and, as a
   variant, from the R of its Kalman filter (10:1);
4. the inclinometer alone, and the gyro angle alone;
5. (not in the seed) a complementary filter of the inclinometer and the gyro rate, crossover
   2 s; the inclinometer with its 0.5 s lag inverted; the factor graph with the inclinometer
   factor at 1 mrad instead of the default 0.1 mrad.

Baselines 2-5 use the logged inclinometer roll (time constant 0.5 s in the simulation), the
gyro's x-axis rate (zeroed over the first static interval, seed eq. 23) and ``L`` = the gauge
reading (interpolated in time): trackfusion/track/level_baselines.py. Every method is compared
with the truth cross-level (left minus right rail height of ``geometry_truth.csv``) at the
same physical points: the pass's grid points at the truth chainage of the trolley when it
passed them. Figures: RMS and max |error| [mm] in motion. Seed 004's own table 2 ("mean square
error", units not stated): Kalman 1.3054, weighted fusion 1.4175.
Writes benchmarks/results/track_level.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from geometry import run_geometry, simulated, truth_chainage  # noqa: E402

from trackfusion.sensors.fileio import read_csv_table  # noqa: E402
from trackfusion.sensors.mcap_log import read_log  # noqa: E402
from trackfusion.track import level_baselines as lb  # noqa: E402
from trackfusion.track.irregularities import cross_level_from_roll  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "track_level.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench-track-level"
SCENARIO = "track-level"
STEP_M = 0.25
COMPLEMENTARY_CROSSOVER_S = 2.0
INCLINOMETER_TAU_S = 0.5   # the scenario's inclinometer time constant (its sensor spec)
SEED_TABLE_2 = {"kalman_filter": 1.3054, "weighted_fusion": 1.4175,
                "note": "seed 004 table 2, 'mean square error' of its field data, units not stated"}


def _stats(err_mm: np.ndarray) -> dict:
    return {"rms_mm": float(np.sqrt(np.mean(err_mm ** 2))), "max_abs_mm": float(np.max(np.abs(err_mm))),
            "mean_mm": float(np.mean(err_mm))}


def baselines(folder: Path, problem) -> dict[str, tuple[np.ndarray, np.ndarray, dict]]:
    """Seed 004's methods on the raw log: name -> (t_s, cross-level [m], info)."""
    log = read_log(folder / "log.mcap")
    inc, imu, gauge = log.inclinometer, log.imu, log.gauge
    t = inc.t_s
    z_inc = inc.roll_rad
    rate_v = (imu.gyro_radps @ problem.trolley.R_vb.T)[:, 0]          # about the trolley's x axis
    a, b = problem.static_intervals_s[0]
    rest = (imu.t_s >= a) & (imu.t_s <= b)
    theta0 = float(np.mean(z_inc[(t >= a) & (t <= b)]))               # the level at rest
    z_gyro_imu = lb.gyro_angle(imu.t_s, rate_v, theta0, rest)
    z_gyro = np.interp(t, imu.t_s, z_gyro_imu)                          # the gyro angle at the inclinometer epochs
    L = np.interp(t, gauge.t_s, gauge.gauge_m)
    weighted = lb.seed_weighted_fusion(z_inc, z_gyro)
    weighted_r = lb.seed_weighted_fusion(z_inc, z_gyro, variances=lb.SEED_R)
    comp_rate = np.interp(t, imu.t_s, rate_v - np.mean(rate_v[rest]))
    return {
        "seed_kalman": (t, cross_level_from_roll(lb.seed_kalman(z_inc, z_gyro), L),
                        {"R": list(lb.SEED_R), "Q": lb.SEED_Q, "steady_gain": lb.steady_state_gain().tolist()}),
        "seed_weighted_fusion": (t, cross_level_from_roll(weighted.angle_rad, L),
                                 {"weights": list(weighted.weights), "variances_rad2": list(weighted.variances)}),
        "seed_weighted_fusion_seed_R": (t, cross_level_from_roll(weighted_r.angle_rad, L),
                                        {"weights": list(weighted_r.weights), "variances": list(lb.SEED_R)}),
        "inclinometer_alone": (t, cross_level_from_roll(z_inc, L), {}),
        "inclinometer_lag_inverted": (t, cross_level_from_roll(lb.inverse_first_order_lag(t, z_inc, INCLINOMETER_TAU_S), L),
                                      {"time_constant_s": INCLINOMETER_TAU_S, "in_seed": False}),
        "gyro_alone": (t, cross_level_from_roll(z_gyro, L), {}),
        "complementary_filter": (t, cross_level_from_roll(lb.complementary_filter(t, z_inc, comp_rate,
                                                                                  COMPLEMENTARY_CROSSOVER_S), L),
                                 {"crossover_s": COMPLEMENTARY_CROSSOVER_S, "in_seed": False}),
    }


def one_seed(seed: int) -> dict:
    folder = simulated(SCENARIO, seed, CACHE)
    truth = read_csv_table(folder / "truth.csv")
    gtruth = read_csv_table(folder / "geometry_truth.csv")
    cl_truth = gtruth["left_u_m"] - gtruth["right_u_m"]
    geometry = {"chords_m": [10.0], "repeatability_chords_m": [], "repeatability_limits_mm": []}
    out: dict = {}
    points = None
    for name, inc in (("factor_graph_inclinometer", True), ("factor_graph_without_inclinometer", False),
                      ("factor_graph_inclinometer_sigma_1mrad", {"sigma_mrad": 1.0})):
        geo, dense, chainage, problem = run_geometry(folder, SCENARIO, geometry=geometry, step_m=STEP_M,
                                                     factors={"inclinometer": inc})
        errs, t_pts, s_pts = [], [], []
        for tab in geo.passes:
            s_true = truth_chainage(tab, dense, chainage, truth)
            ok = np.isfinite(tab["cross_level_mm"]) & (s_true > gtruth["chainage_m"][0]) & (s_true < gtruth["chainage_m"][-1])
            truth_mm = 1e3 * np.interp(s_true[ok], gtruth["chainage_m"], cl_truth)
            errs.append(tab["cross_level_mm"][ok] - truth_mm)
            t_pts.append(tab["t_s"][ok])
            s_pts.append(s_true[ok])
        out[name] = _stats(np.concatenate(errs))
        if inc is True:
            points = (np.concatenate(t_pts), np.concatenate(s_pts))
            base_problem = problem
    t_pts, s_pts = points
    truth_mm = 1e3 * np.interp(s_pts, gtruth["chainage_m"], cl_truth)
    for name, (t, cl_m, info) in baselines(folder, base_problem).items():
        out[name] = {**_stats(1e3 * np.interp(t_pts, t, cl_m) - truth_mm), **info}
    out["points"] = int(t_pts.size)
    out["truth_cross_level_range_mm"] = [float(truth_mm.min()), float(truth_mm.max())]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args()
    tic = time.perf_counter()
    per_seed = {str(s): one_seed(s) for s in args.seeds}
    methods = [k for k, v in per_seed[str(args.seeds[0])].items() if isinstance(v, dict)]
    summary = {m: {"rms_mm_mean": float(np.mean([per_seed[s][m]["rms_mm"] for s in per_seed])),
                   "rms_mm_worst": float(np.max([per_seed[s][m]["rms_mm"] for s in per_seed])),
                   "max_abs_mm_worst": float(np.max([per_seed[s][m]["max_abs_mm"] for s in per_seed]))}
               for m in methods}
    print(f"track-level cross-level error against the truth, seeds {args.seeds} (in motion, mm):")
    print(f"   {'method':<36} {'RMS mean':>9} {'RMS worst':>10} {'max worst':>10}")
    for m, v in summary.items():
        print(f"   {m:<36} {v['rms_mm_mean']:9.3f} {v['rms_mm_worst']:10.3f} {v['max_abs_mm_worst']:10.3f}")
    print(f"   seed 004 table 2 ({SEED_TABLE_2['note']}): Kalman {SEED_TABLE_2['kalman_filter']}, "
          f"weighted {SEED_TABLE_2['weighted_fusion']}")
    results = {"scenario": SCENARIO, "seeds": args.seeds, "date": time.strftime("%Y-%m-%d"),
               "machine": "2 cores, shared by five helpers", "wall_s": time.perf_counter() - tic,
               "summary": summary, "per_seed": per_seed, "seed_004_table_2": SEED_TABLE_2}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
