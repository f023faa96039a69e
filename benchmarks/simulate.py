"""Benchmark: time and peak memory to simulate a scenario end to end (files included), and log size per hour.

Usage: python benchmarks/simulate.py [SCENARIO ...]   (default: bridge-total-station)
Prints a table and writes benchmarks/results/simulate.json. Each scenario runs in a fresh
process so its peak memory (ru_maxrss) is its own. Targets (simulator speed and memory): the 54 min, 500 Hz
bridge survey in under 60 s and under 2 GB on 2 cores.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "simulate.json"


def _child(scenario: str, out_dir: str) -> None:
    from trackfusion.simulation.scenarios import simulate_to_dir

    tic = time.perf_counter()
    report = simulate_to_dir(scenario, out_dir, seed=0)
    wall = time.perf_counter() - tic
    log_bytes = os.path.getsize(Path(out_dir) / "log.mcap")
    from trackfusion.sensors.mcap_log import read_log

    tic = time.perf_counter()
    read_log(Path(out_dir) / "log.mcap")
    read_s = time.perf_counter() - tic
    print(json.dumps({
        "scenario": scenario, "wall_s": wall, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "duration_min": report.duration_s / 60, "imu_samples": report.imu_samples,
        "log_mb": log_bytes / 1e6, "log_mb_per_hour": log_bytes / 1e6 / (report.duration_s / 3600),
        "timings_s": report.timings_s, "read_log_s": read_s,
    }))


def main(argv: list[str]) -> int:
    if len(argv) > 2 and argv[1] == "--child":
        _child(argv[2], argv[3])
        return 0
    scenarios = argv[1:] or ["bridge-total-station"]
    rows = []
    for name in scenarios:
        with tempfile.TemporaryDirectory() as tmp:
            out = subprocess.run([sys.executable, __file__, "--child", name, tmp], check=True,
                                 capture_output=True, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
    print(f"{'scenario':24s} {'min':>6s} {'IMU samples':>12s} {'wall s':>7s} {'peak MB':>8s} {'log MB/h':>9s} {'read s':>7s}")
    for r in rows:
        print(f"{r['scenario']:24s} {r['duration_min']:6.1f} {r['imu_samples']:12d} {r['wall_s']:7.1f} "
              f"{r['peak_rss_mb']:8.0f} {r['log_mb_per_hour']:9.1f} {r['read_log_s']:7.1f}")
        print("   " + ", ".join(f"{k} {v:.1f} s" for k, v in r["timings_s"].items()))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
                                   "results": rows}, indent=2) + "\n")
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
