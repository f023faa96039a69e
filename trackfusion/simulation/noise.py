"""Random error processes shared by the sensor models.

Every function is vectorised (no per-sample Python loop) and deterministic
given the state of the ``numpy.random.Generator`` it is passed. Sigmas are in
the unit of the returned series.
"""

from __future__ import annotations

import numpy as np

from ..errors import SimulationError


def _check_n(n: int) -> int:
    if int(n) != n or n < 0:
        raise SimulationError(f"noise: sample count must be a non-negative integer, got {n}")
    return int(n)


def _check_positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0:
        raise SimulationError(f"noise: {name} must be finite and > 0, got {value}")


def white(n: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """White Gaussian noise, shape (n,), standard deviation ``sigma``."""
    return rng.standard_normal(_check_n(n)) * sigma


def gauss_markov(n: int, dt_s: float, sigma: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary first-order Gauss-Markov process, shape (n,), std ``sigma``, correlation time ``tau_s``.

    Exact discretisation of ``dx/dt = -x / tau + w``: ``x_k = phi x_{k-1} + sqrt(1 - phi^2) sigma w_k``
    with ``phi = exp(-dt_s / tau_s)``, started from its stationary distribution (so
    ``var x_k = sigma^2`` for every k and ``corr(x_k, x_{k+m}) = exp(-m dt_s / tau_s)``).
    Samples are ``dt_s`` apart [s]; runs as one :func:`scipy.signal.lfilter` call.
    """
    n = _check_n(n)
    _check_positive("dt_s", dt_s)
    _check_positive("tau_s", tau_s)
    w = rng.standard_normal(n)
    if sigma == 0 or n == 0:
        return np.zeros(n)
    phi = np.exp(-dt_s / tau_s)
    drive = np.sqrt(1.0 - phi**2) * sigma * w
    x0 = sigma * rng.standard_normal()  # state before the first sample, stationary
    from scipy.signal import lfilter  # here: scipy.signal costs ~2 s to import, and only the simulator needs it
    out, _ = lfilter([1.0], [1.0, -phi], drive, zi=[phi * x0])
    return out


def random_walk(n: int, dt_s: float, sigma_per_sqrt_s: float, rng: np.random.Generator) -> np.ndarray:
    """Random walk (integrated white noise), shape (n,).

    Sample k is the walk at time ``(k + 1) dt_s`` after a start at 0, so its variance is
    ``sigma_per_sqrt_s^2 (k + 1) dt_s`` (``sigma_per_sqrt_s`` in unit/sqrt(s)).
    """
    n = _check_n(n)
    _check_positive("dt_s", dt_s)
    return np.cumsum(rng.standard_normal(n) * sigma_per_sqrt_s * np.sqrt(dt_s))


def quantise(x, step: float) -> np.ndarray:
    """Round ``x`` (any shape) to the nearest multiple of ``step`` (``step`` <= 0: unchanged, as float)."""
    x = np.asarray(x, dtype=float)
    return x if step <= 0 else np.round(x / step) * step
