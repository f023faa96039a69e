"""Priors on a segment's slow states from the data outside it (fusion/slow_pass.py, slow_states.py).

One short noisy open-track survey (215 s: static, 240 m out at 3 m/s, static, 140 m back):

* the smoother's hook: a prior lands on the bias / scale state nearest in time, its covariance
  grown by the random walk over the time between; a tight prior holds the state at its value;
  a ``start`` prior replaces the specification's priors;
* the coarse problem keeps the information per second: its bias and scale estimates match the
  one batch's within the coarse sigma, and its sigmas are the batch's within a factor 1.5;
* the data after a cut is smoothed with a flat prior (the specification counted once: the
  weakly observed lateral accelerometer bias keeps a sigma far above the specification's), and the
  before / after priors of a cut together give back the whole run's coarse estimate there (within
  the combined sigma: the cut also breaks the attitude chain, which carries some of the gyro bias);
* two segments with the priors reproduce the one batch's slow states within its sigma.
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from trackfusion.fusion import segments, slow_pass, smoother
from trackfusion.fusion.slow_states import SlowPrior, replaces_start, slow_prior_factors

from surveys import short_open_track_problem

UG = 9.80665e-6
SETTINGS = slow_pass.SlowPassSettings()


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    prob = short_open_track_problem(tmp_path_factory.mktemp("slow-priors"), 4)
    # the opt-in priors were built and measured on 0.1 s keyframes with the wheel path on every
    # 2nd one (the simulated pipelines before their 0.2 s keyframes: docs/solver_speed.md)
    wheel = prob.factors.wheel_path.model_copy(update={"keyframe_step": 2})
    return replace(prob, keyframes=prob.keyframes.model_copy(update={"spacing_s": 0.1}),
                   factors=prob.factors.model_copy(update={"wheel_path": wheel}),
                   smoother=prob.smoother.model_copy(update={"overlap_s": 30.0, "workers": 2, "slow_priors": True}))


@pytest.fixture(scope="module")
def batch(problem):
    return smoother.smooth(problem, end_covariances=True)


def _bias(res, k):
    return np.r_[res.accel_bias_mps2[k], res.gyro_bias_radps[k]]


def test_a_prior_lands_on_the_nearest_state_with_the_random_walk_added(problem):
    t_key = np.arange(0.0, 100.0, 0.5)
    bias_seg = np.minimum((t_key // 30.0).astype(int), 2)  # states at 0-30, 30-60, 60-100 s
    seg = (t_key // 10.0).astype(int)
    cov = np.diag(np.r_[[1e-10] * 3, [1e-16] * 3])
    p = SlowPrior(120.0, np.r_[1e-4, 0, 0, 1e-8, 0, 0], cov, 5e-5, 1e-10, start=False)
    f_bias, f_scale = slow_prior_factors([p], t_key, bias_seg, seg, problem.imu_noise, problem.factors.odometer)
    assert gtsam.Symbol(f_bias.keys()[0]).index() == 2 and gtsam.Symbol(f_scale.keys()[0]).index() == 9
    dt_bias, dt_scale = 120.0 - 0.5 * (60.0 + 99.5), 120.0 - 0.5 * (90.0 + 99.5)
    n = problem.imu_noise
    expected = np.diag(cov) + np.r_[[n.accel_bias_rw_psd] * 3, [n.gyro_bias_rw_psd] * 3] * dt_bias
    info = f_bias.noiseModel().R().T @ f_bias.noiseModel().R()
    np.testing.assert_allclose(np.diag(np.linalg.inv(info)), expected, rtol=1e-9)
    rw = (problem.factors.odometer.scale_random_walk_ppm_per_sqrt_h * 1e-6) ** 2 / 3600.0
    assert 1.0 / f_scale.noiseModel().sigmas()[0] ** 2 == pytest.approx(1.0 / (1e-10 + rw * dt_scale), rel=1e-9)
    assert not replaces_start([p]) and replaces_start([p, replace(p, start=True)]) and not replaces_start(None)


def test_a_tight_start_prior_holds_the_bias_and_replaces_the_specification(problem, batch):
    held = np.r_[30.0, -20.0, 0.0] * UG + np.r_[0.0, 0.0, batch.accel_bias_mps2[0, 2]]
    tight = np.diag(np.r_[[(0.1 * UG) ** 2] * 3, [1e-22] * 3])
    p = SlowPrior(float(problem.imu.t_s[0]), np.r_[held, batch.gyro_bias_radps[0]], tight, 0.0, 1e-14, start=True)
    res = smoother.smooth(problem, slow_priors=[p])
    np.testing.assert_allclose(res.accel_bias_mps2[0], held, atol=0.5 * UG)
    assert abs(res.odometer_scale[0]) < 1e-6
    assert res.factor_counts["bias_prior"] == 0 and res.factor_counts["slow_prior"] == 2
    assert batch.factor_counts["bias_prior"] == 1 and "slow_prior" not in batch.factor_counts


def test_the_coarse_problem_keeps_the_slow_states_and_their_information(problem, batch):
    coarse = smoother.smooth(slow_pass.coarse_problem(problem, SETTINGS), end_covariances=True)
    assert coarse.t_s.size < batch.t_s.size / 10
    for k, cov_c, cov_b in ((0, coarse.end_cov.bias_first, batch.end_cov.bias_first),
                            (-1, coarse.end_cov.bias_last, batch.end_cov.bias_last)):
        sigma_c, sigma_b = np.sqrt(np.diag(cov_c)), np.sqrt(np.diag(cov_b))
        assert np.all(np.abs(_bias(coarse, k) - _bias(batch, k)) <= 1.0 * sigma_c)
        np.testing.assert_allclose(sigma_c, sigma_b, rtol=0.5)
    assert abs(coarse.odometer_scale[-1] - batch.odometer_scale[-1]) <= np.sqrt(coarse.end_cov.scale_last)


def test_before_and_after_priors_of_a_cut_give_back_the_whole_run(problem):
    t = problem.imu.t_s
    cut = int(np.searchsorted(t, 0.5 * (t[0] + t[-1])))
    before, after = slow_pass.outside_priors(problem, cut, cut, SETTINGS)
    assert before.start and not after.start
    n = problem.imu_noise
    # the data after the cut: no specification prior (the lateral accelerometer bias, which no data
    # here tells well, keeps a sigma far above the specification's)
    assert np.sqrt(after.bias_cov[1, 1]) > 30.0 * n.accel_bias_sigma_mps2
    assert np.sqrt(before.bias_cov[1, 1]) == pytest.approx(n.accel_bias_sigma_mps2, rel=0.05)
    whole = smoother.smooth(slow_pass.coarse_problem(problem, SETTINGS), end_covariances=True)
    k = int(np.searchsorted(whole.t_s, t[cut]))
    info = np.linalg.inv(before.bias_cov) + np.linalg.inv(after.bias_cov)
    combined = np.linalg.solve(info, np.linalg.solve(before.bias_cov, before.bias) + np.linalg.solve(after.bias_cov, after.bias))
    sigma = np.sqrt(np.diag(np.linalg.inv(info)))
    along = [0, 2, 3, 4, 5]  # the observable components (not the lateral accelerometer bias)
    assert np.all(np.abs(combined - _bias(whole, k))[along] <= 1.0 * sigma[along])


def test_segments_with_the_priors_reproduce_the_batch_slow_states(problem, batch, monkeypatch):
    monkeypatch.setattr(segments, "can_fork", lambda n: False)
    res, _, info = segments.smooth_in_segments(problem, every=5)
    assert info["count"] == 2
    assert [s["factors"].get("slow_prior") for s in info["segments"]] == [2, 2]  # bias and scale, one side each
    k = nearest = smoother.nearest_sample(batch.t_s, res.t_s)
    sigma_b = np.sqrt(np.diag(batch.end_cov.bias_last))
    diff = np.abs(np.column_stack([res.accel_bias_mps2, res.gyro_bias_radps]) - np.column_stack(
        [batch.accel_bias_mps2[k], batch.gyro_bias_radps[nearest]]))
    assert np.all(diff.max(axis=0) <= 1.0 * sigma_b)
