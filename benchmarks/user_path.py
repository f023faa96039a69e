"""Benchmark: the user's path around a run — CSV import / export of one survey hour at 500 Hz,
and writing report.html and fused.mcap for the 43-minute demo survey.

Usage: python benchmarks/user_path.py [DEMO_RUN_DIR]
DEMO_RUN_DIR: an output folder of 'trackfusion demo' (default out/demo/out; run 'make demo'
first). Prints a table and writes benchmarks/results/user_path.json. Target (helper brief): one
survey hour at 500 Hz processes in well under a minute — the importer must not be the
bottleneck (target: parsing the CSV files under 20 s on 2 cores; writing the MCAP log is the
same writer the simulator uses).
"""

from __future__ import annotations

import json
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "user_path.json"


def _hour_log():
    from trackfusion.sensors.types import ImuData, OdometerData, SensorLog

    rng = np.random.default_rng(0)
    n = 3600 * 500
    t = np.arange(1, n + 1) / 500.0
    imu = ImuData(t, rng.normal(0, 1e-4, (n, 3)), rng.normal([0, 0, 9.8], 1e-2, (n, 3)))
    t_odo = t[::5]
    odo = OdometerData(t_odo, np.cumsum(rng.uniform(0, 0.01, t_odo.size)), np.arange(t_odo.size, dtype=np.int64))
    return SensorLog(imu=imu, odometer=odo, metadata={"survey": {"name": "hour"}})


def main() -> None:
    from trackfusion.report.html import write_report
    from trackfusion.sensors.fused import write_fused_mcap
    from trackfusion.sensors.fileio import read_csv_table
    from trackfusion.sensors.importers import export_csv, import_log, import_to_mcap
    from trackfusion.sensors.mcap_log import read_log, write_log
    from trackfusion import geodesy

    figures: dict[str, float] = {}

    def timed(name, fn, *args, **kw):
        wall, cpu = time.perf_counter(), time.process_time()
        fn(*args, **kw)
        figures[f"{name}_s"] = time.perf_counter() - wall
        figures[f"{name}_cpu_s"] = time.process_time() - cpu

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_log(d / "hour.mcap", _hour_log())
        timed("export_1h_500hz", export_csv, d / "hour.mcap", d / "csv")
        timed("import_1h_500hz", import_to_mcap, d / "csv" / "import.yaml", d / "back.mcap")
        timed("import_parse_only_1h_500hz", import_log, d / "csv" / "import.yaml")  # without write_log
        figures["round_trip_identical"] = (d / "back.mcap").read_bytes() == (d / "hour.mcap").read_bytes()
    run_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "out/demo/out")
    if (run_dir / "metrics.json").is_file():
        with tempfile.TemporaryDirectory() as tmp:
            timed("report_demo", write_report, run_dir, Path(tmp) / "report.html")
            metrics = json.loads((run_dir / "metrics.json").read_text())
            table = read_csv_table(run_dir / "trajectory.csv")
            o = metrics["origin"]
            timed("fused_mcap_demo", write_fused_mcap, Path(tmp) / "fused.mcap", table,
                  geodesy.Origin(o["lat_deg"], o["lon_deg"], o["h_m"]), raw=read_log(run_dir.parent / "log.mcap"))
            figures["fused_mcap_demo_mb"] = (Path(tmp) / "fused.mcap").stat().st_size / 1e6
    figures["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for k, v in figures.items():
        print(f"{k:<34} {v:.2f}" if isinstance(v, float) else f"{k:<34} {v}")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": platform.platform(), "note": "shared 2-core machine under load: wall times inflated; *_cpu_s is this process's CPU time",
                                   "import_parse_target_s": 20.0, **figures}, indent=2) + "\n")


if __name__ == "__main__":
    main()
