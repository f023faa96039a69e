"""Seed 004's track-level methods, as baselines for the factor graph's roll (benchmarks/track_level.py).

Seed 004 (Wang, "Research on the track level measurement based on multi-sensor information
fusion") measures the cross-level of a T-shaped trolley with an angle sensor (inclinometer:
good static, slow dynamic response) and a MEMS gyro (good dynamic response, drifts), and fuses
them two ways. Its equations, as implemented here (angles in rad; the seed's Q and R are used
as given, in the squared unit of the angle, and only their ratios matter):

- cross-level ``H = L sin(theta)`` (eq. 22): :func:`trackfusion.track.irregularities.cross_level_from_roll`;
- gyro angle ``theta = integral omega dt`` (eq. 23), the gyro's output being zero at rest:
  :func:`gyro_angle` (trapezoidal sum from the initial angle, the rest-mean rate removed);
- Kalman filter (eqs. 1-7): ``X(t|t-1) = A X(t-1|t-1)``, ``P(t|t-1) = A P A' + Q``,
  ``Kg = P H' (H P H' + R)^-1``, ``X(t|t) = X(t|t-1) + Kg (Z - H X(t|t-1))``, ``P(t|t) = (I - Kg H) P``,
  with no control input (B = 0), both sensors measuring the level angle, ``Z_A = X + V_A`` and
  ``Z_B = X + V_B`` (so ``H = [1, 1]'``, the seed's unit measurement matrix for one state), the
  seed's ``R = diag(0.01, 0.1)`` (the gyro's larger for its drift), ``Q = 0.01``, ``X0 = 0`` and
  ``P0 = 1`` (non-zero, as the seed requires): :func:`seed_kalman`. The seed's A was lost in
  its text; ``A = 1`` (the level angle persists) is the model its "no control" system implies.
- weighted fusion (eqs. 8-18): ``x = w1 z1 + w2 z2`` with ``w1 + w2 = 1`` (eq. 14, unbiased),
  the minimum of ``J = w1^2 s1^2 + (1 - w1)^2 s2^2`` (eqs. 15-17) at ``w1 = s2^2 / (s1^2 + s2^2)``;
  the variances from "only the measurement data" (section III): each sensor's error variance
  from the auto- and cross-covariance of the two series, ``s_i^2 = C_ii - C_12`` (errors
  independent of each other and of the level): :func:`seed_weighted_fusion`.

Not in the seed, for comparison: :func:`complementary_filter`, the frequency split the seed's
table 1 describes (inclinometer below a crossover, gyro above), and :func:`inverse_first_order_lag`,
the angle sensor's slow response undone from its stated time constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from ..errors import TrackGeometryError

SEED_R = (0.01, 0.1)   # seed 004: angle sensor, MEMS gyro measurement noise
SEED_Q = 0.01          # seed 004: process noise
SEED_P0 = 1.0          # non-zero initial covariance (any value converges; 0 would freeze the filter)


def gyro_angle(t_s: np.ndarray, rate_radps: np.ndarray, theta0_rad: float = 0.0,
               rest: np.ndarray | None = None) -> np.ndarray:
    """Seed eq. 23: the angle (N,) [rad] from the rate (N,) [rad/s] at t_s (N,) [s], starting at
    ``theta0_rad``; ``rest`` (N,) bool marks samples at rest, whose mean rate is removed first
    (the seed's "output signal is zero in the stationary state")."""
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(rate_radps, dtype=float)
    if rest is not None:
        if not np.any(rest):
            raise TrackGeometryError("gyro_angle: no sample at rest to zero the gyro")
        w = w - np.mean(w[rest])
    steps = 0.5 * (w[1:] + w[:-1]) * np.diff(t)
    return theta0_rad + np.r_[0.0, np.cumsum(steps)]


def seed_kalman(z_angle_sensor: np.ndarray, z_gyro: np.ndarray, r=SEED_R, q: float = SEED_Q,
                x0: float = 0.0, p0: float = SEED_P0) -> np.ndarray:
    """Seed eqs. 1-7 (module docstring) on the two angle series (N,): the filtered level angle (N,).
    With constant A, H, Q and R the covariance recursion does not depend on the data: it is run
    first (scalar), then the state update ``x_k = (1 - k_k (1 + 1)) x_{k-1} + k_k z_A + k_k z_B``
    with the gains ``Kg_k = P(k|k-1) H' (H P H' + R)^-1`` (vectorised: one recursion of length N
    in lfilter once the gains have settled)."""
    za, zb = np.asarray(z_angle_sensor, dtype=float), np.asarray(z_gyro, dtype=float)
    R = np.diag(np.asarray(r, dtype=float))
    Rinv = np.linalg.inv(R)
    info_meas = float(np.sum(Rinv))                   # H' R^-1 H with H = [1, 1]'
    gains = []                                        # Kg (1, 2) per step until steady
    p = p0
    for _ in range(za.size):
        p_prior = p + q
        p = 1.0 / (1.0 / p_prior + info_meas)         # (I - Kg H) P, in information form
        k = p * (Rinv @ np.ones(2))                   # Kg = P H' R^-1 (equal to eq. 6)
        gains.append(k)
        if len(gains) > 2 and np.allclose(gains[-1], gains[-2], rtol=1e-14, atol=0):
            break
    K = np.array(gains)
    n_trans = K.shape[0]
    Kfull = np.vstack([K, np.repeat(K[-1:], za.size - n_trans, axis=0)]) if za.size > n_trans else K[: za.size]
    a = 1.0 - Kfull.sum(axis=1)                       # x_k = a_k x_{k-1} + Kg_k z_k
    u = Kfull[:, 0] * za + Kfull[:, 1] * zb
    x = np.empty(za.size)
    prev = x0
    m = min(n_trans, za.size)
    for i in range(m):                                # the settling steps
        prev = a[i] * prev + u[i]
        x[i] = prev
    if za.size > m:                                   # steady state: a first-order recursion
        x[m:], _ = lfilter([1.0], [1.0, -a[-1]], u[m:], zi=[a[-1] * prev])
    return x


def steady_state_gain(r=SEED_R, q: float = SEED_Q) -> np.ndarray:
    """The steady-state Kalman gain (2,) of :func:`seed_kalman`: the positive root of the scalar
    Riccati equation ``P = ((P + q)^-1 + sum R^-1)^-1``, ``Kg = P H' R^-1``."""
    rinv = 1.0 / np.asarray(r, dtype=float)
    s = float(np.sum(rinv))
    # P (P + q) s = P + q - P  =>  s P^2 + s q P - q = 0
    p = (-s * q + np.sqrt((s * q) ** 2 + 4 * s * q)) / (2 * s)
    return p * rinv


@dataclass(frozen=True)
class WeightedFusion:
    """Seed eqs. 8-18: fused angle (N,) [rad], the weights (w1, w2) and the error variances used."""

    angle_rad: np.ndarray
    weights: tuple[float, float]
    variances: tuple[float, float]


def error_variances_from_data(z1: np.ndarray, z2: np.ndarray) -> tuple[float, float]:
    """Each series' error variance from the data alone (seed section III): ``C_ii - C_12`` with
    C the sample covariance of (z1, z2): both measure the same x with independent errors, so
    ``C_12 = var(x)``. Floored at 1e-6 of the total so the weights stay defined."""
    C = np.cov(np.vstack([z1, z2]))
    floor = 1e-6 * (C[0, 0] + C[1, 1]) + 1e-300
    return float(max(C[0, 0] - C[0, 1], floor)), float(max(C[1, 1] - C[0, 1], floor))


def seed_weighted_fusion(z1: np.ndarray, z2: np.ndarray, variances: tuple[float, float] | None = None
                         ) -> WeightedFusion:
    """Seed eqs. 10-18: ``x = w1 z1 + w2 z2``, ``w1 = s2^2 / (s1^2 + s2^2)``, ``w2 = 1 - w1``;
    ``variances`` (s1^2, s2^2), or None: from the data (:func:`error_variances_from_data`)."""
    z1, z2 = np.asarray(z1, dtype=float), np.asarray(z2, dtype=float)
    v1, v2 = variances if variances is not None else error_variances_from_data(z1, z2)
    w1 = v2 / (v1 + v2)
    return WeightedFusion(w1 * z1 + (1 - w1) * z2, (float(w1), float(1 - w1)), (float(v1), float(v2)))


def complementary_filter(t_s: np.ndarray, z_angle_sensor: np.ndarray, rate_radps: np.ndarray,
                         crossover_s: float) -> np.ndarray:
    """Not in the seed: ``theta_k = a (theta_{k-1} + omega_k dt) + (1 - a) z_k``, ``a = T / (T + dt)``:
    the angle sensor low-passed and the gyro's angle high-passed by the same first-order filter
    of time constant ``crossover_s`` (their transfers sum to 1; each is 1/sqrt(2) in magnitude at
    ``f = 1 / (2 pi T)``). Regular samples t_s (N,) [s]."""
    t = np.asarray(t_s, dtype=float)
    dt = float(np.median(np.diff(t)))
    a = crossover_s / (crossover_s + dt)
    z = np.asarray(z_angle_sensor, dtype=float)
    u = a * np.asarray(rate_radps, dtype=float) * dt + (1 - a) * z
    y, _ = lfilter([1.0], [1.0, -a], u, zi=[a * z[0]])
    return y


def inverse_first_order_lag(t_s: np.ndarray, z: np.ndarray, tau_s: float, window_s: float = 0.1) -> np.ndarray:
    """Not in the seed: the input ``x = z + tau dz/dt`` (N,) of a first-order lag ``tau dz/dt = x - z``
    from its output z (N,) at regular t_s (N,) [s], z first averaged over ``window_s`` (the
    derivative amplifies what white noise the
    averaging leaves by about ``tau / window``)."""
    t = np.asarray(t_s, dtype=float)
    dt = float(np.median(np.diff(t)))
    zs = uniform_filter1d(np.asarray(z, dtype=float), max(1, int(round(window_s / dt))), mode="nearest")
    return zs + tau_s * np.gradient(zs, t)
