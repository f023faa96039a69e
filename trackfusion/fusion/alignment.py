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
    static_s: duration of the static data used [s]; epoch: where the attitude holds, ``"start"``
    (static period at the start), ``"end"`` (none at the start: the static period at the end; the
    smoother chains the attitude back to the start) or ``"moving"`` (no static period at either
    end: levelled with the mean specific force of the first seconds, corrected for the
    acceleration along the track, heading from the GNSS displacement).
    """

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    method: str
    static_s: float
    epoch: str = "start"

    @property
    def R_nb(self) -> np.ndarray:
        """(3, 3) rotation ``b`` to ``n``."""
        return R_from_ypr(self.yaw_rad, self.pitch_rad, self.roll_rad)

    def to_json(self) -> dict:
        """Degrees for people."""
        return {"roll_deg": float(np.degrees(self.roll_rad)), "pitch_deg": float(np.degrees(self.pitch_rad)),
                "yaw_deg": float(np.degrees(self.yaw_rad)), "heading_method": self.method,
                "static_s": self.static_s, "epoch": self.epoch}


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


# --- which data the alignment uses (a run without a static period at one end) -------------------------

#: a static interval starting (ending) within this time of the first (last) IMU sample is at that end [s]
END_MARGIN_S = 5.0
#: levelling while moving averages the specific force over this long [s]
MOVING_LEVEL_S = 10.0


def _displacement(problem, from_end: bool) -> tuple[np.ndarray, bool] | None:
    """First (or, ``from_end``, last) GNSS displacement of more than 5 m in the direction of travel,
    and whether the trolley moved forwards then (from the odometer; forwards without one)."""
    g = problem.gnss
    if g is None or g.t_s.size < 2:
        return None
    ref = -1 if from_end else 0
    far = np.flatnonzero(np.linalg.norm(g.pos_n - g.pos_n[ref], axis=1) > 5.0)
    if not far.size:
        return None
    i = far[-1] if from_end else far[0]
    a, b = (i, g.t_s.size - 1) if from_end else (0, i)
    forward = True
    odo = problem.odometer
    if odo is not None:
        forward = bool(np.interp(g.t_s[b], odo.t_s, odo.distance_m) >= np.interp(g.t_s[a], odo.t_s, odo.distance_m))
    return g.pos_n[b] - g.pos_n[a], forward


def _moving_level(problem) -> tuple[float, float]:
    """Roll and pitch [rad] from the mean specific force over the first ``MOVING_LEVEL_S`` of a run
    that starts moving, minus the mean acceleration along the trolley axis (change of the odometer
    or GNSS speed over the window)."""
    imu = problem.imu
    t0 = imu.t_s[0]
    t1 = min(t0 + MOVING_LEVEL_S, imu.t_s[-1])
    sel = imu.t_s <= t1
    odo, g = problem.odometer, problem.gnss
    if odo is not None:
        speed = np.gradient(odo.distance_m, odo.t_s)
        v0, v1 = np.interp([t0, t1], odo.t_s, speed)
    else:
        v = np.linalg.norm(np.gradient(g.pos_n, g.t_s, axis=0), axis=1)
        v0, v1 = np.interp([t0, t1], g.t_s, v)
    accel_along = (v1 - v0) / max(t1 - t0, 1e-9)
    return level(imu.accel_mps2[sel].mean(axis=0) - accel_along * problem.trolley.axis_b)


def initial_alignment(problem) -> Alignment:
    """The initial attitude of a :class:`~trackfusion.fusion.problem.FusionProblem`.

    Uses the static period at the start of the run (within ``END_MARGIN_S``); without one, the
    static period at the end (``epoch="end"``); without either, levelling while moving and the
    GNSS heading (``epoch="moving"``). Raises :class:`FusionError` when there is no static period
    at either end and no GNSS (no heading and no level).
    """
    imu, t = problem.imu, problem.imu.t_s
    lat = np.radians(problem.origin.lat_deg)
    intervals = problem.static_intervals_s
    start = [iv for iv in intervals if iv[0] <= t[0] + END_MARGIN_S]
    end = [iv for iv in intervals if iv[1] >= t[-1] - END_MARGIN_S]
    for ivs, epoch in ((start, "start"), (end, "end")):
        if ivs:
            a, b = ivs[0] if epoch == "start" else ivs[-1]
            sel = (t >= a) & (t <= b)
            al = align(imu.gyro_radps[sel], imu.accel_mps2[sel], lat, problem.imu_gyro_bias_deg_per_h, float(b - a),
                       _displacement(problem, from_end=epoch == "end"), problem.trolley.R_vb)
            al.epoch = epoch
            return al
    displacement = _displacement(problem, from_end=False)
    if displacement is None:
        raise FusionError("initial alignment: no static period at either end of the run and no GNSS "
                          "displacement to take the heading from (see the static detection settings)")
    roll, pitch = _moving_level(problem)
    d, forward = displacement
    return Alignment(roll, pitch, heading_from_displacement(d, forward, problem.trolley.R_vb, roll, pitch),
                     "displacement", 0.0, "moving")


def back_to_start(R_chain: np.ndarray, R_end: np.ndarray, omega_ie_n: np.ndarray, duration_s: float) -> np.ndarray:
    """Attitude (3,3) at the start such that the attitude chain ends at ``R_end`` (3,3).

    ``R_chain`` (K,3,3) is a chain ``R[k] = E_k R[0] D_k`` started anywhere, where ``E_k`` is the
    Earth's rotation (about one axis, so the factors commute) and ``D_k`` the body rotations;
    ``omega_ie_n`` (3,) [rad/s], ``duration_s`` the chain's span [s]."""
    from ..rotations import so3_exp
    E = so3_exp(-np.asarray(omega_ie_n, dtype=float) * duration_s)
    return E.T @ R_end @ R_chain[-1].T @ E @ R_chain[0]
