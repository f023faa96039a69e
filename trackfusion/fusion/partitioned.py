"""Exact partitioned Gauss-Newton step: the run's linear system solved in time parts
(``smoother.part_s``), with the one-batch answer.

Each linearised factor belongs to one **part**: the part (by time, cut every ``part_s`` seconds
from the first keyframe; never by the number of CPUs) of the earliest keyframe it involves, or
of its earliest state when it involves no keyframe. A
state's time is its keyframe's (``X``, ``V``), its segment's first keyframe's (bias ``B``,
odometer scale ``S``), its fix's (GNSS correlated error ``E``), or the run's start (station
corrections ``T``). A variable whose factors all belong to one part is **interior** to it;
one with factors in two parts or more is a **separator** variable: the keyframes at a cut and
the states the parts share (a bias or scale segment across a cut, the GNSS error chain across
it, the station set-ups seen in several parts).

One step (:meth:`PartitionedSolver.solve`; in ``smoother.workers`` local processes,
trackfusion/parallel.py, with the same numbers): each part's factors are reduced by eliminating its
interior variables (multifrontal QR in COLAMD's order with the part's separator variables
last: GTSAM ``eliminatePartialMultifrontal``), which leaves a Gaussian Bayes tree of the
interior given the separator and the reduced (Schur complement) factors on the separator. The
separator system (every part's reduced factors) is solved, and each part's Bayes tree is
back-substituted given the separator's values, clique by clique from its root (the wrapper's
Bayes tree has no ``optimize(given)``; its conditionals' ``solve`` does each clique). No approximation is
made: the step is the one-batch step to rounding, so the cost, the line search's and the
gating's decisions are the batch's.

Marginals (:class:`PartMarginals`): the marginal of a variable of part ``p`` is that of part
``p``'s factors together with the other parts' reduced factors (the information the rest of the
run holds on the separator), which is exact as well.

Why hand-written: GTSAM has no partitioned solver in its Python wrapper; this is its partial
elimination, applied per part.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..errors import FusionError
from ..parallel import groups_of, run_step

_INDEX_MASK = (1 << 56) - 1


def key_times(keys: np.ndarray, t_key: np.ndarray, bias_seg: np.ndarray, scale_seg: np.ndarray | None,
              gnss_t_s: np.ndarray | None) -> np.ndarray:
    """Time [s] (M,) of each GTSAM key (M,) of the smoother's variables (module docstring)."""
    keys = np.asarray(keys, dtype=np.uint64)
    c = (keys >> np.uint64(56)).astype(np.int64)
    i = (keys & np.uint64(_INDEX_MASK)).astype(np.int64)
    t = np.full(keys.size, t_key[0])
    kv = (c == ord("x")) | (c == ord("v"))
    t[kv] = t_key[i[kv]]
    b = c == ord("b")
    t[b] = t_key[np.searchsorted(bias_seg, i[b], "left")]
    if scale_seg is not None:
        s = c == ord("s")
        t[s] = t_key[np.searchsorted(scale_seg, i[s], "left")]
    if gnss_t_s is not None:
        e = c == ord("e")
        t[e] = gnss_t_s[i[e]]
    return t


def cut_times(t0: float, t1: float, part_s: float) -> np.ndarray:
    """The part boundaries (P-1,) [s] of a run from ``t0`` to ``t1``: every ``part_s`` from
    ``t0``; a last part shorter than a tenth of ``part_s`` joins the one before."""
    cuts = t0 + part_s * np.arange(1, int(np.ceil((t1 - t0) / part_s)) + 1)
    cuts = cuts[cuts < t1]
    if cuts.size and t1 - cuts[-1] < 0.1 * part_s:
        cuts = cuts[:-1]
    return cuts


@dataclass
class Partition:
    """The parts of one run: the cut times (P-1,) [s], the means to time its keys, and the
    number of processes to solve them in."""

    cuts_t_s: np.ndarray
    t_key: np.ndarray
    bias_seg: np.ndarray
    scale_seg: np.ndarray | None
    gnss_t_s: np.ndarray | None
    workers: int = 1  # processes a step's parts are dealt to (trackfusion/parallel.py)

    @property
    def count(self) -> int:
        return int(self.cuts_t_s.size) + 1

    def part_of_keys(self, keys: np.ndarray) -> np.ndarray:
        """Part index (M,) of each key (M,)."""
        t = key_times(keys, self.t_key, self.bias_seg, self.scale_seg, self.gnss_t_s)
        return np.searchsorted(self.cuts_t_s, t, "right")

    def layout(self, gfg: gtsam.GaussianFactorGraph) -> "Layout":
        """Which part each factor of ``gfg`` belongs to, and each part's interior keys."""
        sizes, flat = [], []
        for i in range(gfg.size()):
            f = gfg.at(i)
            ks = f.keys() if f is not None else []
            sizes.append(len(ks))
            flat.extend(ks)
        sizes = np.asarray(sizes, np.int64)
        flat_keys = np.asarray(flat, np.uint64)
        owner = np.repeat(np.arange(sizes.size), sizes)
        part_key = self.part_of_keys(flat_keys)
        c = (flat_keys >> np.uint64(56)).astype(np.int64)
        big = np.iinfo(np.int64).max
        factor_part = np.full(sizes.size, -1, np.int64)
        has = sizes > 0
        first = np.r_[0, np.cumsum(sizes)[:-1]][has]
        # by its keyframes when it has any (a factor on a keyframe and a bias segment that began in
        # the part before belongs to the keyframe's part), else by its other states
        by_keyframe = np.minimum.reduceat(np.where((c == ord("x")) | (c == ord("v")), part_key, big), first)
        factor_part[has] = np.where(by_keyframe < big, by_keyframe, np.minimum.reduceat(part_key, first))
        # a key's parts: the parts of the factors on it
        kp = factor_part[owner]
        uniq, inv = np.unique(flat_keys, return_inverse=True)
        lo = np.full(uniq.size, np.iinfo(np.int64).max)
        hi = np.full(uniq.size, -1)
        np.minimum.at(lo, inv, kp)
        np.maximum.at(hi, inv, kp)
        interior = [uniq[(lo == p) & (hi == p)] for p in range(self.count)]
        home = dict(zip(uniq.tolist(), lo.tolist()))
        return Layout(factor_part, interior, uniq[lo != hi], home)


@dataclass
class Layout:
    """factor_part (F,) the part of each factor (-1: an empty slot); interior: per part its
    interior keys; separator: the keys shared by parts; home: key -> the first part it is in."""

    factor_part: np.ndarray
    interior: list[np.ndarray]
    separator: np.ndarray
    home: dict[int, int]


@dataclass
class _Reduced:
    """One part eliminated: its factors, the Bayes tree of its interior given the separator,
    and the reduced factors on the separator."""

    graph: gtsam.GaussianFactorGraph
    net: list | None  # the Bayes tree's conditionals, each after the ones it is conditioned on
    reduced: gtsam.GaussianFactorGraph


def _reduce(graph: gtsam.GaussianFactorGraph, interior: np.ndarray) -> _Reduced:
    if interior.size == 0:
        return _Reduced(graph, None, graph)
    keys = set(int(k) for k in interior)
    rest = [int(k) for k in graph.keyVector() if int(k) not in keys]
    full = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(graph, rest) if rest else \
        gtsam.Ordering.ColamdGaussianFactorGraph(graph)
    ordering = gtsam.Ordering()
    for i in range(full.size() - len(rest)):
        ordering.push_back(full.at(i))
    try:
        tree, reduced = graph.eliminatePartialMultifrontal(ordering, gtsam.EliminateQR)
    except RuntimeError:
        raise FusionError("the factor graph is singular (a state no measurement determines)") from None
    return _Reduced(graph, _top_down(tree, ordering), reduced)


def _top_down(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering) -> list:
    """The conditionals of ``tree``'s cliques, each after the cliques it is conditioned on: in
    reverse elimination order of their last frontal variable (a parent clique's variables are
    eliminated after its children's)."""
    cliques = {}
    for i in range(ordering.size() - 1, -1, -1):
        cond = tree[ordering.at(i)].conditional()
        first = cond.firstFrontalKey()
        if first not in cliques:
            cliques[first] = cond
    return list(cliques.values())


def _eliminate_all(graph: gtsam.GaussianFactorGraph) -> gtsam.GaussianBayesTree:
    try:
        return graph.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(graph), gtsam.EliminateQR)
    except RuntimeError:
        raise FusionError("the factor graph is singular (a state no measurement determines)") from None


def _union(graphs) -> gtsam.GaussianFactorGraph:
    out = gtsam.GaussianFactorGraph()
    for g in graphs:
        out.push_back(g)
    return out


class PartitionedSolver:
    """Solves linearised graphs of one structure part by part (module docstring). The layout
    is computed on the first graph and reused while the graphs keep its size (the iterations of
    one Gauss-Newton solve)."""

    def __init__(self, partition: Partition, workers: int = 1):
        self.partition, self.workers = partition, workers
        self.layout: Layout | None = None
        self._size = -1

    def split(self, gfg: gtsam.GaussianFactorGraph) -> list[gtsam.GaussianFactorGraph]:
        """The factors of ``gfg`` per part."""
        if self.layout is None or gfg.size() != self._size:
            self.layout, self._size = self.partition.layout(gfg), gfg.size()
        parts = [gtsam.GaussianFactorGraph() for _ in range(self.partition.count)]
        for i, p in enumerate(self.layout.factor_part.tolist()):
            if p >= 0:
                parts[p].push_back(gfg.at(i))
        return parts

    def solve(self, gfg: gtsam.GaussianFactorGraph) -> tuple[gtsam.VectorValues, "PartMarginals"]:
        """The Gauss-Newton step of ``gfg`` and the means to its marginals."""
        parts = self.split(gfg)
        interior = self.layout.interior
        held: dict[int, _Reduced] = {}  # in the process that reduced them (trackfusion/parallel.py)

        def reduce(group: list[int]) -> list[gtsam.GaussianFactorGraph]:
            held.update({p: _reduce(parts[p], interior[p]) for p in group})
            return [held[p].reduced for p in group]

        def solve_separator(reduced: list[list[gtsam.GaussianFactorGraph]]) -> gtsam.VectorValues:
            if not self.layout.separator.size:
                return gtsam.VectorValues()
            return _eliminate_all(_union(g for group in reduced for g in group)).optimize()

        def back_substitute(group: list[int], given: gtsam.VectorValues) -> dict[int, np.ndarray]:
            out = {}
            for p in group:
                if held[p].net is not None:
                    sol = gtsam.VectorValues(given)
                    for cond in held[p].net:
                        sol.insert(cond.solve(sol))
                    out.update((int(k), sol.at(int(k))) for k in interior[p])
            return out

        separator, reduced, steps = run_step(groups_of(len(parts), self.workers), reduce, solve_separator,
                                             back_substitute)
        delta = gtsam.VectorValues(separator)
        for step in steps:
            for k, v in step.items():
                delta.insert(k, v)
        flat = [g for group in reduced for g in group]
        return delta, PartMarginals([_Reduced(parts[p], None, flat[p]) for p in range(len(parts))], self.layout)


class PartMarginals:
    """The marginals of a partitioned solve, with the Bayes tree's calls the smoother uses
    (``marginalCovariance``, ``marginalFactor``, ``joint``): a key's are those of the tree of
    its part's factors and the other parts' reduced factors (exact; module docstring)."""

    def __init__(self, reduced: list[_Reduced], layout: Layout):
        self._reduced, self._layout = reduced, layout
        self._trees: dict[int, gtsam.GaussianBayesTree] = {}

    def tree(self, key: int) -> gtsam.GaussianBayesTree:
        p = self._layout.home[int(key)]
        if p not in self._trees:
            g = _union([self._reduced[p].graph] + [r.reduced for q, r in enumerate(self._reduced) if q != p])
            self._trees = {p: _eliminate_all(g)}  # one part's tree at a time: memory of one part
        return self._trees[p]

    def marginalCovariance(self, key: int) -> np.ndarray:
        return self.tree(key).marginalCovariance(key)

    def marginalFactor(self, key: int, function=gtsam.EliminateQR):
        return self.tree(key).marginalFactor(key, function)

    def joint(self, a: int, b: int):
        return self.tree(a).joint(a, b)
