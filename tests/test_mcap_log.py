"""Raw MCAP log: exact round trip, determinism, one-line errors naming topic and record, fuzzing."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer

from trackfusion.cli import main
from trackfusion.errors import SensorDataError
from trackfusion.sensors.mcap_log import inspect_log, read_log, write_log
from trackfusion.sensors.types import (GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog,
                                       TotalStationData)


def small_log(n=200, gap=False):
    rng = np.random.default_rng(0)
    t = np.arange(1, n + 1) / 100.0
    if gap:
        t[n // 2:] += 1.0
    cov = np.tile(np.diag([1e-4, 1e-4, 4e-4]), (5, 1, 1))
    return SensorLog(
        imu=ImuData(t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) + [0, 0, 9.8]),
        odometer=OdometerData(t[::2], np.cumsum(rng.random(n // 2)), np.arange(n // 2, dtype=np.int64) * 7),
        gnss=GnssData(np.arange(5.0), 22.9 + rng.random(5) * 1e-5, 112.9 + rng.random(5) * 1e-5,
                      20 + rng.random(5), cov, np.array([4, 4, 5, 4, 4])),
        total_stations={"TS01": TotalStationData("TS01", 3.25 + np.arange(10) / 10, rng.random(10), 1.5 + rng.random(10) * 0.1,
                                                 100 + rng.random(10), np.array(["P1"] * 10, dtype=object))},
        inclinometer=InclinometerData(t[::4], rng.normal(size=n // 4) * 1e-3, rng.normal(size=n // 4) * 1e-3),
        gauge=GaugeData(t[::4], 1.435 + rng.normal(size=n // 4) * 1e-4),
        metadata={"survey": {"scenario": "unit", "x": [1, 2]}, "lever_arms": {"prism_b_m": [0, 0, 1]}},
    )


def test_round_trip_is_exact(tmp_path):
    log = small_log()
    write_log(tmp_path / "a.mcap", log)
    back = read_log(tmp_path / "a.mcap")
    assert np.array_equal(back.imu.gyro_radps, log.imu.gyro_radps)
    assert np.array_equal(back.imu.accel_mps2, log.imu.accel_mps2)
    assert np.abs(back.imu.t_s - log.imu.t_s).max() < 1e-9
    assert np.array_equal(back.odometer.distance_m, log.odometer.distance_m)
    assert np.array_equal(back.odometer.ticks, log.odometer.ticks)
    for k in ("lat_deg", "lon_deg", "h_m", "cov_enu_m2", "fix_quality"):
        assert np.array_equal(getattr(back.gnss, k), getattr(log.gnss, k))
    ts, ts0 = back.total_stations["TS01"], log.total_stations["TS01"]
    for k in ("horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m", "prism_id"):
        assert np.array_equal(getattr(ts, k), getattr(ts0, k))
    assert np.array_equal(back.inclinometer.roll_rad, log.inclinometer.roll_rad)
    assert np.array_equal(back.gauge.gauge_m, log.gauge.gauge_m)
    assert back.metadata == log.metadata


def test_identical_input_gives_identical_bytes(tmp_path):
    write_log(tmp_path / "a.mcap", small_log())
    write_log(tmp_path / "b.mcap", small_log())
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_inspect_reports_counts_rates_and_gap(tmp_path, capsys):
    write_log(tmp_path / "a.mcap", small_log(gap=True))
    summary = {t.topic: t for t in inspect_log(tmp_path / "a.mcap").topics}
    assert summary["/imu"].count == 200 and summary["/imu"].gaps == 1
    assert summary["/imu"].largest_gap_s == pytest.approx(1.01)
    assert summary["/gnss"].rate_hz == pytest.approx(1.0)
    assert summary["/total_station/TS01"].first_s == pytest.approx(3.25)
    assert main(["inspect", str(tmp_path / "a.mcap")]) == 0
    assert "/odometer" in capsys.readouterr().out


def _raw_log(path, topic, schema, payloads, times):
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(schema, "jsonschema", b"{}")
        cid = w.register_channel(topic, "json", sid)
        for t, p in zip(times, payloads):
            w.add_message(cid, log_time=t, data=p.encode(), publish_time=t)
        w.finish()


IMU_OK = '{"angular_velocity":{"x":0.1,"y":0.0,"z":0.0},"linear_acceleration":{"x":0.0,"y":0.0,"z":9.8}}'


@pytest.mark.parametrize("topic, schema, payloads, times, message", [
    ("/imu", "trackfusion.Imu", [IMU_OK] * 3, [1, 3, 2], "/imu record 2: log_time going backwards"),
    ("/imu", "trackfusion.Imu", [IMU_OK] * 3, [1, 2, 2], "/imu record 2: log_time duplicated"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace("9.8", "NaN")], [1, 2], "/imu record 1: linear_acceleration.z is nan"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace('"y":0.0,', "", 1)], [1, 2], "/imu record 1: missing field angular_velocity.y"),
    ("/imu", "acme.Imu", [IMU_OK], [1], "/imu record 0: unknown schema 'acme.Imu'"),
    ("/lidar", "trackfusion.Imu", [IMU_OK], [1], "/lidar record 0: unknown topic"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '{"gauge_m":"wide"}'], [1, 2], "/gauge record 1: gauge_m is not a number"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '{"gauge_m":1.4'], [1, 2], "/gauge record 1: invalid JSON"),
])
def test_bad_records_name_topic_and_record(tmp_path, capsys, topic, schema, payloads, times, message):
    path = tmp_path / "bad.mcap"
    _raw_log(path, topic, schema, payloads, times)
    before = path.read_bytes()
    with pytest.raises(SensorDataError, match=message.replace("(", r"\(")):
        read_log(path)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and str(path) in err[0]
    assert path.read_bytes() == before  # inputs are never modified


@pytest.mark.parametrize("fraction", [0.02, 0.3, 0.6, 0.97])
def test_truncated_file_is_an_error_and_its_readable_part_can_be_kept(tmp_path, capsys, fraction):
    full = tmp_path / "a.mcap"
    write_log(full, small_log(4000))
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(SensorDataError, match="truncated"):
        read_log(cut)
    assert main(["inspect", str(cut)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    part = read_log(cut, allow_truncated=True)
    n = 0 if part.imu is None else part.imu.t_s.size
    assert n <= 4000
    if n:
        assert np.array_equal(part.imu.gyro_radps, small_log(4000).imu.gyro_radps[:n])


def test_missing_file(tmp_path, capsys):
    assert main(["inspect", str(tmp_path / "nope.mcap")]) == 2
    assert "file not found" in capsys.readouterr().err


def test_writer_refuses_non_finite(tmp_path):
    log = small_log()
    log.imu.accel_mps2[3, 1] = np.inf
    with pytest.raises(SensorDataError, match="/imu"):
        write_log(tmp_path / "a.mcap", log)
    assert not list(tmp_path.iterdir())  # no partial file left behind


@pytest.fixture(scope="module")
def valid_bytes(tmp_path_factory):
    p = tmp_path_factory.mktemp("fuzz") / "ok.mcap"
    write_log(p, small_log(60))
    return p.read_bytes()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_reader_only_raises_sensor_data_error(tmp_path_factory, valid_bytes, data):
    raw = bytearray(valid_bytes)
    for _ in range(data.draw(st.integers(0, 6))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    raw = raw[: data.draw(st.integers(0, len(raw)))]
    p = tmp_path_factory.mktemp("f") / "x.mcap"
    p.write_bytes(bytes(raw))
    for allow in (False, True):
        try:
            read_log(p, allow_truncated=allow)
        except SensorDataError as exc:
            assert "\n" not in str(exc)
