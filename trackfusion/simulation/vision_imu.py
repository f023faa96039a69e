"""IMU on the measuring frame of a vision run: a design curve with cant, the bogie's relative
motion, gyro and accelerometer signals with datasheet errors.

The measuring frame's attitude in a level frame is ``R = R_z(psi) R_x(phi_t + phi_rel)``: heading
``psi`` from the design's horizontal curvature, the design cant angle ``phi_t`` (negative when
the right rail is raised: a left-hand curve) and the relative roll of
:func:`~trackfusion.simulation.camera_laser.simulate_run`. Its acceleration is the centripetal
``V^2 rho_h`` towards the curve's centre plus the relative motion's ``(r_y'', r_z'')`` in the
canted track frame (the couplings of eq. 43 between the relative motion and the track's rotation
are below 1e-4 m/s^2 here and left out). Specific force ``f_b = R^T (a + g z)``; body rate
``omega_b = R_x(phi)^T (0, 0, psi') + (phi', 0, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRAVITY_MPS2 = 9.81


@dataclass(frozen=True)
class DesignCurve:
    """Straight, then a clothoid from ``transition_start_m`` over ``transition_m`` to an arc of
    ``radius_m`` (curving left) with ``cant_mm`` over a 1.5 m base (raised right rail)."""

    transition_start_m: float
    transition_m: float = 40.0
    radius_m: float = 800.0
    cant_mm: float = 100.0

    def at(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal curvature [1/m] (positive left) and cant angle [rad] at chainage ``s_m``."""
        f = np.clip((np.asarray(s_m) - self.transition_start_m) / self.transition_m, 0.0, 1.0)
        return f / self.radius_m, -np.arcsin(f * self.cant_mm / 1500.0)


@dataclass(frozen=True)
class ImuSpec:
    """Datasheet figures of a tactical MEMS IMU: gyro angle random walk [deg/sqrt(h)] and bias
    [deg/h], accelerometer velocity random walk [m/s/sqrt(h)] and bias [mg]."""

    gyro_arw_deg_per_sqrt_h: float = 0.15
    gyro_bias_deg_per_h: float = 1.0
    accel_vrw_mps_per_sqrt_h: float = 0.03
    accel_bias_mg: float = 0.2


def _rx(phi: np.ndarray) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    o, z = np.ones_like(phi), np.zeros_like(phi)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _rz(psi: np.ndarray) -> np.ndarray:
    c, s = np.cos(psi), np.sin(psi)
    o, z = np.ones_like(psi), np.zeros_like(psi)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def imu_signals(t_s: np.ndarray, s_m: np.ndarray, y_rel_m: np.ndarray, z_rel_m: np.ndarray,
                roll_rel_rad: np.ndarray, curve: DesignCurve, spec: ImuSpec | None,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Gyro (N, 3) [rad/s] and specific force (N, 3) [m/s^2] of the measuring frame (module
    docstring); ``spec=None`` gives error-free signals."""
    rho, cant = curve.at(s_m)
    speed = np.gradient(s_m, t_s)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (rho[1:] + rho[:-1]) * np.diff(s_m))])
    phi = cant + roll_rel_rad
    R = _rz(psi) @ _rx(phi)
    psi_dot = speed * rho
    phi_dot = np.gradient(phi, t_s)
    omega = np.einsum("nji,nj->ni", _rx(phi), np.column_stack([0 * psi, 0 * psi, psi_dot]))
    omega[:, 0] += phi_dot
    a_rel_t = np.column_stack([np.zeros_like(t_s), np.gradient(np.gradient(y_rel_m, t_s), t_s),
                               np.gradient(np.gradient(z_rel_m, t_s), t_s)])
    a_track = np.column_stack([np.gradient(speed, t_s), speed ** 2 * rho, np.zeros_like(t_s)])
    a_n = np.einsum("nij,nj->ni", _rz(psi), a_track) + np.einsum("nij,nj->ni", _rz(psi) @ _rx(cant), a_rel_t)
    f_b = np.einsum("nji,nj->ni", R, a_n + np.array([0.0, 0.0, GRAVITY_MPS2]))
    if spec is not None:
        rate = 1.0 / np.median(np.diff(t_s))
        g_sd = np.radians(spec.gyro_arw_deg_per_sqrt_h) / 60.0 * np.sqrt(rate)
        a_sd = spec.accel_vrw_mps_per_sqrt_h / 60.0 * np.sqrt(rate)
        omega = omega + rng.normal(0, g_sd, omega.shape) + rng.normal(0, np.radians(spec.gyro_bias_deg_per_h) / 3600, 3)
        f_b = f_b + rng.normal(0, a_sd, f_b.shape) + rng.normal(0, spec.accel_bias_mg * 1e-3 * GRAVITY_MPS2, 3)
    return omega, f_b


def encoder_chainage_m(s_m: np.ndarray, rng: np.random.Generator, scale_sd: float = 5e-4,
                       tick_m: float = 1e-3) -> np.ndarray:
    """An encoder's chainage [m] (N,) of the true chainage ``s_m`` (N,): a wheel-radius scale
    error drawn with ``scale_sd`` (a calibrated wheel; the seed's odometry algorithm keeps it
    there) and ticks of ``tick_m``."""
    s = np.asarray(s_m, dtype=float)
    return np.floor(s * (1.0 + rng.normal(0.0, scale_sd)) / tick_m) * tick_m
