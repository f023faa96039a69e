"""The sigma columns are the exact marginals of the linearised graph: every reported position
and attitude sigma of a short survey (40 s, GNSS, odometer, wheel path) equals the one of the
dense covariance, the inverse of the information matrix (by numpy's QR of the whole whitened
Jacobian, the square root of the information), to 1e-6 relative: in one piece (the default on
a run this short) and with the marginals in three parts (the default's way on a run over
``MARGINAL_PART_S``, fusion/partitioned.py). Measured: within 1.3e-7 of the dense inverse."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import scipy.linalg
from gtsam.symbol_shorthand import X

from trackfusion.fusion import smoother
from trackfusion.fusion.normal_solve import KEY_DIM

SIGMA_REL_TOL = 1e-6
#: tangent dimension of each kind of state (pose, velocity, bias, odometer scale, GNSS error, station)
DIMS = KEY_DIM  # the smoother's variables (fusion/normal_solve.py)

#: 10 s static, 60 m at 3 m/s, 5 s static
TINY_OPEN_TRACK = ["motion.passes=1",
                   "motion.segments=[{hold_s: 10}, {move_to_m: 60, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 5}]"]


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    from trackfusion import pipeline as P
    from trackfusion.simulation.scenarios import simulate_to_dir
    d = tmp_path_factory.mktemp("exact-marginals")
    simulate_to_dir("open-track-gnss", d, seed=4, overrides=TINY_OPEN_TRACK)
    pl = P.load_pipeline(d / "pipeline.yaml")
    return P.build_problem(pl, P._read(pl)[0], lambda _m: None)[0]


def _dense_covariance_blocks(gfg, keys: list[int]) -> dict[int, np.ndarray]:
    """Marginal covariance (6,6) of each pose key of ``keys`` from the whole graph ``gfg``:
    the whitened Jacobian assembled densely, R of its QR, the rows of R^-1 of the key."""
    dims, blocks = {}, []
    for i in range(gfg.size()):
        f = gfg.at(i)
        if f is None:
            continue
        A, b = f.jacobian()
        ks = list(f.keys())
        d = [DIMS[chr(gtsam.Symbol(k).chr())] for k in ks]
        assert sum(d) == A.shape[1]
        for k, n in zip(ks, d):
            dims.setdefault(int(k), n)
        blocks.append((ks, d, np.asarray(A)))
    order = sorted(dims)
    col = dict(zip(order, np.r_[0, np.cumsum([dims[k] for k in order])[:-1]].tolist()))
    n = sum(dims.values())
    rows = sum(A.shape[0] for _, _, A in blocks)
    J = np.zeros((rows, n))
    r = 0
    for ks, d, A in blocks:
        c = 0
        for k, m in zip(ks, d):
            J[r:r + A.shape[0], col[int(k)]:col[int(k)] + m] = A[:, c:c + m]
            c += m
        r += A.shape[0]
    R = np.linalg.qr(J, mode="r")
    R_inv = scipy.linalg.solve_triangular(R, np.eye(n))  # cov = R^-1 R^-T
    out = {}
    for k in keys:
        rows_k = R_inv[col[k]:col[k] + 6]
        out[k] = rows_k @ rows_k.T
    return out


def _sigmas(cov: np.ndarray, R_nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) and attitude (3,) sigmas of a pose covariance as :func:`smoother._marginal_sigmas`."""
    att_n = R_nb @ cov[:3, :3] @ R_nb.T
    return np.sqrt(np.diag(R_nb @ cov[3:, 3:] @ R_nb.T)), np.sqrt([cov[0, 0], cov[1, 1], att_n[2, 2]])


def _check_against_dense(problem, monkeypatch) -> int:
    seen = []
    real = smoother._sigma_covariances

    def recording(problem_, sol, gfg, *args):
        seen.append(gfg if gfg is not None else sol.gfg)
        return real(problem_, sol, gfg, *args)
    monkeypatch.setattr(smoother, "_sigma_covariances", recording)
    result = smoother.smooth(problem)
    assert len(seen) == 1
    k_sig = np.searchsorted(result.t_s, result.sigma_t_s)
    assert np.array_equal(result.t_s[k_sig], result.sigma_t_s) and k_sig.size > 30
    dense = _dense_covariance_blocks(seen[0], [X(int(k)) for k in k_sig])
    worst = 0.0
    for i, k in enumerate(k_sig):
        pos, att = _sigmas(dense[X(int(k))], result.R_nb[k])
        worst = max(worst, np.abs(result.sigma_pos_n_m[i] / pos - 1).max(), np.abs(result.sigma_att_rad[i] / att - 1).max())
    assert worst < SIGMA_REL_TOL, worst
    return result


def test_sigmas_equal_the_dense_inverse_in_one_piece(problem, monkeypatch):
    calls = []
    real = smoother.part_marginal_covariances
    monkeypatch.setattr(smoother, "part_marginal_covariances", lambda *a: calls.append(1) or real(*a))
    _check_against_dense(problem, monkeypatch)
    assert not calls  # a run this short: the solve's own Bayes tree


def test_sigmas_equal_the_dense_inverse_in_parts(problem, monkeypatch):
    counts = []
    real = smoother.part_marginal_covariances

    def counting(partition, gfg, keys, workers, *rest):
        counts.append(partition.count)
        return real(partition, gfg, keys, workers, *rest)
    monkeypatch.setattr(smoother, "part_marginal_covariances", counting)
    duration = problem.imu.t_s[-1] - problem.imu.t_s[0]
    monkeypatch.setattr(smoother, "MARGINAL_PART_S", duration / 3 + 0.5)
    _check_against_dense(problem, monkeypatch)
    assert counts == [3]


def test_sigmas_equal_the_dense_inverse_in_parts_by_one_pass_down_each_tree(problem, monkeypatch):
    """The parts' pass down each tree (fusion/tree_marginals.py; the default where the cliques
    are wide, as on the bridge's sigma parts) on every part of this run."""
    from trackfusion.fusion import partitioned, tree_marginals
    passes = []
    real = tree_marginals.marginal_covariances
    monkeypatch.setattr(tree_marginals, "WIDE_CLIQUE_COLUMNS", 0.0)
    monkeypatch.setattr(partitioned, "marginal_covariances", lambda *a: passes.append(1) or real(*a))
    monkeypatch.setattr(smoother, "usable_cpus", lambda: 1)  # every part here, where the passes are counted
    monkeypatch.setattr(smoother, "MARGINAL_PART_S", (problem.imu.t_s[-1] - problem.imu.t_s[0]) / 3 + 0.5)
    _check_against_dense(problem, monkeypatch)
    assert len(passes) == 3


def test_part_covariances_are_the_same_bits_on_any_number_of_processes(problem, monkeypatch):
    """The sigma columns' covariances dealt to 1, 2 or 3 processes (parts of a third of the run)
    are the same bits, and those of :class:`~trackfusion.fusion.partitioned.PartMarginals`."""
    from trackfusion.fusion import partitioned
    seen = []
    real = smoother.part_marginal_covariances

    def recording(partition, gfg, keys, workers, *rest):
        seen.append((partition, gfg, keys))
        return real(partition, gfg, keys, workers, *rest)
    monkeypatch.setattr(smoother, "part_marginal_covariances", recording)
    monkeypatch.setattr(smoother, "MARGINAL_PART_S", (problem.imu.t_s[-1] - problem.imu.t_s[0]) / 3 + 0.5)
    smoother.smooth(problem)
    partition, gfg, keys = seen[0]
    assert partition.count == 3 and len(keys) > 30
    by_workers = [real(partition, gfg, keys, w)[0] for w in (1, 2, 3)]
    lazy = partitioned.part_marginals(partition, gfg)
    home = lazy.layout.home
    for k in keys:
        assert all(np.array_equal(by_workers[0][k], other[k]) for other in by_workers[1:])
        assert np.array_equal(by_workers[0][k], lazy.covariances(home[int(k)], [k])[k])


def test_the_converging_step_in_the_sigma_parts_hands_its_reductions_to_the_sigmas(problem, monkeypatch):
    """A one-batch solve takes its converging step in the sigma columns' parts (the same step),
    and the sigmas are made from that step's reductions: the same bits as reducing the parts
    again, in 1 or 2 processes (the step's worker sends its reductions packed: a part's reduced
    graph can hold a linearised IMU factor between two cut keyframes, which does not pickle)."""
    seen = []
    real = smoother.part_marginal_covariances

    def recording(partition, gfg, keys, workers, *rest):
        seen.append((partition, gfg, keys, rest))
        return real(partition, gfg, keys, workers, *rest)
    monkeypatch.setattr(smoother, "part_marginal_covariances", recording)
    monkeypatch.setattr(smoother, "MARGINAL_PART_S", (problem.imu.t_s[-1] - problem.imu.t_s[0]) / 3 + 0.5)
    smoother.smooth(problem)
    (partition, gfg, keys, (station_keys, made)), = seen
    assert partition.count == 3 and made is not None and len(made.reduced) == 3
    again = real(partition, gfg, keys, 1)[0]
    for workers in (1, 2):
        given = real(partition, gfg, keys, workers, station_keys, made)[0]
        assert all(np.array_equal(given[k], again[k]) for k in keys)
