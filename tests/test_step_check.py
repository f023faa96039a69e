"""The step check of a total station's own readings (registration/steps.py): a
reflector moving along with the prism a few centimetres away is found from the step where the
mis-lock starts and the step back where it ends; curvature, braking, a hard start, a clock step
and hand-overs are not flagged."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from trackfusion import geodesy
from trackfusion.pipeline import parse_pipeline
from trackfusion.registration import steps
from trackfusion.registration.stations import InstrumentPrecision, readings_to_n, station_setup
from trackfusion.sensors.mcap_log import read_log
from trackfusion.simulation import faults as inj
from trackfusion.simulation.scenarios import simulate_to_dir

ARCSEC = np.pi / 180.0 / 3600.0


def _polar_cov(p: np.ndarray, sigma_d_m: float = 3e-3, sigma_a_rad: float = 0.5 * ARCSEC) -> np.ndarray:
    """Covariances (N, 3, 3) of readings at ``p`` (N, 3) from a station at the origin."""
    d = np.linalg.norm(p, axis=1)
    u = p / d[:, None]
    uu = np.einsum("ni,nj->nij", u, u)
    return sigma_d_m**2 * uu + (sigma_a_rad * d)[:, None, None] ** 2 * (np.eye(3) - uu)


def _curve_run(seed: int = 0, hard_start: bool = True):
    """A trolley on a 300 m radius curve passing 6 m from a station (origin): at rest 10 s, a
    hard start (acceleration 0.5 m/s^2 from one instant: a step of acceleration), 1.5 m/s, then
    braking to a stop at 0.3 m/s^2 (raised cosine) and 10 s at rest; readings at 10 Hz with the
    polar noise (3 mm, 0.5"). Returns t (N,), pos (N,3), cov (N,3,3), s (N,) path length."""
    rng = np.random.default_rng(seed)
    dt = 0.001
    tt = np.arange(0.0, 200.0, dt)
    a = np.where((tt >= 10.0) & (tt < 13.0), 0.5, 0.0) if hard_start else np.zeros(tt.size)
    brake = (tt >= 150.0) & (tt < 160.0)
    a -= np.where(brake, 0.3 * np.sin(np.pi * (tt - 150.0) / 10.0) ** 2, 0.0)
    v = np.clip(np.cumsum(a) * dt, 0.0, None)
    s_all = np.cumsum(v) * dt - 60.0
    t = np.arange(0.05, 199.0, 0.1)
    s = np.interp(t, tt, s_all)
    R = 300.0
    p = np.column_stack([R * np.sin(s / R), 6.0 + R * (1.0 - np.cos(s / R)), 1.0 + 0.002 * s])
    cov = _polar_cov(p)
    noise = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.standard_normal(p.shape))
    return t, p + noise, cov, s


def test_curvature_braking_and_a_hard_start_are_no_steps():
    t, p, cov, _ = _curve_run()
    prof = steps.step_profile(t, p, cov)
    assert prof["split"].size > 1500
    assert np.sqrt(prof["z2"].max()) < steps.Z_MIN / 1.5       # a margin below the detection
    flagged, found, _ = steps.station_mislocks(t, p, cov)
    assert not flagged.any() and found == []


@pytest.mark.parametrize("offset_m", [0.02, 0.1, 0.5])
def test_a_reflector_moving_along_is_flagged_reading_for_reading(offset_m):
    t, p, cov, _ = _curve_run(seed=1)
    inside = (t >= 70.0) & (t < 80.0)                        # at 15-30 m past the station, moving
    lateral = np.array([0.0, 1.0, 0.0]) * offset_m          # across the line of sight
    flagged, found, _ = steps.station_mislocks(t, p + inside[:, None] * lateral, cov)
    assert np.array_equal(flagged, inside)
    assert len(found) == 1 and found[0]["z"] > steps.Z_MIN
    for step, truth in ((found[0]["step_m"], lateral), (found[0]["return_m"], -lateral)):
        assert abs(step[1] - truth[1]) < 2e-3                  # across the line of sight: 0.5" at 15-30 m
        np.testing.assert_allclose(step, truth, atol=1e-2)     # along it: 3 mm of distance noise


def test_a_mislock_during_a_stop_and_one_across_the_braking_are_flagged():
    t, p, cov, _ = _curve_run(seed=2)
    offset = np.array([0.01, 0.03, 0.0])
    for lo, hi in ((155.0, 168.0), (185.0, 190.0)):         # braking into the stop; at rest
        inside = (t >= lo) & (t < hi)
        flagged, found, _ = steps.station_mislocks(t, p + inside[:, None] * offset, cov)
        assert np.array_equal(flagged, inside), (lo, hi)


def test_a_step_without_return_and_a_gap_are_not_flagged():
    """A station clock stepping by 20 ms (the stamps; a 3 cm step along the track at 1.5 m/s)
    and a tracking gap after which the points are offset: no step back, nothing flagged."""
    t, p, cov, _ = _curve_run(seed=3)
    jumped = t + 0.02 * (t > 100.0)
    assert not steps.station_mislocks(jumped, p, cov)[0].any()
    keep = (t < 60.0) | (t > 66.0)
    shifted = p + ((t > 66.0) & (t < 90.0))[:, None] * np.array([0.0, 0.05, 0.0])
    flagged, found, _ = steps.station_mislocks(t[keep], shifted[keep], cov[keep])
    assert not flagged.any() and found == []


def test_a_fixed_reflector_is_flagged_from_the_odometer_and_nothing_else():
    """A fixed reflector 8 m aside for 10 s while the trolley moves: two steps without a return,
    between which the readings do not travel with the odometer; a clock step (one step) is not."""
    t, p, cov, s = _curve_run(seed=4)
    inside = (t >= 70.0) & (t < 80.0)
    rng = np.random.default_rng(0)
    fixed = p[np.argmax(inside)] + np.array([0.0, 8.0, 0.0])
    q, cov = p.copy(), cov.copy()
    cov[inside] = _polar_cov(fixed[None, :])
    q[inside] = fixed + rng.standard_normal((inside.sum(), 3)) @ np.linalg.cholesky(cov[np.argmax(inside)]).T
    flagged, found, unpaired = steps.station_mislocks(t, q, cov)
    assert not flagged.any() and found == [] and len(unpaired) == 2
    still, events = steps.motionless_mislocks(t, q, unpaired, t, s)
    assert np.array_equal(still, inside) and [e["kind"] for e in events] == ["motionless"]
    jumped = t + 0.02 * (t > 100.0)
    assert not steps.motionless_mislocks(jumped, p, steps.station_mislocks(jumped, p, cov)[2], t, s)[0].any()


# --- a short simulated bridge: two stations and their hand-overs ---------------------------------------

SHORT = ["motion.segments=[{hold_s: 20}, {move_to_m: 250, speed_mps: 1.5, accel_mps2: 0.3}, {hold_s: 10},"
         " {move_to_m: 100, speed_mps: 1.5, accel_mps2: 0.3}, {hold_s: 20}]",
         "total_stations.handover.1.at_chainage_m=180", "total_stations.handover.2.at_chainage_m=150",
         "total_stations.stations.1.pos_n_m=[-276.0, -6.0, 1.8]"]


@pytest.fixture(scope="module")
def bridge(tmp_path_factory):
    """(log, {station: positions function}) of a short simulated bridge survey (no fusion)."""
    d = tmp_path_factory.mktemp("bridge")
    simulate_to_dir("bridge-total-station", d, seed=4, overrides=SHORT)
    pipe = parse_pipeline(yaml.safe_load((d / "pipeline.yaml").read_text()), str(d / "pipeline.yaml"), d)
    cfg, o = pipe.config.sensors.total_stations, pipe.config.origin
    origin = geodesy.Origin(o.lat_deg, o.lon_deg, o.h_m)
    prec = InstrumentPrecision(cfg.angle_sigma_arcsec, cfg.distance_sigma_mm, cfg.distance_ppm)

    def readings(log, sid):
        r = log.total_stations[sid]
        setup, _ = station_setup(sid, cfg.stations[sid], cfg.control_points, origin, prec, cfg.refraction_k)
        pos, cov = readings_to_n(r.horizontal_angle_rad, r.zenith_angle_rad, r.slope_distance_m, setup, origin,
                                 cfg.refraction_k, prec)
        return r.t_s, pos, cov

    return read_log(d / "log.mcap"), readings


def test_clean_bridge_with_hand_overs_has_no_step(bridge):
    log, readings = bridge
    for sid in ("TS01", "TS02"):
        t, pos, cov = readings(log, sid)
        assert np.sqrt(steps.step_profile(t, pos, cov)["z2"].max()) < steps.Z_MIN / 1.5, sid
        assert not steps.station_mislocks(t, pos, cov)[0].any(), sid


@pytest.mark.parametrize("offset_m", [0.02, 0.1])
def test_moving_reflector_on_the_bridge_is_found_to_the_reading(bridge, offset_m):
    log, readings = bridge
    t0 = log.total_stations["TS01"].t_s[0]
    faulty, info = inj.inject_prism_mislock(log, strength=10.0, start_s=t0 + 40.0, offset_m=offset_m, moving=True)
    t, pos, cov = readings(faulty, "TS01")
    flagged, found, _ = steps.station_mislocks(t, pos, cov)
    assert len(found) == 1
    assert t[found[0]["first"]] == info["t_s"][0] and t[found[0]["last"]] == info["t_s"][-1]
    assert flagged.sum() == info["readings"]
