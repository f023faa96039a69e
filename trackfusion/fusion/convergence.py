"""A step-size stopping rule for the smoother's Gauss-Newton iterations (docs/solver_speed.md).

With Huber losses the iterations are iteratively reweighted least squares, which converges
linearly: each accepted step is about ``rho`` times the one before (measured on the 54 min
bridge survey: ``rho`` = 0.099-0.104 over the last four steps; without the Huber losses the
same problem converges quadratically, in two iterations). The correction still to come after
step ``n`` is then the geometric tail ``s_n rho / (1 - rho)``, with ``s_n`` the step's largest
keyframe position change. The cost criterion (``smoother.relative_tolerance``) waits for the
tail to be far below anything a survey sees (on the bridge: two more full relinearisations
for the last 0.008 mm); this rule stops as soon as the predicted tail is below
``smoother.step_tolerance_mm``.

``rho`` is estimated as the larger of the last two step ratios, so that the first step (from
the coarse initial estimate, metres) never makes the second look converged: the rule needs
three accepted steps, and claims nothing while ``rho`` is above :data:`RHO_MAX`. A solve that
starts at the converged estimate of the same graph with other noise weights (a noise refit
round, ``warm``) has no coarse first step: its first step is the weights' linear response, and
the ratio of its two steps already measures ``rho`` (two steps are enough). Nor does a gating
round (``StopRule.gating`` in fusion/smoother.py) wait for a third step: its estimate only decides
the gate and the noise estimate, and the round after it (or the last round's convergence, which
carries its steps on and needs three) goes on from it, so the final estimate meets the same rule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: step ratio above which the geometric tail is not trusted (slow or erratic convergence)
RHO_MAX = 0.5
#: default ``smoother.step_tolerance_mm`` (1 % of the bridge's 2 mm round-trip target; on the
#: GNSS hour it cuts an iteration and moves the 5 m relative accuracy by 1e-5 mm: docs/solver_speed.md)
DEFAULT_STEP_TOLERANCE_MM = 0.02


@dataclass
class StepHistory:
    """Largest keyframe position change [m] of each accepted Gauss-Newton step, in order."""

    steps_m: list[float] = field(default_factory=list)
    #: the first step starts at the converged estimate of the same graph reweighted (module docstring)
    warm: bool = False

    def add(self, pos_before_n: np.ndarray, pos_after_n: np.ndarray) -> None:
        """Record one accepted step between keyframe positions (K,3) [m]."""
        self.steps_m.append(float(np.max(np.abs(pos_after_n - pos_before_n))) if pos_after_n.size else 0.0)

    def remaining_m(self, first_ratio: bool = False) -> float:
        """Predicted correction still to come [m] (the geometric tail), inf when it cannot be
        estimated (fewer than three steps, two when :attr:`warm` or ``first_ratio``, or a step
        ratio above :data:`RHO_MAX`). ``first_ratio``: the ratio of the first two steps of a cold
        start is trusted too (a gating round's, see :class:`~.smoother.StopRule`)."""
        if len(self.steps_m) < (2 if self.warm or first_ratio else 3):
            return np.inf
        last = self.steps_m[-3:]
        if last[-1] == 0.0:
            return 0.0
        if min(last[:-1]) <= 0.0:
            return np.inf
        rho = max(b / a for a, b in zip(last[:-1], last[1:]))
        return last[-1] * rho / (1.0 - rho) if rho < RHO_MAX else np.inf

    def converged(self, tolerance_m: float, first_ratio: bool = False) -> bool:
        """True when the predicted remaining correction (:meth:`remaining_m`) is below
        ``tolerance_m`` (> 0)."""
        return tolerance_m > 0.0 and self.remaining_m(first_ratio) < tolerance_m

    def copy(self) -> "StepHistory":
        return StepHistory(list(self.steps_m), self.warm)
