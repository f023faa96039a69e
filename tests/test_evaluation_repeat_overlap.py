"""Repeatability across runs (seed 000, tables 2-3) and overlap residuals (seed 003, tables 1-4)."""

import numpy as np
import pytest

from trackfusion.errors import EvaluationError
from trackfusion.evaluation.overlap import overlap_residuals, overlap_statistics
from trackfusion.evaluation.repeatability import repeatability, runs_on_common_grid


def test_repeatability_table_figures():
    # 5 runs, 4 points; per-point std (ddof 1) known by construction
    base = np.array([0.0, 1.0, 2.0, 3.0]) * 1e-3
    offsets = np.array([-2, -1, 0, 1, 2])[:, None] * np.array([0.01, 0.05, 0.1, 0.2])[None, :] * 1e-3
    res = repeatability(base + offsets, limit_mm=0.1)
    std = np.array([0.01, 0.05, 0.1, 0.2]) * np.sqrt(10 / 4)
    np.testing.assert_allclose(res.spread_mm, std, rtol=1e-9)
    assert res.n_points == 4 and res.n_runs == 5
    assert res.n_above == 2  # 0.158 and 0.316 mm exceed 0.1 mm
    assert res.share_above_pct == pytest.approx(50.0)
    assert res.mean_mm == pytest.approx(std.mean())
    assert (res.max_mm, res.min_mm) == (pytest.approx(std.max()), pytest.approx(std.min()))
    j = res.to_json()
    assert j["n_above_limit"] == 2 and j["mean_repeatability_mm"] == pytest.approx(std.mean())
    assert "repeatability mean" in res.format_table()


def test_repeatability_range_and_nan_points():
    v = np.array([[0.0, 1.0, np.nan], [0.5, 1.2, 3.0], [0.2, 0.9, 3.1]]) * 1e-3
    res = repeatability(v, limit_mm=0.25, spread="range")
    np.testing.assert_allclose(res.spread_mm, [0.5, 0.3])
    assert res.n_points == 2  # the column with a NaN is skipped
    with pytest.raises(EvaluationError):
        repeatability(v[:1])
    with pytest.raises(EvaluationError):
        repeatability(v, spread="iqr")


def test_runs_on_common_grid_handles_reversed_runs():
    s1 = np.linspace(0.0, 10.0, 101)
    s2 = np.linspace(12.0, 2.0, 201)  # measured backwards
    grid, values = runs_on_common_grid([(s1, 0.001 * s1), (s2, 0.001 * s2 + 1e-4)], step_m=0.5)
    assert grid[0] == 2.0 and grid[-1] == 10.0
    np.testing.assert_allclose(values[1] - values[0], 1e-4, atol=1e-12)
    with pytest.raises(EvaluationError, match="share no chainage"):
        runs_on_common_grid([(s1, s1), (s1 + 20.0, s1)], 0.5)


def test_overlap_statistics_known_answers_and_seed003_ppm():
    s = np.linspace(100.0, 291.0, 1911)  # 191 m of overlap, as seed 003
    rng = np.random.default_rng(31)
    noise = rng.normal(0.0, 1.0, s.size)
    noise = (noise - noise.mean()) / noise.std(ddof=1)
    r = 3.1e-3 + 2e-6 * (s - s.mean()) + 6.1e-3 * noise
    st = overlap_statistics(s, r)
    assert st.n_points == 1911 and st.length_m == pytest.approx(191.0)
    assert st.mean_mm == pytest.approx(3.1, abs=1e-9)
    i = np.argmax(np.abs(r))
    assert st.max_abs_mm == pytest.approx(1e3 * abs(r[i])) and st.max_abs_signed_mm == pytest.approx(1e3 * r[i])
    slope_fit = np.polyfit(s, r, 1)[0]
    assert st.trend_slope == pytest.approx(slope_fit, rel=1e-9)
    # seed 003: 6.1 mm over 191 m = 31.9 ppm (here std includes the small trend)
    assert st.relative_accuracy_ppm == pytest.approx(st.std_mm * 1e-3 / 191.0 * 1e6)
    pure = overlap_statistics(s, 6.1e-3 * noise)
    assert pure.relative_accuracy_ppm == pytest.approx(31.94, abs=0.01)
    assert pure.to_json()["relative_accuracy_ppm"] == pytest.approx(31.94, abs=0.01)


def test_overlap_residuals_between_two_curves():
    sa = np.linspace(0.0, 100.0, 1001)
    sb = np.linspace(150.0, 40.0, 500)  # the other station, measured the other way
    grid, r = overlap_residuals(sa, 1e-3 * np.sin(sa), sb, 1e-3 * np.sin(sb) + 2e-3 + 1e-5 * sb, step_m=0.25)
    assert grid[0] == pytest.approx(40.0) and grid[-1] == pytest.approx(100.0)
    np.testing.assert_allclose(r, 2e-3 + 1e-5 * grid, atol=1e-5)  # linear interpolation of sin at 0.22 m
    st = overlap_statistics(grid, r)
    assert st.trend_slope == pytest.approx(1e-5, rel=0.05)
    with pytest.raises(EvaluationError, match="do not overlap"):
        overlap_residuals(sa, sa, sa + 200.0, sa)
    with pytest.raises(EvaluationError, match="too short"):
        overlap_statistics([1.0, 2.0], [0.0, 0.0])
