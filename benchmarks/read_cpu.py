"""Benchmark: CPU seconds of reading the speed run's log (``benchmarks/speed.py``'s hour at 500 Hz).

Usage: python benchmarks/read_cpu.py [--src DIR ...] [--repeats N] [--passes N]
Reads the cached ``speed.py`` log (1.72 M IMU messages, 174 MB) with ``read_log`` in a fresh
process per tree and repeat, alternating the trees, and prints per tree the median wall time
and CPU seconds of the reading process and of its forked children (the child reading the second
half of the chunks, or decode workers: docs/read_speed.md), and its peak memory. On a shared machine compare CPU, not wall. ``--src``: source trees to compare
(default: this one), e.g. main's from ``git archive``. Writes benchmarks/results/read_cpu.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "read_cpu.json"

_CHILD = r'''
import json, resource, sys, time
src, path = sys.argv[1:3]
if src:
    sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f)]  # not this tree's install
    sys.path.insert(0, src)
from trackfusion.sensors.mcap_log import read_log
tic = time.perf_counter()
log = read_log(path)
wall = time.perf_counter() - tic
me, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
print(json.dumps({"wall_s": wall, "cpu_main_s": me.ru_utime + me.ru_stime, "cpu_workers_s": kids.ru_utime + kids.ru_stime,
                  "peak_rss_mb": me.ru_maxrss / 1024, "imu_samples": int(log.imu.t_s.size)}))
'''


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", nargs="*", default=[""], help="source trees to run (default: this one)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--passes", type=int, default=4, help="round trips of the speed run (4: about 57 min)")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from speed import simulated
    log = simulated(args.passes) / "log.mcap"
    runs: dict[str, list[dict]] = {src: [] for src in args.src}
    for _ in range(args.repeats):
        for src in args.src:
            done = subprocess.run([sys.executable, "-c", _CHILD, str(Path(src).resolve()) if src else "", str(log)],
                                  capture_output=True, text=True)
            if done.returncode:
                sys.exit(f"reading failed ({done.returncode}):\n{done.stderr.strip()}")
            runs[src].append(json.loads(done.stdout.strip().splitlines()[-1]))
    load = float(Path("/proc/loadavg").read_text().split()[0])
    results = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    for src, entries in runs.items():
        median = {k: statistics.median(e[k] for e in entries) for k in ("wall_s", "cpu_main_s", "cpu_workers_s",
                                                                        "peak_rss_mb")}
        label = src or "this tree"
        results[label] = {"date": time.strftime("%Y-%m-%d %H:%M"), "log": str(log), "repeats": args.repeats,
                          "load_average_1min": load, "median": median, "runs": entries}
        print(f"{label}: wall {median['wall_s']:.1f} s, CPU reading process {median['cpu_main_s']:.1f} s + "
              f"forked children {median['cpu_workers_s']:.1f} s = {median['cpu_main_s'] + median['cpu_workers_s']:.1f} s, "
              f"peak {median['peak_rss_mb']:.0f} MB (median of {args.repeats}; load average {load:.1f})")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
