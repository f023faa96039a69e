"""The log read ahead by ``trackfusion run`` (trackfusion/log_read.py) and the forked children's
answers through an in-memory file (trackfusion/forked.py): the run takes the child's log only
when the validated pipeline asks for the same read, the same arrays as a read here; a bad log's
error is the reader's own; a run that fails first leaves no child behind."""

from __future__ import annotations

import gc
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from trackfusion import forked, log_read
from trackfusion.cli import main
from trackfusion.errors import SensorDataError
from trackfusion.forked import ForkedTasks
from trackfusion.log_read import LogRequest, read_ahead, read_requested, written_request
from trackfusion.pipeline import TopicsConfig, load_pipeline
from trackfusion.sensors.ros2 import ROLES
from trackfusion.simulation.scenarios import simulate_to_dir

pytestmark = pytest.mark.skipif(not forked.can_fork(), reason="needs fork and 2 CPUs")

TINY = ["motion.passes=1",
        "motion.segments=[{hold_s: 20}, {move_to_m: 110, speed_mps: 3, accel_mps2: 0.5}, {hold_s: 12}]"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("tiny")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=TINY)
    return d


def _with_inputs(tiny: Path, folder: Path, **inputs) -> Path:
    """A copy of the tiny survey's pipeline in ``folder`` whose ``inputs`` section has ``inputs``
    added (None: the key removed)."""
    data = yaml.safe_load((tiny / "pipeline.yaml").read_text())
    for key, value in inputs.items():
        if value is None:
            data["inputs"].pop(key, None)
        else:
            data["inputs"][key] = value
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _same_log(a, b) -> None:
    for name in ("imu", "odometer", "gnss"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            for field, value in vars(x).items():
                other = vars(y)[field]
                assert (np.array_equal(value, other) if isinstance(value, np.ndarray) else value == other), field
    assert a.metadata == b.metadata


def test_the_roles_read_ahead_are_those_of_the_pipeline():
    assert set(ROLES) == set(TopicsConfig.model_fields)


@pytest.mark.parametrize("inputs", [{}, {"allow_truncated": True}, {"topics": {"imu": "/imu"}},
                                    {"topics": {}}, {"log": "ABSOLUTE"}])
def test_the_request_as_written_is_the_validated_pipelines(tiny, tmp_path, inputs):
    if inputs.get("log") == "ABSOLUTE":
        inputs = {"log": str(tiny / "log.mcap"), "reference": str(tiny / "truth.csv")}
    elif "log" not in inputs:
        inputs = {**inputs, "log": str(Path(os.path.relpath(tiny, tmp_path / "p")) / "log.mcap"),
                  "reference": str(tiny / "truth.csv")}
    path = _with_inputs(tiny, tmp_path / "p", **inputs)
    written = written_request(str(path))
    assert written is not None and written == LogRequest.of(load_pipeline(path))
    assert written.path.resolve() == (tiny / "log.mcap").resolve()


@pytest.mark.parametrize("inputs", [{"log": 3}, {"allow_truncated": "yes"}, {"topics": ["/imu"]}])
def test_a_section_not_plain_reads_nothing_ahead(tiny, tmp_path, inputs):
    assert written_request(str(_with_inputs(tiny, tmp_path, **inputs))) is None


def test_a_broken_or_vision_yaml_reads_nothing_ahead(tmp_path):
    (tmp_path / "broken.yaml").write_text("inputs: [\n")
    (tmp_path / "vision.yaml").write_text("vision: {}\ninputs: {log: x.mcap}\n")
    assert written_request(str(tmp_path / "broken.yaml")) is None
    assert written_request(str(tmp_path / "vision.yaml")) is None
    assert written_request(str(tmp_path / "missing.yaml")) is None


def _no_read_here(request):
    raise AssertionError("read in this process")


def test_the_run_takes_the_childs_log_the_same_arrays_as_read_here(tiny, monkeypatch):
    pipeline = load_pipeline(tiny / "pipeline.yaml")
    here, _ = read_requested(LogRequest.of(pipeline))
    with read_ahead(str(tiny / "pipeline.yaml")) as ahead:
        assert ahead is not None
        monkeypatch.setattr(log_read, "read_requested", _no_read_here)  # the child has its own already
        said = []
        log, damage = ahead.take(LogRequest.of(pipeline), lambda: said.append("meanwhile"))
    assert damage is None and said == ["meanwhile"]
    _same_log(log, here)
    assert log.imu.t_s.size > 10_000 and log.imu.gyro_radps.flags.writeable


def test_a_json_log_read_ahead_is_the_same_log(tiny, tmp_path):
    """An all-JSON log (the older format), whose reader decodes in worker processes: the read-ahead
    child starts them as the run's own process would (``forked.as_leading_child``)."""
    from trackfusion.sensors.mcap_log import read_log, write_log
    json_dir = tmp_path / "json"
    shutil.copytree(tiny, json_dir)
    write_log(json_dir / "log.mcap", read_log(tiny / "log.mcap"), encoding="json")
    request = LogRequest.of(load_pipeline(json_dir / "pipeline.yaml"))
    with read_ahead(str(json_dir / "pipeline.yaml")) as ahead:
        log, _ = ahead.take(request)
    _same_log(log, read_requested(request)[0])


def _may_fork() -> tuple[bool, bool]:
    with forked.as_leading_child():
        leading = forked.can_fork()
    return leading, forked.can_fork()


def test_a_leading_child_may_fork_workers_for_its_block_only():
    with ForkedTasks(always_fork=True) as tasks:
        assert tasks.submit("asking", _may_fork).result() == (True, False)
    assert _may_fork() == (True, True)  # this process: as it was


def test_another_request_stops_the_child_and_reads_here(tiny, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(tiny, other)
    pipeline = load_pipeline(other / "pipeline.yaml")
    with read_ahead(str(tiny / "pipeline.yaml")) as ahead:
        task = ahead._task
        said = []
        log, _ = ahead.take(LogRequest.of(pipeline), lambda: said.append("meanwhile"))
        assert task.pid is None and said == []  # stopped and reaped; nothing done "meanwhile"
    _same_log(log, read_requested(LogRequest.of(pipeline))[0])


def test_a_bad_log_is_the_readers_own_error(tiny, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(tiny, bad)
    data = bytearray((bad / "log.mcap").read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = b"\xff" * 64  # inside a chunk: its CRC fails
    (bad / "log.mcap").write_bytes(bytes(data))
    request = LogRequest.of(load_pipeline(bad / "pipeline.yaml"))
    with pytest.raises(SensorDataError) as here:
        read_requested(request)
    with read_ahead(str(bad / "pipeline.yaml")) as ahead:
        with pytest.raises(SensorDataError) as ahead_error:
            ahead.take(request)
    assert str(ahead_error.value) == str(here.value)


def test_a_run_that_fails_before_reading_leaves_no_child(tiny, tmp_path, capsys, monkeypatch):
    path = _with_inputs(tiny, tmp_path / "p", log=str(tiny / "log.mcap"), reference=str(tiny / "truth.csv"),
                        imu_axes="sideways")
    started = []
    submit = ForkedTasks.submit

    def recorded(self, what, fn, *args, **kwargs):
        task = submit(self, what, fn, *args, **kwargs)
        started.append(task.pid)
        return task

    monkeypatch.setattr(ForkedTasks, "submit", recorded)
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "inputs.imu_axes" in err[-1] and err[-1].startswith("trackfusion run: error: ")
    assert len(started) == 1 and started[0] is not None  # the reader had been forked
    with pytest.raises(ChildProcessError):
        os.waitpid(started[0], os.WNOHANG)  # stopped and reaped
    assert not (tmp_path / "out").exists()


# --- answers through an in-memory file (forked.py) ----------------------------------------------------------

def _arrays():
    base = np.arange(24.0).reshape(4, 6)
    return {"c": base, "f": np.asfortranarray(base), "strided": base[:, ::2], "empty": np.zeros((0, 3)),
            "int": np.arange(7, dtype=np.int32), "bytes": np.frombuffer(b"abcdefgh", np.uint8),
            "odd": np.arange(3, dtype=np.uint8), "after_odd": np.arange(5.0), "text": "x"}


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _check_one_answer() -> None:
    with ForkedTasks(always_fork=True) as tasks:
        answer = tasks.submit("arrays", _arrays).result()
    sent = _arrays()
    assert answer.keys() == sent.keys() and answer["text"] == "x"
    for name in sent:
        if name != "text":
            a, b = answer[name], sent[name]
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), name
            assert a.flags.writeable == b.flags.writeable, name  # a read-only array stays one
    assert answer["after_odd"].ctypes.data % 8 == 0  # aligned after an odd-sized array
    answer["c"][0, 0] = -1.0  # private to this process


def test_arrays_come_back_as_they_were_with_no_file_left_open():
    gc.collect()  # an earlier test's answers, collected here, would lower the count below
    fds = _open_fds()
    for _ in range(3):
        _check_one_answer()
    tasks = ForkedTasks(always_fork=True)
    tasks.submit("sleeping", __import__("time").sleep, 30)
    tasks.kill()
    gc.collect()  # the answers' arrays held their mappings (and each mapping a descriptor)
    assert _open_fds() == fds


def _answer_files_open() -> set[int]:
    """The in-memory answer files (forked.py) this process holds open, by inode (a descriptor of
    the task's, or the duplicate a mapping of an earlier answer's arrays keeps while they live)."""
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            if "trackfusion-answer" in os.readlink(f"/proc/self/fd/{fd}"):
                out.add(os.stat(f"/proc/self/fd/{fd}").st_ino)
        except OSError:
            continue
    return out


def _report_answer_files(conn) -> None:
    conn.send(_answer_files_open())
    conn.close()


def test_a_process_forked_while_a_task_runs_holds_none_of_its_answer_files():
    """A worker forked while a task runs (a worker of the smoother's parts, of the reader's decode
    pool) would keep the task's answer file, and with it the answer's memory, alive as long as it
    runs. Every fork drops them; the task's child keeps its own, and its answer arrives whole.
    (Earlier tests' answers still alive in this process hold their files through their mappings,
    as any fork inherits a mapping: the running task's file is told apart by its inode.)"""
    import multiprocessing
    from trackfusion.forked import fork_context
    before = _answer_files_open()
    with ForkedTasks(always_fork=True) as tasks:
        task = tasks.submit("arrays later", _arrays_after, 0.5)
        running = _answer_files_open() - before
        assert len(running) == 1 and os.fstat(task._buffers_fd).st_ino in running  # the running task's, here
        here, there = multiprocessing.Pipe()
        worker = fork_context().Process(target=_report_answer_files, args=(there,))
        worker.start()
        assert not here.recv() & running
        worker.join()
        answer = task.result()
    assert np.array_equal(answer["c"], _arrays()["c"])
    del answer, task  # the arrays hold their mapping (and it a descriptor)
    gc.collect()
    assert not _answer_files_open() & running


def _arrays_after(delay_s: float) -> dict:
    import time
    time.sleep(delay_s)
    return _arrays()
