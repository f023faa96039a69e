"""benchmarks/gnss_correlated_oracle.py: its Kalman-filter likelihood against the dense Gaussian
one, and its maximum-likelihood sigma on a long simulated series."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import multivariate_normal

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import gnss_correlated_oracle as bench  # noqa: E402


def test_kalman_likelihood_equals_the_dense_gaussian() -> None:
    """The filter's log-likelihood is the multivariate normal's with covariance
    ``s^2 phi^|dt| + w^2 I``, up to the constant ``-K/2 log(2 pi)``, with a gap in the times."""
    rng = np.random.default_rng(3)
    t = np.r_[np.arange(40.0), 55.0 + np.arange(30.0)]
    sigma, tau, white = 12.0, 25.0, 5.0
    cov = sigma**2 * np.exp(-np.abs(t[:, None] - t[None, :]) / tau) + white**2 * np.eye(t.size)
    y = rng.multivariate_normal(np.zeros(t.size), cov)
    dense = multivariate_normal(np.zeros(t.size), cov).logpdf(y) + 0.5 * t.size * np.log(2 * np.pi)
    assert abs(bench.gauss_markov_log_likelihood(y, t, white, sigma, tau) - dense) < 1e-9 * abs(dense)


def test_oracle_sigma_recovers_the_drawn_one() -> None:
    """On 4 000 epochs of a 20 s process (200 correlation times) the fit is within 10 % of the
    drawn sigma (seeds 5-8 of this draw give 0.97-1.03)."""
    rng = np.random.default_rng(5)
    t = np.arange(4000.0)
    phi = np.exp(-1.0 / 20.0)
    g = np.empty(t.size)
    g[0] = rng.standard_normal() * 10.0
    for k in range(1, t.size):
        g[k] = phi * g[k - 1] + np.sqrt(1 - phi**2) * 10.0 * rng.standard_normal()
    y = g + 4.0 * rng.standard_normal(t.size)
    assert abs(bench.oracle_sigma_mm(y, t, 4.0, 20.0, 10.0) / 10.0 - 1.0) < 0.10
