"""Benchmark: the same simulated surveys give the same files with two versions of the code.

Usage: python benchmarks/outputs_unchanged.py --before /path/to/other/checkout [--after .] [--work DIR]

Simulates two short surveys -- a GNSS one (``open-track-gnss``, one 300 m pass) and a
total-station one (``bridge-total-station`` shortened to 300 m, a station at each end) -- and
runs the pipeline on each, once with the code of ``--before`` and once with ``--after`` (each a
checkout's root, put first on ``PYTHONPATH`` of a fresh ``python -m trackfusion`` process). Both
versions work in the same folder (moved aside afterwards), so paths written into the outputs are
the same. Every file, inputs and outputs, is then compared: byte for byte, else numerically
(CSV cells and JSON numbers within 1e-12, relative to the value's size), leaving out only what
measures the run rather than its result (``timings_s``, ``run_time_s`` and the run-time cells of
report.html). Writes benchmarks/results/outputs_unchanged.json; target: every file the same.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "outputs_unchanged.json"
TOLERANCE = 1e-12
#: name -> (scenario, seed, --set overrides)
SURVEYS = {
    "gnss": ("open-track-gnss", 5, [
        "motion.passes=1",
        "motion.segments=[{hold_s: 60.0}, {move_to_m: 320.0, speed_mps: 3.0, accel_mps2: 0.4}, {hold_s: 20.0}]"]),
    "total-station": ("bridge-total-station", 5, [
        "motion.segments=[{hold_s: 60.0}, {move_to_m: 300.0, speed_mps: 0.78, accel_mps2: 0.3}, {hold_s: 30.0}]",
        "total_stations.stations=[{id: TS01, pos_n_m: [12.0, -6.0, 1.8], orientation_deg: 270.0},"
        " {id: TS02, pos_n_m: [-330.0, -6.0, 1.8], orientation_deg: 90.0}]",
        "total_stations.handover=[{station: TS01}, {station: TS02, at_chainage_m: 160.0}]"]),
}
_VOLATILE_KEYS = {"timings_s", "run_time_s"}
_HTML_SECONDS = re.compile(r"<td>[0-9.]+ s</td>")


def _trackfusion(root: Path, args: list[str]) -> None:
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run([sys.executable, "-m", "trackfusion", *args], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"trackfusion {' '.join(args[:2])} with {root}: exit {done.returncode}\n{done.stderr}")


def produce(root: Path, work: Path, label: str) -> Path:
    """Simulate and run every survey with the code at ``root``; returns the folder holding them."""
    keep = work / label
    shutil.rmtree(keep, ignore_errors=True)
    keep.mkdir(parents=True)
    for name, (scenario, seed, overrides) in SURVEYS.items():
        here = work / name
        shutil.rmtree(here, ignore_errors=True)
        _trackfusion(root, ["simulate", scenario, "--seed", str(seed), "--out", str(here),
                            *[a for o in overrides for a in ("--set", o)]])
        _trackfusion(root, ["run", str(here / "pipeline.yaml"), "--out", str(here / "out")])
        shutil.move(str(here), str(keep / name))
    return keep


def _close(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b)) or abs(a - b) <= TOLERANCE * max(1.0, abs(a), abs(b))


def _same_value(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(k in _VOLATILE_KEYS or _same_value(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return _close(float(a), float(b))
    return a == b


def _same_cell(a: str, b: str) -> bool:
    if a == b:
        return True
    try:
        return _close(float(a), float(b))
    except ValueError:
        return False


def compare(a: Path, b: Path) -> str:
    """'bytes', 'numeric' (same within the tolerance) or 'DIFFERENT' for two versions of one file."""
    da, db = a.read_bytes(), b.read_bytes()
    if da == db:
        return "bytes"
    if a.suffix == ".json":
        same = _same_value(json.loads(da), json.loads(db))
    elif a.suffix == ".csv":
        ra, rb = list(csv.reader(da.decode().splitlines())), list(csv.reader(db.decode().splitlines()))
        same = len(ra) == len(rb) and all(len(x) == len(y) and all(map(_same_cell, x, y)) for x, y in zip(ra, rb))
    elif a.suffix == ".html":
        same = _HTML_SECONDS.sub("", da.decode()) == _HTML_SECONDS.sub("", db.decode())
    else:
        same = False
    return "numeric" if same else "DIFFERENT"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="root of the reference checkout")
    ap.add_argument("--after", type=Path, default=Path(__file__).resolve().parent.parent,
                    help="root of the checkout under test (default: this one)")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "trackfusion-outputs-unchanged")
    args = ap.parse_args()
    before = produce(args.before.resolve(), args.work, "before")
    after = produce(args.after.resolve(), args.work, "after")
    names = sorted({p.relative_to(before).as_posix() for p in before.rglob("*") if p.is_file()}
                   | {p.relative_to(after).as_posix() for p in after.rglob("*") if p.is_file()})
    files = {n: (compare(before / n, after / n) if (before / n).is_file() and (after / n).is_file() else "MISSING")
             for n in names}
    for n, verdict in files.items():
        print(f"  {verdict:9s} {n}")
    met = all(v in ("bytes", "numeric") for v in files.values())
    print(f"{len(files)} files: {sum(v == 'bytes' for v in files.values())} byte for byte, "
          f"{sum(v == 'numeric' for v in files.values())} the same but for run times; target met: {met}")
    RESULTS.write_text(json.dumps({"benchmark": "outputs_unchanged", "tolerance": TOLERANCE, "met": met,
                                   "surveys": {k: {"scenario": s, "seed": seed, "overrides": o}
                                               for k, (s, seed, o) in SURVEYS.items()},
                                   "files": files}, indent=1) + "\n")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
