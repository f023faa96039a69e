"""Command-line conventions: --version, python -m trackfusion, simulate --list, YAML syntax
errors with file and line, the YAML key in hints, -q / -v, and progress (rich bars on a
terminal, plain lines otherwise)."""

from __future__ import annotations

import io
import subprocess
import sys

import pytest

from trackfusion.cli import main
from trackfusion.errors import ConfigError
from trackfusion.progress import NORMAL, QUIET, VERBOSE, Progress, count_of, stage_of
from trackfusion.simulation.config import available_scenarios
from trackfusion.yamlio import load_yaml


def test_version_and_python_dash_m():
    done = subprocess.run([sys.executable, "-m", "trackfusion", "--version"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("trackfusion ")
    done = subprocess.run([sys.executable, "-m", "trackfusion", "run", str("/nonexistent/p.yaml")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.strip() == "trackfusion run: error: /nonexistent/p.yaml: pipeline file not found"


def test_simulate_list_names_every_scenario(capsys):
    assert main(["simulate", "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out] == available_scenarios() + ["tgms-vehicle"]  # + the vision survey
    assert all(len(line.split(None, 1)) == 2 for line in out)  # each with its description


def test_simulate_without_a_scenario_says_how_to_list_them(capsys):
    assert main(["simulate", "--out", "x"]) == 2
    assert "trackfusion simulate --list" in capsys.readouterr().err


@pytest.mark.parametrize("kind, argv", [
    ("pipeline", ["run", "{f}"]), ("mapping", ["import", "{f}", "--out", "{d}/x.mcap"]),
    ("scenario", ["simulate", "{f}", "--out", "{d}/sim"]),
])
def test_yaml_syntax_errors_name_file_line_and_column(tmp_path, capsys, kind, argv):
    f = tmp_path / f"{kind}.yaml"
    f.write_text("name: x\ninputs:\n  log: a.mcap\n  reference: [unclosed\n")
    assert main([a.format(f=f, d=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{f}:5:1: not valid YAML" in err[0], err
    assert not (tmp_path / "sim").exists() and not (tmp_path / "x.mcap").exists()


def test_tolerance_and_design_yaml_use_the_same_loader(tmp_path):
    from trackfusion.geometry_inputs import load_design, load_tolerances
    bad = tmp_path / "t.yaml"
    bad.write_text("checks:\n  - {name: a, kind: limit\n")
    with pytest.raises(ConfigError, match=rf"{bad}:3:1: not valid YAML"):
        load_tolerances(str(bad))
    with pytest.raises(ConfigError, match=rf"{bad}:3:1: not valid YAML"):
        load_design(bad)
    tab = tmp_path / "tab.yaml"
    tab.write_text("a:\n\tb: 1\n")
    with pytest.raises(ConfigError, match=rf"{tab}:2:1: not valid YAML: found character '\\t'"):
        load_yaml(tab)


def test_truncated_log_hint_names_the_yaml_key(tmp_path):
    from trackfusion.sensors.mcap_log import read_log, write_log
    from trackfusion.sensors.types import ImuData, SensorLog
    import numpy as np
    n = 5000
    write_log(tmp_path / "a.mcap", SensorLog(imu=ImuData(np.arange(1, n + 1) / 100, np.zeros((n, 3)), np.ones((n, 3)))))
    data = (tmp_path / "a.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    from trackfusion.errors import SensorDataError
    with pytest.raises(SensorDataError, match="set inputs.allow_truncated: true in the pipeline YAML") as exc:
        read_log(tmp_path / "cut.mcap")
    assert "allow_truncated=True" not in str(exc.value)


def test_progress_plain_lines_quiet_and_verbose():
    out = io.StringIO()
    say = Progress(NORMAL, out, live=False)
    say("[x] reading log.mcap")
    say("warning: the log is damaged")
    assert out.getvalue() == "[x] reading log.mcap\nwarning: the log is damaged\n"
    out = io.StringIO()
    say = Progress(QUIET, out, live=False)
    say("[x] reading log.mcap")
    say("warning: the log is damaged")
    assert out.getvalue() == "warning: the log is damaged\n"  # quiet keeps the warnings
    out = io.StringIO()
    Progress(VERBOSE, out, live=False)("chunk 1 of 3: 0 - 60 s")
    assert out.getvalue().startswith("[") and out.getvalue().rstrip().endswith("] chunk 1 of 3: 0 - 60 s")


def test_progress_on_a_terminal_draws_bars_with_eta():
    out = io.StringIO()
    with Progress(NORMAL, out, live=True) as say:
        say("[x] reading log.mcap")
        say("solving: 100 keyframes, 500 factors")
        say("  iteration 1: cost 10 (step 1)")
        say("chunk 1 of 4: 0 - 60 s")
        say("chunk 2 of 4: 60 - 120 s")
        say("writing the outputs")
        bars = {t.description: t for t in say._bars.tasks}
        assert set(bars) == {"reading", "solving", "chunks", "writing"}
        assert bars["chunks"].total == 4 and bars["chunks"].completed == 2
        assert bars["reading"].finished  # the stage before is done
    text = out.getvalue()
    assert "chunk 2 of 4" in text and "ETA" in text  # the messages scroll above the bars


@pytest.mark.parametrize("message, stage, count", [
    ("[open] reading /x/log.mcap", "reading", None), ("  iteration 3: cost 1 (step 1)", "solving", (3, None)),
    ("chunk 2 of 12: 0 - 60 s", "chunks", (2, 12)), ("batch: [3/9] a (a.yaml): done in 1 s", "batch", (3, 9)),
    ("static intervals: 3 (120 s)", None, None),
])
def test_stages_and_counts_of_messages(message, stage, count):
    assert stage_of(message) == stage and count_of(message) == count


def test_quiet_run_prints_only_results(tmp_path, capsys):
    assert main(["-q", "simulate", "--list"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out
