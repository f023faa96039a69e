"""cli.exit_now / cli.entry: the process ends with the exit code, after the atexit handlers, with
its buffered stdout and stderr written (nothing lost by skipping the interpreter's teardown)."""

from __future__ import annotations

import subprocess
import sys


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_exit_now_runs_atexit_and_flushes_buffered_output(tmp_path):
    marker = tmp_path / "atexit.txt"
    done = _python("import atexit, sys\n"
                   f"atexit.register(lambda: open({str(marker)!r}, 'w').write('ran'))\n"
                   "from trackfusion.cli import exit_now\n"
                   "print('\\n'.join(f'line {i}' for i in range(20000)), end='')\n"  # many buffers of a pipe
                   "sys.stderr.write('last words')\n"
                   "exit_now(3)\n")
    assert done.returncode == 3
    assert done.stdout == "\n".join(f"line {i}" for i in range(20000))
    assert done.stderr == "last words"
    assert marker.read_text() == "ran"


def test_exit_now_waits_for_running_threads():
    done = _python("import threading, time\n"
                   "from trackfusion.cli import exit_now\n"
                   "t = threading.Thread(target=lambda: (time.sleep(0.3), print('thread done')))\n"
                   "t.start()\n"
                   "exit_now(0)\n")
    assert done.returncode == 0 and done.stdout == "thread done\n"


def test_entry_exit_code_and_error_line(tmp_path):
    missing = tmp_path / "nope.yaml"
    done = subprocess.run([sys.executable, "-c", "from trackfusion.cli import entry; entry()", "run", str(missing),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == f"trackfusion run: error: {missing}: pipeline file not found"
    assert not (tmp_path / "out").exists()
