"""Track model: design alignment against closed forms, irregularity spectra and injections, rails."""

import numpy as np
import pytest
from scipy.signal import welch
from scipy.special import fresnel

from trackfusion.errors import ConfigError, TrackGeometryError
from trackfusion.track.design import DesignAlignment
from trackfusion.simulation.irregularity import IrregularitySpec, german_psd, synthesize
from trackfusion.track.rails import TrackModel

CURVE = {
    "horizontal": {"start_e_m": 100.0, "start_n_m": -50.0, "heading_deg": 20.0, "elements": [
        {"type": "tangent", "length_m": 100}, {"type": "clothoid", "length_m": 80},
        {"type": "arc", "length_m": 200, "radius_m": 500, "cant_mm": 120},
        {"type": "clothoid", "length_m": 80}, {"type": "tangent", "length_m": 100}]},
    "vertical": {"pvis": [{"chainage_m": 0, "u_m": 10}, {"chainage_m": 280, "u_m": 11.0, "curve_length_m": 100},
                          {"chainage_m": 560, "u_m": 10.5}]},
}


@pytest.fixture(scope="module")
def design():
    return DesignAlignment.from_dict(CURVE)


def _rotate(xy, ang):
    c, s = np.cos(ang), np.sin(ang)
    return np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]])


def test_clothoid_matches_fresnel_integrals(design):
    A = np.sqrt(500 * 80.0)
    u = np.linspace(0, 80, 17)
    S, C = fresnel(u / (A * np.sqrt(np.pi)))
    local = A * np.sqrt(np.pi) * np.column_stack([C, S])
    start = design.evaluate([100.0]).pos_n[0, :2]
    expected = start + _rotate(local, np.radians(20.0))
    assert np.abs(design.evaluate(100 + u).pos_n[:, :2] - expected).max() < 1e-9


def test_arc_lies_on_its_circle_and_curvature_is_continuous(design):
    st = design.evaluate(np.linspace(180, 380, 101))
    centre = st.pos_n[:, :2] + 500 * np.column_stack([-np.sin(st.heading_rad), np.cos(st.heading_rad)])
    assert np.ptp(centre, axis=0).max() < 1e-9
    s = np.linspace(0, 560, 56_001)
    st = design.evaluate(s)
    assert np.abs(np.diff(st.curvature_h_1pm)).max() < 1e-6  # no jumps at the joins
    assert np.abs(np.diff(np.unwrap(st.heading_rad))).max() <= 0.01 / 500 * (1 + 1e-9)  # kappa_max ds
    # heading is the derivative of position
    d = np.gradient(st.pos_n[:, :2], s, axis=0)
    assert np.abs(np.arctan2(d[1:-1, 1], d[1:-1, 0]) - st.heading_rad[1:-1]).max() < 1e-8


def test_cant_is_linear_in_transitions_and_raises_the_outer_rail(design):
    st = design.evaluate(np.array([100.0, 140.0, 180.0, 280.0, 420.0, 460.0]))
    # left-hand arc: outer rail is the right one, so cant (left minus right) is negative
    assert st.cant_m == pytest.approx([0.0, -0.06, -0.12, -0.12, -0.06, 0.0], abs=1e-12)
    assert np.degrees(st.cant_rad[3]) == pytest.approx(np.degrees(np.arcsin(-0.12 / 1.5)))


def test_vertical_curve_is_the_analytic_parabola(design):
    g1, g2 = 1.0 / 280, -0.5 / 280
    s = np.linspace(230, 330, 11)
    x = s - 230
    expected = 10 + g1 * 230 + g1 * x + (g2 - g1) / (2 * 100) * x**2
    assert design.evaluate(s).pos_n[:, 2] == pytest.approx(expected, abs=1e-12)
    assert design.evaluate([100.0]).slope_rad[0] == pytest.approx(np.arctan(g1))
    grade_mid = (g1 + g2) / 2
    assert design.evaluate([280.0]).curvature_v_1pm[0] == pytest.approx(
        (g2 - g1) / 100 / (1 + grade_mid**2) ** 1.5, rel=1e-12)


def test_track_frame_is_orthonormal_with_x_along_the_tangent(design):
    s = np.linspace(1, 559, 300)
    R = design.evaluate(s).R_nt
    assert np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max() < 1e-12
    h = 1e-4
    d = (design.evaluate(s + h).pos_n - design.evaluate(s - h).pos_n)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.abs(d - R[:, :, 0]).max() < 1e-7


@pytest.mark.parametrize("bad, field", [
    ({"horizontal": {"elements": [{"type": "arc", "length_m": 10}]}}, "horizontal.elements.0"),
    ({"horizontal": {"elements": [{"type": "tangent", "length_m": -1}]}}, "horizontal.elements.0.length_m"),
    ({"horizontal": {"elements": [{"type": "tangent", "length_m": 10}]}, "typo": 1}, "typo"),
])
def test_bad_alignment_names_the_field(bad, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        DesignAlignment.from_dict(bad)


def test_chainage_outside_the_alignment_raises(design):
    with pytest.raises(TrackGeometryError):
        design.evaluate([600.0])


@pytest.mark.parametrize("component", ["profile", "alignment", "cross_level", "gauge_dev"])
def test_synthesised_spectrum_matches_the_german_psd(component):
    spec = IrregularitySpec.from_dict({"psd": {"spectrum": "german_high", "wavelength_min_m": 2.0,
                                               "wavelength_max_m": 100.0}})
    ds = 0.05
    field = synthesize(spec, 40_000.0, np.random.default_rng(11), ds_m=ds)
    x = field.components[component]
    if component == "cross_level":
        x = x / 1.5  # height difference over 2b -> roll angle, the spectrum's quantity
    nper = 8192
    f, p = welch(x, fs=1 / ds, nperseg=nper, detrend=False)  # one-sided, per cycle/m
    omega = 2 * np.pi * f
    p_omega = p / (2 * np.pi)  # per rad/m
    n_avg = 2 * x.size // nper  # Welch with 50 % overlap
    for lam_lo, lam_hi in [(3.0, 6.0), (6.0, 15.0), (15.0, 40.0)]:
        band = (omega > 2 * np.pi / lam_hi) & (omega < 2 * np.pi / lam_lo)
        ratio = p_omega[band].mean() / german_psd(component, omega[band], "german_high").mean()
        # band averages over many bins and segments: a few per cent of scatter at most
        tol = 4.0 / np.sqrt(band.sum() * n_avg / 2)
        assert ratio == pytest.approx(1.0, abs=max(tol, 0.05)), (lam_lo, lam_hi)


def test_injections_sinusoid_weld_dip_corrugation_and_determinism():
    spec = IrregularitySpec.from_dict({
        "sinusoids": [{"direction": "lateral", "rail": "right", "wavelength_m": 2.0, "amplitude_mm": 1.5,
                       "start_m": 10, "end_m": 30}],
        "weld_dips": [{"rail": "left", "chainage_m": 40.0, "depth_mm": 0.4, "length_m": 0.6}],
        "corrugation": [{"rail": "both", "wavelength_mm": 50.0, "amplitude_mm": 0.05, "start_m": 50, "end_m": 60}],
    })
    f = synthesize(spec, 70.0, np.random.default_rng(0))
    s = f.s_m
    mid = (s > 14) & (s < 26)
    assert np.abs(f.rails["lateral_right"][mid]).max() == pytest.approx(1.5e-3, rel=1e-3)
    assert f.rails["lateral_left"][mid].max() == 0.0
    assert f.evaluate([40.0])["vertical_left"][0] == pytest.approx(-0.4e-3, rel=1e-6)
    assert f.evaluate([40.0])["vertical_right"][0] == 0.0
    seg = f.rails["vertical_right"][(s > 52) & (s < 58)]
    spectrum = np.abs(np.fft.rfft(seg - seg.mean()))
    freqs = np.fft.rfftfreq(seg.size, s[1] - s[0])
    assert 1 / freqs[np.argmax(spectrum)] == pytest.approx(0.05, rel=0.05)
    again = synthesize(spec, 70.0, np.random.default_rng(0))
    assert all(np.array_equal(again.rails[k], f.rails[k]) for k in f.rails)


def test_bad_irregularity_key_names_the_field():
    with pytest.raises(ConfigError, match=r"weld_dips\.0\.depth"):
        IrregularitySpec.from_dict({"weld_dips": [{"chainage_m": 1.0, "depth": 0.3}]})


def test_rails_gauge_and_cant_about_the_low_rail(design):
    spec = IrregularitySpec.from_dict({})
    track = TrackModel(design, synthesize(spec, design.length_m, np.random.default_rng(0), ds_m=0.05))
    s = np.array([50.0, 280.0])
    left, right = track.rail_points_n(s, "left"), track.rail_points_n(s, "right")
    assert np.linalg.norm(left - right, axis=1) == pytest.approx([1.435, 1.435], abs=1e-12)
    st = design.evaluate(s)
    # on the arc the inner (left) rail is low and stays on the gradeline, the right rail is raised
    assert left[1, 2] == pytest.approx(st.pos_n[1, 2], abs=1e-12)
    # rolled about the sloping tangent: rise = gauge sin(cant) cos(slope)
    assert right[1, 2] - left[1, 2] == pytest.approx(1.435 * 0.12 / 1.5 * np.cos(st.slope_rad[1]), abs=1e-12)
    assert track.gauge_m(s) == pytest.approx([1.435, 1.435])
