"""trackfusion batch: two tiny surveys finish and a broken third is reported, on a Dask
LocalCluster and on the local process pool; exit code 3 when one failed."""

from __future__ import annotations

import json
import os
import shutil

import pytest
import yaml

from trackfusion.batch import EXIT_SOME_FAILED, BatchResult, run_batch
from trackfusion.cli import main
from trackfusion.simulation.scenarios import simulate_to_dir

TINY = ["motion.passes=1", "motion.segments=[{hold_s: 10}, {move_to_m: 50, speed_mps: 2, accel_mps2: 0.4}, {hold_s: 3}]"]


@pytest.fixture(scope="module")
def surveys(tmp_path_factory):
    """Two good pipelines (different seeds) and one whose log is cut short."""
    root = tmp_path_factory.mktemp("batch")
    paths = []
    for seed in (1, 2):
        d = root / f"s{seed}"
        simulate_to_dir("open-track-gnss", d, seed=seed, ideal=False, overrides=TINY)
        cfg = yaml.safe_load((d / "pipeline.yaml").read_text())
        cfg["outputs"].update(report=False, fused_mcap=False)  # keep the batch test about batching
        (d / "pipeline.yaml").write_text(yaml.safe_dump(cfg))
        paths.append(d / "pipeline.yaml")
    bad = root / "broken"
    shutil.copytree(root / "s1", bad)
    data = (bad / "log.mcap").read_bytes()
    (bad / "log.mcap").write_bytes(data[: len(data) // 3])
    (bad / "pipeline.yaml").rename(bad / "broken.yaml")
    return [str(p) for p in paths] + [str(bad / "broken.yaml")]


def _clean(paths):
    for p in paths:
        shutil.rmtree(p.rsplit("/", 1)[0] + "/out", ignore_errors=True)


@pytest.mark.slow
def test_dask_local_cluster_runs_two_and_reports_the_broken_third(surveys, tmp_path, capsys):
    _clean(surveys)
    code = main(["batch", *surveys, "--engine", "dask", "--workers", "2", "--json", str(tmp_path / "b.json")])
    assert code == EXIT_SOME_FAILED
    out = capsys.readouterr()
    summary = json.loads((tmp_path / "b.json").read_text())
    ok = [o["ok"] for o in summary["outcomes"]]
    assert ok == [True, True, False] and summary["engine"] == "dask"
    for o in summary["outcomes"][:2]:
        metrics = json.loads(open(o["out_dir"] + "/metrics.json").read())
        assert o["figures"]["vertical_mse_mm"] == metrics["relative_accuracy"]["vertical"]["mse_at_threshold_mm"]
    bad = summary["outcomes"][2]
    assert bad["error_kind"] == "input" and "truncated or corrupt" in bad["error"]
    assert bad["out_dir"] is None and not os.path.exists(surveys[2].rsplit("/", 1)[0] + "/out")
    table = out.out.splitlines()
    assert "2 of 3 surveys succeeded (dask engine" in table[-1] and "exit code 3" in table[-1]
    assert "FAILED (input)" in table[4] and "truncated or corrupt" in table[4]
    assert "[3/3]" in out.err  # progress as surveys finish


@pytest.mark.slow
def test_dask_address_reaches_a_running_scheduler(surveys, tmp_path, capsys):
    """--address: the same command on a scheduler started elsewhere (here a LocalCluster this
    test starts: the batch only gets its tcp:// address)."""
    from dask.distributed import LocalCluster
    _clean(surveys)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                      scheduler_kwargs={"dashboard": False}) as cluster:
        code = main(["batch", surveys[0], surveys[2], "--engine", "dask", "--address", cluster.scheduler_address,
                     "--json", str(tmp_path / "a.json")])
    assert code == EXIT_SOME_FAILED
    summary = json.loads((tmp_path / "a.json").read_text())
    assert [o["ok"] for o in summary["outcomes"]] == [True, False] and summary["engine"] == "dask"
    assert os.path.isfile(summary["outcomes"][0]["out_dir"] + "/trajectory.csv")
    assert f"dask scheduler {cluster.scheduler_address}" in capsys.readouterr().err


def test_local_pool_is_the_default_and_keeps_going(surveys, tmp_path):
    result = run_batch([surveys[2], surveys[0]], workers=2, out_root=str(tmp_path))
    assert result.engine == "local" and [o.ok for o in result.outcomes] == [False, True]
    assert result.exit_code == EXIT_SOME_FAILED and result.outcomes[1].figures["keyframes"] > 0
    assert (tmp_path / "pipeline" / "metrics.json").is_file() and not (tmp_path / "broken").exists()
    assert BatchResult("local", result.outcomes[1:], 1.0).exit_code == 0


def test_bad_arguments_exit_2(surveys, tmp_path, capsys):
    assert main(["batch", surveys[0], "--address", "tcp://127.0.0.1:1"]) == 2
    assert "--address: only with --engine dask" in capsys.readouterr().err
    assert main(["batch", surveys[0], surveys[1], "--out-root", str(tmp_path)]) == 2  # both named pipeline.yaml
    assert "two pipelines are named 'pipeline'" in capsys.readouterr().err
    assert main(["batch", surveys[0], "--workers", "0"]) == 2
