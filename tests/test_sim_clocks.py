"""Simulated sensor clocks never give a time an MCAP log cannot hold (negative, non-increasing),
for every built-in scenario and seeds 0-99, checked without simulating the IMU."""

import numpy as np
import pytest

from trackfusion.simulation import aiding
from trackfusion.sensors.mcap_log import _log_time_ns
from trackfusion.simulation import scenarios as S
from trackfusion.simulation.config import available_scenarios, load_scenario

SEEDS = range(100)


def _station_times(name: str):
    """Per seed and station: (IMU times, station times), drawn as the simulator draws the clocks
    (each station's offset and drift from the scenario's spec) on the scenario's tracking intervals."""
    cfg = load_scenario(name)
    specs = S._aiding_specs(cfg)
    if "total_stations" not in specs:
        return
    spec, _lever = specs["total_stations"]
    motion = S._motion_plan(cfg)
    t = S._epochs(motion, 20.0)
    facing = aiding.facing_intervals(t, motion.evaluate(t)[0], spec.handover)
    for seed in SEEDS:
        rng = S._rngs(seed)["total_stations"]
        for st in spec.stations:
            _tilt, _orient, offset, drift = aiding.draw_station_errors(st, spec, rng, False)
            tracked = aiding.tracking_intervals(facing, st.id, spec, float(t[-1]))
            yield seed, st.id, offset, drift, aiding.station_epochs(tracked, spec.rate_hz, offset, drift)


@pytest.mark.parametrize("name", available_scenarios())
def test_every_sensor_time_is_valid_for_seeds_0_to_99(name):
    cfg = load_scenario(name)
    motion = S._motion_plan(cfg)
    for sensor, (spec, _lever) in S._aiding_specs(cfg).items():  # the aiding sensors' own epochs (no draws)
        if hasattr(spec, "rate_hz") and sensor != "total_stations":
            _log_time_ns(f"/{sensor}", S._epochs(motion, spec.rate_hz))
    offsets = []
    for seed, sid, offset, drift, (t_imu, t_station) in _station_times(name):
        offsets.append(offset)
        assert t_station.size > 0, (seed, sid)
        assert t_station.min() >= 0.0, (seed, sid, offset)
        _log_time_ns(f"/total_station/{sid}", t_station)  # raises on a negative or repeated time
        # the station clock is the IMU clock moved by the offset and drift (to rounding)
        np.testing.assert_allclose(t_station, t_imu + offset + drift * 1e-6 * t_imu, rtol=0, atol=1e-9)
    if offsets:
        assert min(offsets) < -1.0 and max(offsets) > 1.0  # negative offsets (the failing case) are drawn


def test_a_station_clock_at_zero_reads_zero_not_minus_rounding():
    """An offset that puts a reading exactly at the station clock's 0 (the case that read -1e-16 s)."""
    t_imu, t_station = aiding.station_epochs([(0.0, 30.0)], 10.0, -3.7, 0.8)
    assert t_station[0] == 0.0 and np.all(np.diff(t_station) > 0)
    assert t_imu[0] == pytest.approx(3.7 / (1 + 0.8e-6))


def test_bridge_seed_5_simulates_valid_station_times():
    """The seed that failed (``simulate bridge-total-station --seed 5``): the aiding sensors as the
    simulator draws them (everything but the IMU), every stream writable to MCAP."""
    log = S.simulate_aiding("bridge-total-station", seed=5)
    for sid, data in log.total_stations.items():
        _log_time_ns(f"/total_station/{sid}", data.t_s)
        assert data.t_s.min() >= 0.0
    _log_time_ns("/odometer", log.odometer.t_s)
