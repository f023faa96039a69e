"""Wheel-path factor: the rear reference-rail wheel runs through the points the front one touched.

Both reference-rail wheels of the trolley (simulation/trolley.py) roll on the same rail line,
a wheelbase ``l`` apart. The rear contact point at time ``t'`` therefore sits where the front
contact point was at time ``t`` when the rear wheel's chainage at ``t'`` is the front wheel's
at ``t``, i.e. when the odometer distance has grown by ``l``: ``d(t') = d(t) + l`` (for a
rear or a front odometer wheel alike). With ``P = p + R_nb lever_arm_b`` the contact point,

    P_rear(t') = P_front(t),

exactly, whatever the irregularity: the trolley frame follows the chord between the wheels
and this says nothing else. Unlike the non-holonomic constraint (NHC, whose vertical and
lateral violation is the irregularity's coloured signal, treated as white noise;
track/nhc_noise.py) it holds for the rigid trolley to the last micrometre. docs/wheel_path.md
derives it and gives the measurements.

The residual is the difference in the trolley frame ``v`` of the front keyframe ``k``, its
lateral and vertical components only (two rows)::

    r = P_yz R_vb R_k^T (P_front(t_k) - P_rear(t'))

The along-rail component is left out: an error ``e`` of the odometer distance over the
wheelbase (scale error, tick quantum, slips) moves the rear point along the rail, which in
``v`` is along x to within the rail's slope against the chord (~1e-3 rad): ``1e-3 e``.

``t'`` falls between keyframes ``j`` and ``j + 1``; the rear contact there is reached from
keyframe ``j`` by integrating the IMU samples over ``tau = t' - t_j`` (< one keyframe spacing)
in ``j``'s body frame (:func:`~.preintegration.body_deltas` and
:func:`~.preintegration.point_after`: the preintegration's mechanisation, shared with the
prism factor)::

    p(t')  = p_j + v_j tau + (g - 2 omega_ie x v_j) tau^2 / 2 + R_j dp
    R(t')  = Exp(-omega_ie tau) R_j dR

so the factor joins three variables: ``X(k)``, ``X(j)``, ``V(j)``. Left out (approximation
error, navigation-grade IMU, 0.1 s keyframes): the IMU bias over ``tau`` (10 ug: 0.5 um), the
accelerometer white noise (0.9 um), the Earth's rotation of the integrated specific force
(0.4 um); the Earth rate of the lever arm is kept (7 um at 1 m). Pairs whose ``j`` is ``k``
(speeds above one wheelbase per keyframe spacing, 12 m/s at 1.2 m and 0.1 s) are skipped.

Pure maths: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..rotations import skew
from .preintegration import body_deltas, point_after

_P_YZ = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

#: odometer distance change [m] per keyframe interval below which the trolley counts as standing
STANDING_M = 1e-4


@dataclass
class WheelPairs:
    """Front keyframe ``k`` (M,) and rear time ``t'`` as keyframe ``j`` (M,) plus ``tau_s`` (M,) [s]."""

    k: np.ndarray
    j: np.ndarray
    tau_s: np.ndarray


def _runs(direction: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs ``(a, b)`` of keyframe intervals ``a .. b-1`` with the same nonzero direction."""
    change = np.flatnonzero(np.diff(direction) != 0) + 1
    bounds = np.r_[0, change, direction.size]
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if direction[a] != 0]


def rear_times(t_key: np.ndarray, odo_t_s: np.ndarray, odo_d_m: np.ndarray, wheelbase_m: float) -> WheelPairs:
    """For each keyframe, the time ``t'`` at which the rear reference-rail wheel reaches the
    front wheel's contact point: ``d(t') = d(t_k) + wheelbase_m`` on the odometer's signed
    distance (N,) [m] at ``odo_t_s`` (N,) [s], inside the same run of motion in one direction
    (a stop or a reversal ends a run; pairs across one are not formed).

    t_key (K,) [s]. Returns the pairs whose ``t'`` lies inside the run and whose rear keyframe
    ``j`` (``t_j <= t' < t_{j+1}``) differs from ``k``.
    """
    d_key = np.interp(t_key, odo_t_s, odo_d_m)
    step = np.diff(d_key)
    direction = np.where(step > STANDING_M, 1, np.where(step < -STANDING_M, -1, 0))
    ks, ts = [], []
    for a, b in _runs(direction):
        if abs(d_key[b] - d_key[a]) <= wheelbase_m:
            continue
        sel = (odo_t_s >= t_key[a]) & (odo_t_s <= t_key[b])
        sign = direction[a]
        d_run = np.maximum.accumulate(sign * odo_d_m[sel])  # monotone (tick noise, repaired records)
        k = np.arange(a, b + 1)
        target = sign * (d_key[k] + wheelbase_m)
        inside = (target >= d_run[0]) & (target <= d_run[-1])
        ks.append(k[inside])
        ts.append(np.interp(target[inside], d_run, odo_t_s[sel]))
    k = np.concatenate(ks) if ks else np.zeros(0, np.int64)
    t_rear = np.concatenate(ts) if ts else np.zeros(0)
    j = np.clip(np.searchsorted(t_key, t_rear, side="right") - 1, 0, t_key.size - 2)
    keep = j != k
    return WheelPairs(k[keep].astype(np.int64), j[keep], (t_rear - t_key[j])[keep])


#: the builder name of the pairs whose front wheel point a previous chunk holds (fusion/chunks.py)
HAND_OVER_BUILDER = "wheel_path_hand_over"


class WheelFront(NamedTuple):
    """Keyframes held fixed as front wheel points (a previous chunk's, fusion/chunks.py):
    t_s (H,) [s] before the first keyframe; R_nb (H,3,3); pos_n (H,3) [m]."""

    t_s: np.ndarray
    R_nb: np.ndarray
    pos_n: np.ndarray


class WheelPathData(NamedTuple):
    """What the wheel-path factors of M pairs hold fixed while the states change (built once):
    tau_s (M,) [s] the rear time after keyframe j; dR (M,3,3), dp (M,3) [m] from
    :func:`~.preintegration.body_deltas`; gravity_n (M,3) [m/s^2] at keyframe j; omega_ie_n (3,) [rad/s]; front_b,
    rear_b (3,) [m] IMU to the front / rear reference-rail wheel contact in ``b``; R_vb (3,3)."""

    tau_s: np.ndarray
    dR: np.ndarray
    dp: np.ndarray
    gravity_n: np.ndarray
    omega_ie_n: np.ndarray
    front_b: np.ndarray
    rear_b: np.ndarray
    R_vb: np.ndarray


def wheel_path_residual(R_k: np.ndarray, p_k: np.ndarray, R_j: np.ndarray, p_j: np.ndarray, v_j: np.ndarray,
                        data: WheelPathData) -> tuple[np.ndarray, list[np.ndarray]]:
    """Lateral and vertical offset in ``v`` (of keyframe k) of the front contact at ``t_k`` from
    the rear contact at ``t' = t_j + tau`` (module docstring).

    R_k, R_j (M,3,3) ``R_nb``; p_k, p_j, v_j (M,3) [m, m/s]; ``data`` the pairs' fixed
    :class:`WheelPathData`.
    Returns r (M,2) [m] and Jacobians [d/pose_k (M,2,6), d/pose_j (M,2,6), d/v_j (M,2,3)].
    """
    P_rear, _, dP_theta_j, dP_v_j = point_after(R_j, p_j, v_j, data, data.rear_b)
    y = np.einsum("kji,kj->ki", R_k, p_k - P_rear)  # R_k^T (p_k - P_rear)
    M = _P_YZ @ data.R_vb  # (2,3)
    r = (y + data.front_b) @ M.T
    Rk_T = np.swapaxes(R_k, 1, 2)
    d_pose_k = np.concatenate([M @ skew(y), np.broadcast_to(M, (y.shape[0], 2, 3))], axis=2)
    A = -M @ Rk_T  # (M,2,3): d r / d P_rear
    d_pose_j = np.concatenate([A @ dP_theta_j, A @ R_j], axis=2)
    return r, [d_pose_k, d_pose_j, A @ dP_v_j]


def wheel_path_builder(problem, t_key: np.ndarray, key_idx: np.ndarray, pos0_n: np.ndarray, keys_x: np.ndarray,
                       keys_v: np.ndarray, omega_ie_n: np.ndarray, front: WheelFront | None = None):
    """The factors of a :class:`~trackfusion.fusion.problem.FusionProblem` with an odometer on
    keyframes ``t_key`` (K,) at IMU samples ``key_idx`` (K,); pos0_n (K,3) [m] the initial
    positions (for gravity); keys_x, keys_v (K,) the pose and velocity keys of the keyframes;
    omega_ie_n (3,) [rad/s] (zero when the Earth rate is switched off); ``front``: keyframes
    before ``t_key[0]`` held fixed (a previous chunk's), whose points the rear wheel reaches
    after ``t_key[0]`` (the odometer must cover them).

    Returns ``(M, build, M_front, build_front)``: the number of factors between keyframes and
    ``build(state) -> LinearBlocks`` at an estimate with arrays ``R`` (K,3,3), ``p`` (K,3), ``v``
    (K,3) (fusion/smoother.py ``_State``); the same for the pairs whose front point is held
    (their blocks on the rear keyframe's pose and velocity only; ``build_front`` None without).
    """
    from .. import geodesy
    from .factors import LinearBlocks
    tr, st = problem.trolley, problem.factors.wheel_path
    held = front if front is not None else WheelFront(np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    H = held.t_s.size
    pairs = rear_times(np.r_[held.t_s, t_key], problem.odometer.t_s, problem.odometer.distance_m, tr.wheelbase_m)
    keep = ((pairs.k - H) % st.keyframe_step == 0) & (pairs.j >= H)  # the rear wheel in this problem's time
    k, j, tau_s = pairs.k[keep] - H, pairs.j[keep] - H, pairs.tau_s[keep]
    dR, _, dp = body_deltas(problem.imu, key_idx[j], tau_s)
    g_n = geodesy.gravity_n(pos0_n[j], problem.origin)
    half = 0.5 * tr.wheelbase_m
    front_b, rear_b = tr.lever_arm_b(np.array([half, 0.0, 0.0])), tr.lever_arm_b(np.array([-half, 0.0, 0.0]))
    sigma = np.full((k.size, 2), st.sigma_mm * 1e-3)
    data = WheelPathData(tau_s, dR, dp, g_n, omega_ie_n, front_b, rear_b, tr.R_vb)
    inside, back = k >= 0, k < 0
    data_in, data_back = (data._replace(tau_s=tau_s[m], dR=dR[m], dp=dp[m], gravity_n=g_n[m]) for m in (inside, back))
    ki, ji, kb, jb = k[inside], j[inside], k[back] + H, j[back]
    keys = [keys_x[ki], keys_x[ji], keys_v[ji]]

    def build(state) -> LinearBlocks:
        r, J = wheel_path_residual(state.R[ki], state.p[ki], state.R[ji], state.p[ji], state.v[ji], data_in)
        return LinearBlocks(keys, J, r, sigma[inside])

    def build_front(state) -> LinearBlocks:
        r, J = wheel_path_residual(held.R_nb[kb], held.pos_n[kb], state.R[jb], state.p[jb], state.v[jb], data_back)
        return LinearBlocks([keys_x[jb], keys_v[jb]], J[1:], r, sigma[back])

    return int(ki.size), build, int(kb.size), build_front if kb.size else None
