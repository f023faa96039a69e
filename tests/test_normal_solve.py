"""Normal-equation solves with a Bayes tree (fusion/normal_solve.py) against the dense normal
equations and against GTSAM's own solve."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, E, X

from trackfusion.fusion import normal_solve as ns


def _graph(seed: int, n: int, constrained: bool = False):
    """A chain of 3-vectors E, each seen with one of two 6-vectors X (a separator in every
    clique), a 6-vector B tied to every fifth E; rows of unit and non-unit noise."""
    rng = np.random.default_rng(seed)
    g = gtsam.GaussianFactorGraph()
    for i in range(n):
        g.add(gtsam.JacobianFactor(E(i), rng.normal(size=(3, 3)), rng.normal(size=3), gtsam.noiseModel.Unit.Create(3)))
        if i:
            g.add(gtsam.JacobianFactor(E(i - 1), rng.normal(size=(3, 3)), E(i), rng.normal(size=(3, 3)),
                                       rng.normal(size=3), gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
        g.add(gtsam.JacobianFactor(E(i), rng.normal(size=(2, 3)), X(i % 2), 1e3 * rng.normal(size=(2, 6)),
                                   rng.normal(size=2), gtsam.noiseModel.Unit.Create(2)))
        if i % 5 == 0:
            g.add(gtsam.JacobianFactor(E(i), rng.normal(size=(1, 3)), B(0), rng.normal(size=(1, 6)),
                                       rng.normal(size=1), gtsam.noiseModel.Unit.Create(1)))
    for k in (X(0), X(1), B(0)):
        g.add(gtsam.JacobianFactor(k, np.eye(6), np.zeros(6), gtsam.noiseModel.Unit.Create(6)))
    if constrained:  # a constrained model (as a zero-sigma bias walk makes): its cliques keep sigmas
        g.add(gtsam.JacobianFactor(B(0), rng.normal(size=(6, 6)), X(0), rng.normal(size=(6, 6)), rng.normal(size=6),
                                   gtsam.noiseModel.Constrained.MixedSigmas(1e3, np.full(6, 1e-3))))
    return g


@pytest.mark.parametrize("seed,n,constrained", [(1, 3, False), (2, 40, False), (3, 200, False), (5, 20, True)])
def test_solves_the_dense_normal_equations(seed, n, constrained):
    g = _graph(seed, n, constrained)
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(g)
    factor = ns.tree_factor(g.eliminateMultifrontal(ordering, gtsam.EliminateQR), ordering)
    stacked = sorted(factor.offset, key=factor.offset.get)
    assert factor.size == 3 * n + 18 and len(stacked) == n + 3
    A, _ = g.jacobian(gtsam.Ordering(stacked))
    rhs = np.random.default_rng(seed).normal(size=(factor.size, 4))
    x = ns.solve_normal(factor, rhs)
    exact = np.linalg.solve(A.T @ A, rhs)
    assert np.abs(x - exact).max() < 1e-9 * np.abs(exact).max()


def test_its_own_right_hand_side_gives_gtsams_step():
    g = _graph(4, 30)
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(g)
    tree = g.eliminateMultifrontal(ordering, gtsam.EliminateQR)
    factor = ns.tree_factor(tree, ordering)
    stacked = sorted(factor.offset, key=factor.offset.get)
    A, b = g.jacobian(gtsam.Ordering(stacked))
    x = ns.solve_normal(factor, (A.T @ b)[:, None])[:, 0]
    delta = tree.optimize()
    for k in stacked:
        o = factor.offset[k]
        assert np.abs(x[o:o + ns.key_dim(k)] - delta.at(k)).max() < 1e-10
    assert np.array_equal(factor.rows(np.array([stacked[1], stacked[0]]), 3)[:, 0],
                          [factor.offset[stacked[1]], factor.offset[stacked[0]]])


def test_a_child_merged_into_its_parent():
    """A star of five 3-vectors on a hub eliminated last: GTSAM merges the first leaf into the
    hub's clique, whose first frontal variable then comes before its children's (seen on the
    smoother's graphs); both passes must take the cliques parents last."""
    rng = np.random.default_rng(11)
    g = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create(3)
    for i in range(5):
        g.add(gtsam.JacobianFactor(E(i), rng.normal(size=(3, 3)), E(5), rng.normal(size=(3, 3)), rng.normal(size=3), unit))
        g.add(gtsam.JacobianFactor(E(i), rng.normal(size=(3, 3)), rng.normal(size=3), unit))
    g.add(gtsam.JacobianFactor(E(5), np.eye(3), np.zeros(3), unit))
    ordering = gtsam.Ordering([E(i) for i in range(6)])
    factor = ns.tree_factor(g.eliminateMultifrontal(ordering, gtsam.EliminateQR), ordering)
    assert factor.cliques[-1].stop - factor.cliques[-1].start == 6  # the merged root: E(0) with the hub
    stacked = sorted(factor.offset, key=factor.offset.get)
    A, _ = g.jacobian(gtsam.Ordering(stacked))
    rhs = rng.normal(size=(factor.size, 3))
    assert np.abs(ns.solve_normal(factor, rhs) - np.linalg.solve(A.T @ A, rhs)).max() < 1e-12
