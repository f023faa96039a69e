"""``smoother.engine: dask``: the parts of each Gauss-Newton step solved on the workers of a Dask
cluster (fusion/partitioned.py ``PartWorker``, trackfusion/parallel.py ``run_step_dask``) give
the local processes' numbers and the one-batch solve (a LocalCluster of 2 worker processes, the
short survey of tests/test_partitioned.py in 3 parts); a misconfiguration is refused with one
line and exit code 2."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from trackfusion.fusion.smoother import smooth

from surveys import short_open_track_problem

pytest.importorskip("distributed")


def _smoother(problem, **update):
    return replace(problem, smoother=problem.smoother.model_copy(update=update))


@pytest.fixture(scope="module")
def survey_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("parts-dask")
    short_open_track_problem(d, seed=6)
    return d


@pytest.fixture(scope="module")
def problem(survey_dir):
    from trackfusion import pipeline as P
    pl = P.load_pipeline(survey_dir / "pipeline.yaml")
    return P.build_problem(pl, P._read(pl)[0], lambda _m: None)[0]


def test_dask_local_cluster_gives_the_local_parts_and_the_one_batch(problem):
    from trackfusion.parallel import close_dask_clients
    batch = smooth(problem)
    local = smooth(_smoother(problem, part_s=75.0, workers=2))
    try:
        dask = smooth(_smoother(problem, part_s=75.0, workers=2, engine="dask"))
    finally:
        close_dask_clients()
    for name in ("pos_n", "vel_n", "R_nb", "accel_bias_mps2", "gyro_bias_radps", "sigma_pos_n_m", "sigma_att_rad"):
        assert np.array_equal(getattr(dask, name), getattr(local, name)), name
    assert dask.iterations == local.iterations == batch.iterations
    assert np.abs(dask.pos_n - batch.pos_n).max() < 1e-6
    dR = np.einsum("kji,kjl->kil", dask.R_nb, batch.R_nb) - np.eye(3)
    assert np.abs(dR).max() < 1e-8


def _run_cli(survey_dir, tmp_path, smoother, capsys):
    import yaml
    from trackfusion import cli
    data = yaml.safe_load((survey_dir / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(smoother)
    data.setdefault("outputs", {}).update(fused_mcap=False, report=False)
    cfg = survey_dir / "dask-unreachable.yaml"  # (beside the log it names)
    cfg.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    code = cli.main(["run", str(cfg), "--out", str(out)])
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.startswith("trackfusion run: error")]
    return code, err, out


def test_unreachable_scheduler_exits_2_with_one_line(survey_dir, tmp_path, capsys, monkeypatch):
    import trackfusion.parallel
    monkeypatch.setattr(trackfusion.parallel, "SCHEDULER_TIMEOUT_S", 2.0)  # the run's 30 s, shortened
    code, err, out = _run_cli(survey_dir, tmp_path, {"part_s": 75.0, "engine": "dask",
                                                      "address": "tcp://127.0.0.1:9"}, capsys)
    assert code == 2
    assert len(err) == 1 and "smoother.address tcp://127.0.0.1:9: cannot reach the Dask scheduler" in err[0]
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("smoother, message", [
    ({"engine": "dask"}, "engine: dask needs part_s"),
    ({"address": "tcp://127.0.0.1:8786", "part_s": 75.0}, "address: only with engine: dask"),
])
def test_dask_misconfiguration_is_refused(survey_dir, smoother, message):
    from trackfusion.errors import ConfigError
    with pytest.raises(ConfigError, match=r"^p\.yaml: smoother: .*" + message):
        _parse(survey_dir, smoother)


def _parse(survey_dir, smoother):
    import yaml
    from trackfusion.pipeline import parse_pipeline
    data = yaml.safe_load((survey_dir / "pipeline.yaml").read_text())
    data.setdefault("smoother", {}).update(smoother)
    return parse_pipeline(data, "p.yaml", survey_dir)


def test_dask_engine_without_distributed_is_refused(survey_dir, monkeypatch):
    import importlib.util
    from trackfusion.errors import ConfigError
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else real(name, *a))
    with pytest.raises(ConfigError, match=r"engine: dask: Dask is not installed \(pip install 'trackfusion\[distributed\]'\)"):
        _parse(survey_dir, {"engine": "dask", "part_s": 75.0})
