"""Initial alignment: coarse levelling, gyrocompassing, heading from the first displacement.

At rest the accelerometers measure ``f_b = R_nb^T (0, 0, g)`` (the reaction to gravity),
which with ``R_nb = Rz(yaw) Ry(-pitch) Rx(roll)`` is
``g (sin pitch, sin roll cos pitch, cos roll cos pitch)``; the gyros measure the Earth
rate ``R_nb^T (0, W cos lat, W sin lat)`` (ENU) plus their bias. Levelling the gyro
mean with roll and pitch gives ``(W cos lat sin yaw, W cos lat cos yaw, W sin lat)``, hence
the heading. The error is about ``gyro bias / (W cos lat)`` [rad] (0.01 deg/h at 43 deg:
1e-3 rad), so gyrocompassing is used for navigation-grade gyros only; otherwise the
heading comes from the direction of the first metres of GNSS or prism displacement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FusionError
from ..geodesy import OMEGA_IE_RADPS
from ..rotations import R_from_ypr

#: gyro bias below which gyrocompassing is trusted [deg/h] (heading error ~ bias/(15 cos lat) rad)
GYROCOMPASS_MAX_BIAS_DEG_PER_H = 0.1
#: without any displacement, a coarse gyrocompass (a FOG's 0.5 deg/h: ~2.5 deg) beats no heading
COARSE_GYROCOMPASS_MAX_BIAS_DEG_PER_H = 2.0


@dataclass
class Alignment:
    """Initial attitude of ``b`` at the first keyframe and how it was found.

    roll_rad, pitch_rad, yaw_rad [rad]; method: ``"gyrocompass"``, ``"displacement"``,
    ``"coarse-gyrocompass"`` (gyros of up to 2 deg/h and nothing better: heading good to a few
    degrees) or ``"none"`` (no heading information: yaw 0, trajectory in an arbitrary azimuth);
    static_s: duration of the static data used [s].
    """

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    method: str
    static_s: float

    @property
    def R_nb(self) -> np.ndarray:
        """(3, 3) rotation ``b`` to ``n``."""
        return R_from_ypr(self.yaw_rad, self.pitch_rad, self.roll_rad)

    def to_json(self) -> dict:
        """Degrees for people."""
        return {"roll_deg": float(np.degrees(self.roll_rad)), "pitch_deg": float(np.degrees(self.pitch_rad)),
                "yaw_deg": float(np.degrees(self.yaw_rad)), "heading_method": self.method,
                "static_s": self.static_s}


def level(accel_mean_b: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] from the mean specific force at rest (3,) [m/s^2]."""
    fx, fy, fz = np.asarray(accel_mean_b, dtype=float)
    if not np.hypot(np.hypot(fx, fy), fz) > 1.0:
        raise FusionError("initial alignment: the static accelerometer mean is not gravity-like")
    return float(np.arctan2(fy, fz)), float(np.arctan2(fx, np.hypot(fy, fz)))


def gyrocompass(gyro_mean_b: np.ndarray, roll_rad: float, pitch_rad: float) -> float:
    """Heading (yaw) [rad] from the mean gyro output at rest (3,) [rad/s] and the attitude's tilt."""
    R_lb = R_from_ypr(0.0, pitch_rad, roll_rad)  # b to the level frame of yaw 0
    w_l = R_lb @ np.asarray(gyro_mean_b, dtype=float)
    return float(np.arctan2(w_l[0], w_l[1]))


def heading_from_displacement(displacement_n: np.ndarray, forward: bool, R_vb: np.ndarray,
                              roll_rad: float, pitch_rad: float) -> float:
    """Yaw of ``b`` [rad] such that the trolley's x axis points along ``displacement_n`` (3,)
    (or against it when the trolley moved backwards); R_vb (3,3) the mounting rotation."""
    d = np.asarray(displacement_n, dtype=float) * (1.0 if forward else -1.0)
    course = np.arctan2(d[1], d[0])
    x_b = R_vb.T @ np.array([1.0, 0.0, 0.0])
    x_level = R_from_ypr(0.0, pitch_rad, roll_rad) @ x_b  # trolley axis at yaw 0
    return float(course - np.arctan2(x_level[1], x_level[0]))


def align(gyro_b: np.ndarray, accel_b: np.ndarray, lat_rad: float, gyro_bias_deg_per_h: float,
          static_s: float, displacement: tuple[np.ndarray, bool] | None, R_vb: np.ndarray) -> Alignment:
    """Initial attitude from the static samples at the start ((N,3) gyro [rad/s] and accel
    [m/s^2]; may be empty when the run starts moving) and, when gyrocompassing is not possible,
    the first displacement ``(displacement_n, forward)``.

    Raises :class:`FusionError` when there is no static data to level with.
    """
    if accel_b.shape[0] == 0:
        raise FusionError("initial alignment needs a static period at the start of the run "
                          "(none detected; see static detection settings)")
    roll, pitch = level(accel_b.mean(axis=0))
    horizontal_rate = OMEGA_IE_RADPS * np.cos(lat_rad)
    if gyro_bias_deg_per_h <= GYROCOMPASS_MAX_BIAS_DEG_PER_H and horizontal_rate > 1e-6:
        return Alignment(roll, pitch, gyrocompass(gyro_b.mean(axis=0), roll, pitch), "gyrocompass", static_s)
    if displacement is not None:
        d, forward = displacement
        return Alignment(roll, pitch, heading_from_displacement(d, forward, R_vb, roll, pitch),
                         "displacement", static_s)
    if gyro_bias_deg_per_h <= COARSE_GYROCOMPASS_MAX_BIAS_DEG_PER_H and horizontal_rate > 1e-6:
        return Alignment(roll, pitch, gyrocompass(gyro_b.mean(axis=0), roll, pitch), "coarse-gyrocompass", static_s)
    return Alignment(roll, pitch, 0.0, "none", static_s)
