"""Marginal covariances in one pass down a Bayes tree (fusion/tree_marginals.py) against the
dense inverse of the normal equations."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from trackfusion.errors import FusionError
from trackfusion.fusion import tree_marginals as tm
from trackfusion.fusion.partitioned import joint_marginal_covariance


def _chain(seed: int, n: int, reach: int, constrained: bool = False) -> gtsam.GaussianFactorGraph:
    """Poses X (6) and velocities V (3) along a chain, each pose tied to the one ``reach``
    keyframes back (as the wheel path's pairs widen the cliques) and, every third, to one bias
    B (6) shared by the whole run; a weak prior on each variable. ``constrained``: one factor of
    tiny sigmas, whose elimination keeps them in its cliques' noise model."""
    rng = np.random.default_rng(seed)
    g = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create
    for i in range(n):
        g.add(X(i), np.eye(6), rng.normal(size=6), gtsam.noiseModel.Isotropic.Sigma(6, 100.0))
        g.add(V(i), np.eye(3), rng.normal(size=3), gtsam.noiseModel.Isotropic.Sigma(3, 100.0))
        if i:
            g.add(X(i - 1), rng.normal(size=(9, 6)), V(i - 1), rng.normal(size=(9, 3)), X(i), rng.normal(size=(9, 6)),
                  rng.normal(size=9), unit(9))
            g.add(V(i - 1), rng.normal(size=(3, 3)), V(i), rng.normal(size=(3, 3)), rng.normal(size=3), unit(3))
        if i >= reach:
            g.add(X(i - reach), rng.normal(size=(2, 6)), X(i), rng.normal(size=(2, 6)), rng.normal(size=2), unit(2))
        if i % 3 == 0:
            g.add(X(i), rng.normal(size=(3, 6)), B(0), rng.normal(size=(3, 6)), rng.normal(size=3), unit(3))
    g.add(B(0), np.eye(6), np.zeros(6), unit(6))
    if constrained:
        g.add(X(0), rng.normal(size=(6, 6)), B(0), rng.normal(size=(6, 6)), rng.normal(size=6),
              gtsam.noiseModel.Constrained.MixedSigmas(1e3, np.full(6, 1e-4)))
    return g


def _tree_and_ordering(g: gtsam.GaussianFactorGraph):
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(g)
    return g.eliminateMultifrontal(ordering, gtsam.EliminateQR), ordering


def _dense_marginals(g: gtsam.GaussianFactorGraph, keys: list[int]) -> dict[int, np.ndarray]:
    """The exact marginal covariances: the inverse of ``A^T A`` (whitened), blocks of ``keys``."""
    order = list(g.keyVector())
    A, _ = g.jacobian(gtsam.Ordering(order))
    cov = np.linalg.inv(A.T @ A)
    dims = [tm.key_dim(k) for k in order]
    start = dict(zip(order, np.cumsum([0] + dims[:-1])))
    return {k: cov[start[k]:start[k] + tm.key_dim(k), start[k]:start[k] + tm.key_dim(k)] for k in keys}


def _worst(got: dict[int, np.ndarray], exact: dict[int, np.ndarray]) -> float:
    """Largest error of any entry over the product of the exact sigmas."""
    return max(float(np.max(np.abs(got[k] - e) / np.outer(np.sqrt(np.diag(e)), np.sqrt(np.diag(e)))))
               for k, e in exact.items())


@pytest.mark.parametrize("seed,n,reach,constrained", [(1, 2, 1, False), (2, 60, 4, False), (3, 150, 9, False),
                                                      (4, 40, 5, True)])
def test_pass_gives_the_dense_inverse(seed, n, reach, constrained):
    g = _chain(seed, n, reach, constrained)
    cliques = tm.cliques_top_down(*_tree_and_ordering(g))
    keys = [X(i) for i in range(n)] + [V(n - 1), B(0)]
    got = tm.marginal_covariances(cliques, keys)
    assert sorted(got) == sorted(keys)
    if not constrained:
        assert _worst(got, _dense_marginals(g, keys)) < 1e-10
    else:  # the normal equations square the tiny sigmas past the pass's accuracy (1.3e-8 of QR's,
        # where the pass is within 2e-10 of it): QR of the graph with every other variable first
        assert any(np.abs(c.whitened()[0]).max() > 1e3 for c in cliques)  # the sigmas were kept (else this tests nothing)
        assert _worst(got, {k: joint_marginal_covariance(g, [k]) for k in keys}) < 1e-9


def test_every_clique_comes_after_its_parent_and_children_are_counted():
    g = _chain(5, 80, 6)
    cliques = tm.cliques_top_down(*_tree_and_ordering(g))
    position = {c.keys[0]: i for i, c in enumerate(cliques)}
    children: dict[int, int] = {}
    for i, c in enumerate(cliques):
        if c.parent is not None:
            assert position[c.parent] < i
            children[c.parent] = children.get(c.parent, 0) + 1
    assert all(c.children == children.get(c.keys[0], 0) for c in cliques)
    frontal = [k for c in cliques for k in c.keys[:c.frontal]]
    assert sorted(frontal) == sorted(g.keyVector())  # every variable frontal in exactly one clique


def test_a_key_the_tree_does_not_hold_is_refused():
    g = _chain(6, 5, 2)
    cliques = tm.cliques_top_down(*_tree_and_ordering(g))
    with pytest.raises(KeyError, match="x99"):
        tm.marginal_covariances(cliques, [X(1), X(99)])


def _with_hard_constraint() -> gtsam.GaussianFactorGraph:
    """A short chain whose first pose equals a bias exactly (a zero-sigma constraint)."""
    g = _chain(7, 8, 3)
    g.add(X(0), np.eye(6), B(0), -np.eye(6), np.zeros(6), gtsam.noiseModel.Constrained.All(6))
    return g


def test_a_hard_constraint_is_refused_by_the_pass_and_left_to_gtsams_marginals(monkeypatch):
    g = _with_hard_constraint()
    cliques = tm.cliques_top_down(*_tree_and_ordering(g))
    assert any(c.sigmas() is not None and not np.all(c.sigmas() > 0) for c in cliques)
    with pytest.raises(FusionError, match="hard constraint"):
        tm.marginal_covariances(cliques, [X(1)])
    monkeypatch.setattr(tm, "WIDE_CLIQUE_COLUMNS", 0.0)
    assert not tm.takes_the_pass(cliques)
    assert tm.takes_the_pass(tm.cliques_top_down(*_tree_and_ordering(_chain(7, 8, 3))))


def test_the_pass_is_taken_from_the_mean_clique_width(monkeypatch):
    cliques = tm.cliques_top_down(*_tree_and_ordering(_chain(8, 30, 6)))
    mean = float(np.mean([c.columns for c in cliques]))
    monkeypatch.setattr(tm, "WIDE_CLIQUE_COLUMNS", mean)
    assert tm.takes_the_pass(cliques)
    monkeypatch.setattr(tm, "WIDE_CLIQUE_COLUMNS", mean + 0.1)
    assert not tm.takes_the_pass(cliques)
