"""A run smoothed as independent time segments in parallel processes (``smoother.workers``).

A run that is smoothed in one batch (shorter than ``smoother.chunk_s + overlap_s``, with GNSS and
no total stations: :func:`independent_segments`) is cut at ``N - 1`` join times into ``N`` cores
of equal duration (``N = smoother.workers``; fewer when a core would be shorter than
``2 overlap_s``). Segment ``s`` is smoothed as a batch (:func:`~.smoother.smooth`) over its core
plus ``overlap_s`` of data before and after it (clipped at the run's ends), each in its own
forked process, all at once (:func:`trackfusion.workers.run_forked`). Unlike the sequential
chunks of fusion/chunks.py nothing is handed over between segments: each is aligned, anchored
and tied to ``n`` by its own GNSS fixes, so they are independent. Its slow states (IMU biases,
odometer scale) take priors from coarse solves of the data before and after it, which its worker
runs first (fusion/slow_pass.py; ``smoother.slow_priors``): in one batch those states are tied to
the rest of the run through their random walks, and half a run alone pins the along-track
accelerometer bias (which trades against pitch) less well. Each worker also densifies its
core and blend windows and decimates them to the output rate (global sample index a multiple
of ``every``); it returns compact arrays (keyframe states, marginal sigmas, the decimated rows,
counts; no GTSAM object) through a pipe.

At a join ``t_j`` the two neighbours' solutions differ by a little (measured per join in
metrics.json ``segments.joins``): mostly a slowly varying offset of a few mm (each segment's own
estimate of the absolute level, which the correlated GNSS error leaves uncertain by about that
much), on the 5 m scale nothing. A blend over a window alone would turn that offset into a ramp
(2 mm over a 60 s window at 3 m/s: 0.05 mm per 5 m, half the relative-accuracy figure), so the
parent first applies a **level correction**: each segment's positions are shifted by a
function linear in time from half the mean difference over the window of its left join
(towards its left neighbour) to half that of its right join (zero at the run's ends), a slope of
a few mm over a whole core; velocities by its rate. What remains at the join is the
difference's variation over the window (tenths of a mm). The parent then blends the two
solutions over the window ``t_j - h .. t_j + h``,
``h = BLEND_FRACTION * overlap_s``, inside the shared overlap (each segment keeps at least
``overlap_s - h`` of data beyond the window), with the quintic smoothstep ``w`` (0 to 1; ``w``,
``w'`` and ``w''`` continuous): position ``(1 - w) p_A + w p_B``; velocity
``(1 - w) v_A + w v_B + w' (p_B - p_A)`` (the derivative of that position); attitude
``R_A Exp(w Log(R_A^T R_B))``; biases, odometer scale and sigmas linearly. Position, attitude
and velocity are thus continuous through the join, and so are their rates.

Combined fields (docs/solver_speed.md "Parallel segments"): keyframes are each segment's outside
the windows and, inside, the keyframes both segments have (blended); factor counts, iterations,
initial and final cost are sums over the segments (an overlap's factors count in both); a
rejected GNSS fix is the rejection of the segment whose side of the join it lies on; the
alignment is the first segment's; ``timings_s`` phases are the slowest segment's (they run at
the same time). Per-segment figures are in ``segments.segments``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from .. import geodesy
from ..rotations import so3_exp, so3_log
from ..workers import can_fork, run_forked
from .chunks import sub_problem
from .problem import FusionProblem
from .settings import SmootherSettings
from .slow_pass import outside_priors
from .smoother import SmootherResult, nearest_sample, smooth
from .trajectory import DenseTrajectory, densify

#: half-width of the blend window at a join, as a fraction of ``smoother.overlap_s``
BLEND_FRACTION = 0.25

_KEY_ARRAYS = ("t_s", "key_idx", "R_nb", "pos_n", "vel_n", "gyro_bias_radps", "accel_bias_mps2", "odometer_scale")


def independent_segments(problem: FusionProblem) -> bool:
    """True when segments of the run may be smoothed independently of each other: GNSS fixes tie
    each segment to ``n`` on its own, and no state spans the whole run. Total-station runs stay
    in one batch: each station's correction state is seen on the way out and back (this is the
    one switch to change once the station corrections are fixed before the trajectory solve)."""
    g = problem.gnss
    return problem.prisms is None and g is not None and problem.factors.gnss.enabled and g.t_s.size > 0


def worker_count(settings: SmootherSettings) -> int:
    """``smoother.workers``, or without it 1: one batch. The default never depends on the
    machine, so the same log gives the same trajectory on any computer (segments are an
    approximation of the batch, docs/solver_speed.md)."""
    return settings.workers if settings.workers is not None else 1


@dataclass(frozen=True)
class Segment:
    """One segment: IMU samples ``i0 .. i1`` (global, inclusive) are smoothed; results inside
    ``keep_t0 .. keep_t1`` [s] (its core and the blend windows at its joins) are returned."""

    i0: int
    i1: int
    keep_t0: float
    keep_t1: float


def plan_segments(t_s: np.ndarray, workers: int, overlap_s: float, spacing_s: float
                  ) -> tuple[np.ndarray, list[Segment]]:
    """Join times (N-1,) [s] and the N segments of a run with IMU times ``t_s`` (module
    docstring); no joins and no segments when fewer than two cores of ``2 overlap_s`` fit.
    A segment starts on the run's keyframe grid (``spacing_s`` from the first sample), so that
    neighbours have the same keyframes in their overlap."""
    t0, t1 = float(t_s[0]), float(t_s[-1])
    n = min(workers, int((t1 - t0) // (2.0 * overlap_s)))
    if n < 2:
        return np.empty(0), []
    h = BLEND_FRACTION * overlap_s
    joins = t0 + (t1 - t0) * np.arange(1, n) / n
    edges = np.r_[t0, joins, t1]
    segments = []
    for s in range(n):
        a = t0 + np.floor((edges[s] - overlap_s - t0) / spacing_s) * spacing_s if s > 0 else t0
        i0 = int(nearest_sample(t_s, np.array([a]))[0]) if s > 0 else 0
        i1 = min(int(np.searchsorted(t_s, edges[s + 1] + overlap_s, "right")) - 1, t_s.size - 1) \
            if s < n - 1 else t_s.size - 1
        segments.append(Segment(i0, i1, edges[s] - h if s > 0 else -np.inf,
                                edges[s + 1] + h if s < n - 1 else np.inf))
    return joins, segments


@dataclass
class SegmentResult:
    """What a worker returns: the keyframe result trimmed to the kept span (global ``key_idx``;
    all its marginals; rejected GNSS fixes indexed into the run's fixes) and its decimated
    trajectory rows there (``rows``) with their global IMU sample indices ``row_idx``."""

    res: SmootherResult
    rows: DenseTrajectory
    row_idx: np.ndarray
    slow_priors: list[str] = field(default_factory=list)  # "before" / "after": the sides that gave priors


def smooth_segment(problem: FusionProblem, seg: Segment, every: int) -> SegmentResult:
    """Smooth one segment with priors on its slow states from the data outside it
    (fusion/slow_pass.py), densify and decimate its kept span (module docstring)."""
    cpu, tic = time.process_time(), time.perf_counter()
    priors = outside_priors(problem, seg.i0, seg.i1) if problem.smoother.slow_priors else None
    slow_s = time.perf_counter() - tic
    sub = sub_problem(problem, seg.i0, seg.i1)
    res = smooth(sub, slow_priors=priors)
    tic = time.perf_counter()
    t = res.t_s
    ka = max(int(np.searchsorted(t, seg.keep_t0, "right")) - 1, 0)
    kb = min(int(np.searchsorted(t, seg.keep_t1, "left")), t.size - 1)
    kk = slice(ka, kb + 1)
    omega_ie_n = geodesy.earth_rate_n(problem.origin) if problem.factors.imu.earth_rate else np.zeros(3)
    dense = densify(sub.imu, res.key_idx[kk], res.R_nb[kk], res.pos_n[kk], res.vel_n[kk], res.gyro_bias_radps[kk],
                    res.accel_bias_mps2[kk], geodesy.gravity_n(res.pos_n[kk], problem.origin), omega_ie_n,
                    every=every, index_offset=seg.i0)  # the rows of the problem's samples i % every == 0
    idx = seg.i0 + np.arange(int(res.key_idx[ka]), int(res.key_idx[kb]) + 1)
    idx = idx[idx % every == 0]
    sel = (dense.t_s >= seg.keep_t0) & (dense.t_s <= seg.keep_t1)
    rows = dense.select(sel)
    del dense
    keep = (t >= seg.keep_t0) & (t <= seg.keep_t1)
    trimmed = {name: getattr(res, name)[keep] for name in _KEY_ARRAYS if getattr(res, name) is not None}
    trimmed["key_idx"] = seg.i0 + trimmed["key_idx"]
    offset = int(np.searchsorted(problem.gnss.t_s, sub.imu.t_s[0], "left"))
    rejected = [{**r, "index": r["index"] + offset} for r in res.rejected_gnss]
    res = replace(res, **trimmed, rejected_gnss=rejected,
                  timings_s={"slow_states_s": slow_s, **res.timings_s, "densify_s": time.perf_counter() - tic,
                             "cpu_s": time.process_time() - cpu})
    return SegmentResult(res, rows, idx[sel], ["before" if p.start else "after" for p in priors or []])


_JOB: tuple[FusionProblem, list[Segment], int] | None = None  # what a forked worker reads (no pickling)


def _job(s: int) -> SegmentResult:
    problem, segments, every = _JOB
    return smooth_segment(problem, segments[s], every)


def smooth_in_segments(problem: FusionProblem, every: int, progress: Callable[[str], None] | None = None,
                       while_waiting: Callable[[], None] | None = None
                       ) -> tuple[SmootherResult, DenseTrajectory, dict[str, Any]] | None:
    """Smooth ``problem`` in parallel segments (module docstring); None when the run is not cut
    (:func:`independent_segments` false, or one segment: smooth it in one batch). Returns the stitched keyframe result, the stitched
    trajectory at every ``every``-th IMU sample (global index a multiple of it) and the
    ``segments`` section of metrics.json. The segments run in forked processes when possible
    (:func:`trackfusion.workers.can_fork`), else one after the other here (the same result).
    ``while_waiting()``: called once the first worker process has finished, while the others
    still run (:func:`trackfusion.workers.run_forked`; not called without worker processes)."""
    global _JOB
    if not independent_segments(problem) or problem.smoother.part_s is not None:  # exact parts instead
        return None
    say = progress or (lambda _m: None)
    sm = problem.smoother
    joins, segments = plan_segments(problem.imu.t_s, worker_count(sm), sm.overlap_s, problem.keyframes.spacing_s)
    if not segments:
        return None
    forked = can_fork(len(segments))
    say(f"smoothing {len(segments)} segments of {(joins[0] - problem.imu.t_s[0]):.0f} s "
        + (f"in {len(segments)} processes at once" if forked else "one after the other (no worker processes here)"))
    tic = time.perf_counter()
    if forked:
        _JOB = (problem, segments, every)
        try:
            parts = run_forked(_job, len(segments), while_waiting)
        finally:
            _JOB = None
    else:
        parts = [smooth_segment(problem, seg, every) for seg in segments]
    wall_s = time.perf_counter() - tic
    h = BLEND_FRACTION * sm.overlap_s
    res, rows, seams = stitch(parts, joins, h)
    res.timings_s["segments_s"] = wall_s
    info = {"count": len(segments), "workers": len(segments) if forked else 1, "overlap_s": sm.overlap_s,
            "blend_half_width_s": h, "joins": seams,
            "segments": [{**_segment_info(problem, seg, p.res), "slow_priors": p.slow_priors}
                         for seg, p in zip(segments, parts)]}
    return res, rows, info


def _segment_info(problem: FusionProblem, seg: Segment, res: SmootherResult) -> dict[str, Any]:
    t = problem.imu.t_s
    out = {"t0_s": float(t[seg.i0]), "t1_s": float(t[seg.i1]), "keyframes_kept": int(res.t_s.size),
           "factors": res.factor_counts, "iterations": res.iterations, "initial_cost": res.initial_cost,
           "final_cost": res.final_cost, "alignment": res.alignment.to_json(), "timings_s": res.timings_s,
           "gyro_bias_deg_per_h_mean": (np.degrees(res.gyro_bias_radps.mean(axis=0)) * 3600.0).tolist(),
           "accel_bias_ug_mean": (res.accel_bias_mps2.mean(axis=0) / 9.80665e-6).tolist()}
    if res.odometer_scale is not None:
        out["odometer_scale_ppm_mean"] = float(res.odometer_scale.mean() * 1e6)
    return out


# --- stitching --------------------------------------------------------------------------------------

def blend_weight(t_s: np.ndarray, join_s: float, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Quintic smoothstep weight (0 at ``join_s - h_s``, 1 at ``join_s + h_s``) and its time
    derivative [1/s] at ``t_s``."""
    u = np.clip((t_s - (join_s - h_s)) / (2.0 * h_s), 0.0, 1.0)
    return u ** 3 * (10.0 - 15.0 * u + 6.0 * u ** 2), 30.0 * u ** 2 * (1.0 - u) ** 2 / (2.0 * h_s)


def _blend_rotations(R_a: np.ndarray, R_b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``R_a Exp(w Log(R_a^T R_b))`` for stacks (M,3,3) and weights (M,)."""
    return R_a @ so3_exp(w[:, None] * so3_log(np.swapaxes(R_a, -1, -2) @ R_b))


def _regions(t_s: np.ndarray, joins: np.ndarray, h: float, s: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Mask of segment ``s``'s own times (outside the blend windows) and of the window at its
    end join (None for the last segment); half-open, so the pieces of all segments tile the run."""
    lo = joins[s - 1] + h if s > 0 else -np.inf
    hi = joins[s] - h if s < joins.size else np.inf
    own = (t_s >= lo) & (t_s < hi)
    window = (t_s >= hi) & (t_s < joins[s] + h) if s < joins.size else None
    return own, window


def _blend_rows(a: DenseTrajectory, b: DenseTrajectory, w: np.ndarray, dw: np.ndarray) -> DenseTrajectory:
    dp = b.pos_n - a.pos_n
    return DenseTrajectory(a.t_s, _blend_rotations(a.R_nb, b.R_nb, w), a.pos_n + w[:, None] * dp,
                           (1.0 - w[:, None]) * a.vel_n + w[:, None] * b.vel_n + dw[:, None] * dp)


def _seam(a: DenseTrajectory, b: DenseTrajectory, join_s: float) -> dict[str, Any]:
    """How far the two solutions are apart over a blend window: largest and at the join."""
    dp = np.linalg.norm(b.pos_n - a.pos_n, axis=1) * 1e3
    dv = np.linalg.norm(b.vel_n - a.vel_n, axis=1) * 1e3
    da = np.linalg.norm(so3_log(np.swapaxes(a.R_nb, -1, -2) @ b.R_nb), axis=1) * (180.0 / np.pi * 3600.0)
    k = int(np.argmin(np.abs(a.t_s - join_s)))
    return {"t_s": float(join_s), "rows": int(a.t_s.size),
            "position_difference_mm": {"max": float(dp.max()), "at_join": float(dp[k])},
            "velocity_difference_mm_per_s": {"max": float(dv.max()), "at_join": float(dv[k])},
            "attitude_difference_arcsec": {"max": float(da.max()), "at_join": float(da[k])}}


def _stitch_rows(parts: list[SegmentResult], joins: np.ndarray, h: float
                 ) -> tuple[DenseTrajectory, list[dict[str, Any]]]:
    pieces, seams = [], []
    for s, p in enumerate(parts):
        own, window = _regions(p.rows.t_s, joins, h, s)
        pieces.append(p.rows.select(own))
        if window is None:
            continue
        nxt = parts[s + 1]
        b_window = (nxt.rows.t_s >= joins[s] - h) & (nxt.rows.t_s < joins[s] + h)
        if not np.array_equal(p.row_idx[window], nxt.row_idx[b_window]):
            raise RuntimeError(f"segments {s} and {s + 1} have different rows at the join at {joins[s]:.1f} s")
        a, b = p.rows.select(window), nxt.rows.select(b_window)
        w, dw = blend_weight(a.t_s, joins[s], h)
        seams.append(_seam(a, b, joins[s]))
        pieces.append(_blend_rows(a, b, w, dw))
    return DenseTrajectory.concatenate(pieces), seams


def _key_part(res: SmootherResult, m: np.ndarray) -> dict[str, np.ndarray]:
    return {name: getattr(res, name)[m] for name in _KEY_ARRAYS if getattr(res, name) is not None}


def _stitch_keyframes(parts: list[SegmentResult], joins: np.ndarray, h: float) -> dict[str, np.ndarray]:
    """Keyframe arrays: each segment's outside the windows; inside, those both neighbours have, blended."""
    pieces = []
    for s, p in enumerate(parts):
        ra = p.res
        own, window = _regions(ra.t_s, joins, h, s)
        pieces.append(_key_part(ra, own))
        if window is None:
            continue
        rb = parts[s + 1].res
        b_window = (rb.t_s >= joins[s] - h) & (rb.t_s < joins[s] + h)
        common, ia, ib = np.intersect1d(ra.key_idx[window], rb.key_idx[b_window], return_indices=True)
        a, b = _key_part(ra, np.flatnonzero(window)[ia]), _key_part(rb, np.flatnonzero(b_window)[ib])
        w, dw = blend_weight(a["t_s"], joins[s], h)
        blended = {name: (1.0 - w.reshape((-1,) + (1,) * (v.ndim - 1))) * v
                   + w.reshape((-1,) + (1,) * (v.ndim - 1)) * b[name] for name, v in a.items()}
        blended["t_s"], blended["key_idx"] = a["t_s"], a["key_idx"]
        blended["R_nb"] = _blend_rotations(a["R_nb"], b["R_nb"], w)
        blended["vel_n"] = blended["vel_n"] + dw[:, None] * (b["pos_n"] - a["pos_n"])
        pieces.append(blended)
    return {name: np.concatenate([p[name] for p in pieces]) for name in pieces[0]}


def _stitch_sigmas(parts: list[SegmentResult], joins: np.ndarray, h: float) -> tuple[np.ndarray, ...]:
    """Marginal sigmas: each segment's outside the windows; inside, at both segments' marginal
    times, interpolated in each and blended."""
    t_parts, pos_parts, att_parts = [], [], []
    for s, p in enumerate(parts):
        ra = p.res
        own, window = _regions(ra.sigma_t_s, joins, h, s)
        t_parts.append(ra.sigma_t_s[own])
        pos_parts.append(ra.sigma_pos_n_m[own])
        att_parts.append(ra.sigma_att_rad[own])
        if window is None:
            continue
        rb = parts[s + 1].res
        t = np.union1d(ra.sigma_t_s[window], rb.sigma_t_s[(rb.sigma_t_s >= joins[s] - h) & (rb.sigma_t_s < joins[s] + h)])
        w = blend_weight(t, joins[s], h)[0][:, None]

        def at(r: SmootherResult, values: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(t, r.sigma_t_s, values[:, i]) for i in range(values.shape[1])])
        t_parts.append(t)
        pos_parts.append((1.0 - w) * at(ra, ra.sigma_pos_n_m) + w * at(rb, rb.sigma_pos_n_m))
        att_parts.append((1.0 - w) * at(ra, ra.sigma_att_rad) + w * at(rb, rb.sigma_att_rad))
    return np.concatenate(t_parts), np.concatenate(pos_parts), np.concatenate(att_parts)


def _window_rows(p: SegmentResult, join_s: float, h: float) -> DenseTrajectory:
    return p.rows.select((p.rows.t_s >= join_s - h) & (p.rows.t_s < join_s + h))


def level_corrections(parts: list[SegmentResult], joins: np.ndarray, h: float) -> list[Callable]:
    """Per segment, its position correction ``c(t)`` (M,) -> (M,3) [m] and its rate [m/s]
    (module docstring): linear over the segment, half the mean difference of the neighbours'
    positions over a join's blend window at that join (towards the neighbour), zero at the
    run's ends."""
    d = [np.mean(_window_rows(parts[j + 1], joins[j], h).pos_n - _window_rows(parts[j], joins[j], h).pos_n, axis=0)
         for j in range(joins.size)]
    zero = np.zeros(3)
    out = []
    for s, p in enumerate(parts):
        t_l = joins[s - 1] if s > 0 else float(p.rows.t_s[0])
        t_r = joins[s] if s < joins.size else float(p.rows.t_s[-1])
        c_l = -0.5 * d[s - 1] if s > 0 else zero
        c_r = 0.5 * d[s] if s < joins.size else zero
        rate = (c_r - c_l) / (t_r - t_l)

        def correction(t_s, c_l=c_l, t_l=t_l, rate=rate):
            return c_l + (np.asarray(t_s)[:, None] - t_l) * rate, rate
        out.append(correction)
    return out


def _levelled(p: SegmentResult, correction: Callable) -> SegmentResult:
    """``p`` with its level correction applied to the positions and velocities of its rows and keyframes."""
    c_rows, rate = correction(p.rows.t_s)
    c_key, _ = correction(p.res.t_s)
    rows = DenseTrajectory(p.rows.t_s, p.rows.R_nb, p.rows.pos_n + c_rows, p.rows.vel_n + rate)
    return SegmentResult(replace(p.res, pos_n=p.res.pos_n + c_key, vel_n=p.res.vel_n + rate), rows, p.row_idx,
                         p.slow_priors)


def stitch(parts: list[SegmentResult], joins: np.ndarray, h: float
           ) -> tuple[SmootherResult, DenseTrajectory, list[dict[str, Any]]]:
    """The run's keyframe result and decimated trajectory from its segments' (module docstring),
    and the seam figures of each join (:func:`_seam`: before the level correction, and ``after``
    it)."""
    raw = [_seam(_window_rows(parts[j], joins[j], h), _window_rows(parts[j + 1], joins[j], h), joins[j])
           for j in range(joins.size)]
    parts = [_levelled(p, c) for p, c in zip(parts, level_corrections(parts, joins, h))]
    rows, seams = _stitch_rows(parts, joins, h)
    seams = [{**r, "after_level_correction": {k: v for k, v in a.items() if k.endswith("_difference_mm")}}
             for r, a in zip(raw, seams)]
    key = _stitch_keyframes(parts, joins, h)
    sigma_t, sigma_pos, sigma_att = _stitch_sigmas(parts, joins, h)
    bounds = np.r_[-np.inf, joins, np.inf]
    rejected = [r for s, p in enumerate(parts) for r in p.res.rejected_gnss if bounds[s] <= r["t_s"] < bounds[s + 1]]
    counts: dict[str, int] = {}
    for p in parts:
        for k, v in p.res.factor_counts.items():
            counts[k] = counts.get(k, 0) + v
    timings = {k: max(p.res.timings_s.get(k, 0.0) for p in parts) for k in parts[0].res.timings_s if k != "cpu_s"}
    first = parts[0].res
    res = SmootherResult(key["t_s"], key["key_idx"], key["R_nb"], key["pos_n"], key["vel_n"], key["gyro_bias_radps"],
                         key["accel_bias_mps2"], key.get("odometer_scale"), sigma_t, sigma_pos, sigma_att,
                         first.alignment, sum(p.res.iterations for p in parts),
                         sum(p.res.initial_cost for p in parts), sum(p.res.final_cost for p in parts), counts,
                         sorted(rejected, key=lambda r: r["t_s"]), timings)
    return res, rows, seams
