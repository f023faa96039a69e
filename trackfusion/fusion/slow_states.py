"""Priors on the slow states of a time segment (fusion/segments.py): IMU biases and odometer scale.

A segment smoothed on its own sees only its own data, so its slow states (the accelerometer and
gyro biases, the odometer scale error: random walks over the whole run) are pinned less well
than in one batch of the run; the along-track accelerometer bias, which trades against pitch,
suffers most (docs/solver_speed.md "Parallel segments"). In one batch, a segment's slow states
are tied to the rest of the run only through their random walks. A :class:`SlowPrior` stands for
that: a Gaussian on the slow states at a time outside the segment, from the data on that side
of it only (fusion/slow_pass.py), carried to the segment's nearest bias and scale state by the
random walk over the time between them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, S

from .preintegration import ImuNoise
from .settings import OdometerFactorSettings


@dataclass(frozen=True)
class SlowPrior:
    """The slow states at time ``t_s`` [s] given the data on one side of a segment only.

    bias (6,): accelerometer [m/s^2] then gyro [rad/s] bias (GTSAM order); bias_cov (6,6) its
    covariance; scale [-] odometer scale error and scale_var [-^2] its variance (None without
    odometer). ``start``: the prior stands for all the data before the segment, the
    specification's turn-on bias and scale priors included, so it replaces those in the segment.
    """

    t_s: float
    bias: np.ndarray
    bias_cov: np.ndarray
    scale: float | None
    scale_var: float | None
    start: bool


def _nearest_state(t_prior_s: float, t_key: np.ndarray, state_of_key: np.ndarray) -> tuple[int, float]:
    """The state (index into ``state_of_key``'s values) whose keyframes' mid-time is nearest to
    ``t_prior_s``, and the time [s] from that mid-time to the prior."""
    n = int(state_of_key[-1]) + 1
    first = np.searchsorted(state_of_key, np.arange(n), "left")
    last = np.searchsorted(state_of_key, np.arange(n), "right") - 1
    mid = 0.5 * (t_key[first] + t_key[last])
    m = int(np.argmin(np.abs(mid - t_prior_s)))
    return m, float(abs(mid[m] - t_prior_s))


def slow_prior_factors(priors: list[SlowPrior], t_key: np.ndarray, bias_seg: np.ndarray, seg: np.ndarray | None,
                       noise: ImuNoise, odometer: OdometerFactorSettings) -> list[gtsam.NonlinearFactor]:
    """GTSAM prior factors on the bias states ``B(m)`` and scale states ``S(m)`` of a segment
    (keyframe times ``t_key`` (K,), their bias and scale state indices (K,)) for ``priors``:
    each on the state nearest in time, its covariance grown by the random walk over that time."""
    rw_psd = np.r_[[noise.accel_bias_rw_psd] * 3, [noise.gyro_bias_rw_psd] * 3]
    scale_rw_var_per_s = (odometer.scale_random_walk_ppm_per_sqrt_h * 1e-6) ** 2 / 3600.0
    out: list[gtsam.NonlinearFactor] = []
    for p in priors:
        m, dt = _nearest_state(p.t_s, t_key, bias_seg)
        cov = p.bias_cov + np.diag(rw_psd * dt)
        out.append(gtsam.PriorFactorConstantBias(B(m), gtsam.imuBias.ConstantBias(p.bias[:3], p.bias[3:]),
                                                 gtsam.noiseModel.Gaussian.Covariance(cov)))
        if seg is not None and p.scale is not None:
            m, dt = _nearest_state(p.t_s, t_key, seg)
            out.append(gtsam.PriorFactorVector(S(m), np.array([p.scale]), gtsam.noiseModel.Isotropic.Sigma(
                1, float(np.sqrt(p.scale_var + scale_rw_var_per_s * dt)))))
    return out


def replaces_start(priors: list[SlowPrior] | None, scale: bool = False) -> bool:
    """True when one of ``priors`` stands for the data before the segment (:attr:`SlowPrior.start`)
    and, with ``scale``, carries the odometer scale."""
    return bool(priors) and any(p.start and (not scale or p.scale is not None) for p in priors)


@dataclass(frozen=True)
class EndCovariances:
    """Marginal covariances of a solve's first and last bias states (6,6) (GTSAM order:
    accelerometer [m/s^2], gyro [rad/s]) and odometer scale states [-^2] (None without odometer)."""

    bias_first: np.ndarray
    bias_last: np.ndarray
    scale_first: float | None
    scale_last: float | None


def slow_end_covariances(joint: Callable[[list[int]], np.ndarray], last_bias: int, last_scale: int | None
                         ) -> EndCovariances:
    """:class:`EndCovariances` from ``joint(keys)`` (the joint marginal covariance of variables,
    in that order) and the indices of the last bias and scale states."""
    bias_keys = [B(0)] + ([B(last_bias)] if last_bias > 0 else [])
    scale_keys = [] if last_scale is None else [S(0)] + ([S(last_scale)] if last_scale > 0 else [])
    cov = joint(bias_keys + scale_keys)
    nb = 6 * len(bias_keys)
    bias_first, bias_last = cov[:6, :6], cov[nb - 6:nb, nb - 6:nb]
    if last_scale is None:
        return EndCovariances(bias_first, bias_last, None, None)
    return EndCovariances(bias_first, bias_last, float(cov[nb, nb]), float(cov[-1, -1]))
