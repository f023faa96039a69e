"""Total-station polar geometry: round trips, conventions, Earth curvature, tilt, refraction."""

import numpy as np
import pytest

from trackfusion import geodesy
from trackfusion.errors import RegistrationError
from trackfusion.registration.polar import StationSetup, gaussian_radius_m, n_to_polar, polar_to_n

ORIGIN = geodesy.Origin(22.9, 112.9, 10.0)
ARCSEC = np.pi / 180 / 3600


def _wrap(a):
    return np.angle(np.exp(1j * a))


@pytest.mark.parametrize("height", [0.0, 1.55])
def test_polar_n_polar_round_trip_1e9_m(height):
    st = StationSetup("TS01", (3.0, -20.0, 1.6), orientation_rad=0.7, tilt_rad=(4 * ARCSEC, -3 * ARCSEC),
                      instrument_height_m=height)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1000, -1000, -5], [1000, 1000, 5], size=(500, 3))
    hz, zen, d = n_to_polar(pts, st, ORIGIN)
    assert np.abs(polar_to_n(hz, zen, d, st, ORIGIN) - pts).max() < 1e-9
    back = n_to_polar(polar_to_n(hz, zen, d, st, ORIGIN), st, ORIGIN)
    assert np.abs(back[2] - d).max() < 1e-9
    assert np.abs(_wrap(back[0] - hz)).max() * 1000 < 1e-9  # 1e-9 m at 1 km
    assert np.abs(back[1] - zen).max() * 1000 < 1e-9


def test_polar_to_n_to_polar_round_trip_from_readings():
    st = StationSetup("TS02", (-400.0, 250.0, 3.0), orientation_rad=4.0, tilt_rad=(-2 * ARCSEC, 1 * ARCSEC))
    rng = np.random.default_rng(1)
    hz = rng.uniform(0, 2 * np.pi, 300)
    zen = rng.uniform(np.radians(80), np.radians(100), 300)
    d = rng.uniform(1.0, 1000.0, 300)
    hz2, zen2, d2 = n_to_polar(polar_to_n(hz, zen, d, st, ORIGIN, 0.2), st, ORIGIN, 0.2)
    assert np.abs(_wrap(hz2 - hz) * d).max() < 1e-9
    assert np.abs((zen2 - zen) * d).max() < 1e-9
    assert np.abs(d2 - d).max() < 1e-9


def test_horizontal_angle_clockwise_from_orientation():
    st = StationSetup("S", (0.0, 0.0, 0.0), orientation_rad=0.0)
    pts = np.array([[0.0, 100.0, 0.0], [100.0, 0.0, 0.0], [0.0, -100.0, 0.0], [-100.0, 0.0, 0.0]])
    hz, zen, d = n_to_polar(pts, st, ORIGIN, refraction_k=0.0)
    assert min(hz[0], 2 * np.pi - hz[0]) < 1e-6  # due north reads 0
    assert hz[1] == pytest.approx(np.pi / 2, abs=1e-5)  # due east reads +90 deg (clockwise)
    assert hz[2] == pytest.approx(np.pi, abs=1e-5)
    assert hz[3] == pytest.approx(3 * np.pi / 2, abs=1e-5)
    assert np.all(zen == pytest.approx(np.pi / 2, abs=1e-4))
    east = StationSetup("S", (0.0, 0.0, 0.0), orientation_rad=np.pi / 2)  # zero direction points east
    assert abs(_wrap(n_to_polar(pts[1], east, ORIGIN, 0.0)[0][0])) < 1e-6
    assert n_to_polar(pts[0], east, ORIGIN, 0.0)[0][0] == pytest.approx(1.5 * np.pi, abs=1e-5)


def test_earth_curvature_level_surface_below_tangent_plane():
    """A point 500 m away on the station's level surface: n's tangent plane lies ~20 mm above it,
    while the levelled station sees it at the height difference zero after the usual
    curvature-and-refraction correction (S cos z + (1 - k) s^2 / 2R)."""
    st = StationSetup("S", (0.0, 0.0, 0.0))
    lat, lon, h = geodesy.n_to_geodetic(np.array([500.0, 0.0, 0.0]), ORIGIN)
    on_level = geodesy.geodetic_to_n(lat, lon, ORIGIN.h_m, ORIGIN)
    assert on_level[2] == pytest.approx(-0.0196, abs=3e-4)  # n's tangent plane is ~20 mm above
    R = gaussian_radius_m(np.radians(ORIGIN.lat_deg))
    for k in (0.0, 0.13):
        hz, zen, d = n_to_polar(on_level[None, :], st, ORIGIN, refraction_k=k)
        s = d[0] * np.sin(zen[0])
        dh = d[0] * np.cos(zen[0]) + (1 - k) * s**2 / (2 * R)
        assert abs(dh) < 1e-4  # zero-ish height difference on the level surface
        assert np.abs(polar_to_n(hz, zen, d, st, ORIGIN, k) - on_level).max() < 1e-9


def test_refraction_lifts_the_target():
    st = StationSetup("S", (0.0, 0.0, 0.0))
    p = np.array([[0.0, 800.0, 1.0]])
    z0 = n_to_polar(p, st, ORIGIN, refraction_k=0.0)[1]
    z1 = n_to_polar(p, st, ORIGIN, refraction_k=0.13)[1]
    R = gaussian_radius_m(np.radians(ORIGIN.lat_deg))
    assert 6.33e6 < R < 6.39e6
    assert (z0 - z1)[0] == pytest.approx(0.13 * np.linalg.norm(p) / (2 * R), rel=1e-9)


def test_tilt_moves_the_reading_by_its_angle():
    tilt = 4 * ARCSEC
    level = StationSetup("S", (0.0, 0.0, 0.0))
    tilted = StationSetup("S", (0.0, 0.0, 0.0), tilt_rad=(tilt, 0.0))  # about east: axis top leans south
    p = np.array([[0.0, 500.0, 0.0]])
    dz = n_to_polar(p, tilted, ORIGIN, 0.0)[1] - n_to_polar(p, level, ORIGIN, 0.0)[1]
    assert dz[0] == pytest.approx(tilt, rel=1e-6)  # the axis leans away: the north point reads lower
    assert abs(dz[0]) * 500 == pytest.approx(0.0097, abs=2e-4)  # seed 003: 0.5 km sin(4") = 9.7 mm
    tilted_n = StationSetup("S", (0.0, 0.0, 0.0), tilt_rad=(0.0, tilt))  # about north: top leans east
    q = np.array([[500.0, 0.0, 0.0]])
    dz_e = n_to_polar(q, tilted_n, ORIGIN, 0.0)[1] - n_to_polar(q, level, ORIGIN, 0.0)[1]
    assert dz_e[0] == pytest.approx(-tilt, rel=1e-6)


def test_instrument_height_and_geodetic_setup():
    mark = np.array([120.0, -40.0, 2.0])
    lat, lon, h = geodesy.n_to_geodetic(mark, ORIGIN)
    a = StationSetup.from_geodetic("S", lat, lon, h, ORIGIN, orientation_rad=0.3, instrument_height_m=1.6)
    b = StationSetup("S", tuple(mark), 0.3, instrument_height_m=1.6)
    assert np.allclose(a.pos_n, mark, atol=1e-8)
    p = np.array([[400.0, 300.0, 1.0]])
    assert np.allclose(np.array(n_to_polar(p, a, ORIGIN)), np.array(n_to_polar(p, b, ORIGIN)), atol=1e-10)
    # the instrument point is 1.6 m up the ellipsoid normal at the mark
    pos_e, R_ek = b.instrument_ecef(ORIGIN)
    assert np.linalg.norm(pos_e - geodesy.n_to_ecef(mark, ORIGIN)) == pytest.approx(1.6, abs=1e-9)
    up_n = geodesy.R_n_local(mark, ORIGIN)[:, 2]  # ellipsoid normal at the mark, in n
    hz, zen, d = n_to_polar(mark + 1.6 * up_n, b, ORIGIN)
    assert d[0] < 1e-9


def test_invalid_input_raises_registration_error():
    st = StationSetup("S", (0.0, 0.0, 0.0))
    with pytest.raises(RegistrationError):
        polar_to_n([0.1], [1.5], [-1.0], st, ORIGIN)
    with pytest.raises(RegistrationError):
        n_to_polar(np.array([[np.nan, 0.0, 0.0]]), st, ORIGIN)
    with pytest.raises(RegistrationError):
        StationSetup("S", (0.0, np.inf, 0.0))
