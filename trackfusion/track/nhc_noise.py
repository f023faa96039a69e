"""How far a rigid trolley on irregular rails violates the non-holonomic constraint (NHC).

The NHC factor (fusion/smoother.py) asks the lateral and vertical velocity, in ``v``, of
``v``'s origin (the midpoint of the two reference-rail wheel contacts, a wheelbase ``l``
apart) to be zero. On irregular rails it is not. With the reference rail displaced by
``w(s)`` (vertically or laterally, small slopes), the origin sits at the mean of
``w(s - l/2)`` and ``w(s + l/2)`` and the frame's x axis along their chord, so at speed
``v`` the origin moves across the frame's x axis at

    u(s) = v * [ (w'(s + l/2) + w'(s - l/2)) / 2 - (w(s + l/2) - w(s - l/2)) / l ].

For ``w = a sin(Omega s)`` this is ``v a H(Omega) cos(Omega s)`` with the transfer function

    H(Omega) = Omega * (cos(x) - sin(x) / x),   x = Omega l / 2,

(:func:`rigid_trolley_transfer`), which falls off as ``Omega^3 l^2 / 12`` for long waves: a
trolley follows long waves without crossing its chord. For a random track of one-sided PSD
``S(Omega)`` [m^2/(rad/m)] the mean square is ``v^2 * integral S(Omega) H(Omega)^2 dOmega``
over the irregularity band (:func:`nhc_velocity_rms_mps`, German spectra of
:mod:`.irregularity`; the reference rail carries ``profile + cross_level / 2`` vertically and
``alignment + gauge_dev / 2`` laterally).

The NHC residual also contains the measured body rate's white noise through the lever arm
``omega x l_b`` (the factor uses the mean of the two gyro samples around each keyframe):
:func:`gyro_noise_velocity_sigma_mps`. :func:`nhc_sigma_mps` combines both in quadrature.

Pure maths: no I/O. docs/pipeline.md ("Choosing the NHC sigma") explains how to use it for a
real trolley, whose flange play and wheel wear add to this rigid-trolley figure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import integrate

from .irregularity import HALF_ROLLING_BASE_M, german_psd

#: Reference-rail PSD as a sum of the German components: axis -> ((component, variance factor), ...).
#: cross_level's PSD is of the roll angle; the rail's half height difference is b * roll.
_RAIL_COMPONENTS = {
    "vertical": (("profile", 1.0), ("cross_level", HALF_ROLLING_BASE_M**2)),
    "lateral": (("alignment", 1.0), ("gauge_dev", 0.25)),
}


def rigid_trolley_transfer(omega_radpm, wheelbase_m: float) -> np.ndarray:
    """|H(Omega)| [1/m]: NHC velocity amplitude per unit speed and unit irregularity amplitude.

    omega_radpm: spatial angular frequency(ies) [rad/m]; wheelbase_m: reference-rail wheelbase [m].
    Returns an array of the shape of ``omega_radpm``.
    """
    omega = np.asarray(omega_radpm, dtype=float)
    x = 0.5 * omega * wheelbase_m
    return np.abs(omega * (np.cos(x) - np.sinc(x / np.pi)))  # np.sinc(y) = sin(pi y) / (pi y)


def nhc_velocity_rms_mps(speed_mps: float, wheelbase_m: float, spectrum: str = "german_low",
                         wavelength_min_m: float = 1.0, wavelength_max_m: float = 200.0,
                         scale: float = 1.0, components: tuple[str, ...] | None = None) -> dict[str, float]:
    """RMS lateral and vertical velocity [m/s] of ``v``'s origin of a rigid trolley.

    speed_mps: trolley speed [m/s]; wheelbase_m [m]; ``spectrum``, band and ``scale`` as in
    :class:`trackfusion.simulation.irregularity.PsdConfig` (``scale`` multiplies the amplitude);
    ``components``: the German components present (default all four).
    Returns ``{"lateral": ..., "vertical": ...}``.
    """
    lo, hi = 2 * np.pi / wavelength_max_m, 2 * np.pi / wavelength_min_m
    omega = np.geomspace(lo, hi, 4001)
    h2 = rigid_trolley_transfer(omega, wheelbase_m) ** 2
    out = {}
    for axis, parts in _RAIL_COMPONENTS.items():
        psd = sum(f * german_psd(c, omega, spectrum) for c, f in parts if components is None or c in components)
        out[axis] = float(speed_mps * scale * np.sqrt(integrate.simpson(psd * h2, x=omega)))
    return out


def nhc_velocity_series_mps(w_m: np.ndarray, ds_m: float, speed_mps: float, wheelbase_m: float) -> np.ndarray:
    """The NHC velocity ``u(s)`` [m/s] of a rail displacement ``w_m`` (M,) sampled every ``ds_m``.

    Evaluated where the wheelbase fits inside the samples (central differences for the
    slopes; the wheelbase is rounded to a whole number of samples): returns (M - 2 h,) with
    ``h = round(l / 2 / ds)``.
    """
    h = max(1, int(round(0.5 * wheelbase_m / ds_m)))
    slope = np.gradient(w_m, ds_m)
    front, rear = slice(2 * h, None), slice(0, w_m.size - 2 * h)
    return speed_mps * (0.5 * (slope[front] + slope[rear]) - (w_m[front] - w_m[rear]) / (2 * h * ds_m))


def gyro_noise_velocity_sigma_mps(gyro_arw_deg_per_sqrt_h: float, rate_hz: float,
                                  lever_arm_v_m) -> dict[str, float]:
    """Sigma [m/s] of ``(omega x l)`` in ``v`` from the gyro white noise (mean of two samples).

    gyro_arw_deg_per_sqrt_h: angle random walk; rate_hz: IMU rate; lever_arm_v_m (3,): from the
    IMU to the constrained point, in ``v`` (``b`` = ``v`` up to the small mounting rotation).
    Per axis the rate noise is ``ARW sqrt(rate / 2)``; ``(w x l)_y = w_z l_x - w_x l_z`` and
    ``(w x l)_z = w_x l_y - w_y l_x``.
    """
    sigma_w = np.radians(gyro_arw_deg_per_sqrt_h) / 60.0 * np.sqrt(rate_hz / 2.0)
    lx, ly, lz = np.asarray(lever_arm_v_m, dtype=float)
    return {"lateral": float(sigma_w * np.hypot(lx, lz)), "vertical": float(sigma_w * np.hypot(ly, lx))}


def nhc_sigma_mps(rail: dict[str, float], gyro: dict[str, float] | None = None) -> float:
    """One NHC sigma [m/s] for both axes: the larger axis of ``rail`` and ``gyro`` in quadrature.

    The factor has one sigma for the lateral and vertical rows (``factors.nhc.sigma_mm_per_s``);
    the larger axis keeps the other conservative rather than over-confident.
    """
    gyro = gyro or {"lateral": 0.0, "vertical": 0.0}
    return float(max(np.hypot(rail[a], gyro[a]) for a in ("lateral", "vertical")))


def _rail_psd(axis: str, omega_radpm: np.ndarray, spectrum: str, components: tuple[str, ...] | None) -> np.ndarray:
    """One-sided PSD [m^2/(rad/m)] of the reference rail's ``axis`` irregularity."""
    return sum(f * german_psd(c, omega_radpm, spectrum) for c, f in _RAIL_COMPONENTS[axis]
               if components is None or c in components)


@dataclass(frozen=True)
class RailSpectrum:
    """The reference rail's irregularity spectrum: the German ``spectrum``, its band
    ``wavelength_min_m`` .. ``wavelength_max_m`` [m], ``scale`` multiplying the amplitude, and the
    German ``components`` present (None: all four), as in
    :class:`trackfusion.simulation.irregularity.PsdConfig`."""

    spectrum: str = "german_low"
    wavelength_min_m: float = 1.0
    wavelength_max_m: float = 200.0
    scale: float = 1.0
    components: tuple[str, ...] | None = None


def equivalent_white_sigma_mps(freq_hz, axis: str, speed_mps: float, wheelbase_m: float, keyframe_dt_s: float,
                               rail: RailSpectrum = RailSpectrum()) -> np.ndarray:
    """Sigma [m/s] of keyframe-spaced white NHC noise whose PSD equals the violation's at ``freq_hz``.

    The violation's one-sided PSD in time is ``P(f) = v^2 S(Omega) H(Omega)^2 2 pi / v`` with
    ``Omega = 2 pi f / v`` (``S`` the ``rail`` spectrum); white samples of sigma ``s`` every
    ``dt`` have ``2 s^2 dt``. Zero outside the irregularity band. Returns an array of the shape
    of ``freq_hz``.
    """
    f = np.asarray(freq_hz, dtype=float)
    omega = 2 * np.pi * f / speed_mps
    band = (omega >= 2 * np.pi / rail.wavelength_max_m) & (omega <= 2 * np.pi / rail.wavelength_min_m)
    psd = np.where(band, _rail_psd(axis, omega, rail.spectrum, rail.components), 0.0) * rail.scale**2
    p_time = speed_mps**2 * psd * rigid_trolley_transfer(omega, wheelbase_m) ** 2 * 2 * np.pi / speed_mps
    return np.sqrt(p_time / (2.0 * keyframe_dt_s))


def informed_band_sigma_mps(axis: str, speed_mps: float, wheelbase_m: float, keyframe_dt_s: float,
                            accel_vrw_mps_per_sqrt_h: float, **psd) -> dict[str, float]:
    """White-noise NHC sigma [m/s] honest in the band where the NHC, not the IMU, sets the velocity.

    Between keyframes the IMU's velocity error is a random walk: one-sided PSD
    ``2 q / (2 pi f)^2`` with ``q = VRW^2``. A white NHC of sigma ``s`` every ``dt`` (PSD
    ``2 s^2 dt``) outweighs it below ``f_c(s) = sqrt(q / (s^2 dt)) / (2 pi)``; above, the IMU
    decides and the NHC's noise model hardly matters. So ``s`` must cover the violation's
    equivalent white sigma (:func:`equivalent_white_sigma_mps`) at every ``f <= f_c(s)``: the
    smallest such ``s`` (a unique fixed point: the bound falls as ``s`` grows), found by
    bisection. ``psd``: the fields of :class:`RailSpectrum`.
    Returns ``{"sigma_mps", "crossover_hz", "crossover_wavelength_m"}``.
    """
    q = (accel_vrw_mps_per_sqrt_h / 60.0) ** 2
    f_grid = np.geomspace(1e-4, 0.5 / keyframe_dt_s, 4000)
    sig_eq = equivalent_white_sigma_mps(f_grid, axis, speed_mps, wheelbase_m, keyframe_dt_s, RailSpectrum(**psd))
    running_max = np.maximum.accumulate(sig_eq)

    def bound(s: float) -> float:
        f_c = np.sqrt(q / (s * s * keyframe_dt_s)) / (2 * np.pi)
        i = np.searchsorted(f_grid, f_c, side="right") - 1
        return float(running_max[i]) if i >= 0 else 0.0

    lo, hi = 1e-9, max(float(sig_eq.max()), 1e-8)
    for _ in range(100):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if mid < bound(mid) else (lo, mid)
    f_c = float(np.sqrt(q / (hi * hi * keyframe_dt_s)) / (2 * np.pi))
    return {"sigma_mps": hi, "crossover_hz": f_c, "crossover_wavelength_m": speed_mps / f_c}
