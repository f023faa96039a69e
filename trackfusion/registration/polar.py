"""Total-station polar geometry, exact through ECEF.

Frames and conventions
----------------------
- Instrument point: the centre of the tilting (trunnion) axis. A set-up gives
  either that point directly (``instrument_height_m = 0``) or a ground mark
  plus the instrument height measured along the plumb line.
- Station level frame ``k``: the local ENU frame at the instrument point, z up
  along the *ellipsoid normal*. The deflection of the vertical (plumb line
  minus ellipsoid normal, a few arcseconds) is ignored: a real instrument
  levels to the plumb line, so a deflection acts like an extra tilt of the
  vertical axis.
- Instrument frame ``i``: ``R_ki = exp([tilt_e, tilt_n, 0]^)``, a small rotation
  of ``k`` about its east axis by ``tilt_rad[0]`` and about its north axis by
  ``tilt_rad[1]``. To first order the top of the vertical axis leans
  ``tilt_rad[1]`` towards east and ``tilt_rad[0]`` towards south.
- Horizontal angle ``hz`` [rad, 0..2 pi): clockwise (surveying convention),
  seen from above, from the instrument's zero direction; the zero direction's
  azimuth (clockwise from north) is ``orientation_rad``. A point due north of
  a level station oriented north reads 0, due east reads +pi/2.
- Zenith angle [rad]: from the instrument's vertical axis (up = 0), as read,
  i.e. after refraction. The line of sight bends towards the ground with
  curvature ``k / R``, so the target looks higher by ``k S / (2 R)``:
  ``zenith_obs = zenith_geometric - k S / (2 R)`` with the refraction
  coefficient ``k`` (0.13 by default; 0 disables), slope distance ``S`` and
  the Gaussian radius of curvature ``R = sqrt(M N)`` at the station. (Using
  ``S`` instead of the horizontal distance changes the correction by less than
  1e-4 of itself at usual zenith angles; the inverse uses the same formula, so
  round trips are exact.)
- Slope distance ``S`` [m]: instrument point to target, straight line.

Because every conversion goes through ECEF (``geodesy.n_to_ecef`` /
``geodesy.ecef_to_n``) Earth curvature is exact: at 500 m the tangent plane of
``n`` lies about 20 mm above the level surface, and a station's own horizon
differs from ``n``'s by the angle between the two ellipsoid normals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import geodesy
from ..errors import RegistrationError
from ..rotations import so3_exp

DEFAULT_REFRACTION_K = 0.13  #: coefficient of terrestrial refraction (Gauss) [-]


def gaussian_radius_m(lat_rad) -> np.ndarray:
    """Gaussian mean radius of curvature ``sqrt(M N) = a sqrt(1 - e^2) / (1 - e^2 sin^2 lat)`` [m]."""
    s2 = np.sin(np.asarray(lat_rad, dtype=float)) ** 2
    return geodesy.A_M * np.sqrt(1.0 - geodesy.E2) / (1.0 - geodesy.E2 * s2)


@dataclass(frozen=True)
class StationSetup:
    """A total-station set-up.

    ``station_id``; ``pos_n`` (3,) [m] position in ``n`` of the instrument point
    (or of the ground mark when ``instrument_height_m`` > 0: the instrument
    point is then that far above it along the ellipsoid normal);
    ``orientation_rad`` azimuth (clockwise from north) of the zero direction of
    the horizontal circle; ``tilt_rad`` (about east, about north) small
    rotation of the vertical axis from the ellipsoid normal (see the module
    docstring); ``instrument_height_m`` [m]. Use :meth:`from_geodetic` for a
    set-up given in latitude, longitude and ellipsoidal height.
    """

    station_id: str
    pos_n: tuple[float, float, float]
    orientation_rad: float = 0.0
    tilt_rad: tuple[float, float] = (0.0, 0.0)
    instrument_height_m: float = 0.0

    def __post_init__(self) -> None:
        values = np.concatenate([np.ravel(np.asarray(self.pos_n, dtype=float)),
                                 np.ravel(np.asarray(self.tilt_rad, dtype=float)),
                                 [self.orientation_rad, self.instrument_height_m]])
        if values.size != 7 or not np.all(np.isfinite(values)):
            raise RegistrationError(f"station {self.station_id}: pos_n needs 3 finite values and tilt_rad 2, "
                                    f"got pos_n={self.pos_n}, tilt_rad={self.tilt_rad}, "
                                    f"orientation_rad={self.orientation_rad}, "
                                    f"instrument_height_m={self.instrument_height_m}")

    @classmethod
    def from_geodetic(cls, station_id: str, lat_deg: float, lon_deg: float, h_m: float,
                      origin: geodesy.Origin, orientation_rad: float = 0.0,
                      tilt_rad: tuple[float, float] = (0.0, 0.0),
                      instrument_height_m: float = 0.0) -> "StationSetup":
        """Set-up from the geodetic position [deg, deg, m ellipsoidal] of the instrument point (or mark)."""
        pos = geodesy.geodetic_to_n(lat_deg, lon_deg, h_m, origin)
        return cls(station_id, tuple(float(x) for x in pos), float(orientation_rad),
                   (float(tilt_rad[0]), float(tilt_rad[1])), float(instrument_height_m))

    def instrument_ecef(self, origin: geodesy.Origin) -> tuple[np.ndarray, np.ndarray]:
        """(instrument point in ECEF [m] (3,), rotation ``R_ek`` (3, 3) of its level frame to ECEF)."""
        mark_e = geodesy.n_to_ecef(np.asarray(self.pos_n, dtype=float), origin)
        lat, lon, _ = geodesy.ecef_to_geodetic(mark_e)
        R_ek = geodesy.R_en(np.radians(lat), np.radians(lon))
        return mark_e + self.instrument_height_m * R_ek[:, 2], R_ek

    def R_ei(self, origin: geodesy.Origin) -> tuple[np.ndarray, np.ndarray]:
        """(``R_ei`` (3, 3) instrument frame -> ECEF, instrument point in ECEF [m] (3,))."""
        pos_e, R_ek = self.instrument_ecef(origin)
        R_ki = so3_exp(np.array([self.tilt_rad[0], self.tilt_rad[1], 0.0]))
        return R_ek @ R_ki, pos_e

    def latitude_rad(self, origin: geodesy.Origin) -> float:
        """Geodetic latitude of the instrument point [rad]."""
        lat, _, _ = geodesy.ecef_to_geodetic(self.instrument_ecef(origin)[0])
        return float(np.radians(lat))


def _refraction_rad(slope_distance_m: np.ndarray, station: StationSetup, origin: geodesy.Origin,
                    refraction_k: float) -> np.ndarray:
    """Apparent lift ``k S / (2 R)`` [rad] of a target at slope distance ``S`` (N,)."""
    if not np.isfinite(refraction_k):
        raise RegistrationError(f"station {station.station_id}: refraction_k must be finite, got {refraction_k}")
    if refraction_k == 0.0:
        return np.zeros_like(slope_distance_m)
    return refraction_k * slope_distance_m / (2.0 * gaussian_radius_m(station.latitude_rad(origin)))


def n_to_polar(points_n, station: StationSetup, origin: geodesy.Origin,
               refraction_k: float = DEFAULT_REFRACTION_K) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Polar readings of points in ``n``.

    points_n: (N, 3) or (3,) [m]. Returns (hz_rad, zenith_rad, slope_distance_m), each (N,):
    horizontal angle in [0, 2 pi) clockwise from the zero direction, zenith angle as read
    (refraction applied), slope distance [m].
    """
    pts = np.atleast_2d(np.asarray(points_n, dtype=float))
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise RegistrationError(f"station {station.station_id}: points_n must be finite (N, 3), got {pts.shape}")
    R_ei, s_e = station.R_ei(origin)
    d_i = (geodesy.n_to_ecef(pts, origin) - s_e) @ R_ei  # rows: R_ie @ (p_e - s_e)
    dist = np.linalg.norm(d_i, axis=-1)
    azimuth_i = np.arctan2(d_i[:, 0], d_i[:, 1])  # clockwise from the instrument's north
    hz = np.mod(azimuth_i - station.orientation_rad, 2.0 * np.pi)
    zenith_geo = np.arctan2(np.hypot(d_i[:, 0], d_i[:, 1]), d_i[:, 2])
    return hz, zenith_geo - _refraction_rad(dist, station, origin, refraction_k), dist


def polar_to_n(hz_rad, zenith_rad, slope_distance_m, station: StationSetup, origin: geodesy.Origin,
               refraction_k: float = DEFAULT_REFRACTION_K) -> np.ndarray:
    """Points (N, 3) in ``n`` [m] from polar readings, each (N,) [rad, rad, m]; inverse of :func:`n_to_polar`."""
    hz, zen, dist = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (hz_rad, zenith_rad, slope_distance_m))
    if not (hz.shape == zen.shape == dist.shape) or hz.ndim != 1:
        raise RegistrationError(f"station {station.station_id}: polar readings must be (N,) of equal length, "
                                f"got {hz.shape}, {zen.shape}, {dist.shape}")
    if not (np.all(np.isfinite(hz)) and np.all(np.isfinite(zen)) and np.all(np.isfinite(dist))) \
            or np.any(dist < 0):
        raise RegistrationError(f"station {station.station_id}: polar readings must be finite with "
                                "slope_distance_m >= 0")
    zen_geo = zen + _refraction_rad(dist, station, origin, refraction_k)
    az = hz + station.orientation_rad
    horiz = dist * np.sin(zen_geo)
    d_i = np.stack([horiz * np.sin(az), horiz * np.cos(az), dist * np.cos(zen_geo)], axis=-1)
    R_ei, s_e = station.R_ei(origin)
    return geodesy.ecef_to_n(s_e + d_i @ R_ei.T, origin)
