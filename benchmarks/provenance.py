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


def pipeline_variant(sim: Path, name: str, sections: dict[str, dict], drop_reference: bool = False) -> Path:
    """``sim``'s pipeline.yaml copied beside it as ``pipeline-{name}.yaml``, the keys of each section
    in ``sections`` set (e.g. ``{"smoother": {"chunk_s": None}}``) and, with ``drop_reference``, no
    reference; returns the copy's path (the figures of a run with other settings come from it)."""
    import yaml
    data = yaml.safe_load((sim / "pipeline.yaml").read_text())
    if drop_reference:
        data["inputs"].pop("reference", None)
    for section, keys in sections.items():
        data.setdefault(section, {}).update(keys)
    path = sim / f"pipeline-{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path
