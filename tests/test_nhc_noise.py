"""The NHC sigma of a rigid trolley on irregular rails (track/nhc_noise.py, simulation/nhc_sigma.py).

Oracles: the hand-computed transfer of a sinusoidal irregularity; the simulator's own rigid
trolley (wheel contacts -> frame) on a track with a sinusoid; a synthesized German-spectrum
track; the configs in configs/ carry the library sigma, not their scenario's derivation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from trackfusion.fusion.settings import NhcSettings
from trackfusion.simulation import scenarios as sc
from trackfusion.simulation.config import load_scenario
from trackfusion.simulation.nhc_sigma import max_speed_mps, nhc_sigmas_mm_per_s
from trackfusion.simulation.trolley import TrolleyGeometry, frame_from_contacts, wheel_contacts
from trackfusion.track.design import DesignAlignment
from trackfusion.simulation.irregularity import IrregularitySpec, PsdConfig, synthesize, synthesize_psd
from trackfusion.track.nhc_noise import (equivalent_white_sigma_mps, gyro_noise_velocity_sigma_mps,
                                         informed_band_sigma_mps, nhc_velocity_rms_mps,
                                         nhc_velocity_series_mps, rigid_trolley_transfer)
from trackfusion.track.rails import TrackModel

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_transfer_by_hand():
    # lambda = 2 m, l = 1.2 m: x = pi * 1.2 / 2 = 1.88496; cos x = -0.30902, sin x / x = 0.50455
    # H = pi * (-0.30902 - 0.50455) = -2.5559 (magnitude)
    assert rigid_trolley_transfer(np.pi, 1.2) == pytest.approx(2.5559, rel=1e-4)
    # long waves: H -> Omega^3 l^2 / 12 (the trolley follows them)
    omega = 2 * np.pi / 200.0
    assert rigid_trolley_transfer(omega, 1.2) == pytest.approx(omega**3 * 1.2**2 / 12, rel=1e-3)
    # a wave of exactly one wheelbase: both wheels at the same height and slope, the origin
    # moves with the slope: H = Omega
    assert rigid_trolley_transfer(2 * np.pi / 1.2, 1.2) == pytest.approx(2 * np.pi / 1.2, rel=1e-9)


def test_series_of_a_sinusoid_by_hand():
    ds, a, lam, v, l = 0.001, 1e-3, 2.0, 3.0, 1.2
    s = ds * np.arange(41_200)  # the series drops one wheelbase: 40 m, 20 whole waves remain
    u = nhc_velocity_series_mps(a * np.sin(2 * np.pi * s / lam), ds, v, l)
    assert np.sqrt(np.mean(u**2)) == pytest.approx(v * a * 2.5559 / np.sqrt(2), rel=2e-3)  # 5.42 mm/s


def _rigid_trolley_velocity_v(spec: dict, speed_mps: float, wheelbase_m: float) -> np.ndarray:
    """Lateral and vertical velocity in v (M, 2) of the simulator's trolley origin on a straight track."""
    design = DesignAlignment.from_dict({"horizontal": {"heading_deg": 30.0, "elements": [{"type": "tangent",
                                                                                          "length_m": 60.0}]}})
    field = synthesize(IrregularitySpec.from_dict(spec), 60.0, np.random.default_rng(0))
    track = TrackModel(design, field)
    geometry = TrolleyGeometry(wheelbase_m=wheelbase_m)
    ds = 0.002
    s = np.arange(15.0, 45.0, ds)
    c = wheel_contacts(track, geometry, s)
    origin_n, R_nv = frame_from_contacts(c["front_n"], c["rear_n"], c["other_n"], other_is_left=False)
    d_origin_v = np.einsum("kji,kj->ki", R_nv, np.gradient(origin_n, ds, axis=0))
    return speed_mps * d_origin_v[:, 1:]


@pytest.mark.parametrize("direction,column", [("vertical", 1), ("lateral", 0)])
def test_simulated_trolley_matches_the_transfer(direction, column):
    lam, amp_mm, v, l = 2.5, 0.8, 2.0, 1.2
    spec = {"sinusoids": [{"direction": direction, "rail": "left", "wavelength_m": lam, "amplitude_mm": amp_mm,
                           "start_m": 0.0, "end_m": 60.0, "taper_m": 0.0}], "grid_step_m": 0.002}
    u = _rigid_trolley_velocity_v(spec, v, l)
    expected = v * amp_mm * 1e-3 * rigid_trolley_transfer(2 * np.pi / lam, l) / np.sqrt(2)
    assert np.sqrt(np.mean(u[:, column] ** 2)) == pytest.approx(expected, rel=0.01)
    assert np.sqrt(np.mean(u[:, 1 - column] ** 2)) < 0.02 * expected  # no cross-talk on a straight


def test_spectral_rms_matches_a_synthesized_track():
    cfg, ds, n = PsdConfig(), 0.005, 800_000  # 4 km
    rng = np.random.default_rng(7)
    profile = synthesize_psd("profile", n, ds, cfg, rng)
    cross = synthesize_psd("cross_level", n, ds, cfg, rng)
    u = nhc_velocity_series_mps(profile + cross / 2, ds, 3.0, 1.2)
    rms = nhc_velocity_rms_mps(3.0, 1.2)
    assert np.sqrt(np.mean(u**2)) == pytest.approx(rms["vertical"], rel=0.08)
    assert rms["vertical"] == pytest.approx(1.04e-3, rel=0.01)  # open-track-gnss: 3 m/s, 1.2 m
    assert rms["lateral"] == pytest.approx(0.554e-3, rel=0.01)
    # linear in speed and amplitude
    assert nhc_velocity_rms_mps(1.5, 1.2, scale=2.0)["vertical"] == pytest.approx(rms["vertical"], rel=1e-12)


def test_gyro_noise_by_hand():
    # 0.15 deg/sqrt(h) at 200 Hz: 4.363e-5 rad/sqrt(s) * sqrt(100) = 4.363e-4 rad/s per axis
    g = gyro_noise_velocity_sigma_mps(0.15, 200.0, (0.0, 0.7175, -0.2))
    assert g["vertical"] == pytest.approx(4.363e-4 * 0.7175, rel=1e-3)
    assert g["lateral"] == pytest.approx(4.363e-4 * 0.2, rel=1e-3)


def test_informed_band_sigma_is_the_fixed_point():
    r = informed_band_sigma_mps("vertical", 3.0, 1.2, 0.1, 0.003)
    f = np.geomspace(1e-4, r["crossover_hz"], 2000)
    peak = equivalent_white_sigma_mps(f, "vertical", 3.0, 1.2, 0.1).max()
    assert peak == pytest.approx(r["sigma_mps"], rel=0.01)  # covers the band it leaves to the NHC, no more
    assert r["sigma_mps"] < nhc_velocity_rms_mps(3.0, 1.2)["vertical"]  # long waves barely violate the NHC


def test_settings_per_axis_and_fallback():
    np.testing.assert_allclose(NhcSettings(sigma_mm_per_s=0.7).sigmas_mps(), [7e-4, 7e-4])
    np.testing.assert_allclose(NhcSettings(sigma_vertical_mm_per_s=0.3).sigmas_mps(), [1e-3, 3e-4])


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.stem)
def test_configs_carry_no_sigma_of_the_simulated_track(path):
    """A shipped pipeline carries the library's NHC sigma (a datasheet value), not its
    scenario's derived one (the benchmark of a mismatch, benchmarks/mismatch.py, uses that as the
    truth); the smoother estimates the noise from the residuals."""
    cfg = load_scenario(path.stem)
    imu = sc._imu_spec(cfg.imu)
    derived = nhc_sigmas_mm_per_s(cfg, sc._motion_plan(cfg).chainage_range_m, imu.gyro_arw_deg_per_sqrt_h,
                                  imu.rate_hz)
    nhc = yaml.safe_load(path.read_text())["factors"]["nhc"]
    assert nhc is True
    assert NhcSettings().sigmas_mps() * 1e3 != pytest.approx([derived["lateral"], derived["vertical"]], rel=0.05)
    assert max_speed_mps(cfg) > 0
