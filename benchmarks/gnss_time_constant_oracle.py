"""What each survey's own GNSS error series says of its time constant, against the smoother's estimate.

Usage: python benchmarks/gnss_time_constant_oracle.py

``gnss_time_constant.py --estimate`` runs the 44 min ``open-track-gnss`` surveys with the
correlated error's time constant drawn at 30, 100 and 1 000 s and the estimate on
(fusion/gnss_time_constant.py). One survey holds one realisation of the process, whose own time
constant is not the drawn one. This script fits each survey's drawn error series itself (the
kept fixes' white + correlated error per ENU axis, ``truth.json``) by maximum likelihood: a scalar
Kalman filter's likelihood (benchmarks/gnss_correlated_oracle.py) with the drawn white sigma
known, the correlated sigma profiled per axis, summed over the axes, at quarter octaves of the
time constant; its peak and 95 % interval as the smoother's are made
(``gnss_time_constant.interval_from_profile``). Reads
``benchmarks/results/gnss_time_constant_estimated_seeds.json`` and the cached surveys; prints per
run the series' fit beside the smoother's estimate and whether the smoother's interval holds the
series' time constant; writes benchmarks/results/gnss_time_constant_oracle.json.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

sys.path.insert(0, str(Path(__file__).resolve().parent))

from gnss_correlated_oracle import drawn_series, gauss_markov_log_likelihood  # noqa: E402

HERE = Path(__file__).resolve().parent
ESTIMATED = HERE / "results" / "gnss_time_constant_estimated_seeds.json"
RESULTS = HERE / "results" / "gnss_time_constant_oracle.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"


def profile_log_likelihood(t_s: np.ndarray, err_mm: np.ndarray, white_mm: np.ndarray, tau_s: float) -> float:
    """The series' log-likelihood at ``tau_s`` [s], each axis's correlated sigma at its best
    (0.1-50 mm); ``err_mm`` (K,3), ``white_mm`` (3,)."""
    total = 0.0
    for a in range(3):
        r = minimize_scalar(lambda u: -gauss_markov_log_likelihood(err_mm[:, a], t_s, white_mm[a], float(np.exp(u)), tau_s),
                            bounds=(np.log(0.1), np.log(50.0)), method="bounded", options={"xatol": 1e-3})
        total -= r.fun
    return total


def series_fit(sim: Path, drawn_s: float) -> dict:
    """The series' time constant [s] and 95 % interval, quarter octaves from drawn / 8 to 8 drawn."""
    from trackfusion.fusion.gnss_time_constant import interval_from_profile
    from trackfusion.simulation.aiding import GnssSpec
    truth = json.loads((sim / "truth.json").read_text())
    spec = GnssSpec(**{k: v for k, v in truth["config"]["gnss"].items() if k != "lever_arm_b_m"})
    white_mm = np.asarray(spec.sigmas_m()[0]) * 1e3
    t, err = drawn_series(sim)
    grid = drawn_s * 2.0 ** (np.arange(-12, 13) / 4.0)
    ll = np.array([profile_log_likelihood(t, err, white_mm, float(tau)) for tau in grid])
    est = interval_from_profile(grid, ll, drawn_s).to_json()  # (an unbounded end: null)
    return {"estimate_s": est["estimate_s"], "interval_95_s": est["interval_95_s"]}


def main() -> None:
    runs = json.loads(ESTIMATED.read_text())["runs"]
    out = []
    print("seed  drawn s  series' fit s (95 %)      smoother's s (95 %)       holds the series' fit")
    for r in runs:
        sim = CACHE / f"gnss-tau-{r['true_s']:g}-{r['seed']}"
        fit = series_fit(sim, r["true_s"])
        smoother = {k: r["time_constant"][k] for k in ("estimate_s", "interval_95_s")}
        lo, hi = smoother["interval_95_s"][0], smoother["interval_95_s"][1] or np.inf
        holds = bool(lo <= fit["estimate_s"] <= hi)
        out.append({"seed": r["seed"], "drawn_s": r["true_s"], "series": fit, "smoother": smoother,
                    "holds_series_fit": holds})
        f_lo, f_hi = fit["interval_95_s"][0], fit["interval_95_s"][1] or np.inf
        print(f"{r['seed']:4d}  {r['true_s']:7.0f}  {fit['estimate_s']:6.0f} ({f_lo:4.0f}-{f_hi:5.0f})"
              f"      {r['time_constant']['estimate_s']:6.0f} ({lo:4.0f}-{hi:5.0f})       {holds}")
    RESULTS.write_text(json.dumps({"runs": out, "held": sum(o["holds_series_fit"] for o in out), "runs_count": len(out)},
                                  indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
