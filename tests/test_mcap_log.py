"""Raw MCAP log: exact round trip, determinism, conformance, one-line errors naming topic and record, fuzzing."""

import json
import os
from concurrent.futures import Future

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from trackfusion.cli import main
from trackfusion.errors import SensorDataError
from trackfusion.sensors import schemas
from trackfusion.sensors.mcap_log import inspect_log, read_log, write_log
from trackfusion.sensors.types import (GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog,
                                       TotalStationData)

EDGE_FLOATS = np.array([0.0, -0.0, 5e-324, -2.2250738585072014e-308, 1e-5, 0.1, 1 / 3, 1e16, -1.7976931348623157e308,
                        123456789.123456789, 9.80665, 2.0**-30])


def small_log(n=200, gap=False, seed=0):
    """A log with every sensor: IMU and odometer on a 10 ms grid, GNSS 1 Hz, one total station."""
    rng = np.random.default_rng(seed)
    t = np.arange(1, n + 1) / 100.0
    if gap:
        t[n // 2:] += 1.0
    gyro = rng.normal(size=(n, 3))
    gyro.flat[:EDGE_FLOATS.size] = EDGE_FLOATS
    cov = np.tile(np.diag([1e-4, 1e-4, 4e-4]), (5, 1, 1))
    cov[:, 0, 1] = cov[:, 1, 0] = rng.random(5) * 1e-5
    return SensorLog(
        imu=ImuData(t, gyro, rng.normal(size=(n, 3)) + [0, 0, 9.8]),
        odometer=OdometerData(t[::2], np.cumsum(rng.random(n // 2)), np.arange(n // 2, dtype=np.int64) * 7 - 2**40),
        gnss=GnssData(np.arange(5.0), 22.9 + rng.random(5) * 1e-5, 112.9 + rng.random(5) * 1e-5,
                      20 + rng.random(5), cov, np.array([4, 4, 5, 4, 1])),
        total_stations={
            "TS01": TotalStationData("TS01", 3.25 + np.arange(10) / 10, rng.random(10), 1.5 + rng.random(10) * 0.1,
                                     100 + rng.random(10), np.array(["P1"] * 9 + ['prism "β"'], dtype=object)),
            "TS02": TotalStationData("TS02", 1000.0 + np.arange(3), rng.random(3), rng.random(3), rng.random(3),
                                     np.array(["P2"] * 3, dtype=object))},
        inclinometer=InclinometerData(t[::4], rng.normal(size=n // 4) * 1e-3, rng.normal(size=n // 4) * 1e-3),
        gauge=GaugeData(t[::4], 1.435 + rng.normal(size=n // 4) * 1e-4),
        metadata={"survey": {"scenario": "unit", "x": [1, 2], "origin": {"lat_deg": 22.9}},
                  "lever_arms": {"prism_b_m": [0, 0, 1.25]}, "sensors": {"imu": {"arw_deg_per_sqrt_h": 0.002}}},
    )


def assert_logs_equal(a: SensorLog, b: SensorLog):
    """Every array bit-exact (float times too: they lie on a 1 ns grid)."""
    def same(x, y):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape
        if x.dtype.kind == "f":
            assert np.array_equal(x.view(np.uint64), y.astype(np.float64).view(np.uint64))
        else:
            assert x.tolist() == y.tolist()

    for name in ("imu", "odometer", "gnss", "inclinometer", "gauge"):
        da, db = getattr(a, name), getattr(b, name)
        assert (da is None) == (db is None)
        if da is not None:
            for f in da.__dataclass_fields__:
                same(getattr(da, f), getattr(db, f))
    assert sorted(a.total_stations) == sorted(b.total_stations)
    for sid in a.total_stations:
        for f in ("t_s", "horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m", "prism_id"):
            same(getattr(a.total_stations[sid], f), getattr(b.total_stations[sid], f))
        assert a.total_stations[sid].station_id == b.total_stations[sid].station_id == sid
    assert a.metadata == b.metadata


def test_round_trip_is_bit_exact_for_every_topic(tmp_path):
    log = small_log()
    write_log(tmp_path / "a.mcap", log)
    back = read_log(tmp_path / "a.mcap")
    assert_logs_equal(log, back)
    assert back.odometer.ticks.dtype == np.int64 and back.gnss.fix_quality.dtype == np.int64
    assert back.gnss.cov_enu_m2.shape == (5, 3, 3)


def test_identical_input_gives_identical_bytes_and_rewrite_is_identical(tmp_path):
    write_log(tmp_path / "a.mcap", small_log())
    write_log(tmp_path / "b.mcap", small_log())
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    write_log(tmp_path / "c.mcap", read_log(tmp_path / "a.mcap"))
    assert (tmp_path / "c.mcap").read_bytes() == (tmp_path / "a.mcap").read_bytes()
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_mcap_library_reads_our_file_with_index_and_crcs(tmp_path):
    log = small_log(3000)
    write_log(tmp_path / "a.mcap", log)
    with open(tmp_path / "a.mcap", "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 3000 + 1500 + 5 + 10 + 3 + 750 + 750
        assert {c.topic for c in summary.channels.values()} == {
            "/imu", "/odometer", "/gnss", "/total_station/TS01", "/total_station/TS02", "/inclinometer", "/gauge"}
        encodings = {s.name: s.encoding for s in summary.schemas.values()}
        assert encodings["sensor_msgs/msg/Imu"] == encodings["trackfusion_msgs/msg/OdometerDistance"] == "ros2msg"
        assert {c.topic: c.message_encoding for c in summary.channels.values()}["/imu"] == "cdr"
        # the ROS 2 topics decode with mcap_ros2's own decoder (what ROS tools and Foxglove do)
        from mcap_ros2.decoder import DecoderFactory
        ros = [m for _, _, _, m in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=["/imu", "/odometer"], log_time_order=False) if hasattr(m, "angular_velocity")]
        assert np.array_equal([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in ros],
                              log.imu.gyro_radps)
        assert np.array_equal([m.linear_acceleration.z for m in ros], log.imu.accel_mps2[:, 2])
        assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in ros] == np.rint(
            log.imu.t_s * 1e9).astype(int).tolist()
        fh.seek(0)
        reader = make_reader(fh, validate_crcs=True)
        gauge = [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=["/gauge"])]
        assert [g["gauge_m"] for _, g in gauge] == log.gauge.gauge_m.tolist()
        assert [t for t, _ in gauge] == np.rint(log.gauge.t_s * 1e9).astype(int).tolist()
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(meta["survey"]["json"]) == log.metadata["survey"]
        assert reader.get_header().library.startswith("trackfusion/")
        fix = json.loads(next(reader.iter_messages(topics=["/gnss"]))[2].data)
        assert fix["timestamp"] == {"sec": 0, "nsec": 0} and fix["position_covariance_type"] == 3


def test_schemas_are_valid_json_schema_documents():
    for name, doc in schemas.SCHEMAS.items():
        assert json.loads(schemas.schema_bytes(name)) == doc
        assert doc["$schema"].endswith("2020-12/schema") and doc["title"] == name
        for path, _ in schemas.FIELDS[name]:
            assert path.split(".")[0] in doc["properties"]


def _foreign_log(path, channels, compression=CompressionType.ZSTD, chunked=True):
    """An MCAP written by the mcap library: channels = [(topic, schema, [(log_time, payload str)])]."""
    with open(path, "wb") as fh:
        w = Writer(fh, compression=compression, use_chunking=chunked, chunk_size=200)
        w.start()
        for topic, schema, msgs in channels:
            sid = w.register_schema(schema, "jsonschema", b"{}")
            cid = w.register_channel(topic, "json", sid)
            for t, payload in msgs:
                w.add_message(cid, log_time=t, data=payload.encode(), publish_time=t)
        w.finish()


@pytest.mark.parametrize("compression, chunked", [(CompressionType.ZSTD, True), (CompressionType.LZ4, True),
                                                  (CompressionType.NONE, True), (CompressionType.NONE, False)])
def test_other_writers_layouts_are_read_exactly(tmp_path, compression, chunked):
    gyro = [0.1, -2.5e-7, 3.0]
    imu = [(10 + i, json.dumps({"linear_acceleration": {"z": 9.8, "y": 0, "x": i}, "extra": "ok",
                                "angular_velocity": dict(zip("xyz", gyro))}, indent=1)) for i in range(50)]
    fixes = [(5, json.dumps({"latitude": 1.5, "longitude": 2.5, "altitude": 3, "fix_quality": 4.0,
                             "position_covariance": list(range(9))}))]
    _foreign_log(tmp_path / "f.mcap", [("/imu", "trackfusion.Imu", imu), ("/gnss", "foxglove.LocationFix", fixes)],
                 compression, chunked)
    log = read_log(tmp_path / "f.mcap")
    assert log.imu.t_s.tolist() == [(10 + i) / 1e9 for i in range(50)]
    assert log.imu.accel_mps2[:, 0].tolist() == list(range(50)) and log.imu.gyro_radps[7].tolist() == gyro
    assert log.gnss.fix_quality.tolist() == [4] and log.gnss.cov_enu_m2[0].ravel().tolist() == list(range(9))


def test_topics_filter_decodes_only_those(tmp_path):
    write_log(tmp_path / "a.mcap", small_log())
    log = read_log(tmp_path / "a.mcap", topics=["/odometer", "/total_station/TS02"])
    assert log.imu is None and log.gnss is None and log.odometer.t_s.size == 100
    assert list(log.total_stations) == ["TS02"]


def test_inspect_reports_counts_rates_and_gap(tmp_path, capsys):
    write_log(tmp_path / "a.mcap", small_log(gap=True))
    result = inspect_log(tmp_path / "a.mcap")
    summary = {t.topic: t for t in result.topics}
    imu = summary["/imu"]
    assert imu.count == 200 and imu.gap_count == 1
    assert imu.largest_gap_s == pytest.approx(1.01) and imu.largest_gap_at_s == pytest.approx(1.0)
    assert imu.median_interval_s == pytest.approx(0.01) and imu.rate_hz == pytest.approx(199 / 2.99)
    assert summary["/gnss"].rate_hz == pytest.approx(1.0) and summary["/gnss"].gap_count == 0
    assert summary["/total_station/TS01"].first_s == pytest.approx(3.25)
    assert summary["/total_station/TS01"].clock == "station" and imu.clock == "imu"
    assert result.metadata == ["lever_arms", "sensors", "survey"]
    assert main(["inspect", str(tmp_path / "a.mcap")]) == 0
    out = capsys.readouterr().out
    assert "/odometer" in out and "trackfusion.Gauge" in out and "lever_arms, sensors, survey" in out


def _raw_log(path, topic, schema, payloads, times, encoding="json"):
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(schema, "jsonschema", b"{}")
        cid = w.register_channel(topic, encoding, sid)
        for t, p in zip(times, payloads):
            w.add_message(cid, log_time=t, data=p.encode(), publish_time=t)
        w.finish()


IMU_OK = '{"angular_velocity":{"x":0.1,"y":0.0,"z":0.0},"linear_acceleration":{"x":0.0,"y":0.0,"z":9.8}}'
IMU_NONCANONICAL = '{"angular_velocity": {"x": 0.1, "y": 0.0, "z": 0.0}, "linear_acceleration": {"x": 0, "y": 0, "z": 9.8}}'
BAD_RECORDS = [
    ("/imu", "trackfusion.Imu", [IMU_OK] * 3, [1, 3, 2], "/imu record 2: log_time going backwards"),
    ("/imu", "trackfusion.Imu", [IMU_OK] * 3, [1, 2, 2], "/imu record 2: log_time duplicated"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace("9.8", "NaN")], [1, 2],
     "/imu record 1: linear_acceleration.z is NaN"),
    ("/imu", "trackfusion.Imu", [IMU_NONCANONICAL, IMU_NONCANONICAL.replace('"y": 0,', '"y": NaN,')], [1, 2],
     "/imu record 1: linear_acceleration.y is NaN"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace("9.8", "-Infinity")], [1, 2],
     "/imu record 1: linear_acceleration.z is infinite"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace("9.8", "1e999")], [1, 2],
     "/imu record 1: linear_acceleration.z is infinite"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace('"y":0.0,', "", 1)], [1, 2],
     "/imu record 1: missing field angular_velocity.y"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace('{"x":0.1,"y":0.0,"z":0.0}', "[1,2,3]")], [1, 2],
     "/imu record 1: missing field angular_velocity.x"),
    ("/imu", "trackfusion.Imu", [IMU_OK, IMU_OK.replace("9.8", "true")], [1, 2],
     "/imu record 1: linear_acceleration.z is not a number"),
    ("/imu", "acme.Imu", [IMU_OK], [1], "/imu record 0: unknown schema 'acme.Imu'"),
    ("/imu", "trackfusion.Imu", [IMU_OK], [1], "/imu record 0: message encoding 'cbor' is not 'json'"),
    ("/lidar", "trackfusion.Imu", [IMU_OK], [1], "/lidar record 0: unknown topic"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '{"gauge_m":"1.4"}'], [1, 2],
     "/gauge record 1: gauge_m is not a number"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '{"gauge_m":1.4'], [1, 2], "/gauge record 1: invalid JSON"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '[1.435]'], [1, 2],
     "/gauge record 1: message is not a JSON object"),
    ("/gauge", "trackfusion.Gauge", ['{"gauge_m":1.435}', '{"gauge_m":1}, {"gauge_m":2}'], [1, 2],
     "/gauge record 1: invalid JSON"),
    ("/odometer", "trackfusion.Odometer", ['{"distance_m":0.5,"ticks":3}', '{"distance_m":0.6,"ticks":3.5}'], [1, 2],
     "/odometer record 1: ticks is not an integer"),
    ("/total_station/A", "trackfusion.PolarObservation",
     ['{"horizontal_angle_rad":1,"zenith_angle_rad":1,"slope_distance_m":9,"prism_id":7}'], [1],
     "/total_station/A record 0: prism_id is not a string"),
    ("/gnss", "foxglove.LocationFix",
     ['{"latitude":1,"longitude":2,"altitude":3,"fix_quality":4,"position_covariance":[1,2,3]}'], [1],
     "/gnss record 0: position_covariance is not an array of 9 numbers"),
]


@pytest.mark.parametrize("topic, schema, payloads, times, message", BAD_RECORDS,
                         ids=[m.split(": ", 1)[1] for *_, m in BAD_RECORDS])
def test_bad_records_name_file_topic_and_record(tmp_path, capsys, topic, schema, payloads, times, message):
    path = tmp_path / "bad.mcap"
    _raw_log(path, topic, schema, payloads, times, encoding="cbor" if "cbor" in message else "json")
    before = path.read_bytes(), path.stat().st_mtime_ns
    with pytest.raises(SensorDataError) as info:
        read_log(path)
    assert str(info.value).startswith(f"{path}: {message}") and "\n" not in str(info.value)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and str(path) in err[0]
    assert (path.read_bytes(), path.stat().st_mtime_ns) == before  # inputs are never modified


@pytest.mark.parametrize("bad_index, edit", [(1523, lambda p: p.replace('"y":', '"y":NaN,"q":', 1)),
                                             (1523, lambda p: p[:-1]),
                                             (0, lambda p: p.replace('"x":', '"x": ', 1))])
def test_first_bad_record_index_in_a_long_canonical_topic(tmp_path, bad_index, edit):
    """A bad record of a long JSON topic (several batches) is named by its exact index."""
    log = small_log(2000)
    write_log(tmp_path / "ok.mcap", log, encoding="json")
    with open(tmp_path / "ok.mcap", "rb") as fh:
        msgs = [(m.log_time, m.data.decode()) for _, _, m in make_reader(fh).iter_messages(topics=["/imu"])]
    msgs[bad_index] = (msgs[bad_index][0], edit(msgs[bad_index][1]))
    _foreign_log(tmp_path / "bad.mcap", [("/imu", "trackfusion.Imu", msgs)])
    if bad_index == 0:  # a harmless layout change: read through the JSON path, exactly
        assert np.array_equal(read_log(tmp_path / "bad.mcap").imu.gyro_radps, log.imu.gyro_radps)
        return
    with pytest.raises(SensorDataError, match=f"/imu record {bad_index}: "):
        read_log(tmp_path / "bad.mcap")


@pytest.mark.parametrize("number", ["01.5", "+1.5", ".5", "1.", "1e", "-", "1.2.3", "1e2.5", "1e+-2", "-01", "0x1"])
def test_numbers_that_are_not_json_are_refused_in_the_canonical_layout(tmp_path, number):
    """numpy would parse some of these; the reader refuses exactly what json refuses."""
    payloads = ['{"gauge_m":1.435}'] * 700 + ['{"gauge_m":%s}' % number] + ['{"gauge_m":1.5}'] * 5
    _raw_log(tmp_path / "g.mcap", "/gauge", "trackfusion.Gauge", payloads, range(1, len(payloads) + 1))
    with pytest.raises(SensorDataError, match="/gauge record 700: invalid JSON"):
        read_log(tmp_path / "g.mcap")


def test_two_channels_with_one_topic(tmp_path):
    _foreign_log(tmp_path / "a.mcap", [("/gauge", "trackfusion.Gauge", [(1, '{"gauge_m":1.4}')]),
                                       ("/gauge", "trackfusion.Gauge", [(2, '{"gauge_m":1.4}')])])
    with pytest.raises(SensorDataError, match="/gauge record 0: topic on two channels"):
        read_log(tmp_path / "a.mcap")


@pytest.fixture(scope="module")
def big_log_bytes(tmp_path_factory):
    p = tmp_path_factory.mktemp("big") / "a.mcap"
    write_log(p, small_log(60000))
    return p.read_bytes()


@pytest.mark.parametrize("cut", [3, 8, 20, 300, 0.2, 0.5, 0.9, 0.995, -200, -40, -1])
def test_truncated_file_is_an_error_and_its_readable_prefix_can_be_kept(tmp_path, capsys, big_log_bytes, cut):
    data = big_log_bytes
    n_bytes = cut if isinstance(cut, int) and cut > 0 else (len(data) + cut if isinstance(cut, int)
                                                               else int(len(data) * cut))
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:n_bytes])
    with pytest.raises(SensorDataError, match=r"truncated or corrupt MCAP .* (\d+) records readable") as info:
        read_log(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    assert main(["inspect", str(path)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    part = read_log(path, allow_truncated=True)
    full = small_log(60000)
    n = 0 if part.imu is None else part.imu.t_s.size
    if n_bytes > 0.5 * len(data):
        assert n > 0
    if cut in (-200, -40, -1):  # only the summary or footer is missing: every message is readable
        assert_logs_equal(part, full)
    if n:
        assert np.array_equal(part.imu.gyro_radps, full.imu.gyro_radps[:n])
        assert np.array_equal(part.imu.t_s, full.imu.t_s[:n])
    if n_bytes > 300:
        assert part.metadata == full.metadata  # metadata precede the chunks


def test_a_cut_chunk_keeps_its_complete_records(tmp_path, big_log_bytes):
    """Cutting inside the last chunk loses only the records after the cut, not the whole chunk."""
    with open(tmp_path / "x.mcap", "wb") as fh:
        fh.write(big_log_bytes)
    with open(tmp_path / "x.mcap", "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) > 2
    last = chunks[-1]
    path = tmp_path / "cut.mcap"
    path.write_bytes(big_log_bytes[:last.chunk_start_offset + last.chunk_length * 3 // 4])
    whole_chunks = read_log(path, allow_truncated=True).imu.t_s.size
    path.write_bytes(big_log_bytes[:last.chunk_start_offset])
    assert whole_chunks > read_log(path, allow_truncated=True).imu.t_s.size


@pytest.mark.parametrize("content, message", [(None, "file not found"), (b"", "empty file"),
                                              (b"PK\x03\x04 not an mcap", "not an MCAP file")])
def test_missing_empty_or_foreign_file(tmp_path, capsys, content, message):
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(SensorDataError, match=message):
        read_log(path)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and str(path) in err[0]


def test_corrupted_chunk_byte_is_detected(tmp_path, big_log_bytes):
    data = bytearray(big_log_bytes)
    data[len(data) // 2] ^= 0x40
    (tmp_path / "x.mcap").write_bytes(bytes(data))
    with pytest.raises(SensorDataError, match="corrupt"):
        read_log(tmp_path / "x.mcap")
    prefix = read_log(tmp_path / "x.mcap", allow_truncated=True).imu.t_s.size
    assert 0 < prefix < 60000


@pytest.mark.parametrize("edit, message", [
    (lambda log: log.imu.accel_mps2.__setitem__((3, 1), np.inf), "/imu: accel_mps2 sample 3 is not finite"),
    (lambda log: setattr(log.gauge, "t_s", np.r_[log.gauge.t_s[:5], log.gauge.t_s[4:-1]]),
     "/gauge: t_s not strictly increasing at sample 5"),
    (lambda log: setattr(log.imu, "gyro_radps", log.imu.gyro_radps[:, :2]), "/imu: gyro_radps has shape"),
    (lambda log: log.metadata.__setitem__("bad", {"x": float("nan")}), "metadata 'bad'"),
])
def test_writer_refuses_what_the_reader_would_refuse(tmp_path, edit, message):
    log = small_log()
    edit(log)
    with pytest.raises(SensorDataError, match=message):
        write_log(tmp_path / "a.mcap", log)
    assert not list(tmp_path.iterdir())  # no partial file left behind


def test_empty_sensors_and_empty_log(tmp_path):
    log = SensorLog(gauge=GaugeData(np.zeros(0), np.zeros(0)))
    write_log(tmp_path / "a.mcap", log)
    back = read_log(tmp_path / "a.mcap")
    assert back.gauge.t_s.size == 0 and back.imu is None
    write_log(tmp_path / "b.mcap", SensorLog())
    assert inspect_log(tmp_path / "b.mcap").topics == []


@pytest.fixture(scope="module")
def valid_bytes(tmp_path_factory):
    p = tmp_path_factory.mktemp("fuzz") / "ok.mcap"
    write_log(p, small_log(60))
    return p.read_bytes()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_reader_only_raises_sensor_data_error(tmp_path_factory, valid_bytes, data):
    raw = bytearray(valid_bytes)
    for _ in range(data.draw(st.integers(0, 6))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    p = tmp_path_factory.mktemp("f") / "x.mcap"
    p.write_bytes(bytes(raw))
    for allow in (False, True):
        try:
            read_log(p, allow_truncated=allow)
        except SensorDataError as exc:
            assert "\n" not in str(exc) and str(p) in str(exc)
    try:
        inspect_log(p).format()
    except SensorDataError:
        pass


@pytest.fixture(scope="module")
def plain_bytes(tmp_path_factory):
    """A small valid log with uncompressed, unchunked messages and no CRCs: mutations reach the JSON layer."""
    p = tmp_path_factory.mktemp("plain") / "ok.mcap"
    log = small_log(40)
    write_log(p.with_name("src.mcap"), log, encoding="json")
    with open(p.with_name("src.mcap"), "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        by_topic: dict[str, list] = {}
        for _, channel, m in reader.iter_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append((m.log_time, m.data.decode()))
        schema_of = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    _foreign_log(p, [(t, schema_of[t], msgs) for t, msgs in by_topic.items()], CompressionType.NONE, chunked=False)
    log.metadata = {}
    assert_logs_equal(read_log(p), log)
    return p.read_bytes()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_message_content_only_raises_sensor_data_error(tmp_path_factory, plain_bytes, data):
    """Byte edits inside uncompressed messages: the reader returns a log or one SensorDataError line."""
    raw = bytearray(plain_bytes)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.sampled_from(list(b'0123456789.eE+-"{}[],:NaIfinty \\\x00\xff')))
    p = tmp_path_factory.mktemp("f") / "x.mcap"
    p.write_bytes(bytes(raw))
    try:
        log = read_log(p)
    except SensorDataError as exc:
        assert "\n" not in str(exc) and str(p) in str(exc)
        return
    for d in (log.imu, log.odometer, log.gauge, log.inclinometer):
        if d is not None:
            assert np.all(np.diff(d.t_s) > 0)
            assert all(np.isfinite(np.asarray(v, dtype=float)).all() for v in vars(d).values())


@pytest.mark.parametrize("workers", [2, 0])
@pytest.mark.parametrize("bad_index", [None, 1523, 900])
def test_decoding_in_batches_while_scanning_is_exact(tmp_path, monkeypatch, bad_index, workers):
    """The reader decodes the pending payloads of a channel once there are 100 (here) of them,
    chunk by chunk during the scan (bounded memory), in worker processes or in turn: the values
    are those of one decode, and a bad record in a later batch keeps its index."""
    import trackfusion.sensors.mcap_log as mcap_log
    monkeypatch.setattr(mcap_log, "_DECODE_BATCH", 100)
    monkeypatch.setattr(mcap_log, "CHUNK_SIZE_BYTES", 64 * 1024)  # several chunks
    monkeypatch.setattr(mcap_log, "DECODE_WORKERS", workers)
    batches = []
    decode = mcap_log._RawChannel.decode_pending

    def counted(ch, schema, decoder=None):
        decode(ch, schema, decoder)
        batches.append(ch.topic)
        assert isinstance(ch.batches[-1][1], Future) == (workers == 2 and decoder is not None)

    monkeypatch.setattr(mcap_log._RawChannel, "decode_pending", counted)
    log = small_log(2000)
    write_log(tmp_path / "ok.mcap", log, encoding="json")
    if bad_index is None:
        assert_logs_equal(read_log(tmp_path / "ok.mcap"), log)
        assert batches.count("/imu") > 2
        return
    with open(tmp_path / "ok.mcap", "rb") as fh:
        msgs = [(m.log_time, m.data.decode()) for _, _, m in make_reader(fh).iter_messages(topics=["/imu"])]
    msgs[bad_index] = (msgs[bad_index][0], msgs[bad_index][1].replace('"y":', '"y":NaN,"q":', 1))
    msgs[1800] = (msgs[1800][0], msgs[1800][1][:-1])  # a later bad record is not the one reported
    _foreign_log(tmp_path / "bad.mcap", [("/imu", "trackfusion.Imu", msgs)])
    batches.clear()
    with pytest.raises(SensorDataError, match=f"/imu record {bad_index}: "):
        read_log(tmp_path / "bad.mcap")
    assert batches.count("/imu") > 2
