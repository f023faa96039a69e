"""Benchmark: ``trackfusion init`` + ``run`` on a car-like simulated survey (IMU + GNSS, no
odometer), as each vehicle kind, against the truth.

Usage: python benchmarks/init_road_vehicle.py [--seed 1] [--nhc-mm-per-s 100 10]
The ``curved-line`` scenario (clothoids, a 1000 m arc with cant, a vertical curve) driven three
times back and forth at 12 m/s (1 m/s^2) with 5 s stops, 12 min at 200 Hz, navigation grade, 1 Hz
RTK fixes, no odometer and no GNSS outage; its pipeline deleted, ``init --vehicle KIND
--imu-grade navigation`` writes the one that is run (for a road vehicle, with each NHC sigma
given). Prints and writes benchmarks/results/init_road_vehicle.json: the RMS position error per
ENU axis [mm], the rejected fixes, the iterations, the wall time. Seed 1 (shared machine):
trolley 11.3 / 6.3 / 12.8 mm, 3 iterations; road-vehicle NHC 100 mm/s 13.3 / 6.5 / 15.6 mm, no
fix rejected, 3 iterations; NHC 10 mm/s 13.3 / 6.5 / 15.5 mm (init's road GNSS model, 3 mm slow error,
against the simulator's railway 8 / 15 mm; with that model: 10.3 / 5.2 / 15.5 mm). (Before the simulator's IMU
samples were exact over each interval, docs/simulation.md: road-vehicle 72.5 mm vertical, 33 good
fixes rejected, 25 iterations, 71 s; the kinks at the cant ramps' ends at 12 m/s.) (The issue's car-survey target,
a 57 min ROS 2 bag through init and run with <= 6 mm RMS per axis, needs the bag reader; this is
the road-vehicle path on the simulator's own log.)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "init_road_vehicle.json"
SEGMENTS = "[{hold_s: 60}, {move_to_m: 820, speed_mps: 12, accel_mps2: 1.0}, {hold_s: 5}, {move_to_m: 20, speed_mps: 12, accel_mps2: 1.0}]"


def _cli(*args: str) -> None:
    subprocess.run([sys.executable, "-c", "from trackfusion.cli import entry; entry()", *args], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _errors_mm(d: Path, out: Path) -> list[float]:
    sys.path.insert(0, str(ROOT / "tests"))
    from surveys import errors_against_truth
    from trackfusion.sensors.fileio import read_csv_table
    err, _ = errors_against_truth(d, read_csv_table(out / "trajectory.csv"))
    return (np.sqrt(np.mean(err**2, axis=0)) * 1e3).tolist()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--nhc-mm-per-s", type=float, nargs="+", default=[100.0, 10.0])
    args = ap.parse_args()
    d = Path(tempfile.mkdtemp(prefix="init-road-")) / "sim"
    _cli("simulate", "curved-line", "--out", str(d), "--seed", str(args.seed), "--set", "odometer=null",
         "--set", "gnss.outages=[]", "--set", "motion.passes=3", "--set", f"motion.segments={SEGMENTS}")
    (d / "pipeline.yaml").unlink()
    cases = [("trolley", None)] + [("road-vehicle", s) for s in args.nhc_mm_per_s]
    rows = []
    for kind, sigma in cases:
        name = kind if sigma is None else f"{kind}-nhc{sigma:g}"
        sets = ["--set", "inputs.reference=truth.csv", "--set", "outputs.report=false",
                "--set", "geometry.enabled=false"]
        if sigma is not None:
            sets += ["--set", f"factors.nhc={{sigma_lateral_mm_per_s: {sigma}, sigma_vertical_mm_per_s: {sigma}}}"]
        _cli("init", str(d / "log.mcap"), "--out", str(d / f"{name}.yaml"), "--vehicle", kind,
             "--imu-grade", "navigation", *sets)
        tic = time.perf_counter()
        _cli("run", str(d / f"{name}.yaml"), "--out", str(d / f"out-{name}"))
        wall = time.perf_counter() - tic
        m = json.loads((d / f"out-{name}" / "metrics.json").read_text())
        row = {"case": name, "rms_enu_mm": _errors_mm(d, d / f"out-{name}"), "rejected_gnss": len(m["rejected_gnss"]),
               "iterations": m["iterations"], "wall_s": wall}
        rows.append(row)
        e, n, u = row["rms_enu_mm"]
        print(f"{name:24s} RMS E {e:7.2f}  N {n:7.2f}  U {u:7.2f} mm; {row['rejected_gnss']} fixes rejected, "
              f"{row['iterations']} iterations, {wall:.0f} s")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"seed": args.seed, "cases": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
