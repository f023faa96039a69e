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
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.linalg import solve_triangular

from ..errors import FusionError
from .factors import STATION_STATE_DIM

#: dimension of each of the smoother's variables by its symbol's character (fusion/smoother.py:
#: pose, velocity, IMU bias, odometer scale, GNSS correlated error, total-station correction)
KEY_DIM = {"x": 6, "v": 3, "b": 6, "s": 1, "e": 3, "t": STATION_STATE_DIM}


def key_dim(key: int) -> int:
    """Dimension of the smoother's variable ``key`` (:data:`KEY_DIM`)."""
    return KEY_DIM[chr(gtsam.Symbol(key).chr())]


@dataclass
class _Clique:
    """One conditional: its frontal rows ``[start, stop)`` of the stacked vector, its
    separator's rows ``sep`` (n_s,), ``R`` (n_f, n_f) and ``S`` (n_f, n_s)."""

    start: int
    stop: int
    sep: np.ndarray
    R: np.ndarray
    S: np.ndarray


@dataclass
class TreeFactor:
    """The triangular factor of a Bayes tree in numpy: ``offset`` of each key's rows in the
    stacked vector (of ``size`` rows), and the cliques from the leaves up."""

    offset: dict[int, int]
    size: int
    cliques: list[_Clique]

    def stack(self, vectors: dict[int, np.ndarray], columns: int) -> np.ndarray:
        """(size, columns) the per-key (d, columns) blocks of ``vectors`` stacked (keys missing: 0)."""
        out = np.zeros((self.size, columns))
        for k, v in vectors.items():
            o = self.offset[int(k)]
            out[o:o + v.shape[0]] = v
        return out

    def rows(self, keys: np.ndarray, dim: int) -> np.ndarray:
        """(K, dim) row indices of the variables ``keys`` (K,) of dimension ``dim``."""
        start = np.array([self.offset[int(k)] for k in np.asarray(keys).tolist()], dtype=np.int64)
        return start[:, None] + np.arange(dim)


def tree_factor(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering) -> TreeFactor:
    """The factor of ``tree``, eliminated in ``ordering``: its cliques in elimination order of
    their first frontal variable (every clique before its parent)."""
    seen, conds = set(), []
    for i in range(ordering.size()):
        cond = tree[ordering.at(i)].conditional()
        first = cond.firstFrontalKey()
        if first not in seen:
            seen.add(first)
            conds.append(cond)
    offset: dict[int, int] = {}
    frontal = []
    size = 0
    for cond in conds:  # the frontal keys: the first ones, whose dimensions fill R
        keys, n_f, start, n = list(cond.keys()), cond.R().shape[0], size, 0
        while size - start < n_f:
            offset[keys[n]] = size
            size, n = size + key_dim(keys[n]), n + 1
        frontal.append((start, size, keys[n:]))
    cliques = []
    for cond, (start, stop, parents) in zip(conds, frontal):
        R, S = np.array(cond.R()), np.array(cond.S())  # copies: the tree may go
        model = cond.get_model()
        if model is not None:  # a constrained factor's elimination keeps its rows' sigmas
            sigmas = np.asarray(model.sigmas())
            if not np.all(sigmas > 0.0):
                raise FusionError("normal solve: a hard constraint (a zero sigma) in the factor graph")
            R, S = R / sigmas[:, None], S / sigmas[:, None]
        sep = np.concatenate([offset[k] + np.arange(key_dim(k)) for k in parents]) if parents else np.zeros(0, np.int64)
        cliques.append(_Clique(start, stop, sep, R, S))
    return TreeFactor(offset, size, cliques)


def solve_normal(factor: TreeFactor, g: np.ndarray) -> np.ndarray:
    """(N, D) the solutions ``x`` of ``(A^T A) x = g`` for the right-hand sides ``g`` (N, D),
    stacked as :meth:`TreeFactor.stack` stacks them (module docstring)."""
    y = np.array(g, dtype=float, copy=True)
    for c in factor.cliques:  # R^T y = g, leaves up
        yf = solve_triangular(c.R, y[c.start:c.stop], trans="T", check_finite=False)
        y[c.start:c.stop] = yf
        if c.sep.size:
            y[c.sep] -= c.S.T @ yf
    for c in reversed(factor.cliques):  # R x = y, root down
        rhs = y[c.start:c.stop] - c.S @ y[c.sep] if c.sep.size else y[c.start:c.stop]
        y[c.start:c.stop] = solve_triangular(c.R, rhs, check_finite=False)
    return y
