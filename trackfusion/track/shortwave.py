"""Short-wave analysis (seed 000): deformation index, defect list, spatial spectrum, inverse filter.

Deformation index (seed 000 eq. 1): ``DI = omega / v`` [deg/m], ``omega`` the pitch rate of the
measuring unit (its rotation rate about the trolley's transverse axis) and ``v`` its speed
along the rails; it is the change of the rail slope per metre. Below ``v_min`` the trolley is
taken as standing and no DI is formed. A defect is a stretch where ``|DI|`` exceeds the
threshold (seed 000: 25 deg/m, set slightly above the 22 deg/m of a 300 mm / 1 mm defect
under its 80 mm wheelbase, eq. 12); stretches closer than ``merge_m`` are one defect.

Spatial spectrum: Welch periodogram of a series on a uniform chainage grid, on a wavelength
axis; dominant wavelengths are its largest local maxima.

Regularised inverse: a versine series ``V = H * y`` (``H`` the chord transfer function) is
deconvolved in the wavenumber domain by ``Y = conj(H) V / (|H|^2 + alpha)`` (Tikhonov), which
recovers the irregularity where ``|H|^2 >> alpha`` and damps it near the chord's zeros
(wavelengths ``L / 2k`` for a symmetric chord of length L).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks, welch

from ..errors import TrackGeometryError
from .versines import chord_transfer


def deformation_index(pitch_rate_radps: np.ndarray, speed_mps: np.ndarray, v_min_mps: float) -> np.ndarray:
    """DI [deg/m] (N,) = pitch rate / speed (seed 000 eq. 1); NaN where ``|speed| < v_min_mps``.
    The speed is signed (along increasing chainage), so the DI is the rail's change of slope
    per metre of chainage whichever way the trolley runs, and passes in both directions agree."""
    v = np.asarray(speed_mps, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.abs(v) >= v_min_mps, np.degrees(np.asarray(pitch_rate_radps, dtype=float)) / v, np.nan)


def di_amplitude(amplitude_m: float, wavelength_m, wheelbase_m: float) -> np.ndarray:
    """Seed 000 eq. 12: ``DI_max = 4 pi A / (l lambda) sin(pi l / lambda)`` [deg/m] of a sinusoid."""
    lam = np.asarray(wavelength_m, dtype=float)
    return np.degrees(4 * np.pi * amplitude_m / (wheelbase_m * lam) * np.abs(np.sin(np.pi * wheelbase_m / lam)))


@dataclass(frozen=True)
class Defect:
    """A detected defect: chainage of the DI peak, its start/end [m] and the peak DI [deg/m]."""

    chainage_m: float
    start_m: float
    end_m: float
    peak_di_deg_per_m: float

    def to_json(self) -> dict:
        return {"chainage_m": self.chainage_m, "start_m": self.start_m, "end_m": self.end_m,
                "peak_di_deg_per_m": self.peak_di_deg_per_m}


def detect_defects(chainage_m: np.ndarray, di_deg_per_m: np.ndarray, threshold_deg_per_m: float,
                   merge_m: float = 0.5) -> list[Defect]:
    """Stretches of ``|DI| > threshold`` (NaN never exceeds), merged when closer than ``merge_m``."""
    s = np.asarray(chainage_m, dtype=float)
    di = np.asarray(di_deg_per_m, dtype=float)
    order = np.argsort(s, kind="stable")
    s, di = s[order], di[order]
    above = np.flatnonzero(np.nan_to_num(np.abs(di), nan=0.0) > threshold_deg_per_m)
    if above.size == 0:
        return []
    splits = np.flatnonzero(np.diff(s[above]) > merge_m) + 1
    defects = []
    for group in np.split(above, splits):
        k = group[np.argmax(np.abs(di[group]))]
        defects.append(Defect(float(s[k]), float(s[group[0]]), float(s[group[-1]]), float(di[k])))
    return defects


def merge_defects(per_pass: list[list[Defect]], tolerance_m: float) -> list[dict]:
    """One entry per defect found in any pass (peaks within ``tolerance_m`` are the same defect):
    mean chainage, largest |peak DI| and the number of passes that found it."""
    found = sorted((d for ds in per_pass for d in ds), key=lambda d: d.chainage_m)
    out: list[list[Defect]] = []
    for d in found:
        if out and d.chainage_m - out[-1][-1].chainage_m <= tolerance_m:
            out[-1].append(d)
        else:
            out.append([d])
    return [{"chainage_m": float(np.mean([d.chainage_m for d in g])),
             "peak_di_deg_per_m": max((d.peak_di_deg_per_m for d in g), key=abs),
             "passes": len(g)} for g in out]


@dataclass(frozen=True)
class Spectrum:
    """Welch spectrum on a wavelength axis: ``wavelength_m`` (K,), ``psd`` (K,) [unit^2 m],
    ``dominant_m`` the wavelengths of the largest peaks (strongest first)."""

    wavelength_m: np.ndarray
    psd: np.ndarray
    dominant_m: list[float]


def spatial_spectrum(values: np.ndarray, step_m: float, segment_m: float | None = None,
                     n_dominant: int = 5) -> Spectrum:
    """Welch periodogram of ``values`` (N,) on a uniform grid ``step_m`` [m] (NaNs are zero-filled
    after removing the mean), segments of ``segment_m`` (default: a quarter of the record)."""
    x = np.asarray(values, dtype=float)
    if x.size < 16:
        raise TrackGeometryError("a spectrum needs at least 16 samples")
    x = np.nan_to_num(x - np.nanmean(x), nan=0.0)
    nper = x.size // 4 if segment_m is None else int(round(segment_m / step_m))
    f, p = welch(x, fs=1.0 / step_m, nperseg=max(16, min(nper, x.size)))
    f, p = f[1:], p[1:]
    peaks, _ = find_peaks(p)
    top = peaks[np.argsort(p[peaks])[::-1][:n_dominant]]
    return Spectrum(1.0 / f, p, [float(1.0 / f[k]) for k in top])


def inverse_chord_filter(versine_m: np.ndarray, step_m: float, before_m: float, after_m: float,
                         alpha: float = 1e-3) -> np.ndarray:
    """Irregularity (N,) [m] reconstructed from a versine series (N,) on a uniform grid by the
    Tikhonov-regularised inverse of the chord's transfer function (module docstring).
    The series is mirrored at both ends before the FFT to limit wrap-around."""
    v = np.asarray(versine_m, dtype=float)
    if np.any(~np.isfinite(v)):
        raise TrackGeometryError("the inverse filter needs a versine series without gaps")
    ext = np.r_[v, v[::-1]]
    k = np.fft.rfftfreq(ext.size, d=step_m)
    with np.errstate(divide="ignore"):
        wavelength = np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), np.inf)
    H = np.where(k > 0, chord_transfer(wavelength, before_m, after_m), 0.0)
    Y = np.conj(H) * np.fft.rfft(ext) / (np.abs(H) ** 2 + alpha)
    return np.fft.irfft(Y, n=ext.size)[: v.size]
