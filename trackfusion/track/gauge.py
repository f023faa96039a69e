"""The gauge reading along chainage: a minimum-mean-square-error (Wiener) smoother whose noise
and signal levels come from the readings themselves (or the noise from the sensor spec).

The other rail's alignment is the reference rail's plus the gauge reading (``traces.py``), so the
gauge sensor's white noise enters that rail's short-chord versines in full: a reading of
standard deviation ``sigma`` taken every ``d = v / f`` metres (speed ``v``, rate ``f``) has the
spatial noise density ``N0 = sigma^2 d`` (two-sided, m^2 per cycle/m), which grows with speed.
A mid-chord versine ``y(s) - (y(s - L/2) + y(s + L/2)) / 2`` passes it with gain ``1 - cos(pi L
k)`` (mean square 1.5), so a box average of ``N = W / d`` readings leaves the versine a noise of
``sigma sqrt(1.5 d / W)`` for ``W <= L / 2`` (0.1 mm at 50 Hz and 1.2 m/s over 0.25 m: 0.038 mm).

Model (the high-wavenumber end of the usual track spectra, e.g. the German spectra of
``irregularity.py``, which fall as ``k^-4``): the gauge is an integrated random walk in
chainage, its second derivative white with density ``q``: ``S(k) = q / (2 pi k)^4``; readings
``g_i = g(s_i) + e_i`` with white ``e_i`` of variance ``sigma^2``. The MMSE estimate is the
penalised least squares (a cubic smoothing spline)

    min_g  sum_i (g_i - g(s_i))^2 / sigma^2  +  (1 / q) int g''(s)^2 ds,

whose transfer for readings ``d`` apart is the Wiener gain

    H(k) = S / (S + N0) = 1 / (1 + (lambda_c k)^4),   lambda_c = 2 pi (N0 / q)^(1/4),

0.5 at the cut-off wavelength ``lambda_c``, where the track's gauge signal and the sensor's
noise have equal density: shorter gauge waves are below the sensor's noise at this speed and
are attenuated, longer ones pass (``H(2 lambda_c) = 0.94``). ``q`` and ``N0`` are fitted to each
pass's own readings (Whittle likelihood of their periodogram); with ``sigma`` from the sensor
spec only ``q`` is fitted. The model is fitted at wavelengths below 5 m only, so ``lambda_c`` is
capped at ``MAX_CUTOFF_M`` = 2.5 m (gain >= 0.94 at 5 m, >= 0.996 at 10 m): a gauge whose short
waves are all below the noise keeps its long waves. The fitted ``sigma`` is reported (a check
of the spec) with ``lambda_c``, so each pass states the resolution of its gauge. Readings are
assumed regular in time (their spacing follows the speed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solveh_banded
from scipy.optimize import minimize

from ..errors import TrackGeometryError

MIN_READINGS = 64          # fewer readings in a pass: too few for a spectrum, box mean instead
FIT_MIN_WAVENUMBER = 0.2   # [cycles/m] the k^-4 model is fitted at wavelengths below 5 m
MAX_CUTOFF_M = 2.5         # [m] so the filter acts only where it was fitted: gain >= 0.94 at 5 m


@dataclass(frozen=True)
class GaugeFit:
    """Noise and signal levels of a pass's gauge readings: ``sigma_m`` [m] reading noise (fitted,
    or the spec), ``q`` [m^2 / (cycle/m)^-3] density of the gauge's second derivative,
    ``spacing_m`` [m] median reading spacing, ``cutoff_m`` [m] wavelength of gain 0.5,
    ``sigma_from_spec`` whether ``sigma_m`` was given."""

    sigma_m: float
    q: float
    spacing_m: float
    cutoff_m: float
    sigma_from_spec: bool

    def to_json(self) -> dict:
        return {"filter": "wiener", "sigma_mm": 1e3 * self.sigma_m, "sigma_from_spec": self.sigma_from_spec,
                "cutoff_wavelength_m": self.cutoff_m, "reading_spacing_mm": 1e3 * self.spacing_m}


def wiener_gain(wavelength_m: np.ndarray, cutoff_m: float) -> np.ndarray:
    """Transfer ``1 / (1 + (cutoff / lambda)^4)`` of :func:`smooth_gauge` at ``wavelength_m``."""
    return 1.0 / (1.0 + (cutoff_m / np.asarray(wavelength_m, dtype=float)) ** 4)


def uniform_resample(s_m: np.ndarray, y: np.ndarray, spacing_m: float) -> np.ndarray:
    """Readings (K,) at chainages s_m (K,) as a uniform series ``spacing_m`` apart (bin means;
    empty bins interpolated)."""
    k = np.floor((s_m - s_m.min()) / spacing_m).astype(int)
    n = int(k.max()) + 1
    cnt = np.bincount(k, minlength=n)
    total = np.bincount(k, y, minlength=n)
    filled = cnt > 0
    u = np.zeros(n)
    u[filled] = total[filled] / cnt[filled]
    idx = np.arange(n)
    return np.interp(idx, idx[filled], u[filled])


def periodogram(u: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided spectral density (Hann taper, linear trend removed) of a uniform series u (N,):
    wavenumbers [cycles/m] (M,) and density [unit^2 / (cycle/m)] (M,); white noise of variance
    ``s^2`` has density ``s^2 spacing``."""
    i = np.arange(u.size)
    u = u - np.polyval(np.polyfit(i, u, 1), i)
    w = np.hanning(u.size)
    density = np.abs(np.fft.rfft(u * w)) ** 2 * spacing_m / np.sum(w ** 2)
    return np.fft.rfftfreq(u.size, spacing_m), density


def fit_gauge_spectrum(s_m: np.ndarray, gauge_m: np.ndarray, sigma_m: float | None = None) -> GaugeFit:
    """:class:`GaugeFit` of one pass's readings gauge_m (K,) [m] at chainages s_m (K,) [m]: the
    Whittle likelihood of the model density ``q / (2 pi k)^4 + sigma^2 d`` over the periodogram
    at wavenumbers above ``FIT_MIN_WAVENUMBER``; ``sigma_m`` given: only ``q`` is fitted."""
    order = np.argsort(s_m, kind="stable")
    s, g = np.asarray(s_m, dtype=float)[order], np.asarray(gauge_m, dtype=float)[order]
    gaps = np.diff(s)
    d = float(np.median(gaps[gaps > 0])) if np.any(gaps > 0) else 0.0
    if s.size < MIN_READINGS or d <= 0:
        raise TrackGeometryError(f"{s.size} gauge readings over {np.ptp(s):.2f} m: too few for the gauge spectrum")
    k, density = periodogram(uniform_resample(s, g, d), d)
    use = k >= FIT_MIN_WAVENUMBER
    if np.count_nonzero(use) < 8:
        use = k > 0
    k, density = k[use], density[use]
    scale = float(np.mean(density)) or 1.0          # work in units of the mean density
    density = density / scale
    kw4 = (2 * np.pi * k) ** 4

    def nll(p: np.ndarray) -> float:
        q, n0 = np.exp(p[0]), (np.exp(p[1]) if sigma_m is None else sigma_m ** 2 * d / scale)
        model = q / kw4 + n0
        return float(np.sum(np.log(model) + density / model))

    q0 = float(np.median(density[: max(4, density.size // 20)] * kw4[: max(4, density.size // 20)]))
    start = np.log([max(q0, 1e-30), max(float(np.median(density[-max(4, density.size // 10):])), 1e-30)])
    bounds = [(start[0] - 60, start[0] + 30), (np.log(1e-20), np.log(10.0))]
    if sigma_m is not None:
        start, bounds = start[:1], bounds[:1]
    p = minimize(nll, start, method="L-BFGS-B", bounds=bounds).x
    q = float(np.exp(p[0])) * scale
    n0 = float(np.exp(p[1])) * scale if sigma_m is None else sigma_m ** 2 * d
    cutoff = float(2 * np.pi * (n0 / q) ** 0.25) if q > 0 else np.inf
    return GaugeFit(float(np.sqrt(n0 / d)), q, d, min(cutoff, MAX_CUTOFF_M), sigma_m is not None)


def smooth_gauge(s_m: np.ndarray, gauge_m: np.ndarray, s_query_m: np.ndarray, fit: GaugeFit) -> np.ndarray:
    """The penalised least-squares gauge (module docstring) at s_query_m (M,) [m] from the
    readings gauge_m (K,) at s_m (K,): solved on a grid of ``min(5 cm, cutoff / 8)`` spanning
    the readings (linear interpolation between grid points; constant beyond the readings).
    The cut-off is at least four grid steps (an ideal sensor: nearly interpolation)."""
    h = max(0.01, min(0.05, fit.cutoff_m / 8))
    grid = s_m.min() + h * np.arange(int(np.ceil(np.ptp(s_m) / h)) + 1)
    cutoff = max(fit.cutoff_m, 4 * h)
    mu = (cutoff / (2 * np.pi)) ** 4 / fit.spacing_m          # = sigma^2 / q
    f = (s_m - grid[0]) / h
    i = np.clip(np.floor(f).astype(int), 0, grid.size - 2)
    frac = f - i
    n = grid.size
    # normal equations A^T A + mu h D^T D (A: linear interpolation at the readings, D: second
    # differences / h^2), symmetric pentadiagonal: upper bands for solveh_banded
    ab = np.zeros((3, n))
    ab[2] = np.bincount(i, (1 - frac) ** 2, n) + np.bincount(i + 1, frac ** 2, n)
    ab[1, 1:] = np.bincount(i, (1 - frac) * frac, n)[:-1]
    w = mu * h / h ** 4
    r = np.arange(n - 2)
    c = (1.0, -2.0, 1.0)
    for a in range(3):
        ab[2] += w * np.bincount(r + a, np.full(n - 2, c[a] ** 2), n)
    for a in range(2):
        ab[1, 1:] += w * np.bincount(r + a, np.full(n - 2, c[a] * c[a + 1]), n)[:-1]
    ab[0, 2:] += w * c[0] * c[2]
    g0 = float(np.mean(gauge_m))                                 # solve for the variation
    rhs = np.bincount(i, (1 - frac) * (gauge_m - g0), n) + np.bincount(i + 1, frac * (gauge_m - g0), n)
    x = solveh_banded(ab, rhs)
    return g0 + np.interp(s_query_m, grid, x)
