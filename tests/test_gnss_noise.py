"""GNSS white noise from the residuals (fusion/gnss_noise.py): the redundancy against its
analytic value, and on a short open-track survey whose receiver states half (and twice) its
true white sigma (5 % outliers) the estimate, the gate and the result against the honest
receiver's run."""

import json

import gtsam
import numpy as np
import pytest
import yaml
from gtsam.symbol_shorthand import E, X

from surveys import SHORT_OPEN_TRACK, errors_against_truth
from trackfusion import pipeline as P
from trackfusion.fusion import gnss_noise
from trackfusion.fusion.factors import LinearBlocks
from trackfusion.simulation.aiding import GnssSpec
from trackfusion.sensors.fileio import read_csv_table
from trackfusion.simulation.scenarios import simulate_to_dir

SEED = 3
OUTLIERS = "gnss.outlier_fraction=0.05"


def test_redundancy_of_a_mean_with_error_states():
    """N fixes y_i = x + e_i + n_i (n_i ~ s^2, a prior e_i ~ s_e^2): the hat matrix's diagonal
    is 1/N + k (1 - 1/N), k = s_e^2 / (s_e^2 + s^2), so the redundancy is (1 - k)(1 - 1/N)."""
    N, s, s_e = 12, 0.01, 0.006
    gfg = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create(3)
    gfg.add(gtsam.JacobianFactor(X(0), np.hstack([np.eye(3), np.zeros((3, 3))]), np.zeros(3), unit))  # rotation
    J = np.hstack([np.zeros((3, 3)), np.eye(3)])
    for i in range(N):
        gfg.add(gtsam.JacobianFactor(X(0), J / s, E(i), np.eye(3) / s, np.zeros(3), unit))
        gfg.add(gtsam.JacobianFactor(E(i), np.eye(3) / s_e, np.zeros(3), unit))
    tree = gfg.eliminateMultifrontal()
    blocks = LinearBlocks([np.full(N, X(0)), E(0) + np.arange(N)], [np.broadcast_to(J, (N, 3, 6)),
                          np.broadcast_to(np.eye(3), (N, 3, 3))], np.zeros((N, 3)), np.full((N, 3), s))
    red = gnss_noise.redundancy(tree, blocks, np.broadcast_to(np.eye(3) * s**2, (N, 3, 3)), np.arange(N))
    k = s_e**2 / (s_e**2 + s**2)
    np.testing.assert_allclose(red, (1 - k) * (1 - 1 / N), rtol=1e-9)
    # without error states: 1 - 1/N
    plain = LinearBlocks([np.full(N, X(0))], [np.broadcast_to(J, (N, 3, 6))], np.zeros((N, 3)), np.full((N, 3), s))
    gfg2 = gtsam.GaussianFactorGraph()
    gfg2.add(gtsam.JacobianFactor(X(0), np.hstack([np.eye(3), np.zeros((3, 3))]), np.zeros(3), unit))
    for i in range(N):
        gfg2.add(gtsam.JacobianFactor(X(0), J / s, np.zeros(3), unit))
    red2 = gnss_noise.redundancy(gfg2.eliminateMultifrontal(), plain, np.broadcast_to(np.eye(3) * s**2, (N, 3, 3)),
                                 np.arange(3))
    np.testing.assert_allclose(red2, 1 - 1 / N, rtol=1e-9)


def _survey(root, stated_factor):
    d = root / f"stated-{stated_factor}"
    simulate_to_dir("open-track-gnss", d, seed=SEED,
                    overrides=SHORT_OPEN_TRACK + [OUTLIERS, f"gnss.stated_sigma_factor={stated_factor}"])
    return d


def _run(d, name, estimate=True):
    cfg = yaml.safe_load((d / "pipeline.yaml").read_text())
    if not estimate:
        cfg["factors"]["gnss"] = {"estimate_white_noise": False}
    path = d / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    said = []
    res = P.run(P.load_pipeline(path), d / name, progress=said.append)
    rounds = sum("gating round" in s for s in said)
    res.metrics["summary"] = P.format_summary(res)
    return res.metrics, read_csv_table(d / name / "trajectory.csv"), rounds


def _truly_outside(d, gate_chi2):
    """Fixes whose drawn error lies outside the gate against the true noise (white + Gauss-Markov)."""
    truth = json.loads((d / "truth.json").read_text())
    spec = GnssSpec(**{k: v for k, v in truth["config"]["gnss"].items() if k != "lever_arm_b_m"})
    white, gm, _ = spec.sigmas_m()
    err = np.asarray(truth["errors"]["gnss"]["error_n_m"])
    return int(np.sum(np.sum(err**2 / (white**2 + gm**2), axis=1) > gate_chi2)), err.shape[0]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("gnss-noise")
    honest, optimistic, pessimistic = _survey(root, 1.0), _survey(root, 0.5), _survey(root, 2.0)
    return {"honest": (honest, *_run(honest, "out")), "honest_fixed": (honest, *_run(honest, "fixed", False)),
            "optimistic": (optimistic, *_run(optimistic, "out")),
            "optimistic_fixed": (optimistic, *_run(optimistic, "fixed", False)),
            "pessimistic": (pessimistic, *_run(pessimistic, "out")),
            "pessimistic_fixed": (pessimistic, *_run(pessimistic, "fixed", False))}


def test_honest_receiver_keeps_the_one_batch_answer(runs):
    """The honest receiver's white noise is not above its stated one: factor 1 applied, the
    same trajectory to the bit as without the estimate, and the estimate reported."""
    d, m, tab, rounds = runs["honest"]
    _, m0, tab0, rounds0 = runs["honest_fixed"]
    est = m["noise_estimates"]["gnss"]
    assert est["applied_variance_factor"] == {"horizontal": 1.0, "vertical": 1.0}
    assert est["variance_factor"]["horizontal"] < 1.0 + 2 * est["variance_factor_sigma"]["horizontal"]
    assert rounds == rounds0 and m["rejected_gnss"] == m0["rejected_gnss"]
    for c in ("e_m", "n_m", "u_m", "sigma_u_m"):
        np.testing.assert_array_equal(tab[c], tab0[c])
    assert "gnss" not in m0.get("noise_estimates", {})


def test_optimistic_receiver_estimated_and_gated_on_the_estimate(runs):
    d, m, tab, rounds = runs["optimistic"]
    _, m_fixed, _, _ = runs["optimistic_fixed"]
    hd, mh, tab_h, rounds_h = runs["honest"]
    est = m["noise_estimates"]["gnss"]
    # the drawn white sigma: 8 mm horizontal, 15 mm vertical (the scenario's), within 15 %
    drawn = np.array([8.0, 8.0, 15.0])
    ratio = np.asarray(est["estimated_white_sigma_mm"]) / drawn
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    np.testing.assert_allclose(est["stated_white_sigma_mm"][2], np.sqrt(0.25 * 15**2 + 15**2 + 2**2 - 15**2),
                               rtol=1e-6)  # what the receiver said: half its white sigma
    assert est["fixes"] >= 30
    assert f"from the residuals {est['estimated_white_sigma_mm'][0]:.1f}/" in m["summary"]
    # rejections against the fixes truly outside the gate
    outside, n = _truly_outside(d, 21.1)
    assert outside > 0
    assert len(m["rejected_gnss"]) <= 1.2 * outside + 0.01 * n, (len(m["rejected_gnss"]), outside)
    assert len(m_fixed["rejected_gnss"]) > 1.2 * outside + 0.01 * n  # without the estimate: too many
    assert rounds <= rounds_h
    # the result: as good as the honest receiver's run and its sigmas as consistent
    for axis in ("vertical", "lateral"):
        ra, ra_h = m["relative_accuracy"][axis], mh["relative_accuracy"][axis]
        assert ra["mse_at_threshold_mm"] <= 1.2 * ra_h["mse_at_threshold_mm"], axis
    err, _ = errors_against_truth(d, tab)
    err_h, _ = errors_against_truth(hd, tab_h)
    z = np.sqrt(np.mean((err / np.column_stack([tab[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")]))**2, 0))
    z_h = np.sqrt(np.mean((err_h / np.column_stack([tab_h[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")]))**2,
                          0))
    np.testing.assert_allclose(z, z_h, rtol=0.25)


def test_the_same_estimate_with_exact_time_parts(runs):
    """``smoother.part_s``: the residuals and the marginals are the one-batch ones, and so are
    the estimate, the gate and the trajectory (to rounding)."""
    d, m, tab, _ = runs["optimistic"]
    cfg = yaml.safe_load((d / "pipeline.yaml").read_text())
    cfg["smoother"] = {"part_s": 60}
    path = d / "parts.yaml"
    path.write_text(yaml.safe_dump(cfg))
    mp = P.run(P.load_pipeline(path), d / "parts").metrics
    est, est_p = m["noise_estimates"]["gnss"], mp["noise_estimates"]["gnss"]
    for key in ("variance_factor", "applied_variance_factor", "mean_redundancy"):
        for g in ("horizontal", "vertical"):
            assert est_p[key][g] == pytest.approx(est[key][g], rel=1e-6), (key, g)
    assert [r["index"] for r in mp["rejected_gnss"]] == [r["index"] for r in m["rejected_gnss"]]
    tab_p = read_csv_table(d / "parts" / "trajectory.csv")
    np.testing.assert_allclose(tab_p["u_m"], tab["u_m"], atol=1e-8)


def test_pessimistic_receiver_weighted_up_on_the_estimate(runs):
    """A receiver stating twice its true white sigma (the same draws as the honest survey): the
    estimate (a quarter of the stated variance) is applied, the white sigma found within 15 % of
    the drawn one, and the trajectory is the honest receiver's run's, far closer to it than the
    run on the stated noise; its sigmas as consistent."""
    d, m, tab, _ = runs["pessimistic"]
    _, _, tab_fixed, _ = runs["pessimistic_fixed"]
    hd, _, tab_h, _ = runs["honest"]
    est = m["noise_estimates"]["gnss"]
    ratio = np.asarray(est["estimated_white_sigma_mm"]) / np.array([8.0, 8.0, 15.0])
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    for g in ("horizontal", "vertical"):
        assert est["variance_factor"][g] < 0.5  # the last solve's; it applied the one before
        assert est["applied_variance_factor"][g] == pytest.approx(est["variance_factor"][g],
                                                                  rel=gnss_noise.FACTOR_TOLERANCE)
    outside, n = _truly_outside(d, 21.1)
    assert len(m["rejected_gnss"]) <= 1.2 * outside + 0.01 * n, (len(m["rejected_gnss"]), outside)
    off = {name: max(np.max(np.abs(t[c] - tab_h[c])) for c in ("e_m", "n_m", "u_m"))
           for name, t in (("estimated", tab), ("stated", tab_fixed))}
    # measured: 0.08 mm against 1.25 mm
    assert off["estimated"] < 0.2 * off["stated"], off

    def rms_z(directory, table):
        err, _ = errors_against_truth(directory, table)
        return np.sqrt(np.mean((err / np.column_stack([table[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")]))
                               ** 2, 0))
    np.testing.assert_allclose(rms_z(d, tab), rms_z(hd, tab_h), rtol=0.05)


def test_applied_correlated_factor_scales_the_first_error_states_prior(tmp_path, monkeypatch):
    """A variance factor applied to the GNSS correlated part scales the whole Gauss-Markov
    process: its steps and the prior of the first error state (its stationary sigma). One pass of
    the open track (14 min) with the correlated error drawn at 2.5 x the configured 8 / 15 mm:
    the horizontal factor is applied, and the last graph's prior sigma is the configured one
    times the square root of the factor applied, per component; the first graph's the configured."""
    from trackfusion.fusion import smoother
    d = tmp_path / "one-pass"
    simulate_to_dir("open-track-gnss", d, seed=SEED,
                    overrides=["motion.passes=1", "gnss.gm_sigma_h_mm=20", "gnss.gm_sigma_v_mm=40"])
    priors = []
    original = smoother._Builder._gnss_error_prior

    def recording(self, first, values, corr, tau_s):
        priors.append(np.array(corr))
        return original(self, first, values, corr, tau_s)
    monkeypatch.setattr(smoother._Builder, "_gnss_error_prior", recording)
    res = P.run(P.load_pipeline(d / "pipeline.yaml"), d / "out")
    applied = res.metrics["noise_estimates"]["gnss_error"]
    f_h, f_v = applied["horizontal"]["applied_variance_factor"], applied["vertical"]["applied_variance_factor"]
    assert f_h > 2.0
    np.testing.assert_allclose(priors[-1] * 1e3, [8.0 * np.sqrt(f_h)] * 2 + [15.0 * np.sqrt(f_v)], rtol=1e-12)
    np.testing.assert_allclose(priors[0] * 1e3, [8.0, 8.0, 15.0], rtol=1e-12)
