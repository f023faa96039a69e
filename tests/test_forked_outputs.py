"""Outputs written in forked children (trackfusion/forked.py, report/outputs.py, CsvTableWriter
``background``): the same bytes as written in turn, errors of a child raised in the parent, and a
failed child leaves no output at all (exit code 2, one line)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from trackfusion import forked
from trackfusion.cli import main
from trackfusion.errors import SensorDataError
from trackfusion.forked import ForkedTaskError, ForkedTasks
from trackfusion.sensors.fileio import CsvTableWriter, write_csv_table
from trackfusion.simulation.scenarios import simulate_to_dir

pytestmark = pytest.mark.skipif(not forked.can_fork(), reason="needs fork and 2 CPUs")

TINY = ["motion.passes=1",
        "motion.segments=[{hold_s: 20}, {move_to_m: 110, speed_mps: 3, accel_mps2: 0.5}, {hold_s: 12}]"]
ORIGIN = {"lat_deg": 42.86, "lon_deg": 90.17, "h_m": 60.0}


def _double(x):
    return 2 * x, os.getpid()


def _fail():
    raise SensorDataError("some.csv: record 7: bad value")


def _die():
    os._exit(7)


def test_a_task_runs_in_another_process_and_hands_back_its_result():
    with ForkedTasks() as tasks:
        task = tasks.submit("doubling", _double, np.arange(3.0))
    value, pid = task.result()
    assert pid != os.getpid() and np.array_equal(value, [0.0, 2.0, 4.0])


def test_fork_map_gives_the_values_in_turn_and_raises_a_childs_error():
    """The first item here, the others in forked children: the same list as in turn (the pids
    say where each ran); a child's exception is raised as it was."""
    items = [np.arange(3.0), np.arange(4.0), np.arange(5.0)]
    mapped = forked.fork_map("doubling", _double, items)
    assert [p == os.getpid() for _, p in mapped] == [True, False, False]
    assert all(np.array_equal(v, 2 * x) for (v, _), x in zip(mapped, items))
    with pytest.raises(SensorDataError, match=r"^some\.csv: record 7: bad value$"):
        forked.fork_map("failing", lambda fail: _fail() if fail else 0, [False, True])


def _niceness():
    return os.getpid(), os.nice(0)


def test_an_idle_task_runs_at_the_lowest_priority_in_its_child_only(monkeypatch):
    """``submit_idle`` (fused.mcap's copy of the raw log while the run smooths): its child at nice 19,
    the submitting process untouched; run in turn (no fork) it keeps the caller's priority."""
    own = os.nice(0)
    with ForkedTasks() as tasks:
        task = tasks.submit_idle("copying", _niceness)
    pid, niceness = task.result()
    assert pid != os.getpid() and niceness == 19 and os.nice(0) == own
    monkeypatch.setattr(forked, "ENABLED", False)
    with ForkedTasks() as tasks:
        task = tasks.submit_idle("copying", _niceness)
    assert task.result() == (os.getpid(), own)


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


def _blas_threads_in_child():
    return os.getpid(), _blas_threads()


def test_blas_runs_on_one_thread_in_the_block_and_its_forked_children_then_as_before():
    """``one_blas_thread`` (the sigma parts' pass down each tree): numpy's BLAS on one thread here
    and in a child forked meanwhile; its own thread count again after."""
    before = _blas_threads()
    assert before and max(before) >= 2  # numpy's OpenBLAS, threaded on this machine (else this tests nothing)
    with forked.one_blas_thread():
        assert _blas_threads() == [1] * len(before)
        with ForkedTasks() as tasks:
            task = tasks.submit("counting BLAS threads", _blas_threads_in_child)
        pid, in_child = task.result()
    assert pid != os.getpid() and in_child == [1] * len(before)
    assert _blas_threads() == before


def test_the_error_of_a_child_is_raised_in_the_parent_as_it_was():
    with pytest.raises(SensorDataError, match=r"^some\.csv: record 7: bad value$"):
        with ForkedTasks() as tasks:
            tasks.submit("failing", _fail)


def test_a_child_that_dies_is_a_one_line_error_naming_the_work():
    tasks = ForkedTasks()
    task = tasks.submit("writing x.csv", _die)
    with pytest.raises(ForkedTaskError, match=r"^writing x\.csv: the forked child process died \(exit code 7\)$"):
        tasks.wait()
    assert task.pid is None  # reaped


def test_children_are_stopped_when_the_parent_fails():
    with pytest.raises(RuntimeError, match="parent"):
        with ForkedTasks() as tasks:
            task = tasks.submit("sleeping", __import__("time").sleep, 60)
            pid = task.pid
            raise RuntimeError("parent")
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # killed and reaped already


def test_without_fork_tasks_run_in_turn_with_the_same_results(monkeypatch):
    monkeypatch.setattr(forked, "ENABLED", False)
    tasks = ForkedTasks()
    assert tasks.submit("doubling", _double, 2.0).result() == (4.0, os.getpid())
    tasks.submit("failing", _fail)
    with pytest.raises(SensorDataError):
        tasks.wait()


#: edge values of the rows: negatives, -0.0, large and small magnitudes, %g's switch to exponents, NaN
EDGE = np.array([0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 1e-4, 9.99999999999e-5, 1e-5, -1.234567890123456e-7,
                 123456789012.0, 999999999999.5, 1e12, -1e300, 5e-324, 1e-320, np.pi, -np.e * 1e6, 0.1 + 0.2,
                 np.nan, 2.0 ** 52 + 0.5, 1 / 3])


def _columns(n: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(4)
    values = np.concatenate([EDGE, rng.normal(size=n) * 10.0 ** rng.integers(-8, 9, n)])
    return {"t_s": np.arange(values.size) * 0.01, "x_m": values, "y_m": values[::-1].copy()}


UNITS = {"t_s": "s", "x_m": "m", "y_m": "m"}


def test_rows_written_by_a_child_are_the_bytes_written_in_turn(tmp_path):
    cols = _columns(3000)
    write_csv_table(tmp_path / "turn.csv", cols, UNITS, "n", ORIGIN, fmt="%.12g")
    with ForkedTasks() as tasks:
        with CsvTableWriter(tmp_path / "forked.csv", list(UNITS), UNITS, "n", ORIGIN, fmt="%.12g") as w:
            half = {k: v[:1500] for k, v in cols.items()}
            w.write(half, tasks)
            w.write({k: v[1500:] for k, v in cols.items()}, tasks)  # after the first block (in order)
    assert (tmp_path / "forked.csv").read_bytes() == (tmp_path / "turn.csv").read_bytes()
    assert (tmp_path / "forked.json").read_bytes() == (tmp_path / "turn.json").read_bytes()
    assert b",nan," in (tmp_path / "turn.csv").read_bytes() and b",-0," in (tmp_path / "turn.csv").read_bytes()


def test_a_failed_child_writer_leaves_no_file(tmp_path, monkeypatch):
    monkeypatch.setattr(CsvTableWriter, "_write_rows", lambda self, data: _fail())
    with pytest.raises(SensorDataError):
        with ForkedTasks() as tasks:
            with CsvTableWriter(tmp_path / "t.csv", list(UNITS), UNITS, "n", ORIGIN) as w:
                w.write(_columns(10), tasks)
    assert list(tmp_path.iterdir()) == []


# --- the pipeline --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=TINY)
    return d


def _run(tiny: Path, out: Path) -> int:
    return main(["run", str(tiny / "pipeline.yaml"), "--out", str(out)])


@pytest.fixture(scope="module")
def two_runs(tiny, tmp_path_factory):
    """The tiny survey run with the outputs written in forked children and in turn."""
    d = tmp_path_factory.mktemp("runs")
    assert _run(tiny, d / "forked") == 0
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(forked, "ENABLED", False)
        assert _run(tiny, d / "turn") == 0
    return d / "forked", d / "turn"


def _masked_report(folder: Path) -> str:
    return re.sub(r"(run time|output folder)</th><td>[^<]*", "", (folder / "report.html").read_text())


def test_outputs_written_in_forked_children_are_those_written_in_turn(two_runs):
    a, b = two_runs
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert {"trajectory.csv", "geometry.csv", "fused.mcap", "report.html", "metrics.json"} <= set(names)
    assert not [n for n in names if n.startswith(".fused")]  # the copy begun while smoothing became fused.mcap
    for name in names:
        if name not in ("report.html", "metrics.json"):  # those two show the run time
            assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert _masked_report(a) == _masked_report(b)
    assert _masked_report(a).count("data:image/png;base64,") == 6  # plan, sigmas, accuracy, 3 geometry


@pytest.mark.parametrize("failure", ["error", "death", "copy error", "copy death"])
def test_a_failed_forked_writer_leaves_nothing_and_exits_with_one_line(tiny, tmp_path, monkeypatch, capsys,
                                                                       failure):
    """fused.mcap's writer fails, or the copy of the raw log it began while the run smoothed:
    an error of the output (a full disk) exits with 2, a child that died with 1 (not the input's
    fault, as a dead worker of the smoother's parts)."""
    from trackfusion.sensors import fused

    def broken(path, *args, **kwargs):
        if failure.endswith("death"):
            os._exit(9)
        raise SensorDataError(f"{path if 'copy' not in failure else path / 'fused.mcap'}: no space left on device")

    monkeypatch.setattr(fused, "start_raw_copy" if "copy" in failure else "write_fused_mcap", broken)
    out = tmp_path / "out"
    assert _run(tiny, out) == (1 if failure.endswith("death") else 2)
    err = capsys.readouterr().err.strip().splitlines()  # progress lines, then the error
    errors = [line for line in err if ": error: " in line]
    assert errors == [err[-1]] and err[-1].startswith("trackfusion run: error: ") and "Traceback" not in "".join(err)
    assert err[-1].endswith("fused.mcap: no space left on device" if failure.endswith("error")
                            else ("copying the raw log into fused.mcap" if "copy" in failure else "writing fused.mcap")
                            + ": the forked child process died (exit code 9)")
    assert not out.exists() and list(tmp_path.iterdir()) == []  # nor a staging folder
