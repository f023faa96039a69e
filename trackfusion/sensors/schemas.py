"""JSON schemas of the raw-log topics: the public interface other tools write (docs/log_format.md).

Each topic carries one schema name. Messages are JSON objects (MCAP channel
``message_encoding: "json"``); schemas are JSON Schema draft 2020-12 documents
(MCAP schema ``encoding: "jsonschema"``).

Besides the JSON Schema documents this module holds, per schema:

- ``FIELDS``: the fields the reader requires, as (dotted path, kind) with kind
  ``"float"`` (a finite JSON number), ``"int"`` (an integral JSON number),
  ``"str"`` (a JSON string) or ``"float9"`` (an array of 9 finite numbers);
- ``CANONICAL``: the exact text layout trackfusion writes (literal pieces
  around the values). Files in this layout are read by a vectorised fast path;
  any other valid JSON layout (key order, whitespace, extra fields) is read by
  the general JSON path with the same checks.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

DRAFT = "https://json-schema.org/draft/2020-12/schema"
_NUM = {"type": "number"}
_TIMESTAMP = {
    "type": "object",
    "description": "optional; the time of record is the MCAP log_time",
    "properties": {"sec": {"type": "integer", "minimum": 0},
                   "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
    "required": ["sec", "nsec"],
}


def _num(description: str) -> dict:
    return {"type": "number", "description": description}


def _vec3(description: str) -> dict:
    return {"type": "object", "description": description,
            "properties": {"x": _NUM, "y": _NUM, "z": _NUM}, "required": ["x", "y", "z"]}


def _schema(name: str, description: str, properties: dict, required: list[str]) -> dict:
    return {"$schema": DRAFT, "$id": name, "title": name, "description": description, "type": "object",
            "properties": {**properties, "timestamp": properties.get("timestamp", _TIMESTAMP)},
            "required": required}


IMU = "trackfusion.Imu"
ODOMETER = "trackfusion.Odometer"
LOCATION_FIX = "foxglove.LocationFix"
POLAR = "trackfusion.PolarObservation"
INCLINATION = "trackfusion.Inclination"
GAUGE = "trackfusion.Gauge"

SCHEMAS: dict[str, dict] = {
    IMU: _schema(
        IMU,
        "IMU sample in the body frame b (x forward, y left, z up): the means over (t - dt, t] of the "
        "angular rate with respect to inertial space and of the specific force.",
        {"angular_velocity": _vec3("angular rate w.r.t. inertial space in frame b [rad/s]"),
         "linear_acceleration": _vec3("specific force in frame b [m/s^2]")},
        ["angular_velocity", "linear_acceleration"]),
    ODOMETER: _schema(
        ODOMETER, "Measuring wheel: cumulative signed distance and cumulative signed encoder count.",
        {"distance_m": _num("cumulative signed distance [m]"),
         "ticks": {"type": "integer", "description": "cumulative signed encoder count"}},
        ["distance_m", "ticks"]),
    LOCATION_FIX: _schema(
        LOCATION_FIX,
        "GNSS fix (the Foxglove LocationFix schema) plus the NMEA GGA fix quality.",
        {"timestamp": _TIMESTAMP,
         "frame_id": {"type": "string", "description": "antenna frame name"},
         "latitude": _num("WGS-84 latitude [deg]"),
         "longitude": _num("WGS-84 longitude [deg]"),
         "altitude": _num("ellipsoidal height (WGS-84) [m]"),
         "position_covariance": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9,
                                 "description": "3x3 position covariance in local ENU, row-major [m^2]"},
         "position_covariance_type": {"type": "integer", "minimum": 0, "maximum": 3,
                                      "description": "0 unknown, 1 approximated, 2 diagonal known, 3 known"},
         "fix_quality": {"type": "integer",
                         "description": "NMEA GGA quality: 0 invalid, 1 single, 2 DGNSS, 4 RTK fixed, 5 RTK float; "
                                        "required on the /gnss topic of a raw log (the reader checks it)"}},
        # (fix_quality not required here: fused.mcap's /trajectory/fix shares this one LocationFix schema)
        ["latitude", "longitude", "altitude", "position_covariance"]),
    POLAR: _schema(
        POLAR, "Robotic total-station reading of a prism; MCAP log_time is on the station's own clock.",
        {"horizontal_angle_rad": _num("horizontal direction, clockwise from the instrument's zero direction [rad]"),
         "zenith_angle_rad": _num("zenith angle from the station's plumb line, as observed [rad]"),
         "slope_distance_m": _num("slope distance to the prism [m]"),
         "prism_id": {"type": "string", "description": "name of the tracked prism"}},
        ["horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m", "prism_id"]),
    INCLINATION: _schema(
        INCLINATION, "Inclinometer: roll (left side up) and pitch (nose up) against the plumb line.",
        {"roll_rad": _num("roll, left side up [rad]"), "pitch_rad": _num("pitch, nose up [rad]")},
        ["roll_rad", "pitch_rad"]),
    GAUGE: _schema(
        GAUGE, "Track gauge sensor.", {"gauge_m": _num("gauge between the running edges [m]")}, ["gauge_m"]),
}

#: Fixed topics and their schema names; total stations use ``/total_station/<id>``.
TOPICS: dict[str, str] = {"/imu": IMU, "/odometer": ODOMETER, "/gnss": LOCATION_FIX,
                          "/inclinometer": INCLINATION, "/gauge": GAUGE}
TOTAL_STATION_PREFIX = "/total_station/"
TOTAL_STATION_SCHEMA = POLAR

#: Required fields per schema: (dotted path, kind), in the order the reader checks them.
FIELDS: dict[str, tuple[tuple[str, str], ...]] = {
    IMU: tuple((f"{v}.{a}", "float") for v in ("angular_velocity", "linear_acceleration") for a in "xyz"),
    ODOMETER: (("distance_m", "float"), ("ticks", "int")),
    LOCATION_FIX: (("latitude", "float"), ("longitude", "float"), ("altitude", "float"),
                   ("position_covariance", "float9"), ("fix_quality", "int")),
    POLAR: (("horizontal_angle_rad", "float"), ("zenith_angle_rad", "float"), ("slope_distance_m", "float"),
            ("prism_id", "str")),
    INCLINATION: (("roll_rad", "float"), ("pitch_rad", "float")),
    GAUGE: (("gauge_m", "float"),),
}


@dataclass(frozen=True)
class Canonical:
    """The exact text trackfusion writes for one schema: ``pieces[0] v0 pieces[1] v1 ... pieces[k]``.

    ``kinds[i]`` is the printf conversion of value i: ``%r`` (float, shortest exact repr),
    ``%d`` (integer) or ``%s`` (text already JSON-encoded, e.g. a quoted string); ``names[i]`` is its
    dotted field path (array elements as ``position_covariance.0``).
    """

    pieces: tuple[str, ...]
    kinds: tuple[str, ...]
    names: tuple[str, ...]

    @property
    def template(self) -> str:
        """printf template of one message (``%`` characters in the pieces are escaped)."""
        out = [self.pieces[0].replace("%", "%%")]
        for kind, piece in zip(self.kinds, self.pieces[1:]):
            out += [kind, piece.replace("%", "%%")]
        return "".join(out)

    @property
    def numeric(self) -> bool:
        """True when every value is a number (the reader's vectorised fast path applies)."""
        return all(k in ("%r", "%d") for k in self.kinds)


CANONICAL: dict[str, Canonical] = {
    IMU: Canonical(('{"angular_velocity":{"x":', ',"y":', ',"z":', '},"linear_acceleration":{"x":', ',"y":',
                    ',"z":', '}}'), ("%r",) * 6,
                tuple(f"{v}.{a}" for v in ("angular_velocity", "linear_acceleration") for a in "xyz")),
    ODOMETER: Canonical(('{"distance_m":', ',"ticks":', '}'), ("%r", "%d"), ("distance_m", "ticks")),
    LOCATION_FIX: Canonical(('{"timestamp":{"sec":', ',"nsec":', '},"frame_id":"gnss","latitude":', ',"longitude":',
                             ',"altitude":', ',"position_covariance":[', ',', ',', ',', ',', ',', ',', ',', ',',
                             '],"position_covariance_type":3,"fix_quality":', '}'),
                            ("%d", "%d") + ("%r",) * 12 + ("%d",),
                            ("timestamp.sec", "timestamp.nsec", "latitude", "longitude", "altitude")
                            + tuple(f"position_covariance.{i}" for i in range(9)) + ("fix_quality",)),
    POLAR: Canonical(('{"horizontal_angle_rad":', ',"zenith_angle_rad":', ',"slope_distance_m":', ',"prism_id":',
                      '}'), ("%r", "%r", "%r", "%s"),
                ("horizontal_angle_rad", "zenith_angle_rad", "slope_distance_m", "prism_id")),
    INCLINATION: Canonical(('{"roll_rad":', ',"pitch_rad":', '}'), ("%r", "%r"), ("roll_rad", "pitch_rad")),
    GAUGE: Canonical(('{"gauge_m":', '}'), ("%r",), ("gauge_m",)),
}


def schema_for_topic(topic: str) -> str | None:
    """The schema name a topic must carry, or None for an unknown topic."""
    if topic.startswith(TOTAL_STATION_PREFIX) and len(topic) > len(TOTAL_STATION_PREFIX):
        return TOTAL_STATION_SCHEMA
    return TOPICS.get(topic)


def schema_bytes(name: str) -> bytes:
    """The JSON Schema document of ``name`` as UTF-8 bytes (deterministic: sorted keys, compact)."""
    return json.dumps(SCHEMAS[name], sort_keys=True, separators=(",", ":")).encode()
