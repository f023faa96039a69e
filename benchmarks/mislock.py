"""Benchmark: a total station locked onto a wrong target for 10 s (issue 8 target).

Usage: python benchmarks/mislock.py [--seed 1] [--start-s 600] [--duration-s 10]
Simulates ``bridge-total-station`` twice with the same seed, once clean and once with TS01
reading another reflector (8 m beside the track, 400 m away) for ``duration_s``, runs the
pipeline on both, and compares the two fused trajectories (IMU origin, 100 Hz) with each other
and with the truth outside the mis-lock interval. Simulations are cached under
``$TMPDIR/trackfusion-bench``. Writes benchmarks/results/mislock.json.
Target: no error above 1 mm outside the interval caused by the mis-lock (the change against the
clean run); also reported: the readings rejected as ``mis_lock``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "mislock.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"


def _positions_mm(table: dict[str, np.ndarray]) -> np.ndarray:
    return np.column_stack([table["e_m"], table["n_m"], table["u_m"]]) * 1e3


def _run(name: str, seed: int, overrides: list[str]) -> dict[str, np.ndarray]:
    from trackfusion.pipeline import load_pipeline, run
    from trackfusion.simulation.scenarios import simulate_to_dir
    sim = CACHE / name
    if not (sim / "pipeline.yaml").is_file():
        simulate_to_dir("bridge-total-station", sim, seed=seed, overrides=overrides, progress=print)
    result = run(load_pipeline(sim / "pipeline.yaml"), sim / "out", progress=print)
    return {"table": result.trajectory, "rejected": result.metrics.get("rejected_prism", []), "sim": sim}


def main() -> None:
    from trackfusion.sensors.fileio import read_csv_table
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start-s", type=float, default=600.0)
    ap.add_argument("--duration-s", type=float, default=10.0)
    args = ap.parse_args()
    t0, t1 = args.start_s, args.start_s + args.duration_s
    mislock = (f"total_stations.stations.0.mislocks=[{{start_s: {t0}, duration_s: {args.duration_s}, "
               "target_n_m: [-380.0, -4.0, 2.0]}]")
    clean = _run(f"bridge-total-station-{args.seed}-clean", args.seed, [])
    bad = _run(f"bridge-total-station-{args.seed}-mislock-{t0:g}-{args.duration_s:g}", args.seed, [mislock])
    t = clean["table"]["t_s"]
    if not np.array_equal(t, bad["table"]["t_s"]):
        raise SystemExit("the two runs have different output times")
    truth = read_csv_table(bad["sim"] / "truth.csv")
    p_true = np.column_stack([np.interp(t, truth["t_s"], truth[k]) for k in ("e_m", "n_m", "u_m")]) * 1e3
    outside = (t < t0) | (t > t1)
    change = np.linalg.norm(_positions_mm(bad["table"]) - _positions_mm(clean["table"]), axis=1)
    err_clean = np.linalg.norm(_positions_mm(clean["table"]) - p_true, axis=1)
    err_bad = np.linalg.norm(_positions_mm(bad["table"]) - p_true, axis=1)
    rejected = [r for r in bad["rejected"] if r["station"] == "TS01" and r["reason"] == "mis_lock"]
    result = {
        "seed": args.seed, "interval_s": [t0, t1],
        "max_change_outside_mm": float(change[outside].max()),
        "max_change_inside_mm": float(change[~outside].max()),
        "max_error_outside_clean_mm": float(err_clean[outside].max()),
        "max_error_outside_mislock_mm": float(err_bad[outside].max()),
        "mis_lock_rejections_ts01": len(rejected),
        "mis_lock_rejections_in_interval": sum(1 for r in rejected if t0 - 0.5 <= r["t_s"] <= t1 + 0.5),
        "target_mm": 1.0,
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
