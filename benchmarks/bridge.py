"""Benchmark: the seed-003 bridge survey (``bridge-total-station``) end to end, several seeds.

Usage: python benchmarks/bridge.py [--seeds 1 2 3] [--variants]
For each seed: simulate the 54-minute, 500 Hz round trip with two robotic total stations
(drawn clock offsets and drifts, tilts up to 4", orientation errors, set-up errors of the
instrument points of 1 mm per axis, 0.5" / 3 mm + 1.5 ppm noise), run the pipeline (registration
in the factor graph) and compare with the truth:

- each station's clock offset (at IMU time 0) minus the truth [ms], its drift, and ``r_max``;
- each station's tilt about its north axis (the component seen along the east-west bridge) and
  about its east axis (rotation about the line of sight: not observable on this geometry),
  and the orientation error, minus the truth [arcsec]; its translation minus the drawn set-up
  error [mm], with the sigmas of both;
- the round trip's repeatability after fusion (seed 003 tables 3-4: max |r|, mean, std, ppm);
- the absolute RMS error against the truth, vertical and lateral; RMS(error / sigma) per ENU axis
  with its effective independent samples and the 95 % interval for honest sigmas;
- the overlap residuals TS01-TS02 before registration, after seed 003's method and after the
  factor graph's (tables 1-2 form);
- the wall time of the whole run with its outputs written (``timings_s.wall_s``, since
  2026-12-07; ``timings_s.total_s`` before, which leaves the writing out: ``run_before_outputs_s``;
  the machine may be shared), and its CPU seconds with its forked workers' (``cpu_s``) and the load
  average before and after it. (The interpreter's start, about 1 s, is outside both.)
With ``--variants`` (first seed only) the survey is also fused with ``registration: seed``
and ``registration: none`` for a side-by-side of the fused results.
Simulations are cached under ``$TMPDIR/trackfusion-bench`` (``--work``: elsewhere). Writes benchmarks/results/bridge.json.
Targets (total-station registration): clocks within 2 ms, tilt within 0.5", round-trip std <= 0.5 mm and max |r|
<= 2 mm (elevation and across the track), absolute RMS <= 1.5 mm, total run < 60 s on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import yaml

RESULTS = Path(__file__).resolve().parent / "results" / "bridge.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
TARGETS = {"clock_ms": 2.0, "tilt_north_axis_arcsec": 0.5, "round_trip_std_mm": 0.5, "round_trip_max_mm": 2.0,
           "absolute_rms_mm": 1.5, "run_s": 60.0}


def simulated(seed: int) -> Path:
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"bridge-total-station-{seed}-ros2"  # (the raw log with CDR topics)
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("bridge-total-station", out, seed=seed)
    return out


#: where the runs write their outputs (``--out-root``; default: beside each cached simulation)
OUT_ROOT: Path | None = None


def run(sim: Path, registration: str):
    from trackfusion.pipeline import parse_pipeline, run as run_pipeline
    data = yaml.safe_load((sim / "pipeline.yaml").read_text())
    data["factors"]["total_stations"] = {"enabled": True, "registration": registration}
    out = (OUT_ROOT / sim.name if OUT_ROOT is not None else sim) / f"out-{registration}"
    return run_pipeline(parse_pipeline(data, str(sim / "pipeline.yaml"), sim), out)


def clock_error_in_tracking_ms(offset_s: float, drift_ppm: float, truth: dict) -> float:
    """Largest |clock error| [ms] over the station's tracking intervals (IMU time): the offset at
    IMU time 0 extrapolates the drift outside them (TS02 tracks from about 1000 s on)."""
    t = np.array(truth["tracking_intervals_s"], dtype=float).ravel()
    err = (offset_s - truth["clock_offset_s"]) + 1e-6 * (drift_ppm - truth["clock_drift_ppm"]) * t
    return float(1e3 * np.max(np.abs(err)))


def figures(metrics: dict, truth: dict) -> dict:
    out: dict = {"stations": {}}
    for sid, tr in truth["total_stations"].items():
        sync = metrics["time_sync"][sid]
        est = metrics["registration"]["stations"][sid]
        sigma = est.get("sigma", {})
        out["stations"][sid] = {
            "clock_error_ms": 1e3 * (sync["offset_s"] - tr["clock_offset_s"]),
            "clock_error_in_tracking_ms": clock_error_in_tracking_ms(sync["offset_s"], sync["drift_ppm"], tr),
            "clock_offset_sigma_ms": sigma.get("clock_offset_ms"),
            "tilt_sigma_arcsec": sigma.get("tilt_arcsec"),
            "tilt_vector_error_arcsec": float(np.hypot(est["tilt_arcsec"][0] - tr["tilt_arcsec"][0],
                                                       est["tilt_arcsec"][1] - tr["tilt_arcsec"][1])),
            "clock_error_correlation_only_ms": 1e3 * (sync["offset_correlation_s"] - tr["clock_offset_s"]),
            "drift_error_ppm": sync["drift_ppm"] - tr["clock_drift_ppm"], "r_max": sync["r_max"],
            "tilt_north_axis_error_arcsec": est["tilt_arcsec"][1] - tr["tilt_arcsec"][1],
            "tilt_east_axis_error_arcsec": est["tilt_arcsec"][0] - tr["tilt_arcsec"][0],
            "orientation_error_arcsec": est["orientation_error_arcsec"] - tr["orientation_error_arcsec"],
            "tilt_true_arcsec": tr["tilt_arcsec"], "position_error_true_mm": tr.get("position_error_mm"),
            "translation_error_mm": (np.subtract(est["translation_mm"], tr.get("position_error_mm", 0.0))).tolist(),
            "translation_sigma_mm": sigma.get("translation_mm")}
    rt = metrics["round_trip"]
    out["round_trip"] = {when: {c: {k: rt[when][c][k] for k in ("max_abs_signed_mm", "mean_mm", "std_mm",
                                                                "relative_accuracy_ppm")}
                                for c in ("elevation", "across_track")} for when in ("before_fusion", "after_fusion")}
    out["absolute_rms_mm"] = {c: metrics["absolute_error"][c]["rms_mm"] for c in ("vertical", "lateral", "along")}
    pair = metrics["registration"]["pairs"]["TS01-TS02"]
    out["overlap_TS01_TS02"] = {m: {c: {k: pair[m][c][k] for k in ("max_abs_mm", "mean_mm", "std_mm", "slope_mm_per_m",
                                                                  "relative_accuracy_ppm")}
                                    for c in ("elevation", "across_track")}
                                for m in ("before", "seed_003", "factor_graph") if m in pair}
    out["consistency_rms_error_over_sigma"] = metrics.get("consistency_rms_error_over_sigma")
    out["consistency"] = metrics.get("consistency")
    out["rejected_prism"] = len(metrics["rejected_prism"])
    out["run_s"] = metrics["timings_s"]["wall_s"]  # with the outputs written
    out["run_before_outputs_s"] = metrics["timings_s"]["total_s"]
    out["timings_s"] = metrics["timings_s"]
    return out


def cpu_s() -> float:
    """CPU seconds [s] of this process and of its children waited for (the run's forked workers)."""
    import resource
    return sum(resource.getrusage(who).ru_utime + resource.getrusage(who).ru_stime
               for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))


def checks(f: dict) -> dict:
    st = f["stations"].values()
    rt = f["round_trip"]["after_fusion"]
    return {
        "clock_ms": max(abs(s["clock_error_ms"]) for s in st),
        # the component seen on this east-west bridge; the one about the east axis (the line of
        # sight) is a vertical shift of the whole line, equal to the station's height offset,
        # and keeps its prior: reported as tilt_vector_arcsec, not targeted (docs/total_stations.md)
        "tilt_north_axis_arcsec": max(abs(s["tilt_north_axis_error_arcsec"]) for s in st),
        "round_trip_std_mm": max(rt[c]["std_mm"] for c in rt),
        "round_trip_max_mm": max(abs(rt[c]["max_abs_signed_mm"]) for c in rt),
        "absolute_rms_mm": max(f["absolute_rms_mm"]["vertical"], f["absolute_rms_mm"]["lateral"]),
        "run_s": f["run_s"]}


def reported(f: dict) -> dict:
    """Figures printed beside the targets, with no target of their own."""
    st = f["stations"].values()
    return {"clock_in_tracking_ms": max(s["clock_error_in_tracking_ms"] for s in st),
            "tilt_vector_arcsec": max(s["tilt_vector_error_arcsec"] for s in st),
            "tilt_north_sigma_arcsec": max((s["tilt_sigma_arcsec"] or [0, 0])[1] for s in st),
            "estimation_core_s": sum(f["timings_s"].get(k, 0.0) for k in
                                     ("stations_s", "preintegrate_s", "build_s", "solve_s", "marginals_s"))}


def run_variants(seed: int) -> dict:
    """The survey of ``seed`` fused with the seed's registration and with none."""
    sim = simulated(seed)
    truth = json.loads((sim / "truth.json").read_text())
    variants = {"seed": seed}
    for reg in ("seed", "none"):
        f = figures(run(sim, reg).metrics, truth)
        variants[reg] = {"figures": f, "checks": checks(f)}
        print(f"seed {seed}, registration {reg}: " + ", ".join(f"{k} {v:.3g}" for k, v in variants[reg]["checks"].items()))
    return variants


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--variants", action="store_true")
    ap.add_argument("--out-root", type=Path, default=None,
                    help="write the runs' outputs under this folder (default: beside the cached simulations)")
    ap.add_argument("--results", type=Path, default=RESULTS, help="JSON result file")
    ap.add_argument("--work", type=Path, default=None, help="cache the simulations here")
    ap.add_argument("--variants-only", action="store_true",
                    help="run only the variants (first seed) and add them to an existing results file")
    args = ap.parse_args()
    global OUT_ROOT, CACHE
    OUT_ROOT, CACHE = args.out_root, args.work or CACHE
    if args.variants_only:
        result = json.loads(RESULTS.read_text())
        result["variants"] = run_variants(args.seeds[0])
        RESULTS.write_text(json.dumps(result, indent=1, default=float) + "\n")
        print(f"wrote {RESULTS}")
        return
    per_seed, worst = {}, {k: 0.0 for k in TARGETS}
    for seed in args.seeds:
        sim = simulated(seed)
        truth = json.loads((sim / "truth.json").read_text())
        load_before, cpu0 = os.getloadavg()[0], cpu_s()
        f = figures(run(sim, "graph").metrics, truth)
        # the run's CPU seconds (this process and its forked workers): less swayed by a shared machine
        f["cpu_s"], f["load_average_1min"] = cpu_s() - cpu0, [load_before, os.getloadavg()[0]]
        c = checks(f)
        per_seed[seed] = {"figures": f, "checks": c, "reported": reported(f)}
        worst = {k: max(worst[k], c[k]) for k in TARGETS}
        print(f"seed {seed}: " + ", ".join(f"{k} {v:.3g} (target {TARGETS[k]:g})" for k, v in c.items()))
        print(f"  run: {f['run_s']:.1f} s wall with its outputs written ({f['run_before_outputs_s']:.1f} s before them), "
              f"{f['cpu_s']:.1f} CPU s (with its workers), load average "
              f"{f['load_average_1min'][0]:.1f} before / {f['load_average_1min'][1]:.1f} after")
        print(f"  also: " + ", ".join(f"{k} {v:.3g}" for k, v in per_seed[seed]["reported"].items())
              + f", consistency e/n/u {f['consistency_rms_error_over_sigma']}")
        for sid, s in f["stations"].items():
            print(f"  {sid}: clock {s['clock_error_ms']:+.2f} ms (correlation only {s['clock_error_correlation_only_ms']:+.2f}),"
                  f" r_max {s['r_max']:.3f}, tilt N-axis {s['tilt_north_axis_error_arcsec']:+.2f}\","
                  f" (sigma {(s['tilt_sigma_arcsec'] or [0, 0])[1]:.2f}), E-axis {s['tilt_east_axis_error_arcsec']:+.2f}\" (not observable),"
                  f" orientation {s['orientation_error_arcsec']:+.2f}\", translation - set-up error "
                  f"{np.round(s['translation_error_mm'], 2)} mm (sigma {np.round(s['translation_sigma_mm'] or [], 2)})")
        for m, tab in f["overlap_TS01_TS02"].items():
            print(f"  overlap {m:>12}: " + "; ".join(
                f"{c} max {v['max_abs_mm']:.2f} mean {v['mean_mm']:+.2f} std {v['std_mm']:.2f} mm, "
                f"slope {v['slope_mm_per_m']:+.2e} mm/m, {v['relative_accuracy_ppm']:.1f} ppm" for c, v in tab.items()))
    variants = run_variants(args.seeds[0]) if args.variants else {}
    result = {"benchmark": "bridge", "targets": TARGETS, "worst": worst,
              "met": {k: worst[k] <= TARGETS[k] for k in TARGETS}, "seeds": per_seed, "variants": variants,
              "cpu_count": os.cpu_count(), "load_average": list(os.getloadavg()),
              "note": "wall times measured on a machine shared with other jobs"}
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print("worst over seeds: " + ", ".join(f"{k} {v:.3g} ({'met' if v <= TARGETS[k] else 'NOT met'})"
                                             for k, v in worst.items()))
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
