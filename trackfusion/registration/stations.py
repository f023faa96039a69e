"""Station set-ups (given, or by free-station resection) and prism readings in ``n``.

A set-up is either given (instrument point, orientation, optional tilt and instrument
height, as :class:`StationSetupConfig`) or computed by **free-station resection** from
readings (horizontal angle, zenith angle, slope distance) to three or more control points of
known ``n`` coordinates. The resection solves for the instrument point (3) and the
orientation of the horizontal circle (1) by weighted Gauss-Newton on the exact polar model
(:mod:`.polar`, through ECEF, refraction included); the instrument is taken as levelled (its
compensator), so a residual tilt shows up in the residuals and is estimated later in the
fusion. The residuals of every reading are reported (arcsec, arcsec, mm) with the a-posteriori
standard deviation of unit weight.

:func:`readings_to_n` turns a station's readings into points in ``n`` with their covariance,
propagated from the instrument's angle and distance precision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from .. import geodesy
from ..errors import RegistrationError
from ..strict import StrictModel
from .polar import StationSetup, n_to_polar, polar_to_n

ARCSEC = np.pi / 180.0 / 3600.0
Vec3 = tuple[float, float, float]

#: a set-up's stated accuracy of the instrument point [mm, 1-sigma per axis of ``n``]: centring
#: over the mark and the measured instrument height, or a resection from control points of about
#: that accuracy. The fusion's prior on each station's translation; the simulator draws each
#: station's true set-up error from it.
SETUP_POSITION_SIGMA_MM = 1.0


class ControlReading(StrictModel):
    """A set-up reading to a control point: ``point`` (a name in ``control_points``), horizontal
    and zenith angle [deg] as read, slope distance [m] to the control point's reflector."""

    point: str
    hz_deg: float
    zenith_deg: float = Field(gt=0, lt=180)
    slope_distance_m: float = Field(gt=0)


class StationSetupConfig(StrictModel):
    """One station in a pipeline YAML: either ``pos_n_m`` (instrument point, or the ground mark
    when ``instrument_height_m`` > 0) and ``orientation_deg`` (azimuth of the horizontal circle's
    zero, clockwise from north), or ``resection`` readings to three or more control points.
    ``tilt_arcsec`` (about east, about north) if known; ``clock_offset_s`` (station clock minus
    IMU clock) if known, else it is found by time synchronisation."""

    pos_n_m: Vec3 | None = None
    orientation_deg: float | None = None
    instrument_height_m: float = Field(0.0, ge=0)
    tilt_arcsec: tuple[float, float] = (0.0, 0.0)
    clock_offset_s: float | None = None
    resection: list[ControlReading] | None = None


@dataclass(frozen=True)
class InstrumentPrecision:
    """A total station's reading precision (1-sigma, white): ``angle_sigma_arcsec`` [arcsec] on
    the horizontal and the zenith angle, ``distance_sigma_mm`` [mm] plus ``distance_ppm`` [ppm]
    of the slope distance."""

    angle_sigma_arcsec: float
    distance_sigma_mm: float
    distance_ppm: float

    def distance_sigma_m(self, slope_distance_m: np.ndarray) -> np.ndarray:
        """Sigma [m] (N,) of slope distances (N,) [m]."""
        return self.distance_sigma_mm * 1e-3 + self.distance_ppm * 1e-6 * slope_distance_m


@dataclass(frozen=True)
class Resection:
    """Free-station result: the set-up, residuals per reading (measured minus computed) of
    horizontal angle [arcsec], zenith angle [arcsec], slope distance [mm], their 3-D size at the
    point [mm], and the a-posteriori sigma of unit weight."""

    setup: StationSetup
    points: list[str]
    hz_arcsec: np.ndarray
    zenith_arcsec: np.ndarray
    distance_mm: np.ndarray
    position_mm: np.ndarray
    sigma0: float
    iterations: int

    def to_json(self) -> dict:
        return {"pos_n_m": list(self.setup.pos_n), "orientation_deg": float(np.degrees(self.setup.orientation_rad)),
                "sigma0": self.sigma0, "iterations": self.iterations,
                "residuals": [{"point": p, "hz_arcsec": float(a), "zenith_arcsec": float(z), "distance_mm": float(d),
                               "position_mm": float(q)}
                              for p, a, z, d, q in zip(self.points, self.hz_arcsec, self.zenith_arcsec,
                                                       self.distance_mm, self.position_mm)]}


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * a))


def _initial_setup(station_id: str, ctrl_n: np.ndarray, hz: np.ndarray, zen: np.ndarray, dist: np.ndarray,
                   height_m: float) -> StationSetup:
    """Plane approximation: a 2-D rotation and translation (Procrustes) mapping the readings'
    horizontal vectors onto the control points, and the mean height difference."""
    horiz = dist * np.sin(zen)
    d_xy = np.column_stack([horiz * np.sin(hz), horiz * np.cos(hz)])  # azimuth = hz + orientation
    c_xy = ctrl_n[:, :2]
    a, b = d_xy - d_xy.mean(0), c_xy - c_xy.mean(0)
    # rotation by -orientation in the (east, north) plane maps a onto b (azimuths clockwise)
    angle = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    orientation = float(np.mod(-angle, 2 * np.pi))
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    xy = c_xy.mean(0) - rot @ d_xy.mean(0)
    z = float(np.mean(ctrl_n[:, 2] - dist * np.cos(zen))) - height_m
    return StationSetup(station_id, (float(xy[0]), float(xy[1]), z), orientation, (0.0, 0.0), height_m)


def resect(station_id: str, control_n: dict[str, Vec3], readings: list[ControlReading], origin: geodesy.Origin,
           precision: InstrumentPrecision, refraction_k: float, instrument_height_m: float = 0.0,
           max_iterations: int = 20) -> Resection:
    """Free-station resection (module docstring), the readings weighted by ``precision``. Raises :class:`RegistrationError` for fewer than
    three readings, unknown control points or a solution that does not converge."""
    if len(readings) < 3:
        raise RegistrationError(f"station {station_id}: resection needs readings to >= 3 control points, "
                                f"got {len(readings)}")
    missing = [r.point for r in readings if r.point not in control_n]
    if missing:
        raise RegistrationError(f"station {station_id}: resection: unknown control point(s) {missing} "
                                "(not in sensors.total_stations.control_points)")
    ctrl = np.array([control_n[r.point] for r in readings], dtype=float)
    hz = np.radians([r.hz_deg for r in readings])
    zen = np.radians([r.zenith_deg for r in readings])
    dist = np.array([r.slope_distance_m for r in readings])
    sig = np.concatenate([np.full(2 * dist.size, precision.angle_sigma_arcsec * ARCSEC),
                          precision.distance_sigma_m(dist)])
    setup = _initial_setup(station_id, ctrl, hz, zen, dist, instrument_height_m)

    def misclosure(x: np.ndarray) -> np.ndarray:
        st = StationSetup(station_id, tuple(x[:3]), float(x[3]), (0.0, 0.0), instrument_height_m)
        h, z, d = n_to_polar(ctrl, st, origin, refraction_k)
        return np.concatenate([_wrap(hz - h), zen - z, dist - d]) / sig

    x = np.r_[setup.pos_n, setup.orientation_rad]
    steps = np.array([1e-4, 1e-4, 1e-4, 1e-8])
    it = 0
    for it in range(1, max_iterations + 1):
        f0 = misclosure(x)
        J = np.column_stack([(misclosure(x + e) - misclosure(x - e)) / (2 * e[i])
                             for i, e in enumerate(np.diag(steps))])
        dx = np.linalg.lstsq(-J, f0, rcond=None)[0]
        x = x + dx
        if np.all(np.abs(dx[:3]) < 1e-7) and abs(dx[3]) < 1e-10:
            break
    else:
        raise RegistrationError(f"station {station_id}: resection did not converge in {max_iterations} iterations")
    n = dist.size
    v = misclosure(x) * sig
    dof = 3 * n - 4
    sigma0 = float(np.sqrt(np.sum((v / sig) ** 2) / dof)) if dof > 0 else 0.0
    st = StationSetup(station_id, tuple(float(a) for a in x[:3]), float(np.mod(x[3], 2 * np.pi)), (0.0, 0.0),
                      instrument_height_m)
    pos_mm = 1e3 * np.linalg.norm(polar_to_n(hz, zen, dist, st, origin, refraction_k) - ctrl, axis=1)
    return Resection(st, [r.point for r in readings], v[:n] / ARCSEC, v[n:2 * n] / ARCSEC, 1e3 * v[2 * n:],
                     pos_mm, sigma0, it)


def station_setup(station_id: str, cfg: StationSetupConfig, control_n: dict[str, Vec3], origin: geodesy.Origin,
                  precision: InstrumentPrecision, refraction_k: float) -> tuple[StationSetup, Resection | None]:
    """The set-up of one configured station: as given, or resected (then with its report)."""
    if cfg.resection is not None:
        res = resect(station_id, control_n, cfg.resection, origin, precision, refraction_k, cfg.instrument_height_m)
        return res.setup, res
    if cfg.pos_n_m is None or cfg.orientation_deg is None:
        raise RegistrationError(f"station {station_id}: give pos_n_m and orientation_deg, or resection readings")
    return StationSetup(station_id, cfg.pos_n_m, float(np.radians(cfg.orientation_deg)),
                        (cfg.tilt_arcsec[0] * ARCSEC, cfg.tilt_arcsec[1] * ARCSEC), cfg.instrument_height_m), None


def readings_to_n(hz_rad: np.ndarray, zenith_rad: np.ndarray, slope_distance_m: np.ndarray, setup: StationSetup,
                  origin: geodesy.Origin, refraction_k: float,
                  precision: InstrumentPrecision) -> tuple[np.ndarray, np.ndarray]:
    """Prism points (N,3) [m] in ``n`` and their covariance (N,3,3) [m^2] from the instrument's
    white angle and distance noise (``precision``; first-order propagation; the refraction
    term's derivative, ~1e-5 of itself, is left out)."""
    pos_n = polar_to_n(hz_rad, zenith_rad, slope_distance_m, setup, origin, refraction_k)
    az = hz_rad + setup.orientation_rad
    sz, cz, sa, ca = np.sin(zenith_rad), np.cos(zenith_rad), np.sin(az), np.cos(az)
    S = slope_distance_m
    # columns: d/dhz, d/dzenith, d/dS of the instrument-frame vector S (sz sa, sz ca, cz)
    J_i = np.stack([np.column_stack([S * sz * ca, -S * sz * sa, 0 * S]),
                    np.column_stack([S * cz * sa, S * cz * ca, -S * sz]),
                    np.column_stack([sz * sa, sz * ca, cz])], axis=2)
    R_ei, _ = setup.R_ei(origin)
    R_ni = geodesy.origin_R_en(origin).T @ R_ei
    J_n = R_ni @ J_i
    var = np.column_stack([np.full(S.size, (precision.angle_sigma_arcsec * ARCSEC) ** 2)] * 2
                          + [precision.distance_sigma_m(S) ** 2])
    cov = np.einsum("kij,kj,klj->kil", J_n, var, J_n)
    return pos_n, cov
