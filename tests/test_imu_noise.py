"""IMU noise from static periods (fusion/imu_noise.py) against known noise: the simulated
grades' datasheet values, the stated uncertainty's consistency over many draws, and the
analytic floor of white noise plus a rate random walk."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.fusion.imu_noise import BIAS_FLOOR, estimate_imu_noise
from trackfusion.sensors.imu import IMU_GRADES
from trackfusion.simulation.imu import simulate_imu
from trackfusion.sensors.types import ImuData

DEG = np.pi / 180.0
STATIC = [(0.0, 30.0), (100.0, 130.0), (170.0, 199.0)]


def _still_imu(spec, seed: int, duration_s: float = 200.0) -> ImuData:
    t = np.arange(0.0, duration_s, 1.0 / spec.rate_hz)
    gyro = np.tile([2e-5, 5e-5, 4e-5], (t.size, 1))  # the Earth rate of some latitude
    accel = np.tile([0.01, -0.02, 9.81], (t.size, 1))
    return simulate_imu(t, gyro, accel, spec, np.random.default_rng(seed))[0]


@pytest.mark.parametrize("grade", ["navigation-500", "fog", "mems-tactical"])
def test_white_noise_of_each_grade(grade):
    """ARW and VRW of a still IMU with every error of the grade (biases, instability,
    scale, misalignment, quantisation) come back within 1 % and 4 stated sigmas."""
    spec = IMU_GRADES[grade]
    est = estimate_imu_noise(_still_imu(spec, seed=1), STATIC, spec)
    assert est.periods == 3 and est.static_s == pytest.approx(89.0, abs=0.1)
    for key in ("gyro_arw_deg_per_sqrt_h", "accel_vrw_mps_per_sqrt_h"):
        term = est.terms()[key]
        truth = getattr(spec, key)
        assert term.value == pytest.approx(truth, rel=0.01)
        assert abs(term.value - truth) < 4 * term.sigma
        assert term.ratio() == pytest.approx(term.value / truth)
        assert all(v == pytest.approx(truth, rel=0.02) for v in term.per_axis)


def test_stated_sigma_is_honest():
    """Over 40 draws of white noise, (estimate - truth) / sigma has an RMS near 1."""
    rate_hz, n_true = 200.0, 3e-6  # [rad/sqrt(s)]
    t = np.arange(0.0, 20.0, 1.0 / rate_hz)
    z = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        gyro = rng.normal(0.0, n_true * np.sqrt(rate_hz), (t.size, 3))
        est = estimate_imu_noise(ImuData(t, gyro, rng.normal(0.0, 1e-3, (t.size, 3))), [(0.0, 20.0)])
        term = est.gyro_arw_deg_per_sqrt_h
        z.append((term.value - n_true * 60.0 / DEG) / term.sigma)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 < rms < 1.6, rms


def test_floor_of_white_noise_and_rate_random_walk():
    """White noise N and a rate random walk K: the Allan variance N^2/tau + K^2 tau/3 has its
    minimum 2 N K / sqrt(3) at tau = sqrt(3) N / K; the reported bias instability is that
    floor's deviation / 0.664."""
    rate_hz, n, k = 100.0, 1e-4, 1e-5  # tau* = 17 s
    t = np.arange(0.0, 1500.0, 1.0 / rate_hz)
    rng = np.random.default_rng(3)
    gyro = rng.normal(0.0, n * np.sqrt(rate_hz), (t.size, 3)) + np.cumsum(
        rng.normal(0.0, k / np.sqrt(rate_hz), (t.size, 3)), axis=0)
    est = estimate_imu_noise(ImuData(t, gyro, gyro * 0.0 + 9.81), [(0.0, 1500.0)])
    term = est.gyro_bias_instability_deg_per_h
    floor_radps = np.sqrt(2.0 * n * k / np.sqrt(3.0))
    assert term.value is not None
    # the smallest of noisy estimates is biased low (by ~8 %, its 1-sigma at tau*): within 15 %
    assert term.value == pytest.approx(floor_radps / BIAS_FLOOR * 3600.0 / DEG, rel=0.15)


def test_bias_instability_not_observable_on_short_still_periods():
    """Half a minute still of a navigation-grade IMU cannot tell its bias instability: no number,
    a reason and an upper bound instead."""
    spec = IMU_GRADES["navigation-500"]
    est = estimate_imu_noise(_still_imu(spec, seed=2), STATIC, spec)
    term = est.gyro_bias_instability_deg_per_h
    assert term.value is None and term.sigma is None
    assert "not observable" in term.why and "at most" in term.why
    assert est.to_json()["gyro_bias_instability_deg_per_h"]["why"] == term.why


def test_no_static_period_no_estimate():
    spec = IMU_GRADES["navigation"]
    imu = _still_imu(spec, seed=0, duration_s=20.0)
    assert estimate_imu_noise(imu, []) is None
    assert estimate_imu_noise(imu, [(1.0, 4.0)]) is None  # shorter than MIN_PERIOD_S


def test_run_uses_the_estimate_where_the_datasheet_is_off(tmp_path):
    """A survey whose gyros are 3x noisier than the pipeline's datasheet says: the run reports the
    estimate, uses it for the gyros (outside the 1.5x tolerance) and keeps the accelerometers'
    datasheet value (inside it)."""
    import yaml

    from surveys import SHORT_OPEN_TRACK
    from trackfusion.pipeline import load_pipeline, run
    from trackfusion.simulation.scenarios import simulate_to_dir

    simulate_to_dir("open-track-gnss", tmp_path, seed=7,
                    overrides=SHORT_OPEN_TRACK + ["imu.gyro_arw_deg_per_sqrt_h=0.003"])
    path = tmp_path / "pipeline.yaml"
    cfg = yaml.safe_load(path.read_text())
    assert cfg["sensors"]["imu"]["gyro_arw_deg_per_sqrt_h"] == 0.003
    cfg["sensors"]["imu"]["gyro_arw_deg_per_sqrt_h"] = 0.001  # the datasheet, optimistic
    path.write_text(yaml.safe_dump(cfg))
    said: list[str] = []
    est = run(load_pipeline(path), tmp_path / "out", progress=said.append).metrics["noise_estimates"]["imu"]
    assert est["used"] == ["gyro_arw_deg_per_sqrt_h"]
    assert est["gyro_arw_deg_per_sqrt_h"]["value"] == pytest.approx(0.003, rel=0.03)
    assert est["gyro_arw_deg_per_sqrt_h"]["ratio_to_datasheet"] == pytest.approx(3.0, rel=0.03)
    assert any("sensors.imu.gyro_arw_deg_per_sqrt_h" in m and "uses the estimate" in m for m in said)


def test_noise_free_static_data_keep_the_datasheet():
    """An ideal log's still periods hold no noise: the estimate is reported (0) and not used."""
    from trackfusion.pipeline import _imu_spec_from_data

    spec = IMU_GRADES["navigation"]
    t = np.arange(0.0, 40.0, 1.0 / spec.rate_hz)
    imu = ImuData(t, np.tile([0.0, 5e-5, 4e-5], (t.size, 1)), np.tile([0.0, 0.0, 9.81], (t.size, 1)))
    est = estimate_imu_noise(imu, [(0.0, 40.0)], spec)
    assert est.gyro_arw_deg_per_sqrt_h.value < 1e-20  # rounding of the constant samples
    assert _imu_spec_from_data(spec, est, 1.5) == (spec, [])
