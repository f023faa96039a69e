"""Total-station polar geometry: round trips, conventions, Earth curvature."""

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.registration.polar import StationSetup, n_to_polar, polar_to_n

ORIGIN = geodesy.Origin(22.9, 112.9, 10.0)
ARCSEC = np.pi / 180 / 3600


def test_polar_n_polar_round_trip_1e9_m():
    st = StationSetup("TS01", (3.0, -20.0, 1.6), orientation_rad=0.7, tilt_rad=(4 * ARCSEC, -3 * ARCSEC))
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1000, -1000, -5], [1000, 1000, 5], size=(500, 3))
    hz, zen, d = n_to_polar(pts, st, ORIGIN)
    assert np.abs(polar_to_n(hz, zen, d, st, ORIGIN) - pts).max() < 1e-9
    back = n_to_polar(polar_to_n(hz, zen, d, st, ORIGIN), st, ORIGIN)
    assert np.abs(back[2] - d).max() < 1e-9
    assert np.abs(np.angle(np.exp(1j * (back[0] - hz)))).max() * 1000 < 1e-9  # 1e-9 m at 1 km
    assert np.abs(back[1] - zen).max() * 1000 < 1e-9


def test_horizontal_angle_clockwise_from_orientation():
    st = StationSetup("S", (0.0, 0.0, 0.0), orientation_rad=0.0)
    hz, zen, d = n_to_polar(np.array([[0.0, 100.0, 0.0], [100.0, 0.0, 0.0]]), st, ORIGIN, refraction_k=0.0)
    assert hz[0] == pytest.approx(0.0, abs=1e-6) or hz[0] == pytest.approx(2 * np.pi, abs=1e-6)
    assert hz[1] == pytest.approx(np.pi / 2, abs=1e-5)  # due east reads +90 deg


def test_earth_curvature_level_surface_below_tangent_plane():
    """A point 500 m away at the station's ellipsoidal height lies ~20 mm below its horizon (and n's)."""
    st = StationSetup("S", (0.0, 0.0, 0.0))
    lat, lon, h = geodesy.n_to_geodetic(np.array([500.0, 0.0, 0.0]), ORIGIN)
    on_level = geodesy.geodetic_to_n(lat, lon, ORIGIN.h_m, ORIGIN)
    assert on_level[2] == pytest.approx(-0.0196, abs=3e-4)  # n's tangent plane is ~20 mm above
    hz, zen, d = n_to_polar(on_level[None, :], st, ORIGIN, refraction_k=0.0)
    assert d[0] * np.cos(zen[0]) == pytest.approx(-500.0**2 / (2 * 6.38e6), rel=0.01)
    back = polar_to_n(hz, zen, d, st, ORIGIN, refraction_k=0.0)
    assert np.abs(back - on_level).max() < 1e-9


def test_refraction_lifts_the_target():
    st = StationSetup("S", (0.0, 0.0, 0.0))
    p = np.array([[0.0, 800.0, 1.0]])
    z0 = n_to_polar(p, st, ORIGIN, refraction_k=0.0)[1]
    z1 = n_to_polar(p, st, ORIGIN, refraction_k=0.13)[1]
    assert (z0 - z1)[0] == pytest.approx(0.13 * 800 / (2 * 6_371_000), rel=1e-3)


def test_tilt_moves_the_reading_by_its_angle():
    tilt = 4 * ARCSEC
    level = StationSetup("S", (0.0, 0.0, 0.0))
    tilted = StationSetup("S", (0.0, 0.0, 0.0), tilt_rad=(tilt, 0.0))  # about east: north side up
    p = np.array([[0.0, 500.0, 0.0]])
    dz = n_to_polar(p, tilted, ORIGIN, 0.0)[1] - n_to_polar(p, level, ORIGIN, 0.0)[1]
    assert abs(dz[0]) == pytest.approx(tilt, rel=1e-6)
    assert abs(dz[0]) * 500 == pytest.approx(0.0097, abs=2e-4)  # seed 003: 0.5 km sin(4") = 9.7 mm
