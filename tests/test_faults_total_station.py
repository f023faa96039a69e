"""Total-station faults: mis-locks and gaps listed in metrics.json ``faults``, station
clock jumps found and corrected (or refused). Unit tests on synthetic readings, and one short
bridge survey with a mis-lock and a gap of TS01 and a clock jump of TS02 in the same log."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from trackfusion.errors import RegistrationError, SensorDataError
from trackfusion.fusion.faults import correct_clock_jumps, prism_gaps, prism_mislocks, summary_lines
from trackfusion.pipeline import format_summary, parse_pipeline, run
from trackfusion.registration.clock_jumps import correct_station_clock_jumps
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.simulation import faults as inj
from trackfusion.simulation.scenarios import simulate_to_dir


# --- synthetic readings ------------------------------------------------------------------------------

def _straight_run(speed_mps=1.5, rate_hz=10.0, duration_s=120.0, sigma_m=3e-3, seed=0):
    """A trolley accelerating to ``speed_mps`` along a line, its odometer (100 Hz) and a station
    reading the prism at ``rate_hz`` with white noise ``sigma_m`` per axis."""
    rng = np.random.default_rng(seed)
    t_odo = np.arange(0.0, duration_s, 0.01)
    v = speed_mps * np.clip((t_odo - 10.0) / 5.0, 0.0, 1.0)          # at rest 10 s, then 5 s to full speed
    d = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * 0.01)]
    t = np.arange(0.0, duration_s - 1.0, 1.0 / rate_hz)
    s = np.interp(t, t_odo, d)
    pos = np.column_stack([s * 0.8, s * 0.6, 0.01 * s]) + rng.normal(0.0, sigma_m, (t.size, 3))
    cov = np.tile(np.eye(3) * sigma_m**2, (t.size, 1, 1))
    return t, pos, cov, t_odo, d


@pytest.mark.parametrize("step_s", [0.02, -0.05, 0.3])
def test_station_clock_jump_while_moving_is_found_and_removed(step_s):
    t, pos, cov, t_odo, d = _straight_run()
    offset = 2.5
    t_station = t + offset
    t_station[t > 60.0] += step_s
    fixed, jumps = correct_station_clock_jumps("TS09", t_station, offset, pos, cov, t_odo, d)
    assert len(jumps) == 1
    j = jumps[0]
    assert j["topic"] == "/total_station/TS09" and j["index"] == int(np.argmax(t > 60.0))
    assert abs(j["step_s"] - step_s) < 1e-3
    assert np.max(np.abs(fixed - offset - t)) < 1e-3


def test_clean_readings_and_an_odometer_slip_are_no_clock_jump():
    t, pos, cov, t_odo, d = _straight_run()
    assert correct_station_clock_jumps("TS09", t + 1.0, 1.0, pos, cov, t_odo, d)[1] == []
    slipped = d + 0.03 * (t_odo > 60.0)                    # 30 mm of slip at constant speed: the odometer's step
    fixed, jumps = correct_station_clock_jumps("TS09", t + 1.0, 1.0, pos, cov, t_odo, slipped)
    assert jumps == [] and np.array_equal(fixed, t + 1.0)


def test_a_clock_jump_the_motion_cannot_pin_is_refused():
    t, pos, cov, t_odo, d = _straight_run(speed_mps=0.15, sigma_m=4e-3)   # creeping: 4 mm is 27 ms
    t_station = t + 0.0
    t_station[t > 60.0] += 0.5
    with pytest.raises(RegistrationError, match=r"/total_station/TS09: the station's clock jumps by about \+[45]\d\d ms"):
        correct_station_clock_jumps("TS09", t_station, 0.0, pos, cov, t_odo, d)


def test_a_clock_jump_hidden_in_a_tracking_gap_is_refused_a_clean_gap_passes():
    """No reading sees a step inside a gap: a clock jump and an odometer slip are the same step."""
    t, pos, cov, t_odo, d = _straight_run()
    keep = (t < 60.0) | (t > 66.0)                          # the station lost the prism for 6 s
    t, pos, cov = t[keep], pos[keep], cov[keep]
    fixed, jumps = correct_station_clock_jumps("TS09", t + 1.0, 1.0, pos, cov, t_odo, d)
    assert jumps == [] and np.array_equal(fixed, t + 1.0)
    t_station = t + 1.0 + 0.05 * (t > 63.0)
    with pytest.raises(RegistrationError, match=r"/total_station/TS09: after its tracking gap 59\.9-66\.\d s "
                       r"\(IMU clock\) the readings lie 7\d mm along the track .* \(\+[45]\d ms .*cannot tell which"):
        correct_station_clock_jumps("TS09", t_station, 1.0, pos, cov, t_odo, d)


def test_gaps_are_losses_of_lock_not_hand_overs():
    ta = np.r_[np.arange(0.0, 50.0, 0.1), np.arange(60.0, 100.0, 0.1), np.arange(300.0, 400.0, 0.1)]
    tb = np.arange(104.0, 296.0, 0.1)                       # TS02 tracks while the prism faces it
    t = np.r_[ta, tb]
    station = np.r_[np.zeros(ta.size, int), np.ones(tb.size, int)]
    order = np.argsort(t)
    gaps = prism_gaps(t[order], station[order], ["TS01", "TS02"])
    assert len(gaps) == 1
    g = gaps[0]
    assert g["station"] == "TS01" and g["start_s"] == pytest.approx(49.9) and g["end_s"] == pytest.approx(60.0)
    assert g["readings_missing"] == 100


def test_mislock_episodes_from_rejected_runs():
    t = np.arange(0.0, 20.0, 0.1)
    station = np.zeros(t.size, int)
    flag = (t > 5.05) & (t < 8.05)
    ev = prism_mislocks(t, station, ["TS01"], flag)
    assert ev == [{"station": "TS01", "start_s": pytest.approx(5.1), "end_s": pytest.approx(8.0), "readings": 30,
                   "detected_by": "gate"}]
    both = prism_mislocks(t, station, ["TS01"], flag, by_step_check=flag & (t < 7.05))
    assert both[0]["detected_by"] == "step_check+gate"
    lines = summary_lines({"prism_mislocks": {"count": 1, "events": ev}})
    assert lines == ["  TS01 mis-locked 5.1-8.0 s (30 readings rejected, gate)"]


def test_inclinometer_clock_jump_sub_period_corrected_else_refused():
    """The inclinometer's data say nothing about time (pipeline: zeros as data): a sub-period
    step is corrected, a step with lost samples is refused."""
    t = np.arange(0.0, 60.0, 0.02)
    jumped = t.copy()
    jumped[1500:] += 0.007
    fixed, jumps = correct_clock_jumps(jumped, np.zeros(t.size), "/inclinometer", "log.mcap", noise=1.0)
    assert [j["index"] for j in jumps] == [1500] and abs(jumps[0]["step_s"] - 0.007) < 1e-9
    np.testing.assert_allclose(fixed, t, atol=1e-9)
    jumped[1500:] += 0.02                                   # 27 ms: one period more, and a phase step
    with pytest.raises(SensorDataError, match=r"log.mcap: /inclinometer record 1500 .* the data cannot tell"):
        correct_clock_jumps(jumped, np.zeros(t.size), "/inclinometer", "log.mcap", noise=1.0)


# --- end to end -----------------------------------------------------------------------------------------

SHORT = ["motion.segments=[{hold_s: 20}, {move_to_m: 250, speed_mps: 1.5, accel_mps2: 0.3}, {hold_s: 10},"
         " {move_to_m: 100, speed_mps: 1.5, accel_mps2: 0.3}, {hold_s: 20}]",
         "total_stations.handover.1.at_chainage_m=180", "total_stations.handover.2.at_chainage_m=150",
         "total_stations.stations.1.pos_n_m=[-276.0, -6.0, 1.8]"]
MISLOCK = {"start_after_s": 40.0, "duration_s": 5.0}
GAP = {"start_after_s": 70.0, "duration_s": 10.0}
JUMP = {"after_s": 20.0, "step_s": 0.04}
MOVING = {"start_after_s": 60.0, "duration_s": 8.0, "offset_m": 0.03}   # a reflector 3 cm beside the prism


def _faulty_run(d):
    """The short bridge survey with TS01 mis-locked, TS01 losing the prism and TS02's clock
    jumping, run; returns (result, truth of the stations, the three injections' info)."""
    simulate_to_dir("bridge-total-station", d, seed=4, overrides=SHORT)
    log = read_log(d / "log.mcap")
    t1, t2 = log.total_stations["TS01"].t_s[0], log.total_stations["TS02"].t_s[0]
    log, mis = inj.inject_prism_mislock(log, strength=MISLOCK["duration_s"], start_s=t1 + MISLOCK["start_after_s"])
    log, gap = inj.inject_prism_gap(log, strength=GAP["duration_s"], start_s=t1 + GAP["start_after_s"])
    log, jump = inj.inject_clock_jump(log, strength=JUMP["step_s"], topic="/total_station/TS02",
                                      at_s=t2 + JUMP["after_s"])
    log, moving = inj.inject_prism_mislock(log, strength=MOVING["duration_s"], station="TS02", moving=True,
                                           start_s=t2 + JUMP["step_s"] + MOVING["start_after_s"],
                                           offset_m=MOVING["offset_m"])
    write_log(d / "faulty.mcap", log)
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data["inputs"]["log"] = str(d / "faulty.mcap")
    result = run(parse_pipeline(data, str(d / "pipeline.yaml"), d), d / "out")
    truth = json.loads((d / "truth.json").read_text())["total_stations"]
    return result, truth, mis, gap, jump, moving


def _imu(truth, sid, t_station):
    return (np.asarray(t_station) - truth[sid]["clock_offset_s"]) / (1.0 + 1e-6 * truth[sid]["clock_drift_ppm"])


def _check_mislocks(result, truth, mis, moving):
    """The fixed reflector (TS01) and the one moving with the prism (TS02, after its clock jump)
    found by the step check before the fusion, to a reading."""
    ev = result.metrics["faults"]["prism_mislocks"]["events"]
    assert [e["station"] for e in ev] == ["TS01", "TS02"]
    for e, injected in zip(ev, (mis, moving)):
        t_true = _imu(truth, e["station"], np.array(injected["t_s"]) - (JUMP["step_s"] if e["station"] == "TS02" else 0))
        assert abs(e["start_s"] - t_true[0]) <= 0.05 and abs(e["end_s"] - t_true[-1]) <= 0.05
        assert e["readings"] == injected["readings"] and e["detected_by"] == "step_check"


def _check_gap(result, truth, gap):
    ev = result.metrics["faults"]["prism_gaps"]["events"]
    assert len(ev) == 1 and ev[0]["station"] == "TS01"       # the hand-overs are no gaps
    t0, t1 = _imu(truth, "TS01", [gap["start_s"], gap["end_s"]])
    assert abs(ev[0]["start_s"] - t0) <= 0.2 and abs(ev[0]["end_s"] - t1) <= 0.2
    assert abs(ev[0]["readings_missing"] - gap["readings_removed"]) <= 2


def _check_clock_jump(result, truth, jump):
    events = result.metrics["faults"]["clock_jumps"]["events"]
    assert [e["topic"] for e in events] == ["/total_station/TS02"]
    offset = result.metrics["time_sync"]["TS02"]["offset_s"]
    true_offset = truth["TS02"]["clock_offset_s"]
    assert abs(offset - true_offset) < 2e-3                                        # before the jump
    assert abs(offset + events[0]["step_s"] - (true_offset + jump["step_s"])) < 2e-3   # after it
    assert abs(events[0]["t_s"] - _imu(truth, "TS02", jump["at_s"])) < 0.2


def _check_summary_and_report(result):
    text = format_summary(result)
    assert "prism_mislocks 2" in text and "prism_gaps 1" in text and "TS01 mis-locked" in text
    assert "TS01 lost the prism" in text and "/total_station/TS02 clock jump of +4" in text
    html = (result.out_dir / "report.html").read_text()
    assert "<h3>prism_mislocks (2)</h3>" in html and "<h3>prism_gaps (1)</h3>" in html


@pytest.mark.slow
def test_short_bridge_with_a_mislock_a_gap_and_a_station_clock_jump(tmp_path):
    """One run (one test, so that two xdist workers do not each run it): the mis-locks and the
    gap in metrics.json faults with their intervals to about a reading, the clock jump corrected
    to 2 ms, all three in the summary and the report."""
    result, truth, mis, gap, jump, moving = _faulty_run(tmp_path)
    _check_mislocks(result, truth, mis, moving)
    _check_gap(result, truth, gap)
    _check_clock_jump(result, truth, jump)
    _check_summary_and_report(result)
