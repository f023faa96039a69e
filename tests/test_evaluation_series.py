"""Error series: matching, along/lateral/vertical split, moving part, passes, distance grid."""

import numpy as np
import pytest

from trackfusion.errors import EvaluationError
from trackfusion.evaluation import synthetic as syn
from trackfusion.evaluation.api import EvaluationConfig, evaluate_trajectories
from trackfusion.evaluation.errors_series import (Trajectory, error_series, hermite_interpolate,
                                                  resample_on_distance)


def _run(rate_est=200.0, rate_ref=50.0, error=lambda t, s: np.zeros((t.size, 3)), **kw):
    """Estimate (rate_est) and reference (rate_ref) of one round trip of 200 m (hold 10 s at both ends)."""
    t_ref = np.arange(0.0, 420.0 + 1e-9, 1 / rate_ref)
    t_est = np.arange(0.0, 420.0 + 1e-9, 1 / rate_est)
    ref = syn.truth_columns(t_ref, **kw)
    truth_at_est = syn.truth_columns(t_est, **kw)
    est = syn.with_errors(truth_at_est, error(t_est, truth_at_est["chainage_m"]))
    return Trajectory.from_columns(est, "est.csv"), Trajectory.from_columns(ref, "ref.csv")


def test_hermite_interpolation_is_exact_for_cubics():
    t = np.array([0.0, 0.7, 1.5, 3.0])
    p = np.column_stack([t**3 - 2 * t, 0.5 * t**2, 3.0 + 0 * t])
    v = np.column_stack([3 * t**2 - 2, t, 0 * t])
    tq = np.linspace(0.0, 3.0, 101)
    out = hermite_interpolate(t, p, v, tq)
    np.testing.assert_allclose(out, np.column_stack([tq**3 - 2 * tq, 0.5 * tq**2, 3.0 + 0 * tq]), atol=1e-12)


def test_error_free_estimate_has_no_error_with_a_50hz_reference():
    est, ref = _run()
    series = error_series(est, ref)
    assert np.abs(series.error_m).max() < 1e-7  # Hermite interpolation of a 50 Hz reference on a 40 m wave
    assert series.n_passes == 2
    assert series.pass_direction.tolist() == [1, -1]


def test_components_follow_increasing_chainage_on_a_round_trip():
    """Constant offsets: along +2 mm, lateral +3 mm (left of increasing chainage), vertical -1 mm,
    on the outward and on the return pass alike."""
    est, ref = _run(error=lambda t, s: np.tile([0.002, 0.003, -0.001], (t.size, 1)))
    series = error_series(est, ref)
    for p in range(series.n_passes):
        e = series.error_m[series.pass_index == p]
        np.testing.assert_allclose(e, np.tile([0.002, 0.003, -0.001], (len(e), 1)), atol=1e-9)


def test_static_part_is_excluded_and_documented_threshold_applies():
    est, ref = _run()
    series = error_series(est, ref, min_speed_mps=0.1)
    speed = np.hypot(*np.array([ref.vel_n_mps[:, 0], ref.vel_n_mps[:, 1]]))
    kept_speed = np.interp(series.t_s, ref.t_s, speed)
    assert kept_speed.min() >= 0.1 - 1e-9
    assert series.n_static > 2 * 10 * 200  # both 10 s holds at 200 Hz, plus the slow ends
    assert series.n_matched == est.t_s.size


def test_errors_as_a_function_of_chainage_resample_exactly_on_the_grid():
    """An error linear in chainage stays linear through matching and resampling."""
    est, ref = _run(error=lambda t, s: np.column_stack([0 * s, 1e-5 * s, 2e-5 * s]))
    dist = resample_on_distance(error_series(est, ref), step_m=0.05)
    assert len(dist.passes) == 2
    for p in dist.passes:
        np.testing.assert_allclose(p.error_m[:, 1], 1e-5 * p.chainage_m, atol=1e-9)
        np.testing.assert_allclose(p.error_m[:, 2], 2e-5 * p.chainage_m, atol=1e-9)
        assert np.allclose(np.diff(p.chainage_m), 0.05)
        assert p.start_index * 0.05 == pytest.approx(p.chainage_m[0])
    assert {p.direction for p in dist.passes} == {1, -1}


def test_chainage_matching_agrees_with_time_matching():
    err = lambda t, s: np.column_stack([0 * s, 1e-3 * np.sin(s / 7.0), 5e-4 * np.cos(s / 3.0)])
    est, ref = _run(error=err)
    by_time = error_series(est, ref, match="time")
    by_s = error_series(est, ref, match="chainage")
    # chainage matching interpolates the reference linearly (50 Hz, <= 2.4 mm spacing on a 40 m / 20 mm wave)
    common = np.intersect1d(by_time.t_s, by_s.t_s)
    a = by_time.error_m[np.isin(by_time.t_s, common)]
    b = by_s.error_m[np.isin(by_s.t_s, common)]
    np.testing.assert_allclose(a[:, 1:], b[:, 1:], atol=2e-6)


def test_known_error_statistics_end_to_end():
    """Lateral white noise on the grid: sigma1 = sqrt(2) sigma and sigma from eq. 1, through the whole chain."""
    rng = np.random.default_rng(21)
    grid_noise = rng.normal(0.0, 0.4e-3, 4001)  # one value per 0.05 m of chainage 0..200 m
    err = lambda t, s: np.column_stack([0 * s, grid_noise[np.clip(np.rint(s / 0.05).astype(int), 0, 4000)], 0 * s])
    # estimate sampled exactly on the grid: chainage lookup picks the noise of the nearest grid point
    est, ref = _run(rate_est=400.0, error=err)
    res = evaluate_trajectories(est, ref, config=EvaluationConfig(scales_m=(0.5, 1.0, 5.0)))
    lat = res.relative_accuracy["lateral"]
    assert lat.sigma_mm == pytest.approx(0.4, rel=0.05)
    assert lat.mse_mm[0] == pytest.approx(np.sqrt(2) * 0.4, rel=0.1)
    assert res.relative_accuracy["vertical"].mse_mm.max() < 1e-4


def test_no_time_overlap_names_both_files():
    est, ref = _run()
    late = Trajectory(est.t_s + 1000.0, est.pos_n_m, est.vel_n_mps, est.chainage_m, "est.csv")
    with pytest.raises(EvaluationError, match=r"est\.csv: no overlap in time with ref\.csv"):
        error_series(late, ref)


def test_non_increasing_reference_time_is_reported():
    est, ref = _run()
    t = ref.t_s.copy()
    t[5] = t[4]
    bad = Trajectory(t, ref.pos_n_m, ref.vel_n_mps, ref.chainage_m, "ref.csv")
    with pytest.raises(EvaluationError, match=r"ref\.csv: t_s is not strictly increasing at data row 6"):
        error_series(est, bad)


def test_standing_still_is_an_error():
    est, ref = _run()
    still = Trajectory(ref.t_s, ref.pos_n_m, 0 * ref.vel_n_mps, ref.chainage_m, "ref.csv")
    with pytest.raises(EvaluationError, match="no moving sample"):
        error_series(est, still)
