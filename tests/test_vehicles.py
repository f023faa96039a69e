"""Vehicles and the sensors a run fuses: ``vehicle:`` (and the older ``trolley:``), the factors each
kind supports, switched-on factors without their topic, topics used without their ``sensors:``
section, unused topics listed (trackfusion/vehicles.py, trackfusion/sensor_use.py)."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest
import yaml

from trackfusion import pipeline as P
from trackfusion.cli import main
from trackfusion.errors import ConfigError
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.simulation.scenarios import simulate_to_dir

from surveys import SHORT_OPEN_TRACK

ROAD = {"kind": "road-vehicle", "lever_arm_imu_v_m": [1.2, 0.1, 0.5]}
RAIL = {"kind": "rail-vehicle", "axle_distance_m": 2.5, "lever_arm_imu_v_m": [0.0, -0.7175, 0.9]}


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A short open-track survey (IMU, odometer, GNSS) and its pipeline mapping; a copy of its
    log without /odometer and one without /gnss."""
    d = tmp_path_factory.mktemp("vehicles")
    simulate_to_dir("open-track-gnss", d, seed=2, overrides=SHORT_OPEN_TRACK)
    log = read_log(d / "log.mcap")
    write_log(d / "no-odometer.mcap", replace(log, odometer=None, source=None))
    write_log(d / "no-gnss.mcap", replace(log, gnss=None, source=None))
    return d, yaml.safe_load((d / "pipeline.yaml").read_text())


def _problem(d, data):
    pl = P.parse_pipeline(data, str(d / "p.yaml"), d)
    log, _ = P._read(pl)
    return P.build_problem(pl, log, lambda _m: None)


def _edit(data, *pairs):
    out = copy.deepcopy(data)
    for path, value in pairs:
        node = out
        for k in path[:-1]:
            node = node.setdefault(k, {})
        if value is None:
            node.pop(path[-1], None)
        else:
            node[path[-1]] = value
    return out


def test_trolley_section_reads_as_a_trolley_vehicle(survey):
    d, data = survey
    old = _edit(data, (["vehicle"], None))
    old["trolley"] = {k: v for k, v in data["vehicle"].items() if k != "kind"}
    a = P.parse_pipeline(old, "old.yaml", d).config
    b = P.parse_pipeline(data, "new.yaml", d).config
    assert a == b and a.vehicle.kind == "trolley"
    with pytest.raises(ConfigError, match="not both"):
        P.parse_pipeline({**data, "trolley": old["trolley"]}, "both.yaml", d)
    # errors name the section as written
    old["trolley"]["wheelbase_m"] = -1
    with pytest.raises(ConfigError, match=r"old.yaml: trolley.wheelbase_m: "):
        P.parse_pipeline(old, "old.yaml", d)
    with pytest.raises(ConfigError, match=r"new.yaml: vehicle.axle_distance_m: Field required"):
        P.parse_pipeline(_edit(data, (["vehicle"], {"kind": "rail-vehicle", "lever_arm_imu_v_m": [0, 0, 0]})),
                         "new.yaml", d)


@pytest.mark.parametrize("vehicle, edits, key", [
    (ROAD, [(["factors", "wheel_path"], True)], "factors.wheel_path: not for vehicle.kind road-vehicle"),
    (RAIL, [(["factors", "wheel_path"], {"enabled": True})], "factors.wheel_path: not for vehicle.kind rail-vehicle"),
    (ROAD, [(["factors", "wheel_path"], False), (["geometry"], {"enabled": True})],
     "geometry.enabled: not for vehicle.kind road-vehicle"),
])
def test_factor_the_kind_cannot_use_is_refused(survey, vehicle, edits, key):
    d, data = survey
    with pytest.raises(ConfigError, match=key):
        P.parse_pipeline(_edit(data, (["vehicle"], vehicle), *edits), "p.yaml", d)


def test_kinds_geometry_and_nhc_points(survey):
    d, data = survey
    road = P.parse_pipeline(_edit(data, (["vehicle"], ROAD), (["factors", "wheel_path"], False)), "p.yaml", d)
    assert road.config.geometry.enabled is False  # off unless written, for a road vehicle
    problem, _ = _problem(d, road.config.model_dump(mode="json") | {"inputs": data["inputs"]})
    tf = problem.trolley
    assert tf.kind == "road-vehicle"
    # NHC at v's origin (the rear axle centre), the speed measured there too: IMU -> origin in b
    np.testing.assert_allclose(tf.nhc_lever_arm_b, -np.array(ROAD["lever_arm_imu_v_m"]))
    np.testing.assert_allclose(tf.wheel_lever_arm_b, tf.nhc_lever_arm_b)
    wheel = _edit(data, (["vehicle"], {**ROAD, "odometer_lever_arm_v_m": [0.0, 0.8, 0.0]}),
                  (["factors", "wheel_path"], False))
    tf = _problem(d, wheel)[0].trolley
    np.testing.assert_allclose(tf.wheel_lever_arm_b, np.array([0.0, 0.8, 0.0]) - ROAD["lever_arm_imu_v_m"])
    rail = _problem(d, _edit(data, (["vehicle"], RAIL), (["factors", "wheel_path"], False)))[0].trolley
    assert rail.kind == "rail-vehicle" and rail.wheelbase_m == 2.5  # odometer on the rear axle, 1.25 m back
    np.testing.assert_allclose(rail.wheel_lever_arm_b, np.array([-1.25, 0.0, 0.0]) - RAIL["lever_arm_imu_v_m"])


@pytest.mark.parametrize("log, edits, needles", [
    ("no-odometer.mcap", [], ["factors.odometer: on", "/odometer"]),
    ("no-odometer.mcap", [(["factors", "wheel_path"], False), (["factors", "odometer"], None)],
     ["factors.odometer: on", "/odometer"]),  # its sensors section written: it is meant to be there
    ("no-gnss.mcap", [], ["factors.gnss: on", "/gnss"]),
    ("log.mcap", [(["factors", "odometer"], False)], ["factors.wheel_path", "factors.odometer is off"]),
])
def test_switched_on_factor_without_its_topic_exits_2(survey, tmp_path, capsys, log, edits, needles):
    d, data = survey
    p = _edit(data, (["inputs"], {"log": str(d / log)}), *edits)
    cfg = tmp_path / "p.yaml"
    cfg.write_text(yaml.safe_dump(p))
    assert main(["run", str(cfg), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(err)
    for n in needles:
        assert n in err[-1], (n, err[-1])
    assert not (tmp_path / "out").exists()


def test_default_factor_without_topic_is_not_used(survey):
    """Left at its default (not written, no sensors section), a factor whose topic is absent is
    simply not used."""
    d, data = survey
    p = _edit(data, (["inputs", "log"], "no-odometer.mcap"), (["factors", "odometer"], None),
              (["factors", "wheel_path"], False), (["sensors", "odometer"], None))
    problem, info = _problem(d, p)
    assert problem.odometer is None and info["sensors_unused"] == []


def test_topic_used_without_its_sensors_section(survey):
    """The log's /odometer is used without a sensors.odometer section (clock offset 0), and the
    run says so; GNSS without a lever arm is refused; topics whose factor is off are listed."""
    d, data = survey
    p = _edit(data, (["sensors", "odometer"], None), (["factors", "odometer"], None))
    problem, info = _problem(d, p)
    assert problem.odometer is not None and problem.odometer.t_s.size > 1000
    assert info["sensors_defaulted"] == ["/odometer: no sensors.odometer section, used with clock_offset_s 0 (default)"]
    with pytest.raises(ConfigError, match=r"sensors.gnss.lever_arm_b_m: the log .* has /gnss"):
        _problem(d, _edit(data, (["sensors", "gnss"], None), (["factors", "gnss"], None)))
    _, info = _problem(d, _edit(data, (["factors", "gnss"], False), (["factors", "wheel_path"], False)))
    assert info["sensors_unused"] == [{"topic": "/gnss", "reason": "factors.gnss is off"}]
    lines = P.sensor_summary_lines({**info, "sensors_defaulted": ["x"]})
    assert lines == ["  default: x", "  sensors in the log not used: /gnss (factors.gnss is off)"]


def test_odometer_speed_check_follows_the_kind():
    """40 m/s is no trolley (distance_m in the wrong unit?) but a rail vehicle or a car."""
    from trackfusion.errors import SensorDataError
    from trackfusion.fusion.input_checks import check_odometer_units
    from trackfusion.sensors.types import OdometerData
    from trackfusion.vehicles import MAX_SPEED_MPS
    t = np.arange(0.0, 10.0, 0.01)
    odo = OdometerData(t, 40.0 * t, np.zeros(t.size, dtype=np.int64))
    with pytest.raises(SensorDataError, match=r"faster than a trolley \(30 m/s\)"):
        check_odometer_units(odo, "log.mcap", max_speed_mps=MAX_SPEED_MPS["trolley"], vehicle="trolley")
    for kind in ("rail-vehicle", "road-vehicle"):
        check_odometer_units(odo, "log.mcap", max_speed_mps=MAX_SPEED_MPS[kind], vehicle=kind)
