"""Roll relative to the track, the relative-motion ODE (seed 001 eq. 46) and the centreline
traces (eq. 40) of the vision-inertial system, on simulated measuring-frame motion."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.simulation.camera_laser import simulate_run
from trackfusion.simulation.vision_imu import DesignCurve, ImuSpec, encoder_chainage_m, imu_signals
from trackfusion.track.rail_profile import rail_head
from trackfusion.vision.relative_motion import (band_trace, design_along, design_chainage_m, rail_centre_trace,
                                                relative_trajectory, tilt_roll_rad, zero_phase_roll)

HEAD = rail_head("60E1")
RATE_HZ = 250.0


@pytest.fixture(scope="module")
def curve_run():
    """40 s at 30 m/s: 20 m of straight, a 40 m transition into an 800 m curve with 100 mm cant;
    the measuring frame following the track's alignment and vertical profile and moving on the
    bogie; IMU signals error-free and with a tactical MEMS datasheet's errors."""
    n = int(40 * RATE_HZ)
    run = simulate_run(HEAD, n_frames=n, speed_mps=30.0, seed=4)
    curve = DesignCurve(transition_start_m=600.0)
    args = (run.t_s, run.s_m, run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m,
            run.roll_rel_rad, curve)
    ideal = imu_signals(*args, None, np.random.default_rng(0))
    noisy = imu_signals(*args, ImuSpec(), np.random.default_rng(1))
    rho, cant = curve.at(run.s_m)
    return run, curve, ideal, noisy, design_along(run.s_m, run.t_s, rho, cant)


def test_tilt_roll_of_a_steady_curve_is_exact():
    """Specific force of a body rolled by phi in a steady curve, ``R(-phi) (V^2 rho, g)``: the
    tilt with the design particle's acceleration taken out is phi itself."""
    phi = np.radians(np.array([-3.8, -1.0, 0.0, 0.7]))
    speed, rho = np.full(4, 30.0), np.full(4, 1 / 800)
    a_h = speed ** 2 * rho
    f = np.column_stack([np.zeros(4), np.cos(phi) * a_h + np.sin(phi) * 9.81,
                         -np.sin(phi) * a_h + np.cos(phi) * 9.81])
    assert np.allclose(tilt_roll_rad(f, speed, rho), phi, atol=1e-14)


def test_zero_phase_roll_follows_the_relative_roll_and_ignores_gyro_bias(curve_run):
    """Error-free signals: the relative roll (design cant removed) to 0.002 deg rms away from
    the record's ends (measured 0.0015); a 10 deg/h gyro bias changes it by under 0.002 deg (measured 0.0013; the
    symmetric low-pass passes its ramp); the datasheet's errors: a constant offset (the drawn
    accelerometer y bias over g: measured mean 0.0154 deg) and a varying part under 0.003 deg
    rms (measured 0.0022); the tilt of single samples is off by degrees on the bogie's
    vibration."""
    run, curve, (gyro, accel), (g_n, a_n), design = curve_run
    _, cant = curve.at(run.s_m)
    mid = slice(int(5 * RATE_HZ), -int(5 * RATE_HZ))

    def err_deg(g, a):
        roll = zero_phase_roll(run.t_s, g, a, design["speed_mps"], design["rho_h_per_m"]) - cant
        return np.degrees(roll - run.roll_rel_rad)[mid]

    e0 = err_deg(gyro, accel)
    assert np.sqrt(np.mean(e0 ** 2)) < 0.002
    biased = gyro + np.array([np.radians(10.0) / 3600, 0.0, 0.0])
    assert np.abs(err_deg(biased, accel) - e0).max() < 0.002
    e_n = err_deg(g_n, a_n)
    assert abs(e_n.mean()) < 0.02
    assert e_n.std() < 0.003, e_n.std()
    tilt = np.degrees(tilt_roll_rad(accel, design["speed_mps"], design["rho_h_per_m"]) - cant - run.roll_rel_rad)
    assert np.sqrt(np.mean(np.unwrap(np.radians(tilt[mid])) ** 2)) > 0.01


def test_eq40_traces_recover_the_centreline_from_true_poses(curve_run):
    """Eq. 40 with the true profile origins, relative roll and relative position is the
    centreline's alignment and vertical profile exactly (a round trip through the simulator)."""
    run = curve_run[0]
    o = {k: v * 1e3 for k, v in run.origin_v_m.items()}
    centre = rail_centre_trace(o["left"], o["right"], run.roll_rel_rad)
    r = np.column_stack([run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m])
    assert np.allclose(centre + r, np.column_stack([run.alignment_m, run.vertical_profile_m]), atol=1e-12)


def test_relative_trajectory_in_the_d1_band(curve_run):
    """Eq. 46 integrated forward from rest with the true relative roll and the encoder's
    chainage (0.05 % scale error): the measuring frame's position relative to the design track
    in the D1 band (3-25 m) to 0.03 mm rms, error-free (measured 0.010 / 0.020 mm lateral /
    vertical: the simulator's numerical derivatives) and with the datasheet's IMU errors
    (0.013 / 0.021 mm), away from the ends."""
    run, curve, (_, accel), (_, a_n), _ = curve_run
    enc = encoder_chainage_m(run.s_m, np.random.default_rng(3))
    rho, cant = curve.at(enc)
    design = design_along(enc, run.t_s, rho, cant)
    truth = np.column_stack([run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m])
    keep = (run.s_m > 150) & (run.s_m < run.s_m[-1] - 150)
    for a, tol_mm in ((accel, 0.03), (a_n, 0.03)):
        r = relative_trajectory(run.t_s, a, run.roll_rel_rad, design)
        for k in range(2):
            err = (band_trace(enc, r[:, k]) - band_trace(run.s_m, truth[:, k]))[keep] * 1e3
            assert np.sqrt(np.mean(err ** 2)) < tol_mm, (k, np.sqrt(np.mean(err ** 2)))


def test_curvature_matching_recovers_the_odometer_offset(curve_run):
    """An encoder 1.7 m ahead and 0.05 % long: matching the measured curvature (eq. 48, the yaw
    rate turned by the roll) to the design's puts it back to within 0.08 m at the transition's
    start (measured 0.058 m: the one shift leaves the scale error's 0.3 m over the record)."""
    run, curve, _, (g_n, a_n), _ = curve_run
    enc = run.s_m * 1.0005 + 1.7
    s = design_chainage_m(run.t_s, enc, g_n, a_n, curve.at)
    mid = run.s_m.size // 2
    assert abs(s[mid] - run.s_m[mid]) < 0.08, s[mid] - run.s_m[mid]
    assert abs(enc[mid] - run.s_m[mid]) > 1.7


def test_wear_near_glare_is_a_fault_gauge_stays():
    """A saturated glint beside the left stripe of one noise-free frame (at the image's left
    end, off the wear windows): that rail's wear is NaN and listed as ``glare_near_stripe``;
    the frame's gauge and the other frames' wear are numbers."""
    from trackfusion.simulation.camera_laser import StripeLook, default_units, expose, frame_images
    from trackfusion.vision.measure import measure_frames

    sims = default_units(1.435 / 2 + HEAD.gauge_point_mm()[0] / 1000)
    run = simulate_run(HEAD, n_frames=3, seed=2)
    imgs = {side: frame_images(sims[side], HEAD, run, StripeLook(), seed=5, noise=False)[0]
            for side in ("left", "right")}
    cam = sims["left"].unit.camera
    rows = np.nanmedian(np.argmax(imgs["left"][1], axis=0)[:60])
    yy, xx = np.mgrid[0:cam.height_px, 0:cam.width_px]
    glint = 600.0 * np.exp(-0.5 * (((xx - 10) / 12) ** 2 + ((yy - rows - 20) / 5) ** 2))
    imgs["left"][1] = expose(imgs["left"][1].astype(np.float32) - StripeLook().ambient_dn + glint,
                             StripeLook(blur_sigma_px=0.0), None)
    m = measure_frames({k: s.unit for k, s in sims.items()}, HEAD, imgs, run.roll_rel_rad)
    assert m.faults == [(1, "left", "glare_near_stripe")]
    assert np.isnan(m.vertical_wear_mm["left"][1]) and np.isnan(m.side_wear_mm["left"][1])
    assert np.isfinite(m.gauge_m).all() and np.isfinite(m.vertical_wear_mm["right"]).all()
    assert np.isfinite(m.vertical_wear_mm["left"][[0, 2]]).all()
