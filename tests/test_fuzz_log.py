"""Structure-aware fuzzing of the log reader: records dropped, duplicated, swapped, re-typed,
their length fields or ids changed, message times and payloads replaced by other JSON; every
input gives a SensorLog or one SensorDataError line naming the file, never another exception.

(tests/test_mcap_log.py fuzzes raw bytes; these mutations keep the records well framed, so they
reach the schema, channel, time and message-content checks behind the framing.)
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType

from test_mcap_log import _foreign_log, small_log
from trackfusion.errors import SensorDataError
from trackfusion.sensors.mcap_log import inspect_log, read_log, write_log

EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", 150))
HEAD = struct.Struct("<BQ")


def _records(data: bytes) -> list[tuple[int, bytes]]:
    """Top-level (opcode, body) records between the two magics."""
    out, pos = [], 8
    while pos + 9 <= len(data) - 8:
        op, n = HEAD.unpack_from(data, pos)
        out.append((op, data[pos + 9:pos + 9 + n]))
        pos += 9 + n
    return out


def _assemble(records: list[tuple[int, bytes]], magic: bytes) -> bytes:
    return magic + b"".join(HEAD.pack(op, len(body)) + body for op, body in records) + magic


@pytest.fixture(scope="module")
def plain_records(tmp_path_factory):
    """A small log written unchunked and uncompressed by the mcap library (every message a
    top-level record; CRCs 0, so edited records are not caught by a CRC first)."""
    d = tmp_path_factory.mktemp("plain")
    log = small_log(40)
    write_log(d / "src.mcap", log)
    src = read_log(d / "src.mcap")
    chans = [("/imu", "trackfusion.Imu", [(int(round(t * 1e9)), json.dumps(
                 {"angular_velocity": dict(zip("xyz", g)), "linear_acceleration": dict(zip("xyz", a))}))
                 for t, g, a in zip(src.imu.t_s, src.imu.gyro_radps.tolist(), src.imu.accel_mps2.tolist())]),
             ("/odometer", "trackfusion.Odometer", [(int(round(t * 1e9)), json.dumps({"distance_m": d_, "ticks": int(k)}))
                                                    for t, d_, k in zip(src.odometer.t_s, src.odometer.distance_m,
                                                                        src.odometer.ticks)]),
             ("/gnss", "foxglove.LocationFix", [(int(round(t * 1e9)), json.dumps(
                 {"latitude": la, "longitude": lo, "altitude": h, "position_covariance": c.ravel().tolist(),
                  "fix_quality": int(q)})) for t, la, lo, h, c, q in zip(src.gnss.t_s, src.gnss.lat_deg, src.gnss.lon_deg,
                                                                        src.gnss.h_m, src.gnss.cov_enu_m2,
                                                                        src.gnss.fix_quality)])]
    _foreign_log(d / "plain.mcap", chans, CompressionType.NONE, chunked=False)
    data = (d / "plain.mcap").read_bytes()
    assert read_log(d / "plain.mcap").imu.t_s.size == 40
    return data[:8], _records(data)


json_values = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                                     st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=6)),
                           lambda kids: st.one_of(st.lists(kids, max_size=9),
                                                  st.dictionaries(st.sampled_from(
                                                      ["x", "y", "z", "angular_velocity", "linear_acceleration",
                                                       "distance_m", "ticks", "latitude", "fix_quality",
                                                       "position_covariance", "altitude", "longitude"]), kids,
                                                      max_size=4)), max_leaves=12)


def _mutate_message(body: bytes, data) -> bytes:
    """A message record body: channel, sequence, log time, publish time, payload."""
    channel, seq, log_time, pub = struct.unpack_from("<HIQQ", body)
    payload = body[22:]
    what = data.draw(st.sampled_from(["channel", "time", "payload", "field"]))
    if what == "channel":
        channel = data.draw(st.integers(0, 6))
    elif what == "time":
        log_time = data.draw(st.one_of(st.integers(0, 2**64 - 1), st.integers(log_time - 10**8, log_time + 10**8)
                                       .map(lambda v: max(v, 0))))
    elif what == "payload":
        payload = json.dumps(data.draw(json_values)).encode()
    else:
        try:
            msg = json.loads(payload)
        except ValueError:  # an earlier mutation cut this record
            msg = None
        if isinstance(msg, dict) and msg:
            msg[data.draw(st.sampled_from(sorted(msg)))] = data.draw(json_values)
            payload = json.dumps(msg).encode()
    return struct.pack("<HIQQ", channel, seq, log_time, pub) + payload


def _mutate_definition(body: bytes, data) -> bytes:
    """A schema or channel record: change its leading id, or rewrite one of its strings."""
    if data.draw(st.booleans()):
        return struct.pack("<H", data.draw(st.integers(0, 5))) + body[2:]
    for name in (b"trackfusion.Imu", b"trackfusion.Odometer", b"foxglove.LocationFix", b"/imu", b"/odometer",
                 b"/gnss", b"jsonschema", b"json"):
        i = body.find(struct.pack("<I", len(name)) + name)
        if i >= 0:
            new = data.draw(st.sampled_from(["acme.Imu", "/camera", "/gnss", "/imu", "cbor", "trackfusion.Gauge",
                                             "/total_station/", "", "\u00e9"])).encode()
            return body[:i] + struct.pack("<I", len(new)) + new + body[i + 4 + len(name):]
    return body


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_structured_mutations_only_raise_sensor_data_error(tmp_path_factory, plain_records, data):
    magic, records = plain_records
    recs = list(records)
    length_edit = None
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(recs) - 1))
        op, body = recs[i]
        action = data.draw(st.sampled_from(["drop", "duplicate", "swap", "opcode", "length", "cut", "edit"]))
        if action == "drop":
            del recs[i]
        elif action == "duplicate":
            recs.insert(data.draw(st.integers(0, len(recs))), (op, body))
        elif action == "swap":
            j = data.draw(st.integers(0, len(recs) - 1))
            recs[i], recs[j] = recs[j], recs[i]
        elif action == "opcode":
            recs[i] = (data.draw(st.integers(0, 255)), body)
        elif action == "length":
            length_edit = (i, data.draw(st.integers(-40, 40)))
        elif action == "cut":
            recs[i] = (op, body[:data.draw(st.integers(0, max(len(body) - 1, 0)))])
        elif op == 5 and len(body) >= 22:
            recs[i] = (op, _mutate_message(body, data))
        elif op in (3, 4):
            recs[i] = (op, _mutate_definition(body, data))
        if not recs:
            break
    raw = bytearray(_assemble(recs, magic))
    if length_edit is not None and length_edit[0] < len(recs):
        pos = 8 + sum(9 + len(b) for _, b in recs[:length_edit[0]])
        n = struct.unpack_from("<Q", raw, pos + 1)[0]
        struct.pack_into("<Q", raw, pos + 1, max(n + length_edit[1], 0))
    p = tmp_path_factory.mktemp("s") / "x.mcap"
    p.write_bytes(bytes(raw))
    for allow in (False, True):
        try:
            log = read_log(p, allow_truncated=allow)
        except SensorDataError as exc:
            assert "\n" not in str(exc) and str(p) in str(exc)
            continue
        for d in (log.imu, log.odometer, log.gnss):
            if d is not None:
                assert np.all(np.diff(d.t_s) > 0)
                assert all(np.isfinite(np.asarray(v, dtype=float)).all() for v in vars(d).values())
    try:
        inspect_log(p).format()
    except SensorDataError:
        pass
