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
    :class:`trackfusion.track.irregularity.PsdConfig` (``scale`` multiplies the amplitude);
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
