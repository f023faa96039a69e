"""Roll of the measuring frame relative to the track from its IMU: seed 001 section 9's Madgwick
filter with the track's expected acceleration removed from the accelerometer.

Madgwick's IMU filter (gyro + accelerometer, no magnetometer; Madgwick et al. 2011): the
quaternion ``q`` (body to level frame, Hamilton, ``[w, x, y, z]``) is integrated with the gyro
rate and pulled along the gradient of the misfit between the measured and the predicted
direction of gravity with gain ``beta`` [rad/s]. The plain filter takes the specific force as
gravity (eq. 52); on a vehicle in a curve the centripetal acceleration ``rho_h V^2`` is a large
part of it, so, as the seed proposes (eq. 53), the acceleration of a particle moving along the
design track at the same speed is subtracted first: ``V^2 rho_h`` horizontally towards the
curve's centre (and ``V dot`` along the track), expressed in the body frame with the current
attitude estimate.

``phi^{t,tgms}`` of eq. 37 is then the filter's roll minus the design cant angle at the frame's
chainage (from the track preprocessor). A sequential filter: one Python step per IMU sample
(the state carries from sample to sample), used as the seed's baseline.
"""

from __future__ import annotations

import numpy as np


def _quat_mult(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _rotate_to_body(q: np.ndarray, v_level: np.ndarray) -> np.ndarray:
    """``R(q)^T v``: a level-frame vector in the body frame."""
    w, x, y, z = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return R.T @ v_level


def madgwick_roll(t_s: np.ndarray, gyro_b: np.ndarray, accel_b: np.ndarray, speed_mps: np.ndarray,
                  curvature_h_per_m: np.ndarray, beta: float = 0.005, roll0_rad: float = 0.0,
                  correct_track_acceleration: bool = True) -> np.ndarray:
    """Roll [rad] (N,) of the body (x forward, y left, z up) from gyro (N, 3) [rad/s] and specific
    force (N, 3) [m/s^2] at times ``t_s`` (N,), with the design's horizontal curvature (N,)
    [1/m] (positive to the left) and the speed (N,) [m/s] at each sample (module docstring).
    The heading is not observable without a magnetometer; only roll and pitch are used."""
    n = len(t_s)
    q = np.array([np.cos(roll0_rad / 2), np.sin(roll0_rad / 2), 0.0, 0.0])
    roll = np.empty(n)
    dt = np.diff(t_s, prepend=t_s[0] - (t_s[1] - t_s[0]))
    vdot = np.gradient(speed_mps, t_s)
    for k in range(n):
        f = accel_b[k].copy()
        if correct_track_acceleration:
            # the track-following particle's acceleration, in a level frame whose x axis is the
            # body's heading (yaw does not matter for the gravity direction)
            w, x, y, z = q
            yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            q_level = _quat_mult(np.array([np.cos(-yaw / 2), 0, 0, np.sin(-yaw / 2)]), q)
            a_level = np.array([vdot[k], curvature_h_per_m[k] * speed_mps[k] ** 2, 0.0])
            f = f - _rotate_to_body(q_level, a_level)
        norm = np.linalg.norm(f)
        w, x, y, z = q
        q_dot = 0.5 * _quat_mult(q, np.array([0.0, *gyro_b[k]]))
        if norm > 0:
            ax, ay, az = f / norm
            # misfit of the predicted gravity direction (Madgwick 2011, IMU case)
            F = np.array([2 * (x * z - w * y) - ax, 2 * (w * x + y * z) - ay, 2 * (0.5 - x * x - y * y) - az])
            J = np.array([[-2 * y, 2 * z, -2 * w, 2 * x], [2 * x, 2 * w, 2 * z, 2 * y], [0, -4 * x, -4 * y, 0]])
            grad = J.T @ F
            gn = np.linalg.norm(grad)
            if gn > 0:
                q_dot = q_dot - beta * grad / gn
        q = q + q_dot * dt[k]
        q /= np.linalg.norm(q)
        w, x, y, z = q
        roll[k] = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return roll
