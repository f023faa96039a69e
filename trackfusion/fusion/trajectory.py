"""The trajectory between keyframes at the IMU rate (seed 000's forward/reverse dead reckoning).

Each IMU sample between keyframes k and k+1 is reached twice: integrating forward from the
smoothed state k and backward from the smoothed state k+1, with the smoothed biases and the
same mechanisation as the preintegration (Earth rate, the keyframe's gravity, sculling
compensation). The two are blended with weights linear in time, so the result passes
through both smoothed states and keeps the IMU's short-wave detail. All intervals are
integrated at once (one numpy step per sample offset, not per sample).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import so3_exp, so3_log
from ..sensors.types import ImuData
from .preintegration import sculling_compensated


@dataclass
class DenseTrajectory:
    """States at IMU sample times: t_s (N,), R_nb (N,3,3), pos_n (N,3) [m], vel_n (N,3) [m/s]."""

    t_s: np.ndarray
    R_nb: np.ndarray
    pos_n: np.ndarray
    vel_n: np.ndarray

    @classmethod
    def concatenate(cls, parts: "list[DenseTrajectory]") -> "DenseTrajectory":
        """The parts one after the other (in time order)."""
        return cls(*(np.concatenate([getattr(d, n) for d in parts]) for n in ("t_s", "R_nb", "pos_n", "vel_n")))

    def select(self, sel) -> "DenseTrajectory":
        """The samples ``sel`` (a slice, an index array or a boolean mask over the N samples)."""
        return DenseTrajectory(self.t_s[sel], self.R_nb[sel], self.pos_n[sel], self.vel_n[sel])


def _padded(key_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Sample index (K-1, m) of offset j=1..m in each interval, the valid mask, and m."""
    lengths = np.diff(key_idx)
    m = int(lengths.max())
    j = np.arange(1, m + 1)
    idx = key_idx[:-1, None] + j[None, :]
    valid = j[None, :] <= lengths[:, None]
    return np.where(valid, idx, key_idx[1:, None]), valid, m


def densify(imu: ImuData, key_idx: np.ndarray, R_nb: np.ndarray, pos_n: np.ndarray, vel_n: np.ndarray,
            gyro_bias: np.ndarray, accel_bias: np.ndarray, gravity_n: np.ndarray,
            omega_ie_n: np.ndarray, block: int = 2000) -> DenseTrajectory:
    """Blend forward and backward integration between keyframes.

    key_idx (K,) keyframe sample indices; R_nb (K,3,3), pos_n, vel_n, gyro_bias [rad/s],
    accel_bias [m/s^2], gravity_n [m/s^2] each (K,3) at the keyframes; omega_ie_n (3,) [rad/s].
    Returns the states at every IMU sample from ``key_idx[0]`` to ``key_idx[-1]``; works on
    ``block`` intervals at a time to bound memory.
    """
    dt, f_all = sculling_compensated(imu)
    parts = []
    for a in range(0, key_idx.size - 1, block):
        s = slice(a, min(a + block, key_idx.size - 1) + 1)
        d = _densify_block(imu, dt, f_all, key_idx[s], R_nb[s], pos_n[s], vel_n[s], gyro_bias[s],
                           accel_bias[s], gravity_n[s], omega_ie_n)
        parts.append(d if s.stop == key_idx.size else d.select(slice(None, -1)))  # the next block starts there
    return DenseTrajectory.concatenate(parts)


def _densify_block(imu, dt, f_all, key_idx, R_nb, pos_n, vel_n, gyro_bias, accel_bias, gravity_n, omega_ie_n):
    idx, valid, m = _padded(key_idx)
    K1 = key_idx.size - 1
    w = imu.gyro_radps[idx] - gyro_bias[:-1, None, :]  # bias of the interval's first keyframe
    f = f_all[idx] - accel_bias[:-1, None, :]
    h = np.where(valid, dt[idx], 0.0)  # padded steps have zero length
    g = gravity_n[:-1]

    def accel_n(R, f_b, v):
        return np.einsum("kij,kj->ki", R, f_b) + g - 2.0 * np.cross(omega_ie_n, v)

    fwd_R, fwd_p, fwd_v = (np.empty((K1, m + 1) + s) for s in ((3, 3), (3,), (3,)))
    fwd_R[:, 0], fwd_p[:, 0], fwd_v[:, 0] = R_nb[:-1], pos_n[:-1], vel_n[:-1]
    for j in range(m):
        R, p, v, hj = fwd_R[:, j], fwd_p[:, j], fwd_v[:, j], h[:, j, None]
        a = accel_n(R, f[:, j], v)
        fwd_p[:, j + 1] = p + v * hj + 0.5 * a * hj**2
        fwd_v[:, j + 1] = v + a * hj
        fwd_R[:, j + 1] = so3_exp(-omega_ie_n * hj) @ R @ so3_exp(w[:, j] * hj)
    bwd_R, bwd_p, bwd_v = (np.zeros_like(a) for a in (fwd_R, fwd_p, fwd_v))  # padding stays finite
    last = valid.sum(axis=1)  # offset of the next keyframe in each interval
    rows = np.arange(K1)
    bwd_R[rows, last], bwd_p[rows, last], bwd_v[rows, last] = R_nb[1:], pos_n[1:], vel_n[1:]
    for j in range(m - 1, -1, -1):
        active = (j < last)[:, None]
        R, p, v, hj = bwd_R[:, j + 1], bwd_p[:, j + 1], bwd_v[:, j + 1], h[:, j, None]
        R_prev = so3_exp(omega_ie_n * hj) @ R @ so3_exp(-w[:, j] * hj)
        a = accel_n(R_prev, f[:, j], v)
        v_prev = v - a * hj
        p_prev = p - v_prev * hj - 0.5 * a * hj**2
        bwd_R[:, j] = np.where(active[:, :, None], R_prev, bwd_R[:, j])
        bwd_v[:, j] = np.where(active, v_prev, bwd_v[:, j])
        bwd_p[:, j] = np.where(active, p_prev, bwd_p[:, j])
    span = (imu.t_s[key_idx[1:]] - imu.t_s[key_idx[:-1]])[:, None]
    t_off = np.concatenate([np.zeros((K1, 1)), np.cumsum(h, axis=1)], axis=1)
    wgt = np.clip(t_off / span, 0.0, 1.0)
    keep = np.concatenate([np.ones((K1, 1), bool), valid], axis=1)
    keep[rows, last] = False  # the next keyframe starts the next interval
    R_blend = fwd_R @ so3_exp(wgt[..., None] * so3_log(np.swapaxes(fwd_R, -1, -2) @ bwd_R))
    p_blend = (1 - wgt[..., None]) * fwd_p + wgt[..., None] * bwd_p
    v_blend = (1 - wgt[..., None]) * fwd_v + wgt[..., None] * bwd_v
    sample = np.concatenate([key_idx[:-1, None], idx], axis=1)
    t = imu.t_s[np.r_[sample[keep], key_idx[-1]]]
    return DenseTrajectory(t, np.concatenate([R_blend[keep], R_nb[-1:]]),
                           np.concatenate([p_blend[keep], pos_n[-1:]]), np.concatenate([v_blend[keep], vel_n[-1:]]))
