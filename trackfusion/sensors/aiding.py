"""Measurement simulation for the aiding sensors: odometer, GNSS, total stations, inclinometer, gauge.

Each ``simulate_*`` takes the truth at the sensor's epochs (or a callable
giving it), a strict spec, a ``numpy.random.Generator`` and ``ideal`` (every
error off: the output equals the truth), and returns the data container and
a JSON-able dict of every error drawn (for ``truth.json``). The error models
are documented in ``docs/error_models.md``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter

from .. import geodesy
from ..registration.polar import DEFAULT_REFRACTION_K, StationSetup, n_to_polar
from . import noise
from .types import GaugeData, GnssData, InclinometerData, OdometerData, TotalStationData

ARCSEC = np.pi / 180.0 / 3600.0


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Interval(_Spec):
    """A time interval [start_s, start_s + duration_s) on the IMU clock."""

    start_s: float
    duration_s: float = Field(gt=0)


class Slip(Interval):
    """A wheel slip: ``extra_m`` of reported distance accumulated evenly over the interval."""

    extra_m: float


def _in_intervals(t: np.ndarray, intervals) -> np.ndarray:
    mask = np.zeros(t.shape, dtype=bool)
    for iv in intervals:
        mask |= (t >= iv.start_s) & (t < iv.start_s + iv.duration_s)
    return mask


# --- odometer ---------------------------------------------------------------------------------

class OdometerSpec(_Spec):
    """Wheel encoder. ``scale_error_ppm`` 1-sigma of the constant scale error; ``radius_drift_ppm_per_h``
    linear change of the wheel radius (wear, temperature); ``slips``; ``gross_error_probability`` per
    sample of an isolated gross error of up to ``gross_error_max_m`` (seed 000 III.C.7)."""

    rate_hz: float = Field(100.0, gt=0)
    wheel_diameter_m: float = Field(0.15, gt=0)
    ticks_per_rev: int = Field(10000, gt=0)
    scale_error_ppm: float = Field(200.0, ge=0)
    radius_drift_ppm_per_h: float = 0.0
    slips: list[Slip] = []
    gross_error_probability: float = Field(0.0, ge=0, le=0.1)
    gross_error_max_m: float = Field(0.05, ge=0)

    @property
    def ticks_per_m(self) -> float:
        """Encoder ticks per metre of nominal wheel circumference."""
        return self.ticks_per_rev / (np.pi * self.wheel_diameter_m)


def simulate_odometer(t_s: np.ndarray, wheel_distance_m: np.ndarray, spec: OdometerSpec,
                      rng: np.random.Generator, ideal: bool = False) -> tuple[OdometerData, dict]:
    """Odometer records at ``t_s`` (N,) from the true signed rolled distance of the wheel (N,) [m]."""
    t = np.asarray(t_s, dtype=float)
    d_true = np.asarray(wheel_distance_m, dtype=float) - wheel_distance_m[0]
    if ideal:
        ticks = np.round(d_true * spec.ticks_per_m).astype(np.int64)
        return OdometerData(t, d_true.copy(), ticks), {"ideal": True}
    scale = rng.standard_normal() * spec.scale_error_ppm * 1e-6
    drift = spec.radius_drift_ppm_per_h * 1e-6 * (t - t[0]) / 3600.0
    # distance increments scaled by the (slowly changing) scale error, plus slips
    inc = np.diff(d_true, prepend=0.0) * (1.0 + scale + drift)
    for slip in spec.slips:
        m = _in_intervals(t, [slip])
        if m.any():
            inc[m] += slip.extra_m / m.sum()
    d_meas = np.cumsum(inc)
    ticks = np.floor(d_meas * spec.ticks_per_m).astype(np.int64)
    distance = ticks / spec.ticks_per_m
    gross = rng.random(t.size) < spec.gross_error_probability
    gross_idx = np.flatnonzero(gross)
    distance[gross_idx] += rng.uniform(-1, 1, gross_idx.size) * spec.gross_error_max_m
    drawn = {"scale_error": float(scale), "gross_error_indices": gross_idx.tolist(),
             "gross_error_m": (distance[gross_idx] - ticks[gross_idx] / spec.ticks_per_m).tolist()}
    return OdometerData(t, distance, ticks), drawn


# --- GNSS ---------------------------------------------------------------------------------------

class GnssSpec(_Spec):
    """RTK GNSS (2 cm + 1 ppm class). White noise and a Gauss-Markov error per axis (horizontal,
    vertical), a ppm term from the baseline to the base station, float episodes, multipath
    outliers displaced 0.3-3 m (reported covariance unchanged) and outages."""

    rate_hz: float = Field(1.0, gt=0)
    sigma_h_mm: float = Field(8.0, ge=0)
    sigma_v_mm: float = Field(15.0, ge=0)
    gm_sigma_h_mm: float = Field(8.0, ge=0)
    gm_sigma_v_mm: float = Field(15.0, ge=0)
    gm_tau_s: float = Field(300.0, gt=0)
    baseline_km: float = Field(5.0, ge=0)
    ppm: float = Field(1.0, ge=0)
    float_episodes: list[Interval] = []
    float_sigma_h_mm: float = Field(80.0, ge=0)
    float_sigma_v_mm: float = Field(150.0, ge=0)
    outlier_fraction: float = Field(0.0, ge=0, le=0.5)
    outlier_min_m: float = Field(0.3, ge=0)
    outlier_max_m: float = Field(3.0, ge=0)
    outages: list[Interval] = []


def simulate_gnss(t_s: np.ndarray, antenna_pos_n: np.ndarray, origin: geodesy.Origin, spec: GnssSpec,
                  rng: np.random.Generator, ideal: bool = False) -> tuple[GnssData, dict]:
    """GNSS fixes at ``t_s`` (N,) of the antenna truth (N, 3) in ``n``; outage epochs are dropped."""
    t = np.asarray(t_s, dtype=float)
    n = t.size
    dt = 1.0 / spec.rate_hz
    ppm_m = spec.ppm * 1e-6 * spec.baseline_km * 1e3
    sig_h = np.hypot(spec.sigma_h_mm * 1e-3, ppm_m)
    sig_v = np.hypot(spec.sigma_v_mm * 1e-3, ppm_m)
    sig = np.array([sig_h, sig_h, sig_v])
    gm_sig = np.array([spec.gm_sigma_h_mm, spec.gm_sigma_h_mm, spec.gm_sigma_v_mm]) * 1e-3
    white = np.column_stack([noise.white(n, s, rng) for s in sig])
    gm = np.column_stack([noise.gauss_markov(n, dt, s, spec.gm_tau_s, rng) for s in gm_sig])
    is_float = _in_intervals(t, spec.float_episodes)
    float_sig = np.array([spec.float_sigma_h_mm, spec.float_sigma_h_mm, spec.float_sigma_v_mm]) * 1e-3
    float_err = np.column_stack([noise.gauss_markov(n, dt, s, 30.0, rng) for s in float_sig])
    outlier = rng.random(n) < spec.outlier_fraction
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    jump = direction * rng.uniform(spec.outlier_min_m, spec.outlier_max_m, n)[:, None]
    err = white + gm + np.where(is_float[:, None], float_err, 0.0) + np.where(outlier[:, None], jump, 0.0)
    keep = ~_in_intervals(t, spec.outages)
    if ideal:
        err[:] = 0.0
        is_float[:] = False
        outlier[:] = False
    pos = antenna_pos_n + err
    lat, lon, h = geodesy.n_to_geodetic(pos[keep], origin)
    sigma = np.where(is_float[:, None], np.hypot(sig, float_sig), np.hypot(sig, gm_sig))[keep]
    cov = np.zeros((int(keep.sum()), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sigma**2
    quality = np.where(is_float, 5, 4)[keep]
    drawn = {"ideal": ideal, "outlier_times_s": t[outlier & keep].tolist(),
             "float_times_s": t[is_float & keep].tolist(), "error_n_m_rms": np.sqrt((err[keep] ** 2).mean(0)).tolist()}
    return GnssData(t[keep], lat, lon, h, cov, quality.astype(np.int64)), drawn


# --- total stations -------------------------------------------------------------------------------

class StationConfig(_Spec):
    """One station: instrument point in ``n`` [m], nominal orientation [deg], and optionally fixed
    errors (else drawn): tilt of the vertical axis [arcsec] (east, north), orientation error [arcsec],
    clock offset [s] (t_station = t_imu + offset + drift t_imu) and drift [ppm]."""

    id: str
    pos_n_m: tuple[float, float, float]
    orientation_deg: float = 0.0
    tilt_arcsec: tuple[float, float] | None = None
    orientation_error_arcsec: float | None = None
    clock_offset_s: float | None = None
    clock_drift_ppm: float | None = None


class Handover(_Spec):
    """From the moment the trolley crosses ``at_chainage_m`` (after the previous hand-over), the prism
    faces ``station`` (seed 003 figure 3). The first entry has no chainage: the start."""

    station: str
    at_chainage_m: float | None = None


class TotalStationSpec(_Spec):
    """Robotic total stations tracking the trolley prism (seed 003 section 2.1.1: TS60, 0.5" angles,
    3 mm + 1.5 ppm distances, vertical axes within 4" of each other)."""

    stations: list[StationConfig] = Field(min_length=1)
    handover: list[Handover] = Field(min_length=1)
    handover_gap_s: float = Field(4.0, ge=0)
    rate_hz: float = Field(10.0, gt=0)
    angle_sigma_arcsec: float = Field(0.5, ge=0)
    distance_sigma_mm: float = Field(3.0, ge=0)
    distance_ppm: float = Field(1.5, ge=0)
    max_tilt_arcsec: float = Field(4.0, ge=0)
    orientation_sigma_arcsec: float = Field(2.0, ge=0)
    max_clock_offset_s: float = Field(5.0, ge=0)
    clock_drift_sigma_ppm: float = Field(1.0, ge=0)
    max_range_m: float = Field(1000.0, gt=0)
    refraction_k: float = DEFAULT_REFRACTION_K
    prism_id: str = "P1"


def _facing_intervals(t: np.ndarray, chainage: np.ndarray, handover: list[Handover]) -> dict[str, list]:
    """IMU-time intervals during which the prism faces each station, from the hand-over list."""
    out: dict[str, list] = {}
    start_idx = 0
    bounds = []
    for h in handover[1:]:
        s_rel = chainage[start_idx:] - h.at_chainage_m
        cross = np.flatnonzero(np.sign(s_rel[1:]) != np.sign(s_rel[:-1]))
        if cross.size == 0:
            break
        start_idx += int(cross[0]) + 1
        bounds.append(start_idx)
    edges = [0] + bounds + [t.size - 1]
    for h, a, b in zip(handover, edges[:-1], edges[1:]):
        out.setdefault(h.station, []).append((float(t[a]), float(t[b])))
    return out


def simulate_total_stations(t_truth_s: np.ndarray, chainage_m: np.ndarray,
                            prism_pos_at: Callable[[np.ndarray], np.ndarray], origin: geodesy.Origin,
                            spec: TotalStationSpec, rng: np.random.Generator, ideal: bool = False
                            ) -> tuple[dict[str, TotalStationData], dict]:
    """Polar observations of the prism by every station.

    t_truth_s, chainage_m: (M,) truth times [s, IMU clock] and chainage, to place the hand-overs;
    prism_pos_at: callable mapping IMU times (K,) to exact prism positions (K, 3) in ``n``.
    Returns observations per station (on each station's clock) and the drawn errors, including
    ``stations: {id: {"clock_offset_s", "clock_drift_ppm", "tilt_arcsec", "orientation_error_arcsec"}}``.
    """
    facing = _facing_intervals(t_truth_s, chainage_m, spec.handover)
    data: dict[str, TotalStationData] = {}
    drawn: dict[str, dict] = {}
    for st in spec.stations:
        tilt = np.zeros(2) if ideal else (
            np.array(st.tilt_arcsec) if st.tilt_arcsec is not None else
            _random_tilt(spec.max_tilt_arcsec, rng))
        orient_err = 0.0 if ideal else (st.orientation_error_arcsec if st.orientation_error_arcsec is not None
                                        else rng.standard_normal() * spec.orientation_sigma_arcsec)
        offset = 0.0 if ideal else (st.clock_offset_s if st.clock_offset_s is not None
                                    else rng.uniform(-spec.max_clock_offset_s, spec.max_clock_offset_s))
        drift = 0.0 if ideal else (st.clock_drift_ppm if st.clock_drift_ppm is not None
                                   else rng.standard_normal() * spec.clock_drift_sigma_ppm)
        setup = StationSetup(st.id, st.pos_n_m, np.radians(st.orientation_deg) + orient_err * ARCSEC,
                             tuple(tilt * ARCSEC))
        t_imu = _station_epochs(facing.get(st.id, []), spec, offset, drift)
        prism = prism_pos_at(t_imu) if t_imu.size else np.zeros((0, 3))
        hz, zen, dist = n_to_polar(prism, setup, origin, spec.refraction_k) if t_imu.size else (t_imu,) * 3
        in_range = dist <= spec.max_range_m
        t_imu, hz, zen, dist = t_imu[in_range], hz[in_range], zen[in_range], dist[in_range]
        if not ideal:
            hz = np.mod(hz + noise.white(hz.size, spec.angle_sigma_arcsec * ARCSEC, rng), 2 * np.pi)
            zen = zen + noise.white(zen.size, spec.angle_sigma_arcsec * ARCSEC, rng)
            dist = dist + rng.standard_normal(dist.size) * (spec.distance_sigma_mm * 1e-3
                                                            + spec.distance_ppm * 1e-6 * dist)
        t_station = t_imu + offset + drift * 1e-6 * t_imu
        data[st.id] = TotalStationData(st.id, t_station, hz, zen, dist, np.full(t_imu.size, spec.prism_id, dtype=object))
        drawn[st.id] = {"clock_offset_s": float(offset), "clock_drift_ppm": float(drift),
                        "tilt_arcsec": [float(x) for x in tilt], "orientation_error_arcsec": float(orient_err),
                        "orientation_rad": float(setup.orientation_rad), "pos_n_m": list(st.pos_n_m),
                        "facing_intervals_s": facing.get(st.id, []), "observations": int(t_imu.size)}
    return data, {"stations": drawn, "refraction_k": spec.refraction_k}


def _random_tilt(max_arcsec: float, rng: np.random.Generator) -> np.ndarray:
    """A tilt of uniform magnitude in [0, max] and uniform direction, (east, north) [arcsec]."""
    mag, ang = rng.uniform(0.0, max_arcsec), rng.uniform(0.0, 2 * np.pi)
    return mag * np.array([np.cos(ang), np.sin(ang)])


def _station_epochs(intervals: list, spec: TotalStationSpec, offset_s: float, drift_ppm: float) -> np.ndarray:
    """IMU times of the station's samples: a regular grid on the station clock inside the facing
    intervals, leaving ``handover_gap_s`` at each start for turning the prism and locking on."""
    out = []
    for a, b in intervals:
        # station clock: t_st = t (1 + drift) + offset; a regular grid of it
        st_a = a * (1 + drift_ppm * 1e-6) + offset_s + spec.handover_gap_s
        st_b = b * (1 + drift_ppm * 1e-6) + offset_s
        if st_b <= st_a:
            continue
        grid = np.ceil(st_a * spec.rate_hz) / spec.rate_hz + np.arange(int((st_b - st_a) * spec.rate_hz)) / spec.rate_hz
        out.append((grid - offset_s) / (1 + drift_ppm * 1e-6))
    return np.concatenate(out) if out else np.zeros(0)


# --- inclinometer and gauge ---------------------------------------------------------------------------

class InclinometerSpec(_Spec):
    """Two-axis inclinometer: first-order response ``time_constant_s``, white noise, constant bias."""

    rate_hz: float = Field(50.0, gt=0)
    time_constant_s: float = Field(0.5, ge=0)
    sigma_arcsec: float = Field(5.0, ge=0)
    bias_arcsec: float = Field(10.0, ge=0)


def simulate_inclinometer(t_s, roll_rad, pitch_rad, spec: InclinometerSpec, rng: np.random.Generator,
                          ideal: bool = False) -> tuple[InclinometerData, dict]:
    """Inclinometer readings at ``t_s`` (N,) of the true roll and pitch (N,) [rad] (w.r.t. the plumb line)."""
    t = np.asarray(t_s, dtype=float)
    if ideal:
        return InclinometerData(t, np.array(roll_rad, float), np.array(pitch_rad, float)), {"ideal": True}
    bias = rng.standard_normal(2) * spec.bias_arcsec * ARCSEC
    out = []
    for k, x in enumerate((roll_rad, pitch_rad)):
        x = np.asarray(x, dtype=float)
        if spec.time_constant_s > 0:
            a = np.exp(-1.0 / (spec.rate_hz * spec.time_constant_s))
            x = lfilter([1 - a], [1, -a], x - x[0]) + x[0]
        out.append(x + bias[k] + noise.white(t.size, spec.sigma_arcsec * ARCSEC, rng))
    return InclinometerData(t, out[0], out[1]), {"bias_rad": bias.tolist()}


class GaugeSpec(_Spec):
    """Gauge sensor: white noise and a constant bias [mm]."""

    rate_hz: float = Field(50.0, gt=0)
    sigma_mm: float = Field(0.1, ge=0)
    bias_mm: float = Field(0.2, ge=0)


def simulate_gauge(t_s, gauge_m, spec: GaugeSpec, rng: np.random.Generator, ideal: bool = False
                   ) -> tuple[GaugeData, dict]:
    """Gauge readings at ``t_s`` (N,) of the true gauge (N,) [m]."""
    t = np.asarray(t_s, dtype=float)
    if ideal:
        return GaugeData(t, np.array(gauge_m, float)), {"ideal": True}
    bias = rng.standard_normal() * spec.bias_mm * 1e-3
    return GaugeData(t, np.asarray(gauge_m, float) + bias + noise.white(t.size, spec.sigma_mm * 1e-3, rng)), \
        {"bias_m": float(bias)}
