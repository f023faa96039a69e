"""The report's figures: tolerance levels drawn as +-lines, exceedance hot-spots in the PNG's
pixels, the plan's offset from the chord (analytic), labels in words."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.report import figures
from trackfusion.report.html import num
from trackfusion.report.track_plots import column_label


def test_levels_are_drawn_as_plus_minus_lines_and_exceedances_as_spots():
    s = np.arange(0.0, 100.0, 0.25)
    levels = {"alert": 1.0, "intervention": 2.0, "immediate_action": 4.0}
    exc = [{"column": "a_mm", "from_m": 40.0, "to_m": 45.0, "chainage_m": 42.0, "value_mm": 2.5, "label": "E1"}]
    fig, spots = figures.series_with_bands(s, {"a_mm": np.sin(s), "b_mm": np.cos(s)}, {"a_mm": levels}, "t", exc)
    ax_a, ax_b = fig.axes
    flat = sorted({float(np.asarray(ln.get_ydata())[0]) for ln in ax_a.lines
                   if np.ptp(np.asarray(ln.get_ydata(), float)) == 0 and len(ln.get_ydata()) == 2})
    assert flat == [-4.0, -2.0, -1.0, 1.0, 2.0, 4.0]
    assert not [ln for ln in ax_b.lines if len(ln.get_ydata()) == 2]  # no levels for b
    (label, x0, y0, x1, y1), = spots
    png_w, png_h = (fig.get_size_inches() * fig.dpi).round().astype(int)
    # the spot spans 40-45 m on panel a: its pixel x matches the axes' transform, inside the PNG
    xa = ax_a.transData.transform((40.0, 0.0))[0]
    assert label == "E1" and abs(x0 - xa) <= 1 and 0 <= x0 < x1 <= png_w and 0 <= y0 < y1 <= png_h
    assert y1 <= png_h - ax_b.get_window_extent().y1 + 1  # on the upper panel (a), above b


def test_offset_from_chord_of_an_arc_is_its_sagitta():
    R, half = 600.0, 0.2  # a 600 m curve, chainage over +-0.2 rad
    theta = np.linspace(-half, half, 401)
    e, n = R * np.sin(theta), R * (1 - np.cos(theta))  # bends to the left (north) of east
    s = R * theta
    off = figures.offset_from_chord_m(e[::-1], n[::-1], s[::-1])  # order of the rows does not matter
    # the middle lies to the right of the chord (left positive): minus the sagitta R (1 - cos half)
    assert off.min() == pytest.approx(-R * (1 - np.cos(half)), rel=1e-12) and off.max() <= 1e-9
    assert off[0] == pytest.approx(0.0, abs=1e-9) and off[-1] == pytest.approx(0.0, abs=1e-9)


def test_labels_in_words_and_no_negative_zero():
    assert column_label("left_vertical_mm") == "left longitudinal level"
    assert column_label("right_lateral_D2_mm") == "right alignment D2"
    assert column_label("left_vertical_versine_10m_mm") == "left vertical versine, 10 m chord"
    assert column_label("twist_3m_mm") == "twist, 3 m base"
    assert num(-0.004, 2) == "0.00" and num(-0.006, 2) == "-0.01" and num(1.005e3, 1) == "1005.0"
