"""JSON schemas of the raw-log topics (the public interface other tools write; docs/log_format.md).

Each topic has one schema name; messages are JSON (``message_encoding: json``)
and schemas are JSON Schema (``encoding: jsonschema``). ``FIELDS`` lists, per
schema, the numeric fields the reader requires (dotted paths), in the order the
reader returns them.
"""

from __future__ import annotations

import json

_NUM = {"type": "number"}


def _vec3(unit: str, frame: str) -> dict:
    return {"type": "object", "description": f"[{unit}] in frame {frame}",
            "properties": {"x": _NUM, "y": _NUM, "z": _NUM}, "required": ["x", "y", "z"]}


def _schema(title: str, description: str, properties: dict, required: list[str]) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
            "description": description, "type": "object", "properties": properties, "required": required}


_TIMESTAMP = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}

SCHEMAS: dict[str, dict] = {
    "trackfusion.Imu": _schema(
        "trackfusion.Imu",
        "IMU sample: means over (t - dt, t] of the angular rate w.r.t. inertial space and the specific force, body frame b (x forward, y left, z up).",
        {"angular_velocity": _vec3("rad/s", "b"), "linear_acceleration": _vec3("m/s^2", "b")},
        ["angular_velocity", "linear_acceleration"]),
    "trackfusion.Odometer": _schema(
        "trackfusion.Odometer", "Cumulative signed distance of the measuring wheel and its encoder count.",
        {"distance_m": _NUM, "ticks": {"type": "integer"}}, ["distance_m", "ticks"]),
    "foxglove.LocationFix": _schema(
        "foxglove.LocationFix", "GNSS fix (Foxglove schema) plus the NMEA fix quality (1 single, 2 DGNSS, 4 RTK fixed, 5 RTK float).",
        {"timestamp": _TIMESTAMP, "frame_id": {"type": "string"}, "latitude": _NUM, "longitude": _NUM,
         "altitude": {**_NUM, "description": "ellipsoidal height [m]"},
         "position_covariance": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9,
                                 "description": "row-major 3x3 ENU covariance [m^2]"},
         "position_covariance_type": {"type": "integer"}, "fix_quality": {"type": "integer"}},
        ["latitude", "longitude", "altitude", "position_covariance", "fix_quality"]),
    "trackfusion.PolarObservation": _schema(
        "trackfusion.PolarObservation", "Total-station reading of a prism, on the station's clock.",
        {"horizontal_angle_rad": {**_NUM, "description": "clockwise from the orientation direction"},
         "zenith_angle_rad": _NUM, "slope_distance_m": _NUM, "prism_id": {"type": "string"}},
        ["horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m", "prism_id"]),
    "trackfusion.Inclination": _schema(
        "trackfusion.Inclination", "Roll (left side up) and pitch (nose up) against the plumb line.",
        {"roll_rad": _NUM, "pitch_rad": _NUM}, ["roll_rad", "pitch_rad"]),
    "trackfusion.Gauge": _schema(
        "trackfusion.Gauge", "Track gauge between the running edges.", {"gauge_m": _NUM}, ["gauge_m"]),
}

#: Fixed topics and their schema names; total stations use ``/total_station/<id>``.
TOPICS = {"/imu": "trackfusion.Imu", "/odometer": "trackfusion.Odometer", "/gnss": "foxglove.LocationFix",
          "/inclinometer": "trackfusion.Inclination", "/gauge": "trackfusion.Gauge"}
TOTAL_STATION_PREFIX = "/total_station/"
TOTAL_STATION_SCHEMA = "trackfusion.PolarObservation"

#: Numeric fields the reader extracts per schema (dotted paths).
FIELDS: dict[str, tuple[str, ...]] = {
    "trackfusion.Imu": ("angular_velocity.x", "angular_velocity.y", "angular_velocity.z",
                        "linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z"),
    "trackfusion.Odometer": ("distance_m", "ticks"),
    "foxglove.LocationFix": ("latitude", "longitude", "altitude", "fix_quality") + tuple(
        f"position_covariance.{i}" for i in range(9)),
    "trackfusion.PolarObservation": ("horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m"),
    "trackfusion.Inclination": ("roll_rad", "pitch_rad"),
    "trackfusion.Gauge": ("gauge_m",),
}


def schema_for_topic(topic: str) -> str | None:
    """The schema name a topic must carry, or None for an unknown topic."""
    if topic.startswith(TOTAL_STATION_PREFIX) and len(topic) > len(TOTAL_STATION_PREFIX):
        return TOTAL_STATION_SCHEMA
    return TOPICS.get(topic)


def schema_bytes(name: str) -> bytes:
    """The JSON Schema document of ``name`` as UTF-8 bytes (deterministic)."""
    return json.dumps(SCHEMAS[name], sort_keys=True, separators=(",", ":")).encode()
