"""End to end: simulate a short survey, run the pipeline, compare with the truth.

An ideal (noise-free) log on a track without irregularities must come back as the truth
within 0.1 mm (every model in the chain is exact there: preintegration with Earth rate and
per-position gravity, NHC at the wheelbase centre, odometer chord, GNSS lever arm, the
forward/backward densification). With irregularities, the NHC is violated by the rail's
short waves (about 1e-3 x speed); that case is covered by the accuracy benchmark.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackfusion.cli import main
from trackfusion.evaluation.errors_series import hermite_interpolate
from trackfusion.pipeline import TRAJECTORY_UNITS, load_pipeline, run
from trackfusion.rotations import R_from_quat, so3_log
from trackfusion.sensors.fileio import read_csv_table
from trackfusion.simulation.scenarios import simulate_to_dir

from surveys import SHORT_OPEN_TRACK as SHORT


@pytest.fixture(scope="module")
def ideal_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("ideal")
    simulate_to_dir("open-track-gnss", d, seed=4, ideal=True, overrides=SHORT + ["irregularities={}"])
    return d, run(load_pipeline(d / "pipeline.yaml"), d / "out")


def _errors(result, truth_csv):
    truth = read_csv_table(truth_csv)
    tab = result.trajectory
    pos_t = np.column_stack([truth[c] for c in ("e_m", "n_m", "u_m")])
    vel_t = np.column_stack([truth[c] for c in ("ve_mps", "vn_mps", "vu_mps")])
    inside = (tab["t_s"] >= truth["t_s"][0]) & (tab["t_s"] <= truth["t_s"][-1])
    ref = hermite_interpolate(truth["t_s"], pos_t, vel_t, tab["t_s"][inside])
    est = np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")])[inside]
    q_t = np.column_stack([np.interp(tab["t_s"][inside], truth["t_s"], truth[c]) for c in ("qw", "qx", "qy", "qz")])
    q_e = np.column_stack([tab[c] for c in ("qw", "qx", "qy", "qz")])[inside]
    dR = np.swapaxes(R_from_quat(q_t / np.linalg.norm(q_t, axis=1, keepdims=True)), -1, -2) @ R_from_quat(q_e)
    return est - ref, so3_log(dR)


def test_ideal_log_gives_the_truth(ideal_run):
    d, result = ideal_run
    pos_err, att_err = _errors(result, d / "truth.csv")
    assert np.max(np.abs(pos_err)) < 1e-4
    assert np.max(np.abs(att_err)) < 2e-6  # rad
    assert result.metrics["rejected_gnss"] == []


def test_ideal_chainage_and_scale(ideal_run):
    d, result = ideal_run
    truth = read_csv_table(d / "truth.csv")
    tab = result.trajectory
    ref = np.interp(tab["t_s"], truth["t_s"], truth["chainage_m"] - truth["chainage_m"][0])
    assert np.max(np.abs(tab["chainage_m"] - ref)) < 5e-3  # odometer wheel path vs centreline chainage
    scale = result.metrics["odometer_scale_ppm"]
    assert abs(scale["mean"]) < 1.0
    # an ideal wheel: no drift; over this 215 s run the scale moves by well under 2 ppm (measured:
    # +0.76 -> -0.65 ppm, a slope of -24 ppm/h)
    assert abs(scale["first"]) < 1.0 and abs(scale["last"]) < 1.0
    duration_h = (tab["t_s"][-1] - tab["t_s"][0]) / 3600.0
    assert abs(scale["drift_ppm_per_h"]) * duration_h < 2.0


def test_odometer_scale_drift_figure_is_the_slope():
    """metrics.json's drift of the odometer scale: the least-squares slope [ppm/h] over the
    keyframes (numpy's line fit); a constant scale has none."""
    from trackfusion.pipeline import _odometer_scale_figures
    t_s = np.linspace(100.0, 1900.0, 901)
    scale = 500e-6 + 3000e-6 * t_s / 3600.0 + 2e-6 * np.sin(2 * np.pi * t_s / 1800.0)
    fig = _odometer_scale_figures(t_s, scale)
    assert fig["drift_ppm_per_h"] == pytest.approx(np.polyfit(t_s / 3600.0, scale * 1e6, 1)[0], rel=1e-9)
    flat = _odometer_scale_figures(t_s, np.full(t_s.size, 500e-6))
    assert flat["drift_ppm_per_h"] == pytest.approx(0.0, abs=1e-9) and flat["mean"] == pytest.approx(500.0)
    assert fig["first"] == pytest.approx(scale[0] * 1e6) and fig["last"] == pytest.approx(scale[-1] * 1e6)


def test_output_files_follow_the_contract(ideal_run):
    d, result = ideal_run
    out = d / "out"
    assert sorted(result.files) == ["fused.mcap", "geometry.csv", "geometry.json", "metrics.json", "report.html",
                                   "trajectory.csv", "trajectory.json"]
    header = (out / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header == list(TRAJECTORY_UNITS)
    side = json.loads((out / "trajectory.json").read_text())
    assert side["frame"] == "n" and set(side["origin"]) == {"lat_deg", "lon_deg", "h_m"}
    assert side["columns"] == TRAJECTORY_UNITS
    m = json.loads((out / "metrics.json").read_text())
    for key in ("run_time_s", "keyframes", "factors", "final_cost", "odometer_scale_ppm", "gyro_bias_deg_per_h",
                "accel_bias_ug", "rejected_gnss", "timings_s", "relative_accuracy", "static_intervals_s"):
        assert key in m, key
    for key in ("read_s", "preintegrate_s", "build_s", "solve_s", "output_s", "write_s", "wall_s"):
        assert key in m["timings_s"], key
    t = m["timings_s"]  # metrics.json is written last: the writing of every other output is in it
    assert 0 < t["write_s"] and t["wall_s"] == pytest.approx(t["total_s"] + t["write_s"])
    assert result.metrics["timings_s"] == t
    assert set(m["relative_accuracy"]) == {"along", "lateral", "vertical"}
    assert not [p.name for p in d.iterdir() if p.name.startswith(".out-")]  # no staging folder left


def test_sigmas_are_positive_and_rate_as_configured(ideal_run):
    _, result = ideal_run
    tab = result.trajectory
    for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m", "sigma_roll_rad", "sigma_pitch_rad", "sigma_yaw_rad"):
        assert np.all(tab[c] > 0) and np.all(np.isfinite(tab[c]))
    assert np.median(np.diff(tab["t_s"])) == pytest.approx(0.01, rel=1e-6)  # truth.rate_hz = 100


def test_run_command_and_identical_output(ideal_run, tmp_path, capsys):
    d, result = ideal_run
    assert main(["run", str(d / "pipeline.yaml"), "--out", str(tmp_path / "again")]) == 0
    out = capsys.readouterr().out
    assert "trajectory.csv" in out and "vertical" in out
    assert (tmp_path / "again" / "trajectory.csv").read_bytes() == (d / "out" / "trajectory.csv").read_bytes()


def test_gnss_outliers_are_rejected(tmp_path):
    """Fixes displaced by 0.3-3 m are gated out and reported in metrics.json."""
    simulate_to_dir("open-track-gnss", tmp_path, seed=5, overrides=SHORT + ["gnss.outlier_fraction=0.05"])
    truth = json.loads((tmp_path / "truth.json").read_text())
    injected = truth["errors"]["gnss"]["outlier_times_s"]
    result = run(load_pipeline(tmp_path / "pipeline.yaml"), tmp_path / "out")
    rejected = [r["t_s"] for r in result.metrics["rejected_gnss"]]
    assert len(injected) > 3
    assert set(np.round(injected, 6)) <= set(np.round(rejected, 6))
    assert len(rejected) <= len(injected) + 2
    # the IMU's white noise from the static ends, against the simulated IMU's
    spec = truth["errors"]["imu"]["spec"]
    est = result.metrics["noise_estimates"]["imu"]
    for key in ("gyro_arw_deg_per_sqrt_h", "accel_vrw_mps_per_sqrt_h"):
        assert est[key]["value"] == pytest.approx(spec[key], rel=0.03)
        assert abs(est[key]["value"] - spec[key]) < 4 * est[key]["sigma"] + 0.002 * spec[key]
