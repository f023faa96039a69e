"""The exact partitioned Gauss-Newton step (fusion/partitioned.py, ``smoother.part_s``) gives the
one-batch solve: on a short noisy open-track survey (215 s, GNSS, odometer, wheel path) with
1, 2 and 3 parts, with a part boundary inside a static period and inside a GNSS outage, and on
a short bridge survey with two total stations with the boundary on the stations' hand-over.
Measured: positions within 2e-12 m, attitudes within 1e-12 rad, marginal sigmas within 4e-6
(relative); the targets are 1 um, 1e-8 rad and 1 %."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from trackfusion.fusion import partitioned as PT
from trackfusion.fusion.smoother import smooth

from surveys import short_open_track_problem

POS_TOL_M = 1e-9
ATT_TOL_RAD = 1e-10
SIGMA_REL_TOL = 1e-5


def _with_parts(problem, part_s):
    return replace(problem, smoother=problem.smoother.model_copy(update={"part_s": part_s}))


def _assert_same(a, b):
    assert np.array_equal(a.t_s, b.t_s)
    assert np.abs(a.pos_n - b.pos_n).max() < POS_TOL_M
    assert np.abs(a.vel_n - b.vel_n).max() < POS_TOL_M
    dR = np.einsum("kji,kjl->kil", a.R_nb, b.R_nb) - np.eye(3)
    assert np.abs(dR).max() < ATT_TOL_RAD
    assert np.abs(a.accel_bias_mps2 - b.accel_bias_mps2).max() < 1e-10
    assert np.abs(a.gyro_bias_radps - b.gyro_bias_radps).max() < 1e-12
    assert a.iterations == b.iterations and a.final_cost == pytest.approx(b.final_cost, rel=1e-9)
    assert [r["index"] for r in a.rejected_gnss] == [r["index"] for r in b.rejected_gnss]
    assert np.array_equal(a.sigma_t_s, b.sigma_t_s)
    assert np.abs(b.sigma_pos_n_m / a.sigma_pos_n_m - 1.0).max() < SIGMA_REL_TOL
    assert np.abs(b.sigma_att_rad / a.sigma_att_rad - 1.0).max() < SIGMA_REL_TOL


@pytest.fixture(scope="module")
def survey_dir(tmp_path_factory):
    """The short survey simulated once (its problem: :func:`survey`; runs of it: the CLI tests)."""
    d = tmp_path_factory.mktemp("parts")
    short_open_track_problem(d, seed=6)
    return d


@pytest.fixture(scope="module")
def survey(survey_dir):
    from trackfusion import pipeline as P
    pl = P.load_pipeline(survey_dir / "pipeline.yaml")
    problem = P.build_problem(pl, P._read(pl)[0], lambda _m: None)[0]
    return problem, smooth(problem)


def test_cut_times_every_part_s_from_the_start():
    assert np.allclose(PT.cut_times(0.0, 215.0, 100.0), [100.0, 200.0])
    assert np.allclose(PT.cut_times(0.0, 205.0, 100.0), [100.0])  # a last part under part_s / 10 joins the one before
    assert PT.cut_times(0.0, 215.0, 300.0).size == 0


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_parts_give_the_one_batch_solve(survey, parts):
    problem, batch = survey
    duration = batch.t_s[-1] - batch.t_s[0]
    _assert_same(batch, smooth(_with_parts(problem, duration / parts + 1e-3)))


def test_separator_holds_the_cut_keyframes_and_the_states_parts_share(survey):
    """With a cut at 100 s: the keyframe at the cut (its IMU factor to the next is the next
    part's neighbour), the bias segment running across it; no keyframe far from the cut."""
    problem, batch = survey
    captured = []
    real = PT.PartitionedSolver.solve

    def recording(self, gfg):
        out = real(self, gfg)
        captured.append(self.layout)
        return out
    PT.PartitionedSolver.solve = recording
    try:
        smooth(_with_parts(problem, 100.0))
    finally:
        PT.PartitionedSolver.solve = real
    sep = set(captured[-1].separator.tolist())
    k_cut = int(np.searchsorted(batch.t_s, batch.t_s[0] + 100.0))
    assert X(k_cut) in sep and V(k_cut) in sep
    assert not any(X(k) in sep for k in range(5, k_cut - 50))  # the wheel path reaches back a few keyframes only
    m = int((batch.t_s[k_cut] - batch.t_s[0]) // problem.keyframes.bias_segment_s)
    assert B(m) in sep
    assert len(sep) < 200


def _cut_at(t_s, t_cut):
    return t_cut - t_s[0]


def test_boundary_inside_a_static_period(survey):
    problem, batch = survey
    a, b = [iv for iv in problem.static_intervals_s if iv[0] > 1.0][0]
    _assert_same(batch, smooth(_with_parts(problem, _cut_at(batch.t_s, 0.5 * (a + b)))))


def test_boundary_inside_a_gnss_outage(survey):
    problem, _ = survey
    g = problem.gnss
    keep = (g.t_s < 60.0) | (g.t_s > 90.0)  # a 30 s outage while moving
    cut = replace(g, t_s=g.t_s[keep], pos_n=g.pos_n[keep], cov_n=g.cov_n[keep], fix_quality=g.fix_quality[keep])
    outage = replace(problem, gnss=cut)
    batch = smooth(outage)
    _assert_same(batch, smooth(_with_parts(outage, _cut_at(batch.t_s, 75.0))))


@pytest.fixture(scope="module")
def bridge(tmp_path_factory):
    """The short bridge survey (tests/test_total_station_run.py) as a problem, and its batch."""
    from trackfusion import pipeline as P
    from trackfusion.simulation.scenarios import simulate_to_dir
    sys.path.insert(0, str(Path(__file__).parent))
    from test_total_station_run import SHORT
    d = tmp_path_factory.mktemp("bridge-parts")
    simulate_to_dir("bridge-total-station", d, seed=3, overrides=SHORT)
    pl = P.load_pipeline(d / "pipeline.yaml")
    log, _ = P._read(pl)
    problem, _ = P._prepare_total_stations(pl, log, P.build_problem(pl, log, lambda _m: None)[0], lambda _m: None)
    return problem, smooth(problem)


@pytest.mark.slow
def test_boundary_on_a_total_station_hand_over(bridge):
    """Short bridge survey: the cut between the last reading of the first station and the first
    of the next; the station corrections and their joint covariance, and the prism gating's
    rejections, are the batch's."""
    problem, batch = bridge
    pr = problem.prisms
    switch = int(np.flatnonzero(np.diff(pr.station) != 0)[0])
    parts = smooth(_with_parts(problem, _cut_at(batch.t_s, 0.5 * (pr.t_s[switch] + pr.t_s[switch + 1]))))
    _assert_same(batch, parts)
    assert np.abs(batch.station_states - parts.station_states).max() < 1e-8
    # the batch's is GTSAM's joint down the whole tree: with the wheel path's wider cliques it
    # differs from the parts' by 2.3e-4 of the largest element (the clock drift's variance;
    # 1.2e-4 of its sigma), 1.3e-5 without the factor
    assert np.abs(parts.station_cov - batch.station_cov).max() < 1e-3 * np.abs(batch.station_cov).max()
    assert parts.rejected_prism == batch.rejected_prism and batch.rejected_prism


@pytest.mark.slow
def test_station_covariance_from_the_sigma_parts_separator(bridge, monkeypatch):
    """A run long enough for its sigma columns in parts (here cut in thirds): the stations'
    joint covariance comes from the parts' separator system; it equals the exact joint marginal
    of the whole last linearisation (every other variable eliminated by QR first), an independent
    route, and the stations' sigmas are the batch tree's. Measured: 8e-14 of the largest element
    (rounding), sigmas within 8e-11 of the batch tree's."""
    from gtsam.symbol_shorthand import T
    from trackfusion.fusion import smoother as SM
    problem, batch = bridge
    seen = []
    real = SM._sigma_covariances

    def recording(problem_, sol, gfg, partition, kf, keys, *rest):
        out = real(problem_, sol, gfg, partition, kf, keys, *rest)
        seen.append((sol.gfg, SM._partition(problem_, kf, SM.MARGINAL_PART_S), out[1]))
        return out
    monkeypatch.setattr(SM, "_sigma_covariances", recording)
    monkeypatch.setattr(SM, "MARGINAL_PART_S", (batch.t_s[-1] - batch.t_s[0]) / 3 + 0.5)
    result = SM.smooth(problem)
    (gfg, parts, from_separator), = seen
    assert parts.count == 3 and from_separator is not None and np.array_equal(result.station_cov, from_separator)
    for workers in (1, 2, 3):  # the same bits in any number of processes
        assert np.array_equal(PT.part_marginal_covariances(parts, gfg, [], workers, [T(0), T(1)])[1], from_separator)
    exact = PT.joint_marginal_covariance(gfg, [T(0), T(1)])
    scale = np.abs(exact).max()
    assert np.abs(result.station_cov - exact).max() < 1e-10 * scale
    assert np.allclose(np.sqrt(np.diag(result.station_cov)), np.sqrt(np.diag(batch.station_cov)), rtol=1e-8, atol=0)


def test_workers_give_the_numbers_of_one_process(survey):
    """3 parts in 1, 2 and 3 local processes (trackfusion/parallel.py): the same bits."""
    problem, _ = survey
    three = _with_parts(problem, 75.0)
    here = smooth(three)
    for workers in (2, 3):
        other = smooth(replace(three, smoother=three.smoother.model_copy(update={"workers": workers})))
        for name in ("pos_n", "vel_n", "R_nb", "accel_bias_mps2", "sigma_pos_n_m", "sigma_att_rad"):
            assert np.array_equal(getattr(here, name), getattr(other, name)), (workers, name)


def test_part_queue_hands_each_part_to_one_process_once():
    """PartQueue in run_step's processes (2 and 3: this one and forked children): every part is
    taken exactly once, and while one process is held on part 0 (until the last part is taken)
    the others take every other part, not a contiguous share each."""
    import multiprocessing

    from trackfusion.parallel import PartQueue, groups_of, run_step

    n_parts = 6
    for workers in (2, 3):
        queue, last_taken = PartQueue(n_parts), multiprocessing.get_context("fork").Event()

        def take(_group, _given):
            taken = []
            for p in queue:
                if p == 0:
                    assert last_taken.wait(30.0)
                if p == n_parts - 1:
                    last_taken.set()
                taken.append(p)
            return taken

        _, _, done = run_step(groups_of(n_parts, workers), lambda g: None, lambda r: None, take)
        assert sorted(p for taken in done for p in taken) == list(range(n_parts))
        assert [0] in done, (workers, done)


def test_a_dead_worker_ends_the_solve_naming_its_part(survey, monkeypatch):
    import os
    import signal
    from trackfusion.parallel import PartWorkerDied
    problem, batch = survey
    parent, last = os.getpid(), X(batch.t_s.size - 1)
    real = PT._reduce

    def dying(graph, interior, *ordering):  # the process of the last part is killed
        if os.getpid() != parent and last in interior:
            os.kill(os.getpid(), signal.SIGKILL)
        return real(graph, interior, *ordering)
    monkeypatch.setattr(PT, "_reduce", dying)
    three = _with_parts(problem, 75.0)
    with pytest.raises(PartWorkerDied, match=r"^the smoother's worker process of part 3 died \(killed by signal 9\)$"):
        smooth(replace(three, smoother=three.smoother.model_copy(update={"workers": 3})))
    import multiprocessing
    assert not multiprocessing.active_children()


def test_a_dead_worker_exits_1_with_one_line_and_nothing_written(survey_dir, tmp_path, monkeypatch, capsys):
    import os
    import signal
    import yaml
    from trackfusion import cli
    data = yaml.safe_load((survey_dir / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(part_s=75.0, workers=3)
    data.setdefault("outputs", {}).update(fused_mcap=False, report=False)
    cfg = survey_dir / "parts-dying.yaml"
    cfg.write_text(yaml.safe_dump(data))
    parent = os.getpid()
    real = PT._reduce

    def dying(graph, interior, *ordering):
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return real(graph, interior, *ordering)
    monkeypatch.setattr(PT, "_reduce", dying)
    out = tmp_path / "out"
    assert cli.main(["run", str(cfg), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()  # the progress lines, then the error's one line
    assert err[-1] == "trackfusion run: error: the smoother's worker process of part 2 died (killed by signal 9)"
    assert sum(line.startswith("trackfusion run: error") for line in err) == 1
    assert not out.exists() or not any(out.iterdir())



def test_ctrl_c_during_a_step_leaves_no_process_behind(survey, monkeypatch):
    """SIGINT to the run while its part workers are busy: KeyboardInterrupt here, every worker
    process gone."""
    import multiprocessing
    import os
    import signal
    import threading
    import time
    problem, _ = survey
    parent = os.getpid()
    real = PT._reduce
    started = multiprocessing.get_context("fork").Event()

    def slow(graph, interior, *ordering):
        if os.getpid() != parent:
            started.set()
            time.sleep(60.0)
        return real(graph, interior, *ordering)
    monkeypatch.setattr(PT, "_reduce", slow)

    def interrupt():
        started.wait(30.0)
        os.kill(parent, signal.SIGINT)
    # Python's own Ctrl-C handler, whatever this process inherited (pytest-xdist's workers and
    # background jobs of a shell start with SIGINT ignored)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    threading.Thread(target=interrupt, daemon=True).start()
    three = _with_parts(problem, 75.0)
    tic = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            smooth(replace(three, smoother=three.smoother.model_copy(update={"workers": 3})))
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.perf_counter() - tic < 30.0
    assert not multiprocessing.active_children()


def test_default_run_is_the_one_batch_on_any_number_of_cpus(survey_dir, tmp_path, monkeypatch):
    """``trackfusion run`` with the smoother's defaults, with ``smoother.workers: 1`` and with 3
    parts in 2 workers: the same trajectory.csv, whatever the CPUs (a 4-CPU affinity here), so
    the same log gives the same trajectory on any computer."""
    import os
    import yaml
    from trackfusion.pipeline import parse_pipeline, run
    from trackfusion.sensors.fileio import read_csv_table
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    outs = {}
    for name, smoother in (("default", {}), ("one-batch", {"workers": 1}), ("parts", {"part_s": 75.0, "workers": 2})):
        data = yaml.safe_load((survey_dir / "pipeline.yaml").read_text())
        data.setdefault("smoother", {}).update(smoother)
        data.setdefault("outputs", {}).update(fused_mcap=False, report=False)
        outs[name] = run(parse_pipeline(data, str(survey_dir / "pipeline.yaml"), survey_dir), tmp_path / name).out_dir
    default = (outs["default"] / "trajectory.csv").read_bytes()
    assert (outs["one-batch"] / "trajectory.csv").read_bytes() == default
    a, b = (read_csv_table(outs[k] / "trajectory.csv") for k in ("default", "parts"))
    assert max(np.abs(a[c] - b[c]).max() for c in ("e_m", "n_m", "u_m")) < 1e-8  # %.12g: 1e-9 m a digit here


def test_removed_key_is_refused_with_what_replaced_it(tmp_path):
    from trackfusion.errors import ConfigError
    from trackfusion.pipeline import parse_pipeline
    with pytest.raises(ConfigError, match=r"^p\.yaml: smoother\.slow_priors: removed; .*smoother\.part_s"):
        parse_pipeline({"smoother": {"slow_priors": True}}, "p.yaml", tmp_path)
