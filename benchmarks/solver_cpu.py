"""Benchmark: CPU seconds of the smoother's stages on the speed benchmark's hour of 500 Hz data.

Usage: python benchmarks/solver_cpu.py [--passes N] [--scenario open-track|bridge] [--out FILE]
       [--densify] [--part-s S] [--wheel-path on|off]
The wall times of benchmarks/speed.py and bridge.py swing with the load of a shared machine;
the process CPU time of the estimation core (preintegrate, build, solve, marginals) does much
less, so before/after comparisons of the solver are made with this script (run it from each
tree on the same machine). Reads the log and builds the problem as ``trackfusion run`` does
(not timed), then smooths it with every stage timed in CPU seconds. ``open-track``: the
simulation of benchmarks/speed.py (``--passes`` round trips, 4: 57 min); ``bridge``: seed 1
of benchmarks/bridge.py (53 min). Writes benchmarks/results/solver_cpu.json (solver_cpu_bridge.json).
Bridge: ``--seed``.
Target (speed): the estimation core's share of the 60 s hour, about 25 s on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from provenance import git_commit

RESULTS = Path(__file__).resolve().parent / "results" / "solver_cpu.json"


def problem(scenario: str, passes: int, seed: int = 1):
    """The fusion problem of the cached simulation, as ``trackfusion run`` builds it."""
    from trackfusion import pipeline as P
    if scenario == "bridge":
        from bridge import simulated as bridge_simulated
        sim = bridge_simulated(seed)
    else:
        from speed import simulated
        sim = simulated(passes)
    pl = P.load_pipeline(sim / "pipeline.yaml")
    if scenario == "bridge":  # as benchmarks/bridge.py runs it
        import yaml
        data = yaml.safe_load((sim / "pipeline.yaml").read_text())
        data["factors"]["total_stations"] = {"enabled": True, "registration": "graph"}
        pl = P.parse_pipeline(data, str(sim / "pipeline.yaml"), sim)
    log, _ = P._read(pl)
    prob, _ = P.build_problem(pl, log, lambda _m: None)
    return P._prepare_total_stations(pl, log, prob, lambda _m: None)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--scenario", choices=["open-track", "bridge"], default="open-track")
    ap.add_argument("--out", type=Path, default=None, help="JSON result file (default: results/solver_cpu[_bridge].json)")
    ap.add_argument("--seed", type=int, default=1, help="bridge: the seed of benchmarks/bridge.py")
    ap.add_argument("--densify", action="store_true", help="one batch: time the densification too")
    ap.add_argument("--part-s", type=float, default=None,
                    help="solve each step in exact time parts of this duration (smoother.part_s), in this process")
    ap.add_argument("--wheel-path", choices=["on", "off"], default=None,
                    help="switch factors.wheel_path on or off (default: as the pipeline.yaml; docs/wheel_path.md)")
    args = ap.parse_args()
    prob = problem(args.scenario, args.passes, args.seed)
    if args.wheel_path is not None:
        wheel = prob.factors.wheel_path.model_copy(update={"enabled": args.wheel_path == "on"})
        prob = replace(prob, factors=prob.factors.model_copy(update={"wheel_path": wheel}))
    from trackfusion.fusion import smoother
    if args.part_s is not None:
        prob = replace(prob, smoother=prob.smoother.model_copy(update={"part_s": args.part_s}))
    wall, cpu = time.perf_counter(), time.process_time()
    real_clock = time.perf_counter
    time.perf_counter = time.process_time  # the smoother's own stage timings, in CPU seconds
    try:
        res = smoother.smooth(prob)
        if args.densify:
            tic = time.process_time()
            densify_rows(prob, res)
            res.timings_s["densify_s"] = time.process_time() - tic
    finally:
        time.perf_counter = real_clock
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    stages = {k: round(v, 2) for k, v in res.timings_s.items()}
    result = {
        "commit": git_commit(),
        "date": time.strftime("%Y-%m-%d %H:%M"), "scenario": args.scenario,
        **({"seed": args.seed} if args.scenario == "bridge" else {}),
        "imu_samples": int(prob.imu.t_s.size), "keyframes": int(res.t_s.size),
        "factors": sum(res.factor_counts.values()), "iterations": res.iterations,
        "final_cost": res.final_cost, "cpu_s": round(cpu, 2), "wall_s": round(wall, 2), "cpu_stages_s": stages,
        "load_average_1min": float(Path("/proc/loadavg").read_text().split()[0]), "part_s": args.part_s,
    }
    out = args.out or (RESULTS if args.scenario == "open-track" else RESULTS.with_name("solver_cpu_bridge.json"))
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"{args.scenario}: {result['imu_samples']} IMU samples, {result['keyframes']} keyframes, "
          f"{result['factors']} factors, {res.iterations} iterations")
    print(f"estimation core: {cpu:.1f} CPU s ({wall:.1f} s wall, load {result['load_average_1min']:.1f}): "
          + ", ".join(f"{k[:-2]} {v:.1f}" for k, v in stages.items()))
    print(f"wrote {out}")


def densify_rows(prob, res) -> None:
    """The one-batch run's densification (pipeline.run does it after the smoother)."""
    import numpy as np
    from trackfusion import geodesy
    from trackfusion.fusion.trajectory import KeyframeStates, densify
    densify(prob.imu, KeyframeStates.of(res, prob.origin),
            geodesy.earth_rate_n(prob.origin) if prob.factors.imu.earth_rate else np.zeros(3))


if __name__ == "__main__":
    main()
