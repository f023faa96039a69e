"""The accelerometer bias prior: the turn-on bias and the constant error the scale-factor and
misalignment errors make of gravity (fusion/preintegration.py ``accel_bias_prior_sigma_mps2``),
against the simulator's error model drawn many times."""

import numpy as np
import pytest

from trackfusion.fusion.preintegration import ImuNoise
from trackfusion.sensors.imu import IMU_GRADES, ImuSpec
from trackfusion.simulation.imu import simulate_imu

G = 9.80665


def _constant_errors(spec: ImuSpec, f_b: np.ndarray, draws: int) -> np.ndarray:
    """Accelerometer error (draws, 3) [m/s^2] of a still IMU sensing ``f_b`` (3,), one IMU per draw
    (no white noise, no bias instability: what stays constant over a survey)."""
    still = spec.model_copy(update={"accel_vrw_mps_per_sqrt_h": 0.0, "accel_bias_instability_ug": 0.0})
    t = np.array([0.0, 1.0 / spec.rate_hz])
    f = np.tile(f_b, (2, 1))
    rng = np.random.default_rng(5)
    return np.array([simulate_imu(t, np.zeros((2, 3)), f, still, rng)[0].accel_mps2[0] - f_b for _ in range(draws)])


@pytest.mark.parametrize("f_b", [np.array([0.0, 0.0, G]), np.array([1.7, -3.0, 9.1])])
def test_prior_is_the_spread_of_the_drawn_constant_errors(f_b):
    spec = IMU_GRADES["navigation"].model_copy(update={"accel_scale_ppm": 10.0, "accel_misalignment_arcsec": 5.0})
    errors = _constant_errors(spec, f_b, 6000)
    sigma = ImuNoise.from_spec(spec).accel_bias_prior_sigma_mps2(f_b)
    # 6000 draws: the sample sigma is within 3 % (3.3 of its 0.9 % standard error)
    np.testing.assert_allclose(errors.std(axis=0), sigma, rtol=0.03)


def test_level_navigation_grade_horizontal_axes_are_dominated_by_the_misalignment():
    spec = IMU_GRADES["navigation"].model_copy(update={"accel_scale_ppm": 10.0, "accel_misalignment_arcsec": 5.0})
    sigma_ug = ImuNoise.from_spec(spec).accel_bias_prior_sigma_mps2(np.array([0.0, 0.0, G])) / (G * 1e-6)
    arcsec = np.pi / 180.0 / 3600.0
    np.testing.assert_allclose(sigma_ug, [np.hypot(10.0, 5.0 * arcsec * 1e6)] * 2 + [np.hypot(10.0, 10.0)],
                               rtol=1e-3)
    assert sigma_ug[0] > 2.5 * spec.accel_bias_ug  # the turn-on bias alone was the prior before
