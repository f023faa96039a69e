"""Outputs are never lost and never overwrite a file trackfusion did not write: ``--out`` on
another file system (a real tmpfs mount when this runs as root, else a simulated EXDEV), a
file, a read-only folder, a folder of someone else's files, a folder locked by another run;
exit codes and one-line messages through the CLI; nothing written on failure; inputs intact."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from trackfusion.cli import main
from trackfusion.errors import OutputError
from trackfusion.outdir import LOCK, MANIFEST, OutputFile, OutputFolder, foreign_entries
from trackfusion.simulation.scenarios import simulate_to_dir

SHORT = ["motion.passes=1",
         "motion.segments=[{hold_s: 20}, {move_to_m: 100, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 5},"
         " {move_to_m: 40, speed_mps: 3, accel_mps2: 0.4}]"]


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    d = tmp_path_factory.mktemp("survey")
    simulate_to_dir("open-track-gnss", d, seed=3, overrides=SHORT)
    (d / "pipeline.yaml").write_text((d / "pipeline.yaml").read_text() + "outputs: {report: false, fused_mcap: false}\n")
    return d


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "no error line"
    return err[-1]


def _refused(capsys, argv, *words):
    """The command exits 2 with one line holding ``words`` (and no traceback)."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    line = captured.err.strip().splitlines()[-1]
    for w in words:
        assert w in line, line
    return line


# --- the folder checks, before computing -----------------------------------------------------

def test_out_that_is_a_file_is_refused_before_reading(survey, tmp_path, capsys):
    target = tmp_path / "results"
    target.write_text("mine\n")
    _refused(capsys, ["-q", "run", str(survey / "pipeline.yaml"), "--out", str(target)], "is a file", str(target))
    assert target.read_text() == "mine\n"


def test_read_only_out_is_refused(survey, tmp_path, capsys):
    """A folder without write permission; as root (who writes through permissions), a read-only
    file system."""
    ro = tmp_path / "ro"
    if os.geteuid() != 0:
        ro.mkdir()
        ro.chmod(0o555)
        undo = ["chmod", "755", str(ro)]
    elif _tmpfs(ro, "ro,size=1m"):
        undo = ["umount", str(ro)]
    else:
        pytest.skip("root, and no read-only file system can be mounted here")
    try:
        _refused(capsys, ["run", str(survey / "pipeline.yaml"), "--out", str(ro)], "not writable")
    finally:
        subprocess.run(undo, check=True)


def test_read_only_out_is_refused_before_computing(tmp_path, monkeypatch):
    """(as root, which may write anywhere, through the permission check the folder gets)"""
    ro = tmp_path / "ro"
    ro.mkdir()
    monkeypatch.setattr(os, "access", lambda p, mode: Path(p) != ro)
    with pytest.raises(OutputError, match="is not writable"):
        OutputFolder(ro).check()
    with pytest.raises(OutputError, match="cannot be created"):
        OutputFolder(ro / "new" / "deeper").check()


def test_a_folder_of_someone_elses_files_is_refused_and_kept(survey, tmp_path, capsys):
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "trajectory.csv").write_text("their own table\n")
    (out / "notes.txt").write_text("notes\n")
    before = _digest(out)
    line = _refused(capsys, ["run", str(survey / "pipeline.yaml"), "--out", str(out)],
                    "did not write", "notes.txt", "trajectory.csv", "--force")
    assert "reading" not in line
    assert _digest(out) == before and sorted(p.name for p in out.iterdir()) == ["notes.txt", "trajectory.csv"]


def test_every_command_refuses_someone_elses_folder(survey, tmp_path, capsys):
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    for argv in (["simulate", "fog-odometer", "--out", str(out)], ["demo", "--out", str(out)],
                 ["export", str(survey / "log.mcap"), "--out", str(out)],
                 ["batch", str(survey / "pipeline.yaml"), "--out-root", str(tmp_path / "root")]):
        if argv[0] == "batch":
            (tmp_path / "root" / "pipeline").mkdir(parents=True, exist_ok=True)
            (tmp_path / "root" / "pipeline" / "keep.txt").write_text("x")
        _refused(capsys, argv, "did not write")
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


def test_single_file_outputs_never_replace_a_users_file(survey, tmp_path, capsys):
    mine = tmp_path / "report.html"
    mine.write_text("my report\n")
    _refused(capsys, ["report", str(survey), "--out", str(mine)], "not written by trackfusion")
    mapping = tmp_path / "import.yaml"
    log = tmp_path / "log.mcap"
    log.write_bytes(b"my log")
    _refused(capsys, ["import", str(mapping), "--out", str(log)], "not written by trackfusion")
    summary = tmp_path / "summary.json"
    summary.write_text("{}")
    _refused(capsys, ["evaluate", str(survey / "truth.csv"), str(survey / "truth.csv"), "--json", str(summary)],
             "--json", "not written by trackfusion")
    assert mine.read_text() == "my report\n" and log.read_bytes() == b"my log" and summary.read_text() == "{}"


def test_an_output_file_that_is_an_input_is_refused_even_with_force(survey, capsys):
    _refused(capsys, ["evaluate", str(survey / "truth.csv"), str(survey / "truth.csv"), "--force",
                      "--json", str(survey / "truth.csv")], "is an input")


def test_a_locked_folder_refuses_a_second_run(survey, tmp_path, capsys):
    out = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", f"""
import sys, time
from trackfusion.outdir import OutputFolder
with OutputFolder({str(out)!r}).locked():
    print("locked", flush=True)
    sys.stdin.readline()
"""], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env={**os.environ})
    try:
        assert holder.stdout.readline().strip() == "locked"
        _refused(capsys, ["run", str(survey / "pipeline.yaml"), "--out", str(out)], "another trackfusion run")
    finally:
        holder.communicate("\n", timeout=30)
    assert holder.returncode == 0
    assert not out.exists()  # the holder created it, wrote nothing, and removed it


def test_a_killed_run_leaves_no_lock_that_blocks(tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-c", f"""
import os
from trackfusion.outdir import OutputFolder
f = OutputFolder({str(out)!r})
with f.locked():
    with f.staging() as stage:
        (stage / "half.csv").write_text("1,2\\n")
        os.kill(os.getpid(), 9)
"""])
    proc.wait(timeout=60)
    assert (out / LOCK).exists()  # the lock file stays, its flock died with the process
    folder = OutputFolder(out)
    with folder.writing() as stage:
        (stage / "a.csv").write_text("1\n")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.csv"]  # the stale stage is cleaned up


# --- staging on the same file system -----------------------------------------------------------

def _fake_exdev(monkeypatch):
    """``os.replace`` raising EXDEV, as between two file systems, whenever the source is not inside
    the destination's folder (the old staging folder beside ``--out`` was not)."""
    real = os.replace

    def replace(src, dst):
        if Path(dst).resolve().parent not in Path(src).resolve().parents:
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", replace)


def _tmpfs(path: Path, options: str = "size=64m") -> bool:
    path.mkdir()
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True)
    return done.returncode == 0


@pytest.fixture
def mounted(tmp_path):
    """An empty folder that is a tmpfs mount point (or, unmountable here, a plain folder)."""
    mnt = tmp_path / "usb"
    real = _tmpfs(mnt)
    yield mnt, real
    if real:
        subprocess.run(["umount", str(mnt)], check=True)


def test_run_into_a_mount_point_then_again_then_refused(survey, mounted, monkeypatch, capsys):
    out, real = mounted
    if real:
        assert os.stat(out).st_dev != os.stat(out.parent).st_dev
    else:
        _fake_exdev(monkeypatch)
    inputs = _digest(survey)
    assert main(["-q", "run", str(survey / "pipeline.yaml"), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "verdict: the survey" in stdout.splitlines()[-1]
    files = json.loads((out / MANIFEST).read_text())["files"]
    assert {"trajectory.csv", "trajectory.json", "metrics.json"} <= set(files)
    assert sorted(p.name for p in out.iterdir()) == sorted(files + [MANIFEST])  # no staging left, no lock
    first = (out / "metrics.json").read_text()
    # a re-run into a folder of a previous run's outputs replaces them without --force
    (out / "report.html").write_text("stale")  # listed by the manifest as if an earlier run wrote it
    manifest = json.loads((out / MANIFEST).read_text())
    (out / MANIFEST).write_text(json.dumps({**manifest, "files": manifest["files"] + ["report.html"]}))
    assert main(["-q", "run", str(survey / "pipeline.yaml"), "--out", str(out)]) == 0
    assert not (out / "report.html").exists()  # the earlier run's file this run did not write is gone
    assert (out / "metrics.json").read_text() != first  # (timings differ)
    # a file of the user's beside them: refused; with --force written beside it, kept
    (out / "mine.txt").write_text("mine")
    _refused(capsys, ["run", str(survey / "pipeline.yaml"), "--out", str(out)], "mine.txt")
    assert main(["-q", "run", str(survey / "pipeline.yaml"), "--out", str(out), "--force"]) == 0
    assert (out / "mine.txt").read_text() == "mine"
    assert foreign_entries(out) == ["mine.txt"]
    assert _digest(survey) == inputs  # the inputs are untouched


def test_a_failed_run_writes_nothing(survey, tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    text = (survey / "pipeline.yaml").read_text().replace("log: log.mcap", f"log: {survey / 'log.mcap'}")
    bad.write_text(text.replace("reference: truth.csv", f"reference: {tmp_path / 'broken.csv'}"))
    (tmp_path / "broken.csv").write_text("t_s,e_m\n0,1\n")
    out = tmp_path / "new" / "out"
    assert main(["-q", "run", str(bad), "--out", str(out)]) == 2
    assert not out.exists()


def test_export_into_a_mount_point_and_import_beside_it(survey, mounted, monkeypatch, capsys):
    out, real = mounted
    if not real:
        _fake_exdev(monkeypatch)
    assert main(["export", str(survey / "log.mcap"), "--out", str(out)]) == 0
    assert "imu.csv" in capsys.readouterr().out
    assert main(["import", str(out / "import.yaml"), "--out", str(out / "again.mcap")]) == 0
    assert main(["import", str(out / "import.yaml"), "--out", str(out / "again.mcap")]) == 0  # ours: replaced
    assert "again.mcap" in json.loads((out / MANIFEST).read_text())["files"]
    assert main(["export", str(survey / "log.mcap"), "--out", str(out)]) == 0  # export's and import's files only


def test_output_file_records_itself_in_the_folder_manifest(tmp_path):
    f = OutputFile(tmp_path / "x.json")
    with f.writing() as path:
        path.write_text("{}")
    assert json.loads((tmp_path / MANIFEST).read_text())["files"] == ["x.json"]
    OutputFile(tmp_path / "x.json").check()  # ours now: no --force needed


def test_a_failed_command_removes_every_folder_it_created(tmp_path):
    folder = OutputFolder(tmp_path / "a" / "b" / "c")
    with pytest.raises(RuntimeError):
        with folder.locked():
            with folder.staging() as stage:
                (stage / "x.csv").write_text("1\n")
                raise RuntimeError("fails while writing")
    assert list(tmp_path.iterdir()) == []


def test_an_input_in_the_output_folder_is_never_replaced_even_with_force(survey, tmp_path, capsys):
    """The reference named trajectory.csv in --out: refused before reading, --force or not."""
    case = tmp_path / "case"
    case.mkdir()
    for name in ("log.mcap", "pipeline.yaml"):
        (case / name).write_bytes((survey / name).read_bytes())
    (case / "trajectory.csv").write_bytes((survey / "truth.csv").read_bytes())
    (case / "trajectory.json").write_bytes((survey / "truth.json").read_bytes())
    (case / "pipeline.yaml").write_text((case / "pipeline.yaml").read_text().replace("truth.csv", "trajectory.csv"))
    before = _digest(case)
    _refused(capsys, ["run", str(case / "pipeline.yaml"), "--out", str(case), "--force"], "would replace the input")
    assert _digest(case) == before
