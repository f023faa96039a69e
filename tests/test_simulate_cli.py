"""`trackfusion simulate` end to end: the files, their contracts, determinism, bad input."""

import json

import numpy as np
import pytest
import yaml

from trackfusion.outdir import MANIFEST
from trackfusion.cli import main
from trackfusion.sensors.fileio import read_csv_table, read_sidecar
from trackfusion.sensors.mcap_log import read_log
from trackfusion.simulation.scenarios import GEOMETRY_COLUMNS, TRUTH_COLUMNS

FILES = ["log.mcap", "truth.csv", "truth.json", "geometry_truth.csv", "geometry_truth.json", "pipeline.yaml"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("sim")
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        assert main(["simulate", "track-level", "--out", str(base / name), "--seed", str(seed)]) == 0
    return base


def test_writes_every_file_with_its_contract(runs):
    out = runs / "a"
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(FILES)
    assert json.loads((out / MANIFEST).read_text())["files"] == sorted(FILES)  # what the run wrote
    truth = read_csv_table(out / "truth.csv", required=list(TRUTH_COLUMNS))
    assert list(truth)[:12] == list(TRUTH_COLUMNS)
    assert np.median(np.diff(truth["t_s"])) <= 1 / 50  # at least 50 rows per second
    side = read_sidecar(out / "truth.csv")
    assert side["frame"] == "n" and set(side["origin"]) == {"lat_deg", "lon_deg", "h_m"}
    assert side["columns"]["e_m"] == "m"
    assert side["errors"]["imu"]["gyro_radps"]["bias"]  # drawn errors are recorded
    geo = read_csv_table(out / "geometry_truth.csv", required=list(GEOMETRY_COLUMNS))
    assert list(geo)[:7] == list(GEOMETRY_COLUMNS)
    assert np.allclose(np.diff(geo["chainage_m"]), 0.25)
    log = read_log(out / "log.mcap")
    assert {"survey", "sensors", "lever_arms"} <= set(log.metadata)
    assert log.inclinometer is not None and log.gauge is not None and log.odometer is not None
    pipeline = yaml.safe_load((out / "pipeline.yaml").read_text())
    assert pipeline["inputs"] == {"log": "log.mcap", "reference": "truth.csv"}
    assert pipeline["factors"]["inclinometer"] is True


def test_same_seed_gives_byte_identical_files(runs):
    for f in FILES:
        assert (runs / "a" / f).read_bytes() == (runs / "b" / f).read_bytes(), f
    assert (runs / "a" / "log.mcap").read_bytes() != (runs / "c" / "log.mcap").read_bytes()


def test_total_station_truth_json_has_clock_offsets(tmp_path):
    out = tmp_path / "ts"
    assert main(["simulate", "bridge-total-station", "--out", str(out),
                 "--set", "motion.segments.1.move_to_m=700", "--set", "motion.segments.3.move_to_m=400",
                 "--set", "motion.segments.0.hold_s=10", "--set", "total_stations.handover.1.at_chainage_m=600",
                 "--set", "total_stations.handover.2.at_chainage_m=500"]) == 0
    info = json.loads((out / "truth.json").read_text())
    assert set(info["total_stations"]) == {"TS01", "TS02"}
    for sid, d in info["total_stations"].items():
        assert abs(d["clock_offset_s"]) <= 5.0
    log = read_log(out / "log.mcap")
    assert set(log.total_stations) == {"TS01", "TS02"}


@pytest.mark.parametrize("args, message", [
    (["simulate", "no-such-scenario", "--out", "{tmp}/x"], "unknown scenario"),
    (["simulate", "track-level", "--out", "{tmp}/x", "--set", "imu.rate_hz=0"], "imu: rate_hz"),
    (["simulate", "track-level", "--out", "{tmp}/x", "--set", "trolley.wheelbase=1"], "trolley.wheelbase"),
    (["simulate", "track-level", "--out", "{tmp}/x", "--set", "motion.start_m=5000"], "motion"),
])
def test_bad_input_exit_2_one_line_no_output(tmp_path, capsys, args, message):
    args = [a.format(tmp=tmp_path) for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())
