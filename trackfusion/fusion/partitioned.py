"""Exact partitioned Gauss-Newton step: the run's linear system solved in time parts
(``smoother.part_s``), with the one-batch answer.

Each linearised factor belongs to one **part**: the part (by time, cut every ``part_s`` seconds
from the first keyframe; never by the number of CPUs) of the earliest keyframe it involves, or
of its earliest state when it involves no keyframe. A
state's time is its keyframe's (``X``, ``V``), its segment's first keyframe's (bias ``B``,
odometer scale ``S`` and its drift rate ``D``), its fix's (GNSS correlated error ``E``), or the
run's start (station corrections ``T``). A variable whose factors all belong to one part is
**interior** to it; one with factors in two parts or more is a **separator** variable: the keyframes at a cut and
the states the parts share (a bias or scale segment across a cut, the GNSS error chain across
it, the station set-ups seen in several parts).

One step (:meth:`PartitionedSolver.solve`; in ``smoother.workers`` local processes,
trackfusion/parallel.py, with the same numbers): each part's factors are reduced by eliminating its
interior variables (multifrontal QR in COLAMD's order with the part's separator variables
last: GTSAM ``eliminatePartialMultifrontal``), which leaves a Gaussian Bayes tree of the
interior given the separator and the reduced (Schur complement) factors on the separator. The
separator system (every part's reduced factors) is solved, and each part's Bayes tree is
back-substituted given the separator's values: its cliques' conditionals, in elimination order,
make a Gaussian Bayes net whose ``optimize(given)`` solves them from the root down (the wrapper's
Bayes tree has no ``optimize(given)``). No approximation is
made: the step is the one-batch step to rounding, so the cost, the line search's and the
gating's decisions are the batch's.

Marginals (:class:`PartMarginals`): the marginal of a variable of part ``p`` is that of part
``p``'s factors together with the other parts' reduced factors (the information the rest of the
run holds on the separator), which is exact as well. They are also the one-batch solve's
marginals (:func:`part_marginal_covariances`, parts of :data:`MARGINAL_PART_S` dealt to the
CPUs; :func:`part_marginals` is the same in one process): GTSAM's Bayes-tree
marginals recurse from the root down every clique on the way (each clique's separator marginal
from its parent's), and along the tree of a whole hour's chain that recursion drifts, by up to
0.4 % of a position sigma on the hour of ``benchmarks/speed.py`` against the exact marginal
(every other variable eliminated first, QR), whichever of Cholesky or QR it uses; a part's tree
is short enough to stay within 2e-7 of it. Where a part's cliques are wide (the bridge's, with
the stations and the wheel path's pairs in them), one pass down its tree in square-root
information form gives all its covariances instead, exact to rounding and the cheaper there
(fusion/tree_marginals.py, :meth:`PartMarginals.covariances`).

Why hand-written: GTSAM has no partitioned solver in its Python wrapper; this is its partial
elimination, applied per part.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..errors import FusionError
from ..parallel import PartQueue, dask_client, groups_of, run_step, run_step_dask
from .tree_marginals import cliques_top_down, marginal_covariances, takes_the_pass

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
        s = (c == ord("s")) | (c == ord("d"))  # a scale segment's drift rate: its segment's time
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
    engine: str = "local"  # or "dask": the workers of a Dask cluster (``smoother.engine``)
    address: str | None = None  # the Dask scheduler's; None: a LocalCluster of ``workers`` processes

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
        members = [np.flatnonzero(factor_part == p) for p in range(self.count)]
        return Layout(factor_part, interior, uniq[lo != hi], home, members)


@dataclass
class Layout:
    """factor_part (F,) the part of each factor (-1: an empty slot); interior: per part its
    interior keys; separator: the keys shared by parts; home: key -> the first part it is in;
    members: per part the indices of its factors (ascending)."""

    factor_part: np.ndarray
    interior: list[np.ndarray]
    separator: np.ndarray
    home: dict[int, int]
    members: list[np.ndarray]

    def part_graph(self, gfg: gtsam.GaussianFactorGraph, p: int) -> gtsam.GaussianFactorGraph:
        """Part ``p``'s factors of ``gfg`` (a graph of this layout), in their order in ``gfg``."""
        out = gtsam.GaussianFactorGraph()
        for i in self.members[p].tolist():
            out.push_back(gfg.at(i))
        return out

    def keys_by_part(self, keys) -> dict[int, list[int]]:
        """``keys`` grouped by their home part (part -> keys, in the order given)."""
        by_part: dict[int, list[int]] = {}
        for k in keys:
            by_part.setdefault(self.home[int(k)], []).append(int(k))
        return by_part


@dataclass
class _Reduced:
    """One part eliminated: its factors, the Bayes net of its interior given the separator,
    the reduced factors on the separator, and the elimination ordering of its interior."""

    graph: gtsam.GaussianFactorGraph
    net: gtsam.GaussianBayesNet | None  # the Bayes tree's clique conditionals in elimination order
    reduced: gtsam.GaussianFactorGraph
    ordering: gtsam.Ordering | None = None


def interior_ordering(graph: gtsam.GaussianFactorGraph, interior: np.ndarray) -> gtsam.Ordering:
    """COLAMD's elimination order of ``graph``'s ``interior`` keys, with every other key of the
    graph (its separator keys) constrained last and left out."""
    keys = set(int(k) for k in interior)
    rest = [int(k) for k in graph.keyVector() if int(k) not in keys]
    full = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(graph, rest) if rest else \
        gtsam.Ordering.ColamdGaussianFactorGraph(graph)
    ordering = gtsam.Ordering()
    for i in range(full.size() - len(rest)):
        ordering.push_back(full.at(i))
    return ordering


def _reduce(graph: gtsam.GaussianFactorGraph, interior: np.ndarray, ordering: gtsam.Ordering | None = None
            ) -> _Reduced:
    """Part ``graph`` with its ``interior`` keys eliminated (in ``ordering``: their
    :func:`interior_ordering`, computed when not given; the iterations of one solve share it)."""
    if interior.size == 0:
        return _Reduced(graph, None, graph)
    ordering = ordering if ordering is not None else interior_ordering(graph, interior)
    try:
        tree, reduced = graph.eliminatePartialMultifrontal(ordering, gtsam.EliminateQR)
    except RuntimeError:
        raise FusionError("the factor graph is singular (a state no measurement determines)") from None
    net = gtsam.GaussianBayesNet()
    for cond in reversed(_top_down(tree, ordering)):
        net.push_back(cond)
    return _Reduced(graph, net, reduced, ordering)


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


def _back_substitute(held: dict[int, _Reduced], interior: dict[int, np.ndarray] | list[np.ndarray],
                     group: list[int], given: gtsam.VectorValues) -> dict[int, np.ndarray]:
    """The steps of the interior keys of the reduced parts ``group`` given the separator's."""
    out = {}
    for p in group:
        if held[p].net is not None:
            sol = held[p].net.optimize(given)
            out.update((int(k), sol.at(int(k))) for k in interior[p])
    return out


def _pack(graph: gtsam.GaussianFactorGraph) -> list[str]:
    """A linear graph of Jacobian factors as their GTSAM serialisations (a graph itself does not
    pickle; a factor's text archive keeps every double to the bit). A linearised ``ImuFactor``
    reaches Python as a bare ``GaussianFactor``: ``JacobianFactor(f)`` copies it as it is."""
    out = []
    for i in range(graph.size()):
        f = graph.at(i)
        out.append((f if isinstance(f, gtsam.JacobianFactor) else gtsam.JacobianFactor(f)).serialize())
    return out


def _unpack(packed: list[str]) -> gtsam.GaussianFactorGraph:
    out = gtsam.GaussianFactorGraph()
    for text in packed:
        f = gtsam.JacobianFactor()
        f.deserialize(text)
        out.push_back(f)
    return out


def _ordering_keys(ordering: gtsam.Ordering | None) -> list[int] | None:
    return None if ordering is None else [int(ordering.at(i)) for i in range(ordering.size())]


def _ordering_of(keys: list[int] | None) -> gtsam.Ordering | None:
    return None if keys is None else gtsam.Ordering(keys)


def _pack_values(values: gtsam.VectorValues, keys: np.ndarray) -> dict[int, np.ndarray]:
    """The vectors of ``keys`` (all that ``values`` holds) as a picklable mapping."""
    return {int(k): np.array(values.at(int(k))) for k in keys}


def _unpack_values(packed: dict[int, np.ndarray]) -> gtsam.VectorValues:
    out = gtsam.VectorValues()
    for k, v in packed.items():
        out.insert(k, v)
    return out


class PartWorker:
    """The parts of one group on a Dask worker (an actor: it keeps their eliminations between a
    step's two halves, as Bayes trees do not pickle): the same :func:`_reduce` and
    :func:`_back_substitute` as the local processes, on the parts' factors sent to it."""

    def __init__(self):
        self.held: dict[int, _Reduced] = {}
        self.interior: dict[int, np.ndarray] = {}

    def reduce(self, payload: list[tuple]) -> list[tuple[list[str], list[int] | None]]:
        """``payload``: per part (index, packed factors, interior keys, ordering keys or None)."""
        out = []
        for p, packed, interior, order in payload:
            self.interior[p] = np.asarray(interior, np.uint64)
            self.held[p] = _reduce(_unpack(packed), self.interior[p], _ordering_of(order))
            out.append((_pack(self.held[p].reduced), None if order is not None else _ordering_keys(self.held[p].ordering)))
        return out

    def back_substitute(self, given: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        return _back_substitute(self.held, self.interior, list(self.held), _unpack_values(given))


def _eliminate_all(graph: gtsam.GaussianFactorGraph, ordering: gtsam.Ordering | None = None) -> gtsam.GaussianBayesTree:
    try:
        return graph.eliminateMultifrontal(ordering or gtsam.Ordering.ColamdGaussianFactorGraph(graph), gtsam.EliminateQR)
    except RuntimeError:
        raise FusionError("the factor graph is singular (a state no measurement determines)") from None


def _union(graphs) -> gtsam.GaussianFactorGraph:
    out = gtsam.GaussianFactorGraph()
    for g in graphs:
        out.push_back(g)
    return out


#: length [s] of the parts the sigma columns of a one-batch solve are computed in (module
#: docstring): a fixed length, so that they do not depend on the machine
MARGINAL_PART_S = 600.0


def marginal_covariance(tree, key: int) -> np.ndarray:
    """Marginal covariance of one variable from ``tree`` (a Bayes tree or
    :class:`PartMarginals`): GTSAM's (Cholesky down the tree); when that meets the
    conditioning limit of the elimination, by QR: the marginal is then a conditional
    ``R x = d`` with unit noise, so the covariance is ``R^-1 R^-T``."""
    try:
        return tree.marginalCovariance(key)
    except RuntimeError:
        # keep the conditional alive while reading it: R() of a temporary reads freed memory
        # (marginals of 1e-90 and 0.1 rad seen on open-track-gnss with the wheel-path factor)
        marginal = tree.marginalFactor(key, gtsam.EliminateQR)
        R_inv = np.linalg.inv(np.array(marginal.R()))
        return R_inv @ R_inv.T


def tree_covariances(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering, keys: list[int],
                     exact: bool = False) -> dict[int, np.ndarray]:
    """The marginal covariances of ``keys`` (frontal keys of ``tree``, eliminated in
    ``ordering``): by one pass down the tree where its cliques are wide or ``exact`` is asked for,
    and they hold no hard constraint (fusion/tree_marginals.py ``takes_the_pass``: exact to
    rounding), else by GTSAM's per-key marginals (:func:`marginal_covariance`)."""
    cliques = cliques_top_down(tree, ordering)
    if takes_the_pass(cliques, exact):
        return marginal_covariances(cliques, keys)
    return {k: marginal_covariance(tree, k) for k in keys}


def joint_marginal_covariance(gfg: gtsam.GaussianFactorGraph, keys: list[int]) -> np.ndarray:
    """Joint marginal covariance (sum of dims, square) of ``keys`` (in that order) by QR: every
    other variable eliminated first (COLAMD), the marginal Bayes net ``R x = d`` of the keys
    inverted. Unlike the Bayes tree's per-key marginals (Cholesky of shortcuts), this stays
    valid for the velocities of the stiff graphs here (those came out with zero or 1 m/s sigmas)."""
    full = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(gfg, keys)
    others = gtsam.Ordering()
    for i in range(full.size() - len(keys)):
        others.push_back(full.at(i))
    R, _ = gfg.marginalMultifrontalBayesNet(gtsam.Ordering(keys), others, gtsam.EliminateQR).matrix()
    R_inv = np.linalg.inv(R)
    return R_inv @ R_inv.T


def part_marginal_covariances(partition: Partition, gfg: gtsam.GaussianFactorGraph, keys: list[int],
                              workers: int, joint_keys: list[int] | None = None,
                              made: "PartMarginals | None" = None) -> tuple[dict[int, np.ndarray], np.ndarray | None]:
    """The marginal covariances of ``keys`` in linearised graph ``gfg``, computed in the parts of
    ``partition`` as :class:`PartMarginals` computes them (the same numbers), with the parts
    dealt to ``workers`` processes (trackfusion/parallel.py): each reduces its group of parts,
    every part's reduced factors go to every process, and each then takes the next part not yet
    taken (:class:`~trackfusion.parallel.PartQueue`), eliminates its tree and answers the keys
    that live in it. Only the reduced factors and the covariances cross processes.

    Also returns the joint marginal covariance of ``joint_keys`` (in that order; the sum of their
    dimensions, square) when they are all separator keys (e.g. total-station set-ups seen in
    several parts), else None: the reduced factors of all the parts together are the exact
    marginal information of the separator, so this is :func:`joint_marginal_covariance` of that
    small graph (no Bayes tree of the whole run is walked).

    ``made``: the marginals of a step solved in these parts of ``gfg`` (:meth:`PartitionedSolver.solve`),
    whose layout and reduced factors are the ones made here otherwise (the same numbers): the
    processes then only make the trees, the children reading it from the memory they were forked with."""
    layout = made.layout if made is not None else partition.layout(gfg)
    by_part = layout.keys_by_part(keys)

    def reduce(group: list[int]) -> list[list[str]]:  # packed: a linear graph does not pickle
        if made is not None:
            return []
        return [_pack(_reduce(layout.part_graph(gfg, p), layout.interior[p]).reduced) for p in group]

    # the trees and covariances, each part's in whichever process is free next (PartQueue): the
    # parts' costs differ by up to 3x (docs/solver_speed.md); every process holds every reduced factor
    queue = PartQueue(partition.count)

    def covariances(_group: list[int], packed: list[list[str]]) -> dict[int, np.ndarray]:
        marginals = made if made is not None else PartMarginals(gfg, [_unpack(r) for r in packed], layout)
        return {k: v for p in queue if p in by_part for k, v in marginals.covariances(p, by_part[p]).items()}

    def all_reduced(per_group: list[list[list[str]]]) -> list[list[str]]:
        return [r for group in per_group for r in group]

    packed, _, done = run_step(groups_of(partition.count, workers), reduce, all_reduced, covariances)
    joint = None
    if joint_keys and np.isin(np.asarray(joint_keys, np.uint64), layout.separator).all():
        joint = joint_marginal_covariance(_union(made.reduced if made is not None else (_unpack(r) for r in packed)),
                                          list(joint_keys))
    return {k: v for group in done for k, v in group.items()}, joint


def part_marginals(partition: Partition, gfg: gtsam.GaussianFactorGraph) -> "PartMarginals":
    """The marginals of linearised graph ``gfg`` computed in the parts of ``partition`` (each
    part reduced here as :meth:`PartitionedSolver.solve` reduces it; no step is solved). With
    one part, that part's tree is the whole graph's."""
    layout = partition.layout(gfg)
    if partition.count == 1:
        return PartMarginals(gfg, [gtsam.GaussianFactorGraph()], layout)
    return PartMarginals(gfg, [_reduce(layout.part_graph(gfg, p), layout.interior[p]).reduced
                               for p in range(partition.count)], layout)


class PartitionedSolver:
    """Solves linearised graphs of one structure part by part (module docstring). The layout
    and each part's interior ordering are computed on the first graph and reused while the
    graphs keep its size (the iterations of one Gauss-Newton solve). Each process picks its own
    parts' factors out of the graph (a forked worker reads them from the memory it was forked
    with) and keeps their Bayes nets for the back-substitution."""

    def __init__(self, partition: Partition, workers: int = 1):
        self.partition, self.workers = partition, workers
        self.layout: Layout | None = None
        self._size = -1
        self._orderings: dict[int, gtsam.Ordering] = {}

    def _layout_of(self, gfg: gtsam.GaussianFactorGraph) -> Layout:
        if self.layout is None or gfg.size() != self._size:
            self.layout, self._size, self._orderings = self.partition.layout(gfg), gfg.size(), {}
        return self.layout

    def split(self, gfg: gtsam.GaussianFactorGraph) -> list[gtsam.GaussianFactorGraph]:
        """The factors of ``gfg`` per part."""
        layout = self._layout_of(gfg)
        return [layout.part_graph(gfg, p) for p in range(self.partition.count)]

    def solve(self, gfg: gtsam.GaussianFactorGraph) -> tuple[gtsam.VectorValues, "PartMarginals"]:
        """The Gauss-Newton step of ``gfg`` and the means to its marginals."""
        layout = self._layout_of(gfg)
        interior, orderings = layout.interior, self._orderings
        held: dict[int, _Reduced] = {}  # in the process that reduced them (trackfusion/parallel.py)

        def reduce(group: list[int]) -> list[tuple[list[str], gtsam.Ordering | None]]:
            for p in group:
                held[p] = _reduce(layout.part_graph(gfg, p), interior[p], orderings.get(p))
            # packed: a reduced graph may hold a linearised GTSAM factor between two separator
            # keys as it is, a bare GaussianFactor, which does not pickle; a part's ordering goes
            # back once (the parent keeps it for the next iterations' workers)
            return [(_pack(held[p].reduced), None if p in orderings else held[p].ordering) for p in group]

        def solve_separator(reduced: list[list]) -> gtsam.VectorValues:  # of the unpacked groups
            if not layout.separator.size:
                return gtsam.VectorValues()
            return _eliminate_all(_union(g for group in reduced for g, _ in group)).optimize()

        unpacked: list[list[tuple[gtsam.GaussianFactorGraph, gtsam.Ordering | None]]] = []

        def solve_local(reduced: list[list]) -> gtsam.VectorValues:
            unpacked.extend([(_unpack(r), o) for r, o in group] for group in reduced)
            return solve_separator(unpacked)

        def back_substitute(group: list[int], given: gtsam.VectorValues) -> dict[int, np.ndarray]:
            return _back_substitute(held, interior, group, given)

        groups = groups_of(self.partition.count, self.workers)
        if self.partition.engine == "dask":
            separator, reduced, steps = self._dask_step(gfg, layout, groups, solve_separator)
        else:
            separator, _, steps = run_step(groups, reduce, solve_local, back_substitute)
            reduced = unpacked
        flat = [item for group in reduced for item in group]
        for p, (_, ordering) in enumerate(flat):
            if ordering is not None:
                orderings[p] = ordering
        delta = gtsam.VectorValues(separator)
        for step in steps:
            for k, v in step.items():
                delta.insert(k, v)
        return delta, PartMarginals(gfg, [g for g, _ in flat], layout, self.partition)


    def _dask_step(self, gfg: gtsam.GaussianFactorGraph, layout: Layout, groups: list[list[int]], solve_separator):
        """:meth:`solve`'s step on Dask workers (:class:`PartWorker`): each group's factors
        sent packed, its reduced factors and new orderings back, unpacked here once."""
        client = dask_client(self.partition.address, self.workers)
        payloads = [[(p, _pack(layout.part_graph(gfg, p)), layout.interior[p].tolist(),
                      _ordering_keys(self._orderings.get(p))) for p in g] for g in groups]
        unpacked: list = []

        def solve(reduced: list[list]) -> gtsam.VectorValues:
            unpacked.extend([(_unpack(r), _ordering_of(o)) for r, o in group] for group in reduced)
            return solve_separator(unpacked)
        separator, _, steps = run_step_dask(client, groups, PartWorker, payloads, solve,
                                           lambda given: _pack_values(given, layout.separator))
        return separator, unpacked, steps


class PartMarginals:
    """The marginals of a partitioned solve, with the Bayes tree's calls the smoother uses
    (``marginalCovariance``, ``marginalFactor``, ``joint`` with an elimination function): a
    key's are those of the tree of its part's factors and the other parts' reduced factors
    (exact; module docstring). Each part's tree is made at its first query and kept (together
    about the memory of the one-batch tree)."""

    def __init__(self, gfg: gtsam.GaussianFactorGraph, reduced: list[gtsam.GaussianFactorGraph], layout: Layout,
                 partition: Partition | None = None):
        self._gfg, self._reduced, self._layout = gfg, reduced, layout
        self._trees: dict[int, gtsam.GaussianBayesTree] = {}
        self._orderings: dict[int, gtsam.Ordering] = {}
        self.partition = partition  # the parts of the step that made it (None: not told)

    @property
    def reduced(self) -> list[gtsam.GaussianFactorGraph]:
        """Every part's reduced factors on the separator (in part order)."""
        return self._reduced

    @property
    def layout(self) -> Layout:
        """The parts' :class:`Layout` of the linearised graph."""
        return self._layout

    def tree(self, key: int) -> gtsam.GaussianBayesTree:
        p = self._layout.home[int(key)]
        if p not in self._trees:
            g = _union([self._layout.part_graph(self._gfg, p)] + [r for q, r in enumerate(self._reduced) if q != p])
            self._orderings[p] = gtsam.Ordering.ColamdGaussianFactorGraph(g)
            self._trees[p] = _eliminate_all(g, self._orderings[p])
        return self._trees[p]

    def covariances(self, part: int, keys: list[int], exact: bool = False) -> dict[int, np.ndarray]:
        """The marginal covariances of ``keys``, all of part ``part``: by one pass down the
        part's tree where its cliques are wide (fusion/tree_marginals.py: exact to rounding, and
        then the cheaper) or ``exact`` is asked for, and they hold no hard constraint, else by
        GTSAM's per-key marginals (:func:`marginal_covariance`). The choice follows the tree
        only: the same on any machine."""
        if not keys:
            return {}
        return tree_covariances(self.tree(keys[0]), self._orderings[part], keys, exact)

    def exact_covariances(self, keys: list[int]) -> dict[int, np.ndarray]:
        """The marginal covariances of ``keys`` of any parts, each part's by one pass down its
        tree (:meth:`covariances` with ``exact``)."""
        by_part = self._layout.keys_by_part(keys)
        return {k: v for p in sorted(by_part)
                for k, v in self.covariances(p, by_part[p], exact=True).items()}

    def marginalCovariance(self, key: int) -> np.ndarray:
        return self.tree(key).marginalCovariance(key)

    def marginalFactor(self, key: int, function=gtsam.EliminateQR):
        return self.tree(key).marginalFactor(key, function)

    def joint(self, a: int, b: int, *function):
        return self.tree(a).joint(a, b, *function)
