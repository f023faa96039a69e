"""The step-size stopping rule (fusion/convergence.py): the geometric tail of a linearly
converging sequence of steps. On a short simulated bridge the rule gives the cost criterion's
solution in fewer iterations: tests/test_total_station_run.py (its simulation)."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.fusion import convergence as C


def _history(steps_m, warm=False):
    h = C.StepHistory(warm=warm)
    p = np.zeros((4, 3))
    for s in steps_m:
        q = p.copy()
        q[1, 2] += s  # the largest change of one keyframe's position
        h.add(p, q)
        p = q
    return h


def test_geometric_tail_of_linear_convergence():
    h = _history([1.0, 1e-3, 1e-4])  # the first step (from the coarse start) is far larger
    assert h.remaining_m() == pytest.approx(1e-4 * 0.1 / 0.9)
    assert h.converged(2e-5) and not h.converged(1e-5) and not h.converged(0.0)


def test_no_claim_before_three_steps_or_when_slow():
    assert _history([1.0, 1e-6]).remaining_m() == np.inf  # one ratio: could be the first step's
    assert _history([1e-3, 6e-4, 3e-4]).remaining_m() == np.inf  # rho above RHO_MAX
    assert _history([1e-3, 1e-4, 0.0]).remaining_m() == 0.0


def test_two_steps_enough_from_a_converged_start():
    """A refit round starts at the converged estimate: its first step is the new weights'
    response, not a coarse start's, so its ratio to the second counts."""
    h = _history([1e-3, 1e-4], warm=True)
    assert h.remaining_m() == pytest.approx(1e-4 * 0.1 / 0.9)
    assert h.copy().warm and h.copy().remaining_m() == h.remaining_m()
    assert _history([1e-3], warm=True).remaining_m() == np.inf
    assert _history([1e-3, 6e-4], warm=True).remaining_m() == np.inf  # rho above RHO_MAX
    assert _history([1.0, 1e-3, 1e-4], warm=True).remaining_m() == pytest.approx(1e-4 * 0.1 / 0.9)


def test_a_gating_round_trusts_the_first_two_steps():
    """A gating round's estimate only decides the gate (smoother.StopRule.gating): the first two
    steps' ratio counts, as a warm start's does; the round that goes on from it does not."""
    h = _history([8.5e-3, 2.8e-4])  # bridge seed 1's first round: 8.5 mm, then 0.28 mm
    tail = 2.8e-4 * (2.8e-4 / 8.5e-3) / (1 - 2.8e-4 / 8.5e-3)
    assert h.remaining_m(first_ratio=True) == pytest.approx(tail)
    assert h.converged(2e-5, first_ratio=True) and not h.converged(2e-5)
    assert h.remaining_m() == np.inf and h.copy().remaining_m() == np.inf  # what the last round's convergence sees
    assert _history([1.0, 0.6]).remaining_m(first_ratio=True) == np.inf  # rho above RHO_MAX
    assert _history([1.0]).remaining_m(first_ratio=True) == np.inf


def test_default_tolerance():
    from trackfusion.fusion.settings import SmootherSettings
    assert SmootherSettings().step_tolerance_mm == C.DEFAULT_STEP_TOLERANCE_MM
