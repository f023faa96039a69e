"""Geodesy against analytic and published values."""

import numpy as np
import pytest

from trackfusion import geodesy as g
from trackfusion.errors import GeodesyError


def test_normal_gravity_equator_and_poles_are_the_defining_constants():
    assert g.normal_gravity_mps2(0.0) == pytest.approx(9.7803253359, rel=1e-12)
    assert g.normal_gravity_mps2(np.pi / 2) == pytest.approx(9.8321849378, rel=1e-12)
    assert g.normal_gravity_mps2(-np.pi / 2) == pytest.approx(9.8321849378, rel=1e-12)


def test_normal_gravity_matches_somigliana_original_form():
    # Somigliana's original form (a ge cos^2 + b gp sin^2) / sqrt(a^2 cos^2 + b^2 sin^2)
    lat = np.radians(np.linspace(-90, 90, 37))
    c2, s2 = np.cos(lat) ** 2, np.sin(lat) ** 2
    expected = (g.A_M * g.GAMMA_E_MPS2 * c2 + g.B_M * g.GAMMA_P_MPS2 * s2) / np.sqrt(
        g.A_M**2 * c2 + g.B_M**2 * s2)
    assert g.normal_gravity_mps2(lat) == pytest.approx(expected, rel=1e-14)
    assert g.normal_gravity_mps2(np.radians(45.0)) == pytest.approx(9.806198, abs=2e-6)


def test_free_air_gradient_near_surface():
    # first-order term: d gamma / dh = -2 gamma / a (1 + f + m - 2 f sin^2) ~ -3.086e-6 s^-2
    lat = np.radians(45.0)
    grad = (g.normal_gravity_mps2(lat, 1.0) - g.normal_gravity_mps2(lat, -1.0)) / 2.0
    assert grad == pytest.approx(-3.086e-6, rel=2e-3)
    # second-order term is 3 gamma h^2 / a^2: compare 10 km against the series by hand
    g0 = g.normal_gravity_mps2(lat)
    s2 = np.sin(lat) ** 2
    expected = g0 * (1 - 2 / g.A_M * (1 + g.F + g.M_RATIO - 2 * g.F * s2) * 1e4 + 3e8 / g.A_M**2)
    assert g.normal_gravity_mps2(lat, 1e4) == pytest.approx(expected, rel=1e-15)


def test_gravity_vector_at_origin_points_down():
    o = g.Origin(45.0, 7.0, 300.0)
    gv = g.gravity_n(np.zeros(3), o)
    assert gv[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
    assert gv[2] == pytest.approx(-g.normal_gravity_mps2(np.radians(45.0), 300.0), rel=1e-12)


def test_gravity_direction_turns_157_microrad_per_km():
    o = g.Origin(45.0, 7.0, 0.0)
    for pos in ([1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0]):
        gv = g.gravity_n(np.array(pos), o)
        tilt = np.arctan2(np.hypot(gv[0], gv[1]), -gv[2])
        assert 150e-6 < tilt < 160e-6
        # the horizontal component points back towards the origin (towards the Earth's centre)
        assert np.dot(gv[:2], pos[:2]) < 0


def test_n_ecef_geodetic_round_trip():
    o = g.Origin(47.3, 8.5, 420.0)
    rng = np.random.default_rng(1)
    pos = rng.uniform(-2000, 2000, size=(1000, 3))
    back = g.ecef_to_n(g.n_to_ecef(pos, o), o)
    assert np.abs(back - pos).max() < 1e-8
    lat, lon, h = g.n_to_geodetic(pos, o)
    assert np.abs(g.geodetic_to_n(lat, lon, h, o) - pos).max() < 1e-6


def test_R_en_is_a_rotation_and_up_is_the_normal():
    R = g.R_en(np.radians([0.0, 45.0, 90.0]), np.radians([0.0, 30.0, -60.0]))
    assert np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max() < 1e-15
    assert np.linalg.det(R) == pytest.approx(np.ones(3))
    assert R[0, :, 2] == pytest.approx([1.0, 0.0, 0.0])


def test_earth_rate_in_n():
    w = g.earth_rate_n(g.Origin(30.0, 0.0))
    assert np.linalg.norm(w) == pytest.approx(7.292115e-5, rel=1e-15)
    assert w[0] == 0.0 and w[2] == pytest.approx(7.292115e-5 * 0.5)


def test_bad_origin_raises():
    with pytest.raises(GeodesyError):
        g.Origin(91.0, 0.0)
    with pytest.raises(GeodesyError):
        g.Origin(float("nan"), 0.0)
