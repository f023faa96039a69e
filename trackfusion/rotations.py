"""Vectorised rotation helpers: skew matrices, SO(3) exp/log, Euler angles, quaternions.

Every function accepts stacked inputs with leading axes ``...``.
Euler convention (see the package docstring): ``R_nb = Rz(yaw) Ry(-pitch) Rx(roll)``,
yaw from east towards north, pitch positive nose up, roll positive left side up.
Quaternions are Hamilton ``(qw, qx, qy, qz)``, body to n, with ``qw >= 0``.
"""

from __future__ import annotations

import numpy as np


def skew(v) -> np.ndarray:
    """Cross-product matrix [v]x, shape (..., 3, 3), so that ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([z, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], z, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], z], -1),
    ], -2)


def _rodrigues_ab(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``theta^2``, ``a = sin(theta)/theta`` and ``b = (1 - cos(theta))/theta^2`` of rotation
    vectors (..., 3) [rad], each (...,), with their series below theta = 1e-6 rad."""
    theta2 = np.einsum("...i,...i->...", phi, phi)
    small = theta2 < 1e-12
    theta = np.sqrt(np.where(small, 1.0, theta2))
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(theta) / theta)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(theta)) / (theta * theta))
    return theta2, a, b


def so3_exp(phi) -> np.ndarray:
    """Rotation matrix of rotation vector ``phi`` [rad], shape (..., 3) -> (..., 3, 3) (Rodrigues:
    ``R = (1 - b theta^2) I + a [phi]x + b phi phi^T``, a and b of :func:`_rodrigues_ab`)."""
    phi = np.asarray(phi, dtype=float)
    theta2, a, b = _rodrigues_ab(phi)
    R = b[..., None, None] * phi[..., :, None] * phi[..., None, :]
    c = 1.0 - b * theta2
    ax, ay, az = (a * phi[..., i] for i in range(3))
    R[..., 0, 0] += c
    R[..., 1, 1] += c
    R[..., 2, 2] += c
    R[..., 0, 1] -= az
    R[..., 1, 0] += az
    R[..., 0, 2] += ay
    R[..., 2, 0] -= ay
    R[..., 1, 2] -= ax
    R[..., 2, 1] += ax
    return R


def so3_exp_rotate(phi, x) -> np.ndarray:
    """``so3_exp(phi) @ x`` for vectors x, shape (..., 3) each, without forming the matrices:
    ``x + a phi x x + b phi x (phi x x)``."""
    phi, x = np.asarray(phi, dtype=float), np.asarray(x, dtype=float)
    _, a, b = _rodrigues_ab(phi)
    px = np.cross(phi, x)
    return x + a[..., None] * px + b[..., None] * np.cross(phi, px)


def so3_log(R) -> np.ndarray:
    """Rotation vector [rad], shape (..., 3), of rotation matrices (..., 3, 3); angle in [0, pi)."""
    R = np.asarray(R, dtype=float)
    q = quat_from_R(R)
    w = np.clip(q[..., 0], -1.0, 1.0)
    vnorm = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(vnorm, w)
    scale = np.where(vnorm < 1e-15, 2.0, angle / np.where(vnorm < 1e-15, 1.0, vnorm))
    return q[..., 1:] * scale[..., None]


def R_from_ypr(yaw_rad, pitch_rad, roll_rad) -> np.ndarray:
    """``R_nb = Rz(yaw) Ry(-pitch) Rx(roll)``, shape (..., 3, 3)."""
    y, p, r = np.broadcast_arrays(np.asarray(yaw_rad, float), np.asarray(pitch_rad, float),
                                  np.asarray(roll_rad, float))
    cy, sy = np.cos(y), np.sin(y)
    cp, sp = np.cos(p), np.sin(p)
    cr, sr = np.cos(r), np.sin(r)
    # Rz(y) @ Ry(-p) @ Rx(r), written out
    R = np.empty(y.shape + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = -sy * cr - cy * sp * sr
    R[..., 0, 2] = sy * sr - cy * sp * cr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = cy * cr - sy * sp * sr
    R[..., 1, 2] = -cy * sr - sy * sp * cr
    R[..., 2, 0] = sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def ypr_from_R(R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`R_from_ypr`: (yaw, pitch, roll) [rad]; yaw in (-pi, pi]."""
    R = np.asarray(R, dtype=float)
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    pitch = np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return yaw, pitch, roll


def quat_from_R(R) -> np.ndarray:
    """Hamilton quaternion ``(qw, qx, qy, qz)`` with ``qw >= 0`` of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # four candidate forms, pick the best-conditioned per element (Shepperd)
    t = np.stack([m00 + m11 + m22, m00 - m11 - m22, -m00 + m11 - m22, -m00 - m11 + m22], -1)
    k = np.argmax(t, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    s = np.sqrt(np.maximum(1.0 + np.take_along_axis(t, k[..., None], -1)[..., 0], 1e-300)) * 2.0
    r21_m_r12 = R[..., 2, 1] - R[..., 1, 2]
    r02_m_r20 = R[..., 0, 2] - R[..., 2, 0]
    r10_m_r01 = R[..., 1, 0] - R[..., 0, 1]
    r01_p_r10 = R[..., 0, 1] + R[..., 1, 0]
    r02_p_r20 = R[..., 0, 2] + R[..., 2, 0]
    r12_p_r21 = R[..., 1, 2] + R[..., 2, 1]
    cand = np.stack([
        np.stack([s / 4, r21_m_r12 / s, r02_m_r20 / s, r10_m_r01 / s], -1),
        np.stack([r21_m_r12 / s, s / 4, r01_p_r10 / s, r02_p_r20 / s], -1),
        np.stack([r02_m_r20 / s, r01_p_r10 / s, s / 4, r12_p_r21 / s], -1),
        np.stack([r10_m_r01 / s, r02_p_r20 / s, r12_p_r21 / s, s / 4], -1),
    ], -2)
    q = np.take_along_axis(cand, k[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def R_from_quat(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of Hamilton quaternions ``(qw, qx, qy, qz)`` (normalised first)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
