"""The noise estimate of a refit round computed in a forked child while the smoother takes the
step that shows the solve converged (fusion/smoother.py ``_estimate_while_converging``): the same
numbers as the estimate and the step in turn, whether the step is kept (the estimate settles) or
dropped (it calls for another solve)."""

import numpy as np
import pytest

from trackfusion import forked
from trackfusion.fusion import smoother as sm


def _smooth_recording(problem, monkeypatch, enabled: bool):
    """smooth() with forking on or off; the overlapped estimates' outcomes (True: the step dropped)."""
    outcomes = []
    inner = sm._estimate_while_converging

    def recording(*args, **kwargs):
        refit, settled = inner(*args, **kwargs)
        outcomes.append(refit)
        assert (settled is None) == refit
        return refit, settled

    monkeypatch.setattr(sm, "_estimate_while_converging", recording)
    monkeypatch.setattr(forked, "ENABLED", enabled)
    monkeypatch.setattr(forked, "usable_cpus", lambda: 2)  # the child forked on a 1-CPU machine too
    return sm.smooth(problem), outcomes


@pytest.mark.parametrize("ideal, dropped", [(False, False), (True, True)])
def test_overlapped_estimate_gives_the_numbers_in_turn(tmp_path, monkeypatch, ideal, dropped):
    """Short open track: with sensor noise the second estimate settles and the overlapped step is
    kept; noise-free, the refits go on (the odometer's estimate swings about its tiny error) and
    the step is dropped. Either way the trajectory, its sigmas and the estimates are the bits of
    the run without forking, which never overlaps."""
    from surveys import short_open_track_problem
    problem = short_open_track_problem(tmp_path, 1, ideal=ideal)
    overlapped, outcomes = _smooth_recording(problem, monkeypatch, True)
    in_turn, none = _smooth_recording(problem, monkeypatch, False)
    assert none == [] and outcomes and (dropped in outcomes)
    assert np.array_equal(overlapped.pos_n, in_turn.pos_n) and np.array_equal(overlapped.R_nb, in_turn.R_nb)
    assert np.array_equal(overlapped.sigma_pos_n_m, in_turn.sigma_pos_n_m)
    assert overlapped.iterations == in_turn.iterations
    assert overlapped.noise_components == in_turn.noise_components


def test_a_run_over_the_keyframe_bound_estimates_in_turn(tmp_path, monkeypatch):
    """Beyond ESTIMATE_BESIDE_STEP_MAX_KEYFRAMES the child's copy of the tree would add to the
    step's memory (2 h at 500 Hz: 4.7 against 3.5 GB): the estimate then runs in turn, forking on."""
    from surveys import short_open_track_problem
    problem = short_open_track_problem(tmp_path, 1, ideal=False)
    monkeypatch.setattr(sm, "ESTIMATE_BESIDE_STEP_MAX_KEYFRAMES", 10)
    res, outcomes = _smooth_recording(problem, monkeypatch, True)
    assert outcomes == [] and res.noise_components is not None
