"""Parallel segments (fusion/segments.py, ``smoother.workers``).

One short noisy open-track survey (215 s: static, 240 m out at 3 m/s, static, 140 m back) is
smoothed as one batch and as two segments (``overlap_s`` 30 s: the join at 107.5 s while moving at
3 m/s, each segment with 30 s of data beyond it, blended over 107.5 +- 7.5 s):

* the segmented trajectory equals the batch's within 3 sigma in position, and its 5 m error
  differences (what the relative accuracy is made of) within 0.05 mm RMS of the batch's;
* it is continuous at the join: each row-to-row step in the blend window is the segment's own
  step to within 1 um and 0.01 arcsec (a switch from one solution to the other would jump by
  their difference there, measured in metrics.json: tens of um here);
* the segments run in forked processes, and give the same bytes as when run one after the
  other in this process (determinism); a worker's error reaches the command line as exit 2 and
  one line, with no output and no process left.
"""

from __future__ import annotations

import json
import multiprocessing
import os

import numpy as np
import pytest
import yaml

from trackfusion import cli
from trackfusion.errors import FusionError
from trackfusion.fusion import segments
from trackfusion.pipeline import parse_pipeline, run
from trackfusion.rotations import R_from_quat, so3_log
from trackfusion.simulation.scenarios import simulate_to_dir

from surveys import SHORT_OPEN_TRACK as SHORT, errors_against_truth

OVERLAP_S = 30.0
FAST = {"fused_mcap": False, "report": False}


def _config(d, workers):
    data = yaml.safe_load((d / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(overlap_s=OVERLAP_S, workers=workers)
    data.setdefault("outputs", {}).update(FAST)
    # without the wheel path: with it the 5 m errors of this short run are a grade set by the GNSS
    # over each segment's length, not what the segmentation adds (docs/wheel_path.md)
    data["factors"]["wheel_path"] = False
    return data


def _run(d, workers, name):
    return run(parse_pipeline(_config(d, workers), str(d / "pipeline.yaml"), d), d / name)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("segments")
    simulate_to_dir("open-track-gnss", d, seed=6, overrides=SHORT)
    return d, _run(d, 1, "out-batch"), _run(d, 2, "out-segments")


@pytest.fixture(scope="module")
def here(runs):
    """The segmented run with its segments smoothed one after the other in this process (no
    fork), and what the stitching was given (the segments' results, joins, blend half-width)."""
    d = runs[0]
    given = []
    real_stitch, real_fork = segments.stitch, segments.can_fork

    def recording(parts, joins, h):
        given.append((parts, joins, h))
        return real_stitch(parts, joins, h)
    segments.stitch, segments.can_fork = recording, lambda n: False
    try:
        result = _run(d, 2, "out-here")
    finally:
        segments.stitch, segments.can_fork = real_stitch, real_fork
    return result, given[0]


def test_plan_cuts_equal_cores_with_overlap_on_the_keyframe_grid():
    t = np.arange(0.0, 1000.0, 0.01)
    joins, segs = segments.plan_segments(t, 3, 100.0, 0.1)
    assert np.allclose(joins, [1000.0 * 0.99999 / 3, 2000.0 * 0.99999 / 3], atol=0.01)
    assert [s.i0 for s in segs][0] == 0 and segs[-1].i1 == t.size - 1
    for s, seg in enumerate(segs[1:], 1):
        assert t[seg.i0] == pytest.approx(joins[s - 1] - 100.0, abs=0.1)  # the overlap before the core
        assert (t[seg.i0] / 0.1) == pytest.approx(round(t[seg.i0] / 0.1), abs=1e-6)  # on the keyframe grid
        assert seg.keep_t0 == pytest.approx(joins[s - 1] - 25.0)  # blend half-width: a quarter of the overlap
    assert t[segs[0].i1] == pytest.approx(joins[0] + 100.0, abs=0.01)
    assert segments.plan_segments(t, 3, 200.0, 0.1)[0].size == 1  # cores of 2 overlaps at least: 2 segments
    assert segments.plan_segments(t, 2, 300.0, 0.1)[1] == []  # too short to cut


def test_blend_weight_is_smooth_and_its_rate_is_its_derivative():
    t = np.linspace(90.0, 110.0, 2001)
    w, dw = segments.blend_weight(t, 100.0, 5.0)
    assert w[0] == 0.0 and w[-1] == 1.0 and np.all(np.diff(w) >= 0)
    assert w[np.searchsorted(t, 100.0)] == pytest.approx(0.5)
    assert np.allclose(np.gradient(w, t), dw, atol=2e-4)
    assert dw[0] == 0.0 and dw[-1] == 0.0


def _pos(tab):
    return np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")])


def test_segmented_run_has_one_join_and_the_batch_rows(runs):
    _, batch, seg = runs
    m = seg.metrics["segments"]
    assert m["count"] == 2 and m["workers"] == 2 and len(m["joins"]) == 1
    t = batch.trajectory["t_s"]
    assert m["joins"][0]["t_s"] == pytest.approx(0.5 * (t[0] + t[-1]), abs=0.01)  # two equal cores
    assert "segments" not in batch.metrics
    np.testing.assert_array_equal(seg.trajectory["t_s"], batch.trajectory["t_s"])
    # sums over the segments: each overlap's factors counted in both
    assert sum(seg.metrics["factors"].values()) > sum(batch.metrics["factors"].values())
    assert sum(sum(s["factors"].values()) for s in m["segments"]) == sum(seg.metrics["factors"].values())


def test_segmented_run_equals_the_batch_within_tolerance(runs):
    """Positions within 3 sigma of the batch's (and 10 mm); sigmas within 25 %; the 5 m error
    differences of the segmented run within 0.05 mm RMS of the batch's (their RMS is 0.1-0.2 mm;
    an overlap of 30 s is a tenth of the GNSS error's correlation time) and their RMS within 15 %."""
    d, batch, seg = runs
    a, b = batch.trajectory, seg.trajectory
    sigma = np.column_stack([a[c] for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m")])
    diff = _pos(b) - _pos(a)
    assert np.all(np.abs(diff) <= np.maximum(3.0 * sigma, 1e-4)) and np.abs(diff).max() < 0.010
    for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m"):
        assert np.allclose(b[c], a[c], rtol=0.25)
    ea, s = errors_against_truth(d, a)
    eb, _ = errors_against_truth(d, b)
    moving = np.gradient(s, a["t_s"]) > 0.5
    i = np.flatnonzero(moving)
    j = np.searchsorted(s, s[i] + 5.0)
    ok = (j < s.size) & moving[np.minimum(j, s.size - 1)]
    i, j = i[ok], j[ok]
    da, db = (ea[j] - ea[i])[:, 1:] * 1e3, (eb[j] - eb[i])[:, 1:] * 1e3  # lateral (n), vertical
    assert np.sqrt(np.mean((db - da) ** 2, axis=0)).max() < 0.05
    assert np.sqrt(np.mean(db ** 2, axis=0)) == pytest.approx(np.sqrt(np.mean(da ** 2, axis=0)), rel=0.15, abs=0.01)


def test_position_attitude_and_velocity_are_continuous_at_the_join(runs, here):
    d, _, seg = runs
    join = seg.metrics["segments"]["joins"][0]
    h = seg.metrics["segments"]["blend_half_width_s"]
    tab = seg.trajectory
    t = tab["t_s"]
    k = np.flatnonzero((t >= join["t_s"] - h - 1.0) & (t <= join["t_s"] + h + 1.0))
    # the segment solutions themselves, from the rows of the two segments inside the window
    given, joins, h = here[1]
    parts = [segments._levelled(p, c).rows for p, c in zip(given, segments.level_corrections(given, joins, h))]
    R = R_from_quat(np.column_stack([tab[c] for c in ("qw", "qx", "qy", "qz")]))
    p, v = _pos(tab), np.column_stack([tab[c] for c in ("ve_mps", "vn_mps", "vu_mps")])
    for rows in parts:
        idx = np.searchsorted(rows.t_s, t[k])
        own = rows.t_s[np.minimum(idx, rows.t_s.size - 1)] == t[k]
        kk, ii = k[own][:-1], idx[own][:-1]
        step_p = (p[kk + 1] - p[kk]) - (rows.pos_n[ii + 1] - rows.pos_n[ii])
        assert np.abs(step_p).max() < 1e-6  # m: 1 um
        step_v = (v[kk + 1] - v[kk]) - (rows.vel_n[ii + 1] - rows.vel_n[ii])
        assert np.abs(step_v).max() < 1e-6  # m/s
        dR_stitched = so3_log(np.swapaxes(R[kk], 1, 2) @ R[kk + 1])
        dR_own = so3_log(np.swapaxes(rows.R_nb[ii], 1, 2) @ rows.R_nb[ii + 1])
        assert np.abs(dR_stitched - dR_own).max() < np.radians(0.01 / 3600)
    # a hard switch would have jumped by the difference of the solutions at the join
    assert join["position_difference_mm"]["at_join"] > 1e-3 * 20


def test_forked_segments_give_the_bytes_of_segments_run_here(runs, here):
    """Determinism: the segments run one after the other in this process (no fork) give the
    same trajectory.csv, geometry.csv and metrics (but timings) as the forked run."""
    d, _, seg = runs
    here = here[0]
    assert (here.out_dir / "trajectory.csv").read_bytes() == (seg.out_dir / "trajectory.csv").read_bytes()
    assert here.metrics["segments"]["workers"] == 1

    def strip(m):
        m = {k: v for k, v in m.items() if k not in ("timings_s", "run_time_s")}
        seg_info = dict(m["segments"], workers=None)
        seg_info["segments"] = [{k: v for k, v in s.items() if k != "timings_s"} for s in seg_info["segments"]]
        return {**m, "segments": seg_info}
    assert strip(here.metrics) == strip(seg.metrics)
    assert (here.out_dir / "geometry.csv").read_bytes() == (seg.out_dir / "geometry.csv").read_bytes()


def test_an_error_in_a_worker_exits_2_with_no_output_and_no_process_left(runs, tmp_path, monkeypatch, capsys):
    d = runs[0]
    real = segments.smooth

    def failing(problem, *args, **kwargs):
        if problem.imu.t_s[0] > 1.0:  # the second segment's worker only
            raise FusionError("segment 2 cannot be smoothed (test)")
        return real(problem, *args, **kwargs)

    monkeypatch.setattr(segments, "smooth", failing)  # inherited by the forked workers
    cfg = d / "segments-failing.yaml"
    cfg.write_text(yaml.safe_dump(_config(d, 2)))
    out = tmp_path / "out"
    assert cli.main(["run", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("segment 2 cannot be smoothed (test)") and "Traceback" not in "".join(err)
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert multiprocessing.active_children() == []
    children = open(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read().split()
    assert not [c for c in children if "trackfusion-worker" in _cmdline(c) or _is_fork_of_us(c)]


def _cmdline(pid: str) -> str:
    try:
        return open(f"/proc/{pid}/comm").read()
    except OSError:
        return ""


def _is_fork_of_us(pid: str) -> bool:
    """A child running this interpreter (a forked worker has our command line)."""
    try:
        return open(f"/proc/{pid}/cmdline", "rb").read() == open(f"/proc/{os.getpid()}/cmdline", "rb").read()
    except OSError:
        return False


def test_total_station_runs_stay_in_one_batch():
    from trackfusion.fusion.problem import PrismReadings
    from dataclasses import replace
    t = np.arange(3)
    problem = _tiny_problem()
    assert segments.independent_segments(problem)
    prisms = PrismReadings(t, np.zeros((3, 3)), np.zeros((3, 3, 3)), np.zeros(3, int), ["A"], np.zeros((1, 3)),
                           np.zeros(3), np.ones((1, 8)))
    assert not segments.independent_segments(replace(problem, prisms=prisms))
    assert not segments.independent_segments(replace(problem, gnss=None))


def _tiny_problem():
    from trackfusion.fusion.preintegration import ImuNoise
    from trackfusion.fusion.problem import FusionProblem, GnssFixes, TrolleyFrame
    from trackfusion.geodesy import Origin
    from trackfusion.sensors.imu import IMU_GRADES
    from trackfusion.sensors.types import ImuData
    t = np.arange(3.0)
    return FusionProblem(ImuData(t, np.zeros((3, 3)), np.zeros((3, 3))), ImuNoise.from_spec(IMU_GRADES["navigation"]),
                         0.01, Origin(45.0, 7.0, 0.0), TrolleyFrame.from_angles((0, 0, 0), (0, 0, 0), 1.2), [],
                         gnss=GnssFixes(t, np.zeros((3, 3)), np.zeros((3, 3, 3)), np.full(3, 4)))


def test_default_is_the_one_batch_solve_on_any_number_of_cpus(runs, monkeypatch):
    """With ``smoother.workers`` unset the run is the one-batch run, byte for byte, whatever the
    CPUs: the same log gives the same trajectory on any computer."""
    d, batch, _ = runs
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})  # a 4-CPU machine
    data = _config(d, 1)
    del data["smoother"]["workers"]
    res = run(parse_pipeline(data, str(d / "pipeline.yaml"), d), d / "out-default")
    assert "segments" not in res.metrics
    assert (res.out_dir / "trajectory.csv").read_bytes() == (batch.out_dir / "trajectory.csv").read_bytes()
