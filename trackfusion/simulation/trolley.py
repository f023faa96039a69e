"""A rigid survey trolley riding on two irregular rails: truth pose and kinematics.

Geometry (a T-shaped three-wheel trolley, as the common survey trolleys):
two wheels on the *reference rail* a wheelbase ``l`` apart, and a third wheel
on the other rail abreast of their midpoint. The trolley frame ``v`` is
defined by the three wheel-contact points alone:

- origin: midpoint of the two reference-rail contact points;
- x: from the rear to the front reference-rail contact point;
- z: normal to the plane of the three contact points, upwards;
- y = z x x (left).

Because the frame is fixed by where the wheels touch the rails, the wheelbase
filters short wavelengths exactly as on a real trolley: the frame height at
the origin is the mean of the two rail heights a wheelbase apart, which gives
the two-point transfer function ``cos(pi l / lambda)`` of seed 000 as a
consequence, not as a formula. (The finite wheel radius, which rounds off the
deepest corrugation troughs, is not modelled: contacts follow the rail
reference point.)

The IMU sits at ``lever_arm_imu_v`` in ``v`` with mounting rotation ``R_vb``.
The pose of ``b`` is computed on a fine chainage grid and represented by a
quintic spline (C4) of position and unwrapped yaw/pitch/roll against
chainage; with the analytic chainage-time law of :mod:`.motion` this gives
position, velocity, acceleration, attitude and body rate at any time, and the
IMU measurements as interval means (:meth:`TrolleyKinematics.imu_interval_means`: the rotation
and velocity change over each sample exact, the rest by 3-point Gauss-Legendre quadrature).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.interpolate import make_interp_spline

from .. import geodesy
from ..errors import SimulationError
from ..rotations import R_from_ypr, so3_log, ypr_from_R
from .motion import MotionProfile

_GL3_NODES = np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])  # on [-1, 1]
_GL3_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0  # normalised to sum 1


class RailModel(Protocol):
    """What the trolley needs of the track: reference points of each rail in ``n``."""

    def rail_points_n(self, s_m: np.ndarray, side: str) -> np.ndarray:  # (N, 3)
        ...


@dataclass(frozen=True)
class TrolleyGeometry:
    """Trolley dimensions and sensor mounting.

    wheelbase_m: distance between the two reference-rail wheels [m].
    reference_rail: ``"left"`` or ``"right"``, the rail carrying two wheels.
    lever_arm_imu_v: IMU origin in ``v`` [m], shape (3,).
    mounting_ypr_rad: (yaw, pitch, roll) of ``b`` relative to ``v`` [rad] (``R_vb``).
    odometer_wheel: ``"rear"`` or ``"front"`` reference-rail wheel carrying the encoder.
    """

    wheelbase_m: float = 1.0
    reference_rail: str = "left"
    lever_arm_imu_v: tuple[float, float, float] = (0.0, -0.7175, 0.25)
    mounting_ypr_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    odometer_wheel: str = "rear"

    def __post_init__(self) -> None:
        if not self.wheelbase_m > 0:
            raise SimulationError("trolley.wheelbase_m must be > 0")
        if self.reference_rail not in ("left", "right"):
            raise SimulationError("trolley.reference_rail must be 'left' or 'right'")
        if self.odometer_wheel not in ("rear", "front"):
            raise SimulationError("trolley.odometer_wheel must be 'rear' or 'front'")

    @property
    def other_rail(self) -> str:
        """The rail carrying the single wheel."""
        return "right" if self.reference_rail == "left" else "left"

    @property
    def R_vb(self) -> np.ndarray:
        """Mounting rotation from ``b`` to ``v``, (3, 3)."""
        return R_from_ypr(*self.mounting_ypr_rad)


def frame_from_contacts(front_n, rear_n, other_n, other_is_left: bool) -> tuple[np.ndarray, np.ndarray]:
    """Trolley frame from the three wheel-contact points, each (N, 3) in ``n``.

    Returns ``origin_n`` (N, 3) and ``R_nv`` (N, 3, 3) as defined in the module docstring.
    """
    x = front_n - rear_n
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    origin = 0.5 * (front_n + rear_n)
    w = other_n - origin
    y = w - np.sum(w * x, axis=-1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    if not other_is_left:
        y = -y
    z = np.cross(x, y)
    return origin, np.stack([x, y, z], axis=-1)


@dataclass
class TrolleyKinematics:
    """Truth pose of the IMU along the track, splined in chainage.

    Build with :meth:`build`. ``s_grid_m`` (M,) the chainage grid; the splines give
    ``pos_n`` (3) and unwrapped ``(yaw, pitch, roll)`` of ``R_nb`` against chainage,
    the odometer wheel's rolled arc length, and normal gravity in ``n``.
    """

    geometry: TrolleyGeometry
    origin: geodesy.Origin
    s_grid_m: np.ndarray
    _pose_spline: object = field(repr=False)
    _wheel_arc_spline: object = field(repr=False)
    _gravity_spline: object = field(repr=False)
    omega_ie_n: np.ndarray = field(repr=False, default=None)

    @classmethod
    def build(cls, rails: RailModel, geometry: TrolleyGeometry, origin: geodesy.Origin,
              s_min_m: float, s_max_m: float, ds_m: float = 0.005) -> "TrolleyKinematics":
        """Sample the pose on a chainage grid covering [s_min_m, s_max_m] (plus a margin) and spline it."""
        margin = 10 * ds_m
        n = int(np.ceil((s_max_m - s_min_m + 2 * margin) / ds_m)) + 1
        s = s_min_m - margin + ds_m * np.arange(n)
        pos_n, R_nb, contacts = _pose_on_grid(rails, geometry, s)
        yaw, pitch, roll = ypr_from_R(R_nb)
        ypr = np.column_stack([np.unwrap(yaw), pitch, roll])
        pose_spline = make_interp_spline(s, np.column_stack([pos_n, ypr]), k=5)
        wheel = contacts["front_n" if geometry.odometer_wheel == "front" else "rear_n"]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wheel, axis=0), axis=1))])
        wheel_arc_spline = make_interp_spline(s, arc, k=3)
        gravity_spline = make_interp_spline(s, geodesy.gravity_n(pos_n, origin), k=3)
        return cls(geometry, origin, s, pose_spline, wheel_arc_spline, gravity_spline,
                   geodesy.earth_rate_n(origin))

    # --- pose against chainage -------------------------------------------------------------
    def _check_range(self, s_m: np.ndarray) -> None:
        lo, hi = self.s_grid_m[0], self.s_grid_m[-1]
        if np.any(s_m < lo) or np.any(s_m > hi):
            raise SimulationError(f"chainage outside the built range [{lo:.3f}, {hi:.3f}] m")

    def pose_at_chainage(self, s_m) -> tuple[np.ndarray, np.ndarray]:
        """IMU position ``pos_n`` (N, 3) [m] and ``R_nb`` (N, 3, 3) at chainages ``s_m`` (N,)."""
        s = np.atleast_1d(np.asarray(s_m, dtype=float))
        self._check_range(s)
        y = self._pose_spline(s)
        return y[:, :3], R_from_ypr(y[:, 3], y[:, 4], y[:, 5])

    def wheel_distance_m(self, s_m) -> np.ndarray:
        """Arc length rolled by the odometer wheel from the grid start to chainage ``s_m`` [m]."""
        return self._wheel_arc_spline(np.asarray(s_m, dtype=float))

    # --- kinematics against time --------------------------------------------------------------
    def state(self, t_s, motion: MotionProfile) -> dict[str, np.ndarray]:
        """Truth state at times ``t_s`` (N,).

        Returns a dict: ``s_m`` (N,), ``sdot_mps`` (N,), ``pos_n`` (N,3) [m], ``vel_n`` (N,3) [m/s],
        ``acc_n`` (N,3) [m/s^2], ``R_nb`` (N,3,3), ``omega_nb_b`` (N,3) [rad/s],
        ``gravity_n`` (N,3) [m/s^2].
        """
        s, sd, sdd = motion.evaluate(np.atleast_1d(np.asarray(t_s, dtype=float)))
        self._check_range(s)
        y0 = self._pose_spline(s)
        y1 = self._pose_spline(s, 1)
        y2 = self._pose_spline(s, 2)
        vel = y1[:, :3] * sd[:, None]
        acc = y2[:, :3] * (sd**2)[:, None] + y1[:, :3] * sdd[:, None]
        yaw, pitch, roll = y0[:, 3], y0[:, 4], y0[:, 5]
        rates = y1[:, 3:] * sd[:, None]  # d/dt of (yaw, pitch, roll)
        return {
            "s_m": s, "sdot_mps": sd, "pos_n": y0[:, :3], "vel_n": vel, "acc_n": acc,
            "R_nb": R_from_ypr(yaw, pitch, roll),
            "omega_nb_b": _body_rate(pitch, roll, rates),
            "gravity_n": self._gravity_spline(s),
        }

    def inertial_rates(self, t_s, motion: MotionProfile) -> tuple[np.ndarray, np.ndarray]:
        """Instantaneous gyro and accelerometer truth at ``t_s`` (N,).

        ``w_ib_b = w_nb_b + R_bn Omega_n`` [rad/s] and
        ``f_b = R_bn (a_n + 2 Omega_n x v_n - gamma_n)`` [m/s^2], each (N, 3).
        """
        return self.inertial_rates_of(self.state(t_s, motion))

    def inertial_rates_of(self, st: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`inertial_rates` of a :meth:`state` ``st``."""
        R_bn = np.swapaxes(st["R_nb"], -1, -2)
        omega = self.omega_ie_n
        w_ib_b = st["omega_nb_b"] + R_bn @ omega
        f_n = st["acc_n"] + 2.0 * np.cross(omega, st["vel_n"]) - st["gravity_n"]
        return w_ib_b, np.einsum("nij,nj->ni", R_bn, f_n)

    def imu_interval_means(self, t_s, dt_s: float, motion: MotionProfile,
                           chunk: int = 100_000) -> tuple[np.ndarray, np.ndarray]:
        """Error-free IMU samples: means of ``w_ib_b`` and ``f_b`` over (t - dt, t] for each ``t_s`` (N,).

        The motion's own part is exact over each interval: the rotation ``Log(R_nb(t-dt)^T R_nb(t)) / dt``
        (the constant rate that turns the body from one end to the other, as a preintegrator reads
        a sample) and the velocity change ``(v(t) - v(t-dt)) / dt``, turned into ``b`` at the
        interval's middle. The smooth rest (Earth rate, gravity, Coriolis, and the turn of ``b``
        within the interval) is 3-point Gauss-Legendre quadrature. Quadrature alone
        mis-integrates the short, large accelerations at a kink of a rail (the end of a linear
        cant ramp, at 12 m/s: +-17 m/s^2 within a millisecond, up to 17 mm/s of velocity error in
        one sample, which only a tight non-holonomic constraint hides). Returns two (N, 3) arrays.
        """
        t = np.asarray(t_s, dtype=float)
        gyro = np.empty((t.size, 3))
        accel = np.empty((t.size, 3))
        offsets = -0.5 * dt_s + 0.5 * dt_s * _GL3_NODES
        for a in range(0, t.size, chunk):
            tc = t[a:a + chunk]
            n = tc.size
            st = self.state((tc[:, None] + offsets[None, :]).ravel(), motion)
            w, f = self.inertial_rates_of(st)
            mean = {k: np.einsum("k,nkj->nj", _GL3_WEIGHTS, x.reshape(n, 3, 3))
                    for k, x in (("w", w), ("f", f), ("w_nb", st["omega_nb_b"]), ("acc_n", st["acc_n"]))}
            R_mid_bn = np.swapaxes(st["R_nb"].reshape(n, 3, 3, 3)[:, 1], -1, -2)  # GL3's middle node
            ends = self.state(np.concatenate([tc - dt_s, tc]), motion)
            R0, R1 = ends["R_nb"][:n], ends["R_nb"][n:]
            acc_n = (ends["vel_n"][n:] - ends["vel_n"][:n]) / dt_s
            gyro[a:a + chunk] = mean["w"] - mean["w_nb"] + so3_log(np.swapaxes(R0, -1, -2) @ R1) / dt_s
            accel[a:a + chunk] = mean["f"] + np.einsum("nij,nj->ni", R_mid_bn, acc_n - mean["acc_n"])
        return gyro, accel


def wheel_contacts(rails: RailModel, geometry: TrolleyGeometry, s: np.ndarray, iterations: int = 4
                   ) -> dict[str, np.ndarray]:
    """Chainages and points of the three wheel contacts of a rigid trolley at positions ``s`` (M,).

    The two reference-rail wheels sit at chainages ``s -/+ d`` with ``d`` solved so that
    their contact points are exactly one wheelbase apart (on a curve the rail is shorter
    or longer than the centreline); the single wheel sits where the other rail crosses
    the frame's transverse plane through the origin. Fixed-point iterations converge
    quadratically here; returns ``front_n``, ``rear_n``, ``other_n`` (M, 3) and
    ``s_front``, ``s_rear``, ``s_other`` (M,).
    """
    l = geometry.wheelbase_m
    half = np.full(s.shape, 0.5 * l)
    for _ in range(iterations):
        front = rails.rail_points_n(s + half, geometry.reference_rail)
        rear = rails.rail_points_n(s - half, geometry.reference_rail)
        half = half * l / np.linalg.norm(front - rear, axis=-1)
    front = rails.rail_points_n(s + half, geometry.reference_rail)
    rear = rails.rail_points_n(s - half, geometry.reference_rail)
    x = (front - rear) / np.linalg.norm(front - rear, axis=-1, keepdims=True)
    mid = 0.5 * (front + rear)
    s_other = s.copy()
    for _ in range(iterations):
        other = rails.rail_points_n(s_other, geometry.other_rail)
        s_other = s_other - np.sum((other - mid) * x, axis=-1)
    other = rails.rail_points_n(s_other, geometry.other_rail)
    return {"front_n": front, "rear_n": rear, "other_n": other,
            "s_front": s + half, "s_rear": s - half, "s_other": s_other}


def _pose_on_grid(rails: RailModel, geometry: TrolleyGeometry, s: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """IMU position (M, 3), ``R_nb`` (M, 3, 3) and the wheel contacts with the trolley at chainages ``s``."""
    c = wheel_contacts(rails, geometry, s)
    origin_n, R_nv = frame_from_contacts(c["front_n"], c["rear_n"], c["other_n"],
                                         other_is_left=geometry.other_rail == "left")
    pos_n = origin_n + R_nv @ np.asarray(geometry.lever_arm_imu_v, dtype=float)
    return pos_n, R_nv @ geometry.R_vb, c


def _body_rate(pitch, roll, ypr_rates) -> np.ndarray:
    """Body rate ``w_nb_b`` (N, 3) of ``R_nb = Rz(yaw) Ry(-pitch) Rx(roll)`` from Euler-angle rates (N, 3)."""
    yaw_d, pitch_d, roll_d = ypr_rates[:, 0], ypr_rates[:, 1], ypr_rates[:, 2]
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    # w_b = roll_d e_x + Rx(roll)^T (-pitch_d e_y) + Rx(roll)^T Ry(-pitch)^T (yaw_d e_z)
    wx = roll_d + sp * yaw_d
    wy = -cr * pitch_d + sr * cp * yaw_d
    wz = sr * pitch_d + cr * cp * yaw_d
    return np.column_stack([wx, wy, wz])
