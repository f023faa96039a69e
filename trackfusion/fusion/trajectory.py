"""The trajectory between keyframes at the IMU rate (seed 000's forward/reverse dead reckoning).

Each IMU sample between keyframes k and k+1 is reached twice: integrating forward from the
smoothed state k and backward from the smoothed state k+1, with the smoothed biases and the
same mechanisation as the preintegration (Earth rate, the keyframe's gravity, sculling
compensation). The two are blended with weights linear in time, so the result passes
through both smoothed states and keeps the IMU's short-wave detail. All intervals are
integrated at once (one numpy step per sample offset, not per sample).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..geodesy import Origin, gravity_n
from ..rotations import skew, so3_exp, so3_exp_rotate, so3_log
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
        return cls(*(np.concatenate([getattr(d, f.name) for d in parts]) for f in fields(cls)))

    def select(self, sel) -> "DenseTrajectory":
        """The samples ``sel`` (a slice, an index array or a boolean mask over the N samples)."""
        return DenseTrajectory(self.t_s[sel], self.R_nb[sel], self.pos_n[sel], self.vel_n[sel])


@dataclass(frozen=True)
class KeyframeStates:
    """The smoothed states :func:`densify` blends between: keyframe IMU sample indices ``key_idx``
    (K,); at each keyframe ``R_nb`` (K,3,3), ``pos_n`` (K,3) [m], ``vel_n`` (K,3) [m/s], ``gyro_bias``
    (K,3) [rad/s], ``accel_bias`` (K,3) [m/s^2] and ``gravity_n`` (K,3) [m/s^2]."""

    key_idx: np.ndarray
    R_nb: np.ndarray
    pos_n: np.ndarray
    vel_n: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gravity_n: np.ndarray

    @classmethod
    def of(cls, result, origin: Origin, sel=slice(None)) -> "KeyframeStates":
        """The keyframes ``sel`` (a slice or an index array) of a smoothed
        :class:`~.smoother.SmootherResult` ``result``, with normal gravity at their positions
        (``origin`` the origin of ``n``)."""
        pos_n = result.pos_n[sel]
        return cls(result.key_idx[sel], result.R_nb[sel], pos_n, result.vel_n[sel], result.gyro_bias_radps[sel],
                   result.accel_bias_mps2[sel], gravity_n(pos_n, origin))

    def select(self, sel) -> "KeyframeStates":
        """The keyframes ``sel`` (a slice or an index array over the K keyframes)."""
        return KeyframeStates(*(getattr(self, f.name)[sel] for f in fields(self)))


def _padded(key_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Sample index (K-1, m) of offset j=1..m in each interval, the valid mask, and m."""
    lengths = np.diff(key_idx)
    m = int(lengths.max())
    j = np.arange(1, m + 1)
    idx = key_idx[:-1, None] + j[None, :]
    valid = j[None, :] <= lengths[:, None]
    return np.where(valid, idx, key_idx[1:, None]), valid, m


def densify(imu: ImuData, keys: KeyframeStates, omega_ie_n: np.ndarray, block: int = 2000, every: int = 1,
            index_offset: int = 0) -> DenseTrajectory:
    """Blend forward and backward integration between keyframes.

    keys: the states at the keyframes (:class:`KeyframeStates`); omega_ie_n (3,) [rad/s].
    Returns the states at every IMU sample from ``key_idx[0]`` to ``key_idx[-1]``, or with
    ``every`` > 1 only at the samples i with ``(index_offset + i) % every == 0`` (the same
    values: the integration still steps through every sample); works on ``block`` intervals
    at a time to bound memory.
    """
    dt, f_all = sculling_compensated(imu)
    key_idx = keys.key_idx
    parts = []
    for a in range(0, key_idx.size - 1, block):
        s = slice(a, min(a + block, key_idx.size - 1) + 1)
        parts.append(_densify_block(imu, (dt, f_all), keys.select(s), omega_ie_n, every, index_offset))
    if (index_offset + key_idx[-1]) % every == 0:
        parts.append(DenseTrajectory(imu.t_s[key_idx[-1:]], keys.R_nb[-1:], keys.pos_n[-1:], keys.vel_n[-1:]))
    return DenseTrajectory.concatenate(parts)


def _densify_block(imu: ImuData, compensated: tuple[np.ndarray, np.ndarray], keys: KeyframeStates,
                   omega_ie_n: np.ndarray, every: int, index_offset: int) -> DenseTrajectory:
    """:func:`densify` of one block of intervals (``keys`` the block's keyframes), up to and
    without the block's last keyframe; ``compensated``: the IMU's
    :func:`~.preintegration.sculling_compensated` (dt (N,) [s], specific force (N,3) [m/s^2]).

    The attitude needs no step-by-step recursion per direction. With ``C_j`` the product of
    the body increments ``exp(w_i h_i)`` over the first j samples of an interval and ``t_j``
    their time, forward integration from keyframe k gives ``exp(-W t_j) R_k C_j`` and backward
    integration from k+1 gives ``exp(W (T - t_j)) R_k+1 C_T^T C_j`` (W = [omega_ie_n]x; the
    Earth-rate increments share one axis, so they commute). Their difference is then
    ``C_j^T M C_j`` with one closure rotation ``M = R_k^T exp(W T) R_k+1 C_T^T`` per interval,
    and the blend ``fwd exp(wgt log(fwd^T bwd))`` equals ``exp(-W t_j) R_k exp(wgt log M) C_j``.
    """
    dt, f_all = compensated
    key_idx, R_nb, pos_n, vel_n = keys.key_idx, keys.R_nb, keys.pos_n, keys.vel_n
    gyro_bias, accel_bias, gravity_n = keys.gyro_bias, keys.accel_bias, keys.gravity_n
    idx, valid, m = _padded(key_idx)
    K1 = key_idx.size - 1
    rows = np.arange(K1)
    last = valid.sum(axis=1)  # offset of the next keyframe in each interval
    w = imu.gyro_radps[idx] - gyro_bias[:-1, None, :]  # bias of the interval's first keyframe
    f = f_all[idx] - accel_bias[:-1, None, :]
    h = np.where(valid, dt[idx], 0.0)  # padded steps have zero length
    t_off = np.concatenate([np.zeros((K1, 1)), np.cumsum(h, axis=1)], axis=1)  # (K1, m+1) [s]
    T = t_off[rows, last]
    C = np.empty((K1, m + 1, 3, 3))
    C[:, 0] = np.eye(3)
    W_body = so3_exp(w * h[..., None])
    for j in range(m):
        C[:, j + 1] = C[:, j] @ W_body[:, j]
    R0, R1 = R_nb[:-1], R_nb[1:]
    to_next = R1 @ np.swapaxes(C[rows, last], -1, -2)  # R_k+1 C_T^T
    phi_M = so3_log(np.swapaxes(R0, -1, -2) @ so3_exp(omega_ie_n * T[:, None]) @ to_next)
    Cf = np.einsum("kjab,kjb->kja", C[:, :m], f)  # C_j f_j
    fwd_f = so3_exp_rotate(-omega_ie_n * t_off[:, :m, None], np.einsum("kab,kjb->kja", R0, Cf))
    bwd_f = so3_exp_rotate(omega_ie_n * (T[:, None] - t_off[:, :m])[..., None], np.einsum("kab,kjb->kja", to_next, Cf))
    g = gravity_n[:-1]
    coriolis_T = -2.0 * skew(omega_ie_n).T  # v @ coriolis_T == -2 omega_ie_n x v

    fwd_p, fwd_v = np.empty((K1, m + 1, 3)), np.empty((K1, m + 1, 3))
    fwd_p[:, 0], fwd_v[:, 0] = pos_n[:-1], vel_n[:-1]
    for j in range(m):
        p, v, hj = fwd_p[:, j], fwd_v[:, j], h[:, j, None]
        a = fwd_f[:, j] + g + v @ coriolis_T
        fwd_p[:, j + 1] = p + v * hj + 0.5 * a * hj**2
        fwd_v[:, j + 1] = v + a * hj
    bwd_p, bwd_v = np.zeros_like(fwd_p), np.zeros_like(fwd_v)  # padding stays finite
    bwd_p[rows, last], bwd_v[rows, last] = pos_n[1:], vel_n[1:]
    for j in range(m - 1, -1, -1):
        active = (j < last)[:, None]
        p, v, hj = bwd_p[:, j + 1], bwd_v[:, j + 1], h[:, j, None]
        a = bwd_f[:, j] + g + v @ coriolis_T
        v_prev = v - a * hj
        p_prev = p - v_prev * hj - 0.5 * a * hj**2
        bwd_v[:, j] = np.where(active, v_prev, bwd_v[:, j])
        bwd_p[:, j] = np.where(active, p_prev, bwd_p[:, j])
    span = (imu.t_s[key_idx[1:]] - imu.t_s[key_idx[:-1]])[:, None]
    wgt = np.clip(t_off / span, 0.0, 1.0)
    sample = np.concatenate([key_idx[:-1, None], idx], axis=1)
    keep = np.concatenate([np.ones((K1, 1), bool), valid], axis=1)
    keep[rows, last] = False  # the next keyframe starts the next interval
    if every > 1:
        keep &= (index_offset + sample) % every == 0
    k = np.nonzero(keep)[0]  # the interval of each kept sample
    wgt = wgt[keep]
    R_blend = so3_exp(-omega_ie_n * t_off[keep][:, None]) @ R0[k] @ so3_exp(wgt[:, None] * phi_M[k]) @ C[keep]
    p_blend = (1 - wgt[:, None]) * fwd_p[keep] + wgt[:, None] * bwd_p[keep]
    v_blend = (1 - wgt[:, None]) * fwd_v[keep] + wgt[:, None] * bwd_v[keep]
    return DenseTrajectory(imu.t_s[sample[keep]], R_blend, p_blend, v_blend)
