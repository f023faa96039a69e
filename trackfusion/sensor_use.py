"""Which of a log's sensors a pipeline uses, decided before any computing (docs/pipeline.md,
"Sensors in the log").

* A factor switched on in the pipeline (written ``factors.X: true`` or a mapping, or its
  ``sensors.X`` section written) whose topic is not in the log: :class:`ConfigError`, one line
  naming the factor and the topic. A factor left at its default (on) whose topic is absent is
  simply not used.
* A topic in the log whose factor is on is used, with or without its ``sensors.X`` section:
  datasheet defaults then (clock offset 0; the odometer's and the inclinometer's place is the
  vehicle's geometry), said in the run summary (``sensors_defaulted`` in metrics.json). Not the
  GNSS antenna: its lever arm is never zero on a real vehicle (antennas sit on the roof, the
  IMU inside; a zero lever arm puts decimetres of attitude-dependent error into every fix and
  the smoother cannot tell), so a log with fixes, the GNSS factor on and no
  ``sensors.gnss.lever_arm_b_m`` is refused (``trackfusion init`` writes one to fill in).
* Topics present but not used are listed (``sensors_unused``), each with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .errors import ConfigError
from .strict import StrictModel

#: the log topic of each fused sensor (sensors/schemas.py's topics)
TOPICS = {"odometer": "/odometer", "gnss": "/gnss", "inclinometer": "/inclinometer"}
TOTAL_STATION_TOPICS = "/total_station/<id>"


class ClockConfig(StrictModel):
    """A sensor section's clock: ``clock_offset_s``, the sensor's clock minus the IMU clock
    (t_sensor = t_imu + offset) [s]; the default of a sensor used without its section."""

    clock_offset_s: float = 0.0


@dataclass
class SensorUse:
    """The sensors a run fuses: ``use`` (name -> bool) for odometer, gnss, inclinometer and
    total_stations; ``clocks`` (name -> the ``sensors.X`` section or its defaults);
    ``defaulted`` (lines: sensors used with datasheet defaults); ``unused`` ({topic, reason})."""

    use: dict[str, bool]
    clocks: dict[str, Any]
    defaulted: list[str] = field(default_factory=list)
    unused: list[dict[str, str]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """``sensors_defaulted`` and ``sensors_unused`` of metrics.json."""
        return {"sensors_defaulted": list(self.defaulted), "sensors_unused": list(self.unused)}


def _present(data) -> bool:
    return data is not None and getattr(data, "t_s", None) is not None and data.t_s.size > 0


def _switched_on(cfg, name: str) -> bool:
    """The factor is on and the pipeline says so: its factor key or its sensors section written."""
    fs = cfg.factors
    return getattr(fs, name).enabled and (name in fs.model_fields_set or getattr(cfg.sensors, name, None) is not None)


def _missing(source: str, log_path: str, key: str, topic: str) -> ConfigError:
    return ConfigError(f"{source}: {key}: on, but the log {log_path} has no {topic} topic "
                       f"(set {key}: false to run without it)")


def decide_sensor_use(cfg, log, source: str, log_path: str) -> SensorUse:
    """What the pipeline ``cfg`` fuses of ``log`` (a :class:`~trackfusion.sensors.types.SensorLog`);
    raises :class:`ConfigError` for a switched-on factor without its topic, and for GNSS fixes
    to fuse without a lever arm (module docstring)."""
    fs, sensors = cfg.factors, cfg.sensors
    use: dict[str, bool] = {}
    clocks: dict[str, Any] = {}
    out = SensorUse(use, clocks)
    for name, topic in TOPICS.items():
        present, on = _present(getattr(log, name)), getattr(fs, name).enabled
        if on and not present and _switched_on(cfg, name):
            raise _missing(source, log_path, f"factors.{name}", topic)
        use[name] = on and present
        clocks[name] = getattr(sensors, name)
        if use[name] and clocks[name] is None:
            if name == "gnss":
                raise ConfigError(f"{source}: sensors.gnss.lever_arm_b_m: the log {log_path} has {topic} and "
                                  "factors.gnss is on: give the antenna's lever arm in b (measured: it is never "
                                  "zero), or set factors.gnss: false")
            clocks[name] = ClockConfig()
            out.defaulted.append(f"{topic}: no sensors.{name} section, used with clock_offset_s 0 (default)")
        if present and not on:
            out.unused.append({"topic": topic, "reason": f"factors.{name} is off"})
    stations = sorted(log.total_stations)
    use["total_stations"] = fs.total_stations.enabled and bool(stations)
    if fs.total_stations.enabled and not stations:
        raise _missing(source, log_path, "factors.total_stations", TOTAL_STATION_TOPICS)
    if stations and not fs.total_stations.enabled:
        out.unused += [{"topic": f"/total_station/{s}", "reason": "factors.total_stations is off"} for s in stations]
    if fs.wheel_path.enabled and not use["odometer"]:
        why = "factors.odometer is off" if _present(log.odometer) else f"the log {log_path} has no /odometer topic"
        raise ConfigError(f"{source}: factors.wheel_path: on, but it needs the odometer and {why} "
                          "(set factors.wheel_path: false to run without it)")
    if _present(log.gauge) and not cfg.geometry.enabled:
        out.unused.append({"topic": "/gauge", "reason": "geometry is off"})
    return out


def summary_lines(metrics: dict) -> list[str]:
    """The run summary's lines on sensors used with defaults and sensors not used."""
    lines = [f"  default: {d}" for d in metrics.get("sensors_defaulted", [])]
    unused = metrics.get("sensors_unused", [])
    if unused:
        lines.append("  sensors in the log not used: " + ", ".join(f"{u['topic']} ({u['reason']})" for u in unused))
    return lines
