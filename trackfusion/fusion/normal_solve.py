"""Normal-equation solves ``(A^T A) x = g`` with the Bayes tree GTSAM already made of ``A``, for
many right-hand sides at once.

A multifrontal QR elimination leaves one conditional per clique, ``R_f x_f + S x_s = d`` (``R_f``
upper-triangular over the clique's frontal variables ``f``, ``S`` over its separator ``s``;
rows whitened by their sigmas where a constrained noise model's elimination kept them).
Stacked in elimination order they make the upper-triangular ``R`` with ``R^T R = A^T A``, so ``(A^T A) x = g`` is two triangular passes over the cliques:

- ``R^T y = g`` from the leaves up: ``y_f = R_f^-T g_f``, then ``g_s -= S^T y_f`` (a clique's
  separator variables are frontal in an ancestor, eliminated later);
- ``R x = y`` from the root down: ``x_f = R_f^-1 (y_f - S x_s)``.

Why hand-written: GTSAM's Python wrapper solves a Bayes tree only for its own right-hand side
``d`` (``optimize``), and the transposed system only on a Bayes net, one vector at a time
(``backSubstituteTranspose``). Both passes here take a matrix of right-hand sides (N, D) and
cost one small matrix product per clique and pass, without a new elimination.

Not for marginal covariances: their recursion from the root down (``Sigma_ff = R_f^-1 R_f^-T +
W Sigma_ss W^T``, ``W = R_f^-1 S``) amplifies rounding by ``W`` at every level; tried on a
216 s GNSS-only survey's tree, the pose variances were wrong from the 70th second and negative
by the 108th (GTSAM's shortcut marginals, fusion/partitioned.py, do not blow up). The same pass
in square-root information form is exact to rounding (fusion/tree_marginals.py, which the
sigma parts take where their cliques are wide).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import gtsam
import numpy as np

from ..errors import FusionError
from .factors import STATION_STATE_DIM

#: dimension of each of the smoother's variables by its symbol's character (fusion/smoother.py:
#: pose, velocity, IMU bias, odometer scale, GNSS correlated error, total-station correction)
KEY_DIM = {"x": 6, "v": 3, "b": 6, "s": 1, "d": 1, "e": 3, "t": STATION_STATE_DIM}


@functools.lru_cache(maxsize=None)
def key_dim(key: int) -> int:
    """Dimension of the smoother's variable ``key`` (:data:`KEY_DIM`)."""
    return KEY_DIM[chr(gtsam.Symbol(key).chr())]


@dataclass
class _Clique:
    """One conditional: its frontal rows ``[start, stop)`` of the stacked vector, its
    separator's rows ``sep`` (n_s,), ``R_inv`` the inverse of its ``R`` (n_f, n_f) and ``S``
    (n_f, n_s)."""

    start: int
    stop: int
    sep: np.ndarray
    R_inv: np.ndarray
    S: np.ndarray


@dataclass
class TreeFactor:
    """The triangular factor of a Bayes tree in numpy: ``offset`` of each key's rows in the
    stacked vector (of ``size`` rows), and the cliques from the leaves up."""

    offset: dict[int, int]
    size: int
    cliques: list[_Clique]
    _sorted: tuple[np.ndarray, np.ndarray] | None = None  # the keys sorted, and their offsets

    def rows(self, keys: np.ndarray, dim: int) -> np.ndarray:
        """(K, dim) row indices of the variables ``keys`` (K,) of dimension ``dim``."""
        if self._sorted is None:
            k = np.fromiter(self.offset.keys(), np.uint64, len(self.offset))
            o = np.fromiter(self.offset.values(), np.int64, len(self.offset))
            order = np.argsort(k)
            self._sorted = (k[order], o[order])
        sorted_keys, sorted_offsets = self._sorted
        keys = np.asarray(keys, np.uint64)
        at = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
        if not np.array_equal(sorted_keys[at], keys):
            raise FusionError("normal solve: a variable that the Bayes tree does not hold")
        return sorted_offsets[at][:, None] + np.arange(dim)


def tree_factor(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering) -> TreeFactor:
    """The factor of ``tree``, eliminated in ``ordering``: its cliques in elimination order of
    their last frontal variable, every clique before its parent. (Not of their first: GTSAM
    merges a child into its parent, so a clique's frontal variables need not be consecutive in
    the ordering, and a clique whose first frontal variable comes before another's may be its
    parent.)"""
    position = {ordering.at(i): i for i in range(ordering.size())}
    offset: dict[int, int] = {}  # of the frontal keys of the cliques taken
    conds, frontal, last = [], [], []
    size = 0
    for _, cond, keys, n in each_clique(tree, ordering):  # cond kept: it holds R and S while the tree may go
        start = size
        for k in keys[:n]:
            offset[k], size = size, size + key_dim(k)
        conds.append(cond)
        frontal.append((start, size, keys[n:]))
        last.append(max(position[k] for k in keys[:n]))
    order = np.argsort(last, kind="stable")
    conds, frontal = [conds[i] for i in order], [frontal[i] for i in order]
    blocks = []
    seps = _separator_rows([parents for _, _, parents in frontal], offset)
    for cond, (start, stop, _), sep in zip(conds, frontal, seps):
        R, S = whitened(cond, "normal solve")
        blocks.append((start, stop, sep, R, S))
    R_inv = _inverses([b[3] for b in blocks])
    return TreeFactor(offset, size, [_Clique(a, b, sep, r, S) for (a, b, sep, _, S), r in zip(blocks, R_inv)])


def each_clique(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering, top_down: bool = False
                ) -> Iterator[tuple[gtsam.GaussianBayesTreeClique, gtsam.GaussianConditional, list[int], int]]:
    """Each clique of ``tree`` (eliminated in ``ordering``) once: the clique, its conditional, the
    conditional's keys (frontal first) and how many are frontal (:func:`frontal_count`). In the
    order of their first frontal key in ``ordering``; ``top_down``: in reverse order of their last,
    every clique after its parent."""
    taken: set[int] = set()
    for i in (range(ordering.size() - 1, -1, -1) if top_down else range(ordering.size())):
        key = ordering.at(i)
        if key in taken:
            continue
        clique = tree[key]
        cond = clique.conditional()
        keys = list(cond.keys())
        n = frontal_count(keys, cond.rows())
        taken.update(keys[:n])
        yield clique, cond, keys, n


def frontal_count(keys: list[int], rows: int) -> int:
    """How many of a conditional's ``keys`` (frontal first) are frontal: the first ones, whose
    :func:`key_dim` fill its ``rows`` rows of ``R``."""
    n, filled = 0, 0
    while filled < rows:
        filled, n = filled + key_dim(keys[n]), n + 1
    return n


def kept_sigmas(cond: gtsam.GaussianConditional) -> np.ndarray | None:
    """The rows' sigmas (F,) that a constrained factor's elimination kept in conditional
    ``cond``'s model, or None (unit noise)."""
    model = cond.get_model()
    return None if model is None or model.isUnit() else np.asarray(model.sigmas())


def whitened(cond: gtsam.GaussianConditional, who: str) -> tuple[np.ndarray, np.ndarray]:
    """Conditional ``cond``'s ``R`` (F, F) and ``S`` (F, N - F), copied, with unit noise (rows
    divided by their :func:`kept_sigmas`). A hard constraint (a zero sigma) is refused, the
    error naming ``who`` asked."""
    R, S = np.array(cond.R()), np.array(cond.S())
    sigmas = kept_sigmas(cond)
    if sigmas is not None:
        if not np.all(sigmas > 0.0):
            raise FusionError(f"{who}: a hard constraint (a zero sigma) in the factor graph")
        R, S = R / sigmas[:, None], S / sigmas[:, None]
    return R, S


def log_abs_determinant(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering) -> float:
    """``log |det R|`` of ``tree``'s triangular factor (eliminated in ``ordering``): half of
    ``log det(A^T A)`` of the whitened system it was made from [-]. Why not GTSAM's
    ``logDeterminant``: it takes the log of ``R``'s signed diagonal, NaN wherever QR left a
    negative entry (tests/test_gnss_time_constant.py)."""
    return float(sum(np.sum(np.log(np.abs(np.diag(whitened(cond, "log determinant")[0]))))
                     for _, cond, _, _ in each_clique(tree, ordering)))


def _separator_rows(parents: list[list[int]], offset: dict[int, int]) -> list[np.ndarray]:
    """Per clique, the rows (n_s,) of its separator keys ``parents`` (each key's :func:`key_dim`
    rows from its ``offset``), made for all cliques at once."""
    flat = [k for keys in parents for k in keys]
    starts = np.fromiter((offset[k] for k in flat), np.int64, len(flat))
    dims = np.fromiter((key_dim(k) for k in flat), np.int64, len(flat))
    first = np.cumsum(dims) - dims  # each key's first row in the concatenation
    rows = np.repeat(starts - first, dims) + np.arange(int(dims.sum()), dtype=np.int64)
    ends = np.concatenate(([0], np.cumsum(dims)))[np.cumsum([len(keys) for keys in parents])]
    return np.split(rows, ends[:-1])


def _inverses(R: list[np.ndarray]) -> list[np.ndarray]:
    """The inverses of the square matrices ``R``, inverted in batches of one size (the passes
    then cost a matrix product per clique; the whitened system's R is conditioned to ~1e7, so
    an inverse keeps ~9 digits, far more than a Hutchinson draw needs)."""
    out: list = [None] * len(R)
    by_size: dict[int, list[int]] = {}
    for i, r in enumerate(R):
        by_size.setdefault(r.shape[0], []).append(i)
    for idx in by_size.values():
        for i, r in zip(idx, np.linalg.inv(np.stack([R[i] for i in idx]))):
            out[i] = r
    return out


def solve_normal(factor: TreeFactor, g: np.ndarray) -> np.ndarray:
    """(N, D) the solutions ``x`` of ``(A^T A) x = g`` for the right-hand sides ``g`` (N, D),
    in the rows :attr:`TreeFactor.offset` gives each key (module docstring)."""
    y = np.array(g, dtype=float, copy=True)
    for c in factor.cliques:  # R^T y = g, leaves up
        yf = c.R_inv.T @ y[c.start:c.stop]
        y[c.start:c.stop] = yf
        if c.sep.size:
            y[c.sep] -= c.S.T @ yf
    for c in reversed(factor.cliques):  # R x = y, root down
        rhs = y[c.start:c.stop] - c.S @ y[c.sep] if c.sep.size else y[c.start:c.stop]
        y[c.start:c.stop] = c.R_inv @ rhs
    return y
