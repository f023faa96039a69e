"""Benchmark: the exact time parts (``smoother.part_s``, fusion/partitioned.py) against one batch.

Usage: python benchmarks/parts.py [--seeds 1 2 3] [--part-s 600] [--workers 1 2 4] [--dask] [--default-only] [--out FILE]
For each seed, the ``open-track-gnss`` survey (as simulated, 44 min at 200 Hz, wheel path on)
is run with the default configuration (one batch on any machine), with ``smoother.workers: 1``
(one batch, said explicitly) and in parts of ``--part-s`` seconds in each number of
``--workers`` local processes (with ``--dask`` also on a Dask ``LocalCluster`` of 2 worker
processes, ``smoother.engine: dask``). Prints and writes benchmarks/results/parts.json: per run the
largest position difference of trajectory.csv (%.12g: 10 nm at these coordinates) from the
default's, the 5 m vertical MSE / ADEV and the whole run's wall time (``run_time_s``; the
machine's load is written beside it: it is shared, so the times are indicative only).
``--default-only``: the default run alone (the 5 m figures over more seeds). ``--smoother``: the
smoother alone (``smooth()`` on the problem ``trackfusion run`` builds) of the first seed, in one
piece and in parts in each number of workers: solve and marginals wall time, largest position
difference and relative position-sigma difference (results/parts_smoother.json). Simulations are
cached as by benchmarks/accuracy.py.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from accuracy import run_variant, simulated
from provenance import git_commit

RESULTS = Path(__file__).resolve().parent / "results" / "parts.json"


def _positions(out_dir: Path) -> np.ndarray:
    from trackfusion.sensors.fileio import read_csv_table
    tab = read_csv_table(out_dir / "trajectory.csv")
    return np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")])


def smoother_only(seed: int, part_s: float, workers: list[int], out: Path) -> None:
    from dataclasses import replace
    from trackfusion import pipeline as P
    from trackfusion.fusion.smoother import smooth
    sim = simulated("open-track-gnss", seed)
    pl = P.load_pipeline(sim / "pipeline.yaml")
    log, _ = P._read(pl)
    prob = P.build_problem(pl, log, lambda _m: None)[0]
    ref, rows = None, []
    runs = [("one piece", {})] + [(f"parts of {part_s:g} s, {w} workers", {"part_s": part_s, "workers": w})
                                  for w in workers]
    for label, update in runs:
        load = os.getloadavg()[0]
        r = smooth(replace(prob, smoother=prob.smoother.model_copy(update=update)))
        ref = r if ref is None else ref
        row = {"seed": seed, "run": label, "solve_s": r.timings_s["solve_s"], "marginals_s": r.timings_s["marginals_s"],
               "max_position_difference_m": float(np.abs(r.pos_n - ref.pos_n).max()),
               "max_position_sigma_difference_rel": float(np.abs(r.sigma_pos_n_m / ref.sigma_pos_n_m - 1.0).max()),
               "load_average_1min": load}
        rows.append(row)
        print(json.dumps(row), flush=True)
    out.write_text(json.dumps({"machine": "2 shared CPUs (other agents' jobs running: times indicative)",
                               "runs": rows}, indent=1) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--part-s", type=float, default=600.0)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--default-only", action="store_true")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--smoother", action="store_true")
    ap.add_argument("--dask", action="store_true", help="also the parts on a Dask LocalCluster of 2 workers")
    args = ap.parse_args()
    if args.smoother:
        smoother_only(args.seeds[0], args.part_s, args.workers, RESULTS.with_name("parts_smoother.json"))
        return
    rows = []
    for seed in args.seeds:
        sim = simulated("open-track-gnss", seed)
        runs = {"default": {}} if args.default_only else {"default": {}, "one batch": {"smoother": {"workers": 1}}}
        for w in [] if args.default_only else args.workers:
            runs[f"parts of {args.part_s:g} s, {w} workers"] = {"smoother": {"part_s": args.part_s, "workers": w}}
        if args.dask and not args.default_only:
            runs[f"parts of {args.part_s:g} s, Dask LocalCluster of 2 workers"] = {
                "smoother": {"part_s": args.part_s, "workers": 2, "engine": "dask"}}
        ref = None
        for label, change in runs.items():
            load = os.getloadavg()[0]
            result = run_variant(sim, change, f"parts-{label}")
            pos = _positions(result.out_dir)
            ref = pos if ref is None else ref
            ra = result.metrics["relative_accuracy"]["vertical"]
            row = {"seed": seed, "run": label, "max_position_difference_um": float(np.abs(pos - ref).max() * 1e6),
                   "vertical_mse_5m_mm": ra["mse_at_threshold_mm"], "vertical_adev_5m_mm": ra["adev_at_threshold_mm"],
                   "iterations": result.metrics.get("iterations"),
                   "run_time_s": result.metrics["run_time_s"], "load_average_1min": load}
            rows.append(row)
            print(json.dumps(row), flush=True)
    default = [r for r in rows if r["run"] == "default"]
    summary = {
        "largest_position_difference_um": max(r["max_position_difference_um"] for r in rows),
        "dask_largest_position_difference_um": max((r["max_position_difference_um"] for r in rows
                                                    if "Dask" in r["run"]), default=None),
        "default_vertical_mse_adev_5m_mm_mean": [float(np.mean([r["vertical_mse_5m_mm"] for r in default])),
                                                 float(np.mean([r["vertical_adev_5m_mm"] for r in default]))],
        "default_vertical_mse_adev_5m_mm_worst": [max(r["vertical_mse_5m_mm"] for r in default),
                                                  max(r["vertical_adev_5m_mm"] for r in default)],
    }
    print(json.dumps(summary, indent=1))
    commit = git_commit()
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text(json.dumps({"commit": commit, "part_s": args.part_s, "seeds": args.seeds,
                                   "machine": "2 shared CPUs (other agents' jobs running: times indicative)",
                                   "summary": summary, "runs": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
