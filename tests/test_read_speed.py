"""The reader's fast paths (docs/read_speed.md) give exactly what the plain paths give: on a log
from the simulator, every decoded value is bit for bit json.loads of the payload the mcap
library reads, and the vectorised record offsets are those of the record walk."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader

from trackfusion.sensors import mcap_log
from trackfusion.sensors.mcap_log import read_log
from trackfusion.simulation.scenarios import simulate_to_dir

TINY = ["motion.passes=1", "imu.rate_hz=500",
        "motion.segments=[{hold_s: 10}, {move_to_m: 60, speed_mps: 3, accel_mps2: 0.5}, {hold_s: 5}]"]


@pytest.fixture(scope="module")
def simulated_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    simulate_to_dir("open-track-gnss", d, seed=5, overrides=TINY)
    return d / "log.mcap"


def _plain(msg) -> dict:
    """A message decoded by mcap_ros2 as the dict of its JSON counterpart's fields."""
    if hasattr(msg, "angular_velocity"):
        return {k: {a: getattr(getattr(msg, k), a) for a in "xyz"} for k in ("angular_velocity", "linear_acceleration")}
    return {"distance_m": msg.distance_m, "ticks": msg.ticks}


def _reference_messages(path) -> dict[str, list[dict]]:
    """topic -> the decoded messages, by the mcap library with json.loads or mcap_ros2's CDR
    decoder (no trackfusion code)."""
    from mcap_ros2.decoder import DecoderFactory
    out: dict[str, list[dict]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        cdr_topics = [c.topic for c in reader.get_summary().channels.values() if c.message_encoding == "cdr"]
        for _schema, channel, _message, ros in reader.iter_decoded_messages(cdr_topics, log_time_order=False):
            out.setdefault(channel.topic, []).append(_plain(ros))
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic not in cdr_topics:
                out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out


def _bits(values) -> list[int]:
    return np.asarray(values, dtype=np.float64).view(np.int64).ravel().tolist()


@pytest.mark.parametrize("workers", [0, 2])
def test_simulated_log_decodes_to_the_reference_parse_bit_for_bit(simulated_log, monkeypatch, workers):
    monkeypatch.setattr(mcap_log, "DECODE_WORKERS", workers)
    monkeypatch.setattr(mcap_log, "_DECODE_BATCH", 3000)  # several batches (and workers) per topic
    log = read_log(simulated_log)
    ref = _reference_messages(simulated_log)
    imu = ref["/imu"]
    assert log.imu.t_s.size == len(imu) > 20_000
    for k, a in enumerate("xyz"):
        assert _bits(log.imu.gyro_radps[:, k]) == _bits([m["angular_velocity"][a] for m in imu])
        assert _bits(log.imu.accel_mps2[:, k]) == _bits([m["linear_acceleration"][a] for m in imu])
    odo = ref["/odometer"]
    assert _bits(log.odometer.distance_m) == _bits([m["distance_m"] for m in odo])
    assert log.odometer.ticks.tolist() == [m["ticks"] for m in odo]
    gnss = ref["/gnss"]
    for field, name in (("lat_deg", "latitude"), ("lon_deg", "longitude"), ("h_m", "altitude")):
        assert _bits(getattr(log.gnss, field)) == _bits([m[name] for m in gnss])
    assert _bits(log.gnss.cov_enu_m2) == _bits([m["position_covariance"] for m in gnss])
    values = np.concatenate([log.imu.gyro_radps.ravel(), log.imu.accel_mps2.ravel()])
    assert (values == 0).any() or np.abs(values).min() < 1e-5  # small values with exponents are in there


def _chunks(path):
    """The decompressed records of every chunk of a trackfusion-written file."""
    data = path.read_bytes()
    pos, out = 8, []
    while True:
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 2:
            return out
        if op == 6:
            body = data[pos + 9:pos + 9 + length]
            size = struct.unpack_from("<Q", body, 16)[0]
            name_len = struct.unpack_from("<I", body, 28)[0]
            out.append(zstandard.ZstdDecompressor().decompress(body[40 + name_len:], max_output_size=size))
        pos += 9 + length


def _walked(records: bytes) -> list[int]:
    pos, offsets = 0, []
    while pos + 9 <= len(records):
        op, length = struct.unpack_from("<BQ", records, pos)
        if op == 5:
            offsets.append(pos)
        pos += 9 + length
    return offsets


def _message(log_time: int, payload: bytes, channel: int = 1) -> bytes:
    return struct.pack("<BQHIQQ", 5, 22 + len(payload), channel, 0, log_time, log_time) + payload


def test_record_offsets_are_those_of_the_walk(simulated_log):
    chunks = _chunks(simulated_log)
    assert len(chunks) >= 2
    for records in chunks:
        assert mcap_log._message_offsets(records).tolist() == _walked(records)


def test_offsets_skip_opcode_bytes_inside_records_and_refuse_other_records():
    # log_time byte 5 (record byte 20) is the opcode 5 and the payload byte 31 bytes on is "{":
    # a candidate inside a record, which no record ends at
    payload = b'{"angular_velocity":{"x":1.0}}'
    inside = _message(5 << 40, payload)
    assert inside[20] == 5 and inside[20 + 31] == ord("{")
    records = _message(1, payload) + inside + _message(7, payload)
    assert mcap_log._message_offsets(records).tolist() == _walked(records) == [0, len(inside), 2 * len(inside)]
    channel = struct.pack("<BQ", 4, 4) + b"\0" * 4  # a non-message record: walked in turn
    assert mcap_log._message_offsets(records + channel) is None
    assert mcap_log._message_offsets(records[:-3]) is None  # cut record
    assert mcap_log._message_offsets(_message(1, b" {}")) is None  # payload not starting with "{"
