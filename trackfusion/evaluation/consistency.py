"""Statistical consistency of an estimate's sigmas: RMS of error / sigma and how far one run can trust it.

If the sigmas are honest, ``z = error / sigma`` has unit variance and ``RMS(z)`` is about 1.
Over one run that holds only when the run holds many *independent* errors. A survey's
absolute error is dominated by the GNSS's correlated error (300 s correlation time): along a
track the odometer ties every epoch of a 44 min run to nearly one common offset, so the
along-track ``RMS(z)`` of one run is close to a single draw of ``|N(0, 1)|``, and values of
0.3 or 1.8 are as likely as 1.0. Removing the mean would not help: the sigma is of the
absolute error, mean included.

So next to ``RMS(z)`` this module gives the run's effective number of independent samples
``n_eff`` and the interval that ``RMS(z)`` falls in with 95 % probability when the sigmas are
honest (chi-square with ``n_eff`` degrees of freedom), and pools several runs (seeds) into one
figure with its own interval. For a Gaussian stationary ``z`` with autocorrelation ``rho``,
``var(mean z^2) = 2 / N * sum_k rho(k)^2``, hence ``n_eff = N / (1 + 2 sum_{k>=1} rho(k)^2)``;
``rho`` is estimated under the hypothesis tested (zero mean, no mean removed), summed up to the
first lag where it falls below 0.05 (a window, as in Sokal's estimator of the integrated
autocorrelation time), and ``n_eff`` is at least 1.
"""

from __future__ import annotations

import numpy as np
from scipy import fft, stats


def autocorrelation(z: np.ndarray) -> np.ndarray:
    """Autocorrelation (N,) of ``z`` (N,) about zero (not mean-removed), each lag ``k`` averaged over
    its ``N - k`` pairs: ``mean(z_i z_{i+k}) / mean(z_i^2)`` (a constant series gives 1 at every lag)."""
    z = np.asarray(z, dtype=float)
    n = z.size
    m = fft.next_fast_len(2 * n, real=True)
    spec = fft.rfft(z, m)
    acov = fft.irfft(spec * np.conj(spec), m)[:n] / (n - np.arange(n))
    return acov / acov[0] if acov[0] > 0 else np.zeros(n)


def effective_samples(z: np.ndarray, rho_min: float = 0.05) -> float:
    """Effective number of independent samples of ``mean(z^2)`` for the series ``z`` (N,)."""
    rho = autocorrelation(z)[1:]
    below = np.flatnonzero(rho < rho_min)
    window = rho[: below[0]] if below.size else rho
    return float(max(1.0, z.size / (1.0 + 2.0 * np.sum(window**2))))


def rms_interval(n_eff: float, level: float = 0.95) -> tuple[float, float]:
    """Interval of ``RMS(z)`` with probability ``level`` for honest sigmas and ``n_eff`` samples."""
    tail = 0.5 * (1.0 - level)
    lo, hi = stats.chi2.ppf([tail, 1.0 - tail], n_eff)
    return float(np.sqrt(lo / n_eff)), float(np.sqrt(hi / n_eff))


def consistency_of(z: np.ndarray) -> dict[str, float | list[float]]:
    """``{"rms", "n_eff", "interval_95"}`` of the normalised errors ``z`` (N,)."""
    n_eff = effective_samples(z)
    return {"rms": float(np.sqrt(np.mean(np.square(z)))), "n_eff": n_eff, "interval_95": list(rms_interval(n_eff))}


def pooled(runs: list[dict]) -> dict[str, float | list[float]]:
    """Pool runs of equal weight per sample: ``runs`` are :func:`consistency_of` results with
    ``"samples"`` (N of each run). RMS over all samples, ``n_eff`` summed, its 95 % interval."""
    n = np.array([r["samples"] for r in runs], dtype=float)
    rms = float(np.sqrt(np.sum(n * np.array([r["rms"] for r in runs]) ** 2) / np.sum(n)))
    n_eff = float(sum(r["n_eff"] for r in runs))
    return {"rms": rms, "n_eff": n_eff, "interval_95": list(rms_interval(n_eff))}
