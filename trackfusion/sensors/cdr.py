"""Vectorised decoding of ROS 2 CDR messages of fixed layout (docs/log_format.md, "ROS 2").

A ROS 2 message serialised as CDR (little-endian, XCDR1, what rosbag2 records) is a 4-byte
encapsulation header (``00 01 00 00``) followed by the fields in definition order, each aligned
to its own size counted from the end of that header; a string is a uint32 length (with its
NUL) followed by the characters. ``sensor_msgs/msg/Imu`` and the other messages read here
hold one or two strings (``frame_id``) and otherwise numbers, so every record of a topic has
the same layout once its strings' lengths are known.

Hand-written because the libraries deserialise one message at a time into Python objects
(``rosbags`` ``deserialize_cdr``, ``mcap_ros2`` decoders): about 10-20 us a message, i.e.
20-40 s for an hour of 500 Hz IMU messages (1.8 M). Here every field is one numpy gather over
all the records of a topic at once (the records concatenated in one byte array): the strings'
lengths and the field offsets are computed for all records together, every record's size is
checked against its layout, and the numeric fields are gathered as (N, k) arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: CDR little-endian encapsulation (representation identifier 0x0001, options 0)
_ENCAPSULATION_LE = (0, 1)

_HEADER = [("stamp.sec", "<i4", 1), ("stamp.nanosec", "<u4", 1), ("frame_id", "string", 0)]
_VEC3, _QUAT = 3, 4

#: Field layouts: (path, numpy dtype or "string", count) in definition order, nested messages flattened.
LAYOUTS: dict[str, list[tuple[str, str, int]]] = {
    "sensor_msgs/msg/Imu": _HEADER + [
        ("orientation", "<f8", _QUAT), ("orientation_covariance", "<f8", 9),
        ("angular_velocity", "<f8", _VEC3), ("angular_velocity_covariance", "<f8", 9),
        ("linear_acceleration", "<f8", _VEC3), ("linear_acceleration_covariance", "<f8", 9)],
    "sensor_msgs/msg/NavSatFix": _HEADER + [
        ("status.status", "<i1", 1), ("status.service", "<u2", 1),
        ("latitude", "<f8", 1), ("longitude", "<f8", 1), ("altitude", "<f8", 1),
        ("position_covariance", "<f8", 9), ("position_covariance_type", "<u1", 1)],
    "nav_msgs/msg/Odometry": _HEADER + [
        ("child_frame_id", "string", 0),
        ("pose.pose.position", "<f8", 3), ("pose.pose.orientation", "<f8", _QUAT), ("pose.covariance", "<f8", 36),
        ("twist.twist.linear", "<f8", _VEC3), ("twist.twist.angular", "<f8", _VEC3),
        ("twist.covariance", "<f8", 36)],
    "trackfusion_msgs/msg/OdometerDistance": _HEADER + [("distance_m", "<f8", 1), ("ticks", "<i8", 1)],
}

#: the fields each decode returns (the others are only stepped over and size-checked)
WANTED: dict[str, tuple[str, ...]] = {
    "sensor_msgs/msg/Imu": ("stamp.sec", "stamp.nanosec", "angular_velocity", "linear_acceleration"),
    "sensor_msgs/msg/NavSatFix": ("stamp.sec", "stamp.nanosec", "status.status", "latitude", "longitude",
                                  "altitude", "position_covariance", "position_covariance_type"),
    "nav_msgs/msg/Odometry": ("stamp.sec", "stamp.nanosec", "pose.pose.position", "twist.twist.linear"),
    "trackfusion_msgs/msg/OdometerDistance": ("stamp.sec", "stamp.nanosec", "distance_m", "ticks"),
}

#: the trackfusion odometer message (its .msg definition; docs/log_format.md)
ODOMETER_DISTANCE_MSG = """\
# Cumulative signed distance of a measuring wheel (trackfusion).
std_msgs/Header header   # stamp: time of the count, on the IMU clock
float64 distance_m       # cumulative signed distance along the wheel path [m]
int64 ticks              # cumulative signed encoder count
"""


class CdrRecordError(Exception):
    """Record ``index`` (0-based in the records decoded) is not a valid CDR message of the type."""

    def __init__(self, index: int, reason: str):
        super().__init__(reason)
        self.index, self.reason = index, reason


@dataclass
class Records:
    """The serialised records of one topic: ``data`` uint8 (B,) holds them back to back;
    ``start`` (N,) int64 where each begins, ``size`` (N,) int64 its length [bytes]."""

    data: np.ndarray
    start: np.ndarray
    size: np.ndarray

    @classmethod
    def from_payloads(cls, payloads: list[bytes]) -> "Records":
        """Records of a list of message payloads (joined once)."""
        size = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
        start = np.zeros(size.size, np.int64)
        np.cumsum(size[:-1], out=start[1:])
        return cls(np.frombuffer(b"".join(payloads), np.uint8), start, size)


def _gather(data: np.ndarray, at: np.ndarray, nbytes: int) -> np.ndarray:
    """Bytes ``data[at[i] : at[i] + nbytes]`` of every record as an (N, nbytes) uint8 array."""
    if at.size == 0:
        return np.zeros((0, nbytes), np.uint8)
    return sliding_window_view(data, nbytes)[at]


def _first(bad: np.ndarray) -> int:
    return int(np.argmax(bad))


def _uniform_offsets(records: Records, msgtype: str) -> dict[str, int] | None:
    """Field offsets (from each record's start) shared by every record, or None when the records
    differ in size or in their strings' lengths (then the general path decides)."""
    n = records.start.size
    if n == 0 or not (records.size == records.size[0]).all():
        return None
    first = Records(records.data, records.start[:1], records.size[:1])
    try:
        layout = _layout(first, msgtype)
    except CdrRecordError:
        return None
    for at, length in layout["strings"]:
        lengths = _gather(records.data, records.start + at, 4).copy().view("<u4").ravel()
        if not (lengths == length).all():
            return None
    if not (_gather(records.data, records.start, 2) == _ENCAPSULATION_LE).all():
        return None
    return {path: int(at[0] - records.start[0]) for path, at in layout["offsets"].items()}


def decode(records: Records, msgtype: str) -> dict[str, np.ndarray]:
    """The :data:`WANTED` fields of every record of ``msgtype`` (a key of :data:`LAYOUTS`).

    Returns path -> array: (N,) for a scalar field, (N, count) for arrays and vectors, in the
    field's dtype (float64, int64...). Raises :class:`CdrRecordError` for the first record that
    is not little-endian CDR, whose string runs past its end or whose size differs from its
    layout (trailing padding to a multiple of 4 is allowed, as DDS writers add it).
    Records of one size and equal strings (the usual case: one frame_id per topic) share one
    layout, found on the first record and checked on all; others are laid out record by record
    (still vectorised).
    """
    n = records.start.size
    uniform = _uniform_offsets(records, msgtype)
    if uniform is not None:
        offsets = {path: records.start + at for path, at in uniform.items()}
    else:
        offsets = _layout(records, msgtype)["offsets"]
    out: dict[str, np.ndarray] = {}
    for path, kind, count in LAYOUTS[msgtype]:
        if path in offsets:
            dtype = np.dtype(kind)
            values = _gather(records.data, offsets[path], dtype.itemsize * count).copy().view(dtype)
            out[path] = values.ravel() if count == 1 else values.reshape(n, count)
    return out


def _layout(records: Records, msgtype: str) -> dict:
    """Check every record against the layout of ``msgtype``; returns ``offsets`` (path -> (N,)
    int64 offsets of the :data:`WANTED` fields in ``records.data``) and ``strings`` (for the
    first record: (offset from its start, length) of each string's length field). Raises
    :class:`CdrRecordError` for the first bad record."""
    n = records.start.size
    data, base, size = records.data, records.start + 4, records.size - 4
    short = size < 0
    if short.any():
        raise CdrRecordError(_first(short), f"CDR record of {int(records.size[_first(short)])} bytes: shorter "
                                            "than its 4-byte header")
    if n:
        head = _gather(data, records.start, 2)
        bad = (head[:, 0] != _ENCAPSULATION_LE[0]) | (head[:, 1] != _ENCAPSULATION_LE[1])
        if bad.any():
            i = _first(bad)
            raise CdrRecordError(i, f"CDR encapsulation {bytes(head[i]).hex()} is not little-endian CDR (0001)")
    pos = np.zeros(n, np.int64)  # offset in the body (after the header) of the next field
    offsets: dict[str, np.ndarray] = {}
    strings: list[tuple[int, int]] = []
    wanted = set(WANTED[msgtype])
    for path, kind, count in LAYOUTS[msgtype]:
        align = 4 if kind == "string" else np.dtype(kind).itemsize
        pos = (pos + (align - 1)) & -align
        nbytes = 4 if kind == "string" else align * count
        beyond = pos + nbytes > size
        if beyond.any():
            i = _first(beyond)
            raise CdrRecordError(i, f"CDR record of {int(records.size[i])} bytes ends inside field {path}")
        if kind == "string":
            length = _gather(data, base + pos, 4).copy().view("<u4").ravel().astype(np.int64)
            if n:
                strings.append((4 + int(pos[0]), int(length[0])))
            pos = pos + 4 + length
            over = (pos > size) | (length == 0)
            if over.any():
                i = _first(over)
                raise CdrRecordError(i, f"CDR record of {int(records.size[i])} bytes: string {path} of length "
                                        f"{int(length[i])} does not fit")
        else:
            if path in wanted:
                offsets[path] = base + pos
            pos = pos + nbytes
    wrong = (size < pos) | (size > ((pos + 3) & -4))
    if wrong.any():
        i = _first(wrong)
        raise CdrRecordError(i, f"CDR record of {int(records.size[i])} bytes, its {msgtype} layout needs "
                                f"{int(pos[i]) + 4}")
    return {"offsets": offsets, "strings": strings}


def stamp_ns(fields: dict[str, np.ndarray]) -> np.ndarray:
    """Header stamps (N,) int64 [ns] of decoded fields."""
    return fields["stamp.sec"].astype(np.int64) * 1_000_000_000 + fields["stamp.nanosec"].astype(np.int64)


def _layout_dtype(msgtype: str, frame_id: str) -> tuple[np.dtype, int]:
    """The numpy structured dtype of one record (encapsulation header included) with ``frame_id``
    as its only string, and its serialised size (for writing)."""
    names, formats, offs = [], [], []
    pos = 0
    for path, kind, count in LAYOUTS[msgtype]:
        if kind == "string":
            pos = (pos + 3) & -4
            names += [path + ".length", path]
            formats += ["<u4", f"S{len(frame_id) + 1}"]
            offs += [4 + pos, 8 + pos]
            pos += 4 + len(frame_id) + 1
            continue
        dtype = np.dtype(kind)
        pos = (pos + dtype.itemsize - 1) & -dtype.itemsize
        names.append(path)
        formats.append(dtype if count == 1 else (dtype, (count,)))
        offs.append(4 + pos)
        pos += dtype.itemsize * count
    names.append("encapsulation")
    formats.append("V4")
    offs.append(0)
    size = 4 + pos
    return np.dtype({"names": names, "formats": formats, "offsets": offs, "itemsize": size}), size


def encode(msgtype: str, frame_id: str, values: dict[str, np.ndarray], n: int) -> np.ndarray:
    """N records of ``msgtype`` (one frame_id, every other field from ``values``: path ->
    (N,) or (N, count); missing fields are zero) as a structured array (its ``tobytes()`` is the
    records back to back, each ``itemsize`` bytes)."""
    if any(kind == "string" for path, kind, _ in LAYOUTS[msgtype] if path != "frame_id"):
        raise ValueError(f"{msgtype}: only messages whose one string is frame_id can be written")
    dtype, _ = _layout_dtype(msgtype, frame_id)
    out = np.zeros(n, dtype)
    out["encapsulation"] = np.frombuffer(bytes([*_ENCAPSULATION_LE, 0, 0]), "V4")[0]
    out["frame_id.length"] = len(frame_id) + 1
    out["frame_id"] = frame_id.encode()
    for path, v in values.items():
        out[path] = v
    return out


def msgdef(msgtype: str) -> str:
    """The ROS 2 message definition text of ``msgtype`` with its dependencies (MCAP schema
    encoding ``ros2msg``), as ``rosbags`` generates it."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg
    store = get_typestore(Stores.ROS2_HUMBLE)
    if msgtype == "trackfusion_msgs/msg/OdometerDistance":
        store.register(get_types_from_msg(ODOMETER_DISTANCE_MSG, msgtype))
    return store.generate_msgdef(msgtype, ros_version=2)[0]
