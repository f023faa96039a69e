"""In-memory sensor data: one dataclass of numpy arrays per sensor, and the whole log.

Times ``t_s`` are float seconds on the recording sensor's own clock (the IMU
clock for every sensor except the total stations, which keep their own).
Shapes: N samples per sensor; vectors are (N, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


def finite_array(x, n: int, name: str, field_name: str, width: int | None, error: type[Exception]) -> np.ndarray:
    """``x`` as a float array of shape (n,) or (n, width) with finite values; otherwise raise
    ``error`` with one line naming ``name`` and ``field_name``."""
    a = np.asarray(x, dtype=float)
    shape = (n,) if width is None else (n, width)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise error(f"{name}: {field_name} must be finite with shape {shape}, got {a.shape}")
    return a


@dataclass
class ImuData:
    """IMU samples: ``t_s`` (N,) [s]; ``gyro_radps`` (N, 3) angular rate w.r.t. inertial space in
    ``b`` [rad/s]; ``accel_mps2`` (N, 3) specific force in ``b`` [m/s^2]. Each sample is the mean
    over the interval (t_s - dt, t_s] (an integrating IMU's delta-angle and delta-velocity over dt)."""

    t_s: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray


@dataclass
class OdometerData:
    """Odometer: ``t_s`` (N,) [s]; ``distance_m`` (N,) cumulative signed distance [m];
    ``ticks`` (N,) cumulative signed encoder count (int64)."""

    t_s: np.ndarray
    distance_m: np.ndarray
    ticks: np.ndarray


@dataclass
class GnssData:
    """GNSS fixes: ``t_s`` (N,) [s]; ``lat_deg``, ``lon_deg`` (N,) [deg]; ``h_m`` (N,) ellipsoidal
    height [m]; ``cov_enu_m2`` (N, 3, 3) position covariance in local ENU [m^2];
    ``fix_quality`` (N,) int (NMEA GGA: 1 single, 2 DGNSS, 4 RTK fixed, 5 RTK float)."""

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    h_m: np.ndarray
    cov_enu_m2: np.ndarray
    fix_quality: np.ndarray


@dataclass
class TotalStationData:
    """Polar observations of one robotic total station, on the *station's* clock.

    ``t_s`` (N,) [s, station clock]; ``horizontal_angle_rad``, ``zenith_angle_rad`` (N,) [rad];
    ``slope_distance_m`` (N,) [m]; ``prism_id`` (N,) str (object array)."""

    station_id: str
    t_s: np.ndarray
    horizontal_angle_rad: np.ndarray
    zenith_angle_rad: np.ndarray
    slope_distance_m: np.ndarray
    prism_id: np.ndarray


@dataclass
class InclinometerData:
    """Inclinometer: ``t_s`` (N,) [s]; ``roll_rad``, ``pitch_rad`` (N,) [rad] (conventions of the package)."""

    t_s: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray


@dataclass
class GaugeData:
    """Gauge sensor: ``t_s`` (N,) [s]; ``gauge_m`` (N,) track gauge between running edges [m]."""

    t_s: np.ndarray
    gauge_m: np.ndarray


@dataclass
class SensorLog:
    """A whole raw log: every sensor present (``None`` or empty dict where absent) and the run
    metadata (record name -> JSON-able dict: survey description, sensor specifications, lever
    arms, total-station set-ups). ``source``: set by
    :func:`~trackfusion.sensors.mcap_log.read_log` when the log was read whole from an intact
    file (a :class:`~trackfusion.sensors.mcap_log.RawSource`: what ``fused.mcap`` needs to copy
    the file's records byte for byte); not part of the log's value (ignored by ``==``)."""

    imu: ImuData | None = None
    odometer: OdometerData | None = None
    gnss: GnssData | None = None
    total_stations: dict[str, TotalStationData] = field(default_factory=dict)
    inclinometer: InclinometerData | None = None
    gauge: GaugeData | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    source: Any = field(default=None, compare=False, repr=False)
