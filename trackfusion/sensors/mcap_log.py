"""The raw survey log: MCAP files with JSON-encoded messages (docs/log_format.md).

``write_log`` writes a :class:`SensorLog` (atomically, byte-identical for identical
input); ``read_log`` reads one back and checks every record: known topic and
schema, decodable JSON with the schema's fields, finite numbers, and
``log_time`` strictly increasing per topic. The first bad record raises a
:class:`SensorDataError` of one line naming the file, topic and record index
(0-based within its topic). A truncated or corrupt file raises an error that
says how many messages were readable; ``allow_truncated=True`` returns that
readable part instead. ``inspect_log`` summarises a log.

``log_time`` is integer nanoseconds of the recording sensor's clock:
``round(t_s * 1e9)``; reading gives ``t_s = log_time / 1e9``.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from ..errors import SensorDataError
from . import schemas
from .fileio import atomic_path
from .types import GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog, TotalStationData

LIBRARY = "trackfusion"
_GNSS_FRAME = "gnss_antenna"

# --- writing ---------------------------------------------------------------------------------------

_IMU_T = ('{"angular_velocity":{"x":%r,"y":%r,"z":%r},'
          '"linear_acceleration":{"x":%r,"y":%r,"z":%r}}')
_ODO_T = '{"distance_m":%r,"ticks":%d}'
_GNSS_T = ('{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"' + _GNSS_FRAME + '","latitude":%r,"longitude":%r,'
           '"altitude":%r,"position_covariance":[%r,%r,%r,%r,%r,%r,%r,%r,%r],'
           '"position_covariance_type":3,"fix_quality":%d}')
_INC_T = '{"roll_rad":%r,"pitch_rad":%r}'
_GAUGE_T = '{"gauge_m":%r}'


def _ns(t_s: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)


def _rows(*cols) -> list[tuple]:
    """Python-native rows (floats stay floats so ``%r`` gives their shortest exact repr)."""
    return list(zip(*[np.asarray(c).tolist() for c in cols]))


def _check_finite(name: str, *arrays) -> None:
    for a in arrays:
        if not np.all(np.isfinite(np.asarray(a, dtype=float))):
            raise SensorDataError(f"cannot write {name}: non-finite value")


def _payloads(log: SensorLog) -> list[tuple[str, str, np.ndarray, list[str]]]:
    """(topic, schema, log_time_ns (N,), JSON payloads) for every sensor present."""
    out = []
    if log.imu is not None:
        d = log.imu
        _check_finite("/imu", d.t_s, d.gyro_radps, d.accel_mps2)
        out.append(("/imu", "trackfusion.Imu", _ns(d.t_s),
                    [_IMU_T % r for r in _rows(*d.gyro_radps.T, *d.accel_mps2.T)]))
    if log.odometer is not None:
        d = log.odometer
        _check_finite("/odometer", d.t_s, d.distance_m)
        out.append(("/odometer", "trackfusion.Odometer", _ns(d.t_s),
                    [_ODO_T % r for r in _rows(d.distance_m, d.ticks.astype(np.int64))]))
    if log.gnss is not None:
        d = log.gnss
        _check_finite("/gnss", d.t_s, d.lat_deg, d.lon_deg, d.h_m, d.cov_enu_m2)
        ns = _ns(d.t_s)
        cov = d.cov_enu_m2.reshape(-1, 9)
        out.append(("/gnss", "foxglove.LocationFix", ns,
                    [_GNSS_T % r for r in _rows(ns // 10**9, ns % 10**9, d.lat_deg, d.lon_deg, d.h_m,
                                                 *cov.T, d.fix_quality.astype(np.int64))]))
    for sid in sorted(log.total_stations):
        d = log.total_stations[sid]
        topic = schemas.TOTAL_STATION_PREFIX + sid
        _check_finite(topic, d.t_s, d.horizontal_angle_rad, d.zenith_angle_rad, d.slope_distance_m)
        payloads = [json.dumps({"horizontal_angle_rad": h, "zenith_angle_rad": z, "slope_distance_m": s,
                                "prism_id": str(p)}, separators=(",", ":"))
                    for h, z, s, p in _rows(d.horizontal_angle_rad, d.zenith_angle_rad, d.slope_distance_m,
                                            d.prism_id)]
        out.append((topic, schemas.TOTAL_STATION_SCHEMA, _ns(d.t_s), payloads))
    if log.inclinometer is not None:
        d = log.inclinometer
        _check_finite("/inclinometer", d.t_s, d.roll_rad, d.pitch_rad)
        out.append(("/inclinometer", "trackfusion.Inclination", _ns(d.t_s), [_INC_T % r for r in _rows(d.roll_rad, d.pitch_rad)]))
    if log.gauge is not None:
        d = log.gauge
        _check_finite("/gauge", d.t_s, d.gauge_m)
        out.append(("/gauge", "trackfusion.Gauge", _ns(d.t_s), [_GAUGE_T % r for r in _rows(d.gauge_m)]))
    return out


def write_log(path: str | Path, log: SensorLog) -> None:
    """Write ``log`` as an MCAP file (zstd chunks), atomically and deterministically.

    Messages of all topics are interleaved in ``log_time`` order (ties: topic order).
    Each ``log.metadata`` entry becomes a metadata record of that name holding
    ``{"json": <the value as JSON text, keys sorted>}``.
    """
    topics = _payloads(log)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD, chunk_size=4 * 1024 * 1024)
        w.start(profile="", library=LIBRARY)
        schema_ids: dict[str, int] = {}
        channels, times, payloads = [], [], []
        for topic, schema, ns, data in topics:
            if schema not in schema_ids:
                schema_ids[schema] = w.register_schema(schema, "jsonschema", schemas.schema_bytes(schema))
            cid = w.register_channel(topic, "json", schema_ids[schema])
            channels.append(np.full(ns.size, cid, dtype=np.int64))
            times.append(ns)
            payloads.extend(data)
        if times:
            all_t = np.concatenate(times)
            all_c = np.concatenate(channels)
            order = np.lexsort((all_c, all_t))
            counters: dict[int, int] = {}
            for i, c, t in zip(order.tolist(), all_c[order].tolist(), all_t[order].tolist()):
                seq = counters.get(c, 0)
                counters[c] = seq + 1
                w.add_message(c, log_time=t, data=payloads[i].encode(), publish_time=t, sequence=seq)
        for name in sorted(log.metadata):
            w.add_metadata(name, {"json": json.dumps(log.metadata[name], sort_keys=True, allow_nan=False)})
        w.finish()


# --- reading ---------------------------------------------------------------------------------------

@dataclass
class _RawChannel:
    topic: str
    schema: str
    times: list[int] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)


def _scan(path: Path, allow_truncated: bool) -> tuple[dict[int, _RawChannel], dict[str, dict]]:
    """All messages grouped by channel, and the metadata; checks only the file's structure."""
    if not path.is_file():
        raise SensorDataError(f"{path}: file not found")
    schema_names: dict[int, str] = {}
    channels: dict[int, _RawChannel] = {}
    metadata: dict[str, dict] = {}
    n_messages = 0
    complete = False
    try:
        with open(path, "rb") as fh:
            for rec in StreamReader(io.BufferedReader(fh), validate_crcs=True).records:
                if isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is None:
                        raise SensorDataError(f"{path}: message {n_messages} refers to unknown channel {rec.channel_id}")
                    ch.times.append(rec.log_time)
                    ch.data.append(rec.data)
                    n_messages += 1
                elif isinstance(rec, Schema):
                    schema_names[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    if rec.id not in channels:
                        channels[rec.id] = _RawChannel(rec.topic, schema_names.get(rec.schema_id, ""))
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Footer):
                    complete = True
    except SensorDataError:
        raise
    except Exception as exc:  # the MCAP parser's own errors: truncation, corruption, bad CRC
        if not allow_truncated:
            raise SensorDataError(f"{path}: truncated or corrupt MCAP ({type(exc).__name__}) after {n_messages} "
                                  "readable messages; read_log(..., allow_truncated=True) keeps them") from None
        complete = True
    if not complete and not allow_truncated:
        raise SensorDataError(f"{path}: truncated MCAP (no footer) after {n_messages} readable messages; "
                              "read_log(..., allow_truncated=True) keeps them")
    return channels, metadata


def _get(d, path: str):
    for part in path.split("."):
        d = d[int(part)] if isinstance(d, list) else d[part]
    return d


def _decode(path: Path, ch: _RawChannel) -> list:
    try:
        msgs = json.loads(b"[" + b",".join(ch.data) + b"]")
    except (ValueError, UnicodeDecodeError):
        msgs = None
    if msgs is None or any(not isinstance(m, dict) for m in msgs):
        for i, raw in enumerate(ch.data):
            try:
                if not isinstance(json.loads(raw), dict):
                    raise ValueError("not a JSON object")
            except (ValueError, UnicodeDecodeError) as exc:
                raise SensorDataError(f"{path}: {ch.topic} record {i}: invalid JSON ({exc})") from None
    return msgs


def _field(path: Path, ch: _RawChannel, msgs: list, name: str) -> np.ndarray:
    try:
        values = np.array([_get(m, name) for m in msgs], dtype=float)
        if values.ndim != 1:
            raise TypeError
    except (KeyError, IndexError, TypeError, ValueError):
        for i, m in enumerate(msgs):
            try:
                v = _get(m, name)
            except (KeyError, IndexError, TypeError):
                raise SensorDataError(f"{path}: {ch.topic} record {i}: missing field {name}") from None
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise SensorDataError(f"{path}: {ch.topic} record {i}: {name} is not a number") from None
        raise SensorDataError(f"{path}: {ch.topic}: unreadable field {name}") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise SensorDataError(f"{path}: {ch.topic} record {bad[0]}: {name} is {values[bad[0]]}")
    return values


def _check_channel(path: Path, ch: _RawChannel) -> np.ndarray:
    """Schema and time checks; returns the times [s]."""
    expected = schemas.schema_for_topic(ch.topic)
    if expected is None:
        raise SensorDataError(f"{path}: {ch.topic} record 0: unknown topic")
    if ch.schema != expected:
        raise SensorDataError(f"{path}: {ch.topic} record 0: unknown schema {ch.schema!r} (expected {expected!r})")
    ns = np.array(ch.times, dtype=np.int64)
    back = np.flatnonzero(np.diff(ns) <= 0)
    if back.size:
        i = back[0] + 1
        what = "duplicated" if ns[i] == ns[i - 1] else "going backwards"
        raise SensorDataError(f"{path}: {ch.topic} record {i}: log_time {what} ({ns[i]} ns after {ns[i - 1]} ns)")
    return ns / 1e9


def read_log(path: str | Path, topics: list[str] | None = None, allow_truncated: bool = False) -> SensorLog:
    """Read and check a raw log; ``topics`` limits which topics are decoded (default: all).

    Raises :class:`SensorDataError` (one line: file, topic, record index) on the first bad record.
    """
    p = Path(path)
    channels, metadata = _scan(p, allow_truncated)
    log = SensorLog()
    for ch in channels.values():
        t = _check_channel(p, ch)
        if topics is not None and ch.topic not in topics:
            continue
        msgs = _decode(p, ch)
        cols = {name: _field(p, ch, msgs, name) for name in schemas.FIELDS[ch.schema]}
        _store(log, ch, t, cols, msgs, p)
    for name, data in metadata.items():
        try:
            log.metadata[name] = json.loads(data["json"]) if set(data) == {"json"} else data
        except ValueError:
            raise SensorDataError(f"{p}: metadata {name!r}: invalid JSON") from None
    return log


def _store(log: SensorLog, ch: _RawChannel, t: np.ndarray, c: dict, msgs: list, p: Path) -> None:
    s = ch.schema
    if s == "trackfusion.Imu":
        log.imu = ImuData(t, np.column_stack([c[f"angular_velocity.{a}"] for a in "xyz"]),
                          np.column_stack([c[f"linear_acceleration.{a}"] for a in "xyz"]))
    elif s == "trackfusion.Odometer":
        log.odometer = OdometerData(t, c["distance_m"], c["ticks"].astype(np.int64))
    elif s == "foxglove.LocationFix":
        cov = np.column_stack([c[f"position_covariance.{i}"] for i in range(9)]).reshape(-1, 3, 3)
        log.gnss = GnssData(t, c["latitude"], c["longitude"], c["altitude"], cov, c["fix_quality"].astype(np.int64))
    elif s == schemas.TOTAL_STATION_SCHEMA:
        sid = ch.topic[len(schemas.TOTAL_STATION_PREFIX):]
        prism = np.array([str(m.get("prism_id", "")) for m in msgs], dtype=object)
        log.total_stations[sid] = TotalStationData(sid, t, c["horizontal_angle_rad"], c["zenith_angle_rad"],
                                                   c["slope_distance_m"], prism)
    elif s == "trackfusion.Inclination":
        log.inclinometer = InclinometerData(t, c["roll_rad"], c["pitch_rad"])
    elif s == "trackfusion.Gauge":
        log.gauge = GaugeData(t, c["gauge_m"])


# --- inspect ---------------------------------------------------------------------------------------

@dataclass
class TopicSummary:
    """One topic: schema, message count, mean rate [Hz], first/last time and span [s], gaps
    (intervals longer than 3x the median interval: count, largest [s], where it starts [s])."""

    topic: str
    schema: str
    count: int
    rate_hz: float
    first_s: float
    last_s: float
    span_s: float
    gaps: int
    largest_gap_s: float
    largest_gap_at_s: float


@dataclass
class LogSummary:
    """What ``trackfusion inspect`` prints: the file, its topics and metadata record names."""

    path: Path
    size_bytes: int
    topics: list[TopicSummary]
    metadata: list[str]

    def format(self) -> str:
        """A readable table."""
        lines = [f"{self.path}: {self.size_bytes / 1e6:.1f} MB, {len(self.topics)} topics",
                 f"{'topic':24s} {'schema':30s} {'count':>9s} {'rate Hz':>8s} {'first s':>10s} {'last s':>10s} "
                 f"{'span s':>9s} {'gaps':>5s} {'max gap s':>9s} {'at s':>9s}"]
        for t in self.topics:
            lines.append(f"{t.topic:24s} {t.schema:30s} {t.count:9d} {t.rate_hz:8.2f} {t.first_s:10.3f} "
                         f"{t.last_s:10.3f} {t.span_s:9.3f} {t.gaps:5d} {t.largest_gap_s:9.3f} "
                         f"{t.largest_gap_at_s:9.3f}")
        lines.append("metadata: " + (", ".join(self.metadata) or "none"))
        return "\n".join(lines)


def _topic_summary(topic: str, schema: str, t: np.ndarray) -> TopicSummary:
    span = float(t[-1] - t[0]) if t.size else 0.0
    dt = np.diff(t)
    if dt.size:
        long = dt > 3 * np.median(dt)
        k = int(np.argmax(dt))
        gaps, largest, at = int(long.sum()), (float(dt[k]) if long.any() else 0.0), (float(t[k]) if long.any() else 0.0)
    else:
        gaps, largest, at = 0, 0.0, 0.0
    rate = (t.size - 1) / span if span > 0 else 0.0
    return TopicSummary(topic, schema, int(t.size), rate, float(t[0]) if t.size else 0.0,
                        float(t[-1]) if t.size else 0.0, span, gaps, largest, at)


def inspect_log(path: str | Path) -> LogSummary:
    """Check a log fully (as :func:`read_log`) and summarise it per topic."""
    p = Path(path)
    log = read_log(p)
    entries: list[tuple[str, str, np.ndarray]] = []
    for topic, schema in schemas.TOPICS.items():
        data = getattr(log, topic[1:], None)
        if data is not None:
            entries.append((topic, schema, data.t_s))
    for sid, d in sorted(log.total_stations.items()):
        entries.append((schemas.TOTAL_STATION_PREFIX + sid, schemas.TOTAL_STATION_SCHEMA, d.t_s))
    return LogSummary(p, p.stat().st_size, [_topic_summary(*e) for e in entries], sorted(log.metadata))
