"""fused.mcap against the official Foxglove schemas (the ``foxglove-schemas-protobuf`` package):
every message of a ``foxglove.*`` schema parses strictly (no unknown field, right types) into
the official message; absolute times from the log's epoch; one schema record per name; the
n -> b FrameTransform follows the trajectory."""

from __future__ import annotations

import importlib
import json
from datetime import datetime, timezone

import numpy as np
import pytest

pytest.importorskip("foxglove_schemas_protobuf")
from google.protobuf import json_format  # noqa: E402  (ships with foxglove-schemas-protobuf)
from mcap.reader import make_reader  # noqa: E402

from trackfusion.errors import SensorDataError  # noqa: E402
from trackfusion.geodesy import Origin  # noqa: E402
from trackfusion.sensors.fused import survey_epoch_ns, write_fused_mcap  # noqa: E402
from trackfusion.sensors.types import GnssData, ImuData, SensorLog  # noqa: E402

EPOCH = "2024-06-03T08:00:00Z"
EPOCH_NS = int(datetime(2024, 6, 3, 8, tzinfo=timezone.utc).timestamp()) * 10**9
ORIGIN = Origin(42.86, 90.17, 60.0)


def _official(name: str):
    """The official protobuf message class of a Foxglove schema name (``foxglove.LocationFix``)."""
    short = name.split(".", 1)[1]
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2"), short)


def _to_proto_json(obj, descriptor):
    """Foxglove's JSON encoding ({sec, nsec} times) -> protobuf's canonical JSON (RFC 3339 / "1.5s")."""
    if not isinstance(obj, dict):
        return obj
    out = {}
    for key, value in obj.items():
        field = descriptor.fields_by_name.get(key)
        kind = field.message_type.full_name if field is not None and field.message_type is not None else None
        if kind == "google.protobuf.Timestamp":
            value = datetime.fromtimestamp(value["sec"], timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") \
                + f".{value['nsec']:09d}Z"
        elif kind == "google.protobuf.Duration":
            value = f"{value['sec'] + value['nsec'] * 1e-9:.9f}s"
        elif kind is not None:
            value = [_to_proto_json(v, field.message_type) for v in value] if isinstance(value, list) \
                else _to_proto_json(value, field.message_type)
        out[key] = value
    return out


def _survey(n: int = 400, epoch: str | None = EPOCH):
    t = np.arange(1, n + 1) * 0.01
    table = {"t_s": t, "e_m": 0.5 * t, "n_m": 0.1 * t, "u_m": np.zeros(n), "qw": np.cos(0.1 * t),
             "qx": np.zeros(n), "qy": np.zeros(n), "qz": np.sin(0.1 * t), "chainage_m": 0.5 * t,
             **{f"sigma_{a}_m": np.full(n, 0.002) for a in "enu"}}
    tg = t[::100]
    cov = np.tile(np.diag([1e-4, 1e-4, 4e-4]), (tg.size, 1, 1))
    raw = SensorLog(imu=ImuData(t, np.zeros((n, 3)), np.tile([0, 0, 9.8], (n, 1))),
                    gnss=GnssData(tg, 42.86 + 1e-6 * tg, 90.17 + 1e-6 * tg, 60 + 0 * tg, cov, np.full(tg.size, 4)))
    raw.metadata = {"survey": {"origin": ORIGIN.to_dict(), **({"epoch_utc": epoch} if epoch else {})}}
    geometry = {"chainage_m": np.arange(0, 2, 0.25), **{f"{s}_{a}_m": np.arange(0, 2, 0.25) + (0.75 if s == "right" else 0)
                                                    for s in ("left", "right") for a in "enu"}}
    return table, raw, geometry


def _read(path):
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        msgs = list(reader.iter_messages(log_time_order=True))
    return summary, msgs


@pytest.fixture(scope="module")
def fused(tmp_path_factory):
    path = tmp_path_factory.mktemp("fx") / "fused.mcap"
    table, raw, geometry = _survey()
    write_fused_mcap(path, table, ORIGIN, raw=raw, geometry=geometry)
    return path, table


def test_every_foxglove_message_parses_strictly_into_the_official_schema(fused):
    summary, msgs = _read(fused[0])
    seen = set()
    for schema, channel, msg in msgs:
        if not schema.name.startswith("foxglove."):
            continue
        cls = _official(schema.name)
        doc = json.loads(msg.data)
        if channel.topic == "/gnss":
            assert doc.pop("fix_quality") == 4  # trackfusion's one documented extension of LocationFix
        json_format.ParseDict(_to_proto_json(doc, cls.DESCRIPTOR), cls())  # raises on an unknown field or bad type
        seen.add((channel.topic, schema.name))
    assert seen == {("/gnss", "foxglove.LocationFix"), ("/trajectory/pose", "foxglove.PoseInFrame"),
                    ("/trajectory/fix", "foxglove.LocationFix"), ("/trajectory/tf", "foxglove.FrameTransform"),
                    ("/trajectory/path", "foxglove.SceneUpdate"), ("/track/rails", "foxglove.SceneUpdate"),
                    ("/track/rails_geojson", "foxglove.GeoJSON")}


def test_one_schema_record_per_name(fused):
    summary, _msgs = _read(fused[0])
    names = [s.name for s in summary.schemas.values()]
    assert len(names) == len(set(names)), names
    by_topic = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    gnss = [c.schema_id for c in summary.channels.values() if c.topic in ("/gnss", "/trajectory/fix")]
    assert len(set(gnss)) == 1 and by_topic["/gnss"] == "foxglove.LocationFix"


def test_times_are_absolute_from_the_logs_epoch(fused):
    _summary, msgs = _read(fused[0])
    path, table = fused
    by_topic = {}
    for _s, channel, msg in msgs:
        by_topic.setdefault(channel.topic, []).append(msg)
    imu = by_topic["/imu"]
    assert imu[0].log_time == EPOCH_NS + round(table["t_s"][0] * 1e9)  # the raw topics moved by the epoch
    pose = json.loads(by_topic["/trajectory/pose"][3].data)
    assert pose["timestamp"]["sec"] * 10**9 + pose["timestamp"]["nsec"] == by_topic["/trajectory/pose"][3].log_time
    assert by_topic["/trajectory/pose"][0].log_time - EPOCH_NS == round(table["t_s"][0] * 1e9)
    gnss = json.loads(by_topic["/gnss"][0].data)  # the raw payloads as in the log (as a byte copy keeps them)
    assert gnss["timestamp"]["sec"] * 10**9 + gnss["timestamp"]["nsec"] == by_topic["/gnss"][0].log_time - EPOCH_NS


def test_frame_transform_is_n_to_b_at_the_poses(fused):
    _summary, msgs = _read(fused[0])
    tf = [(m.log_time, json.loads(m.data)) for _s, c, m in msgs if c.topic == "/trajectory/tf"]
    poses = [(m.log_time, json.loads(m.data)) for _s, c, m in msgs if c.topic == "/trajectory/pose"]
    assert len(tf) == len(poses) > 10
    for (t1, a), (t2, p) in zip(tf, poses):
        assert t1 == t2 and a["parent_frame_id"] == "n" and a["child_frame_id"] == "b"
        assert a["translation"] == p["pose"]["position"] and a["rotation"] == p["pose"]["orientation"]


def test_without_an_epoch_the_imu_clock_is_kept(tmp_path):
    table, raw, geometry = _survey(epoch=None)
    write_fused_mcap(tmp_path / "f.mcap", table, ORIGIN, raw=raw)
    _summary, msgs = _read(tmp_path / "f.mcap")
    assert min(m.log_time for _s, _c, m in msgs) == round(table["t_s"][0] * 1e9)


@pytest.mark.parametrize("text, ns", [(EPOCH, EPOCH_NS), ("2024-06-03T10:00:00+02:00", EPOCH_NS),
                                      ("2024-06-03T08:00:00.25Z", EPOCH_NS + 250_000_000)])
def test_epoch_parsing(text, ns):
    assert survey_epoch_ns({"survey": {"epoch_utc": text}}) == ns


@pytest.mark.parametrize("text", ["yesterday", "2024-06-03T08:00:00"])
def test_bad_epoch_is_a_one_line_error(text):
    with pytest.raises(SensorDataError, match="survey.epoch_utc"):
        survey_epoch_ns({"survey": {"epoch_utc": text}})
