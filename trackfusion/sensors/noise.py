"""Random error processes shared by the sensor models (vectorised, deterministic given the generator)."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def white(n: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """White Gaussian noise, (n,), standard deviation ``sigma``."""
    return rng.standard_normal(n) * sigma


def gauss_markov(n: int, dt_s: float, sigma: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary first-order Gauss-Markov process, (n,), std ``sigma``, correlation time ``tau_s``.

    Exact discretisation ``x_k = phi x_{k-1} + sqrt(1 - phi^2) sigma w_k`` with
    ``phi = exp(-dt / tau)``, started from its stationary distribution.
    """
    w = rng.standard_normal(n)
    if sigma == 0 or n == 0:
        return np.zeros(n)
    phi = np.exp(-dt_s / tau_s)
    drive = np.sqrt(1.0 - phi**2) * sigma * w
    x0 = sigma * rng.standard_normal()
    out, _ = lfilter([1.0], [1.0, -phi], drive, zi=[phi * x0])
    return out


def random_walk(n: int, dt_s: float, sigma_per_sqrt_s: float, rng: np.random.Generator) -> np.ndarray:
    """Random walk, (n,), starting at 0 after the first step: variance grows as sigma^2 t."""
    return np.cumsum(rng.standard_normal(n) * sigma_per_sqrt_s * np.sqrt(dt_s))


def quantise(x, step: float) -> np.ndarray:
    """Round ``x`` to the nearest multiple of ``step`` (``step`` <= 0: unchanged)."""
    x = np.asarray(x, dtype=float)
    return x if step <= 0 else np.round(x / step) * step
