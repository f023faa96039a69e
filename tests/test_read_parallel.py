"""The log read in two processes (sensors/mcap_parallel.py) gives exactly the serial read's
result: the same arrays (bit for bit, dtype, order), metadata and copy source, the same one-line
error for a bad record, a CRC error or a damaged file, and the same readable part and damage
report with ``allow_truncated``. Logs here are small, so the size limit is lowered to 0 and the
chunks and decode batches are made small: many chunks, batches straddling chunks and the cut."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from mcap.writer import Writer

from trackfusion.errors import SensorDataError
from trackfusion.sensors import mcap_log, mcap_parallel, schemas
from trackfusion.sensors.mcap_log import read_log_with_damage
from trackfusion.sensors.types import GnssData, ImuData, OdometerData, SensorLog, TotalStationData

N_IMU = 6000


def _streams(seed=3) -> list[mcap_log._Stream]:
    """Four channels in trackfusion's layout (IMU 100 Hz, odometer 50 Hz, GNSS 1 Hz, a station)."""
    rng = np.random.default_rng(seed)
    t = np.arange(1, N_IMU + 1) / 100.0
    cov = np.tile(np.diag([1e-4, 1e-4, 4e-4]), (60, 1, 1))
    log = SensorLog(
        imu=ImuData(t, rng.normal(size=(N_IMU, 3)) * 1e-3, rng.normal(size=(N_IMU, 3)) + [0, 0, 9.8]),
        odometer=OdometerData(t[::2], np.cumsum(rng.random(N_IMU // 2)), np.arange(N_IMU // 2) * 3),
        gnss=GnssData(np.arange(60.0) + 0.5, 22.9 + rng.random(60) * 1e-5, 112.9 + rng.random(60) * 1e-5,
                      20 + rng.random(60), cov, np.full(60, 4)),
        total_stations={"TS1": TotalStationData("TS1", 2 + np.arange(300) / 10, rng.random(300), 1.5 + rng.random(300),
                                                100 + rng.random(300), np.array(["P1"] * 300, dtype=object))},
        metadata={"survey": {"scenario": "parallel read"}})
    return mcap_log._streams(log), mcap_log._metadata_records(log.metadata)


def _write(path, edit=None) -> None:
    """The log, with ``edit(topic, payloads)`` changing payloads first; chunks of 24 KiB (about 25)."""
    streams, metadata = _streams()
    for s in streams:
        if edit is not None:
            edit(s.topic, s.payloads)
    old = mcap_log.CHUNK_SIZE_BYTES
    mcap_log.CHUNK_SIZE_BYTES = 24 * 1024
    try:
        with open(path, "wb") as fh:
            mcap_log._write_mcap(fh, streams, metadata)
    finally:
        mcap_log.CHUNK_SIZE_BYTES = old


@pytest.fixture(scope="module")
def log_bytes(tmp_path_factory):
    path = tmp_path_factory.mktemp("par") / "log.mcap"
    _write(path)
    return path.read_bytes()


@pytest.fixture
def small_batches(monkeypatch):
    monkeypatch.setattr(mcap_log, "_DECODE_BATCH", 700)  # batches close inside the child's run too


def _outcome(path, parallel: bool, monkeypatch, **kw):
    """What a read gives, comparable: (arrays as (dtype, shape, bytes), metadata, source, damage,
    chunks the child read), or ("error", the message)."""
    taken = []
    take = mcap_parallel._Split.take

    def counted(split, scan, at):
        done = take(split, scan, at)
        taken.append(done)
        return done

    with monkeypatch.context() as mp:
        mp.setattr(mcap_parallel, "MIN_BYTES", 0 if parallel else 1 << 60)
        mp.setattr(mcap_parallel._Split, "take", counted)
        try:
            log, damage = read_log_with_damage(path, **kw)
        except SensorDataError as exc:
            return ("error", str(exc)), sum(taken)
    arrays = {}
    for name in ("imu", "odometer", "gnss", "inclinometer", "gauge"):
        data = getattr(log, name)
        for f in (data.__dataclass_fields__ if data is not None else ()):
            a = np.asarray(getattr(data, f))
            arrays[f"{name}.{f}"] = (a.dtype.str, a.shape, a.tobytes())
    for sid, data in log.total_stations.items():
        for f in data.__dataclass_fields__:
            a = np.asarray(getattr(data, f))
            arrays[f"{sid}.{f}"] = (a.dtype.str, a.shape, a.tolist() if a.dtype == object else a.tobytes())
    return (arrays, log.metadata, log.source, damage), sum(taken)


def _same_both_ways(path, monkeypatch, **kw):
    """The serial and the parallel outcome (asserted equal); returns it and the child's chunks."""
    serial, none = _outcome(path, False, monkeypatch, **kw)
    parallel, taken = _outcome(path, True, monkeypatch, **kw)
    assert none == 0
    assert parallel == serial
    return parallel, taken


def _chunk_offsets(data: bytes) -> list[tuple[int, int]]:
    fb = _Bytes(data)
    return [(start, stop) for op, start, stop in mcap_parallel._top_level(fb, len(data)) if op == mcap_log._CHUNK]


class _Bytes:
    def __init__(self, data):
        self.data = data

    def __getitem__(self, where):
        return self.data[where]


@pytest.mark.parametrize("topics", [None, ["/imu", "/total_station/TS1"]])
def test_intact_log_is_read_identically_and_the_child_reads_its_half(tmp_path, monkeypatch, small_batches,
                                                                      log_bytes, topics):
    path = tmp_path / "log.mcap"
    path.write_bytes(log_bytes)
    (arrays, metadata, source, damage), taken = _same_both_ways(path, monkeypatch, topics=topics)
    chunks = _chunk_offsets(log_bytes)
    assert len(chunks) > 20 and len(chunks) // 3 < taken < len(chunks) * 2 // 3
    assert arrays["imu.t_s"][1] == (N_IMU,) and ("gnss.cov_enu_m2" in arrays) == (topics is None)
    assert damage is None and metadata == {"survey": {"scenario": "parallel read"}}
    assert (source is None) == (topics is not None)


def test_one_batch_per_channel_reads_identically(tmp_path, monkeypatch, log_bytes):
    """With the default batch size every channel's payloads are one batch, decoded by the parent
    (it straddles the cut)."""
    path = tmp_path / "log.mcap"
    path.write_bytes(log_bytes)
    assert _same_both_ways(path, monkeypatch)[1] > 0


@pytest.mark.parametrize("where", [0.2, 0.55, 0.8, 0.97, "in last chunk", "after chunks", -30])
@pytest.mark.parametrize("allow", [False, True])
def test_truncated_log_gives_the_same_error_or_readable_part(tmp_path, monkeypatch, small_batches, log_bytes,
                                                             where, allow):
    chunks = _chunk_offsets(log_bytes)
    if where == "in last chunk":
        cut = (chunks[-1][0] + chunks[-1][1]) // 2
    elif where == "after chunks":
        cut = chunks[-1][1] + 20
    else:
        cut = int(len(log_bytes) * where) if where > 0 else len(log_bytes) + where
    path = tmp_path / "cut.mcap"
    path.write_bytes(log_bytes[:cut])
    outcome, _ = _same_both_ways(path, monkeypatch, allow_truncated=allow)
    if allow:
        assert outcome[3]["byte"] >= 0 and outcome[3]["records_readable"]["/imu"] > 0
    else:
        assert outcome[0] == "error" and "truncated or corrupt MCAP" in outcome[1] and "\n" not in outcome[1]


@pytest.mark.parametrize("where", ["first chunk", "parent's last chunk", "child's chunk", "child's last chunk",
                                   "message index"])
@pytest.mark.parametrize("allow", [False, True])
def test_corrupt_byte_gives_the_same_error_or_readable_part(tmp_path, monkeypatch, small_batches, log_bytes,
                                                            where, allow):
    chunks = _chunk_offsets(log_bytes)
    half = len(chunks) // 2
    start, stop = {"first chunk": chunks[0], "parent's last chunk": chunks[half - 2], "child's chunk": chunks[-5],
                   "child's last chunk": chunks[-1], "message index": (chunks[-3][1], chunks[-2][0])}[where]
    data = bytearray(log_bytes)
    data[stop - 40 if where != "message index" else start + 30] ^= 0x10
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    outcome, _ = _same_both_ways(path, monkeypatch, allow_truncated=allow)
    if allow:
        assert outcome[3] is not None
    else:
        assert outcome[0] == "error" and ("CRC" in outcome[1] or "zstd" in outcome[1])


def _replace(topic, index, old, new):
    def edit(t, payloads):
        if t == topic:
            assert old in payloads[index]
            payloads[index] = payloads[index].replace(old, new, 1)
    return edit


def _both(*edits):
    def edit(t, payloads):
        for e in edits:
            e(t, payloads)
    return edit


BAD = {
    "NaN late in the IMU": _replace("/imu", 5000, '"y":', '"y":NaN,"q":'),
    "cut JSON in the child's part": _replace("/imu", 5800, "}}", "}"),
    "not canonical, valid (JSON path)": _replace("/imu", 4321, '"x":', '"x": '),
    "overflow to infinity": _replace("/odometer", 2900, '"distance_m":', '"distance_m":1e999,"q":'),
    "bad records in both halves": _both(_replace("/imu", 5500, '"z":', '"z":true,"q":'),
                                        _replace("/odometer", 100, '"ticks":', '"ticks":1.5,"q":')),
    "covariance not finite": _replace("/gnss", 50, '"position_covariance":[', '"position_covariance":[1e999,'),
    "prism id not a string": _replace("/total_station/TS1", 280, '"prism_id":"P1"', '"prism_id":7'),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_record_gives_the_same_error(tmp_path, monkeypatch, small_batches, name):
    path = tmp_path / "bad.mcap"
    _write(path, BAD[name])
    outcome, taken = _same_both_ways(path, monkeypatch)
    assert taken > 0
    if name.startswith("not canonical"):
        assert outcome[0]["imu.gyro_radps"][1] == (N_IMU, 3)
    else:
        assert outcome[0] == "error" and f"{path}: /" in outcome[1] and "\n" not in outcome[1]


def test_a_wrong_prediction_or_a_dead_child_falls_back_to_reading_here(tmp_path, monkeypatch, small_batches,
                                                                       log_bytes):
    path = tmp_path / "log.mcap"
    path.write_bytes(log_bytes)
    pending = mcap_parallel._pending
    monkeypatch.setattr(mcap_parallel, "_pending", lambda *a: {c: n + 1 for c, n in pending(*a).items()})
    assert _same_both_ways(path, monkeypatch)[1] == 0  # the child's start state was not the parent's
    monkeypatch.setattr(mcap_parallel, "_pending", pending)
    monkeypatch.setattr(mcap_parallel, "_read_part", lambda *a: os._exit(3))
    assert _same_both_ways(path, monkeypatch)[1] == 0


def test_channels_inside_chunks_are_read_here(tmp_path, monkeypatch, small_batches):
    """The mcap library writes channel records inside chunks: the child cannot start from them."""
    path = tmp_path / "foreign.mcap"
    payloads = [schemas.CANONICAL[schemas.IMU].template % (i * 1e-3, 0.5, -1.0, 0.25, 0.0, 9.8) for i in range(4000)]
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=8 * 1024)
        w.start()
        cid = w.register_channel("/imu", "json", w.register_schema(schemas.IMU, "jsonschema", b"{}"))
        for i, p in enumerate(payloads):
            w.add_message(cid, log_time=i + 1, data=p.encode(), publish_time=i + 1)
        w.finish()
    outcome, taken = _same_both_ways(path, monkeypatch)
    assert taken == 0 and outcome[0]["imu.accel_mps2"][1] == (4000, 3)
    assert json.loads(payloads[7])["angular_velocity"]["x"] == 0.007
