"""Consistency RMS(error / sigma) with its effective sample count and interval (evaluation/consistency.py).

Oracles: white and Gauss-Markov errors of known sigma (n_eff of a Gauss-Markov series is about
T / tau), the coverage of the 95 % interval over many honest runs, and a sigma twice too large.
"""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.evaluation.consistency import consistency_of, effective_samples, pooled, rms_interval
from trackfusion.evaluation.errors_series import Trajectory
from trackfusion.evaluation.reference import consistency, consistency_detail
from trackfusion.simulation.noise import gauss_markov


def test_white_errors():
    z = np.random.default_rng(1).standard_normal(20_000)
    c = consistency_of(z)
    assert c["rms"] == pytest.approx(1.0, abs=0.02)
    assert c["n_eff"] == pytest.approx(20_000, rel=0.1)
    assert c["interval_95"][0] < 1.0 < c["interval_95"][1] and c["interval_95"][1] < 1.03


def test_gauss_markov_effective_samples_about_T_over_tau():
    # dt = 1 s, tau = 50 s, T = 10 000 s: n_eff = N / (1 + 2 sum rho^2) = N / (1 + 2 / (e^{2/50} - 1)) = 199
    z = gauss_markov(10_000, 1.0, 1.0, 50.0, np.random.default_rng(2))
    assert effective_samples(z) == pytest.approx(199.0, rel=0.3)


def test_one_sample_interval_by_hand():
    # chi-square with 1 degree of freedom: 2.5 % and 97.5 % quantiles 0.000982 and 5.0239
    lo, hi = rms_interval(1.0)
    assert lo == pytest.approx(np.sqrt(0.000982), rel=1e-3) and hi == pytest.approx(np.sqrt(5.0239), rel=1e-4)


def _coverage(sigma_scale: float) -> float:
    rng = np.random.default_rng(3)
    inside = 0
    for _ in range(200):
        z = gauss_markov(3000, 1.0, 1.0, 300.0, rng) / sigma_scale  # T / tau = 10: few samples per run
        c = consistency_of(z)
        inside += c["interval_95"][0] <= c["rms"] <= c["interval_95"][1]
    return inside / 200


def test_interval_covers_honest_runs_and_rejects_a_wrong_sigma():
    assert 0.85 <= _coverage(1.0) <= 1.0
    assert _coverage(3.0) < 0.2  # sigma three times too large


def test_pooled_runs():
    runs = [{"rms": 0.5, "n_eff": 10.0, "samples": 100}, {"rms": 0.34, "n_eff": 6.0, "samples": 100},
            {"rms": 1.81, "n_eff": 2.0, "samples": 100}]
    p = pooled(runs)
    assert p["rms"] == pytest.approx(np.sqrt((0.25 + 0.1156 + 3.2761) / 3))
    assert p["n_eff"] == 18.0 and p["interval_95"] == list(rms_interval(18.0))


def test_metrics_from_a_trajectory_table():
    t = np.arange(0.0, 100.0, 0.1)
    pos = np.column_stack([t, 0 * t, 0 * t])
    vel = np.tile([1.0, 0.0, 0.0], (t.size, 1))
    reference = Trajectory.from_columns({"t_s": t, "e_m": pos[:, 0], "n_m": pos[:, 1], "u_m": pos[:, 2],
                                         "ve_mps": vel[:, 0], "vn_mps": vel[:, 1], "vu_mps": vel[:, 2],
                                         "chainage_m": t},
                                        source="reference")
    table = {"t_s": t, "e_m": t + 0.002, "n_m": 0 * t - 0.001, "u_m": 0 * t + 0.003,
             "sigma_e_m": 0.001 + 0 * t, "sigma_n_m": 0.002 + 0 * t, "sigma_u_m": 0.003 + 0 * t}
    assert consistency(table, reference) == pytest.approx({"e": 2.0, "n": 0.5, "u": 1.0})
    detail = consistency_detail(table, reference)
    assert detail["e"]["samples"] == t.size and detail["e"]["n_eff"] == 1.0  # a constant error: one sample
