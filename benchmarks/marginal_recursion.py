"""Benchmark: the sigma parts' pose marginals by one pass down each part's Bayes tree
(fusion/tree_marginals.py, the default where the cliques are wide), against GTSAM's per-key
marginals (the default elsewhere), for time and exactness.

Usage: python benchmarks/marginal_recursion.py [--scenario bridge|open-track] [--seed N]
       [--check-every N] [--out FILE]

The sigma columns of a run longer than 600 s come from time parts (fusion/partitioned.py
``part_marginal_covariances``): per part, one GTSAM Bayes tree of its factors and the other
parts' reduced factors, then GTSAM's ``marginalCovariance`` for each sigma keyframe's pose (a
Cholesky of the shortcut marginals, cached along the tree). This script smooths the cached
simulation as ``trackfusion run`` does (``bridge``: seed ``--seed`` of benchmarks/bridge.py;
``open-track``: the hour of benchmarks/speed.py), takes the graphs the sigma parts would use, and
times per part:

- ``tree_s``: the part's Bayes tree (COLAMD, multifrontal QR), as the smoother makes it;
- ``gtsam_s``: GTSAM's marginals of the part's sigma keyframes (the smoother's way);
- ``qr_pass_s``: one pass from the root down in square-root information form
  (fusion/tree_marginals.py): each clique's ``[[R, S], [0, M]]`` (``M``: the square-root
  information of its separator's marginal) gives its children's ``M`` by a QR with their
  separator's columns last, and a wanted pose's covariance by one triangular solve; the part
  takes it when its cliques are wider than ``WIDE_CLIQUE_COLUMNS`` on average
  (``mean_clique_columns``);
- ``cov_pass_s``: the same pass in covariance form (``Sigma_ff = R^-1 R^-T + W Sigma_ss W^T``,
  ``W = R^-1 S``), the form fusion/normal_solve.py's docstring found unstable.

Each method's covariances of every ``--check-every``-th key are compared with the exact
marginal (QR of the part's graph with every other variable eliminated first,
``joint_marginal_covariance``): the largest error of any entry over the product of the two
sigmas (a correlation's error; diagonal: a variance's relative error); null where a covariance
overflowed.
Writes benchmarks/results/marginal_recursion[_open-track].json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from provenance import git_commit
from solver_cpu import problem

RESULTS = Path(__file__).resolve().parent / "results"


def sigma_part_graphs(prob):
    """Smooth ``prob``; return, per sigma part, (its graph: the part's factors and the other
    parts' reduced factors, its sigma keyframes' pose keys)."""
    from trackfusion.fusion import partitioned, smoother
    seen: dict = {}
    real = smoother.part_marginal_covariances

    def keep(partition, gfg, keys, workers, joint_keys=None, made=None):
        seen.update(gfg=gfg, keys=keys, made=made)
        return real(partition, gfg, keys, workers, joint_keys, made)

    smoother.part_marginal_covariances = keep
    try:
        smoother.smooth(prob)
    finally:
        smoother.part_marginal_covariances = real
    made, gfg = seen["made"], seen["gfg"]
    layout = made.layout
    out = []
    for p in range(len(made.reduced)):
        graph = partitioned._union([layout.part_graph(gfg, p)] + [r for q, r in enumerate(made.reduced) if q != p])
        out.append((graph, [int(k) for k in seen["keys"] if layout.home[int(k)] == p]))
    return out


def qr_pass(tree, ordering, keys: list[int]) -> dict[int, np.ndarray]:
    """The pass in square-root information form (fusion/tree_marginals.py)."""
    from trackfusion.fusion.tree_marginals import cliques_top_down, marginal_covariances
    return marginal_covariances(cliques_top_down(tree, ordering), keys)


def cov_pass(tree, ordering, keys: list[int]) -> dict[int, np.ndarray]:
    """The same covariances, one pass down in covariance form."""
    from trackfusion.fusion.normal_solve import key_dim
    from trackfusion.fusion.tree_marginals import cliques_top_down
    wanted, out, held = set(keys), {}, {}
    for c in cliques_top_down(tree, ordering):
        offset, size = {}, 0
        for k in c.keys:
            offset[k], size = size, size + key_dim(k)
        R, S = c.whitened()
        f = R.shape[0]
        R_inv = np.linalg.inv(R)
        cov = np.empty((size, size))
        cov[:f, :f] = R_inv @ R_inv.T
        if c.parent is not None:
            parent = held[c.parent]
            rows = [j for k in c.keys[c.frontal:] for j in range(parent[1][k], parent[1][k] + key_dim(k))]
            cov_ss = parent[0][np.ix_(rows, rows)]
            W = R_inv @ S
            with np.errstate(over="ignore", invalid="ignore"):  # it overflows on the bridge
                cov[:f, f:] = -W @ cov_ss
                cov[:f, :f] += W @ cov_ss @ W.T
            cov[f:, :f] = cov[:f, f:].T
            cov[f:, f:] = cov_ss
        for k in c.keys[:c.frontal]:
            if k in wanted:
                out[k] = cov[offset[k]:offset[k] + key_dim(k), offset[k]:offset[k] + key_dim(k)].copy()
        if c.children:
            held[c.keys[0]] = (cov, offset)
    return out


def worst_error(covs: dict[int, np.ndarray], exact: dict[int, np.ndarray]) -> float | None:
    """Largest |error| of any entry over the product of the exact sigmas (None: a covariance
    overflowed)."""
    worst = 0.0
    for k, ref in exact.items():
        sd = np.sqrt(np.diag(ref))
        with np.errstate(over="ignore", invalid="ignore"):
            error = np.abs(covs[k] - ref) / np.outer(sd, sd)
        if not np.all(np.isfinite(error)):
            return None
        worst = max(worst, float(np.max(error)))
    return worst


def measure_part(graph, keys: list[int], check_every: int) -> dict:
    import gtsam
    from trackfusion.fusion.partitioned import joint_marginal_covariance, marginal_covariance
    from trackfusion.fusion.tree_marginals import cliques_top_down
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(graph)
    row, covs = {"sigma_keyframes": len(keys)}, {}
    for name, method in (("gtsam", None), ("qr_pass", qr_pass), ("cov_pass", cov_pass)):
        t0 = time.perf_counter()
        tree = graph.eliminateMultifrontal(ordering, gtsam.EliminateQR)
        t1 = time.perf_counter()
        covs[name] = {k: marginal_covariance(tree, k) for k in keys} if method is None \
            else method(tree, ordering, keys)
        row[f"{name}_s"] = round(time.perf_counter() - t1, 3)
        row["tree_s"] = round(t1 - t0, 3)
    cliques = cliques_top_down(tree, ordering)
    row["cliques"] = len(cliques)
    row["mean_clique_columns"] = round(float(np.mean([c.columns for c in cliques])), 1)
    exact = {k: joint_marginal_covariance(graph, [k]) for k in keys[::check_every]}
    for name in covs:
        row[f"{name}_error"] = worst_error(covs[name], exact)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=["bridge", "open-track"], default="bridge")
    ap.add_argument("--seed", type=int, default=1, help="bridge: the seed of benchmarks/bridge.py")
    ap.add_argument("--check-every", type=int, default=60, help="every N-th sigma keyframe against the exact marginal")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    prob = problem(args.scenario, 4, args.seed)
    parts = []
    for p, (graph, keys) in enumerate(sigma_part_graphs(prob)):
        row = measure_part(graph, keys, args.check_every)
        parts.append(row)
        print(f"part {p}: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
              flush=True)
    total = {k: round(sum(r[k] for r in parts), 2) for k in ("tree_s", "gtsam_s", "qr_pass_s", "cov_pass_s")}
    worst = {k: None if any(r[k] is None for r in parts) else max(r[k] for r in parts)
             for k in ("gtsam_error", "qr_pass_error", "cov_pass_error")}
    print(f"total (one CPU): {total}; worst error: {worst}")
    out = args.out or RESULTS / ("marginal_recursion.json" if args.scenario == "bridge"
                                 else f"marginal_recursion_{args.scenario}.json")
    out.write_text(json.dumps({"benchmark": "marginal_recursion", "commit": git_commit(), "scenario": args.scenario,
                               "seed": args.seed, "parts": parts, "total_s": total, "worst_error": worst}, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
