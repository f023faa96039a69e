"""Benchmark (diagnosis): how much of the 5 m vertical error of ``open-track-gnss`` is one constant
grade error, and where it comes from.

Usage: python benchmarks/grade_error.py --seeds 1 .. 10 [--label out-default(-wheelpath)] [--out F]
Reads the runs ``benchmarks/accuracy.py`` left in its cache (``$TMPDIR/trackfusion-bench/
open-track-gnss-<seed>/<label>``: trajectory.csv, metrics.json) and the simulation's truth.
Per seed:

* the **grade error** [urad = um/m]: the slope of the vertical error against chainage, one offset
  per pass (the GNSS's slowly varying error) and one slope common to all passes, fitted to the
  moving samples on the 5 cm grid of the evaluation;
* the 5 m vertical ADEV [mm] as evaluated and with that grade removed (what the rest of the error makes);
* the along-track accelerometer's **effective constant bias** [ug] the simulator drew: turn-on bias
  + its Gauss-Markov part (mean of the first and last sample) + the x-row's scale and
  misalignment times the specific force at rest ``(0, 0, g)`` (the IMU is mounted level on the
  trolley), against the smoother's estimate (``metrics.json`` ``accel_bias_ug.mean``). A pitch
  error trades with this bias one for one (1 ug of bias taken as pitch is 1 urad of grade);
* the GNSS-only Cramer-Rao bound of a constant grade for this survey: generalised least squares
  of the vertical fixes on (1, chainage) with the simulated receiver's error covariance (white
  ``sigma_v`` + Gauss-Markov ``gm_sigma_v (+) ppm baseline`` with ``gm_tau_s``), i.e. how well the
  fixes alone tell the grade (the bias then tells nothing more: a level IMU that never turns
  cannot separate its along-track bias from pitch), and the grade the drawn errors of the fixes imply
  (the same least squares applied to them);
* with ``--posterior``: the smoother's own posterior sigma of that bias [ug] (the marginal of the
  middle bias segment in the solve's Bayes tree, the scenario's pipeline.yaml solved again as
  ``benchmarks/accuracy.py``'s default variant ran it) and the bias error over it.
Writes benchmarks/results/grade_error.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from provenance import git_commit, write_result

RESULTS = Path(__file__).resolve().parent / "results" / "grade_error.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
G0_MPS2 = 9.80665
SCALE_M = 5.0


def _distance_series(folder: Path, label: str):
    from trackfusion.evaluation.api import read_trajectory
    from trackfusion.evaluation.errors_series import error_series, resample_on_distance
    est, _ = read_trajectory(folder / label / "trajectory.csv")
    ref, _ = read_trajectory(folder / "truth.csv")
    return resample_on_distance(error_series(est, ref))


def grade_fit(passes_u_m: list[np.ndarray], chainage_m: list[np.ndarray]) -> float:
    """Common slope [m/m] of the vertical errors (one (n_p,) array per pass) against chainage, one
    offset per pass (least squares)."""
    P = len(passes_u_m)
    rows = [np.column_stack([np.eye(P)[np.full(c.size, i)], c]) for i, c in enumerate(chainage_m)]
    coef, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(passes_u_m), rcond=None)
    return float(coef[-1])


def adev_mm(passes_u_m: list[np.ndarray], step_m: float) -> float:
    from trackfusion.evaluation.relative import allan_deviation, scale_samples
    return allan_deviation(passes_u_m, scale_samples(SCALE_M, step_m)) * 1e3


def effective_along_bias_ug(truth: dict) -> float:
    """The x accelerometer's constant error at rest [ug] (module docstring)."""
    a = truth["errors"]["imu"]["accel_mps2"]
    E = np.asarray(a["error_matrix"])
    gm = 0.5 * (a["bias_gm_first"][0] + a["bias_gm_last"][0])
    at_rest = (E - np.eye(3))[0] @ np.array([0.0, 0.0, G0_MPS2])
    return float((a["bias"][0] + gm + at_rest) / (G0_MPS2 * 1e-6))


def gnss_grade(folder: Path, truth: dict) -> tuple[float, float]:
    """``(bound, implied)`` [urad]: the Cramer-Rao bound of a constant grade from the vertical fixes
    alone, and the grade their drawn errors imply (the same generalised least squares applied to
    ``errors.gnss.error_n_m``'s up column: what the fixes tilt a trajectory by). Fix epochs
    ``k / rate_hz`` from 0, as the simulator writes them (no outages in the scenario)."""
    from trackfusion.sensors.fileio import read_csv_table
    from trackfusion.simulation.aiding import GnssSpec
    spec = GnssSpec(**{k: v for k, v in truth["config"]["gnss"].items() if k != "lever_arm_b_m"})
    error_u_m = np.asarray(truth["errors"]["gnss"]["error_n_m"])[:, 2]
    tab = read_csv_table(folder / "truth.csv")
    t = np.arange(error_u_m.size) / spec.rate_hz
    s = np.interp(t, tab["t_s"], tab["chainage_m"])
    gm = np.hypot(spec.gm_sigma_v_mm, spec.ppm * spec.baseline_km) * 1e-3
    C = gm**2 * np.exp(-np.abs(t[:, None] - t[None, :]) / spec.gm_tau_s) + (spec.sigma_v_mm * 1e-3) ** 2 * np.eye(t.size)
    X = np.column_stack([np.ones_like(s), s])
    cov = np.linalg.inv(X.T @ np.linalg.solve(C, X))
    implied = cov @ X.T @ np.linalg.solve(C, error_u_m)
    return float(np.sqrt(cov[1, 1]) * 1e6), float(implied[1] * 1e6)


def posterior_along_bias_sigma_ug(folder: Path) -> float:
    """The smoother's posterior sigma [ug] of the x accelerometer bias of the middle bias segment:
    ``folder``'s pipeline.yaml read, built and smoothed as ``trackfusion run`` does, the marginal
    taken from the solve's last Bayes tree (the whole run's: exact to about 1 % on an hour,
    docs/solver_speed.md, enough for a sigma)."""
    import gtsam
    from trackfusion import pipeline as P
    from trackfusion.fusion import smoother
    pl = P.load_pipeline(folder / "pipeline.yaml")
    log, _ = P._read(pl)
    problem, _ = P.build_problem(pl, log, lambda _m: None)
    sigma: list[float] = []
    marginals = smoother._marginals

    def capture(problem, rounds, *args, **kwargs):
        b = sorted(gtsam.Symbol(k).index() for k in rounds.sol.values.keys() if gtsam.Symbol(k).chr() == ord("b"))
        cov = rounds.sol.tree.marginalCovariance(gtsam.symbol("b", b[len(b) // 2]))  # (accel, gyro)
        sigma.append(float(np.sqrt(cov[0, 0]) / (G0_MPS2 * 1e-6)))
        return marginals(problem, rounds, *args, **kwargs)
    smoother._marginals = capture
    try:
        smoother.smooth(problem)
    finally:
        smoother._marginals = marginals
    return sigma[0]


def seed_figures(seed: int, label: str, posterior: bool = False) -> dict:
    folder = CACHE / f"open-track-gnss-{seed}"
    truth = json.loads((folder / "truth.json").read_text())
    metrics = json.loads((folder / label / "metrics.json").read_text())
    ds = _distance_series(folder, label)
    u = ds.component("vertical")
    ch = [p.chainage_m for p in ds.passes]
    grade = grade_fit(u, ch)
    detrended = [e - grade * c for e, c in zip(u, ch)]
    true_bias = effective_along_bias_ug(truth)
    est_bias = float(metrics["accel_bias_ug"]["mean"][0])
    row = {"seed": seed, "grade_error_urad": grade * 1e6,
           "vertical_adev_5m_mm": adev_mm(u, ds.step_m), "vertical_adev_5m_without_grade_mm": adev_mm(detrended, ds.step_m),
           "along_bias_effective_ug": true_bias, "along_bias_estimated_ug": est_bias,
           "along_bias_error_ug": est_bias - true_bias}
    row["gnss_grade_bound_urad"], row["gnss_implied_grade_urad"] = gnss_grade(folder, truth)
    if posterior:
        row["along_bias_posterior_sigma_ug"] = posterior_along_bias_sigma_ug(folder)
        row["along_bias_error_over_sigma"] = row["along_bias_error_ug"] / row["along_bias_posterior_sigma_ug"]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--label", default="out-default(-wheelpath)", help="run folder in each simulation")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--made-by", default="this checkout", help="the code that made the runs (for the JSON)")
    ap.add_argument("--posterior", action="store_true",
                    help="also solve each survey again for the bias's posterior sigma (about 20 s a seed)")
    args = ap.parse_args()
    rows = [seed_figures(s, args.label, args.posterior) for s in args.seeds]
    for r in rows:
        print(f"seed {r['seed']:3d}: grade error {r['grade_error_urad']:+6.1f} urad; 5 m vertical ADEV "
              f"{r['vertical_adev_5m_mm']:.3f} mm, without the grade {r['vertical_adev_5m_without_grade_mm']:.3f} mm; "
              f"along-track bias drawn {r['along_bias_effective_ug']:+6.1f} ug, estimated {r['along_bias_estimated_ug']:+6.1f} ug; "
              f"the fixes' errors imply {r['gnss_implied_grade_urad']:+6.1f} urad")
    rms = {k: float(np.sqrt(np.mean([r[k] ** 2 for r in rows])))
           for k in ("grade_error_urad", "vertical_adev_5m_mm", "vertical_adev_5m_without_grade_mm",
                     "along_bias_effective_ug", "along_bias_error_ug")}
    if args.posterior:
        z = [r["along_bias_error_over_sigma"] for r in rows]
        rms["along_bias_error_over_sigma"] = float(np.sqrt(np.mean(np.square(z))))
        print("along-track bias posterior sigma " + " / ".join(f"{r['along_bias_posterior_sigma_ug']:.2f}" for r in rows)
              + f" ug; RMS(error / sigma) {rms['along_bias_error_over_sigma']:.2f}")
    grades = [r["grade_error_urad"] for r in rows]
    corr = float(np.corrcoef(grades, [r["along_bias_error_ug"] for r in rows])[0, 1])
    corr_gnss = float(np.corrcoef(grades, [r["gnss_implied_grade_urad"] for r in rows])[0, 1])
    print(f"RMS over the seeds: {rms}; correlation of grade error and bias error {corr:.3f}; "
          f"with the grade the fixes' errors imply {corr_gnss:.3f}; "
          f"GNSS-only bound of the grade (seed {rows[0]['seed']}): {rows[0]['gnss_grade_bound_urad']:.1f} urad")
    result = {"commit": git_commit(),
              "date": time.strftime("%Y-%m-%d"), "label": args.label, "runs_made_by": args.made_by, "seeds": args.seeds, "runs": rows,
              "rms": rms, "correlation_grade_bias_error": corr,
              "correlation_grade_gnss_implied": corr_gnss}
    write_result(args.out, result)


if __name__ == "__main__":
    main()
