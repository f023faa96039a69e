"""``trackfusion init``: a runnable, commented pipeline for a log (trackfusion/init.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from trackfusion.cli import main
from trackfusion.pipeline import load_pipeline, run
from trackfusion.sensors.imu import IMU_GRADES
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.simulation.scenarios import simulate_to_dir

from surveys import SHORT_OPEN_TRACK


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A short simulated open-track survey, its own pipeline moved aside, and a copy of its log
    without the lever-arm and sensor records (as a logger that records none would write it)."""
    d = tmp_path_factory.mktemp("init")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=SHORT_OPEN_TRACK)
    (d / "pipeline.yaml").rename(d / "simulator.yaml")
    log = read_log(d / "log.mcap")
    bare = {k: v for k, v in log.metadata.items() if k not in ("lever_arms", "sensors")}
    write_log(d / "bare.mcap", replace(log, metadata=bare, source=None))
    return d


def _init(capsys, *args):
    code = main(["init", *map(str, args)])
    return code, capsys.readouterr()


def test_init_then_run_matches_the_simulators_pipeline(survey, capsys):
    """Simulate, delete the pipeline, ``init`` + ``run``: the accuracy of the simulator's own
    pipeline (whose NHC sigmas the simulator derives from its own track; init writes the
    library's datasheet defaults and the grade's figures)."""
    d = survey
    code, cap = _init(capsys, d / "log.mcap", "--out", d / "pipeline.yaml", "--imu-grade", "navigation",
                      "--set", "inputs.reference=truth.csv", "--set", "outputs.report=false")
    assert code == 0, cap.err
    text = (d / "pipeline.yaml").read_text()
    assert "# /imu: 43000 records at 200 Hz" in text and "/odometer: 21501 records at 100 Hz" in text
    cfg = load_pipeline(d / "pipeline.yaml").config
    assert cfg.vehicle.kind == "trolley" and cfg.factors.wheel_path.enabled and cfg.factors.gnss.enabled
    assert cfg.sensors.imu.gyro_arw_deg_per_sqrt_h == IMU_GRADES["navigation"].gyro_arw_deg_per_sqrt_h
    assert cfg.sensors.gnss.lever_arm_b_m == (0.0, 0.0, 1.5)  # the log's lever_arms record
    ours = run(load_pipeline(d / "pipeline.yaml"), d / "out-init").metrics
    sim = yaml.safe_load((d / "simulator.yaml").read_text())
    sim["outputs"]["report"] = False
    (d / "simulator.yaml").write_text(yaml.safe_dump(sim))
    theirs = run(load_pipeline(d / "simulator.yaml"), d / "out-sim").metrics
    for c in ("vertical", "lateral"):
        a, b = ours["absolute_error"][c]["rms_mm"], theirs["absolute_error"][c]["rms_mm"]
        assert a <= 1.05 * b + 0.05, (c, a, b)
        a = ours["relative_accuracy"][c]["mse_at_threshold_mm"]
        b = theirs["relative_accuracy"][c]["mse_at_threshold_mm"]
        assert a <= 1.05 * b + 0.005, (c, a, b)
    assert ours["static_intervals_s"] == theirs["static_intervals_s"]


def test_init_without_records_writes_zeros_to_fill_in(survey, capsys):
    d = survey
    out = d / "bare.yaml"
    code, cap = _init(capsys, d / "bare.mcap", "--out", out)
    assert code == 0, cap.err
    assert "fill in" in cap.out and "sensors.gnss.lever_arm_b_m" in cap.out
    text = out.read_text()
    assert ("# FILL IN before trusting the results: vehicle.wheelbase_m, vehicle.lever_arm_imu_v_m, "
            "sensors.gnss.lever_arm_b_m") in text
    assert "FILL IN: antenna phase centre" in text
    cfg = load_pipeline(out).config
    assert cfg.vehicle.wheelbase_m == 1.0 and not cfg.factors.wheel_path.enabled  # a placeholder: no wheel path
    assert cfg.sensors.gnss.lever_arm_b_m == (0.0, 0.0, 0.0) and cfg.vehicle.lever_arm_imu_v_m == (0.0, 0.0, 0.0)
    assert cfg.sensors.imu.gyro_bias_deg_per_h == IMU_GRADES["navigation"].gyro_bias_deg_per_h  # no record: navigation
    assert cfg.origin.lat_deg == pytest.approx(42.86)  # the survey metadata record's
    # --set a measured lever arm (YAML value), a key below a factor written as true, a grade
    code, cap = _init(capsys, d / "bare.mcap", "--out", out, "--force", "--vehicle", "trolley", "--imu-grade", "fog",
                      "--set", "vehicle.wheelbase_m=1.2", "--set", "sensors.gnss.lever_arm_b_m=[0.1, 0.3, 0.2]",
                      "--set", "factors.odometer.sigma_mm=0.1")
    assert code == 0, cap.err
    cfg = load_pipeline(out).config
    assert cfg.vehicle.wheelbase_m == 1.2 and cfg.factors.wheel_path.enabled  # measured: the wheel path on
    assert cfg.sensors.gnss.lever_arm_b_m == (0.1, 0.3, 0.2) and cfg.factors.odometer.sigma_mm == 0.1
    assert cfg.factors.odometer.enabled and cfg.sensors.imu.gyro_arw_deg_per_sqrt_h == 0.03
    assert "sensors.gnss.lever_arm_b_m" not in out.read_text().split("FILL IN before")[-1].splitlines()[0]


@pytest.mark.parametrize("kind, geometry, wheel_path, nhc", [
    ("road-vehicle", False, False, 100.0), ("rail-vehicle", True, False, 50.0)])
def test_init_other_kinds(survey, capsys, kind, geometry, wheel_path, nhc):
    d = survey
    out = d / f"{kind}.yaml"
    code, cap = _init(capsys, d / "log.mcap", "--out", out, "--vehicle", kind)
    assert code == 0, cap.err
    cfg = load_pipeline(out).config
    assert cfg.vehicle.kind == kind and cfg.geometry.enabled is geometry
    assert cfg.factors.wheel_path.enabled is wheel_path and cfg.factors.odometer.enabled
    assert cfg.factors.nhc.sigmas_mps() == pytest.approx(np.array([nhc, nhc]) * 1e-3)


@pytest.mark.parametrize("args, needle", [
    (["--set", "sensors.gnss.lever_arm=[0,0,1]"], "--set sensors.gnss.lever_arm: not a pipeline key"),
    (["--set", "factors.nhc.sigma=1"], "--set factors.nhc.sigma: not a pipeline key"),
    (["--set", "colour=red"], "--set colour: not a pipeline key"),
    (["--set", "factors.nhc.sigma_mm_per_s=-1"], "factors.nhc.sigma_mm_per_s"),
    (["--set", "no-equals-sign"], "--set no-equals-sign"),
    (["--set", "vehicle.kind=boat"], "vehicle"),
])
def test_init_bad_set_exits_2_naming_the_key(survey, capsys, args, needle):
    d = survey
    out = d / "bad.yaml"
    code, cap = _init(capsys, d / "log.mcap", "--out", out, *args)
    err = cap.err.strip().splitlines()
    assert code == 2 and needle in err[-1] and "Traceback" not in cap.err, err
    assert not out.exists()


def test_init_refuses_to_overwrite(survey, capsys):
    d = survey
    out = d / "kept.yaml"
    out.write_text("mine\n")
    code, cap = _init(capsys, d / "log.mcap", "--out", out)
    assert code == 2 and "--force" in cap.err and out.read_text() == "mine\n"
    code, cap = _init(capsys, d / "log.mcap", "--out", out, "--force")
    assert code == 0 and load_pipeline(out).config.vehicle.kind == "trolley"


def test_init_trolley_with_total_stations_gets_the_wheel_path(tmp_path, capsys):
    """A trolley log with an odometer and prism readings (no GNSS): the wheel path on 0.2 s
    keyframes, as measured on the bridge (benchmarks/bridge_keyframes.py); the stations wait
    for their set-ups."""
    from test_total_station_run import SHORT as SHORT_BRIDGE
    simulate_to_dir("bridge-total-station", tmp_path, seed=2, overrides=SHORT_BRIDGE[:4])
    code, cap = _init(capsys, tmp_path / "log.mcap", "--out", tmp_path / "init.yaml")
    assert code == 0, cap.err
    cfg = load_pipeline(tmp_path / "init.yaml").config
    assert cfg.factors.wheel_path.enabled and cfg.keyframes.spacing_s == 0.2
    assert not cfg.factors.gnss.enabled and not cfg.factors.total_stations.enabled
