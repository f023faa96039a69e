"""Seed 004's track-level methods (track/level_baselines.py) against analytic cases."""

import numpy as np
import pytest

from trackfusion.errors import TrackGeometryError
from trackfusion.track import level_baselines as lb
from trackfusion.track.irregularities import cross_level_from_roll

DT = 0.02  # 50 Hz


def test_constant_cant_gives_the_exact_cross_level():
    """A constant 120 mm cant over 1.5 m and ideal sensors: every method returns H = L sin(theta)."""
    theta = np.arcsin(0.120 / 1.5)
    n = 2000
    t = DT * np.arange(n)
    z = np.full(n, theta)
    gyro = lb.gyro_angle(t, np.zeros(n), theta)
    H_exact = 1.5 * np.sin(theta)
    assert np.allclose(cross_level_from_roll(gyro, 1.5), 0.120, atol=1e-12)
    # the Kalman filter starts at the seed's X0 = 0 and converges (P0 = 1): exact after settling
    kal = lb.seed_kalman(z, gyro)
    assert abs(kal[0] - theta) > 1e-3 * theta
    assert np.allclose(cross_level_from_roll(kal[50:], 1.5), H_exact, rtol=0, atol=1e-12)
    w = lb.seed_weighted_fusion(z, gyro, variances=lb.SEED_R)
    assert np.allclose(cross_level_from_roll(w.angle_rad, 1.5), H_exact, atol=1e-12)
    assert w.weights == pytest.approx((10 / 11, 1 / 11))
    comp = lb.complementary_filter(t, z, np.zeros(n), 2.0)
    assert np.allclose(cross_level_from_roll(comp, 1.5), H_exact, atol=1e-12)


def test_gyro_angle_integrates_and_is_zeroed_at_rest():
    t = DT * np.arange(1000)
    bias = 1e-4
    rate = np.where(t >= 5.0, 0.01, 0.0) + bias       # 5 s at rest, then 0.01 rad/s
    theta = lb.gyro_angle(t, rate, 0.02, rest=t < 5.0)
    expected = 0.02 + 0.01 * np.clip(t - 5.0, 0, None)
    assert np.allclose(theta, expected, atol=0.01 * DT)
    with pytest.raises(TrackGeometryError):
        lb.gyro_angle(t, rate, rest=np.zeros(t.size, bool))


def test_kalman_reaches_the_riccati_steady_state_gain():
    """With constant Q and R the gains converge to the scalar Riccati root; the filter's impulse
    response then decays by 1 - sum(Kg) per step (checks eqs. 3-7 against the closed form)."""
    k = lb.steady_state_gain()
    r_inv = 1 / np.array(lb.SEED_R)
    p = k[0] / r_inv[0]
    assert p == pytest.approx(1 / (1 / (p + lb.SEED_Q) + r_inv.sum()), rel=1e-12)   # fixed point
    assert k[0] / k[1] == pytest.approx(10.0)                                       # R_B / R_A
    n = 400
    step = np.zeros(n)
    step[200:] = 1.0
    out = lb.seed_kalman(step, step, x0=0.0, p0=p)          # started in steady state
    a = 1 - k.sum()
    assert np.allclose(out[200:210], 1 - a ** np.arange(1, 11), atol=1e-12)
    # a different Q gives a different response: the test can fail
    assert not np.allclose(lb.seed_kalman(step, step, q=0.1, p0=p)[200:210], out[200:210], atol=1e-3)


def test_weighted_fusion_reaches_the_seed_optimum_from_data_alone():
    """Seed eqs. 15-18: weights s2^2 / (s1^2 + s2^2) estimated from the two series' covariance
    give the minimum variance s1^2 s2^2 / (s1^2 + s2^2), below either sensor's."""
    rng = np.random.default_rng(5)
    n = 200_000
    x = 1e-3 * np.sin(np.arange(n) / 500) + 1e-3 * rng.standard_normal(n)   # the level, varying (stationary)
    s1, s2 = 2e-4, 6e-4
    z1, z2 = x + s1 * rng.standard_normal(n), x + s2 * rng.standard_normal(n)
    w = lb.seed_weighted_fusion(z1, z2)
    assert w.variances[0] == pytest.approx(s1 ** 2, rel=0.05) and w.variances[1] == pytest.approx(s2 ** 2, rel=0.05)
    assert w.weights[0] == pytest.approx(s2 ** 2 / (s1 ** 2 + s2 ** 2), rel=0.02)
    fused_var = np.var(w.angle_rad - x)
    assert fused_var == pytest.approx(s1 ** 2 * s2 ** 2 / (s1 ** 2 + s2 ** 2), rel=0.05)
    assert fused_var < s1 ** 2


def test_complementary_filter_transfer_at_its_crossover():
    """At f = 1 / (2 pi T) the angle-sensor path has gain 1/sqrt(2) and the gyro path the
    complement; a true sinusoidal roll seen by both ideal sensors passes unchanged."""
    T = 2.0
    f = 1 / (2 * np.pi * T)
    t = DT * np.arange(int(400 / DT))
    theta = 1e-3 * np.sin(2 * np.pi * f * t)
    rate = 1e-3 * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    inner = t > 100

    def amp(y):
        X = np.column_stack([np.sin(2 * np.pi * f * t[inner]), np.cos(2 * np.pi * f * t[inner])])
        return np.hypot(*np.linalg.lstsq(X, y[inner], rcond=None)[0]) / 1e-3

    assert amp(lb.complementary_filter(t, theta, np.zeros(t.size), T)) == pytest.approx(1 / np.sqrt(2), rel=0.01)
    assert amp(lb.complementary_filter(t, np.zeros(t.size), rate, T)) == pytest.approx(1 / np.sqrt(2), rel=0.01)
    both = lb.complementary_filter(t, theta, rate, T)
    assert np.abs(both[inner] - theta[inner]).max() < 0.01 * 1e-3


def test_inverse_first_order_lag_undoes_the_simulated_inclinometer_lag():
    from trackfusion.simulation.aiding import first_order_lag
    t = DT * np.arange(5000)
    ramp = np.clip((t - 20) * 1e-3, 0, 0.08)                  # a cant ramp, then constant
    lagged = first_order_lag(ramp, DT, 0.5)
    assert np.abs(lagged - ramp).max() > 4e-4                  # lag x rate = 0.5 mrad
    back = lb.inverse_first_order_lag(t, lagged, 0.5, window_s=DT)
    inner = (np.abs(t - 20) > 0.2) & (np.abs(t - 100) > 0.2)   # away from the kinks
    assert np.abs(back - ramp)[inner].max() < 2e-5
