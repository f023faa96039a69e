"""The raw survey log: one MCAP file per run (docs/log_format.md): ``/imu`` and ``/odometer``
as ROS 2 CDR messages, the other topics as JSON; logs whose every topic is JSON (the older
format) are read too. ROS 2 bags in MCAP are read with the same checks (:func:`read_cdr_topics`).

- :func:`write_log` writes a :class:`SensorLog` atomically and byte-identically
  for identical input (zstd chunks, full MCAP index and summary).
- :func:`read_log` reads one back and checks every record: known topic and
  schema, message encoding (``cdr`` for the ROS 2 types, else ``json``), a CDR record of its
  type's layout or decodable JSON with the schema's fields, finite numbers, ``log_time``
  strictly increasing per topic. The first bad record raises a :class:`SensorDataError` of one
  line naming the file, topic and record index (0-based within its topic). A truncated or
  corrupt file raises an error that says how many records were readable;
  ``allow_truncated=True`` returns that readable prefix instead.
- :func:`inspect_log` summarises a log per topic (:class:`LogSummary`).
- :func:`copy_log` writes a log file that :func:`read_log` read whole and intact
  (``SensorLog.source``) again byte for byte, followed by extra channels (``fused.mcap``).

``log_time`` is integer nanoseconds of the recording sensor's clock:
``round(t_s * 1e9)``; reading gives ``t_s = log_time / 1e9`` (so times are
quantised to 1 ns; values round-trip bit-exactly).

The MCAP structure is read here rather than with the ``mcap`` library's reader, which yields one
Python object per message (several seconds for an hour of 500 Hz IMU messages): a chunk's
records are located from its message indexes (checked to chain exactly) and each channel's
CDR records of a chunk are copied out as one array and decoded together (:mod:`.cdr`). The
small records (header, schemas, channels, summary) are written with the ``mcap`` library's
record builder; CRCs are zlib's. JSON payloads are parsed with ``json`` in batches (in two
worker processes on a machine with two CPUs).
"""

from __future__ import annotations

import io
import itertools
import json
import operator
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
import zstandard
from numpy.lib.stride_tricks import sliding_window_view
from mcap.data_stream import RecordBuilder
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)

from .. import __version__
from ..forked import ForkedPool, result_of, thread_map
from ..errors import SensorDataError
from . import cdr, schemas
from .fileio import atomic_path
from .spill import trim_heap
from .types import GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog, TotalStationData

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = f"trackfusion/{__version__}"
CHUNK_SIZE_BYTES = 4 * 1024 * 1024
ZSTD_LEVEL = 3
_MAX_CHUNK_BYTES = 1 << 30  # refuse to inflate a chunk that claims more than 1 GiB

# MCAP opcodes
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _CHUNK_INDEX = 1, 2, 3, 4, 5, 6, 7, 8
_STATISTICS, _METADATA, _METADATA_INDEX, _SUMMARY_OFFSET, _DATA_END = 11, 12, 13, 14, 15
_RECORD_NAMES = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk", 7: "message index",
                 8: "chunk index", 9: "attachment", 10: "attachment index", 11: "statistics", 12: "metadata",
                 13: "metadata index", 14: "summary offset", 15: "data end"}

#: Packed header of a Message record: opcode, record length, channel, sequence, log/publish time (31 bytes).
_MSG_HEADER = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                        ("log_time", "<u8"), ("publish_time", "<u8")])
_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
_RECORD_HEAD = struct.Struct("<BQ")
_INT64_MAX = np.iinfo(np.int64).max


# =================================================================================================
# writing
# =================================================================================================

@dataclass
class _Stream:
    """One channel to write: ``log_time_ns`` (N,) int64 and N JSON payloads (ASCII str);
    ``schema_data``: the JSON Schema bytes when ``schema`` is not one of :mod:`.schemas`."""

    topic: str
    schema: str
    log_time_ns: np.ndarray
    payloads: list[str]
    schema_data: bytes | None = None
    #: MCAP message encoding of the channel and schema encoding ("cdr"/"ros2msg" for ROS 2 messages)
    encoding: str = "json"
    schema_encoding: str = "jsonschema"


@dataclass
class ExtraChannel:
    """A channel of another schema written beside a log's sensors (e.g. Foxglove messages in
    ``fused.mcap``): ``topic``, ``schema_name``, ``schema_data`` (JSON Schema bytes),
    ``log_time_ns`` (N,) int64 non-decreasing and N JSON payloads (ASCII text)."""

    topic: str
    schema_name: str
    schema_data: bytes
    log_time_ns: np.ndarray
    payloads: list[str]


def _fail(topic: str, reason: str) -> SensorDataError:
    return SensorDataError(f"cannot write {topic}: {reason}")


def _log_time_ns(topic: str, t_s: np.ndarray) -> np.ndarray:
    """Integer nanoseconds (N,) of ``t_s`` (N,) [s]; must be finite, >= 0 and strictly increasing."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1:
        raise _fail(topic, f"t_s must be 1-D, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise _fail(topic, f"t_s[{int(np.flatnonzero(~np.isfinite(t))[0])}] is not finite")
    if t.size and (t.min() < 0 or t.max() > 9.2e9):
        raise _fail(topic, "t_s outside [0, 9.2e9] s (MCAP log_time is unsigned nanoseconds)")
    ns = np.rint(t * 1e9).astype(np.int64)
    bad = np.flatnonzero(np.diff(ns) <= 0)
    if bad.size:
        raise _fail(topic, f"t_s not strictly increasing at sample {int(bad[0]) + 1} (after rounding to 1 ns)")
    return ns


def _columns(topic: str, n: int, named: Iterable[tuple[str, Any, tuple[int, ...]]]) -> list[list]:
    """Check shapes and finiteness; return per value a Python list (floats stay floats for ``%r``).

    named: (name, array, trailing shape); each array must have shape (n, *trailing shape).
    """
    out: list[list] = []
    for name, values, trailing in named:
        a = np.asarray(values)
        if a.shape != (n, *trailing):
            raise _fail(topic, f"{name} has shape {a.shape}, expected {(n, *trailing)}")
        if a.dtype.kind not in "fiub":
            raise _fail(topic, f"{name} must be numeric, got dtype {a.dtype}")
        flat = a.reshape(n, int(np.prod(trailing, dtype=int)))
        bad = ~np.isfinite(flat).all(axis=1) if a.dtype.kind == "f" else np.zeros(n, bool)
        if bad.any():
            raise _fail(topic, f"{name} sample {int(np.argmax(bad))} is not finite")
        as_type = np.float64 if a.dtype.kind == "f" else np.int64
        out.extend(flat[:, j].astype(as_type).tolist() for j in range(flat.shape[1]))
    return out


#: the ROS 2 message types of trackfusion's own high-rate topics (CDR; docs/log_format.md)
CDR_IMU = "sensor_msgs/msg/Imu"
CDR_ODOMETER = "trackfusion_msgs/msg/OdometerDistance"
#: topic -> the ROS 2 type it may carry instead of its JSON schema
CDR_TOPICS = {"/imu": CDR_IMU, "/odometer": CDR_ODOMETER}
#: REP-145: element 0 of a covariance set to -1 says "no estimate" (the IMU gives no orientation)
_UNKNOWN_COVARIANCE = (-1.0,) + (0.0,) * 8


def _checked(topic: str, n: int, name: str, values, trailing: tuple[int, ...]) -> np.ndarray:
    """``values`` as an array of shape (n, *trailing), numeric and finite; else the writer's error."""
    a = np.asarray(values)
    if a.shape != (n, *trailing):
        raise _fail(topic, f"{name} has shape {a.shape}, expected {(n, *trailing)}")
    if a.dtype.kind not in "fiub":
        raise _fail(topic, f"{name} must be numeric, got dtype {a.dtype}")
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a.reshape(n, -1)).all(axis=1)
        if bad.any():
            raise _fail(topic, f"{name} sample {int(np.argmax(bad))} is not finite")
    return a


_MSGDEFS: dict[str, bytes] = {}


def _msgdef(msgtype: str) -> bytes:
    """The ``ros2msg`` schema text of a ROS 2 type (made once per process)."""
    if msgtype not in _MSGDEFS:
        _MSGDEFS[msgtype] = cdr.msgdef(msgtype).encode()
    return _MSGDEFS[msgtype]


def _cdr_stream(topic: str, msgtype: str, frame_id: str, ns: np.ndarray, values: dict[str, Any],
                offset_ns: int = 0) -> _Stream:
    """A channel of CDR messages: every record of one layout, header.stamp = log_time (``ns``);
    ``offset_ns`` moves the log_time only (``fused.mcap`` on the absolute clock, payloads as in the log)."""
    values = {**values, "stamp.sec": ns // 10**9, "stamp.nanosec": ns % 10**9}
    records = cdr.encode(msgtype, frame_id, values, ns.size)
    size = records.dtype.itemsize
    text = records.tobytes().decode("latin-1")
    return _Stream(topic, msgtype, ns + offset_ns, [text[i:i + size] for i in range(0, len(text), size)],
                   _msgdef(msgtype), encoding="cdr", schema_encoding="ros2msg")


def _format(schema: str, columns: list[list]) -> list[str]:
    """Payloads: one printf of the schema's canonical template per message (vectorised via map)."""
    return list(map(schemas.CANONICAL[schema].template.__mod__, zip(*columns)))


def _streams(log: SensorLog, encoding: str = "ros2", offset_ns: int = 0) -> list[_Stream]:
    """Every sensor present, in channel order, checked and formatted (``encoding`` "json": the
    IMU and odometer too as JSON, the format of logs before CDR); ``offset_ns`` is added to every
    log_time (``fused.mcap`` on the survey's absolute clock; the payloads stay as in the log, as
    :func:`copy_log` keeps them)."""
    out: list[_Stream] = []
    if log.imu is not None:
        out.append(_imu_stream(log.imu, encoding, offset_ns))
    if log.odometer is not None:
        out.append(_odometer_stream(log.odometer, encoding, offset_ns))
    if log.gnss is not None:
        out.append(_gnss_stream(log.gnss, offset_ns))
    for sid in sorted(log.total_stations):
        out.append(_total_station_stream(sid, log.total_stations[sid], offset_ns))
    if log.inclinometer is not None:
        d = log.inclinometer
        out.append(_json_stream("/inclinometer", schemas.INCLINATION, d.t_s, offset_ns,
                                [("roll_rad", d.roll_rad, ()), ("pitch_rad", d.pitch_rad, ())]))
    if log.gauge is not None:
        out.append(_json_stream("/gauge", schemas.GAUGE, log.gauge.t_s, offset_ns,
                                [("gauge_m", log.gauge.gauge_m, ())]))
    return out


def _json_stream(topic: str, schema: str, t_s: np.ndarray, offset_ns: int,
                 named: list[tuple[str, Any, tuple[int, ...]]]) -> _Stream:
    """A JSON channel of ``schema`` whose payloads are the ``named`` columns (name, values, trailing
    shape per message) checked by :func:`_columns`; ``t_s`` (N,) [s] on the log's clock."""
    ns = _log_time_ns(topic, t_s) + offset_ns
    return _Stream(topic, schema, ns, _format(schema, _columns(topic, ns.size, named)))


def _imu_stream(d: ImuData, encoding: str, offset_ns: int) -> _Stream:
    """``/imu``: CDR ``sensor_msgs/msg/Imu`` (orientation unknown), or JSON when ``encoding`` is "json"."""
    topic = "/imu"
    if encoding == "json":
        return _json_stream(topic, schemas.IMU, d.t_s, offset_ns,
                            [("gyro_radps", d.gyro_radps, (3,)), ("accel_mps2", d.accel_mps2, (3,))])
    ns = _log_time_ns(topic, d.t_s)
    values = {"angular_velocity": _checked(topic, ns.size, "gyro_radps", d.gyro_radps, (3,)),
              "linear_acceleration": _checked(topic, ns.size, "accel_mps2", d.accel_mps2, (3,)),
              "orientation": (0.0, 0.0, 0.0, 1.0), "orientation_covariance": _UNKNOWN_COVARIANCE}
    return _cdr_stream(topic, CDR_IMU, "imu", ns, values, offset_ns)


def _odometer_stream(d: OdometerData, encoding: str, offset_ns: int) -> _Stream:
    """``/odometer``: CDR of :data:`CDR_ODOMETER`, or JSON when ``encoding`` is "json"; ticks
    must be integers."""
    topic = "/odometer"
    if encoding == "json":
        ns = _log_time_ns(topic, d.t_s) + offset_ns
        cols = _columns(topic, ns.size, [("distance_m", d.distance_m, ()), ("ticks", np.asarray(d.ticks), ())])
        if np.asarray(d.ticks).dtype.kind == "f" and not np.array_equal(np.asarray(d.ticks), np.rint(d.ticks)):
            raise _fail(topic, "ticks must be integers")
        return _Stream(topic, schemas.ODOMETER, ns, _format(schemas.ODOMETER, cols))
    ns = _log_time_ns(topic, d.t_s)
    ticks = np.asarray(d.ticks)
    if ticks.dtype.kind == "f" and not np.array_equal(ticks, np.rint(ticks)):
        raise _fail(topic, "ticks must be integers")
    values = {"distance_m": _checked(topic, ns.size, "distance_m", d.distance_m, ()),
              "ticks": _checked(topic, ns.size, "ticks", ticks, ()).astype(np.int64)}
    return _cdr_stream(topic, CDR_ODOMETER, "odometer", ns, values, offset_ns)


def _gnss_stream(d: GnssData, offset_ns: int) -> _Stream:
    """``/gnss`` as JSON location fixes; the payload's timestamp stays on the log's clock."""
    topic = "/gnss"
    own = _log_time_ns(topic, d.t_s)  # the payload's timestamp: the log's clock, as a copy keeps it
    ns = own + offset_ns
    n = ns.size
    cols = [(own // 10**9).tolist(), (own % 10**9).tolist()] + _columns(topic, n, [
        ("lat_deg", d.lat_deg, ()), ("lon_deg", d.lon_deg, ()), ("h_m", d.h_m, ()),
        ("cov_enu_m2", d.cov_enu_m2, (3, 3)), ("fix_quality", np.asarray(d.fix_quality).astype(np.int64), ())])
    return _Stream(topic, schemas.LOCATION_FIX, ns, _format(schemas.LOCATION_FIX, cols))


def _total_station_stream(sid: str, d: TotalStationData, offset_ns: int) -> _Stream:
    """The polar observations of total station ``sid`` (a name without '/') as JSON."""
    topic = schemas.TOTAL_STATION_PREFIX + sid
    if not sid or "/" in sid:
        raise _fail(topic, "station id must be a non-empty name without '/'")
    ns = _log_time_ns(topic, d.t_s) + offset_ns
    cols = _columns(topic, ns.size, [("horizontal_angle_rad", d.horizontal_angle_rad, ()),
                                     ("zenith_angle_rad", d.zenith_angle_rad, ()),
                                     ("slope_distance_m", d.slope_distance_m, ())])
    prism = np.asarray(d.prism_id, dtype=object)
    if prism.shape != (ns.size,):
        raise _fail(topic, f"prism_id has shape {prism.shape}, expected {(ns.size,)}")
    cols.append([json.dumps(str(p)) for p in prism.tolist()])
    return _Stream(topic, schemas.POLAR, ns, _format(schemas.POLAR, cols))


def _metadata_records(metadata: dict[str, Any]) -> list[tuple[str, dict[str, str]]]:
    """(record name, {"json": text}) sorted by name; the text has sorted keys and no NaN."""

    def plain(obj):
        if hasattr(obj, "tolist"):
            return obj.tolist()
        raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")

    out = []
    for name in sorted(metadata):
        if not isinstance(name, str) or not name:
            raise SensorDataError(f"cannot write metadata: record name {name!r} is not a non-empty string")
        try:
            text = json.dumps(metadata[name], sort_keys=True, allow_nan=False, separators=(",", ":"), default=plain)
        except (TypeError, ValueError) as exc:
            raise SensorDataError(f"cannot write metadata {name!r}: {exc}") from None
        out.append((name, {"json": text}))
    return out


def _record(rec) -> bytes:
    """Serialise one small MCAP record with the mcap library's own record writer."""
    builder = RecordBuilder()
    rec.write(builder)
    return builder.end()


@dataclass
class _Merged:
    """All messages in file order: channel id, log_time [ns], sequence (M,) and payloads (M)."""

    channel: np.ndarray
    log_time_ns: np.ndarray
    sequence: np.ndarray
    payloads: list[str]


def _merge(streams: list[_Stream], first_id: int = 1) -> _Merged:
    """Interleave the channels in log_time order (ties: channel order); channel ids start at ``first_id``."""
    if not streams:
        return _Merged(np.zeros(0, np.uint16), np.zeros(0, np.int64), np.zeros(0, np.uint32), [])
    chan = np.concatenate([np.full(s.log_time_ns.size, i + first_id, np.uint16) for i, s in enumerate(streams)])
    times = np.concatenate([s.log_time_ns for s in streams])
    seq = np.concatenate([np.arange(s.log_time_ns.size, dtype=np.uint64) for s in streams]) % (1 << 32)
    order = np.lexsort((chan, times))
    payloads = list(itertools.chain.from_iterable(s.payloads for s in streams))
    return _Merged(chan[order], times[order], seq[order].astype(np.uint32), [payloads[i] for i in order.tolist()])


def _chunk_bounds(record_bytes: np.ndarray, target_bytes: int) -> list[tuple[int, int]]:
    """[start, stop) message ranges: each chunk closes at the first message reaching target_bytes."""
    cum = np.cumsum(record_bytes)
    bounds, start = [], 0
    while start < record_bytes.size:
        base = cum[start - 1] if start else 0
        stop = int(np.searchsorted(cum, base + target_bytes, side="left")) + 1
        stop = min(max(stop, start + 1), record_bytes.size)
        bounds.append((start, stop))
        start = stop
    return bounds


def _chunk_records(m: _Merged, lengths: np.ndarray, start: int, stop: int) -> bytes:
    """The uncompressed records of one chunk: 31-byte message headers interleaved with payloads."""
    hdr = np.empty(stop - start, dtype=_MSG_HEADER)
    hdr["op"] = _MESSAGE
    hdr["length"] = lengths[start:stop] + 22
    hdr["channel"] = m.channel[start:stop]
    hdr["sequence"] = m.sequence[start:stop]
    hdr["log_time"] = m.log_time_ns[start:stop]
    hdr["publish_time"] = m.log_time_ns[start:stop]
    text = hdr.tobytes().decode("latin-1")
    parts: list[str] = [""] * (2 * (stop - start))
    parts[0::2] = [text[i:i + 31] for i in range(0, len(text), 31)]
    parts[1::2] = m.payloads[start:stop]
    return "".join(parts).encode("latin-1")


def _message_indexes(m: _Merged, lengths: np.ndarray, start: int, stop: int, chunk_end: int
                     ) -> tuple[bytes, dict[int, int]]:
    """MessageIndex records following a chunk (one per channel in it) and their file offsets."""
    offsets = np.concatenate([[0], np.cumsum(lengths[start:stop] + 31)[:-1]]).astype(np.uint64)
    chan = m.channel[start:stop]
    out, where, pos = [], {}, chunk_end
    for c in np.unique(chan).tolist():
        sel = chan == c
        entries = np.empty(int(sel.sum()), dtype=_INDEX_ENTRY)
        entries["log_time"] = m.log_time_ns[start:stop][sel]
        entries["offset"] = offsets[sel]
        body = entries.tobytes()
        rec = struct.pack("<BQHI", _MESSAGE_INDEX, 6 + len(body), c, len(body)) + body
        where[c] = pos
        pos += len(rec)
        out.append(rec)
    return b"".join(out), where


class _Output:
    """A file being written: tracks the byte position and the running CRC-32 of the data section."""

    def __init__(self, fh, pos: int = 0, crc: int = 0):
        """``pos``, ``crc``: of the bytes the file already holds (a file being continued)."""
        self.fh, self.pos, self.crc = fh, pos, crc

    def put(self, data: bytes, in_crc: bool = True) -> int:
        """Write ``data``; returns the offset it was written at."""
        at = self.pos
        self.fh.write(data)
        self.pos += len(data)
        if in_crc:
            self.crc = zlib.crc32(data, self.crc)
        return at


def _compress(data: bytes) -> bytes:
    return zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(data)


@dataclass(frozen=True)
class RawSource:
    """An intact raw log file as :func:`read_log` checked it: what copying its records byte for
    byte needs (``fused.mcap`` carries the raw inputs unchanged without formatting them again).

    schemas: id -> (name, encoding, data); channels: id -> (schema id, topic, message encoding,
    metadata); records: (opcode, start, stop) byte ranges of the data section's chunk, message
    index and metadata records, in file order; message_counts: channel id -> messages.
    """

    path: Path
    size: int
    mtime_ns: int
    schemas: dict[int, tuple[str, str, bytes]]
    channels: dict[int, tuple[int, str, str, dict[str, str]]]
    records: tuple[tuple[int, int, int], ...]
    message_counts: dict[int, int]

    def unchanged(self) -> bool:
        """True when the file still has the size and modification time it had when read."""
        try:
            st = self.path.stat()
        except OSError:
            return False
        return (st.st_size, st.st_mtime_ns) == (self.size, self.mtime_ns)


def _copied_records(out: _Output, source: RawSource, offset_ns: int = 0, workers: int = 2
                    ) -> tuple[list[MetadataIndex], list[ChunkIndex]]:
    """Copy the source's metadata, chunk and message index records unchanged (chunks stay
    compressed; message indexes are relative to their chunk, so they stay valid); returns the
    metadata and chunk indexes of the copies. With ``offset_ns``, every message's log and
    publish time moves by it (:func:`_shifted_records`, on ``workers`` threads)."""
    metadata_indexes: list[MetadataIndex] = []
    chunk_indexes: list[ChunkIndex] = []
    for op, start, rec in _shifted_records(_source_records(source), offset_ns, workers):
        if op == _METADATA:
            name = _Cursor(rec[9:], start + 9).text()
            metadata_indexes.append(MetadataIndex(offset=out.put(rec), length=len(rec), name=name))
        elif op == _CHUNK:
            t0, t1, size = struct.unpack_from("<QQQ", rec, 9)
            n = struct.unpack_from("<I", rec, 37)[0]
            compressed = struct.unpack_from("<Q", rec, 41 + n)[0]
            chunk_indexes.append(ChunkIndex(
                message_start_time=t0, message_end_time=t1, chunk_start_offset=out.put(rec),
                chunk_length=len(rec), message_index_offsets={}, message_index_length=0,
                compression=rec[41:41 + n].decode("utf-8"), compressed_size=compressed, uncompressed_size=size))
        else:  # a message index: it follows its chunk (_source_records)
            index = chunk_indexes[-1]
            index.message_index_offsets[struct.unpack_from("<H", rec, 9)[0]] = out.put(rec)
            index.message_index_length += len(rec)
    return metadata_indexes, chunk_indexes


def _source_records(source: RawSource) -> Iterator[tuple[int, int, bytes]]:
    """``(opcode, start, record bytes)`` of the source's records that a copy takes, in file order:
    the metadata, the chunks and the message indexes that follow a chunk (others are dropped)."""
    last_op = None
    with open(source.path, "rb") as src:
        for op, start, stop in source.records:
            src.seek(start)
            rec = src.read(stop - start)
            if len(rec) != stop - start:
                raise SensorDataError(f"{source.path}: changed while being copied")
            follows_chunk = last_op in (_CHUNK, _MESSAGE_INDEX)
            last_op = op if op != _METADATA else last_op
            if op in (_METADATA, _CHUNK) or op == _MESSAGE_INDEX and follows_chunk:
                yield op, start, rec


#: chunks shifted at a time on the two threads (about 1 MB compressed each: bounded memory)
SHIFT_WINDOW_CHUNKS = 8


def _shifted_records(records: Iterable[tuple[int, int, bytes]], offset_ns: int, workers: int = 2
                     ) -> Iterator[tuple[int, int, bytes]]:
    """``records`` (:func:`_source_records`) with every message's log and publish time moved by
    ``offset_ns``: the chunks (:func:`_shifted_chunk`) and message indexes
    (:func:`_shifted_message_index`) of a window of :data:`SHIFT_WINDOW_CHUNKS` chunks at a time
    on ``workers`` threads (inflating and compressing release the GIL), in their order. Unchanged
    without an offset."""
    if not offset_ns:
        yield from records
        return

    def shift(item: tuple[int, int, bytes]) -> bytes:
        op, start, rec = item
        if op == _CHUNK:
            return _shifted_chunk(rec, offset_ns, start)
        return _shifted_message_index(rec, offset_ns) if op == _MESSAGE_INDEX else rec

    window: list[tuple[int, int, bytes]] = []
    chunks = 0
    for item in records:
        window.append(item)
        chunks += item[0] == _CHUNK
        if chunks == SHIFT_WINDOW_CHUNKS:
            yield from ((op, start, rec) for (op, start, _), rec in thread_map(shift, window, workers=workers))
            window, chunks = [], 0
    yield from ((op, start, rec) for (op, start, _), rec in thread_map(shift, window, workers=workers))


def _shifted_chunk(rec: bytes, offset_ns: int, at: int) -> bytes:
    """A chunk record with every message's log_time and publish_time moved by ``offset_ns``
    (both are times on one clock, the MCAP specification's publish time of 0 included): inflated,
    the message headers patched, compressed
    again with the chunk's own compression (its payloads, and any schema and channel records in
    it, stay byte for byte); start and end time and CRC follow."""
    t0, t1, size, crc = struct.unpack_from("<QQQI", rec, 9)
    n = struct.unpack_from("<I", rec, 37)[0]
    compression = rec[41:41 + n].decode("utf-8")
    clen = struct.unpack_from("<Q", rec, 41 + n)[0]
    data = bytearray(_inflate(compression, rec[49 + n:49 + n + clen], size, at, complete=True))
    offsets = _message_offsets(bytes(data))  # every record a message (what trackfusion writes): at once
    if offsets is None:
        offsets, pos = [], 0
        while pos + 9 <= len(data):  # any writer's records, in order
            op, length = struct.unpack_from("<BQ", data, pos)
            if op == _MESSAGE:
                offsets.append(pos)
            pos += 9 + length
        offsets = np.asarray(offsets, np.int64)
    raw = np.frombuffer(data, np.uint8)
    at_times = (offsets + 15)[:, None] + np.arange(16)  # log_time and publish_time of each message
    times = raw[at_times].copy().view("<u8")  # (M, 2): log_time, publish_time
    times += np.uint64(offset_ns)
    raw[at_times] = times.view(np.uint8).reshape(-1, 16)
    raw = bytes(data)
    if compression == "zstd":
        comp = _compress(raw)
    elif compression == "lz4":
        import lz4.frame
        comp = lz4.frame.compress(raw)
    else:
        comp = raw
    body = struct.pack("<QQQI", t0 + offset_ns if size else t0, t1 + offset_ns if size else t1, size,
                       zlib.crc32(raw) if crc else 0) + struct.pack("<I", n) + rec[41:41 + n] + struct.pack(
        "<Q", len(comp))
    return _RECORD_HEAD.pack(_CHUNK, len(body) + len(comp)) + body + comp


def _shifted_message_index(rec: bytes, offset_ns: int) -> bytes:
    """A message index record with its log times moved by ``offset_ns`` (offsets unchanged)."""
    pairs = np.frombuffer(rec, dtype="<u8", offset=15).reshape(-1, 2).copy()
    pairs[:, 0] += np.uint64(offset_ns)
    return rec[:15] + pairs.tobytes()


def _write_chunks(out: _Output, merged: _Merged) -> list[ChunkIndex]:
    """The merged messages as zstd chunks of about CHUNK_SIZE_BYTES, each followed by its message
    indexes; returns their chunk indexes."""
    lengths = np.fromiter(map(len, merged.payloads), dtype=np.int64, count=len(merged.payloads))
    bounds = _chunk_bounds(lengths + 31, CHUNK_SIZE_BYTES)
    chunk_indexes = []
    raw_chunks = (_chunk_records(merged, lengths, a, b) for a, b in bounds)
    for (raw, comp), (a, b) in zip(thread_map(_compress, raw_chunks, workers=2), bounds):  # zstd releases the GIL
        t0, t1 = int(merged.log_time_ns[a:b].min()), int(merged.log_time_ns[a:b].max())
        body = struct.pack("<QQQII", t0, t1, len(raw), zlib.crc32(raw), 4) + b"zstd" + struct.pack(
            "<Q", len(comp))
        head = _RECORD_HEAD.pack(_CHUNK, len(body) + len(comp))
        start = out.put(head + body)
        out.put(comp)
        index_bytes, index_at = _message_indexes(merged, lengths, a, b, out.pos)
        out.put(index_bytes)
        chunk_indexes.append(ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=start,
            chunk_length=len(head) + len(body) + len(comp), message_index_offsets=index_at,
            message_index_length=len(index_bytes), compression="zstd", compressed_size=len(comp),
            uncompressed_size=len(raw)))
    return chunk_indexes


@dataclass
class _Head:
    """What the first part of a file (:func:`_write_head`) put in it, for the rest
    (:func:`_write_tail`): the schema and channel records (the summary repeats them), the
    copied metadata and chunk indexes, and the copied channels' message counts."""

    schemas: list[Schema] = field(default_factory=list)
    channels: list[Channel] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    message_counts: dict[int, int] = field(default_factory=dict)


def _write_head(out: _Output, source: RawSource | None = None, offset_ns: int = 0, workers: int = 2) -> _Head:
    """Magic and header, then with ``source`` its schemas, channels (same ids) and records, copied
    (:func:`_copied_records`; ``workers``: threads moving its chunks by ``offset_ns``)."""
    out.put(MAGIC)
    out.put(_record(Header(profile="", library=LIBRARY)))
    if source is None:
        return _Head()
    head = _Head([Schema(id=i, name=n, encoding=e, data=d) for i, (n, e, d) in sorted(source.schemas.items())],
                 [Channel(id=i, schema_id=sid, topic=t, message_encoding=e, metadata=m)
                  for i, (sid, t, e, m) in sorted(source.channels.items())],
                 message_counts=dict(source.message_counts))
    for rec in head.schemas + head.channels:
        out.put(_record(rec))
    head.metadata_indexes, head.chunk_indexes = _copied_records(out, source, offset_ns, workers)
    return head


def _write_tail(out: _Output, head: _Head, streams: list[_Stream], metadata: list[tuple[str, dict[str, str]]]) -> None:
    """The rest of a file after :func:`_write_head`: the ``streams``' schemas (one record per name,
    the head's reused) and channels (the ids after the head's), ``metadata``, the streams' chunks,
    data end, summary, footer."""
    schema_recs, channel_recs = list(head.schemas), list(head.channels)
    next_schema = max((r.id for r in schema_recs), default=0) + 1
    first_channel = max((r.id for r in channel_recs), default=0) + 1
    # one schema record per name: a stream whose schema name the file has already (the source's, or
    # an earlier stream's) uses that record, so that a viewer never meets two schemas of one name
    schema_ids: dict[str, int] = {r.name: r.id for r in schema_recs}
    new_schemas: list[Schema] = []
    for s in streams:
        if s.schema not in schema_ids:
            data = s.schema_data if s.schema_data is not None else schemas.schema_bytes(s.schema)
            schema_ids[s.schema] = next_schema
            next_schema += 1
            new_schemas.append(Schema(id=schema_ids[s.schema], name=s.schema, encoding=s.schema_encoding, data=data))
    new_channels = [Channel(id=first_channel + i, schema_id=schema_ids[s.schema], topic=s.topic,
                            message_encoding=s.encoding, metadata={}) for i, s in enumerate(streams)]
    for rec in new_schemas + new_channels:
        out.put(_record(rec))
    schema_recs += new_schemas
    channel_recs += new_channels
    metadata_indexes, chunk_indexes = list(head.metadata_indexes), list(head.chunk_indexes)
    for name, data in metadata:
        rec = _record(Metadata(name=name, metadata=data))
        metadata_indexes.append(MetadataIndex(offset=out.put(rec), length=len(rec), name=name))
    chunk_indexes += _write_chunks(out, _merge(streams, first_channel))
    out.put(_record(DataEnd(data_section_crc=out.crc)), in_crc=False)

    counts = dict(head.message_counts)
    counts.update({first_channel + i: int(s.log_time_ns.size) for i, s in enumerate(streams)})
    timed = [c for c in chunk_indexes if c.uncompressed_size]
    stats = Statistics(
        message_count=sum(counts.values()), schema_count=len(schema_recs), channel_count=len(channel_recs),
        attachment_count=0, metadata_count=len(metadata_indexes), chunk_count=len(chunk_indexes),
        message_start_time=min((c.message_start_time for c in timed), default=0),
        message_end_time=max((c.message_end_time for c in timed), default=0), channel_message_counts=counts)
    _write_summary(out, [(_SCHEMA, schema_recs), (_CHANNEL, channel_recs), (_STATISTICS, [stats]),
                         (_CHUNK_INDEX, chunk_indexes), (_METADATA_INDEX, metadata_indexes)])


def _write_summary(out: _Output, groups: list[tuple[int, list]]) -> None:
    """The summary section of the record ``groups`` (opcode, records), its offsets, footer and magic."""
    summary_start = out.pos
    summary, offsets = [], []
    for opcode, recs in groups:
        if recs:
            blob = b"".join(_record(r) for r in recs)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + sum(map(len, summary)),
                                         group_length=len(blob)))
            summary.append(blob)
    summary_offset_start = summary_start + sum(map(len, summary))
    summary.append(b"".join(_record(o) for o in offsets))
    summary_blob = b"".join(summary)
    footer_head = struct.pack("<BQQQ", _FOOTER, 20, summary_start, summary_offset_start)
    summary_crc = zlib.crc32(footer_head, zlib.crc32(summary_blob))
    out.put(summary_blob, in_crc=False)
    out.put(_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                           summary_crc=summary_crc)), in_crc=False)
    out.put(MAGIC, in_crc=False)


def write_log(path: str | Path, log: SensorLog, extra: Iterable[ExtraChannel] = (), encoding: str = "ros2",
              time_offset_ns: int = 0) -> None:
    """Write ``log`` to ``path`` as an MCAP raw log (docs/log_format.md).

    Every sensor present (not None; total stations by id) becomes one channel; messages of
    all channels are interleaved in ``log_time`` order (ties: channel order) in zstd chunks of
    about 4 MiB, with message indexes, chunk indexes and a summary. Each ``log.metadata`` entry
    becomes a metadata record of that name holding ``{"json": <the value as JSON text>}``.
    The file appears atomically (temporary name, then rename) and is byte-identical for
    identical input (no wall-clock time). Raises :class:`SensorDataError` for data the reader
    would refuse (non-finite values, times not strictly increasing, wrong shapes).
    ``extra`` channels follow the sensors' (a file with them is no longer a raw log that
    :func:`read_log` accepts; ``fused.mcap`` is written this way). ``encoding``: "ros2" writes
    ``/imu`` as ``sensor_msgs/msg/Imu`` and ``/odometer`` as ``trackfusion_msgs/msg/OdometerDistance``
    (CDR), "json" every topic as JSON (the older format, still read). ``time_offset_ns`` [ns] is
    added to the sensors' log_time (``fused.mcap`` on the survey's absolute clock; the extra
    channels carry their own times).
    """
    if encoding not in ("ros2", "json"):
        raise ValueError(f"encoding must be 'ros2' or 'json', got {encoding!r}")
    streams = _streams(log, encoding, int(time_offset_ns)) + _extra_streams(extra)
    metadata = _metadata_records(log.metadata)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        out = _Output(fh)
        _write_tail(out, _write_head(out), streams, metadata)


def _extra_streams(extra: Iterable[ExtraChannel]) -> list[_Stream]:
    return [_Stream(c.topic, c.schema_name, np.asarray(c.log_time_ns, np.int64), list(c.payloads), c.schema_data)
            for c in extra]


def copy_log(path: str | Path, source: RawSource, extra: Iterable[ExtraChannel] = (), time_offset_ns: int = 0) -> None:
    """Write to ``path`` the raw log file ``source`` (a ``SensorLog.source`` from :func:`read_log`)
    with its schemas, channels (same ids), metadata and chunks copied byte for byte (no decoding,
    no recompression), then the ``extra`` channels (next ids) in chunks of their own; summary
    as :func:`write_log`. Atomic and byte-identical for identical input. Raises
    :class:`SensorDataError` when the file changed since it was read. ``time_offset_ns`` [ns]
    moves the copied messages' log and publish times (``fused.mcap`` on the survey's absolute
    clock): their chunks are inflated, patched and compressed again, payloads untouched.
    The same bytes as :func:`start_copy` then :func:`finish_copy`."""
    with atomic_path(path) as tmp:
        finish_copy(tmp, start_copy(tmp, source, time_offset_ns), extra)


@dataclass
class CopyHead:
    """The first part of :func:`copy_log` (:func:`start_copy`) in the file ``path``: its first
    ``pos`` bytes, the data section's CRC-32 over them ``crc``, and what the rest needs of them."""

    path: Path
    pos: int
    crc: int
    head: _Head


def start_copy(path: str | Path, source: RawSource, time_offset_ns: int = 0, workers: int = 2) -> CopyHead:
    """Write the first part of :func:`copy_log` (same arguments) to ``path``: magic, header and
    the source's schemas, channels and records, the longest part of the copy, which needs nothing
    of the extra channels (a run begins it while it smooths). ``workers``: threads that move the
    chunks onto the other clock (the same bytes for any number). The file is removed again on an
    error; :func:`finish_copy` writes the rest."""
    if not source.unchanged():
        raise SensorDataError(f"{source.path}: changed since it was read; read it again")
    try:
        with open(path, "wb") as fh:
            out = _Output(fh)
            head = _write_head(out, source, int(time_offset_ns), workers)
        return CopyHead(Path(path), out.pos, out.crc, head)
    except BaseException:
        Path(path).unlink(missing_ok=True)
        raise


def finish_copy(path: str | Path, copy: CopyHead, extra: Iterable[ExtraChannel] = ()) -> None:
    """Write the rest of :func:`copy_log` after ``copy`` (:func:`start_copy`): the ``extra``
    channels and the summary appended to its file, which is then renamed ``path`` (in the same
    folder: atomic); the file is removed on an error."""
    try:
        with open(copy.path, "r+b") as fh:
            fh.seek(copy.pos)
            fh.truncate()
            _write_tail(_Output(fh, copy.pos, copy.crc), copy.head, _extra_streams(extra), [])
        os.replace(copy.path, path)
    except BaseException:
        copy.path.unlink(missing_ok=True)
        raise


# =================================================================================================
# reading: file structure
# =================================================================================================

class _Corrupt(Exception):
    """Internal: the file structure is broken at ``at`` (byte offset)."""

    def __init__(self, reason: str, at: int):
        super().__init__(reason)
        self.reason, self.at = reason, at


class _Cursor:
    """Bounds-checked little-endian reads from one record body (``base``: its file offset)."""

    def __init__(self, data: bytes, base: int):
        self.data, self.pos, self.base = data, 0, base

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise _Corrupt("record shorter than its fields", self.base + self.pos)
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values if len(values) > 1 else values[0]

    def raw(self, size: int) -> bytes:
        if size < 0 or self.pos + size > len(self.data):
            raise _Corrupt("field length beyond its record", self.base + self.pos)
        out = self.data[self.pos:self.pos + size]
        self.pos += size
        return out

    def text(self) -> str:
        raw = self.raw(self.take("<I"))
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise _Corrupt("string is not UTF-8", self.base + self.pos) from None

    def string_map(self) -> dict[str, str]:
        sub = _Cursor(self.raw(self.take("<I")), self.base + self.pos)
        out = {}
        while sub.pos < len(sub.data):
            key = sub.text()
            out[key] = sub.text()
        return out


#: payloads of a channel decoded at once while the file is scanned (bounds the memory of a read
#: to the decoded arrays: the raw JSON text of a long log would take ~20 times more)
_DECODE_BATCH = 50_000


@dataclass
class _RawChannel:
    """A channel as found in the file, with its messages' times (list of uint64 arrays), the
    payloads not yet decoded, the decoded field batches and the first invalid record found."""

    topic: str
    schema_id: int
    encoding: str
    metadata: dict[str, str] = field(default_factory=dict)
    times: list[np.ndarray] = field(default_factory=list)
    payloads: list[bytes] = field(default_factory=list)
    count: int = 0
    #: (index of the batch's first record, its decoding: a :func:`_decode_batch` result or a future of one)
    batches: list[tuple[int, Any]] = field(default_factory=list)
    decoded: int = 0

    def decode_pending(self, schema: str, decoder: "_Decoder | None" = None) -> None:
        """Hand the pending payloads to ``decoder`` as one batch (decoded here without one)."""
        result = (decoder.decode(self.payloads, schema) if decoder is not None
                  else _decode_batch(self.payloads, schema))
        self.batches.append((self.decoded, result))
        self.decoded += len(self.payloads)
        self.payloads = []

    def arrays(self, schema: str) -> list[np.ndarray]:
        """The channel's sensor value arrays (:func:`_sensor_arrays`); raises _Bad for its first
        invalid record."""
        if self.payloads or not self.batches:
            self.decode_pending(schema)
        pending, self.batches = self.batches, []
        batches = []
        while pending:  # popped: a batch left in ``pending`` would stay alive through the join
            first, result = pending.pop(0)
            result = result_of(result)
            if isinstance(result, tuple):  # the first invalid record is in the first bad batch
                raise _Bad(first + result[0], result[1])
            batches.append(result)
        del result
        return _join_batches(batches)


def _join_batches(batches: list[list[np.ndarray]]) -> list[np.ndarray]:
    """Concatenate batches of arrays into arrays allocated once, freeing each batch once copied:
    the peak memory is the batches plus one batch, not twice the data (the freed batches' heap
    pages are handed back every few batches: a 20 km log's read peaks 95 MB lower)."""
    total = sum(len(b[0]) for b in batches)
    out = [np.empty((total,) + a.shape[1:], a.dtype) for a in batches[0]]
    at = 0
    batches.reverse()
    while batches:
        batch = batches.pop()
        n = len(batch[0])
        for whole, part in zip(out, batch):
            whole[at:at + n] = part
        at += n
        del batch
        if len(batches) % 4 == 0:
            trim_heap()
    return out


def _decode_batch(payloads: list[bytes], schema: str) -> list[np.ndarray] | tuple[int, str]:
    """The sensor value arrays (:func:`_sensor_arrays`) of a batch of payloads, or (index, reason)
    of its first invalid record (picklable: it may run in a worker process)."""
    try:
        if schema in cdr.LAYOUTS:
            return _cdr_arrays(cdr.Records.from_payloads(payloads), schema)
        return _sensor_arrays(schema, _decode_fields(payloads, schema))
    except _Bad as bad:
        return bad.index, bad.reason


def _cdr_batch(records: cdr.Records, msgtype: str) -> list[np.ndarray] | tuple[int, str]:
    """:func:`_decode_batch` of CDR records."""
    try:
        return _cdr_arrays(records, msgtype)
    except _Bad as bad:
        return bad.index, bad.reason


def _cdr_arrays(records: cdr.Records, msgtype: str) -> list[np.ndarray]:
    """The :data:`cdr.WANTED` fields of a batch of CDR records, checked finite; raises _Bad."""
    try:
        fields = cdr.decode(records, msgtype)
    except cdr.CdrRecordError as exc:
        raise _Bad(exc.index, exc.reason) from None
    first = None
    for name, values in fields.items():
        if values.dtype.kind == "f":
            flat = values.reshape(len(values), int(np.prod(values.shape[1:], dtype=int)))
            bad = ~np.isfinite(flat).all(axis=1)
            if bad.any() and (first is None or int(np.argmax(bad)) < first.index):
                i = int(np.argmax(bad))
                j = int(np.argmax(~np.isfinite(flat[i])))
                what = "NaN" if np.isnan(flat[i, j]) else "infinite"
                axis = f".{'xyzw'[j]}" if flat.shape[1] in (3, 4) else (f"[{j}]" if flat.shape[1] > 1 else "")
                first = _Bad(i, f"{name}{axis} is {what}")
    if first is not None:
        raise first
    return [fields[k] for k in cdr.WANTED[msgtype]]


#: worker processes decoding payload batches while a scan goes on (below 2: none, decode in turn)
DECODE_WORKERS = 2
#: batches decoded by worker processes at once at most (bounds the payload text a read holds)
_MAX_IN_FLIGHT = 2


class _Decoder:
    """Decodes the payload batches of a scan in two forked worker processes while the scan goes
    on (:class:`~trackfusion.forked.ForkedPool`; results are taken in batch order: identical to
    decoding them in turn); they only run :func:`_decode_batch`. Without two CPUs, without
    ``fork``, inside a worker process (e.g. ``trackfusion batch``) or where processes cannot be
    started, batches are decoded in this process."""

    def __init__(self):
        self.pool = ForkedPool(DECODE_WORKERS, _MAX_IN_FLIGHT)

    def decode(self, payloads: list[bytes], schema: str) -> Any:
        """A future of :func:`_decode_batch` (or its result when decoding here; CDR batches are
        always decoded here: they take less time than sending them to a worker)."""
        if schema in cdr.LAYOUTS:
            return _decode_batch(payloads, schema)
        return self.pool.submit(_decode_batch, payloads, schema)

    def close(self) -> None:
        self.pool.close()


@dataclass
class _Scan:
    """The structural content of a file: schemas, channels with messages, metadata, first problem."""

    path: str
    wanted: set[str] | None
    library: str = ""
    schemas: dict[int, tuple[str, str]] = field(default_factory=dict)
    channels: dict[int, _RawChannel] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    problem: _Corrupt | None = None
    n_messages: int = 0
    schema_data: dict[int, bytes] = field(default_factory=dict)
    #: (opcode, start, stop) of the data section's chunk, message index and metadata records
    copy_records: list[tuple[int, int, int]] = field(default_factory=list)
    #: False when the data section holds records that a byte copy would not carry (top-level messages, attachments)
    copyable: bool = True
    stat: os.stat_result | None = None
    decoder: _Decoder = field(default_factory=_Decoder)
    #: reading a ROS 2 bag: topic -> message type of the topics read (others are not checked)
    cdr_types: dict[str, str] | None = None

    def source(self) -> "RawSource | None":
        """What copying the whole file needs, or None unless it was read whole, intact and copyable."""
        if self.wanted is not None or self.problem is not None or not self.copyable or self.stat is None:
            return None
        return RawSource(Path(self.path).resolve(), self.stat.st_size, self.stat.st_mtime_ns,
                         {i: (n, e, self.schema_data[i]) for i, (n, e) in self.schemas.items()},
                         {i: (c.schema_id, c.topic, c.encoding, dict(c.metadata)) for i, c in self.channels.items()},
                         tuple(self.copy_records), {i: c.count for i, c in self.channels.items()})

    def add_schema(self, c: _Cursor) -> None:
        sid = c.take("<H")
        name, encoding = c.text(), c.text()
        data = c.raw(c.take("<I"))
        if sid == 0:
            raise _Corrupt("schema id 0 is reserved", c.base)
        if self.schemas.setdefault(sid, (name, encoding)) != (name, encoding):
            raise _Corrupt(f"schema id {sid} defined twice differently", c.base)
        self.schema_data.setdefault(sid, bytes(data))

    def note_record(self, op: int, start: int, stop: int) -> None:
        """Remember where a top-level data-section record lies (what :class:`RawSource` copies)."""
        if op in (_CHUNK, _MESSAGE_INDEX, _METADATA):
            self.copy_records.append((op, start, stop))
        elif op not in (_SCHEMA, _CHANNEL):
            self.copyable = False

    def add_channel(self, c: _Cursor) -> None:
        cid, schema_id = c.take("<HH")
        topic, encoding = c.text(), c.text()
        metadata = c.string_map()
        known = self.channels.get(cid)
        if known is None:
            if schema_id and schema_id not in self.schemas:
                raise _Corrupt(f"channel {topic} refers to undefined schema id {schema_id}", c.base)
            self.channels[cid] = _RawChannel(topic, schema_id, encoding, metadata)
        elif (known.topic, known.schema_id, known.encoding) != (topic, schema_id, encoding):
            raise _Corrupt(f"channel id {cid} defined twice differently", c.base)

    def add_messages(self, data: bytes, offsets: list[int] | np.ndarray, base: int) -> None:
        """Messages of one chunk (or one top-level message): ``offsets`` of their records in ``data``."""
        if len(offsets) == 0:
            return
        off = np.asarray(offsets, dtype=np.int64)
        raw = np.frombuffer(data, dtype=np.uint8)
        hdr = sliding_window_view(raw, 31)[off].view(_MSG_HEADER).ravel()
        if np.any(hdr["length"] < 22):
            raise _Corrupt("message record shorter than 22 bytes", base + int(off[np.argmax(hdr["length"] < 22)]))
        channel = hdr["channel"]
        unknown = ~np.isin(channel, list(self.channels))
        if unknown.any():
            i = int(np.argmax(unknown))
            raise _Corrupt(f"message refers to undefined channel {int(channel[i])}", base + int(off[i]))
        starts = off + 31
        stops = off + 9 + hdr["length"].astype(np.int64)
        for cid in np.unique(channel).tolist():
            ch = self.channels[cid]
            sel = channel == cid
            ch.count += int(sel.sum())
            if self.wanted is not None and ch.topic not in self.wanted:
                continue
            ch.times.append(hdr["log_time"][sel])
            if ch.encoding == "cdr" and not ch.payloads and self.cdr_rows(ch, raw, starts[sel], stops[sel]):
                continue
            ch.payloads.extend(map(data.__getitem__, map(slice, starts[sel].tolist(), stops[sel].tolist())))
            if len(ch.payloads) >= _DECODE_BATCH:
                try:
                    schema = _channel_schema(self, ch)
                except _Bad:
                    continue  # a channel problem: reported by read_log after the scan
                ch.decode_pending(schema, self.decoder)
        self.n_messages += len(offsets)

    def cdr_rows(self, ch: _RawChannel, raw: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> bool:
        """Decode one chunk's CDR messages of a channel at once when they all have one size: the
        records are copied out of the chunk as one (n, size) array (no bytes object per message).
        False (nothing done) otherwise: then the payloads are cut out one by one."""
        size = stops - starts
        if size.size == 0 or size[0] <= 0 or not (size == size[0]).all():
            return False
        try:
            msgtype = _channel_schema(self, ch)
        except _Bad:
            return False  # reported by the read after the scan
        if msgtype not in cdr.LAYOUTS:
            return False
        length = int(size[0])
        rows = sliding_window_view(raw, length)[starts]
        records = cdr.Records(rows.reshape(-1), np.arange(size.size, dtype=np.int64) * length, size)
        ch.batches.append((ch.decoded, _cdr_batch(records, msgtype)))
        ch.decoded += size.size
        return True

    def readable(self) -> str:
        per_topic = ", ".join(f"{c.topic} {c.count}" for c in self.channels.values() if c.count)
        return f"{self.n_messages} records readable" + (f" ({per_topic})" if per_topic else "")


def _message_offsets(data: bytes) -> np.ndarray | None:
    """Offsets (int64) of a chunk's records when every record is a Message whose payload is a JSON
    object or little-endian CDR (what trackfusion writes), found without walking the records one
    by one; None otherwise (then :func:`_walk_chunk` walks them).

    Candidates are the bytes 5 (Message opcode) followed by a 32-bit record length and, 31 bytes
    on, ``{`` or the CDR header ``00 01``; the record lengths must then chain them from offset 0 to the end of the chunk, so
    the offsets are exactly those a walk finds (a candidate that lies inside a record is skipped:
    no record ends at it)."""
    raw = np.frombuffer(data, np.uint8)
    if raw.size < 32 or raw[0] != _MESSAGE:
        return None
    candidates = np.flatnonzero(raw[:raw.size - 40] == np.uint8(_MESSAGE))  # (a whole header and a byte)
    first = raw[candidates + 31]
    candidates = candidates[(first == ord("{")) | ((first == 0) & (raw[candidates + 32] == 1))]
    lengths = raw[candidates[:, None] + np.arange(1, 9)].copy().view("<u8").ravel()
    stops = candidates + 9 + np.minimum(lengths, raw.size).astype(np.int64)
    following = np.searchsorted(candidates, stops)  # the candidate at each record's end, if any
    landed = np.append(candidates, raw.size)[following] == stops
    reached = np.zeros(candidates.size + 1, bool)  # offset 0 and every candidate a record ends at
    reached[0] = True
    reached[following[landed]] = True
    chain = np.flatnonzero(reached[:-1])
    if not (landed[chain].all() and np.array_equal(following[chain], np.append(chain[1:], candidates.size))):
        return None
    return candidates[chain]


def _indexed_offsets(data: bytes, hint: np.ndarray | None) -> np.ndarray | None:
    """The offsets of a chunk's records from its message index records (``hint``: every offset
    they list), when those offsets chain exactly: the first at 0, each record a Message ending
    where the next starts, the last ending at the chunk's end; then they are the offsets a walk
    finds. None otherwise."""
    if hint is None or hint.size == 0:
        return None
    off = np.sort(hint).astype(np.int64)
    raw = np.frombuffer(data, np.uint8)
    if off[0] != 0 or off[-1] + 9 > raw.size or (np.diff(off) <= 0).any():
        return None
    head = sliding_window_view(raw, 9)[off]
    lengths = head[:, 1:].copy().view("<u8").ravel()
    if not (head[:, 0] == _MESSAGE).all() or (lengths > raw.size).any():
        return None
    stops = off + 9 + lengths.astype(np.int64)
    if not (np.array_equal(stops[:-1], off[1:]) and stops[-1] == raw.size):
        return None
    return off


def _walk_chunk(scan: _Scan, data: bytes, base: int, complete: bool, hint: np.ndarray | None = None) -> None:
    """Parse the records of one decompressed chunk; a cut last record ends a partial chunk.
    ``hint``: the record offsets its message indexes list (used when they chain exactly)."""
    if complete:
        fast = _indexed_offsets(data, hint)
        fast = _message_offsets(data) if fast is None else fast
        if fast is not None:
            scan.add_messages(data, fast, base)
            return
    offsets: list[int] = []
    pos, size, head = 0, len(data), _RECORD_HEAD.unpack_from
    while pos + 9 <= size:
        op, length = head(data, pos)
        stop = pos + 9 + length
        if stop > size:
            break
        if op == _MESSAGE:
            offsets.append(pos)
        elif op == _SCHEMA:
            scan.add_schema(_Cursor(data[pos + 9:stop], base))
        elif op == _CHANNEL:
            scan.add_channel(_Cursor(data[pos + 9:stop], base))
        pos = stop
    scan.add_messages(data, offsets, base)
    if complete and pos != size:
        raise _Corrupt("chunk records do not fill the chunk", base)


def _inflate(compression: str, data: bytes, size: int, at: int, complete: bool = False) -> bytes:
    """Decompress a chunk's records (up to ``size`` bytes; a cut zstd frame yields its readable prefix).
    A ``complete`` zstd chunk is inflated in one call (a quarter faster than streaming), streamed
    only when that fails (the streamed result and its checks then say why)."""
    if size > _MAX_CHUNK_BYTES:
        raise _Corrupt(f"chunk claims {size} uncompressed bytes", at)
    if compression == "":
        return data[:size]
    if compression == "zstd":
        if complete:
            try:
                return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
            except zstandard.ZstdError:
                pass
        try:
            return zstandard.ZstdDecompressor().decompressobj().decompress(data)
        except zstandard.ZstdError as exc:
            raise _Corrupt(f"zstd: {exc}", at) from None
    if compression == "lz4":
        import lz4.frame

        try:
            return lz4.frame.decompress(data)
        except RuntimeError as exc:
            raise _Corrupt(f"lz4: {exc}", at) from None
    raise _Corrupt(f"unsupported chunk compression {compression!r}", at)


def _read_chunk(scan: _Scan, body: bytes, at: int, complete: bool, hint: np.ndarray | None = None) -> None:
    """A Chunk record (``body`` may be cut short when ``complete`` is False)."""
    _walk_chunk(scan, _chunk_data(body, at, complete), at, complete, hint)


def _index_hint(mm, pos: int, size: int) -> np.ndarray | None:
    """The record offsets listed by the MessageIndex records that follow a chunk ending at
    ``pos`` (None when there are none or they are malformed; the walk checks them anyway)."""
    parts = []
    while pos + 9 <= size:
        op, length = _RECORD_HEAD.unpack(mm[pos:pos + 9])
        if op != _MESSAGE_INDEX or pos + 9 + length > size or length < 6:
            break
        body = mm[pos + 9:pos + 9 + length]
        n = struct.unpack_from("<I", body, 2)[0]
        if n % 16 or 6 + n > len(body):
            return None
        parts.append(np.frombuffer(body, _INDEX_ENTRY, n // 16, 6)["offset"])
        pos += 9 + length
    return np.concatenate(parts) if parts else None


def _chunk_data(body: bytes, at: int, complete: bool) -> bytes:
    """The records of a Chunk record at file offset ``at``, inflated and checked (length, CRC)."""
    c = _Cursor(body, at + 9)
    _start, _end, size, crc = c.take("<QQQI")
    compression = c.raw(c.take("<I")).decode("utf-8", "replace")
    declared = c.take("<Q")
    data = body[c.pos:c.pos + declared]
    if complete and len(data) != declared:
        raise _Corrupt("chunk data length beyond its record", at)
    records = _inflate(compression, data, size, at, complete)
    if complete:
        if len(records) != size:
            raise _Corrupt(f"chunk inflates to {len(records)} bytes, header says {size}", at)
        if crc and zlib.crc32(records) != crc:
            raise _Corrupt("chunk CRC mismatch", at)
    return records


def _read_record(scan: _Scan, op: int, body: bytes, at: int, hint: np.ndarray | None = None) -> None:
    """One complete top-level record of the data section (``hint``: a chunk's :func:`_index_hint`)."""
    if op == _CHUNK:
        _read_chunk(scan, body, at, complete=True, hint=hint)
    elif op == _MESSAGE:
        _walk_chunk(scan, _RECORD_HEAD.pack(op, len(body)) + body, at, complete=True)
    elif op == _SCHEMA:
        scan.add_schema(_Cursor(body, at + 9))
    elif op == _CHANNEL:
        scan.add_channel(_Cursor(body, at + 9))
    elif op == _METADATA:
        c = _Cursor(body, at + 9)
        name = c.text()
        scan.metadata[name] = c.string_map()
    elif op == _HEADER:
        raise _Corrupt("second header record", at)


def _scan_records(scan: _Scan, mm, size: int) -> None:
    """Walk the top-level records; raises _Corrupt at the first structural problem."""
    if size < len(MAGIC) or mm[:len(MAGIC)] != MAGIC:
        if MAGIC.startswith(mm[:size]):
            raise _Corrupt("file ends inside the MCAP magic", size)
        raise SensorDataError(f"{scan.path}: not an MCAP file (bad magic bytes)")
    pos, crc, in_data = len(MAGIC), zlib.crc32(MAGIC), True
    while True:
        if pos + 9 > size:
            raise _Corrupt("file ends before the footer", pos)
        op, length = _RECORD_HEAD.unpack(mm[pos:pos + 9])
        stop = pos + 9 + length
        if pos == len(MAGIC) and op != _HEADER:
            raise _Corrupt("first record is not a header", pos)
        if stop > size:
            if op == _CHUNK and in_data:
                _read_chunk(scan, mm[pos + 9:size], pos, complete=False)
            what = _RECORD_NAMES.get(op, f"opcode {op}")
            raise _Corrupt(f"{what} record of {length} bytes cut by the end of the file", pos)
        body = mm[pos + 9:stop]
        if op == _FOOTER:
            _check_footer(mm, size, pos, stop, body)
            return
        if op == _HEADER and pos == len(MAGIC):
            c = _Cursor(body, pos + 9)
            c.text()
            scan.library = c.text()
        elif in_data and op == _DATA_END:
            expected = _Cursor(body, pos + 9).take("<I")
            if expected and expected != crc:
                raise _Corrupt("data section CRC mismatch", pos)
            in_data = False
        elif in_data:
            _read_record(scan, op, body, pos, _index_hint(mm, stop, size) if op == _CHUNK else None)
            scan.note_record(op, pos, stop)
        if in_data:
            crc = zlib.crc32(body, zlib.crc32(mm[pos:pos + 9], crc))
        pos = stop


class _FileBytes:
    """Byte ranges of an open file read on demand (``data[a:b]`` -> bytes, clipped to the file):
    a scan holds one record at a time. (A memory map of the whole file would keep every page it
    touched resident: the read's peak memory would grow by the file's size.)"""

    def __init__(self, fd: int, size: int):
        self.fd, self.size = fd, size

    def __getitem__(self, where: slice) -> bytes:
        start = where.start or 0
        stop = self.size if where.stop is None else min(where.stop, self.size)
        return os.pread(self.fd, stop - start, start) if stop > start else b""


def _check_footer(mm, size: int, pos: int, stop: int, body: bytes) -> None:
    """The footer must be followed by the closing magic; its summary CRC must match."""
    summary_start, summary_offset_start, summary_crc = _Cursor(body, pos + 9).take("<QQI")
    if mm[stop:size] != MAGIC:
        raise _Corrupt("footer not followed by the closing magic", stop)
    if summary_crc:
        start = summary_start if summary_start else pos
        if not len(MAGIC) <= start <= pos:
            raise _Corrupt("footer points outside the file", pos)
        computed = zlib.crc32(mm[pos:pos + 9 + 16], zlib.crc32(mm[start:pos]))
        if computed != summary_crc:
            raise _Corrupt("summary CRC mismatch", pos)


def _scan_file(path: Path, allow_truncated: bool, wanted: set[str] | None,
               cdr_types: dict[str, str] | None = None) -> _Scan:
    """Read the file's structure; strict unless ``allow_truncated`` (then keep the readable prefix).
    The caller closes ``scan.decoder`` (here on error). ``cdr_types``: a ROS 2 bag's topics to
    read (topic -> message type; then ``wanted`` is their set)."""
    scan = _Scan(str(path), wanted, cdr_types=cdr_types)
    try:
        _scan_into(scan, path, allow_truncated)
    except BaseException:
        scan.decoder.close()
        raise
    return scan


def _scan_into(scan: _Scan, path: Path, allow_truncated: bool) -> None:
    try:
        with open(path, "rb") as fh:
            scan.stat = os.fstat(fh.fileno())
            size = fh.seek(0, io.SEEK_END)
            if size == 0:
                raise _Corrupt("empty file", 0)
            _scan_records(scan, _FileBytes(fh.fileno(), size), size)
    except FileNotFoundError:
        raise SensorDataError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise SensorDataError(f"{path}: is a directory, not an MCAP file") from None
    except PermissionError:
        raise SensorDataError(f"{path}: permission denied") from None
    except OSError as exc:
        raise SensorDataError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except _Corrupt as exc:
        scan.problem = exc
    except (SensorDataError, MemoryError):
        raise
    except Exception as exc:  # any other parse failure on a damaged file is a structural problem
        scan.problem = _Corrupt(f"{type(exc).__name__}: {exc}", -1)
    if scan.problem is not None and not allow_truncated:
        where = f" at byte {scan.problem.at}" if scan.problem.at >= 0 else ""
        raise SensorDataError(f"{path}: truncated or corrupt MCAP{where} ({scan.problem.reason}); "
                              f"{scan.readable()} before it; set inputs.allow_truncated: true in the pipeline YAML to run on them")


# =================================================================================================
# reading: message content
# =================================================================================================

class _Bad(Exception):
    """Internal: record ``index`` of a topic is invalid for ``reason``."""

    def __init__(self, index: int, reason: str):
        super().__init__(reason)
        self.index, self.reason = index, reason


def _value_problem(v, path: str, kind: str) -> str | None:
    """Why value ``v`` of field ``path`` is invalid for ``kind``, or None."""
    if kind == "str":
        return None if type(v) is str else f"{path} is not a string"
    if kind == "float9":
        if type(v) is not list or len(v) != 9:
            return f"{path} is not an array of 9 numbers"
        return next((p for j, e in enumerate(v) if (p := _value_problem(e, f"{path}[{j}]", "float"))), None)
    if type(v) not in (int, float):
        return f"{path} is not a number"
    if type(v) is int and abs(v) >= 2**63:
        return f"{path} is out of range"
    if v != v:
        return f"{path} is NaN"
    if v in (float("inf"), float("-inf")):
        return f"{path} is infinite"
    if kind == "int" and v != int(v):
        return f"{path} is not an integer"
    return None


def _scan_field(msgs: list, path: str, kind: str) -> _Bad:
    """The first message whose field ``path`` is missing or invalid (the slow, exact path)."""
    keys = path.split(".")
    for i, m in enumerate(msgs):
        v = m
        for key in keys:
            if type(v) is not dict or key not in v:
                return _Bad(i, f"missing field {path}")
            v = v[key]
        problem = _value_problem(v, path, kind)
        if problem:
            return _Bad(i, problem)
    return _Bad(len(msgs), f"{path} is unreadable")


def _json_field(msgs: list, path: str, kind: str) -> np.ndarray | _Bad:
    """Field ``path`` of every message as an array ((N,), or (N, 9) for float9), or the first bad record."""
    try:
        values = msgs
        for key in path.split("."):
            values = list(map(operator.itemgetter(key), values))
    except (KeyError, TypeError, IndexError):
        return _scan_field(msgs, path, kind)
    types = set(map(type, values))
    try:
        if kind == "str" and types <= {str}:
            return np.array(values, dtype=object)
        if kind == "float9" and types <= {list} and set(map(len, values)) <= {9} and set(
                map(type, itertools.chain.from_iterable(values))) <= {int, float}:
            array = np.array(values, dtype=np.float64).reshape(len(values), 9)
        elif kind in ("float", "int") and types <= {int, float}:
            array = np.array(values, dtype=np.float64)
        else:
            return _scan_field(msgs, path, kind)
    except OverflowError:
        return _scan_field(msgs, path, kind)
    finite = np.isfinite(array)
    rows = ~(finite.all(axis=1) if array.ndim == 2 else finite)
    if kind == "int":
        rows |= np.isfinite(array) & ((array != np.rint(array)) | (np.abs(array) >= 2**63))
    if rows.any():
        i = int(np.argmax(rows))
        return _Bad(i, _value_problem(values[i], path, kind) or f"{path} is out of range")
    if kind == "int":
        return np.array(values, dtype=np.int64) if types <= {int} else array.astype(np.int64)
    return array


def _json_messages(payloads: list[bytes]) -> list[dict]:
    """Decode payloads as JSON objects (one joined parse; per message only to find the first bad one)."""
    try:
        msgs = json.loads(b"[" + b",".join(payloads) + b"]")
        if len(msgs) == len(payloads) and all(type(m) is dict for m in msgs):
            return msgs
    except (ValueError, RecursionError):
        pass
    msgs = []
    for i, raw in enumerate(payloads):
        try:
            m = json.loads(raw)
        except UnicodeDecodeError:
            raise _Bad(i, "message is not UTF-8 text") from None
        except json.JSONDecodeError as exc:
            raise _Bad(i, f"invalid JSON ({exc.msg} at character {exc.pos})") from None
        except (ValueError, RecursionError) as exc:
            raise _Bad(i, f"invalid JSON ({type(exc).__name__})") from None
        if type(m) is not dict:
            raise _Bad(i, "message is not a JSON object")
        msgs.append(m)
    return msgs


def _decode_fields(payloads: list[bytes], schema: str) -> dict[str, np.ndarray]:
    """Required fields of every message; raises _Bad for the first invalid record."""
    if not payloads:
        empty = {"float": np.zeros(0), "int": np.zeros(0, np.int64), "str": np.zeros(0, object),
                 "float9": np.zeros((0, 9))}
        return {path: empty[kind] for path, kind in schemas.FIELDS[schema]}
    msgs = _json_messages(payloads)
    out, first = {}, None
    for path, kind in schemas.FIELDS[schema]:
        result = _json_field(msgs, path, kind)
        if isinstance(result, _Bad):
            first = result if first is None or result.index < first.index else first
        else:
            out[path] = result
    if first is not None:
        raise first
    return out


def _check_times(ns: np.ndarray) -> np.ndarray:
    """``t_s`` (N,) [s] from log_time (N,) uint64 [ns]; raises _Bad unless strictly increasing."""
    too_big = ns > np.uint64(_INT64_MAX)
    if too_big.any():
        raise _Bad(int(np.argmax(too_big)), f"log_time {int(ns[np.argmax(too_big)])} ns out of range")
    t = ns.astype(np.int64)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        what = "duplicated" if t[i] == t[i - 1] else "going backwards"
        raise _Bad(i, f"log_time {what} ({int(t[i])} ns after {int(t[i - 1])} ns)")
    return t / 1e9


def _channel_schema(scan: _Scan, ch: _RawChannel) -> str:
    """The channel's schema name after checking topic, schema and encoding; raises _Bad(0, ...).
    A trackfusion topic of :data:`CDR_TOPICS` may carry its ROS 2 type (CDR) instead; in a ROS 2
    bag (``scan.cdr_types``) a topic read must carry the type it was chosen for."""
    name = scan.schemas.get(ch.schema_id, ("", ""))[0]
    if scan.cdr_types is not None:
        msgtype = scan.cdr_types[ch.topic]
        if name != msgtype:
            raise _Bad(0, f"schema {name!r} is not {msgtype!r}")
        if ch.encoding != "cdr":
            raise _Bad(0, f"message encoding {ch.encoding!r} is not 'cdr'")
        return msgtype
    expected = schemas.schema_for_topic(ch.topic)
    if expected is None:
        raise _Bad(0, "unknown topic")
    if CDR_TOPICS.get(ch.topic) == name:
        if ch.encoding != "cdr":
            raise _Bad(0, f"message encoding {ch.encoding!r} is not 'cdr'")
        return name
    if not name:
        raise _Bad(0, f"channel has no schema (expected {expected!r})")
    if name != expected:
        also = f" or {CDR_TOPICS[ch.topic]!r}" if ch.topic in CDR_TOPICS else ""
        raise _Bad(0, f"unknown schema {name!r} (expected {expected!r}{also})")
    if ch.encoding != "json":
        raise _Bad(0, f"message encoding {ch.encoding!r} is not 'json'")
    return name


def _sensor_arrays(schema: str, f: dict[str, np.ndarray]) -> list[np.ndarray]:
    """The value arrays of a topic's sensor dataclass (the fields after ``t_s``, in their final
    shapes) from its decoded fields ``f``."""
    if schema == schemas.IMU:
        return [np.column_stack([f[f"{v}.{a}"] for a in "xyz"]).reshape(-1, 3)
                for v in ("angular_velocity", "linear_acceleration")]
    if schema == schemas.LOCATION_FIX:
        return [f["latitude"], f["longitude"], f["altitude"], f["position_covariance"].reshape(-1, 3, 3),
                f["fix_quality"]]
    return [f[path] for path, _ in schemas.FIELDS[schema]]


_SENSOR_TYPES = {schemas.IMU: ImuData, schemas.ODOMETER: OdometerData, schemas.LOCATION_FIX: GnssData,
                 schemas.INCLINATION: InclinometerData, schemas.GAUGE: GaugeData}


def _sensor(topic: str, schema: str, t_s: np.ndarray, arrays: list[np.ndarray]):
    """The sensor dataclass of one decoded topic (``arrays``: :func:`_sensor_arrays`, or for a
    CDR topic the stamp and the :data:`cdr.WANTED` fields)."""
    if schema == CDR_IMU:
        return ImuData(t_s, arrays[2], arrays[3])
    if schema == CDR_ODOMETER:
        return OdometerData(t_s, arrays[2], arrays[3])
    if schema == schemas.POLAR:
        return TotalStationData(topic[len(schemas.TOTAL_STATION_PREFIX):], t_s, *arrays)
    return _SENSOR_TYPES[schema](t_s, *arrays)


def _store(log: SensorLog, topic: str, data) -> None:
    if isinstance(data, TotalStationData):
        log.total_stations[data.station_id] = data
    else:
        setattr(log, topic[1:], data)


def _decode_metadata(path: Path, records: dict[str, dict[str, str]]) -> dict[str, Any]:
    """``{"json": text}`` records -> the decoded value; any other record stays a string map."""
    out: dict[str, Any] = {}
    for name, data in records.items():
        if set(data) != {"json"}:
            out[name] = dict(data)
            continue
        try:
            out[name] = json.loads(data["json"])
        except (ValueError, RecursionError):
            raise SensorDataError(f"{path}: metadata record {name!r}: invalid JSON in key 'json'") from None
    return out


def read_log(path: str | Path, topics: Iterable[str] | None = None, allow_truncated: bool = False) -> SensorLog:
    """Read and check a raw MCAP log (docs/log_format.md).

    path: the ``.mcap`` file (never modified). topics: decode only these topics (e.g.
    ``["/imu", "/odometer"]``; default all); every channel's topic and schema are still checked and
    a truncated file is still detected. allow_truncated: when the file is cut short or corrupt,
    return the records readable before the damage (whole records of complete chunks plus the
    complete records of a cut chunk) instead of raising.

    Returns a :class:`SensorLog` (times ``t_s`` = log_time / 1e9 on each sensor's clock; metadata
    records decoded from their ``json`` key). Raises :class:`SensorDataError` with one line
    naming the file, topic and record index for the first invalid record, and for a missing,
    truncated or corrupt file (then saying how many records were readable).
    """
    if isinstance(topics, str):
        topics = [topics]
    return _read(Path(path), None if topics is None else set(topics), allow_truncated)[0]


def read_log_with_damage(path: str | Path, topics: Iterable[str] | None = None, allow_truncated: bool = False
                         ) -> tuple[SensorLog, dict[str, Any] | None]:
    """:func:`read_log`, also saying what was lost when ``allow_truncated`` kept the readable part
    of a damaged file: ``{"file", "byte", "reason", "records_readable": {topic: count}}`` (``byte``
    -1 when unknown), or None for an intact file."""
    if isinstance(topics, str):
        topics = [topics]
    log, scan = _read(Path(path), None if topics is None else set(topics), allow_truncated)
    if scan.problem is None:
        return log, None
    return log, {"file": str(path), "byte": int(scan.problem.at), "reason": scan.problem.reason,
                 "records_readable": {c.topic: int(c.count) for c in scan.channels.values() if c.count}}


def _decode_channel(scan: _Scan, ch: _RawChannel, schema: str):
    """The sensor data of one channel; raises _Bad for its first invalid record (time or content)."""
    ns = np.concatenate(ch.times) if ch.times else np.zeros(0, np.uint64)
    problems, t_s, arrays = [], None, None
    try:
        t_s = _check_times(ns)
    except _Bad as bad:
        problems.append(bad)
    try:
        arrays = ch.arrays(schema)
    except _Bad as bad:
        problems.append(bad)
    if problems:
        raise min(problems, key=lambda b: b.index)
    return _sensor(ch.topic, schema, t_s, arrays)


def channel_types(path: str | Path) -> dict[str, tuple[str, int]]:
    """topic -> (schema name, message count) of an MCAP file, from its summary (read with the
    ``mcap`` library); a file without a summary is scanned (every chunk checked, nothing decoded)."""
    p = Path(path)
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    summary = None
    try:
        with open(p, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except (McapError, ValueError, struct.error, EOFError):
        summary = None
    except OSError as exc:
        raise SensorDataError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if summary is not None and summary.statistics is not None:
        counts = summary.statistics.channel_message_counts
        return {c.topic: (summary.schemas[c.schema_id].name if c.schema_id in summary.schemas else "",
                          int(counts.get(cid, 0))) for cid, c in summary.channels.items()}
    scan = _scan_file(p, True, set())
    scan.decoder.close()
    return {c.topic: (scan.schemas.get(c.schema_id, ("", ""))[0], c.count) for c in scan.channels.values()}


def read_cdr_topics(path: str | Path, topics: dict[str, str], allow_truncated: bool = False
                    ) -> tuple[dict[str, tuple[np.ndarray, dict[str, np.ndarray]]], dict[str, Any] | None]:
    """The CDR topics of a ROS 2 MCAP bag: topic -> (log times (N,) uint64 [ns], the decoded
    :data:`cdr.WANTED` fields of its message type), and the damage report (as
    :func:`read_log_with_damage`). ``topics``: topic -> message type. The whole file is checked
    (records, CRCs); other topics are not decoded. Raises SensorDataError naming the topic and
    record (0-based in the topic) for the first bad record."""
    p = Path(path)
    scan = _scan_file(p, allow_truncated, set(topics), cdr_types=dict(topics))
    out = {}
    try:
        for ch in scan.channels.values():
            if ch.topic not in topics:
                continue
            try:
                msgtype = _channel_schema(scan, ch)
                ns = np.concatenate(ch.times) if ch.times else np.zeros(0, np.uint64)
                out[ch.topic] = (ns, dict(zip(cdr.WANTED[msgtype], ch.arrays(msgtype))))
            except _Bad as bad:
                raise SensorDataError(f"{p}: {ch.topic} record {bad.index}: {bad.reason}") from None
            ch.payloads, ch.times, ch.batches = [], [], []
    finally:
        scan.decoder.close()
    for topic in topics:
        out.setdefault(topic, (np.zeros(0, np.uint64), {}))
    damage = None if scan.problem is None else {
        "file": str(path), "byte": int(scan.problem.at), "reason": scan.problem.reason,
        "records_readable": {c.topic: int(c.count) for c in scan.channels.values() if c.count}}
    return out, damage


#: the topics fused.mcap adds to the raw log's (sensors/fused.py): summarised by inspect, not read
FUSED_TOPIC_PREFIXES = ("/trajectory/", "/track/")


def _read(p: Path, wanted: set[str] | None, allow_truncated: bool,
          others: list[tuple[str, str, np.ndarray]] | None = None) -> tuple[SensorLog, _Scan]:
    """read_log, also returning the file's structural scan. With ``others`` (a list), fused.mcap's
    own topics (FUSED_TOPIC_PREFIXES, with a ``foxglove.*`` schema: trajectory and rails) are
    not refused: each is appended as (topic, schema name, sorted log times [s]), its payloads not
    decoded. Any other unknown topic is refused as by read_log."""
    scan = _scan_file(p, allow_truncated, wanted)
    log = SensorLog()
    seen: dict[str, int] = {}
    try:
        for cid, ch in scan.channels.items():
            try:
                schema = scan.schemas.get(ch.schema_id, ("", ""))[0]
                if others is not None and ch.topic.startswith(FUSED_TOPIC_PREFIXES) and schema.startswith("foxglove."):
                    ns = np.sort(np.concatenate(ch.times)) if ch.times else np.zeros(0, np.uint64)
                    others.append((ch.topic, schema, ns / 1e9))
                    ch.payloads, ch.times, ch.batches = [], [], []
                    continue
                schema = _channel_schema(scan, ch)
                if ch.topic in seen:
                    raise _Bad(0, f"topic on two channels (ids {seen[ch.topic]} and {cid})")
                seen[ch.topic] = cid
                if wanted is None or ch.topic in wanted:
                    _store(log, ch.topic, _decode_channel(scan, ch, schema))
            except _Bad as bad:
                raise SensorDataError(f"{p}: {ch.topic} record {bad.index}: {bad.reason}") from None
            ch.payloads, ch.times, ch.batches = [], [], []
    finally:
        scan.decoder.close()
    log.metadata = _decode_metadata(p, scan.metadata)
    log.source = scan.source()
    return log, scan


# =================================================================================================
# inspect
# =================================================================================================

GAP_FACTOR = 3.0


@dataclass
class TopicSummary:
    """One topic of a log.

    count: messages; rate_hz: mean rate (count - 1) / span [Hz]; first_s, last_s, span_s: time of
    the first and last message and their difference [s, on the topic's clock]; median_interval_s:
    median sample interval [s]; gap_count: intervals longer than GAP_FACTOR x the median interval;
    largest_gap_s: the longest interval [s] (0 without gaps); largest_gap_at_s: where it starts [s].
    """

    topic: str
    schema: str
    clock: str
    count: int
    rate_hz: float
    first_s: float
    last_s: float
    span_s: float
    median_interval_s: float
    gap_count: int
    largest_gap_s: float
    largest_gap_at_s: float


@dataclass
class LogSummary:
    """What ``trackfusion inspect`` prints: the file, its writer, its topics and metadata record names."""

    path: Path
    size_bytes: int
    library: str
    topics: list[TopicSummary]
    metadata: list[str]

    def format(self) -> str:
        """A readable table: one row per topic, then the metadata record names."""
        total = sum(t.count for t in self.topics)
        lines = [f"{self.path}: {self.size_bytes / 1e6:.2f} MB, {total} messages on {len(self.topics)} topics"
                 f" (written by {self.library or 'unknown'})",
                 f"{'topic':24s} {'schema':38s} {'clock':7s} {'count':>9s} {'rate Hz':>9s} {'first s':>11s} "
                 f"{'last s':>11s} {'span s':>10s} {'gaps':>5s} {'max gap s':>10s} {'at s':>11s}"]
        for t in self.topics:
            lines.append(f"{t.topic:24s} {t.schema:38s} {t.clock:7s} {t.count:9d} {t.rate_hz:9.3f} "
                         f"{t.first_s:11.3f} {t.last_s:11.3f} {t.span_s:10.3f} {t.gap_count:5d} "
                         f"{t.largest_gap_s:10.3f} {t.largest_gap_at_s:11.3f}")
        lines.append("metadata records: " + (", ".join(self.metadata) or "none"))
        return "\n".join(lines)


def summarise_times(topic: str, schema: str, t_s: np.ndarray) -> TopicSummary:
    """Count, mean rate, span and gaps of one topic's times ``t_s`` (N,) [s], strictly increasing."""
    t = np.asarray(t_s, dtype=float)
    clock = "station" if topic.startswith(schemas.TOTAL_STATION_PREFIX) else "imu"
    if t.size == 0:
        return TopicSummary(topic, schema, clock, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0)
    span = float(t[-1] - t[0])
    dt = np.diff(t)
    median = float(np.median(dt)) if dt.size else 0.0
    long = dt > GAP_FACTOR * median if dt.size else np.zeros(0, bool)
    k = int(np.argmax(dt)) if long.any() else -1
    return TopicSummary(topic, schema, clock, int(t.size), (t.size - 1) / span if span > 0 else 0.0,
                        float(t[0]), float(t[-1]), span, median, int(long.sum()),
                        float(dt[k]) if k >= 0 else 0.0, float(t[k]) if k >= 0 else 0.0)


def inspect_log(path: str | Path) -> LogSummary:
    """Check a log fully (as :func:`read_log`, strict) and summarise it per topic. fused.mcap's own
    topics (FUSED_TOPIC_PREFIXES: trajectory, fixes and rails, ``foxglove.*`` schemas) are
    summarised from their log times, after the sensor topics, without decoding their payloads.
    A ROS 2 bag is summarised by :func:`.ros2.inspect_bag` (either: :func:`.ros2.inspect_log_or_bag`)."""
    p = Path(path)
    others: list[tuple[str, str, np.ndarray]] = []
    log, scan = _read(p, None, allow_truncated=False, others=others)
    entries: list[tuple[str, str, np.ndarray]] = []
    written = {c.topic: scan.schemas.get(c.schema_id, ("", ""))[0] for c in scan.channels.values()}
    for topic, schema in schemas.TOPICS.items():
        data = getattr(log, topic[1:])
        if data is not None:
            entries.append((topic, written.get(topic, schema), data.t_s))
    for sid, d in sorted(log.total_stations.items()):
        entries.append((schemas.TOTAL_STATION_PREFIX + sid, schemas.TOTAL_STATION_SCHEMA, d.t_s))
    entries.extend(sorted(others))
    return LogSummary(p, p.stat().st_size, scan.library, [summarise_times(*e) for e in entries], sorted(log.metadata))
