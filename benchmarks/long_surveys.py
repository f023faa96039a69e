"""Benchmark: the accuracy of long surveys, smoothed in chunks, against a 1 h survey.

Usage: python benchmarks/long_surveys.py [--seeds 1 2 3] [--passes 4 8 41] [--out FILE] [--append]
                                        [--one-batch | --hour-chunks]
       python benchmarks/long_surveys.py --summary   (the summary of the runs in --out again)
The ``open-track-gnss`` scenario (1 km of track driven back and forth at 3 m/s, 200 Hz
navigation-grade IMU, odometer, 1 Hz RTK, the wheel-path factor; 14.7 min a round trip) made
longer with ``motion.passes``: 4 round trips (57 min) and 8 (1 h 55 min), one batch with the
default ``smoother.chunk_s: auto``, and 41 (9 h 48 min: ten chunks of an hour). Each survey is run
with its generated pipeline (the defaults) in a fresh process: its 5 m vertical / lateral MSE
and ADEV (the run's own evaluation against truth.csv), its wall time and peak memory (VmHWM),
and, for the chunked runs, the RMS of the 5 m error differences (error 5 m of travel further
minus the error here, lateral and vertical) over the pairs straddling a join, starting within
30 s of one, and elsewhere (benchmarks/chunk_seams.py's pairs). Targets (issue 17): 5 m
vertical MSE within 10 % of the 1 h survey's; errors near a join no larger than elsewhere.
Simulations are cached under ``$TMPDIR/trackfusion-bench``. Writes
benchmarks/results/long_surveys.json; with ``--append`` the runs are added to those already in
the file (a run of the same seed, passes and kind replaced) and the summary is made over all of
them (e.g. the 10 h survey of one seed after the 1 h and 2 h ones of three); with ``--one-batch``
the surveys are run as one batch (``smoother.chunk_s: null``), with ``--hour-chunks`` in chunks of
an hour (``smoother.chunk_s: 3600``, the default before ``auto``: what the chunks give away). A run
in one batch gets the figures at the joins chunks of an hour would have, for comparison.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from chunk_seams import errors_of, join_masks, pairs, rms_by_mask
from long_run import _PEAK, child
from provenance import git_commit, pipeline_variant

RESULTS = Path(__file__).resolve().parent / "results" / "long_surveys.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"

_CHILD = """
import json, sys, time
from trackfusion.pipeline import load_pipeline, run
tic = time.perf_counter()
r = run(load_pipeline(sys.argv[1]), sys.argv[2], force=True)
ra = r.metrics["relative_accuracy"]
print(json.dumps({"wall_s": time.perf_counter() - tic, "duration_s": r.metrics["duration_s"],
                  "imu_samples": r.metrics["imu_samples"], "factors": r.metrics["factors"],
                  **{f"{c}_{k}_mm": ra[c][f"{k}_at_threshold_mm"] for c in ("vertical", "lateral")
                     for k in ("mse", "adev")}, "peak_rss_mb": %s}))
""" % _PEAK


def simulated(seed: int, passes: int) -> Path:
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"open-track-gnss-{seed}-{passes}passes"
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("open-track-gnss", out, seed=seed, overrides=[f"motion.passes={passes}"])
    return out


#: the runs besides the default: their ``smoother.chunk_s`` and output folder
KINDS = {"one batch": (None, "out-long-batch"), "chunks of an hour": (3600.0, "out-long-hour-chunks")}


def run_survey(sim: Path, kind: str = "default") -> dict:
    """``trackfusion run`` of ``sim``'s pipeline.yaml in a fresh process (its figures as JSON);
    another ``kind`` (:data:`KINDS`): with its ``smoother.chunk_s``."""
    pipeline = sim / "pipeline.yaml"
    if kind != "default":
        pipeline = pipeline_variant(sim, _out_dir(kind), {"smoother": {"chunk_s": KINDS[kind][0]}})
    return child(_CHILD, str(pipeline), str(sim / _out_dir(kind)))


def _out_dir(kind: str) -> str:
    return KINDS[kind][1] if kind in KINDS else "out-long"


def join_figures(sim: Path, chunk_s: float, overlap_s: float, out: str = "out-long") -> dict:
    """RMS [mm] of the 5 m error differences, lateral / vertical, over the pairs across the
    joins, starting within 30 s of one and elsewhere (benchmarks/chunk_seams.py), and their counts."""
    from trackfusion.fusion.chunks import join_times
    from trackfusion.sensors.fileio import read_csv_table
    truth = read_csv_table(sim / "truth.csv")
    t, err = errors_of(sim, out, truth)
    i, j = pairs(t, np.interp(t, truth["t_s"], truth["chainage_m"]))
    joins = join_times(t[0], t[-1], chunk_s, overlap_s)
    masks = join_masks(t, i, j, joins)
    return {"joins_s": joins.tolist(), **{f"{k}_pairs": int(m.sum()) for k, m in masks.items()},
            **rms_by_mask(err, i, j, masks)}


def with_joins(row: dict, sim: Path) -> None:
    """Add to a run's ``row`` the figures (:func:`join_figures`) at its chunks' joins, or, for a run
    in one batch, at the joins chunks of an hour would have (for comparison), when there are any."""
    import yaml
    from trackfusion.fusion.settings import SmootherSettings
    written = yaml.safe_load((sim / "pipeline.yaml").read_text())
    spacing_s, smoother, kind = written["keyframes"]["spacing_s"], written.get("smoother", {}), row["run"]
    cfg = SmootherSettings(**{**smoother, **({"chunk_s": KINDS[kind][0]} if kind in KINDS else {})})
    limit_s = cfg.one_batch_up_to_s(spacing_s)
    if limit_s is None or row["duration_s"] <= limit_s:
        cfg = SmootherSettings(**{**smoother, "chunk_s": KINDS["chunks of an hour"][0]})
        limit_s = cfg.one_batch_up_to_s(spacing_s)
    if row["duration_s"] > limit_s:
        row["joins"] = join_figures(sim, cfg.chunk_length_s, cfg.chunk_overlap_s, _out_dir(kind))


def _label(row: dict) -> str:
    return str(row["passes"]) + ("" if row["run"] == "default" else f", {row['run']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--passes", type=int, nargs="+", default=[4, 8, 41])
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--append", action="store_true", help="add the runs to those in --out")
    ap.add_argument("--one-batch", action="store_true", help="the surveys as one batch (smoother.chunk_s: null)")
    ap.add_argument("--hour-chunks", action="store_true",
                    help="the surveys in chunks of an hour (smoother.chunk_s: 3600, the default before auto)")
    ap.add_argument("--summary", action="store_true", help="no new run: the summary of those in --out again")
    args = ap.parse_args()
    rows = []
    run = "one batch" if args.one_batch else "chunks of an hour" if args.hour_chunks else "default"
    args.append |= args.summary
    for seed in [] if args.summary else args.seeds:
        for passes in args.passes:
            sim = simulated(seed, passes)
            row = {"seed": seed, "passes": passes, "run": run, **run_survey(sim, run)}
            with_joins(row, sim)
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.append and args.out.is_file():
        new = {(r["seed"], r["passes"], r["run"]) for r in rows}
        kept = [r for r in (dict(r, run=r.get("run", "default")) for r in json.loads(args.out.read_text())["runs"])
                if (r["seed"], r["passes"], r["run"]) not in new]
        for r in kept:  # their join figures again, as this script computes them now (when their output is still there)
            sim = simulated(r["seed"], r["passes"])
            if (sim / _out_dir(r["run"]) / "trajectory.csv").is_file():
                with_joins(r, sim)
        rows = sorted(kept + rows, key=lambda r: (r["passes"], r["run"] != "default", r["seed"]))
    summary = {}
    for label in dict.fromkeys(_label(r) for r in rows):
        sel = [r for r in rows if _label(r) == label]
        summary[label] = {f"{c}_{k}_mm_mean": float(np.mean([r[f"{c}_{k}_mm"] for r in sel]))
                          for c in ("vertical", "lateral") for k in ("mse", "adev")}
        summary[label].update(hours=float(np.mean([r["duration_s"] for r in sel]) / 3600.0),
                              seeds=[r["seed"] for r in sel], wall_s_mean=float(np.mean([r["wall_s"] for r in sel])),
                              peak_rss_mb_max=float(max(r["peak_rss_mb"] for r in sel)))
        joined = [r["joins"] for r in sel if "joins" in r]
        for name in ("straddling", "within_30s", "elsewhere"):  # pooled over the seeds, by pairs
            have = [j for j in joined if f"{name}_lateral_mm" in j]
            n = sum(j[f"{name}_pairs"] for j in have)
            for c in ("lateral", "vertical"):
                if n:
                    summary[label][f"joins_{name}_{c}_mm"] = float(np.sqrt(
                        sum(j[f"{name}_pairs"] * j[f"{name}_{c}_mm"] ** 2 for j in have) / n))
    shortest = min(r["passes"] for r in rows)
    base = {r["seed"]: r["vertical_mse_mm"] for r in rows if r["passes"] == shortest and r["run"] == "default"}
    print("open-track-gnss, mean 5 m MSE / ADEV [mm], vertical; lateral; the vertical MSE over the shortest "
          "survey's of the same seeds (and of all seeds)")
    for label, s in summary.items():
        s["vertical_mse_ratio"] = s["vertical_mse_mm_mean"] / float(np.mean([base[seed] for seed in s["seeds"]]))
        s["vertical_mse_ratio_to_all_shortest"] = s["vertical_mse_mm_mean"] / float(np.mean(list(base.values())))
        print(f"{label:>14} passes ({s['hours']:.2f} h, seeds {s['seeds']}): {s['vertical_mse_mm_mean']:.4f} / "
              f"{s['vertical_adev_mm_mean']:.4f}; {s['lateral_mse_mm_mean']:.4f} / {s['lateral_adev_mm_mean']:.4f};"
              f" x {s['vertical_mse_ratio']:.3f} (x {s['vertical_mse_ratio_to_all_shortest']:.3f})")
    for r in rows:
        if "joins" in r:
            j = r["joins"]
            cells = "  ".join(f"{label} {j[f'{label}_lateral_mm']:.3f}/{j[f'{label}_vertical_mm']:.3f}"
                              f" ({j[f'{label}_pairs']})" for label in ("straddling", "within_30s", "elsewhere")
                              if f"{label}_lateral_mm" in j)
            print(f"seed {r['seed']}, {_label(r)} passes, {len(j['joins_s'])} joins, 5 m error differences "
                  f"lateral/vertical [mm] (pairs): {cells}")
    result = {"commit": git_commit(), "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(),
              "runs": rows, "summary": summary, "target_vertical_mse_ratio": 1.1}
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
