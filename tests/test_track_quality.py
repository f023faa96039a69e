"""The track quality index (standard deviation per 200 m section) and EN 13848-5 style levels of
tolerance checks, against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.errors import ConfigError
from trackfusion.geometry_inputs import load_tolerances
from trackfusion.track.geometry import ToleranceCheck, limit_exceedances
from trackfusion.track.quality import quality_index, section_std

STEP = 0.25


def test_sinusoid_over_whole_periods_has_std_amplitude_over_root_two():
    s = np.arange(0.0, 400.0, STEP)
    v = 1.7 * np.sin(2 * np.pi * s / 20.0) + 0.3  # the mean is removed per section
    secs = section_std(s, v, STEP)
    assert [(x["from_m"], x["to_m"], x["samples"], x["coverage"]) for x in secs] == \
        [(0.0, 200.0, 800, 1.0), (200.0, 400.0, 800, 1.0)]
    for x in secs:
        assert x["std"] == pytest.approx(1.7 / np.sqrt(2), rel=1e-12)


def test_ramp_has_the_discrete_uniform_std():
    s = np.arange(0.0, 200.0, STEP)
    (sec,) = section_std(s, 2.0 * s, STEP)
    n = s.size
    assert sec["std"] == pytest.approx(2.0 * STEP * np.sqrt((n * n - 1) / 12.0), rel=1e-12)


def test_sections_align_on_whole_multiples_and_need_half_coverage():
    s = np.arange(150.0, 600.0, STEP)
    v = np.where(s < 400, np.cos(2 * np.pi * s / 10.0), 5.0 * np.cos(2 * np.pi * s / 10.0))
    v[(s >= 400) & (s < 540)] = np.nan  # 70 % of the third section not measured
    secs = section_std(s, v, STEP)
    assert [x["from_m"] for x in secs] == [0.0, 200.0, 400.0]
    assert secs[0]["coverage"] == 0.25 and secs[0]["std"] is None
    assert secs[1]["std"] == pytest.approx(1 / np.sqrt(2), rel=1e-12)
    assert secs[2]["coverage"] == pytest.approx(0.3) and secs[2]["std"] is None
    assert section_std(s, v, STEP, min_coverage=0.3)[2]["std"] == pytest.approx(5 / np.sqrt(2), rel=1e-12)


def test_quality_index_lists_unmeasured_columns():
    s = np.arange(0.0, 200.0, STEP)
    table = {"chainage_m": s, "left_vertical_mm": np.sin(2 * np.pi * s / 25.0), "right_vertical_mm": np.full_like(s, np.nan)}
    qi = quality_index(table, STEP, {"left longitudinal level": "left_vertical_mm",
                                     "right longitudinal level": "right_vertical_mm", "left alignment": "left_lateral_mm"})
    assert qi["columns"] == {"left longitudinal level": "left_vertical_mm"}
    assert qi["not_measured"] == ["left alignment", "right longitudinal level"]
    assert qi["sections"] == [{"from_m": 0.0, "to_m": 200.0,
                               "left longitudinal level": pytest.approx(1 / np.sqrt(2), rel=1e-12)}]


def test_levels_classify_each_stretch_by_its_peak():
    s = np.arange(0.0, 100.0, STEP)
    v = np.zeros_like(s)
    v[(s >= 10) & (s < 12)] = 3.0   # alert only
    v[(s >= 40) & (s <= 45)] = -5.0  # beyond intervention
    v[s == 70.0] = 9.0               # beyond immediate action, one sample
    check = ToleranceCheck("ll", "limit", quantity="longitudinal_level", alert_mm=2.0, intervention_mm=4.0,
                           immediate_action_mm=8.0)
    table = {"chainage_m": s, "left_vertical_mm": v, "right_vertical_mm": np.full_like(s, np.nan)}
    ex = limit_exceedances(table, check, STEP)
    assert [(e["column"], e["from_m"], e["to_m"], e["length_m"], e["value_mm"], e["level"], e["limit_mm"])
            for e in ex] == [("left_vertical_mm", 10.0, 11.75, 2.0, 3.0, "alert", 2.0),
                             ("left_vertical_mm", 40.0, 45.0, 5.25, -5.0, "intervention", 4.0),
                             ("left_vertical_mm", 70.0, 70.0, 0.25, 9.0, "immediate_action", 8.0)]


def test_tables_with_levels_load_and_old_tables_keep_one_limit(tmp_path):
    _, (old,) = load_tolerances("seed000-shortwave")
    assert old.levels() == [("limit", 2.0)]
    p = tmp_path / "t.yaml"
    p.write_text("name: mine\nchecks:\n  - {name: ll, kind: limit, quantity: longitudinal_level, "
                 "alert_mm: 6, intervention_mm: 10, immediate_action_mm: 15}\n")
    name, (c,) = load_tolerances(str(p))
    assert name == "mine" and c.limit_mm == 6 and c.levels()[-1] == ("immediate_action", 15.0)
    p.write_text("checks:\n  - {name: ll, kind: limit, quantity: alignment, alert_mm: 6, intervention_mm: 5}\n")
    with pytest.raises(ConfigError, match="must increase"):
        load_tolerances(str(p))
    p.write_text("checks:\n  - {name: ll, kind: limit, quantity: alignment}\n")
    with pytest.raises(ConfigError, match="needs limit_mm"):
        load_tolerances(str(p))
