"""Benchmark: accuracy of ``trackfusion run`` on simulated surveys, against the truth.

Usage: python benchmarks/accuracy.py [--seeds 1 2 3] [--variants ...]
1. ``open-track-gnss`` (seed 002's set-up) for each seed, in variants in the shape of
   seed 002's table 3: GNSS only, GNSS + NHC, GNSS + NHC + odometer (all with ZUPT), then the full
   pipeline as simulated (adding the wheel-path factor, docs/wheel_path.md), the full pipeline
   with the correlated GNSS errors switched off (white fixes), and the full pipeline in 600 s chunks (the 44 min run has 4 joins: a seam would show against the batch), and in
   one batch said explicitly (``smoother.workers: 1``; the default is one batch as well), with and
   without the wheel path (chunked runs leave it out: pipeline.py). Relative
   accuracy at L = 5 m (MSE sigma1 and ADEV, vertical and lateral), absolute RMS, and the
   consistency RMS(error / sigma) per n axis; mean and worst over the seeds, and the consistency
   pooled over the seeds with its 95 % interval for honest sigmas (one run of the GNSS's
   correlated error holds only a few independent samples: evaluation/consistency.py).
2. ``curved-line`` with its 60 s GNSS outage: the largest position error inside the outage.
Simulations are cached under ``$TMPDIR/trackfusion-bench``. Writes benchmarks/results/accuracy.json.
Targets (relative accuracy of the GNSS survey): vertical MSE <= 0.15 mm, ADEV <= 0.07 mm; lateral MSE <= 0.25, ADEV <= 0.12 mm;
consistency within 0.5..2. Seed 002's field results: vertical 0.31 / 0.13, lateral 0.51 / 0.25 mm.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from provenance import git_commit, write_result

RESULTS = Path(__file__).resolve().parent / "results" / "accuracy.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
VARIANTS = {
    # the wheel path needs the odometer's distance but not its factor: off where the table leaves out
    "gnss": {"nhc": False, "odometer": False, "wheel_path": False},
    "gnss+nhc": {"odometer": False, "wheel_path": False},
    "gnss+nhc+odometer": {"wheel_path": False},
    "default (+ wheel path)": {},  # as simulated: the pipeline.yaml of the scenario
    "full, white GNSS": {"gnss": {"correlated_sigma_h_mm": 0.0, "correlated_sigma_v_mm": 0.0}},
    "full, 600 s chunks": {"smoother": {"chunk_s": 600.0, "overlap_s": 120.0}},  # no wheel path in chunks
    # the default is one batch on any machine: these two say it explicitly
    "full, one batch": {"smoother": {"workers": 1}},
    "gnss+nhc+odometer, one batch": {"smoother": {"workers": 1}, "wheel_path": False},
}
TARGETS = {"vertical": (0.15, 0.07), "lateral": (0.25, 0.12)}
SEED_002 = {"vertical": (0.31, 0.13), "lateral": (0.51, 0.25)}


def simulated(scenario: str, seed: int) -> Path:
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"{scenario}-{seed}"
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir(scenario, out, seed=seed)
    return out


def run_variant(sim: Path, factors: dict, label: str):
    from trackfusion.pipeline import parse_pipeline, run
    data = yaml.safe_load((sim / "pipeline.yaml").read_text())
    for name, value in factors.items():
        if name == "smoother":
            data.setdefault("smoother", {}).update(value)
        else:
            data["factors"][name] = value
    safe = label.replace(" ", "").replace(",", "_").replace("+", "-")
    return run(parse_pipeline(data, str(sim / "pipeline.yaml"), sim), sim / f"out-{safe}")


def figures(metrics: dict) -> dict:
    ra = metrics["relative_accuracy"]
    return {
        **{f"{c}_{k}_mm": ra[c][f"{k}_at_threshold_mm"] for c in ("vertical", "lateral") for k in ("mse", "adev")},
        **{f"{c}_abs_rms_mm": metrics["absolute_error"][c]["rms_mm"] for c in ("along", "lateral", "vertical")},
        **{f"consistency_{a}": v for a, v in metrics["consistency_rms_error_over_sigma"].items()},
        **{f"consistency_{a}_n_eff": v["n_eff"] for a, v in metrics["consistency"].items()},
        **{f"consistency_{a}_samples": v["samples"] for a, v in metrics["consistency"].items()},
        "run_time_s": metrics["run_time_s"], "rejected_gnss": len(metrics["rejected_gnss"]),
    }


def pooled_consistency(rows: list[dict]) -> dict:
    """RMS(error / sigma) per axis pooled over the seeds' runs, with its 95 % interval for honest
    sigmas (evaluation/consistency.py: one run of a correlated error holds few independent samples)."""
    from trackfusion.evaluation.consistency import pooled
    return {a: pooled([{"rms": r[f"consistency_{a}"], "n_eff": r[f"consistency_{a}_n_eff"],
                        "samples": r[f"consistency_{a}_samples"]} for r in rows]) for a in "enu"}


def outage_drift(seed: int) -> dict:
    """Largest error inside the curved-line scenario's GNSS outage(s)."""
    from trackfusion.sensors.fileio import read_csv_table
    sim = simulated("curved-line", seed)
    result = run_variant(sim, {}, "full")
    cfg = json.loads((sim / "truth.json").read_text())["config"]
    truth = read_csv_table(sim / "truth.csv")
    tab = result.trajectory
    out = []
    for iv in cfg["gnss"]["outages"]:
        start, end = iv["start_s"], iv["start_s"] + iv["duration_s"]
        sel = (tab["t_s"] >= start) & (tab["t_s"] <= end)
        err = np.column_stack([tab[c][sel] - np.interp(tab["t_s"][sel], truth["t_s"], truth[c])
                               for c in ("e_m", "n_m", "u_m")])
        out.append({"start_s": start, "end_s": end,
                    "max_3d_mm": float(np.max(np.linalg.norm(err, axis=1)) * 1e3),
                    "max_abs_enu_mm": (np.max(np.abs(err), axis=0) * 1e3).tolist()})
    return {"seed": seed, "outages": out, **figures(result.metrics)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", type=Path, default=RESULTS, help="JSON result file")
    args = ap.parse_args()
    rows: dict[str, list[dict]] = {v: [] for v in args.variants}
    for seed in args.seeds:
        sim = simulated("open-track-gnss", seed)
        for label in args.variants:
            factors = VARIANTS[label]
            rows[label].append({"seed": seed, **figures(run_variant(sim, factors, label).metrics)})
            print(f"seed {seed} {label}: {rows[label][-1]}", flush=True)
    summary = {}
    for label, rs in rows.items():
        keys = [k for k in rs[0] if k != "seed"]
        summary[label] = {k: {"mean": float(np.mean([r[k] for r in rs])), "worst": float(np.max([r[k] for r in rs]))}
                          for k in keys}
        summary[label]["consistency_pooled"] = pooled_consistency(rs)
    outage = outage_drift(args.seeds[0])
    print()
    print(f"open-track-gnss, L = 5 m, mean (worst) over seeds {args.seeds} [mm]")
    print(f"{'variant':<20}{'vert MSE':>16}{'vert ADEV':>16}{'lat MSE':>16}{'lat ADEV':>16}{'abs RMS v/l':>16}  consistency e/n/u")
    for label, s in summary.items():
        cells = "".join(f"{s[k]['mean']:>8.3f} ({s[k]['worst']:.3f})"
                        for k in ("vertical_mse_mm", "vertical_adev_mm", "lateral_mse_mm", "lateral_adev_mm"))
        print(f"{label:<20}{cells}{s['vertical_abs_rms_mm']['mean']:>8.1f}/{s['lateral_abs_rms_mm']['mean']:.1f}"
              f"   {s['consistency_e']['mean']:.2f}/{s['consistency_n']['mean']:.2f}/{s['consistency_u']['mean']:.2f}")
    print(f"consistency RMS(error/sigma) pooled over seeds {args.seeds}, e / n / u [95 % interval for honest sigmas]")
    for label, s in summary.items():
        print(f"{label:<20}" + "  ".join(f"{a} {c['rms']:.2f} [{c['interval_95'][0]:.2f}, {c['interval_95'][1]:.2f}]"
                                         for a, c in s["consistency_pooled"].items()))
    print(f"targets: vertical {TARGETS['vertical']}, lateral {TARGETS['lateral']} (MSE, ADEV); "
          f"seed 002 field: vertical {SEED_002['vertical']}, lateral {SEED_002['lateral']}")
    for o in outage["outages"]:
        print(f"curved-line GNSS outage {o['start_s']:.0f}-{o['end_s']:.0f} s: largest error {o['max_3d_mm']:.1f} mm "
              f"(e/n/u {', '.join(f'{x:.1f}' for x in o['max_abs_enu_mm'])} mm)")
    result = {"commit": git_commit(),
              "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(), "seeds": args.seeds,
              "targets_mm": TARGETS, "seed_002_mm": SEED_002, "open_track_gnss": {"runs": rows, "summary": summary},
              "curved_line_outage": outage}
    write_result(args.out, result)


if __name__ == "__main__":
    main()
