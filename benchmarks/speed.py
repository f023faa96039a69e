"""Benchmark: one hour of 500 Hz IMU data with odometer and GNSS through ``trackfusion run``.

Usage: python benchmarks/speed.py [--passes N]
Simulates ``open-track-gnss`` at 500 Hz with more passes (about an hour; cached under
``$TMPDIR/trackfusion-bench``), then runs the pipeline in a fresh process and measures its
wall time and peak memory (VmHWM of the child). Prints where the time goes (the
``timings_s`` of metrics.json) and writes benchmarks/results/speed.json.
Targets (issue 4): under 60 s on 2 cores (>= 30 000 IMU samples/s) and under 4 GB.
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

RESULTS = Path(__file__).resolve().parent / "results" / "speed.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"


def simulated(passes: int) -> Path:
    """Folder of the cached 500 Hz simulation (made on first use)."""
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"speed-500hz-{passes}passes"
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("open-track-gnss", out, seed=11,
                        overrides=["imu.rate_hz=500", f"motion.passes={passes}"], progress=print)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=4, help="round trips (4: about 57 min)")
    args = ap.parse_args()
    sim = simulated(args.passes)
    out = sim / "out-speed"
    tic = time.perf_counter()
    # the child reports its own VmHWM: ru_maxrss of a child includes this process's resident size
    # at the fork (the simulation above, when it was not cached)
    child = ("import sys\nfrom trackfusion.cli import main\ncode = main(sys.argv[1:])\n"
             "print(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1])\n"
             "sys.exit(code)")
    done = subprocess.run([sys.executable, "-c", child, "run", str(sim / "pipeline.yaml"), "--out", str(out)],
                          check=True, capture_output=True, text=True)
    wall = time.perf_counter() - tic
    peak_mb = int(done.stdout.strip().splitlines()[-1]) / 1024
    metrics = json.loads((out / "metrics.json").read_text())
    samples = metrics["imu_samples"]
    result = {
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                 cwd=Path(__file__).parent).stdout.strip(),
        "date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(),
        "imu_samples": samples, "duration_min": metrics["duration_s"] / 60, "keyframes": metrics["keyframes"],
        "factors": sum(metrics["factors"].values()), "wall_s": wall, "samples_per_s": samples / wall,
        "peak_rss_mb": peak_mb, "timings_s": metrics["timings_s"],
        "targets": {"wall_s": 60.0, "samples_per_s": 30000, "peak_rss_mb": 4096},
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(f"{samples} IMU samples ({result['duration_min']:.1f} min at 500 Hz), {metrics['keyframes']} keyframes")
    print(f"wall {wall:.1f} s (target < 60 s), {samples / wall:.0f} samples/s (target >= 30000), "
          f"peak memory {peak_mb:.0f} MB (target < 4096 MB)")
    print("where the time goes: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in metrics["timings_s"].items()))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
