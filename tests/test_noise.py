"""Statistics of the shared error processes."""

import numpy as np
import pytest

from trackfusion.simulation import noise


def test_gauss_markov_variance_and_correlation_time():
    rng = np.random.default_rng(3)
    dt, tau, sigma, n = 0.1, 5.0, 2.0, 400_000
    x = noise.gauss_markov(n, dt, sigma, tau, rng)
    # n dt / tau = 8000 correlation times: std of the variance estimate ~ sqrt(2 tau / (n dt)) ~ 1.6 %
    assert x.std() == pytest.approx(sigma, rel=0.05)
    lag = int(tau / dt)
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(np.exp(-1.0), abs=0.03)


def test_gauss_markov_starts_stationary():
    rng = np.random.default_rng(4)
    first = np.array([noise.gauss_markov(3, 0.01, 1.5, 100.0, rng)[0] for _ in range(4000)])
    assert first.std() == pytest.approx(1.5, rel=0.05)


def test_random_walk_variance_grows_linearly():
    rng = np.random.default_rng(5)
    walks = np.array([noise.random_walk(1000, 0.01, 0.3, rng) for _ in range(2000)])
    assert walks[:, -1].var() == pytest.approx(0.3**2 * 10.0, rel=0.08)
    assert walks[:, 499].var() == pytest.approx(0.3**2 * 5.0, rel=0.08)


def test_white_and_quantise():
    rng = np.random.default_rng(6)
    assert noise.white(200_000, 0.7, rng).std() == pytest.approx(0.7, rel=0.01)
    assert noise.quantise([0.24, 0.26, -0.74], 0.5).tolist() == [0.0, 0.5, -0.5]
    assert noise.quantise([0.123], 0.0).tolist() == [0.123]


def test_same_generator_state_same_series_and_bad_arguments():
    a = noise.gauss_markov(1000, 0.01, 1.0, 2.0, np.random.default_rng(7))
    b = noise.gauss_markov(1000, 0.01, 1.0, 2.0, np.random.default_rng(7))
    assert np.array_equal(a, b)
    assert noise.gauss_markov(5, 0.01, 0.0, 2.0, np.random.default_rng(7)).tolist() == [0.0] * 5
    from trackfusion.errors import SimulationError
    for call in (lambda: noise.gauss_markov(10, 0.01, 1.0, 0.0, np.random.default_rng()),
                 lambda: noise.gauss_markov(10, -1.0, 1.0, 1.0, np.random.default_rng()),
                 lambda: noise.random_walk(10, 0.0, 1.0, np.random.default_rng()),
                 lambda: noise.white(-1, 1.0, np.random.default_rng())):
        with pytest.raises(SimulationError):
            call()
