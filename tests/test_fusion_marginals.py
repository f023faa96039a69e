"""The sigma columns come from the Bayes tree of the solve's last Gauss-Newton iteration (no
extra linearisation and elimination for the marginals). That tree is linearised at most one
converged step before the estimate, so its marginals must equal those of a fresh
linearisation at the estimate (to far below the sigmas' own meaning; 1e-3 relative here)."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.fusion import smoother

from surveys import short_open_track_problem


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    return short_open_track_problem(tmp_path_factory.mktemp("marginals"), 3)


def test_marginals_of_the_last_iteration_equal_a_fresh_linearisation(problem, monkeypatch):
    reused = smoother.smooth(problem)
    solve = smoother.gauss_newton

    def fresh_tree(G, values, with_scale, *args, **kwargs):
        sol = solve(G, values, with_scale, *args, **kwargs)
        sol.tree = smoother._eliminate(smoother._linearize(G, sol.values, with_scale))
        return sol

    monkeypatch.setattr(smoother, "gauss_newton", fresh_tree)
    fresh = smoother.smooth(problem)
    np.testing.assert_array_equal(reused.sigma_t_s, fresh.sigma_t_s)
    assert reused.sigma_pos_n_m.shape[0] > 10
    np.testing.assert_allclose(reused.sigma_pos_n_m, fresh.sigma_pos_n_m, rtol=1e-3)
    np.testing.assert_allclose(reused.sigma_att_rad, fresh.sigma_att_rad, rtol=1e-3)
    np.testing.assert_array_equal(reused.pos_n, fresh.pos_n)
