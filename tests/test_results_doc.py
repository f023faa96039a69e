"""docs/results.md is the output of benchmarks/results_doc.py (template + benchmarks/results/*.json),
so the measured figures it shows cannot drift from the JSON the benchmarks wrote."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _results_doc():
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "benchmarks" / "results_doc.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_committed_results_doc_is_the_scripts_output():
    rd = _results_doc()
    assert (ROOT / "docs" / "results.md").read_text(encoding="utf-8") == rd.render(), \
        "docs/results.md is stale: run 'python benchmarks/results_doc.py'"


def test_placeholders_take_their_value_from_the_json(tmp_path):
    rd = _results_doc()
    (tmp_path / "x.json").write_text(json.dumps({"a": {"b c": [1.25, 2.5]}}))
    text = rd.render("v {{x.json:a.b c.1:.2f}} and {{x.json:a.b c.0:.1f}} mm", tmp_path)
    assert text == rd.HEADER + "v 2.50 and 1.2 mm"
    with pytest.raises(KeyError, match="no 'd'"):
        rd.render("{{x.json:a.d:.1f}}", tmp_path)
