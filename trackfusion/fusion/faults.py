"""Data faults the fusion survives: detected, repaired where possible, and listed in
``metrics.json`` under ``faults`` (docs/robustness.md).

* :func:`correct_clock_jumps`: a step in a sensor's time offset (GNSS or odometer time stamps
  jumping) found from the sensor's own sampling grid and its data; corrected when the data
  determine the step, refused with one line otherwise.
* :func:`gnss_outages`, :func:`gnss_degraded_episodes`: gaps in the fixes; runs of RTK-float
  (or worse) fixes.
* :func:`odometer_slips`: intervals where the odometer disagrees with the smoothed motion
  (IMU, NHC, GNSS), from the odometer factor's residuals after the solve (the Huber loss has
  already down-weighted them).
* :func:`prism_mislocks`, :func:`prism_gaps`: total-station readings of another reflector
  (the step check's and the gate's mis-lock runs) and intervals in which a station lost the prism while no other
  station was tracking it.
* :func:`summarise_faults`: the ``faults`` section from everything detected.

Pure maths on arrays; times on the IMU clock [s].
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import SensorDataError
from ..registration import readings as prism_readings
from . import factors as fx
from .alignment import END_MARGIN_S

__all__ = ["correct_clock_jumps", "gnss_outages", "gnss_degraded_episodes", "odometer_slips",
           "prism_mislocks", "prism_gaps", "summarise_faults", "summary_lines", "OUTAGE_FACTOR", "SLIP_WHITENED_THRESHOLD", "SLIP_MIN_M",
           "SLIP_SCALE_WINDOW_S", "residual_scale"]

#: an interval between fixes longer than this many nominal intervals is an outage
OUTAGE_FACTOR = 3.0
#: whitened odometer residual (in units of ``factors.odometer.sigma_mm``) beyond which an
#: increment disagrees with the smoothed motion
SLIP_WHITENED_THRESHOLD = 8.0
#: smallest distance discrepancy [m] reported as a slip episode
SLIP_MIN_M = 2e-3
#: window [s] of the running median of the residual scale (residual over increment) that the
#: slip test removes first: a scale error or drift the scale state did not take up is not a slip
SLIP_SCALE_WINDOW_S = 30.0
#: increments shorter than this [m] do not enter the residual scale's median (at rest)
_SLIP_MOVING_M = 1e-3


def _runs(mask: np.ndarray, bridge: int = 0) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``mask`` (N,); runs separated by at most
    ``bridge`` False samples are merged."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > bridge + 1)
    firsts = np.r_[idx[0], idx[cut + 1]]
    lasts = np.r_[idx[cut], idx[-1]]
    return list(zip(firsts.tolist(), lasts.tolist()))


# --- clock jumps --------------------------------------------------------------------------------

def _velocity(t: np.ndarray, x: np.ndarray, i0: int, i1: int) -> np.ndarray | None:
    """Mean velocity (d,) over samples i0..i1 (inclusive, clipped), or None for fewer than 2."""
    i0, i1 = max(i0, 0), min(i1, t.size - 1)
    if i1 <= i0:
        return None
    return (x[i1] - x[i0]) / (t[i1] - t[i0])


def _true_intervals(t: np.ndarray, x: np.ndarray, k: int, period_s: float, noise: float) -> int | None:
    """Number of nominal periods between samples k and k+1 judged from the data ``x`` (N, d): the
    increment divided by the speed around it; None when the sensor is (nearly) at rest there."""
    v_before, v_after = _velocity(t, x, k - 3, k), _velocity(t, x, k + 1, k + 4)
    if v_before is None or v_after is None:
        return None
    v = 0.5 * (v_before + v_after)
    speed = float(np.linalg.norm(v))
    if speed * period_s < 20.0 * noise or np.linalg.norm(v_before - v_after) > 0.3 * speed:
        return None
    n = float((x[k + 1] - x[k]) @ v) / (speed**2 * period_s)
    return max(1, int(round(n)))


def correct_clock_jumps(t_s: np.ndarray, x: np.ndarray, topic: str, source: str, noise: float
                        ) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Find steps of a regularly sampled sensor's clock and remove them.

    A sensor sampling at a fixed period ``T`` (the median interval) stamps its samples on a grid
    ``t0 + k T``. A clock jump of ``J`` seconds after sample k moves every later stamp by ``J``:
    the interval ``t[k+1] - t[k]`` becomes ``n T + J`` (n = 1, or more when samples were also
    lost). The sub-period part of ``J`` shows as a step of the grid's phase; the whole-period part
    is found from the data: the increment ``x[k+1] - x[k]`` (positions or distance, ``x`` (N, d))
    over the speed around it gives ``n``. A long interval whose increment matches its length is
    an outage, not a jump. Where the phase steps but the sensor is at rest (so ``n`` is unknown)
    and the interval is not one period plus the step, the jump cannot be determined: refused.

    Whole-period jumps while at rest leave no trace in the time stamps and cannot be found here;
    the fixes then disagree with the motion and the GNSS gate rejects them (docs/robustness.md).

    Parameters: ``t_s`` (N,) strictly increasing [s]; ``noise``: measurement noise of ``x``
    [its unit]; ``topic``, ``source``: labels for messages. Returns the corrected times (a new
    array) and one ``{"topic", "index", "t_s", "step_s"}`` per jump (``index`` the first sample
    after it, ``t_s`` its corrected time).
    """
    t = np.asarray(t_s, dtype=float).copy()
    x = np.asarray(x, dtype=float).reshape(t.size, -1)
    if t.size < 8:
        return t, []
    dt = np.diff(t)
    period = float(np.median(dt))
    whole = np.maximum(np.round(dt / period), 1.0)
    off_grid = dt - whole * period
    regular = np.abs(off_grid) < 0.1 * period
    jitter = float(np.median(np.abs(off_grid[regular]))) if regular.any() else 0.0
    tol = max(1e-3 * period, 20.0 * jitter, 1e-6)  # the time-stamp jitter decides, not a fixed fraction
    candidates = np.flatnonzero((np.abs(off_grid) > tol) | (whole > 1.5))
    jumps: list[dict[str, Any]] = []
    shift = 0.0
    for k in candidates.tolist():
        n = _true_intervals(t, x, k, period, noise)
        if n is None:
            if abs(off_grid[k]) <= tol:
                continue                                         # a gap on the grid: an outage
            if whole[k] != 1.0:
                raise SensorDataError(
                    f"{source}: {topic} record {k + 1} (t = {t[k + 1]:.6f} s): the time stamps jump by "
                    f"{dt[k]:.6g} s where the sensor samples every {period:.6g} s, while at rest: a clock jump "
                    f"of {off_grid[k]:+.6g} s plus an unknown number of periods; the data cannot tell which")
            n = 1
        step = dt[k] - n * period
        if abs(step) <= tol:
            continue                                             # an outage of n - 1 samples
        shift += step
        jumps.append({"topic": topic, "index": k + 1, "t_s": float(t[k + 1] - shift), "step_s": float(step)})
        t[k + 1:] -= step
    return t, jumps


# --- GNSS -----------------------------------------------------------------------------------------

def gnss_outages(t_s: np.ndarray, t_imu_s: tuple[float, float]) -> list[dict[str, float]]:
    """Gaps between fixes longer than ``OUTAGE_FACTOR`` nominal intervals, inside the IMU span
    ``(first, last)`` [s] (also before the first and after the last fix). One
    ``{"start_s", "end_s", "duration_s"}`` per outage (last fix before, first fix after)."""
    t = np.asarray(t_s, dtype=float)
    t0, t1 = t_imu_s
    if t.size < 2:
        return [{"start_s": t0, "end_s": t1, "duration_s": t1 - t0}] if t1 > t0 else []
    period = float(np.median(np.diff(t)))
    edges = np.r_[min(t0, t[0]), t, max(t1, t[-1])]
    gap = np.diff(edges)
    out = [{"start_s": float(a), "end_s": float(b), "duration_s": float(b - a)}
           for a, b, g in zip(edges[:-1], edges[1:], gap) if g > OUTAGE_FACTOR * period]
    return out


def gnss_degraded_episodes(t_s: np.ndarray, fix_quality: np.ndarray) -> list[dict[str, Any]]:
    """Runs of fixes that are not RTK-fixed (quality 4): ``{"start_s", "end_s", "fixes",
    "quality"}`` (``quality``: the qualities seen, e.g. [5] for RTK float)."""
    q = np.asarray(fix_quality)
    out = []
    for a, b in _runs(q != 4):
        out.append({"start_s": float(t_s[a]), "end_s": float(t_s[b]), "fixes": int(b - a + 1),
                    "quality": sorted(set(q[a:b + 1].tolist()))})
    return out


# --- odometer slips --------------------------------------------------------------------------------

def residual_scale(t_s: np.ndarray, r_m: np.ndarray, delta_m: np.ndarray,
                   window_s: float = SLIP_SCALE_WINDOW_S) -> np.ndarray:
    """Scale error (K,) [-] left in the odometer residuals: the running median, over
    ``window_s`` of the moving increments around each one, of ``r_m / delta_m`` (``t_s`` (K,)
    the increments' start times [s], ``r_m`` (K,) residuals, ``delta_m`` (K,) increments [m]).

    A scale error the scale state did not take up (a drift faster than its random walk, a prior
    that held it back) makes the residual proportional to the increment everywhere; a slip adds
    distance over a fraction of a second. The median over a window many times a slip's length
    follows the first and ignores the second. Increments at rest (shorter than 1 mm) do not
    count and get the median of their nearest moving neighbours (0 without any)."""
    moving = np.flatnonzero(np.abs(delta_m) > _SLIP_MOVING_M)
    if moving.size == 0:
        return np.zeros(r_m.shape)
    from scipy.ndimage import median_filter
    period_s = float(np.median(np.diff(t_s[moving]))) if moving.size > 1 else window_s
    size = max(1, int(round(window_s / max(period_s, 1e-9))) | 1)
    med = median_filter(r_m[moving] / delta_m[moving], size=size, mode="nearest")
    return np.interp(t_s, t_s[moving], med)


def odometer_slips(t_key_s: np.ndarray, R_nb: np.ndarray, pos_n: np.ndarray, scale: np.ndarray,
                   delta_m: np.ndarray, wheel_lever_arm_b: np.ndarray, axis_b: np.ndarray, sigma_m: float
                   ) -> list[dict[str, float]]:
    """Slip episodes from the odometer residuals of the smoothed trajectory: steps the scale
    cannot explain.

    ``t_key_s`` (K,) keyframe times; ``R_nb`` (K,3,3), ``pos_n`` (K,3) smoothed poses; ``scale``
    (K,) smoothed scale error; ``delta_m`` (K-1,) measured distance increments between keyframes;
    ``sigma_m`` the increment's white noise [m]. First the scale error still left in the
    residuals (:func:`residual_scale`, a running median over ``SLIP_SCALE_WINDOW_S``) is
    removed; then an increment is suspect when its whitened residual exceeds
    ``SLIP_WHITENED_THRESHOLD``; suspects at most two intervals apart form one episode, reported
    when its summed discrepancy exceeds ``SLIP_MIN_M``: ``{"start_s", "end_s", "extra_m"}``
    (``extra_m``: distance reported beyond the smoothed motion, negative when distance was lost)
    and ``max_whitened``.
    """
    r, _ = fx.odometer_residual(R_nb[:-1], pos_n[:-1], R_nb[1:], pos_n[1:], scale[:-1], delta_m,
                                wheel_lever_arm_b, axis_b)
    r = r[:, 0]
    r = r - residual_scale(t_key_s[:-1], r, delta_m) * delta_m
    w = np.abs(r) / sigma_m
    out = []
    for a, b in _runs(w > SLIP_WHITENED_THRESHOLD, bridge=2):
        extra = -float(r[a:b + 1].sum())
        if abs(extra) >= SLIP_MIN_M:
            out.append({"start_s": float(t_key_s[a]), "end_s": float(t_key_s[b + 1]), "extra_m": extra,
                        "max_whitened": float(w[a:b + 1].max())})
    return out


# --- total stations ----------------------------------------------------------------------------------

def prism_mislocks(t_s: np.ndarray, station: np.ndarray, station_ids: list[str], mislocked: np.ndarray,
                   by_step_check: np.ndarray | None = None) -> list[dict[str, Any]]:
    """Mis-lock episodes: runs of consecutive readings of one station rejected as ``mis_lock``,
    by the step check before the fusion (registration/steps.py) or by the gate
    (registration/mislock.py). ``t_s`` (N,) reading times [s] sorted, ``station`` (N,) index
    into ``station_ids``, ``mislocked`` (N,) bool, ``by_step_check`` (N,) bool (None: none). One
    ``{"station", "start_s", "end_s", "readings", "detected_by"}`` per run (first and last
    mis-locked reading; ``detected_by``: ``step_check``, ``gate`` or ``step_check+gate``)."""
    step = np.zeros(t_s.size, dtype=bool) if by_step_check is None else by_step_check
    out = []
    for j, sid in enumerate(station_ids):
        mine = np.flatnonzero(station == j)
        for a, b in _runs(mislocked[mine]):
            n_step = int(step[mine[a:b + 1]].sum())
            how = "step_check" if n_step == b - a + 1 else "gate" if n_step == 0 else "step_check+gate"
            out.append({"station": sid, "start_s": float(t_s[mine[a]]), "end_s": float(t_s[mine[b]]),
                        "readings": int(b - a + 1), "detected_by": how})
    return sorted(out, key=lambda e: (e["start_s"], e["station"]))


def _tracked_intervals(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """(R, 2) [start, end] of the runs of readings ``t`` (sorted) with no interval above ``max_gap_s``."""
    cut = np.flatnonzero(np.diff(t) > max_gap_s)
    return np.column_stack([np.r_[t[0], t[cut + 1]], np.r_[t[cut], t[-1]]])


def _covered_s(a: float, b: float, intervals: np.ndarray) -> float:
    """Length [s] of [a, b] covered by the (disjoint) ``intervals`` (R, 2)."""
    if intervals.size == 0:
        return 0.0
    return float(np.clip(np.minimum(intervals[:, 1], b) - np.maximum(intervals[:, 0], a), 0.0, None).sum())


def prism_gaps(t_s: np.ndarray, station: np.ndarray, station_ids: list[str]) -> list[dict[str, Any]]:
    """Intervals in which a station lost the prism: between two of its readings, longer than
    ``registration.readings.PRISM_GAP_MIN_S`` and ``OUTAGE_FACTOR`` median reading intervals, and at most half covered
    by another station's tracking (a hand-over: the prism turned to the other station is no
    gap). Before a station's first and after its last reading it is not expected to track.
    ``t_s`` (N,) [s] sorted, ``station`` (N,) index into ``station_ids``. One ``{"station",
    "start_s", "end_s", "duration_s", "readings_missing"}`` per gap (last reading before, first
    after; readings missing at the median rate)."""
    per = [np.asarray(t_s[station == j], dtype=float) for j in range(len(station_ids))]
    limit = [max(prism_readings.PRISM_GAP_MIN_S, OUTAGE_FACTOR * float(np.median(np.diff(t)))) if t.size > 2 else np.inf
             for t in per]
    tracked = [_tracked_intervals(t, g) if t.size > 2 else np.zeros((0, 2)) for t, g in zip(per, limit)]
    out = []
    for j, (t, g) in enumerate(zip(per, limit)):
        if t.size <= 2:
            continue
        others = np.concatenate([tracked[i] for i in range(len(per)) if i != j] or [np.zeros((0, 2))])
        period = float(np.median(np.diff(t)))
        for k in np.flatnonzero(np.diff(t) > g):
            a, b = float(t[k]), float(t[k + 1])
            if _covered_s(a, b, others) <= 0.5 * (b - a):
                out.append({"station": station_ids[j], "start_s": a, "end_s": b, "duration_s": b - a,
                            "readings_missing": int(round((b - a) / period)) - 1})
    return sorted(out, key=lambda e: (e["start_s"], e["station"]))


def _prism_faults(prisms, result) -> dict[str, list]:
    """``prism_mislocks`` and ``prism_gaps`` of a run, on the IMU clock with each station's
    refined clock offset and drift (as ``rejected_prism`` in metrics.json)."""
    states = result.station_states if result.station_states is not None else np.zeros((len(prisms.station_ids), 8))
    q = states[prisms.station]
    t_imu = prisms.t_s - q[:, 6] - 1e-6 * q[:, 7] * prisms.t_s
    mis_t = np.array([r["t_s"] for r in result.rejected_prism if r["reason"] == "mis_lock"])
    mis_sid = np.array([prisms.station_ids.index(r["station"]) for r in result.rejected_prism
                        if r["reason"] == "mis_lock"], dtype=int)
    mislocked = np.zeros(prisms.t_s.size, dtype=bool)
    for j in np.unique(mis_sid):
        mislocked |= (prisms.station == j) & np.isin(prisms.t_s, mis_t[mis_sid == j])
    order = np.argsort(t_imu, kind="stable")
    step = prisms.flagged[order] if prisms.flagged is not None else None
    return {"prism_mislocks": prism_mislocks(t_imu[order], prisms.station[order], prisms.station_ids,
                                             mislocked[order], step),
            "prism_gaps": prism_gaps(t_imu[order], prisms.station[order], prisms.station_ids)}


# --- the metrics section ----------------------------------------------------------------------------

def summarise_faults(found: dict[str, list | dict | None], gnss_fixes: int | None = None) -> dict[str, Any]:
    """The ``faults`` section of metrics.json: one entry per fault kind that was detected.

    ``found`` maps a fault name to its list of events (or a dict for one-off faults such as
    ``truncated_log``); empty or None entries are left out. List entries become
    ``{"count": n, "events": [...]}`` (``gnss_outliers`` also gets ``fraction`` of
    ``gnss_fixes``).
    """
    out: dict[str, Any] = {}
    for name, events in found.items():
        if not events:
            continue
        if isinstance(events, dict):
            out[name] = events
            continue
        entry: dict[str, Any] = {"count": len(events), "events": list(events)}
        if name == "gnss_outliers" and gnss_fixes:
            entry["fraction"] = len(events) / gnss_fixes
        out[name] = entry
    return out


def summary_lines(faults: dict[str, Any], limit: int = 5) -> list[str]:
    """Terminal lines (``pipeline.format_summary``) for the located faults of a ``faults``
    section: each total-station mis-lock and gap, each clock jump (at most ``limit`` per kind)."""
    how = {"prism_mislocks": "mis-locked", "prism_gaps": "lost the prism"}
    lines = []
    for kind, verb in how.items():
        events = faults.get(kind, {}).get("events", [])
        lines += [f"  {e['station']} {verb} {e['start_s']:.1f}-{e['end_s']:.1f} s"
                  + (f" ({e['readings']} readings rejected" + (f", {e['detected_by'].replace('_', ' ')})"
                                                                 if "detected_by" in e else ")")
                     if "readings" in e else "") for e in events[:limit]]
        if len(events) > limit:
            lines.append(f"  ... {len(events) - limit} more {kind} in metrics.json")
    jumps = faults.get("clock_jumps", {}).get("events", [])
    lines += [f"  {e['topic']} clock jump of {e['step_s'] * 1e3:+.1f} ms at {e['t_s']:.1f} s, corrected"
              for e in jumps[:limit]]
    return lines


def detected_faults(problem, result, found: dict[str, Any]) -> dict[str, Any]:
    """The ``faults`` section of a run: ``found`` (faults seen before fusion: ``truncated_log``,
    ``clock_jumps``, ``odometer_gross_errors``) plus what the smoothed run shows: GNSS outliers
    (the gate's rejections), RTK-float episodes, outages, odometer slips, total-station mis-locks
    and gaps, and the alignment's
    fallback when a static period was missing at the start. ``problem``: the
    :class:`~trackfusion.fusion.problem.FusionProblem`; ``result``: its ``SmootherResult``."""
    found = dict(found)
    g = problem.gnss
    if g is not None and problem.factors.gnss.enabled:
        found["gnss_outliers"] = result.rejected_gnss
        found["gnss_float"] = gnss_degraded_episodes(g.t_s, g.fix_quality)
        found["gnss_outages"] = gnss_outages(g.t_s, (float(problem.imu.t_s[0]), float(problem.imu.t_s[-1])))
    if problem.prisms is not None:
        found.update(_prism_faults(problem.prisms, result))
    odo = problem.odometer
    if odo is not None and result.odometer_scale is not None:
        delta = np.diff(np.interp(result.t_s, odo.t_s, odo.distance_m))
        found["odometer_slips"] = odometer_slips(result.t_s, result.R_nb, result.pos_n, result.odometer_scale, delta,
                                                 problem.trolley.wheel_lever_arm_b, problem.trolley.axis_b,
                                                 problem.factors.odometer.sigma_mm * 1e-3)
    al, t = result.alignment, problem.imu.t_s
    missing = [end for end, present in (
        ("start", any(a <= t[0] + END_MARGIN_S for a, _ in problem.static_intervals_s)),
        ("end", any(b >= t[-1] - END_MARGIN_S for _, b in problem.static_intervals_s))) if not present]
    if missing:
        found["missing_static_period"] = {
            "at": missing, "alignment_epoch": al.epoch, "heading_method": al.method,
            "action": {"start": "attitude from the static period at the start",
                       "end": "attitude from the static period at the end, chained back to the start",
                       "moving": "levelled on the mean specific force of the first seconds while moving "
                                 "(less the acceleration along the track), heading from the GNSS displacement"
                       }[al.epoch]}
    return summarise_faults(found, None if g is None else int(g.t_s.size))
