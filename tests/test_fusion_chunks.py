"""Overlapping chunks (fusion/chunks.py): no seam.

One short noisy open-track survey (200 s, the wheel-path factor on, as simulated) is smoothed as one batch and in chunks of 60 s
with 30 s overlap (joins at 60 s and 180 s while moving at 3 and 2 m/s, and at 120 s during a
stop). At the joins:

* continuity: the second difference of the 100 Hz position (and the first difference of the
  attitude) across each join is no larger than anywhere else in its neighbourhood (a jump of
  1 um would show: the motion's own second difference is ~0.04 um at 100 Hz here);
* relative accuracy: the 5 m error differences (error at t + 5 m of travel minus error at t),
  lateral and vertical, of the chunked solution differ from the batch's no more across the
  joins than inside the chunks, and their RMS across the joins is that of the pairs within
  30 s of a join (a chunk of 60 s + 30 s sees less data than the 200 s batch: with the wheel
  path its lateral 5 m error is 0.13 mm near the joins against the batch's 0.007 mm, a heading
  error of about 30 urad on both sides of the join, not a seam);
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
    # the same noise model in the batch and the chunks (a 90 s first chunk estimates its own:
    # test_later_chunks_apply_the_first_chunks_noise)
    data["factors"]["noise_estimation"] = False
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
    # metrics.json and the report say how each run was smoothed
    sm = chunked.metrics["smoothing"]
    assert not sm["one_batch"] and (sm["chunk_length_s"], sm["overlap_s"]) == (CHUNK_S, OVERLAP_S)
    np.testing.assert_array_equal(sm["joins_s"], _joins(chunked.trajectory))
    assert batch.metrics["smoothing"] == {"one_batch": True, "chunk_s": None, "one_batch_up_to_s": None}
    minutes = ", ".join(f"{(t - sm['start_s']) / 60:.1f}" for t in sm["joins_s"])
    assert f"in 4 chunks of {CHUNK_S:.0f} s with {OVERLAP_S:.0f} s overlap" in (chunked.out_dir / "report.html").read_text()
    assert f"joined {minutes} min after the start" in (chunked.out_dir / "report.html").read_text()
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
    straddle, near = np.zeros(i.size, bool), np.zeros(i.size, bool)
    for t_join in _joins(chunked.trajectory):
        straddle |= (t[i] < t_join) & (t[j] > t_join)
        near |= np.abs(t[i] - t_join) < 30.0
    near &= ~straddle
    assert np.count_nonzero(straddle) > 100 and np.count_nonzero(~straddle) > 1000 and np.count_nonzero(near) > 1000
    diff = np.abs(d_c - d_b)
    assert np.all(np.max(diff[straddle], axis=0) <= 1.5 * np.max(diff[~straddle], axis=0) + 1e-5)
    rms = lambda x: np.sqrt(np.mean(x**2, axis=0))  # noqa: E731
    # measured 1.04 / 1.10 (lateral / vertical); a seam of 0.1 mm would make the lateral 1.25
    assert np.all(rms(d_c[straddle]) <= 1.2 * rms(d_c[near])), (rms(d_c[straddle]), rms(d_c[near]))


def test_chunked_sigmas_equal_the_batch_ones(runs):
    """The hand-over's past-only marginal gives the next chunk the information the batch has
    (within 25 %; counting the overlap twice would shrink them, dropping it would swell them)."""
    _, batch, chunked = runs
    for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m"):
        ratio = chunked.trajectory[c] / batch.trajectory[c]
        assert 0.8 < ratio.min() and ratio.max() < 1.25, (c, ratio.min(), ratio.max())


def test_chunked_run_keeps_the_wheel_path(runs):
    """A run in chunks keeps the wheel-path factor on the configured keyframes, across the joins."""
    d, batch, chunked = runs
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    assert data["factors"]["wheel_path"]["enabled"] is True and data["keyframes"]["spacing_s"] == 0.2
    assert "factors_left_out" not in chunked.metrics
    factors = chunked.metrics["factors"]
    assert factors["wheel_path"] > batch.metrics["factors"]["wheel_path"]  # (the overlaps count twice)
    # the pairs across the two moving joins (3 and 2 m/s, a 1.2 m wheelbase, 0.2 s keyframes):
    # front wheel point in the previous chunk, held; the rear in the next
    assert 2 <= factors["wheel_path_hand_over"] <= 2 * 3


def test_later_chunks_apply_the_first_chunks_noise(runs, monkeypatch):
    """With the noise estimated (the default), the first chunk estimates each group's noise and
    every later chunk applies the same factors (no estimate of its own); metrics.json says so.
    The odometer scale's drift rate is handed over with its variance."""
    import trackfusion.fusion.chunks as chunks_module
    from trackfusion.pipeline import build_problem
    from trackfusion.sensors.mcap_log import read_log

    d = runs[0]
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    assert data["factors"].get("noise_estimation", True) is not False
    pipeline = parse_pipeline(data, str(d / "pipeline.yaml"), d)
    problem, _ = build_problem(pipeline, read_log(d / "log.mcap"), lambda _m: None)
    joins, real = [], chunks_module.smooth

    def spy(sub, say, join=None, hand_over_t_s=None):
        joins.append(join)
        return real(sub, say, join=join, hand_over_t_s=hand_over_t_s)

    monkeypatch.setattr(chunks_module, "smooth", spy)
    res, _ = chunks_module.smooth_in_chunks(problem, CHUNK_S, OVERLAP_S, 5)
    first = res.noise_components
    assert first["estimated_on"].startswith("the first chunk") and len(joins) == 4 and joins[0] is None
    applied = {g: {c: v["applied_variance_factor"] for c, v in comps.items()} for g, comps in first["groups"].items()}
    assert applied["nhc"]["lateral"] != 1.0  # the datasheet's NHC is far from this trolley's (docs/noise_estimation.md)
    rate_prior_var = (problem.factors.odometer.scale_rate_sigma_ppm_per_h * 1e-6) ** 2
    for join in joins[1:]:
        assert join.noise_applied == applied
        # the odometer scale's drift rate handed over with its variance, which the data narrowed
        assert np.isfinite(join.rate) and 0.0 < join.rate_var < 0.9 * rate_prior_var
    # each chunk starts from the last one's rate: what they learn adds up (measured sigmas 2618 /
    # 1834 / 1710 ppm/h against the prior's 3000; a chunk learning it afresh: each about 2600)
    assert joins[2].rate_var < joins[1].rate_var and joins[3].rate_var < joins[2].rate_var


def test_the_removed_spacing_key_is_refused(runs):
    """``keyframes.spacing_without_wheel_path_s`` went with the chunks' leaving the wheel path out:
    refused with one line that says what replaced it."""
    from trackfusion.errors import ConfigError
    d = runs[0]
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data["keyframes"]["spacing_without_wheel_path_s"] = 0.1
    with pytest.raises(ConfigError, match=r"keyframes\.spacing_without_wheel_path_s: removed; runs in chunks keep "
                                          r"the wheel-path factor"):
        parse_pipeline(data, str(d / "pipeline.yaml"), d)


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
    data["factors"]["noise_estimation"] = False  # as _run
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


def test_the_imu_read_into_memory_is_freed_once_spilled(runs, tmp_path, monkeypatch):
    """A run in chunks holds its IMU in a mapped file (sensors/spill.py): while its chunks are
    smoothed, nothing keeps the arrays it read into memory alive (the run's own problem kept
    them through the whole smoothing before: 144 MB on a 20 km survey at 500 Hz)."""
    import gc
    import weakref

    import trackfusion.fusion.chunks as chunks_module
    from trackfusion.sensors import spill

    d = runs[0]
    read = []
    real_init = spill.SpilledImu.__init__

    def init(self, imu, folder=None):
        real_init(self, imu, folder)
        read.extend(weakref.ref(a) for a in (imu.t_s, imu.gyro_radps, imu.accel_mps2))
    monkeypatch.setattr(spill.SpilledImu, "__init__", init)
    alive = []
    real_smooth = chunks_module.smooth

    def smooth(*args, **kwargs):
        gc.collect()
        alive.append(sum(r() is not None for r in read))
        return real_smooth(*args, **kwargs)
    monkeypatch.setattr(chunks_module, "smooth", smooth)
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(chunk_s=CHUNK_S, overlap_s=OVERLAP_S)
    run(parse_pipeline(data, str(d / "pipeline.yaml"), d), tmp_path / "out")
    assert len(read) == 3 and len(alive) >= 3
    assert alive == [0] * len(alive)
