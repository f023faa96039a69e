"""Time synchronisation of a total station with the IMU/odometer clock (seed 003 section 2.2.2).

Each robotic total station stamps its readings with its own clock,
``t_station = t_imu + offset_s (+ drift t_imu)`` (DESIGN.md section 4). The seed finds
``offset_s`` in three steps, and so does :func:`synchronise`:

1. the prism speed from differenced positions of consecutive readings (station clock);
2. the reference speed over the *same* differencing intervals, shifted by a trial lag, from
   the odometer distance (IMU clock); the Pearson correlation ``r`` (seed eq. 3) over a grid
   of lags;
3. the lag of the largest ``r`` (``r_max``), refined below the grid step by a parabola
   through the peak and its two neighbours.

Why the odometer speed and not a first IMU + odometer smoothing pass: the odometer is on
the IMU clock already, its speed needs no smoothing pass (which would double the run's
cost), and its scale error multiplies the speed, which Pearson's ``r`` ignores. Both speeds
are formed by the same difference operator over the same intervals, so their filtering is
identical and the correlation peak is not biased by unequal smoothing.

The correlation's peak is good to some tens of milliseconds (the speed signal lives in the
starts and stops); the fusion refines each station's clock offset and drift further as
states of the factor graph (docs/total_stations.md), seeded with this result.

Refused, with :class:`~trackfusion.errors.RegistrationError`: a station that saw no motion in
its interval (nothing to correlate), ``r_max`` below ``min_r``, and an ambiguous peak
(another local maximum more than ``exclusion_s`` away within ``ambiguity_margin`` of
``r_max``).

A linear clock drift is not resolved here: over a few minutes of constant speed the speed
profile carries no timing information, so halves of an interval do not synchronise
separately. The factor graph estimates the drift (optional) together with the offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pydantic import Field

from ..errors import RegistrationError
from ..strict import StrictModel


class TimeSyncSettings(StrictModel):
    """``factors.total_stations.time_sync`` of a pipeline YAML. ``max_lag_s``: lags searched are
    ``[-max_lag_s, max_lag_s]``, first on a grid of ``lag_step_s``, then on ``fine_step_s`` within
    two coarse steps of the coarse peak; ``min_r``: smallest acceptable ``r_max``;
    ``ambiguity_margin``: a second peak this close to ``r_max`` makes the result ambiguous;
    ``exclusion_s``: how far from the best lag a second peak must lie; ``min_travel_m``: least
    travel (odometer) in the station's interval; ``max_gap_factor``: readings further apart than
    this many median intervals are not differenced; prism speeds above ``max_speed_factor`` times
    the odometer's highest speed plus ``speed_margin_mps`` are left out (jumps)."""

    max_lag_s: float = Field(10.0, gt=0)
    lag_step_s: float = Field(0.1, gt=0)
    fine_step_s: float = Field(0.005, gt=0)
    min_r: float = Field(0.8, gt=-1, le=1)
    ambiguity_margin: float = Field(0.02, ge=0)
    exclusion_s: float = Field(2.0, gt=0)
    min_travel_m: float = Field(1.0, gt=0)
    max_gap_factor: float = Field(1.5, gt=1)
    max_speed_factor: float = Field(1.5, gt=0)
    speed_margin_mps: float = Field(0.3, ge=0)


@dataclass(frozen=True)
class TimeSync:
    """Result for one station: ``offset_s`` (station clock minus IMU clock), ``r_max``, the
    correlation curve ``lags_s`` (L,) and ``r`` (L,), ``n_pairs`` speed samples used, and
    ``drift_ppm`` (0 here; the fusion may estimate it)."""

    station_id: str
    offset_s: float
    r_max: float
    lags_s: np.ndarray
    r: np.ndarray
    n_pairs: int
    drift_ppm: float = 0.0

    def to_json(self, max_points: int = 401) -> dict:
        """The contract's ``time_sync`` entry (the curve thinned to at most ``max_points``)."""
        step = max(1, int(np.ceil(self.lags_s.size / max_points)))
        return {"offset_s": self.offset_s, "r_max": self.r_max, "drift_ppm": self.drift_ppm,
                "n_pairs": self.n_pairs, "lags_s": self.lags_s[::step].tolist(), "r": self.r[::step].tolist()}


def prism_speed(t_station_s: np.ndarray, pos_n: np.ndarray, max_gap_factor: float = 1.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed [m/s] from consecutive prism positions (N,3) [m] at station times (N,) [s].

    Returns (t_start (M,), t_end (M,), speed (M,)) of the differenced pairs whose gap is at most
    ``max_gap_factor`` times the median reading interval (gaps in tracking are skipped).
    """
    t = np.asarray(t_station_s, dtype=float)
    dt = np.diff(t)
    if t.size < 3:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    ok = (dt > 0) & (dt <= max_gap_factor * np.median(dt[dt > 0]))
    speed = np.linalg.norm(np.diff(pos_n, axis=0), axis=1)[ok] / dt[ok]
    return t[:-1][ok], t[1:][ok], speed


def reference_speed(t0_imu_s: np.ndarray, t1_imu_s: np.ndarray, odo_t_s: np.ndarray,
                    odo_distance_m: np.ndarray) -> np.ndarray:
    """|odometer distance difference| / interval over the given IMU-clock intervals (M,) [m/s]."""
    d0 = np.interp(t0_imu_s, odo_t_s, odo_distance_m)
    d1 = np.interp(t1_imu_s, odo_t_s, odo_distance_m)
    return np.abs(d1 - d0) / (t1_imu_s - t0_imu_s)


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    # plain sums, not np.dot: BLAS threads for a 10^4-vector cost ~40 ms each on a busy machine
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else np.nan


def correlation_curve(t0_s: np.ndarray, t1_s: np.ndarray, speed_mps: np.ndarray, odo_t_s: np.ndarray,
                      odo_distance_m: np.ndarray, lags_s: np.ndarray) -> np.ndarray:
    """Pearson ``r`` (L,) between the prism speed and the odometer speed for each trial offset
    (station clock minus IMU clock) in ``lags_s`` (L,). Pairs that fall outside the odometer's
    span at a lag are left out at that lag; ``nan`` where fewer than 10 pairs remain."""
    r = np.full(lags_s.size, np.nan)
    lo, hi = odo_t_s[0], odo_t_s[-1]
    # consecutive pairs share their readings (one pair's end is the next one's start): the odometer
    # is interpolated once per distinct reading time, the same values as reference_speed's
    times, which = np.unique(np.r_[t0_s, t1_s], return_inverse=True)
    start, end = which[:t0_s.size], which[t0_s.size:]
    for i, lag in enumerate(lags_s):
        a, b = t0_s - lag, t1_s - lag
        inside = (a >= lo) & (b <= hi)
        if np.count_nonzero(inside) >= 10:
            d = np.interp(times - lag, odo_t_s, odo_distance_m)
            ref = np.abs(d[end[inside]] - d[start[inside]]) / (b[inside] - a[inside])  # = reference_speed
            r[i] = _pearson(speed_mps[inside], ref)
    return r


def _parabola_peak(lags: np.ndarray, r: np.ndarray, i: int) -> tuple[float, float]:
    """Vertex (lag, r) of the parabola through the grid peak ``i`` and its neighbours."""
    if i == 0 or i == lags.size - 1 or not np.all(np.isfinite(r[i - 1:i + 2])):
        return float(lags[i]), float(r[i])
    y0, y1, y2 = r[i - 1], r[i], r[i + 1]
    den = y0 - 2.0 * y1 + y2
    if den >= 0:
        return float(lags[i]), float(y1)
    u = 0.5 * (y0 - y2) / den  # in grid steps, within [-0.5, 0.5] at a true peak
    step = lags[i + 1] - lags[i]
    return float(lags[i] + u * step), float(y1 - 0.25 * (y0 - y2) * u)


def _second_peak(lags: np.ndarray, r: np.ndarray, best_lag: float, exclusion_s: float) -> float:
    """Largest local maximum of ``r`` more than ``exclusion_s`` from ``best_lag`` (-inf: none)."""
    rr = np.where(np.isfinite(r), r, -np.inf)
    interior = (rr[1:-1] >= rr[:-2]) & (rr[1:-1] >= rr[2:]) & np.isfinite(r[1:-1])
    idx = np.flatnonzero(interior) + 1
    far = idx[np.abs(lags[idx] - best_lag) > exclusion_s]
    return float(rr[far].max()) if far.size else -np.inf


def _correlation_peak(station_id: str, t0: np.ndarray, t1: np.ndarray, v: np.ndarray, odo_t: np.ndarray,
                      odo_d: np.ndarray, coarse: np.ndarray, settings: TimeSyncSettings) -> tuple:
    """The correlation on the coarse lags, then on the fine grid around its peak: (r_coarse,
    coarse peak lag, fine lags, r_fine, best lag (parabola), r_max)."""
    r_coarse = correlation_curve(t0, t1, v, odo_t, odo_d, coarse)
    if not np.any(np.isfinite(r_coarse)):
        raise RegistrationError(f"time sync: station {station_id}: no lag in +-{settings.max_lag_s:g} s "
                                "overlaps the odometer record")
    c = coarse[int(np.nanargmax(r_coarse))]
    n_fine = int(np.ceil(2.0 * settings.lag_step_s / settings.fine_step_s))
    fine = c + settings.fine_step_s * np.arange(-n_fine, n_fine + 1)
    r_fine = correlation_curve(t0, t1, v, odo_t, odo_d, fine)
    best, r_max = _parabola_peak(fine, r_fine, int(np.nanargmax(r_fine)))
    return r_coarse, c, fine, r_fine, best, r_max


#: a prism speed further than this many robust sigmas (and 0.1 m/s) from the odometer's is an outlier
SPEED_OUTLIER_SIGMA = 6.0


def _speed_inliers(a: np.ndarray, b: np.ndarray, v: np.ndarray, odo_t: np.ndarray, odo_d: np.ndarray) -> np.ndarray:
    """Prism speeds (M,) over the IMU-clock intervals [a, b] that agree with the odometer's: the
    residual to the odometer speed within ``SPEED_OUTLIER_SIGMA`` x 1.4826 x its median absolute
    deviation (and at least 0.1 m/s). Intervals outside the odometer span are kept."""
    inside = (a >= odo_t[0]) & (b <= odo_t[-1])
    res = np.zeros(v.size)
    res[inside] = v[inside] - reference_speed(a[inside], b[inside], odo_t, odo_d)
    mad = float(np.median(np.abs(res[inside] - np.median(res[inside])))) if inside.any() else 0.0
    return np.abs(res) <= max(SPEED_OUTLIER_SIGMA * 1.4826 * mad, 0.1)


def synchronise(station_id: str, t_station_s: np.ndarray, prism_pos_n: np.ndarray, odo_t_s: np.ndarray,
                odo_distance_m: np.ndarray, settings: TimeSyncSettings = TimeSyncSettings(),
                centre_s: float = 0.0) -> TimeSync:
    """Clock offset of one station (module docstring).

    t_station_s (N,) [s, station clock]; prism_pos_n (N,3) [m]; odo_t_s, odo_distance_m (M,) the
    odometer on the IMU clock. Lags are searched in ``centre_s +- max_lag_s``. Raises
    :class:`RegistrationError` for no motion, a weak or an ambiguous correlation.
    """
    t0, t1, v = prism_speed(t_station_s, np.asarray(prism_pos_n, dtype=float), settings.max_gap_factor)
    if v.size < 10:
        raise RegistrationError(f"time sync: station {station_id}: fewer than 10 consecutive readings "
                                f"({np.asarray(t_station_s).size} readings) to form a prism speed")
    span = (t0[0] - centre_s - settings.max_lag_s, t1[-1] - centre_s + settings.max_lag_s)
    d_span = np.interp(np.array(span), odo_t_s, odo_distance_m)
    inside = (odo_t_s >= span[0]) & (odo_t_s <= span[1])
    travel = float(np.ptp(np.r_[odo_distance_m[inside], d_span]))
    if travel < settings.min_travel_m or np.ptp(v) == 0.0:
        raise RegistrationError(f"time sync: station {station_id}: the trolley did not move in the station's "
                                f"interval (odometer travel {travel:.3f} m < {settings.min_travel_m:g} m): "
                                "its clock cannot be synchronised; give sensors.total_stations.stations."
                                f"{station_id}.clock_offset_s")
    odo_t, odo_d = odo_t_s[inside], odo_distance_m[inside]
    if odo_t.size < 2:
        raise RegistrationError(f"time sync: station {station_id}: no odometer record within "
                                f"+-{settings.max_lag_s:g} s of the station's readings")
    # a jump of the reported point (mis-lock onto another reflector, a gross error) is no motion
    # of the trolley: leave out speeds the trolley never reached
    odo_speed = reference_speed(odo_t[:-1], odo_t[1:], odo_t, odo_d)
    plausible = v <= settings.max_speed_factor * float(odo_speed.max()) + settings.speed_margin_mps
    t0, t1, v = t0[plausible], t1[plausible], v[plausible]
    n_lag = int(np.floor(settings.max_lag_s / settings.lag_step_s + 1e-9))
    coarse = centre_s + settings.lag_step_s * np.arange(-n_lag, n_lag + 1)
    peak = _correlation_peak(station_id, t0, t1, v, odo_t, odo_d, coarse, settings)
    # a mis-lock: a station locked onto a fixed reflector reports no motion while the trolley moves;
    # leave out such speed outliers (against the odometer at the first peak) and correlate again
    keep = _speed_inliers(t0 - peak[4], t1 - peak[4], v, odo_t, odo_d)
    if not keep.all():
        t0, t1, v = t0[keep], t1[keep], v[keep]
        peak = _correlation_peak(station_id, t0, t1, v, odo_t, odo_d, coarse, settings)
    r_coarse, c, fine, r_fine, best, r_max = peak
    lags = np.r_[coarse[coarse < fine[0]], fine, coarse[coarse > fine[-1]]]
    r = np.r_[r_coarse[coarse < fine[0]], r_fine, r_coarse[coarse > fine[-1]]]
    if not r_max >= settings.min_r:
        raise RegistrationError(f"time sync: station {station_id}: best correlation r_max = {r_max:.3f} is "
                                f"below the limit {settings.min_r:g} (lag {best:.3f} s): the prism speed does "
                                "not match the odometer's")
    if coarse[0] == c or coarse[-1] == c:
        raise RegistrationError(f"time sync: station {station_id}: the correlation peaks at the edge of the lag "
                                f"range ({best:.3f} s); widen time_sync.max_lag_s")
    second = _second_peak(coarse, r_coarse, best, settings.exclusion_s)
    if r_max - second < settings.ambiguity_margin:
        raise RegistrationError(f"time sync: station {station_id}: ambiguous correlation peak (r = {r_max:.3f} "
                                f"at {best:.3f} s, another peak r = {second:.3f} more than "
                                f"{settings.exclusion_s:g} s away)")
    return TimeSync(station_id, best, r_max, lags, r, int(v.size))
