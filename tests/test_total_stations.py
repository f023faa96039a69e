"""Total-station surveys: time synchronisation, seed-003 registration, free-station resection,
polar covariance, mis-lock run logic (fast, synthetic data)."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.errors import RegistrationError
from trackfusion.registration import timesync as ts
from trackfusion.registration.mislock import classify_flags
from trackfusion.registration.polar import StationSetup, n_to_polar, polar_to_n
from trackfusion.registration.seed_method import overlap_axes, register_seed
from trackfusion.registration.polar import DEFAULT_REFRACTION_K
from trackfusion.registration.stations import (ARCSEC, ControlReading, InstrumentPrecision, StationSetupConfig,
                                              readings_to_n, resect, station_setup)

ORIGIN = geodesy.Origin(22.93, 112.87, 25.0)
PRECISION = InstrumentPrecision(angle_sigma_arcsec=0.5, distance_sigma_mm=1.0, distance_ppm=1.5)


def _speed_profile(t):
    """Trolley speed [m/s]: hold, ramp up, cruise with a slow wobble, stop, hold, ramp again."""
    v = np.interp(t, [0, 20, 23, 120, 123, 150, 153, 260, 263, 300],
                  [0, 0, 0.8, 0.8, 0, 0, 0.6, 0.6, 0, 0])
    return v * (1 + 0.05 * np.sin(2 * np.pi * t / 37.0))


def _survey(offset_s, rate_hz=10.0, noise_m=0.0, seed=0):
    """Odometer (100 Hz, IMU clock) and a station's prism points on a straight line, read on the
    station's own clock ``t_station = t_imu + offset_s``."""
    t_odo = np.arange(0, 300, 0.01)
    d_odo = np.concatenate([[0], np.cumsum(0.5 * (_speed_profile(t_odo[1:]) + _speed_profile(t_odo[:-1])) * 0.01)])
    t_station = np.arange(np.ceil((5 + offset_s) * rate_hz), np.floor((295 + offset_s) * rate_hz)) / rate_hz
    d = np.interp(t_station - offset_s, t_odo, d_odo)
    pos = np.column_stack([-d, np.full_like(d, 3.0), 0.0035 * d])
    pos += np.random.default_rng(seed).normal(0, noise_m, pos.shape)
    return t_odo, d_odo, t_station, pos


@pytest.mark.parametrize("offset", [2.8137, -0.8146, 0.0])
def test_time_sync_recovers_injected_offset(offset):
    t_odo, d_odo, t_st, pos = _survey(offset)
    r = ts.synchronise("TS01", t_st, pos, t_odo, d_odo)
    assert abs(r.offset_s - offset) < 0.01 * 0.1  # 1 % of the 10 Hz sample interval
    assert r.r_max > 0.99
    assert r.lags_s.size == r.r.size and np.nanmax(r.r) == pytest.approx(r.r_max, abs=1e-3)


def test_time_sync_with_noise_keeps_within_a_few_ms():
    t_odo, d_odo, t_st, pos = _survey(1.234, noise_m=0.003)
    r = ts.synchronise("TS02", t_st, pos, t_odo, d_odo)
    assert abs(r.offset_s - 1.234) < 0.02
    assert 0.8 < r.r_max < 0.999


def test_station_without_motion_is_refused():
    t_odo = np.arange(0, 300, 0.01)
    d_odo = np.where(t_odo < 200, 0.0, 0.8 * (t_odo - 200))  # moves only after 200 s
    t_st = np.arange(20, 150, 0.1)
    pos = np.tile([-14.0, 3.0, 0.0], (t_st.size, 1)) + np.random.default_rng(1).normal(0, 0.003, (t_st.size, 3))
    with pytest.raises(RegistrationError, match="TS01: the trolley did not move"):
        ts.synchronise("TS01", t_st, pos, t_odo, d_odo)


def test_weak_correlation_is_refused():
    t_odo, d_odo, t_st, pos = _survey(0.5)
    rng = np.random.default_rng(3)
    pos = pos[rng.permutation(pos.shape[0])]  # a station reporting unrelated points
    with pytest.raises(RegistrationError, match="below the limit 0.8"):
        ts.synchronise("TS03", t_st, pos, t_odo, d_odo)


def test_ambiguous_peak_is_refused():
    """A periodic speed profile correlates equally well one period later."""
    t_odo = np.arange(0, 400, 0.01)
    v = 0.5 + 0.3 * np.sign(np.sin(2 * np.pi * t_odo / 6.0))
    d_odo = np.concatenate([[0], np.cumsum(v[1:] * 0.01)])
    t_st = np.arange(50, 350, 0.1)
    d = np.interp(t_st - 0.3, t_odo, d_odo)
    pos = np.column_stack([d, 0 * d, 0 * d])
    with pytest.raises(RegistrationError, match="ambiguous"):
        ts.synchronise("TS01", t_st, pos, t_odo, d_odo)


# --- seed 003 registration ----------------------------------------------------------------------

def _curve(s):
    """An arch-shaped straight track running west (seed 003's bridge), with short waves."""
    e = -s
    n = 0.004 * np.sin(s / 17.0)
    u = 1.995 * (1 - ((s - 570) / 570) ** 2) + 0.002 * np.sin(s / 9.0)
    return np.column_stack([e, n, u])


def test_seed_registration_recovers_rotation_and_translation_exactly():
    s_ref = np.arange(0, 700, 0.08)
    s_tgt = np.arange(500, 1120, 0.08)
    ref = _curve(s_ref)
    centre = np.array([-1152.0, -6.0, 1.8])
    theta, dz, dy = 4.0 * ARCSEC, -0.0092, 0.0033
    true_tgt = _curve(s_tgt)
    # the target station's frame: its points are the truth rotated by -theta and shifted back, in
    # the method's frame (X: the reference chord over the overlap grid 500..699.75 m)
    axes = overlap_axes(s_ref, ref, 500.0, 699.75)
    local = (true_tgt - centre) @ axes.T
    m, y, h = local[:, 0], local[:, 1] - dy, local[:, 2] - dz
    c, sn = np.cos(-theta), np.sin(-theta)
    seen = centre + np.column_stack([m * c - h * sn, y, m * sn + h * c]) @ axes
    reg = register_seed(s_ref, ref, s_tgt, seen, centre)
    assert reg.theta_rad == pytest.approx(theta, abs=1e-12)
    assert reg.dz_m == pytest.approx(dz, abs=1e-9)
    assert reg.dy_m == pytest.approx(dy, abs=1e-12)
    np.testing.assert_allclose(reg.apply(seen), true_tgt, atol=1e-9)


# --- free-station resection -----------------------------------------------------------------------

CONTROL = {"CP1": (40.0, 25.0, 2.1), "CP2": (-60.0, 30.0, 1.2), "CP3": (-20.0, -45.0, 3.4), "CP4": (55.0, -35.0, 0.7)}


def _readings(setup, noise=None, points=CONTROL):
    pts = np.array(list(points.values()))
    hz, zen, d = n_to_polar(pts, setup, ORIGIN)
    if noise is not None:
        hz, zen, d = hz + noise[0], zen + noise[1], d + noise[2]
    return [ControlReading(point=k, hz_deg=float(np.degrees(a)), zenith_deg=float(np.degrees(z)),
                           slope_distance_m=float(r)) for k, a, z, r in zip(points, hz, zen, d)]


def test_resection_recovers_the_setup_and_round_trips():
    truth = StationSetup("TS01", (12.0, -6.0, 1.8), orientation_rad=np.radians(271.3))
    res = resect("TS01", CONTROL, _readings(truth), ORIGIN, PRECISION, 0.13)
    np.testing.assert_allclose(res.setup.pos_n, truth.pos_n, atol=1e-6)
    assert abs(np.angle(np.exp(1j * (res.setup.orientation_rad - truth.orientation_rad)))) < 1e-9
    assert np.max(np.abs(res.hz_arcsec)) < 1e-3 and np.max(np.abs(res.distance_mm)) < 1e-3
    pts = np.random.default_rng(0).uniform([-800, -50, -2], [50, 50, 5], (200, 3))
    hz, zen, d = n_to_polar(pts, res.setup, ORIGIN)
    assert np.abs(polar_to_n(hz, zen, d, res.setup, ORIGIN) - pts).max() < 1e-9


def test_resection_reports_residuals_of_noisy_readings():
    truth = StationSetup("TS02", (-1152.0, -6.0, 1.8), orientation_rad=np.radians(90.0))
    rng = np.random.default_rng(5)
    noise = (rng.normal(0, 0.5 * ARCSEC, 4), rng.normal(0, 0.5 * ARCSEC, 4), rng.normal(0, 1e-3, 4))
    control = {k: (v[0] - 1152.0, v[1], v[2]) for k, v in CONTROL.items()}
    res = resect("TS02", control, _readings(truth, noise, control), ORIGIN, PRECISION, 0.13)
    assert np.linalg.norm(np.array(res.setup.pos_n) - truth.pos_n) < 3e-3
    assert 0.1 < res.sigma0 < 3.0
    assert len(res.to_json()["residuals"]) == 4 and np.all(np.abs(res.distance_mm) < 5)


def test_station_from_pipeline_config_given_or_resected():
    truth = StationSetup("TS02", (-20.0, 4.0, 1.7), orientation_rad=np.radians(88.0))
    cfg = StationSetupConfig.model_validate({"resection": [r.model_dump() for r in _readings(truth)]})
    setup, res = station_setup("TS02", cfg, CONTROL, ORIGIN, PRECISION, DEFAULT_REFRACTION_K)
    np.testing.assert_allclose(setup.pos_n, truth.pos_n, atol=1e-6)
    assert res is not None and res.to_json()["residuals"][0]["point"] == "CP1"
    given = StationSetupConfig(pos_n_m=(1.0, 2.0, 3.0), orientation_deg=90.0, tilt_arcsec=(2.0, -1.0))
    setup, res = station_setup("TS01", given, {}, ORIGIN, PRECISION, 0.13)
    assert res is None and setup.orientation_rad == pytest.approx(np.pi / 2)
    assert setup.tilt_rad == pytest.approx((2 * ARCSEC, -1 * ARCSEC))
    with pytest.raises(RegistrationError, match="give pos_n_m and orientation_deg"):
        station_setup("TS03", StationSetupConfig(pos_n_m=(0.0, 0.0, 0.0)), {}, ORIGIN, PRECISION, 0.13)


def test_resection_needs_three_points():
    truth = StationSetup("TS01", (0.0, 0.0, 0.0))
    two = dict(list(CONTROL.items())[:2])
    with pytest.raises(RegistrationError, match=">= 3 control points"):
        resect("TS01", CONTROL, _readings(truth, points=two), ORIGIN, PRECISION, 0.13)


# --- polar covariance and mis-locks -------------------------------------------------------------

def test_reading_covariance_matches_numerical_propagation():
    st = StationSetup("S", (10.0, -5.0, 1.5), orientation_rad=1.1, tilt_rad=(2 * ARCSEC, -1 * ARCSEC))
    hz, zen, d = np.array([0.3, 2.5]), np.array([1.56, 1.60]), np.array([450.0, 30.0])
    _, cov = readings_to_n(hz, zen, d, st, ORIGIN, 0.13, InstrumentPrecision(0.5, 3.0, 1.5))
    sig = np.array([0.5 * ARCSEC, 0.5 * ARCSEC, 0.0])
    for k in range(2):
        sig[2] = 3e-3 + 1.5e-6 * d[k]
        J = np.empty((3, 3))
        for i, h in enumerate([1e-7, 1e-7, 1e-4]):
            e = np.zeros(3)
            e[i] = h
            plus = polar_to_n(hz[k] + e[0], zen[k] + e[1], d[k] + e[2], st, ORIGIN)[0]
            minus = polar_to_n(hz[k] - e[0], zen[k] - e[1], d[k] - e[2], st, ORIGIN)[0]
            J[:, i] = (plus - minus) / (2 * h)
        # the refraction term's derivative (k / 2R per metre) is left out: 1e-4 of the largest term
        np.testing.assert_allclose(cov[k], J @ np.diag(sig**2) @ J.T, rtol=1e-4, atol=1e-4 * np.abs(cov[k]).max())


def test_mislock_runs_and_isolated_outliers():
    flags = np.zeros(40, dtype=bool)
    flags[[3]] = True  # isolated outlier
    flags[[10, 11, 13, 14, 17, 18]] = True  # a run with gaps of <= 3 accepted readings
    flags[[30, 35]] = True  # too far apart: two outliers
    rejected, mislock = classify_flags(flags, min_run=5, max_gap=3)
    assert np.flatnonzero(mislock).tolist() == list(range(10, 19))
    assert np.flatnonzero(rejected).tolist() == [3] + list(range(10, 19)) + [30, 35]


def test_seed_registration_undo_restores_the_nominal_points():
    from trackfusion.registration.seed_method import SeedRegistration
    from trackfusion.registration.survey import StationPrep, _undo
    axes = np.vstack([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    reg = SeedRegistration(3.0 * ARCSEC, 0.004, -0.002, np.array([-1152.0, -6.0, 1.8]), axes, (500.0, 690.0))
    pts = _curve(np.arange(500, 1100, 0.5))
    setup = StationSetup("TS02", (-1152.0, -6.0, 1.8))
    prep = StationPrep(setup, reg.centre_n, np.zeros(len(pts)), reg.apply(pts), np.zeros((len(pts), 3, 3)), 0.0,
                       None, None, reg)
    np.testing.assert_allclose(_undo(prep), pts, atol=1e-10)
