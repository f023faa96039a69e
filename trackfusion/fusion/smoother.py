"""Batch factor-graph smoother (DESIGN.md section 5).

Variables per keyframe k: pose ``X(k)`` (``R_nb``, IMU origin in ``n``), velocity ``V(k)``
[m/s, n]; IMU bias ``B(m)`` per bias segment and odometer scale error ``S(m)`` per scale
segment (random walks between segments). Factors: ``ImuFactor`` between keyframes
(why not ``CombinedImuFactor``: fusion/preintegration.py); bias and scale priors; ZUPT (zero
velocity prior, zero relative pose between static keyframes); GNSS (``GPSFactorArm``,
Huber, gated); and the vectorised factors of :mod:`.factors` (NHC, odometer,
inclinometer). Gauss-Newton with a backtracking line search: GTSAM linearises its
factors, numpy linearises ours, GTSAM eliminates (multifrontal Cholesky).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, D, E, S, T, V, X

from .. import geodesy
from ..errors import FusionError
from ..rotations import so3_exp, ypr_from_R
from . import factors as fx
from . import gnss_noise
from . import gnss_time_constant as gtc
from . import noise_components as nc
from .alignment import Alignment, back_to_start, initial_alignment
from .convergence import StepHistory
from .normal_solve import tree_factor
from .preintegration import body_deltas, preintegrate
from .preprocess import odometer_quantum_m
from .problem import FusionProblem, GnssFixes
from ..forked import ForkedTasks, can_fork, usable_cpus
from ..parallel import dask_client
from .partitioned import (MARGINAL_PART_S, Partition, PartitionedSolver, PartMarginals, cut_times,
                          joint_marginal_covariance, part_marginal_covariances,
                          tree_covariances)
from .wheel_path import HAND_OVER_BUILDER, WheelFront, wheel_path_builder
from ..registration.mislock import gate_prisms, prefused_rejections

if TYPE_CHECKING:
    from ..registration.readings import PrismReadings

DEG = np.pi / 180.0
#: sigma of the hand-over priors of a chunk (fusion/chunks.py) relative to the previous chunk's
#: marginal sigma: holds the seam continuous
JOIN_TIGHT = 1e-3
#: the most keyframes whose noise estimate is forked beside the converging step
#: (:func:`_estimate_while_converging`): the child copies the last Bayes tree while this process
#: and its sigma-part workers take the step. 2 h at 500 Hz (34 401 keyframes): 4.7 GB for the
#: process tree, against 3.5 GB in turn (docs/long_runs.md); the same numbers either way
ESTIMATE_BESIDE_STEP_MAX_KEYFRAMES = 25_000
#: how far back [s] a chunk hands its keyframes over as the front wheel points of the next
#: chunk's first wheel-path pairs: a wheelbase at 0.05 m/s and more
WHEEL_FRONT_S = 60.0


@dataclass
class SmootherResult:
    """Smoothed keyframe states and their uncertainty.

    t_s (K,) keyframe times [s]; key_idx (K,) their IMU sample indices; R_nb (K,3,3);
    pos_n (K,3) [m]; vel_n (K,3) [m/s]; gyro_bias_radps, accel_bias_mps2 (K,3);
    odometer_scale (K,) [-] scale error at each keyframe (None without odometer);
    sigma_t_s (M,) times of the marginals; sigma_pos_n_m (M,3) [m]; sigma_att_rad (M,3)
    (roll, pitch about body x/y, yaw about n up) [rad].
    """

    t_s: np.ndarray
    key_idx: np.ndarray
    R_nb: np.ndarray
    pos_n: np.ndarray
    vel_n: np.ndarray
    gyro_bias_radps: np.ndarray
    accel_bias_mps2: np.ndarray
    odometer_scale: np.ndarray | None
    sigma_t_s: np.ndarray
    sigma_pos_n_m: np.ndarray
    sigma_att_rad: np.ndarray
    alignment: Alignment
    iterations: int
    initial_cost: float
    final_cost: float
    factor_counts: dict[str, int]
    rejected_gnss: list[dict]
    timings_s: dict[str, float] = field(default_factory=dict)
    station_states: np.ndarray | None = None  # (J,8) total-station corrections (factors.STATION_STATE_DIM)
    rejected_prism: list[dict] = field(default_factory=list)  # [{"station", "t_s", "reason", "nis"}]
    hand_over: "HandOver | None" = None  # the state at ``hand_over_t_s`` (fusion/chunks.py)
    station_cov: np.ndarray | None = None  # (8J,8J) joint marginal covariance of station_states (estimated ones)
    gnss_noise: "gnss_noise.GnssNoiseEstimate | None" = None  # the GNSS white noise from the residuals
    noise_components: dict | None = None  # every other group's noise, metrics.json's (fusion/noise_components.py)
    gnss_time_constant: dict | None = None  # the GNSS correlated time constant estimated (fusion/gnss_time_constant.py)


@dataclass
class HandOver:
    """The smoothed state at one keyframe of a chunk, which the next chunk starts from
    (fusion/chunks.py).

    k: keyframe index in the chunk; t_s [s]; R_nb (3,3); pos_n (3,) [m]; vel_n (3,) [m/s];
    bias (6,) GTSAM order (accelerometer [m/s^2], gyro [rad/s]); scale [-] or None; the GNSS
    error state of the last used fix at or before t_s: gnss_error_t_s [s] and gnss_error_n (3,)
    [m], or None; cov (9,9) or (12,12): joint marginal covariance of [pose (GTSAM tangent:
    rotation, position in ``b``), velocity, GNSS error] given the data up to t_s only (the next
    chunk holds the data after it: no information counted twice); bias_var (6,) and scale_var
    (or None) the marginal variances of the bias and scale there, on the same data; rate [1/h]
    and rate_var (or None) the scale's drift rate there and its marginal variance;
    wheel_front: the chunk's keyframes in the :data:`WHEEL_FRONT_S` before ``t_s`` (times,
    attitudes, positions), the front wheel points of the next chunk's first wheel-path pairs;
    noise_applied: the groups' noise variance factors the chunk applied (estimated in the run's
    first chunk, fusion/noise_components.py; None: not estimated), which the next applies too;
    gnss_time_constant_s [s]: the GNSS correlated error's time constant the chunk solved with
    (estimated in the run's first chunk when asked, fusion/gnss_time_constant.py), the next's too.
    """

    k: int
    t_s: float
    R_nb: np.ndarray
    pos_n: np.ndarray
    vel_n: np.ndarray
    bias: np.ndarray
    scale: float | None
    gnss_error_t_s: float | None
    gnss_error_n: np.ndarray | None
    cov: np.ndarray
    bias_var: np.ndarray
    scale_var: float | None
    wheel_front: WheelFront | None = None
    noise_applied: dict[str, dict[str, float]] | None = None
    rate: float | None = None
    rate_var: float | None = None
    gnss_time_constant_s: float | None = None

    @property
    def alignment(self) -> Alignment:
        yaw, pitch, roll = ypr_from_R(self.R_nb)
        return Alignment(float(roll), float(pitch), float(yaw), "hand-over", 0.0)


# --- keyframes and the initial estimate ----------------------------------------------------------

def nearest_sample(t_s: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Index (M,) of the sample of ``t_s`` (N,) nearest to each query time."""
    i = np.clip(np.searchsorted(t_s, t_query), 1, t_s.size - 1)
    return np.where(np.abs(t_s[i - 1] - t_query) <= np.abs(t_s[i] - t_query), i - 1, i)


def keyframe_indices(t_s: np.ndarray, spacing_s: float, extra_t_s: np.ndarray | None = None) -> np.ndarray:
    """Sorted unique IMU sample indices (K,) of keyframes: a regular grid of ``spacing_s``, the
    first and last samples, and the samples nearest to ``extra_t_s`` (aiding epochs)."""
    fixed = [np.array([0, t_s.size - 1])]
    if extra_t_s is not None and extra_t_s.size:
        inside = extra_t_s[(extra_t_s >= t_s[0]) & (extra_t_s <= t_s[-1])]
        fixed.append(nearest_sample(t_s, inside))
    fixed_idx = np.unique(np.concatenate(fixed).astype(np.int64))
    grid = np.unique(nearest_sample(t_s, np.arange(t_s[0], t_s[-1], spacing_s)))
    # a grid keyframe closer than a quarter spacing to a fixed one would make a very short,
    # badly conditioned interval: drop it
    j = np.clip(np.searchsorted(t_s[fixed_idx], t_s[grid]), 1, fixed_idx.size - 1)
    gap = np.minimum(np.abs(t_s[grid] - t_s[fixed_idx[j - 1]]), np.abs(t_s[grid] - t_s[fixed_idx[j]]))
    return np.unique(np.concatenate([fixed_idx, grid[gap >= 0.25 * spacing_s]]))


def static_mask(t_s: np.ndarray, intervals: list[tuple[float, float]]) -> np.ndarray:
    """Boolean (K,) true where ``t_s`` lies inside a static interval."""
    mask = np.zeros(t_s.size, dtype=bool)
    for a, b in intervals:
        mask |= (t_s >= a) & (t_s <= b)
    return mask


def _alignment(problem: FusionProblem) -> Alignment:
    # start, else end static period, else levelling while moving (fusion/alignment.py)
    return initial_alignment(problem)


def _chain_rotations(R0: np.ndarray, pims, dt_key: np.ndarray, omega_ie_n: np.ndarray) -> np.ndarray:
    """Attitudes (K,3,3) from the preintegrated rotations and the Earth's rotation."""
    dR = np.array([p.deltaRij().matrix() for p in pims])
    earth = so3_exp(-omega_ie_n[None, :] * dt_key[:, None])
    R = np.empty((len(pims) + 1, 3, 3))
    R[0] = R0
    for k in range(len(pims)):
        R[k + 1] = earth[k] @ R[k] @ dR[k]
    return R


def initial_states(problem: FusionProblem, t_key: np.ndarray, R_nb: np.ndarray,
                   static: np.ndarray, median_window: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Initial positions (K,3) and velocities (K,3): odometer speed along the trolley axis (else
    differenced GNSS), integrated, then shifted onto the GNSS fixes (interpolated residuals;
    with ``median_window`` > 1, residuals median-filtered over that many fixes first, so that a
    run of gross errors shorter than half the window does not pull the start)."""
    axis_n = R_nb @ problem.trolley.axis_b
    g = problem.gnss
    if problem.odometer is not None:
        d = np.interp(t_key, problem.odometer.t_s, problem.odometer.distance_m)
        vel = axis_n * np.gradient(d, t_key)[:, None]
    elif g is not None and g.t_s.size > 1:
        vel = np.column_stack([np.interp(t_key, g.t_s, np.gradient(g.pos_n[:, i], g.t_s)) for i in range(3)])
    else:
        vel = np.zeros((t_key.size, 3))
    vel[static] = 0.0
    pos = np.zeros_like(vel)
    pos[1:] = np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(t_key)[:, None], axis=0)
    if g is not None and g.t_s.size:
        antenna = pos + R_nb @ g.lever_arm_b
        pred = np.column_stack([np.interp(g.t_s, t_key, antenna[:, i]) for i in range(3)])
        resid = g.pos_n - pred
        if median_window > 1:
            from scipy.ndimage import median_filter
            resid = median_filter(resid, size=(median_window, 1), mode="nearest")
        pos += np.column_stack([np.interp(t_key, g.t_s, resid[:, i]) for i in range(3)])
    return pos, vel


# --- the graph --------------------------------------------------------------------------------------

@dataclass
class _Graph:
    """The built-in factors (a GTSAM graph) and builders of the vectorised ones."""

    graph: gtsam.NonlinearFactorGraph
    builders: list[tuple[str, Callable[["_State"], fx.LinearBlocks]]]
    counts: dict[str, int]
    gnss: Callable[["_State"], fx.LinearBlocks] | None = None  # builder of the GNSS position factors


@dataclass
class _State:
    """The estimate as arrays: R (K,3,3), p (K,3), v (K,3), odometer scale s (M,), GNSS errors e (F,3),
    total-station corrections ts (J,8), the odometer scale's drift rate d (M-1,) [1/h] (None
    without its states)."""

    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    s: np.ndarray | None
    e: np.ndarray
    ts: np.ndarray | None = None
    d: np.ndarray | None = None

    @classmethod
    def of(cls, values: gtsam.Values, with_scale: bool) -> "_State":
        P = gtsam.utilities.extractPose3(values)
        s = gtsam.utilities.extractVectors(values, "s")[:, 0] if with_scale else None
        d = gtsam.utilities.extractVectors(values, "d")
        return cls(P[:, :9].reshape(-1, 3, 3), P[:, 9:].copy(), gtsam.utilities.extractVectors(values, "v"), s,
                   gtsam.utilities.extractVectors(values, "e"), gtsam.utilities.extractVectors(values, "t"),
                   d[:, 0] if d.size else None)


@dataclass(frozen=True)
class _Keyframes:
    """The keyframes of a solve: IMU sample indices ``idx`` (K,), times ``t_s`` (K,) [s], ``static``
    (K,) bool (inside a static interval, with ZUPT on), and of each keyframe its IMU bias segment
    ``bias_seg`` (K,) and odometer scale segment ``scale_seg`` (K,) (None: no scale states)."""

    idx: np.ndarray
    t_s: np.ndarray
    static: np.ndarray
    bias_seg: np.ndarray
    scale_seg: np.ndarray | None
    with_rate: bool = False  # the scale's drift rate states D (two scale segments or more, a rate prior)

    @property
    def with_scale(self) -> bool:
        return self.scale_seg is not None


def _keyframe_layout(problem: FusionProblem, key_idx: np.ndarray) -> _Keyframes:
    """The :class:`_Keyframes` of ``problem`` at the IMU samples ``key_idx`` (K,)."""
    fs = problem.factors
    t_key = problem.imu.t_s[key_idx]
    static = static_mask(t_key, problem.static_intervals_s) if fs.zupt.enabled else np.zeros(t_key.size, bool)
    with_scale = problem.odometer is not None and fs.odometer.enabled
    seg = (np.floor((t_key - t_key[0]) / fs.odometer.scale_segment_s).astype(np.int64) if with_scale else None)
    # bias segment of each interval (the last keyframe belongs to the last interval's)
    bias_seg = np.floor((t_key - t_key[0]) / problem.keyframes.bias_segment_s).astype(np.int64)
    bias_seg[-1] = bias_seg[-2]
    # drift-rate states (docs/error_models.md): a rate prior set and two scale segments or more
    with_rate = with_scale and fs.odometer.scale_rate_sigma_ppm_per_h is not None and int(seg[-1]) >= 1
    return _Keyframes(key_idx, t_key, static, bias_seg, seg, with_rate)


@dataclass(frozen=True)
class _Initial:
    """The initial estimate at the keyframes: ``R_nb`` (K,3,3), ``pos_n`` (K,3) [m], ``vel_n`` (K,3) [m/s]."""

    R_nb: np.ndarray
    pos_n: np.ndarray
    vel_n: np.ndarray


class _Builder:
    """Adds every factor of a problem to a graph, given keyframes, the IMU preintegrated between
    them (``pims``, K-1) and the initial estimate."""

    def __init__(self, problem: FusionProblem, kf: _Keyframes, pims, initial: _Initial, alignment: Alignment):
        self.pb, self.kf, self.t, self.idx, self.pims, self.static = problem, kf, kf.t_s, kf.idx, pims, kf.static
        self.pos0, self.R0, self.vel0, self.alignment = initial.pos_n, initial.R_nb, initial.vel_n, alignment
        self.seg, self.bias_seg = kf.scale_seg, kf.bias_seg
        self.g = gtsam.NonlinearFactorGraph()
        self.builders: list = []
        self.counts: dict[str, int] = {}
        self.join: HandOver | None = None
        self.soft = _SoftJoin()
        self._prism_span: fx.PrismObservations | None = None  # every reading's (:meth:`_prism_observations`)
        self._prism_keyframe = np.zeros(0, np.int64)

    def _count(self, name: str, n: int) -> None:
        self.counts[name] = self.counts.get(name, 0) + int(n)

    def snapshot(self) -> tuple:
        """The factors so far (the graph itself, copies of the rest), for :meth:`restart`."""
        return self.g, list(self.builders), dict(self.counts), self.soft.copy()

    def restart(self, base: tuple) -> None:
        """Back to the factors of ``base`` (:meth:`snapshot`), on a copy of its graph."""
        graph, builders, counts, soft = base
        self.g, self.counts, self.builders, self.soft = (gtsam.NonlinearFactorGraph(graph), dict(counts),
                                                         list(builders), soft.copy())

    def imu(self) -> None:
        for k, pim in enumerate(self.pims):
            self.g.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(int(self.bias_seg[k])), pim))
        n = self.pb.imu_noise
        # specific force at rest in b at the first keyframe: minus gravity
        f_b = -self.R0[0].T @ geodesy.gravity_n(self.pos0[0], self.pb.origin)
        sig = np.r_[n.accel_bias_prior_sigma_mps2(f_b), [n.gyro_bias_sigma_radps] * 3]
        bias0 = gtsam.imuBias.ConstantBias()
        T = self.pb.keyframes.bias_segment_s
        rw_var = np.r_[[n.accel_bias_rw_psd * T] * 3, [n.gyro_bias_rw_psd * T] * 3]
        if self.join is not None:  # the previous chunk's segment, then one random-walk step
            bias0 = gtsam.imuBias.ConstantBias(self.join.bias[:3], self.join.bias[3:])
            sig = np.sqrt(self.join.bias_var + rw_var)
        self.g.add(gtsam.PriorFactorConstantBias(B(0), bias0, gtsam.noiseModel.Diagonal.Sigmas(sig)))
        n_seg = int(self.bias_seg[-1]) + 1
        rw = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(rw_var))
        for m in range(n_seg - 1):
            self.g.add(gtsam.BetweenFactorConstantBias(B(m), B(m + 1), gtsam.imuBias.ConstantBias(), rw))
        self._count("imu", len(self.pims))
        self._count("bias_prior", 1)
        self._count("bias_random_walk", n_seg - 1)

    def anchor(self, absolute: bool) -> None:
        """Prior on the first pose: levelled attitude always (loose), yaw and position only
        when no sensor fixes them (gauge freedom)."""
        yaw_sigma = 1.0 if absolute or self.alignment.method == "gyrocompass" else 1e-6
        sig = np.r_[0.05, 0.05, yaw_sigma, [1e3 if absolute else 1e-4] * 3]
        self.g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(gtsam.Rot3(self.R0[0]), self.pos0[0]),
                                          gtsam.noiseModel.Diagonal.Sigmas(sig)))
        self._count("pose_prior", 1)

    def join_priors(self) -> None:
        """Instead of :meth:`anchor` in a chunk after the first: the pose and velocity of keyframe 0
        held at the previous chunk's (continuity at the seam); for the marginals, the previous
        chunk's marginal covariances instead (``self.soft``)."""
        j = self.join
        sigma = np.sqrt(np.diag(j.cov)) * JOIN_TIGHT
        pose = gtsam.Pose3(gtsam.Rot3(j.R_nb), j.pos_n)
        self.soft.remove += [self.g.size(), self.g.size() + 1]
        self.g.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(sigma[:6])))
        self.g.add(gtsam.PriorFactorVector(V(0), j.vel_n, gtsam.noiseModel.Diagonal.Sigmas(sigma[6:9])))
        self.soft.keys, self.soft.cov = [X(0), V(0)], j.cov[:9, :9]
        self._count("hand_over", 2)

    def zupt(self) -> None:
        st = self.pb.factors.zupt
        sv = st.sigma_velocity_mm_per_s * 1e-3
        sr = st.sigma_rate_deg_per_h * DEG / 3600.0
        vel_noise = gtsam.noiseModel.Isotropic.Sigma(3, sv)
        ks = np.flatnonzero(self.static)
        for k in ks:
            self.g.add(gtsam.PriorFactorVector(V(int(k)), np.zeros(3), vel_noise))
        pairs = ks[:-1][np.diff(ks) == 1]
        for k in pairs:
            dt = self.t[k + 1] - self.t[k]
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sr * dt] * 3, [st.sigma_displacement_mm * 1e-3] * 3])
            self.g.add(gtsam.BetweenFactorPose3(X(int(k)), X(int(k) + 1), gtsam.Pose3(), noise))
        self._count("zupt_velocity", ks.size)
        self._count("zupt_rate", pairs.size)

    def gnss_white(self, used: np.ndarray) -> np.ndarray:
        """The stated white covariances (F,3,3) [m^2] of the used fixes (:func:`white_covariance`)."""
        g, st = self.pb.gnss, self.pb.factors.gnss
        corr = np.array([st.correlated_sigma_h_mm] * 2 + [st.correlated_sigma_v_mm]) * 1e-3
        return white_covariance(g.cov_n[used] * st.covariance_scale, corr, st.min_sigma_mm * 1e-3)

    def gnss(self, used: np.ndarray, values: gtsam.Values, white_factor: np.ndarray,
             error_factor: np.ndarray | None = None) -> Callable[["_State"], fx.LinearBlocks]:
        """Factors of the used fixes (indices into the GNSS data), their stated white covariance
        scaled by ``white_factor`` (horizontal, vertical; fusion/gnss_noise.py); with a
        correlated-error model, one error state ``E(i)`` per used fix ``i`` (inserted into / kept
        in ``values``) joined by first-order Gauss-Markov steps. ``error_factor`` (3,): the
        correlated part's variance factors applied (e, n, u; fusion/noise_components.py scales
        the steps, and with them the process's stationary variance, which the first error state's
        prior takes here). Returns the builder of the position factors (for gating)."""
        g, st = self.pb.gnss, self.pb.factors.gnss
        kk = nearest_sample(self.t, g.t_s[used])
        # move each fix to its keyframe's time along the initial velocity (< half an IMU interval)
        fix = g.pos_n[used] - self.vel0[kk] * (g.t_s[used] - self.t[kk])[:, None]
        corr = np.array([st.correlated_sigma_h_mm] * 2 + [st.correlated_sigma_v_mm]) * 1e-3
        W = np.linalg.inv(np.linalg.cholesky(gnss_noise.scaled_white(self.gnss_white(used), white_factor)))
        keys_x, keys_e = X(0) + kk, E(0) + used
        ones = np.ones((used.size, 3))
        with_error = bool(np.any(corr > 0))
        lever = g.lever_arm_b

        def build(state: _State) -> fx.LinearBlocks:
            r, J = fx.gnss_residual(state.R[kk], state.p[kk], lever, fix, state.e if with_error else None)
            if with_error:
                return fx.LinearBlocks([keys_x, keys_e], [J, np.broadcast_to(np.eye(3), r.shape + (3,))], r, ones,
                                       st.huber_k, W)
            return fx.LinearBlocks([keys_x], [J], r, ones, st.huber_k, W)

        self.builders.append(("gnss", build))
        self._count("gnss", used.size)
        if with_error:
            process = corr * np.sqrt(error_factor) if error_factor is not None else corr
            self._gnss_error_states(used, values, corr, st.correlation_time_s, process)
        return build

    def _gnss_error_states(self, used: np.ndarray, values: gtsam.Values, corr: np.ndarray, tau_s: float,
                           process: np.ndarray) -> None:
        """The error states of the used fixes, the Gauss-Markov steps between them (of the
        configured sigma ``corr`` (3,) [m]: their variance factor is applied when the builders are
        wrapped) and the prior of the first (the process's sigma ``process`` (3,) [m], the factor
        applied)."""
        g = self.pb.gnss
        for i in used:
            if not values.exists(E(int(i))):
                values.insert(E(int(i)), np.zeros(3))
        self._gnss_error_prior(int(used[0]), values, process, tau_s)
        phi = np.exp(-np.diff(g.t_s[used]) / tau_s)[:, None] * np.ones(3)
        sigma = np.maximum(corr * np.sqrt(1.0 - phi**2), 1e-9)
        keys_i, keys_j = E(0) + used[:-1], E(0) + used[1:]

        def build(state: _State) -> fx.LinearBlocks:
            r, J = fx.gauss_markov_residual(state.e[:-1], state.e[1:], phi)
            return fx.LinearBlocks([keys_i, keys_j], J, r, sigma)

        self.builders.append(("gnss_error", build))
        self._count("gnss_error", used.size)

    # --- total stations --------------------------------------------------------------------------

    def prisms(self, used: np.ndarray, values: gtsam.Values) -> Callable[["_State"], fx.LinearBlocks]:
        """Factors of the used prism readings (indices into ``problem.prisms``) and one correction
        state ``T(j)`` per station (inserted into ``values`` when missing) with its prior from the
        instrument specification. Each reading is tied to the keyframe at or before it and reached
        from there with the IMU samples in between (fusion/factors.py ``prism_residual``).
        Returns the factors' builder."""
        pr, st = self.pb.prisms, self.pb.factors.total_stations
        for j in range(len(pr.station_ids)):
            if not values.exists(T(j)):
                values.insert(T(j), np.zeros(fx.STATION_STATE_DIM))
            self.g.add(gtsam.PriorFactorVector(T(j), np.zeros(fx.STATION_STATE_DIM),
                                               gtsam.noiseModel.Diagonal.Sigmas(pr.prior_sigma[j])))
        obs = self._prism_observations()
        obs = obs._replace(**{name: getattr(obs, name)[used] for name in fx.PRISM_PER_READING})
        kk, sid = self._prism_keyframe[used], pr.station[used]
        W = np.linalg.inv(np.linalg.cholesky(pr.cov_n[used]))
        keys = [X(0) + kk, V(0) + kk, T(0) + sid]
        ones = np.ones((used.size, 3))
        group = kk * len(pr.station_ids) + sid  # readings sharing their keys: one factor

        def build(state: _State) -> fx.LinearBlocks:
            r, J = fx.prism_residual(state.R[kk], state.p[kk], state.v[kk], state.ts[sid], obs)
            return fx.LinearBlocks(keys, J, r, ones, st.huber_k, W, group)

        self.builders.append(("prism", build))
        self._count("prism", used.size)
        self._count("station_prior", len(pr.station_ids))
        return build

    def _prism_observations(self) -> fx.PrismObservations:
        """Every prism reading as the prism factor sees it, made once per run (the gating rounds
        take their used readings' rows): tied to the keyframe at or before it, with the IMU
        samples up to the reading (fusion/factors.py ``prism_residual``)."""
        if self._prism_span is not None:
            return self._prism_span
        pr, imu = self.pb.prisms, self.pb.imu
        t_read = pr.t_s
        kk = np.clip(np.searchsorted(self.t, t_read, side="right") - 1, 0, self.t.size - 1)
        tau = t_read - self.t[kk]
        dR, dv, dp = body_deltas(imu, self.idx[kk], tau)
        holds = np.clip(np.searchsorted(imu.t_s, t_read), 0, imu.t_s.size - 1)  # the sample whose interval holds it
        omega_ie_n = geodesy.earth_rate_n(self.pb.origin) if self.pb.factors.imu.earth_rate else np.zeros(3)
        g_n = geodesy.gravity_n(self.pos0[kk], self.pb.origin)
        # a reading outside the IMU's span has no samples to reach it: the first-order step from the
        # end keyframe's velocity (without gravity, which the missing samples would have cancelled)
        g_n[(t_read < self.t[0]) | (t_read > self.t[-1])] = 0.0
        self._prism_keyframe = kk
        from_station_n = pr.pos_n - pr.station_pos_n[pr.station]
        self._prism_span = fx.PrismObservations(pr.lever_arm_b, tau, t_read, pr.pos_n, from_station_n, dR, dv, dp,
                                                imu.gyro_radps[holds], g_n, omega_ie_n)
        return self._prism_span

    def _gnss_error_prior(self, first: int, values: gtsam.Values, corr: np.ndarray, tau_s: float) -> None:
        """Prior of the first used fix's error: the Gauss-Markov process's, or in a later chunk its
        step from the previous chunk's error state (tight for the solve, with that state's
        marginal covariance for the marginals)."""
        j = self.join
        if j is None or j.gnss_error_n is None:
            self.g.add(gtsam.PriorFactorVector(E(first), np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(corr)))
            return
        phi = np.exp(-abs(self.pb.gnss.t_s[first] - j.gnss_error_t_s) / tau_s)
        mean = phi * j.gnss_error_n
        step_var = corr**2 * (1.0 - phi**2)
        values.update(E(first), mean)
        tight = np.sqrt(np.maximum(step_var, np.diag(j.cov)[9:] * JOIN_TIGHT**2))
        self.soft.remove.append(self.g.size())
        self.g.add(gtsam.PriorFactorVector(E(first), mean, gtsam.noiseModel.Diagonal.Sigmas(tight)))
        step = np.diag(np.r_[np.ones(9), phi * np.ones(3)])  # the Gauss-Markov step from the hand-over's error state
        self.soft.keys = [X(0), V(0), E(first)]
        self.soft.cov = step @ j.cov @ step + np.diag(np.r_[np.zeros(9), step_var])

    def odometer(self) -> None:
        odo, st = self.pb.odometer, self.pb.factors.odometer
        d = np.interp(self.t, odo.t_s, odo.distance_m)
        delta = np.diff(d)
        K = delta.size
        keys_i, keys_j = X(0) + np.arange(K), X(0) + np.arange(1, K + 1)
        keys_s = S(0) + self.seg[:-1]
        sigma = np.full((K, 1), st.sigma_mm * 1e-3)
        lever, axis = self.pb.trolley.wheel_lever_arm_b, self.pb.trolley.axis_b

        def build(state: _State) -> fx.LinearBlocks:
            r, J = fx.odometer_residual(state.R[:-1], state.p[:-1], state.R[1:], state.p[1:],
                                        state.s[self.seg[:-1]], delta, lever, axis)
            return fx.LinearBlocks([keys_i, keys_j, keys_s], J, r, sigma, st.huber_k)

        self.builders.append(("odometer", build))
        self._count("odometer", K)
        self._odometer_scale_model(st)

    def _odometer_scale_model(self, st) -> None:
        """Prior and process model of the scale-error states S(0..M-1), one per scale segment
        (docs/error_models.md, "Odometer scale in the fusion"). The prior on S(0) (the previous
        chunk's estimate after a chunk seam). The scale a random walk (rw over one segment)
        plus a drift: with ``scale_rate_sigma_ppm_per_h`` set, a rate state D(m) [1/h] per
        segment, S(m+1) - S(m) - D(m) segment / 3600 ~ N(0, rw^2), its prior D(0) ~ N(0,
        rate sigma^2) (the previous chunk's rate after a seam) and its own random walk
        D(m+1) - D(m) ~ N(0, q^2 segment / 3600), q in 1/h/sqrt(h): a steady drift costs nothing.
        The rate is in 1/h (not ppm/h) so that its information is of the scale's order: the
        Bayes tree's marginals keep their digits."""
        n_seg = int(self.seg[-1]) + 1
        rw = st.scale_random_walk_ppm_per_sqrt_h * 1e-6 * np.sqrt(st.scale_segment_s / 3600.0)
        scale0, scale_sigma = np.zeros(1), st.scale_sigma_ppm * 1e-6
        if self.join is not None and self.join.scale is not None:  # the previous chunk's, then one step
            scale0, scale_sigma = np.array([self.join.scale]), np.sqrt(self.join.scale_var + rw**2)
        self.g.add(gtsam.PriorFactorVector(S(0), scale0, gtsam.noiseModel.Isotropic.Sigma(1, scale_sigma)))
        self._count("odometer_scale", n_seg)
        if n_seg < 2:
            return
        if not self.kf.with_rate:  # the scale a random walk
            rw_noise = gtsam.noiseModel.Isotropic.Sigma(1, rw)
            for m in range(n_seg - 1):
                self.g.add(gtsam.BetweenFactorVector(S(m), S(m + 1), np.zeros(1), rw_noise))
            return
        rate_step = st.scale_rate_random_walk_ppm_per_h_per_sqrt_h * 1e-6 * np.sqrt(st.scale_segment_s / 3600.0)
        rate0, rate_sigma = np.zeros(1), st.scale_rate_sigma_ppm_per_h * 1e-6
        if self.join is not None and self.join.rate is not None:  # the previous chunk's, then one step
            rate0, rate_sigma = np.array([self.join.rate]), np.sqrt(self.join.rate_var + rate_step**2)
        self.g.add(gtsam.PriorFactorVector(D(0), rate0, gtsam.noiseModel.Isotropic.Sigma(1, rate_sigma)))
        rate_rw = gtsam.noiseModel.Isotropic.Sigma(1, rate_step)
        for m in range(n_seg - 2):
            self.g.add(gtsam.BetweenFactorVector(D(m), D(m + 1), np.zeros(1), rate_rw))
        self._count("odometer_scale_rate", n_seg - 1)
        m = np.arange(n_seg - 1)
        keys = [S(0) + m, S(0) + m + 1, D(0) + m]
        per_rate = st.scale_segment_s / 3600.0  # scale change per segment of a rate of 1/h
        J = [np.full((m.size, 1, 1), c) for c in (-1.0, 1.0, -per_rate)]
        sigma = np.full((m.size, 1), rw)

        def build(state: _State) -> fx.LinearBlocks:
            r = (state.s[m + 1] - state.s[m] - per_rate * state.d[m])[:, None]
            return fx.LinearBlocks(keys, J, r, sigma)

        self.builders.append(("odometer_scale_drift", build))

    def nhc(self) -> None:
        st, tr, imu = self.pb.factors.nhc, self.pb.trolley, self.pb.imu
        K = self.t.size
        i1 = np.minimum(self.idx + 1, imu.t_s.size - 1)
        w_ib_b = 0.5 * (imu.gyro_radps[self.idx] + imu.gyro_radps[i1])  # centred on the keyframe
        omega_ie_n = geodesy.earth_rate_n(self.pb.origin)
        lever = tr.nhc_lever_arm_b
        keys_x, keys_v = X(0) + np.arange(K), V(0) + np.arange(K)
        sigma = np.tile(st.sigmas_mps(), (K, 1))  # (lateral, vertical) rows

        def build(state: _State) -> fx.LinearBlocks:
            w_nb_b = w_ib_b - np.einsum("kji,j->ki", state.R, omega_ie_n)
            r, d_theta, d_vel = fx.nhc_residual(state.R, state.v, w_nb_b, lever, tr.R_vb)
            d_pose = np.concatenate([d_theta, np.zeros_like(d_theta)], axis=2)
            return fx.LinearBlocks([keys_x, keys_v], [d_pose, d_vel], r, sigma)

        self.builders.append(("nhc", build))
        self._count("nhc", K)

    def wheel_path(self, omega_ie_n: np.ndarray) -> None:
        """Rear wheel through the front wheel's points (fusion/wheel_path.py)."""
        K = self.t.size
        front = self.join.wheel_front if self.join is not None else None
        n, build, n_front, build_front = wheel_path_builder(self.pb, self.t, self.idx, self.pos0, X(0) + np.arange(K),
                                                            V(0) + np.arange(K), omega_ie_n, front)
        self.builders.append(("wheel_path", build))
        self._count("wheel_path", n)
        if n_front:  # pairs whose front wheel point the previous chunk holds (fusion/chunks.py)
            self.builders.append((HAND_OVER_BUILDER, build_front))
            self._count(HAND_OVER_BUILDER, n_front)

    def inclinometer(self) -> None:
        inc, st = self.pb.inclinometer, self.pb.factors.inclinometer
        inside = np.flatnonzero((self.t >= inc.t_s[0]) & (self.t <= inc.t_s[-1]))
        roll = np.interp(self.t[inside], inc.t_s, inc.roll_rad)
        pitch = np.interp(self.t[inside], inc.t_s, inc.pitch_rad)
        up_b = fx.up_vector_from_roll_pitch(roll, pitch) @ self.pb.trolley.R_vb  # R_vb^T up_v
        g_n = geodesy.gravity_n(self.pos0[inside], self.pb.origin)
        up_n = -g_n / np.linalg.norm(g_n, axis=1, keepdims=True)
        keys = X(0) + inside
        sigma = np.full((inside.size, 2), st.sigma_mrad * 1e-3)

        def build(state: _State) -> fx.LinearBlocks:
            r, d_theta = fx.inclinometer_residual(state.R[inside], up_n, up_b)
            return fx.LinearBlocks([keys], [np.concatenate([d_theta, np.zeros_like(d_theta)], axis=2)], r, sigma)

        self.builders.append(("inclinometer", build))
        self._count("inclinometer", inside.size)


# --- solving ------------------------------------------------------------------------------------------

def _total_cost(G: _Graph, values: gtsam.Values, with_scale: bool, state: "_State | None" = None,
                blocks: list | None = None) -> float:
    """Cost at ``values`` (``state``: the same estimate as arrays, when already extracted). With
    ``blocks`` (a list), the vectorised factors' :class:`~.factors.LinearBlocks` at ``values``
    are appended to it (one per builder, for :func:`_linearize` at the same estimate)."""
    state = state or _State.of(values, with_scale)
    built = [build(state) for _, build in G.builders]
    if blocks is not None:
        blocks.extend(built)
    return G.graph.error(values) + sum(b.cost() for b in built)


def cost_breakdown(G: _Graph, values: gtsam.Values, with_scale: bool) -> dict[str, float]:
    """Cost (0.5 sum of squared whitened residuals) per factor type at ``values``."""
    out: dict[str, float] = {}
    for i in range(G.graph.size()):
        f = G.graph.at(i)
        if f is not None:
            name = type(f).__name__
            out[name] = out.get(name, 0.0) + f.error(values)
    state = _State.of(values, with_scale)
    for name, build in G.builders:
        out[name] = build(state).cost()
    return out


def _linearize(G: _Graph, values: gtsam.Values, with_scale: bool, state: "_State | None" = None,
               blocks: list | None = None) -> gtsam.GaussianFactorGraph:
    """The graph linearised at ``values``; ``blocks``: the vectorised factors' blocks at ``values``
    when already built (:func:`_total_cost`), else built here."""
    gfg = G.graph.linearize(values)
    if blocks is None:
        state = state or _State.of(values, with_scale)
        blocks = [build(state) for _, build in G.builders]
    for b in blocks:
        fx.to_jacobian_factors(b, gfg)
    return gfg


def _eliminate(gfg: gtsam.GaussianFactorGraph, ordering: gtsam.Ordering | None = None) -> gtsam.GaussianBayesTree:
    """Multifrontal QR elimination in ``ordering`` (default: COLAMD's for this graph; the
    iterations of one solve share one, as their graphs have the same structure).

    QR, not Cholesky: the whitened Jacobian spans seven orders of magnitude (navigation-grade
    gyro noise over 0.1 s against a loose NHC or GNSS), which the normal equations square past
    double precision; GTSAM's Cholesky then reports an indeterminate system on data that is
    perfectly determined (measured on the open-track scenario with ``nhc.sigma_mm_per_s: 30``).
    """
    try:
        return gfg.eliminateMultifrontal(ordering or gtsam.Ordering.ColamdGaussianFactorGraph(gfg), gtsam.EliminateQR)
    except RuntimeError as exc:
        lines = str(exc).splitlines()
        near = [i for i, ln in enumerate(lines) if "near variable" in ln]
        first = lines[near[0] + 1].strip() if near and near[0] + 1 < len(lines) else ""
        raise FusionError("the factor graph is singular (a state no measurement determines"
                          + (f"; {first}" if first else "") + ")") from None


@dataclass
class _Solved:
    """What :func:`gauss_newton` returns: the estimate (``values``, and ``state``: the same as
    arrays), the iterations, the initial and final cost, and the last linearisation ``gfg``
    (at ``values``, or one converged step before them) and its Bayes tree, which the marginals
    reuse instead of linearising once more (:func:`_sigma_covariances`)."""

    values: gtsam.Values
    state: _State
    iterations: int
    initial_cost: float
    cost: float
    tree: gtsam.GaussianBayesTree
    ordering: gtsam.Ordering | None = None
    history: StepHistory = field(default_factory=StepHistory)  # fusion/convergence.py
    gfg: gtsam.GaussianFactorGraph | None = None
    early: bool = False  # stopped at the gate's tolerance (StopRule.gate_step_tol_m), not the rule's own


@dataclass(frozen=True)
class StopRule:
    """When :func:`gauss_newton` stops: after ``max_iterations``, when the cost falls by less than
    ``rtol`` (relative), or when the predicted remaining correction is below ``step_tol_m`` [m]
    (0: off; fusion/convergence.py). ``gating``: a gating round's, whose estimate only decides the
    gate and the noise estimate, the next round or the last one's convergence (:func:`_solve_in_rounds`)
    going on from it: the first two steps' ratio already predicts the correction to come.
    ``gate_step_tol_m`` [m] (0: none): a gating round may stop earlier, once the correction still
    to come is below it, for its gate (:func:`_solve_in_rounds` carries the steps on to
    ``step_tol_m`` when the gate rejects nothing); the solve is then ``early``."""

    max_iterations: int
    rtol: float
    step_tol_m: float = 0.0
    gating: bool = False
    gate_step_tol_m: float = 0.0


@dataclass(frozen=True)
class _Start:
    """How a solve without a ``previous`` one starts (:func:`gauss_newton`): ``warm``: its values
    are the converged estimate of this graph with other noise weights (fusion/convergence.py);
    ``ordering``: the elimination order of a graph of this one's structure (COLAMD's otherwise);
    ``first_in_parts``: the first step solved in these parts on their workers (the same step to
    rounding; the first round's, in the sigma parts: a cold start takes a second step, whose
    tree the gate reads, unless the first already converged, when the gate reads the parts'
    marginals as with ``smoother.part_s``)."""

    warm: bool = False
    ordering: gtsam.Ordering | None = None
    first_in_parts: "Partition | None" = None


def gauss_newton(G: _Graph, values: gtsam.Values, with_scale: bool, stop: StopRule, say: Callable[[str], None],
                 previous: _Solved | None = None, partition: "Partition | None" = None,
                 start: _Start = _Start()) -> _Solved:
    """Gauss-Newton with step halving (see :class:`_Solved`), until ``stop`` (:class:`StopRule`).
    ``previous``: the solve of the same graph that ended at ``values``
    (e.g. a gating round whose gate rejected nothing): its ordering and step history carry on,
    and when its steps have converged already its tree is returned without a new iteration.
    ``partition``: each step solved in time parts (fusion/partitioned.py: the same step; the
    returned ``tree`` is then its :class:`~.partitioned.PartMarginals`). ``start``: :class:`_Start`."""
    state = previous.state if previous is not None else _State.of(values, with_scale)
    blocks = None if previous is not None else []  # the vectorised factors' blocks at ``values``
    cost = cost0 = previous.cost if previous is not None else _total_cost(G, values, with_scale, state, blocks)
    it = 0
    tree, ordering = (previous.tree, previous.ordering) if previous is not None else (None, start.ordering)
    gfg = previous.gfg if previous is not None else None
    history = previous.history.copy() if previous is not None else StepHistory(warm=start.warm)
    if history.converged(stop.step_tol_m):
        return _Solved(values, state, 0, cost0, cost, tree, ordering, history, gfg)
    solver = PartitionedSolver(partition, partition.workers) if partition is not None else None
    early = False
    for it in range(1, stop.max_iterations + 1):
        gfg = _linearize(G, values, with_scale, state, blocks)
        blocks = None
        if solver is not None:
            delta, tree = solver.solve(gfg)
        elif it == 1 and start.first_in_parts is not None:
            delta, tree = PartitionedSolver(start.first_in_parts, start.first_in_parts.workers).solve(gfg)
        else:
            ordering = ordering or gtsam.Ordering.ColamdGaussianFactorGraph(gfg)
            tree = _eliminate(gfg, ordering)
            delta = tree.optimize()
        step, new_cost = 1.0, np.inf
        while step > 1e-3:
            new = values.retract(delta if step == 1.0 else delta.scale(step))
            new_state = _State.of(new, with_scale)
            new_blocks: list = []
            new_cost = _total_cost(G, new, with_scale, new_state, new_blocks)
            if new_cost <= cost:
                break
            step *= 0.5
        if not new_cost <= cost:
            break
        decrease = (cost - new_cost) / max(cost, 1e-300)
        if step < 1.0:  # a damped step says nothing about the rate of convergence
            history = StepHistory()
        history.add(state.p, new_state.p)
        values, cost, state, blocks = new, new_cost, new_state, new_blocks
        say(f"  iteration {it}: cost {cost:.6g} (step {step:g})")
        if decrease < stop.rtol or history.converged(stop.step_tol_m, stop.gating):
            break
        early = stop.gate_step_tol_m > stop.step_tol_m and history.converged(stop.gate_step_tol_m, stop.gating)
        if early:
            break
    return _Solved(values, state, it, cost0, cost, tree, ordering, history, gfg, early)


def white_covariance(cov_n: np.ndarray, correlated_sigma_m: np.ndarray, min_sigma_m: float) -> np.ndarray:
    """The white part (K,3,3) of reported fix covariances (K,3,3) [m^2]: minus the correlated
    error's variance (diagonal, per axis), with every eigenvalue at least ``min_sigma_m^2``."""
    white = cov_n - np.diag(correlated_sigma_m**2)
    lam, vec = np.linalg.eigh(white)
    lam = np.maximum(lam, min_sigma_m**2)
    return vec @ (lam[:, :, None] * np.swapaxes(vec, -1, -2))


def _sigma_keyframes(t_key: np.ndarray, step_s: float) -> np.ndarray:
    """Indices of the keyframes about ``step_s`` apart (and the last one) that carry the sigmas."""
    return np.unique(np.r_[nearest_sample(t_key, np.arange(t_key[0], t_key[-1], step_s)), t_key.size - 1])


def _marginal_sigmas(covs: dict[int, np.ndarray], state: _State, t_key: np.ndarray, sel: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position and attitude sigmas at keyframes ``sel`` from the pose marginal covariances ``covs``
    (key -> (6,6) in the body frame: attitude, position)."""
    sig_pos = np.empty((sel.size, 3))
    sig_att = np.empty((sel.size, 3))
    for i, k in enumerate(sel):
        cov = covs[X(int(k))]
        R = state.R[k]
        sig_pos[i] = np.sqrt(np.diag(R @ cov[3:, 3:] @ R.T))
        att_n = R @ cov[:3, :3] @ R.T
        sig_att[i] = np.sqrt([cov[0, 0], cov[1, 1], att_n[2, 2]])
    return t_key[sel], sig_pos, sig_att


@dataclass
class _SoftJoin:
    """For the marginals of a chunk after the first: the tight hand-over priors (graph indices)
    and the wheel-path pairs whose front point the previous chunk holds (as exact) give way to
    one joint prior of the previous chunk's marginal covariance (keys, cov)."""

    remove: list[int] = field(default_factory=list)
    keys: list[int] = field(default_factory=list)
    cov: np.ndarray | None = None

    def copy(self) -> "_SoftJoin":
        return _SoftJoin(list(self.remove), list(self.keys), self.cov)


def _marginal_graph(G: _Graph, values: gtsam.Values, with_scale: bool, soft: _SoftJoin) -> gtsam.GaussianFactorGraph:
    """The linearised graph for the marginals (with the soft hand-over prior, see :class:`_SoftJoin`)."""
    if not soft.keys:
        return _linearize(G, values, with_scale)
    graph = gtsam.NonlinearFactorGraph(G.graph)
    for i in soft.remove:
        graph.remove(i)
    builders = [(name, build) for name, build in G.builders if name != HAND_OVER_BUILDER]
    gfg = _linearize(_Graph(graph, builders, G.counts, G.gnss), values, with_scale)
    A = np.linalg.cholesky(np.linalg.inv(soft.cov)).T  # A^T A = information; b: zero at the estimate
    d = np.cumsum([0, 6, 3, 3][:len(soft.keys) + 1])
    blocks = [item for j, key in enumerate(soft.keys) for item in (key, A[:, d[j]:d[j + 1]])]
    gfg.add(gtsam.JacobianFactor(*blocks, np.zeros(A.shape[0]), gtsam.noiseModel.Unit.Create(A.shape[0])))
    return gfg


def _past_graph(gfg: gtsam.GaussianFactorGraph, k: int, kf: _Keyframes,
                gnss_t_s: np.ndarray | None) -> gtsam.GaussianFactorGraph:
    """The factors of ``gfg`` that involve only states up to keyframe ``k`` (the data before it)."""
    t_key, bias_seg, seg = kf.t_s, kf.bias_seg, kf.scale_seg
    last = {ord("x"): k, ord("v"): k, ord("b"): int(bias_seg[k]), ord("s"): int(seg[k]) if seg is not None else -1,
            ord("d"): int(seg[k]) - 1 if seg is not None else -1}
    past = gtsam.GaussianFactorGraph()
    for i in range(gfg.size()):
        f = gfg.at(i)
        if f is None:
            continue
        ok = True
        for key in f.keys():
            sym = gtsam.Symbol(key)
            c, n = sym.chr(), sym.index()
            if (c == ord("e") and gnss_t_s[n] > t_key[k] + 1e-9) or (c != ord("e") and n > last[c]):
                ok = False
                break
        if ok:
            past.push_back(f)
    return past


def _hand_over(gfg: gtsam.GaussianFactorGraph, values: gtsam.Values, kf: _Keyframes, k: int, gnss,
               used: np.ndarray) -> HandOver:
    """The state at keyframe ``k`` and its marginal covariances (see :class:`HandOver`); ``gnss``
    the fixes (None: GNSS off) of which ``used`` were used."""
    with_scale, t_key, bias_seg, seg = kf.with_scale, kf.t_s, kf.bias_seg, kf.scale_seg
    state = _State.of(values, with_scale)
    bias = values.atConstantBias(B(int(bias_seg[k]))).vector()
    keys = [X(k), V(k)]
    e_t = e = None
    if gnss is not None and used.size:
        earlier = used[gnss.t_s[used] <= t_key[k] + 1e-9]
        if earlier.size and values.exists(E(int(earlier[-1]))):
            i = int(earlier[-1])
            e_t, e = float(gnss.t_s[i]), values.atVector(E(i)).copy()
            keys.append(E(i))
    d = 3 * len(keys) + 3  # pose, velocity (, GNSS error)
    keys.append(B(int(bias_seg[k])))
    if with_scale:
        keys.append(S(int(seg[k])))
    rate_m = int(seg[k]) - 1 if kf.with_rate and seg[k] >= 1 else None  # the last step's rate up to k
    if rate_m is not None:
        keys.append(D(rate_m))
    past = _past_graph(gfg, k, kf, gnss.t_s if gnss is not None else None)
    cov = joint_marginal_covariance(past, keys)
    var = np.diag(cov)
    rate = (float(state.d[rate_m]), float(var[d + 7])) if rate_m is not None else (None, None)
    front = (t_key >= t_key[k] - WHEEL_FRONT_S) & (np.arange(t_key.size) < k)
    return HandOver(k, float(t_key[k]), state.R[k].copy(), state.p[k].copy(), state.v[k].copy(), bias,
                    float(state.s[seg[k]]) if with_scale else None, e_t, e, cov[:d, :d], var[d:d + 6],
                    float(var[d + 6]) if with_scale else None,
                    WheelFront(t_key[front].copy(), state.R[front].copy(), state.p[front].copy()),
                    rate=rate[0], rate_var=rate[1])


@dataclass
class Preintegrated:
    """The IMU preintegrated between a problem's keyframes (:func:`preintegrate_problem`):
    keyframe sample indices ``key_idx`` (K,), K-1 ``pims`` and their ``params``
    (:func:`~.preintegration.preintegrate`), and the wall time it took ``wall_s`` [s]."""

    key_idx: np.ndarray
    pims: list
    params: list
    wall_s: float


def _keyframes(problem: FusionProblem) -> np.ndarray:
    """The keyframes' IMU sample indices of :func:`smooth` (K,): the grid, and the GNSS fixes' times."""
    gnss = problem.gnss if problem.factors.gnss.enabled else None
    return keyframe_indices(problem.imu.t_s, problem.keyframes.spacing_s, gnss.t_s if gnss is not None else None)


def preintegrate_problem(problem: FusionProblem) -> Preintegrated:
    """The IMU of ``problem`` preintegrated between the keyframes :func:`smooth` makes (gravity
    at the origin; the smoother sets each interval's once it has positions)."""
    tic = time.perf_counter()
    key_idx = _keyframes(problem)
    omega_ie_n = geodesy.earth_rate_n(problem.origin) if problem.factors.imu.earth_rate else np.zeros(3)
    gravity0 = geodesy.gravity_n(np.zeros((key_idx.size, 3)), problem.origin)
    pims, params = preintegrate(problem.imu, key_idx, problem.imu_noise, gravity0, omega_ie_n)
    return Preintegrated(key_idx, pims, params, time.perf_counter() - tic)


def smooth(problem: FusionProblem, progress: Callable[[str], None] | None = None, join: HandOver | None = None,
           hand_over_t_s: float | None = None,
           preintegrated: "Preintegrated | None" = None) -> SmootherResult:
    """Smooth a whole run (see module docstring). Raises :class:`FusionError` when the data
    cannot determine a trajectory.

    For overlapping chunks (fusion/chunks.py): ``join`` is the previous chunk's state at this
    chunk's first sample (replaces the alignment and the anchor); with ``hand_over_t_s`` the
    result carries the state at the keyframe nearest to that time (``SmootherResult.hand_over``).
    ``preintegrated``: this problem's :func:`preintegrate_problem`, done beforehand (the pipeline
    does it while the total stations are prepared in a forked child); its ``wall_s`` counts in
    ``timings_s["preintegrate_s"]``.
    """
    say = progress or (lambda _m: None)
    timings: dict[str, float] = {}
    tic = time.perf_counter()
    problem = _with_handed_over(problem, join)
    imu, fs = problem.imu, problem.factors
    if imu.t_s.size < 10:
        raise FusionError("the IMU log holds fewer than 10 samples")
    gnss = problem.gnss if fs.gnss.enabled else None
    kf = _keyframe_layout(problem, _keyframes(problem))
    init_problem = _with_prism_fixes(problem) if gnss is None and problem.prisms is not None else problem
    alignment = join.alignment if join is not None else _alignment(init_problem)
    omega_ie_n = geodesy.earth_rate_n(problem.origin) if fs.imu.earth_rate else np.zeros(3)
    preintegrated, given = _preintegration(problem, kf.idx, preintegrated, say)
    timings["preintegrate_s"] = time.perf_counter() - tic + (preintegrated.wall_s if given else 0.0)

    tic = time.perf_counter()
    initial = _initial_estimate(problem, init_problem, kf, preintegrated, alignment, join, omega_ie_n)
    b = _Builder(problem, kf, preintegrated.pims, initial, alignment)
    b.join = join
    values = _initial_values(kf, initial, join)
    gates = _Gates.start(problem, kf.t_s)
    _add_base_factors(b, gates.gnss is not None or gates.prisms is not None, omega_ie_n)
    timings["build_s"] = time.perf_counter() - tic

    tic = time.perf_counter()
    partition = _partition(problem, kf)
    sigma_parts = _sigma_parts(problem, kf, partition, join, hand_over_t_s)
    components = _noise_components(problem, join.noise_applied if join is not None else None)
    rounds = _solve_in_rounds(problem, b, values, gates, partition, components, say, sigma_parts)
    # estimated in one batch or a run's first chunk; the later chunks take the first's
    time_constant = _time_constant(problem, rounds, gates, say) if join is None else None
    if time_constant is not None and time_constant.applies:  # solved again with the estimate
        return _solved_again(problem, time_constant, progress, hand_over_t_s, preintegrated, time.perf_counter() - tic)
    timings["solve_s"] = time.perf_counter() - tic
    noise = gates.final_noise(say)
    components_json = _components_json(components, fs, say)
    sol = rounds.sol
    state = sol.state  # the last solve's (a gate after it only erases GNSS error states: R, p, v, s, ts hold)
    biases = np.array([sol.values.atConstantBias(B(m)).vector()
                       for m in range(int(kf.bias_seg[-1]) + 1)])[kf.bias_seg]

    tic = time.perf_counter()
    (sig_t, sig_pos, sig_att), hand_over, station_cov = _marginals(problem, rounds, b.soft, partition, kf,
                                                                   hand_over_t_s, gates, sigma_parts)
    hand_over = _handed_on(hand_over, fs, components)
    timings["marginals_s"] = time.perf_counter() - tic
    scale = state.s[kf.scale_seg] if kf.with_scale else None
    return SmootherResult(kf.t_s, kf.idx, state.R, state.p, state.v, biases[:, 3:], biases[:, :3], scale,
                          sig_t, sig_pos, sig_att, alignment, rounds.iterations, float(rounds.initial_cost),
                          float(sol.cost), dict(b.counts), sorted(gates.rejected, key=lambda r: r["t_s"]), timings,
                          station_states=None if gates.prisms is None else state.ts,
                          station_cov=station_cov,
                          rejected_prism=sorted(gates.rejected_prism, key=lambda r: (r["t_s"], r["station"])),
                          hand_over=hand_over, gnss_noise=noise, noise_components=components_json,
                          gnss_time_constant=time_constant.to_json() if time_constant is not None else None)


def _time_constant(problem: FusionProblem, rounds: _Rounds, gates: "_Gates",
                   say: Callable[[str], None]) -> "gtc.TimeConstantEstimate | None":
    """The GNSS correlated error's time constant from the solve ``rounds`` when
    ``factors.gnss.estimate_time_constant`` (fusion/gnss_time_constant.py); None when off, without
    GNSS or its correlated model."""
    st = problem.factors.gnss
    if not (st.enabled and st.estimate_time_constant) or gates.gnss is None or not gates.used.size:
        return None
    est = gtc.estimate(rounds.G.graph, rounds.sol.values, rounds.G.builders, rounds.sol.state,
                       st.correlation_time_s, problem.gnss.t_s[gates.used], say, _white_ratio(gates))
    if est is not None:
        say(est.summary())
    return est


def _white_ratio(gates: "_Gates") -> np.ndarray | None:
    """The GNSS white variance factors estimated over those the last solve used, per ENU axis (3,)
    [-]; None without an estimate."""
    if gates.noise is None:
        return None
    return gnss_noise.per_enu_axis(gates.noise.factor) / gnss_noise.per_enu_axis(gates.solved_factor)


def _solved_again(problem: FusionProblem, time_constant: "gtc.TimeConstantEstimate",
                  progress: Callable[[str], None] | None, hand_over_t_s: float | None,
                  preintegrated: "Preintegrated", first_s: float) -> SmootherResult:
    """:func:`smooth` again with the estimated GNSS time constant, the first solve and the
    estimate (``first_s`` [s]) counted in its solve time, the estimate reported."""
    again = smooth(_with_time_constant(problem, time_constant.estimate_s), progress,
                   hand_over_t_s=hand_over_t_s, preintegrated=preintegrated)
    again.timings_s["solve_s"] += first_s
    return replace(again, gnss_time_constant=time_constant.to_json())


def _with_handed_over(problem: FusionProblem, join: HandOver | None) -> FusionProblem:
    """A later chunk's ``problem`` with the GNSS time constant the first chunk solved with."""
    if join is None or join.gnss_time_constant_s is None:
        return problem
    return _with_time_constant(problem, join.gnss_time_constant_s)


def _handed_on(hand_over: HandOver | None, fs, components: "nc.NoiseComponents | None") -> HandOver | None:
    """``hand_over`` with what the next chunk solves with too: the GNSS time constant of the
    factor settings ``fs`` and the groups' noise factors ``components`` applied."""
    if hand_over is None:
        return None
    return replace(hand_over, gnss_time_constant_s=fs.gnss.correlation_time_s,
                   noise_applied=None if components is None else {g: dict(c) for g, c in components.applied.items()})


def _with_time_constant(problem: FusionProblem, tau_s: float) -> FusionProblem:
    """``problem`` with the GNSS correlated time constant ``tau_s`` [s], not to be estimated again."""
    gnss = problem.factors.gnss.model_copy(update={"correlation_time_s": tau_s, "estimate_time_constant": False})
    return replace(problem, factors=problem.factors.model_copy(update={"gnss": gnss}))


def _preintegration(problem: FusionProblem, key_idx: np.ndarray, preintegrated: "Preintegrated | None",
                    say: Callable[[str], None]) -> tuple["Preintegrated", bool]:
    """The IMU preintegrated between the keyframes ``key_idx`` (K,): ``preintegrated`` when given
    (checked to be of these keyframes), else done here; and whether it was given."""
    given = preintegrated is not None
    if not given:
        say(f"preintegrating {problem.imu.t_s.size} IMU samples into {key_idx.size - 1} intervals")
        preintegrated = preintegrate_problem(problem)
    elif not np.array_equal(preintegrated.key_idx, key_idx):
        raise ValueError("smooth: the given preintegration is of other keyframes")
    return preintegrated, given


def _initial_estimate(problem: FusionProblem, init_problem: FusionProblem, kf: _Keyframes,
                      preintegrated: "Preintegrated", alignment: Alignment, join: HandOver | None,
                      omega_ie_n: np.ndarray) -> _Initial:
    """The initial estimate at the keyframes: attitudes chained through the preintegrated
    rotations from the alignment (or the hand-over ``join``), positions and velocities from
    :func:`initial_states` on ``init_problem`` (the problem with its prism readings as fixes when
    it has no GNSS). With ``factors.imu.gravity_per_position``, sets each interval's gravity in
    the preintegration's parameters at these positions. omega_ie_n (3,) [rad/s]."""
    gnss = problem.gnss if problem.factors.gnss.enabled else None
    pims, params, t_key = preintegrated.pims, preintegrated.params, kf.t_s
    R0 = _chain_rotations(join.R_nb if join is not None else alignment.R_nb, pims, np.diff(t_key), omega_ie_n)
    if alignment.epoch == "end":  # aligned on the static period at the end: chain back to the start
        R0 = _chain_rotations(back_to_start(R0, alignment.R_nb, omega_ie_n, t_key[-1] - t_key[0]), pims,
                              np.diff(t_key), omega_ie_n)
    pos0, vel0 = initial_states(init_problem if gnss is not None or problem.prisms is not None
                                else _without_gnss(problem), t_key, R0, kf.static,
                                PRISM_INIT_MEDIAN if gnss is None and problem.prisms is not None else 0)
    if join is not None and gnss is None and problem.prisms is None:
        pos0 += join.pos_n - pos0[0]
    if problem.factors.imu.gravity_per_position:
        # the parameters are shared with the preintegrated measurements: set each interval's gravity
        g_n = geodesy.gravity_n(pos0, problem.origin)
        for k, p in enumerate(params):
            p.n_gravity = g_n[k]
    return _Initial(R0, pos0, vel0)


def _initial_values(kf: _Keyframes, initial: _Initial, join: HandOver | None) -> gtsam.Values:
    """The initial estimate as GTSAM values: poses, velocities, zero biases and scale errors; the
    first keyframe's at the hand-over ``join`` (if any)."""
    values = gtsam.Values()
    for k in range(kf.t_s.size):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(initial.R_nb[k]), initial.pos_n[k]))
        values.insert(V(k), initial.vel_n[k])
    for m in range(int(kf.bias_seg[-1]) + 1):
        values.insert(B(m), gtsam.imuBias.ConstantBias())
    if kf.with_scale:
        for m in range(int(kf.scale_seg[-1]) + 1):
            values.insert(S(m), np.zeros(1))
        if kf.with_rate:
            for m in range(int(kf.scale_seg[-1])):
                values.insert(D(m), np.zeros(1))
    if join is not None:
        values.update(X(0), gtsam.Pose3(gtsam.Rot3(join.R_nb), join.pos_n))
        values.update(V(0), join.vel_n)
        values.update(B(0), gtsam.imuBias.ConstantBias(join.bias[:3], join.bias[3:]))
        if kf.with_scale and join.scale is not None:
            values.update(S(0), np.array([join.scale]))
        if kf.with_rate and join.rate is not None:
            values.update(D(0), np.array([join.rate]))
    return values


def _add_base_factors(b: _Builder, absolute: bool, omega_ie_n: np.ndarray) -> None:
    """Every factor but the gated ones (GNSS, prisms): IMU, the first keyframe's anchor (with
    ``absolute``: GNSS or prisms fix yaw and position) or hand-over priors, and each switched-on
    factor the problem has the data for. omega_ie_n (3,) [rad/s]."""
    problem, fs = b.pb, b.pb.factors
    b.imu()
    if b.join is not None:
        b.join_priors()
    else:
        b.anchor(absolute=absolute)
    if fs.zupt.enabled:
        b.zupt()
    if fs.nhc.enabled:
        b.nhc()
    if b.kf.with_scale:
        b.odometer()
    if fs.wheel_path.enabled and problem.odometer is not None:
        b.wheel_path(omega_ie_n)
    if problem.inclinometer is not None and fs.inclinometer.enabled:
        b.inclinometer()


@dataclass
class _Gates:
    """What the gating rounds of :func:`smooth` carry from one round to the next: the GNSS fixes
    ``gnss`` (None: GNSS off), the indices ``used`` of those used and the rejected ones; the prism
    readings ``prisms`` (None: no total stations), the indices ``prism_used`` of those used and the
    rejected ones; the GNSS white-noise variance factors applied (horizontal, vertical;
    fusion/gnss_noise.py), the round's solve's ``solved_factor``, and their estimate ``noise``."""

    gnss: GnssFixes | None
    used: np.ndarray
    rejected: list[dict]
    prisms: "PrismReadings | None"
    prism_used: np.ndarray | None
    rejected_prism: list[dict]
    white_factor: np.ndarray = field(default_factory=lambda: np.ones(2))
    solved_factor: np.ndarray | None = None
    noise: "gnss_noise.GnssNoiseEstimate | None" = None

    @classmethod
    def start(cls, problem: FusionProblem, t_key: np.ndarray) -> "_Gates":
        """Before the first round: the fixes within the keyframes (t_key (K,) [s]) of an accepted
        quality; the prism readings not flagged as mis-locks."""
        fs = problem.factors
        gnss = problem.gnss if fs.gnss.enabled else None
        prisms = problem.prisms if fs.total_stations.enabled else None
        used = np.zeros(0, np.int64)
        if gnss is not None:
            ok = (gnss.t_s >= t_key[0]) & (gnss.t_s <= t_key[-1])
            if not fs.gnss.accept_float:
                ok &= gnss.fix_quality != 5
            used = np.flatnonzero(ok)
        # readings the step check flagged as mis-locks before the fusion are rejected from the start
        prism_used, rejected_prism = prefused_rejections(prisms) if prisms is not None else (None, [])
        return cls(gnss, used, [], prisms, prism_used, rejected_prism)

    @property
    def gating(self) -> bool:
        return self.gnss is not None or self.prisms is not None

    def labels(self) -> dict[str, np.ndarray]:
        return _component_labels(self.prisms, self.prism_used)

    def gate(self, prism_build, gnss_build, sol: "_Solved", b: _Builder, values: gtsam.Values) -> tuple[bool, bool]:
        """Gate the prism readings (mis-lock runs) and GNSS fixes at the solve ``sol``, with the
        builders of their factors (None: none); rejected fixes lose their error state in
        ``values``. Whether any was rejected, and whether the GNSS white noise needs a refit."""
        fs = b.pb.factors
        rejected = refit = False
        if prism_build is not None:  # total stations: gate, mis-lock runs
            self.prism_used, newly = gate_prisms(prism_build(sol.state), self.prism_used, self.prisms,
                                                 fs.total_stations)
            self.rejected_prism += newly
            rejected = bool(newly)
        if gnss_build is not None:
            gnss_rejected, refit = self._gate_gnss(gnss_build(sol.state), sol, b.gnss_white(self.used), values, fs.gnss)
            rejected |= gnss_rejected
        return rejected, refit

    def _gate_gnss(self, blocks: fx.LinearBlocks, sol: "_Solved", white: np.ndarray, values: gtsam.Values,
                   st) -> tuple[bool, bool]:
        """The GNSS gate on the position factors' ``blocks`` at ``sol``, the used fixes' stated white
        covariances ``white`` (F,3,3) [m^2] and the settings ``st`` (``factors.gnss``); with
        ``estimate_white_noise``, on the noise the residuals show. Whether a fix was rejected, and
        whether the white noise's factor moved (a refit)."""
        refit = False
        if st.estimate_white_noise:
            self.noise = gnss_noise.estimate_white_noise(blocks, white, self.white_factor, sol.tree,
                                                         st.gate_chi2, st.min_sigma_mm * 1e-3) or self.noise
            if self.noise is not None and gnss_noise.needs_refit(self.white_factor, self.noise.applied):
                self.white_factor, refit = self.noise.applied, True
        nis = gnss_noise.nis(blocks.residual, gnss_noise.scaled_white(white, self.white_factor))
        bad = nis > st.gate_chi2
        for i, q in zip(self.used[bad], nis[bad]):
            self.rejected.append({"t_s": float(self.gnss.t_s[i]), "index": int(i), "nis": float(q)})
            if values.exists(E(int(i))):
                values.erase(E(int(i)))
        self.used = self.used[~bad]
        return bool(np.any(bad)), refit

    def final_noise(self, say: Callable[[str], None]) -> "gnss_noise.GnssNoiseEstimate | None":
        """The GNSS white-noise estimate with the factor of the last solve (a refit the rounds ran
        out for is not applied), said; None when not estimated."""
        if self.noise is None:
            return None
        noise = replace(self.noise, applied=self.solved_factor)
        say(noise.summary())
        return noise


@dataclass
class _Rounds:
    """What :func:`_solve_in_rounds` returns: the last solve ``sol`` and its graph ``G``, the
    iterations of every round, and the first round's initial cost."""

    sol: "_Solved"
    G: _Graph
    iterations: int
    initial_cost: float


def _round_graph(b: _Builder, base: tuple, values: gtsam.Values, gates: _Gates,
                 components: "nc.NoiseComponents | None") -> tuple[_Graph, Callable | None, Callable | None]:
    """One gating round's graph: the base factors (``b.snapshot()``), the used GNSS fixes' and
    prism readings' factors (their states inserted into ``values``), the estimated groups' noise.
    Returns the graph and the builders of the GNSS and prism factors (None: none)."""
    b.restart(base)
    gates.solved_factor = gates.white_factor  # what this round's solve uses
    error_factor = components.applied_per_row("gnss_error") if components is not None else None
    gnss_build = (b.gnss(gates.used, values, gates.white_factor, error_factor)
                  if gates.gnss is not None and gates.used.size else None)
    prism_build = b.prisms(gates.prism_used, values) if gates.prisms is not None else None
    if components is not None:  # the groups' estimated noise (fusion/noise_components.py)
        b.builders = components.wrap(b.builders, gates.labels())
        prism_build = dict(b.builders).get("prism", prism_build)
    return _Graph(b.g, b.builders, b.counts, gnss_build), gnss_build, prism_build


def _solve_in_rounds(problem: FusionProblem, b: _Builder, values: gtsam.Values, gates: _Gates,
                     partition: Partition | None, components: "nc.NoiseComponents | None",
                     say: Callable[[str], None], sigma_parts: Partition | None = None) -> _Rounds:
    """Solve, gate the GNSS fixes and prism readings (``gates``) and estimate the noise
    ``components``, and again, until a round rejects nothing (at most 4 rounds, and the noise
    refits); that round then converges to the configured tolerance, in the parts ``sigma_parts``
    when given (:func:`_sigma_parts`: the same step; its reductions then serve the sigmas)."""
    base = b.snapshot()
    sm = problem.smoother
    stop = StopRule(sm.max_iterations, sm.relative_tolerance, sm.step_tolerance_mm * 1e-3)  # step: m; 0: off
    # a gating round need not converge to the last digit before its gate: the tolerance is
    # tightened once the gate rejects nothing more (below)
    round_stop = replace(stop, rtol=max(stop.rtol, GATE_RELATIVE_TOLERANCE), gating=True,
                         gate_step_tol_m=_gate_step_tolerance_m(problem, gates)) if gates.gating else stop
    iterations, cost0, reweighted = 0, None, False
    for round_ in range(4 + (nc.MAX_REFITS if components is not None else 0)):
        G, gnss_build, prism_build = _round_graph(b, base, values, gates, components)
        say(f"solving: {b.t.size} keyframes, {sum(b.counts.values())} factors"
            + (f" (gating round {round_ + 1})" if gates.gating else ""))
        # a round that only reweights the last one's graph starts at its solution: one step
        # moves it to the new weights' (the next one is ~1e-5 of it: docs/solver_speed.md)
        this_stop = replace(round_stop, max_iterations=1, gate_step_tol_m=0.0) if reweighted else round_stop
        # (a reweighted round's graph has the last one's factors: COLAMD would give its ordering again)
        sol = gauss_newton(G, values, b.kf.with_scale, this_stop, say, partition=partition,
                           start=_Start(reweighted, sol.ordering if reweighted else None,
                                        sigma_parts if round_ == 0 and partition is None else None))
        values, iterations = sol.values, iterations + sol.iterations
        cost0 = sol.initial_cost if cost0 is None else cost0
        rejected, refit = gates.gate(prism_build, gnss_build, sol, b, values)
        if sol.early and not (rejected or refit):  # the noise estimate and the last round need the round's own tolerance
            sol = gauss_newton(G, values, b.kf.with_scale, replace(this_stop, gate_step_tol_m=0.0), say, sol, partition)
            values, iterations = sol.values, iterations + sol.iterations
            rejected, refit = gates.gate(prism_build, gnss_build, sol, b, values)

        def converge(tell: Callable[[str], None], sol: _Solved = sol, G: _Graph = G, values=values) -> _Solved:
            return gauss_newton(G, values, b.kf.with_scale, stop, tell, sol, sigma_parts or partition)
        settled = None
        # the groups' noise from the same solve as the GNSS white noise's (one round for both,
        # as Helmert's estimate takes every component at once); not while readings were rejected
        if components is not None and not components.fixed and not rejected:
            if reweighted and not refit and partition is None and can_fork() \
                    and b.t.size <= ESTIMATE_BESIDE_STEP_MAX_KEYFRAMES:
                more, settled = _estimate_while_converging(components, G, sol, gates.labels(), converge, say)
            else:
                more = _estimate_components(components, G, sol, gates.labels())
            refit |= more
        if not (rejected or refit):
            if gates.gating or reweighted:  # settled: converge to the configured tolerance (the same graph: carry on)
                sol = settled or converge(say)
                iterations += sol.iterations
            break
        reweighted = not rejected
    return _Rounds(sol, G, iterations, cost0)


def _gate_step_tolerance_m(problem: FusionProblem, gates: _Gates) -> float:
    """The correction still to come [m] below which a gating round may apply its GNSS gate:
    :data:`GATE_STEP_SHARE` of the smallest white sigma the gate works with
    (``factors.gnss.min_sigma_mm``), so that no fix's normalised residual moves by more than that
    share of one sigma afterwards; 0 (the round's own tolerance) where prism readings are gated as
    well, whose sigmas are finer. A round whose gate rejects a fix is followed by another one
    from its estimate, so the steps it saves are not taken at all (docs/solver_speed.md)."""
    if gates.gnss is None or gates.prisms is not None:
        return 0.0
    return GATE_STEP_SHARE * problem.factors.gnss.min_sigma_mm * 1e-3


def _components_json(components: "nc.NoiseComponents | None", fs, say: Callable[[str], None]) -> dict | None:
    """The estimated groups' noise for metrics.json (fusion/noise_components.py), said; None
    when not estimated."""
    if components is None or not components.estimates:
        return None
    components_json = nc.components_json(components, fs)
    for line in nc.summary_lines(components, fs):
        say(line)
    return components_json


def _marginals(problem: FusionProblem, rounds: _Rounds, soft: "_SoftJoin", partition: Partition | None,
               kf: _Keyframes, hand_over_t_s: float | None, gates: _Gates, sigma_parts: Partition | None = None
               ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], HandOver | None, np.ndarray | None]:
    """The sigmas of :func:`_marginal_sigmas` at the solve, the :class:`HandOver` at the
    keyframe nearest to ``hand_over_t_s`` (None: none), and the station corrections' joint
    covariance (:func:`_station_covariance`; None: no total stations). ``sigma_parts``:
    :func:`_sigma_parts`."""
    sol = rounds.sol
    values = sol.values
    # the solve's last linearisation serves the marginals (at most one converged step before the
    # estimate); a later chunk's marginals need their own graph (:class:`_SoftJoin`)
    gfg = _marginal_graph(rounds.G, values, kf.with_scale, soft) if soft.keys or hand_over_t_s is not None else None
    sel = _sigma_keyframes(kf.t_s, problem.smoother.marginal_step_s)
    station_keys = [T(j) for j in range(len(gates.prisms.station_ids))] if gates.prisms is not None else None
    covs, station_cov = _sigma_covariances(problem, sol, gfg if soft.keys else None, partition, kf,
                                           [X(int(k)) for k in sel], station_keys, sigma_parts)
    if station_keys is not None and station_cov is None:
        station_cov = _station_covariance(gates.prisms, sol.tree)
    sigmas = _marginal_sigmas(covs, sol.state, kf.t_s, sel)
    hand_over = None
    if hand_over_t_s is not None:
        k = int(nearest_sample(kf.t_s, np.array([hand_over_t_s]))[0])
        hand_over = _hand_over(gfg, values, kf, k, gates.gnss, gates.used)
    return sigmas, hand_over, station_cov


def _noise_components(problem: FusionProblem, carried: dict[str, dict[str, float]] | None
                      ) -> "nc.NoiseComponents | None":
    """The groups' noise estimation of a solve (fusion/noise_components.py; None: off), the
    odometer's tick length from its log as its quantum. ``carried``: a later chunk's (fusion/
    chunks.py): the factors the run's first chunk estimated, applied as they are (a chunk's own
    estimate would change the noise model at each join)."""
    if not problem.factors.noise_estimation.enabled:
        return None
    if carried is not None:
        return nc.NoiseComponents(applied={g: dict(c) for g, c in carried.items()}, fixed=True)
    odometer = problem.odometer if problem.factors.odometer.enabled else None
    return nc.NoiseComponents(quanta_m={"odometer": odometer_quantum_m(odometer)} if odometer is not None else {})


def _component_labels(prisms, prism_used: np.ndarray | None) -> dict[str, np.ndarray]:
    """Labels of the rows of the groups estimated per label (fusion/noise_components.py): the
    station of each used prism reading."""
    return {"prism": np.asarray(prisms.station_ids)[prisms.station[prism_used]]} if prisms is not None else {}


def _estimate_components(components: "nc.NoiseComponents", G: _Graph, sol: "_Solved",
                         labels: dict[str, np.ndarray]) -> bool:
    """The groups' noise from the solve ``sol`` (fusion/noise_components.py) with its last
    linearisation's Bayes tree: a one-batch solve's own; a partitioned solve's (whose parts
    are not one tree) made here once, in the order a one-batch solve takes, so that the
    estimates are the one-batch ones to rounding. Whether to solve again."""
    tree, ordering = sol.tree, sol.ordering
    if not isinstance(tree, gtsam.GaussianBayesTree):
        ordering = gtsam.Ordering.ColamdGaussianFactorGraph(sol.gfg)
        tree = _eliminate(sol.gfg, ordering)
    return components.update(G.builders, sol.state, sol.gfg, G.graph.size(), tree_factor(tree, ordering), labels)


def _estimate_while_converging(components: "nc.NoiseComponents", G: _Graph, sol: "_Solved",
                               labels: dict[str, np.ndarray], converge: Callable[[Callable[[str], None]], "_Solved"],
                               say: Callable[[str], None]) -> tuple[bool, "_Solved | None"]:
    """:func:`_estimate_components` in a forked child while this process takes the step that shows
    the solve converged, ``converge(say)``: the round needs that step when the estimate settles
    (after a refit round it usually does, docs/solver_speed.md). Returns whether to solve again
    and, when not, the converged solve; a step the estimate makes void is dropped (and its progress
    lines with it). ``components`` becomes the child's: the same numbers as in turn."""
    said: list[str] = []
    with ForkedTasks() as tasks:
        task = tasks.submit("estimating the sensor noise", _estimate_in_child, components, G, sol, labels)
        stepped = converge(said.append)
        refit, estimated = task.result()
    vars(components).update(vars(estimated))
    if refit:
        return True, None
    for line in said:
        say(line)
    return False, stepped


def _estimate_in_child(components: "nc.NoiseComponents", G: _Graph, sol: "_Solved",
                       labels: dict[str, np.ndarray]) -> tuple[bool, "nc.NoiseComponents"]:
    """The forked child's part of :func:`_estimate_while_converging`: the estimate, and the
    components it leaves (sent back: the child's memory goes with it)."""
    refit = _estimate_components(components, G, sol, labels)
    return refit, components


def _sigma_covariances(problem: FusionProblem, sol: _Solved, gfg: gtsam.GaussianFactorGraph | None,
                       partition: Partition | None, kf: _Keyframes, keys: list[int],
                       station_keys: list[int] | None = None, sigma_parts: Partition | None = None
                       ) -> tuple[dict[int, np.ndarray], np.ndarray | None]:
    """The marginal covariances of ``keys`` behind the sigma columns, exact on a run of any
    length: of ``gfg`` (a chunk's own marginal graph) or else of the solve's last linearisation,
    in parts of at most :data:`~.partitioned.MARGINAL_PART_S` (fusion/partitioned.py: a whole
    hour's Bayes tree drifts), dealt to the CPUs this process may use (the same numbers on any
    count). The solve's own tree when it is that already: a run no longer than one such part,
    or one solved in parts no longer. Also the joint covariance of ``station_keys`` when the
    parts give it (their separator's: :func:`~.partitioned.part_marginal_covariances`), else None.
    When the solve's last step was solved in ``sigma_parts`` (:func:`_sigma_parts`), its parts'
    reductions are those the sigma parts would make again: only their trees are made."""
    if gfg is None and sigma_parts is not None and isinstance(sol.tree, PartMarginals) \
            and sol.tree.partition is sigma_parts:
        return part_marginal_covariances(sigma_parts, sol.gfg, keys, usable_cpus(), station_keys, sol.tree)
    # the solve's own tree(s) by one pass down each (fusion/tree_marginals.py): exact to rounding,
    # where GTSAM's per-key marginals lose digits (4e-5 of a sigma along the scale's drift rate)
    parts = sigma_parts or _partition(problem, kf, MARGINAL_PART_S)
    if gfg is None and partition is not None and problem.smoother.part_s <= MARGINAL_PART_S:
        return sol.tree.exact_covariances(keys), None
    if gfg is None and parts.count == 1:
        tree, ordering = sol.tree, sol.ordering
    elif parts.count == 1:
        ordering = gtsam.Ordering.ColamdGaussianFactorGraph(gfg)
        tree = _eliminate(gfg, ordering)
    else:
        return part_marginal_covariances(parts, gfg if gfg is not None else sol.gfg, keys, usable_cpus(),
                                         station_keys)
    return tree_covariances(tree, ordering, keys, exact=True), None


def _sigma_parts(problem: FusionProblem, kf: _Keyframes, partition: Partition | None, join: HandOver | None,
                 hand_over_t_s: float | None) -> Partition | None:
    """The parts of :data:`~.partitioned.MARGINAL_PART_S` that the sigma columns of a one-batch
    solve are computed in, on the CPUs this process may use (the same numbers on any count), for
    the solve's converging steps (:func:`_solve_in_rounds`): their last step's reductions are the
    ones the sigmas need (:func:`_sigma_covariances`). None: a run of one such part, a solve in
    parts already, or a chunk (whose marginals come from a graph of their own)."""
    if partition is not None or join is not None or hand_over_t_s is not None:
        return None
    parts = _partition(problem, kf, MARGINAL_PART_S)
    if parts.count == 1:
        return None
    return replace(parts, workers=usable_cpus(), engine="local", address=None)


def _partition(problem: FusionProblem, kf: _Keyframes, part_s: float | None = None) -> Partition | None:
    """The time parts of ``part_s`` (default ``smoother.part_s``; fusion/partitioned.py) of the
    keyframes ``kf``, or None: one batch."""
    part_s = part_s or problem.smoother.part_s
    if part_s is None:
        return None
    cuts = cut_times(float(kf.t_s[0]), float(kf.t_s[-1]), part_s)
    if problem.smoother.engine == "dask":  # an unreachable scheduler is refused before the solve
        dask_client(problem.smoother.address, problem.smoother.workers or 1)
    gnss = problem.gnss if problem.factors.gnss.enabled else None
    return Partition(cuts, kf.t_s, kf.bias_seg, kf.scale_seg, gnss.t_s if gnss is not None else None,
                     problem.smoother.workers or 1, problem.smoother.engine, problem.smoother.address)


def _station_covariance(prisms, tree: gtsam.GaussianBayesTree) -> np.ndarray | None:
    """Joint marginal covariance (8J,8J) of the estimated station corrections from the solve's
    Bayes tree (pairwise joints: the stations sit in every separator, near the root), or None
    when there are no prisms."""
    if prisms is None:
        return None
    J, d = len(prisms.station_ids), fx.STATION_STATE_DIM
    cov = np.zeros((J * d, J * d))
    if J == 1:
        cov[:] = tree.marginalCovariance(T(0))
        return cov
    try:
        for a in range(J):
            for b in range(a + 1, J):
                A = tree.joint(T(a), T(b)).jacobian()[0]  # rows over [T(a), T(b)] in key order
                pair = np.linalg.inv(A.T @ A)
                for i, j in ((a, a), (a, b), (b, a), (b, b)):
                    ii, jj = (i > a) * d, (j > a) * d
                    cov[i * d:(i + 1) * d, j * d:(j + 1) * d] = pair[ii:ii + d, jj:jj + d]
    except RuntimeError:  # GTSAM's joint() can find the pair's shortcut indeterminate (a stiff chain, seen
        # on the 53 min bridge): each station's own marginal then, without the cross-covariances
        cov[:] = 0.0
        for a in range(J):
            cov[a * d:(a + 1) * d, a * d:(a + 1) * d] = tree.marginalCovariance(T(a))
    return cov


#: relative cost decrease at which a gating round stops iterating and applies its gate (the
#: last round, whose gate rejects nothing, then goes on to ``smoother.relative_tolerance``)
GATE_RELATIVE_TOLERANCE = 1e-4

#: share of the smallest GNSS white sigma that a gating round's correction still to come may be when
#: its gate is applied (:func:`_gate_step_tolerance_m`)
GATE_STEP_SHARE = 0.1


#: prism readings over which the initial shift onto them is median-filtered (30 s at 10 Hz: a
#: mis-lock of up to 15 s does not pull the initial trajectory)
PRISM_INIT_MEDIAN = 301


def _with_prism_fixes(problem: FusionProblem) -> FusionProblem:
    """The problem with its prism readings standing in as position fixes (for the alignment's
    heading and the initial positions only)."""
    from dataclasses import replace
    pr, ok = problem.prisms, problem.prisms.usable()  # not the step check's mis-locks
    fixes = GnssFixes(pr.t_s[ok], pr.pos_n[ok], pr.cov_n[ok], np.full(ok.size, 4), pr.lever_arm_b)
    return replace(problem, gnss=fixes)


def _without_gnss(problem: FusionProblem) -> FusionProblem:
    from dataclasses import replace
    return replace(problem, gnss=None)
