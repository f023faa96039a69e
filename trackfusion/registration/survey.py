"""A total-station survey from readings to fusion input and back to a registration report.

:func:`prepare_prisms`: set-ups (given or resected), readings to ``n``, each station's clock
synchronised (:mod:`.timesync`) and its clock jumps removed (:mod:`.clock_jumps`), readings of another reflector
flagged by the step check first (:mod:`.steps`; left out of all of these and of the fusion), optionally the seed's registration applied
(:mod:`.seed_method`), and the :class:`~trackfusion.registration.readings.PrismReadings` with the
priors of each station's correction state.

:func:`registration_report`: residuals between consecutive stations over their shared
chainage, in the form of seed 003 tables 1-2 (max |r|, mean, standard deviation, slope of the
trend line, relative accuracy in ppm), before registration, after the seed's method and after
the factor graph's, side by side; the stations' estimated tilt, orientation, translation and
clock; and the round trip's repeatability (seed 003 tables 3-4) before and after fusion.

Pure computation: no file I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import geodesy
from ..errors import RegistrationError
from ..evaluation.overlap import overlap_residuals, overlap_statistics
from ..sensors.types import OdometerData, TotalStationData
from . import timesync
from .readings import PrismReadings
from .clock_jumps import correct_station_clock_jumps
from .steps import motionless_mislocks, station_mislocks
from .polar import StationSetup
from .seed_method import SeedRegistration, overlap_axes, register_seed
from .stations import ARCSEC, InstrumentPrecision, Resection, readings_to_n, station_setup


@dataclass
class StationPrep:
    """One station after set-up and synchronisation: its set-up, instrument point ``centre_n``
    (3,), readings on the synchronised IMU clock ``t_s`` (N,), nominal points ``pos_n`` (N,3),
    covariance (N,3,3), the time sync (None when the offset was given) and resection report."""

    setup: StationSetup
    centre_n: np.ndarray
    t_s: np.ndarray
    pos_n: np.ndarray
    cov_n: np.ndarray
    offset_s: float
    sync: timesync.TimeSync | None
    resection: Resection | None
    seed: SeedRegistration | None = None
    flagged: np.ndarray | None = None  # (N,) bool: the step check's mis-locked readings


@dataclass
class PrismSurvey:
    """What :func:`prepare_prisms` produced: the stations (in configuration order), the fusion
    input and ``info`` (``clock_jumps``: the stations' corrected clock jumps; ``step_mislocks``:
    the step check's mis-locks, :mod:`.steps`)."""

    stations: dict[str, StationPrep]
    readings: PrismReadings
    info: dict[str, Any] = field(default_factory=dict)


def _chainage(t_s: np.ndarray, odometer: OdometerData) -> np.ndarray:
    return np.interp(t_s, odometer.t_s, odometer.distance_m)


def prepare_prisms(data: dict[str, TotalStationData], cfg, fs, origin: geodesy.Origin,
                   odometer: OdometerData | None) -> PrismSurvey:
    """Fusion input from the logged readings ``data`` (station id -> readings, station clock).

    ``cfg``: the pipeline's ``sensors.total_stations`` (set-ups, control points, instrument
    precision and priors); ``fs``: ``factors.total_stations``. Stations configured but absent
    from the log, and logged stations not configured, are refused (:class:`RegistrationError`).
    """
    missing = sorted(set(cfg.stations) - set(data))
    if missing:
        raise RegistrationError(f"sensors.total_stations.stations: {missing} not in the log "
                                f"(logged: {sorted(data)})")
    unknown = sorted(set(data) - set(cfg.stations))
    if unknown:
        raise RegistrationError(f"sensors.total_stations.stations: the log has readings of {unknown}, "
                                "which are not configured")
    prec = InstrumentPrecision(cfg.angle_sigma_arcsec, cfg.distance_sigma_mm, cfg.distance_ppm)
    stations: dict[str, StationPrep] = {}
    clock_jumps: list[dict] = []
    step_mislocks: list[dict] = []
    for sid, sc in cfg.stations.items():
        d = data[sid]
        if d.t_s.size == 0:
            raise RegistrationError(f"/total_station/{sid}: no readings")
        setup, res = station_setup(sid, sc, cfg.control_points, origin, prec, cfg.refraction_k)
        pos_n, cov_n = readings_to_n(d.horizontal_angle_rad, d.zenith_angle_rad, d.slope_distance_m, setup, origin,
                                     cfg.refraction_k, prec)
        flagged, mislocks, unpaired = station_mislocks(d.t_s, pos_n, cov_n)  # a mis-lock onto another reflector
        ok = ~flagged
        sync = None
        if sc.clock_offset_s is not None:
            offset = float(sc.clock_offset_s)
        else:
            if odometer is None:
                raise RegistrationError(f"station {sid}: time synchronisation needs the odometer "
                                        f"(or give sensors.total_stations.stations.{sid}.clock_offset_s)")
            sync = timesync.synchronise(sid, d.t_s[ok], pos_n[ok], odometer.t_s, odometer.distance_m, fs.time_sync)
            offset = sync.offset_s
        t_station = d.t_s
        if odometer is not None:  # steps of the station's clock (clock_jumps.py)
            t_station, jumps = correct_station_clock_jumps(sid, d.t_s, offset, pos_n, cov_n, odometer.t_s,
                                                           odometer.distance_m, excluded=flagged)
            if jumps and sync is not None:  # the correlation again, on the corrected stamps
                sync = timesync.synchronise(sid, t_station[ok], pos_n[ok], odometer.t_s, odometer.distance_m,
                                            fs.time_sync)
                offset = sync.offset_s
            clock_jumps += [{**j, "t_s": float(t_station[j["index"]] - offset)} for j in jumps]
        if odometer is not None:  # a reflector that does not move with the trolley
            still, more = motionless_mislocks(t_station - offset, pos_n, unpaired, odometer.t_s, odometer.distance_m)
            flagged, mislocks = flagged | still, sorted(mislocks + more, key=lambda m: m["first"])
        step_mislocks += [{"station": sid, "start_s": float(t_station[m["first"]] - offset),
                           "end_s": float(t_station[m["last"]] - offset), **m} for m in mislocks]
        centre = geodesy.ecef_to_n(setup.instrument_ecef(origin)[0], origin)
        stations[sid] = StationPrep(setup, centre, t_station - offset, pos_n, cov_n, offset, sync, res,
                                    flagged=flagged)
    if fs.registration == "seed":
        _apply_seed_registration(stations, odometer)
    return PrismSurvey(stations, _readings(stations, cfg, fs),
                       {"clock_jumps": clock_jumps, "step_mislocks": step_mislocks})


def _apply_seed_registration(stations: dict[str, StationPrep], odometer: OdometerData | None) -> None:
    """Register every station onto the one before it (configuration order), seed 003's way."""
    if odometer is None:
        raise RegistrationError("factors.total_stations.registration: seed needs the odometer (chainage)")
    ids = list(stations)
    for a, b in zip(ids[:-1], ids[1:]):
        ref, tgt = stations[a], stations[b]
        tgt.seed = register_seed(_chainage(ref.t_s, odometer), ref.pos_n, _chainage(tgt.t_s, odometer), tgt.pos_n,
                                 tgt.centre_n)
        tgt.pos_n = tgt.seed.apply(tgt.pos_n)


def _readings(stations: dict[str, StationPrep], cfg, fs) -> PrismReadings:
    ids = list(stations)
    t = np.concatenate([stations[s].t_s for s in ids])
    order = np.argsort(t, kind="stable")
    station = np.concatenate([np.full(stations[s].t_s.size, j) for j, s in enumerate(ids)])[order]
    pos = np.concatenate([stations[s].pos_n for s in ids])[order]
    cov = np.concatenate([stations[s].cov_n for s in ids])[order]
    flagged = np.concatenate([stations[s].flagged if stations[s].flagged is not None
                              else np.zeros(stations[s].t_s.size, bool) for s in ids])[order]
    free = fs.registration == "graph"
    rot = np.array([cfg.tilt_sigma_arcsec, cfg.tilt_sigma_arcsec, cfg.orientation_sigma_arcsec]) * ARCSEC
    fixed = 1e-9
    sigma = np.r_[rot if free else [fixed] * 3, [cfg.position_sigma_mm * 1e-3 if free else fixed] * 3,
                  fs.clock_offset_sigma_s, cfg.clock_drift_sigma_ppm if fs.estimate_clock_drift else 1e-6]
    return PrismReadings(t[order], pos, cov, station, ids, np.array([stations[s].centre_n for s in ids]),
                         np.asarray(cfg.prism_lever_arm_b_m, dtype=float), np.tile(sigma, (len(ids), 1)),
                         flagged if flagged.any() else None)


# --- after the fusion -------------------------------------------------------------------------

def corrected_points(prep: StationPrep, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(IMU times (N,), points (N,3)) of a station's readings with its estimated correction state (8,)."""
    t = prep.t_s - state[6] - 1e-6 * state[7] * prep.t_s
    d = prep.pos_n - prep.centre_n
    return t, prep.pos_n + np.cross(state[:3], d) + state[3:6]


def station_estimates(survey: PrismSurvey, states: np.ndarray | None, origin: geodesy.Origin,
                      cov: np.ndarray | None = None) -> dict[str, dict]:
    """Per station: estimated tilt (about the station's east, north axes) [arcsec], orientation
    error [arcsec], translation [mm], clock offset [s] and drift [ppm]; set-up and resection;
    with ``cov`` (8J,8J, the states' joint marginal covariance) their sigmas (``sigma``)."""
    out = {}
    for j, (sid, p) in enumerate(survey.stations.items()):
        q = states[j] if states is not None else np.zeros(8)
        R_nk = geodesy.R_n_local(p.centre_n[None, :], origin)[0]
        rot_k = R_nk.T @ q[:3]
        tilt = np.array(p.setup.tilt_rad) + rot_k[:2]
        out[sid] = {"pos_n_m": list(p.setup.pos_n), "orientation_deg": float(np.degrees(p.setup.orientation_rad)),
                    "tilt_arcsec": (tilt / ARCSEC).tolist(), "orientation_error_arcsec": float(-rot_k[2] / ARCSEC),
                    "translation_mm": (1e3 * q[3:6]).tolist(), "clock_offset_s": p.offset_s + float(q[6]),
                    "clock_drift_ppm": float(q[7]), "readings": int(p.t_s.size)}
        if cov is not None:
            c = cov[8 * j:8 * j + 8, 8 * j:8 * j + 8]
            rot_sigma = np.sqrt(np.diag(R_nk.T @ c[:3, :3] @ R_nk)) / ARCSEC
            out[sid]["sigma"] = {"tilt_arcsec": rot_sigma[:2].tolist(), "orientation_arcsec": float(rot_sigma[2]),
                                 "translation_mm": (1e3 * np.sqrt(np.diag(c[3:6, 3:6]))).tolist(),
                                 "clock_offset_ms": float(1e3 * np.sqrt(c[6, 6])),
                                 "clock_drift_ppm": float(np.sqrt(c[7, 7]))}
        if p.resection is not None:
            out[sid]["resection"] = p.resection.to_json()
        if p.seed is not None:
            out[sid]["seed_003"] = p.seed.to_json()
    return out


def _component_stats(grid: np.ndarray, r_m: np.ndarray) -> dict[str, float]:
    st = overlap_statistics(grid, r_m)
    return {"max_abs_mm": st.max_abs_mm, "max_abs_signed_mm": st.max_abs_signed_mm, "mean_mm": st.mean_mm,
            "std_mm": st.std_mm, "slope_mm_per_m": 1e3 * st.trend_slope,
            "relative_accuracy_ppm": st.relative_accuracy_ppm, "n_points": st.n_points, "length_m": st.length_m}


def residual_table(s_a: np.ndarray, p_a: np.ndarray, s_b: np.ndarray, p_b: np.ndarray, axes: np.ndarray,
                   step_m: float = 0.25) -> dict[str, dict]:
    """Seed-003 statistics of curve b minus curve a at common chainage: elevation (up) and
    across the track (``axes`` row Y)."""
    out = {}
    for name, axis in (("elevation", axes[2]), ("across_track", axes[1])):
        grid, r = overlap_residuals(s_a, p_a @ axis, s_b, p_b @ axis, step_m)
        out[name] = _component_stats(grid, r)
    return out


def registration_report(survey: PrismSurvey, states: np.ndarray | None, odometer: OdometerData,
                        method: str, origin: geodesy.Origin, cov: np.ndarray | None = None) -> dict[str, Any]:
    """The contract's ``registration`` entry (module docstring). ``states`` (J,8): the smoothed
    station corrections (None: none estimated); ``cov``: their covariance (see :func:`station_estimates`)."""
    ids = list(survey.stations)
    pairs: dict[str, dict] = {}
    for a, b in zip(ids[:-1], ids[1:]):
        A, Bp = survey.stations[a], survey.stations[b]
        raw_b = Bp.pos_n if Bp.seed is None else _undo(Bp)
        s_a, s_b = _chainage(A.t_s, odometer), _chainage(Bp.t_s, odometer)
        try:
            seed = register_seed(s_a, A.pos_n if A.seed is None else _undo(A), s_b, raw_b, Bp.centre_n)
        except Exception as exc:  # no usable overlap: say so in the report
            pairs[f"{a}-{b}"] = {"error": str(exc)}
            continue
        lo, hi = seed.overlap_m
        axes = overlap_axes(s_a, A.pos_n, lo, hi)
        entry = {"overlap_m": [lo, hi], "before": residual_table(s_a, A.pos_n, s_b, raw_b, axes),
                 "seed_003": residual_table(s_a, A.pos_n, s_b, seed.apply(raw_b), axes),
                 "seed_003_parameters": seed.to_json()}
        if states is not None:
            ta, pa = corrected_points(A, states[ids.index(a)])
            tb, pb = corrected_points(Bp, states[ids.index(b)])
            entry["factor_graph"] = residual_table(_chainage(ta, odometer), pa, _chainage(tb, odometer), pb, axes)
        pairs[f"{a}-{b}"] = entry
    first = next((p for p in pairs.values() if "before" in p), None)
    after_key = {"graph": "factor_graph", "seed": "seed_003"}.get(method)
    residuals = {}
    if first is not None:
        residuals = {"before": first["before"], "after": first.get(after_key, first["before"]) if after_key
                     else first["before"]}
    return {"method": {"graph": "factor_graph", "seed": "seed_003", "none": "none"}[method],
            "stations": station_estimates(survey, states, origin, cov), "residuals": residuals, "pairs": pairs}


def _undo(p: StationPrep) -> np.ndarray:
    """The nominal points of a station whose seed registration was applied before fusion."""
    s = p.seed
    local = (p.pos_n - s.centre_n) @ s.axes_n.T
    m, y, h = local.T
    h = h - s.dz_m
    c, sn = np.cos(s.theta_rad), np.sin(s.theta_rad)
    out = np.column_stack([m * c + h * sn, y - s.dy_m, -m * sn + h * c])
    return s.centre_n + out @ s.axes_n


def round_trip(t_s: np.ndarray, pos_n: np.ndarray, chainage_m: np.ndarray, min_speed_mps: float = 0.05,
               step_m: float = 0.25) -> dict[str, dict]:
    """Repeatability of a trajectory over the chainage its forward and backward passes share
    (seed 003 tables 3-4): statistics of backward minus forward, elevation and across the track.
    t_s, chainage_m (N,), pos_n (N,3). Points slower than ``min_speed_mps`` are left out."""
    v = np.gradient(chainage_m, t_s)
    fwd, bwd = v > min_speed_mps, v < -min_speed_mps
    if np.count_nonzero(fwd) < 3 or np.count_nonzero(bwd) < 3:
        raise RegistrationError("round trip: the run has no forward and backward pass")
    lo = max(chainage_m[fwd].min(), chainage_m[bwd].min())
    hi = min(chainage_m[fwd].max(), chainage_m[bwd].max())
    axes = overlap_axes(chainage_m[fwd], pos_n[fwd], lo, hi)
    return {"overlap_m": [float(lo), float(hi)],
            **residual_table(chainage_m[fwd], pos_n[fwd], chainage_m[bwd], pos_n[bwd], axes, step_m)}
