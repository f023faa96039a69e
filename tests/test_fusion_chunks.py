"""Overlapping chunks (fusion/chunks.py): no seam.

One short noisy open-track survey (200 s) is smoothed as one batch and in chunks of 60 s
with 30 s overlap (joins at 60 s and 180 s while moving at 3 and 2 m/s, and at 120 s during a
stop). At the joins:

* continuity: the second difference of the 100 Hz position (and the first difference of the
  attitude) across each join is no larger than anywhere else in its neighbourhood (a jump of
  1 um would show: the motion's own second difference is ~0.04 um at 100 Hz here);
* relative accuracy: the 5 m error differences (error at t + 5 m of travel minus error at t),
  lateral and vertical, of the chunked solution differ from the batch's no more across the
  joins than inside the chunks, and their RMS across the joins is the batch's;
* the sigmas are the batch's (a 200 s run is too short for the consistency statistic: it holds
  less than one draw of the 300 s correlated GNSS error).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from trackfusion.fusion.chunks import join_times
from trackfusion.pipeline import parse_pipeline, run
from trackfusion.rotations import R_from_quat, so3_log
from trackfusion.simulation.scenarios import simulate_to_dir

from surveys import SHORT_OPEN_TRACK as SHORT, errors_against_truth

CHUNK_S, OVERLAP_S = 60.0, 30.0


def _run(d, chunk_s):
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    # workers 1: the batch is one batch (with this overlap it would be cut into parallel segments)
    data.setdefault("smoother", {}).update(chunk_s=chunk_s, overlap_s=OVERLAP_S, workers=1)
    data["factors"]["wheel_path"] = False  # chunked runs leave it out (test_chunked_run_leaves_the_wheel_path_out)
    data["keyframes"]["spacing_s"] = data["keyframes"]["spacing_without_wheel_path_s"]  # and so run on these
    data["factors"]["noise_estimation"] = False  # chunks keep the configured noise (docs/noise_estimation.md)
    return run(parse_pipeline(data, str(d / "pipeline.yaml"), d), d / f"out-{chunk_s}")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("chunks")
    simulate_to_dir("open-track-gnss", d, seed=6, overrides=SHORT)
    return d, _run(d, None), _run(d, CHUNK_S)


def _joins(tab):
    return join_times(tab["t_s"][0], tab["t_s"][-1], CHUNK_S, OVERLAP_S)


def test_chunked_run_has_the_joins_and_the_same_rows(runs):
    _, batch, chunked = runs
    assert _joins(chunked.trajectory).size == 3
    assert chunked.metrics["factors"]["hand_over"] == 2 * 3
    np.testing.assert_array_equal(batch.trajectory["t_s"], chunked.trajectory["t_s"])


def test_position_and_attitude_are_continuous_at_the_joins(runs):
    _, _, chunked = runs
    tab = chunked.trajectory
    p = np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")])
    R = R_from_quat(np.column_stack([tab[c] for c in ("qw", "qx", "qy", "qz")]))
    acc = np.linalg.norm(np.diff(p, 2, axis=0), axis=1)          # (N-2,) centred on samples 1..N-2
    turn = np.linalg.norm(so3_log(np.swapaxes(R[:-1], -1, -2) @ R[1:]), axis=1)
    for t_join in _joins(tab):
        j = int(np.argmin(np.abs(tab["t_s"] - t_join)))
        near = slice(j - 300, j + 300)
        seam = slice(j - 3, j + 2)
        assert np.max(acc[seam]) <= np.max(acc[near][np.r_[:290, 310:600]]) + 1e-7, t_join
        assert np.max(turn[seam]) <= np.max(turn[near][np.r_[:290, 310:600]]) + 1e-8, t_join


def test_relative_accuracy_across_joins_equals_inside(runs):
    """The track runs east: n is lateral, u vertical. The chunked solution differs from the batch
    one (each chunk sees less data) by as much inside the chunks as across the joins: a seam
    would add to the pairs straddling a join."""
    d, batch, chunked = runs
    err_c, s = errors_against_truth(d, chunked.trajectory)
    err_b, _ = errors_against_truth(d, batch.trajectory)
    t = chunked.trajectory["t_s"]
    ahead = np.searchsorted(s, s + 5.0)  # forward runs: first sample 5 m further
    ok = (ahead < s.size) & (np.gradient(s, t) > 0.5)
    i = np.flatnonzero(ok)
    i = i[np.abs(s[ahead[i]] - s[i] - 5.0) < 0.05]
    j = ahead[i]
    d_c, d_b = (err_c[j] - err_c[i])[:, 1:], (err_b[j] - err_b[i])[:, 1:]  # lateral, vertical [m]
    straddle = np.zeros(i.size, bool)
    for t_join in _joins(chunked.trajectory):
        straddle |= (t[i] < t_join) & (t[j] > t_join)
    assert np.count_nonzero(straddle) > 100 and np.count_nonzero(~straddle) > 1000
    diff = np.abs(d_c - d_b)
    assert np.all(np.max(diff[straddle], axis=0) <= 1.5 * np.max(diff[~straddle], axis=0) + 1e-5)
    rms = lambda x: np.sqrt(np.mean(x**2, axis=0))  # noqa: E731
    assert np.all(rms(d_c[straddle]) <= 1.5 * rms(d_b[straddle]) + 2e-5)


def test_chunked_sigmas_equal_the_batch_ones(runs):
    """The hand-over's past-only marginal gives the next chunk the information the batch has
    (within 25 %; counting the overlap twice would shrink them, dropping it would swell them)."""
    _, batch, chunked = runs
    for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m"):
        ratio = chunked.trajectory[c] / batch.trajectory[c]
        assert 0.8 < ratio.min() and ratio.max() < 1.25, (c, ratio.min(), ratio.max())


def test_chunked_run_leaves_the_wheel_path_out(runs, tmp_path):
    """As simulated (wheel path on), a run in chunks is smoothed without it and says so."""
    d = runs[0]
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    assert data["factors"]["wheel_path"]["enabled"] is True
    data.setdefault("smoother", {}).update(chunk_s=CHUNK_S, overlap_s=OVERLAP_S, workers=1)
    data.setdefault("outputs", {}).update(fused_mcap=False, report=False)
    said = []
    res = run(parse_pipeline(data, str(d / "pipeline.yaml"), d), tmp_path / "out", progress=said.append)
    assert "wheel_path" not in res.metrics["factors"]
    assert "hand-over" in res.metrics["factors_left_out"]["wheel_path"]
    assert any(m.startswith("factors.wheel_path left out") and "keyframes every 0.1 s" in m for m in said)
    assert data["keyframes"]["spacing_s"] == 0.2 and res.metrics["keyframes"] == runs[2].metrics["keyframes"]
    np.testing.assert_array_equal(res.trajectory["e_m"], runs[2].trajectory["e_m"])


# --- long runs stream their output (fusion/output_rate.py, sensors/fileio.py CsvTableWriter) ---

def test_streamed_trajectory_csv_is_the_whole_run_table(runs):
    """The chunked run writes trajectory.csv chunk by chunk; its bytes are those of the one-piece
    writer given the table of the whole chunked trajectory (chunks.py without ``on_dense``)."""
    from trackfusion.fusion.chunks import smooth_in_chunks
    from trackfusion.pipeline import TRAJECTORY_UNITS, _decimation, build_problem, chainage_along, trajectory_table
    from trackfusion.sensors.fileio import write_csv_table
    from trackfusion.sensors.mcap_log import read_log

    d, _, chunked = runs
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data["factors"]["wheel_path"] = False
    pipeline = parse_pipeline(data, str(d / "pipeline.yaml"), d)
    problem, _ = build_problem(pipeline, read_log(d / "log.mcap"), lambda _m: None)
    every = _decimation(1.0 / np.median(np.diff(problem.imu.t_s)), pipeline.config.outputs.trajectory_rate_hz)
    res, dense = smooth_in_chunks(problem, CHUNK_S, OVERLAP_S, every)
    table = trajectory_table(dense, res, chainage_along(dense, res, problem.odometer, problem.trolley.axis_b), 1)
    write_csv_table(d / "whole.csv", table, TRAJECTORY_UNITS, "n", problem.origin.to_dict(), fmt="%.12g")
    assert (d / "whole.csv").read_bytes() == (chunked.out_dir / "trajectory.csv").read_bytes()
    np.testing.assert_array_equal(res.t_s, chunked.smoother.t_s)
    assert sorted(chunked.files) == ["fused.mcap", "geometry.csv", "geometry.json", "metrics.json", "report.html",
                                     "trajectory.csv", "trajectory.json"]


def test_a_chunked_run_failing_late_leaves_no_output(runs, tmp_path, monkeypatch):
    """A failure after the first chunks' rows are written: no out/, no staging folder left."""
    import trackfusion.fusion.chunks as chunks_module

    d = runs[0]
    calls = []
    real = chunks_module.smooth

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("chunk 3 fails")
        return real(*args, **kwargs)

    monkeypatch.setattr(chunks_module, "smooth", failing)
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(chunk_s=CHUNK_S, overlap_s=OVERLAP_S)
    with pytest.raises(RuntimeError, match="chunk 3"):
        run(parse_pipeline(data, str(d / "pipeline.yaml"), d), tmp_path / "out")
    assert len(calls) == 3
    assert list(tmp_path.iterdir()) == []
