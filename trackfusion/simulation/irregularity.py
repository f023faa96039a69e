"""Track irregularity synthesis: random fields from the German spectra plus deterministic injections.

The spectra and the field type are :mod:`trackfusion.track.irregularity`.

Synthesis: a stationary Gaussian process by inverse FFT of complex Gaussian
coefficients with variance ``S(Omega_k) dOmega`` per bin on a uniform grid
(default 5 mm, finer when an injection needs it), so periodograms scatter
around the formula as a real track's would.

Injections: sinusoids (tapered in and out with a C2 smootherstep), weld dips
(``-depth cos^4(pi x / length)``, C3) and corrugation (30-300 mm
wavelength). Per-rail series: ``vertical_left = profile + cross_level/2``,
``vertical_right = profile - cross_level/2``, ``lateral_left = alignment +
gauge_dev/2``, ``lateral_right = alignment - gauge_dev/2`` (lateral positive
to the left, so a wider gauge moves the left rail left and the right rail
right). The field is evaluated through a quintic spline (C4), which the
trolley simulation differentiates.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator
from scipy import fft

from ..errors import config_error_from_validation
from ..strict import StrictModel
from ..track.irregularity import COMPONENTS, HALF_ROLLING_BASE_M, IrregularityField, german_psd


class PsdConfig(StrictModel):
    """Random irregularities from a German spectrum over a wavelength band."""

    spectrum: Literal["german_low", "german_high"] = "german_low"
    components: list[Literal["profile", "alignment", "cross_level", "gauge_dev"]] = list(COMPONENTS)
    wavelength_min_m: float = Field(1.0, gt=0)
    wavelength_max_m: float = Field(200.0, gt=0)
    scale: float = Field(1.0, ge=0)

    @model_validator(mode="after")
    def _band(self) -> "PsdConfig":
        if self.wavelength_max_m <= self.wavelength_min_m:
            raise ValueError("wavelength_max_m must exceed wavelength_min_m")
        return self


class SinusoidConfig(StrictModel):
    """A sinusoid on one or both rails, vertical or lateral, faded in/out over ``taper_m``."""

    direction: Literal["vertical", "lateral"] = "vertical"
    rail: Literal["left", "right", "both"] = "both"
    wavelength_m: float = Field(gt=0)
    amplitude_mm: float
    start_m: float
    end_m: float
    taper_m: float | None = Field(None, ge=0)
    phase_deg: float = 0.0


class WeldDipConfig(StrictModel):
    """A dip of ``depth_mm`` and ``length_m`` centred at ``chainage_m`` on one rail (top of rail)."""

    rail: Literal["left", "right", "both"] = "left"
    chainage_m: float
    depth_mm: float = Field(gt=0)
    length_m: float = Field(0.6, gt=0)


class CorrugationConfig(StrictModel):
    """Rail-head corrugation: ``wavelength_mm`` 30-300 mm, ``amplitude_mm``, from ``start_m`` to ``end_m``."""

    rail: Literal["left", "right", "both"] = "both"
    wavelength_mm: float = Field(ge=30, le=300)
    amplitude_mm: float
    start_m: float
    end_m: float


class IrregularitySpec(StrictModel):
    """All irregularities of a track (any section may be omitted)."""

    psd: PsdConfig | None = None
    sinusoids: list[SinusoidConfig] = []
    weld_dips: list[WeldDipConfig] = []
    corrugation: list[CorrugationConfig] = []
    grid_step_m: float | None = Field(None, gt=0)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None, source: str = "irregularities") -> "IrregularitySpec":
        """Validate a dict; raises :class:`ConfigError` naming the field path."""
        try:
            return cls.model_validate(data or {})
        except ValidationError as exc:
            raise config_error_from_validation(exc, source) from None

    def grid_step(self) -> float:
        """Grid spacing [m]: the given one, else 5 mm or 1/12 of the shortest injected wavelength."""
        if self.grid_step_m is not None:
            return self.grid_step_m
        shortest = [c.wavelength_mm / 1000.0 for c in self.corrugation]
        shortest += [s.wavelength_m for s in self.sinusoids] + [d.length_m / 2 for d in self.weld_dips]
        return min([0.005] + [w / 12.0 for w in shortest])


def synthesize_psd(component: str, n: int, ds_m: float, cfg: PsdConfig, rng: np.random.Generator) -> np.ndarray:
    """One stationary Gaussian series (n,) of ``component`` with the configured spectrum and band."""
    n_fft = fft.next_fast_len(n, real=True)
    k = np.arange(n_fft // 2 + 1)
    d_omega = 2 * np.pi / (n_fft * ds_m)
    omega = k * d_omega
    band = (omega >= 2 * np.pi / cfg.wavelength_max_m) & (omega <= 2 * np.pi / cfg.wavelength_min_m)
    psd = np.zeros_like(omega)
    psd[band] = german_psd(component, omega[band], cfg.spectrum)
    # complex Gaussian coefficient per bin with E|c|^2 = S dOmega / 2: irfft sums 2 Re(c e^{i w s})
    # over the positive bins, each term then has variance S dOmega (one-sided PSD)
    coef = (rng.standard_normal(k.size) + 1j * rng.standard_normal(k.size)) * np.sqrt(psd * d_omega / 4.0)
    x = fft.irfft(coef * n_fft, n=n_fft)[:n]
    if component == "cross_level":
        x = x * 2 * HALF_ROLLING_BASE_M  # roll angle -> rail height difference
    return cfg.scale * x


def _smootherstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2)


def _taper(s, start, end, taper):
    if taper <= 0:
        return ((s >= start) & (s <= end)).astype(float)
    return _smootherstep((s - start) / taper) * _smootherstep((end - s) / taper)


def _rails_of(rail: str) -> tuple[str, ...]:
    return ("left", "right") if rail == "both" else (rail,)


def synthesize(spec: IrregularitySpec, length_m: float, rng: np.random.Generator,
               ds_m: float | None = None) -> IrregularityField:
    """Irregularities over [0, length_m] on a uniform grid (``ds_m`` or ``spec.grid_step()``)."""
    ds = ds_m or spec.grid_step()
    n = int(np.ceil(length_m / ds)) + 1
    s = ds * np.arange(n)
    comps = {c: np.zeros(n) for c in COMPONENTS}
    if spec.psd is not None:
        for c in COMPONENTS:  # always draw all four so switching one off keeps the others
            x = synthesize_psd(c, n, ds, spec.psd, rng)
            if c in spec.psd.components:
                comps[c] = x
    rails = {
        "vertical_left": comps["profile"] + comps["cross_level"] / 2,
        "vertical_right": comps["profile"] - comps["cross_level"] / 2,
        "lateral_left": comps["alignment"] + comps["gauge_dev"] / 2,
        "lateral_right": comps["alignment"] - comps["gauge_dev"] / 2,
    }
    for sn in spec.sinusoids:
        taper = sn.wavelength_m if sn.taper_m is None else sn.taper_m
        wave = sn.amplitude_mm / 1000 * np.sin(2 * np.pi * s / sn.wavelength_m + np.radians(sn.phase_deg))
        for r in _rails_of(sn.rail):
            rails[f"{sn.direction}_{r}"] += wave * _taper(s, sn.start_m, sn.end_m, taper)
    for d in spec.weld_dips:
        x = s - d.chainage_m
        dip = np.where(np.abs(x) < d.length_m / 2, -d.depth_mm / 1000 * np.cos(np.pi * x / d.length_m) ** 4, 0.0)
        for r in _rails_of(d.rail):
            rails[f"vertical_{r}"] += dip
    for c in spec.corrugation:
        lam = c.wavelength_mm / 1000
        wave = c.amplitude_mm / 1000 * np.sin(2 * np.pi * (s - c.start_m) / lam)
        for r in _rails_of(c.rail):
            rails[f"vertical_{r}"] += wave * _taper(s, c.start_m, c.end_m, 3 * lam)
    return IrregularityField(s, comps, rails)
