"""Measurement simulation for the aiding sensors: odometer, GNSS, total stations, inclinometer, gauge.

Each ``simulate_*`` takes the truth at the sensor's epochs (the total stations:
a callable or a denser truth series, because they sample on their own
clocks), a strict spec (pydantic, unknown keys refused, units in the field
names), a ``numpy.random.Generator`` and ``ideal``. ``ideal=True`` switches
every *error* off, so the output equals the truth (clock offsets included);
the observation geometry stays (GNSS outages, total-station hand-overs, range
and line-of-sight limits). The same generator state gives the same output.
Each returns the data container and a JSON-able dict of the errors actually
drawn (for ``truth.json``). The error models are documented in
``docs/error_models.md``.
"""

from __future__ import annotations

from typing import Callable, Union

import numpy as np
from pydantic import Field, model_validator
from scipy.interpolate import CubicSpline
from scipy.signal import lfilter

from .. import geodesy
from ..errors import SimulationError
from ..registration.polar import DEFAULT_REFRACTION_K, StationSetup, n_to_polar
from ..registration.stations import SETUP_POSITION_SIGMA_MM
from ..sensors.types import GaugeData, GnssData, InclinometerData, OdometerData, TotalStationData, finite_array
from ..strict import StrictModel
from . import noise

ARCSEC = np.pi / 180.0 / 3600.0  #: one arcsecond [rad]


class Interval(StrictModel):
    """A time interval [start_s, start_s + duration_s) on the IMU clock [s]."""

    start_s: float
    duration_s: float = Field(gt=0)


class Slip(Interval):
    """A wheel slip: ``extra_m`` [m] of reported distance (negative: lost) accrued evenly over the interval."""

    extra_m: float


def _in_intervals(t: np.ndarray, intervals) -> np.ndarray:
    """Boolean mask (N,) of the times ``t`` (N,) inside any of the intervals."""
    mask = np.zeros(t.shape, dtype=bool)
    for iv in intervals:
        mask |= (t >= iv.start_s) & (t < iv.start_s + iv.duration_s)
    return mask


def _times(t_s, name: str) -> np.ndarray:
    """Validated sample times (N,) [s]: finite, 1-D, strictly increasing."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise SimulationError(f"{name}: t_s must be a finite, strictly increasing 1-D array")
    return t


def _series(x, n: int, name: str, field: str, width: int | None = None) -> np.ndarray:
    """Validated truth series of n rows ((n,) or (n, width)), finite."""
    return finite_array(x, n, name, field, width, SimulationError)


def _step_s(t: np.ndarray, rate_hz: float) -> float:
    """Nominal sample interval [s] of (regular) epochs ``t``: their median step, else ``1 / rate_hz``."""
    return float(np.median(np.diff(t))) if t.size > 1 else 1.0 / rate_hz


# --- odometer ---------------------------------------------------------------------------------

class OdometerSpec(StrictModel):
    """Wheel encoder on the measuring wheel.

    ``scale_error_ppm`` 1-sigma of the constant scale-factor error (drawn once);
    ``radius_drift_ppm_per_h`` linear change of the effective wheel radius (wear, temperature);
    ``slips`` given slip episodes; ``random_slips_per_km`` mean number of random slips per km
    travelled, each of ``random_slip_duration_s`` with an extra distance uniform in
    +-``random_slip_max_m``; ``gross_error_probability`` per sample of an isolated gross error
    (spike) in the reported distance of magnitude uniform in
    [``gross_error_min_m``, ``gross_error_max_m``] and random sign (seed 000 III.C.7).
    """

    rate_hz: float = Field(100.0, gt=0)
    wheel_diameter_m: float = Field(0.15, gt=0)
    ticks_per_rev: int = Field(10000, gt=0)
    scale_error_ppm: float = Field(200.0, ge=0)
    radius_drift_ppm_per_h: float = 0.0
    slips: list[Slip] = []
    random_slips_per_km: float = Field(0.0, ge=0)
    random_slip_duration_s: float = Field(0.5, gt=0)
    random_slip_max_m: float = Field(0.02, ge=0)
    gross_error_probability: float = Field(0.0, ge=0, le=0.1)
    gross_error_min_m: float = Field(0.02, ge=0)
    gross_error_max_m: float = Field(0.05, ge=0)

    @model_validator(mode="after")
    def _gross_range(self) -> "OdometerSpec":
        if self.gross_error_max_m < self.gross_error_min_m:
            raise ValueError("gross_error_max_m must be >= gross_error_min_m")
        return self

    @property
    def ticks_per_m(self) -> float:
        """Encoder ticks per metre of nominal wheel circumference."""
        return self.ticks_per_rev / (np.pi * self.wheel_diameter_m)


def _random_slips(t: np.ndarray, inc_m: np.ndarray, spec: OdometerSpec, rng: np.random.Generator) -> list[Slip]:
    """Random slips: Poisson count for the distance travelled, starting at moving epochs."""
    travelled_km = float(np.abs(inc_m).sum()) * 1e-3
    count = int(rng.poisson(spec.random_slips_per_km * travelled_km)) if spec.random_slips_per_km > 0 else 0
    moving = np.flatnonzero(np.abs(inc_m) > 0)
    if count == 0 or moving.size == 0:
        return []
    starts = t[np.sort(rng.choice(moving, size=count))]
    extra = rng.uniform(-spec.random_slip_max_m, spec.random_slip_max_m, count)
    return [Slip(start_s=float(a), duration_s=spec.random_slip_duration_s, extra_m=float(e))
            for a, e in zip(starts, extra)]


def _slip_ramp_m(t: np.ndarray, slips: list[Slip]) -> np.ndarray:
    """Accumulated extra distance (N,) [m] of the slips: a linear ramp over each slip interval."""
    out = np.zeros(t.shape)
    for s in slips:
        out += s.extra_m * np.clip((t - s.start_s) / s.duration_s, 0.0, 1.0)
    return out


def simulate_odometer(t_s: np.ndarray, wheel_distance_m: np.ndarray, spec: OdometerSpec,
                      rng: np.random.Generator, ideal: bool = False) -> tuple[OdometerData, dict]:
    """Odometer records at ``t_s`` (N,) [s] from the true signed cumulative rolled distance of the
    measuring wheel (N,) [m].

    The counter is zeroed at the first epoch (``distance_m[0] = 0``). Measured distance:
    ``d_meas = cumsum(delta d_true (1 + scale + drift (t - t0))) + slips``; ``ticks =
    floor(d_meas ticks_per_m)``; ``distance_m = ticks / ticks_per_m`` plus isolated gross errors.
    Ideal: ``distance_m`` is the exact true distance and ``ticks`` its rounded count.
    Drawn: ``scale_error`` [-], ``radius_drift_ppm_per_h``, ``slips`` [{start_s, duration_s, extra_m}],
    ``gross_error_indices``, ``gross_error_m``.
    """
    t = _times(t_s, "odometer")
    d_true = _series(wheel_distance_m, t.size, "odometer", "wheel_distance_m")
    d_true = d_true - d_true[0]
    if ideal:
        ticks = np.round(d_true * spec.ticks_per_m).astype(np.int64)
        return OdometerData(t, d_true.copy(), ticks), {"ideal": True, "scale_error": 0.0, "slips": [],
                                                       "gross_error_indices": [], "gross_error_m": []}
    scale = rng.standard_normal() * spec.scale_error_ppm * 1e-6
    drift = spec.radius_drift_ppm_per_h * 1e-6 * (t - t[0]) / 3600.0
    inc = np.diff(d_true, prepend=0.0)
    slips = list(spec.slips) + _random_slips(t, inc, spec, rng)
    d_meas = np.cumsum(inc * (1.0 + scale + drift)) + _slip_ramp_m(t, slips)
    ticks = np.floor(d_meas * spec.ticks_per_m + 1e-9).astype(np.int64)
    distance = ticks / spec.ticks_per_m
    gross_idx = np.flatnonzero(rng.random(t.size) < spec.gross_error_probability)
    gross = (rng.uniform(spec.gross_error_min_m, spec.gross_error_max_m, gross_idx.size)
             * rng.choice([-1.0, 1.0], gross_idx.size))
    distance[gross_idx] += gross
    drawn = {"ideal": False, "scale_error": float(scale), "radius_drift_ppm_per_h": spec.radius_drift_ppm_per_h,
             "slips": [s.model_dump() for s in slips],
             "gross_error_indices": gross_idx.tolist(), "gross_error_m": gross.tolist()}
    return OdometerData(t, distance, ticks), drawn


# --- GNSS ---------------------------------------------------------------------------------------

class GnssSpec(StrictModel):
    """RTK GNSS (2 cm + 1 ppm class, seed 002).

    Per axis (horizontal: east and north; vertical): white noise ``sigma_*_mm``; a first-order
    Gauss-Markov error ``gm_sigma_*_mm`` with ``gm_tau_s`` (multipath and residual atmosphere),
    to which ``ppm`` x ``baseline_km`` is added in quadrature; ``float_episodes`` (fix quality 5,
    extra Gauss-Markov error ``float_sigma_*_mm`` with ``float_tau_s``, covariance inflated to
    match); ``outlier_fraction`` of the fixes displaced by ``outlier_min_m``..``outlier_max_m``
    in a random 3-D direction with the reported covariance unchanged (multipath); ``outages``
    (no fixes). ``stated_sigma_factor``: the receiver reports this times its true white sigma
    in its covariance (real receivers' stated accuracy is optimistic: 0.5 reports half; 1, an
    honest receiver, the default); the error drawn is the same.
    """

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
    float_tau_s: float = Field(30.0, gt=0)
    outlier_fraction: float = Field(0.0, ge=0, le=0.5)
    outlier_min_m: float = Field(0.3, ge=0)
    outlier_max_m: float = Field(3.0, ge=0)
    outages: list[Interval] = []
    stated_sigma_factor: float = Field(1.0, gt=0)

    @model_validator(mode="after")
    def _outlier_range(self) -> "GnssSpec":
        if self.outlier_max_m < self.outlier_min_m:
            raise ValueError("outlier_max_m must be >= outlier_min_m")
        return self

    def sigmas_m(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(white, Gauss-Markov incl. ppm, float) 1-sigma per ENU axis, each (3,) [m]."""
        ppm_m = self.ppm * 1e-6 * self.baseline_km * 1e3
        white = np.array([self.sigma_h_mm, self.sigma_h_mm, self.sigma_v_mm]) * 1e-3
        gm = np.hypot(np.array([self.gm_sigma_h_mm, self.gm_sigma_h_mm, self.gm_sigma_v_mm]) * 1e-3, ppm_m)
        flt = np.array([self.float_sigma_h_mm, self.float_sigma_h_mm, self.float_sigma_v_mm]) * 1e-3
        return white, gm, flt


def _gm_columns(n: int, dt_s: float, sigmas: np.ndarray, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """Independent Gauss-Markov series, (n, len(sigmas))."""
    return np.column_stack([noise.gauss_markov(n, dt_s, s, tau_s, rng) for s in sigmas])


def simulate_gnss(t_s: np.ndarray, antenna_pos_n: np.ndarray, origin: geodesy.Origin, spec: GnssSpec,
                  rng: np.random.Generator, ideal: bool = False) -> tuple[GnssData, dict]:
    """GNSS fixes at the (regular) epochs ``t_s`` (N,) [s] of the antenna truth (N, 3) in ``n`` [m].

    Epochs inside an outage are dropped (also when ideal). Latitude, longitude and ellipsoidal
    height come from the erroneous position through :func:`geodesy.n_to_geodetic`; the reported
    covariance is diagonal ENU (at the antenna; the ENU/n rotation, < 1e-4 rad over 500 m, is
    neglected): (stated_sigma_factor white)^2 + GM^2, plus float^2 in float episodes, unchanged
    for outliers.
    Drawn (kept fixes): ``error_n_m`` (K, 3), ``outlier_times_s``, ``outlier_offsets_n_m``,
    ``float_times_s``, ``error_n_m_rms``.
    """
    t = _times(t_s, "gnss")
    truth = _series(antenna_pos_n, t.size, "gnss", "antenna_pos_n", 3)
    n = t.size
    keep = ~_in_intervals(t, spec.outages)
    is_float = _in_intervals(t, spec.float_episodes)
    sig_w, sig_gm, sig_f = spec.sigmas_m()
    if ideal:
        err = np.zeros((n, 3))
        outlier = np.zeros(n, dtype=bool)
        jump = np.zeros((n, 3))
        is_float[:] = False
    else:
        dt = _step_s(t, spec.rate_hz)
        err = np.column_stack([noise.white(n, s, rng) for s in sig_w]) + _gm_columns(n, dt, sig_gm, spec.gm_tau_s, rng)
        err += np.where(is_float[:, None], _gm_columns(n, dt, sig_f, spec.float_tau_s, rng), 0.0)
        outlier = rng.random(n) < spec.outlier_fraction
        direction = rng.standard_normal((n, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        jump = np.where(outlier[:, None], direction * rng.uniform(spec.outlier_min_m, spec.outlier_max_m, n)[:, None],
                        0.0)
        err += jump
    lat, lon, h = geodesy.n_to_geodetic(truth[keep] + err[keep], origin)
    var = (spec.stated_sigma_factor * sig_w)**2 + sig_gm**2 + np.where(is_float[:, None], sig_f**2, 0.0)
    cov = np.zeros((int(keep.sum()), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = var[keep]
    quality = np.where(is_float, 5, 4)[keep].astype(np.int64)
    k_err = err[keep]
    drawn = {"ideal": ideal, "outlier_times_s": t[outlier & keep].tolist(),
             "outlier_offsets_n_m": jump[outlier & keep].tolist(),
             "float_times_s": t[is_float & keep].tolist(), "error_n_m": k_err.tolist(),
             "error_n_m_rms": (np.sqrt((k_err**2).mean(0)) if k_err.size else np.zeros(3)).tolist()}
    return GnssData(t[keep], lat, lon, h, cov, quality), drawn


# --- total stations -------------------------------------------------------------------------------

class MisLock(Interval):
    """The station tracks another reflector at ``target_n_m`` [m, n] during the interval (IMU clock)."""

    target_n_m: tuple[float, float, float]


class StationConfig(StrictModel):
    """One station: ``pos_n_m`` instrument point (tilting axis) in ``n`` [m], or the ground mark when
    ``instrument_height_m`` > 0; nominal ``orientation_deg`` (azimuth of the horizontal circle's zero,
    clockwise from north); ``blocked`` intervals (IMU clock) with the line of sight obstructed; and
    optionally fixed true errors (else drawn): ``tilt_arcsec`` (about east, about north),
    ``orientation_error_arcsec``, ``position_error_mm`` (the set-up's, along ``n``'s e, n, u:
    the true point is ``pos_n_m`` plus it), ``clock_offset_s``, ``clock_drift_ppm``
    (t_station = t_imu + offset + drift t_imu); ``mislocks``: intervals in which it reads another
    reflector instead of the prism."""

    id: str
    pos_n_m: tuple[float, float, float]
    orientation_deg: float = 0.0
    instrument_height_m: float = Field(0.0, ge=0)
    blocked: list[Interval] = []
    tilt_arcsec: tuple[float, float] | None = None
    orientation_error_arcsec: float | None = None
    position_error_mm: tuple[float, float, float] | None = None
    clock_offset_s: float | None = None
    clock_drift_ppm: float | None = None
    mislocks: list[MisLock] = []


class Handover(StrictModel):
    """From the moment the trolley crosses ``at_chainage_m`` (after the previous hand-over), the prism
    faces ``station`` (seed 003 figure 3, "mirror rotating location"). The first entry has no
    chainage: the station faced at the start."""

    station: str
    at_chainage_m: float | None = None


class TotalStationSpec(StrictModel):
    """Robotic total stations tracking the trolley prism (seed 003 section 2.1.1: Leica TS60, 0.5"
    angles, 3 mm + 1.5 ppm distances, about 10 Hz, vertical axes within 4" of each other, 2" set-up).

    ``handover_gap_s``: after a hand-over the new station needs this long to find and lock on the
    prism; ``handover_overlap_s``: the station handed over keeps tracking this long after the
    hand-over (a 360-degree prism; 0 for the seed's one-sided prism, whose overlap is in chainage
    only). ``min_range_m``/``max_range_m``: distance limits of tracking. ``position_sigma_mm``: the
    set-up's stated accuracy of the instrument point (1-sigma per axis, the pipeline's prior); each
    station's true point is its nominal one plus an error drawn from it.
    """

    stations: list[StationConfig] = Field(min_length=1)
    handover: list[Handover] = Field(min_length=1)
    handover_gap_s: float = Field(4.0, ge=0)
    handover_overlap_s: float = Field(0.0, ge=0)
    rate_hz: float = Field(10.0, gt=0)
    angle_sigma_arcsec: float = Field(0.5, ge=0)
    distance_sigma_mm: float = Field(3.0, ge=0)
    distance_ppm: float = Field(1.5, ge=0)
    max_tilt_arcsec: float = Field(4.0, ge=0)
    orientation_sigma_arcsec: float = Field(2.0, ge=0)
    position_sigma_mm: float = Field(SETUP_POSITION_SIGMA_MM, ge=0)
    max_clock_offset_s: float = Field(5.0, ge=0)
    clock_drift_sigma_ppm: float = Field(1.0, ge=0)
    min_range_m: float = Field(2.0, ge=0)
    max_range_m: float = Field(1000.0, gt=0)
    refraction_k: float = DEFAULT_REFRACTION_K
    prism_id: str = "P1"

    @model_validator(mode="after")
    def _consistent(self) -> "TotalStationSpec":
        ids = [s.id for s in self.stations]
        if len(set(ids)) != len(ids):
            raise ValueError(f"station ids must be unique, got {ids}")
        for k, h in enumerate(self.handover):
            if h.station not in ids:
                raise ValueError(f"handover[{k}].station {h.station!r} is not one of the stations {ids}")
            if (k == 0) != (h.at_chainage_m is None):
                raise ValueError("handover: the first entry has no at_chainage_m, every later one needs it")
        if self.max_range_m <= self.min_range_m:
            raise ValueError("max_range_m must be > min_range_m")
        return self


PrismTruth = Union[Callable[[np.ndarray], np.ndarray], np.ndarray]


def facing_intervals(t: np.ndarray, chainage: np.ndarray, handover: list[Handover]) -> list[tuple[str, float, float]]:
    """(station, t_start, t_end) [s, IMU clock] during which the prism faces each station, in order.

    Each hand-over happens at the first truth epoch at which the chainage has crossed (or reached)
    ``at_chainage_m`` after the previous hand-over; hand-overs never reached are dropped.
    """
    start = 0
    bounds = []
    for h in handover[1:]:
        rel = chainage[start:] - h.at_chainage_m
        cross = np.flatnonzero((np.sign(rel[1:]) != np.sign(rel[:-1])) | (rel[1:] == 0))
        if cross.size == 0:
            break
        start += int(cross[0]) + 1
        bounds.append(start)
    edges = [0] + bounds + [t.size - 1]
    return [(h.station, float(t[a]), float(t[b])) for h, a, b in zip(handover, edges[:-1], edges[1:])]


def station_epochs(intervals: list[tuple[float, float]], rate_hz: float, offset_s: float,
                   drift_ppm: float) -> tuple[np.ndarray, np.ndarray]:
    """(IMU times (K,), station times (K,)) [s] of a station's samples: the regular grid
    k / rate_hz (k >= 0) of its own clock inside the given IMU-clock intervals (merged where they
    touch or overlap). The station times are that grid itself, never the IMU times plus the offset
    (whose rounding made a clock at 0 read -1e-16 s): a station clock never reads a negative time,
    whatever its offset; with a negative offset the station's first readings of the run are
    missing (its clock is not yet at 0)."""
    t_imu, t_station = [np.zeros(0)], [np.zeros(0)]
    for a, b in _merge(intervals):
        st_a, st_b = (np.array([a, b]) * (1.0 + drift_ppm * 1e-6) + offset_s) * rate_hz
        k = np.arange(max(np.ceil(st_a), 0.0), np.floor(st_b) + 1)  # a station clock starts at 0
        t = (k / rate_hz - offset_s) / (1.0 + drift_ppm * 1e-6)
        inside = (t >= a) & (t <= b)  # guard against rounding at the ends
        t_imu.append(t[inside])
        t_station.append(k[inside] / rate_hz)
    return np.concatenate(t_imu), np.concatenate(t_station)


def _merge(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Union of closed intervals, sorted; empty ones (end < start) dropped."""
    merged: list[list[float]] = []
    for a, b in sorted(iv for iv in intervals if iv[1] >= iv[0]):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged]


def tracking_intervals(facing: list[tuple[str, float, float]], station_id: str, spec: TotalStationSpec,
                        t_end_s: float) -> list[tuple[float, float]]:
    """IMU-time intervals tracked by one station: its facing intervals, less ``handover_gap_s`` at a
    hand-over start (not at the run start), plus ``handover_overlap_s`` after a hand-over away."""
    out = []
    for k, (sid, a, b) in enumerate(facing):
        if sid != station_id:
            continue
        a = a + (spec.handover_gap_s if k > 0 else 0.0)
        b = min(b + (spec.handover_overlap_s if k < len(facing) - 1 else 0.0), t_end_s)
        if b >= a:
            out.append((a, b))
    return out


def _prism_callable(t_truth: np.ndarray, prism_pos_n: PrismTruth) -> Callable[[np.ndarray], np.ndarray]:
    """The prism truth as a callable of IMU time: as given, or a cubic spline through (M, 3) samples."""
    if callable(prism_pos_n):
        return prism_pos_n
    pos = _series(prism_pos_n, t_truth.size, "total_stations", "prism_pos_n", 3)
    return CubicSpline(t_truth, pos, axis=0)


def draw_station_errors(st: StationConfig, spec: TotalStationSpec, rng: np.random.Generator,
                         ideal: bool) -> tuple[np.ndarray, float, float, float]:
    """(tilt (2,) [arcsec], orientation error [arcsec], clock offset [s], clock drift [ppm]); fixed
    values of the config win over draws; all zero when ideal. Draws happen in a fixed order."""
    mag, ang = rng.uniform(0.0, spec.max_tilt_arcsec), rng.uniform(0.0, 2 * np.pi)
    draws = (mag * np.array([np.cos(ang), np.sin(ang)]), rng.standard_normal() * spec.orientation_sigma_arcsec,
             rng.uniform(-spec.max_clock_offset_s, spec.max_clock_offset_s),
             rng.standard_normal() * spec.clock_drift_sigma_ppm)
    if ideal:
        return np.zeros(2), 0.0, 0.0, 0.0
    fixed = (st.tilt_arcsec, st.orientation_error_arcsec, st.clock_offset_s, st.clock_drift_ppm)
    tilt, orient, offset, drift = (d if f is None else f for f, d in zip(fixed, draws))
    return np.asarray(tilt, dtype=float), float(orient), float(offset), float(drift)


def draw_position_errors(spec: TotalStationSpec, rng: np.random.Generator, ideal: bool) -> np.ndarray:
    """(S, 3) set-up errors [mm] of the instrument points of ``spec.stations`` along ``n``'s axes:
    normal with ``position_sigma_mm`` per axis; fixed values of the config win; zero when ideal."""
    drawn = rng.standard_normal((len(spec.stations), 3)) * spec.position_sigma_mm
    if ideal:
        return np.zeros_like(drawn)
    fixed = [st.position_error_mm for st in spec.stations]
    return np.array([d if f is None else f for f, d in zip(fixed, drawn)], dtype=float).reshape(-1, 3)


def true_station_setup(st: StationConfig, tilt_arcsec, orientation_error_arcsec: float,
                       position_error_mm=(0.0, 0.0, 0.0)) -> StationSetup:
    """The true :class:`StationSetup` of a station config with its (drawn) tilt, orientation and
    position error [mm, ``n``]."""
    return StationSetup(st.id, tuple(float(x) for x in np.add(st.pos_n_m, 1e-3 * np.asarray(position_error_mm))),
                        float(np.radians(st.orientation_deg) + orientation_error_arcsec * ARCSEC),
                        tuple(float(x) * ARCSEC for x in tilt_arcsec), st.instrument_height_m)


def simulate_total_stations(t_truth_s: np.ndarray, chainage_m: np.ndarray, prism_pos_n: PrismTruth,
                            origin: geodesy.Origin, spec: TotalStationSpec, rng: np.random.Generator,
                            ideal: bool = False, *,
                            setup_rng: np.random.Generator) -> tuple[dict[str, TotalStationData], dict]:
    """Polar observations of the trolley prism by every station of ``spec.stations``.

    t_truth_s, chainage_m: (M,) truth epochs [s, IMU clock] and the trolley's chainage [m] there
    (places the hand-overs; sample densely, e.g. 20 Hz). prism_pos_n: the exact prism position in
    ``n`` as a callable mapping IMU times (K,) to (K, 3) [m], or an (M, 3) array at ``t_truth_s``
    that is interpolated by a cubic spline (truth at >= 20 Hz keeps the spline error below
    0.01 mm for trolley motion). Each station samples at ``rate_hz`` on its *own* clock
    (``t_station = t_imu + offset + drift t_imu``) while the prism faces it and it is within range
    and line of sight. The set-ups' position errors are drawn from ``setup_rng`` (a stream of
    their own: the other draws of a seed do not depend on them). Returns {station id: observations
    (station clock)} and the drawn errors ``{"stations": {id: {"clock_offset_s", "clock_drift_ppm",
    "tilt_arcsec", "tilt_magnitude_arcsec", "tilt_lean_azimuth_deg", "orientation_error_arcsec",
    "orientation_rad", "position_error_mm", "pos_n_m", "instrument_height_m", "tracking_intervals_s",
    "observations", "angle_noise_rms_arcsec", "distance_noise_rms_mm"}}, "refraction_k"}``;
    ``orientation_rad`` and ``pos_n_m`` are the true orientation and point (or mark).
    """
    t_truth = _times(t_truth_s, "total_stations")
    chainage = _series(chainage_m, t_truth.size, "total_stations", "chainage_m")
    prism_at = _prism_callable(t_truth, prism_pos_n)
    facing = facing_intervals(t_truth, chainage, spec.handover)
    data: dict[str, TotalStationData] = {}
    drawn: dict[str, dict] = {}
    for st, pos_err in zip(spec.stations, draw_position_errors(spec, setup_rng, ideal)):
        tilt, orient_err, offset, drift = draw_station_errors(st, spec, rng, ideal)
        setup = true_station_setup(st, tilt, orient_err, pos_err)
        tracked = tracking_intervals(facing, st.id, spec, float(t_truth[-1]))
        t_imu, t_station = station_epochs(tracked, spec.rate_hz, offset, drift)
        seen = ~_in_intervals(t_imu, st.blocked)
        t_imu, t_station = t_imu[seen], t_station[seen]
        prism = np.asarray(prism_at(t_imu), dtype=float).reshape(-1, 3) if t_imu.size else np.zeros((0, 3))
        for ml in st.mislocks:
            prism[_in_intervals(t_imu, [ml])] = ml.target_n_m
        hz, zen, dist = n_to_polar(prism, setup, origin, spec.refraction_k)
        ok = (dist >= spec.min_range_m) & (dist <= spec.max_range_m)
        t_imu, t_station, hz, zen, dist = t_imu[ok], t_station[ok], hz[ok], zen[ok], dist[ok]
        e_hz, e_zen, e_dist = _polar_noise(dist, spec, rng, ideal)
        data[st.id] = TotalStationData(st.id, t_station,
                                       np.mod(hz + e_hz, 2 * np.pi), zen + e_zen, dist + e_dist,
                                       np.full(t_imu.size, spec.prism_id, dtype=object))
        drawn[st.id] = {
            "clock_offset_s": offset, "clock_drift_ppm": drift, "tilt_arcsec": [float(x) for x in tilt],
            "tilt_magnitude_arcsec": float(np.hypot(*tilt)),
            "tilt_lean_azimuth_deg": float(np.degrees(np.arctan2(tilt[1], -tilt[0])) % 360.0),
            "orientation_error_arcsec": orient_err, "orientation_rad": float(setup.orientation_rad),
            "position_error_mm": pos_err.tolist(), "pos_n_m": list(setup.pos_n), "instrument_height_m": st.instrument_height_m,
            "tracking_intervals_s": [list(iv) for iv in tracked], "observations": int(t_imu.size),
            "mislock_times_s": t_imu[_in_intervals(t_imu, st.mislocks)].tolist(),
            "angle_noise_rms_arcsec": _rms(np.concatenate([e_hz, e_zen])) / ARCSEC,
            "distance_noise_rms_mm": _rms(e_dist) * 1e3}
    return data, {"stations": drawn, "refraction_k": spec.refraction_k}


def _polar_noise(dist_m: np.ndarray, spec: TotalStationSpec, rng: np.random.Generator,
                 ideal: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """White noise (K,) of hz, zenith [rad] and distance [m] (``distance_sigma_mm`` + ``distance_ppm`` d)."""
    if ideal:
        z = np.zeros(dist_m.size)
        return z, z.copy(), z.copy()
    sig_a = spec.angle_sigma_arcsec * ARCSEC
    sig_d = spec.distance_sigma_mm * 1e-3 + spec.distance_ppm * 1e-6 * dist_m
    return (noise.white(dist_m.size, sig_a, rng), noise.white(dist_m.size, sig_a, rng),
            rng.standard_normal(dist_m.size) * sig_d)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else 0.0


# --- inclinometer and gauge ---------------------------------------------------------------------------

class InclinometerSpec(StrictModel):
    """Two-axis inclinometer (seed 004: good static, slow dynamic response): first-order lag
    ``time_constant_s`` (0: none), white noise ``sigma_arcsec``, constant bias per axis drawn with
    1-sigma ``bias_arcsec``."""

    rate_hz: float = Field(50.0, gt=0)
    time_constant_s: float = Field(0.5, ge=0)
    sigma_arcsec: float = Field(5.0, ge=0)
    bias_arcsec: float = Field(10.0, ge=0)


def first_order_lag(x: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """Response (N,) of ``tau dy/dt = x - y`` to samples ``x`` (N,) ``dt_s`` apart, starting at rest at
    ``x[0]``: ``y_k = a y_{k-1} + (1 - a) x_k`` with ``a = exp(-dt / tau)`` (``tau_s`` = 0: ``y = x``)."""
    x = np.asarray(x, dtype=float)
    if tau_s <= 0 or x.size == 0:
        return x.copy()
    a = np.exp(-dt_s / tau_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return y


def simulate_inclinometer(t_s, roll_rad, pitch_rad, spec: InclinometerSpec, rng: np.random.Generator,
                          ideal: bool = False) -> tuple[InclinometerData, dict]:
    """Inclinometer readings at the (regular) epochs ``t_s`` (N,) [s] of the true roll and pitch (N,)
    [rad] against the local plumb line: lag, then bias and white noise. Drawn: ``bias_rad``
    [roll, pitch]."""
    t = _times(t_s, "inclinometer")
    angles = [_series(x, t.size, "inclinometer", f) for x, f in ((roll_rad, "roll_rad"), (pitch_rad, "pitch_rad"))]
    if ideal:
        return InclinometerData(t, angles[0].copy(), angles[1].copy()), {"ideal": True, "bias_rad": [0.0, 0.0]}
    dt = _step_s(t, spec.rate_hz)
    bias = rng.standard_normal(2) * spec.bias_arcsec * ARCSEC
    out = [first_order_lag(x, dt, spec.time_constant_s) + b + noise.white(t.size, spec.sigma_arcsec * ARCSEC, rng)
           for x, b in zip(angles, bias)]
    return InclinometerData(t, out[0], out[1]), {"ideal": False, "bias_rad": bias.tolist()}


class GaugeSpec(StrictModel):
    """Gauge sensor: white noise ``sigma_mm`` and a constant bias drawn with 1-sigma ``bias_mm``."""

    rate_hz: float = Field(50.0, gt=0)
    sigma_mm: float = Field(0.1, ge=0)
    bias_mm: float = Field(0.2, ge=0)


def simulate_gauge(t_s, gauge_m, spec: GaugeSpec, rng: np.random.Generator, ideal: bool = False
                   ) -> tuple[GaugeData, dict]:
    """Gauge readings at ``t_s`` (N,) [s] of the true gauge (N,) [m]. Drawn: ``bias_m``."""
    t = _times(t_s, "gauge")
    g = _series(gauge_m, t.size, "gauge", "gauge_m")
    if ideal:
        return GaugeData(t, g.copy()), {"ideal": True, "bias_m": 0.0}
    bias = rng.standard_normal() * spec.bias_mm * 1e-3
    return GaugeData(t, g + bias + noise.white(t.size, spec.sigma_mm * 1e-3, rng)), {"ideal": False,
                                                                                   "bias_m": float(bias)}
