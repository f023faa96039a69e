"""Every pipeline in configs/ is valid and belongs to a built-in scenario."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from trackfusion.pipeline import parse_pipeline
from trackfusion.simulation.config import SCENARIO_DIR

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").glob("*.yaml"))


def test_one_config_per_scenario():
    assert {p.stem for p in CONFIGS} == {p.stem for p in SCENARIO_DIR.glob("*.yaml")}


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_config_is_valid(path, tmp_path):
    data = yaml.safe_load(path.read_text())
    assert data["inputs"]["log"] == f"../sim/{path.stem}/log.mcap"
    (tmp_path / "log.mcap").write_bytes(b"")
    (tmp_path / "truth.csv").write_text("t_s\n")
    data["inputs"] = {"log": "log.mcap", "reference": "truth.csv"}
    pipeline = parse_pipeline(data, str(path), tmp_path)
    assert pipeline.config.name == path.stem
    assert pipeline.config.factors.total_stations.enabled == (path.stem == "bridge-total-station")
