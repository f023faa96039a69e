"""Every vectorised factor's Jacobians against central differences on the manifold
(GTSAM's conventions: R <- R Exp(dtheta), p <- p + R dp, velocities and scales additive),
plus known zero-residual configurations and the whitening / Huber arithmetic."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from trackfusion.fusion import factors as fx
from trackfusion.rotations import R_from_ypr, so3_exp

K = 12
EPS = 1e-6


def _rot(rng, k=K):
    return so3_exp(rng.uniform(-3, 3, (k, 3)))


def _pose_diff(f, R, p, rows):
    """Central differences of f(R, p) -> (K, m) w.r.t. the pose tangent: (K, m, 6)."""
    J = np.zeros((R.shape[0], rows, 6))
    for i in range(6):
        d = np.zeros((R.shape[0], 6))
        d[:, i] = EPS
        plus = f(R @ so3_exp(d[:, :3]), p + np.einsum("kij,kj->ki", R, d[:, 3:]))
        minus = f(R @ so3_exp(-d[:, :3]), p - np.einsum("kij,kj->ki", R, d[:, 3:]))
        J[:, :, i] = (plus - minus) / (2 * EPS)
    return J


def _vec_diff(f, x, rows):
    J = np.zeros((x.shape[0], rows, x.shape[1]))
    for i in range(x.shape[1]):
        d = np.zeros_like(x)
        d[:, i] = EPS
        J[:, :, i] = (f(x + d) - f(x - d)) / (2 * EPS)
    return J


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_nhc_jacobians(rng):
    R, v, w = _rot(rng), rng.normal(0, 3, (K, 3)), rng.normal(0, 0.1, (K, 3))
    lever, R_vb = rng.normal(0, 1, 3), R_from_ypr(0.02, -0.01, 0.03)
    r, d_theta, d_vel = fx.nhc_residual(R, v, w, lever, R_vb)
    num_pose = _pose_diff(lambda R_, p_: fx.nhc_residual(R_, v, w, lever, R_vb)[0], R, np.zeros((K, 3)), 2)
    np.testing.assert_allclose(d_theta, num_pose[:, :, :3], atol=1e-6)
    np.testing.assert_allclose(num_pose[:, :, 3:], 0.0, atol=1e-9)
    np.testing.assert_allclose(d_vel, _vec_diff(lambda v_: fx.nhc_residual(R, v_, w, lever, R_vb)[0], v, 2), atol=1e-6)


def test_nhc_zero_for_motion_along_the_trolley_axis(rng):
    R, R_vb = _rot(rng), R_from_ypr(0.01, 0.02, -0.01)
    x_n = R @ (R_vb.T @ np.array([1.0, 0.0, 0.0]))
    r, _, _ = fx.nhc_residual(R, 2.5 * x_n, np.zeros((K, 3)), np.array([0.3, -0.7, 0.2]), R_vb)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    r_side, _, _ = fx.nhc_residual(R, 2.5 * x_n + 0.01 * (R @ (R_vb.T @ np.array([0.0, 1.0, 0.0]))),
                                   np.zeros((K, 3)), np.zeros(3), R_vb)
    np.testing.assert_allclose(r_side[:, 0], 0.01, atol=1e-12)


def test_odometer_jacobians(rng):
    Ri, Rj = _rot(rng), _rot(rng)
    pi, pj = rng.normal(0, 5, (K, 3)), rng.normal(0, 5, (K, 3))
    s, delta = rng.normal(0, 1e-3, K), rng.normal(0, 1, K)
    lever, axis = rng.normal(0, 1, 3), np.array([0.6, 0.8, 0.0])
    r, (Ji, Jj, Js) = fx.odometer_residual(Ri, pi, Rj, pj, s, delta, lever, axis)
    num_i = _pose_diff(lambda R_, p_: fx.odometer_residual(R_, p_, Rj, pj, s, delta, lever, axis)[0], Ri, pi, 1)
    num_j = _pose_diff(lambda R_, p_: fx.odometer_residual(Ri, pi, R_, p_, s, delta, lever, axis)[0], Rj, pj, 1)
    num_s = _vec_diff(lambda s_: fx.odometer_residual(Ri, pi, Rj, pj, s_[:, 0], delta, lever, axis)[0], s[:, None], 1)
    np.testing.assert_allclose(Ji, num_i, atol=1e-6)
    np.testing.assert_allclose(Jj, num_j, atol=1e-6)
    np.testing.assert_allclose(Js, num_s, atol=1e-6)


def test_odometer_zero_for_the_scaled_distance_along_the_axis(rng):
    R = _rot(rng)
    axis = np.array([1.0, 0.0, 0.0])
    s, delta = np.full(K, 2e-4), np.full(K, 0.3)
    pj = R @ axis * (delta / (1 + s))[:, None]
    r, _ = fx.odometer_residual(R, np.zeros((K, 3)), R, pj, s, delta, np.zeros(3), axis)
    np.testing.assert_allclose(r, 0.0, atol=1e-14)


def test_gnss_jacobians_and_zero(rng):
    R, p, lever = _rot(rng), rng.normal(0, 10, (K, 3)), np.array([0.1, -0.2, 1.5])
    fix = p + R @ lever
    r, J = fx.gnss_residual(R, p, lever, fix)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    num = _pose_diff(lambda R_, p_: fx.gnss_residual(R_, p_, lever, fix)[0], R, p, 3)
    np.testing.assert_allclose(J, num, atol=1e-6)
    e = rng.normal(0, 0.01, (K, 3))
    np.testing.assert_allclose(fx.gnss_residual(R, p, lever, fix, e)[0], e, atol=1e-12)


def test_gauss_markov_jacobians(rng):
    ei, ej, phi = rng.normal(size=(K, 3)), rng.normal(size=(K, 3)), rng.uniform(0.9, 1.0, (K, 3))
    _, (Ji, Jj) = fx.gauss_markov_residual(ei, ej, phi)
    np.testing.assert_allclose(Ji, _vec_diff(lambda x: fx.gauss_markov_residual(x, ej, phi)[0], ei, 3), atol=1e-8)
    np.testing.assert_allclose(Jj, _vec_diff(lambda x: fx.gauss_markov_residual(ei, x, phi)[0], ej, 3), atol=1e-8)


def test_inclinometer_jacobian_and_zero(rng):
    roll, pitch, yaw = rng.uniform(-0.1, 0.1, K), rng.uniform(-0.1, 0.1, K), rng.uniform(-3, 3, K)
    R = R_from_ypr(yaw, pitch, roll)
    up_n = np.tile([0.0, 0.0, 1.0], (K, 1))
    up_b = fx.up_vector_from_roll_pitch(roll, pitch)
    r, J = fx.inclinometer_residual(R, up_n, up_b)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    R2 = _rot(rng)
    _, J2 = fx.inclinometer_residual(R2, up_n, up_b)
    num = _pose_diff(lambda R_, p_: fx.inclinometer_residual(R_, up_n, up_b)[0], R2, np.zeros((K, 3)), 2)
    np.testing.assert_allclose(J2, num[:, :, :3], atol=1e-6)


def test_huber_weights_cost_and_jacobian_factors(rng):
    r = np.array([[0.5, 0.0], [3.0, 4.0]])  # whitened norms 0.5 and 5 (sigma 1)
    blocks = fx.LinearBlocks([np.array([1, 2])], [np.ones((2, 2, 1))], r, np.ones((2, 2)), huber_k=2.0)
    np.testing.assert_allclose(blocks.weights(), [1.0, 0.4])
    assert blocks.cost() == pytest.approx(0.5 * 0.25 + (2.0 * 5.0 - 2.0))
    # continuity of the Huber cost at k
    at_k = fx.LinearBlocks([np.array([1])], [np.ones((1, 1, 1))], np.array([[2.0]]), np.ones((1, 1)), huber_k=2.0)
    assert at_k.cost() == pytest.approx(2.0)
    # whitened Jacobian factors: error(x) = 0.5 |sqrt(w) W (J x + r)|^2
    W = np.linalg.inv(np.linalg.cholesky(np.array([[4.0, 1.0], [1.0, 2.0]])))
    J = rng.normal(size=(1, 2, 3))
    res = rng.normal(size=(1, 2))
    b = fx.LinearBlocks([np.array([gtsam.symbol("x", 0)])], [J], res, np.ones((1, 2)), whiten=W[None])
    graph = gtsam.GaussianFactorGraph()
    fx.to_jacobian_factors(b, graph)
    x = rng.normal(size=3)
    vv = gtsam.VectorValues()
    vv.insert(gtsam.symbol("x", 0), x)
    expected = 0.5 * np.sum((W @ (J[0] @ x + res[0])) ** 2)
    assert graph.error(vv) == pytest.approx(expected, rel=1e-12)


G_N = np.array([0.0, 0.0, -9.79])
OMEGA_IE_N = np.array([0.0, 5.4e-5, 2.9e-5])


def _prism_obs(lever, tau, t_imu, y, from_station, dR=None, dv=None, dp=None, w=None, omega_ie_n=OMEGA_IE_N):
    n = tau.size
    return fx.PrismObservations(lever, tau, t_imu, y, from_station,
                                np.broadcast_to(np.eye(3), (n, 3, 3)) if dR is None else dR,
                                np.zeros((n, 3)) if dv is None else dv, np.zeros((n, 3)) if dp is None else dp,
                                np.zeros((n, 3)) if w is None else w, np.tile(G_N, (n, 1)), omega_ie_n)


def test_prism_jacobians(rng):
    R, p, v = _rot(rng), rng.normal(0, 50, (K, 3)), rng.normal(0, 1, (K, 3))
    w, lever = rng.normal(0, 0.2, (K, 3)), np.array([0.05, -0.1, 1.0])
    tau, t_imu = rng.uniform(0.0, 0.2, K), rng.uniform(0, 3000, K)
    q = np.column_stack([rng.normal(0, 1e-4, (K, 6)), rng.normal(0, 0.01, K), rng.normal(0, 2, K)])
    y, d = rng.normal(0, 50, (K, 3)), rng.normal(0, 500, (K, 3))
    obs = _prism_obs(lever, tau, t_imu, y, d, so3_exp(rng.normal(0, 0.02, (K, 3))), rng.normal(0, 2, (K, 3)),
                     rng.normal(0, 0.2, (K, 3)), w)

    def f(R_=R, p_=p, v_=v, q_=q):
        return fx.prism_residual(R_, p_, v_, q_, obs)[0]

    r, (Jp, Jv, Jq) = fx.prism_residual(R, p, v, q, obs)
    np.testing.assert_allclose(Jp, _pose_diff(lambda R_, p_: f(R_=R_, p_=p_), R, p, 3), atol=1e-6)
    np.testing.assert_allclose(Jv, _vec_diff(lambda v_: f(v_=v_), v, 3), atol=1e-6)
    np.testing.assert_allclose(Jq, _vec_diff(lambda q_: f(q_=q_), q, 3), atol=1e-5, rtol=1e-6)


def test_prism_zero_residual_on_consistent_data(rng):
    """A reading of the true prism, taken tau after the keyframe by a station whose point cloud is
    rotated and shifted and whose clock is late, is explained exactly by the true correction
    (a body moving at constant velocity: the IMU measures the reaction to gravity)."""
    R, p, v = _rot(rng), rng.normal(0, 50, (K, 3)), rng.normal(0, 1, (K, 3))
    lever, t_imu = np.array([0.0, 0.0, 1.0]), rng.uniform(0, 3000, K)
    centre = np.array([10.0, -5.0, 2.0])
    q = np.tile([2e-5, -1e-5, 3e-5, 0.002, -0.001, 0.003, 0.004, 1.5], (K, 1))
    t_true = rng.uniform(0.0, 0.2, K)
    truth = p + R @ lever + v * t_true[:, None]
    tau = t_true + q[:, 6] + 1e-6 * q[:, 7] * t_imu  # the reading's synchronised time after its keyframe
    f_b = np.einsum("kji,j->ki", R, -G_N)  # R^T (-g): at constant velocity
    # the station sees the truth through the inverse of its correction (first order)
    y = truth - q[:, 3:6]
    y = y - np.cross(q[:, :3], y - centre)
    obs = _prism_obs(lever, tau, t_imu, y, y - centre, dv=f_b * tau[:, None], dp=0.5 * f_b * tau[:, None] ** 2,
                     omega_ie_n=np.zeros(3))
    r, _ = fx.prism_residual(R, p, v, q, obs)
    np.testing.assert_allclose(r, 0.0, atol=1e-6)  # second-order terms of the small rotation


def test_prism_reading_of_an_accelerating_trolley_between_keyframes():
    """A trolley speeding up at 0.3 m/s^2 (and pitching at 0.05 rad/s) read by a station 0.1 s
    after the keyframe: the IMU samples in between (body_deltas) give the prism's position to
    a micrometre; the keyframe's velocity alone would be 1.5 mm off (a tau^2 / 2)."""
    from trackfusion.fusion.preintegration import body_deltas
    from trackfusion.sensors.types import ImuData
    dt, n, a, rate = 0.002, 200, 0.3, np.array([0.0, 0.05, 0.0])
    t = dt * np.arange(1, n + 1)
    # n-frame motion from rest at the keyframe (sample 10): p = a t^2 / 2 along x, R = Exp(rate t)
    tk = t[10]
    R_mid = so3_exp(np.outer(t - 0.5 * dt - tk, rate))  # a sample: the mean over the interval ending at it
    f_b = np.einsum("kji,j->ki", R_mid, np.array([a, 0.0, 0.0]) - G_N)
    imu = ImuData(t, np.tile(rate, (n, 1)), f_b)
    tau = np.array([0.1])
    lever = np.array([0.0, 0.0, 1.0])
    dR, dv, dp = body_deltas(imu, np.array([10]), tau)
    v0 = np.array([[1.2, 0.0, 0.0]])
    obs = _prism_obs(lever, tau, np.array([100.0]), np.zeros((1, 3)), np.zeros((1, 3)), dR, dv, dp,
                     omega_ie_n=np.zeros(3))
    r, _ = fx.prism_residual(np.eye(3)[None], np.zeros((1, 3)), v0, np.zeros((1, 8)), obs)
    R_t = so3_exp(rate * tau[0])
    truth = v0[0] * tau[0] + 0.5 * np.array([a, 0.0, 0.0]) * tau[0] ** 2 + R_t @ lever
    np.testing.assert_allclose(r[0], truth, atol=1e-6)
