"""The one YAML reader of every configuration file (pipeline, scenario, import mapping,
tolerance table, design alignment): a syntax error is one :class:`~trackfusion.errors.ConfigError`
line naming the file, the line and the column (``pipeline.yaml:12:5: not valid YAML: ...``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError


def parse_yaml(text: str, source: str) -> Any:
    """``yaml.safe_load`` of ``text``; a syntax error names ``source`` and its line and column (1-based)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark is not None else source
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        context = getattr(exc, "context", None)
        raise ConfigError(f"{where}: not valid YAML: {problem}" + (f" ({context})" if context else "")) from None


def load_yaml(path: str | os.PathLike, what: str = "file") -> Any:
    """Read and parse a YAML file (:func:`parse_yaml`); a missing or non-UTF-8 file is a
    :class:`ConfigError` naming it (``{path}: {what} not found``)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: {what} not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a folder, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not valid YAML: not UTF-8 text (byte {exc.start})") from None
    return parse_yaml(text, str(p))


@dataclass
class ConfigFile:
    """A validated configuration file: its ``source`` (the name errors give) and ``base_dir``,
    the folder its relative paths start from."""

    base_dir: Path
    source: str

    def path(self, p: str) -> Path:
        """``p`` as given when absolute, else relative to :attr:`base_dir`."""
        q = Path(p)
        return q if q.is_absolute() else self.base_dir / q
