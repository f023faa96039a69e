"""Fuzzing the pipeline loader: any YAML text or tree, and any mutation of a valid pipeline,
gives a Pipeline or one ConfigError line naming the file, never another exception."""

from __future__ import annotations

import copy
import os

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackfusion.errors import ConfigError
from trackfusion.pipeline import load_pipeline, parse_pipeline

VALID = {
    "name": "t", "inputs": {"log": "log.mcap", "allow_truncated": False},
    "origin": {"lat_deg": 42.9, "lon_deg": 90.2, "h_m": 60.0},
    "trolley": {"wheelbase_m": 1.2, "lever_arm_imu_v_m": [0.0, -0.7, 0.25], "mounting_ypr_deg": [0, 0, 0]},
    "sensors": {"imu": {"grade": "navigation", "gyro_range_deg_per_s": 400.0},
                "odometer": {"clock_offset_s": 0.0}, "gnss": {"lever_arm_b_m": [0, 0, 1.5]}},
    "factors": {"nhc": {"sigma_mm_per_s": 1.0}, "gnss": {"huber_k": 2.0, "accept_float": True},
                "odometer": {"gross_error_window": 8}, "zupt": True},
    "keyframes": {"spacing_s": 0.1}, "static": {"window_s": 0.5},
    "smoother": {"max_iterations": 10}, "outputs": {"trajectory_rate_hz": 100.0, "fused_mcap": True},
}

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                    st.sampled_from(["navigation", "left", "rear", "log.mcap", "1e3", "0.1 m", "\x00", "-", ""]))
trees = st.recursive(scalars, lambda kids: st.one_of(st.lists(kids, max_size=4),
                                                     st.dictionaries(st.one_of(st.text(max_size=8), st.integers()),
                                                                     kids, max_size=4)), max_leaves=20)


def _paths(node, prefix=()):
    """Every key path of a nested dict/list tree."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _check(data, tmp):
    try:
        parse_pipeline(data, "p.yaml", tmp)
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("p.yaml")


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 150)), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(tree=trees)
def test_random_trees_only_raise_config_error(tmp_path, tree):
    _check(tree, tmp_path)


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 300)), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutations_of_a_valid_pipeline_only_raise_config_error(tmp_path, data):
    (tmp_path / "log.mcap").write_bytes(b"")
    doc = copy.deepcopy(VALID)
    for _ in range(data.draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        path = data.draw(st.sampled_from(paths))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        action = data.draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = data.draw(trees)
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[data.draw(st.text(max_size=10))] = data.draw(trees)
    _check(doc, tmp_path)


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 150)), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.one_of(st.text(max_size=200), st.binary(max_size=200).map(lambda b: b.decode("latin-1")),
                      st.builds(lambda d, cut: yaml.safe_dump(d)[:cut], st.just(VALID), st.integers(0, 800))))
def test_random_yaml_text_only_raises_config_error(tmp_path, text):
    (tmp_path / "log.mcap").write_bytes(b"")
    p = tmp_path / "p.yaml"
    p.write_text(text, encoding="utf-8", errors="surrogateescape")
    try:
        load_pipeline(p)
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(p) in str(exc)


def test_the_valid_pipeline_loads(tmp_path):
    (tmp_path / "log.mcap").write_bytes(b"")
    assert parse_pipeline(VALID, "p.yaml", tmp_path).config.sensors.imu.gyro_range_deg_per_s == 400.0
