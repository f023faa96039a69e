"""WGS-84 geodesy: ellipsoid, normal gravity, Earth rate and the frames e / n.

Frames (see the package docstring): ``e`` is ECEF (WGS-84), ``n`` is the
Earth-fixed local ENU tangent frame at the survey origin. Conversions between
geodetic, ECEF and ``n`` go through :mod:`pymap3d`; every function is
vectorised over leading axes.

Normal gravity is WGS-84's: Somigliana's closed formula on the ellipsoid
(NIMA TR8350.2, eq. 4-1) with the second-order expansion in ellipsoidal
height (eq. 4-3), directed along the ellipsoid normal (down). Because ``n`` is
a fixed tangent frame, the gravity vector seen in ``n`` turns by about
157 microradians per km travelled: :func:`gravity_n` evaluates it at each
point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d

from .errors import GeodesyError

# --- WGS-84 defining and derived constants (NIMA TR8350.2, tables 3.1-3.3) ---
A_M = 6378137.0  #: semi-major axis a [m]
F = 1.0 / 298.257223563  #: flattening f [-]
GM_M3PS2 = 3.986004418e14  #: geocentric gravitational constant [m^3/s^2]
OMEGA_IE_RADPS = 7.292115e-5  #: Earth rotation rate [rad/s]
B_M = A_M * (1.0 - F)  #: semi-minor axis b [m]
E2 = F * (2.0 - F)  #: first eccentricity squared [-]
GAMMA_E_MPS2 = 9.7803253359  #: normal gravity at the equator [m/s^2]
GAMMA_P_MPS2 = 9.8321849378  #: normal gravity at the poles [m/s^2]
K_SOMIGLIANA = B_M * GAMMA_P_MPS2 / (A_M * GAMMA_E_MPS2) - 1.0  #: Somigliana's k [-]
M_RATIO = OMEGA_IE_RADPS**2 * A_M**2 * B_M / GM_M3PS2  #: m = w^2 a^2 b / GM [-]

_ELLIPSOID = pymap3d.Ellipsoid.from_name("wgs84")


@dataclass(frozen=True)
class Origin:
    """Origin of the local frame ``n``: geodetic latitude/longitude [deg], ellipsoidal height [m]."""

    lat_deg: float
    lon_deg: float
    h_m: float = 0.0

    def __post_init__(self) -> None:
        if not all(np.isfinite([self.lat_deg, self.lon_deg, self.h_m])):
            raise GeodesyError(f"origin: non-finite value {self}")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise GeodesyError(f"origin: lat_deg={self.lat_deg} outside [-90, 90]")

    def to_dict(self) -> dict[str, float]:
        """``{"lat_deg", "lon_deg", "h_m"}`` as written in every JSON sidecar."""
        return {"lat_deg": float(self.lat_deg), "lon_deg": float(self.lon_deg), "h_m": float(self.h_m)}

    @classmethod
    def from_dict(cls, d: dict) -> "Origin":
        """Inverse of :meth:`to_dict`."""
        return cls(float(d["lat_deg"]), float(d["lon_deg"]), float(d.get("h_m", 0.0)))


def normal_gravity_mps2(lat_rad, h_m=0.0):
    """Magnitude of WGS-84 normal gravity [m/s^2].

    lat_rad: geodetic latitude [rad], any shape; h_m: ellipsoidal height [m],
    broadcastable. Somigliana on the ellipsoid (TR8350.2 eq. 4-1) times the
    second-order height factor (eq. 4-3):
    ``1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2``.
    """
    s2 = np.sin(lat_rad) ** 2
    gamma0 = GAMMA_E_MPS2 * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    h = np.asarray(h_m, dtype=float)
    factor = 1.0 - 2.0 / A_M * (1.0 + F + M_RATIO - 2.0 * F * s2) * h + 3.0 * h**2 / A_M**2
    return gamma0 * factor


def R_en(lat_rad, lon_rad):
    """Rotation from local ENU at (lat, lon) to ECEF, shape (..., 3, 3).

    Columns are the east, north and up unit vectors in ``e``.
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat + lon)
    east = np.stack([-so + z, co + z, z], axis=-1)
    north = np.stack([-sl * co, -sl * so, cl + z], axis=-1)
    up = np.stack([cl * co, cl * so, sl + z], axis=-1)
    return np.stack([east, north, up], axis=-1)


def origin_R_en(origin: Origin) -> np.ndarray:
    """Rotation from ``n`` (ENU at the origin) to ECEF, shape (3, 3)."""
    return R_en(np.radians(origin.lat_deg), np.radians(origin.lon_deg))


def earth_rate_n(origin: Origin) -> np.ndarray:
    """Earth rotation vector expressed in ``n`` [rad/s], shape (3,): (0, w cos(lat0), w sin(lat0))."""
    lat = np.radians(origin.lat_deg)
    return np.array([0.0, OMEGA_IE_RADPS * np.cos(lat), OMEGA_IE_RADPS * np.sin(lat)])


def geodetic_to_ecef(lat_deg, lon_deg, h_m) -> np.ndarray:
    """Geodetic [deg, deg, m] to ECEF [m], shape (..., 3)."""
    x, y, z = pymap3d.geodetic2ecef(lat_deg, lon_deg, h_m, ell=_ELLIPSOID, deg=True)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1).astype(float)


def ecef_to_geodetic(xyz_e) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF [m], shape (..., 3), to geodetic (lat_deg, lon_deg, h_m)."""
    xyz = np.asarray(xyz_e, dtype=float)
    lat, lon, h = pymap3d.ecef2geodetic(xyz[..., 0], xyz[..., 1], xyz[..., 2], ell=_ELLIPSOID, deg=True)
    return np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float)


def n_to_ecef(pos_n, origin: Origin) -> np.ndarray:
    """Positions in ``n`` [m], shape (..., 3), to ECEF [m], shape (..., 3)."""
    pos = np.asarray(pos_n, dtype=float)
    x, y, z = pymap3d.enu2ecef(pos[..., 0], pos[..., 1], pos[..., 2],
                               origin.lat_deg, origin.lon_deg, origin.h_m, ell=_ELLIPSOID, deg=True)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1).astype(float)


def ecef_to_n(xyz_e, origin: Origin) -> np.ndarray:
    """ECEF positions [m], shape (..., 3), to ``n`` [m], shape (..., 3)."""
    xyz = np.asarray(xyz_e, dtype=float)
    e, n, u = pymap3d.ecef2enu(xyz[..., 0], xyz[..., 1], xyz[..., 2],
                               origin.lat_deg, origin.lon_deg, origin.h_m, ell=_ELLIPSOID, deg=True)
    return np.stack(np.broadcast_arrays(e, n, u), axis=-1).astype(float)


def geodetic_to_n(lat_deg, lon_deg, h_m, origin: Origin) -> np.ndarray:
    """Geodetic [deg, deg, m] to ``n`` [m], shape (..., 3)."""
    lat = np.asarray(lat_deg, dtype=float)
    if np.any(~np.isfinite(lat)) or np.any(np.abs(lat) > 90.0):
        raise GeodesyError("latitude must be finite and within [-90, 90] deg")
    e, n, u = pymap3d.geodetic2enu(lat, lon_deg, h_m, origin.lat_deg, origin.lon_deg, origin.h_m,
                                   ell=_ELLIPSOID, deg=True)
    return np.stack(np.broadcast_arrays(e, n, u), axis=-1).astype(float)


def n_to_geodetic(pos_n, origin: Origin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions in ``n`` [m], shape (..., 3), to geodetic (lat_deg, lon_deg, h_m)."""
    return ecef_to_geodetic(n_to_ecef(pos_n, origin))


def R_n_local(pos_n, origin: Origin) -> np.ndarray:
    """Rotation from the local ENU frame at each point to ``n``, shape (..., 3, 3)."""
    lat, lon, _ = n_to_geodetic(pos_n, origin)
    return np.swapaxes(origin_R_en(origin), -1, -2) @ R_en(np.radians(lat), np.radians(lon))


def gravity_n(pos_n, origin: Origin) -> np.ndarray:
    """Normal gravity vector in ``n`` at each point [m/s^2], shape (..., 3).

    Magnitude :func:`normal_gravity_mps2` at the point's latitude and height,
    direction minus the ellipsoid normal at the point, rotated into ``n``.
    At the origin this is (0, 0, -gamma).
    """
    lat, lon, h = n_to_geodetic(pos_n, origin)
    up_e = R_en(np.radians(lat), np.radians(lon))[..., :, 2]
    up_n = up_e @ origin_R_en(origin)  # (R_en0^T up_e) for row vectors
    return -normal_gravity_mps2(np.radians(lat), h)[..., None] * up_n
