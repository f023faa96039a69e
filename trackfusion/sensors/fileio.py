"""Atomic file output and CSV tables with JSON sidecars.

Every output file is written to a temporary name in the same folder and
renamed into place only once complete, so a failed run never leaves a partial
file behind. A CSV table ``name.csv`` always has a sidecar ``name.json`` with
``{"frame", "origin": {"lat_deg", "lon_deg", "h_m"}, "columns": {name: unit}}``
plus any extra keys the writer passes.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np

from ..errors import SensorDataError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` on success, delete it on error."""
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the file ordinary permissions
        os.replace(tmp_path, final)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json_atomic(path: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically (keys kept in insertion order)."""
    write_text_atomic(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def sidecar_path(csv_path: str | os.PathLike) -> Path:
    """``foo.csv`` -> ``foo.json``."""
    return Path(csv_path).with_suffix(".json")


def write_csv_table(path: str | os.PathLike, columns: Mapping[str, np.ndarray], units: Mapping[str, str],
                    frame: str, origin: Mapping[str, float], extra: Mapping | None = None,
                    fmt: str = "%.10g") -> None:
    """Write a CSV table and its JSON sidecar, both atomically.

    columns: name -> 1-D array, all of one length N (written in the given order).
    units: name -> unit string for every column. frame: frame name (e.g. ``"n"``).
    origin: ``{"lat_deg", "lon_deg", "h_m"}`` of the frame. extra: more sidecar keys.
    fmt: printf format of the values (the default keeps 10 significant digits;
    pass ``"%.17g"`` for a bit-exact round trip).
    """
    with CsvTableWriter(path, list(columns), units, frame, origin, extra, fmt) as writer:
        writer.write(columns)


class CsvTableWriter:
    """A CSV table and its sidecar written block by block (long runs: the rows never all in
    memory): the same bytes as :func:`write_csv_table` of the blocks' concatenation, and as
    atomic — the rows go to a temporary name beside ``path``, renamed (and the sidecar
    written) by :meth:`close`; :meth:`abort` (or an exception inside ``with``) deletes it.
    Arguments as :func:`write_csv_table`, with the column ``names`` in their order.

    ``write(columns, background=tasks)`` formats the block in a forked child
    (:class:`~trackfusion.forked.ForkedTasks`) while this process goes on; :meth:`close` then
    writes the sidecar, and the table is renamed into place when ``tasks`` has waited for the
    child (a failed child: the temporary file and the sidecar are deleted)."""

    def __init__(self, path: str | os.PathLike, names: list[str], units: Mapping[str, str], frame: str,
                 origin: Mapping[str, float], extra: Mapping | None = None, fmt: str = "%.10g"):
        missing = [c for c in names if c not in units]
        if missing:
            raise ValueError(f"no unit for columns {missing}")
        self.path, self.names, self.fmt, self.rows = Path(path), list(names), fmt, 0
        self.sidecar = {"frame": frame, "origin": dict(origin), "columns": {c: units[c] for c in names}, **(extra or {})}
        self._atomic = atomic_path(self.path)
        self._fh = self._atomic.__enter__().open("w", encoding="utf-8")
        self._fh.write(",".join(self.names) + "\n")
        self._pending = None  # the ForkedTask writing the last block, if any

    def write(self, columns: Mapping[str, np.ndarray], background=None) -> None:
        """Append rows: name -> 1-D array for every column, all of one length; with ``background``
        (a :class:`~trackfusion.forked.ForkedTasks`), formatted in a forked child (class docstring)."""
        data = np.column_stack([np.asarray(columns[c], dtype=float) for c in self.names])
        if self._pending is not None:  # blocks stay in order
            self._pending.result()
            self._pending = None
        if background is None:
            self._write_rows(data)
        else:
            self._fh.flush()  # the child shares the file (and its offset), not this buffer
            self._pending = background.submit(f"{self.path}: writing the rows", self._write_rows, data)
        self.rows += data.shape[0]

    def _write_rows(self, data: np.ndarray) -> None:
        np.savetxt(self._fh, data, delimiter=",", fmt=self.fmt)
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
        if self._pending is None:
            self._atomic.__exit__(None, None, None)
            write_json_atomic(sidecar_path(self.path), self.sidecar)
            return
        write_json_atomic(sidecar_path(self.path), self.sidecar)  # at once: readers of the sidecar need no rows
        # the rows renamed into place once the child has written them, deleted if it fails
        self._pending.then(lambda _rows: self._atomic.__exit__(None, None, None), self._discard_all)

    def _discard_all(self) -> None:
        self._discard()
        sidecar_path(self.path).unlink(missing_ok=True)

    def abort(self) -> None:
        self._fh.close()
        self._discard()  # a child still writing writes to the deleted file

    def _discard(self) -> None:
        with contextlib.suppress(_Aborted):
            self._atomic.__exit__(_Aborted, _Aborted(), None)  # atomic_path deletes the temporary file

    def __enter__(self) -> "CsvTableWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.abort() if exc_type is not None else self.close()


class _Aborted(Exception):
    """Thrown into :func:`atomic_path` to make it delete an unfinished file."""


def read_csv_table(path: str | os.PathLike, required: list[str] | tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read a CSV table written by :func:`write_csv_table` (header line, then numbers).

    Returns name -> float array (N,). Raises :class:`SensorDataError` naming the
    file when it is missing, empty, unparsable, or lacks a ``required`` column.
    """
    p = Path(path)
    if not p.is_file():
        raise SensorDataError(f"{p}: file not found")
    with p.open("r", encoding="utf-8") as fh:
        header = fh.readline().strip()
        if not header:
            raise SensorDataError(f"{p}: empty file (no header line)")
        names = [h.strip() for h in header.split(",")]
        try:
            data = np.loadtxt(fh, delimiter=",", ndmin=2)
        except ValueError as exc:
            raise SensorDataError(f"{p}: unreadable numbers ({exc})") from None
    if data.size == 0:
        raise SensorDataError(f"{p}: no data rows")
    if data.shape[1] != len(names):
        raise SensorDataError(f"{p}: {data.shape[1]} values per row but {len(names)} column names")
    table = {n: data[:, i] for i, n in enumerate(names)}
    missing = [c for c in required if c not in table]
    if missing:
        raise SensorDataError(f"{p}: missing column {missing[0]!r}")
    return table


def read_json(path: str | os.PathLike, what: str = "file"):
    """Read a JSON file; raises :class:`SensorDataError` naming it (``{path}: {what} not found``
    or ``invalid JSON``)."""
    p = Path(path)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SensorDataError(f"{p}: {what} not found") from None
    except json.JSONDecodeError as exc:
        raise SensorDataError(f"{p}: invalid JSON ({exc.msg} at line {exc.lineno})") from None


def read_sidecar(csv_path: str | os.PathLike) -> dict:
    """Read the JSON sidecar of a CSV table; raises :class:`SensorDataError` naming the file."""
    return read_json(sidecar_path(csv_path), "sidecar")


class CsvTableOnDisk(Mapping):
    """The columns of a CSV table written by :func:`write_csv_table`, read (whole, once) on the
    first access: a long run's trajectory stays on disk unless asked for. Values are as written
    (the writer's number format)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._table: dict[str, np.ndarray] | None = None

    def _columns(self) -> dict[str, np.ndarray]:
        if self._table is None:
            self._table = read_csv_table(self.path)
        return self._table

    def __getitem__(self, name: str) -> np.ndarray:
        return self._columns()[name]

    def __iter__(self):
        return iter(self._columns())

    def __len__(self) -> int:
        return len(self._columns())
