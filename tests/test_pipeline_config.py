"""Bad pipeline configs: exit code 2, one line naming the field, nothing written."""

from __future__ import annotations

import copy

import pytest
import yaml

from trackfusion.cli import main
from trackfusion.outdir import MANIFEST

VALID = {
    "name": "t", "inputs": {"log": "log.mcap"},
    "trolley": {"wheelbase_m": 1.2, "lever_arm_imu_v_m": [0.0, -0.7, 0.25]},
    "sensors": {"imu": {"grade": "navigation"}},
    "factors": {"gnss": False},
}


def _case(path, value):
    d = copy.deepcopy(VALID)
    node = d
    for k in path[:-1]:
        node = node.setdefault(k, {})
    node[path[-1]] = value
    return d


@pytest.mark.parametrize("data, field", [
    (_case(["colour"], "red"), "colour"),
    (_case(["factors", "nhc"], {"sigmaa": 1.0}), "factors.nhc.sigmaa"),
    (_case(["keyframes", "spacing_s"], "0.1 m"), "keyframes.spacing_s"),
    (_case(["factors", "nhc"], {"sigma_mm_per_s": -1.0}), "factors.nhc.sigma_mm_per_s"),
    (_case(["sensors", "imu"], {"grade": "toy"}), "sensors.imu"),
    (_case(["inputs", "log"], "missing.mcap"), "inputs.log"),
    (_case(["factors", "total_stations"], True), "sensors.total_stations"),
    (_case(["factors", "gnss"], True), "sensors.gnss"),
    (_case(["smoother", "chunk_s"], 30), "smoother.chunk_s"),
    (_case(["smoother", "chunk_s"], "long"), "smoother.chunk_s"),
    (_case(["smoother", "overlap_s"], 3600), "smoother"),  # auto's hour
])
def test_bad_config_exit_2_names_field_and_writes_nothing(tmp_path, capsys, data, field):
    (tmp_path / "log.mcap").write_bytes(b"")
    cfg = tmp_path / "p.yaml"
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0] and "Traceback" not in err[0]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.mcap", "p.yaml"]


def test_existing_output_untouched_on_failure(tmp_path, capsys):
    """A log that is not MCAP fails at reading: the old results stay as they were."""
    (tmp_path / "log.mcap").write_bytes(b"not an mcap file")
    cfg = tmp_path / "p.yaml"
    cfg.write_text(yaml.safe_dump(VALID))
    out = tmp_path / "out"
    out.mkdir()
    (out / "trajectory.csv").write_text("old\n")
    (out / MANIFEST).write_text('{"files": ["trajectory.csv"]}')  # an earlier run's output (trackfusion/outdir.py)
    assert main(["run", str(cfg), "--out", str(out)]) == 2
    assert "log.mcap" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "trajectory.csv"]
    assert (out / "trajectory.csv").read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.mcap", "out", "p.yaml"]


def test_missing_and_invalid_pipeline_files(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    assert "nope.yaml" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("inputs: [unclosed\n")
    assert main(["run", str(bad)]) == 2
    assert "not valid YAML" in capsys.readouterr().err


def test_bool_shorthand_and_relative_paths(tmp_path):
    from trackfusion.pipeline import load_pipeline
    sub = tmp_path / "survey"
    sub.mkdir()
    (sub / "log.mcap").write_bytes(b"")
    (sub / "p.yaml").write_text(yaml.safe_dump(_case(["factors", "nhc"], False)))
    p = load_pipeline(sub / "p.yaml")
    assert p.config.factors.nhc.enabled is False and p.config.factors.nhc.sigma_mm_per_s == 1.0
    assert p.path(p.config.inputs.log) == sub.resolve() / "log.mcap"


def test_the_removed_two_stage_solve_key_is_refused_in_one_line(tmp_path):
    from trackfusion.errors import ConfigError
    from trackfusion.pipeline import parse_pipeline
    data = {"factors": {"total_stations": {"enabled": True, "solve": "two_stage"}}}
    with pytest.raises(ConfigError, match=r"^p\.yaml: factors\.total_stations\.solve: removed; the joint solve "
                                          r"replaced the two-stage one") as err:
        parse_pipeline(data, "p.yaml", tmp_path)
    assert "\n" not in str(err.value)
    # a section given as a bool (total_stations: false) is no removed key
    with pytest.raises(ConfigError, match=r"^p\.yaml: smoother\.slow_priors: removed"):
        parse_pipeline({"factors": {"total_stations": False}, "smoother": {"slow_priors": 1}}, "p.yaml", tmp_path)
