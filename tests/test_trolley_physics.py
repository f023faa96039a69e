"""The trolley's physics: wheelbase filtering, curve sagitta, cant, stationary IMU."""

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.rotations import ypr_from_R
from trackfusion.simulation.motion import Hold, Move, compile_plan
from trackfusion.simulation.trolley import TrolleyGeometry, TrolleyKinematics

HALF_GAUGE = 0.7175
ORIGIN = geodesy.Origin(45.0, 8.0, 300.0)


class StraightRails:
    """Rails along east through the origin of n; vertical sinusoid on both rails; optional cant."""

    def __init__(self, wavelength_m=5.0, amplitude_m=0.0, cant_m=0.0):
        self.wavelength_m, self.amplitude_m, self.cant_m = wavelength_m, amplitude_m, cant_m

    def rail_points_n(self, s, side):
        s = np.asarray(s, float)
        sign = 1.0 if side == "left" else -1.0
        z = self.amplitude_m * np.sin(2 * np.pi * s / self.wavelength_m) + (sign > 0) * self.cant_m
        return np.column_stack([s, np.full_like(s, sign * HALF_GAUGE), z])


class CircleRails:
    """Rails on concentric circles (centreline radius R, curving left)."""

    def __init__(self, radius_m):
        self.R = radius_m

    def rail_points_n(self, s, side):
        off = HALF_GAUGE if side == "left" else -HALF_GAUGE
        th = np.asarray(s, float) / self.R
        rr = self.R - off
        return np.column_stack([rr * np.sin(th), self.R - rr * np.cos(th), np.zeros_like(th)])


def _pose(rails, geometry, s):
    kin = TrolleyKinematics.build(rails, geometry, ORIGIN, s.min() - 1, s.max() + 1)
    return kin.pose_at_chainage(s)


@pytest.mark.parametrize("wavelength_m", [1.3, 2.0, 3.0, 5.0, 12.0])
def test_wheelbase_filters_vertical_irregularity_as_cos_pi_l_over_lambda(wavelength_m):
    """The frame height follows A cos(pi l / lambda): seed 000's two-point transfer function."""
    l = 1.0
    geometry = TrolleyGeometry(wheelbase_m=l, lever_arm_imu_v=(0.0, 0.0, 0.0))
    s = np.linspace(20, 40, 4001)
    pos, _ = _pose(StraightRails(wavelength_m, 0.002), geometry, s)
    # least-squares amplitude of the sinusoid in the height of the IMU (at the frame origin)
    basis = np.column_stack([np.sin(2 * np.pi * s / wavelength_m), np.cos(2 * np.pi * s / wavelength_m)])
    coef = np.linalg.lstsq(basis, pos[:, 2], rcond=None)[0]
    gain = np.hypot(*coef) / 0.002
    # exact up to the second-order effect of the rail slope on a rigid chord (slope^2 ~ 1e-4 here)
    assert gain == pytest.approx(abs(np.cos(np.pi * l / wavelength_m)), abs=1e-5)


def test_chord_midpoint_in_a_curve_sits_a_sagitta_inside_the_rail():
    R, l = 200.0, 1.2
    geometry = TrolleyGeometry(wheelbase_m=l, lever_arm_imu_v=(0.0, 0.0, 0.0))
    s = np.array([30.0, 50.0])
    pos, R_nb = _pose(CircleRails(R), geometry, s)
    r_rail = R - HALF_GAUGE  # the left (reference) rail is the inner one
    radial = np.hypot(pos[:, 0], pos[:, 1] - R)
    # the wheels are a rigid wheelbase apart: the chord of the rail is l, its sagitta r - sqrt(r^2 - l^2/4)
    assert r_rail - radial == pytest.approx(np.full(2, r_rail - np.sqrt(r_rail**2 - (l / 2) ** 2)), abs=1e-12)
    yaw = ypr_from_R(R_nb)[0]
    assert yaw == pytest.approx(s / R, abs=1e-9)  # the chord is parallel to the tangent at its middle


def test_raised_rail_gives_roll_atan_rise_over_horizontal_spacing():
    cant = 0.12
    geometry = TrolleyGeometry(wheelbase_m=1.0, lever_arm_imu_v=(0.0, 0.0, 0.0))
    _, R_nb = _pose(StraightRails(cant_m=cant), geometry, np.array([10.0]))
    roll = ypr_from_R(R_nb)[2]
    # the fixture lifts the left (reference) rail straight up: left side up is positive roll
    assert roll[0] == pytest.approx(np.arctan(cant / (2 * HALF_GAUGE)), abs=1e-12)


@pytest.mark.parametrize("lat_deg", [0.0, 45.0, 90.0])
def test_stationary_imu_measures_gravity_and_earth_rate(lat_deg):
    origin = geodesy.Origin(lat_deg, 8.0, 300.0)
    geometry = TrolleyGeometry(wheelbase_m=1.0, lever_arm_imu_v=(0.0, -HALF_GAUGE, 0.25))
    kin = TrolleyKinematics.build(StraightRails(), geometry, origin, -2.0, 2.0)
    plan = compile_plan(0.0, [Hold(10.0)])
    t = np.arange(1, 2001) / 200.0
    gyro, accel = kin.imu_interval_means(t, 1 / 200.0, plan)
    gamma = geodesy.normal_gravity_mps2(np.radians(lat_deg), 300.25)
    assert np.linalg.norm(accel, axis=1) == pytest.approx(np.full(t.size, gamma), rel=1e-9)
    assert accel[:, :2] == pytest.approx(np.zeros((t.size, 2)), abs=1e-9 * gamma)
    assert np.linalg.norm(gyro, axis=1) == pytest.approx(np.full(t.size, geodesy.OMEGA_IE_RADPS), rel=1e-9)
    # the body is level and points east: the gyro sees (0, w cos(lat), w sin(lat)) (east, north, up)
    expected = geodesy.earth_rate_n(origin)
    assert gyro == pytest.approx(np.tile(expected, (t.size, 1)), abs=1e-9 * geodesy.OMEGA_IE_RADPS)


def test_moving_state_is_consistent_with_its_derivatives():
    geometry = TrolleyGeometry()
    rails = StraightRails(7.0, 0.003, 0.05)
    kin = TrolleyKinematics.build(rails, geometry, ORIGIN, 0.0, 60.0)
    plan = compile_plan(5.0, [Hold(2.0), Move(50.0, 1.5, 0.4), Hold(2.0)])
    t = np.linspace(0.0, plan.end_s, 200_001)
    st = kin.state(t, plan)
    dt = t[1] - t[0]
    assert np.abs(np.gradient(st["pos_n"], dt, axis=0) - st["vel_n"])[1:-1].max() < 1e-6
    assert np.abs(np.gradient(st["vel_n"], dt, axis=0) - st["acc_n"])[1:-1].max() < 1e-4
