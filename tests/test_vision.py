"""Vision system: rail-head profiles, camera-laser geometry, stripe centres, calibration, per-frame
gauge / cross-level / wear and faults (seed 001 sections 4-6 and 10)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from trackfusion.cli import main
from trackfusion.errors import TrackGeometryError, VisionError
from trackfusion.simulation.camera_laser import (StripeLook, default_units, frame_images, render_stripe,
                                                 section_points_v, simulate_run, stripe_curve_px)
from trackfusion.simulation.vision_calibration import write_calibration_set
from trackfusion.track.rail_profile import (RAIL_54E1, RAIL_60E1, rail_head, running_top_and_gauge_point,
                                            sample_unworn_mm, sample_worn_mm, segment_normals,
                                            signed_distance_mm)
from trackfusion.vision import profile_fit
from trackfusion.vision.calibration import calibrate_folder, load_calibration
from trackfusion.vision.measure import measure_frames
from trackfusion.vision.stripe import stripe_centres

HEAD = rail_head("60E1")
HALF_M = 1.435 / 2 + HEAD.gauge_point_mm()[0] / 1000


def test_60e1_from_its_published_arcs_has_the_72_mm_head():
    # R300/R80/R13 with tangent points 20.456 and 52.053 mm apart and 1:20 flanks: tangency alone
    # puts the top of the flanks 72.0 mm apart, the drawing's head width
    assert 2 * HEAD.half_width_mm == pytest.approx(72.0, abs=0.002)
    assert 2 * rail_head(RAIL_54E1).half_width_mm == pytest.approx(70.0, abs=0.002)


@pytest.mark.parametrize("spec", [RAIL_60E1, RAIL_54E1])
def test_arcs_are_tangent_and_the_gauge_point_is_on_the_corner_arc(spec):
    head = rail_head(spec)
    for a, b in zip(head.arcs[:-1], head.arcs[1:]):
        assert a.a1_rad == pytest.approx(b.a0_rad)            # same normal at the joint
        pa = np.array(a.centre_mm) + a.radius_mm * np.array([np.sin(a.a1_rad), np.cos(a.a1_rad)])
        pb = np.array(b.centre_mm) + b.radius_mm * np.array([np.sin(b.a0_rad), np.cos(b.a0_rad)])
        np.testing.assert_allclose(pa, pb, atol=1e-9)          # same point
    q_g, z_g = head.gauge_point_mm()
    (cq, cz), r = head.arcs[4].centre_mm, head.arcs[4].radius_mm
    assert z_g == -14.0
    assert q_g == pytest.approx(cq + np.sqrt(r * r - (z_g - cz) ** 2), abs=1e-9)
    assert head.arcs[2].centre_mm == (0.0, -spec.crown_radius_mm)


def test_signed_distance_is_zero_on_the_profile_and_its_gradient_is_the_normal():
    pts = sample_unworn_mm(HEAD, 0.05)
    d, nq, nz = signed_distance_mm(HEAD, pts[:, 0], pts[:, 1])
    assert np.nanmax(np.abs(d)) < 1e-9 and not np.isnan(d).any()
    n = segment_normals(pts)                                  # finite differences, O(step / R13)
    inner = slice(3, -3)
    np.testing.assert_allclose(np.column_stack([nq, nz])[inner], n[inner], atol=5e-3)
    off = pts + 0.5 * np.column_stack([nq, nz])
    d2, _, _ = signed_distance_mm(HEAD, off[:, 0], off[:, 1])
    np.testing.assert_allclose(d2, 0.5, atol=1e-9)


def test_worn_profile_has_the_wear_it_was_given():
    worn = sample_worn_mm(HEAD, vertical_wear_mm=1.5, side_wear_mm=2.0, step_mm=0.01)
    near_centre = np.abs(worn[:, 0]) < 0.01
    assert worn[near_centre, 1].mean() == pytest.approx(-1.5, abs=1e-3)
    gauge_side = (worn[:, 0] > 20) & (np.abs(worn[:, 1] + 14.0) < 0.01)
    assert worn[gauge_side, 0].mean() == pytest.approx(HEAD.gauge_point_mm()[0] - 2.0, abs=2e-3)
    # the gauge point 14 mm below the worn running surface (at -1.5 mm)
    top, gp = running_top_and_gauge_point(worn)
    assert top == pytest.approx(-1.5, abs=1e-9) and gp[1] == pytest.approx(-15.5)
    with pytest.raises(TrackGeometryError):
        sample_worn_mm(HEAD, vertical_wear_mm=-1.0)


def test_fit_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    pts = sample_unworn_mm(HEAD, 1.0)
    pts = pts + rng.normal(0, 0.3, pts.shape)
    for side in ("left", "right"):
        pose = np.array([[-700.0 if side == "right" else 700.0, 3.0, 0.02]])
        s = profile_fit.SIDE_SIGN[side]
        c, sn = np.cos(pose[0, 2]), np.sin(pose[0, 2])
        y = pose[0, 0] + c * s * pts[:, 0] - sn * pts[:, 1]
        z = pose[0, 1] + sn * s * pts[:, 0] + c * pts[:, 1]
        d0, J = profile_fit._residuals(HEAD, y[None], z[None], pose, side)
        for k, h in enumerate((1e-6, 1e-6, 1e-9)):
            p = pose.copy()
            p[0, k] += h
            d1, _ = profile_fit._residuals(HEAD, y[None], z[None], p, side)
            np.testing.assert_allclose((d1 - d0)[0] / h, J[0, :, k], atol=2e-3)


def test_laser_plane_intersection_round_trip():
    unit = default_units(HALF_M)["right"].unit
    rng = np.random.default_rng(1)
    a, b, c, d = unit.plane_v
    yz = np.column_stack([rng.uniform(-0.78, -0.72, 50), rng.uniform(-0.03, 0.005, 50)])
    x = -(b * yz[:, 0] + c * yz[:, 1] + d) / a
    p_v = np.column_stack([x, yz])
    uv = unit.camera.project(unit.to_camera(p_v))
    np.testing.assert_allclose(unit.pixels_to_vehicle(uv), p_v, atol=1e-9)


def test_stripe_centre_is_sub_pixel_on_a_rendered_gaussian_stripe():
    cam = default_units(HALF_M)["left"].unit.camera
    u = np.linspace(-5, 650, 400)
    v = 150.3 + 0.15 * u + 8 * np.sin(u / 60)                 # a gently curved line, sub-pixel rows
    look = StripeLook(speckle_contrast=0.0)
    img = render_stripe(cam, np.column_stack([u, v]), np.ones(len(u)), look)
    from trackfusion.simulation.camera_laser import expose
    rows = stripe_centres(expose(img, look, None))
    cols = np.arange(cam.width_px)
    truth = np.interp(cols, u, v)
    ok = np.isfinite(rows)
    ok[:3] = ok[-3:] = False                                  # the blur's image border
    assert ok.mean() > 0.98
    assert np.abs(rows[ok] - truth[ok]).max() < 0.05          # 8-bit rounding, no noise
    rng = np.random.default_rng(2)
    noisy = stripe_centres(expose(img, StripeLook(), rng))
    ok = np.isfinite(noisy)
    assert np.std(noisy[ok] - truth[ok]) < 0.1


def test_no_stripe_no_centres():
    dark = np.full((40, 30), 12, np.uint8)
    assert np.isnan(stripe_centres(dark)).all()


def _frames(n, noise, wear=None, seed=1):
    sims = default_units(HALF_M)
    run = simulate_run(HEAD, n_frames=n, seed=seed, wear=wear)
    imgs, flags = {}, {}
    for i, side in enumerate(("left", "right")):
        imgs[side], flags[side] = frame_images(sims[side], HEAD, run, StripeLook(), seed=10 + i, noise=noise)
    return sims, run, imgs, flags


def test_gauge_and_cross_level_of_noise_free_frames():
    sims, run, imgs, _ = _frames(6, noise=False)
    m = measure_frames({k: s.unit for k, s in sims.items()}, HEAD, imgs, run.roll_rel_rad)
    assert m.faults == []
    assert np.abs(m.gauge_m - run.gauge_m).max() < 1e-5
    assert np.abs(m.cross_level_m - run.cross_level_m).max() < 1e-5
    for side in ("left", "right"):
        np.testing.assert_allclose(m.pose[side][:, :2], run.origin_v_m[side] * 1e3, atol=0.005)
        assert np.abs(m.vertical_wear_mm[side]).max() < 0.01
        assert np.abs(m.side_wear_mm[side]).max() < 0.01


def test_wear_of_noise_free_worn_frames():
    wear = {"start_m": -10.0, "end_m": 100.0, "vertical_mm": 1.0, "side_mm": 2.0, "side_rail": "left"}
    sims, run, imgs, _ = _frames(4, noise=False, wear=wear)
    m = measure_frames({k: s.unit for k, s in sims.items()}, HEAD, imgs, run.roll_rel_rad)
    assert m.faults == []
    np.testing.assert_allclose(m.vertical_wear_mm["left"], 1.0, atol=0.05)
    np.testing.assert_allclose(m.side_wear_mm["left"], 2.0, atol=0.05)
    np.testing.assert_allclose(m.side_wear_mm["right"], 0.0, atol=0.05)
    assert np.abs(m.gauge_m - run.gauge_m).max() < 5e-5


def test_missing_stripe_frames_are_faults_not_numbers():
    sims, run, imgs, _ = _frames(5, noise=False)
    imgs["right"][2] = 12                                        # laser dropout on one camera
    imgs["left"][4] = 12
    m = measure_frames({k: s.unit for k, s in sims.items()}, HEAD, imgs, run.roll_rel_rad, first_frame=100)
    assert (102, "right", "missing_stripe") in m.faults and (104, "left", "missing_stripe") in m.faults
    assert list(m.fault_frames) == [102, 104]
    assert np.isnan(m.gauge_m[[2, 4]]).all() and np.isfinite(m.gauge_m[[0, 1, 3]]).all()
    assert np.isnan(m.cross_level_m[2]) and np.isnan(m.vertical_wear_mm["left"][4])


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calib")
    sim = default_units(HALF_M)["left"]
    write_calibration_set(sim, folder / "left", n_poses=16, seed=3)
    results = calibrate_folder(folder, folder / "calib.yaml")
    return sim, folder, results


def test_calibration_recovers_the_camera_and_the_laser_plane(calibration):
    sim, folder, results = calibration
    (r,) = results
    assert r.views == 16 and r.reprojection_rms_px < 0.1
    est = load_calibration(folder / "calib.yaml")["left"]
    true = sim.unit
    np.testing.assert_allclose(est.camera.K[[0, 1], [0, 1]], true.camera.K[[0, 1], [0, 1]], rtol=0.01)
    # what matters: rail points seen by the true unit, reconstructed with the calibrated one
    pts = sample_unworn_mm(HEAD, 0.3)
    p_v, n_v, lam = section_points_v(sim, pts, segment_normals(pts), np.array([HALF_M, 0.0]), np.arctan(1 / 40))
    uv, _ = stripe_curve_px(sim, p_v, n_v, lam)
    ok = np.isfinite(uv[:, 0])
    err_mm = (est.pixels_to_vehicle(uv[ok]) - p_v[ok])[:, 1:] * 1e3
    assert np.abs(err_mm).max() < 0.1
    plane_err_mm = np.abs(p_v[ok] @ est.plane_v[:3] + est.plane_v[3]) * 1e3
    assert plane_err_mm.max() < 0.1
    assert r.laser_plane_rms_mm < 0.05


def test_calibrate_vision_cli_bad_input_exit_2(tmp_path, capsys):
    assert main(["calibrate-vision", str(tmp_path), "--out", str(tmp_path / "c.yaml")]) == 2
    assert "no calibration_set.yaml" in capsys.readouterr().err
    (tmp_path / "calibration_set.yaml").write_text("side: left\nviews: []\n")
    assert main(["calibrate-vision", str(tmp_path), "--out", str(tmp_path / "c.yaml")]) == 2
    assert not (tmp_path / "c.yaml").exists()
    with pytest.raises(VisionError):
        load_calibration(tmp_path / "missing.yaml")


def test_bad_frames_input_is_named_before_computing():
    sims, run, imgs, _ = _frames(2, noise=False)
    units = {k: s.unit for k, s in sims.items()}
    with pytest.raises(VisionError, match="left images: 2 frames, roll series has 3"):
        measure_frames(units, HEAD, imgs, np.zeros(3))
    with pytest.raises(VisionError, match="left images: 320 x 400 px"):
        measure_frames(units, HEAD, {**imgs, "left": imgs["left"][:, :, :320]}, run.roll_rel_rad)
    with pytest.raises(VisionError, match="no right unit"):
        measure_frames({"left": units["left"]}, HEAD, imgs, run.roll_rel_rad)


def test_madgwick_roll_in_a_steady_canted_curve():
    from trackfusion.simulation.vision_imu import DesignCurve, imu_signals
    from trackfusion.vision.madgwick import madgwick_roll
    t = np.arange(0, 40, 1 / 250)
    v = 30.0
    s = v * t
    zero = np.zeros_like(t)
    curve = DesignCurve(transition_start_m=-1e3, radius_m=800.0, cant_mm=100.0)   # all arc
    gyro, accel = imu_signals(t, s, zero, zero, zero, curve, None, np.random.default_rng(0))
    rho, cant = curve.at(s)
    roll = madgwick_roll(t, gyro, accel, np.full_like(t, v), rho, beta=0.01)
    # the normalised gradient step leaves a limit cycle of beta * dt (4e-5 rad): its mean
    assert abs(np.mean(roll[-250:] - cant[-250:])) < np.radians(0.001)
    assert np.abs(roll[-250:] - cant[-250:]).max() < 0.01 / 250 * 1.2
    # without the track's acceleration the filter takes the specific force for gravity: the
    # centripetal acceleration adds atan(V^2 / (R g)) to its roll
    plain = madgwick_roll(t, gyro, accel, np.full_like(t, v), rho, beta=0.01, correct_track_acceleration=False)
    expected = cant[-1] + np.arctan(v * v / 800.0 / 9.81)
    assert abs(np.mean(plain[-250:]) - expected) < np.radians(0.002)


def test_short_islands_off_the_line_are_dropped():
    from trackfusion.vision.measure import continuous_segments
    y = np.tile(np.linspace(0.0, 60.0, 300), (2, 1))
    z = np.zeros_like(y)
    z[0, 100:106] -= 3.0                      # a glare island 3 mm off the line, 6 columns
    valid = np.ones_like(y, bool)
    valid[1, 150] = False                     # a missing column splits the line, both halves stay
    keep = continuous_segments(y, z, valid)
    assert not keep[0, 100:106].any() and keep[0, :100].all() and keep[0, 106:].all()
    assert keep[1].sum() == 299


def test_forked_batches_give_the_same_figures():
    from trackfusion.vision.measure import measure_run
    sims, run, imgs, _ = _frames(8, noise=True)
    units = {k: s.unit for k, s in sims.items()}
    threads = cv2.getNumThreads()
    one = measure_run(units, HEAD, imgs, run.roll_rel_rad, batch=4, workers=1)
    two = measure_run(units, HEAD, imgs, run.roll_rel_rad, batch=4, workers=2)
    np.testing.assert_array_equal(one.gauge_m, two.gauge_m)
    assert one.faults == two.faults
    assert cv2.getNumThreads() == threads  # OpenCV's threads off only while measuring


def test_glare_columns_give_no_centres():
    sims = default_units(HALF_M)
    cam = sims["left"].unit.camera
    u = np.linspace(-5, 650, 400)
    v = 200.0 + 0.1 * u
    look = StripeLook(speckle_contrast=0.0)
    img = render_stripe(cam, np.column_stack([u, v]), np.ones(len(u)), look)
    yy, xx = np.mgrid[0:cam.height_px, 0:cam.width_px]
    img += 600.0 * np.exp(-0.5 * (((xx - 300) / 15) ** 2 + ((yy - 215) / 6) ** 2))   # a sun glint
    from trackfusion.simulation.camera_laser import expose
    rows = stripe_centres(expose(img, look, None))
    assert np.isnan(rows[280:321]).all()
    assert np.isfinite(rows[:250]).all() and np.isfinite(rows[350:-3]).all()
