"""The slow states outside a time segment, from a coarse solve of the data there (fusion/segments.py).

For segment ``s`` of a run cut into segments (fusion/segments.py), the data before its first
sample and the data after its last one are each smoothed on a coarse problem
(:func:`coarse_problem`): keyframes ``coarse_spacing_s`` apart, the IMU block-averaged to about
``imu_rate_hz`` (registration/two_stage.py ``decimated_imu``), the per-keyframe factors (NHC,
zero velocity, odometer increments) with their sigmas scaled so that their information per
second is the fine problem's. The bias and scale states at the end next to the segment, with
their marginal covariances, become the segment's :class:`~.slow_states.SlowPrior`: the data
before it (the specification's bias and scale priors included: they then replace the segment's
own) and the data after it (smoothed with a flat prior in place of the specification's, so that
the specification is counted once). No data is counted twice: a piece ends where its segment
starts. The segment's bias and scale states are then tied to the rest of the run as in one
batch, through their random walks, with the rest of the run seen at the coarse resolution.

Each segment's worker runs its own pieces (fusion/segments.py), so the pieces of different
segments run at the same time. Pure computation: no file I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import FusionError
from ..registration.two_stage import decimated_imu
from .chunks import sub_problem
from .problem import FusionProblem
from .slow_states import SlowPrior
from .smoother import GATE_RELATIVE_TOLERANCE, SmootherResult, nearest_sample, smooth

#: the flat prior's sigma, in units of the specification's, on the data after a segment
FLAT_FACTOR = 1e3


@dataclass(frozen=True)
class SlowPassSettings:
    """coarse_spacing_s: keyframe spacing of the coarse solves [s]; imu_rate_hz: about the
    rate the IMU is block-averaged to for them [Hz]; min_piece_s: a piece of data outside a
    segment shorter than this is not smoothed (no prior from it) [s]; gnss_spacing_s: the fixes
    kept, the nearest to each time of a grid this far apart from the piece's start [s] (every
    fix is a keyframe)."""

    coarse_spacing_s: float = 2.0
    imu_rate_hz: float = 25.0
    min_piece_s: float = 60.0
    gnss_spacing_s: float = 2.0


def coarse_problem(problem: FusionProblem, settings: SlowPassSettings) -> FusionProblem:
    """``problem`` on coarse keyframes (module docstring), solved to the gating tolerance only
    (smoother.py ``GATE_RELATIVE_TOLERANCE``: the slow states move by far less than their sigma
    after it)."""
    rate_hz = 1.0 / float(np.median(np.diff(problem.imu.t_s)))
    m = max(1, int(round(rate_hz / settings.imu_rate_hz)))
    ratio = np.sqrt(settings.coarse_spacing_s / problem.keyframes.spacing_s)  # sigma scale of per-keyframe factors
    fs = problem.factors
    lateral, vertical = fs.nhc.sigmas_mps() * 1e3
    factors = fs.model_copy(update={
        "nhc": fs.nhc.model_copy(update={"sigma_lateral_mm_per_s": lateral / ratio,
                                         "sigma_vertical_mm_per_s": vertical / ratio}),
        "zupt": fs.zupt.model_copy(update={"sigma_velocity_mm_per_s": fs.zupt.sigma_velocity_mm_per_s / ratio}),
        "odometer": fs.odometer.model_copy(update={"sigma_mm": fs.odometer.sigma_mm * ratio}),
        # a wheelbase is shorter than one coarse keyframe interval: no pair would form
        "wheel_path": fs.wheel_path.model_copy(update={"enabled": False})})
    imu = decimated_imu(problem.imu, m)
    g = problem.gnss
    if g is not None and g.t_s.size > 1:  # the fix nearest to each keyframe of the coarse grid (each fix is a keyframe)
        grid = np.arange(imu.t_s[0], imu.t_s[-1] + settings.gnss_spacing_s, settings.gnss_spacing_s)
        keep = np.unique(nearest_sample(g.t_s, grid))
        g = replace(g, t_s=g.t_s[keep], pos_n=g.pos_n[keep], cov_n=g.cov_n[keep], fix_quality=g.fix_quality[keep])
    return replace(problem, imu=imu, factors=factors, gnss=g,
                   keyframes=problem.keyframes.model_copy(update={"spacing_s": settings.coarse_spacing_s}),
                   smoother=problem.smoother.model_copy(update={"relative_tolerance": GATE_RELATIVE_TOLERANCE}))


def flat_prior(problem: FusionProblem, t_s: float) -> SlowPrior:
    """A prior that stands in for the specification's at the start of data after a segment:
    zero, with ``FLAT_FACTOR`` times its sigmas (keeps the coarse graph regular, adds nothing)."""
    n = problem.imu_noise
    sigma = FLAT_FACTOR * np.r_[[n.accel_bias_sigma_mps2] * 3, [n.gyro_bias_sigma_radps] * 3]
    scale_sigma = FLAT_FACTOR * problem.factors.odometer.scale_sigma_ppm * 1e-6
    return SlowPrior(t_s, np.zeros(6), np.diag(sigma**2), 0.0, scale_sigma**2, start=True)


def _state_mid_time(t_key: np.ndarray, bias_segment_s: float, last: bool) -> float:
    """Mid-time [s] of the first or last bias state of a solve with keyframes ``t_key`` (the
    smoother's bias segments: ``bias_segment_s`` from the first keyframe, the last keyframe in
    the last interval's)."""
    seg = np.floor((t_key - t_key[0]) / bias_segment_s).astype(np.int64)
    seg[-1] = seg[-2]
    on = t_key[seg == (seg[-1] if last else 0)]
    return 0.5 * float(on[0] + on[-1])


def _prior_from(res: SmootherResult, bias_segment_s: float, last: bool, start: bool) -> SlowPrior:
    k = -1 if last else 0
    ec = res.end_cov
    scale = None if res.odometer_scale is None else float(res.odometer_scale[k])
    return SlowPrior(_state_mid_time(res.t_s, bias_segment_s, last),
                     np.r_[res.accel_bias_mps2[k], res.gyro_bias_radps[k]],
                     ec.bias_last if last else ec.bias_first, scale,
                     (ec.scale_last if last else ec.scale_first) if scale is not None else None, start)


def outside_priors(problem: FusionProblem, i0: int, i1: int,
                   settings: SlowPassSettings = SlowPassSettings()) -> list[SlowPrior]:
    """The priors (0 to 2) on the slow states of the segment of IMU samples ``i0 .. i1`` of
    ``problem`` from the data before and after it (module docstring). A side whose data is
    shorter than ``settings.min_piece_s``, or cannot be smoothed on its own (a
    :class:`~trackfusion.errors.FusionError`, e.g. no way to align it), gives no prior: the segment
    then stands on its own data there, as without the priors."""
    t = problem.imu.t_s
    priors = []
    if t[i0] - t[0] >= settings.min_piece_s:  # the data before: its last states
        try:
            before = smooth(coarse_problem(sub_problem(problem, 0, i0), settings), end_covariances=True, sigmas=False)
            priors.append(_prior_from(before, problem.keyframes.bias_segment_s, last=True, start=True))
        except FusionError:
            pass
    if t[-1] - t[i1] >= settings.min_piece_s:  # the data after: its first states
        piece = coarse_problem(sub_problem(problem, i1, t.size - 1), settings)
        try:
            after = smooth(piece, slow_priors=[flat_prior(problem, float(t[i1]))], end_covariances=True,
                           sigmas=False)
            priors.append(_prior_from(after, problem.keyframes.bias_segment_s, last=False, start=False))
        except FusionError:
            pass
    return priors
