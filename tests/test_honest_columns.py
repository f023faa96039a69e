"""Without a gauge sensor the other rail's lateral quantities and the gauge are not measured: NaN
in geometry.csv, listed in ``not_measured`` (metrics and sidecar), not plotted by the report, and
a tolerance check on them is said to be skipped; with a gauge sensor every column is measured."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackfusion.report.html import RunFiles, geometry_section
from trackfusion.report.track_plots import column_label
from trackfusion.track.geometry import GeometryConfig, ToleranceCheck, compute_geometry
from trackfusion.simulation.irregularity import IrregularitySpec, synthesize
from trackfusion.track.design import DesignAlignment
from trackfusion.track.rails import TrackModel
from trackfusion.sensors.types import GaugeData
from trackfusion.track.traces import TrajectoryOnTrack, TrolleyGeometry
from trackfusion.verdict import verdict_line

from test_geometry import _known_pose  # noqa: E402  (the rail-exact trolley pose on a known track)

CHECKS = ("t", [ToleranceCheck(name="lateral_10m", kind="limit", quantity="lateral_versine", length_m=10.0,
                               limit_mm=0.001),
                ToleranceCheck(name="gauge", kind="limit", quantity="gauge_variation", limit_mm=0.001)])


@pytest.fixture(scope="module")
def track():
    design = DesignAlignment.from_dict({"horizontal": {"heading_deg": 30.0, "elements": [
        {"type": "tangent", "length_m": 60.0}]}, "vertical": {"pvis": [{"chainage_m": 0, "u_m": 0}]}})
    spec = IrregularitySpec.from_dict({"psd": {"spectrum": "german_high", "wavelength_min_m": 1.0,
                                               "wavelength_max_m": 50.0}})
    return TrackModel(design, synthesize(spec, design.length_m, np.random.default_rng(5)))


def _geometry(track, with_gauge: bool, reference_rail: str = "left"):
    s = np.arange(3.0, 57.0, 0.004)
    geo, pos_n, R_nb = _known_pose(track, 1.2, (0.0, -0.7175 if reference_rail == "left" else 0.7175, 0.25),
                                   (0, 0, 0), s)
    trolley = TrolleyGeometry(geo.R_vb, np.array(geo.lever_arm_imu_v), 1.2, "left")
    t = s / 1.5
    cfg = GeometryConfig(chords_m=[10.0], repeatability_chords_m=[], repeatability_limits_mm=[])
    gauge = GaugeData(t, track.gauge_m(s)) if with_gauge else None
    return compute_geometry(TrajectoryOnTrack(t, R_nb, pos_n, s), trolley, cfg, 0.25, gauge, None, None, CHECKS)


def test_without_gauge_the_right_rails_lateral_and_the_gauge_are_nan_and_said(track):
    g = _geometry(track, with_gauge=False)
    unmeasured = {"gauge_m", "gauge_variation_mm", "right_lateral_mm", "right_lateral_versine_10m_mm"}
    assert unmeasured <= set(g.metrics["not_measured"])
    assert all(c.startswith("right_lateral") or c.startswith("gauge") for c in g.metrics["not_measured"])
    for c in unmeasured:
        assert np.isnan(g.table[c]).all(), c
    for c in ("left_lateral_mm", "left_lateral_versine_10m_mm", "right_vertical_mm", "cross_level_mm"):
        assert np.isfinite(g.table[c]).sum() > 100, c  # measured: the reference rail, and heights through the roll
    assert g.sidecar()["not_measured"] == g.metrics["not_measured"]
    json.dumps(g.metrics, allow_nan=False)  # metrics.json stays valid
    # the checks on them are skipped, said so; the left rail's lateral check still runs
    skipped = {s["check"]: s.get("columns") for s in g.metrics["skipped_checks"]}
    assert skipped == {"lateral_10m": ["right_lateral_versine_10m_mm"], "gauge": ["gauge_variation_mm"]}
    assert {e["check"] for e in g.metrics["exceedances"]} == {"lateral_10m:left_lateral_versine_10m_mm"}
    assert not verdict_line({"geometry": g.metrics}).startswith("no verdict")  # the left rail was checked


def test_with_a_gauge_sensor_every_column_is_measured(track):
    g = _geometry(track, with_gauge=True)
    assert g.metrics["not_measured"] == {}
    assert np.isfinite(g.table["right_lateral_versine_10m_mm"]).sum() > 100
    assert np.isfinite(g.table["gauge_m"]).all()
    # a real gauge irregularity: the right rail's lateral is not the left's copy
    ok = np.isfinite(g.table["right_lateral_mm"]) & np.isfinite(g.table["left_lateral_mm"])
    assert np.abs(g.table["right_lateral_mm"][ok] - g.table["left_lateral_mm"][ok]).max() > 0.1


def test_report_does_not_draw_a_column_that_is_not_measured(track):
    g = _geometry(track, with_gauge=False)
    metrics = {"geometry": json.loads(json.dumps(g.metrics))}
    run = RunFiles(__import__("pathlib").Path("."), metrics, None, {}, g.table, g.sidecar())
    drawn = []
    import trackfusion.report.html as H
    real = H.figures.series_with_bands

    def spy(s, series, *a, **k):
        drawn.extend(series)
        return real(s, series, *a, **k)
    H.figures.series_with_bands = spy
    try:
        html = geometry_section(run)
    finally:
        H.figures.series_with_bands = real
    assert "Not measured" in html
    assert column_label("right_lateral_mm") in html.split("Not measured", 1)[1]
    assert not [c for c in drawn if c.startswith("right_lateral") or c.startswith("gauge")], drawn
    assert "left_lateral_mm" in drawn and "right_vertical_mm" in drawn


@pytest.mark.parametrize("metrics, line", [
    ({}, "no verdict: no reference and no tolerance table"),
    ({"geometry": {"tolerance_table": "seed002-china", "exceedances": [],
                   "tolerance_checks": [{"name": "a", "columns": ["x"]}, {"name": "b", "columns": ["y"]}],
                   "skipped_checks": [{"check": "a", "reason": "needs a design alignment (inputs.design)"},
                                      {"check": "b", "reason": "needs a design alignment (inputs.design)"}]}},
     "no verdict: tolerance table seed002-china: every check skipped"),
    ({"geometry": {"tolerance_table": "t", "tolerance_checks": [{"name": "a", "columns": ["left_x"]}],
                   "exceedances": [{"check": "a:left_x"}], "skipped_checks": []}},
     "verdict: the survey FAILS tolerance table t: 1 exceedance (a)"),
    ({"geometry": {"tolerance_table": "t", "tolerance_checks": [{"name": "a", "columns": ["left_x"]}],
                   "exceedances": [], "skipped_checks": []}},
     "verdict: the survey MEETS tolerance table t: no exceedance"),
    ({"geometry": {"tolerance_table": "t", "exceedances": [],
                   "tolerance_checks": [{"name": "a", "columns": ["left_x", "right_x"]}],
                   "skipped_checks": [{"check": "a", "columns": ["right_x"], "reason": "not measured (right_x)"}]}},
     "verdict: the survey MEETS tolerance table t: no exceedance (1 check skipped: a not measured (right_x))"),
])
def test_verdict_line(metrics, line):
    assert verdict_line(metrics).startswith(line)


def test_verdict_names_the_failing_figure():
    m = {"evaluation": {"thresholds": {"scale_m": 5.0, "mse_mm": 0.67, "adev_mm": 0.16, "components": ["vertical"]}},
         "relative_accuracy": {"vertical": {"mse_pass": False, "adev_pass": True, "mse_at_threshold_mm": 0.9,
                                            "adev_at_threshold_mm": 0.1}}}
    assert verdict_line(m) == ("verdict: the survey FAILS the relative-accuracy thresholds at 5 m "
                               "(MSE <= 0.67 mm, ADEV <= 0.16 mm): vertical MSE 0.900 mm")


def test_verdict_of_both_sources_says_which_fails():
    m = {"evaluation": {"thresholds": {"scale_m": 5.0, "mse_mm": 0.67, "adev_mm": 0.16, "components": ["lateral"]}},
         "relative_accuracy": {"lateral": {"mse_pass": True, "adev_pass": True, "mse_at_threshold_mm": 0.3,
                                           "adev_at_threshold_mm": 0.1}},
         "geometry": {"tolerance_table": "t", "tolerance_checks": [{"name": "a", "columns": ["left_x"]}],
                      "exceedances": [{"check": "a:left_x"}], "skipped_checks": []}}
    assert verdict_line(m) == ("verdict: the survey FAILS: meets the relative-accuracy thresholds at 5 m "
                               "(MSE <= 0.67 mm, ADEV <= 0.16 mm); fails tolerance table t: 1 exceedance (a)")
