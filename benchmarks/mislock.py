"""Benchmark: a total station locked onto a wrong target for 10 s (robustness target).

Usage: python benchmarks/mislock.py [--seed 1] [--start-s 600] [--duration-s 10]
                                   [--moving-offset-m 0.02 --work DIR]
Simulates ``bridge-total-station`` twice with the same seed, once clean and once with TS01
reading another reflector (8 m beside the track, 400 m away) for ``duration_s``, runs the
pipeline on both, and compares the two fused trajectories (IMU origin, 100 Hz) with each other
and with the truth outside the mis-lock interval. Simulations are cached under
``$TMPDIR/trackfusion-bench``. Writes benchmarks/results/mislock.json.
``--moving-offset-m``: instead, the reflector moves along with the prism that far beside it
(``simulation.faults.inject_prism_mislock``, ``moving=True``, from ``start_s`` of the station
clock), injected into the clean log; the faulty log and both runs' outputs go to ``--work``
(the cache is only read). Writes benchmarks/results/mislock_moving.json.
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


def _run(name: str, seed: int, overrides: list[str], work: Path | None = None, log: Path | None = None
         ) -> dict[str, np.ndarray]:
    """Run the cached simulation ``name`` (made first if missing); with ``work``, on ``log`` and
    with the outputs there (the cache only read)."""
    import yaml
    from trackfusion.pipeline import load_pipeline, parse_pipeline, run
    from trackfusion.simulation.scenarios import simulate_to_dir
    sim = CACHE / name
    if not (sim / "pipeline.yaml").is_file():
        simulate_to_dir("bridge-total-station", sim, seed=seed, overrides=overrides, progress=print)
    if work is None:
        result = run(load_pipeline(sim / "pipeline.yaml"), sim / "out", progress=print)
    else:
        data = yaml.safe_load((sim / "pipeline.yaml").read_text())
        data["inputs"]["log"] = str(log or sim / "log.mcap")
        data["inputs"]["reference"] = str(sim / "truth.csv")
        out = work / f"out-{(log or sim / 'log.mcap').stem}-{name}"
        result = run(parse_pipeline(data, str(sim / "pipeline.yaml"), sim), out, progress=print)
    return {"table": result.trajectory, "rejected": result.metrics.get("rejected_prism", []), "sim": sim,
            "faults": result.metrics.get("faults", {})}


def _moving(seed: int, t0: float, duration_s: float, offset_m: float, work: Path):
    """Clean and faulty runs with TS01 locked onto a reflector moving ``offset_m`` beside the
    prism for ``duration_s`` from ``t0`` (station clock); returns them and the interval on the
    IMU clock."""
    from trackfusion.sensors.mcap_log import read_log, write_log
    from trackfusion.simulation.faults import inject_prism_mislock
    name = f"bridge-total-station-{seed}-clean"
    clean = _run(name, seed, [], work)
    work.mkdir(parents=True, exist_ok=True)
    faulty, info = inject_prism_mislock(read_log(CACHE / name / "log.mcap"), strength=duration_s, start_s=t0,
                                        offset_m=offset_m, moving=True)
    path = work / f"moving-{offset_m:g}-{t0:g}-{duration_s:g}.mcap"
    write_log(path, faulty)
    bad = _run(name, seed, [], work, path)
    tr = json.loads((CACHE / name / "truth.json").read_text())["total_stations"]["TS01"]
    to_imu = [(x - tr["clock_offset_s"]) / (1.0 + 1e-6 * tr["clock_drift_ppm"]) for x in (info["t_s"][0], info["t_s"][-1])]
    return clean, bad, to_imu, info


def main() -> None:
    from trackfusion.sensors.fileio import read_csv_table
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start-s", type=float, default=600.0)
    ap.add_argument("--duration-s", type=float, default=10.0)
    ap.add_argument("--moving-offset-m", type=float, default=None)
    ap.add_argument("--work", type=Path, default=None, help="outputs (with --moving-offset-m)")
    args = ap.parse_args()
    t0, t1 = args.start_s, args.start_s + args.duration_s
    extra = {}
    if args.moving_offset_m is not None:
        clean, bad, (t0, t1), info = _moving(args.seed, t0, args.duration_s, args.moving_offset_m,
                                             args.work or Path(tempfile.gettempdir()) / "mislock-moving")
        extra = {"moving_offset_m": args.moving_offset_m, "readings_injected": info["readings"],
                 "prism_mislocks": bad["faults"].get("prism_mislocks")}
    else:
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
        "target_mm": 1.0, **extra,
    }
    path = RESULTS.with_name("mislock_moving.json") if extra else RESULTS
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
