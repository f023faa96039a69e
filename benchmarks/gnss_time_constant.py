"""What a wrong GNSS correlation time constant costs: the 44 min survey with another true one.

Usage: python benchmarks/gnss_time_constant.py [--seed 1] [--cases 1000:300,600,1000 30:300,45,30] [--estimate]

The pipeline's time constant of the GNSS correlated error (``factors.gnss.correlation_time_s``,
300 s) is a default, not a datasheet value, and trackfusion does not estimate it
(docs/noise_estimation.md). Each case ``TRUE:CONF,...`` simulates the full ``open-track-gnss``
survey with the correlated error's time constant drawn at TRUE s (every other noise at its
datasheet) and runs the generated pipeline with each configured time constant CONF s (the noise
estimation on, as by default). Per run: RMS(error / sigma) per ENU axis, the vertical absolute
RMS error, the 5 m vertical MSE / ADEV and the GNSS correlated part's variance factors applied.
Prints a table; writes benchmarks/results/gnss_time_constant.json. With ``--estimate`` the runs
estimate the time constant as well (``factors.gnss.estimate_time_constant``; its estimate, 95 %
interval and whether it was applied per run) and write gnss_time_constant_estimated.json.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import yaml

RESULTS = Path(__file__).resolve().parent / "results" / "gnss_time_constant.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"


def run_case(seed: int, true_s: float, configured_s: float, estimate: bool = False) -> dict:
    """Simulate (cached) and run one case (``estimate``: the time constant estimated too); its figures."""
    from trackfusion.pipeline import load_pipeline, run
    from trackfusion.simulation.scenarios import simulate_to_dir
    sim = CACHE / f"gnss-tau-{true_s:g}-{seed}"
    if not (sim / "pipeline.yaml").is_file():
        simulate_to_dir("open-track-gnss", sim, seed=seed, overrides=[f"gnss.gm_tau_s={true_s:g}"])
    cfg = yaml.safe_load((sim / "pipeline.yaml").read_text())
    cfg["factors"]["gnss"] = {"enabled": True, "correlation_time_s": float(configured_s),
                              "estimate_time_constant": estimate}
    name = f"configured-{configured_s:g}" + ("-estimated" if estimate else "")
    path = sim / f"{name}.yaml"  # beside the generated one: the same inputs
    path.write_text(yaml.safe_dump(cfg))
    m = run(load_pipeline(path), sim / f"{name}-out", force=True).metrics
    ge = m["noise_estimates"]["gnss_error"]
    return {"time_constant": m["noise_estimates"].get("gnss_time_constant"),
            "true_s": true_s, "configured_s": configured_s,
            "rms_z": [m["consistency_rms_error_over_sigma"][a] for a in "enu"],
            "vertical_abs_rms_mm": m["absolute_error"]["vertical"]["rms_mm"],
            "vertical_mse_5m_mm": m["relative_accuracy"]["vertical"]["mse_at_threshold_mm"],
            "vertical_adev_5m_mm": m["relative_accuracy"]["vertical"]["adev_at_threshold_mm"],
            "gnss_correlated_applied": [ge["horizontal"]["applied_variance_factor"],
                                        ge["vertical"]["applied_variance_factor"]],
            "gnss_correlated_sigma_mm": [ge["horizontal"]["estimated_sigma_mm"], ge["vertical"]["estimated_sigma_mm"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", nargs="+", default=["1000:300,600,1000", "30:300,45,30"])
    ap.add_argument("--estimate", action="store_true", help="estimate the time constant too")
    ap.add_argument("--results", type=Path, help="the JSON to write (default: by --estimate, above)")
    args = ap.parse_args()
    runs = []
    print("true s  configured s  RMS(e/sigma) e / n / u  vertical RMS mm  5 m vertical MSE / ADEV mm")
    for case in args.cases:
        true_s, confs = case.split(":")
        for conf in confs.split(","):
            r = run_case(args.seed, float(true_s), float(conf), args.estimate)
            runs.append(r)
            print(f"{r['true_s']:6.0f}  {r['configured_s']:12.0f}  {' / '.join(f'{z:.2f}' for z in r['rms_z']):>22s}"
                  f"  {r['vertical_abs_rms_mm']:15.2f}  {r['vertical_mse_5m_mm']:.4f} / {r['vertical_adev_5m_mm']:.4f}")
            if r["time_constant"]:
                tc = r["time_constant"]
                print(f"        time constant estimated {tc['estimate_s']:.0f} s (95 %: {tc['interval_95_s'][0]:.0f}"
                      f" to {tc['interval_95_s'][1] or float('inf'):.0f} s), applied: {tc['applied']}")
    results = args.results or (RESULTS.with_name("gnss_time_constant_estimated.json") if args.estimate else RESULTS)
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps({"seed": args.seed, "runs": runs}, indent=1))
    print(f"wrote {results}")


if __name__ == "__main__":
    main()
