"""Total-station surveys solved in two stages (docs/total_stations.md, "Two-stage solve").

Each station's correction state (rotation, translation, clock offset and drift:
fusion/factors.py ``STATION_STATE_DIM``) is connected to every keyframe the station sees, on
the way out and back, so in the joint graph both stations' states sit in every clique's
separator and the elimination costs about twice a chain's (docs/solver_speed.md). Here:

1. **Stations** (:func:`estimate_stations`): the same survey smoothed on a coarse problem:
   keyframes ``coarse_spacing_s`` apart, the IMU block-averaged by ``imu_decimation`` (each
   sample is the mean over its interval, so the block mean is the mean over the block), only
   the prism readings within ``prism_window_s`` of a coarse keyframe. Its station states and
   their joint marginal covariance are kept.
2. **Trajectory** (:func:`smooth_two_stage`): the full problem with the stations held at that
   estimate (``PrismReadings.fixed_states``): no station state in the graph, a chain.
3. **Sigmas**: the trajectory's marginals are conditional on the stations. The stations'
   uncertainty is added to the position sigmas mapped through the prism geometry
   (:func:`station_position_variance`): locally the trajectory follows the readings, so a
   correction ``dq`` of station ``j`` moves it by ``-J_q dq`` (``J_q`` the prism factor's
   Jacobian), averaged over the nearby readings of every station with their information.

Pure computation: no file I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..fusion import factors as fx
from ..fusion.problem import FusionProblem, PrismReadings
from ..fusion.smoother import SmootherResult, nearest_sample, smooth
from ..sensors.types import ImuData, OdometerData


@dataclass(frozen=True)
class TwoStageSettings:
    """coarse_spacing_s: keyframe spacing of the station solve [s]; imu_decimation: IMU samples
    averaged into one for it; prism_window_s: readings kept for it, at most this far from a
    coarse keyframe [s]; sigma_window_s: half-width of the window of readings whose geometry
    maps the station covariance into a sigma keyframe's position [s]."""

    coarse_spacing_s: float = 1.0
    imu_decimation: int = 5
    prism_window_s: float = 0.5
    sigma_window_s: float = 2.0


@dataclass
class StationEstimate:
    """The coarse solve's station corrections ``states`` (J,8), their joint covariance ``cov``
    (8J,8J), and the coarse result itself."""

    states: np.ndarray
    cov: np.ndarray
    coarse: SmootherResult


def decimated_imu(imu: ImuData, m: int) -> ImuData:
    """Means of ``m`` consecutive samples (N // m,), each stamped at the end of its block;
    the samples after the last full block are dropped, except that the last sample is kept as a
    block of its own (the run's end stays a keyframe)."""
    if m <= 1:
        return imu
    n = (imu.t_s.size // m) * m
    t = imu.t_s[m - 1:n:m]
    g = imu.gyro_radps[:n].reshape(-1, m, 3).mean(axis=1)
    a = imu.accel_mps2[:n].reshape(-1, m, 3).mean(axis=1)
    if n < imu.t_s.size:  # the tail (fewer than m samples) as one averaged sample
        t = np.r_[t, imu.t_s[-1]]
        g = np.vstack([g, imu.gyro_radps[n:].mean(axis=0)])
        a = np.vstack([a, imu.accel_mps2[n:].mean(axis=0)])
    return ImuData(t, g, a)


def prisms_near(prisms: PrismReadings, t_grid_s: np.ndarray, window_s: float) -> PrismReadings:
    """The readings at most ``window_s`` from the nearest of ``t_grid_s`` (sorted)."""
    near = np.abs(prisms.t_s - t_grid_s[nearest_sample(t_grid_s, prisms.t_s)]) <= window_s
    flagged = None if prisms.flagged is None else prisms.flagged[near]  # the step check's mis-locks
    return replace(prisms, t_s=prisms.t_s[near], pos_n=prisms.pos_n[near], cov_n=prisms.cov_n[near],
                   station=prisms.station[near], flagged=flagged)


def transported(prisms: PrismReadings, odometer: OdometerData, t_grid_s: np.ndarray,
                baseline_s: float = 2.0, min_travel_m: float = 0.5, speed_step_s: float = 0.1) -> PrismReadings:
    """The readings with the second-order part of their motion to the nearest of ``t_grid_s``
    (sorted) taken out: the prism factor carries a reading to its keyframe along the keyframe's
    velocity, ``dt`` up to half the spacing away, which fails at starts and stops on coarse
    keyframes. Each reading moves by ``-(d(t) - d(g) - d'(g) (t - g)) tangent``: ``d`` the
    odometer distance, ``g`` the grid time, ``d'`` its speed there (central difference over
    ``speed_step_s``) and ``tangent = d pos / d distance`` of the station's readings
    ``baseline_s`` either side (zero where the trolley moved less than ``min_travel_m`` then).
    At constant speed nothing moves. Error: the track's curvature over the shift (well below
    0.1 mm)."""
    def dist(t):
        return np.interp(t, odometer.t_s, odometer.distance_m)

    t = prisms.t_s
    g = t_grid_s[nearest_sample(t_grid_s, t)]
    speed = (dist(g + speed_step_s) - dist(g - speed_step_s)) / (2.0 * speed_step_s)
    second_order_m = dist(t) - dist(g) - speed * (t - g)
    tangent = np.zeros_like(prisms.pos_n)
    for j in range(len(prisms.station_ids)):
        mine = np.flatnonzero(prisms.station == j)
        tj = t[mine]
        a = mine[np.clip(np.searchsorted(tj, tj - baseline_s), 0, tj.size - 1)]
        b = mine[np.clip(np.searchsorted(tj, tj + baseline_s) - 1, 0, tj.size - 1)]
        travel = dist(t[b]) - dist(t[a])
        ok = np.abs(travel) >= min_travel_m
        tangent[mine[ok]] = (prisms.pos_n[b[ok]] - prisms.pos_n[a[ok]]) / travel[ok, None]
    return replace(prisms, pos_n=prisms.pos_n - tangent * second_order_m[:, None])


def coarse_problem(problem: FusionProblem, settings: TwoStageSettings) -> FusionProblem:
    """The station solve's problem (module docstring, step 1); no sigma columns are needed from it."""
    imu = decimated_imu(problem.imu, settings.imu_decimation)
    grid = np.arange(imu.t_s[0], imu.t_s[-1], settings.coarse_spacing_s)
    grid = imu.t_s[np.unique(nearest_sample(imu.t_s, grid))]  # the coarse keyframes' times
    prisms = prisms_near(problem.prisms, grid, settings.prism_window_s)
    if problem.odometer is not None:
        prisms = transported(prisms, problem.odometer, grid)
    return replace(problem, imu=imu, prisms=prisms,
                   keyframes=problem.keyframes.model_copy(update={"spacing_s": settings.coarse_spacing_s}),
                   smoother=problem.smoother.model_copy(update={"marginal_step_s": 1e9}))


def estimate_stations(problem: FusionProblem, settings: TwoStageSettings,
                      progress: Callable[[str], None] | None = None) -> StationEstimate:
    """Step 1: the station corrections and their covariance from the coarse solve."""
    say = progress or (lambda _m: None)
    coarse = coarse_problem(problem, settings)
    say(f"two-stage solve, 1: the stations on {coarse.prisms.t_s.size} readings, keyframes "
        f"{settings.coarse_spacing_s:g} s apart")
    res = smooth(coarse, lambda m: say("  " + m))
    return StationEstimate(res.station_states, res.station_cov, res)


def uses_two_stage(problem: FusionProblem) -> bool:
    """True when the problem's stations are to be estimated in two stages: total stations on,
    ``factors.total_stations.solve: two_stage`` and the stations not already held."""
    fs = problem.factors.total_stations
    return (problem.prisms is not None and fs.enabled and fs.solve == "two_stage"
            and not problem.prisms.stations_fixed)


def smooth_two_stage(problem: FusionProblem, settings: TwoStageSettings = TwoStageSettings(),
                     progress: Callable[[str], None] | None = None,
                     on_solved: Callable[..., None] | None = None,
                     preintegrated=None) -> SmootherResult:
    """The survey smoothed in two stages (module docstring): the returned result's
    ``station_states`` / ``station_cov`` are the coarse solve's, its position sigmas include the
    stations' uncertainty, and its timings add the coarse solve's as ``stations_s``.
    ``on_solved``, ``preintegrated``: as :func:`~trackfusion.fusion.smoother.smooth`'s, for the
    second stage (the survey's own keyframes)."""
    if problem.prisms is None or not problem.factors.total_stations.enabled:
        raise ValueError("smooth_two_stage: the problem has no total-station readings")
    say = progress or (lambda _m: None)
    import time
    tic = time.perf_counter()
    est = estimate_stations(problem, settings, say)
    stations_s = time.perf_counter() - tic
    say("two-stage solve, 2: the trajectory with the stations held")
    held = replace(problem, prisms=replace(problem.prisms, fixed_states=est.states))
    res = smooth(held, say, initial=est.coarse, on_solved=on_solved, preintegrated=preintegrated)
    var = station_position_variance(problem.prisms, est.states, est.cov, res, settings.sigma_window_s)
    res.sigma_pos_n_m = np.sqrt(res.sigma_pos_n_m**2 + var)
    res.station_cov = est.cov
    res.timings_s = {"stations_s": stations_s, **res.timings_s}
    return res


def station_position_variance(prisms: PrismReadings, states: np.ndarray, cov: np.ndarray, res: SmootherResult,
                              window_s: float) -> np.ndarray:
    """Variance (M,3) [m^2] of the positions at ``res.sigma_t_s`` (M,) due to the stations'
    covariance ``cov`` (8J,8J) about ``states`` (J,8) (module docstring, step 3): at each sigma
    time, ``dp = -(sum_i I_i)^-1 sum_i I_i J_q,i dq_s(i)`` over the readings ``i`` nearest to it
    (and within ``window_s``), ``I_i`` each reading's information; a sigma time without such
    readings takes the mapping of the nearest one that has them (held across tracking gaps)."""
    J, d = len(prisms.station_ids), fx.STATION_STATE_DIM
    k = nearest_sample(res.t_s, prisms.t_s)
    R, v = res.R_nb[k], res.vel_n[k]
    info = np.linalg.inv(prisms.cov_n)  # (N,3,3)
    from_station = prisms.pos_n - prisms.station_pos_n[prisms.station]
    zeros = np.zeros_like(prisms.t_s)
    # the prism's velocity (the body rate term is below 1e-4 m/s here and left out)
    _, jac = fx.prism_residual(R, res.pos_n[k], v, np.zeros_like(v), prisms.lever_arm_b, zeros, prisms.t_s,
                               states[prisms.station], prisms.pos_n, from_station)
    IJ = info @ jac[2]  # (N,3,8)
    m = nearest_sample(res.sigma_t_s, prisms.t_s)
    near = np.abs(prisms.t_s - res.sigma_t_s[m]) <= window_s
    M = res.sigma_t_s.size
    info_sum = np.zeros((M, 3, 3))
    weighted = np.zeros((M, 3, J * d))
    np.add.at(info_sum, m[near], info[near])
    cols = prisms.station[near][:, None] * d + np.arange(d)[None, :]  # (n,8) columns of each reading's station
    rows = np.broadcast_to(m[near][:, None, None], (cols.shape[0], 3, d))
    np.add.at(weighted, (rows, np.arange(3)[None, :, None], cols[:, None, :]), IJ[near])
    has = np.linalg.det(info_sum) > 0
    if not np.any(has):
        return np.zeros((M, 3))
    Map = np.zeros((M, 3, J * d))
    Map[has] = -np.linalg.solve(info_sum[has], weighted[has])
    fill = np.flatnonzero(has)[nearest_sample(res.sigma_t_s[has], res.sigma_t_s)] if has.sum() > 1 else \
        np.full(M, np.flatnonzero(has)[0])
    Map = Map[fill]
    return np.einsum("mij,jk,mik->mi", Map, cov, Map)
