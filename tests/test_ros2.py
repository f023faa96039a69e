"""ROS 2 input (sensors/ros2.py, sensors/cdr.py) and IMU conventions (sensors/imu_axes.py).

Bags are written by independent writers (``rosbags.rosbag2.Writer`` with MCAP and sqlite3
storage, ``mcap_ros2.writer``), never by trackfusion's code, and read back to the values
written. Bad input ends ``run``/``import`` with exit 2 and one line. End to end, a simulated
survey converted to a bag, and to F-R-D increments in text imported with ``axes: frd``, runs to
the original's trajectory.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from trackfusion.cli import main
from trackfusion.errors import ConfigError, SensorDataError
from trackfusion.sensors import cdr, imu_axes
from trackfusion.sensors.fileio import read_csv_table
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.sensors.ros2 import inspect_log_or_bag, read_bag
from trackfusion.sensors.types import ImuData, SensorLog
from trackfusion.simulation.scenarios import simulate_to_dir

TINY = ["motion.passes=1",
        "motion.segments=[{hold_s: 20}, {move_to_m: 110, speed_mps: 3, accel_mps2: 0.5}, {hold_s: 12}]"]
ODO = "trackfusion_msgs/msg/OdometerDistance"


def _store():
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(cdr.ODOMETER_DISTANCE_MSG, ODO))
    return store


STORE = _store()
T = STORE.types


def _header(ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                    frame_id=frame)


def _imu_msg(ns, gyro, accel, frame="imu_link"):
    v3, q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    return T["sensor_msgs/msg/Imu"](
        header=_header(ns, frame), orientation=q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.r_[-1.0, np.zeros(8)], angular_velocity=v3(x=gyro[0], y=gyro[1], z=gyro[2]),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=v3(x=accel[0], y=accel[1], z=accel[2]),
        linear_acceleration_covariance=np.zeros(9))


def _fix_msg(ns, lat, lon, h, cov, status):
    return T["sensor_msgs/msg/NavSatFix"](
        header=_header(ns, "gnss"), status=T["sensor_msgs/msg/NavSatStatus"](status=status, service=1),
        latitude=lat, longitude=lon, altitude=h, position_covariance=np.asarray(cov, float).ravel(),
        position_covariance_type=3)


def _odometry_msg(ns, x, vx):
    g = T
    pose = g["geometry_msgs/msg/PoseWithCovariance"](
        pose=g["geometry_msgs/msg/Pose"](position=g["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0),
                                         orientation=g["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        covariance=np.zeros(36))
    twist = g["geometry_msgs/msg/TwistWithCovariance"](
        twist=g["geometry_msgs/msg/Twist"](linear=g["geometry_msgs/msg/Vector3"](x=vx, y=0.0, z=0.0),
                                           angular=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
        covariance=np.zeros(36))
    return g["nav_msgs/msg/Odometry"](header=_header(ns, "odom"), child_frame_id="base_link", pose=pose, twist=twist)


def _odo_msg(ns, d, ticks):
    return T[ODO](header=_header(ns, "wheel"), distance_m=d, ticks=ticks)


def _write_bag(path: Path, topics: dict[str, tuple[str, list[tuple[int, object]]]], storage=StoragePlugin.MCAP,
               receive_offset_ns: int = 1_000_000) -> None:
    """A rosbag2 bag at ``path`` (a folder) by rosbags' writer: topic -> (type, [(stamp ns, msg)])."""
    with Writer(path, version=9, storage_plugin=storage) as w:
        for topic, (msgtype, msgs) in topics.items():
            conn = w.add_connection(topic, msgtype, typestore=STORE)
            for ns, msg in msgs:
                w.write(conn, ns + receive_offset_ns, STORE.serialize_cdr(msg, msgtype))


def _sample_topics(n=50):
    rng = np.random.default_rng(1)
    t_ns = 1_700_000_000_000_000_000 + np.arange(n) * 2_000_000  # 500 Hz, epoch stamps
    gyro, accel = rng.normal(size=(n, 3)) * 1e-3, rng.normal(size=(n, 3)) * 0.01 + [0, 0, 9.81]
    imu = [(int(t), _imu_msg(int(t), g, a, frame="imu" if i % 3 else "imu_link_long"))
           for i, (t, g, a) in enumerate(zip(t_ns, gyro, accel))]
    fixes = [(int(t_ns[i]), _fix_msg(int(t_ns[i]), 48.1 + i * 1e-7, 11.5, 520.0 + i, np.diag([1e-4, 2e-4, 9e-4]),
                                     [2, 0, -1, 1][(i // 10) % 4])) for i in range(0, n, 10)]
    odo = [(int(t), _odo_msg(int(t), 0.01 * i, 10 * i)) for i, t in enumerate(t_ns[::2])]
    expect = {"t_s": (t_ns - 1_700_000_000_000_000_000) / 1e9, "gyro": gyro, "accel": accel}
    return {"/imu/data": ("sensor_msgs/msg/Imu", imu), "/fix": ("sensor_msgs/msg/NavSatFix", fixes),
            "/wheel": (ODO, odo)}, expect


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_rosbags_bag_reads_back_to_the_values_written(tmp_path, storage):
    topics, expect = _sample_topics()
    _write_bag(tmp_path / "bag", topics, storage)
    files = [p for p in (tmp_path / "bag").iterdir() if p.suffix in (".mcap", ".db3")]
    for path in (tmp_path / "bag", files[0]):  # the rosbag2 folder and its storage file alone
        log, damage = read_bag(path)
        assert damage is None
        assert np.array_equal(log.imu.t_s, expect["t_s"])  # header stamps, not the receive times, from the
        assert log.metadata["ros2_time_origin_ns"] == 1_700_000_000_000_000_000  # whole second of the first
        assert np.array_equal(log.imu.gyro_radps, expect["gyro"]) and np.array_equal(log.imu.accel_mps2, expect["accel"])
        assert log.gnss.fix_quality.tolist() == [4, 1, 0, 2, 4]  # NavSatStatus GBAS, FIX, NO_FIX, SBAS
        assert np.array_equal(log.gnss.h_m, 520.0 + np.arange(0, 50, 10))
        assert np.array_equal(log.gnss.cov_enu_m2[0], np.diag([1e-4, 2e-4, 9e-4]))
        assert np.array_equal(log.odometer.distance_m, 0.01 * np.arange(25)) and log.odometer.ticks[-1] == 240
        assert log.metadata["ros2_topics"] == {"imu": "/imu/data", "gnss": "/fix", "odometer": "/wheel"}
        summary = {t.topic: t for t in inspect_log_or_bag(path).topics}
        assert summary["/imu/data"].count == 50 and summary["/imu/data"].schema == "sensor_msgs/msg/Imu"
        assert abs(summary["/imu/data"].rate_hz - 500.0) < 1e-6 and summary["/wheel"].count == 25


def test_odometry_distance_is_the_integrated_forward_speed(tmp_path):
    t_ns = np.arange(0, 101) * 10_000_000  # 100 Hz
    v = 1.0 + 0.5 * np.sin(t_ns / 1e9)
    _write_bag(tmp_path / "bag", {"/odom": ("nav_msgs/msg/Odometry",
                                            [(int(t), _odometry_msg(int(t), 0.0, float(s))) for t, s in zip(t_ns, v)])})
    log, _ = read_bag(tmp_path / "bag")
    t = t_ns / 1e9
    expected = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]
    assert np.allclose(log.odometer.distance_m, expected, rtol=0, atol=1e-12)
    assert abs(log.odometer.distance_m[-1] - (1.0 + 0.5 * (1 - math.cos(1.0)))) < 1e-5  # the analytic integral


def test_mcap_ros2_writer_bag_reads_back(tmp_path):
    from mcap_ros2.writer import Writer as Ros2Writer
    path = tmp_path / "ros2.mcap"
    gyro = np.array([[0.1, -0.2, 0.3], [0.01, 0.02, -0.03]])
    with open(path, "wb") as fh:
        w = Ros2Writer(fh)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", STORE.generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)[0])
        for i, g in enumerate(gyro):
            w.write_message("/imu", schema, {
                "header": {"stamp": {"sec": 5, "nanosec": 1000 * i}, "frame_id": "x"},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}, "orientation_covariance": [0.0] * 9,
                "angular_velocity": dict(zip("xyz", g)), "angular_velocity_covariance": [0.0] * 9,
                "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.8}, "linear_acceleration_covariance": [0.0] * 9},
                log_time=10 + i, publish_time=10 + i, sequence=i)
        w.finish()
    log, _ = read_bag(path)
    assert np.array_equal(log.imu.gyro_radps, gyro) and np.array_equal(log.imu.t_s, [0.0, 1e-6]) and log.metadata["ros2_time_origin_ns"] == 5 * 10**9
    assert log.gnss is None and log.odometer is None


def test_own_raw_log_round_trip_and_cdr_layout():
    n = 1000
    rng = np.random.default_rng(2)
    log = SensorLog(imu=ImuData(np.arange(1, n + 1) / 500, rng.normal(size=(n, 3)), rng.normal(size=(n, 3))))
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        write_log(Path(d) / "a.mcap", log)
        back = read_log(Path(d) / "a.mcap")
        write_log(Path(d) / "j.mcap", log, encoding="json")  # the older all-JSON format reads the same
        assert np.array_equal(read_log(Path(d) / "j.mcap").imu.accel_mps2, log.imu.accel_mps2)
    assert np.array_equal(back.imu.t_s, log.imu.t_s)
    assert np.array_equal(back.imu.gyro_radps, log.imu.gyro_radps) and np.array_equal(back.imu.accel_mps2,
                                                                                       log.imu.accel_mps2)
    # trackfusion's encoder writes what rosbags' serializer writes
    rec = cdr.encode("sensor_msgs/msg/Imu", "imu", {"angular_velocity": log.imu.gyro_radps[:1],
                                                    "linear_acceleration": log.imu.accel_mps2[:1],
                                                    "orientation": [[0, 0, 0, 1.0]], "stamp.sec": 0,
                                                    "stamp.nanosec": 2_000_000}, 1)
    ref = STORE.serialize_cdr(_imu_msg(2_000_000, log.imu.gyro_radps[0], log.imu.accel_mps2[0], "imu"),
                              "sensor_msgs/msg/Imu")
    ref = bytearray(ref)
    ref[4 + 16 + 32:4 + 16 + 40] = bytes(8)  # orientation_covariance[0]: -1 in the helper, 0 here
    assert rec.tobytes() == bytes(ref)


def test_own_log_with_a_cdr_record_of_the_wrong_size_names_it(tmp_path):
    """Records cut out of a chunk one size at a time, and the chunk holding the odd one, keep
    their indexes: the error names /imu record 700 of the raw log."""
    from mcap.reader import make_reader
    from mcap.writer import Writer as McapWriter
    n = 3000
    log = SensorLog(imu=ImuData(np.arange(1, n + 1) / 500, np.zeros((n, 3)), np.tile([0, 0, 9.8], (n, 1))))
    write_log(tmp_path / "ok.mcap", log)
    with open(tmp_path / "ok.mcap", "rb") as fh, open(tmp_path / "bad.mcap", "wb") as out:
        reader = make_reader(fh)
        w = McapWriter(out, chunk_size=64 * 1024)
        w.start(profile="", library="test")
        ids = {}
        for i, (schema, channel, m) in enumerate(reader.iter_messages()):
            if channel.topic not in ids:
                ids[channel.topic] = w.register_channel(channel.topic, "cdr", w.register_schema(
                    schema.name, schema.encoding, schema.data))
            w.add_message(ids[channel.topic], log_time=m.log_time, publish_time=m.log_time,
                          data=m.data + bytes(8) if i == 700 else m.data)
        w.finish()
    with pytest.raises(SensorDataError, match=r"bad.mcap: /imu record 700: CDR record of 324 bytes, its "
                                              r"sensor_msgs/msg/Imu layout needs 316"):
        read_log(tmp_path / "bad.mcap")


def test_cdr_decode_names_the_record_of_the_wrong_size():
    msgs = [bytes(STORE.serialize_cdr(_imu_msg(i, [0, 0, 0], [0, 0, 9.8]), "sensor_msgs/msg/Imu")) for i in range(9)]
    for bad, reason in ((msgs[6][:-8], "ends inside field linear_acceleration_covariance"),
                        (msgs[6] + bytes(8), "layout needs 324"), (b"\x00\x00" + msgs[6][2:], "not little-endian")):
        with pytest.raises(cdr.CdrRecordError) as info:
            cdr.decode(cdr.Records.from_payloads(msgs[:6] + [bad] + msgs[7:]), "sensor_msgs/msg/Imu")
        assert info.value.index == 6 and reason in info.value.reason
    padded = [m + bytes(3) for m in [bytes(STORE.serialize_cdr(_fix_msg(1, 1.0, 2.0, 3.0, np.eye(3), 0),
                                                               "sensor_msgs/msg/NavSatFix"))]]
    assert cdr.decode(cdr.Records.from_payloads(padded), "sensor_msgs/msg/NavSatFix")["latitude"][0] == 1.0


# --- IMU conventions ---------------------------------------------------------------------------------

def test_axes_letters_and_matrices():
    assert np.array_equal(imu_axes.axes_matrix("flu"), np.eye(3))
    assert np.array_equal(imu_axes.axes_matrix("FRD"), np.diag([1.0, -1.0, -1.0]))
    c = imu_axes.axes_matrix("rfu")  # x right, y forward, z up
    assert np.array_equal(c @ [1.0, 0, 0], [0, -1.0, 0]) and imu_axes.axes_name(c) == "rfu"
    assert np.array_equal(imu_axes.axes_matrix([[1, 0, 0], [0, -1, 0], [0, 0, -1]]), imu_axes.axes_matrix("frd"))
    for bad in ("fru", "ffu", "xyz", "fl", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]):
        with pytest.raises(ValueError):
            imu_axes.axes_matrix(bad)


def test_likely_convention_for_each_wrong_declaration():
    g = np.array([0.0, 0.0, 9.81])
    for true in ("flu", "frd", "rfu", "bru", "fur", "ldb"):
        c_true = imu_axes.axes_matrix(true)
        f_s = c_true.T @ g  # what that sensor measures at rest
        for declared in ("flu", "frd"):
            c = imu_axes.axes_matrix(declared)
            imu = ImuData(np.arange(100) / 100.0, np.zeros((100, 3)), np.tile(c @ f_s, (100, 1)))
            if np.allclose(c @ f_s, g):
                imu_axes.check_imu_frame(imu, "x", c, "k")
                continue
            with pytest.raises(SensorDataError) as info:
                imu_axes.check_imu_frame(imu, "x", c, "k")
            likely = imu_axes.axes_matrix(str(info.value).split("likely k: ")[1])
            assert np.allclose(likely @ f_s, g)  # the hinted convention puts gravity's reaction up


def test_increments_divide_by_each_interval():
    t = np.array([0.0, 0.01, 0.02, 0.04])
    inc = np.array([[0.01, 0, 0], [0.01, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    assert np.allclose(imu_axes.rates_from_increments(t, inc)[:, 0], 1.0)


# --- end to end and bad input through the command line ----------------------------------------------

@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A short simulated survey, its log, and the trajectory ``run`` gives on it."""
    d = tmp_path_factory.mktemp("tiny")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=TINY)
    assert main(["run", str(d / "pipeline.yaml"), "--out", str(d / "out")]) == 0
    return d, read_log(d / "log.mcap"), read_csv_table(d / "out" / "trajectory.csv")


def _case(survey, tmp_path, log_name: str, edit=None) -> Path:
    d = survey[0]
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data["inputs"]["log"] = log_name
    data["inputs"]["reference"] = str(d / "truth.csv")
    if edit is not None:
        edit(data)
    (tmp_path / "pipeline.yaml").write_text(yaml.safe_dump(data))
    return tmp_path / "pipeline.yaml"


def _bag_of(log: SensorLog) -> dict:
    imu, gnss, odo = log.imu, log.gnss, log.odometer
    ns = lambda t: np.rint(t * 1e9).astype(np.int64).tolist()  # noqa: E731
    quality = {4: 2, 1: 0, 2: 1, 0: -1}
    return {
        "/imu/data": ("sensor_msgs/msg/Imu", [(t, _imu_msg(t, g, a)) for t, g, a in
                                              zip(ns(imu.t_s), imu.gyro_radps, imu.accel_mps2)]),
        "/fix": ("sensor_msgs/msg/NavSatFix", [(t, _fix_msg(t, la, lo, h, c, quality[int(q)])) for t, la, lo, h, c, q in
                                               zip(ns(gnss.t_s), gnss.lat_deg, gnss.lon_deg, gnss.h_m, gnss.cov_enu_m2,
                                                   gnss.fix_quality)]),
        "/wheel": (ODO, [(t, _odo_msg(t, d, int(k))) for t, d, k in zip(ns(odo.t_s), odo.distance_m, odo.ticks)])}


def _rms_mm(a: dict, b: dict) -> float:
    assert np.array_equal(a["t_s"], b["t_s"])
    d = np.column_stack([a[k] - b[k] for k in ("e_m", "n_m", "u_m")])
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))) * 1e3


def test_bag_of_the_survey_runs_to_the_same_trajectory(survey, tmp_path):
    _, log, original = survey
    assert log.inclinometer is None and not log.total_stations  # the bag carries every sensor the run uses
    _write_bag(tmp_path / "bag", _bag_of(log))
    pipeline = _case(survey, tmp_path, "bag", lambda d: d["inputs"].update(
        topics={"imu": "/imu/data", "gnss": "/fix", "odometer": "/wheel"}))
    assert main(["run", str(pipeline), "--out", str(tmp_path / "out")]) == 0
    rms = _rms_mm(read_csv_table(tmp_path / "out" / "trajectory.csv"), original)
    print(f"bag run against the original run: {rms:.3g} mm RMS")
    assert rms < 1e-9  # (the target is 0.2 mm; the bag holds the log's values bit for bit, so the run must agree)
    # init on the bag writes a pipeline that runs (its topics found as run finds them)
    assert main(["init", str(tmp_path / "bag"), "--out", str(tmp_path / "init.yaml"), "--imu-grade", "navigation"]) == 0
    assert yaml.safe_load((tmp_path / "init.yaml").read_text())["inputs"]["log"] == "bag"
    assert main(["run", str(tmp_path / "init.yaml"), "--out", str(tmp_path / "out_init")]) == 0


def test_frd_increments_imported_with_axes_frd_run_to_the_same_trajectory(survey, tmp_path, capsys):
    d, log, original = survey
    imu = log.imu
    dt = np.diff(imu.t_s, prepend=imu.t_s[0] - np.median(np.diff(imu.t_s)))[:, None]
    flip = np.array([1.0, -1.0, -1.0])  # F-L-U body -> F-R-D sensor
    rows = np.column_stack([imu.t_s, imu.gyro_radps * flip * dt * 180 / math.pi, imu.accel_mps2 * flip * dt])
    np.savetxt(tmp_path / "imu.txt", rows, fmt="%.17g")
    odo = log.odometer
    np.savetxt(tmp_path / "odo.csv", np.column_stack([odo.t_s, odo.distance_m, odo.ticks]), fmt="%.17g",
               delimiter=",", header="t,d,k", comments="")
    g = log.gnss
    np.savetxt(tmp_path / "gnss.csv", np.column_stack([g.t_s, g.lat_deg, g.lon_deg, g.h_m, g.cov_enu_m2.reshape(-1, 9),
                                                       g.fix_quality]), fmt="%.17g", delimiter=",",
               header="t,lat,lon,h," + ",".join(f"c{i}" for i in range(9)) + ",q", comments="")
    mapping = {
        "imu": {"file": "imu.txt", "delimiter": "whitespace", "header": False, "time": {"column": 0, "unit": "s"},
                "gyro": {"columns": [1, 2, 3], "unit": "deg"}, "accel": {"columns": [4, 5, 6], "unit": "m/s"},
                "axes": "frd"},
        "odometer": {"file": "odo.csv", "time": {"column": "t"}, "distance": {"column": "d"}, "ticks": {"column": "k"}},
        "gnss": {"file": "gnss.csv", "time": {"column": "t"}, "latitude": {"column": "lat"},
                 "longitude": {"column": "lon"}, "height": {"column": "h"},
                 "covariance": {"columns": [f"c{i}" for i in range(9)]}, "fix_quality": {"column": "q"}}}
    (tmp_path / "import.yaml").write_text(yaml.safe_dump(mapping))
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "log.mcap")]) == 0
    back = read_log(tmp_path / "log.mcap")
    assert np.allclose(back.imu.accel_mps2, imu.accel_mps2, rtol=1e-12, atol=1e-12)
    assert main(["run", str(_case(survey, tmp_path, "log.mcap")), "--out", str(tmp_path / "out")]) == 0
    rms = _rms_mm(read_csv_table(tmp_path / "out" / "trajectory.csv"), original)
    with capsys.disabled():
        print(f"F-R-D increments imported with axes: frd, against the original run: {rms:.3g} mm RMS")
    assert rms < 1e-6  # (target 0.2 mm; measured 2.6e-9 mm: the increments divided back differ by rounding only)
    # the same file declared with the default axes (flu) is refused: it would run upside down
    mapping["imu"].pop("axes")
    (tmp_path / "import.yaml").write_text(yaml.safe_dump(mapping))
    capsys.readouterr()
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "flu.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "imu.txt" in err[0] and "likely imu.axes: frd" in err[0]
    assert not (tmp_path / "flu.mcap").exists()
    # and the increments declared as rates
    mapping["imu"].update(axes="frd", gyro={"columns": [1, 2, 3], "unit": "deg/s"},
                          accel={"columns": [4, 5, 6], "unit": "m/s^2"})
    (tmp_path / "import.yaml").write_text(yaml.safe_dump(mapping))
    assert main(["import", str(tmp_path / "import.yaml"), "--out", str(tmp_path / "rates.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "per-sample increments" in err[0] and "m/s" in err[0]


def _fails(capsys, argv, *needles):
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if ": error: " in line]
    assert len(errors) == 1 and errors[0] == err[-1] and "Traceback" not in "\n".join(err), err
    for n in needles:
        assert n in err[-1], (n, err[-1])


def test_bad_input_ends_run_with_one_line(survey, tmp_path, capsys):
    d, log, _ = survey
    out = ["--out", str(tmp_path / "out")]
    # wrong axes: the survey's FLU log declared F-R-D
    _fails(capsys, ["run", str(_case(survey, tmp_path, str(d / "log.mcap"),
                                     lambda p: p["inputs"].update(imu_axes="frd"))), *out],
           "log.mcap", "inputs.imu_axes: frd", "likely inputs.imu_axes: flu")
    # increments written as rates (what a logger writing delta-v / delta-theta gives when mapped as rates)
    dt = 1.0 / 200.0
    inc = SensorLog(imu=ImuData(log.imu.t_s, log.imu.gyro_radps * dt, log.imu.accel_mps2 * dt), gnss=log.gnss,
                    odometer=log.odometer)
    write_log(tmp_path / "inc.mcap", inc)
    _fails(capsys, ["run", str(_case(survey, tmp_path, "inc.mcap")), *out], "inc.mcap", "per-sample increments")
    # a bag with two IMU topics, none named: ambiguous
    topics = _bag_of(log)
    _write_bag(tmp_path / "two", {**topics, "/imu/raw": topics["/imu/data"]})
    _fails(capsys, ["run", str(_case(survey, tmp_path, "two")), *out], "inputs.topics.imu", "/imu/data", "/imu/raw")
    # a topic of an unsupported type named in the pipeline
    _write_bag(tmp_path / "cam", {**topics, "/cam/info": ("std_msgs/msg/String", [(1, T["std_msgs/msg/String"](data="x"))])})
    _fails(capsys, ["run", str(_case(survey, tmp_path, "cam", lambda p: p["inputs"].update(topics={"imu": "/cam/info"}))),
                    *out], "inputs.topics.imu", "/cam/info", "unsupported type 'std_msgs/msg/String'")
    # a CDR record of the wrong size (written with the mcap library: a writer that lets it through)
    from mcap.writer import Writer as McapWriter
    with open(tmp_path / "cut.mcap", "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", b"")
        cid = w.register_channel("/imu", "cdr", sid)
        for i, (t, msg) in enumerate(topics["/imu/data"][1]):
            data = bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
            w.add_message(cid, log_time=t, publish_time=t, data=data[:-8] if i == 1234 else data)
        w.finish()
    _fails(capsys, ["run", str(_case(survey, tmp_path, "cut.mcap")), *out], "cut.mcap", "/imu record 1234", "CDR record")
    # a left-handed axes declaration is a config error naming the key
    _fails(capsys, ["run", str(_case(survey, tmp_path, "cut.mcap", lambda p: p["inputs"].update(imu_axes="fru"))),
                    *out], "inputs.imu_axes", "left-handed")
    assert not (tmp_path / "out").exists()


def test_topic_choice_errors():
    found = {"/a": ("sensor_msgs/msg/Imu", 5), "/b": ("sensor_msgs/msg/Imu", 5), "/f": ("sensor_msgs/msg/NavSatFix", 1)}
    from trackfusion.sensors.ros2 import select_topics
    assert select_topics(Path("x"), found, {"imu": "/b"}, "p.yaml") == {"imu": ("/b", "sensor_msgs/msg/Imu"),
                                                                        "gnss": ("/f", "sensor_msgs/msg/NavSatFix")}
    with pytest.raises(ConfigError, match="topic /c is not in x"):
        select_topics(Path("x"), found, {"imu": "/c"}, "p.yaml")
