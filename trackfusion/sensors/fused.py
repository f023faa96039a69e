"""``fused.mcap``: the survey for Foxglove — smoothed trajectory, rail traces and the raw inputs.

Topics (JSON encoding, Foxglove schema names; frame ``n`` is ENU at the survey origin):

- ``/trajectory/pose`` ``foxglove.PoseInFrame``: position of the IMU origin in ``n`` and the
  orientation ``R_nb`` as a quaternion, at most ``max_rate_hz``;
- ``/trajectory/fix`` ``foxglove.LocationFix``: WGS-84 latitude, longitude, ellipsoidal height
  and the diagonal ENU position covariance (type 2, diagonal known), same times (Map panel);
- ``/trajectory/tf`` ``foxglove.FrameTransform``: ``n`` -> ``b`` (translation: the IMU origin in ``n``;
  rotation: ``R_nb``), same times, so that the 3-D panel can follow the trolley (display frame ``b``);
- ``/trajectory/path`` ``foxglove.SceneUpdate``: the whole trajectory as one line (3-D panel);
- with geometry (``geometry.csv`` columns): ``/track/rails`` ``foxglove.SceneUpdate`` with the
  left (red) and right (blue) rail as lines in ``n``, and ``/track/rails_geojson``
  ``foxglove.GeoJSON``: both rails as WGS-84 LineStrings (Map panel);
- the raw log's topics (``/imu``, ``/odometer``, ``/gnss``, ``/total_station/<id>``, ...) copied
  with their schemas and ``log_time`` (docs/log_format.md), and its metadata.

Times: the survey's absolute clock (:func:`survey_epoch_ns`: the log's ``survey.epoch_utc``
plus the IMU clock), so that Foxglove shows the date and time of the survey; a log that does not
give its epoch stays on the IMU clock (times from 1970-01-01). The CSV outputs keep the IMU clock.
One schema record per name (the raw ``/gnss`` and ``/trajectory/fix`` share ``foxglove.LocationFix``).
The scene and GeoJSON messages are stamped at the trajectory's first time and never expire.
Written atomically and deterministically (no wall-clock time in the file).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import geodesy
from . import schemas
from .mcap_log import CopyHead, ExtraChannel, copy_log, finish_copy, start_copy, write_log
from .types import SensorLog

#: Most points per drawn line (traces are decimated evenly to this).
MAX_LINE_POINTS = 50000

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_XYZ = {"type": "object", "properties": {a: {"type": "number"} for a in "xyz"}, "required": list("xyz")}
_QUAT = {"type": "object", "properties": {a: {"type": "number"} for a in "xyzw"}, "required": list("xyzw")}
_POSE = {"title": "foxglove.Pose", "type": "object", "properties": {"position": _XYZ, "orientation": _QUAT},
         "required": ["position", "orientation"]}
_COLOR = {"title": "foxglove.Color", "type": "object",
          "properties": {a: {"type": "number"} for a in "rgba"}, "required": list("rgba")}

POSE_IN_FRAME_SCHEMA = {
    "title": "foxglove.PoseInFrame", "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object", "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    "required": ["timestamp", "frame_id", "pose"]}
FRAME_TRANSFORM_SCHEMA = {
    "title": "foxglove.FrameTransform", "description": "A transform between two reference frames in 3D space",
    "type": "object", "properties": {
        "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
        "translation": {"title": "foxglove.Vector3", **_XYZ}, "rotation": {"title": "foxglove.Quaternion", **_QUAT}},
    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"]}
_LINE = {"title": "foxglove.LinePrimitive", "type": "object", "properties": {
    "type": {"title": "foxglove.LineType", "oneOf": [{"title": t, "const": i} for i, t in
                                                     enumerate(("LINE_STRIP", "LINE_LOOP", "LINE_LIST"))]},
    "pose": _POSE, "thickness": {"type": "number"}, "scale_invariant": {"type": "boolean"},
    "points": {"type": "array", "items": {"title": "foxglove.Point3", **_XYZ}},
    "color": _COLOR, "colors": {"type": "array", "items": _COLOR},
    "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}}},
    "required": ["type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"]}
SCENE_UPDATE_SCHEMA = {
    "title": "foxglove.SceneUpdate", "description": "An update to the entities displayed in a 3D scene",
    "type": "object", "properties": {
        "deletions": {"type": "array", "items": {
            "title": "foxglove.SceneEntityDeletion", "type": "object",
            "properties": {"timestamp": _TIME, "type": {"title": "foxglove.SceneEntityDeletionType",
                                                         "oneOf": [{"title": "MATCHING_ID", "const": 0},
                                                                   {"title": "ALL", "const": 1}]},
                           "id": {"type": "string"}},
            "required": ["timestamp", "type", "id"]}},
        "entities": {"type": "array", "items": {
            "title": "foxglove.SceneEntity", "type": "object", "properties": {
                "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
                "lifetime": {"type": "object", "title": "duration",
                             "properties": {"sec": {"type": "integer"},
                                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
                "frame_locked": {"type": "boolean"},
                "metadata": {"type": "array", "items": {
                    "title": "foxglove.KeyValuePair", "type": "object",
                    "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                    "required": ["key", "value"]}},
                "lines": {"type": "array", "items": _LINE}},
            "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata"]}}},
    "required": ["deletions", "entities"]}
GEOJSON_SCHEMA = {
    "title": "foxglove.GeoJSON", "description": "GeoJSON data for annotating maps", "type": "object",
    "properties": {"geojson": {"type": "string", "description": "GeoJSON data encoded as a UTF-8 string"}},
    "required": ["geojson"]}

_IDENTITY = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
LEFT_RGBA = (0.85, 0.1, 0.1, 1.0)
RIGHT_RGBA = (0.1, 0.3, 0.9, 1.0)
PATH_RGBA = (0.1, 0.7, 0.2, 1.0)


def _schema(doc: dict) -> bytes:
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _dumps(obj) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


def _decimate(points: np.ndarray) -> np.ndarray:
    return points[::max(1, -(-len(points) // MAX_LINE_POINTS))]


def _line(points_n: np.ndarray, rgba: tuple, thickness_px: float = 3.0) -> dict:
    """A LINE_STRIP through ``points_n`` (M, 3) [m], drawn ``thickness_px`` screen pixels wide."""
    pts = [{"x": x, "y": y, "z": z} for x, y, z in _decimate(points_n).tolist()]
    return {"type": 0, "pose": _IDENTITY, "thickness": thickness_px, "scale_invariant": True, "points": pts,
            "color": dict(zip("rgba", rgba)), "colors": [], "indices": []}


def _scene(ns: int, entity_id: str, lines: list[dict], meta: dict[str, str]) -> str:
    entity = {"timestamp": _stamp(ns), "frame_id": "n", "id": entity_id, "lifetime": {"sec": 0, "nsec": 0},
              "frame_locked": False, "metadata": [{"key": k, "value": v} for k, v in meta.items()], "lines": lines}
    return _dumps({"deletions": [], "entities": [entity]})


#: ``_dumps`` of a PoseInFrame and of a LocationFix message as printf templates (``%r`` of a float is
#: its JSON text): the same bytes, formatted without building dicts
_POSE_TEMPLATE = ('{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"n","pose":{"position":{"x":%r,"y":%r,"z":%r},'
                  '"orientation":{"x":%r,"y":%r,"z":%r,"w":%r}}}')
_TF_TEMPLATE = ('{"timestamp":{"sec":%d,"nsec":%d},"parent_frame_id":"n","child_frame_id":"b",'
                '"translation":{"x":%r,"y":%r,"z":%r},"rotation":{"x":%r,"y":%r,"z":%r,"w":%r}}')
_FIX_TEMPLATE = ('{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"n","latitude":%r,"longitude":%r,"altitude":%r,'
                 '"position_covariance":[%r,0.0,0.0,0.0,%r,0.0,0.0,0.0,%r],"position_covariance_type":2}')


def _pose_and_fix_payloads(ns: np.ndarray, pos: np.ndarray, q_xyzw: np.ndarray, var_enu: np.ndarray,
                           llh: np.ndarray) -> tuple[list[str], list[str], list[str]]:
    """PoseInFrame, LocationFix and FrameTransform (n -> b) payloads at times ``ns`` (N,) [ns]: positions ``pos`` (N, 3) [m] in
    ``n``, quaternions ``q_xyzw`` (N, 4), ENU variances ``var_enu`` (N, 3) [m^2], latitude,
    longitude [deg] and height [m] ``llh`` (N, 3). Raises ValueError for non-finite values (as
    ``_dumps``)."""
    if not all(np.isfinite(a).all() for a in (pos, q_xyzw, var_enu, llh)):
        raise ValueError("Out of range float values are not JSON compliant")
    sec, nsec = (ns // 1_000_000_000).tolist(), (ns % 1_000_000_000).tolist()
    pos_q = list(zip(sec, nsec, *_float_columns(pos), *_float_columns(q_xyzw)))
    poses = list(map(_POSE_TEMPLATE.__mod__, pos_q))
    fixes = list(map(_FIX_TEMPLATE.__mod__, zip(sec, nsec, *_float_columns(llh), *_float_columns(var_enu))))
    return poses, fixes, list(map(_TF_TEMPLATE.__mod__, pos_q))


def _float_columns(a: np.ndarray) -> list[list[float]]:
    """The columns of ``a`` (N, k) as lists of Python floats."""
    return [a[:, j].astype(np.float64).tolist() for j in range(a.shape[1])]


#: rate of the poses in fused.mcap [Hz] (a long run keeps only those rows of its trajectory for it)
FUSED_POSE_RATE_HZ = 10.0


def trajectory_channels(table: dict[str, np.ndarray], origin: geodesy.Origin, max_rate_hz: float = FUSED_POSE_RATE_HZ,
                        epoch_ns: int = 0) -> list[ExtraChannel]:
    """Pose, fix, transform and path channels of a trajectory table (trajectory.csv columns), at
    log times ``epoch_ns`` + t_s (the survey's absolute clock, :func:`survey_epoch_ns`)."""
    t = table["t_s"]
    step = max(1, int(round(1.0 / (max_rate_hz * np.median(np.diff(t)))))) if t.size > 1 else 1
    sel = np.arange(0, t.size, step)
    ns = np.rint(t[sel] * 1e9).astype(np.int64) + int(epoch_ns)
    pos = np.column_stack([table["e_m"], table["n_m"], table["u_m"]])[sel]
    q = np.column_stack([table[c] for c in ("qx", "qy", "qz", "qw")])[sel]
    var = np.column_stack([table[f"sigma_{a}_m"] for a in "enu"])[sel] ** 2
    lat, lon, h = geodesy.n_to_geodetic(pos, origin)
    poses, fixes, transforms = _pose_and_fix_payloads(ns, pos, q, var, np.column_stack([lat, lon, h]))
    t0 = ns[:1]
    path = _scene(int(ns[0]), "trajectory", [_line(np.column_stack([table["e_m"], table["n_m"], table["u_m"]]),
                                                   PATH_RGBA, 2.0)], {"what": "smoothed IMU origin path"})
    return [ExtraChannel("/trajectory/pose", "foxglove.PoseInFrame", _schema(POSE_IN_FRAME_SCHEMA), ns, poses),
            ExtraChannel("/trajectory/fix", schemas.LOCATION_FIX, schemas.schema_bytes(schemas.LOCATION_FIX), ns, fixes),
            ExtraChannel("/trajectory/tf", "foxglove.FrameTransform", _schema(FRAME_TRANSFORM_SCHEMA), ns, transforms),
            ExtraChannel("/trajectory/path", "foxglove.SceneUpdate", _schema(SCENE_UPDATE_SCHEMA), t0, [path])]


def rail_channels(geometry: dict[str, np.ndarray], origin: geodesy.Origin, t0_ns: int) -> list[ExtraChannel]:
    """Rail traces of a geometry table (geometry.csv columns ``left_e_m`` ... ``right_u_m``) as a
    3-D scene and as GeoJSON, stamped ``t0_ns``."""
    rails = {side: np.column_stack([geometry[f"{side}_{a}_m"] for a in "enu"]) for side in ("left", "right")}
    scene = _scene(t0_ns, "rails", [_line(rails["left"], LEFT_RGBA), _line(rails["right"], RIGHT_RGBA)],
                   {"left": "red", "right": "blue", "chainage_m": f"{geometry['chainage_m'][0]:.3f} to "
                                                                  f"{geometry['chainage_m'][-1]:.3f}"})
    features = []
    for side, pts in rails.items():
        lat, lon, h = geodesy.n_to_geodetic(_decimate(pts), origin)
        features.append({"type": "Feature", "properties": {"name": f"{side} rail"},
                         "geometry": {"type": "LineString",
                                      "coordinates": np.column_stack([lon, lat, h]).round(9).tolist()}})
    geojson = _dumps({"geojson": _dumps({"type": "FeatureCollection", "features": features})})
    t0 = np.array([t0_ns], np.int64)
    return [ExtraChannel("/track/rails", "foxglove.SceneUpdate", _schema(SCENE_UPDATE_SCHEMA), t0, [scene]),
            ExtraChannel("/track/rails_geojson", "foxglove.GeoJSON", _schema(GEOJSON_SCHEMA), t0, [geojson])]


RAIL_COLUMNS = tuple(f"{side}_{a}_m" for side in ("left", "right") for a in "enu")


def write_fused_mcap(path: str | Path, table: dict[str, np.ndarray], origin: geodesy.Origin,
                     max_rate_hz: float = FUSED_POSE_RATE_HZ, raw: SensorLog | None = None,
                     geometry: dict[str, np.ndarray] | None = None, copy: CopyHead | None = None) -> None:
    """Write ``fused.mcap`` (module docstring): the trajectory table (trajectory.csv columns), the
    rails when ``geometry`` has the rail columns, and the topics and metadata of the raw log
    ``raw`` (as read by :func:`~trackfusion.sensors.mcap_log.read_log`) when given.

    When ``raw`` was read whole from an intact file that is unchanged since (``raw.source``), that
    file's records are copied byte for byte (:func:`~trackfusion.sensors.mcap_log.copy_log`: no
    re-encoding, no recompression); otherwise (e.g. the readable part of a damaged log) the raw
    topics are written from the arrays of ``raw``. ``copy``: that copy's first part, already
    written (:func:`start_raw_copy`); only the rest is written here (the same bytes)."""
    epoch_ns = survey_epoch_ns(raw.metadata) if raw is not None else 0
    extra = trajectory_channels(table, origin, max_rate_hz, epoch_ns)
    if geometry is not None and all(c in geometry for c in RAIL_COLUMNS) and geometry["chainage_m"].size > 1:
        extra += rail_channels(geometry, origin, int(extra[0].log_time_ns[0]))
    if copy is not None:
        finish_copy(path, copy, extra)
    elif raw is not None and raw.source is not None and raw.source.unchanged():
        copy_log(path, raw.source, extra, time_offset_ns=epoch_ns)
    else:
        write_log(path, raw if raw is not None else SensorLog(), extra, time_offset_ns=epoch_ns)


def start_raw_copy(folder: Path, raw: SensorLog | None, workers: int = 1) -> CopyHead | None:
    """The first part of fused.mcap's copy of the raw log ``raw`` (its schemas, channels and
    records on the survey's clock: :func:`~trackfusion.sensors.mcap_log.start_copy`), written to
    :data:`RAW_COPY_NAME` in ``folder`` (that of fused.mcap); None when ``raw`` is not copied
    (:func:`write_fused_mcap` then writes it from the arrays). ``workers``: threads."""
    if raw is None or raw.source is None or not raw.source.unchanged():
        return None
    return start_copy(Path(folder) / RAW_COPY_NAME, raw.source, survey_epoch_ns(raw.metadata), workers)


#: the file the first part of fused.mcap's copy of the raw log is written to (hidden; renamed
#: fused.mcap when the rest is written)
RAW_COPY_NAME = ".fused.mcap.raw"


def survey_epoch_ns(metadata: dict, source: str = "log") -> int:
    """The survey's epoch [ns since 1970-01-01 UTC]: the UTC time at which the IMU clock reads 0,
    from the log's ``survey`` metadata record, key ``epoch_utc`` (ISO 8601, e.g.
    ``2024-05-14T07:30:00Z``; docs/log_format.md); 0 (times stay on the IMU clock) when the log
    does not say. Raises :class:`~trackfusion.errors.SensorDataError` naming ``source`` (the log
    file) for an unreadable value."""
    from datetime import datetime, timezone
    from ..errors import SensorDataError
    survey = metadata.get("survey") if isinstance(metadata, dict) else None
    text = survey.get("epoch_utc") if isinstance(survey, dict) else None
    if text is None:
        return 0
    try:
        when = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise SensorDataError(f"{source}: metadata survey.epoch_utc: {text!r} is not an ISO 8601 time") from None
    if when.tzinfo is None:
        raise SensorDataError(f"{source}: metadata survey.epoch_utc: {text!r} has no time zone (write it in UTC, ...Z)")
    delta = when.astimezone(timezone.utc) - datetime(1970, 1, 1, tzinfo=timezone.utc)
    ns = (delta.days * 86400 + delta.seconds) * 10**9 + delta.microseconds * 1000
    if not 0 <= ns < 9 * 10**18:
        raise SensorDataError(f"{source}: metadata survey.epoch_utc: {text!r} is outside 1970..2255")
    return ns
