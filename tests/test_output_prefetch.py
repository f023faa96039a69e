"""The reference read ahead (trackfusion/output_prefetch.py) gives the metrics of the reference
read afterwards, and a reference that cannot be read raises the same error, when asked for."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.errors import SensorDataError
from trackfusion.evaluation.api import read_trajectory
from trackfusion.evaluation.reference import compare_with_reference
from trackfusion.output_prefetch import OutputPrefetch
from trackfusion.sensors.fileio import write_csv_table
from trackfusion.forked import can_fork

ORIGIN = {"lat_deg": 45.0, "lon_deg": 7.0, "h_m": 300.0}


def _reference(path, n=4000, t0=0.0):
    """A straight run at 2 m/s along e, sampled at 100 Hz (trajectory.csv / truth.csv columns)."""
    t = t0 + np.arange(n) * 0.01
    zeros, ones = np.zeros(n), np.ones(n)
    cols = {"t_s": t, "e_m": 2.0 * t, "n_m": 0.001 * np.sin(t), "u_m": 0.002 * np.cos(0.5 * t),
            "qw": ones, "qx": zeros, "qy": zeros, "qz": zeros, "ve_mps": 2.0 * ones,
            "vn_mps": 0.001 * np.cos(t), "vu_mps": -0.001 * np.sin(0.5 * t), "chainage_m": 2.0 * t}
    write_csv_table(path, cols, {c: "" for c in cols}, "n", ORIGIN, fmt="%.17g")
    return cols


def test_reference_read_ahead_gives_the_same_metrics(tmp_path):
    from trackfusion.forked import ForkedTasks, can_fork as forks_tasks
    ref = _reference(tmp_path / "truth.csv")
    rng = np.random.default_rng(3)
    est = {**ref, **{c: ref[c] + 1e-3 * rng.standard_normal(ref[c].size) for c in ("e_m", "n_m", "u_m")},
           **{f"sigma_{a}_m": np.full(ref["t_s"].size, 1e-3) for a in "enu"}}
    with ForkedTasks() as background:
        prefetch = OutputPrefetch(tmp_path / "truth.csv")
        prefetch.read_in_child(background)
        read = prefetch.reference()
    if forks_tasks():
        assert read is not None
    assert prefetch.reference() is None  # handed over once
    assert compare_with_reference(est, tmp_path / "truth.csv", ORIGIN, read) == \
        compare_with_reference(est, tmp_path / "truth.csv", ORIGIN)


def test_nothing_read_without_a_reference_or_a_call(tmp_path):
    assert OutputPrefetch(None).reference() is None
    _reference(tmp_path / "truth.csv", n=50)
    assert OutputPrefetch(tmp_path / "truth.csv").reference() is None  # never asked to read


@pytest.mark.skipif(not can_fork(2), reason="needs fork and two CPUs")
def test_reference_read_in_a_forked_child(tmp_path):
    from trackfusion.forked import ForkedTasks
    _reference(tmp_path / "truth.csv", n=500)
    direct, meta = read_trajectory(tmp_path / "truth.csv")
    with ForkedTasks() as background:
        prefetch = OutputPrefetch(tmp_path / "truth.csv")
        prefetch.read_in_child(background)
        assert prefetch._task is not None and prefetch._task.pid is not None  # in a child
        read, read_meta = prefetch.reference()
    assert read_meta == meta
    assert all(np.array_equal(getattr(read, f), getattr(direct, f)) for f in ("t_s", "pos_n_m", "vel_n_mps"))
    (tmp_path / "bad.csv").write_text("t_s,e_m\n1,2\n3,x\n")
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SensorDataError) as direct_error:
        read_trajectory(tmp_path / "bad.csv")
    with ForkedTasks() as background:
        prefetch = OutputPrefetch(tmp_path / "bad.csv")
        prefetch.read_in_child(background)
        with pytest.raises(SensorDataError) as later:
            prefetch.reference()
        background.tasks = []  # (its failure raised here, not again by the with block)
    assert str(later.value) == str(direct_error.value)
