"""Benchmark: CPU seconds per phase of the speed run (``benchmarks/speed.py``'s hour at 500 Hz).

Usage: python benchmarks/speed_cpu.py [--src DIR] [--label NAME] [--passes N]
Wall times on a shared machine say little; CPU seconds say where the work is. Runs the
``speed.py`` data set once in a fresh process whose trackfusion modules read
``time.process_time`` instead of ``time.perf_counter``: ``timings_s`` of metrics.json then hold
the CPU seconds of the main process per phase. Forked children (log decode workers, output
writers: trackfusion/forked.py) are counted apart: their CPU seconds in total, and for each
output writer its private memory at its end (Private_Clean + Private_Dirty of
/proc/self/smaps_rollup: the pages it wrote or allocated, not those it shares with the parent).
``--src``: a source tree to run instead of this one (e.g. main's, from ``git archive``), to
compare two trees one after the other. Writes benchmarks/results/speed_cpu.json (entry ``--label``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "speed_cpu.json"

_CHILD = r'''
import glob, json, os, resource, sys, tempfile, time, types
src, pipeline_yaml, out, mem_dir = sys.argv[1:5]
if src:
    sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f)]  # not this tree's install
    sys.path.insert(0, src)
import importlib, pkgutil
import trackfusion
cpu_clock = types.SimpleNamespace(perf_counter=time.process_time, process_time=time.process_time, time=time.time,
                                  strftime=time.strftime, monotonic=time.monotonic, sleep=time.sleep)
for info in pkgutil.walk_packages(trackfusion.__path__, "trackfusion."):
    try:
        module = importlib.import_module(info.name)
    except Exception:
        continue
    if getattr(module, "time", None) is time:
        module.time = cpu_clock
try:
    from trackfusion import forked
    submit = forked.ForkedTasks.submit

    def measured(self, what, fn, *args, **kwargs):
        def run(*a, **k):
            value = fn(*a, **k)
            rollup = dict(l.split(":", 1) for l in open("/proc/self/smaps_rollup").read().splitlines()[1:])
            private_kb = sum(int(rollup[k].split()[0]) for k in ("Private_Clean", "Private_Dirty"))
            with open(os.path.join(mem_dir, f"{os.getpid()}.json"), "w") as fh:
                json.dump({"what": what, "private_mb": private_kb / 1024,
                           "cpu_s": sum(resource.getrusage(resource.RUSAGE_SELF)[:2])}, fh)
            return value
        return submit(self, what, run, *args, **kwargs)

    forked.ForkedTasks.submit = measured
except ImportError:
    pass  # a tree without forked output writers
from trackfusion.pipeline import load_pipeline, run
tic = time.perf_counter()
result = run(load_pipeline(pipeline_yaml), out)
wall = time.perf_counter() - tic
me, children = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
print(json.dumps({"trackfusion": trackfusion.__file__, "wall_s": wall,
                  "cpu_main_s": me.ru_utime + me.ru_stime, "cpu_children_s": children.ru_utime + children.ru_stime,
                  "peak_rss_main_mb": me.ru_maxrss / 1024,
                  "writers": [json.load(open(p)) for p in sorted(glob.glob(os.path.join(mem_dir, "*.json")))],
                  "timings_cpu_s": result.metrics["timings_s"]}))
'''


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default="", help="source tree to run (default: this one)")
    ap.add_argument("--label", default="branch", help="entry name in the results file")
    ap.add_argument("--passes", type=int, default=4, help="round trips (4: about 57 min)")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from speed import simulated
    sim = simulated(args.passes)
    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run([sys.executable, "-c", _CHILD, str(Path(args.src).resolve()) if args.src else "",
                               str(sim / "pipeline.yaml"), str(Path(tmp) / "out"), tmp],
                              capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"the measured run failed ({done.returncode}):\n{done.stderr.strip()}")
    entry = json.loads(done.stdout.strip().splitlines()[-1])
    entry["date"] = time.strftime("%Y-%m-%d %H:%M")
    results = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    results[args.label] = entry
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    t = entry["timings_cpu_s"]
    print(f"{args.label}: {entry['trackfusion']}")
    print(f"CPU: main process {entry['cpu_main_s']:.1f} s, forked children {entry['cpu_children_s']:.1f} s; "
          f"wall {entry['wall_s']:.1f} s (shared machine); main peak {entry['peak_rss_main_mb']:.0f} MB")
    print("CPU seconds of the main process per phase: " + ", ".join(f"{k[:-2]} {v:.1f}" for k, v in t.items()))
    for w in entry["writers"]:
        print(f"  forked writer ({w['what']}): {w['cpu_s']:.1f} s CPU, {w['private_mb']:.0f} MB private at its end")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
