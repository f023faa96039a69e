"""The ``vehicle:`` section of a pipeline: what carries the IMU, and which factors its kind supports.

Three kinds (docs/pipeline.md, "vehicle"). In each, ``v`` is the vehicle frame (x forward, y left,
z up) and ``v``'s origin the point the non-holonomic constraint (NHC) holds at: the point with
no lateral and no vertical velocity in ``v``.

* ``trolley``: a rigid survey trolley. ``v``'s origin is midway between the two reference-rail
  wheel contacts (``wheelbase_m`` apart), where the NHC is exact on a circular arc; the encoder
  wheel is the rear or front one. All factors, the wheel path and the track geometry.
* ``rail-vehicle``: a rail vehicle (measuring car, locomotive) with the IMU on a bogie frame or
  the car body. ``axle_distance_m`` is the distance between the two axles of that bogie (IMU on
  the bogie) or between the two bogie centres (IMU on the body); ``v``'s origin is midway
  between them on the reference rail; the odometer sits on the rear or front axle. Wheelsets
  have lateral play and hunt, so no rigid wheel path; track geometry from the pose.
* ``road-vehicle``: a car. ``v``'s origin is the centre of the rear (non-steered) axle, where a
  car neither slips sideways nor moves vertically (nearly); the speed is measured there unless
  ``odometer_lever_arm_v_m`` says where the measuring wheel is (the mean of the two rear
  wheels' speeds is the axle centre's). No wheel path, no track geometry.

The legacy ``trolley:`` section reads as ``vehicle: {kind: trolley, ...}``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import Field

from .errors import ConfigError
from .fusion.problem import TrolleyFrame
from .strict import StrictModel

Vec3 = tuple[float, float, float]

#: the kinds, in the order docs and ``trackfusion init --vehicle`` list them
VEHICLE_KINDS = ("trolley", "rail-vehicle", "road-vehicle")


class _Mounted(StrictModel):
    """Where the IMU sits: its origin in ``v`` [m] and the mounting angles of ``b`` in ``v``
    (yaw, pitch, roll) [deg]."""

    lever_arm_imu_v_m: Vec3
    mounting_ypr_deg: Vec3 = (0.0, 0.0, 0.0)


class TrolleyVehicle(_Mounted):
    """A rigid survey trolley: wheelbase of the reference-rail wheels, the encoder wheel."""

    kind: Literal["trolley"] = "trolley"
    wheelbase_m: float = Field(gt=0)
    reference_rail: Literal["left", "right"] = "left"
    odometer_wheel: Literal["rear", "front"] = "rear"


class RailVehicle(_Mounted):
    """A rail vehicle: the distance of the two axles (or bogie centres) whose midpoint on the
    reference rail is ``v``'s origin; the odometer's axle."""

    kind: Literal["rail-vehicle"]
    axle_distance_m: float = Field(gt=0)
    reference_rail: Literal["left", "right"] = "left"
    odometer_axle: Literal["rear", "front"] = "rear"


class RoadVehicle(_Mounted):
    """A road vehicle (``v``'s origin: centre of the rear axle) and where its speed is measured
    in ``v`` [m] (default: the rear axle centre)."""

    kind: Literal["road-vehicle"]
    odometer_lever_arm_v_m: Vec3 | None = None


VehicleConfig = Annotated[Union[TrolleyVehicle, RailVehicle, RoadVehicle], Field(discriminator="kind")]


def vehicle_section(data: Any) -> Any:
    """The pipeline mapping with ``trolley:`` read as ``vehicle: {kind: trolley, ...}`` (both
    given: refused), and a road vehicle's ``geometry`` off unless written (before validation)."""
    if not isinstance(data, dict):
        return data
    data = dict(data)
    if "trolley" in data:
        if "vehicle" in data:
            raise ValueError("give vehicle: or the older trolley:, not both")
        old = data.pop("trolley")
        data["vehicle"] = {"kind": "trolley", **old} if isinstance(old, dict) else old
    vehicle = data.get("vehicle")
    if isinstance(vehicle, dict) and vehicle.get("kind") == "road-vehicle":
        geometry = data.get("geometry")
        if geometry is None or (isinstance(geometry, dict) and "enabled" not in geometry):
            data["geometry"] = {**(geometry or {}), "enabled": False}
    return data


def error_location(loc: tuple, wrote_trolley: bool) -> tuple:
    """A validation error's field path as the user wrote it: without the union's kind tag, under
    ``trolley`` when the file has the older section."""
    loc = tuple(loc)
    if loc[:1] == ("vehicle",):
        if len(loc) > 1 and loc[1] in VEHICLE_KINDS:
            loc = loc[:1] + loc[2:]
        if wrote_trolley:
            loc = ("trolley",) + loc[1:]
    return loc


def frame_of(vehicle: TrolleyVehicle | RailVehicle | RoadVehicle) -> TrolleyFrame:
    """The :class:`~trackfusion.fusion.problem.TrolleyFrame` the fusion uses for ``vehicle``:
    mounting, IMU lever arm in ``v``, and the odometer's point (a reference-rail wheel a half
    wheelbase from the origin; a road vehicle's given point or the origin)."""
    if isinstance(vehicle, TrolleyVehicle):
        return TrolleyFrame.from_angles(vehicle.mounting_ypr_deg, vehicle.lever_arm_imu_v_m, vehicle.wheelbase_m,
                                        vehicle.odometer_wheel)
    if isinstance(vehicle, RailVehicle):
        return TrolleyFrame.from_angles(vehicle.mounting_ypr_deg, vehicle.lever_arm_imu_v_m, vehicle.axle_distance_m,
                                        vehicle.odometer_axle, kind="rail-vehicle")
    point = np.zeros(3) if vehicle.odometer_lever_arm_v_m is None else np.asarray(vehicle.odometer_lever_arm_v_m)
    return TrolleyFrame.from_angles(vehicle.mounting_ypr_deg, vehicle.lever_arm_imu_v_m, 0.0, kind="road-vehicle",
                                    odometer_point_v=point)


#: fastest plausible speed of each kind [m/s] (the odometer's units check, fusion/input_checks.py):
#: a pushed or motorised trolley; a rail vehicle up to 360 km/h; a car up to 250 km/h
MAX_SPEED_MPS = {"trolley": 30.0, "rail-vehicle": 100.0, "road-vehicle": 70.0}

#: what each kind cannot use: pipeline key -> (kinds that support it, why the others do not)
KIND_SUPPORT = {
    "factors.wheel_path": (("trolley",), "it needs a rigid trolley whose rear reference-rail wheel runs where "
                                         "its front one ran"),
    "geometry.enabled": (("trolley", "rail-vehicle"), "track geometry needs rail wheels on the rails"),
}


def check_vehicle_support(cfg, source: str) -> None:
    """A :class:`ConfigError` naming the key and the kind when a factor or output is switched on
    that the vehicle's kind cannot use (:data:`KIND_SUPPORT`)."""
    kind = cfg.vehicle.kind
    switched_on = {"factors.wheel_path": cfg.factors.wheel_path.enabled, "geometry.enabled": cfg.geometry.enabled}
    for key, (kinds, why) in KIND_SUPPORT.items():
        if switched_on[key] and kind not in kinds:
            raise ConfigError(f"{source}: {key}: not for vehicle.kind {kind} ({why}; supported by "
                              f"{', '.join(kinds)}); switch it off")
