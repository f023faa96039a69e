"""A navigation-grade IMU standing still for an hour, smoothed with zero-velocity and
zero-rate updates only: it must stay put (< 1 mm) and find north by gyrocompassing; leaving
the Earth rate out of the model must break that (DESIGN.md section 3)."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.fusion.preintegration import ImuNoise
from trackfusion.fusion.problem import FusionProblem, TrolleyFrame
from trackfusion.fusion.settings import FactorSettings, KeyframeSettings
from trackfusion.fusion.smoother import smooth
from trackfusion.rotations import R_from_ypr, ypr_from_R
from trackfusion.sensors.imu import IMU_GRADES
from trackfusion.simulation.imu import simulate_imu

ORIGIN = geodesy.Origin(47.0, 8.0, 400.0)
YAW, PITCH, ROLL = np.radians([63.0, 0.8, -1.5])
DURATION_S = 3600.0
RATE_HZ = 100.0


def stationary_imu(seed: int = 3):
    """One hour of a still, tilted navigation-grade IMU (100 Hz) with its drawn errors."""
    spec = IMU_GRADES["navigation"].model_copy(update={"rate_hz": RATE_HZ})
    t = np.arange(1, int(DURATION_S * RATE_HZ) + 1) / RATE_HZ
    R_nb = R_from_ypr(YAW, PITCH, ROLL)
    gyro = np.tile(R_nb.T @ geodesy.earth_rate_n(ORIGIN), (t.size, 1))
    accel = np.tile(R_nb.T @ -geodesy.gravity_n(np.zeros(3), ORIGIN), (t.size, 1))
    imu, drawn = simulate_imu(t, gyro, accel, spec, np.random.default_rng(seed))
    return imu, spec, drawn


def smooth_stationary(earth_rate: bool):
    imu, spec, _ = stationary_imu()
    factors = FactorSettings(nhc=False, odometer=False, gnss=False, inclinometer=False,
                             imu={"earth_rate": earth_rate})
    problem = FusionProblem(imu=imu, imu_noise=ImuNoise.from_spec(spec),
                            imu_gyro_bias_deg_per_h=spec.gyro_bias_deg_per_h, origin=ORIGIN,
                            trolley=TrolleyFrame.from_angles((0, 0, 0), (0, 0, 0), 1.0),
                            static_intervals_s=[(imu.t_s[0], imu.t_s[-1])], factors=factors,
                            keyframes=KeyframeSettings(spacing_s=1.0))
    res = smooth(problem)
    drift_m = np.max(np.linalg.norm(res.pos_n - res.pos_n[0], axis=1))
    yaw, _, _ = ypr_from_R(res.R_nb)
    yaw_err = np.angle(np.exp(1j * (yaw - YAW)))
    return res, drift_m, yaw_err


@pytest.fixture(scope="module")
def with_earth_rate():
    return smooth_stationary(True)


def test_stays_within_a_millimetre(with_earth_rate):
    _, drift_m, _ = with_earth_rate
    assert drift_m < 1e-3


def heading_bound_rad() -> float:
    """Gyrocompassing accuracy: 3 x gyro bias (0.01 deg/h) / horizontal Earth rate [rad]."""
    horizontal = geodesy.OMEGA_IE_RADPS * np.cos(np.radians(ORIGIN.lat_deg))
    return 3 * np.radians(0.01 / 3600) / horizontal


def test_heading_by_gyrocompassing(with_earth_rate):
    """Gyro bias 0.01 deg/h against 15.04 cos(47) deg/h of horizontal Earth rate: heading good to
    about 1e-3 rad over the whole hour, and the yaw sigma says so."""
    res, _, yaw_err = with_earth_rate
    assert np.max(np.abs(yaw_err)) < heading_bound_rad()
    assert res.alignment.method == "gyrocompass"
    assert np.all(res.sigma_att_rad[:, 2] < heading_bound_rad())


def test_fails_without_earth_rate(with_earth_rate):
    """The same data with the Earth rate left out of the model: the zero-rate updates force the
    10 deg/h of measured Earth rate into the gyro bias, far outside its 0.01 deg/h prior; the
    heading check above fails and the fit's cost is two orders of magnitude higher."""
    res_ok, _, _ = with_earth_rate
    res, _, yaw_err = smooth_stationary(False)
    assert np.max(np.abs(yaw_err)) > heading_bound_rad()
    assert res.final_cost > 30 * res_ok.final_cost
    assert np.degrees(np.abs(res.gyro_bias_radps).max()) * 3600 > 1.0
