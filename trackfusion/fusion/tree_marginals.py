"""Marginal covariances of many variables in one pass down a Gaussian Bayes tree, in
square-root information form.

A multifrontal QR elimination leaves one conditional per clique, ``R x_f + S x_s = d`` with
unit noise (rows whitened by their sigmas where a constrained model's elimination kept them).
Given ``M``, the upper-triangular square-root information of the marginal of the clique's
separator ``s``, the clique's joint marginal has the square-root information
``J = [[R, S], [0, M]]`` (frontal then separator variables). From the root down:

- a child's separator lies in its parent's variables, so the child's ``M`` is the trailing
  triangle of the QR of the parent's ``J`` with the child's separator columns put last (the
  other variables eliminated);
- a frontal variable's covariance is ``E^T J^-1 J^-T E`` (``E`` its unit columns): one
  triangular solve ``J^T Y = E``, then ``Y^T Y``.

Every step is an orthogonal transformation or a triangular solve, so the pass is exact to
rounding (2e-11 of the exact marginal on the hour's and the bridge's sigma parts, against 8e-6
and 2.6e-4 for GTSAM's per-key ``marginalCovariance``: ``benchmarks/marginal_recursion.py``).
The same pass in covariance form, ``Sigma_ff = R^-1 R^-T + W Sigma_ss W^T`` with
``W = R^-1 S``, grows the rounding by ``W`` at every level and overflowed on the bridge.

Why hand-written: GTSAM's Python wrapper gives a clique's parent but not its children, and
answers marginals one key at a time (each a Cholesky of cached shortcuts, whose cost grows
faster with the clique width than this pass's: :data:`WIDE_CLIQUE_COLUMNS`). Where the cliques
are narrow, GTSAM's C++ is the cheaper, this pass's Python per clique (about 80 us) weighing more.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dgeqrf

from ..forked import one_blas_thread
from .normal_solve import each_clique, kept_sigmas, key_dim, whitened

#: mean clique width (frontal and separator columns) from which this pass is the cheaper than
#: GTSAM's per-key marginals of one sigma keyframe a second. Measured on the sigma parts
#: (benchmarks/marginal_recursion.py, CPU s a part, walk and pass): the hour's trees of 40-44
#: columns, GTSAM 0.07-0.22 s against the pass's 0.23-0.38 s; the 53 min bridge's of 62 / 70 /
#: 75 / 76 / 79 columns, GTSAM 0.52 / 1.12 / 0.58 / 1.95 / 2.21 s against 0.47 / 0.59 / 0.36 /
#: 0.88 / 0.85 s (GTSAM's cost per clique grows faster with the width)
WIDE_CLIQUE_COLUMNS = 55.0


@dataclass
class Clique:
    """One clique of a Bayes tree: its conditional ``cond``, the conditional's ``keys``
    (frontal first), how many are frontal, the first frontal key of its parent (None: a root)
    and its number of children."""

    cond: gtsam.GaussianConditional
    keys: list[int]
    frontal: int
    parent: int | None
    children: int

    @property
    def columns(self) -> int:
        return sum(key_dim(k) for k in self.keys)

    def sigmas(self) -> np.ndarray | None:
        """The rows' sigmas (F,) a constrained model's elimination kept, or None (unit noise)."""
        return kept_sigmas(self.cond)

    def whitened(self) -> tuple[np.ndarray, np.ndarray]:
        """``R`` (F, F) and ``S`` (F, N - F) with unit noise. A hard constraint (a zero sigma: no
        square-root information can hold it) is refused."""
        return whitened(self.cond, "tree marginals")


def cliques_top_down(tree: gtsam.GaussianBayesTree, ordering: gtsam.Ordering) -> list[Clique]:
    """The cliques of ``tree`` (eliminated in ``ordering``), each after its parent: in reverse
    elimination order of their last frontal key (fusion/normal_solve.py ``tree_factor``)."""
    out = []
    for clique, cond, keys, frontal in each_clique(tree, ordering, top_down=True):
        parent = clique.parent().conditional().firstFrontalKey() if frontal < len(keys) else None
        out.append(Clique(cond, keys, frontal, parent, clique.nrChildren()))
    return out


def takes_the_pass(cliques: list[Clique], exact: bool = False) -> bool:
    """Whether the cliques are wide enough for this pass to beat GTSAM's per-key marginals
    (:data:`WIDE_CLIQUE_COLUMNS`; with ``exact``, at any width) and hold no hard constraint (a
    zero sigma, which GTSAM's marginals take and the square-root information cannot)."""
    if not cliques or not exact and float(np.mean([c.columns for c in cliques])) < WIDE_CLIQUE_COLUMNS:
        return False
    return all(s is None or np.all(s > 0.0) for s in (c.sigmas() for c in cliques))


def _rows(keys: list[int], offset: dict[int, int]) -> list[int]:
    return [j for k in keys for j in range(offset[k], offset[k] + key_dim(k))]


def _separator_root(parent_J: np.ndarray, rows: list[int]) -> np.ndarray:
    """Upper-triangular square-root information (len(rows), len(rows)) of the variables at
    ``rows`` of the joint square-root information ``parent_J``, the others eliminated (QR)."""
    keep = np.ones(parent_J.shape[0], bool)
    keep[rows] = False
    n = int(keep.sum())
    A = np.empty(parent_J.shape, order="F")  # LAPACK's layout: no copy on the call
    A[:, :n], A[:, n:] = parent_J[:, keep], parent_J[:, rows]
    qr, _, _, info = dgeqrf(A, lwork=64 * A.shape[0], overwrite_a=1)
    if info != 0:
        raise ValueError(f"LAPACK dgeqrf failed (info {info})")
    return np.triu(qr[n:, n:])


def marginal_covariances(cliques: list[Clique], keys) -> dict[int, np.ndarray]:
    """Marginal covariance (d, d) of each of ``keys`` (each a frontal key of one of
    ``cliques``, from :func:`cliques_top_down`), in one pass from the roots down (module
    docstring)."""
    wanted = set(int(k) for k in keys)
    with one_blas_thread():  # the parts run one process per CPU (trackfusion/forked.py)
        out = _pass(cliques, wanted)
    missing = wanted - out.keys()
    if missing:
        raise KeyError(f"not a frontal key of these cliques: {gtsam.DefaultKeyFormatter(min(missing))}")
    return out


def _pass(cliques: list[Clique], wanted: set[int]) -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    held: dict[int, list] = {}  # first frontal key -> [J, offsets, children still to come]
    for c in cliques:
        offset, size = {}, 0
        for k in c.keys:
            offset[k], size = size, size + key_dim(k)
        R, S = c.whitened()
        f = R.shape[0]
        J = np.zeros((size, size))
        J[:f, :f], J[:f, f:] = R, S
        if c.parent is not None:
            parent = held[c.parent]
            J[f:, f:] = _separator_root(parent[0], _rows(c.keys[c.frontal:], parent[1]))
            parent[2] -= 1
            if parent[2] == 0:
                del held[c.parent]
        for k in c.keys[:c.frontal]:
            if k in wanted:
                E = np.zeros((size, key_dim(k)))
                E[offset[k]:offset[k] + key_dim(k)] = np.eye(key_dim(k))
                Y = solve_triangular(J, E, trans="T", check_finite=False)
                out[k] = Y.T @ Y
        if c.children:
            held[c.keys[0]] = [J, offset, c.children]
    return out
