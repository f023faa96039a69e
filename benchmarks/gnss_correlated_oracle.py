"""What the full surveys' GNSS correlated error allows an estimator to know of its sigma.

Usage: python benchmarks/gnss_correlated_oracle.py [--seeds 1 2 3]

``mismatch.py --full`` compares the smoother's estimate of the GNSS correlated sigma with the
sigma the simulator drew (target: within 15 %). One 44 min survey holds one realisation of a
300 s Gauss-Markov process: about nine time constants, so even an estimator that saw the
realisation itself does not return the drawn sigma. This script measures that limit: per seed
of the full ``open-track-gnss`` mismatch survey, it fits the drawn error series of the kept,
non-outlier fixes (``truth.json``: white + correlated, per ENU axis) by maximum likelihood, a
scalar Kalman filter's likelihood over the correlated sigma with the drawn white sigma and time
constant known (the most the series itself can tell), and prints it over the drawn sigma beside
the smoother's estimate over the drawn (from ``benchmarks/results/mismatch_full.json``).
Writes benchmarks/results/gnss_correlated_oracle.json. Reads the surveys ``mismatch.py --full``
simulated (simulates them when missing; no pipeline run).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

sys.path.insert(0, str(Path(__file__).resolve().parent))

RESULTS = Path(__file__).resolve().parent / "results" / "gnss_correlated_oracle.json"
MISMATCH_FULL = Path(__file__).resolve().parent / "results" / "mismatch_full.json"


def gauss_markov_log_likelihood(y_mm: np.ndarray, t_s: np.ndarray, white_mm: float, sigma_mm: float,
                                tau_s: float) -> float:
    """Log-likelihood of the series ``y_mm`` (K,) at ``t_s`` (K,) [s] as a stationary
    Gauss-Markov process of ``sigma_mm`` and ``tau_s`` plus white noise ``white_mm``: a scalar
    Kalman filter (a loop over the epochs: the benchmark's only hot path, ~3 000 epochs)."""
    x, p, total = 0.0, sigma_mm**2, 0.0
    phi = np.exp(-np.diff(t_s, prepend=t_s[0]) / tau_s)
    for yk, f in zip(y_mm, phi):
        x, p = f * x, f * f * p + sigma_mm**2 * (1.0 - f * f)
        s = p + white_mm**2
        r = yk - x
        total -= 0.5 * (np.log(s) + r * r / s)
        k = p / s
        x, p = x + k * r, p * (1.0 - k)
    return total


def oracle_sigma_mm(y_mm: np.ndarray, t_s: np.ndarray, white_mm: float, tau_s: float, drawn_mm: float) -> float:
    """The correlated sigma [mm] of largest likelihood for the series, searched in 0.2-5 x drawn."""
    r = minimize_scalar(lambda u: -gauss_markov_log_likelihood(y_mm, t_s, white_mm, float(np.exp(u)), tau_s),
                        bounds=(np.log(0.2 * drawn_mm), np.log(5.0 * drawn_mm)), method="bounded",
                        options={"xatol": 1e-4})
    return float(np.exp(r.x))


def drawn_series(d: Path) -> tuple[np.ndarray, np.ndarray]:
    """The kept fixes' times (K,) [s] and drawn error (K, 3) [mm] of the survey in ``d``, outliers
    removed (their drawn offsets)."""
    from trackfusion.simulation.aiding import GnssSpec
    truth = json.loads((d / "truth.json").read_text())
    gnss = truth["errors"]["gnss"]
    err = np.array(gnss["error_n_m"]) * 1e3
    spec = GnssSpec(**{k: v for k, v in truth["config"]["gnss"].items() if k != "lever_arm_b_m"})
    t = np.arange(err.shape[0]) / spec.rate_hz  # the open track has no outage: the kept fixes are every epoch
    offsets = np.array(gnss["outlier_offsets_n_m"]).reshape(-1, 3) * 1e3
    outlier = np.zeros(err.shape[0], bool)
    for off in offsets:
        outlier |= np.linalg.norm(err - off, axis=1) < 200.0  # the others lie >= the smallest jump (300 mm) away
    return t[~outlier], err[~outlier]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args()
    import mismatch
    mismatch.FULL = True
    estimates = json.loads(MISMATCH_FULL.read_text())["open-track-gnss"]["seeds"] if MISMATCH_FULL.is_file() else {}
    out = {}
    print("seed  axis  drawn mm  oracle/drawn  estimate/drawn  estimate/oracle")
    for seed in args.seeds:
        d = mismatch.survey("open-track-gnss", seed, stated_true=False)
        drawn = mismatch.drawn_sigmas(d)
        t, err = drawn_series(d)
        white = [drawn["gnss_white_mm"][0]] * 2 + [drawn["gnss_white_mm"][1]]
        corr = [drawn["gnss_correlated_mm"][0]] * 2 + [drawn["gnss_correlated_mm"][1]]
        fitted = [oracle_sigma_mm(err[:, a], t, white[a], drawn["gnss_tau_s"], corr[a]) for a in range(3)]
        # the smoother estimates one horizontal sigma: the oracle's, pooled in variance
        oracle = {"h": float(np.sqrt((fitted[0]**2 + fitted[1]**2) / 2)), "v": fitted[2]}
        est = estimates.get(str(seed), {}).get("sigma_ratio", {})
        row = {}
        for axis, drawn_mm in zip(("h", "v"), drawn["gnss_correlated_mm"]):
            ratio = est.get(f"gnss_correlated_{axis}")
            row[axis] = {"drawn_mm": drawn_mm, "oracle_mm": oracle[axis], "oracle_over_drawn": oracle[axis] / drawn_mm,
                         "estimate_over_drawn": ratio,
                         "estimate_over_oracle": None if ratio is None else ratio * drawn_mm / oracle[axis]}
            r = row[axis]
            est_txt = "-" if ratio is None else f"{ratio:14.2f}  {r['estimate_over_oracle']:15.2f}"
            print(f"{seed:4d}  {axis:4s}  {drawn_mm:8.2f}  {r['oracle_over_drawn']:12.2f}  {est_txt}")
        out[str(seed)] = {"per_axis_oracle_mm": fitted, **row}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"open-track-gnss": out, "tau_s": drawn["gnss_tau_s"]}, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
