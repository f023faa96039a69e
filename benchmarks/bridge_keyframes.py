"""Benchmark: the bridge survey with coarser keyframes and the wheel-path factor (why it keeps
0.1 s keyframes without the factor).

Usage: python benchmarks/bridge_keyframes.py [--seeds 1] [--data noisy ideal] [--out FILE]
On the open track, 0.2 s keyframes with the wheel path keep the 0.1 s accuracy for half the
keyframes (docs/solver_speed.md), which would bring the 53 min bridge survey (31 618 keyframes)
towards its speed target. Each seed of ``bridge-total-station`` (as benchmarks/bridge.py
simulates it; ``ideal``: the same survey with every sensor and station error off, whose
estimated clocks should come out at zero) is fused with:

- ``kf100ms``: 0.1 s keyframes, no wheel path;
- ``kf200ms``: 0.2 s keyframes, no wheel path;
- ``kf200ms_wheel_path``: 0.2 s keyframes, the factor on every keyframe (``keyframe_step: 1``);
- ``kf100ms_wheel_path``: 0.1 s keyframes, the factor on every 2nd.

Printed and written per run: each station's clock error at IMU time 0 and over its tracking
intervals [ms], the absolute RMS error along / across the track and vertical [mm], the 5 m
vertical / lateral MSE [mm], the round trip after fusion (std, max |r|) [mm], the
Gauss-Newton iterations and the run's ``timings_s.total_s``. Simulations are cached under
``$TMPDIR/trackfusion-bench``. Writes benchmarks/results/bridge_keyframes.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from bridge import CACHE, figures, simulated
from provenance import git_commit

RESULTS = Path(__file__).resolve().parent / "results" / "bridge_keyframes.json"
#: variant -> (keyframe spacing [s], wheel-path keyframe step or None: off)
VARIANTS = {"kf100ms": (0.1, None), "kf200ms": (0.2, None), "kf200ms_wheel_path": (0.2, 1),
            "kf100ms_wheel_path": (0.1, 2)}


def simulated_ideal(seed: int) -> Path:
    """The bridge survey of ``seed`` with every sensor and station error off (cached)."""
    from trackfusion.simulation.scenarios import simulate_to_dir
    out = CACHE / f"bridge-total-station-{seed}-ideal-ros2"
    if not (out / "pipeline.yaml").is_file():
        simulate_to_dir("bridge-total-station", out, seed=seed, ideal=True)
    return out


def run_variant(sim: Path, name: str, out_root: Path) -> dict:
    """Fuse ``sim`` with variant ``name`` (:data:`VARIANTS`) and return its figures."""
    from trackfusion.pipeline import parse_pipeline, run as run_pipeline
    spacing_s, step = VARIANTS[name]
    data = yaml.safe_load((sim / "pipeline.yaml").read_text())
    data["factors"]["total_stations"] = {"enabled": True, "registration": "graph"}
    data["factors"]["wheel_path"] = {"enabled": True, "keyframe_step": step} if step else False
    data["keyframes"] = {"spacing_s": spacing_s}
    out = out_root / sim.name / name
    m = run_pipeline(parse_pipeline(data, str(sim / "pipeline.yaml"), sim), out).metrics
    f = figures(m, json.loads((sim / "truth.json").read_text()))
    rt = f["round_trip"]["after_fusion"]
    return {"clock_error_ms": {s: v["clock_error_ms"] for s, v in f["stations"].items()},
            "clock_error_in_tracking_ms": {s: v["clock_error_in_tracking_ms"] for s, v in f["stations"].items()},
            "clock_offset_sigma_ms": {s: v["clock_offset_sigma_ms"] for s, v in f["stations"].items()},
            "absolute_rms_mm": f["absolute_rms_mm"],
            "mse_5m_mm": {c: m["relative_accuracy"][c]["mse_at_threshold_mm"] for c in ("vertical", "lateral")},
            "round_trip_std_mm": max(rt[c]["std_mm"] for c in rt),
            "round_trip_max_mm": max(abs(rt[c]["max_abs_signed_mm"]) for c in rt),
            "keyframes": m["keyframes"], "iterations": m["iterations"], "run_s": f["run_s"]}


def line(seed: int, data: str, name: str, r: dict) -> str:
    clocks = ", ".join(f"{s} {r['clock_error_ms'][s]:+.2f} ({r['clock_error_in_tracking_ms'][s]:.2f})"
                       for s in r["clock_error_ms"])
    a = r["absolute_rms_mm"]
    return (f"seed {seed} {data:5s} {name:18s}: clock [ms] (in tracking) {clocks}; absolute RMS along / lateral / "
            f"vertical {a['along']:.3f} / {a['lateral']:.3f} / {a['vertical']:.3f} mm; 5 m MSE v / l "
            f"{r['mse_5m_mm']['vertical']:.4f} / {r['mse_5m_mm']['lateral']:.4f} mm; round trip std / max "
            f"{r['round_trip_std_mm']:.3f} / {r['round_trip_max_mm']:.3f} mm; {r['keyframes']} keyframes, "
            f"{r['iterations']} iterations, {r['run_s']:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--data", nargs="+", choices=["noisy", "ideal"], default=["noisy", "ideal"])
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    ap.add_argument("--out-root", type=Path, default=CACHE / "bridge-keyframes-out")
    ap.add_argument("--out", type=Path, default=RESULTS, help="JSON result file")
    args = ap.parse_args()
    runs: dict = {}
    for seed in args.seeds:
        for data in args.data:
            sim = simulated(seed) if data == "noisy" else simulated_ideal(seed)
            for name in args.variants:
                r = run_variant(sim, name, args.out_root)
                runs.setdefault(str(seed), {}).setdefault(data, {})[name] = r
                print(line(seed, data, name, r), flush=True)
    args.out.write_text(json.dumps({"benchmark": "bridge_keyframes", "commit": git_commit(), "runs": runs},
                                   indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
