"""Benchmark: write and read time, peak memory and size per hour of the raw MCAP log.

Usage: python benchmarks/log_io.py [N_SAMPLES]   (default 1 600 000 IMU samples at 500 Hz, 53 min)
Prints a table and writes benchmarks/results/log_io.json. Two cases, each in a fresh process:

- ``imu_full_precision``: white-noise IMU values at full float64 precision (17 significant digits,
  the worst case for size) — what the simulator writes;
- ``imu_quantised``: the same values rounded to a typical sensor's resolution (gyro 1e-7 rad/s,
  accel 1e-6 m/s^2), closer to a real logger's output.

Target (brief): 1.6 M IMU messages written and read in well under 20 s each.
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

RESULTS = Path(__file__).resolve().parent / "results" / "log_io.json"
RATE_HZ = 500.0
CASES = ("imu_full_precision", "imu_quantised")


def _imu_log(n: int, quantised: bool):
    """A SensorLog holding only an IMU: n samples at RATE_HZ, gyro (n, 3) [rad/s], accel (n, 3) [m/s^2]."""
    import numpy as np

    from trackfusion.sensors.types import ImuData, SensorLog

    rng = np.random.default_rng(0)
    t = np.arange(1, n + 1) / RATE_HZ
    gyro = rng.normal(scale=1e-3, size=(n, 3)) + [0.0, 0.0, 7.292115e-5]
    accel = rng.normal(scale=2e-2, size=(n, 3)) + [0.0, 0.0, 9.80665]
    if quantised:
        gyro = np.round(gyro / 1e-7) * 1e-7
        accel = np.round(accel / 1e-6) * 1e-6
    return SensorLog(imu=ImuData(t, gyro, accel), metadata={"survey": {"benchmark": "log_io"}})


def _child(case: str, n: int, folder: str) -> None:
    """Time one write and one read in this process and print the figures as one JSON line."""
    from trackfusion.sensors.mcap_log import read_log, write_log

    log = _imu_log(n, quantised=case == "imu_quantised")
    path = Path(folder) / "log.mcap"
    tic = time.perf_counter()
    write_log(path, log)
    write_s = time.perf_counter() - tic
    tic = time.perf_counter()
    back = read_log(path)
    read_s = time.perf_counter() - tic
    assert back.imu.t_s.size == n and (back.imu.accel_mps2 == log.imu.accel_mps2).all()
    size = path.stat().st_size
    hours = n / RATE_HZ / 3600
    print(json.dumps({"case": case, "imu_samples": n, "rate_hz": RATE_HZ, "duration_min": hours * 60,
                      "write_s": write_s, "read_s": read_s, "bytes": size, "mb_per_hour": size / 1e6 / hours,
                      "bytes_per_message": size / n,
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def main(argv: list[str]) -> int:
    """Run every case in a fresh process, print the table, write the JSON results."""
    if len(argv) > 1 and argv[1] == "--child":
        _child(argv[2], int(argv[3]), argv[4])
        return 0
    n = int(argv[1]) if len(argv) > 1 else 1_600_000
    rows = []
    for case in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            out = subprocess.run([sys.executable, __file__, "--child", case, str(n), tmp], check=True,
                                 capture_output=True, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
    print(f"{'case':20s} {'IMU msgs':>9s} {'min':>5s} {'write s':>8s} {'read s':>7s} {'MB':>7s} {'MB/h':>7s} "
          f"{'B/msg':>6s} {'peak MB':>8s}")
    for r in rows:
        print(f"{r['case']:20s} {r['imu_samples']:9d} {r['duration_min']:5.1f} {r['write_s']:8.2f} "
              f"{r['read_s']:7.2f} {r['bytes'] / 1e6:7.1f} {r['mb_per_hour']:7.1f} {r['bytes_per_message']:6.1f} "
              f"{r['peak_rss_mb']:8.0f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
                                   "results": rows}, indent=2) + "\n")
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
