"""Pre-processing: static-interval detection, odometer gross-error repair, sensor clock mapping.

Synthetic trolley runs are built here directly with numpy: speed profiles of raised-cosine
acceleration (peak 0.4 m/s^2 for a 3 m/s change in 15 s), an IMU with white noise plus rolling
vibration proportional to speed, an odometer quantised to encoder ticks.
"""


import numpy as np
import pytest

from trackfusion.errors import ConfigError, SensorDataError
from trackfusion.fusion.preprocess import (MAX_CONSECUTIVE_REPAIRS, detect_static_intervals,
                                           moving_intervals_by_gnss, repair_odometer,
                                           sensor_times_to_imu_clock)
from trackfusion.sensors.types import ImuData, OdometerData

G_MPS2 = 9.80
EARTH_RATE_B_RADPS = np.array([0.0, 5.3e-5, 5.0e-5])  # level IMU at ~43 deg latitude
TICKS_PER_M = 10000 / (np.pi * 0.15)                    # simulator default wheel
ACCEL_VIB_PER_MPS = 0.2                                 # rolling vibration [m/s^2 per m/s]
GYRO_VIB_PER_MPS = 2e-3                                 # rolling vibration [rad/s per m/s]
NAV = dict(gyro_noise_radps=1e-6, accel_noise_mps2=1e-4)
MEMS = dict(gyro_noise_radps=1e-3, accel_noise_mps2=1e-2)
MEMS_THRESHOLDS = dict(gyro_std_radps=3e-3, accel_std_mps2=3e-2)

# (duration_s, speed at the end [m/s]): stand 30 s, 60 s of motion to 3 m/s and back, stand 30 s
STATIC_SEGMENTS = [(30, 0.0), (15, 3.0), (30, 3.0), (15, 0.0), (30, 0.0)]
STATIC_TRUTH_S = [(0.0, 30.0), (90.0, 120.0)]
# 10 minutes with starts, stops, a slow creep, a reversal through zero and back to zero
ODOMETER_SEGMENTS = [(20, 0.0), (15, 3.0), (120, 3.0), (15, 0.0), (10, 0.0), (10, 1.5), (60, 1.5),
                     (15, -1.5), (90, -1.5), (8, 0.0), (20, 0.0), (5, 0.05), (30, 0.05), (5, 0.0),
                     (15, 3.0), (100, 3.0), (15, 0.0), (47, 0.0)]


def trolley(t_s, segments):
    """Speed (N,) [m/s], acceleration (N,) [m/s^2] and distance (N,) [m] at ``t_s`` of a run of
    segments, each a raised-cosine acceleration from the previous speed to its end speed."""
    t = np.asarray(t_s, float)
    v = np.zeros_like(t)
    a = np.zeros_like(t)
    d = np.zeros_like(t)
    t0, v0, d0 = 0.0, 0.0, 0.0
    for duration, v1 in segments:
        m = (t >= t0) & (t < t0 + duration)
        tau = (t[m] - t0) / duration
        dv = v1 - v0
        v[m] = v0 + dv * (tau - np.sin(2 * np.pi * tau) / (2 * np.pi))
        a[m] = dv / duration * (1 - np.cos(2 * np.pi * tau))
        d[m] = d0 + v0 * (t[m] - t0) + dv * duration * (tau**2 / 2 + (np.cos(2 * np.pi * tau) - 1) / (4 * np.pi**2))
        t0, v0, d0 = t0 + duration, v1, d0 + (v0 + v1) / 2 * duration
    return v, a, d


def make_imu(t_s, speed_mps, accel_mps2, rng, gyro_noise_radps, accel_noise_mps2):
    """IMU on straight level track: specific force (a, 0, g), Earth rate, white noise and vibration."""
    n = t_s.size
    vib = np.abs(speed_mps)[:, None]
    f = np.column_stack([accel_mps2, np.zeros(n), np.full(n, G_MPS2)])
    f += rng.standard_normal((n, 3)) * (accel_noise_mps2 + ACCEL_VIB_PER_MPS * vib)
    w = EARTH_RATE_B_RADPS + rng.standard_normal((n, 3)) * (gyro_noise_radps + GYRO_VIB_PER_MPS * vib)
    return ImuData(t_s.copy(), w, f)


def make_odometer(t_s, distance_m):
    """Odometer as the simulator builds it: ticks = floor(d ticks_per_m), distance = ticks / ticks_per_m."""
    ticks = np.floor((distance_m - distance_m[0]) * TICKS_PER_M + 1e-9).astype(np.int64)
    return OdometerData(t_s.copy(), ticks / TICKS_PER_M, ticks)


def static_run(rng, noise, rate_hz=200.0):
    """The 120 s stand-move-stand run: IMU, odometer (100 Hz), IMU times and true speed."""
    t = np.arange(0.0, 120.0, 1 / rate_hz)
    v, a, _ = trolley(t, STATIC_SEGMENTS)
    t_odo = np.arange(0.0, 120.0, 0.01)
    return make_imu(t, v, a, rng, **noise), make_odometer(t_odo, trolley(t_odo, STATIC_SEGMENTS)[2]), t, v


def assert_matches_truth(intervals, t, v, tol_s, max_speed_mps):
    """One detected interval per true one, both ends within ``tol_s``, no faster sample inside."""
    assert len(intervals) == len(STATIC_TRUTH_S), intervals
    for (start, end), (true_start, true_end) in zip(intervals, STATIC_TRUTH_S):
        assert abs(start - true_start) <= tol_s and abs(end - min(true_end, t[-1])) <= tol_s, (start, end)
        inside = (t >= start) & (t <= end)
        assert np.max(np.abs(v[inside])) < max_speed_mps
    assert not any(30.0 + tol_s < s < 90.0 - tol_s or 30.0 + tol_s < e < 90.0 - tol_s for s, e in intervals)


# --- static intervals -------------------------------------------------------------------------

def test_static_navigation_grade_with_odometer_matches_truth():
    imu, odo, t, v = static_run(np.random.default_rng(1), NAV)
    intervals = detect_static_intervals(imu, odo)
    # the onset is so gentle that the trolley moves < 1e-3 m/s for the first 0.5 s
    assert_matches_truth(intervals, t, v, tol_s=0.5, max_speed_mps=1e-3)
    assert intervals[0][0] == 0.0                                     # the record start is not shrunk


def test_static_mems_with_odometer_matches_truth():
    imu, odo, t, v = static_run(np.random.default_rng(2), MEMS)
    intervals = detect_static_intervals(imu, odo, **MEMS_THRESHOLDS)
    assert_matches_truth(intervals, t, v, tol_s=0.5, max_speed_mps=1e-3)


@pytest.mark.parametrize("noise, thresholds, tol_s, max_speed_mps",
                         [(NAV, {}, 1.5, 0.02), (MEMS, MEMS_THRESHOLDS, 3.0, 0.15)])
def test_static_imu_only_sees_motion_by_vibration(noise, thresholds, tol_s, max_speed_mps):
    """Without the odometer a gentle start shows once its vibration (0.2 m/s^2 per m/s) exceeds
    the threshold: about 1 cm/s for a navigation-grade IMU, 10 cm/s for a MEMS one."""
    imu, _, t, v = static_run(np.random.default_rng(3), noise)
    intervals = detect_static_intervals(imu, **thresholds)
    assert_matches_truth(intervals, t, v, tol_s=tol_s, max_speed_mps=max_speed_mps)


def test_static_imu_only_sees_a_start_without_vibration():
    """A smooth track gives no rolling vibration: the standard deviations stay quiet into the
    motion (0.7 m/s after 5 s), but the start's acceleration moves the mean specific force;
    the steady-mean test ends the interval before the trolley reaches 2 mm/s. The 30 s at a
    constant 3 m/s look static to any IMU (hence the GNSS check below)."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 120.0, 1 / 200.0)
    v, a, _ = trolley(t, STATIC_SEGMENTS)
    f = np.column_stack([a, np.zeros(t.size), np.full(t.size, G_MPS2)]) + 1e-4 * rng.standard_normal((t.size, 3))
    w = EARTH_RATE_B_RADPS + 1e-6 * rng.standard_normal((t.size, 3))
    intervals = detect_static_intervals(ImuData(t, w, f))
    assert len(intervals) == 3 and 44.0 <= intervals[1][0] < intervals[1][1] <= 76.0
    assert_matches_truth([intervals[0], intervals[2]], t, v, tol_s=0.7, max_speed_mps=2e-3)


def test_gnss_sees_a_constant_speed_the_imu_cannot():
    """Fixes (2 cm white noise, 1 Hz) over a 30 s interval: at rest it is kept (also with a
    1 cm correlated offset drifting 5 mm, and with gross outliers), at 5 cm/s it is moving; fewer
    than 3 fixes: unchecked."""
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 100.0, 1.0)
    speed = np.where(t >= 50.0, 0.05, 0.0)
    pos = np.column_stack([speed * (t - 50.0), np.zeros_like(t), np.zeros_like(t)])
    pos += 0.02 * rng.standard_normal(pos.shape) + np.array([0.01, 0.0, 0.0]) + 5e-3 * (t / 100.0)[:, None]
    sigma = np.full(pos.shape, 0.02)
    intervals = [(5.0, 35.0), (60.0, 90.0), (40.0, 41.5)]
    assert moving_intervals_by_gnss(intervals, t, pos, sigma) == [1]
    assert moving_intervals_by_gnss(intervals[:1], t, pos + np.array([1.0, 0, 0]) * t[:, None] * 1e-3, sigma) == []
    assert moving_intervals_by_gnss(intervals[:1], t, pos + np.array([1.0, 0, 0]) * t[:, None] * 1e-2, sigma) == [0]
    outliers = pos.copy()
    outliers[[10, 20, 30], 0] += np.array([1.0, 2.5, 0.4])  # gross fixes do not make it move
    assert moving_intervals_by_gnss(intervals[:1], t, outliers, sigma) == []


def test_static_wrong_thresholds_fail():
    """The criteria really act: thresholds below the noise find nothing, thresholds far above
    the vibration (and no odometer) take the whole run for static, the odometer then cuts it."""
    imu, odo, t, _ = static_run(np.random.default_rng(4), MEMS)
    assert detect_static_intervals(imu, gyro_std_radps=3e-4, accel_std_mps2=3e-2) == []
    assert detect_static_intervals(imu, gyro_std_radps=3e-3, accel_std_mps2=3e-3) == []
    huge = dict(gyro_std_radps=1.0, accel_std_mps2=10.0)
    assert detect_static_intervals(imu, **huge) == [(0.0, t[-1])]
    assert detect_static_intervals(imu, odo, **huge, max_odometer_speed_mps=5.0) == [(0.0, t[-1])]
    assert len(detect_static_intervals(imu, odo, **huge)) == 2


def test_static_min_duration_and_gap():
    imu, odo, t, _ = static_run(np.random.default_rng(5), NAV)
    assert detect_static_intervals(imu, odo, min_duration_s=31.0) == []
    # a data gap of 60 s over the whole motion: the windows across it are not quiet
    keep = (t < 30.0) | (t >= 90.0)
    gappy = ImuData(imu.t_s[keep], imu.gyro_radps[keep], imu.accel_mps2[keep])
    intervals = detect_static_intervals(gappy)
    assert len(intervals) == 2 and intervals[0][1] < 30.0 and intervals[1][0] >= 90.0


def test_static_outside_odometer_coverage_is_not_static():
    imu, odo, t, _ = static_run(np.random.default_rng(6), NAV)
    late = odo.t_s >= 10.0
    intervals = detect_static_intervals(imu, OdometerData(odo.t_s[late], odo.distance_m[late], odo.ticks[late]))
    assert intervals[0][0] >= 10.0


def test_static_bad_input():
    imu, odo, _, _ = static_run(np.random.default_rng(7), NAV)
    empty = ImuData(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(SensorDataError, match="imu"):
        detect_static_intervals(empty)
    short = ImuData(imu.t_s[:150], imu.gyro_radps[:150], imu.accel_mps2[:150])   # < two 0.5 s windows
    with pytest.raises(SensorDataError, match="fewer than two"):
        detect_static_intervals(short)
    with pytest.raises(SensorDataError, match="gyro_radps"):
        detect_static_intervals(ImuData(imu.t_s, imu.gyro_radps[:, :2], imu.accel_mps2))
    nan = imu.accel_mps2.copy()
    nan[10, 2] = np.nan
    with pytest.raises(SensorDataError, match="accel_mps2"):
        detect_static_intervals(ImuData(imu.t_s, imu.gyro_radps, nan))
    with pytest.raises(SensorDataError, match="odometer"):
        detect_static_intervals(imu, OdometerData(odo.t_s[::-1], odo.distance_m, odo.ticks))
    with pytest.raises(ConfigError, match="window_s"):
        detect_static_intervals(imu, window_s=0.0)
    with pytest.raises(SensorDataError) as info:
        detect_static_intervals(empty)
    assert "\n" not in str(info.value)


def test_static_on_1_8_million_samples():
    """One hour at 500 Hz (1.8e6 samples): the two long still periods, nothing else (speed is
    measured in benchmarks/speed.py, not here)."""
    rng = np.random.default_rng(8)
    n = 1_800_000
    t = np.arange(n) / 500.0
    v = np.where((t > 600) & (t < 3000), 2.0, 0.0)
    imu = make_imu(t, v, np.zeros(n), rng, **NAV)
    odo = make_odometer(t[::5], np.cumsum(v[::5]) * 0.01)
    intervals = detect_static_intervals(imu, odo)
    assert len(intervals) == 2
    assert intervals[0][1] == pytest.approx(600.0, abs=0.6) and intervals[1][0] == pytest.approx(3000.0, abs=0.6)


# --- odometer repair --------------------------------------------------------------------------

def odometer_run(rate_hz=100.0, spike_ticks=False, seed=10, n_spikes=40):
    """The 10-minute run with a 2 cm slip and isolated spikes of +-0.02..0.05 m.

    Returns the spiked odometer, the clean one, spike indices and sizes [m]."""
    t = np.arange(0.0, 600.0, 1 / rate_hz)
    _, _, d = trolley(t, ODOMETER_SEGMENTS)
    d = d + 0.02 * np.clip((t - 200.0) / 0.5, 0.0, 1.0)        # a wheel slip, as in the simulator
    clean = make_odometer(t, d)
    rng = np.random.default_rng(seed)
    idx = np.sort(np.concatenate([[2, t.size - 1], rng.choice(np.arange(4, t.size - 2, 3), n_spikes - 2, replace=False)]))
    size_m = rng.uniform(0.02, 0.05, idx.size) * rng.choice([-1.0, 1.0], idx.size)
    size_m[0], size_m[-1] = 0.02, -0.02                        # the smallest spikes at both ends
    dist = clean.distance_m.copy()
    dist[idx] += size_m
    ticks = np.round(dist * TICKS_PER_M).astype(np.int64) if spike_ticks else clean.ticks.copy()
    return OdometerData(t, dist, ticks), clean, idx, size_m


def test_odometer_all_spikes_found_none_false_and_repaired():
    spiked, clean, idx, _ = odometer_run()
    copies = [a.copy() for a in (spiked.t_s, spiked.distance_m, spiked.ticks)]
    repaired, report = repair_odometer(spiked)
    assert [r["index"] for r in report] == idx.tolist()
    assert np.max(np.abs(repaired.distance_m - clean.distance_m)) < 1e-3
    assert np.array_equal(repaired.ticks, clean.ticks)         # the spikes were in the distance only
    for r in report:
        i = r["index"]
        assert r["t_s"] == spiked.t_s[i] and r["measured_m"] == spiked.distance_m[i]
        assert r["predicted_m"] == repaired.distance_m[i]
    for a, c in zip((spiked.t_s, spiked.distance_m, spiked.ticks), copies):
        assert np.array_equal(a, c)
    assert repaired.distance_m is not spiked.distance_m and repaired.t_s is not spiked.t_s


def test_odometer_clean_motion_is_not_flagged():
    """Starts, stops, creep, reversal and a slip, with 0.05 mm ticks: nothing to repair; the
    largest one-step prediction error is far below the threshold (a too-small threshold fails)."""
    _, clean, _, _ = odometer_run()
    repaired, report = repair_odometer(clean)
    assert report == [] and np.array_equal(repaired.distance_m, clean.distance_m)
    assert repair_odometer(clean, threshold_m=1e-3)[1] == []
    first_minute = OdometerData(clean.t_s[:6000], clean.distance_m[:6000], clean.ticks[:6000])
    assert len(repair_odometer(first_minute, threshold_m=1e-5)[1]) > 100   # flags tick quantisation


def test_odometer_wrong_threshold_misses_spikes():
    spiked, _, idx, size_m = odometer_run()
    found = [r["index"] for r in repair_odometer(spiked, threshold_m=0.03)[1]]
    assert found == idx[np.abs(size_m) > 0.03].tolist() and len(found) < idx.size


def test_odometer_ticks_repaired_when_spiked_too():
    spiked, clean, idx, _ = odometer_run(spike_ticks=True, seed=11)
    repaired, report = repair_odometer(spiked)
    assert [r["index"] for r in report] == idx.tolist()
    assert np.max(np.abs(repaired.ticks - clean.ticks)) <= 20   # 1 mm of ticks
    assert not np.array_equal(spiked.ticks, clean.ticks)


def test_odometer_adjacent_spikes_and_non_uniform_times():
    t = np.cumsum(np.random.default_rng(12).uniform(0.009, 0.011, 30000))
    _, _, d = trolley(t - t[0], ODOMETER_SEGMENTS)
    clean = make_odometer(t, d)
    dist = clean.distance_m.copy()
    run = 12000 + np.arange(MAX_CONSECUTIVE_REPAIRS)            # the longest run still repaired
    idx = np.concatenate([[1000, 1001, 5000, 5001, 5002], run, [20000]])
    dist[idx] += np.concatenate([[0.03, -0.04, 0.02, 0.05, 0.03], 0.03 * (-1.0) ** run, [-0.02]])
    repaired, report = repair_odometer(OdometerData(t, dist, clean.ticks))
    assert [r["index"] for r in report] == idx.tolist()
    assert np.max(np.abs(repaired.distance_m - clean.distance_m)) < 1e-3


def test_odometer_real_jump_and_gap_are_accepted_not_extrapolated():
    """A counter jump or a data gap is no spike: after MAX_CONSECUTIVE_REPAIRS flags the
    measurements are accepted and checking restarts, instead of extrapolating for ever."""
    _, clean, _, _ = odometer_run()
    jump_m = 0.5 * (clean.t_s >= 300.0)
    keep = (clean.t_s < 27.0) | (clean.t_s >= 29.0)            # 2 s gap while accelerating
    dist = clean.distance_m + jump_m
    dist[40000] += 0.03
    repaired, report = repair_odometer(OdometerData(clean.t_s[keep], dist[keep], clean.ticks[keep]))
    assert [r["t_s"] for r in report] == [clean.t_s[40000]]
    assert np.max(np.abs(repaired.distance_m - (clean.distance_m + jump_m)[keep])) < 1e-3


def test_odometer_bad_input():
    spiked, _, _, _ = odometer_run()
    with pytest.raises(SensorDataError, match="at least 9"):
        repair_odometer(OdometerData(spiked.t_s[:8], spiked.distance_m[:8], spiked.ticks[:8]))
    with pytest.raises(SensorDataError, match="odometer"):
        repair_odometer(OdometerData(np.zeros(0), np.zeros(0), np.zeros(0, np.int64)))
    with pytest.raises(SensorDataError, match="distance_m"):
        repair_odometer(OdometerData(spiked.t_s, spiked.distance_m[:-1], spiked.ticks))
    with pytest.raises(SensorDataError, match="increasing"):
        repair_odometer(OdometerData(spiked.t_s[::-1], spiked.distance_m, spiked.ticks))
    with pytest.raises(SensorDataError, match="ticks"):
        repair_odometer(OdometerData(spiked.t_s, spiked.distance_m, spiked.distance_m))
    with pytest.raises(ConfigError, match="window"):
        repair_odometer(spiked, window=3)
    with pytest.raises(ConfigError, match="threshold_m"):
        repair_odometer(spiked, threshold_m=-0.01)


# --- clocks -----------------------------------------------------------------------------------

def test_sensor_times_to_imu_clock_round_trip():
    t_imu = np.array([0.0, 10.0, 3600.0])
    t_sensor = t_imu * (1 + 50e-6) + 2.5                        # sensor clock 2.5 s ahead, 50 ppm fast
    out = sensor_times_to_imu_clock(t_sensor, offset_s=2.5, drift_ppm=50.0)
    np.testing.assert_allclose(out, t_imu, rtol=0, atol=1e-9)
    assert out is not t_sensor and t_sensor[1] == 10.0 * (1 + 50e-6) + 2.5
    np.testing.assert_array_equal(sensor_times_to_imu_clock(t_imu), t_imu)
    assert sensor_times_to_imu_clock(np.array([12.0]), offset_s=2.0)[0] == 10.0
    with pytest.raises(SensorDataError):
        sensor_times_to_imu_clock(np.array([np.nan]))
    with pytest.raises(ConfigError):
        sensor_times_to_imu_clock(t_imu, drift_ppm=-1e6)


# --- static periods from the IMU alone, any grade ----------------------------------------------

def _grade_imu(t, grade, still_f_b, rng, noise_free=False):
    """A still IMU of a named grade: the specific force ``still_f_b`` and the Earth rate, with the
    grade's datasheet white noise (per-sample sigma = density / sqrt(dt)), its turn-on biases."""
    from trackfusion.sensors.imu import DEG, G0_MPS2, IMU_GRADES
    spec = IMU_GRADES[grade]
    rate = 1.0 / (t[1] - t[0])
    f = np.tile(still_f_b, (t.size, 1)) + spec.accel_bias_ug * 1e-6 * G0_MPS2
    w = np.tile(EARTH_RATE_B_RADPS, (t.size, 1)) + spec.gyro_bias_deg_per_h * DEG / 3600.0
    if not noise_free:
        f = f + rng.standard_normal(f.shape) * spec.accel_vrw_mps_per_sqrt_h / 60.0 * np.sqrt(rate)
        w = w + rng.standard_normal(w.shape) * spec.gyro_arw_deg_per_sqrt_h * DEG / 60.0 * np.sqrt(rate)
    return ImuData(t, w, f), spec


def _smooth_run(t, rng, grade, noise_free):
    """60 s still, a raised-cosine start to 3 m/s, 10 minutes on a 0.5 % grade without
    vibration (quiet to any IMU, but not the rest's specific force), a stop, 60 s still."""
    from trackfusion.sensors.imu import DEG, IMU_GRADES
    segments = [(60, 0.0), (15, 3.0), (600, 3.0), (15, 0.0), (60, 0.0)]
    _, a, _ = trolley(t, segments)
    pitch = 0.005 * np.clip(np.minimum(t - 90.0, 660.0 - t) / 10.0, 0.0, 1.0)  # on a grade while moving
    imu, spec = _grade_imu(t, grade, np.zeros(3), rng, noise_free)
    imu.accel_mps2[:, 0] += a + G_MPS2 * np.sin(pitch)
    imu.accel_mps2[:, 2] += G_MPS2 * np.cos(pitch)
    return imu, spec


@pytest.mark.parametrize("grade", ["navigation", "navigation-500", "fog", "mems-tactical"])
@pytest.mark.parametrize("noise_free", [True, False])
def test_static_from_the_imu_alone_on_any_grade(grade, noise_free):
    """The still ends of a run whose motion is smooth (quiet for minutes, the specific force of
    a grade, not of rest) are found from the IMU alone, with the pipeline's thresholds from the
    grade's datasheet noise and the rate; the motion between is not taken for the rest (the
    long cruise looks static to any IMU: its start and stop are not in it)."""
    from trackfusion.fusion.settings import StaticSettings
    from trackfusion.sensors.imu import IMU_GRADES
    rate = IMU_GRADES[grade].rate_hz
    t = np.arange(0.0, 750.0, 1.0 / rate)
    imu, spec = _smooth_run(t, np.random.default_rng(11), grade, noise_free)
    gyro_deg, accel = StaticSettings().thresholds(spec.gyro_arw_deg_per_sqrt_h, spec.accel_vrw_mps_per_sqrt_h, rate)
    intervals = detect_static_intervals(imu, gyro_std_radps=np.radians(gyro_deg), accel_std_mps2=accel)
    v, a_true, _ = trolley(t, [(60, 0.0), (15, 3.0), (600, 3.0), (15, 0.0), (60, 0.0)])
    first, last = intervals[0], intervals[-1]
    # the start's acceleration (0.0175 m/s^2 x s^2 of its onset) shows once it passes the accel
    # threshold: 1.1 s (FOG), 1.6 s (MEMS) into the motion, at 1 cm/s and 2.5 cm/s
    assert first[0] == 0.0 and 57.0 < first[1] < 62.0, intervals
    assert 688.0 < last[0] < 693.0 and last[1] == t[-1], intervals
    for a, b in (first, last):
        assert np.max(np.abs(v[(t >= a) & (t <= b)])) < 0.05  # MEMS: a start shows later
    for a, b in intervals[1:-1]:  # the cruise (constant speed), and a start's peak to a MEMS
        inside = (t >= a) & (t <= b)
        if grade != "mems-tactical":
            assert np.min(v[inside]) > 2.5, intervals
        # what no IMU tells from rest: a constant specific force (the MEMS thresholds, 0.047 m/s^2,
        # hold the raised cosine's 0.4 m/s^2 peak for 2.4 s; GNSS must exclude such intervals)
        assert np.ptp(a_true[inside]) < accel and np.ptp(v[inside]) > 0 or np.min(v[inside]) > 2.5


@pytest.mark.parametrize("grade", ["navigation", "fog", "mems-tactical"])
def test_static_still_imu_is_static_throughout(grade):
    """A still IMU, level or tilted, noise-free or noisy: one interval, the whole record."""
    from trackfusion.fusion.settings import StaticSettings
    rng = np.random.default_rng(12)
    for noise_free in (True, False):
        for f_b in (np.array([0.0, 0.0, G_MPS2]), G_MPS2 * np.array([0.1, -0.2, np.sqrt(1 - 0.05)])):
            imu, spec = _grade_imu(np.arange(0.0, 120.0, 1.0 / 200.0), grade, f_b, rng, noise_free)
            gyro_deg, accel = StaticSettings().thresholds(spec.gyro_arw_deg_per_sqrt_h,
                                                          spec.accel_vrw_mps_per_sqrt_h, 200.0)
            assert detect_static_intervals(imu, gyro_std_radps=np.radians(gyro_deg),
                                           accel_std_mps2=accel) == [(0.0, imu.t_s[-1])]


def test_slow_constant_speed_is_excluded_by_gnss():
    """A noise-free IMU on a slow (5 cm/s), constant-speed, straight, level stretch between two
    stands reads exactly as at rest; the fixes (1 Hz, 1 cm) through the interval exclude it, and
    keep the stands."""
    t = np.arange(0.0, 200.0, 1 / 200.0)
    segments = [(40, 0.0), (10, 0.05), (100, 0.05), (10, 0.0), (40, 0.0)]
    v, a, d = trolley(t, segments)
    f = np.column_stack([a, np.zeros(t.size), np.full(t.size, G_MPS2)])
    imu = ImuData(t, np.tile(EARTH_RATE_B_RADPS, (t.size, 1)), f)
    intervals = detect_static_intervals(imu)
    assert len(intervals) == 3 and intervals[1][0] < 50.0 and intervals[1][1] > 150.0  # the cruise looks static
    t_fix = np.arange(0.0, 200.0, 1.0)
    pos = np.column_stack([np.interp(t_fix, t, d), np.zeros(t_fix.size), np.zeros(t_fix.size)])
    pos += 0.01 * np.random.default_rng(13).standard_normal(pos.shape)
    assert moving_intervals_by_gnss(intervals, t_fix, pos, np.full(pos.shape, 0.01)) == [1]
