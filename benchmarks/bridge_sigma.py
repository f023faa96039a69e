"""What makes the bridge's position sigmas: each total-station prior tightened in turn.

Usage: python benchmarks/bridge_sigma.py [--seeds 1 2 3] [--more-seeds 4 5 ...] [--work DIR]

The short bridge surveys of benchmarks/mismatch.py (first 200 m out and 100 m back, one station,
noise drawn 0.5-2x datasheet), simulated twice: ``no_set_up_error`` (the station's instrument
point exactly at its nominal one, as the simulator drew it before; the scenario override
``total_stations.position_sigma_mm=0``) and ``set_up_error`` (drawn with the stated 1 mm per
axis, the default). Each is processed with the datasheet pipeline; the ``no_set_up_error``
surveys also with one of the station's correction priors (``position_sigma_mm``,
``orientation_sigma_arcsec``, ``tilt_sigma_arcsec``, or all three) tightened 100-fold: the sigma
that prior carries is what the trajectory's sigma loses. Per case and ENU axis: the RMS sigma,
the RMS error and RMS(error / sigma) pooled over the seeds; the station's simulated set-up errors
(truth.json). ``--reuse``: the runs already in the cache are read, not repeated. ``--more-seeds``: further ``set_up_error`` surveys (datasheet pipeline only) for the
pooled RMS(error / sigma), whose error is mostly one set-up draw per survey and axis: beside it,
the 90 % interval of that figure for honest sigmas with one draw per seed (chi-square).
Prints a table; writes benchmarks/results/bridge_sigma.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

RESULTS = Path(__file__).resolve().parent / "results" / "bridge_sigma.json"
SCENARIO = "bridge-total-station"
TIGHTEN = 100.0
#: the cases: name -> the station priors (sensors.total_stations) divided by TIGHTEN
CASES = {"datasheet": (), "position": ("position_sigma_mm",), "orientation": ("orientation_sigma_arcsec",),
         "tilt": ("tilt_sigma_arcsec",),
         "all": ("position_sigma_mm", "orientation_sigma_arcsec", "tilt_sigma_arcsec")}
#: the simulations: name -> (scenario overrides beside mismatch.py's, the cases run on them)
SIMULATORS = {"no_set_up_error": (["total_stations.position_sigma_mm=0"], tuple(CASES)),
              "set_up_error": ([], ("datasheet",))}


def survey(seed: int, simulator: str) -> Path:
    """The short bridge survey of mismatch.py for ``seed`` (its noise draws), simulated with
    ``simulator``'s overrides (cached)."""
    import mismatch
    from trackfusion.simulation.scenarios import simulate_to_dir
    d = mismatch.CACHE / f"bridge-sigma-{seed}-{simulator}"
    if not (d / "pipeline.yaml").is_file():
        extra, _ = SIMULATORS[simulator]
        simulate_to_dir(SCENARIO, d, seed=seed,
                        overrides=mismatch._overrides(SCENARIO, mismatch.draws(seed), False) + extra)
    return d


def case_config(d: Path, priors: tuple[str, ...]) -> dict:
    """The datasheet pipeline of the survey in ``d`` with ``priors`` tightened TIGHTEN-fold."""
    import mismatch
    from trackfusion.pipeline import TotalStationsConfig
    cfg = mismatch.datasheet_config(d)
    ts = cfg["sensors"]["total_stations"]
    for key in priors:
        ts[key] = ts.get(key, TotalStationsConfig.model_fields[key].default) / TIGHTEN
    return cfg


def run_case(d: Path, name: str, cfg: dict, reuse: bool) -> dict:
    """Squared errors and sigmas summed per ENU axis, and the station's sigmas, of one run
    (``reuse``: the outputs of an earlier run with the same pipeline in the same folder)."""
    import yaml
    from surveys import errors_against_truth
    from trackfusion import pipeline as P
    from trackfusion.sensors.fileio import read_csv_table
    path, out = d / f"sigma-{name}.yaml", d / f"sigma-{name}"
    text = yaml.safe_dump(cfg)
    if reuse and path.is_file() and path.read_text() == text and (out / "metrics.json").is_file():
        m = json.loads((out / "metrics.json").read_text())
    else:
        path.write_text(text)
        m = P.run(P.load_pipeline(path), out, force=True).metrics
    tab = read_csv_table(out / "trajectory.csv")
    err, _ = errors_against_truth(d, tab)
    sig = np.column_stack([tab[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")])
    return {"samples": int(err.shape[0]), "sum_err2_mm2": (1e6 * np.sum(err**2, axis=0)).tolist(),
            "sum_sigma2_mm2": (1e6 * np.sum(sig**2, axis=0)).tolist(),
            "sum_z2": np.sum((err / sig) ** 2, axis=0).tolist(),
            "stations": {s: {k: v for k, v in e.items() if k in ("sigma", "translation_mm", "tilt_arcsec",
                                                                   "orientation_error_arcsec")}
                         for s, e in m["registration"]["stations"].items()}}


def pooled(runs: list[dict]) -> dict:
    """RMS sigma, RMS error [mm] and RMS(error / sigma) per ENU axis over ``runs``."""
    n = sum(r["samples"] for r in runs)
    total = {k: np.sum([r[k] for r in runs], axis=0) for k in ("sum_err2_mm2", "sum_sigma2_mm2", "sum_z2")}
    return {"rms_sigma_mm": np.sqrt(total["sum_sigma2_mm2"] / n).tolist(),
            "rms_error_mm": np.sqrt(total["sum_err2_mm2"] / n).tolist(),
            "rms_z": np.sqrt(total["sum_z2"] / n).tolist()}


def set_up_errors(d: Path) -> dict:
    """The simulated station's set-up errors (truth.json), for the table."""
    drawn = json.loads((d / "truth.json").read_text())["errors"]["total_stations"]["stations"]
    return {s: {k: e[k] for k in ("tilt_arcsec", "orientation_error_arcsec", "position_error_mm")}
            for s, e in drawn.items()}


def honest_interval(seeds: int) -> list[float]:
    """90 % interval of the pooled RMS(error / sigma) of honest sigmas when each survey's error
    is one normal draw (chi-square with ``seeds`` degrees of freedom)."""
    from scipy.stats import chi2
    return np.sqrt(chi2.ppf([0.05, 0.95], seeds) / seeds).tolist()


def _print(label: str, p: dict) -> None:
    print(f"{label:40s} sigma e/n/u {np.round(p['rms_sigma_mm'], 3)} mm, error {np.round(p['rms_error_mm'], 3)} mm,"
          f" rms z {np.round(p['rms_z'], 2)}", flush=True)


def main() -> None:
    import mismatch
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--more-seeds", type=int, nargs="*", default=[])
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--reuse", action="store_true", help="read the runs already in the cache instead of repeating them")
    args = ap.parse_args()
    mismatch.CACHE = args.work or mismatch.CACHE
    out: dict = {"machine": "2 cores shared with other agents", "tighten": TIGHTEN, "seeds": args.seeds,
                 "more_seeds": args.more_seeds}
    for simulator, (_, cases) in SIMULATORS.items():
        seeds = args.seeds + (args.more_seeds if simulator == "set_up_error" else [])
        runs: dict[str, list[dict]] = {c: [] for c in cases}
        per_seed = {}
        for seed in seeds:
            d = survey(seed, simulator)
            per_seed[seed] = {"set_up_errors": set_up_errors(d), "cases": {}}
            for case in cases:
                r = run_case(d, case, case_config(d, CASES[case]), args.reuse)
                runs[case].append(r)
                per_seed[seed]["cases"][case] = r
                _print(f"{simulator} seed {seed} {case}", pooled([r]))
        out[simulator] = {"seeds": per_seed, "cases": {c: pooled(runs[c]) for c in cases},
                          "honest_rms_z_interval_90": honest_interval(len(seeds))}
        for case in cases:
            _print(f"{simulator} pooled over {len(seeds)} seeds {case}", out[simulator]["cases"][case])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
