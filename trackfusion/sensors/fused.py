"""``fused.mcap``: the smoothed trajectory as Foxglove messages (JSON encoding).

Topics: ``/trajectory/pose`` (``foxglove.PoseInFrame``, position of the IMU origin in the
frame ``n``, orientation ``R_nb`` as a quaternion) and ``/trajectory/fix``
(``foxglove.LocationFix``, WGS-84 latitude, longitude, ellipsoidal height and the diagonal
position covariance in ENU), at most ``max_rate_hz``. Written atomically and
deterministically (no wall-clock time in the file).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, Writer

from .. import geodesy
from .fileio import atomic_path

_POSE_SCHEMA = {
    "title": "foxglove.PoseInFrame", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {
            "position": {"type": "object", "properties": {a: {"type": "number"} for a in "xyz"}},
            "orientation": {"type": "object", "properties": {a: {"type": "number"} for a in "xyzw"}}}},
    },
}
_FIX_SCHEMA = {
    "title": "foxglove.LocationFix", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"}, "longitude": {"type": "number"}, "altitude": {"type": "number"},
        "position_covariance": {"type": "array", "items": {"type": "number"}},
        "position_covariance_type": {"type": "integer"},
    },
}


def _stamp(t_s: float) -> dict:
    ns = int(round(t_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def write_fused_mcap(path: str | Path, table: dict[str, np.ndarray], origin: geodesy.Origin,
                     max_rate_hz: float = 10.0) -> None:
    """Write the trajectory table (trajectory.csv columns) to ``path`` (see module docstring)."""
    t = table["t_s"]
    step = max(1, int(round(1.0 / (max_rate_hz * np.median(np.diff(t)))))) if t.size > 1 else 1
    sel = np.arange(0, t.size, step)
    pos = np.column_stack([table["e_m"], table["n_m"], table["u_m"]])[sel]
    lat, lon, h = geodesy.n_to_geodetic(pos, origin)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        w = Writer(stream, compression=CompressionType.ZSTD)
        w.start(profile="", library="trackfusion")
        pose_ch = w.register_channel("/trajectory/pose", "json", w.register_schema(
            "foxglove.PoseInFrame", "jsonschema", json.dumps(_POSE_SCHEMA).encode()))
        fix_ch = w.register_channel("/trajectory/fix", "json", w.register_schema(
            "foxglove.LocationFix", "jsonschema", json.dumps(_FIX_SCHEMA).encode()))
        for j, i in enumerate(sel):
            stamp = _stamp(float(t[i]))
            log_time = stamp["sec"] * 1_000_000_000 + stamp["nsec"]
            pose = {"timestamp": stamp, "frame_id": "n", "pose": {
                "position": {"x": float(pos[j, 0]), "y": float(pos[j, 1]), "z": float(pos[j, 2])},
                "orientation": {"x": float(table["qx"][i]), "y": float(table["qy"][i]), "z": float(table["qz"][i]),
                                "w": float(table["qw"][i])}}}
            cov = [float(table[f"sigma_{a}_m"][i]) ** 2 for a in "enu"]
            fix = {"timestamp": stamp, "frame_id": "n", "latitude": float(lat[j]), "longitude": float(lon[j]),
                   "altitude": float(h[j]),
                   "position_covariance": [cov[0], 0.0, 0.0, 0.0, cov[1], 0.0, 0.0, 0.0, cov[2]],
                   "position_covariance_type": 2}
            w.add_message(pose_ch, log_time=log_time, data=json.dumps(pose).encode(), publish_time=log_time)
            w.add_message(fix_ch, log_time=log_time, data=json.dumps(fix).encode(), publish_time=log_time)
        w.finish()
