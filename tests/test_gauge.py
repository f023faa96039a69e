"""The gauge reading along chainage (track/gauge.py, traces.box_mean): noise reduction against
theory, the Wiener smoother's transfer at its cut-off, the fitted noise against the simulated
sensor's, and the versine noise the gauge leaves in the other rail."""

import numpy as np
import pytest

from trackfusion.errors import TrackGeometryError
from trackfusion.track.gauge import GaugeFit, fit_gauge_spectrum, smooth_gauge, wiener_gain
from trackfusion.track.traces import box_mean, gauge_along_pass

SIGMA = 1e-4      # 0.1 mm reading noise (the simulator's GaugeSpec default)
SPACING = 0.012   # 50 Hz at 0.6 m/s


def _readings(length_m=120.0, spacing=SPACING):
    return np.arange(0.0, length_m, spacing)


def _irw(s, q, rng):
    """An integrated random walk in chainage: second derivative white with density q."""
    d = s[1] - s[0]
    return np.cumsum(np.cumsum(rng.standard_normal(s.size) * np.sqrt(q / d))) * d ** 2


def test_box_mean_reduces_noise_by_sqrt_n():
    rng = np.random.default_rng(1)
    s = _readings()
    noise = SIGMA * rng.standard_normal(s.size)
    q = np.arange(1.0, 119.0, 0.3)                 # windows 0.3 m apart do not overlap
    for width in (0.12, 0.24, 0.6):
        n = round(width / SPACING) + 1             # readings in a closed window
        out = box_mean(s, noise, q, width)
        assert np.std(out) == pytest.approx(SIGMA / np.sqrt(n), rel=0.1), width


def test_wiener_noise_reduction_matches_its_transfer():
    """White noise through the smoother: variance sigma^2 d int H^2 dk = sigma^2 d 2 k_c 3 pi / (8 sqrt 2)."""
    rng = np.random.default_rng(2)
    s = _readings(300.0)
    for cutoff in (0.6, 1.3, 3.0):
        fit = GaugeFit(SIGMA, 1.0, SPACING, cutoff, True)
        out = smooth_gauge(s, 1.435 + SIGMA * rng.standard_normal(s.size), s, fit) - 1.435
        inner = (s > 10) & (s < 290)
        expected = SIGMA * np.sqrt(SPACING * 2 / cutoff * 3 * np.pi / (8 * np.sqrt(2)))
        assert np.std(out[inner]) == pytest.approx(expected, rel=0.1), cutoff


@pytest.mark.parametrize("ratio,gain", [(1.0, 0.5), (2.0, 1 / (1 + 1 / 16)), (0.5, 1 / 17)])
def test_wiener_transfer_at_and_around_cutoff(ratio, gain):
    cutoff = 1.3
    s = _readings(200.0, 0.005)
    lam = ratio * cutoff
    y = 1e-3 * np.sin(2 * np.pi * s / lam)
    out = smooth_gauge(s, y, s, GaugeFit(SIGMA, 1.0, 0.005, cutoff, True))
    inner = (s > 20) & (s < 180)
    X = np.column_stack([np.sin(2 * np.pi * s[inner] / lam), np.cos(2 * np.pi * s[inner] / lam)])
    amp = np.hypot(*np.linalg.lstsq(X, out[inner], rcond=None)[0]) / 1e-3
    assert amp == pytest.approx(gain, rel=0.03, abs=0.005)
    assert wiener_gain(lam, cutoff) == pytest.approx(gain)


def test_fit_recovers_the_sensor_noise_and_the_wiener_cutoff():
    rng = np.random.default_rng(3)
    s = _readings(120.0)
    cutoff_true = 1.3
    q = SIGMA ** 2 * SPACING * (2 * np.pi / cutoff_true) ** 4      # signal = noise density at 1.3 m
    g = 1.435 + _irw(s, q, rng) + SIGMA * rng.standard_normal(s.size)
    fit = fit_gauge_spectrum(s, g)
    assert fit.sigma_m == pytest.approx(SIGMA, rel=0.05)
    assert fit.cutoff_m == pytest.approx(cutoff_true, rel=0.2)
    assert not fit.sigma_from_spec
    # the spec's noise given: only q fitted, same cut-off
    spec = fit_gauge_spectrum(s, g, SIGMA)
    assert spec.sigma_m == SIGMA and spec.cutoff_m == pytest.approx(fit.cutoff_m, rel=0.1)
    with pytest.raises(TrackGeometryError):
        fit_gauge_spectrum(s[:10], g[:10])


def _versine_1m(s, y):
    return y - 0.5 * (np.interp(s - 0.5, s, y) + np.interp(s + 0.5, s, y))


def test_wiener_gauge_leaves_less_versine_error_than_the_box():
    """Gauge = IRW signal + 0.1 mm noise at 50 Hz and 1.2 m/s: the 1 m versine error of the
    smoothed gauge is below the box mean's theoretical sigma sqrt(1.5 d / W), and the gauge
    itself is closer to the truth too (a test that fails if the smoother over- or under-smooths)."""
    rng = np.random.default_rng(4)
    d = 0.024
    s = _readings(150.0, d)
    q = SIGMA ** 2 * 0.012 * (2 * np.pi / 1.3) ** 4
    truth = 1.435 + _irw(s, q, rng)
    g = truth + SIGMA * rng.standard_normal(s.size)
    grid = np.arange(5.0, 145.0, 0.01)
    true_v = _versine_1m(grid, np.interp(grid, s, truth))
    err = {}
    for method in ("wiener", "box"):
        est, info = gauge_along_pass(s, g, grid, method, 0.25)
        assert info["filter"] == method
        err[method] = (np.sqrt(np.mean((_versine_1m(grid, est) - true_v)[60:-60] ** 2)),
                       np.sqrt(np.mean((est - np.interp(grid, s, truth)) ** 2)))
    box_theory = SIGMA * np.sqrt(1.5 * d / 0.25)
    assert err["box"][0] == pytest.approx(box_theory, rel=0.15)
    assert err["wiener"][0] < 0.7 * box_theory
    assert err["wiener"][1] < err["box"][1]
    # too few readings: the box mean, and said so
    _, info = gauge_along_pass(s[:20], g[:20], grid[:5], "wiener", 0.25)
    assert info["filter"] == "box"


def test_long_waves_pass_when_the_short_waves_are_below_the_noise():
    """A 44 m gauge wave and 0.1 mm noise, nothing else: the fit finds no short-wave signal,
    the cut-off stops at MAX_CUTOFF_M and the long wave is kept (an uncapped fit would flatten it)."""
    from trackfusion.track.gauge import MAX_CUTOFF_M
    rng = np.random.default_rng(6)
    s = _readings(500.0, 0.017)
    wave = 1e-3 * np.sin(s / 7.0)
    for sigma in (None, SIGMA):
        est, info = gauge_along_pass(s, 1.435 + wave + SIGMA * rng.standard_normal(s.size), s, "wiener", 0.25, sigma)
        assert info["cutoff_wavelength_m"] == MAX_CUTOFF_M
        assert np.std(est - 1.435 - wave) < 0.2 * SIGMA
