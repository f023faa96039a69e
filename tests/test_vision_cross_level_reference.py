"""The cross-level's design reference (``vision.cross_level_reference``, docs/vision.md): the
run's constant roll offset -- a lateral accelerometer bias through the roll -- estimated from
the measured cross-level, against analytic oracles (a bias added to a simulated IMU record, the
autocorrelation time of AR(1) series, the scatter of simulated tracks' run means)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from trackfusion.simulation.camera_laser import simulate_run
from trackfusion.simulation.tgms_vehicle import TgmsScenario, design_of
from trackfusion.simulation.vision_imu import GRAVITY_MPS2, ImuSpec, encoder_chainage_m, imu_signals
from trackfusion.track.rail_profile import rail_head
from trackfusion.vision.cross_level_reference import effective_samples, estimate_roll_offset
from trackfusion.vision.measure import FrameMeasurements, cross_level_of_poses
from trackfusion.vision.run import motion, reference_cross_level

HEAD = rail_head("60E1")
RATE_HZ, SPEED_MPS = 250.0, 30.0
BIAS_MPS2 = 1e-3 * GRAVITY_MPS2          # 1 mg on the accelerometer's y axis


def _poses(run, frames: slice) -> dict:
    """The true profile poses (F, 3) in the measuring frame ((y, z) [mm], roll [rad]): the vision
    without its noise, so the cross-level's error is the roll's alone."""
    return {k: np.column_stack([run.origin_v_m[k][frames] * 1e3, run.roll_v_rad[k][frames]]) for k in ("left", "right")}


@pytest.fixture(scope="module")
def biased_and_free():
    """1500 m filmed at 30 m/s (30 s of IMU lead-in, 10 s tail) through the tgms-vehicle line
    (transitions, an 800 m arc with 100 mm cant); the IMU with the datasheet's noise and gyro
    bias but no accelerometer bias, and the same record with 1 mg added to ``a_y``. Each run's
    motion (``trackfusion.vision.run.motion``), then both references."""
    sc = TgmsScenario(length_m=1500.0, lead_s=30.0, tail_s=10.0)
    lead, film = int(sc.lead_s * RATE_HZ), int(sc.length_m / SPEED_MPS * RATE_HZ)
    run = simulate_run(HEAD, n_frames=lead + film + int(sc.tail_s * RATE_HZ), speed_mps=SPEED_MPS, rate_hz=RATE_HZ,
                       seed=3, truth_frames=slice(0, 0))
    design = design_of(sc, SPEED_MPS * lead / RATE_HZ)
    gyro, accel = imu_signals(run.t_s, run.s_m, run.alignment_m + run.y_rel_m, run.vertical_profile_m + run.z_rel_m,
                              run.roll_rel_rad, design, ImuSpec(accel_bias_mg=0.0), np.random.default_rng(10))
    enc = encoder_chainage_m(run.s_m, np.random.default_rng(14))
    filmed = slice(lead, lead + film)
    pose = _poses(run, filmed)
    out = {"truth_mm": run.cross_level_m[filmed] * 1e3}
    for name, bias in (("free", 0.0), ("biased", BIAS_MPS2)):
        log = {"t_imu_s": run.t_s, "gyro_b": gyro, "accel_b": accel + np.array([0.0, bias, 0.0]), "encoder_m": enc,
               "t_frame_s": run.t_s[filmed]}
        mo = motion(log, design)
        m = FrameMeasurements(np.full(film, np.nan), cross_level_of_poses(pose["left"], pose["right"],
                                                                          mo["frame_roll_rad"]), {}, {}, pose, {})
        out[name] = {"mo": mo, "m": m, **{ref: reference_cross_level(mo, m, ref) for ref in ("design", "none")}}
    return out


def test_a_known_lateral_accelerometer_bias_is_given_back(biased_and_free):
    """The biased run's estimate is the bias within its stated uncertainty (measured: 0.999 +-
    0.069 mg for 1 mg); the two runs' estimates differ by ``b / g`` within 0.5 % (measured 0.33 %
    less: in the 800 m arc the specific force is 9.87 m/s^2, not g)."""
    est = {k: biased_and_free[k]["design"][0]["cross_level_reference"] for k in ("free", "biased")}
    b = est["biased"]
    assert b["applied"] and b["reference"] == "design"
    assert abs(b["lateral_accel_bias_mg"] - 1.0) < b["lateral_accel_bias_sd_mg"] < 0.08
    assert b["lateral_accel_bias_mps2"] == pytest.approx(b["lateral_accel_bias_mg"] * 1e-3 * GRAVITY_MPS2)
    assert b["roll_offset_deg"] == pytest.approx(np.degrees(b["roll_offset_urad"] * 1e-6))
    diff_urad = b["roll_offset_urad"] - est["free"]["roll_offset_urad"]
    assert diff_urad == pytest.approx(BIAS_MPS2 / GRAVITY_MPS2 * 1e6, rel=5e-3)


def test_referenced_cross_level_is_the_bias_free_run_s(biased_and_free):
    """With the offset taken off, the biased run's cross-level is the bias-free run's: within
    0.0076 mm of its referenced one (the bias's roll is b/|f|, not quite constant through the
    cant ramp) and within 0.0057 mm rms of its unreferenced one; without it the bias is there
    whole (1 mg: 1.5 mm)."""
    cl = {k: {ref: biased_and_free[k][ref][1].cross_level_m * 1e3 for ref in ("design", "none")}
          for k in ("free", "biased")}
    rms = lambda x: float(np.sqrt(np.mean(x * x)))  # noqa: E731
    assert np.abs(cl["biased"]["design"] - cl["free"]["design"]).max() < 0.01
    assert rms(cl["biased"]["design"] - cl["free"]["none"]) < 0.008
    assert np.mean(cl["biased"]["none"] - cl["free"]["none"]) == pytest.approx(1.5, abs=0.02)
    truth = biased_and_free["truth_mm"]
    assert rms(cl["biased"]["design"] - truth) < 0.1 < 1.4 < rms(cl["biased"]["none"] - truth)


def test_none_changes_nothing_and_the_relative_trajectory_stays(biased_and_free):
    """``none``: the motion and the cross-level are the inputs, bit for bit, the estimate only
    reported. ``design``: only the frames' roll (by the offset) and the cross-level change; eq.
    46's relative trajectory sees ``a_y - g phi``, where the bias and its roll offset cancel."""
    for k in ("free", "biased"):
        mo, m = biased_and_free[k]["mo"], biased_and_free[k]["m"]
        mo_n, m_n = biased_and_free[k]["none"]
        assert m_n is m and not mo_n["cross_level_reference"]["applied"]
        assert all(np.array_equal(mo_n[key], mo[key]) for key in mo)
        mo_d, _ = biased_and_free[k]["design"]
        offset = mo_d["cross_level_reference"]["roll_offset_urad"] * 1e-6
        assert np.array_equal(mo_d["r_t"], mo["r_t"])
        np.testing.assert_allclose(mo_d["frame_roll_rad"], mo["frame_roll_rad"] - offset, rtol=0, atol=1e-15)


def test_effective_samples_of_ar1_series():
    """``n / tau`` with ``tau = (1 + a) / (1 - a)`` for AR(1) series of coefficient ``a`` (20000
    samples; and with 10 % of them NaN): measured 4.1 / 5.4 % low (a = 0.5), 12.3 / 11.7 % high
    (a = 0.9: the sum stops at the first non-positive lag); white noise exact."""
    rng = np.random.default_rng(0)
    for a, tol in ((0.0, 0.01), (0.5, 0.06), (0.9, 0.15)):
        x = lfilter([1.0], [1.0, -a], rng.standard_normal(20000))
        gaps = np.where(rng.random(x.size) < 0.1, np.nan, x)
        for series in (x, gaps):
            n = np.isfinite(series).sum()
            assert effective_samples(series) / n == pytest.approx((1 - a) / (1 + a), rel=tol)


def test_stated_uncertainty_matches_the_scatter_of_simulated_tracks():
    """The simulator's cross-level irregularity (rms 1.5 mm, wavelengths above ~5 m) over 200 m,
    100 tracks, the roll true: the offset (the run's mean cross-level, which the reference would
    wrongly take off) over its stated standard deviation has an rms of 1.11 (the stated value is
    about 10 % low), and the offset's scatter is 219 urad (0.33 mm of cross-level: as large as a
    0.2 mg bias's 0.30 mm)."""
    n = int(200.0 / SPEED_MPS * RATE_HZ)
    z, offsets = [], []
    for seed in range(1, 101):
        run = simulate_run(HEAD, n_frames=n, speed_mps=SPEED_MPS, rate_hz=RATE_HZ, seed=seed, truth_frames=slice(0, 0))
        pose = _poses(run, slice(None))
        est = estimate_roll_offset(run.cross_level_m, pose["left"], pose["right"], run.roll_rel_rad)
        z.append(est.offset_rad / est.sd_rad)
        offsets.append(est.offset_rad)
    assert 1.0 < float(np.sqrt(np.mean(np.square(z)))) < 1.25
    assert 150e-6 < float(np.std(offsets)) < 250e-6


def test_an_outlying_frame_is_left_out_and_too_few_frames_give_no_estimate():
    """A frame 5 robust sigmas off the median does not move the offset; fewer than 3 frames:
    offset 0 and no standard deviation (``None`` in metrics.json)."""
    rng = np.random.default_rng(2)
    F = 400
    pose_l = np.column_stack([np.full(F, 750.0), rng.normal(0, 1.0, F), np.zeros(F)])
    pose_r = np.column_stack([np.full(F, -750.0), np.zeros(F), np.zeros(F)])
    roll = np.zeros(F)
    cl = cross_level_of_poses(pose_l, pose_r, roll)
    est = estimate_roll_offset(cl, pose_l, pose_r, roll)
    assert est.offset_rad == pytest.approx(np.mean(cl) / 1.5, rel=1e-12)
    bad = cl.copy()
    bad[7] = 0.05                                          # a 50 mm cross-level: a mis-fit
    assert estimate_roll_offset(bad, pose_l, pose_r, roll).offset_rad == pytest.approx(
        np.mean(np.delete(cl, 7)) / 1.5, rel=1e-12)
    few = np.full(F, np.nan)
    few[:2] = cl[:2]
    none = estimate_roll_offset(few, pose_l, pose_r, roll)
    assert none.offset_rad == 0.0 and not np.isfinite(none.sd_rad)
    doc = none.as_metrics("design")
    assert doc["roll_offset_sd_urad"] is None and doc["cross_level_mean_mm"] is None


def test_weight_against_the_datasheet_bias():
    """The share taken off is the minimum-variance combination of the datasheet's prior (0 +-
    sigma_b / g) and the estimate (+- sd): equal sigmas give a half; a precise estimate nearly
    all; no datasheet figure all; no estimate none. Its expected squared error is below both."""
    from trackfusion.vision.cross_level_reference import prior_weight
    assert prior_weight(2e-4, 0.2) == pytest.approx(0.5)
    assert prior_weight(2e-5, 0.2) == pytest.approx(1.0 / 1.01)
    assert prior_weight(2e-4, None) == 1.0
    assert prior_weight(float("nan"), 0.2) == 0.0
    rng = np.random.default_rng(5)
    roll_err = rng.normal(0.0, 2e-4, 200_000)         # the bias b / g, 0.2 mg
    estimate = roll_err + rng.normal(0.0, 3e-4, roll_err.size)  # plus the track's run mean
    w = prior_weight(3e-4, 0.2)
    mse = {k: float(np.mean(e**2)) for k, e in (("none", roll_err), ("whole", roll_err - estimate),
                                                 ("weighted", roll_err - w * estimate))}
    assert mse["weighted"] == pytest.approx((2e-4 * 3e-4) ** 2 / (2e-4**2 + 3e-4**2), rel=0.01)
    assert mse["weighted"] < min(mse["none"], mse["whole"])


def test_the_run_takes_off_the_weighted_offset(biased_and_free):
    """With the datasheet figure the run's roll moves by the weight times the estimate, as
    reported."""
    mo, m = biased_and_free["biased"]["mo"], biased_and_free["biased"]["m"]
    ref_mo, _ = reference_cross_level(mo, m, "design", accel_bias_mg=0.2)
    rep = ref_mo["cross_level_reference"]
    assert 0.0 < rep["weight"] < 1.0
    assert np.allclose(mo["frame_roll_rad"] - ref_mo["frame_roll_rad"], rep["roll_offset_applied_urad"] * 1e-6,
                       rtol=0, atol=1e-15)
    assert rep["roll_offset_applied_urad"] == pytest.approx(rep["weight"] * rep["roll_offset_urad"])
