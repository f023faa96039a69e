"""Variance component estimation: each measurement group's noise from its residuals.

Model: the true variance of every row of group ``g`` (component ``c`` of it: NHC lateral and
vertical, GNSS correlated horizontal and vertical, one total station) is ``f_gc`` times the
configured (datasheet) variance. After a solve with the factors ``f0`` applied, with
``e_i`` the whitened residual of row ``i``, the square sum ``Omega_gc = sum e_i^2`` over the
component's factors has the expectation ``r_gc f_gc / f0_gc`` (Helmert / Foerstner),
``r_gc = n_gc - tr(H_gc)`` the group's **redundancy**, ``H`` the hat matrix of the whole
whitened, linearised system ``A (A^T A)^-1 A^T`` (rows Huber-weighted as the solve had them).

**Outliers.** A group the solve itself treats as robust (a Huber loss: the odometer, the total
stations' readings) expects gross errors: its sum is taken over the factors inside a gate on
the group's robust scale (:func:`_inliers`: the median, then a chi-square gate of tail
:data:`GATE_TAIL`; the gate is the estimated noise's, not the stated one's). A group the solve
weighs as plain Gaussian (the NHC, the wheel path, the inclinometer, the GNSS correlated steps)
is summed over every row, as the solve weighs them: its large residuals are the constraint's
real violation, which need not be Gaussian. (The NHC's is heavy-tailed where the track's
curvature and cant change: on the short open-track survey 8 % of its rows lay outside the gate
on the median's scale, and the gated estimate came 20 % under the violation's RMS.)

**Quantised sensors.** A group may have a quantum (:attr:`NoiseComponents.quanta_m`: the
odometer's distance per encoder tick). Its error is then not Gaussian: at a steady speed the
ticks counted per keyframe interval beat against the interval, so most increments are nearly
exact and every few tens one is a whole tick off. The robust scale sees the many small ones,
and its gate would throw out the one-tick rows as outliers, leaving an estimate far below the
error the data carry (bridge survey, seed 2: 0.0045 mm against the increments' 0.0089 mm).
A residual no larger than one quantum is therefore always an inlier: quantisation alone can
make it.

**Redundancy.** ``tr(H_gc)`` is the Hutchinson estimate ``E[z_gc^T (H z)_gc]`` over random
right-hand sides ``z ~ N(0, I)`` of every row of the graph (the IMU and prior factors too):
``H z = A delta`` with ``delta = (A^T A)^-1 A^T z``, solved for all draws at once with the Bayes
tree the solve's last Gauss-Newton step already made (fusion/normal_solve.py: two triangular
passes, no new elimination; the vectorised groups' rows at the solution, one converged step
past that tree's linearisation). Hand-written because GTSAM has no trace of the hat matrix.
Unbiased; its variance per draw is at most ``2 tr(H_gc)``: the draws' scatter is part of the
stated uncertainty.

**Estimate, with the datasheet as prior**: a normal prior on ``u = log f_gc`` at 0 (the
datasheet) of variance ``2 / PRIOR_DOF`` (:data:`PRIOR_DOF` degrees of freedom: the curvature an
inverse-gamma prior of as many has at 1), ``Omega_gc`` as ``f_gc / f0_gc`` times a chi-square of
``r_gc`` degrees of freedom; the estimate is the posterior's mode (:func:`_posterior_mode`, the
root of ``r_gc + PRIOR_DOF u = f0_gc Omega_gc exp(-u)``), but not below
``PRIOR_DOF / (PRIOR_DOF + r_gc)``, the resolution of ``r_gc`` rows against the prior's: what
an inverse-gamma prior of ``PRIOR_DOF`` rows at the datasheet gives when every residual is 0.
Its 1-sigma is ``f_gc sqrt(2 / (PRIOR_DOF + r_gc))`` with the redundancy's Monte Carlo error in
quadrature. In logarithms the prior pulls a datasheet 10 times too high as little as one 10 times
too low (an inverse-gamma prior on ``f`` itself, ``(PRIOR_DOF + f0 Omega) / (PRIOR_DOF + r)``,
adds ``PRIOR_DOF`` rows at the datasheet's variance: with the library's NHC sigma of 1 mm/s on a
bridge whose violation is 0.094 mm/s, those 8 rows outweighed the 2 200 measured ones, 17 % over);
the floor keeps a noise-free survey's refits from running a factor to 0 (the mode alone went to
``exp(-r / PRIOR_DOF)``: the short noise-free open track's odometer to 0.0003, its GNSS
correlated part to 0.0003). It is applied (the group's sigmas scaled by ``sqrt(f)``, the Huber
weights and the gates then decided on the estimated noise) when it differs from 1 by more than
:data:`SIGNIFICANCE` sigmas and by more than :data:`MIN_CHANGE`, and once applied it follows
its estimates (:func:`_next_factor`); the solve is repeated (at most :data:`MAX_REFITS` times)
while an applied factor moves by more than :data:`MIN_CHANGE`.
A correct datasheet therefore leaves the solve as it was. The groups of :data:`FLOOR_GROUPS`
keep their configured sigma as a floor.

**Low-share components.** The Newton slope ``r / n`` and the ``2 / r`` variance assume every
row of the component carries the same share of redundancy. The GNSS correlated steps do not:
the error states absorb most of them and a few long-wave modes carry the rest (44 min
``open-track-gnss``: ``r / n = 0.023``, but ``t / r = 0.45`` with ``t = tr((I - H)_gg^2)``),
and the shared draws' Monte Carlo error of ``r`` (``tr(H_gg)`` of thousands of rows, less
``n``) is a third of ``r`` itself. Since ``I - H`` is a symmetric projection, ``E[f0 Omega] =
f t + f0 (r - t)``: the plain estimate moves only ``t / r`` of a change of the true factor and
stays near the datasheet. A component whose share is below :data:`LOW_SHARE` therefore gets
:data:`DRAWS` right-hand sides on its own rows (:func:`_own_draws`: ``r = E[z^T (I - H) z]``
and ``t = E[|((I - H) z)_g|^2]``); ``W = f0 (Omega - r + t)``, whose expectation is ``f t``,
is then taken as ``f`` times a chi-square of ``t`` degrees of freedom, and the estimate is the
posterior's mode above with ``(W, t)`` for ``(f0 Omega, r)``, floored at ``PRIOR_DOF /
(PRIOR_DOF + t)``: the fixed point itself, applied as it is (no Newton step). Its 1-sigma is
``f sqrt(2 / (PRIOR_DOF + t))`` with ``f0`` times the Monte Carlo error of ``r`` over ``t`` in
quadrature.

**Robust rows.** ``r - t`` is the other rows' share of ``E[f0 Omega]`` when every other row has
unit variance in the weighted system the solve had. A Huber-weighted group's rows do not: its
weights keep ``rho = sum(w e^2) / sum(e^2)`` of its whitened residuals' square sum (0.88 for
Gaussian fixes under the GNSS factor's ``k = 2`` on their 3-D norm, 26 % of them weighted down).
So the fixed point takes ``r - t - c``: ``c = E[|(H x)_g|^2]`` with ``x ~ N(0, 1 - rho)`` on each
such group's rows (:func:`robust_rows`), from :data:`DRAWS` more right-hand sides of the same
passes. Without ``c`` the GNSS correlated sigma of the 44 min open track (seed 1, every other
noise configured true) came out 0.96 / 0.94 (h / v) of what its error series itself shows
(benchmarks/gnss_correlated_oracle.py); with it 1.01 / 1.00. The constant ``rho`` is the
weighted least squares' linear response; an M-estimator's down-weighted rows respond less (their
influence is bounded), and on a test walk the correction removes about 75 % of the bias
(tests/test_noise_components.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np
from scipy.optimize import brentq
from scipy.sparse import csr_matrix
from scipy.stats import chi2

from . import factors as fx
from .normal_solve import TreeFactor, key_dim, solve_normal
from .wheel_path import HAND_OVER_BUILDER

#: degrees of freedom of the datasheet as a prior of each variance factor
PRIOR_DOF = 8.0
#: an estimate is applied when it differs from 1 by more than this many of its sigmas ...
SIGNIFICANCE = 3.0
#: ... and by more than this fraction (also: the change of an applied factor that calls for a new solve)
MIN_CHANGE = 0.15
#: the most solves repeated because an applied factor moved
MAX_REFITS = 3
#: largest amplification of an estimate's change by the Newton step of the applied factor
MAX_STEP_GAIN = 5.0
#: tail of the chi-square gate on the robust scale: the factors beyond it are left out of the estimate
GATE_TAIL = 1e-4
#: random right-hand sides of the redundancy estimate
DRAWS = 16
#: a component whose redundancy share ``r / n`` (from the shared draws) is below this gets draws
#: of its own (module docstring, "Low-share components")
LOW_SHARE = 0.5
#: significant digits an applied factor is rounded to (its own uncertainty is >= 1 %): the
#: one-batch and the partitioned solve, whose estimates differ by rounding, apply the same factor
APPLIED_DIGITS = 3
#: the groups estimated, and each one's components by residual row (None: one per label, e.g. per station)
COMPONENTS: dict[str, tuple[str, ...] | None] = {
    "nhc": ("lateral", "vertical"),
    "odometer": ("along",),
    "wheel_path": ("lateral", "vertical"),
    "gnss_error": ("horizontal", "horizontal", "vertical"),
    "inclinometer": ("tilt", "tilt"),
    "prism": None,
}
#: groups whose configured sigma is a floor: an estimate below it is reported, not applied. The
#: wheel path's residual is the factor's approximation error (fusion/wheel_path.py), smooth in
#: time: weighted as white noise of its own small variance it over-weights (short open-track
#: survey seed 2: the 5 m vertical ADEV 0.053 mm at the trolley's 0.01 mm, 0.063 mm at the
#: estimated 0.002 mm)
FLOOR_GROUPS = ("wheel_path",)


def _component_index(name: str, blocks: fx.LinearBlocks, labels: np.ndarray | None) -> tuple[np.ndarray, list[str]]:
    """(K, m) component index of each residual row of a group and the components' names."""
    K, m = blocks.residual.shape
    names = COMPONENTS[name]
    if names is None:  # one component per label (station), all rows of a reading
        uniq = [str(u) for u in np.unique(labels)] if labels is not None else ["all"]
        idx = np.searchsorted(np.unique(labels), labels) if labels is not None else np.zeros(K, np.int64)
        return np.repeat(idx[:, None], m, axis=1), uniq
    comp = list(dict.fromkeys(names))
    return np.tile(np.array([comp.index(n) for n in names[:m]]), (K, 1)), comp


def scale_blocks(blocks: fx.LinearBlocks, factor_rows: np.ndarray) -> fx.LinearBlocks:
    """``blocks`` with each row's variance multiplied by ``factor_rows`` (K, m)."""
    s = np.sqrt(factor_rows)
    if blocks.whiten is None:
        return fx.LinearBlocks(blocks.keys, blocks.jacobians, blocks.residual, blocks.sigma * s, blocks.huber_k,
                               None, blocks.group)
    return fx.LinearBlocks(blocks.keys, blocks.jacobians, blocks.residual, blocks.sigma, blocks.huber_k,
                           blocks.whiten / s[:, :, None], blocks.group)


@dataclass
class GroupEstimate:
    """One component's estimate: ``factor`` (true over configured variance), its ``sigma``,
    ``applied`` (what the last solve used), ``redundancy`` ``r``, ``rows`` ``n``, ``slope``: the
    share of a change of the true factor that the plain estimate shows (``r / n``, or ``t / r``
    from a low-share component's own draws, module docstring), ``fixed_point``: the estimate is
    the fixed point itself (a low-share component's), not one step towards it."""

    factor: float
    sigma: float
    applied: float
    redundancy: float
    rows: int
    slope: float = 1.0
    fixed_point: bool = False

    def to_json(self, configured_sigma: float | None, unit: str) -> dict:
        out = {"variance_factor": self.factor, "variance_factor_sigma": self.sigma,
               "sigma_scale": float(np.sqrt(self.factor)),
               "sigma_scale_sigma": float(self.sigma / (2 * np.sqrt(self.factor))),
               "applied_variance_factor": self.applied, "redundancy": self.redundancy, "rows": self.rows,
               "slope": self.slope}
        if configured_sigma is not None:
            out[f"configured_sigma_{unit}"] = configured_sigma
            out[f"estimated_sigma_{unit}"] = float(configured_sigma * np.sqrt(self.factor))
        return out


#: builders whose rows are of another group's noise: a chunk's wheel-path pairs whose front point
#: the previous chunk holds (fusion/chunks.py) are the wheel path's
SAME_NOISE_AS = {HAND_OVER_BUILDER: "wheel_path"}


@dataclass
class NoiseComponents:
    """The variance factors applied per group and component, and the last estimates;
    ``quanta_m``: the quantum of a group's readings, by group (module docstring); ``fixed``:
    the factors are given (a later chunk applies its run's first chunk's, fusion/chunks.py) and
    not estimated."""

    applied: dict[str, dict[str, float]] = field(default_factory=dict)
    estimates: dict[str, dict[str, GroupEstimate]] = field(default_factory=dict)
    refits: int = 0
    seed: int = 0
    quanta_m: dict[str, float] = field(default_factory=dict)
    fixed: bool = False

    def applied_per_row(self, name: str) -> np.ndarray:
        """The variance factor applied to each residual row of group ``name`` (one per entry of
        :data:`COMPONENTS`; 1 where its component has none), e.g. (3,) e, n, u for ``gnss_error``."""
        applied = self.applied.get(name, {})
        return np.array([applied.get(c, 1.0) for c in COMPONENTS[name]])

    def wrap(self, builders: list, labels: dict[str, np.ndarray]) -> list:
        """``builders`` (name, build) with the applied factors of their groups (the others as they are)."""
        out = []
        for name, build in builders:
            group = SAME_NOISE_AS.get(name, name)
            if group not in COMPONENTS or group not in self.applied:
                out.append((name, build))
                continue
            out.append((name, self._scaled(group, build, labels.get(name))))
        return out

    def _scaled(self, name: str, build: Callable, labels: np.ndarray | None) -> Callable:
        applied = self.applied[name]

        def scaled(state) -> fx.LinearBlocks:
            blocks = build(state)
            idx, comp = _component_index(name, blocks, labels)
            f = np.array([applied.get(c, 1.0) for c in comp])
            return scale_blocks(blocks, f[idx])
        return scaled

    def update(self, builders: list, state, gfg: gtsam.GaussianFactorGraph, graph_factors: int,
               factor: TreeFactor, labels: dict[str, np.ndarray]) -> bool:
        """Estimate every group's factors from a solve (module docstring): ``builders`` its
        (wrapped) vectorised factors' builders, ``state`` its estimate, ``gfg`` its (last)
        linearisation, whose first ``graph_factors`` factors are the GTSAM-built ones, and
        ``factor`` that linearisation's Bayes tree (fusion/normal_solve.py). Returns whether an
        applied factor moved enough to solve again."""
        if not any(n in COMPONENTS for n, _ in builders):
            return False
        blocks = {n: b(state) for n, b in builders}
        weighted = _weighted_slots(blocks, factor)
        products = _hat_products(_graph_groups(gfg, graph_factors), weighted, factor, self.seed)
        moved = False
        for name, blk in blocks.items():
            if name not in COMPONENTS:
                continue
            idx, comp = _component_index(name, blk, labels.get(name))
            inlier = _inliers(blk, idx, len(comp), products[name].mean(axis=0), self.quanta_m.get(name, 0.0)) \
                if blk.huber_k is not None else np.ones(blk.residual.shape[0], bool)  # module docstring: outliers
            rows = [(idx == c) & inlier[:, None] for c in range(len(comp))]
            own = _own_draws(name, blocks, weighted, rows, products[name], factor, self.seed)
            new = {}
            for c, cname in enumerate(comp):
                f0 = self.applied.get(name, {}).get(cname, 1.0)
                g = _component_estimate(blk, products[name], rows[c], f0, own.get(c))
                new[cname] = g
                target = _next_factor(g, floor=name in FLOOR_GROUPS)
                if abs(target / f0 - 1.0) > MIN_CHANGE:
                    moved = True
                    # a new dict: the graph solved holds the old one (its last step stays its own)
                    self.applied[name] = {**self.applied.get(name, {}), cname: target}
            self.estimates[name] = new
        if moved and self.refits < MAX_REFITS:
            self.refits += 1
            return True
        for name, comps in self.estimates.items():  # no new solve: what the last one used is applied
            self.applied[name] = {c: g.applied for c, g in comps.items()}
        return False


def _next_factor(g: GroupEstimate, floor: bool) -> float:
    """The factor the next solve applies from the estimate ``g`` of a solve that applied
    ``g.applied``: 1 (the datasheet) unless the estimate is significant (module docstring) or a
    factor is applied already; a ``floor`` group's (:data:`FLOOR_GROUPS`) never below 1. Once
    applied, a factor follows its estimates and does not fall back to 1 when one of them lies
    inside the gate: an estimate near the gate would otherwise switch it on and off between
    solves (the hour of benchmarks/speed.py: the GNSS correlated part's 0.69 +- 0.09, applied;
    then 0.74 +- 0.10, back to 1; then 0.69 again, until the refits ran out)."""
    f0, f = g.applied, g.factor
    significant = abs(f - 1.0) > max(SIGNIFICANCE * g.sigma, MIN_CHANGE)
    if not (significant or f0 != 1.0) or (floor and f < 1.0):
        return 1.0
    return _rounded(f) if g.fixed_point else _newton_step(f0, f, g.slope)


def _newton_step(f0: float, f: float, redundancy_share: float) -> float:
    """The factor to apply next, from the estimate ``f`` of a solve that applied ``f0``.

    The estimate is a fixed-point map of the applied factor whose slope at the answer is the
    group's share of the fit, ``1 - r / n`` (exactly so for one observed state, and the mean
    over the group's rows otherwise): with a low redundancy the plain iteration ``f0 <- f``
    crawls (``r / n = 0.2``: 20 % of the way per solve). The Newton step on that slope, in
    logarithms (a factor stays positive), with the step at most :data:`MAX_STEP_GAIN` times the
    plain one; rounded to :data:`APPLIED_DIGITS` significant digits."""
    gain = min(1.0 / max(redundancy_share, 1e-9), MAX_STEP_GAIN)
    return _rounded(f0 * np.exp(np.log(f / f0) * gain))


def _rounded(f: float) -> float:
    """``f`` to :data:`APPLIED_DIGITS` significant digits."""
    return float(f"{f:.{APPLIED_DIGITS}g}")


def _component_estimate(blk: fx.LinearBlocks, products: np.ndarray, rows: np.ndarray, f0: float,
                        own: tuple[float, float, float, float] | None = None) -> GroupEstimate:
    """The estimate (module docstring) of the component whose residual rows are ``rows`` (K, m)
    bool, from the draws' row products ``z (H z)`` (D, K, m) and the factor ``f0`` applied; a
    low-share component's ``own`` draws (:func:`_own_draws`: ``r``, its Monte Carlo error, ``t``,
    the robust rows' share ``c``) make it the fixed point (module docstring, "Low-share components")."""
    n = int(rows.sum())
    square_sum = f0 * float((blk.whitened()[rows] ** 2).sum())  # unweighted: a Huber weight would bias it low
    if own is not None:
        r, r_sd, t, robust = max(own[0], 1.0), own[1], max(own[2], 1.0), own[3]
        f = max(_posterior_mode(square_sum - f0 * (r - t - robust), t), PRIOR_DOF / (PRIOR_DOF + t))
        sigma = float(np.hypot(f * np.sqrt(2.0 / (PRIOR_DOF + t)), f0 * r_sd / t))
        return GroupEstimate(f, sigma, f0, r, n, t / r, fixed_point=True)
    per_draw = np.array([p[rows].sum() for p in products])
    r = max(n - float(per_draw.mean()), 1.0)
    r_sd = float(per_draw.std(ddof=1) / np.sqrt(per_draw.size)) if per_draw.size > 1 else 0.0
    f = max(_posterior_mode(square_sum, r), PRIOR_DOF / (PRIOR_DOF + r))
    sigma = f * float(np.hypot(np.sqrt(2.0 / (PRIOR_DOF + r)), r_sd / r))
    return GroupEstimate(f, sigma, f0, r, n, r / max(n, 1))


def _own_draws(name: str, blocks: dict[str, fx.LinearBlocks], weighted: dict[str, tuple[list, list]],
               rows: list[np.ndarray], products: np.ndarray, factor: TreeFactor, seed: int
               ) -> dict[int, tuple[float, float, float, float]]:
    """Per component ``c`` of group ``name``'s ``rows`` (each (K, m) bool) whose redundancy share
    from the shared draws ``products`` (D, K, m) is below :data:`LOW_SHARE`: its redundancy
    ``r = tr((I - H)_gg)``, that estimate's Monte Carlo error, ``t = tr((I - H)_gg^2)``, from
    :data:`DRAWS` right-hand sides ``z`` on its own rows only (``E[z^T (I - H) z]`` and
    ``E[|((I - H) z)_g|^2]``), and what the other Huber-weighted groups of ``blocks``
    (:func:`robust_rows`: each one's slot of ``weighted`` and the variance its weights take off,
    ``1 - rho``) take off the other rows' ``r - t``: ``E[|(H x)_g|^2]`` over as many draws
    ``x ~ N(0, 1 - rho)`` on their rows (module docstring, "Robust rows"). ``weighted``: every
    group's rows in ``factor`` and weighted Jacobians (:func:`_weighted_slots`). One pair of
    triangular passes for all."""
    low = [c for c, m in enumerate(rows) if m.any() and
           1.0 - float(np.mean([p[m].sum() for p in products])) / m.sum() < LOW_SHARE]
    if not low:
        return {}
    robust = robust_rows(blocks, name, weighted)
    rng = np.random.default_rng(seed + 1)
    idx, Js = weighted[name]
    own = len(low) * DRAWS
    mask = np.concatenate([np.repeat(rows[c][:, :, None], DRAWS, axis=2) for c in low], axis=2)
    z = np.zeros(mask.shape[:2] + (own + (DRAWS if robust else 0),))
    z[:, :, :own] = rng.standard_normal(mask.shape) * mask  # (K, m, DRAWS x len(low))
    slots = [(idx, Js, z)]
    for rows_idx, rJs, taken in robust:
        zr = np.zeros(rJs[0].shape[:2] + (z.shape[2],))
        zr[:, :, own:] = np.sqrt(taken) * rng.standard_normal(rJs[0].shape[:2] + (DRAWS,))
        slots.append((rows_idx, rJs, zr))
    fitted = _fitted(idx, Js, _normal_solution(factor, slots))
    res = (z[:, :, :own] - fitted[:, :, :own]) * mask  # ((I - H) z) on the rows
    t1 = np.einsum("kmd,kmd->d", z[:, :, :own], res).reshape(len(low), DRAWS)
    t2 = np.einsum("kmd,kmd->d", res, res).reshape(len(low), DRAWS)
    robust_sq = fitted[:, :, own:] ** 2  # |(H x)|^2 of the robust rows' draws, per row (empty without)
    taken_off = [float(np.mean(np.sum(robust_sq * rows[c][:, :, None], axis=(0, 1)))) if robust else 0.0
                 for c in low]
    return {c: (float(a.mean()), float(a.std(ddof=1) / np.sqrt(DRAWS)), float(b.mean()), off)
            for c, a, b, off in zip(low, t1, t2, taken_off)}


def robust_rows(blocks: dict[str, fx.LinearBlocks], name: str, weighted: dict[str, tuple[list, list]]
                ) -> list[tuple[list, list, float]]:
    """The Huber-weighted groups of ``blocks`` other than ``name`` whose weights take variance
    off (module docstring, "Robust rows"), as :func:`_own_draws` takes them: per group, its rows
    and weighted Jacobians (its slot of ``weighted``) and ``1 - rho``, ``rho = sum(w e^2) /
    sum(e^2)`` the share of its whitened residuals' square sum its Huber weights ``w`` keep."""
    out = []
    for other, blk in blocks.items():
        if other == name or blk.huber_k is None or blk.residual.size == 0:
            continue
        e2 = np.sum(blk.whitened() ** 2, axis=1)
        rho = float(np.sum(blk.weights() * e2) / max(float(e2.sum()), 1e-300))
        if rho < 1.0:
            out.append((*weighted[other], 1.0 - rho))
    return out


def _weighted_slots(blocks: dict[str, fx.LinearBlocks], factor: TreeFactor) -> dict[str, tuple[list, list]]:
    """Per vectorised group: its keys' rows in ``factor`` (K, d) and its whitened, Huber-weighted
    Jacobians (K, m, d), per key slot; made once per estimate for the hat products and the own
    draws."""
    out = {}
    for name, blk in blocks.items():
        Js = blk.weighted_jacobians()
        out[name] = ([factor.rows(k, J.shape[2]) for k, J in zip(blk.keys, Js)], Js)
    return out


def _posterior_mode(square_sum: float, redundancy: float) -> float:
    """The variance factor ``f = exp(u)`` at the posterior's mode (module docstring): the root of
    ``r + PRIOR_DOF u = W exp(-u)``, ``W`` = ``square_sum`` = ``f0 Omega``, ``r`` = ``redundancy``
    >= 1. The left side rises and the right falls in ``u``, so the root is unique; it lies between
    0 and ``log(W / r)`` (``-r / PRIOR_DOF`` when ``W`` is 0)."""
    r, w = float(redundancy), float(square_sum)
    if w <= 0.0:
        return float(np.exp(-r / PRIOR_DOF))
    log_w = float(np.log(w))
    end = log_w - float(np.log(r))

    def excess(u: float) -> float:  # W exp(-u) <= r between the ends: no overflow
        return r + PRIOR_DOF * u - np.exp(log_w - u)

    return float(np.exp(0.0 if end == 0.0 else brentq(excess, min(0.0, end), max(0.0, end), xtol=1e-14, rtol=1e-14)))


def _inliers(blk: fx.LinearBlocks, idx: np.ndarray, n_comp: int, hat: np.ndarray, quantum: float = 0.0) -> np.ndarray:
    """(K,) the factors inside the gate :data:`GATE_TAIL` on the robust scale of their
    components: each component's variance factor from the median of its squared whitened
    residuals over its redundancy share ``1 - mean(h)`` (``h`` the draws' estimate of the hat
    matrix's diagonal), then each factor's squared whitened residual, scaled by it, against the
    chi-square quantile of its rows. With a ``quantum`` (the residual's unit, e.g. m), a factor
    whose every residual is at most one quantum is inside whatever the gate says."""
    e2 = blk.whitened() ** 2
    scale = np.ones(n_comp)
    for c in range(n_comp):
        rows = idx == c
        if rows.any():
            share = float(np.clip(1.0 - hat[rows].mean(), 0.05, 1.0))
            scale[c] = max(np.median(e2[rows]) / (chi2.median(1) * share), 1e-300)
    q = np.sum(e2 / scale[idx], axis=1)
    inside = q <= chi2.ppf(1.0 - GATE_TAIL, blk.residual.shape[1])
    if quantum > 0.0:
        inside |= np.all(np.abs(blk.residual) <= quantum, axis=1)
    return inside


def _hat_products(graph_groups: list, weighted: dict[str, tuple[list, list]], factor: TreeFactor,
                  seed: int) -> dict[str, np.ndarray]:
    """Per estimated group, the row products ``z * (H z)`` (D, K, m) of :data:`DRAWS` random
    right-hand sides (module docstring: their sum over a component's rows is the Hutchinson
    estimate of its ``tr(H)``, their mean per row of ``H``'s diagonal). ``weighted``: every
    vectorised factor group's rows and weighted Jacobians at the solution (:func:`_weighted_slots`);
    ``graph_groups``: the other factors' whitened blocks (:func:`_graph_groups`); ``factor``: the
    solve's Bayes tree (fusion/normal_solve.py), with which ``H z = A (A^T A)^-1 A^T z`` costs two
    triangular passes for all draws at once."""
    rng = np.random.default_rng(seed)
    graph_slots = [([factor.rows(k, J.shape[2]) for k, J in zip(keys, Js)], Js) for keys, Js in graph_groups]
    slots = graph_slots + list(weighted.values())  # (rows, J) per slot
    names = [None] * len(graph_groups) + list(weighted)
    z = [rng.standard_normal(Js[0].shape[:2] + (DRAWS,)) for _, Js in slots]  # (K, m, D) per group
    delta = _normal_solution(factor, [(idx_slots, Js, zg) for (idx_slots, Js), zg in zip(slots, z)])
    return {n: np.moveaxis(zg * _fitted(idx_slots, Js, delta), 2, 0)
            for n, (idx_slots, Js), zg in zip(names, slots, z) if n in COMPONENTS}


def _normal_solution(factor: TreeFactor, slots: list[tuple[list, list, np.ndarray]]) -> np.ndarray:
    """``delta = (A^T A)^-1 A^T z`` (N, D) for D right-hand sides ``z`` on the rows of ``slots``
    (each: its keys' rows in ``factor`` (K, d) per key, the weighted Jacobians (K, m, d) per key,
    ``z`` (K, m, D)), with ``factor``'s Bayes tree: two triangular passes for all draws."""
    grad = np.zeros((factor.size, slots[0][2].shape[2]))  # A^T z, per draw
    for idx_slots, Js, z in slots:
        for idx, J in zip(idx_slots, Js):
            _scatter_add(grad, idx, np.matmul(J.transpose(0, 2, 1), z))
    return solve_normal(factor, grad)


def _fitted(idx_slots: list, Js: list, delta: np.ndarray) -> np.ndarray:
    """``A delta`` (K, m, D) on one slot's rows (:func:`_normal_solution`'s slot layout)."""
    return sum(np.matmul(J, delta[idx]) for idx, J in zip(idx_slots, Js))


def _scatter_add(out: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """``out[rows] += values`` with repeated rows summed: ``out`` (N, D), ``rows`` (K, d),
    ``values`` (K, d, D) (as one sparse product: ``np.add.at`` is ten times slower)."""
    flat = rows.ravel()
    ones = np.ones(flat.size)
    scatter = csr_matrix((ones, (flat, np.arange(flat.size))), shape=(out.shape[0], flat.size))
    out += scatter @ values.reshape(flat.size, -1)


def _graph_groups(gfg: gtsam.GaussianFactorGraph, count: int) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
    """The first ``count`` factors of ``gfg`` (the GTSAM-built ones, already whitened), grouped
    by their shape (their keys' dimensions and their rows): per group, the keys (K,) and the
    blocks (K, m, d) of each of its key slots."""
    groups: dict[tuple, tuple[list, list]] = {}
    for i in range(count):
        f = gfg.at(i)
        if f is None:
            continue
        A, _ = f.jacobian()
        keys = list(f.keys())
        keys_of, A_of = groups.setdefault((tuple(key_dim(k) for k in keys), A.shape[0]), ([], []))
        keys_of.append(keys)
        A_of.append(A)
    out = []
    for (dims, _), (keys_of, A_of) in groups.items():
        keys, A = np.array(keys_of, dtype=np.uint64), np.stack(A_of)
        cuts = np.cumsum((0,) + dims)
        out.append(([keys[:, j] for j in range(len(dims))], [A[:, :, cuts[j]:cuts[j + 1]] for j in range(len(dims))]))
    return out


def configured_sigmas(fs) -> dict[str, dict[str, tuple[float, str]]]:
    """The configured sigma and its unit of each component, from the factor settings ``fs``
    (fusion/settings.py ``FactorSettings``); the total stations' readings have a full
    covariance of the instrument's precision, and only a factor."""
    lat, ver = fs.nhc.sigmas_mps() * 1e3
    return {"nhc": {"lateral": (float(lat), "mm_per_s"), "vertical": (float(ver), "mm_per_s")},
            "odometer": {"along": (fs.odometer.sigma_mm, "mm")},
            "wheel_path": {"lateral": (fs.wheel_path.sigma_mm, "mm"), "vertical": (fs.wheel_path.sigma_mm, "mm")},
            "gnss_error": {"horizontal": (fs.gnss.correlated_sigma_h_mm, "mm"),
                           "vertical": (fs.gnss.correlated_sigma_v_mm, "mm")},
            "inclinometer": {"tilt": (fs.inclinometer.sigma_mrad, "mrad")}}


def components_json(est: NoiseComponents, fs) -> dict:
    """metrics.json's entry per group (``noise_estimates``): each component's estimate, its
    1-sigma, the factor applied, the redundancy, and the configured and estimated sigma."""
    conf = configured_sigmas(fs)
    out = {}
    for name, comps in est.estimates.items():
        out[name] = {c: g.to_json(*conf.get(name, {}).get(c, (None, ""))) for c, g in comps.items()}
    return {"groups": out, "refits": est.refits, "draws": DRAWS, "prior_dof": PRIOR_DOF}


def summary_lines(est: NoiseComponents, fs) -> list[str]:
    """One line per group: the configured and estimated sigmas and the factor applied."""
    conf = configured_sigmas(fs)
    lines = []
    for name, comps in est.estimates.items():
        parts = []
        for c, g in comps.items():
            value, unit = conf.get(name, {}).get(c, (None, ""))
            est_txt = (f"{value:.3g} -> {value * np.sqrt(g.factor):.3g} {unit.replace('_per_', '/')}"
                       if value is not None else f"sigma x {np.sqrt(g.factor):.2f}")
            parts.append(f"{c} {est_txt} (+-{g.sigma / (2 * np.sqrt(g.factor)) * 100:.0f} %"
                         + (f", applied x {np.sqrt(g.applied):.2f}" if g.applied != 1.0 else "") + ")")
        lines.append(f"noise of {name}: " + "; ".join(parts))
    return lines
