"""Every scenario: ideal logs integrate back to the truth; sensors follow their error models."""

import functools

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.errors import ConfigError
from trackfusion.registration.polar import StationSetup, polar_to_n
from trackfusion.simulation.config import available_scenarios
from trackfusion.simulation.scenarios import simulate

import strapdown

SCENARIOS = ["open-track-gnss", "bridge-total-station", "fog-odometer", "track-level", "curved-line"]
ARCSEC = np.pi / 180 / 3600


@functools.lru_cache(maxsize=None)
def sim(name, ideal, seed=1):
    return simulate(name, seed=seed, ideal=ideal)


def test_all_scenarios_are_built_in():
    assert set(SCENARIOS) <= set(available_scenarios())


@pytest.mark.parametrize("name", SCENARIOS)
def test_ideal_log_integrates_back_to_the_truth(name):
    """An independent strapdown on the ideal IMU log stays within 1 mm over 60 s of motion."""
    s = sim(name, True)
    imu, motion = s.log.imu, s.motion
    first_hold = motion.static_intervals()[0]
    t_move = first_hold[1] if first_hold[0] == 0.0 else 0.0
    dt = imu.t_s[1] - imu.t_s[0]
    k0 = int(round((t_move - 2.0) / dt)) - 1
    k1 = int(round((t_move + 60.0) / dt))
    t = imu.t_s[k0:k1]
    truth = s.kinematics.state(t, motion)
    pos = strapdown.integrate(t, imu.gyro_radps[k0:k1], imu.accel_mps2[k0:k1], truth["pos_n"][0],
                              truth["vel_n"][0], truth["R_nb"][0], s.origin)
    moved = abs(truth["s_m"][-1] - truth["s_m"][0])
    assert moved > 30.0
    assert np.linalg.norm(pos - truth["pos_n"], axis=1).max() < 1e-3


def test_ideal_total_station_observations_convert_back_to_the_prism():
    s = sim("bridge-total-station", True)
    lever = np.array(s.truth_info["lever_arms_b_m"]["prism"])
    info = s.truth_info["total_stations"]
    assert set(s.log.total_stations) == {"TS01", "TS02"}
    for sid, obs in s.log.total_stations.items():
        setup = StationSetup(sid, tuple(info[sid]["pos_n_m"]), info[sid]["orientation_rad"])
        pts = polar_to_n(obs.horizontal_angle_rad, obs.zenith_angle_rad, obs.slope_distance_m, setup, s.origin)
        st = s.kinematics.state(obs.t_s, s.motion)  # ideal: station clock == IMU clock
        prism = st["pos_n"] + st["R_nb"] @ lever
        assert np.abs(pts - prism).max() < 1e-5  # 0.01 mm, Earth curvature included
        assert obs.slope_distance_m.max() > 500.0


def test_total_stations_noise_tilt_clock_and_handover():
    s = sim("bridge-total-station", False)
    lever = np.array(s.truth_info["lever_arms_b_m"]["prism"])
    info = s.truth_info["total_stations"]
    chainages = {}
    for sid, obs in s.log.total_stations.items():
        d = info[sid]
        assert abs(d["clock_offset_s"]) <= 5.0 and np.hypot(*d["tilt_arcsec"]) <= 4.0
        setup = StationSetup(sid, tuple(d["pos_n_m"]), d["orientation_rad"], tuple(np.array(d["tilt_arcsec"]) * ARCSEC))
        t_imu = (obs.t_s - d["clock_offset_s"]) / (1 + d["clock_drift_ppm"] * 1e-6)
        st = s.kinematics.state(t_imu, s.motion)
        err = polar_to_n(obs.horizontal_angle_rad, obs.zenith_angle_rad, obs.slope_distance_m, setup,
                         s.origin, 0.13) - (st["pos_n"] + st["R_nb"] @ lever)
        # 3 mm + 1.5 ppm in range, 0.5" across: the 3-D error is a few mm, unbiased
        assert 2e-3 < np.sqrt((err**2).sum(1).mean()) < 6e-3
        assert np.abs(err.mean(0)).max() < 5e-4
        chainages[sid] = st["s_m"]
    # hand-over: each station tracks its own part with an overlap in chainage (seed 003: 191 m)
    lo = max(chainages["TS01"].min(), chainages["TS02"].min())
    hi = min(chainages["TS01"].max(), chainages["TS02"].max())
    assert 150.0 < hi - lo < 250.0


def test_gnss_ideal_exact_and_noisy_statistics():
    ideal, noisy = sim("curved-line", True), sim("curved-line", False)
    for s in (ideal, noisy):
        g = s.log.gnss
        pos = geodesy.geodetic_to_n(g.lat_deg, g.lon_deg, g.h_m, s.origin)
        st = s.kinematics.state(g.t_s, s.motion)
        err = pos - (st["pos_n"] + st["R_nb"] @ np.array([0.0, 0.0, 1.5]))
        if s.ideal:
            assert np.abs(err).max() < 1e-6
        else:
            reported = np.sqrt(np.diagonal(g.cov_enu_m2, axis1=1, axis2=2))
            z = err / reported
            assert 0.4 < np.sqrt((z**2).mean()) < 1.6  # errors consistent with the reported sigmas
        # the 60 s outage has no fixes
        assert not np.any((g.t_s >= 330.0) & (g.t_s < 390.0))


def test_gnss_outliers_share():
    s = simulate("open-track-gnss", seed=2, overrides=["gnss.outlier_fraction=0.05"])
    n_out = len(s.truth_info["errors"]["gnss"]["outlier_times_s"])
    n = s.log.gnss.t_s.size
    assert n_out / n == pytest.approx(0.05, abs=3 * np.sqrt(0.05 * 0.95 / n))


def test_odometer_ideal_and_scale_error():
    ideal, noisy = sim("track-level", True), sim("track-level", False)
    wheel = ideal.kinematics.wheel_distance_m(ideal.motion.evaluate(ideal.log.odometer.t_s)[0])
    assert ideal.log.odometer.distance_m == pytest.approx(wheel - wheel[0], abs=1e-12)
    scale = noisy.truth_info["errors"]["odometer"]["scale_error"]
    d_true, d_meas = wheel[-1] - wheel[0], noisy.log.odometer.distance_m[-1]
    ticks_per_m = 10000 / (np.pi * 0.15)
    assert d_meas == pytest.approx(d_true * (1 + scale), abs=2 / ticks_per_m)
    assert np.all(np.diff(noisy.log.odometer.ticks) >= 0)


def test_inclinometer_and_gauge_follow_the_track():
    s = sim("track-level", True)
    inc = s.log.inclinometer
    # in the arc (cant 120 mm over 1.5 m) the trolley rolls by about asin(0.12 / 1.5)
    in_arc = s.motion.evaluate(inc.t_s)[0] > 215.0
    assert np.abs(inc.roll_rad[in_arc]).mean() == pytest.approx(np.arcsin(0.12 / 1.5), abs=3e-3)
    assert s.log.gauge.gauge_m == pytest.approx(1.435, abs=0.01)


def test_same_seed_same_data_other_seed_other_data():
    a = simulate("track-level", seed=5)
    b = simulate("track-level", seed=5)
    c = simulate("track-level", seed=6)
    assert np.array_equal(a.log.imu.accel_mps2, b.log.imu.accel_mps2)
    assert np.array_equal(a.log.odometer.ticks, b.log.odometer.ticks)
    assert not np.array_equal(a.log.imu.accel_mps2, c.log.imu.accel_mps2)


def test_imu_errors_are_drawn_and_recorded():
    s = sim("track-level", False)
    ideal = sim("track-level", True)
    diff = s.log.imu.gyro_radps - ideal.log.imu.gyro_radps
    drawn = s.truth_info["errors"]["imu"]["gyro_radps"]
    # over the first static minute the mean gyro error is the bias plus the Gauss-Markov part
    static = s.log.imu.t_s < 60.0
    spec_bi = 2.0 * np.pi / 180 / 3600
    assert np.abs(diff[static].mean(0) - np.array(drawn["bias"])).max() < 4 * spec_bi


@pytest.mark.parametrize("override, field", [
    (["imu.rate_hz=-5"], "imu: rate_hz"),
    (["gnss.outlier_fraction=2"], "gnss: outlier_fraction"),
    (["motion.segments.1.speed_mps=0"], "motion.segments.1.speed_mps"),
    (["nonsense=1"], "nonsense"),
])
def test_bad_overrides_name_the_field(override, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        simulate("curved-line", overrides=override)
