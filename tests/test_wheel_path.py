"""The wheel-path factor (fusion/wheel_path.py): Jacobians against central differences, the
rear-time pairing from the odometer, and the residual at the simulated truth of a rigid trolley
on irregular rails (exact to micrometres, where the NHC is violated by a millimetre per second)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.surveys import SHORT_OPEN_TRACK
from tests.test_fusion_factors import _pose_diff, _rot, _vec_diff
from trackfusion import geodesy
from trackfusion.fusion import wheel_path as wp
from trackfusion.fusion.preintegration import body_deltas
from trackfusion.fusion.smoother import keyframe_indices
from trackfusion.rotations import R_from_ypr
from trackfusion.sensors.types import ImuData

K = 12
OMEGA = np.array([0.0, 5.3e-5, 4.9e-5])


def _args(rng):
    return dict(R_k=_rot(rng), p_k=rng.normal(0, 2, (K, 3)), R_j=_rot(rng), p_j=rng.normal(0, 2, (K, 3)),
                v_j=rng.normal(0, 3, (K, 3)),
                data=wp.WheelPathData(tau_s=rng.uniform(0, 0.1, K), dR=_rot(rng), dp=rng.normal(0, 0.3, (K, 3)),
                                      gravity_n=np.tile([0.0, 0.0, -9.8], (K, 1)), omega_ie_n=OMEGA,
                                      front_b=np.array([0.6, 0.7, -0.25]), rear_b=np.array([-0.6, 0.7, -0.25]),
                                      R_vb=R_from_ypr(0.02, -0.01, 0.03)))


def test_wheel_path_jacobians():
    a = _args(np.random.default_rng(3))
    r, (Jk, Jj, Jv) = wp.wheel_path_residual(**a)
    assert r.shape == (K, 2)
    f = lambda **kw: wp.wheel_path_residual(**{**a, **kw})[0]  # noqa: E731
    np.testing.assert_allclose(Jk, _pose_diff(lambda R, p: f(R_k=R, p_k=p), a["R_k"], a["p_k"], 2), atol=1e-6)
    np.testing.assert_allclose(Jj, _pose_diff(lambda R, p: f(R_j=R, p_j=p), a["R_j"], a["p_j"], 2), atol=1e-6)
    np.testing.assert_allclose(Jv, _vec_diff(lambda v: f(v_j=v), a["v_j"], 2), atol=1e-6)


def test_rear_times_from_the_odometer():
    """Forward at 2 m/s, stop, back at 1 m/s: the rear wheel reaches the front's point a
    wheelbase of distance later in the forward run, earlier in the backward run, never across
    the stop."""
    t_key = np.arange(0.0, 30.01, 0.1)
    d = np.interp(t_key, [0, 10, 15, 30], [0.0, 20.0, 20.0, 5.0])
    pairs = wp.rear_times(t_key, t_key, d, 1.2)
    d_rear = np.interp(t_key[pairs.j] + pairs.tau_s, t_key, d)
    np.testing.assert_allclose(d_rear, d[pairs.k] + 1.2, atol=1e-9)
    fwd, bwd = t_key[pairs.k] < 10.01, t_key[pairs.k] > 14.99
    assert np.all(fwd | bwd)
    np.testing.assert_allclose(t_key[pairs.j[fwd]] + pairs.tau_s[fwd] - t_key[pairs.k[fwd]], 0.6, atol=1e-9)
    np.testing.assert_allclose(t_key[pairs.j[bwd]] + pairs.tau_s[bwd] - t_key[pairs.k[bwd]], -1.2, atol=1e-9)
    assert fwd.sum() == 95 and bwd.sum() == 139  # up to 1.2 m before the stop; from 1.2 m after it
    assert np.all((pairs.tau_s >= 0) & (pairs.tau_s < 0.1 + 1e-12)) and np.all(pairs.j != pairs.k)


def test_body_deltas_integrate_a_constant_rate_and_force():
    """A constant body rate w: dR = Exp(w tau); a constant specific force f without rotation:
    dv = f tau, dp = f tau^2 / 2; at any fraction of a sample interval."""
    from trackfusion.rotations import so3_exp
    t = np.arange(1, 101) * 0.005
    w, f = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.2, 9.8])
    tau = np.array([0.0, 0.0123, 0.1])
    turning = ImuData(t, np.tile(w, (100, 1)), np.tile(f, (100, 1)))
    dR, _, _ = body_deltas(turning, np.array([10, 10, 20]), tau)
    np.testing.assert_allclose(dR, so3_exp(np.outer(tau, w)), atol=1e-12)
    still = ImuData(t, np.zeros((100, 3)), np.tile(f, (100, 1)))
    _, dv, dp = body_deltas(still, np.array([10, 10, 20]), tau)
    np.testing.assert_allclose(dv, np.outer(tau, f), atol=1e-14)
    np.testing.assert_allclose(dp, 0.5 * np.outer(tau**2, f), atol=1e-15)


def test_body_deltas_of_a_span_do_not_depend_on_the_others():
    """Spans of 0 to 40 samples computed together are, to the bit, each computed alone; a span
    from the last sample (a reading after the log's end) has no sample to integrate: the identity
    and zeros (it used to integrate the last sample once for every step the longest span took)."""
    rng = np.random.default_rng(7)
    n = 200
    t = np.cumsum(rng.uniform(0.004, 0.006, n))
    imu = ImuData(t, rng.normal(0, 0.02, (n, 3)), rng.normal([0, 0, 9.8], 0.3, (n, 3)))
    start = np.r_[rng.integers(0, n - 45, 30), n - 1, n - 2]
    tau = np.r_[rng.uniform(-0.01, 0.2, 30), 0.05, 0.05]
    together = body_deltas(imu, start, tau)
    for i in range(start.size):
        alone = body_deltas(imu, start[i:i + 1], tau[i:i + 1])
        for a, b in zip(together, alone):
            np.testing.assert_array_equal(a[i], b[0])
    np.testing.assert_array_equal(together[0][30], np.eye(3))
    np.testing.assert_array_equal(together[1][30], np.zeros(3))
    assert not np.array_equal(together[1][31], np.zeros(3))  # n - 2: the last sample, once
    np.testing.assert_allclose(together[1][31], body_deltas(imu, np.array([n - 2]), np.array([t[-1] - t[-2]]))[1][0],
                               rtol=0, atol=0)


@pytest.fixture(scope="module")
def truth_residuals():
    """Wheel-path residuals and NHC velocities at the truth of a short ideal open-track survey."""
    from trackfusion.fusion import factors as fx
    from trackfusion.simulation.scenarios import simulate
    sim = simulate("open-track-gnss", seed=1, ideal=True, overrides=SHORT_OPEN_TRACK)
    imu, odo, kin = sim.log.imu, sim.log.odometer, sim.kinematics
    key_idx = keyframe_indices(imu.t_s, 0.1)
    t_key = imu.t_s[key_idx]
    st = kin.state(t_key, sim.motion)
    geo = kin.geometry
    R_vb = R_from_ypr(*geo.mounting_ypr_rad)
    lever_v = np.asarray(geo.lever_arm_imu_v)
    half = 0.5 * geo.wheelbase_m
    front_b, rear_b = (R_vb.T @ (np.array([x, 0.0, 0.0]) - lever_v) for x in (half, -half))
    pairs = wp.rear_times(t_key, odo.t_s, odo.distance_m, geo.wheelbase_m)
    k, j = pairs.k, pairs.j
    dR, _, dp = body_deltas(imu, key_idx[j], pairs.tau_s)
    omega = geodesy.earth_rate_n(sim.origin)
    data = wp.WheelPathData(pairs.tau_s, dR, dp, geodesy.gravity_n(st["pos_n"][j], sim.origin), omega,
                            front_b, rear_b, R_vb)
    r, _ = wp.wheel_path_residual(st["R_nb"][k], st["pos_n"][k], st["R_nb"][j], st["pos_n"][j], st["vel_n"][j], data)
    nhc, _, _ = fx.nhc_residual(st["R_nb"], st["vel_n"], st["omega_nb_b"], R_vb.T @ -lever_v, R_vb)
    moving = np.abs(st["sdot_mps"]) > 0.5
    return r, nhc[moving], pairs


def test_wheel_path_exact_at_the_truth_where_the_nhc_is_not(truth_residuals):
    r, nhc, pairs = truth_residuals
    assert pairs.k.size > 1500  # 240 m out and 140 m back at 0.1 s keyframes, less the ends
    rms_um = np.sqrt(np.mean(r**2, axis=0)) * 1e6
    assert np.all(rms_um < 1.0), rms_um  # lateral, vertical [um]
    nhc_rms = np.sqrt(np.mean(nhc**2, axis=0)) * 1e3  # [mm/s]
    assert np.all(nhc_rms > 0.1), nhc_rms  # the irregularity's NHC violation


@pytest.mark.parametrize("value, field", [
    ({"sigma": 0.01}, "factors.wheel_path.sigma"),
    ({"sigma_mm": 0.0}, "factors.wheel_path.sigma_mm"),
    ({"keyframe_step": 0}, "factors.wheel_path.keyframe_step"),
    ({"enabled": "maybe"}, "factors.wheel_path.enabled"),
])
def test_bad_wheel_path_config_exit_2_names_the_field(tmp_path, capsys, value, field):
    from tests.test_pipeline_config import _case, test_bad_config_exit_2_names_field_and_writes_nothing as check
    check(tmp_path, capsys, _case(["factors", "wheel_path"], value), field)


def test_wheel_path_settings_shorthand_and_defaults():
    from trackfusion.fusion.settings import FactorSettings
    assert not FactorSettings().wheel_path.enabled and FactorSettings().wheel_path.sigma_mm == 0.01
    assert FactorSettings(wheel_path=True).wheel_path.enabled


@pytest.mark.slow
def test_wheel_path_sharpens_the_short_wave_trajectory(tmp_path):
    """A short noisy open-track survey with its irregularities, run with and without the factor:
    the vertical and lateral 5 m relative error (ADEV against the truth) fall by a third or more
    (seed 2: vertical 0.089 -> 0.049 mm; a 3 min survey, its GNSS and alignment weigh more than
    in the 43 min benchmark, where it falls eightfold)."""
    from trackfusion.pipeline import parse_pipeline, run
    from trackfusion.simulation.scenarios import simulate_to_dir
    import yaml
    simulate_to_dir("open-track-gnss", tmp_path, seed=2, overrides=SHORT_OPEN_TRACK)
    data = yaml.safe_load((tmp_path / "pipeline.yaml").read_text())
    data.setdefault("smoother", {})["workers"] = 1
    simulated = data["factors"]["wheel_path"]  # on, on every keyframe (0.2 s)
    out = {}
    for on in (False, True):
        data["factors"]["wheel_path"] = simulated if on else False
        res = run(parse_pipeline(data, str(tmp_path / "pipeline.yaml"), tmp_path), tmp_path / f"out-{on}")
        out[on] = res.metrics
    assert out[True]["factors"]["wheel_path"] > 700 and "wheel_path" not in out[False]["factors"]
    for axis in ("vertical", "lateral"):
        with_, without = (out[on]["relative_accuracy"][axis]["adev_at_threshold_mm"] for on in (True, False))
        assert with_ < 0.67 * without, (axis, with_, without)


def test_held_front_points_give_a_later_chunk_the_whole_runs_pairs(tmp_path):
    """A later chunk's wheel path (fusion/chunks.py): with the keyframes of the minute before its
    start held as front wheel points, its pairs are the whole run's pairs whose rear keyframe is
    in it, with the same residuals and rear Jacobians (any state: here a random one); the pairs
    whose front keyframe is before the start are ``wheel_path_hand_over``'s."""
    from types import SimpleNamespace

    from tests.surveys import short_open_track_problem
    from trackfusion.fusion.chunks import sub_problem
    from trackfusion.fusion.smoother import WHEEL_FRONT_S

    prob = short_open_track_problem(tmp_path, seed=3, ideal=True)
    key_idx = keyframe_indices(prob.imu.t_s, 0.2)
    t_key = prob.imu.t_s[key_idx]
    K = t_key.size
    rng = np.random.default_rng(5)
    state = SimpleNamespace(R=_rot(rng, K), p=rng.normal(0.0, 100.0, (K, 3)), v=rng.normal(0.0, 3.0, (K, 3)))
    omega = geodesy.earth_rate_n(prob.origin)
    keys = np.arange(K, dtype=np.int64)
    pos0 = state.p.copy()
    n, build, n_front, _ = wp.wheel_path_builder(prob, t_key, key_idx, pos0, keys, keys + 10**6, omega)
    assert n_front == 0 and n > 500
    whole = build(state)
    k_whole, j_whole = whole.keys[0], whole.keys[1]
    c = int(np.searchsorted(t_key, 80.0)) // 2 * 2  # on the way out at 3 m/s; even: the same keyframe_step phase
    held = (t_key >= t_key[c] - WHEEL_FRONT_S) & (keys < c)
    front = wp.WheelFront(t_key[held], state.R[held], state.p[held])
    sub = sub_problem(prob, int(key_idx[c]), prob.imu.t_s.size - 1, WHEEL_FRONT_S)
    n2, build2, n2_front, build2_front = wp.wheel_path_builder(sub, t_key[c:], key_idx[c:] - key_idx[c], pos0[c:],
                                                               keys[c:], keys[c:] + 10**6, omega, front)
    later = SimpleNamespace(R=state.R[c:], p=state.p[c:], v=state.v[c:])
    inside, back = build2(later), build2_front(later)
    sel_in, sel_back = (k_whole >= c) & (j_whole >= c), (k_whole < c) & (j_whole >= c)
    assert n2 == sel_in.sum() and n2_front == sel_back.sum() >= 1
    np.testing.assert_array_equal(inside.keys[0], k_whole[sel_in])
    np.testing.assert_array_equal(back.keys[0], j_whole[sel_back])
    np.testing.assert_allclose(inside.residual, whole.residual[sel_in], rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.residual, whole.residual[sel_back], rtol=0, atol=1e-12)
    for J_back, J_whole in zip(back.jacobians, whole.jacobians[1:]):
        np.testing.assert_allclose(J_back, J_whole[sel_back], rtol=0, atol=1e-9)
