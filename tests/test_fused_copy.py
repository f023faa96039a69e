"""fused.mcap carries the raw log unchanged: its records are copied byte for byte when the log was
read whole from an intact file (any writer's layout), and written from the arrays otherwise."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from trackfusion.errors import SensorDataError
from trackfusion.geodesy import Origin
from trackfusion.sensors.fused import write_fused_mcap
from trackfusion.sensors.mcap_log import _scan_file, copy_log, finish_copy, read_log, start_copy, write_log
from test_mcap_log import small_log

ORIGIN = Origin(22.9, 112.9, 20.0)
EXTRA_TOPICS = {"/trajectory/pose", "/trajectory/fix", "/trajectory/tf", "/trajectory/path"}


def _table(n=300):
    """A trajectory table (trajectory.csv columns) at 100 Hz."""
    t = 0.5 + np.arange(n) / 100.0
    z = np.zeros(n)
    return {"t_s": t, "e_m": t * 2.0, "n_m": np.sin(t), "u_m": z + 1.0, "qw": z + 1.0, "qx": z, "qy": z, "qz": z,
            "sigma_e_m": z + 1e-3, "sigma_n_m": z + 1e-3, "sigma_u_m": z + 2e-3}


def _contents(path):
    """topic -> [(schema name, schema data, encoding, channel metadata, log_time, bytes)], metadata, summary."""
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        for schema, ch, msg in reader.iter_messages(log_time_order=True):
            out.setdefault(ch.topic, []).append((schema.name, schema.data, ch.message_encoding, ch.metadata,
                                                 msg.log_time, msg.data))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        return out, meta, reader.get_summary()


def _foreign(path, compression, chunked):
    """A raw log by the mcap library (schemas and channels inside its chunks; non-canonical JSON)."""
    with open(path, "wb") as fh:
        w = Writer(fh, compression=compression, use_chunking=chunked, chunk_size=500)
        w.start(library="other-logger")
        w.add_metadata("survey", {"json": json.dumps({"scenario": "foreign"})})
        imu = w.register_channel("/imu", "json", w.register_schema("trackfusion.Imu", "jsonschema", b"{}"),
                                 metadata={"sensor": "xsens"})
        odo = w.register_channel("/odometer", "json", w.register_schema("trackfusion.Odometer", "jsonschema", b"{}"))
        for i in range(400):
            w.add_message(imu, log_time=10**7 * (i + 1), publish_time=0, data=json.dumps(
                {"angular_velocity": {"x": i * 1e-3, "y": 0, "z": 7e-5},
                 "linear_acceleration": {"z": 9.8, "x": 0.1, "y": -0.2}, "temp_c": 21.5}, indent=1).encode())
            if i % 4 == 0:
                w.add_message(odo, log_time=10**7 * (i + 1) + 3, publish_time=0,
                              data=json.dumps({"ticks": i, "distance_m": i * 0.01}).encode())
        w.finish()


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE])
def test_raw_records_are_copied_byte_for_byte_from_any_writer(tmp_path, compression):
    _foreign(tmp_path / "raw.mcap", compression, chunked=True)
    log = read_log(tmp_path / "raw.mcap")
    assert log.source is not None and log.source.message_counts == {1: 400, 2: 100}
    write_fused_mcap(tmp_path / "fused.mcap", _table(), ORIGIN, raw=log)
    raw, raw_meta, _ = _contents(tmp_path / "raw.mcap")
    fused, fused_meta, summary = _contents(tmp_path / "fused.mcap")
    for topic, msgs in raw.items():  # schema, channel metadata, log_time and payload bytes identical
        assert fused[topic] == msgs, topic
    assert set(fused) == set(raw) | EXTRA_TOPICS and fused_meta == raw_meta
    assert summary.statistics.message_count == sum(map(len, fused.values()))
    assert summary.statistics.channel_message_counts[1] == 400
    assert {summary.channels[i].topic for i in (1, 2)} == {"/imu", "/odometer"}  # raw channel ids kept
    assert _scan_file(tmp_path / "fused.mcap", False, None).problem is None  # our own structural checks
    write_fused_mcap(tmp_path / "again.mcap", _table(), ORIGIN, raw=log)
    assert (tmp_path / "again.mcap").read_bytes() == (tmp_path / "fused.mcap").read_bytes()


def test_our_raw_log_copied_is_what_re_encoding_gives(tmp_path):
    """For a trackfusion log the copy holds the same messages as writing the arrays again."""
    write_log(tmp_path / "raw.mcap", small_log(3000))
    log = read_log(tmp_path / "raw.mcap")
    write_fused_mcap(tmp_path / "copied.mcap", _table(), ORIGIN, raw=log)
    log.source = None
    write_fused_mcap(tmp_path / "encoded.mcap", _table(), ORIGIN, raw=log)
    copied, meta_c, _ = _contents(tmp_path / "copied.mcap")
    encoded, meta_e, _ = _contents(tmp_path / "encoded.mcap")
    assert copied == encoded and meta_c == meta_e and len(copied) == 7 + len(EXTRA_TOPICS)


def test_what_cannot_be_copied_is_written_from_the_arrays(tmp_path):
    """Unchunked messages, a topic subset, the readable part of a damaged file and a file changed
    since it was read have no source to copy; fused.mcap then encodes the arrays."""
    _foreign(tmp_path / "flat.mcap", CompressionType.NONE, chunked=False)
    assert read_log(tmp_path / "flat.mcap").source is None
    write_log(tmp_path / "raw.mcap", small_log(3000))
    assert read_log(tmp_path / "raw.mcap", topics=["/imu"]).source is None
    data = (tmp_path / "raw.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[:len(data) // 2])
    assert read_log(tmp_path / "cut.mcap", allow_truncated=True).source is None

    log = read_log(tmp_path / "raw.mcap")
    (tmp_path / "raw.mcap").write_bytes(data + b"x")  # (never done to a real input)
    assert not log.source.unchanged()
    with pytest.raises(SensorDataError, match="changed since it was read"):
        copy_log(tmp_path / "x.mcap", log.source)
    write_fused_mcap(tmp_path / "fused.mcap", _table(), ORIGIN, raw=log)
    fused, _, _ = _contents(tmp_path / "fused.mcap")
    assert {m[0] for m in fused["/imu"]} == {"sensor_msgs/msg/Imu"}  # written again from the arrays, as CDR
    import struct
    assert [struct.unpack_from("<d", m[-1], 4 + 16 + 32 + 72)[0] for m in fused["/imu"]] == \
        log.imu.gyro_radps[:, 0].tolist()  # angular_velocity.x of each CDR record (frame_id "imu")
    assert not (tmp_path / "x.mcap").exists()


def test_pose_and_fix_payloads_are_the_json_of_their_messages():
    """The printf templates give exactly the compact JSON of the message dicts."""
    from trackfusion.sensors.fused import _dumps, _pose_and_fix_payloads, _stamp

    rng = np.random.default_rng(3)
    n = 500
    ns = np.sort(rng.integers(0, 10**13, n))
    pos, q, var, llh = (rng.normal(size=(n, k)) * 10.0 ** rng.integers(-12, 8, (n, k)) for k in (3, 4, 3, 3))
    poses, fixes, transforms = _pose_and_fix_payloads(ns, pos, q, var, llh)
    for k in range(n):
        stamp = _stamp(int(ns[k]))
        assert poses[k] == _dumps({"timestamp": stamp, "frame_id": "n", "pose": {
            "position": dict(zip("xyz", pos[k].tolist())), "orientation": dict(zip("xyzw", q[k].tolist()))}})
        assert transforms[k] == _dumps({"timestamp": stamp, "parent_frame_id": "n", "child_frame_id": "b",
                                        "translation": dict(zip("xyz", pos[k].tolist())),
                                        "rotation": dict(zip("xyzw", q[k].tolist()))})
        v = var[k].tolist()
        assert fixes[k] == _dumps({"timestamp": stamp, "frame_id": "n", "latitude": llh[k, 0], "longitude": llh[k, 1],
                                   "altitude": llh[k, 2], "position_covariance": [v[0], 0.0, 0.0, 0.0, v[1], 0.0,
                                                                                  0.0, 0.0, v[2]],
                                   "position_covariance_type": 2})
    pos[7, 1] = np.nan
    with pytest.raises(ValueError):
        _pose_and_fix_payloads(ns, pos, q, var, llh)


def test_inspect_summarises_a_fused_log_with_its_foxglove_topics(tmp_path, capsys):
    from trackfusion.cli import main
    from trackfusion.sensors.mcap_log import inspect_log
    write_log(tmp_path / "raw.mcap", small_log())
    raw = read_log(tmp_path / "raw.mcap")
    write_fused_mcap(tmp_path / "fused.mcap", _table(), ORIGIN, raw=raw)
    summary = {t.topic: t for t in inspect_log(tmp_path / "fused.mcap").topics}
    assert summary["/imu"].count == raw.imu.t_s.size and summary["/imu"].schema == "sensor_msgs/msg/Imu"
    pose = summary["/trajectory/pose"]
    assert pose.schema == "foxglove.PoseInFrame" and pose.count == 30  # 100 Hz rows, poses at 10 Hz
    assert pose.first_s == pytest.approx(0.5) and pose.rate_hz == pytest.approx(10.0)
    assert summary["/trajectory/path"].count == 1
    assert main(["inspect", str(tmp_path / "fused.mcap")]) == 0
    assert "foxglove.LocationFix" in capsys.readouterr().out


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE])
def test_a_copy_on_the_absolute_clock_moves_only_the_times(tmp_path, compression):
    """With the survey's epoch the copied records keep their bytes but for log and publish
    times; chunk CRCs and the summary's times follow."""
    _foreign(tmp_path / "raw.mcap", compression, chunked=True)
    log = read_log(tmp_path / "raw.mcap")
    offset = 1_717_401_600 * 10**9
    copy_log(tmp_path / "moved.mcap", log.source, time_offset_ns=offset)
    raw, raw_meta, raw_summary = _contents(tmp_path / "raw.mcap")
    moved, moved_meta, summary = _contents(tmp_path / "moved.mcap")  # (validate_crcs)
    assert moved_meta == raw_meta and set(moved) == set(raw)
    for topic, msgs in raw.items():
        assert moved[topic] == [m[:4] + (m[4] + offset, m[5]) for m in msgs], topic
    assert summary.statistics.message_start_time == raw_summary.statistics.message_start_time + offset
    assert _scan_file(tmp_path / "moved.mcap", False, None).problem is None
    with open(tmp_path / "moved.mcap", "rb") as fh:  # the writer's publish times of 0, moved as well
        assert {m.publish_time for _s, _c, m in make_reader(fh).iter_messages()} == {offset}


def test_a_moved_copy_is_the_same_bytes_whatever_the_threads_window(tmp_path, monkeypatch):
    """The chunks are shifted a window at a time on two threads (sensors/mcap_log.py
    ``_shifted_records``): the file is the same bytes for one chunk at a time and for all at once."""
    from trackfusion.sensors import mcap_log
    _foreign(tmp_path / "raw.mcap", CompressionType.ZSTD, chunked=True)
    log = read_log(tmp_path / "raw.mcap")
    assert sum(op == mcap_log._CHUNK for op, _, _ in log.source.records) > 3 * mcap_log.SHIFT_WINDOW_CHUNKS
    copies = []
    for window in (1, mcap_log.SHIFT_WINDOW_CHUNKS, 10**6):
        monkeypatch.setattr(mcap_log, "SHIFT_WINDOW_CHUNKS", window)
        copy_log(tmp_path / f"moved{window}.mcap", log.source, time_offset_ns=10**18)
        copies.append((tmp_path / f"moved{window}.mcap").read_bytes())
    assert copies[0] == copies[1] == copies[2]


def test_our_log_copied_on_the_absolute_clock(tmp_path):
    write_log(tmp_path / "raw.mcap", small_log(3000))
    log = read_log(tmp_path / "raw.mcap")
    copy_log(tmp_path / "moved.mcap", log.source, time_offset_ns=10**18)
    raw, _, _ = _contents(tmp_path / "raw.mcap")
    moved, _, _ = _contents(tmp_path / "moved.mcap")
    for topic, msgs in raw.items():
        assert moved[topic] == [m[:4] + (m[4] + 10**18, m[5]) for m in msgs], topic
    with open(tmp_path / "moved.mcap", "rb") as fh:
        assert all(m.publish_time == m.log_time for _s, _c, m in make_reader(fh).iter_messages())


@pytest.mark.parametrize("workers", [1, 2])
def test_a_copy_begun_early_and_finished_later_is_the_copy_in_one_go(tmp_path, workers):
    """A run begins fused.mcap's copy while it smooths (``start_copy``, one thread) and writes the
    rest with the estimate (``finish_copy``): the same bytes as ``copy_log``, and nothing left
    beside the file."""
    _foreign(tmp_path / "raw.mcap", CompressionType.ZSTD, chunked=True)
    log = read_log(tmp_path / "raw.mcap")
    extra = __import__("trackfusion.sensors.fused", fromlist=["trajectory_channels"]).trajectory_channels(
        _table(), ORIGIN, 10.0, 10**18)
    copy_log(tmp_path / "whole.mcap", log.source, extra, time_offset_ns=10**18)
    (tmp_path / "out").mkdir()
    head = start_copy(tmp_path / "out" / ".begun", log.source, 10**18, workers)
    assert head.pos == (tmp_path / "out" / ".begun").stat().st_size
    finish_copy(tmp_path / "out" / "fused.mcap", head, extra)
    assert (tmp_path / "out" / "fused.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["fused.mcap"]
    fused, _, summary = _contents(tmp_path / "whole.mcap")
    assert set(fused) == {"/imu", "/odometer"} | EXTRA_TOPICS and summary.statistics.channel_message_counts[1] == 400


def test_a_copy_that_fails_leaves_no_file(tmp_path, monkeypatch):
    """The first part is removed when it fails, and so is the whole when its rest fails."""
    from trackfusion.sensors import mcap_log
    _foreign(tmp_path / "raw.mcap", CompressionType.ZSTD, chunked=True)
    log = read_log(tmp_path / "raw.mcap")
    (tmp_path / "out").mkdir()
    head = start_copy(tmp_path / "out" / ".begun", log.source, 10**18)

    def full(*_args):
        raise OSError("no space left on device")
    monkeypatch.setattr(mcap_log, "_write_chunks", full)
    with pytest.raises(OSError):
        finish_copy(tmp_path / "out" / "fused.mcap", head, [])
    monkeypatch.setattr(mcap_log, "_copied_records", full)
    with pytest.raises(OSError):
        start_copy(tmp_path / "out" / ".begun", log.source, 10**18)
    assert list((tmp_path / "out").iterdir()) == []
