"""`trackfusion evaluate`: files in, table and JSON out, bad input -> exit 2 with one line; the figure."""

import json

import numpy as np
import pytest

from trackfusion import cli
from trackfusion.evaluation import synthetic as syn
from trackfusion.evaluation.api import EvaluationConfig, evaluate_files
from trackfusion.report.evaluation_plots import relative_accuracy_png
from trackfusion.sensors.fileio import write_csv_table

ORIGIN = {"lat_deg": 43.3, "lon_deg": 89.6, "h_m": 50.0}
TRUTH_UNITS = {k: v for k, v in syn.TRAJECTORY_UNITS.items() if not k.startswith("sigma")}


def _write(path, cols, units=None, origin=ORIGIN):
    units = units or {k: syn.TRAJECTORY_UNITS[k] for k in cols}
    write_csv_table(path, cols, units, frame="n", origin=origin, fmt="%.12g")
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    rng = np.random.default_rng(41)
    t_ref = np.arange(0.0, 420.0 + 1e-9, 0.02)
    t_est = np.arange(0.0, 420.0 + 1e-9, 0.01)
    truth = syn.truth_columns(t_est)
    err = np.column_stack([np.cumsum(rng.normal(0, 2e-6, t_est.size)),
                           1e-3 * np.sin(truth["chainage_m"] / 9.0), rng.normal(0, 5e-5, t_est.size)])
    est = _write(d / "trajectory.csv", syn.with_errors(truth, err))
    ref = _write(d / "truth.csv", syn.truth_columns(t_ref), TRUTH_UNITS)
    return d, est, ref


def test_evaluate_prints_table_and_writes_design_json(files, capsys):
    d, est, ref = files
    out = d / "metrics" / "evaluate.json"
    assert cli.main(["evaluate", str(est), str(ref), "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert "MSE sigma1 (eq. 2)" in table and "ADEV (eqs. 5-6)" in table and "result:" in table
    j = json.loads(out.read_text())
    for comp in ("vertical", "lateral", "along"):
        ra = j["relative_accuracy"][comp]
        assert ra["scales_m"] == [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
        assert isinstance(ra["sigma_mm"], float)
        assert len(ra["mse_mm"]) == len(ra["adev_mm"]) == len(ra["oadev_mm"]) == 7
        assert ra["n_points"] > 0
    assert j["thresholds"] == {"scale_m": 5.0, "mse_mm": 0.67, "adev_mm": 0.16, "components": ["vertical", "lateral"]}
    assert j["samples"]["passes"] == 2
    assert len(j["overlaps"]) == 1 and j["overlaps"][0]["passes"] == [0, 1]
    # lateral error 1 mm * sin(s / 9 m): sigma (eq. 1) = 1/sqrt(2) mm, MSE(5 m) = sqrt(2) sin(5 / 18) mm
    lat = j["relative_accuracy"]["lateral"]
    assert lat["sigma_mm"] == pytest.approx(1 / np.sqrt(2), rel=0.05)
    assert lat["mse_at_threshold_mm"] == pytest.approx(np.sqrt(2) * np.sin(5 / 18), rel=0.05)
    assert lat["mse_pass"] is True and lat["adev_pass"] is False  # ADEV ~ 0.38 mm > 0.16 mm
    assert j["passed"] is False


def test_chainage_match_and_configurable_thresholds(files):
    _, est, ref = files
    cfg = EvaluationConfig(scales_m=(1.0, 5.0), adev_threshold_mm=0.5, mse_threshold_mm=0.67)
    res = evaluate_files(est, ref, match="chainage", config=cfg)
    assert res.relative_accuracy["lateral"].scales_m.tolist() == [1.0, 5.0]
    assert res.passed
    assert res.to_json()["match"] == "chainage"


def test_threshold_scale_outside_the_scales_is_still_checked(files):
    _, est, ref = files
    res = evaluate_files(est, ref, config=EvaluationConfig(scales_m=(1.0, 2.0)))
    assert np.isfinite(res.checks["vertical"].mse_mm)


def test_figure_is_a_png(files, tmp_path):
    _, est, ref = files
    res = evaluate_files(est, ref)
    png = relative_accuracy_png(res, tmp_path / "ra.png", title="test")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "ra.png").read_bytes() == png


def _run_cli(capsys, *args):
    code = cli.main(["evaluate", *map(str, args)])
    err = capsys.readouterr().err
    return code, err


def test_empty_file_exit_2(files, capsys, tmp_path):
    _, est, _ = files
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    code, err = _run_cli(capsys, est, empty)
    assert code == 2
    assert err.count("\n") == 1 and str(empty) in err and "empty" in err


def test_missing_column_exit_2(files, capsys, tmp_path):
    _, est, ref = files
    cols = syn.truth_columns(np.arange(0.0, 100.0, 0.02))
    del cols["vu_mps"]
    bad = _write(tmp_path / "novu.csv", cols, {k: TRUTH_UNITS[k] for k in cols})
    code, err = _run_cli(capsys, bad, ref)
    assert code == 2
    assert err.count("\n") == 1 and str(bad) in err and "'vu_mps'" in err


def test_no_time_overlap_exit_2(files, capsys, tmp_path):
    _, est, _ = files
    cols = syn.truth_columns(np.arange(0.0, 420.0, 0.02))
    cols["t_s"] = cols["t_s"] + 5000.0
    late = _write(tmp_path / "late.csv", cols, TRUTH_UNITS)
    code, err = _run_cli(capsys, est, late)
    assert code == 2
    assert err.count("\n") == 1 and str(est) in err and "no overlap in time" in err


def test_missing_sidecar_and_other_origin_exit_2(files, capsys, tmp_path):
    _, est, ref = files
    cols = syn.truth_columns(np.arange(0.0, 420.0, 0.02))
    other = _write(tmp_path / "other.csv", cols, TRUTH_UNITS, origin={"lat_deg": 1.0, "lon_deg": 2.0, "h_m": 3.0})
    code, err = _run_cli(capsys, est, other)
    assert code == 2 and "origin" in err and err.count("\n") == 1
    (tmp_path / "other.json").unlink()
    code, err = _run_cli(capsys, est, other)
    assert code == 2 and "sidecar not found" in err and "other.json" in err


def test_header_only_file_exit_2_with_one_line(files, capsys, tmp_path):
    _, est, _ = files
    hdr = tmp_path / "header_only.csv"
    hdr.write_text("t_s,e_m,n_m,u_m,ve_mps,vn_mps,vu_mps,chainage_m\n")
    code, err = _run_cli(capsys, est, hdr)
    assert code == 2
    assert err.count("\n") == 1 and str(hdr) in err and "no data rows" in err


def test_estimate_time_not_increasing_exit_2(files, capsys, tmp_path):
    _, _, ref = files
    cols = syn.truth_columns(np.arange(0.0, 420.0, 0.01))
    cols["t_s"] = cols["t_s"][::-1].copy()
    rev = _write(tmp_path / "reversed.csv", syn.with_errors(cols, np.zeros((cols["t_s"].size, 3))))
    code, err = _run_cli(capsys, rev, ref)
    assert code == 2
    assert err.count("\n") == 1 and str(rev) in err and "t_s is not strictly increasing at data row 2" in err
