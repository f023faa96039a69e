"""The NHC sigma a simulated survey should be processed with, derived from its scenario.

The simulated trolley is rigid, so its only NHC violation is what the rails make it
(:mod:`trackfusion.track.nhc_noise`): the random irregularities (spectrum and band of
``irregularities.psd``, integrated through the wheelbase transfer function), the deterministic
injections (sinusoids, weld dips, corrugation: their mean square over the surveyed chainage),
at the fastest speed of the motion plan, plus the gyro white noise through the lever arm from
the IMU to ``v``'s origin. The three add in quadrature per axis.
"""

from __future__ import annotations

import numpy as np

from .irregularity import IrregularitySpec, synthesize
from ..track.nhc_noise import gyro_noise_velocity_sigma_mps, nhc_velocity_rms_mps, nhc_velocity_series_mps
from .config import ScenarioConfig


def max_speed_mps(cfg: ScenarioConfig) -> float:
    """Fastest commanded speed of the motion plan [m/s] (0 when it only holds)."""
    return max([seg.speed_mps for seg in cfg.motion.segments if seg.speed_mps is not None], default=0.0)


def _injections_rms_mps(cfg: ScenarioConfig, chainage_range_m: tuple[float, float], speed_mps: float
                        ) -> dict[str, float]:
    """RMS NHC velocity [m/s] of the deterministic injections on the reference rail over the
    surveyed chainage range [m] (lateral, vertical)."""
    spec = IrregularitySpec.from_dict(cfg.irregularities)
    out = {"lateral": 0.0, "vertical": 0.0}
    if not (spec.sinusoids or spec.weld_dips or spec.corrugation):
        return out
    lo, hi = chainage_range_m
    deterministic = spec.model_copy(update={"psd": None})
    field = synthesize(deterministic, hi + cfg.trolley.wheelbase_m, np.random.default_rng(0))
    inside = (field.s_m >= lo - 0.5 * cfg.trolley.wheelbase_m) & (field.s_m <= hi + 0.5 * cfg.trolley.wheelbase_m)
    ds = float(field.s_m[1] - field.s_m[0])
    for axis in out:
        w = field.rails[f"{axis}_{cfg.trolley.reference_rail}"][inside]
        u = nhc_velocity_series_mps(w, ds, speed_mps, cfg.trolley.wheelbase_m)
        out[axis] = float(np.sqrt(np.mean(u**2)))
    return out


def nhc_sigmas_mm_per_s(cfg: ScenarioConfig, chainage_range_m: tuple[float, float],
                        gyro_arw_deg_per_sqrt_h: float, imu_rate_hz: float) -> dict[str, float]:
    """Per-axis NHC sigma [mm/s] of a simulated survey: ``{"lateral": ..., "vertical": ...}``.

    chainage_range_m: (lowest, highest) chainage of the motion plan [m];
    gyro_arw_deg_per_sqrt_h / imu_rate_hz: the simulated IMU's angle random walk and rate.
    """
    speed = max_speed_mps(cfg)
    psd = IrregularitySpec.from_dict(cfg.irregularities).psd
    rail = {"lateral": 0.0, "vertical": 0.0}
    if psd is not None and speed > 0:
        rail = nhc_velocity_rms_mps(speed, cfg.trolley.wheelbase_m, psd.spectrum, psd.wavelength_min_m,
                                    psd.wavelength_max_m, psd.scale, tuple(psd.components))
    injected = _injections_rms_mps(cfg, chainage_range_m, speed)
    to_origin_v = -np.asarray(cfg.trolley.lever_arm_imu_v_m, dtype=float)
    gyro = gyro_noise_velocity_sigma_mps(gyro_arw_deg_per_sqrt_h, imu_rate_hz, to_origin_v)
    return {a: float(np.sqrt(rail[a] ** 2 + injected[a] ** 2 + gyro[a] ** 2) * 1e3) for a in rail}
