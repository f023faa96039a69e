"""Motion of the measuring frame relative to the design track, and the rail traces it gives
with the vision (seed 001 sections 6-7: eqs. 33, 37, 40, 46).

Frames as in :mod:`trackfusion.vision.measure`: ``v`` the measuring frame (x forward, y left,
z up), ``t`` the design track frame at the frame's chainage (canted by the design cant angle
``phi^t``, negative when the right rail is raised). ``r = (r_y, r_z)`` [m] is the position of
``v`` in ``t`` (eq. 46's ``r^{tgms}``) and ``phi`` [rad] the roll of ``v`` relative to ``t``.

Two estimates of ``(phi, r)`` from the same IMU (gyro, specific force), encoder chainage and the
track design (horizontal curvature and cant against chainage, from the track preprocessor). The
design is read at the encoder's chainage shifted onto the design's by curvature matching
(:func:`design_chainage_m`): in a transition the cant changes by about 0.1 deg per metre, so a
metre of odometer drift would be a 0.1 deg roll error (2.5 mm of cross-level).

* the seed's: :func:`~trackfusion.vision.madgwick.madgwick_roll` (a causal filter) minus the
  design cant, and :func:`relative_trajectory` of its roll (eq. 46 integrated forward);
* :func:`zero_phase_roll`: the gyro's integrated roll rate corrected at long periods by the
  tilt of the specific force minus the design particle's acceleration (eq. 53), the two blended
  by a zero-phase (forward-backward) low-pass -- a post-processing estimate that a causal filter
  cannot be: its symmetric kernel passes a linear ramp unchanged, so the integrated gyro bias
  cancels exactly, and the crossover is not delayed.

:func:`rail_centre_trace` adds the vision's profile origins to ``r`` (eqs. 33 and 40): the
track centreline's alignment and vertical profile relative to the design track frame;
:func:`band_trace` band-passes such a trace over chainage (EN 13848 D1: 3-25 m).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.signal import butter, sosfiltfilt

from ..errors import VisionError
from ..track.irregularities import bandpass

GRAVITY_MPS2 = 9.81


def design_along(s_m: np.ndarray, t_s: np.ndarray, curvature_h_per_m: np.ndarray, cant_rad: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """Speed [m/s], its rate [m/s^2] (numerical derivatives of the encoder chainage ``s_m`` (N,)
    at ``t_s`` (N,), as the seed does), and the design's twist ``d phi^t / ds`` [rad/m] from the
    cant angle ``cant_rad`` (N,) at those chainages; the curvature (N,) [1/m] is passed on."""
    speed = np.gradient(s_m, t_s)
    ds = np.gradient(s_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        twist = np.where(np.abs(ds) > 0, np.gradient(cant_rad) / ds, 0.0)
    return {"speed_mps": speed, "vdot_mps2": np.gradient(speed, t_s), "rho_h_per_m": curvature_h_per_m,
            "cant_rad": cant_rad, "twist_rad_per_m": twist}


def measured_curvature_per_m(gyro_b: np.ndarray, roll_rad: np.ndarray, speed_mps: np.ndarray,
                             min_speed_mps: float = 1.0) -> np.ndarray:
    """The horizontal curvature of the measuring frame's path (seed eq. 48, ``omega_z / V``) with
    the body's yaw rate turned to the vertical by its roll: ``(omega_y sin phi + omega_z cos phi)
    / V`` [1/m] (N,); NaN below ``min_speed_mps``."""
    yaw_rate = gyro_b[:, 1] * np.sin(roll_rad) + gyro_b[:, 2] * np.cos(roll_rad)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(speed_mps >= min_speed_mps, yaw_rate / speed_mps, np.nan)


def chainage_offset_m(s_m: np.ndarray, curvature_per_m: np.ndarray, design_curvature, search_m: float = 10.0,
                      step_m: float = 0.01) -> float:
    """The shift [m] to add to the encoder's chainage ``s_m`` (N,) so that the measured
    curvature (N,) [1/m] best matches the design's (``design_curvature(s)`` [1/m], a callable of
    chainage): the seed's curvature matching (section 8, eqs. 49-51: the squared difference of
    the two curvature functions) over the whole record, searched within ``+-search_m`` on a
    ``step_m`` grid and refined by a parabola through the best three. A record whose design has
    no curvature change within it cannot be matched: the shift is then 0 (``VisionError`` is
    not raised: the encoder's chainage is used as it is)."""
    ok = np.isfinite(curvature_per_m)
    s, k = s_m[ok], curvature_per_m[ok]
    shifts = np.arange(-search_m, search_m + step_m / 2, step_m)
    base = design_curvature(s)
    if np.ptp(base) == 0 and np.ptp(design_curvature(s + search_m)) == 0:
        return 0.0
    cost = np.array([np.sum((k - design_curvature(s + d)) ** 2) for d in shifts])
    i = int(np.clip(np.argmin(cost), 1, shifts.size - 2))
    c0, c1, c2 = cost[i - 1:i + 2]
    den = c0 - 2 * c1 + c2
    return float(shifts[i] + (0.5 * step_m * (c0 - c2) / den if den > 0 else 0.0))


def design_chainage_m(t_s: np.ndarray, s_enc_m: np.ndarray, gyro_b: np.ndarray, accel_b: np.ndarray,
                      design_at) -> np.ndarray:
    """The encoder's chainage (N,) [m] shifted onto the design's by :func:`chainage_offset_m`:
    ``design_at(s)`` returns the design's horizontal curvature [1/m] and cant angle [rad] at
    chainages ``s``; the roll that turns the yaw rate to the vertical is
    :func:`zero_phase_roll` at the encoder's chainage."""
    rho, _ = design_at(s_enc_m)
    speed = np.gradient(s_enc_m, t_s)
    roll = zero_phase_roll(t_s, gyro_b, accel_b, speed, rho)
    kappa = measured_curvature_per_m(gyro_b, roll, speed)
    return s_enc_m + chainage_offset_m(s_enc_m, kappa, lambda s: design_at(s)[0])


def tilt_roll_rad(accel_b: np.ndarray, speed_mps: np.ndarray, curvature_h_per_m: np.ndarray) -> np.ndarray:
    """Roll [rad] (N,) of the body in a level frame from its specific force (N, 3) [m/s^2] with
    the acceleration of a particle on the design track at the same speed (``V^2 rho_h`` towards
    the curve's centre, eq. 53) taken out: ``f_(y,z) = R(-phi) (V^2 rho_h, g)``."""
    a_h = speed_mps ** 2 * curvature_h_per_m
    return np.arctan2(accel_b[:, 1], accel_b[:, 2]) - np.arctan2(a_h, GRAVITY_MPS2)


def zero_phase_roll(t_s: np.ndarray, gyro_b: np.ndarray, accel_b: np.ndarray, speed_mps: np.ndarray,
                    curvature_h_per_m: np.ndarray, crossover_hz: float = 0.05) -> np.ndarray:
    """Roll [rad] (N,) of the body in a level frame (module docstring): ``phi_g``, the integral
    of the roll rate ``gyro_b[:, 0]`` [rad/s] (the pitch of a measuring frame on a rail vehicle
    stays below a degree; its coupling is left out), plus the slowly varying offset that turns
    the specific force, de-rotated by ``phi_g``, into the design particle's acceleration plus
    gravity (eq. 53, as :func:`tilt_roll_rad`). The de-rotated force's ``(y, z)`` components are
    low-passed first (zero-phase Butterworth, 2nd order each way, ``crossover_hz``): linear in
    the accelerometer's noise and the bogie's vibration (taking angles of single samples
    rectifies them), and its symmetric kernel passes the integrated gyro bias (a ramp) exactly.
    The ends are padded by reflection (an odd extension would pin them to the last sample's
    vibration). Samples at ``t_s`` (N,) [s], uniformly spaced."""
    dt = np.diff(t_s)
    if t_s.size < 16 or np.any(dt <= 0):
        raise VisionError("zero-phase roll: needs at least 16 IMU samples at increasing times")
    rate_hz = 1.0 / float(np.median(dt))
    phi_g = cumulative_trapezoid(gyro_b[:, 0], t_s, initial=0.0)
    c, s = np.cos(phi_g), np.sin(phi_g)
    f_y = c * accel_b[:, 1] - s * accel_b[:, 2]
    f_z = s * accel_b[:, 1] + c * accel_b[:, 2]
    sos = butter(2, crossover_hz, btype="low", output="sos", fs=rate_hz)
    pad = min(t_s.size - 1, int(3 * rate_hz / crossover_hz))
    low = sosfiltfilt(sos, np.column_stack([f_y, f_z, speed_mps ** 2 * curvature_h_per_m]), axis=0,
                      padtype="even", padlen=pad)
    return phi_g + np.arctan2(low[:, 0], low[:, 1]) - np.arctan2(low[:, 2], GRAVITY_MPS2)


def track_frame_acceleration(accel_b: np.ndarray, roll_rel_rad: np.ndarray, design: dict,
                             pitch_rel_rad: np.ndarray | None = None) -> np.ndarray:
    """Right-hand side of eq. 46 (N, 2) [m/s^2]: the specific force turned into the design track
    frame by the relative roll (and pitch), minus gravity there and the design particle's
    acceleration (``V^2 rho_h`` horizontal, turned by the cant). The rotations are exact; the
    seed's small-angle form is their first order."""
    c, s = np.cos(roll_rel_rad), np.sin(roll_rel_rad)
    f_y = c * accel_b[:, 1] - s * accel_b[:, 2]
    f_z = s * accel_b[:, 1] + c * accel_b[:, 2]
    if pitch_rel_rad is not None:
        f_z = f_z - accel_b[:, 0] * pitch_rel_rad
    cant = design["cant_rad"]
    a_h = design["speed_mps"] ** 2 * design["rho_h_per_m"]
    # R_x(cant)^T (0, a_h, g): the design particle's acceleration plus gravity in the canted frame
    g_y = np.cos(cant) * a_h + np.sin(cant) * GRAVITY_MPS2
    g_z = -np.sin(cant) * a_h + np.cos(cant) * GRAVITY_MPS2
    return np.column_stack([f_y - g_y, f_z - g_z])


def relative_trajectory(t_s: np.ndarray, accel_b: np.ndarray, roll_rel_rad: np.ndarray, design: dict,
                        pitch_rel_rad: np.ndarray | None = None, iterations: int = 3) -> np.ndarray:
    """The seed's relative-motion ODE (eq. 46) integrated forward from rest at ``r = 0``:
    ``r'' + C r' + K r = b`` with ``b`` from :func:`track_frame_acceleration` and the
    time-varying ``C`` (Coriolis of the track frame's twist rate) and ``K`` (its centripetal and
    angular-acceleration terms; the design's vertical curvature is taken as zero). ``C`` and
    ``K`` are of order ``V^2 rho^2`` (1e-3 1/s^2), so the coupled system is solved by a few
    fixed-point passes of vectorised double integration (trapezoidal) instead of a per-sample
    loop. Returns ``r`` (N, 2) [m]."""
    b = track_frame_acceleration(accel_b, roll_rel_rad, design, pitch_rel_rad)
    V, Vd = design["speed_mps"], design["vdot_mps2"]
    rho_h, rho_tw = design["rho_h_per_m"], design["twist_rad_per_m"]
    k_yy = -V ** 2 * (rho_tw ** 2 + rho_h ** 2)
    k_yz = -Vd * rho_tw
    k_zy = Vd * rho_tw
    k_zz = -V ** 2 * rho_tw ** 2
    r = np.zeros_like(b)
    rd = np.zeros_like(b)
    for _ in range(iterations):
        rdd = b.copy()
        rdd[:, 0] -= -2 * V * rho_tw * rd[:, 1] + k_yy * r[:, 0] + k_yz * r[:, 1]
        rdd[:, 1] -= 2 * V * rho_tw * rd[:, 0] + k_zy * r[:, 0] + k_zz * r[:, 1]
        rd = cumulative_trapezoid(rdd, t_s, axis=0, initial=0.0)
        r = cumulative_trapezoid(rd, t_s, axis=0, initial=0.0)
    return r


def rail_centre_trace(origin_left_mm: np.ndarray, origin_right_mm: np.ndarray, roll_rel_rad: np.ndarray
                      ) -> np.ndarray:
    """The vision's part of eq. 40 (N, 2) [m]: the mean of the two rails' profile origins (each
    (N, 2) ``(y, z)`` [mm] in the measuring frame) turned into the track frame by the relative
    roll; adding ``r`` gives the centreline's alignment and vertical profile. NaN rows (faults)
    stay NaN."""
    m = 0.5 * (origin_left_mm + origin_right_mm) / 1e3
    c, s = np.cos(roll_rel_rad), np.sin(roll_rel_rad)
    return np.column_stack([c * m[:, 0] - s * m[:, 1], s * m[:, 0] + c * m[:, 1]])


def band_trace(s_m: np.ndarray, x: np.ndarray, band_m: tuple[float, float] = (3.0, 25.0),
               step_m: float = 0.1) -> np.ndarray:
    """A trace ``x`` (N,) sampled at chainages ``s_m`` (N,, increasing) band-passed over
    chainage (:func:`trackfusion.track.irregularities.bandpass`, zero-phase) on a uniform grid of
    ``step_m`` and read back at ``s_m``; NaN samples (faults) are bridged linearly for the filter
    and NaN again in the result."""
    ok = np.isfinite(x)
    if ok.sum() < 2 or np.any(np.diff(s_m) <= 0):
        raise VisionError("band trace: needs increasing chainages and at least two finite samples")
    grid = np.arange(s_m[0], s_m[-1], step_m)
    y = bandpass(np.interp(grid, s_m[ok], x[ok]), step_m, *band_m)
    return np.where(ok, np.interp(s_m, grid, y), np.nan)
