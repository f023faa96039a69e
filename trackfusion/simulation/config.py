"""Scenario configuration: a strict pydantic model loaded from YAML, with dotted ``--set`` overrides.

A scenario file names every physical choice of a simulated survey: the origin
of ``n``, the design alignment and irregularities, the trolley, its motion
plan and each sensor's specification. Unknown keys are refused, and every
error names its field path (``imu.rate_hz: Input should be greater than 0``).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import Field, ValidationError, model_validator

from ..errors import ConfigError, config_error_from_validation
from ..strict import StrictModel

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "data" / "scenarios"


class OriginConfig(StrictModel):
    """Origin of ``n``: geodetic latitude/longitude [deg] and ellipsoidal height [m]."""

    lat_deg: float = Field(ge=-90, le=90)
    lon_deg: float = Field(ge=-180, le=360)
    h_m: float = 0.0


class TrolleyConfig(StrictModel):
    """Trolley geometry (see :class:`trackfusion.simulation.trolley.TrolleyGeometry`)."""

    wheelbase_m: float = Field(1.0, gt=0)
    reference_rail: Literal["left", "right"] = "left"
    lever_arm_imu_v_m: tuple[float, float, float] = (0.0, -0.7175, 0.25)
    mounting_ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    odometer_wheel: Literal["rear", "front"] = "rear"


class SegmentConfig(StrictModel):
    """One motion segment: either ``hold_s`` or ``move_to_m`` (+ ``speed_mps``, ``accel_mps2``)."""

    hold_s: float | None = Field(None, gt=0)
    move_to_m: float | None = None
    speed_mps: float | None = Field(None, gt=0)
    accel_mps2: float = Field(0.3, gt=0)

    @model_validator(mode="after")
    def _one_kind(self) -> "SegmentConfig":
        if (self.hold_s is None) == (self.move_to_m is None):
            raise ValueError("give exactly one of hold_s or move_to_m")
        if self.move_to_m is not None and self.speed_mps is None:
            raise ValueError("a move needs speed_mps")
        return self


class MotionConfig(StrictModel):
    """Motion plan: start chainage [m] and the segments, optionally repeated ``passes`` times."""

    start_m: float
    segments: list[SegmentConfig] = Field(min_length=1)
    passes: int = Field(1, ge=1)


class TruthConfig(StrictModel):
    """Truth output: trajectory rate [Hz] (>= 50) and geometry chainage step [m]."""

    rate_hz: float = Field(100.0, ge=50)
    geometry_step_m: float = Field(0.25, gt=0)


class ScenarioConfig(StrictModel):
    """A whole simulated survey. Sensor sections are passed to the sensor models' own strict specs."""

    name: str
    description: str = ""
    origin: OriginConfig
    alignment: dict[str, Any]
    irregularities: dict[str, Any] = Field(default_factory=dict)
    trolley: TrolleyConfig = TrolleyConfig()
    motion: MotionConfig
    imu: dict[str, Any]
    odometer: dict[str, Any] | None = None
    gnss: dict[str, Any] | None = None
    total_stations: dict[str, Any] | None = None
    inclinometer: dict[str, Any] | None = None
    gauge: dict[str, Any] | None = None
    truth: TruthConfig = TruthConfig()


def available_scenarios() -> list[str]:
    """Names of the built-in scenarios."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def scenario_descriptions() -> dict[str, str]:
    """Built-in scenario name -> its one-line ``description`` (``trackfusion simulate --list``)."""
    from ..yamlio import load_yaml
    out = {}
    for name in available_scenarios():
        data = load_yaml(SCENARIO_DIR / f"{name}.yaml", "scenario file")
        out[name] = str(data.get("description", "")) if isinstance(data, dict) else ""
    return out


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Apply ``key.sub=value`` overrides (value parsed as YAML) to a nested dict; returns a copy.

    List elements are addressed by index (``motion.segments.1.speed_mps=1.2``).
    """
    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"--set {key}: value {raw!r} is not valid YAML") from None
        node: Any = out
        parts = key.split(".")
        for depth, part in enumerate(parts):
            last = depth == len(parts) - 1
            if isinstance(node, list):
                try:
                    idx = int(part)
                    node[idx]
                except (ValueError, IndexError):
                    raise ConfigError(f"--set {key}: no list element {part!r}") from None
                if last:
                    node[idx] = value
                else:
                    node = node[idx]
            elif isinstance(node, dict):
                if last:
                    node[part] = value
                else:
                    node = node.setdefault(part, {})
            else:
                raise ConfigError(f"--set {key}: {'.'.join(parts[:depth])} is not a section")
    return out


def load_scenario(name_or_path: str, overrides: list[str] | None = None) -> ScenarioConfig:
    """Load a built-in scenario by name, or a scenario YAML by path, and apply overrides.

    Raises :class:`ConfigError` naming the scenario and field at fault.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = SCENARIO_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown scenario {name_or_path!r} (built-in: {', '.join(available_scenarios())})")
    if not path.is_file():
        raise ConfigError(f"{path}: file not found")
    from ..yamlio import load_yaml
    data = load_yaml(path, "scenario file")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    data = apply_overrides(data, overrides or [])
    try:
        return ScenarioConfig.model_validate(data)
    except ValidationError as exc:
        raise config_error_from_validation(exc, str(path)) from None
