"""Benchmark: a car survey made by an independent simulator (``pyins``), as a ROS 2 bag written
by ``rosbags``, through ``trackfusion init`` (road-vehicle, navigation grade, the lever arms
given by ``--set``) and ``run``; the same data as KF-GINS-style F-R-D increments through
``import`` (``axes: frd``) and ``run``.

Usage: python benchmarks/car_survey.py [--minutes 57] [--seed 1] [--stated honest optimistic] [--estimate-time-constant]
The survey (tests/pyins_car.py): 57 min at 200 Hz, navigation-grade IMU errors drawn by pyins,
1 Hz RTK fixed fixes with white (8 / 15 mm) plus Gauss-Markov (2 / 3 mm, 600 s) error, their
stated std honest (the true total) or optimistic (half of it). Prints and writes
benchmarks/results/car_survey.json: per case the RMS position error per N/E/D axis [mm] against
pyins' truth, RMS(error/sigma) per axis, the fixes rejected, the GNSS variance factors
estimated, the whole-process wall and CPU time of ``run`` (shared machine), and the import
path's RMS difference from the bag's trajectory [mm]. ``--estimate-time-constant``: ``init`` sets
``factors.gnss.estimate_time_constant`` (fusion/gnss_time_constant.py), each case records the
estimate, and the results go to car_survey_time_constant.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "car_survey.json"
sys.path.insert(0, str(ROOT / "tests"))


def _cli(*args: str) -> tuple[float, float]:
    """Runs trackfusion in a new process; its wall and CPU time [s]."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from trackfusion.cli import entry; entry()", *args], check=True,
                   stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def init_args(log: Path, out: Path, extra: tuple[str, ...] = ()) -> list[str]:
    """``trackfusion init`` of a car survey: road-vehicle, navigation grade, the drawings' lever
    arms; ``extra``: more ``--set`` keys."""
    from pyins_car import ANTENNA_B_M, IMU_V_M
    sets = [f"sensors.gnss.lever_arm_b_m={ANTENNA_B_M.tolist()}", f"vehicle.lever_arm_imu_v_m={IMU_V_M.tolist()}",
            "outputs.report=false", *extra]
    return ["init", str(log), "--out", str(out), "--vehicle", "road-vehicle", "--imu-grade", "navigation",
            *[a for s in sets for a in ("--set", s)]]


def evaluate(survey, out: Path, pipeline: Path) -> dict:
    """Per-axis N/E/D error RMS [mm] and RMS(error/sigma) of a run's trajectory against the truth."""
    import yaml
    from pyins_car import truth_errors_m
    from trackfusion.sensors.fileio import read_csv_table
    tab = read_csv_table(out / "trajectory.csv")
    err_enu = truth_errors_m(survey, tab, yaml.safe_load(pipeline.read_text())["origin"])
    sig_enu = np.column_stack([tab[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")])
    m = json.loads((out / "metrics.json").read_text())
    ned = [1, 0, 2]
    return {"rms_ned_mm": (np.sqrt(np.mean(err_enu**2, axis=0))[ned] * 1e3).tolist(),
            "rms_error_over_sigma_ned": np.sqrt(np.mean((err_enu / sig_enu) ** 2, axis=0))[ned].tolist(),
            "rejected_gnss": len(m["rejected_gnss"]), "fixes": int(survey.fix_t_s.size),
            "gnss_noise": m.get("noise_estimates", {}).get("gnss"), "iterations": m["iterations"],
            "gnss_time_constant": m.get("noise_estimates", {}).get("gnss_time_constant")}


def run_case(survey, d: Path, name: str, extra: tuple[str, ...] = ()) -> dict:
    """Bag -> init -> run, and text -> import -> run, of one survey in folder ``d`` (``extra``:
    more ``--set`` keys of ``init``)."""
    from pyins_car import write_bag, write_text
    from trackfusion.sensors.fileio import read_csv_table
    write_bag(survey, d / "bag")
    _cli(*init_args(d / "bag", d / "bag.yaml", extra))
    wall, cpu = _cli("run", str(d / "bag.yaml"), "--out", str(d / "out-bag"))
    row = {"case": name, **evaluate(survey, d / "out-bag", d / "bag.yaml"), "wall_s": wall, "cpu_s": cpu}
    _cli("import", str(write_text(survey, d / "text")), "--out", str(d / "text.mcap"))
    _cli(*init_args(d / "text.mcap", d / "text.yaml", extra))
    _cli("run", str(d / "text.yaml"), "--out", str(d / "out-text"))
    a, b = read_csv_table(d / "out-bag" / "trajectory.csv"), read_csv_table(d / "out-text" / "trajectory.csv")
    diff = np.column_stack([a[c] - b[c] for c in ("e_m", "n_m", "u_m")])
    row["import_vs_bag_rms_mm"] = float(np.sqrt(np.mean(np.sum(diff**2, axis=1)))) * 1e3
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=57.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--stated", nargs="+", default=["honest", "optimistic"])
    ap.add_argument("--estimate-time-constant", action="store_true", help="the GNSS time constant estimated too")
    args = ap.parse_args()
    extra = ("factors.gnss.estimate_time_constant=true",) if args.estimate_time_constant else ()
    from pyins_car import make_car_survey
    root = Path(tempfile.mkdtemp(prefix="car-survey-"))
    rows = []
    for stated in args.stated:
        survey = make_car_survey(args.minutes * 60, stated=stated, seed=args.seed)
        (root / stated).mkdir()
        row = run_case(survey, root / stated, stated, extra)
        rows.append(row)
        n, e, dd = row["rms_ned_mm"]
        zn, ze, zd = row["rms_error_over_sigma_ned"]
        print(f"{stated:10s} RMS N {n:5.2f}  E {e:5.2f}  D {dd:5.2f} mm; error/sigma {zn:.2f} {ze:.2f} {zd:.2f}; "
              f"{row['rejected_gnss']}/{row['fixes']} fixes rejected, {row['iterations']} iterations; "
              f"run {row['wall_s']:.1f} s wall, {row['cpu_s']:.1f} s CPU (shared machine); "
              f"import vs bag {row['import_vs_bag_rms_mm']:.3g} mm RMS")
        if row["gnss_time_constant"]:
            print(f"           GNSS time constant: {row['gnss_time_constant']}")
    results = RESULTS.with_name("car_survey_time_constant.json") if args.estimate_time_constant else RESULTS
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps({"seed": args.seed, "minutes": args.minutes, "cases": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
