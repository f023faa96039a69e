"""CSV/text importers: round trips (simulate / every sensor -> export -> import -> the same log),
unit conversions of a hand-written mapping, and bad files (exit 2, one line naming file, line,
column; no output written)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trackfusion.cli import main
from trackfusion.sensors.importers import G0_MPS2, import_log
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.sensors.types import (GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog,
                                       TotalStationData)
from trackfusion.simulation.scenarios import simulate_to_dir

SHORT = ["motion.passes=1",
         "motion.segments=[{hold_s: 5}, {move_to_m: 40, speed_mps: 2, accel_mps2: 0.4}]"]


def _every_sensor_log() -> SensorLog:
    rng = np.random.default_rng(7)
    t = np.round(np.arange(1, 301) * 0.005 + 1000.0, 9)
    n = t.size
    cov = np.einsum("ni,ij->nij", rng.uniform(1e-4, 1e-3, (n, 3)), np.eye(3))
    cov[:, 0, 1] = cov[:, 1, 0] = 1e-5
    ts = {sid: TotalStationData(sid, t[::3] + k * 0.1234, rng.uniform(0, 6.28, n // 3), rng.uniform(1.4, 1.7, n // 3),
                                rng.uniform(5, 300, n // 3), np.array(["P1", "P2"] * (n // 6), dtype=object))
          for k, sid in enumerate(("TS01", "TS02"))}
    return SensorLog(
        imu=ImuData(t, rng.normal(0, 1e-3, (n, 3)), rng.normal([0, 0, 9.8], 0.1, (n, 3))),
        odometer=OdometerData(t, np.cumsum(rng.uniform(0, 0.01, n)), np.arange(n, dtype=np.int64) * 7),
        gnss=GnssData(t[::10], 52.0 + rng.normal(0, 1e-6, n // 10), 13.0 + rng.normal(0, 1e-6, n // 10),
                      rng.normal(40, 0.01, n // 10), cov[::10], np.full(n // 10, 4)),
        total_stations=ts, inclinometer=InclinometerData(t, rng.normal(0, 0.01, n), rng.normal(0, 0.01, n)),
        gauge=GaugeData(t, rng.normal(1.435, 0.001, n)),
        metadata={"survey": {"name": "all", "origin": {"lat_deg": 52.0, "lon_deg": 13.0, "h_m": 40.0}}})


def _round_trip(log_path, tmp_path):
    assert main(["export", str(log_path), "--out", str(tmp_path / "csv")]) == 0
    assert main(["import", str(tmp_path / "csv" / "import.yaml"), "--out", str(tmp_path / "back.mcap")]) == 0
    return tmp_path / "back.mcap"


def test_simulated_log_round_trips_through_csv(tmp_path):
    simulate_to_dir("open-track-gnss", tmp_path / "sim", seed=3, ideal=False, overrides=SHORT)
    back = _round_trip(tmp_path / "sim" / "log.mcap", tmp_path)
    assert back.read_bytes() == (tmp_path / "sim" / "log.mcap").read_bytes()


def test_every_sensor_round_trips_through_csv(tmp_path):
    write_log(tmp_path / "all.mcap", _every_sensor_log())
    back = _round_trip(tmp_path / "all.mcap", tmp_path)
    assert back.read_bytes() == (tmp_path / "all.mcap").read_bytes()
    log = read_log(back)
    assert set(log.total_stations) == {"TS01", "TS02"} and log.total_stations["TS02"].prism_id[1] == "P2"


MAPPING = """
survey: {name: field survey, origin: {lat_deg: 48.1, lon_deg: 11.5, h_m: 520.0}}
imu:
  file: imu.txt
  delimiter: whitespace
  header: false
  time: {column: 0, unit: ms}
  gyro: {columns: [1, 2, 3], unit: deg/s}
  accel: {columns: [4, 5, 6], unit: g}
odometer:
  file: odo.csv
  delimiter: ";"
  skip_rows: 2
  time: {column: time_us, unit: us}
  distance: {column: dist_mm, unit: mm}
  ticks_per_m: 1000
gnss:
  file: gnss.csv
  time: {column: t, unit: s}
  latitude: {column: lat, unit: deg}
  longitude: {column: lon, unit: deg}
  height: {column: h, unit: m}
  sigma_enu: {columns: [se, sn, su], unit: mm}
total_stations:
  TS7:
    file: ts7.csv
    time: {column: t, unit: s}
    horizontal_angle: {column: hz, unit: gon}
    zenith_angle: {column: v, unit: gon}
    slope_distance: {column: sd, unit: m}
    prism_id: "360"
"""


def _field_files(d):
    (d / "import.yaml").write_text(MAPPING)
    (d / "imu.txt").write_text("# t_ms wx wy wz fx fy fz\n10  1.0 0 0  0 0 1.0\n20  0 2.0 0  0.5 0 1.0\n"
                               "\n30  0 0 -1.5  0 0 1.0\n")
    (d / "odo.csv").write_text("logger v2\nexported 2024-05-01\ntime_us;dist_mm\n10000;0.0\n20000;1.5\n30000;3.25\n")
    (d / "gnss.csv").write_text("t,lat,lon,h,se,sn,su\n0.01,48.1,11.5,520.5,10,10,20\n1.01,48.1000001,11.5,520.5,10,12,20\n")
    (d / "ts7.csv").write_text("t,hz,v,sd\n100.0,100.0,100.0,12.5\n100.1,200.0,99.5,12.6\n")


def test_mapping_converts_units_and_layouts(tmp_path):
    _field_files(tmp_path)
    log = import_log(tmp_path / "import.yaml")
    np.testing.assert_allclose(log.imu.t_s, [0.01, 0.02, 0.03], rtol=0, atol=1e-15)
    np.testing.assert_allclose(log.imu.gyro_radps[1], [0.0, math.radians(2.0), 0.0], rtol=1e-15)
    np.testing.assert_allclose(log.imu.accel_mps2[1], [0.5 * G0_MPS2, 0.0, G0_MPS2], rtol=1e-15)
    np.testing.assert_allclose(log.odometer.distance_m, [0.0, 1.5e-3, 3.25e-3], rtol=1e-15)
    assert log.odometer.ticks.tolist() == [0, 2, 3]  # round(distance * 1000 ticks/m)
    np.testing.assert_allclose(log.gnss.cov_enu_m2[1], np.diag([1e-4, 1.44e-4, 4e-4]), rtol=1e-12)
    assert log.gnss.fix_quality.tolist() == [4, 4]
    ts = log.total_stations["TS7"]
    np.testing.assert_allclose(ts.horizontal_angle_rad, [math.pi / 2, math.pi], rtol=1e-15)
    np.testing.assert_allclose(ts.zenith_angle_rad[1], 99.5 * math.pi / 200, rtol=1e-15)
    assert ts.prism_id.tolist() == ["360", "360"]
    assert log.metadata["survey"]["origin"]["h_m"] == 520.0
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "log.mcap")]) == 0
    assert read_log(tmp_path / "log.mcap").total_stations["TS7"].t_s.tolist() == [100.0, 100.1]


@pytest.mark.parametrize("file, text, message", [
    ("imu.txt", "10 1 0 0 0 0 1\n20 1 0 x 0 0 1\n", "imu.txt: line 2, column 3: 'x' is not a number"),
    ("imu.txt", "10 1 0 0 0 0 1\n20 1 0 0 0 0\n", "imu.txt: line 2, column 6: missing"),
    ("imu.txt", "# c\n10 1 0 0 0 0 1\n10 1 0 0 0 0 1\n", "imu.txt: line 3, column 0: time does not increase"),
    ("gnss.csv", "t,lat,lon,h,se,sn,su\n0.01,48.1,11.5,nan,10,10,20\n", "gnss.csv: line 2, column 'h': 'nan' is not finite"),
    ("gnss.csv", "t,lat,lon,height,se,sn,su\n0.01,48.1,11.5,5,10,10,20\n", "gnss.csv: column 'h' not in the header"),
    ("ts7.csv", "", "ts7.csv: no header line"),
])
def test_bad_file_exits_2_naming_file_line_and_column(tmp_path, capsys, file, text, message):
    _field_files(tmp_path)
    (tmp_path / file).write_text(text)
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "log.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "log.mcap").exists() and [p.name for p in tmp_path.glob(".*")] == []


def test_bad_mapping_names_the_field(tmp_path, capsys):
    _field_files(tmp_path)
    (tmp_path / "import.yaml").write_text(MAPPING.replace("unit: deg/s", "unit: furlong/s"))
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "log.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert "imu.txt: gyro: unknown unit 'furlong/s'" in err
    (tmp_path / "import.yaml").write_text(MAPPING.replace("delimiter: whitespace", "separator: x"))
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "log.mcap")]) == 2
    assert "import.yaml: imu.separator" in capsys.readouterr().err
