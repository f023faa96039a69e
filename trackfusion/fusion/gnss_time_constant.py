"""The GNSS correlated error's time constant from the data (``factors.gnss.estimate_time_constant``).

The smoother models each fix's correlated error as a first-order Gauss-Markov process of
stationary sigma ``s`` and time constant ``tau`` (fusion/smoother.py, the ``gnss_error`` steps).
The noise estimation (fusion/noise_components.py) scales the steps' variance; it cannot tell
``tau``: over short lags the steps show only the diffusion ``2 s^2 / tau``.

**Model.** With the whole survey linearised at the solve's estimate, the whitened system
``A(theta) x = b(theta)`` is Gaussian, and the measurements' marginal likelihood (Laplace's, the
other states integrated out) is, up to a constant,

    l(theta) = -c(theta) / 2 - log |det R(theta)| - sum_k log sigma_k(theta)

with ``c`` the least-squares cost at the linear optimum, ``R`` the QR factor of ``A``
(``R^T R = A^T A``) and ``sigma_k`` the Gauss-Markov steps' sigmas, the only rows that depend on
``theta = (tau, g)``. Only those rows change between evaluations; each evaluation is one QR
elimination of the whole graph, in the solve's ordering.

**The profile.** At octaves of the configured time constant (from four fix intervals to the
survey's length), from the configured one outwards until the profile has fallen 1.92 below its
best on each side (:func:`walk_grid`; the grid's end otherwise), and at the half octaves on
either side of the best node (:func:`refine_peak`), the steps' variance is set to the diffusion
the solve had (``tau / tau0`` times its stationary variance) times ``g``, searched in steps of
``sqrt 2`` from the best ``g`` of the nearest time constant already taken (from 1 at the first) and closed by
a parabola in ``log g``: the profile likelihood ``l(tau)``. The estimate is
the peak of the parabola in ``tau ** -1/2`` (:func:`rate_coordinate`) through the best node and
its neighbours; its 95 % interval spans the nodes whose ``l`` lies within 1.92 of the peak, its
ends on the same parabolas (unbounded above when the last node does: long time constants trade
with the trajectory, which the IMU and odometer do not hold over hundreds of seconds). The
configured time constant is replaced when its own ``l`` lies more than 1.92 below the peak (the
likelihood-ratio test at 95 %): a flat, bumpy profile rejects nothing.

The fixes that passed the gate enter at their full weight (the Gaussian model the likelihood is
of), not the solve's Huber weights, and with the white noise at its estimate
(fusion/gnss_noise.py), applied by the solve or not (:func:`_as_estimated`). Not modelled: the
first error state's prior (3 rows) keeps the solve's sigma, and the white noise is not profiled.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..forked import fork_map
from . import factors as fx
from .normal_solve import log_abs_determinant

#: half the 95 % quantile of chi-square with one degree of freedom: the likelihood-ratio interval
HALF_CHI2_95 = 1.92
#: the step [-] of the diffusion factor ``g`` in its search at each time constant (in steps of 4 the
#: parabola in ``log g`` lay up to 1.6 above the peak on the pyins car survey, where the profile
#: in ``g`` falls steeply beyond its peak)
DIFFUSION_STEP = 2.0 ** 0.5


@dataclass(frozen=True)
class TimeConstantEstimate:
    """The estimate [s], its 95 % interval [s] (``inf``: unbounded above; 0: not bounded below
    within the grid, whose first node is four fix intervals), the configured time
    constant [s], whether the likelihood-ratio test rejects it (``applies``), and the profile
    (time constants [s], log-likelihood relative to its peak [-])."""

    configured_s: float
    estimate_s: float
    interval_s: tuple[float, float]
    applies: bool
    profile_tau_s: list[float] = field(default_factory=list)
    profile_log_likelihood: list[float] = field(default_factory=list)

    def to_json(self) -> dict:
        """For metrics.json ``noise_estimates.gnss_time_constant`` (``null`` for an unbounded end)."""
        hi = self.interval_s[1]
        return {"configured_s": self.configured_s, "estimate_s": self.estimate_s,
                "interval_95_s": [self.interval_s[0], hi if np.isfinite(hi) else None],
                "applied": self.applies, "profile_tau_s": self.profile_tau_s,
                "profile_log_likelihood": self.profile_log_likelihood}

    def summary(self) -> str:
        """One line for the run's log."""
        lo, hi = self.interval_s
        upper = f"{hi:.0f}" if np.isfinite(hi) else "unbounded"
        verdict = "applied: the survey solved again" if self.applies else "the configured one kept"
        return (f"GNSS correlated time constant from the data: {self.estimate_s:.0f} s (95 %: {lo:.0f} s to "
                f"{upper}), configured {self.configured_s:g} s, {verdict}")


def tau_grid(configured_s: float, fix_interval_s: float, duration_s: float) -> np.ndarray:
    """Octaves of ``configured_s`` [s] from four fix intervals to the survey's ``duration_s`` [s]."""
    k = np.arange(-12, 13)
    grid = configured_s * 2.0 ** k
    keep = (grid >= 4.0 * fix_interval_s) & (grid <= max(duration_s, configured_s))
    return grid[keep]


def rate_coordinate(tau_s: np.ndarray | float) -> np.ndarray:
    """``tau ** -1/2`` [s^-1/2]: the coordinate in which the profile is interpolated. The
    information a series holds on its process's rate ``1 / tau`` grows as ``1 / rate`` (an
    Ornstein-Uhlenbeck rate's maximum-likelihood variance is ``2 rate / T``), so the square root
    of the rate carries a constant one and the profile is near a parabola in it; in ``log tau``
    it is steep towards short and flat towards long time constants (interpolated there between
    octaves, an exact series' peak came out 25 % long, docs/noise_estimation.md)."""
    return np.asarray(tau_s, dtype=float) ** -0.5


def _parabola(x: np.ndarray, y: np.ndarray, i: int) -> np.ndarray:
    """``(c, b, a)`` of ``a + b x + c x^2`` through nodes ``i - 1, i, i + 1`` (an interior node)."""
    return np.polyfit(x[i - 1:i + 2], y[i - 1:i + 2], 2)


def _peak(x: np.ndarray, y: np.ndarray, i: int) -> tuple[float, float]:
    """Peak ``(x, y)`` of the parabola through nodes ``i - 1, i, i + 1`` of ``x`` (the node itself at
    an end or where the three do not curve down; within the two neighbours)."""
    if i == 0 or i == x.size - 1:
        return float(x[i]), float(y[i])
    c, b, a = _parabola(x, y, i)
    if c >= 0.0:
        return float(x[i]), float(y[i])
    u = float(np.clip(-b / (2.0 * c), min(x[i - 1], x[i + 1]), max(x[i - 1], x[i + 1])))
    return u, float(a + b * u + c * u * u)


def _crossing(x: np.ndarray, y: np.ndarray, level: float, j: int, step: int) -> float:
    """Where ``y`` falls below ``level`` between node ``j`` (at or above it) and ``j + step``, ``x``
    the :func:`rate_coordinate` of increasing time constants: on the parabola through ``j - 1 ..
    j + 1`` where it crosses the level there (a profile this peaked is far from linear between
    octaves), else linearly; when ``j`` is the last node that way, ``inf`` (a time constant of 0)
    towards shorter time constants and 0 (an unbounded one) towards longer."""
    if not 0 <= j + step < x.size:
        return np.inf if step < 0 else 0.0
    lo, hi = sorted((float(x[j]), float(x[j + step])))
    if 0 < j < x.size - 1:
        c, b, a = _parabola(x, y, j)
        roots = np.roots([c, b, a - level]) if c < 0.0 else np.array([])
        inside = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and lo <= r.real <= hi]
        if inside:
            return inside[0]
    return float(x[j] + (x[j + step] - x[j]) * (y[j] - level) / (y[j] - y[j + step]))


def interval_from_profile(tau_s: np.ndarray, log_likelihood: np.ndarray, configured_s: float
                          ) -> TimeConstantEstimate:
    """:class:`TimeConstantEstimate` from the profile ``log_likelihood`` (T,) at the time constants
    ``tau_s`` (T,) [s], increasing (module docstring), interpolated in :func:`rate_coordinate`.
    The interval spans every node within 1.92 of the peak (a profile that dips below that level
    and comes back is not cut at the dip); the configured time constant is rejected by the
    likelihood-ratio test of its own node (of the interval when it is not a node)."""
    x, y = rate_coordinate(tau_s), np.asarray(log_likelihood, dtype=float)
    i = int(np.argmax(y))
    x_hat, peak = _peak(x, y, i)
    peak = max(peak, float(y[i]))
    level = peak - HALF_CHI2_95
    above = np.flatnonzero(y >= level)
    lo, hi = _crossing(x, y, level, int(above[0]), -1), _crossing(x, y, level, int(above[-1]), +1)
    interval = (float(lo ** -2.0) if np.isfinite(lo) else 0.0, float(hi ** -2.0) if hi > 0.0 else np.inf)
    node = np.flatnonzero(np.isclose(tau_s, configured_s, rtol=1e-9))
    applies = bool(y[node[0]] < level) if node.size else not interval[0] <= configured_s <= interval[1]
    return TimeConstantEstimate(float(configured_s), float(x_hat ** -2.0), interval, applies,
                                [float(t) for t in tau_s], [float(v - peak) for v in y])


def _steps_with(blocks: fx.LinearBlocks, e: np.ndarray, tau_ratio: float, g: float) -> fx.LinearBlocks:
    """The Gauss-Markov steps ``blocks`` (the solve's, time constant ``tau0``) with the time
    constant ``tau0 / tau_ratio`` and the stationary variance ``g / tau_ratio`` times the solve's;
    ``e`` (N,3) [m] the error states."""
    phi0 = np.clip(-blocks.jacobians[0][:, :, 0][:, :1], 1e-300, 1.0 - 1e-15)  # (K,1)
    stationary = blocks.sigma / np.sqrt(1.0 - phi0**2)
    phi = phi0**tau_ratio
    sigma = np.maximum(stationary * np.sqrt(g / tau_ratio) * np.sqrt(1.0 - phi**2), 1e-12)
    r, J = fx.gauss_markov_residual(e[:-1], e[1:], phi * np.ones(3))
    return fx.LinearBlocks(blocks.keys, J, r, sigma)


def fixed_part(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               blocks: Sequence[tuple[str, fx.LinearBlocks]]) -> gtsam.GaussianFactorGraph:
    """The linearised system at ``values`` without the ``gnss_error`` steps: ``graph`` (the
    GTSAM-built factors) and every other of ``blocks`` (name, blocks at ``values``); made once."""
    gfg = graph.linearize(values)
    for name, b in blocks:
        if name != "gnss_error":
            fx.to_jacobian_factors(b, gfg)
    return gfg


def log_likelihood(fixed: gtsam.GaussianFactorGraph, steps: fx.LinearBlocks, e: np.ndarray,
                   ordering: gtsam.Ordering, tau_ratio: float, g: float) -> float:
    """``l(theta)`` of the module docstring [-] (up to a constant): the system ``fixed``
    (:func:`fixed_part`) with the Gauss-Markov ``steps`` (the solve's blocks, time constant
    ``tau0``) at time constant ``tau0 / tau_ratio`` and stationary variance ``g / tau_ratio`` times
    the solve's, eliminated in ``ordering``; ``e`` (N,3) [m] the error states."""
    gfg = gtsam.GaussianFactorGraph()
    gfg.push_back(fixed)  # the same factors, shared: elimination does not change them
    b = _steps_with(steps, e, tau_ratio, g)
    fx.to_jacobian_factors(b, gfg)
    tree = gfg.eliminateMultifrontal(ordering, gtsam.EliminateQR)
    cost = 2.0 * gfg.error(tree.optimize())
    return -0.5 * cost - log_abs_determinant(tree, ordering) - float(np.sum(np.log(b.sigma)))


def estimate(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             builders: Sequence[tuple[str, Callable]], state, configured_s: float, fix_t_s: np.ndarray,
             say: Callable[[str], None] = lambda _m: None, white_ratio: np.ndarray | None = None
             ) -> TimeConstantEstimate | None:
    """The time constant of the GNSS correlated error from the solve at ``values`` (``state``
    its arrays, with ``e`` the used fixes' error states), ``graph`` and ``builders`` its factors
    (fusion/smoother.py ``_Graph``); ``configured_s`` [s] the solve's time constant, ``fix_t_s``
    (N,) [s] the used fixes' times; ``white_ratio`` (3,) [-]: the fixes' white variance estimated
    over the one the solve used, per ENU axis (fusion/gnss_noise.py; None: 1). None without a
    correlated-error model or with fewer than 30 fixes."""
    if fix_t_s.size < 30 or "gnss_error" not in dict(builders):
        return None
    blocks = [(name, _as_estimated(build(state), white_ratio) if name == "gnss" else build(state))
              for name, build in builders]
    steps = dict(blocks)["gnss_error"]
    grid = tau_grid(configured_s, float(np.median(np.diff(fix_t_s))), float(fix_t_s[-1] - fix_t_s[0]))
    fixed = fixed_part(graph, values, blocks)
    with_steps = gtsam.GaussianFactorGraph()
    with_steps.push_back(fixed)
    fx.to_jacobian_factors(steps, with_steps)
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(with_steps)

    best_log2_g: dict[float, float] = {}  # the diffusion factor's best node at each time constant taken

    def profile(tau_and_start: tuple[float, float]) -> tuple[float, float]:
        tau, start = tau_and_start
        return profile_over_diffusion(lambda g: log_likelihood(fixed, steps, state.e, ordering, configured_s / tau, g),
                                      start)

    def profiles(taus: list[float]) -> list[float]:  # the walk's nodes on both sides at once, on two CPUs
        say(f"  GNSS time constant: likelihood at {' and '.join(f'{t:.0f}' for t in taus)} s")
        starts = [_nearest(best_log2_g, tau) for tau in taus]
        out = fork_map("the GNSS time constant's likelihood", profile, list(zip(taus, starts)))
        best_log2_g.update(zip(taus, (g for _, g in out)))
        return [v for v, _ in out]
    lo, hi, values_at = walk_grid(profiles, grid, int(np.argmin(np.abs(np.log(grid / configured_s)))))
    tau, values = refine_peak(profiles, grid[lo:hi + 1], values_at)
    return interval_from_profile(tau, values, configured_s)


def _as_estimated(fixes: fx.LinearBlocks, white_ratio: np.ndarray | None) -> fx.LinearBlocks:
    """The fixes' factors as the likelihood takes them: at their full weight (the Gaussian model's;
    with the solve's Huber weights the estimate at a true 30 s was 43 s, 34-56 s, against 36 s,
    27-48 s), and with the white noise at its estimate, applied by the solve or not (a variance
    left 4-7 % low, not significant at two sigmas, went into the error states at the shortest time
    constant and rejected the pyins car survey's true 600 s)."""
    if white_ratio is None:
        return replace(fixes, huber_k=None)
    # the fixes carry their whitening W (fusion/smoother.py ``gnss``); W D^-1 whitens D C D
    return replace(fixes, huber_k=None, whiten=fixes.whiten / np.sqrt(np.asarray(white_ratio, dtype=float)))


def _nearest(best_log2_g: dict[float, float], tau_s: float) -> float:
    """The search's start at ``tau_s`` [s]: the best ``log2 g`` of the nearest time constant taken
    (0, the solve's diffusion, at the first)."""
    if not best_log2_g:
        return 0.0
    return best_log2_g[min(best_log2_g, key=lambda t: abs(np.log(t / tau_s)))]


def refine_peak(f: Callable[[list[float]], list[float]], tau_s: np.ndarray, values: Sequence[float]
                ) -> tuple[np.ndarray, np.ndarray]:
    """The profile ``values`` at the octave nodes ``tau_s`` (T,) [s] with the half octaves on either
    side of its best node added (``f``, as in :func:`walk_grid`, gives them at once): the peak
    and, on a profile this narrow, the interval's ends then lie between nodes half an octave
    apart. Returns the nodes (increasing) and the profile at them."""
    i = int(np.argmax(values))
    mids = [float(np.sqrt(tau_s[k] * tau_s[k + 1])) for k in (i - 1, i) if 0 <= k < tau_s.size - 1]
    tau = np.concatenate([tau_s, mids])
    order = np.argsort(tau)
    return tau[order], np.concatenate([np.asarray(values, dtype=float), f(mids) if mids else []])[order]


def walk_grid(f: Callable[[list[float]], list[float]], grid: np.ndarray, start: int) -> tuple[int, int, list[float]]:
    """The profile on the nodes of ``grid`` from ``start`` outwards, on each side until a node
    falls more than :data:`HALF_CHI2_95` below the best so far (what the interval needs) or the
    grid ends; ``f`` gives it at a list of time constants [s] (a step's nodes on both sides at
    once). Returns the first and last node taken and the profile at the nodes between (both
    included)."""
    taken = {start: f([float(grid[start])])[0]}
    lo = hi = start
    while True:
        level = max(taken.values()) - HALF_CHI2_95
        nodes = ([lo - 1] if lo > 0 and taken[lo] >= level else []) \
            + ([hi + 1] if hi < grid.size - 1 and taken[hi] >= level else [])
        if not nodes:
            return lo, hi, [taken[i] for i in range(lo, hi + 1)]
        taken.update(zip(nodes, f([float(grid[i]) for i in nodes])))
        lo, hi = min(lo, nodes[0]), max(hi, nodes[-1])


def profile_over_diffusion(ll: Callable[[float], float], start_log2_g: float = 0.0, max_steps: int = 24
                           ) -> tuple[float, float]:
    """The largest ``ll(g)`` over the diffusion factor ``g`` [-] and the ``log2 g`` of the best node
    searched: from ``2 ** start_log2_g`` in steps of :data:`DIFFUSION_STEP` uphill until it falls (at
    most ``max_steps``), then the parabola in ``log g`` through the best and its two neighbours."""
    h = float(np.log2(DIFFUSION_STEP))
    at_log2 = lambda k: start_log2_g + k * h  # noqa: E731  (nodes keyed by their step index k)
    x = {k: ll(2.0 ** at_log2(k)) for k in (0, 1)}
    step = 1 if x[1] > x[0] else -1
    at = max(step, 0)
    for _ in range(max_steps):
        x[at + step] = ll(2.0 ** at_log2(at + step))
        if x[at + step] <= x[at]:
            break
        at += step
    if at + 1 not in x or at - 1 not in x:  # the best at the end of the steps taken
        return float(x[at]), at_log2(at)
    nodes = np.array([at - 1, at, at + 1], dtype=float)
    return max(_peak(nodes, np.array([x[n] for n in (at - 1, at, at + 1)]), 1)[1], float(x[at])), at_log2(at)
