"""Fault injection into raw logs: the data faults of real surveys, on demand (docs/robustness.md).

Each injector takes a :class:`~trackfusion.sensors.types.SensorLog` and returns a *new* log
with one fault added (the input's arrays are never modified), plus a JSON-able description of
what was injected (the truth the detection is checked against). ``benchmarks/faults.py`` and
the tests use them; :data:`INJECTORS` lists them by name with the strengths the benchmark
runs (``strength`` is each injector's main keyword).

Adding a fault takes one function of the same form, ``inject_x(log, *, strength, **options) ->
(new_log, info)``, and one :data:`INJECTORS` entry (faults of any log with GNSS and odometer)
or :data:`TS_INJECTORS` entry (total-station faults, run on a bridge survey); the benchmark
picks it up.

Times are on each sensor's own clock [s]; positions are displaced in the local ENU frame of
each fix [m].
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from .. import geodesy
from ..errors import SimulationError
from ..sensors.types import GnssData, ImuData, OdometerData, SensorLog, TotalStationData
from . import noise
from .aiding import TotalStationSpec

__all__ = ["inject_gnss_outliers", "inject_gnss_float", "inject_gnss_outage", "inject_odometer_slip",
           "inject_odometer_gross_errors", "inject_clock_jump", "drop_static_start", "inject_imu_saturation",
           "motion_start_s", "inject_prism_mislock", "inject_prism_gap", "INJECTORS", "TS_INJECTORS", "Injector"]


def _copy(log: SensorLog) -> SensorLog:
    """A deep copy (every array new)."""
    return copy.deepcopy(log)


def _need(data, name: str):
    if data is None or data.t_s.size == 0:
        raise SimulationError(f"fault injection: the log has no {name} data")
    return data


def _displace_fixes(g: GnssData, idx: np.ndarray, d_local_m: np.ndarray) -> GnssData:
    """Fixes ``idx`` moved by ``d_local_m`` (len(idx), 3) [m] in their local ENU frames (exactly, via ECEF)."""
    origin = geodesy.Origin(float(g.lat_deg[0]), float(g.lon_deg[0]), float(g.h_m[0]))
    pos_n = geodesy.geodetic_to_n(g.lat_deg[idx], g.lon_deg[idx], g.h_m[idx], origin)
    moved = pos_n + np.einsum("kij,kj->ki", geodesy.R_n_local(pos_n, origin), d_local_m)
    lat, lon, h = geodesy.n_to_geodetic(moved, origin)
    out = replace(g, lat_deg=g.lat_deg.copy(), lon_deg=g.lon_deg.copy(), h_m=g.h_m.copy())
    out.lat_deg[idx], out.lon_deg[idx], out.h_m[idx] = lat, lon, h
    return out


def inject_gnss_outliers(log: SensorLog, *, strength: float = 0.05, min_m: float = 0.3, max_m: float = 3.0,
                         seed: int = 0) -> tuple[SensorLog, dict]:
    """Displace a fraction ``strength`` of the fixes by ``min_m``..``max_m`` (uniform) in a random
    3-D direction, reported covariance unchanged (multipath)."""
    g = _need(log.gnss, "GNSS")
    rng = np.random.default_rng(seed)
    n = int(round(strength * g.t_s.size))
    idx = np.sort(rng.choice(g.t_s.size, size=n, replace=False))
    u = rng.normal(size=(n, 3))
    d = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(min_m, max_m, n)[:, None]
    out = _copy(log)
    out.gnss = _displace_fixes(g, idx, d)
    return out, {"fault": "gnss_outliers", "fraction": strength, "t_s": g.t_s[idx].tolist(),
                 "displacement_m": np.linalg.norm(d, axis=1).tolist()}


def inject_gnss_float(log: SensorLog, *, strength: float = 0.1, start_s: float | None = None,
                      duration_s: float = 60.0, tau_s: float = 30.0, seed: int = 0) -> tuple[SensorLog, dict]:
    """An RTK-float episode: fixes in [start_s, start_s + duration_s) get quality 5, a Gauss-Markov
    error of ``strength`` [m] 1-sigma per horizontal axis (twice that vertically) with correlation
    time ``tau_s``, and covariances inflated to match. ``start_s`` defaults to mid-run."""
    g = _need(log.gnss, "GNSS")
    start = float(np.median(g.t_s)) if start_s is None else start_s
    idx = np.flatnonzero((g.t_s >= start) & (g.t_s < start + duration_s))
    rng = np.random.default_rng(seed)
    sigma = np.array([strength, strength, 2.0 * strength])
    dt_s = float(np.median(np.diff(g.t_s)))
    err = np.column_stack([noise.gauss_markov(idx.size, dt_s, s, tau_s, rng) for s in sigma])
    out = _copy(log)
    out.gnss = _displace_fixes(g, idx, err)
    out.gnss.fix_quality = np.asarray(g.fix_quality).copy()
    out.gnss.fix_quality[idx] = 5
    out.gnss.cov_enu_m2 = g.cov_enu_m2.copy()
    out.gnss.cov_enu_m2[idx] += np.diag(sigma**2)
    return out, {"fault": "gnss_float", "start_s": start, "end_s": start + duration_s, "fixes": int(idx.size),
                 "sigma_h_m": strength}


def inject_gnss_outage(log: SensorLog, *, strength: float = 30.0, start_s: float | None = None
                       ) -> tuple[SensorLog, dict]:
    """Remove the fixes in [start_s, start_s + strength) [s] (``start_s`` default: mid-run)."""
    g = _need(log.gnss, "GNSS")
    start = float(np.median(g.t_s)) if start_s is None else start_s
    keep = ~((g.t_s >= start) & (g.t_s < start + strength))
    out = _copy(log)
    out.gnss = GnssData(g.t_s[keep], g.lat_deg[keep], g.lon_deg[keep], g.h_m[keep], g.cov_enu_m2[keep],
                        np.asarray(g.fix_quality)[keep])
    return out, {"fault": "gnss_outage", "start_s": start, "duration_s": strength, "fixes_removed": int((~keep).sum())}


def motion_start_s(log: SensorLog, threshold_m: float = 1e-3, from_end: bool = False) -> float:
    """Time [s] the odometer first (``from_end``: last) reports more than ``threshold_m`` of travel
    from its first (last) reading."""
    o = _need(log.odometer, "odometer")
    ref = o.distance_m[-1] if from_end else o.distance_m[0]
    moved = np.flatnonzero(np.abs(o.distance_m - ref) > threshold_m)
    if not moved.size:
        raise SimulationError("fault injection: the odometer never moves")
    return float(o.t_s[moved[-1] if from_end else moved[0]])


def _moving_time(log: SensorLog, after_s: float) -> float:
    """The time ``after_s`` [s] after the motion starts."""
    return motion_start_s(log) + after_s


def inject_odometer_slip(log: SensorLog, *, strength: float = 0.02, start_s: float | None = None,
                         duration_s: float = 0.5) -> tuple[SensorLog, dict]:
    """A wheel slip: ``strength`` [m] of extra reported distance (negative: lost) accrued evenly over
    [start_s, start_s + duration_s) and kept afterwards (ticks follow). ``start_s`` default: 40 s
    after the motion starts."""
    o = _need(log.odometer, "odometer")
    start = _moving_time(log, 40.0) if start_s is None else start_s
    ramp = strength * np.clip((o.t_s - start) / duration_s, 0.0, 1.0)
    ticks_per_m = _ticks_per_m(o)
    out = _copy(log)
    out.odometer = OdometerData(o.t_s.copy(), o.distance_m + ramp,
                                o.ticks + np.round(ramp * ticks_per_m).astype(o.ticks.dtype))
    return out, {"fault": "odometer_slip", "start_s": start, "end_s": start + duration_s, "extra_m": strength}


def _ticks_per_m(o: OdometerData) -> float:
    dd = np.diff(o.distance_m)
    return float(np.diff(o.ticks.astype(float)) @ dd / max(dd @ dd, 1e-300))


def inject_odometer_gross_errors(log: SensorLog, *, strength: float = 0.03, count: int = 10, seed: int = 0
                                 ) -> tuple[SensorLog, dict]:
    """``count`` isolated spikes of +-``strength`` [m] in the reported distance at random samples
    (the ticks unchanged, as a glitch of the distance output)."""
    o = _need(log.odometer, "odometer")
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(np.arange(20, o.t_s.size - 20), size=count, replace=False))
    out = _copy(log)
    out.odometer.distance_m[idx] += strength * rng.choice([-1.0, 1.0], size=count)
    return out, {"fault": "odometer_gross_errors", "t_s": o.t_s[idx].tolist(), "magnitude_m": strength}


def _stream(log: SensorLog, topic: str):
    """The data of ``topic`` (``/gnss``, ``/odometer``, ``/inclinometer``, ``/total_station/<id>``)."""
    if topic.startswith("/total_station/"):
        return _need(log.total_stations.get(topic.split("/", 2)[2]), topic)
    return _need(getattr(log, topic.strip("/"), None), topic)


def _with_stream(log: SensorLog, topic: str, data) -> SensorLog:
    """A copy of ``log`` with ``topic``'s data replaced by ``data``."""
    out = _copy(log)
    if topic.startswith("/total_station/"):
        out.total_stations[topic.split("/", 2)[2]] = data
    else:
        setattr(out, topic.strip("/"), data)
    return out


def inject_clock_jump(log: SensorLog, *, strength: float = 0.3, topic: str = "/gnss", at_s: float | None = None
                      ) -> tuple[SensorLog, dict]:
    """Every time stamp of ``topic`` (``/gnss``, ``/odometer``, ``/inclinometer`` or
    ``/total_station/<id>``) from ``at_s`` on (the sensor's own clock) moves by ``strength`` [s]
    (a clock step; the data are unchanged). ``at_s`` default: 60 s after the motion starts (or
    mid-run without an odometer); for a total station, 100 s after its first reading."""
    data = _stream(log, topic)
    if at_s is None:
        if topic.startswith("/total_station/"):
            at_s = float(data.t_s[0]) + 100.0
        else:
            at_s = _moving_time(log, 60.0) if log.odometer is not None else float(np.median(data.t_s))
    t = data.t_s.copy()
    after = t >= at_s
    t[after] += strength
    if np.any(np.diff(t) <= 0):
        raise SimulationError(f"fault injection: a clock jump of {strength} s at {at_s} s makes {topic} go backwards")
    return _with_stream(log, topic, replace(data, t_s=t)), {"fault": "clock_jump", "topic": topic, "at_s": float(at_s),
                                                           "step_s": strength}


# --- total stations (times on the station's clock) ---------------------------------------------------

def _station_window(log: SensorLog, station: str, start_s: float | None, duration_s: float
                    ) -> tuple[TotalStationData, np.ndarray, float]:
    """The station's readings, the mask of those in [start, start + duration_s) and start [s,
    station clock]; ``start_s`` default: 50 s after the station's first reading."""
    ts = _stream(log, f"/total_station/{station}")
    start = float(ts.t_s[0]) + 50.0 if start_s is None else float(start_s)
    sel = (ts.t_s >= start) & (ts.t_s < start + duration_s)
    if not sel.any():
        raise SimulationError(f"fault injection: station {station} has no readings in [{start}, {start + duration_s}) s")
    return ts, sel, start


def inject_prism_mislock(log: SensorLog, *, strength: float = 10.0, station: str = "TS01",
                         start_s: float | None = None, offset_m: float = 8.0, moving: bool = False,
                         seed: int = 0) -> tuple[SensorLog, dict]:
    """``station`` reads another reflector for ``strength`` [s] from ``start_s`` (station clock;
    default 50 s after its first reading). Static (default): a fixed reflector ``offset_m``
    beside the line of sight to the prism at the first mis-locked reading, read with the
    instrument's noise (``TotalStationSpec`` defaults: 0.5", 3 mm). ``moving``: a reflector
    travelling with the prism, ``offset_m`` beside it (the horizontal angle turned by
    ``offset_m`` / horizontal distance, reading by reading)."""
    ts, sel, start = _station_window(log, station, start_s, strength)
    hz, zen, dist = ts.horizontal_angle_rad.copy(), ts.zenith_angle_rad.copy(), ts.slope_distance_m.copy()
    idx = np.flatnonzero(sel)
    turn = offset_m / (dist[idx] * np.sin(zen[idx]))      # from the noise-free reading: no leak of the noise
    if not moving:
        rng = np.random.default_rng(seed)
        spec = TotalStationSpec.model_fields
        sig_a = np.radians(spec["angle_sigma_arcsec"].default / 3600.0)
        k = idx.size
        hz[idx] = hz[idx[0]] + rng.standard_normal(k) * sig_a
        zen[idx] = zen[idx[0]] + rng.standard_normal(k) * sig_a
        dist[idx] = dist[idx[0]] + rng.standard_normal(k) * spec["distance_sigma_mm"].default * 1e-3
    hz[idx] = np.mod(hz[idx] + (turn[0] if not moving else turn), 2 * np.pi)
    new = replace(ts, horizontal_angle_rad=hz, zenith_angle_rad=zen, slope_distance_m=dist)
    return _with_stream(log, f"/total_station/{station}", new), {
        "fault": "prism_mislock", "station": station, "start_s": start, "end_s": start + strength,
        "readings": int(idx.size), "t_s": ts.t_s[idx].tolist(), "offset_m": offset_m, "moving": moving}


def inject_prism_gap(log: SensorLog, *, strength: float = 30.0, station: str = "TS01", start_s: float | None = None
                     ) -> tuple[SensorLog, dict]:
    """``station`` loses lock for ``strength`` [s] from ``start_s`` (station clock; default 50 s
    after its first reading): its readings in that interval are removed."""
    ts, sel, start = _station_window(log, station, start_s, strength)
    keep = ~sel
    new = TotalStationData(ts.station_id, ts.t_s[keep], ts.horizontal_angle_rad[keep], ts.zenith_angle_rad[keep],
                           ts.slope_distance_m[keep], ts.prism_id[keep])
    return _with_stream(log, f"/total_station/{station}", new), {
        "fault": "prism_gap", "station": station, "start_s": start, "end_s": start + strength,
        "readings_removed": int(sel.sum())}


def drop_static_start(log: SensorLog, *, strength: float = 0.0, ends: tuple[str, ...] = ("start",)
                      ) -> tuple[SensorLog, dict]:
    """Cut every sensor's data before the motion starts (+ ``strength`` [s]) and, with ``"end"`` in
    ``ends``, after it stops (- ``strength``): a run without a static period at that end (logging
    began late or stopped early). Needs an odometer (to find the motion)."""
    lo = motion_start_s(log) + strength if "start" in ends else -np.inf
    hi = motion_start_s(log, from_end=True) - strength if "end" in ends else np.inf
    out = _copy(log)
    for name in ("imu", "odometer", "gnss", "inclinometer", "gauge"):
        data = getattr(out, name)
        if data is None:
            continue
        keep = (data.t_s >= lo) & (data.t_s <= hi)
        fields = {k: (np.asarray(v)[keep] if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape else v)
                  for k, v in vars(data).items()}
        setattr(out, name, type(data)(**fields))
    return out, {"fault": "missing_static_period", "ends": list(ends),
                 "kept_s": [float(v) if np.isfinite(v) else None for v in (lo, hi)]}


def inject_imu_saturation(log: SensorLog, *, strength: float = 0.2, limit: float, axis: int = 2,
                          field: str = "accel_mps2", start_s: float | None = None) -> tuple[SensorLog, dict]:
    """An IMU axis pinned at ``limit`` (its range, in the field's unit) for ``strength`` [s] from
    ``start_s`` (default mid-run): a saturation, which ``trackfusion run`` refuses."""
    imu: ImuData = _need(log.imu, "IMU")
    start = float(np.median(imu.t_s)) if start_s is None else start_s
    sel = (imu.t_s >= start) & (imu.t_s < start + strength)
    out = _copy(log)
    getattr(out.imu, field)[sel, axis] = limit
    return out, {"fault": "imu_saturation", "start_s": start, "samples": int(sel.sum()), "field": field, "axis": axis}


@dataclass(frozen=True)
class Injector:
    """A fault of the benchmark: its injector, the strengths to run (unit in ``unit``), and the
    ``faults`` entry of metrics.json that must report it."""

    inject: Callable[..., tuple[SensorLog, dict[str, Any]]]
    strengths: tuple[float, ...]
    unit: str
    detected_as: str


#: the faults ``benchmarks/faults.py`` injects, by name
INJECTORS: dict[str, Injector] = {
    "gnss_outliers": Injector(inject_gnss_outliers, (0.02, 0.05, 0.10), "fraction of fixes", "gnss_outliers"),
    "gnss_float": Injector(inject_gnss_float, (0.05, 0.2, 0.5), "m (1-sigma horizontal)", "gnss_float"),
    "gnss_outage": Injector(inject_gnss_outage, (10.0, 30.0, 60.0), "s", "gnss_outages"),
    "odometer_slip": Injector(inject_odometer_slip, (0.005, 0.02, 0.1), "m", "odometer_slips"),
    "odometer_gross_errors": Injector(inject_odometer_gross_errors, (0.02, 0.05, 0.5), "m",
                                      "odometer_gross_errors"),
    "gnss_clock_jump": Injector(inject_clock_jump, (0.1, 0.3, 2.0), "s", "clock_jumps"),
    "odometer_clock_jump": Injector(lambda log, *, strength: inject_clock_jump(log, strength=strength,
                                                                              topic="/odometer"),
                                    (0.005, 0.05, 0.5), "s", "clock_jumps"),
    "missing_static_start": Injector(drop_static_start, (0.0,), "s after the motion starts",
                                     "missing_static_period"),
    "missing_static_both_ends": Injector(lambda log, *, strength: drop_static_start(log, strength=strength,
                                                                                   ends=("start", "end")),
                                         (0.0,), "s inside the motion", "missing_static_period"),
}

def _station_jump_in_gap(log: SensorLog, *, strength: float, station: str = "TS01") -> tuple[SensorLog, dict]:
    """``station`` loses the prism for 10 s from 50 s after its first reading, and its clock
    jumps by ``strength`` [s] in the middle of that gap (no reading sees the step)."""
    t0 = float(_stream(log, f"/total_station/{station}").t_s[0])
    gapped, gap = inject_prism_gap(log, strength=10.0, station=station, start_s=t0 + 50.0)
    out, info = inject_clock_jump(gapped, strength=strength, topic=f"/total_station/{station}", at_s=t0 + 55.0)
    return out, {**info, "gap": gap}


#: total-station faults ``benchmarks/faults.py`` injects into a short bridge survey (TS01), by name
TS_INJECTORS: dict[str, Injector] = {
    "prism_mislock": Injector(inject_prism_mislock, (2.0, 10.0, 30.0), "s (static reflector 8 m aside)",
                              "prism_mislocks"),
    "prism_mislock_moving": Injector(lambda log, *, strength: inject_prism_mislock(log, strength=10.0,
                                                                                   offset_m=strength, moving=True),
                                     (0.02, 0.1, 0.5), "m (10 s, reflector moving along)", "prism_mislocks"),
    "prism_gap": Injector(inject_prism_gap, (5.0, 30.0, 120.0), "s", "prism_gaps"),
    "station_clock_jump": Injector(lambda log, *, strength: inject_clock_jump(log, strength=strength,
                                                                              topic="/total_station/TS01"),
                                   (0.02, 0.05, 0.2), "s", "clock_jumps"),
    "station_clock_jump_small": Injector(lambda log, *, strength: inject_clock_jump(log, strength=strength,
                                                                                    topic="/total_station/TS01"),
                                         (0.003, 0.005), "s (below the detection)", "clock_jumps"),
    "station_clock_jump_in_gap": Injector(_station_jump_in_gap, (0.05,), "s (inside a 10 s tracking gap)",
                                          "clock_jumps"),
}
