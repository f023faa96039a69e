"""Bad input, end to end through the command line: exit code 2, one line naming the
file, topic, record or config field, no traceback, no output written, inputs unchanged.

Cases: truncated or corrupt log (and ``inputs.allow_truncated`` running on the readable part),
NaN/Inf, time going backwards or duplicated, IMU saturation, unknown schema or topic, missing
files, unknown or ill-typed config keys, inconsistent units; for ``run``, ``inspect``,
``evaluate`` and ``simulate``. A run failing late (while writing) leaves no trajectory.csv.
"""

from __future__ import annotations

import copy
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.writer import CompressionType, Writer

from trackfusion.outdir import MANIFEST
from trackfusion.cli import main
from trackfusion.errors import TrackfusionError
from trackfusion.sensors.fileio import read_csv_table, write_csv_table
from trackfusion.sensors.imu import IMU_GRADES
from trackfusion.sensors.mcap_log import read_log, write_log
from trackfusion.sensors.types import InclinometerData
from trackfusion.simulation.faults import inject_clock_jump, inject_imu_saturation
from trackfusion.simulation.scenarios import simulate_to_dir

TINY = ["motion.passes=1",
        "motion.segments=[{hold_s: 20}, {move_to_m: 110, speed_mps: 3, accel_mps2: 0.5}, {hold_s: 12}]"]


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A short simulated survey (log, truth, pipeline) and its decoded log."""
    d = tmp_path_factory.mktemp("tiny")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=TINY)
    return d, read_log(d / "log.mcap")


def _digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err.strip().splitlines()
    last = err[-1]
    assert last.startswith("trackfusion ") and ": error: " in last, err
    assert "Traceback" not in "\n".join(err)
    for n in needles:
        assert n in last, (n, last)
    return last


def _case_dir(survey, tmp_path, log=None, raw: bytes | None = None, edit_pipeline=None) -> Path:
    """A copy of the survey in ``tmp_path`` with a replaced log and/or pipeline."""
    src, _ = survey
    for name in ("truth.csv", "truth.json"):
        (tmp_path / name).write_bytes((src / name).read_bytes())
    if log is not None:
        write_log(tmp_path / "log.mcap", log)
    elif raw is not None:
        (tmp_path / "log.mcap").write_bytes(raw)
    else:
        (tmp_path / "log.mcap").write_bytes((src / "log.mcap").read_bytes())
    data = yaml.safe_load((src / "pipeline.yaml").read_text())
    if edit_pipeline is not None:
        edit_pipeline(data)
    (tmp_path / "pipeline.yaml").write_text(yaml.safe_dump(data))
    return tmp_path


def _run_fails(case: Path, capsys, *needles) -> str:
    before = _digests(case)
    code = main(["run", str(case / "pipeline.yaml"), "--out", str(case / "out")])
    line = _one_error_line(capsys, *needles)
    assert code == 2
    assert not (case / "out").exists()
    assert not [p for p in case.iterdir() if p.name.startswith(".out-")]   # no staging folder left
    assert _digests(case) == before                                      # inputs unchanged
    return line


def _modified(log, fn):
    out = copy.deepcopy(log)
    fn(out)
    return out


# --- the log: damaged files ----------------------------------------------------------------------

def test_truncated_log_is_refused_saying_how_much_was_readable(survey, tmp_path, capsys):
    raw = (survey[0] / "log.mcap").read_bytes()
    case = _case_dir(survey, tmp_path, raw=raw[: int(len(raw) * 0.7)])
    line = _run_fails(case, capsys, "log.mcap", "truncated or corrupt MCAP", "records readable", "/imu ")
    assert main(["inspect", str(case / "log.mcap")]) == 2
    assert _one_error_line(capsys) .split(": error: ")[1] == line.split(": error: ")[1]


def test_allow_truncated_runs_on_the_readable_part_and_says_so(survey, tmp_path, capsys):
    raw = (survey[0] / "log.mcap").read_bytes()

    def allow(d):
        d["inputs"]["allow_truncated"] = True
    case = _case_dir(survey, tmp_path, raw=raw[: int(len(raw) * 0.7)], edit_pipeline=allow)
    before = _digests(case)
    assert main(["run", str(case / "pipeline.yaml"), "--out", str(case / "out")]) == 0
    err = capsys.readouterr().err
    assert "running on the readable part" in err and "/imu " in err
    m = json.loads((case / "out" / "metrics.json").read_text())
    lost = m["faults"]["truncated_log"]
    assert lost["byte"] > 0 and 0 < lost["records_readable"]["/imu"] < survey[1].imu.t_s.size
    assert m["imu_samples"] == lost["records_readable"]["/imu"]
    assert _digests(case) == before


def test_corrupt_byte_is_refused(survey, tmp_path, capsys):
    raw = bytearray((survey[0] / "log.mcap").read_bytes())
    raw[len(raw) // 2] ^= 0x20
    _run_fails(_case_dir(survey, tmp_path, raw=bytes(raw)), capsys, "log.mcap", "corrupt")


def _foreign(path: Path, log, edit):
    """Rewrite ``log`` with the mcap library, one message at a time through ``edit(topic, i, t_ns,
    payload) -> (topic_schema, t_ns, payload)``, so records the writer would refuse can be made."""
    tmp = path.with_name("canonical.mcap")
    write_log(tmp, log, encoding="json")  # JSON records, edited as text
    from mcap.reader import make_reader
    with open(tmp, "rb") as fh:
        msgs = [(c.topic, s.name, m.log_time, m.data.decode()) for s, c, m in make_reader(fh).iter_messages()]
    tmp.unlink()
    counts: dict[str, int] = {}
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start()
        ids: dict[tuple[str, str], int] = {}
        for topic, schema, t, payload in msgs:
            i = counts.get(topic, 0)
            counts[topic] = i + 1
            (topic, schema), t, payload = edit((topic, schema), i, t, payload)
            if (topic, schema) not in ids:
                ids[(topic, schema)] = w.register_channel(topic, "json", w.register_schema(schema, "jsonschema", b"{}"))
            w.add_message(ids[(topic, schema)], log_time=t, data=payload.encode(), publish_time=t)
        w.finish()


def _at(topic, index, fn):
    def edit(ts, i, t, payload):
        return fn(ts, t, payload) if ts[0] == topic and i == index else (ts, t, payload)
    return edit


@pytest.mark.parametrize("edit, needles", [
    (_at("/imu", 500, lambda ts, t, p: (ts, t, p.replace('"z":', '"z":NaN,"zz":', 1))), ["/imu record 500", "NaN"]),
    (_at("/gnss", 3, lambda ts, t, p: (ts, t, p.replace('"altitude":', '"altitude":Infinity,"a":', 1))),
     ["/gnss record 3", "infinite"]),
    (_at("/odometer", 40, lambda ts, t, p: (ts, t - 30_000_000, p)), ["/odometer record 40", "going backwards"]),
    (_at("/gnss", 5, lambda ts, t, p: (ts, t - 1_000_000_000, p)), ["/gnss record 5", "duplicated"]),
    (lambda ts, i, t, p: ((ts[0], "acme.Imu"), t, p) if ts[0] == "/imu" else (ts, t, p),
     ["/imu record 0", "unknown schema 'acme.Imu'"]),
    (lambda ts, i, t, p: (("/camera", ts[1]), t, p) if ts[0] == "/gnss" else (ts, t, p),
     ["/camera record 0", "unknown topic"]),
    (_at("/imu", 7, lambda ts, t, p: (ts, t, p.replace('"angular_velocity"', '"angular_rate"'))),
     ["/imu record 7", "missing field angular_velocity"]),
])
def test_bad_records_refused_by_run_and_inspect(survey, tmp_path, capsys, edit, needles):
    case = _case_dir(survey, tmp_path)
    _foreign(case / "log.mcap", survey[1], edit)
    _run_fails(case, capsys, "log.mcap", *needles)
    assert main(["inspect", str(case / "log.mcap")]) == 2
    _one_error_line(capsys, "log.mcap", *needles)


# --- the log: whole-series checks -----------------------------------------------------------------

NAV = IMU_GRADES["navigation"]


@pytest.mark.parametrize("edit, needles", [
    (lambda log: log.__setattr__("imu", inject_imu_saturation(log, limit=NAV.accel_range_mps2, axis=2)[0].imu),
     ["/imu record", "linear_acceleration.z flat at", "saturated", "accel_range_mps2"]),
    (lambda log: log.__setattr__("imu", inject_imu_saturation(log, limit=-np.radians(NAV.gyro_range_deg_per_s),
                                                              axis=0, field="gyro_radps", strength=0.05)[0].imu),
     ["/imu record", "angular_velocity.x flat at", "saturated", "gyro_range_deg_per_s"]),
    (lambda log: log.imu.accel_mps2.__setitem__((3000, 0), 150.0), ["/imu record 3000", "beyond the IMU's range"]),
    (lambda log: log.imu.__setattr__("accel_mps2", log.imu.accel_mps2 / 9.80665), ["/imu", "in g, not m/s^2"]),
    (lambda log: log.imu.__setattr__("gyro_radps", np.degrees(log.imu.gyro_radps)), ["/imu record", "not in rad/s"]),
    (lambda log: log.odometer.__setattr__("distance_m", log.odometer.distance_m * 1000.0),
     ["/odometer record", "not in metres"]),
    (lambda log: log.gnss.__setattr__("lat_deg", np.radians(log.gnss.lat_deg)), ["/gnss record 0", "km from the origin"]),
    (lambda log: log.gnss.cov_enu_m2.__setitem__((4, 2, 2), -1e-4), ["/gnss record 4", "position_covariance"]),
    (lambda log: log.gnss.lat_deg.__setitem__(6, 100.0), ["/gnss record 6", "not geodetic degrees"]),
])
def test_implausible_series_refused(survey, tmp_path, capsys, edit, needles):
    _run_fails(_case_dir(survey, tmp_path, log=_modified(survey[1], edit)), capsys, "log.mcap", *needles)


def test_inclinometer_in_degrees_refused(survey, tmp_path, capsys):
    log = survey[1]
    t = log.imu.t_s[::10]
    inc = _modified(log, lambda lg: setattr(lg, "inclinometer", InclinometerData(t, np.full(t.size, 2.0),
                                                                                  np.zeros(t.size))))

    def use(d):
        d["sensors"]["inclinometer"] = {"clock_offset_s": 0.0}
        d["factors"]["inclinometer"] = True
    _run_fails(_case_dir(survey, tmp_path, log=inc, edit_pipeline=use), capsys, "/inclinometer record 0", "degrees")


def test_clock_jump_at_rest_that_the_data_cannot_resolve_is_refused(survey, tmp_path, capsys):
    log, _ = inject_clock_jump(survey[1], strength=2.4, topic="/gnss", at_s=10.0)   # at rest, off the 1 s grid
    _run_fails(_case_dir(survey, tmp_path, log=log), capsys, "/gnss record 10", "clock jump", "at rest")


# --- the pipeline ---------------------------------------------------------------------------------

def _set(path, value):
    def edit(d):
        node = d
        for k in path[:-1]:
            node = node.setdefault(k, {})
        node[path[-1]] = value
    return edit


@pytest.mark.parametrize("edit, needles", [
    (_set(["inputs", "log"], "nope.mcap"), ["inputs.log", "file not found", "nope.mcap"]),
    (_set(["inputs", "reference"], "nope.csv"), ["inputs.reference", "file not found"]),
    (_set(["factors", "gnss"], {"huber_kk": 2.0}), ["factors.gnss.huber_kk", "Extra inputs are not permitted"]),
    (_set(["sensors", "imu", "rate_hz"], "fast"), ["sensors.imu.rate_hz"]),
    (_set(["factors", "nhc"], {"sigma_mm_per_s": float("inf")}), ["factors.nhc.sigma_mm_per_s", "finite"]),
    (_set(["origin", "lat_deg"], "42 N"), ["origin.lat_deg"]),
    (_set(["vehicle", "lever_arm_imu_v_m"], [0, 1]), ["vehicle.lever_arm_imu_v_m"]),
    (_set(["sensors", "imu", "grade"], ["navigation"]), ["sensors.imu", "unknown grade"]),
    (_set(["sensors", "imu", "rate_hz"], 500.0), ["sensors.imu.rate_hz", "500 Hz", "runs at 200 Hz"]),
    (_set(["inputs", "allow_truncated"], "sometimes"), ["inputs.allow_truncated"]),
])
def test_bad_pipeline_refused_naming_the_field(survey, tmp_path, capsys, edit, needles):
    _run_fails(_case_dir(survey, tmp_path, edit_pipeline=edit), capsys, "pipeline.yaml", *needles)


def test_a_run_failing_while_writing_leaves_no_trajectory(survey, tmp_path, capsys, monkeypatch):
    """Fail late: after trajectory.csv and metrics.json are staged, while writing fused.mcap."""
    import trackfusion.sensors.fused as fused

    def broken(*_a, **_k):
        raise TrackfusionError("disk full (simulated)")
    monkeypatch.setattr(fused, "write_fused_mcap", broken)
    case = _case_dir(survey, tmp_path)
    (case / "out").mkdir()
    (case / "out" / "metrics.json").write_text("{}\n")      # an older result stays untouched
    (case / "out" / MANIFEST).write_text('{"files": ["metrics.json"]}')  # (an earlier run's: trackfusion/outdir.py)
    before = _digests(case)
    assert main(["run", str(case / "pipeline.yaml"), "--out", str(case / "out")]) == 2
    _one_error_line(capsys, "disk full")
    assert sorted(p.name for p in (case / "out").iterdir()) == [MANIFEST, "metrics.json"]  # no staging, no lock
    assert (case / "out" / "metrics.json").read_text() == "{}\n"
    assert not [p for p in case.iterdir() if p.name.startswith(".out-")]
    assert _digests(case) == before


# --- evaluate and simulate ------------------------------------------------------------------------

def test_evaluate_bad_files(survey, tmp_path, capsys):
    d = survey[0]
    assert main(["evaluate", str(tmp_path / "none.csv"), str(d / "truth.csv")]) == 2
    _one_error_line(capsys, "none.csv", "not found")
    tab = read_csv_table(d / "truth.csv")
    side = json.loads((d / "truth.json").read_text())
    bad = dict(tab)
    bad["e_m"] = tab["e_m"].copy()
    bad["e_m"][10] = np.nan
    write_csv_table(tmp_path / "nan.csv", bad, side["columns"], side["frame"], side["origin"], fmt="%.12g")
    assert main(["evaluate", str(tmp_path / "nan.csv"), str(d / "truth.csv")]) == 2
    _one_error_line(capsys, "nan.csv")
    dup = {k: np.r_[v[:5], v[4:]] for k, v in tab.items()}
    write_csv_table(tmp_path / "dup.csv", dup, side["columns"], side["frame"], side["origin"], fmt="%.12g")
    assert main(["evaluate", str(tmp_path / "dup.csv"), str(d / "truth.csv")]) == 2
    _one_error_line(capsys, "dup.csv")


@pytest.mark.parametrize("args, needles", [
    (["--set", "imu.gyro_range_deg_per_s=-5"], ["imu", "gyro_range_deg_per_s"]),
    (["--set", "gnss.rate_hz=fast"], ["gnss", "rate_hz"]),
    (["--set", "odometer.slipz=[]"], ["odometer", "slipz"]),
    (["--set", "nokey"], ["nokey"]),
])
def test_simulate_bad_settings(tmp_path, capsys, args, needles):
    assert main(["simulate", "open-track-gnss", "--out", str(tmp_path / "x"), *args]) == 2
    _one_error_line(capsys, *needles)
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())
