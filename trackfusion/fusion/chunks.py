"""Long runs in overlapping chunks: memory bounded by the chunk, not by the run.

The run is cut at join times ``t0 + chunk_s, t0 + 2 chunk_s, ...``. Chunk ``i`` is smoothed as a
batch over its core plus ``overlap_s`` of the data after its join, so that its state at the
join has seen the data on both sides (the smoothed estimate there depends on data within
about the correlation time of the errors). Its keyframes up to the join are kept. Chunk
``i+1`` starts at the join's IMU sample from that state (:class:`~.smoother.HandOver`): pose
and velocity held at it, bias, odometer scale and the GNSS correlated error carried on, so
the trajectory is continuous at the seam in position, attitude and velocity; for its
marginal covariances the hand-over priors take the previous chunk's marginal covariance
instead. The wheel-path factor (fusion/wheel_path.py) crosses the seam as well: the previous
chunk's keyframes of the minute before the join are handed over as the front wheel points of
the pairs whose rear wheel point is in the new chunk (held fixed: the previous chunk's
estimate there saw the data on both sides of the join). Each chunk's core is densified and
decimated to the output rate at once, so the IMU-rate trajectory never exists for the whole run
either; with ``on_dense`` the decimated
core goes to the caller chunk by chunk (the pipeline writes its trajectory.csv rows at once,
fusion/output_rate.py) and is not kept here.

What stays proportional to the run: the sensor arrays (read by the pipeline) and the
keyframe results (about 40 numbers per keyframe), and without ``on_dense`` the decimated output
trajectory.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from .. import geodesy
from ..sensors.types import ImuData, InclinometerData, OdometerData
from .problem import FusionProblem, GnssFixes
from .smoother import WHEEL_FRONT_S, HandOver, SmootherResult, smooth
from .trajectory import DenseTrajectory, KeyframeStates, densify

#: sensor data kept beyond a chunk's ends (interpolation of the odometer and inclinometer) [s]
_MARGIN_S = 1.0


def join_times(t0_s: float, t1_s: float, chunk_s: float, overlap_s: float) -> np.ndarray:
    """Nominal join times (J,) [s] between chunks of ``chunk_s``; a last piece shorter than
    ``overlap_s`` is merged into the chunk before it."""
    joins = t0_s + chunk_s * np.arange(1, int(np.ceil((t1_s - t0_s) / chunk_s)))
    return joins[joins < t1_s - overlap_s]


def _slice_time(t_s: np.ndarray, a_s: float, b_s: float) -> slice:
    return slice(int(np.searchsorted(t_s, a_s, "left")), int(np.searchsorted(t_s, b_s, "right")))


def sub_problem(problem: FusionProblem, i0: int, i1: int, odometer_before_s: float = 0.0) -> FusionProblem:
    """The problem restricted to IMU samples ``i0 .. i1`` (inclusive) and the other sensors'
    data in that time span (odometer and inclinometer with a margin for interpolation; the
    odometer from ``odometer_before_s`` [s] earlier, for the wheel-path pairs of a hand-over)."""
    imu = problem.imu
    s = slice(i0, i1 + 1)
    a, b = float(imu.t_s[i0]), float(imu.t_s[i1])
    sub = ImuData(imu.t_s[s], imu.gyro_radps[s], imu.accel_mps2[s])
    odo = problem.odometer
    if odo is not None:
        k = _slice_time(odo.t_s, a - _MARGIN_S - odometer_before_s, b + _MARGIN_S)
        odo = OdometerData(odo.t_s[k], odo.distance_m[k], odo.ticks[k])
    g = problem.gnss
    if g is not None:
        k = _slice_time(g.t_s, a, b)
        g = GnssFixes(g.t_s[k], g.pos_n[k], g.cov_n[k], g.fix_quality[k], g.lever_arm_b)
    inc = problem.inclinometer
    if inc is not None:
        k = _slice_time(inc.t_s, a - _MARGIN_S, b + _MARGIN_S)
        inc = InclinometerData(inc.t_s[k], inc.roll_rad[k], inc.pitch_rad[k])
    static = [(max(p, a), min(q, b)) for p, q in problem.static_intervals_s if q > a and p < b]
    return replace(problem, imu=sub, odometer=odo, gnss=g, inclinometer=inc, static_intervals_s=static)


def _decimated(dense: DenseTrajectory, first_index: int, every: int, skip_first: bool) -> DenseTrajectory:
    """Samples of ``dense`` (consecutive IMU samples from global index ``first_index``) whose
    global index is a multiple of ``every``; without the first sample when it is a seam's."""
    idx = first_index + np.arange(dense.t_s.size)
    keep = idx % every == 0
    keep[0] &= not skip_first
    return dense.select(keep)


def _core(res: SmootherResult, k_end: int, k_start: int, t_lo: float) -> dict[str, np.ndarray]:
    """Per-keyframe arrays of keyframes ``k_start .. k_end`` and the marginals after ``t_lo``."""
    s = slice(k_start, k_end + 1)
    sig = (res.sigma_t_s > t_lo) & (res.sigma_t_s <= res.t_s[k_end] + 1e-9)
    out = {"t_s": res.t_s[s], "R_nb": res.R_nb[s], "pos_n": res.pos_n[s], "vel_n": res.vel_n[s],
           "gyro_bias_radps": res.gyro_bias_radps[s], "accel_bias_mps2": res.accel_bias_mps2[s],
           "sigma_t_s": res.sigma_t_s[sig], "sigma_pos_n_m": res.sigma_pos_n_m[sig],
           "sigma_att_rad": res.sigma_att_rad[sig]}
    if res.odometer_scale is not None:
        out["odometer_scale"] = res.odometer_scale[s]
    return out


def smooth_in_chunks(problem: FusionProblem, chunk_s: float, overlap_s: float, every: int,
                     progress: Callable[[str], None] | None = None,
                     on_dense: Callable[[DenseTrajectory, SmootherResult, bool], None] | None = None
                     ) -> tuple[SmootherResult, DenseTrajectory | None]:
    """Smooth ``problem`` in overlapping chunks (module docstring) and densify it.

    Returns the keyframe result of the whole run (arrays concatenated over the chunk cores;
    key_idx global; counts, costs, iterations and timings summed; the alignment of the first
    chunk) and the trajectory at every ``every``-th IMU sample (global index multiple of it).
    With ``on_dense``, each chunk's piece of that trajectory is passed instead as
    ``on_dense(piece, result_so_far, last)`` (``result_so_far``: the keyframe result of the
    chunks done, as returned at the end) and None is returned for it.
    """
    say = progress or (lambda _m: None)
    imu = problem.imu
    joins = join_times(float(imu.t_s[0]), float(imu.t_s[-1]), chunk_s, overlap_s)
    omega_ie_n = geodesy.earth_rate_n(problem.origin) if problem.factors.imu.earth_rate else np.zeros(3)
    parts: list[dict[str, np.ndarray]] = []
    dense_parts: list[DenseTrajectory] = []
    results: list[SmootherResult] = []
    rejected: list[dict] = []
    i0, join, t_lo = 0, None, -np.inf
    for c in range(joins.size + 1):
        last = c == joins.size
        t_end = float(imu.t_s[-1]) if last else joins[c] + overlap_s
        i1 = imu.t_s.size - 1 if last else min(int(np.searchsorted(imu.t_s, t_end, "right")) - 1, imu.t_s.size - 1)
        say(f"chunk {c + 1} of {joins.size + 1}: {imu.t_s[i0]:.0f} - {imu.t_s[i1]:.0f} s")
        sub = sub_problem(problem, i0, i1, 0.0 if join is None else WHEEL_FRONT_S)
        res = smooth(sub, say, join=join, hand_over_t_s=None if last else float(joins[c]))
        k_end = res.t_s.size - 1 if last else res.hand_over.k
        k_start = 0 if join is None else 1
        part = _core(res, k_end, k_start, t_lo)
        part["key_idx"] = i0 + res.key_idx[k_start:k_end + 1]
        parts.append(part)
        kk = slice(0, k_end + 1)
        dense = densify(sub.imu, KeyframeStates.of(res, problem.origin, kk), omega_ie_n)
        piece = _decimated(dense, i0 + int(res.key_idx[0]), every, skip_first=join is not None)
        del dense
        offset = 0 if problem.gnss is None else int(np.searchsorted(problem.gnss.t_s, sub.imu.t_s[0], "left"))
        t_hi = res.t_s[k_end]
        rejected += [{**r, "index": r["index"] + offset} for r in res.rejected_gnss if t_lo < r["t_s"] <= t_hi]
        results.append(_summary(res))
        t_lo, join, i0 = float(t_hi), res.hand_over, i0 + int(res.key_idx[k_end])
        del res, sub
        if not last:
            _check_seam(join)
        if on_dense is None:
            dense_parts.append(piece)
        else:
            on_dense(piece, _combined(results, parts, rejected), last)
    if on_dense is not None:
        return _combined(results, parts, rejected), None
    return _combined(results, parts, rejected), DenseTrajectory.concatenate(dense_parts)


def _summary(res: SmootherResult) -> SmootherResult:
    """``res`` without its arrays (what :func:`_combined` takes of each chunk but the first's
    alignment): a chunk's arrays beyond its core are not kept."""
    empty = np.empty(0)
    return replace(res, t_s=empty, key_idx=empty, R_nb=empty, pos_n=empty, vel_n=empty, gyro_bias_radps=empty,
                   accel_bias_mps2=empty, odometer_scale=None, sigma_t_s=empty, sigma_pos_n_m=empty,
                   sigma_att_rad=empty, hand_over=None)


def _on_the_first_chunk(estimate: dict | None, later: str) -> dict | None:
    """An estimate (metrics.json's) the first chunk made, saying so and what the ``later`` chunks
    do with it; None when not estimated."""
    if estimate is None:
        return None
    return {**estimate, "estimated_on": f"the first chunk; the later chunks {later}"}


def _check_seam(join: HandOver) -> None:
    if not np.all(np.isfinite(join.cov)):
        from ..errors import FusionError
        raise FusionError(f"chunk hand-over at t = {join.t_s:.1f} s: the marginal covariance is not finite")


def _combined(results: list[SmootherResult], parts: list[dict[str, np.ndarray]], rejected: list[dict]
              ) -> SmootherResult:
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    counts: dict[str, int] = {}
    timings: dict[str, float] = {}
    for r in results:
        for k, v in r.factor_counts.items():
            counts[k] = counts.get(k, 0) + v
        for k, v in r.timings_s.items():
            timings[k] = timings.get(k, 0.0) + v
    first = results[0]
    return SmootherResult(cat["t_s"], cat["key_idx"], cat["R_nb"], cat["pos_n"], cat["vel_n"], cat["gyro_bias_radps"],
                          cat["accel_bias_mps2"], cat.get("odometer_scale"), cat["sigma_t_s"], cat["sigma_pos_n_m"],
                          cat["sigma_att_rad"], first.alignment, sum(r.iterations for r in results),
                          sum(r.initial_cost for r in results), sum(r.final_cost for r in results), counts,
                          sorted(rejected, key=lambda r: r["t_s"]), timings,
                          noise_components=_on_the_first_chunk(first.noise_components, "apply its factors"),
                          gnss_time_constant=_on_the_first_chunk(first.gnss_time_constant,
                                                                 "apply what it solved with"))
