"""Benchmark: CPU milliseconds per frame (both cameras) of a vision run's frame processing, by stage.

Usage: python benchmarks/vision_stages.py [--src [LABEL=]DIR ...] [--repeats N] [--length-m 60]

A ``tgms-vehicle`` survey (seed 1, ``--length-m`` filmed at 30 m/s) is simulated twice by this
tree, with its images as PNG (``foxglove.CompressedImage``) and as ``sensor_msgs/msg/Image``
(``--set image_encoding=raw``), and calibrated. Each source tree (``--src``, default this one,
labelled by its folder's name or ``LABEL``; e.g. ``main=DIR`` with main's from ``git archive``)
then measures every frame of each log in a fresh process, in
batches of 64 as ``trackfusion run`` does, one process: the log's frames read and decoded
(slicing the run's image stacks), and ``measure_frames`` with its stages timed by wrapping
them: stripe centres (``stripe_centres``), points (undistortion and the laser plane,
``pixels_to_vehicle``), the continuous runs, the profile fit (``fit_profiles``) and the rest
(gauge, wear, glare windows, faults), with OpenCV's threads as the tree's ``measure_run`` sets
them. CPU seconds (``time.process_time``: a shared machine distorts wall clocks, less so CPU),
the least of ``--repeats`` passes (trees alternating), per frame of both cameras. A tree that
cannot read a log (an older one, the raw images) is listed as such. The measurements of every
tree are compared bit for bit. Beside (this tree, the PNG log's first 128 frames of the left
camera): CPU ms per image of ``cv2.imdecode`` with ``IMREAD_UNCHANGED`` and with
``IMREAD_GRAYSCALE``, of decompressing the raw pixels in 1 MB chunks compressed as the MCAP
writer does (zstd, lz4), and ``measure_frames`` per frame with OpenCV's threads on (its default)
and off. Writes benchmarks/results/vision_stages.json with the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "vision_stages.json"
ROOT = Path(__file__).resolve().parent.parent

_CHILD = r'''
import json, pickle, sys, time
src, folder, out = sys.argv[1:4]
sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f)]  # not this tree's install
sys.path.insert(0, src)
from pathlib import Path
import numpy as np
from trackfusion.track.rail_profile import rail_head
from trackfusion.vision import camera, measure
from trackfusion.vision.calibration import load_calibration
from trackfusion.vision.image_log import read_vision_log
folder = Path(folder)
try:
    log = read_vision_log(folder / "log.mcap")
    images = log["images"]
    images["left"][0:1]
except Exception as exc:
    print(json.dumps({"unsupported": f"{type(exc).__name__}: {exc}"[:200]}))
    sys.exit(0)
units, head = load_calibration(folder / "calibration.yaml"), rail_head("60E1")
F = len(log["t_frame_s"])
cpu = {}
def timed(owner, name, stage):
    f = getattr(owner, name)
    def g(*a, **k):
        c = time.process_time()
        r = f(*a, **k)
        cpu[stage] = cpu.get(stage, 0.0) + time.process_time() - c
        return r
    setattr(owner, name, g)
timed(measure, "stripe_centres", "stripe_centres")
timed(camera.CameraLaserUnit, "pixels_to_vehicle", "points")
timed(measure, "continuous_segments", "continuous_runs")
timed(measure, "fit_profiles", "profile_fit")
roll = np.zeros(F)
parts = []
if hasattr(measure, "one_opencv_thread"):  # as the tree's measure_run does
    measure.one_opencv_thread().__enter__()
for a in range(0, F, 64):
    c = time.process_time()
    batch = {k: v[a:a + 64] for k, v in images.items()}
    cpu["read_decode"] = cpu.get("read_decode", 0.0) + time.process_time() - c
    c = time.process_time()
    parts.append(measure.measure_frames(units, head, batch, roll[a:a + 64], first_frame=a))
    cpu["measure_frames"] = cpu.get("measure_frames", 0.0) + time.process_time() - c
m = measure.concatenate(parts)
cpu["rest"] = cpu["measure_frames"] - sum(cpu[k] for k in ("stripe_centres", "points", "continuous_runs", "profile_fit"))
cpu["total"] = cpu["read_decode"] + cpu["measure_frames"]
pickle.dump({"gauge_m": m.gauge_m, "cross_level_m": m.cross_level_m, "faults": m.faults,
             **{f"{k}_{s}": getattr(m, k)[s] for k in ("vertical_wear_mm", "side_wear_mm", "pose", "rms_mm")
                for s in ("left", "right")}}, open(out, "wb"))
print(json.dumps({"frames": F, "ms_per_frame": {k: v / F * 1e3 for k, v in cpu.items()}}))
'''


def simulate(work: Path, length_m: float) -> dict[str, Path]:
    """The seed-1 survey as PNG and raw logs, calibrated (the same calibration file)."""
    from trackfusion.simulation.tgms_vehicle import simulate_tgms_to_dir
    from trackfusion.vision.calibration import calibrate_folder
    out = {}
    for enc in ("png", "raw"):
        d = work / enc
        simulate_tgms_to_dir(d, seed=1, overrides=[f"length_m={length_m}", f"image_encoding={enc}"])
        out[enc] = d
    calibrate_folder(out["png"] / "calibration", out["png"] / "calibration.yaml")
    (out["raw"] / "calibration.yaml").write_bytes((out["png"] / "calibration.yaml").read_bytes())
    return out


def least_cpu_ms(fn, n: int, repeats: int) -> float:
    """The least CPU time [ms] of ``repeats`` calls of ``fn``, per item of ``n``."""
    import time
    best = float("inf")
    for _ in range(repeats):
        c = time.process_time()
        fn()
        best = min(best, time.process_time() - c)
    return best / n * 1e3


def codec_figures(png_folder: Path, repeats: int) -> dict:
    """CPU ms per image of PNG decoding (two flags) and of chunk decompression (zstd, lz4), and
    per frame of ``measure_frames`` with OpenCV's threads on and off (module docstring)."""
    import cv2
    import lz4.frame
    import numpy as np
    import zstandard
    from trackfusion.track.rail_profile import rail_head
    from trackfusion.vision.calibration import load_calibration
    from trackfusion.vision.image_log import read_vision_log
    from trackfusion.vision.measure import measure_frames
    log = read_vision_log(png_folder / "log.mcap")
    imgs = log["images"]["left"][0:128]
    pngs = [cv2.imencode(".png", im)[1] for im in imgs]
    out = {}
    for flag in ("IMREAD_UNCHANGED", "IMREAD_GRAYSCALE"):
        out[f"png_decode_{flag}_ms_per_image"] = least_cpu_ms(
            lambda f=getattr(cv2, flag): [cv2.imdecode(p, f) for p in pngs], len(pngs), repeats)
    chunks = [imgs[i:i + 4].tobytes() for i in range(0, len(imgs), 4)]            # 1 MB, as MCAP's
    for name, comp, dec in (("zstd", zstandard.compress, zstandard.decompress),
                            ("lz4", lz4.frame.compress, lz4.frame.decompress)):
        packed = [comp(c) for c in chunks]
        out[f"{name}_ratio"] = sum(map(len, packed)) / sum(map(len, chunks))
        out[f"{name}_decompress_ms_per_image"] = least_cpu_ms(lambda p=packed, d=dec: [d(x) for x in p],
                                                              len(imgs), repeats)
    units, head = load_calibration(png_folder / "calibration.yaml"), rail_head("60E1")
    batches = [{k: v[a:a + 64] for k, v in log["images"].items()} for a in range(0, 128, 64)]
    roll = np.zeros(64)
    default = cv2.getNumThreads()
    for label, threads in (("default", default), ("one", 1)) * repeats:
        cv2.setNumThreads(threads)
        ms = least_cpu_ms(lambda: [measure_frames(units, head, b, roll) for b in batches], 128, 1)
        key = f"measure_frames_opencv_threads_{label}_ms_per_frame"
        out[key] = min(ms, out.get(key, ms))
    cv2.setNumThreads(default)
    out["opencv_default_threads"] = default
    return out


def tree_label(arg: str) -> tuple[str, str]:
    """``(label, dir)`` of a ``--src`` argument ``LABEL=DIR`` or ``DIR`` (labelled by its name)."""
    label, sep, folder = arg.partition("=")
    return (label, folder) if sep else (Path(arg).name, arg)


def same_measurements(a: dict, b: dict) -> bool:
    """Every array equal (NaN where NaN) and the same fault list."""
    import numpy as np
    return a.keys() == b.keys() and all(
        a[k] == b[k] if k == "faults" else np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", nargs="+", default=[str(ROOT)])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--length-m", type=float, default=60.0)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    best: dict = {}
    outputs: dict = {}
    with tempfile.TemporaryDirectory(prefix="trackfusion-bench-stages-") as work:
        logs = simulate(Path(work), args.length_m)
        trees = {d: label for label, d in map(tree_label, args.src)}
        for rep in range(args.repeats):
            for src, label in trees.items():
                for enc, folder in logs.items():
                    dump = Path(work) / f"m_{len(outputs)}.pkl"
                    r = json.loads(subprocess.run([sys.executable, "-c", _CHILD, src, str(folder), str(dump)],
                                                  check=True, capture_output=True, text=True).stdout)
                    key = f"{label} {enc}"
                    if "unsupported" in r:
                        best[key] = r
                        continue
                    if dump.is_file():
                        outputs[key] = pickle.loads(dump.read_bytes())
                    old = best.get(key, {}).get("ms_per_frame", {})
                    best[key] = {"frames": r["frames"], "ms_per_frame": {
                        k: min(v, old.get(k, v)) for k, v in r["ms_per_frame"].items()}}
                    print(key, json.dumps({k: round(v, 3) for k, v in best[key]["ms_per_frame"].items()}), flush=True)
        codecs = codec_figures(logs["png"], max(args.repeats, 3))
    first = next(iter(outputs.values()))
    doc = {"trees": best, "codecs": codecs, "same_measurements_all_trees_and_logs": all(same_measurements(first, o) for o in outputs.values()),
           "length_m": args.length_m, "repeats": args.repeats, "load_average": os.getloadavg(), "cpus": os.cpu_count()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))
    print(json.dumps({"same_measurements_all_trees_and_logs": doc["same_measurements_all_trees_and_logs"],
                      "load_average": doc["load_average"]}))


if __name__ == "__main__":
    main()
