"""A gating round applies its GNSS gate once the correction still to come is below a tenth of
the smallest white sigma the gate works with (smoother.GATE_STEP_SHARE): when the gate rejects a
fix, the next round goes on from that estimate and the steps the round would have taken to its own
tolerance are not taken; when it rejects nothing, the round carries on to its tolerance first.
Checked against the same surveys solved with the round's own tolerance (share 0): the same fixes
rejected and the same trajectory to a small fraction of a micrometre (measured 1e-8 to 8e-8 m on
seeds 1-3 with 5 % GNSS outliers), or the same bits where nothing is rejected. And the first
round's first step, solved in the sigma parts on every CPU, against the batch's step."""

from __future__ import annotations

import numpy as np
import pytest

from surveys import SHORT_OPEN_TRACK
from trackfusion import pipeline as P
from trackfusion.fusion import smoother as SM
from trackfusion.simulation.scenarios import simulate_to_dir


def _problem(d, outliers: bool):
    simulate_to_dir("open-track-gnss", d, seed=1,
                    overrides=SHORT_OPEN_TRACK + (["gnss.outlier_fraction=0.05"] if outliers else []))
    pl = P.load_pipeline(d / "pipeline.yaml")
    log, _ = P._read(pl)
    return P.build_problem(pl, log, lambda _m: None)[0]


def _both(problem, monkeypatch):
    """The smooth with the gate's tolerance (the default) and with the round's own; the number of
    Gauss-Newton steps each took."""
    out = []
    for share in (SM.GATE_STEP_SHARE, 0.0):
        monkeypatch.setattr(SM, "GATE_STEP_SHARE", share)
        said: list[str] = []
        out.append((SM.smooth(problem, said.append), sum("iteration" in s for s in said)))
    return out


def test_a_round_that_rejects_a_fix_stops_at_the_gates_tolerance(tmp_path, monkeypatch):
    (early, steps_early), (full, steps_full) = _both(_problem(tmp_path / "outliers", True), monkeypatch)
    assert full.rejected_gnss and steps_early < steps_full
    assert [r["index"] for r in early.rejected_gnss] == [r["index"] for r in full.rejected_gnss]
    assert np.max(np.abs(early.pos_n - full.pos_n)) < 2.5e-7  # m (measured 8.1e-8)
    assert np.max(np.abs(early.R_nb - full.R_nb)) < 1e-9  # measured 3.2e-10
    np.testing.assert_allclose(early.sigma_pos_n_m, full.sigma_pos_n_m, rtol=3e-7)  # measured 9.6e-8


def test_a_round_that_rejects_nothing_converges_as_before(tmp_path, monkeypatch):
    (early, _), (full, _) = _both(_problem(tmp_path / "clean", False), monkeypatch)
    assert not full.rejected_gnss
    for name in ("pos_n", "vel_n", "R_nb", "sigma_pos_n_m", "sigma_att_rad"):
        assert np.array_equal(getattr(early, name), getattr(full, name)), name


def test_no_early_gate_with_prism_readings():
    """Prism readings are gated on sigmas finer than the GNSS floor: their rounds keep their own tolerance."""
    class Gates:
        gnss, prisms = object(), object()
    assert SM._gate_step_tolerance_m(None, Gates()) == 0.0
    Gates.prisms = None

    class Problem:
        class factors:
            class gnss:
                min_sigma_mm = 2.0
    assert SM._gate_step_tolerance_m(Problem(), Gates()) == pytest.approx(SM.GATE_STEP_SHARE * 2e-3)


def test_the_first_step_in_the_sigma_parts_is_the_batch_step(tmp_path, monkeypatch):
    """The first round's first step of a run with sigma parts is solved in those parts, on every
    CPU (the same step to rounding: fusion/partitioned.py); the rest of the solve as before."""
    problem = _problem(tmp_path / "parts", False)
    monkeypatch.setattr(SM, "MARGINAL_PART_S", (problem.imu.t_s[-1] - problem.imu.t_s[0]) / 3 + 0.5)
    solved_in_parts = []
    real = SM.PartitionedSolver.solve
    monkeypatch.setattr(SM.PartitionedSolver, "solve", lambda self, gfg: solved_in_parts.append(1) or real(self, gfg))
    in_parts = SM.smooth(problem)
    first = len(solved_in_parts)
    real_start = SM._Start
    monkeypatch.setattr(SM, "_Start", lambda warm=False, ordering=None, _parts=None: real_start(warm, ordering))
    batch = SM.smooth(problem)
    assert first == len(solved_in_parts) - first + 1  # the first step, and the converging step(s) in both
    # measured: positions 7.4e-13 m, velocities 9.8e-14 m/s, rotations 4.1e-16; the sigmas 1.2e-7
    # relative (the marginals of these narrow cliques are GTSAM's, whose own error is about that)
    for name, atol in (("pos_n", 5e-12), ("vel_n", 1e-12), ("R_nb", 4e-15)):
        np.testing.assert_allclose(getattr(in_parts, name), getattr(batch, name), rtol=0, atol=atol)
    np.testing.assert_allclose(in_parts.sigma_pos_n_m, batch.sigma_pos_n_m, rtol=5e-7)
