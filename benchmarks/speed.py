"""Benchmark: one hour of 500 Hz IMU data with odometer and GNSS through ``trackfusion run``.

Usage: python benchmarks/speed.py [--passes N] [--runs N] [--results FILE] [--chunk-s S]
Simulates ``open-track-gnss`` at 500 Hz with more passes (about an hour; cached under
``$TMPDIR/trackfusion-bench``), then runs the pipeline in fresh processes: ``--runs`` timed runs
(wall time of the whole process, to its exit; CPU seconds, the run's and its forked workers';
peak memory, VmHWM of the run's process), whose median is the figure (the host's speed drifts by
several per cent within minutes), then one run sampled for the peak memory of the run and its
forked children together (PSS). The timed runs are not sampled: reading ``smaps_rollup`` of the
2 GB process tree costs about 25 ms of CPU a sample, an eighth of a core at five samples a second,
which a run keeping both cores busy pays in wall time. Prints where the time goes (the
``timings_s`` of the median run's metrics.json) and writes benchmarks/results/speed.json (or
``--results``: ``--passes 8 --results benchmarks/results/speed_2h.json`` is the 1 h 55 min survey,
one batch by default).
Targets (speed of an hour at 200 Hz): under 60 s on 2 cores (>= 30 000 IMU samples/s) and under 4 GB.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from provenance import git_commit, pipeline_variant, write_result

RESULTS = Path(__file__).resolve().parent / "results" / "speed.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"


def simulated(passes: int) -> Path:
    """Folder of the cached 500 Hz simulation (made on first use)."""
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"speed-500hz-{passes}passes-ros2"  # (the raw log with CDR topics)
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("open-track-gnss", out, seed=11,
                        overrides=["imu.rate_hz=500", f"motion.passes={passes}"], progress=print)
    return out


def _peak_tree_pss_mb(proc: subprocess.Popen, every_s: float = 0.2) -> float:
    """Largest sum of the proportional set sizes of ``proc`` and its descendants (its smoothing
    workers: shared pages counted once) until it exits, sampled every ``every_s``."""
    def tree(pid: int) -> list[int]:
        try:
            kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        except OSError:
            return [pid]
        return [pid] + [q for k in kids for q in tree(int(k))]

    def pss_kb(pid: int) -> int:
        try:
            return next(int(l.split()[1]) for l in open(f"/proc/{pid}/smaps_rollup") if l.startswith("Pss:"))
        except (OSError, StopIteration):
            return 0
    peak = 0
    while proc.poll() is None:
        peak = max(peak, sum(pss_kb(p) for p in tree(proc.pid)))
        try:
            proc.wait(timeout=every_s)
        except subprocess.TimeoutExpired:
            pass
    return peak / 1024


#: the run's process: ``trackfusion run`` as the command runs it (cli.entry: cli.exit_now), printing
#: its own VmHWM last (ru_maxrss of a child includes this process's resident size at the fork)
CHILD = ("import sys\nfrom trackfusion.cli import exit_now, main\ncode = main(sys.argv[1:])\n"
         "print(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1])\n"
         "exit_now(code)")


def _run(pipeline: Path, out: Path, sampled: bool) -> dict:
    """One ``trackfusion run`` of ``pipeline`` into ``out`` in a fresh process: its wall time [s] to its
    exit, CPU seconds (with its forked workers), VmHWM [MB], metrics.json and, when ``sampled``,
    the peak PSS of its process tree [MB] (:func:`_peak_tree_pss_mb`)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryFile("w+") as stdout, tempfile.TemporaryFile("w+") as stderr:
        tic = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", CHILD, "run", str(pipeline), "--out", str(out)],
                                stdout=stdout, stderr=stderr, text=True)
        tree_pss_mb = _peak_tree_pss_mb(proc) if sampled else None
        code = proc.wait()
        wall = time.perf_counter() - tic
        stdout.seek(0)
        stderr.seek(0)
        if code:
            sys.exit(f"trackfusion run failed ({code}): {stderr.read().strip()}")
        child_stdout = stdout.read()
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # the run and its reaped forked workers
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime - before.ru_utime - before.ru_stime,
            "peak_rss_mb": int(child_stdout.strip().splitlines()[-1]) / 1024, "tree_pss_mb": tree_pss_mb,
            "metrics": json.loads((out / "metrics.json").read_text())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=4, help="round trips (4: about 57 min)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs, whose median is the figure (default 5)")
    ap.add_argument("--out", type=Path, help="output folder (default: out-speed beside the simulation)")
    ap.add_argument("--results", type=Path, default=RESULTS, help=f"JSON result file (default {RESULTS.name})")
    ap.add_argument("--chunk-s", help="smoother.chunk_s for the run (seconds, auto or null; default: the pipeline's)")
    args = ap.parse_args()
    sim = simulated(args.passes)
    pipeline = sim / "pipeline.yaml" if args.chunk_s is None else \
        pipeline_variant(sim, f"chunk-{args.chunk_s}", {"smoother": {"chunk_s": yaml.safe_load(args.chunk_s)}})
    out = args.out or sim / "out-speed"
    runs = sorted((_run(pipeline, out, sampled=False) for _ in range(max(1, args.runs))), key=lambda r: r["wall_s"])
    median = runs[len(runs) // 2]
    tree_pss_mb = _run(pipeline, out, sampled=True)["tree_pss_mb"]
    metrics = median["metrics"]
    samples = metrics["imu_samples"]
    wall = median["wall_s"]
    result = {
        "commit": git_commit(),
        "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(),
        "imu_samples": samples, "duration_min": metrics["duration_s"] / 60, "keyframes": metrics["keyframes"],
        "factors": sum(metrics["factors"].values()), "runs": len(runs), "wall_s": wall,
        "samples_per_s": samples / wall, "wall_s_runs": [r["wall_s"] for r in runs],
        "samples_per_s_best": samples / runs[0]["wall_s"], "cpu_s": median["cpu_s"],
        "peak_rss_mb": max(r["peak_rss_mb"] for r in runs), "peak_tree_pss_mb": tree_pss_mb,
        "timings_s": metrics["timings_s"], "chunk_s": args.chunk_s or "the pipeline's",
        "relative_accuracy_5m_mm": {c: {k: metrics["relative_accuracy"][c][f"{k}_at_threshold_mm"] for k in ("mse", "adev")}
                                    for c in ("vertical", "lateral")},
        "segments": metrics.get("segments", {}).get("count", 1),
        "load_average_1min": float(Path("/proc/loadavg").read_text().split()[0]),
        "targets": {"wall_s": 60.0, "samples_per_s": 30000, "peak_rss_mb": 4096},
    }
    print(f"{samples} IMU samples ({result['duration_min']:.1f} min at 500 Hz), {metrics['keyframes']} keyframes")
    print(f"wall {wall:.1f} s, the median of {len(runs)} runs ({runs[0]['wall_s']:.1f}-{runs[-1]['wall_s']:.1f} s; "
          f"target < 60 s), {samples / wall:.0f} samples/s (target >= 30000), CPU {median['cpu_s']:.1f} s (all "
          f"processes), peak memory {result['peak_rss_mb']:.0f} MB (target < 4096 MB); with its worker processes "
          f"{tree_pss_mb:.0f} MB (PSS)")
    print("where the time goes: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in metrics["timings_s"].items()))
    write_result(args.results, result)


if __name__ == "__main__":
    main()
