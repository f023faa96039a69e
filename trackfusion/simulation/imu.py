"""IMU measurement simulation: the error model applied to error-free interval means.

A measured sample (mean over its interval dt = 1 / rate_hz) is::

    w_meas = (I + S_g + N_g) w_true + b_g + b_g_gm(t) + n_g      [rad/s]
    f_meas = (I + S_a + N_a) f_true + b_a + b_a_gm(t) + n_a      [m/s^2]

- ``S``: diagonal scale-factor errors, drawn once (``*_scale_ppm`` is the 1-sigma).
- ``N``: axis misalignment / non-orthogonality, six off-diagonal elements drawn
  once (``*_misalignment_arcsec`` 1-sigma).
- ``b``: turn-on bias, constant over the run (``gyro_bias_deg_per_h``, ``accel_bias_ug``).
- ``b_gm``: bias instability as a first-order Gauss-Markov process with
  standard deviation ``*_bias_instability_*`` and correlation time ``*_bias_tau_s``.
- ``n``: white noise from the angle / velocity random walk:
  sample sigma = ``ARW / sqrt(dt)`` (ARW in rad/sqrt(s)), ``VRW / sqrt(dt)``.
- quantisation of the increments ``w dt`` and ``f dt`` to ``gyro_quantum_rad`` and
  ``accel_quantum_mps`` with the remainder carried over (as integrating IMUs
  do), so quantisation adds noise but no drift.
- saturation: each axis is clipped to +-``gyro_range_deg_per_s`` and
  +-``accel_range_mps2`` (the measurement range of the grade's data sheet class);
  a flat-lined axis at the limit is refused by ``trackfusion run``
  (:mod:`trackfusion.fusion.input_checks`).

The figures come from an :class:`~trackfusion.sensors.imu.ImuSpec` (a datasheet; named
grades in :data:`trackfusion.sensors.imu.IMU_GRADES`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sensors.imu import ARCSEC, DEG, G0_MPS2, ImuSpec
from ..sensors.types import ImuData
from . import noise


def _error_matrix(scale_sigma: float, misalignment_sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """I + diag(scale) + off-diagonal misalignment, (3, 3), drawn once."""
    scale = rng.normal(0.0, 1.0, 3) * scale_sigma
    off = rng.normal(0.0, 1.0, 6) * misalignment_sigma_rad
    M = np.eye(3) + np.diag(scale)
    M[[0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] = off
    return M


@dataclass(frozen=True)
class TriadErrors:
    """One triad's error model in SI units (module docstring), all 1-sigma: the turn-on
    ``bias_sigma``, the Gauss-Markov ``instability_sigma`` with correlation time ``tau_s`` [s],
    the white noise's ``white_root_psd`` (per sqrt(s)), the scale factor ``scale_sigma``
    (fraction), the axis misalignment ``misalignment_sigma_rad`` [rad]; the increments'
    ``quantum`` (0: none). Rates in rad/s for the gyro, m/s^2 for the accelerometer."""

    bias_sigma: float
    instability_sigma: float
    tau_s: float
    white_root_psd: float
    scale_sigma: float
    misalignment_sigma_rad: float
    quantum: float

    @classmethod
    def gyro(cls, spec: ImuSpec) -> "TriadErrors":
        """The gyro triad's errors of a datasheet."""
        return cls(bias_sigma=spec.gyro_bias_deg_per_h * DEG / 3600.0,
                   instability_sigma=spec.gyro_bias_instability_deg_per_h * DEG / 3600.0, tau_s=spec.gyro_bias_tau_s,
                   white_root_psd=spec.gyro_arw_deg_per_sqrt_h * DEG / 60.0, scale_sigma=spec.gyro_scale_ppm * 1e-6,
                   misalignment_sigma_rad=spec.gyro_misalignment_arcsec * ARCSEC, quantum=spec.gyro_quantum_rad)

    @classmethod
    def accel(cls, spec: ImuSpec) -> "TriadErrors":
        """The accelerometer triad's errors of a datasheet."""
        return cls(bias_sigma=spec.accel_bias_ug * 1e-6 * G0_MPS2,
                   instability_sigma=spec.accel_bias_instability_ug * 1e-6 * G0_MPS2, tau_s=spec.accel_bias_tau_s,
                   white_root_psd=spec.accel_vrw_mps_per_sqrt_h / 60.0, scale_sigma=spec.accel_scale_ppm * 1e-6,
                   misalignment_sigma_rad=spec.accel_misalignment_arcsec * ARCSEC, quantum=spec.accel_quantum_mps)


def _sensor_errors(true: np.ndarray, dt_s: float, rng: np.random.Generator,
                   errors: TriadErrors) -> tuple[np.ndarray, dict]:
    """Apply one triad's error model to ``true`` (N, 3); returns measured (N, 3) and drawn values."""
    n = true.shape[0]
    M = _error_matrix(errors.scale_sigma, errors.misalignment_sigma_rad, rng)
    bias = rng.normal(0.0, 1.0, 3) * errors.bias_sigma
    gm = np.column_stack([noise.gauss_markov(n, dt_s, errors.instability_sigma, errors.tau_s, rng)
                          for _ in range(3)])
    white = np.column_stack([noise.white(n, errors.white_root_psd / np.sqrt(dt_s), rng) for _ in range(3)])
    meas = true @ M.T + bias + gm + white
    if errors.quantum > 0:
        meas = _quantise_increments(meas, dt_s, errors.quantum)
    drawn = {"bias": bias.tolist(), "error_matrix": M.tolist(),
             "bias_gm_first": gm[0].tolist(), "bias_gm_last": gm[-1].tolist()}
    return meas, drawn


def _quantise_increments(rate: np.ndarray, dt_s: float, quantum: float) -> np.ndarray:
    """Quantise the increments ``rate * dt`` to ``quantum`` with the remainder carried over."""
    cumulative = np.cumsum(rate * dt_s, axis=0)
    q = noise.quantise(cumulative, quantum)
    return np.diff(q, axis=0, prepend=np.zeros((1, rate.shape[1]))) / dt_s


def simulate_imu(t_s: np.ndarray, gyro_true_radps: np.ndarray, accel_true_mps2: np.ndarray, spec: ImuSpec,
                 rng: np.random.Generator, ideal: bool = False) -> tuple[ImuData, dict]:
    """Measured IMU samples from error-free interval means.

    t_s (N,) [s]; gyro_true_radps, accel_true_mps2 (N, 3). Returns the :class:`ImuData`
    and a JSON-able dict of every error drawn (in SI units). ``ideal`` returns the truth.
    """
    if ideal:
        return ImuData(np.asarray(t_s, float), np.array(gyro_true_radps, float),
                       np.array(accel_true_mps2, float)), {"ideal": True}
    dt = 1.0 / spec.rate_hz
    gyro, drawn_g = _sensor_errors(gyro_true_radps, dt, rng, TriadErrors.gyro(spec))
    accel, drawn_a = _sensor_errors(accel_true_mps2, dt, rng, TriadErrors.accel(spec))
    drawn = {"gyro_radps": drawn_g, "accel_mps2": drawn_a, "spec": spec.model_dump()}
    gyro_range = spec.gyro_range_deg_per_s * DEG
    return ImuData(np.asarray(t_s, float), np.clip(gyro, -gyro_range, gyro_range),
                   np.clip(accel, -spec.accel_range_mps2, spec.accel_range_mps2)), drawn
