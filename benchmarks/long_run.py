"""Benchmark: peak memory of ``trackfusion run`` on 2, 10 and 20 km runs at 500 Hz (chunks).

Usage: python benchmarks/long_run.py [--km 2 10 20] [--chunk-s 300] [--overlap-s 60] [--out FILE]
A simple straight open-track survey made long with ``--set``: the 1 km ``open-track-gnss``
track driven back and forth (one round trip = 2.04 km; 60 s hold before each), navigation-grade
IMU at 500 Hz, odometer at 100 Hz, GNSS at 0.2 Hz, trolley at 5 m/s (fewer samples to simulate
for the same distance; the smoother's memory depends on the duration). Simulations are cached
under ``$TMPDIR/trackfusion-bench``. Each run is a fresh process (peak = its VmHWM) with
``smoother.chunk_s`` / ``overlap_s`` as given, no reference and no fused.mcap; a second fresh
process only reads the log (``read_log``), which shows how much of the peak is the log in
memory. With ``--batch`` the shortest run is also made as one batch.
Target (memory of a long survey): 20 km within 1.5 x the 2 km peak. Each run's
``peak_tree_pss_mb``: the largest sum of the proportional set sizes of the run and its forked
children (benchmarks/speed.py's sampling, every 0.2 s).
Writes benchmarks/results/long_run.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from provenance import git_commit, pipeline_variant

RESULTS = Path(__file__).resolve().parent / "results" / "long_run.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
ROUND_TRIP_KM = 2.04

# the peak is the child's VmHWM: ru_maxrss would include the parent's resident size at the fork
_PEAK = "int(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1]) / 1024"
_CHILD_RUN = """
import json, sys, time
from trackfusion.pipeline import load_pipeline, run
tic = time.perf_counter()
r = run(load_pipeline(sys.argv[1]), sys.argv[2])
print(json.dumps({"wall_s": time.perf_counter() - tic, "imu_samples": r.metrics["imu_samples"],
                  "duration_s": r.metrics["duration_s"], "keyframes": r.metrics["keyframes"],
                  "hand_overs": r.metrics["factors"].get("hand_over", 0) // 2,
                  "timings_s": r.metrics["timings_s"],
                  "peak_rss_mb": %s}))
""" % _PEAK
_CHILD_READ = """
import json, sys
from trackfusion.sensors.mcap_log import read_log
read_log(sys.argv[1], topics=["/imu", "/odometer", "/gnss", "/inclinometer"])
print(json.dumps({"peak_rss_mb": %s}))
""" % _PEAK


def simulated(passes: int) -> Path:
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"long-500hz-{passes}passes-ros2"  # (the raw log with CDR topics)
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("open-track-gnss", out, seed=21, progress=print, overrides=[
            "imu.grade=navigation-500", "imu.rate_hz=500", "gnss.rate_hz=0.2", f"motion.passes={passes}",
            "motion.segments=[{hold_s: 60}, {move_to_m: 1040, speed_mps: 5, accel_mps2: 0.5}, {hold_s: 5},"
            " {move_to_m: 20, speed_mps: 5, accel_mps2: 0.5}]"])
    return out


def child(code: str, *args: str, tree_pss: bool = False) -> dict:
    """The JSON line a fresh process running ``code`` prints last; with ``tree_pss`` also
    ``peak_tree_pss_mb``: the largest sum of the PSS of it and its forked children (speed.py)."""
    if not tree_pss:
        out = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True)
        return json.loads(out.stdout.strip().splitlines()[-1])
    from speed import _peak_tree_pss_mb
    with tempfile.TemporaryFile("w+") as stdout, tempfile.TemporaryFile("w+") as stderr:
        proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=stdout, stderr=stderr, text=True)
        peak = _peak_tree_pss_mb(proc)
        stdout.seek(0)
        stderr.seek(0)
        if proc.wait():
            sys.exit(f"trackfusion run failed ({proc.returncode}): {stderr.read().strip()}")
        return {**json.loads(stdout.read().strip().splitlines()[-1]), "peak_tree_pss_mb": peak}


def measure(sim: Path, chunk_s: float | None, overlap_s: float) -> dict:
    label = "batch" if chunk_s is None else f"chunk{chunk_s:g}"
    path = pipeline_variant(sim, label, {"smoother": {"chunk_s": chunk_s, "overlap_s": overlap_s},
                                         "outputs": {"fused_mcap": False}}, drop_reference=True)
    return child(_CHILD_RUN, str(path), str(sim / f"out-{label}"), tree_pss=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--km", type=float, nargs="+", default=[2, 10, 20])
    ap.add_argument("--chunk-s", type=float, default=300.0)
    ap.add_argument("--overlap-s", type=float, default=60.0)
    ap.add_argument("--batch", action="store_true", help="also the shortest run as one batch")
    ap.add_argument("--out", type=Path, default=RESULTS, help="JSON result file")
    args = ap.parse_args()
    rows = []
    for km in args.km:
        passes = max(1, round(km / ROUND_TRIP_KM))
        sim = simulated(passes)
        row = {"km": passes * ROUND_TRIP_KM, "passes": passes, **measure(sim, args.chunk_s, args.overlap_s),
               "read_only_peak_rss_mb": child(_CHILD_READ, str(sim / "log.mcap"))["peak_rss_mb"]}
        if args.batch and km == min(args.km):
            row["batch"] = measure(sim, None, args.overlap_s)
        rows.append(row)
        print(f"{row['km']:5.1f} km, {row['duration_s'] / 60:5.1f} min, {row['imu_samples']} IMU samples, "
              f"{row['hand_overs']} hand-overs: peak {row['peak_rss_mb']:.0f} MB, with its children (PSS) "
              f"{row['peak_tree_pss_mb']:.0f} MB (reading the log alone "
              f"{row['read_only_peak_rss_mb']:.0f} MB), wall {row['wall_s']:.1f} s"
              + (f"; one batch: peak {row['batch']['peak_rss_mb']:.0f} MB, wall {row['batch']['wall_s']:.1f} s"
                 if "batch" in row else ""), flush=True)
    ratio = rows[-1]["peak_rss_mb"] / rows[0]["peak_rss_mb"]
    print(f"peak ratio {rows[-1]['km']:.0f} km / {rows[0]['km']:.0f} km: {ratio:.2f} (target <= 1.5)")
    result = {"commit": git_commit(),
              "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(), "chunk_s": args.chunk_s,
              "overlap_s": args.overlap_s, "runs": rows, "peak_ratio_longest_to_shortest": ratio,
              "target_ratio": 1.5}
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
