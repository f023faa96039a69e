"""Track irregularity spectra and fields: the German spectra and the per-rail series on a grid.

Spectra (one-sided, in spatial angular frequency Omega [rad/m]; the German
low- and high-interference track spectra as tabulated by W. Zhai,
*Vehicle-Track Coupled Dynamics*, Springer 2020, ch. 3)::

    vertical profile  S_v(W) = A_v Wc^2 / ((W^2 + Wr^2)(W^2 + Wc^2))                  [m^2 / (rad/m)]
    alignment         S_a(W) = A_a Wc^2 / ((W^2 + Wr^2)(W^2 + Wc^2))                  [m^2 / (rad/m)]
    cross-level       S_c(W) = A_v / b^2 Wc^2 W^2 / ((W^2+Wr^2)(W^2+Wc^2)(W^2+Ws^2))  [rad^2 / (rad/m)]
    gauge             S_g(W) = A_g Wc^2 W^2 / ((W^2+Wr^2)(W^2+Wc^2)(W^2+Ws^2))        [m^2 / (rad/m)]

with Wc = 0.8246, Wr = 0.0206, Ws = 0.4380 rad/m, b = 0.75 m and A [m rad]
from :data:`GERMAN_SPECTRA`. One-sided means the variance is the integral of
S over Omega > 0. The cross-level spectrum is of the roll angle; the height
difference of the rails is ``2 b`` times it. The spectra describe
wavelengths of about 1 to a few hundred metres; the synthesis band is
configurable (default 1-200 m) and shorter waves come from the injections.

The random fields drawn from these spectra, and the deterministic injections, are synthesised
by :mod:`trackfusion.simulation.irregularity`; the measured irregularities are
:mod:`trackfusion.track.irregularities`. Per-rail series: ``vertical_left = profile + cross_level/2``,
``vertical_right = profile - cross_level/2``, ``lateral_left = alignment + gauge_dev/2``,
``lateral_right = alignment - gauge_dev/2`` (lateral positive to the left). An
:class:`IrregularityField` is evaluated through a quintic spline (C4), which the trolley simulation
differentiates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

OMEGA_C, OMEGA_R, OMEGA_S = 0.8246, 0.0206, 0.4380  # rad/m
HALF_ROLLING_BASE_M = 0.75  # b
#: A_v, A_a, A_g [m rad] of the German spectra.
GERMAN_SPECTRA = {
    "german_low": {"A_v": 4.032e-7, "A_a": 2.119e-7, "A_g": 0.532e-7},
    "german_high": {"A_v": 1.080e-6, "A_a": 6.125e-7, "A_g": 1.032e-7},
}
COMPONENTS = ("profile", "alignment", "cross_level", "gauge_dev")
RAIL_SERIES = ("vertical_left", "vertical_right", "lateral_left", "lateral_right")


def german_psd(component: str, omega_radpm, spectrum: str = "german_low") -> np.ndarray:
    """One-sided PSD of ``component`` at ``omega_radpm`` (rad/m): m^2/(rad/m), or rad^2/(rad/m) for cross-level."""
    A = GERMAN_SPECTRA[spectrum]
    w2 = np.asarray(omega_radpm, dtype=float) ** 2
    base = OMEGA_C**2 / ((w2 + OMEGA_R**2) * (w2 + OMEGA_C**2))
    if component == "profile":
        return A["A_v"] * base
    if component == "alignment":
        return A["A_a"] * base
    hp = base * w2 / (w2 + OMEGA_S**2)
    if component == "cross_level":
        return A["A_v"] / HALF_ROLLING_BASE_M**2 * hp
    if component == "gauge_dev":
        return A["A_g"] * hp
    raise ValueError(f"unknown component {component!r}")


@dataclass
class IrregularityField:
    """Irregularities on a uniform grid ``s_m`` (M,) [m]: ``components`` (profile, alignment,
    cross_level as a rail height difference, gauge_dev) and the four per-rail series, all [m]."""

    s_m: np.ndarray
    components: dict[str, np.ndarray]
    rails: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        self._spline = make_interp_spline(self.s_m, np.column_stack([self.rails[k] for k in RAIL_SERIES]), k=5)

    def evaluate(self, s_m) -> dict[str, np.ndarray]:
        """Per-rail irregularities [m] at chainages ``s_m`` (N,): ``RAIL_SERIES`` -> (N,)."""
        y = self._spline(np.asarray(s_m, dtype=float))
        return {k: y[..., i] for i, k in enumerate(RAIL_SERIES)}
