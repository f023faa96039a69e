"""Benchmark: reading an hour of 500 Hz IMU (1.8 M messages) from a ROS 2 MCAP bag and from
trackfusion's own raw log (``/imu`` as ``sensor_msgs/msg/Imu`` CDR).

Usage: python benchmarks/ros2_read.py [N_SAMPLES]   (default 1 800 000: 60 min at 500 Hz)
Prints the figures and writes benchmarks/results/ros2_read.json. Each read runs in a fresh
process pinned to one core (``taskset`` when available): wall and CPU seconds of the read call
(the read is single-threaded; on a shared machine its CPU seconds are the figure to compare).

- ``bag``: written by the ``mcap`` library's writer (profile ``ros2``, zstd chunks of 1 MiB, its
  defaults) with CDR payloads serialised by numpy; read by ``sensors.ros2.read_bag``.
- ``raw_log``: written by ``trackfusion``'s ``write_log``; read by ``read_log``.

Targets: bag decoded <= 3 s; raw log read <= 2 s (on one core).
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "ros2_read.json"
RATE_HZ = 500.0


def _imu(n: int):
    import numpy as np
    rng = np.random.default_rng(0)
    t_ns = np.arange(1, n + 1, dtype=np.int64) * int(1e9 / RATE_HZ)
    gyro = rng.normal(scale=1e-3, size=(n, 3)) + [0.0, 0.0, 7.292115e-5]
    accel = rng.normal(scale=2e-2, size=(n, 3)) + [0.0, 0.0, 9.80665]
    return t_ns, gyro, accel


def _write_bag(path: Path, n: int) -> None:
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    from trackfusion.sensors import cdr

    t_ns, gyro, accel = _imu(n)
    records = cdr.encode("sensor_msgs/msg/Imu", "imu_link", {
        "stamp.sec": t_ns // 10**9, "stamp.nanosec": t_ns % 10**9, "orientation": (0.0, 0.0, 0.0, 1.0),
        "angular_velocity": gyro, "linear_acceleration": accel}, n)
    size = records.dtype.itemsize
    blob = records.tobytes()
    msgdef = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)[0]
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="benchmark")
        cid = w.register_channel("/imu/data", "cdr", w.register_schema("sensor_msgs/msg/Imu", "ros2msg", msgdef.encode()))
        for i, t in enumerate(t_ns.tolist()):
            w.add_message(cid, log_time=t, publish_time=t, data=blob[i * size:(i + 1) * size], sequence=i)
        w.finish()


def _write_raw(path: Path, n: int) -> None:
    from trackfusion.sensors.mcap_log import write_log
    from trackfusion.sensors.types import ImuData, SensorLog

    t_ns, gyro, accel = _imu(n)
    write_log(path, SensorLog(imu=ImuData(t_ns / 1e9, gyro, accel)))


def _child(case: str, path: str, n: int) -> None:
    """Time one read in this process; print one JSON line."""
    tic, cpu = time.perf_counter(), time.process_time()
    if case == "bag":
        from trackfusion.sensors.ros2 import read_bag
        imu = read_bag(path)[0].imu
    else:
        from trackfusion.sensors.mcap_log import read_log
        imu = read_log(path).imu
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu
    assert imu.t_s.size == n
    print(json.dumps({"case": case, "read_s": round(wall, 3), "read_cpu_s": round(cpu, 3),
                      "file_mb": round(os.path.getsize(path) / 1e6, 1)}))


def _measure(case: str, path: Path, n: int) -> dict:
    cmd = [sys.executable, __file__, "--child", case, str(path), str(n)]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", "0"] + cmd
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env={**os.environ}).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(n: int) -> None:
    with tempfile.TemporaryDirectory() as d:
        bag, raw = Path(d) / "imu_bag.mcap", Path(d) / "raw.mcap"
        _write_bag(bag, n)
        tic = time.perf_counter()
        _write_raw(raw, n)
        write_s = time.perf_counter() - tic
        rows = [_measure("bag", bag, n), _measure("raw_log", raw, n)]
    rows[1]["write_s"] = round(write_s, 3)
    result = {"messages": n, "rate_hz": RATE_HZ, "minutes": n / RATE_HZ / 60, "one_core": bool(shutil.which("taskset")),
              "load_average": os.getloadavg(), "python": platform.python_version(),
              "cases": rows, "targets_s": {"bag": 3.0, "raw_log": 2.0}}
    for r in rows:
        target = result["targets_s"][r["case"]]
        r["cpu_within_target"] = r["read_cpu_s"] <= target
        r["wall_within_target"] = r["read_s"] <= target
        print(f"{r['case']:8s} read {r['read_s']:6.2f} s wall, {r['read_cpu_s']:6.2f} s CPU, {r['file_mb']} MB; "
              f"target <= {target} s: CPU {'MEETS' if r['cpu_within_target'] else 'MISSES'}, wall "
              f"{'MEETS' if r['wall_within_target'] else 'MISSES'} (load average {os.getloadavg()[0]:.1f})")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        _child(sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        main(int(sys.argv[1]) if len(sys.argv) > 1 else 1_800_000)
