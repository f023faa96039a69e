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
best on each side (:func:`walk_grid`; the grid's end otherwise), the steps' variance is set to the diffusion the solve had
(``tau / tau0`` times its stationary variance) times ``g``, searched in steps of 4 from 1 and
closed by a parabola in ``log g``: the profile likelihood ``l(tau)``. The estimate is the peak
of the parabola in ``log tau`` through the best node; its 95 % interval spans the nodes whose
``l`` lies within 1.92 of the peak (unbounded above when the last does: long time constants trade
with the trajectory, which the IMU and odometer do not hold over hundreds of seconds). The
configured time constant is replaced when its own ``l`` lies more than 1.92 below the peak (the
likelihood-ratio test at 95 %): a flat, bumpy profile rejects nothing.

The fixes that passed the gate enter at their full weight (the Gaussian model the likelihood is
of), not the solve's Huber weights. Not modelled: the first error state's prior (3 rows) keeps
the solve's sigma, and the white noise the solve's estimate.
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
#: the step [-] of the diffusion factor ``g`` in its search at each time constant
DIFFUSION_STEP = 4.0


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


def _parabola(y: np.ndarray, i: int) -> tuple[float, float]:
    """``(b, c)`` of the parabola ``y[i] + b u + c u^2`` through nodes ``i - 1, i, i + 1`` of an
    equally spaced grid (``u`` in node steps from node ``i``, an interior node)."""
    return (y[i + 1] - y[i - 1]) / 2.0, (y[i + 1] + y[i - 1] - 2.0 * y[i]) / 2.0


def _peak(x: np.ndarray, y: np.ndarray, i: int) -> tuple[float, float]:
    """Peak ``(x, y)`` of the parabola through nodes ``i - 1, i, i + 1`` of equally spaced ``x``
    (the node itself at an end or where the three do not curve down)."""
    if i == 0 or i == x.size - 1:
        return float(x[i]), float(y[i])
    h = x[i + 1] - x[i]
    b, c = _parabola(y, i)
    if c >= 0.0:
        return float(x[i]), float(y[i])
    u = float(np.clip(-b / (2.0 * c), -1.0, 1.0))
    return float(x[i] + u * h), float(y[i] + b * u + c * u * u)


def _crossing(x: np.ndarray, y: np.ndarray, level: float, j: int, step: int) -> float:
    """Where ``y`` falls below ``level`` between node ``j`` (at or above it) and ``j + step`` over
    equally spaced ``x``: on the parabola through ``j - 1 .. j + 1`` where it curves down (a
    profile this peaked is far from linear between octaves), else linearly; +-inf when ``j`` is
    the grid's last node that way."""
    if not 0 <= j + step < x.size:
        return float(np.inf * step)
    if 0 < j < x.size - 1:
        b, c = _parabola(y, j)
        disc = b * b - 4.0 * c * (y[j] - level)
        if c < 0.0 and disc >= 0.0:  # the root of y[j] + b u + c u^2 = level on the side of ``step``
            u = (-b - step * np.sqrt(disc)) / (2.0 * c)
            return float(x[j] + u * (x[j + 1] - x[j]))
    return float(x[j] + (x[j + step] - x[j]) * (y[j] - level) / (y[j] - y[j + step]))


def interval_from_profile(tau_s: np.ndarray, log_likelihood: np.ndarray, configured_s: float
                          ) -> TimeConstantEstimate:
    """:class:`TimeConstantEstimate` from the profile ``log_likelihood`` (T,) at the octave grid
    ``tau_s`` (T,) [s] (module docstring). The interval spans every node within 1.92 of the peak
    (a profile that dips below that level and comes back is not cut at the dip); the configured
    time constant is rejected by the likelihood-ratio test of its own node (of the interval when
    it is not a node)."""
    x, y = np.log2(tau_s), np.asarray(log_likelihood, dtype=float)
    i = int(np.argmax(y))
    x_hat, peak = _peak(x, y, i)
    peak = max(peak, float(y[i]))
    level = peak - HALF_CHI2_95
    above = np.flatnonzero(y >= level)
    lo, hi = _crossing(x, y, level, int(above[0]), -1), _crossing(x, y, level, int(above[-1]), +1)
    interval = (float(2.0 ** lo) if np.isfinite(lo) else 0.0, float(2.0 ** hi) if np.isfinite(hi) else np.inf)
    node = np.flatnonzero(np.isclose(tau_s, configured_s, rtol=1e-9))
    applies = bool(y[node[0]] < level) if node.size else not interval[0] <= configured_s <= interval[1]
    return TimeConstantEstimate(float(configured_s), float(2.0 ** x_hat), interval, applies,
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
             say: Callable[[str], None] = lambda _m: None) -> TimeConstantEstimate | None:
    """The time constant of the GNSS correlated error from the solve at ``values`` (``state``
    its arrays, with ``e`` the used fixes' error states), ``graph`` and ``builders`` its factors
    (fusion/smoother.py ``_Graph``); ``configured_s`` [s] the solve's time constant, ``fix_t_s``
    (N,) [s] the used fixes' times. None without a correlated-error model or with fewer than 30
    fixes."""
    # the gated fixes at their full weight: the likelihood is the Gaussian model's (with the
    # solve's Huber weights the estimate at a true 30 s was 43 s, 34-56 s; without, 36 s, 27-48 s)
    blocks = [(name, replace(build(state), huber_k=None) if name == "gnss" else build(state))
              for name, build in builders]
    steps = dict(blocks).get("gnss_error")
    if steps is None or fix_t_s.size < 30:
        return None
    grid = tau_grid(configured_s, float(np.median(np.diff(fix_t_s))), float(fix_t_s[-1] - fix_t_s[0]))
    fixed = fixed_part(graph, values, blocks)
    with_steps = gtsam.GaussianFactorGraph()
    with_steps.push_back(fixed)
    fx.to_jacobian_factors(steps, with_steps)
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(with_steps)

    def profile(tau: float) -> float:
        return profile_over_diffusion(lambda g: log_likelihood(fixed, steps, state.e, ordering, configured_s / tau, g))

    def profiles(taus: list[float]) -> list[float]:  # the walk's nodes on both sides at once, on two CPUs
        say(f"  GNSS time constant: likelihood at {' and '.join(f'{t:.0f}' for t in taus)} s")
        return fork_map("the GNSS time constant's likelihood", profile, taus)
    lo, hi, values_at = walk_grid(profiles, grid, int(np.argmin(np.abs(np.log(grid / configured_s)))))
    return interval_from_profile(grid[lo:hi + 1], np.array(values_at), configured_s)


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


def profile_over_diffusion(ll: Callable[[float], float], max_steps: int = 6) -> float:
    """The largest ``ll(g)`` over the diffusion factor ``g`` [-]: from 1 (the solve's diffusion)
    in steps of :data:`DIFFUSION_STEP` uphill until it falls (at most ``max_steps``), then the
    parabola in ``log g`` through the best and its two neighbours."""
    h = float(np.log2(DIFFUSION_STEP))
    x = {0.0: ll(1.0), h: ll(DIFFUSION_STEP)}  # keyed by log2 g
    step = h if x[h] > x[0.0] else -h
    at = h if step > 0 else 0.0
    for _ in range(max_steps):
        nxt = at + step
        x[nxt] = ll(2.0**nxt)
        if x[nxt] <= x[at]:
            break
        at = nxt
    if at + step not in x or at - step not in x:  # the best at the end of the steps taken
        return float(x[at])
    nodes = np.array([at - h, at, at + h])
    return max(_peak(nodes, np.array([x[n] for n in nodes]), 1)[1], float(x[at]))
