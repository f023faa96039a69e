"""Seed 002 relative-accuracy statistics (eqs. 1-6): known answers, allantools, eq. 4."""

import allantools
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from trackfusion.errors import EvaluationError
from trackfusion.evaluation import relative as rel

STEP_M = 0.1
SCALES_M = (0.5, 1.0, 2.0, 5.0, 10.0)


def test_white_noise_known_answers():
    rng = np.random.default_rng(11)
    sigma = 0.8e-3
    x = rng.normal(0.0, sigma, size=(200, 10_000))  # 200 passes of 1 km at 0.1 m
    ra = rel.relative_accuracy(x, STEP_M, SCALES_M)
    m = np.array([rel.scale_samples(s, STEP_M) for s in SCALES_M])
    assert ra.sigma_mm == pytest.approx(0.8, rel=3e-3)
    np.testing.assert_allclose(ra.mse_mm, np.sqrt(2) * 0.8, rtol=5e-3)  # sigma1 = sqrt(2) sigma
    np.testing.assert_allclose(ra.sigma2_mm, np.sqrt(2.0 / m) * 0.8, rtol=2e-2)
    np.testing.assert_allclose(ra.adev_mm, 0.8 / np.sqrt(m), rtol=2e-2)  # ADEV = sigma / sqrt(m)
    np.testing.assert_allclose(ra.oadev_mm, 0.8 / np.sqrt(m), rtol=2e-2)
    assert ra.n_points == 2_000_000
    assert ra.n_pairs.tolist() == [200 * (10_000 - k) for k in m]
    assert ra.n_cluster_differences.tolist() == [200 * (10_000 // k - 1) for k in m]


def test_random_walk_known_answers():
    rng = np.random.default_rng(12)
    q = 0.05e-3  # step standard deviation per grid step (m)
    n, passes = 4000, 400
    x = np.cumsum(rng.normal(0.0, q, size=(passes, n)), axis=1)
    ra = rel.relative_accuracy(x, STEP_M, SCALES_M)
    m = np.array([rel.scale_samples(s, STEP_M) for s in SCALES_M], dtype=float)
    # eq. 1: E[sum_k x_k^2] = q^2 n (n + 1) / 2 per pass (x_k sums k + 1 steps), divided by N - 1;
    # checked on many short passes (one long walk's sigma scatters too much)
    short = np.cumsum(rng.normal(0.0, q, size=(20_000, 200)), axis=1)
    expected = q * np.sqrt(20_000 * 200 * 201 / 2 / (20_000 * 200 - 1))
    assert rel.sigma_eq1(short) == pytest.approx(expected, rel=0.02)
    np.testing.assert_allclose(ra.mse_mm, 1e3 * q * np.sqrt(m), rtol=0.01)  # sigma1^2 = q^2 m
    # sigma2^2 = q^2 (2 m^2 + 1) / (3 m): weights r/m and (m - r)/m of the steps
    np.testing.assert_allclose(ra.sigma2_mm, 1e3 * q * np.sqrt((2 * m**2 + 1) / (3 * m)), rtol=0.03)
    np.testing.assert_allclose(ra.adev_mm, ra.sigma2_mm / np.sqrt(2), rtol=1e-12)


def test_sinusoid_known_answers():
    amp, wavelength = 1.5e-3, 20.0
    step = 0.05
    i = np.arange(int(4000 / step))  # 4 km: 200 whole periods
    x = amp * np.sin(2 * np.pi * i * step / wavelength + 0.3)
    scales = (0.5, 1.0, 2.0, 5.0)
    ra = rel.relative_accuracy(x, step, scales)
    L = np.array(scales)
    m = L / step
    dirichlet = np.sin(np.pi * L / wavelength) / (m * np.sin(np.pi * step / wavelength))
    assert ra.sigma_mm == pytest.approx(1e3 * amp / np.sqrt(2) * np.sqrt(i.size / (i.size - 1)), rel=1e-9)
    np.testing.assert_allclose(ra.mse_mm, 1e3 * np.sqrt(2) * amp * np.sin(np.pi * L / wavelength), rtol=2e-3)
    adev = 1e3 * amp * dirichlet * np.sin(np.pi * L / wavelength)
    np.testing.assert_allclose(ra.adev_mm, adev, rtol=2e-3)
    np.testing.assert_allclose(ra.oadev_mm, adev, rtol=2e-3)
    np.testing.assert_allclose(ra.sigma2_mm, np.sqrt(2) * adev, rtol=2e-3)


@pytest.mark.parametrize("kind", ["white", "walk", "flicker-ish"])
def test_adev_and_oadev_agree_with_allantools(kind):
    rng = np.random.default_rng(13)
    w = rng.normal(0.0, 1e-3, 30_001)
    x = {"white": w, "walk": np.cumsum(w) * 0.1, "flicker-ish": lfilter([1.0], [1.0, -0.95], w) + 0.02}[kind]
    step = 0.05
    for scale in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        m = rel.scale_samples(scale, step)
        _, ad, _, n = allantools.adev(x, rate=1 / step, data_type="freq", taus=[scale])
        _, oad, _, on = allantools.oadev(x, rate=1 / step, data_type="freq", taus=[scale])
        assert rel.allan_deviation(x, m) == pytest.approx(ad[0], rel=1e-9)
        assert rel.overlapping_allan_deviation(x, m) == pytest.approx(oad[0], rel=1e-9)
        assert rel.cluster_difference_sums(x, m)[1] == n[0]
        assert rel.overlapping_cluster_difference_sums(x, m)[1] == on[0]


def _gauss_markov(rng, n, corr_steps, sigma):
    phi = np.exp(-1.0 / corr_steps)
    x = lfilter([np.sqrt(1 - phi**2)], [1.0, -phi], rng.normal(0.0, sigma, n))
    return x + rng.normal(0.0, sigma) * phi ** np.arange(n)  # start (nearly) stationary


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), scale_m=st.sampled_from([0.5, 1.0, 2.0]),
       corr_over_scale=st.floats(10.0, 40.0), sigma_mm=st.floats(0.1, 20.0), bias_mm=st.floats(-20.0, 20.0))
def test_eq4_holds_for_slowly_varying_errors(seed, scale_m, corr_over_scale, sigma_mm, bias_mm):
    """Seed 002 eq. 4, sigma >= sigma1(L) >= sigma2(L), for errors correlated over >= 10 L."""
    rng = np.random.default_rng(seed)
    corr_m = corr_over_scale * scale_m
    n = int(150 * corr_m / STEP_M)  # 150 correlation lengths
    x = 1e-3 * (_gauss_markov(rng, n, corr_m / STEP_M, sigma_mm) + bias_mm)
    m = rel.scale_samples(scale_m, STEP_M)
    s, s1, s2 = rel.sigma_eq1(x), rel.sigma1(x, m), rel.sigma2(x, m)
    assert s >= s1 >= s2


def test_eq4_fails_for_white_noise():
    """White noise has no correlation at any L: sigma1 = sqrt(2) sigma > sigma, so eq. 4 does not hold."""
    x = np.random.default_rng(14).normal(0.0, 1e-3, 200_000)
    s, s1 = rel.sigma_eq1(x), rel.sigma1(x, 10)
    assert s1 > s
    assert s1 / s == pytest.approx(np.sqrt(2), rel=0.01)


def test_long_wave_sinusoid_satisfies_eq4_strictly():
    x = 2e-3 * np.sin(2 * np.pi * np.arange(100_000) * STEP_M / 100.0)
    m = rel.scale_samples(5.0, STEP_M)
    assert rel.sigma_eq1(x) > rel.sigma1(x, m) > rel.sigma2(x, m)


def test_pooling_never_differences_across_passes():
    a, b = np.zeros(100), np.ones(100)  # each pass constant: no relative error inside a pass
    ra = rel.relative_accuracy([a, b], 0.1, (0.5, 1.0))
    np.testing.assert_array_equal(ra.mse_mm, 0.0)
    np.testing.assert_array_equal(ra.adev_mm, 0.0)
    assert ra.sigma_mm == pytest.approx(1e3 * np.sqrt(100 / 199))


def test_too_short_scale_is_nan_and_bad_scale_is_an_error():
    ra = rel.relative_accuracy(np.zeros(30), 0.1, (1.0, 2.0, 5.0))
    assert np.isfinite(ra.mse_mm[:2]).all() and np.isnan(ra.mse_mm[2])  # 5 m needs > 50 points
    assert np.isnan(ra.adev_mm[1])  # 2 m clusters of 20: only one cluster in 30 points
    assert ra.to_json()["mse_mm"][2] is None
    with pytest.raises(EvaluationError, match="not a whole multiple"):
        rel.relative_accuracy(np.zeros(30), 0.1, (0.25,))
    with pytest.raises(EvaluationError):
        rel.scale_samples(0.01, 0.05)
