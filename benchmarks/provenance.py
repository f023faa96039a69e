"""Where a benchmark's figures come from: the commit of the checkout that measured them.

Imported by the benchmark scripts (``python benchmarks/NAME.py`` puts this folder first on the path)."""

from __future__ import annotations

import subprocess
from pathlib import Path


def git_commit() -> str:
    """The checked-out commit (40 hex digits) of the repository this folder is in; empty outside git."""
    return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                          cwd=Path(__file__).parent).stdout.strip()


def write_result(path: Path, result: dict) -> None:
    """Write a benchmark's ``result`` to ``path`` as indented JSON (its folder made if missing)
    and say so."""
    import json
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path}")
