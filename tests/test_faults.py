"""Data faults the fusion survives: detection units on synthetic series, the injectors,
and end-to-end runs of injected faults against the clean run (5 % GNSS outliers: absolute RMS
< 1.5x, 5 m relative accuracy < 1.2x), determinism, and runs without a static period."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import yaml

from trackfusion.errors import SensorDataError
from trackfusion.fusion import faults
from trackfusion.fusion.input_checks import _flat_runs_at_limit
from trackfusion.pipeline import format_summary, parse_pipeline, run
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.simulation import faults as inj
from trackfusion.simulation.scenarios import simulate_to_dir

# --- clock jumps ----------------------------------------------------------------------------------


def _track(n=120, period=1.0, speed=3.0, noise=0.01, seed=0):
    """Positions (n,3) [m] of a sensor sampled every ``period`` along a straight at ``speed``."""
    rng = np.random.default_rng(seed)
    t = 100.0 + np.arange(n) * period
    x = np.column_stack([speed * (t - t[0]), 0.5 * (t - t[0]), np.zeros(n)]) + rng.normal(0, noise, (n, 3))
    return t, x


@pytest.mark.parametrize("step", [0.3, -0.3, 2.0, 5.0, 0.004])
def test_clock_jump_while_moving_is_found_and_removed(step):
    t, x = _track()
    jumped = t.copy()
    jumped[60:] += step
    fixed, jumps = faults.correct_clock_jumps(jumped, x, "/gnss", "f", noise=0.01)
    assert len(jumps) == 1 and jumps[0]["index"] == 60 and jumps[0]["step_s"] == pytest.approx(step, abs=1e-9)
    assert np.allclose(fixed, t, atol=1e-9)


def test_outage_is_not_a_jump_and_a_jump_after_an_outage_is():
    t, x = _track()
    keep = np.r_[0:50, 60:120]
    fixed, jumps = faults.correct_clock_jumps(t[keep], x[keep], "/gnss", "f", noise=0.01)
    assert jumps == [] and np.array_equal(fixed, t[keep])
    t2 = t[keep].copy()
    t2[50:] += 0.4
    fixed, jumps = faults.correct_clock_jumps(t2, x[keep], "/gnss", "f", noise=0.01)
    assert [j["index"] for j in jumps] == [50] and np.allclose(fixed, t[keep], atol=1e-9)


def test_odometer_clock_jump_on_a_100_hz_distance():
    t = np.arange(3000) / 100.0
    d = 2.5 * t + 0.1 * np.sin(t)
    tj = t.copy()
    tj[1700:] += 0.5
    fixed, jumps = faults.correct_clock_jumps(tj, d, "/odometer", "f", noise=1e-4)
    assert len(jumps) == 1 and jumps[0]["step_s"] == pytest.approx(0.5, abs=1e-9)
    assert np.allclose(fixed, t, atol=1e-9)


def test_clock_jump_at_rest_sub_period_corrected_else_refused():
    t, x = _track(speed=0.0)
    x[:, 1] = x[:, 0]
    tj = t.copy()
    tj[40:] += 0.25
    fixed, jumps = faults.correct_clock_jumps(tj, x, "/gnss", "f", noise=0.01)
    assert len(jumps) == 1 and np.allclose(fixed, t, atol=1e-9)
    tj = t.copy()
    tj[40:] += 2.25
    with pytest.raises(SensorDataError, match=r"f: /gnss record 40 .*clock jump of \+0.25 s plus an unknown"):
        faults.correct_clock_jumps(tj, x, "/gnss", "f", noise=0.01)


def test_regular_series_has_no_jumps():
    t, x = _track(n=500)
    assert faults.correct_clock_jumps(t, x, "/gnss", "f", noise=0.01)[1] == []


# --- GNSS episodes, odometer slips, the metrics section ---------------------------------------------

def test_gnss_outages_and_degraded_episodes():
    t = np.r_[np.arange(10.0, 50.0), np.arange(80.0, 100.0)]
    out = faults.gnss_outages(t, (0.0, 120.0))
    assert [(o["start_s"], o["end_s"]) for o in out] == [(0.0, 10.0), (49.0, 80.0), (99.0, 120.0)]
    q = np.full(t.size, 4)
    q[5:9] = 5
    q[20] = 1
    ep = faults.gnss_degraded_episodes(t, q)
    assert [(e["start_s"], e["fixes"], e["quality"]) for e in ep] == [(15.0, 4, [5]), (30.0, 1, [1])]


def test_odometer_slip_from_residuals_of_a_straight_run():
    K = 200
    t = np.arange(K) * 0.1
    R = np.repeat(np.eye(3)[None], K, axis=0)
    pos = np.column_stack([2.0 * t, np.zeros(K), np.zeros(K)])
    delta = np.diff(pos[:, 0]) + np.random.default_rng(1).normal(0, 2e-5, K - 1)
    delta[100:105] += 0.004          # 2 cm slip over 0.5 s
    slips = faults.odometer_slips(t, R, pos, np.zeros(K), delta, np.array([-0.6, 0.7, -0.25]),
                                  np.array([1.0, 0, 0]), 5e-5)
    assert len(slips) == 1
    assert slips[0]["start_s"] == pytest.approx(10.0) and slips[0]["end_s"] == pytest.approx(10.5)
    assert slips[0]["extra_m"] == pytest.approx(0.02, abs=2e-4)


def _straight_run(K=1200, speed_mps=1.5, dt_s=0.2):
    t = np.arange(K) * dt_s
    R = np.repeat(np.eye(3)[None], K, axis=0)
    pos = np.column_stack([speed_mps * t, np.zeros(K), np.zeros(K)])
    return t, R, pos, np.diff(pos[:, 0])


def test_a_scale_left_in_the_residuals_is_not_a_slip_but_a_step_still_is():
    # a 1 % scale error the scale state did not take up, drifting by 0.3 % over the run:
    # 3 mm per 0.3 m increment (60 sigma), yet no slip; a 1 cm step over 0.4 s on top is found
    t, R, pos, true_inc = _straight_run()
    drift = 0.01 + 0.003 * t[:-1] / t[-1]
    delta = true_inc * (1.0 + drift) + np.random.default_rng(2).normal(0, 2e-5, true_inc.size)
    args = (np.array([-0.6, 0.7, -0.25]), np.array([1.0, 0, 0]), 5e-5)
    assert faults.odometer_slips(t, R, pos, np.zeros(t.size), delta, *args) == []
    found = faults.residual_scale(t[:-1], -(delta - true_inc), delta)   # residual = model - measured
    assert np.max(np.abs(found + drift / (1 + drift))) < 1e-4     # of a 3e-3 spread; noise 7e-5 a sample
    delta[600:602] += 0.005
    (slip,) = faults.odometer_slips(t, R, pos, np.zeros(t.size), delta, *args)
    assert slip["start_s"] == pytest.approx(t[600]) and slip["end_s"] == pytest.approx(t[602])
    assert slip["extra_m"] == pytest.approx(0.01, abs=2e-4)


def test_residual_scale_at_rest_takes_the_nearest_moving_value():
    t = np.arange(10.0)
    delta = np.r_[np.zeros(3), np.full(7, 0.3)]
    r = -0.002 * delta
    np.testing.assert_allclose(faults.residual_scale(t, r, delta, window_s=3.0), -0.002)
    assert not faults.residual_scale(t, r, np.zeros(10)).any()


def test_summary_keeps_detected_faults_only():
    s = faults.summarise_faults({"gnss_outliers": [{"t_s": 1.0}], "gnss_outages": [], "truncated_log": None,
                                 "clock_jumps": [{"step_s": 0.2}]}, gnss_fixes=20)
    assert s == {"gnss_outliers": {"count": 1, "events": [{"t_s": 1.0}], "fraction": 0.05},
                 "clock_jumps": {"count": 1, "events": [{"step_s": 0.2}]}}


def test_saturation_needs_three_equal_samples_at_the_limit():
    x = np.array([0.0, 98.0, 98.0, 1.0, 98.0, 98.0, 98.0, 2.0])
    assert _flat_runs_at_limit(x, 98.0) == (4, 3)
    assert _flat_runs_at_limit(x[:4], 98.0) is None
    assert _flat_runs_at_limit(np.array([50.0] * 10), 98.0) is None   # flat but far from the limit


# --- end to end -----------------------------------------------------------------------------------

SHORT = ["motion.passes=1",
         "motion.segments=[{hold_s: 20}, {move_to_m: 320, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 15}]"]


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for d in arrays:
        if d is not None:
            for v in vars(d).values():
                if isinstance(v, np.ndarray):
                    h.update(np.ascontiguousarray(v).tobytes() if v.dtype != object else repr(v.tolist()).encode())
    return h.hexdigest()


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    d = tmp_path_factory.mktemp("faults")
    simulate_to_dir("open-track-gnss", d, seed=2, overrides=SHORT)
    log = read_log(d / "log.mcap")
    return d, log, _run(d, d / "log.mcap", d / "out-clean")


def _run(sim, log_path, out):
    data = yaml.safe_load((sim / "pipeline.yaml").read_text())
    data["inputs"]["log"] = str(log_path)
    return run(parse_pipeline(data, str(sim / "pipeline.yaml"), sim), out)


def _faulty(clean, name, *steps):
    d, log, _ = clean
    for fn, kw in steps:
        log, _ = fn(log, **kw)
    write_log(d / f"{name}.mcap", log)
    return _run(d, d / f"{name}.mcap", d / f"out-{name}")


def _abs_rms_3d(m):
    return float(np.sqrt(sum(m["absolute_error"][c]["rms_mm"] ** 2 for c in ("along", "lateral", "vertical"))))


def test_injectors_never_modify_their_input(clean):
    _, log, _ = clean
    sensors = (log.imu, log.odometer, log.gnss)
    before = _digest(sensors)
    for name, injector in inj.INJECTORS.items():
        new, info = injector.inject(log, strength=injector.strengths[-1])
        assert new is not log and info
        json.dumps(info, allow_nan=False)
    assert _digest(sensors) == before


def test_clean_run_reports_no_faults(clean):
    assert clean[2].metrics["faults"] == {}


@pytest.mark.slow
def test_identical_input_gives_identical_output(clean, tmp_path):
    """Bit for bit: trajectory.csv, trajectory.json and fused.mcap; metrics.json apart from the
    wall-clock fields (run_time_s, timings_s), which are the only difference."""
    d, _, first = clean
    again = _run(d, d / "log.mcap", tmp_path / "again")
    for name in ("trajectory.csv", "trajectory.json", "fused.mcap"):
        assert (first.out_dir / name).read_bytes() == (again.out_dir / name).read_bytes(), name
    m1, m2 = (json.loads((r.out_dir / "metrics.json").read_text()) for r in (first, again))
    for m in (m1, m2):
        del m["run_time_s"], m["timings_s"]
    assert json.dumps(m1) == json.dumps(m2)


@pytest.mark.slow
def test_five_percent_gnss_outliers_meet_the_target(clean):
    _, log, base = clean
    res = _faulty(clean, "outliers", (inj.inject_gnss_outliers, {"strength": 0.05, "seed": 7}))
    _, info = inj.inject_gnss_outliers(log, strength=0.05, seed=7)
    m, c = res.metrics, base.metrics
    found = {round(e["t_s"], 6) for e in m["faults"]["gnss_outliers"]["events"]}
    assert {round(t, 6) for t in info["t_s"]} <= found and len(found) <= len(info["t_s"]) + 2
    assert _abs_rms_3d(m) / _abs_rms_3d(c) < 1.5
    for comp in ("vertical", "lateral"):
        for k in ("mse_at_threshold_mm", "adev_at_threshold_mm"):
            assert m["relative_accuracy"][comp][k] / c["relative_accuracy"][comp][k] < 1.2


@pytest.mark.slow
def test_several_faults_in_one_log_are_each_detected(clean):
    _, log, base = clean
    t0 = inj.motion_start_s(log)
    res = _faulty(clean, "several",
                  (inj.inject_gnss_outage, {"strength": 20.0, "start_s": t0 + 10}),
                  (inj.inject_odometer_slip, {"strength": 0.02, "start_s": t0 + 35}),
                  (inj.inject_clock_jump, {"strength": 0.3, "topic": "/gnss", "at_s": t0 + 50.5}),
                  (inj.inject_clock_jump, {"strength": 0.05, "topic": "/odometer", "at_s": t0 + 65}),
                  (inj.inject_gnss_float, {"strength": 0.2, "start_s": t0 + 75, "duration_s": 20}),
                  (inj.inject_odometer_gross_errors, {"strength": 0.03, "count": 5}))
    f = res.metrics["faults"]
    assert set(f) == {"gnss_outages", "odometer_slips", "clock_jumps", "gnss_float", "odometer_gross_errors",
                      "gnss_outliers"} - ({"gnss_outliers"} - set(f))
    (outage,) = [o for o in f["gnss_outages"]["events"] if o["duration_s"] > 5]
    assert outage["start_s"] < t0 + 10 < t0 + 30 < outage["end_s"] + 1
    (slip,) = f["odometer_slips"]["events"]
    assert slip["start_s"] == pytest.approx(t0 + 35, abs=0.2) and slip["extra_m"] == pytest.approx(0.02, abs=2e-3)
    jumps = {j["topic"]: j for j in f["clock_jumps"]["events"]}
    assert jumps["/gnss"]["step_s"] == pytest.approx(0.3, abs=1e-6)
    assert jumps["/odometer"]["step_s"] == pytest.approx(0.05, abs=1e-6)
    (flt,) = f["gnss_float"]["events"]
    assert flt["quality"] == [5] and flt["fixes"] == 20
    assert f["odometer_gross_errors"]["count"] == 5
    assert _abs_rms_3d(res.metrics) / _abs_rms_3d(base.metrics) < 1.5


@pytest.mark.slow
@pytest.mark.parametrize("ends, epoch", [(("start",), "end"), (("start", "end"), "moving")])
def test_run_without_a_static_start_aligns_elsewhere_and_says_so(clean, ends, epoch):
    _, _, base = clean
    res = _faulty(clean, "nostatic-" + "-".join(ends), (inj.drop_static_start, {"ends": ends}))
    m = res.metrics
    miss = m["faults"]["missing_static_period"]
    assert miss["at"] == list(ends) and miss["alignment_epoch"] == epoch and m["alignment"]["epoch"] == epoch
    assert f"no static period at the {' and '.join(ends)}: " in format_summary(res)
    assert _abs_rms_3d(m) / _abs_rms_3d(base.metrics) < 1.5
    assert m["relative_accuracy"]["vertical"]["mse_at_threshold_mm"] < 1.2 * \
        base.metrics["relative_accuracy"]["vertical"]["mse_at_threshold_mm"]
