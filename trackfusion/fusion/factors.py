"""Vectorised custom factors: non-holonomic constraint, odometer increment, inclinometer.

GTSAM's Python ``CustomFactor`` costs ~0.3 ms per factor inside its optimisers (a
Python callback from worker threads), far too slow for 36 000 keyframes an hour.
These factors are therefore evaluated for all keyframes at once with numpy, at the
current estimate, and handed to GTSAM as whitened ``JacobianFactor`` s
(:func:`to_jacobian_factors`); the smoother iterates Gauss-Newton itself.

Tangent conventions are GTSAM's: a pose is perturbed on the right,
``R <- R Exp(dtheta)``, ``p <- p + R dp`` (tangent ``[dtheta, dp]``), a velocity
(in ``n``) and the odometer scale additively. ``R`` below is ``R_nb`` (K, 3, 3).

Every factor returns its residual ``r`` (K, m) *before* whitening and the Jacobian
blocks (K, m, d) for each key; tests/test_fusion_factors.py checks each block against
numerical derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import gtsam
import numpy as np

from ..rotations import skew
from .preintegration import point_after

_P_YZ = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class LinearBlocks:
    """A batch of K factors linearised at the current estimate.

    keys: list of (K,) int arrays of GTSAM keys, one per variable slot;
    jacobians: list of (K, m, d_slot) arrays; residual: (K, m) unwhitened;
    sigma: (K, m) standard deviations; huber_k: Huber threshold on whitened residuals
    (None: plain least squares).
    """

    keys: list[np.ndarray]
    jacobians: list[np.ndarray]
    residual: np.ndarray
    sigma: np.ndarray
    huber_k: float | None = None
    whiten: np.ndarray | None = None  # (K, m, m) square-root information; replaces sigma
    group: np.ndarray | None = None  # (K,) int: factors of one group share their keys and become one JacobianFactor

    def _w(self, x: np.ndarray) -> np.ndarray:
        if self.whiten is None:
            return x / (self.sigma if x.ndim == 2 else self.sigma[:, :, None])
        return self.whiten @ x if x.ndim == 3 else np.einsum("kij,kj->ki", self.whiten, x)

    def whitened(self) -> np.ndarray:
        """Whitened residuals (K, m)."""
        return self._w(self.residual)

    def weights(self) -> np.ndarray:
        """Huber IRLS weight per factor (K,) from the norm of its whitened residual."""
        if self.huber_k is None:
            return np.ones(self.residual.shape[0])
        e = np.linalg.norm(self.whitened(), axis=1)
        return np.where(e <= self.huber_k, 1.0, self.huber_k / np.maximum(e, 1e-300))

    def weighted_jacobians(self) -> list[np.ndarray]:
        """Whitened, Huber-reweighted Jacobian blocks (K, m, d) per key slot, as GTSAM gets them."""
        sw = np.sqrt(self.weights())
        return [self._w(J) * sw[:, None, None] for J in self.jacobians]

    def cost(self) -> float:
        """0.5 sum of the (robust) squared whitened residuals, as GTSAM's ``error``."""
        e = np.linalg.norm(self.whitened(), axis=1)
        if self.huber_k is None:
            return 0.5 * float(np.sum(e**2))
        k = self.huber_k
        return float(np.sum(np.where(e <= k, 0.5 * e**2, k * e - 0.5 * k * k)))


def to_jacobian_factors(blocks: LinearBlocks, graph: gtsam.GaussianFactorGraph) -> None:
    """Append one whitened (and Huber-reweighted) ``JacobianFactor`` per factor to ``graph``."""
    A = blocks.weighted_jacobians()
    b = -blocks.whitened() * np.sqrt(blocks.weights())[:, None]
    if blocks.group is not None:
        _stacked_jacobian_factors(blocks.keys, A, b, blocks.group, graph)
        return
    unit = gtsam.noiseModel.Unit.Create(b.shape[1])
    keys = [k.tolist() for k in blocks.keys]
    if len(A) == 1:
        for i in range(b.shape[0]):
            graph.add(gtsam.JacobianFactor(keys[0][i], A[0][i], b[i], unit))
    elif len(A) == 2:
        for i in range(b.shape[0]):
            graph.add(gtsam.JacobianFactor(keys[0][i], A[0][i], keys[1][i], A[1][i], b[i], unit))
    elif len(A) == 3:
        for i in range(b.shape[0]):
            graph.add(gtsam.JacobianFactor(keys[0][i], A[0][i], keys[1][i], A[1][i], keys[2][i], A[2][i],
                                           b[i], unit))
    else:
        raise ValueError("factors with 1 to 3 keys only")


def _stacked_jacobian_factors(keys: list[np.ndarray], A: list[np.ndarray], b: np.ndarray, group: np.ndarray,
                              graph: gtsam.GaussianFactorGraph) -> None:
    """One JacobianFactor per group of factors with the same keys, their whitened rows stacked
    (the same information as one factor each, in far fewer Python calls and GTSAM factors).
    keys: per slot (K,); A: per slot (K, m, d); b (K, m); group (K,) int."""
    order = np.argsort(group, kind="stable")
    start = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0])
    size = np.diff(np.r_[start, order.size])
    m = b.shape[1]
    for n in np.unique(size):
        first = start[size == n]
        idx = order[first[:, None] + np.arange(n)[None, :]]  # (G, n) members of each group of n
        As = [a[idx].reshape(idx.shape[0], n * m, a.shape[2]) for a in A]
        bs = b[idx].reshape(idx.shape[0], n * m)
        ks = [k[idx[:, 0]].tolist() for k in keys]
        unit = gtsam.noiseModel.Unit.Create(n * m)
        for g in range(idx.shape[0]):
            args = [item for j in range(len(As)) for item in (ks[j][g], As[j][g])]
            graph.add(gtsam.JacobianFactor(*args, bs[g], unit))


# --- non-holonomic constraint ------------------------------------------------------------------

def nhc_residual(R_nb: np.ndarray, vel_n: np.ndarray, omega_nb_b: np.ndarray, lever_arm_b: np.ndarray,
                 R_vb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lateral and vertical velocity in ``v`` of the point at ``lever_arm_b`` (seed 002 eqs. 20-22).

    R_nb (K,3,3); vel_n (K,3) [m/s] IMU velocity; omega_nb_b (K,3) [rad/s] body rate w.r.t. n
    (held constant: a measured quantity); lever_arm_b (3,) [m] from the IMU to the constrained
    point; R_vb (3,3) mounting rotation. Returns r (K,2) [m/s], dr/dtheta (K,2,3) (pose
    rotation), dr/dvel (K,2,3); dr/dp is zero.
    """
    y = np.einsum("kji,kj->ki", R_nb, vel_n)  # R^T v
    point_b = y + np.cross(omega_nb_b, lever_arm_b)
    PR = _P_YZ @ R_vb  # (2,3)
    r = point_b @ PR.T
    d_theta = PR @ skew(y)  # (K,2,3)
    d_vel = np.einsum("ij,kli->kjl", PR.T, R_nb)  # PR R^T: (K,2,3)
    return r, d_theta, d_vel


# --- odometer increment ------------------------------------------------------------------------

def odometer_residual(R_i: np.ndarray, p_i: np.ndarray, R_j: np.ndarray, p_j: np.ndarray, scale: np.ndarray,
                      delta_m: np.ndarray, lever_arm_b: np.ndarray, axis_b: np.ndarray
                      ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Odometer distance increment between keyframes i and j.

    Model: ``delta_m = (1 + scale) axis_b . R_i^T (w_j - w_i)`` with the wheel contact
    ``w = p + R lever_arm_b``; axis_b (3,) the trolley's x axis in ``b``. The chord of a
    0.1 s interval equals the rolled arc to 1e-7 (curvature and irregularity slopes).
    R_* (K,3,3), p_* (K,3) [m], scale (K,) [-] dimensionless scale error, delta_m (K,) [m].
    Returns r (K,1) [m] and Jacobians [d/pose_i (K,1,6), d/pose_j (K,1,6), d/scale (K,1,1)].
    """
    q = p_j + R_j @ lever_arm_b - p_i - R_i @ lever_arm_b
    y = np.einsum("kji,kj->ki", R_i, q)  # R_i^T q
    k1 = (1.0 + scale)[:, None]
    proj = y @ axis_b
    r = (1.0 + scale) * proj - delta_m
    l_x = skew(lever_arm_b)
    Rij = np.einsum("kji,kjl->kil", R_i, R_j)  # R_i^T R_j
    ax = axis_b[None, None, :]
    d_pose_i = np.concatenate([ax @ (skew(y) + l_x), -np.broadcast_to(ax, (y.shape[0], 1, 3))], axis=2)
    d_pose_j = np.concatenate([-(ax @ Rij @ l_x), ax @ Rij], axis=2)
    d_pose_i = d_pose_i * k1[:, :, None]
    d_pose_j = d_pose_j * k1[:, :, None]
    d_scale = proj[:, None, None]
    return r[:, None], [d_pose_i, d_pose_j, d_scale]


# --- GNSS antenna position ------------------------------------------------------------------------

def gnss_residual(R_nb: np.ndarray, pos_n: np.ndarray, lever_arm_b: np.ndarray, fix_n: np.ndarray,
                  error_n: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Antenna position ``p + R lever_arm_b`` (+ the correlated GNSS error state) minus the fix.

    R_nb (K,3,3), pos_n (K,3) [m], lever_arm_b (3,) [m], fix_n (K,3) [m], error_n (K,3) [m] or None.
    Returns r (K,3) [m] and d/pose (K,3,6); d/error is the identity.
    """
    r = pos_n + R_nb @ lever_arm_b - fix_n
    if error_n is not None:
        r = r + error_n
    d_theta = -R_nb @ skew(lever_arm_b)
    return r, np.concatenate([d_theta, R_nb], axis=2)


def gauss_markov_residual(e_i: np.ndarray, e_j: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """First-order Gauss-Markov step ``e_j - phi e_i`` (K,3) with ``phi = exp(-dt/tau)`` (K,3);
    Jacobians [d/e_i (K,3,3), d/e_j (K,3,3)]."""
    eye = np.broadcast_to(np.eye(3), (e_i.shape[0], 3, 3))
    return e_j - phi * e_i, [-phi[:, :, None] * eye, eye]


# --- inclinometer ------------------------------------------------------------------------------

def up_vector_from_roll_pitch(roll_rad: np.ndarray, pitch_rad: np.ndarray) -> np.ndarray:
    """Unit up-vector (N,3) in a frame with the given roll and pitch (package conventions)."""
    cp = np.cos(pitch_rad)
    return np.column_stack([np.sin(pitch_rad), np.sin(roll_rad) * cp, np.cos(roll_rad) * cp])


def inclinometer_residual(R_nb: np.ndarray, up_n: np.ndarray, up_b_measured: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal components of the local up direction in ``b``, predicted minus measured.

    R_nb (K,3,3); up_n (K,3) unit plumb-line direction at the keyframe position (normal gravity,
    so the 157 urad/km turn of the vertical is included); up_b_measured (K,3) from the
    inclinometer's roll and pitch through its mounting. Returns r (K,2) [rad, small angles]
    and dr/dtheta (K,2,3).
    """
    y = np.einsum("kji,kj->ki", R_nb, up_n)
    r = y[:, :2] - up_b_measured[:, :2]
    return r, skew(y)[:, :2, :]


# --- total-station prism ------------------------------------------------------------------------

#: layout of a station's correction state ``T(j)`` (8,): rotation of its point cloud about the
#: station centre [rad] (3, in ``n``), translation [m] (3), clock offset [s], clock drift [ppm]
STATION_STATE_DIM = 8


class PrismObservations(NamedTuple):
    """K prism readings as :func:`prism_residual` sees them (fixed while the states change, built
    once): lever_arm_b (3,) [m] IMU to prism in ``b``; tau_s (K,) [s] each reading's time after
    its keyframe on the synchronised clock; t_imu_s (K,) [s] its IMU time; prism_n (K,3) [m] the
    reading in ``n`` with the nominal set-up; from_station_n (K,3) [m] = prism_n minus the station
    centre; the IMU from the keyframe to the reading: dR (K,3,3), dv (K,3) [m/s], dp (K,3) [m]
    (:func:`~.preintegration.body_deltas`) and omega_ib_b (K,3) [rad/s] (the sample holding the
    reading); gravity_n (K,3) [m/s^2] at the keyframe; omega_ie_n (3,) [rad/s]."""

    lever_arm_b: np.ndarray
    tau_s: np.ndarray
    t_imu_s: np.ndarray
    prism_n: np.ndarray
    from_station_n: np.ndarray
    dR: np.ndarray
    dv: np.ndarray
    dp: np.ndarray
    omega_ib_b: np.ndarray
    gravity_n: np.ndarray
    omega_ie_n: np.ndarray


#: the fields of :class:`PrismObservations` with one row per reading
PRISM_PER_READING = ("tau_s", "t_imu_s", "prism_n", "from_station_n", "dR", "dv", "dp", "omega_ib_b", "gravity_n")


def prism_residual(R_nb: np.ndarray, pos_n: np.ndarray, vel_n: np.ndarray, station_state: np.ndarray,
                   obs: PrismObservations) -> tuple[np.ndarray, list[np.ndarray]]:
    """Predicted minus (station-corrected) measured prism position, K readings at once.

    The reading was taken ``tau_s`` (K,) [s] after its keyframe on the synchronised clock. The
    prism ``P = p + R lever`` there is reached from the keyframe's state with the IMU samples in
    between (:func:`~.preintegration.point_after`: the preintegration's mechanisation, exact for
    any acceleration; a first-order step from the keyframe's velocity was 0.23 mm RMS off along
    a trolley's track at 0.1 s: docs/total_stations.md). The station's correction state ``q``
    (K,8) (:data:`STATION_STATE_DIM`) moves the reading in time by ``-(q[6] + 1e-6 q[7] t_imu_s)``
    (milliseconds: first order, along the prism's velocity ``v + R (w x lever)`` at the reading)
    and in space by ``q[:3] x from_station_n + q[3:6]`` (a small rotation about the station
    centre, then a translation: first order, < 1e-7 m for rotations of arcseconds at 1 km).

    R_nb (K,3,3), pos_n, vel_n (K,3): the keyframes' states; station_state (K,8); obs the
    readings (:class:`PrismObservations`).
    Returns r (K,3) [m] and Jacobians [d/pose (K,3,6), d/vel (K,3,3), d/q (K,3,8)].
    """
    lever, tau, t_imu, from_station_n = obs.lever_arm_b, obs.tau_s, obs.t_imu_s, obs.from_station_n
    q = station_state
    P, earth_R_j, dP_theta, dP_v = point_after(R_nb, pos_n, vel_n, obs, lever)
    coriolis = obs.gravity_n - 2.0 * np.cross(obs.omega_ie_n, vel_n)
    v_t = vel_n + coriolis * tau[:, None] + np.einsum("kij,kj->ki", R_nb, obs.dv)
    # the prism's velocity at the reading: v + R (w_nb x lever), w_nb = w_ib - R^T omega_ie
    w_x_l_j = np.einsum("kij,kj->ki", obs.dR, np.cross(obs.omega_ib_b, lever))  # in j's body frame
    lever_j = np.einsum("kij,j->ki", obs.dR, lever)
    R_lever = np.einsum("kij,kj->ki", earth_R_j, lever_j)
    u = v_t + np.einsum("kij,kj->ki", earth_R_j, w_x_l_j) - np.cross(obs.omega_ie_n, R_lever)
    shift = q[:, 6] + 1e-6 * q[:, 7] * t_imu  # (K,) [s]
    corrected = obs.prism_n + np.cross(q[:, :3], from_station_n) + q[:, 3:6]
    r = P - u * shift[:, None] - corrected
    du_theta = (-R_nb @ skew(obs.dv) - earth_R_j @ skew(w_x_l_j)
                + skew(obs.omega_ie_n)[None] @ earth_R_j @ skew(lever_j))
    d_theta = dP_theta - du_theta * shift[:, None, None]
    d_pose = np.concatenate([d_theta, R_nb], axis=2)
    du_v = np.eye(3)[None] - 2.0 * skew(obs.omega_ie_n)[None] * tau[:, None, None]
    d_vel = dP_v - du_v * shift[:, None, None]
    d_q = np.concatenate([skew(from_station_n), -np.broadcast_to(np.eye(3), r.shape + (3,)),
                          -u[:, :, None], -(u * 1e-6 * t_imu[:, None])[:, :, None]], axis=2)
    return r, [d_pose, d_vel, d_q]
