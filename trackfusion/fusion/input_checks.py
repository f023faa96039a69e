"""Plausibility checks of a log against its pipeline before fusion (bad input, exit code 2).

The log reader (:mod:`trackfusion.sensors.mcap_log`) checks each record on its own (finite
numbers, time strictly increasing per topic, known topics and schemas). The checks here look
at whole series against the sensor specification, where a record-by-record check cannot see
the fault:

* :func:`check_imu_saturation`: an axis flat-lined at its measurement range (``ImuSpec``
  ``gyro_range_deg_per_s``, ``accel_range_mps2``), or values beyond the range (units or
  specification wrong). A saturated IMU has lost the true rate or force, and every
  preintegrated interval over it is wrong: the run is refused, naming the record.
* :func:`check_imu_units`, :func:`check_static_gyro_units`: specific force in g instead of
  m/s^2, angular rate in deg/s instead of rad/s; the log's IMU rate against ``rate_hz``.
* :func:`check_odometer_units`, :func:`check_gnss`, :func:`check_inclinometer_units`:
  odometer in mm, non-positive GNSS covariances, fixes far from the origin (degrees and
  radians mixed up, or latitude and longitude swapped), angles in degrees.

Every check raises :class:`SensorDataError` (or :class:`ConfigError` for a specification that
contradicts the log) with one line naming the file, the topic and the record index. Pure maths:
``source`` is only a label for the messages. All checks are vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import geodesy
from ..errors import ConfigError, SensorDataError
from ..geodesy import OMEGA_IE_RADPS
from ..sensors.imu import ImuSpec
from ..sensors.types import GnssData, ImuData, InclinometerData, OdometerData

__all__ = ["check_imu_saturation", "check_imu_units", "check_static_gyro_units", "check_odometer_units",
           "check_gnss", "check_inclinometer_units", "SATURATION_MIN_SAMPLES"]

#: this many consecutive identical samples of one axis at (within 1 % of) its range limit are a
#: saturation; fewer may be a legitimate extreme value that happens to repeat
SATURATION_MIN_SAMPLES = 3
#: values beyond this multiple of the range cannot come from the specified IMU
_BEYOND_RANGE = 1.01
_G0 = 9.80665
#: fastest plausible trolley speed [m/s] (a survey trolley is pushed at up to a few m/s)
MAX_TROLLEY_SPEED_MPS = 30.0
#: largest plausible distance of a fix from the origin of ``n`` [m]
MAX_FIX_DISTANCE_M = 200e3
#: largest plausible roll or pitch of a railway trolley [rad] (cant < 0.2 rad, gradients < 0.1)
MAX_TILT_RAD = 0.35


def _flat_runs_at_limit(x: np.ndarray, limit: float) -> tuple[int, int] | None:
    """First run of >= SATURATION_MIN_SAMPLES equal values with |value| >= 0.99 limit in ``x``
    (N,): (first index, length), or None."""
    at_limit = np.abs(x) >= 0.99 * limit
    same = np.r_[False, x[1:] == x[:-1]] & at_limit & np.r_[False, at_limit[:-1]]
    edges = np.diff(np.r_[0, same.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    long = (stops - starts + 1) >= SATURATION_MIN_SAMPLES
    if not long.any():
        return None
    k = int(np.argmax(long))
    return int(starts[k]) - 1, int(stops[k] - starts[k] + 1)


def check_imu_saturation(imu: ImuData, spec: ImuSpec, source: str) -> None:
    """Refuse an IMU log with an axis flat-lined at its range limit or beyond its range.

    imu: samples (N,) with gyro (N,3) [rad/s] and accel (N,3) [m/s^2]; spec: the IMU
    specification (``gyro_range_deg_per_s``, ``accel_range_mps2``); source: file label.
    """
    names = ("angular_velocity", "linear_acceleration")
    limits = (np.radians(spec.gyro_range_deg_per_s), spec.accel_range_mps2)
    keys = ("sensors.imu.gyro_range_deg_per_s", "sensors.imu.accel_range_mps2")
    for name, data, limit, key in zip(names, (imu.gyro_radps, imu.accel_mps2), limits, keys):
        beyond = np.abs(data) > _BEYOND_RANGE * limit
        if beyond.any():
            i, a = np.unravel_index(int(np.argmax(beyond)), beyond.shape)
            raise SensorDataError(
                f"{source}: /imu record {i}: {name}.{'xyz'[a]} = {data[i, a]:.6g} is beyond the IMU's range "
                f"+-{limit:.6g} ({key}): wrong units or wrong range in the specification")
        for a in range(3):
            run = _flat_runs_at_limit(data[:, a], limit)
            if run is not None:
                i, n = run
                raise SensorDataError(
                    f"{source}: /imu record {i} (t = {imu.t_s[i]:.3f} s): {name}.{'xyz'[a]} flat at "
                    f"{data[i, a]:.6g} for {n} samples, at the range limit +-{limit:.6g} ({key}): "
                    "the IMU saturated; the run cannot be fused through it")


def check_imu_units(imu: ImuData, spec: ImuSpec, source: str, pipeline_source: str) -> None:
    """Specific force in m/s^2 (median norm within 20 % of g) and the log's IMU rate equal to the
    specification's ``rate_hz`` (within 2 %)."""
    norm = np.linalg.norm(imu.accel_mps2, axis=1)
    median = float(np.median(norm))
    if not 0.8 * _G0 < median < 1.2 * _G0:
        hint = " (in g, not m/s^2?)" if 0.8 < median < 1.2 else ""
        raise SensorDataError(f"{source}: /imu: median linear_acceleration norm {median:.4g} m/s^2 is not "
                              f"gravity-like (~9.8){hint}")
    rate_hz = 1.0 / float(np.median(np.diff(imu.t_s)))
    if abs(rate_hz / spec.rate_hz - 1.0) > 0.02:
        raise ConfigError(f"{pipeline_source}: sensors.imu.rate_hz: {spec.rate_hz:g} Hz, but the /imu topic "
                          f"of the log runs at {rate_hz:.6g} Hz")


def odometer_rest_intervals(odometer: OdometerData | None, window_s: float = 2.0,
                            max_speed_mps: float = 1e-3) -> list[tuple[float, float]]:
    """Intervals [s] of at least ``window_s`` where the odometer moves by less than
    ``max_speed_mps * window_s``: the trolley at rest, whatever the IMU says."""
    if odometer is None or odometer.t_s.size < 2:
        return []
    t, d = odometer.t_s, odometer.distance_m
    j = np.searchsorted(t, t + window_s)
    ok = j < t.size
    i = np.flatnonzero(ok)
    quiet = np.flatnonzero(np.abs(d[j[ok]] - d[i]) < max_speed_mps * window_s)
    step = max(1, int(window_s / np.median(np.diff(t))))   # windows about one window apart
    return [(float(t[i[k]]), float(t[j[i[k]]])) for k in quiet[::step]]


def check_static_gyro_units(imu: ImuData, spec: ImuSpec, rest_intervals_s: list[tuple[float, float]],
                            source: str) -> None:
    """At rest the gyro measures the Earth rate plus its bias. When even the quietest interval at
    rest (``rest_intervals_s``: detected static intervals and intervals where the odometer stands
    still) shows a mean rate above 5x the Earth rate plus the specified bias and bias instability,
    the angular rate is not in rad/s (deg/s, say)."""
    limit = 5.0 * (OMEGA_IE_RADPS + np.radians(spec.gyro_bias_deg_per_h + spec.gyro_bias_instability_deg_per_h)
                   / 3600.0)
    if not rest_intervals_s:
        return
    ab = np.asarray(rest_intervals_s, dtype=float)
    i0 = np.searchsorted(imu.t_s, ab[:, 0])
    i1 = np.searchsorted(imu.t_s, ab[:, 1], side="right")
    ok = i1 - i0 >= 2
    if not ok.any():
        return
    cum = np.zeros((imu.t_s.size + 1, 3))  # one buffer, filled in place (long runs: memory)
    np.subtract(imu.gyro_radps, imu.gyro_radps[0], out=cum[1:])
    np.cumsum(cum[1:], axis=0, out=cum[1:])
    mean = (cum[i1[ok]] - cum[i0[ok]]) / (i1[ok] - i0[ok])[:, None] + imu.gyro_radps[0]
    rate = np.linalg.norm(mean, axis=1)
    k = int(np.argmin(rate))
    if rate[k] > limit:
        (a, b), i = ab[ok][k], int(i0[ok][k])
        raise SensorDataError(
            f"{source}: /imu record {i}: at rest from {a:.1f} to {b:.1f} s the mean angular rate is "
            f"{rate[k]:.3g} rad/s, more than the Earth rate plus the gyro bias allow ({limit:.3g}): "
            "angular_velocity not in rad/s?")


def check_odometer_units(odometer: OdometerData, source: str, gnss_path_m: float | None = None,
                         max_speed_mps: float = MAX_TROLLEY_SPEED_MPS, vehicle: str = "trolley") -> None:
    """Odometer speed over 1 s no faster than the vehicle (``max_speed_mps``, a trolley's 30 m/s by
    default), and, when the GNSS path is longer than 50 m, the odometer path between half and
    twice it (``gnss_path_m`` [m])."""
    t, d = odometer.t_s, odometer.distance_m
    if t.size < 2:
        return
    j = np.minimum(np.searchsorted(t, t + 1.0), t.size - 1)
    ok = j > np.arange(t.size)
    speed = np.abs(d[j] - d)[ok] / (t[j] - t)[ok]
    if speed.size and speed.max() > max_speed_mps:
        i = int(np.flatnonzero(ok)[int(np.argmax(speed))])
        raise SensorDataError(f"{source}: /odometer record {i}: {speed.max():.4g} m/s over 1 s is faster than a "
                              f"{vehicle} ({max_speed_mps:g} m/s): distance_m not in metres?")
    path_m = float(np.abs(np.diff(d)).sum())
    if gnss_path_m is not None and gnss_path_m > 50.0 and not 0.5 < path_m / gnss_path_m < 2.0:
        raise SensorDataError(f"{source}: /odometer: path length {path_m:.6g} m against {gnss_path_m:.6g} m of "
                              "GNSS fixes: distance_m not in metres?")


def gnss_path_length_m(pos_n: np.ndarray) -> float:
    """Horizontal path length [m] of fixes (N,3) [m], ignoring steps under 5 cm (fix noise at rest)."""
    step = np.linalg.norm(np.diff(pos_n[:, :2], axis=0), axis=1)
    return float(step[step > 0.05].sum())


def check_gnss(gnss: GnssData, pos_n: np.ndarray, source: str) -> None:
    """Each reported covariance symmetric with positive variances, and each fix (positions ``pos_n``
    (N,3) [m] in ``n``) within 200 km of the origin."""
    cov = gnss.cov_enu_m2
    diag = np.diagonal(cov, axis1=1, axis2=2)
    bad = ~(diag > 0).all(axis=1) | ~np.isclose(cov, np.swapaxes(cov, 1, 2), rtol=1e-6, atol=1e-12).all(axis=(1, 2))
    if bad.any():
        i = int(np.argmax(bad))
        raise SensorDataError(f"{source}: /gnss record {i}: position_covariance must be symmetric with positive "
                              f"variances, got diagonal {diag[i].tolist()}")
    dist = np.linalg.norm(pos_n, axis=1)
    far = dist > MAX_FIX_DISTANCE_M
    if far.any():
        i = int(np.argmax(far))
        raise SensorDataError(f"{source}: /gnss record {i}: the fix ({gnss.lat_deg[i]:.6f}, {gnss.lon_deg[i]:.6f}) "
                              f"is {dist[i] / 1e3:.0f} km from the origin: latitude/longitude not in degrees, "
                              "swapped, or the wrong origin?")


def check_inclinometer_units(inc: InclinometerData, source: str) -> None:
    """Roll and pitch of a railway trolley stay below 0.35 rad (20 deg)."""
    for name, x in (("roll_rad", inc.roll_rad), ("pitch_rad", inc.pitch_rad)):
        big = np.abs(x) > MAX_TILT_RAD
        if big.any():
            i = int(np.argmax(big))
            raise SensorDataError(f"{source}: /inclinometer record {i}: {name} = {x[i]:.4g} is steeper than a "
                                  f"railway ({MAX_TILT_RAD} rad): degrees instead of radians?")


@dataclass(frozen=True)
class AidingSensors:
    """The aiding sensors' data a pipeline uses (None: not used, or not in the log)."""

    gnss: GnssData | None = None
    odometer: OdometerData | None = None
    inclinometer: InclinometerData | None = None


def _checked_gnss_positions(gnss: GnssData, origin, source: str) -> np.ndarray | None:
    """The fixes' positions (N,3) [m] in ``n`` (``origin`` its :class:`~trackfusion.geodesy.Origin`)
    once their latitude and longitude are degrees and :func:`check_gnss` passes; None without fixes."""
    if not gnss.t_s.size:
        return None
    bad = ~(np.abs(gnss.lat_deg) <= 90.0) | ~(np.abs(gnss.lon_deg) <= 360.0)
    if bad.any():
        i = int(np.argmax(bad))
        raise SensorDataError(f"{source}: /gnss record {i}: latitude {gnss.lat_deg[i]!r}, longitude "
                              f"{gnss.lon_deg[i]!r} are not geodetic degrees (swapped?)")
    pos_n = geodesy.geodetic_to_n(gnss.lat_deg, gnss.lon_deg, gnss.h_m, origin)
    check_gnss(gnss, pos_n, source)
    return pos_n


def check_log(imu: ImuData, spec: ImuSpec, origin, source: str, pipeline_source: str,
              aiding: AidingSensors = AidingSensors(), *, max_speed_mps: float = MAX_TROLLEY_SPEED_MPS,
              vehicle: str = "trolley") -> None:
    """Every check above on the IMU and the ``aiding`` sensors a pipeline uses; ``origin``: the
    :class:`~trackfusion.geodesy.Origin` of ``n``; ``max_speed_mps``: the fastest the ``vehicle``
    (its kind, for the message) goes."""
    check_imu_saturation(imu, spec, source)
    check_imu_units(imu, spec, source, pipeline_source)
    pos_n = _checked_gnss_positions(aiding.gnss, origin, source) if aiding.gnss is not None else None
    if aiding.odometer is not None:
        check_odometer_units(aiding.odometer, source, gnss_path_length_m(pos_n) if pos_n is not None else None,
                             max_speed_mps, vehicle)
    if aiding.inclinometer is not None:
        check_inclinometer_units(aiding.inclinometer, source)
