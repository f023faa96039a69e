"""ROS 2 bags as survey input (docs/log_format.md, "ROS 2 bags").

A bag is an MCAP file (rosbag2's default storage; MCAP header profile ``ros2``), a sqlite3
``.db3`` file, or a rosbag2 folder with ``metadata.yaml``. Three roles are read:

- ``imu``: ``sensor_msgs/msg/Imu`` (angular_velocity [rad/s], linear_acceleration [m/s^2];
  REP-103 body axes, x forward, y left, z up, unless ``inputs.imu_axes`` says otherwise);
- ``gnss``: ``sensor_msgs/msg/NavSatFix`` (position_covariance ENU [m^2]; ``status.status``
  -1 no fix, 0 fix, 1 SBAS, 2 GBAS -> fix quality 0, 1, 2, 4);
- ``odometer``: ``trackfusion_msgs/msg/OdometerDistance`` (header, ``float64 distance_m``,
  ``int64 ticks``) or ``nav_msgs/msg/Odometry`` (distance = the signed integral of
  ``twist.twist.linear.x`` over time, trapezoidal, from 0 at the first message; ticks 0).

Times are the messages' ``header.stamp`` (the sensor's acquisition time), or the bag's
receive times when every stamp of a topic is zero, counted from the whole second at or before
the first stamp of the topics read (``metadata["ros2_time_origin_ns"]``: ROS stamps are epoch
times, which float64 seconds would hold to ~0.2 us only). A topic is taken from ``inputs.topics``
or, when the pipeline names none for a role, found as the only topic of a supported type.
MCAP bags are read with trackfusion's MCAP reader (chunk CRCs, damage reports: sensors/mcap_log.py);
``.db3`` and folders through ``rosbags``. The payloads of a topic are decoded together
(:mod:`.cdr`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, SensorDataError
from . import cdr
from .types import GnssData, ImuData, OdometerData, SensorLog

IMU_TYPES = ("sensor_msgs/msg/Imu",)
GNSS_TYPES = ("sensor_msgs/msg/NavSatFix",)
ODOMETER_TYPES = ("trackfusion_msgs/msg/OdometerDistance", "nav_msgs/msg/Odometry")
#: role -> supported message types
ROLES: dict[str, tuple[str, ...]] = {"imu": IMU_TYPES, "gnss": GNSS_TYPES, "odometer": ODOMETER_TYPES}

#: NavSatStatus.status -> NMEA GGA fix quality (GBAS, i.e. RTK / ground augmentation, counts as RTK fixed)
_FIX_QUALITY = {-1: 0, 0: 1, 1: 2, 2: 4}


def is_bag(path: Path) -> bool:
    """True for a rosbag2 folder, a ``.db3`` file, or an MCAP file with the ``ros2`` profile."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    if path.suffix == ".db3":
        return True
    try:
        with open(path, "rb") as fh:
            from mcap.reader import make_reader
            return make_reader(fh).get_header().profile == "ros2"
    except Exception:  # not a readable MCAP file: the log reader says why
        return False


def _mcap_storage(path: Path) -> Path | None:
    """The MCAP file of a bag read by trackfusion's MCAP reader, or None (read through rosbags)."""
    if path.is_file():
        return path if path.suffix != ".db3" else None
    import yaml
    try:
        meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, KeyError, TypeError, yaml.YAMLError) as exc:
        raise SensorDataError(f"{path / 'metadata.yaml'}: not a rosbag2 metadata file ({exc})") from None
    files = meta.get("relative_file_paths") or []
    if meta.get("storage_identifier") == "mcap" and len(files) == 1 and not meta.get("compression_mode"):
        return path / files[0]
    return None


def bag_topics(path: Path) -> dict[str, tuple[str, int]]:
    """topic -> (message type, message count) of a bag."""
    mcap_path = _mcap_storage(path)
    if mcap_path is not None:
        from .mcap_log import channel_types
        return channel_types(mcap_path)
    with _rosbags_reader(path) as reader:
        return {t: (info.msgtype or "", int(info.msgcount)) for t, info in reader.topics.items()}


def _rosbags_reader(path: Path):
    from rosbags.rosbag2 import Reader
    try:
        return Reader(path)
    except Exception as exc:
        raise SensorDataError(f"{path}: cannot open as a ROS 2 bag ({exc})") from None


def select_topics(path: Path, found: dict[str, tuple[str, int]], named: dict[str, str | None],
                  source: str) -> dict[str, tuple[str, str]]:
    """role -> (topic, message type) for every role present: the topic ``named`` in the pipeline
    (``inputs.topics.<role>``; it must exist and be of a supported type), else the only topic of
    a supported type. Raises ConfigError (the pipeline ``source``) for a named topic that is
    missing or of another type, and for two candidates of a role none is named for."""
    out: dict[str, tuple[str, str]] = {}
    listing = ", ".join(f"{t} ({ty})" for t, (ty, _) in sorted(found.items())) or "none"
    for role, types in ROLES.items():
        topic = named.get(role)
        if topic is not None:
            if topic not in found:
                raise ConfigError(f"{source}: inputs.topics.{role}: topic {topic} is not in {path} "
                                  f"(topics: {listing})")
            msgtype = found[topic][0]
            if msgtype not in types:
                raise ConfigError(f"{source}: inputs.topics.{role}: {path}: topic {topic} has the unsupported "
                                  f"type {msgtype!r} (supported: {', '.join(types)})")
            out[role] = (topic, msgtype)
            continue
        candidates = sorted(t for t, (ty, _) in found.items() if ty in types)
        if len(candidates) > 1:
            raise ConfigError(f"{source}: inputs.topics.{role}: {path} has {len(candidates)} topics of type "
                              f"{' or '.join(types)} ({', '.join(candidates)}): name one")
        if candidates:
            out[role] = (candidates[0], found[candidates[0]][0])
    return out


def _times_ns(path: Path, topic: str, fields: dict[str, np.ndarray], receive_ns: np.ndarray) -> np.ndarray:
    """Header stamps (or the receive times when all stamps are zero), checked strictly increasing."""
    ns = cdr.stamp_ns(fields)
    if ns.size and not ns.any():
        ns = receive_ns.astype(np.int64)
    back = np.flatnonzero(np.diff(ns) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise SensorDataError(f"{path}: {topic} record {i}: header.stamp not increasing "
                              f"({int(ns[i])} ns after {int(ns[i - 1])} ns)")
    if ns.size and ns[0] < 0:
        raise SensorDataError(f"{path}: {topic} record 0: negative header.stamp")
    return ns


def _imu(fields: dict[str, np.ndarray], t_s: np.ndarray) -> ImuData:
    return ImuData(t_s, fields["angular_velocity"], fields["linear_acceleration"])


def _gnss(path: Path, topic: str, fields: dict[str, np.ndarray], t_s: np.ndarray) -> GnssData:
    status = fields["status.status"].astype(np.int64)
    unknown = ~np.isin(status, list(_FIX_QUALITY))
    if unknown.any():
        i = int(np.argmax(unknown))
        raise SensorDataError(f"{path}: {topic} record {i}: status.status {int(status[i])} is not -1, 0, 1 or 2")
    quality = np.select([status == s for s in _FIX_QUALITY], list(_FIX_QUALITY.values()))
    cov = fields["position_covariance"].reshape(-1, 3, 3)
    return GnssData(t_s, fields["latitude"], fields["longitude"], fields["altitude"], cov, quality.astype(np.int64))


def _odometer(msgtype: str, fields: dict[str, np.ndarray], t_s: np.ndarray) -> OdometerData:
    if msgtype == "nav_msgs/msg/Odometry":
        v = fields["twist.twist.linear"][:, 0]
        d = np.zeros(t_s.size)
        np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t_s), out=d[1:])
        return OdometerData(t_s, d, np.zeros(t_s.size, np.int64))
    return OdometerData(t_s, fields["distance_m"], fields["ticks"].astype(np.int64))


def _finite(path: Path, topic: str, fields: dict[str, np.ndarray]) -> None:
    for name, values in fields.items():
        if values.dtype.kind == "f":
            bad = ~np.isfinite(values.reshape(len(values), int(np.prod(values.shape[1:], dtype=int)))).all(axis=1)
            if bad.any():
                raise SensorDataError(f"{path}: {topic} record {int(np.argmax(bad))}: {name} is not finite")


def _decoded(path: Path, topic: str, msgtype: str, records: cdr.Records) -> dict[str, np.ndarray]:
    try:
        fields = cdr.decode(records, msgtype)
    except cdr.CdrRecordError as exc:
        raise SensorDataError(f"{path}: {topic} record {exc.index}: {exc.reason}") from None
    _finite(path, topic, fields)
    return fields


def _read_rosbags(path: Path, roles: dict[str, tuple[str, str]]
                  ) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """topic -> (receive times [ns], decoded fields) through ``rosbags`` (sqlite3 and folder bags)."""
    payloads: dict[str, list[bytes]] = {t: [] for t, _ in roles.values()}
    times: dict[str, list[int]] = {t: [] for t in payloads}
    with _rosbags_reader(path) as reader:
        conns = [c for c in reader.connections if c.topic in payloads]
        for conn, stamp, raw in reader.messages(connections=conns):
            payloads[conn.topic].append(raw)
            times[conn.topic].append(stamp)
    out = {}
    for topic, msgtype in roles.values():
        out[topic] = (np.asarray(times[topic], np.int64),
                      _decoded(path, topic, msgtype, cdr.Records.from_payloads(payloads.pop(topic))))
    return out


def read_bag(path: str | Path, topics: dict[str, str | None] | None = None, source: str = "",
             allow_truncated: bool = False) -> tuple[SensorLog, dict[str, Any] | None]:
    """A ROS 2 bag as a :class:`SensorLog` (IMU, GNSS, odometer) and the damage report of a
    damaged MCAP bag read with ``allow_truncated`` (as
    :func:`~trackfusion.sensors.mcap_log.read_log_with_damage`; else None).

    topics: role -> topic (``inputs.topics``; None: found automatically). The IMU's axes are
    the bag's (REP-103): turning them into the body frame is :func:`.imu_axes.to_body`'s.
    Raises SensorDataError (bad record: topic and record index) or ConfigError (topic choice).
    """
    p = Path(path)
    found = bag_topics(p)
    roles = select_topics(p, found, topics or {}, source or str(p))
    mcap_path = _mcap_storage(p)
    damage = None
    if mcap_path is not None:
        from .mcap_log import read_cdr_topics
        decoded, damage = read_cdr_topics(mcap_path, dict(roles.values()), allow_truncated)
    else:
        decoded = _read_rosbags(p, roles)
    stamps = {topic: _times_ns(p, topic, fields, receive_ns) for topic, (receive_ns, fields) in decoded.items()
              if receive_ns.size}
    origin_ns = min((int(ns[0]) for ns in stamps.values()), default=0) // 10**9 * 10**9
    log = SensorLog(metadata={"ros2_topics": {role: topic for role, (topic, _) in roles.items()},
                              "ros2_time_origin_ns": origin_ns})
    for role, (topic, msgtype) in roles.items():
        if topic not in stamps:
            continue
        fields = decoded[topic][1]
        t_s = (stamps[topic] - origin_ns) / 1e9  # integer ns first: epoch seconds in float64 keep only ~0.2 us
        if role == "imu":
            log.imu = _imu(fields, t_s)
        elif role == "gnss":
            log.gnss = _gnss(p, topic, fields, t_s)
        else:
            log.odometer = _odometer(msgtype, fields, t_s)
    return log, damage


def inspect_bag(path: str | Path):
    """:func:`~trackfusion.sensors.mcap_log.inspect_log` of a bag: the topics of the roles read
    (found as by :func:`read_bag`, strictly: no damage allowed), summarised from their times,
    under the bag's topic names and types."""
    from .mcap_log import LogSummary, summarise_times
    p = Path(path)
    found = bag_topics(p)
    roles = select_topics(p, found, {}, str(p))
    log, _ = read_bag(p)
    data = {"imu": log.imu, "gnss": log.gnss, "odometer": log.odometer}
    topics = [summarise_times(topic, msgtype, data[role].t_s) for role, (topic, msgtype) in roles.items()
              if data[role] is not None]
    size = sum(f.stat().st_size for f in p.iterdir() if f.is_file()) if p.is_dir() else p.stat().st_size
    return LogSummary(p, size, "ROS 2 bag", topics, sorted(log.metadata))


def inspect_log_or_bag(path: str | Path):
    """A log summarised per topic, whichever its format: a ROS 2 bag by :func:`inspect_bag`, a
    trackfusion MCAP log by :func:`~trackfusion.sensors.mcap_log.inspect_log`."""
    from .mcap_log import inspect_log
    p = Path(path)
    return inspect_bag(p) if is_bag(p) else inspect_log(p)
