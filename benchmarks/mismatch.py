"""Mismatch benchmark: each sensor's true noise drawn at 0.5x-2x its datasheet value, the pipeline
given the datasheet only; against the same draws processed with the true noise configured.

Usage: python benchmarks/mismatch.py [--seeds 1 2 3] [--scenarios open-track-gnss bridge-total-station]
       [--full] [--work DIR] [--out JSON]

Per scenario and seed, factors ``k`` (log-uniform in 0.5-2, from the seed; printed) scale the
simulated IMU white noise (gyro, accelerometer), the GNSS white and correlated parts, the odometer
quantum (its ticks per revolution / k), the rails' irregularity amplitude (the NHC violation)
and the total stations' angle and distance noise. The receiver states the datasheet white
sigma (``gnss.stated_sigma_factor = 1 / k``), and 5 % of its fixes are gross errors. Two runs of the one simulated survey:

* ``datasheet``: the IMU grade's nominal figures, the library's NHC / odometer / wheel-path
  sigmas, the pipeline's GNSS correlated defaults (8 / 15 mm, 300 s), the instrument's stated
  precision: what a surveyor writes;
* ``true``: the drawn IMU noise, the receiver stating its true white sigma, the drawn correlated
  sigmas (with the receiver's 1 ppm x baseline term in quadrature, as drawn: 8.2 / 15.1 mm at
  the datasheet's 8 / 15 and the scenario's 2 km), the NHC sigma of the drawn track
  (simulation/nhc_sigma.py), the RMS error of the odometer's increments, the drawn
  total-station precision; noise estimation off.

The short surveys (tests/surveys.py's ``open-track-gnss``, 215 s; the bridge's first 200 m out
and 100 m back, one station), or with ``--full`` the scenarios' own surveys (44 and 53 min): a
short survey sees one draw of the GNSS correlated error (300 s), which no estimator can tell
from the datasheet's, so only the full ones test that group. Figures: 5 m vertical / lateral
MSE (datasheet over true), each seed's and pooled over the seeds (``mse_ratio_pooled``: the RMS
of the datasheet runs' figures over the true-noise runs'; on the open track each seed's figure is
one draw of the grade error, docs/noise_estimation.md, so a single seed's ratio scatters), pooled
RMS(error / sigma) per ENU axis (with its effective independent samples and the 95 % interval
for honest sigmas, evaluation/consistency.py), GNSS fixes rejected against those truly outside the gate,
the estimated GNSS white / correlated, odometer and NHC sigmas over the drawn ones (the NHC's:
the top speed's RMS violation scaled to the survey's RMS speed, ``nhc_lateral``, and the RMS
violation the survey really had at its keyframes, ``nhc_lateral_realized``,
:func:`realized_nhc_mm_per_s`; the odometer's: the RMS error its increments between keyframes
carry, :func:`realized_odometer_mm`).
Prints a table; writes benchmarks/results/mismatch.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

RESULTS = Path(__file__).resolve().parent / "results" / "mismatch.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
#: run the scenarios' full-length surveys instead of the short ones (``--full``)
FULL = False
GROUPS = ("gyro", "accel", "gnss_white", "gnss_correlated", "odometer", "nhc", "total_station")
BRIDGE_SHORT = ["motion.segments=[{hold_s: 30}, {move_to_m: 214, speed_mps: 0.78, accel_mps2: 0.3}, {hold_s: 10},"
                " {move_to_m: 114, speed_mps: 0.78, accel_mps2: 0.3}, {hold_s: 10}]",
                "total_stations.stations=[{id: TS01, pos_n_m: [12.0, -6.0, 1.8], orientation_deg: 270.0}]",
                "total_stations.handover=[{station: TS01}]"]


def draws(seed: int) -> dict[str, float]:
    """The true-over-datasheet noise factor of each group for ``seed``."""
    rng = np.random.default_rng(1000 + seed)
    return {g: float(np.exp(rng.uniform(np.log(0.5), np.log(2.0)))) for g in GROUPS}


def _overrides(scenario: str, k: dict[str, float], stated_true: bool) -> list[str]:
    from surveys import SHORT_OPEN_TRACK
    from trackfusion.simulation import aiding
    from trackfusion.sensors.imu import IMU_GRADES
    from trackfusion.simulation.config import load_scenario
    cfg = load_scenario(scenario)
    grade = IMU_GRADES[cfg.imu["grade"]]
    short = SHORT_OPEN_TRACK if scenario == "open-track-gnss" else BRIDGE_SHORT
    out = ([] if FULL else short) + [
        f"imu.gyro_arw_deg_per_sqrt_h={grade.gyro_arw_deg_per_sqrt_h * k['gyro']:.6g}",
        f"imu.accel_vrw_mps_per_sqrt_h={grade.accel_vrw_mps_per_sqrt_h * k['accel']:.6g}",
        f"irregularities.psd.scale={k['nhc']:.6g}"]
    if cfg.odometer is not None:
        ticks = aiding.OdometerSpec(**cfg.odometer).ticks_per_rev
        out.append(f"odometer.ticks_per_rev={max(1, int(round(ticks / k['odometer'])))}")
    if cfg.gnss is not None:
        g = aiding.GnssSpec(**{a: b for a, b in cfg.gnss.items() if a != "lever_arm_b_m"})
        out += ["gnss.outlier_fraction=0.05", f"gnss.sigma_h_mm={g.sigma_h_mm * k['gnss_white']:.6g}",
                f"gnss.sigma_v_mm={g.sigma_v_mm * k['gnss_white']:.6g}",
                f"gnss.stated_sigma_factor={1.0 if stated_true else 1.0 / k['gnss_white']:.6g}",
                f"gnss.gm_sigma_h_mm={g.gm_sigma_h_mm * k['gnss_correlated']:.6g}",
                f"gnss.gm_sigma_v_mm={g.gm_sigma_v_mm * k['gnss_correlated']:.6g}"]
    if cfg.total_stations is not None:
        t = aiding.TotalStationSpec(**{a: b for a, b in cfg.total_stations.items() if a != "prism_lever_arm_b_m"})
        out += [f"total_stations.angle_sigma_arcsec={t.angle_sigma_arcsec * k['total_station']:.6g}",
                f"total_stations.distance_sigma_mm={t.distance_sigma_mm * k['total_station']:.6g}"]
    return out


def survey(scenario: str, seed: int, stated_true: bool) -> Path:
    """The simulated survey (the same draws either way; ``stated_true``: the receiver states its
    true white sigma, else the datasheet's)."""
    from trackfusion.simulation.scenarios import simulate_to_dir
    d = CACHE / f"mismatch-{'full-' if FULL else ''}{scenario}-{seed}{'-stating-true' if stated_true else ''}"
    if not (d / "pipeline.yaml").is_file():
        simulate_to_dir(scenario, d, seed=seed, overrides=_overrides(scenario, draws(seed), stated_true))
    return d


def drawn_sigmas(d: Path) -> dict:
    """The drawn noise of the survey in ``d`` in the pipeline's units (from its truth.json)."""
    from trackfusion.simulation import aiding
    from trackfusion.sensors.imu import ImuSpec
    from trackfusion.simulation.config import ScenarioConfig
    from trackfusion.simulation.nhc_sigma import nhc_sigmas_mm_per_s
    from trackfusion.simulation.scenarios import _imu_spec, _motion_plan
    cfg = ScenarioConfig.model_validate(json.loads((d / "truth.json").read_text())["config"])
    survey = pipeline_survey(d)
    imu: ImuSpec = _imu_spec(cfg.imu)
    from trackfusion.sensors.fileio import read_csv_table
    from trackfusion.simulation.nhc_sigma import max_speed_mps
    truth = read_csv_table(d / "truth.csv")
    speed = np.linalg.norm(np.column_stack([truth[c] for c in ("ve_mps", "vn_mps", "vu_mps")]), axis=1)
    # the violation grows with the speed (track/nhc_noise.py): its RMS over the survey from the top speed's
    over_survey = float(np.sqrt(np.mean(speed**2)) / max_speed_mps(cfg))
    top = nhc_sigmas_mm_per_s(cfg, _motion_plan(cfg).chainage_range_m, imu.gyro_arw_deg_per_sqrt_h, imu.rate_hz)
    out = {"imu": imu.model_dump(), "nhc_top_speed_mm_per_s": top,
           "nhc_mm_per_s": {a: v * over_survey for a, v in top.items()},
           "nhc_realized_mm_per_s": realized_nhc_mm_per_s(d, survey)}
    if cfg.odometer is not None:
        out["odometer_mm"] = realized_odometer_mm(d, cfg, survey)
    if cfg.gnss is not None:
        g = aiding.GnssSpec(**{a: b for a, b in cfg.gnss.items() if a != "lever_arm_b_m"})
        gm_mm = g.sigmas_m()[1] * 1e3  # the Gauss-Markov part with the ppm x baseline term in quadrature
        out.update(gnss_white_mm=[g.sigma_h_mm, g.sigma_v_mm], gnss_correlated_mm=[float(gm_mm[0]), float(gm_mm[2])],
                   gnss_tau_s=g.gm_tau_s)
    if cfg.total_stations is not None:
        t = aiding.TotalStationSpec(**{a: b for a, b in cfg.total_stations.items() if a != "prism_lever_arm_b_m"})
        out.update(ts_angle_sigma_arcsec=t.angle_sigma_arcsec, ts_distance_sigma_mm=t.distance_sigma_mm,
                   ts_factor=t.distance_sigma_mm / aiding.TotalStationSpec.model_fields["distance_sigma_mm"].default)
    return out


def datasheet_config(d: Path) -> dict:
    """The generated pipeline with the IMU grade's nominal figures (the simulator drew others)."""
    from trackfusion.sensors.imu import IMU_GRADES
    from trackfusion.simulation.config import ScenarioConfig
    cfg = yaml.safe_load((d / "pipeline.yaml").read_text())
    scen = ScenarioConfig.model_validate(json.loads((d / "truth.json").read_text())["config"])
    grade = IMU_GRADES[scen.imu["grade"]].model_dump()
    cfg["sensors"]["imu"] = {**cfg["sensors"]["imu"], **{key: grade[key] for key in
                                                        ("gyro_arw_deg_per_sqrt_h", "accel_vrw_mps_per_sqrt_h")}}
    return cfg


@dataclass
class PipelineSurvey:
    """The survey in a folder as its ``pipeline.yaml`` reads it: the ``log``, the fusion
    ``problem`` ``trackfusion run`` builds from it, and its keyframes' times ``t_key_s`` (K,)."""

    log: object
    problem: object
    t_key_s: np.ndarray


def pipeline_survey(d: Path) -> PipelineSurvey:
    """:class:`PipelineSurvey` of the survey in ``d`` (its log read once for every oracle)."""
    from trackfusion import pipeline as P
    from trackfusion.fusion.smoother import _keyframes  # the smoother's own keyframes
    pl = P.load_pipeline(d / "pipeline.yaml")
    log = P._read(pl)[0]
    problem, _ = P.build_problem(pl, log, lambda _m: None)
    return PipelineSurvey(log, problem, problem.imu.t_s[_keyframes(problem)])


def realized_odometer_mm(d: Path, cfg, survey: PipelineSurvey) -> float:
    """RMS [mm] of the error the odometer increments between the pipeline's keyframes carry in
    the survey in ``d``: its logged distance against the exact wheel distance of the same draws
    (``simulate_aiding(..., ideal=True)``) times the drawn scale, both interpolated to the
    keyframes as the odometer factor does. The error is the difference of two readings'
    quantisation: at a steady speed the ticks per interval beat against it, so it is far from
    the ``q / sqrt(6)`` of independent uniform errors (bridge seed 2: 0.0089 against 0.0144 mm)."""
    from trackfusion.simulation.scenarios import simulate_aiding
    truth = json.loads((d / "truth.json").read_text())
    odo = truth["errors"]["odometer"]
    if odo.get("slips") or odo.get("gross_error_indices"):
        raise ValueError(f"{d}: the odometer's realised noise is measured on surveys without slips or gross errors")
    log = survey.log
    exact = simulate_aiding(cfg, truth["seed"], ideal=True).odometer
    drift = odo["radius_drift_ppm_per_h"] * 1e-6 * (exact.t_s - exact.t_s[0]) / 3600.0
    unquantised = np.cumsum(np.diff(exact.distance_m, prepend=0.0) * (1.0 + odo["scale_error"] + drift))
    t_key = survey.t_key_s[(survey.t_key_s >= exact.t_s[0]) & (survey.t_key_s <= exact.t_s[-1])]
    err = np.diff(np.interp(t_key, log.odometer.t_s, log.odometer.distance_m) - np.interp(t_key, exact.t_s, unquantised))
    return float(np.sqrt(np.mean(err**2)) * 1e3)


def realized_nhc_mm_per_s(d: Path, survey: PipelineSurvey) -> dict[str, float]:
    """RMS [mm/s] of the lateral and vertical velocity the NHC point really had at the pipeline's
    keyframes in the survey in ``d``: fusion/factors.py ``nhc_residual`` of the truth (truth.csv's
    attitude and velocity interpolated to the keyframe times, the body rate w.r.t. ``n`` from its
    attitude increments) with the pipeline's lever arm and mounting. The noise the NHC factor
    really meets, where ``nhc_mm_per_s`` is the track's violation at the top speed scaled to the
    survey's RMS speed (a short survey runs over a few hundred metres of one irregularity draw)."""
    from trackfusion.fusion import factors as fx
    from trackfusion.rotations import R_from_quat, so3_exp, so3_log
    from trackfusion.sensors.fileio import read_csv_table
    trolley = survey.problem.trolley
    truth = read_csv_table(d / "truth.csv")
    t = truth["t_s"]
    t_key = survey.t_key_s[(survey.t_key_s >= t[0]) & (survey.t_key_s <= t[-1])]
    R = R_from_quat(np.column_stack([truth[c] for c in ("qw", "qx", "qy", "qz")]))
    vel = np.column_stack([truth[c] for c in ("ve_mps", "vn_mps", "vu_mps")])
    step = so3_log(np.einsum("kji,kjl->kil", R[:-1], R[1:]))  # body rotation between truth rows
    i = np.clip(np.searchsorted(t, t_key, "right") - 1, 0, t.size - 2)
    a = (t_key - t[i]) / (t[i + 1] - t[i])
    rate = step / np.diff(t)[:, None]  # at the rows' midpoints
    mid = 0.5 * (t[:-1] + t[1:])
    w_nb_b = np.column_stack([np.interp(t_key, mid, rate[:, j]) for j in range(3)])
    r, _, _ = fx.nhc_residual(R[i] @ so3_exp(a[:, None] * step[i]), vel[i] + a[:, None] * (vel[i + 1] - vel[i]),
                              w_nb_b, trolley.nhc_lever_arm_b, trolley.R_vb)
    rms = np.sqrt(np.mean(r**2, axis=0)) * 1e3
    return {"lateral": float(rms[0]), "vertical": float(rms[1])}


def true_config(d: Path, drawn: dict) -> dict:
    """The same pipeline with the drawn noise configured, and no noise estimation."""
    cfg = yaml.safe_load((d / "pipeline.yaml").read_text())
    f = cfg["factors"]
    f["noise_estimation"] = {"enabled": False}
    f["nhc"] = {f"sigma_{a}_mm_per_s": max(v, 1e-3) for a, v in drawn["nhc_top_speed_mm_per_s"].items()}
    if "odometer_mm" in drawn:
        f["odometer"] = {"sigma_mm": drawn["odometer_mm"]}
    if "gnss_white_mm" in drawn:
        f["gnss"] = {"correlated_sigma_h_mm": drawn["gnss_correlated_mm"][0],
                     "correlated_sigma_v_mm": drawn["gnss_correlated_mm"][1], "estimate_white_noise": False}
    if "ts_angle_sigma_arcsec" in drawn:
        cfg["sensors"]["total_stations"]["angle_sigma_arcsec"] = drawn["ts_angle_sigma_arcsec"]
        cfg["sensors"]["total_stations"]["distance_sigma_mm"] = drawn["ts_distance_sigma_mm"]
    return cfg


def run_one(d: Path, name: str, cfg: dict) -> dict:
    from gnss_noise import GATE_CHI2
    from surveys import errors_against_truth
    from trackfusion import pipeline as P
    from trackfusion.evaluation.consistency import consistency_of
    from trackfusion.sensors.fileio import read_csv_table
    path = d / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    m = P.run(P.load_pipeline(path), d / name, force=True).metrics
    tab = read_csv_table(d / name / "trajectory.csv")
    err, _ = errors_against_truth(d, tab)
    sig = np.column_stack([tab[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")])
    ra = m["relative_accuracy"]
    out = {"vertical_mse_5m_mm": ra["vertical"]["mse_at_threshold_mm"],
           "lateral_mse_5m_mm": ra["lateral"]["mse_at_threshold_mm"],
           "sum_z2": np.sum((err / sig) ** 2, axis=0).tolist(), "samples": int(err.shape[0]),
           "rms_z": np.sqrt(np.mean((err / sig) ** 2, axis=0)).tolist(),
           "consistency": [dict(consistency_of(z), samples=int(z.size)) for z in (err / sig).T],
           "rejected_gnss": len(m["rejected_gnss"]), "noise_estimates": m.get("noise_estimates", {})}
    truth = json.loads((d / "truth.json").read_text())
    if "gnss" in truth.get("errors", {}):
        from gnss_noise import truly_outside
        outside, n = truly_outside(d)
        out.update(truly_outside=outside, fixes=n, rejected_target=1.2 * outside + 0.01 * n, gate_chi2=GATE_CHI2)
    return out


def ratios(est: dict, drawn: dict) -> dict:
    """Estimated over drawn sigma per group (those both know)."""
    out = {}
    g = est.get("gnss")
    if g and "gnss_white_mm" in drawn:
        e = g["estimated_white_sigma_mm"]
        out["gnss_white_h"], out["gnss_white_v"] = e[0] / drawn["gnss_white_mm"][0], e[2] / drawn["gnss_white_mm"][1]
    ge = est.get("gnss_error")
    if ge and "gnss_correlated_mm" in drawn:
        out["gnss_correlated_h"] = ge["horizontal"]["estimated_sigma_mm"] / drawn["gnss_correlated_mm"][0]
        out["gnss_correlated_v"] = ge["vertical"]["estimated_sigma_mm"] / drawn["gnss_correlated_mm"][1]
    if est.get("odometer") and "odometer_mm" in drawn:
        out["odometer"] = est["odometer"]["along"]["estimated_sigma_mm"] / drawn["odometer_mm"]
    for station, e in (est.get("prism") or {}).items():  # angle and distance noise both drawn k times
        out[f"total_station_{station}"] = e["sigma_scale"] / drawn["ts_factor"]
    if est.get("nhc"):
        for a in ("lateral", "vertical"):
            out[f"nhc_{a}"] = est["nhc"][a]["estimated_sigma_mm_per_s"] / drawn["nhc_mm_per_s"][a]
            if "nhc_realized_mm_per_s" in drawn:
                out[f"nhc_{a}_realized"] = est["nhc"][a]["estimated_sigma_mm_per_s"] / drawn["nhc_realized_mm_per_s"][a]
    return out


def pooled_mse_ratio(out: dict) -> dict[str, float]:
    """The 5 m MSE of the datasheet runs over the true-noise runs', RMS over the seeds of ``out``
    (one scenario's result), vertical and lateral."""
    runs = out["seeds"].values()
    return {axis: float(np.sqrt(np.mean([r["datasheet"][f"{axis}_mse_5m_mm"] ** 2 for r in runs])
                                / np.mean([r["true"][f"{axis}_mse_5m_mm"] ** 2 for r in runs])))
            for axis in ("vertical", "lateral")}


def run_scenario(scenario: str, seeds: list[int]) -> dict:
    from trackfusion.evaluation.consistency import pooled
    out: dict = {"survey": "full" if FULL else "short", "seeds": {}}
    for seed in seeds:
        d, d_true = survey(scenario, seed, False), survey(scenario, seed, True)
        drawn = drawn_sigmas(d)
        r = {"draws": draws(seed), "drawn": drawn,
             "datasheet": run_one(d, "datasheet", datasheet_config(d)),
             "true": run_one(d_true, "true", true_config(d_true, drawn))}
        r["sigma_ratio"] = ratios(r["datasheet"]["noise_estimates"], drawn)
        for axis in ("vertical", "lateral"):
            r[f"{axis}_mse_ratio"] = r["datasheet"][f"{axis}_mse_5m_mm"] / r["true"][f"{axis}_mse_5m_mm"]
        out["seeds"][seed] = r
        ds = r["datasheet"]
        print(f"{scenario} seed {seed} k {({g: round(v, 2) for g, v in r['draws'].items()})}\n"
              f"  5 m MSE v/l datasheet {ds['vertical_mse_5m_mm']:.4f}/{ds['lateral_mse_5m_mm']:.4f} mm, "
              f"true {r['true']['vertical_mse_5m_mm']:.4f}/{r['true']['lateral_mse_5m_mm']:.4f} mm "
              f"(ratio {r['vertical_mse_ratio']:.2f}/{r['lateral_mse_ratio']:.2f}); rms z {np.round(ds['rms_z'], 2)} "
              f"(true {np.round(r['true']['rms_z'], 2)}); rejected {ds['rejected_gnss']} "
              f"(truly outside {ds.get('truly_outside')}, target <= {ds.get('rejected_target', 0):.0f})\n"
              f"  estimated / drawn sigma {({g: round(v, 3) for g, v in r['sigma_ratio'].items()})}", flush=True)
    for case in ("datasheet", "true"):
        z2 = np.sum([out["seeds"][s][case]["sum_z2"] for s in seeds], axis=0)
        n = sum(out["seeds"][s][case]["samples"] for s in seeds)
        out[f"rms_z_pooled_{case}"] = np.sqrt(z2 / n).tolist()
        out[f"consistency_pooled_{case}"] = [pooled([out["seeds"][s][case]["consistency"][axis] for s in seeds])
                                             for axis in range(3)]
    out["mse_ratio_pooled"] = pooled_mse_ratio(out)
    print(f"{scenario} 5 m MSE datasheet / true, RMS over the seeds: vertical {out['mse_ratio_pooled']['vertical']:.2f}, "
          f"lateral {out['mse_ratio_pooled']['lateral']:.2f}")
    print(f"{scenario} pooled RMS(error/sigma) e/n/u: datasheet {np.round(out['rms_z_pooled_datasheet'], 2)}, "
          f"true {np.round(out['rms_z_pooled_true'], 2)}; independent samples e/n/u "
          f"{[round(c['n_eff'], 1) for c in out['consistency_pooled_datasheet']]}, 95 % intervals for honest sigmas "
          f"{[np.round(c['interval_95'], 2).tolist() for c in out['consistency_pooled_datasheet']]}")
    return out


def main() -> None:
    global CACHE, RESULTS, FULL
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--scenarios", nargs="*", default=["open-track-gnss", "bridge-total-station"])
    ap.add_argument("--full", action="store_true", help="the scenarios' full-length surveys (module docstring)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=RESULTS, help="the JSON written (default: results/mismatch.json)")
    ap.add_argument("--pool-only", action="store_true",
                    help="only add mse_ratio_pooled to the scenarios already in --out (no run)")
    args = ap.parse_args()
    CACHE, RESULTS, FULL = args.work or CACHE, args.out, args.full
    old = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    if args.pool_only:
        for scenario in (s for s in args.scenarios if s in old):
            old[scenario]["mse_ratio_pooled"] = pooled_mse_ratio(old[scenario])
            print(f"{scenario}: 5 m MSE datasheet / true, RMS over seeds {sorted(old[scenario]['seeds'])}: "
                  + ", ".join(f"{a} {v:.3f}" for a, v in old[scenario]["mse_ratio_pooled"].items()))
        RESULTS.write_text(json.dumps(old, indent=1))
        return
    old["machine"] = "2 cores shared with other agents"
    for scenario in args.scenarios:
        old[scenario] = run_scenario(scenario, args.seeds)
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(old, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
