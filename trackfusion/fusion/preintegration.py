"""IMU preintegration between keyframes (GTSAM ``ImuFactor``).

Why not ``CombinedImuFactor`` (a bias state at every keyframe): a navigation-grade bias
instability (0.005 deg/h over an hour) makes the bias random walk between keyframes 0.1 s
apart carry an information of ~1e19 against ~1e12 from the measurements; eliminating
that chain cancels catastrophically and GTSAM stops with an indeterminate system (measured
on the open-track scenario). The bias therefore lives in segments of
``keyframes.bias_segment_s`` (default 60 s) joined by random-walk factors of the same
density, where the two informations are of one order.

Noise densities come from the IMU specification (continuous-time, SI): gyro ARW
[rad/sqrt(s)], accelerometer VRW [m/s/sqrt(s)], and the bias instability
``sigma_b`` with correlation time ``tau`` as a random walk of density
``sqrt(2 sigma_b^2 / tau)`` (the Gauss-Markov process's short-term behaviour).

Each interval gets its own parameters: the Earth rate in ``n`` (``setOmegaCoriolis``,
first-order Coriolis; the centrifugal part is inside normal gravity) and the normal
gravity vector of the keyframe's own position (DESIGN.md section 3).

Sculling compensation: a sample is the mean over its interval, and GTSAM rotates it
with the attitude at the interval start. For a body turning at a constant rate
``w`` under a specific force fixed in ``n`` the exact input is
``f + 0.5 dt (w x f)``; we feed that (removes a systematic ~1e-4 m/s per second of
velocity error at 0.01 rad/s; see tests/test_fusion_ideal.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import gtsam
import numpy as np

from ..rotations import skew, so3_exp
from ..sensors.imu import ImuSpec
from ..sensors.types import ImuData

DEG = np.pi / 180.0
#: integration-error density added to every step [m/s^2/sqrt(Hz) squared]; tiny, keeps the
#: preintegrated covariance well conditioned at high rates.
INTEGRATION_VAR = 1e-16


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise densities in SI units.

    gyro_psd_rad2ps (rad^2/s), accel_psd_m2ps3 (m^2/s^3): white noise (PSD);
    gyro_bias_rw_psd, accel_bias_rw_psd: bias random-walk PSDs (rad^2/s^3, m^2/s^5);
    gyro_bias_sigma_radps, accel_bias_sigma_mps2: turn-on bias 1-sigma (prior);
    accel_scale, accel_misalignment_rad: 1-sigma of each accelerometer's scale-factor error [-] and
    of each of its six axis misalignments [rad] (the datasheet's), which the preintegration does
    not model: on the nearly constant specific force of a vehicle at rest or on a track (gravity)
    they make a constant bias, :meth:`accel_bias_prior_sigma_mps2`.
    """

    gyro_psd_rad2ps: float
    accel_psd_m2ps3: float
    gyro_bias_rw_psd: float
    accel_bias_rw_psd: float
    gyro_bias_sigma_radps: float
    accel_bias_sigma_mps2: float
    accel_scale: float = 0.0
    accel_misalignment_rad: float = 0.0

    @classmethod
    def from_spec(cls, spec: ImuSpec) -> "ImuNoise":
        """Densities from an :class:`ImuSpec` (quantisation adds ``q^2 / (12 dt)``)."""
        dt = 1.0 / spec.rate_hz
        g_arw = spec.gyro_arw_deg_per_sqrt_h * DEG / 60.0
        a_vrw = spec.accel_vrw_mps_per_sqrt_h / 60.0
        g_bi = spec.gyro_bias_instability_deg_per_h * DEG / 3600.0
        a_bi = spec.accel_bias_instability_ug * 9.80665e-6
        gyro_psd = g_arw**2 + spec.gyro_quantum_rad**2 / 12.0 / dt
        accel_psd = a_vrw**2 + spec.accel_quantum_mps**2 / 12.0 / dt
        # floors keep the information matrices finite for an ideal (noise-free) spec
        return cls(max(gyro_psd, 1e-22), max(accel_psd, 1e-18),
                   max(2.0 * g_bi**2 / spec.gyro_bias_tau_s, 1e-30),
                   max(2.0 * a_bi**2 / spec.accel_bias_tau_s, 1e-24),
                   max(spec.gyro_bias_deg_per_h * DEG / 3600.0, 1e-12),
                   max(spec.accel_bias_ug * 9.80665e-6, 1e-9),
                   spec.accel_scale_ppm * 1e-6, spec.accel_misalignment_arcsec * DEG / 3600.0)

    def accel_bias_prior_sigma_mps2(self, specific_force_b_mps2: np.ndarray) -> np.ndarray:
        """1-sigma (3,) [m/s^2] per accelerometer axis of the constant bias the bias state holds
        while the specific force in ``b`` stays near ``specific_force_b_mps2`` (3,) [m/s^2]
        (gravity, for a vehicle that does not roll over): the turn-on bias and what the scale
        error ``s_i f_i`` and the misalignments ``m_ij f_j`` (j != i) make of that force, added
        in quadrature. A level navigation-grade IMU (5 arcsec, 10 ug) gets 26 ug on x and y: the
        misalignment towards z times g (24 ug) is no less a bias than the turn-on one, and a
        prior of 10 ug would push the rest into pitch (a grade error of the trajectory)."""
        f2 = np.asarray(specific_force_b_mps2, dtype=float) ** 2
        var = (self.accel_bias_sigma_mps2**2 + self.accel_scale**2 * f2
               + self.accel_misalignment_rad**2 * (f2.sum() - f2))
        return np.sqrt(var)


def make_params(noise: ImuNoise, gravity_n: np.ndarray, omega_ie_n: np.ndarray,
                covariances: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> gtsam.PreintegrationParams:
    """GTSAM preintegration parameters for one interval (gravity (3,) and Earth rate (3,) in ``n``);
    ``covariances``: :func:`noise_covariances` of ``noise`` when already at hand (one per run)."""
    gyro, accel, integration = covariances or noise_covariances(noise)
    p = gtsam.PreintegrationParams.MakeSharedU(9.8)
    p.n_gravity = np.asarray(gravity_n, dtype=float)
    p.setGyroscopeCovariance(gyro)
    p.setAccelerometerCovariance(accel)
    p.setIntegrationCovariance(integration)
    p.setOmegaCoriolis(np.asarray(omega_ie_n, dtype=float))
    return p


def noise_covariances(noise: ImuNoise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro, accelerometer and integration covariance densities (3,3) of the parameters."""
    return noise.gyro_psd_rad2ps * np.eye(3), noise.accel_psd_m2ps3 * np.eye(3), INTEGRATION_VAR * np.eye(3)


def sculling_compensated(imu: ImuData) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample ``dt`` (N,) [s] and compensated specific force (N, 3) [m/s^2] (module docstring).

    ``dt[0]`` is the median sample interval (the first sample's interval is not in the log).
    """
    dt = np.diff(imu.t_s, prepend=np.nan)
    dt[0] = np.median(dt[1:]) if dt.size > 1 else 0.0
    return dt, _sculled(imu.accel_mps2, imu.gyro_radps, dt)


def _sculled(accel_mps2: np.ndarray, gyro_radps: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """Sculling-compensated specific force (N, 3) [m/s^2] of samples (N, 3) over intervals ``dt_s`` (N,) [s]."""
    return accel_mps2 + 0.5 * dt_s[:, None] * np.cross(gyro_radps, accel_mps2)


def preintegrate(imu: ImuData, key_idx: np.ndarray, noise: ImuNoise, gravity_n: np.ndarray,
                 omega_ie_n: np.ndarray, bias_hat: gtsam.imuBias.ConstantBias | None = None
                 ) -> tuple[list[gtsam.PreintegratedImuMeasurements], list[gtsam.PreintegrationParams]]:
    """Preintegrated measurements between consecutive keyframes.

    key_idx: (K,) increasing IMU sample indices of the keyframes (a keyframe sits at the time of
    its sample); interval k integrates samples ``key_idx[k]+1 .. key_idx[k+1]``.
    gravity_n: (K, 3) normal gravity at each keyframe [m/s^2]; omega_ie_n: (3,) [rad/s].
    Returns K-1 GTSAM preintegrated measurements (one Python call per IMU sample: ~2 us each)
    and their parameters (shared with them: setting ``params[k].n_gravity`` later changes the
    gravity interval k's factor uses).
    """
    bias_hat = bias_hat or gtsam.imuBias.ConstantBias()
    dt, f = sculling_compensated(imu)
    w = imu.gyro_radps
    pims, params = [], []
    covariances = noise_covariances(noise)
    for k in range(key_idx.size - 1):
        params.append(make_params(noise, gravity_n[k], omega_ie_n, covariances))
        pim = gtsam.PreintegratedImuMeasurements(params[-1], bias_hat)
        integrate = pim.integrateMeasurement
        for i in range(key_idx[k] + 1, key_idx[k + 1] + 1):
            integrate(f[i], w[i], dt[i])
        pims.append(pim)
    return pims, params


def body_deltas(imu: ImuData, start_idx: np.ndarray, tau_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation ``dR`` (M,3,3), velocity ``dv`` (M,3) [m/s] and position ``dp`` (M,3) [m]
    integrated in the body frame of the IMU sample ``start_idx`` (M,) over ``tau_s`` (M,) [s]
    (the samples after it, the last one for the part of its interval up to ``tau``; a sample is
    the mean over the interval that ends at it), without gravity, bias and Earth rate: the
    preintegration's ``deltaRij``, ``deltaVij`` and ``deltaPij`` over a fraction of an interval.
    A ``tau_s`` <= 0 gives the identity and zeros."""
    n = imu.t_s.size
    t_end = imu.t_s[start_idx] + tau_s
    last = np.minimum(np.searchsorted(imu.t_s, t_end), n - 1)  # the sample whose interval holds t_end
    # the longest spans first, so that each step works on the prefix of the spans still running
    # (a span's steps after its last sample would add nothing: about half the work on the spans
    # of a keyframe interval)
    order = np.argsort(start_idx - last, kind="stable")
    start, t_end, steps = start_idx[order], t_end[order], (last - start_idx)[order]
    M = start.size
    dR = np.broadcast_to(np.eye(3), (M, 3, 3)).copy()
    dv, dp = np.zeros((M, 3)), np.zeros((M, 3))
    for offset in range(1, int(np.max(steps, initial=0)) + 1):
        m = int(np.searchsorted(-steps, -offset, side="right"))  # the spans with steps >= offset
        s = np.minimum(start[:m] + offset, n - 1)  # >= 1
        dt = imu.t_s[s] - imu.t_s[s - 1]
        f = _sculled(imu.accel_mps2[s], imu.gyro_radps[s], dt)
        h = np.clip(t_end[:m] - imu.t_s[s - 1], 0.0, dt)
        a = np.einsum("kij,kj->ki", dR[:m], f)
        dp[:m] += dv[:m] * h[:, None] + 0.5 * a * h[:, None] ** 2
        dv[:m] += a * h[:, None]
        dR[:m] = dR[:m] @ so3_exp(imu.gyro_radps[s] * h[:, None])
    inverse = np.empty_like(order)
    inverse[order] = np.arange(M)
    return dR[inverse], dv[inverse], dp[inverse]


class ImuSpan(Protocol):
    """What :func:`point_after` reads of M spans from a keyframe ``j`` (fusion/wheel_path.py
    ``WheelPathData``, fusion/factors.py ``PrismObservations``): tau_s (M,) [s] after ``t_j``;
    dR (M,3,3), dp (M,3) [m] of :func:`body_deltas`; gravity_n (M,3) [m/s^2] at the keyframe;
    omega_ie_n (3,) [rad/s]."""

    tau_s: np.ndarray
    dR: np.ndarray
    dp: np.ndarray
    gravity_n: np.ndarray
    omega_ie_n: np.ndarray


def point_after(R_j: np.ndarray, p_j: np.ndarray, v_j: np.ndarray, span: ImuSpan, lever_b: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The point ``lever_b`` (body frame) at ``t' = t_j + tau`` reached from keyframe ``j`` with
    the IMU's :func:`body_deltas` ``dR``, ``dp`` (``span``; the preintegration's mechanisation)::

        p(t') = p_j + v_j tau + (g - 2 omega_ie x v_j) tau^2 / 2 + R_j dp
        R(t') = Exp(-omega_ie tau) R_j dR,     P = p(t') + R(t') lever_b

    R_j (M,3,3) ``R_nb``; p_j, v_j (M,3) [m, m/s]; lever_b (3,) [m]. Returns P (M,3) [m],
    ``Exp(-omega_ie tau) R_j`` (M,3,3) (j's body frame to ``n`` at ``t'``: ``R(t')`` is it times ``dR``) and
    the Jacobians of P on keyframe j's attitude (right perturbation, (M,3,3)) and velocity
    (M,3,3); on its position it is ``R_j`` (GTSAM's pose retraction)."""
    tau, dR, dp, gravity_n, omega_ie_n = span.tau_s[:, None], span.dR, span.dp, span.gravity_n, span.omega_ie_n
    earth_R_j = so3_exp(-omega_ie_n[None, :] * tau) @ R_j  # j's body frame to n at t'
    lever_j = np.einsum("kij,kj->ki", dR, np.broadcast_to(lever_b, p_j.shape))  # in j's body frame
    P = (p_j + v_j * tau + 0.5 * (gravity_n - 2.0 * np.cross(omega_ie_n, v_j)) * tau**2
         + np.einsum("kij,kj->ki", R_j, dp) + np.einsum("kij,kj->ki", earth_R_j, lever_j))
    dP_theta = -R_j @ skew(dp) - earth_R_j @ skew(lever_j)
    dP_v = np.eye(3)[None] * tau[:, :, None] - skew(omega_ie_n)[None] * (tau**2)[:, :, None]
    return P, earth_R_j, dP_theta, dP_v
