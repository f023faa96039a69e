"""Speed profiles: analytic derivatives, holds, reversals."""

import numpy as np
import pytest

from trackfusion.errors import SimulationError
from trackfusion.simulation.motion import Hold, Move, compile_plan


@pytest.fixture
def plan():
    return compile_plan(10.0, [Hold(5), Move(100, 1.0, 0.3), Hold(3), Move(20, 1.2, 0.3), Hold(5),
                               Move(20.5, 1.0, 0.3)])


def test_derivatives_match_finite_differences(plan):
    t = np.linspace(0, plan.end_s, 400_001)
    s, v, a = plan.evaluate(t)
    dt = t[1] - t[0]
    assert np.abs(np.gradient(s, dt) - v)[1:-1].max() < 1e-6
    assert np.abs(np.gradient(v, dt) - a)[1:-1].max() < 1e-5
    # acceleration is continuous: no jumps larger than the jerk bound allows
    moving = plan.T_a_s > 0
    jerk_max = np.max(plan.a_peak[moving] * np.pi / plan.T_a_s[moving])
    assert np.abs(np.diff(a)).max() <= jerk_max * dt * 1.0001


def test_targets_speeds_and_holds(plan):
    s, v, _ = plan.evaluate(np.array([0.0, 4.9, plan.end_s]))
    assert s[0] == 10.0 and s[1] == 10.0 and s[2] == pytest.approx(20.5, abs=1e-12)
    t = np.linspace(0, plan.end_s, 100_001)
    s, v, a = plan.evaluate(t)
    assert v.max() == pytest.approx(1.0, abs=1e-12)
    assert v.min() == pytest.approx(-1.2, abs=1e-12)  # the reversal runs backwards
    assert np.abs(a).max() <= 0.3 + 1e-12
    for t0, t1 in plan.static_intervals():
        inside = (t > t0 + 1e-9) & (t < t1 - 1e-9)
        assert np.all(v[inside] == 0.0)
    assert plan.chainage_range_m == (10.0, 100.0)


def test_short_move_lowers_speed():
    p = compile_plan(0.0, [Move(0.5, 2.0, 0.3)])
    v = p.evaluate(np.linspace(0, p.end_s, 10_001))[1]
    assert v.max() == pytest.approx(np.sqrt(0.5 * 0.3 / 2), rel=1e-9)
    assert p.evaluate(p.end_s)[0] == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize("seg", [Hold(0.0), Move(5.0, 0.0), Move(5.0, 1.0, -1.0), Move(0.0, 1.0)])
def test_bad_segments_raise(seg):
    with pytest.raises(SimulationError):
        compile_plan(0.0, [seg])
