"""Output folders that never lose a result and never overwrite a file trackfusion did not write.

Every command that writes a folder (``run``, ``simulate``, ``demo``, ``batch``, ``export``) or
a file (``report --out``, ``import --out``, ``--json``) goes through :class:`OutputFolder`
(:class:`OutputFile` for one file):

1. **Checked before computing** (:meth:`OutputFolder.check`): ``--out`` must not be a file,
   must be writable (or creatable), and may hold only what trackfusion wrote there before:
   the files its manifest lists (:data:`MANIFEST`, written by every successful write into the
   folder) and sub-folders holding a manifest of their own (the demo's ``out/``). Any other
   entry refuses the run (:class:`~trackfusion.errors.OutputError`, exit 2) unless ``force``;
   even with ``force``, an input of the run is never replaced.
2. **Locked** (:data:`LOCK`, an ``flock`` held for the whole write): a second run into the same
   folder is refused at once. The lock dies with its process, so a killed run leaves no stale
   lock behind.
3. **Staged on the same file system** and renamed: the files are written into a hidden folder
   *inside* ``--out`` (created first when missing; its ``st_dev`` checked to be the folder's),
   so that the final ``os.replace`` never crosses a file system --
   ``--out`` may be a mount point (a USB or network drive, a tmpfs). On success each staged file
   replaces its namesake; files of the previous run that this one did not write are removed (no
   stale ``report.html`` beside a new trajectory); the manifest is rewritten. On failure the
   staging folder goes with everything in it, and a folder the run created is removed: nothing
   is written.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from .errors import OutputError

#: the list of files trackfusion wrote into a folder (hidden; JSON ``{"files": [...], "command": ...}``)
MANIFEST = ".trackfusion-manifest.json"
#: the lock file of a folder being written
LOCK = ".trackfusion.lock"
#: prefix of the staging folders (inside ``--out``, or beside it while it does not exist)
STAGE_PREFIX = ".trackfusion-stage-"
_OWN = (MANIFEST, LOCK)


def read_manifest(folder: Path) -> list[str]:
    """The file names trackfusion's last write into ``folder`` left there ([] without a manifest)."""
    try:
        data = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        files = data.get("files", []) if isinstance(data, dict) else []
        return [f for f in files if isinstance(f, str) and "/" not in f and f not in ("", ".", "..")]
    except (OSError, ValueError):
        return []


def _ours(entry: Path, listed: set[str]) -> bool:
    name = entry.name
    if name in listed or name in _OWN or name.startswith(STAGE_PREFIX):
        return True
    return entry.is_dir() and not entry.is_symlink() and (entry / MANIFEST).is_file()


def foreign_entries(folder: Path) -> list[str]:
    """Names in ``folder`` that trackfusion did not write (module docstring, point 1), sorted."""
    listed = set(read_manifest(folder))
    return sorted(p.name for p in folder.iterdir() if not _ours(p, listed))


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not p.exists():
        p = p.parent
    return p


def _writable_dir(path: Path) -> bool:
    return os.access(path, os.W_OK | os.X_OK)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


class OutputFolder:
    """A folder of outputs written as the module docstring says. ``what``: how the error lines
    name it (``--out``); ``inputs``: files the command reads (never replaced, even with
    ``force``); ``command``: recorded in the manifest.

    Use: ``with folder.locked():`` around the whole command (checked and locked before any
    computing), and ``with folder.staging() as stage:`` around the writing of every file into
    ``stage``; leaving that block without an exception moves them into ``folder.path``
    (:meth:`writing`: both at once)."""

    def __init__(self, path: str | os.PathLike, force: bool = False, what: str = "--out",
                 inputs: Iterable[str | os.PathLike] = (), command: str = "trackfusion",
                 writes: Iterable[str] = ()):
        self.path = Path(path)
        self.force, self.what, self.command = force, what, command
        self.inputs = [Path(p) for p in inputs]
        self.writes = tuple(writes)  # names the command may write: an input of one of them is refused at once
        self._lock_fd: int | None = None
        self._created = self._committed = False

    def _fail(self, message: str) -> OutputError:
        return OutputError(f"{self.what} {self.path}: {message}")

    def check(self) -> None:
        """Raise :class:`OutputError` (one line) when the folder cannot or must not be written."""
        p = self.path
        if p.exists() and not p.is_dir():
            raise self._fail("is a file, not a folder")
        if not p.exists():
            base = _existing_ancestor(p)
            if not base.is_dir():
                raise self._fail(f"cannot be created: {base} is a file")
            if not _writable_dir(base):
                raise self._fail(f"cannot be created: {base} is not writable")
            return
        if not _writable_dir(p):
            raise self._fail("is not writable")
        for name in self.writes:
            for source in self.inputs:
                if _same_file(source, p / name):
                    raise self._fail(f"would replace the input {source}; write the outputs elsewhere")
        foreign = foreign_entries(p)
        if foreign and not self.force:
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise self._fail(f"holds files trackfusion did not write ({shown}); choose an empty or new "
                             "folder, or pass --force to write beside them")

    # --- the lock ---------------------------------------------------------------------------

    def _lock(self) -> None:
        """Take the folder's ``flock`` (non-blocking); the lock file is checked to be the one
        locked (another run may have removed it between our open and our lock)."""
        import fcntl
        path = self.path / LOCK
        for _ in range(10):
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EACCES, errno.EAGAIN):
                    raise self._fail("another trackfusion run is writing into this folder "
                                     f"(lock {LOCK}); wait for it or choose another folder") from None
                raise
            try:
                same = os.fstat(fd).st_ino == os.stat(path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self._lock_fd = fd
                return
            os.close(fd)
        raise self._fail(f"cannot take the lock {LOCK}")

    def _unlock(self) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                (self.path / LOCK).unlink()
            os.close(self._lock_fd)
            self._lock_fd = None

    # --- locking, staging and commit ----------------------------------------------------------

    @contextlib.contextmanager
    def locked(self) -> Iterator["OutputFolder"]:
        """Check, create the folder when missing and hold its lock for the block; a folder this
        created is removed again when nothing was committed into it."""
        self.check()
        created = []  # the folders this makes, the deepest first
        p = self.path.absolute()
        while not p.exists():
            created.append(p)
            p = p.parent
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise self._fail(f"cannot be created ({exc.strerror})") from None
        self._created = bool(created)
        try:
            self._lock()
            self.check()  # again, now that no other run can change the folder
            for stale in self.path.glob(STAGE_PREFIX + "*"):  # of a killed run (we hold the lock)
                shutil.rmtree(stale, ignore_errors=True)
            yield self
        finally:
            self._unlock()
            if self._created and not self._committed:
                with contextlib.suppress(OSError):
                    for folder in created:
                        folder.rmdir()  # only when empty: what the run created and nothing else
            self._created = False

    @contextlib.contextmanager
    def staging(self) -> Iterator[Path]:
        """A staging folder inside the (locked) folder; its files are moved into the folder when
        the block ends without an exception, deleted otherwise."""
        if self._lock_fd is None:
            raise RuntimeError("OutputFolder.staging() outside locked()")
        stage = Path(tempfile.mkdtemp(prefix=STAGE_PREFIX, dir=self.path))
        try:
            if os.stat(stage).st_dev != os.stat(self.path).st_dev:  # (a mount inside --out, only)
                raise self._fail("its staging folder is on another file system")
            yield stage
            self._commit(stage)
        finally:
            shutil.rmtree(stage, ignore_errors=True)

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """:meth:`locked` and :meth:`staging` in one: yields the staging folder."""
        with self.locked(), self.staging() as stage:
            yield stage

    def _commit(self, stage: Path) -> None:
        names = sorted(p.name for p in stage.iterdir())
        for name in names:
            for source in self.inputs:
                if _same_file(source, self.path / name):
                    raise self._fail(f"would replace the input {source}; write the outputs elsewhere")
        previous = read_manifest(self.path)
        # the manifest lists both runs' files while they are swapped, so an interruption leaves no file unowned
        self._write_manifest(sorted(set(previous) | set(names)))
        for name in names:
            os.replace(stage / name, self.path / name)
        for name in sorted(set(previous) - set(names)):
            target = self.path / name
            if target.is_file() and not any(_same_file(s, target) for s in self.inputs):
                target.unlink()
        self._write_manifest(names)
        self._committed = True

    def _write_manifest(self, names: list[str]) -> None:
        tmp = self.path / f"{MANIFEST}.tmp"
        tmp.write_text(json.dumps({"written_by": self.command, "files": names}, indent=2) + "\n", encoding="utf-8")
        os.replace(tmp, self.path / MANIFEST)


class OutputFile:
    """One output file (``report --out``, ``import --out``, ``--json``) in a folder that may hold
    anything: written by an atomic writer (a temporary name in its own folder, then a rename), after
    the same checks as :class:`OutputFolder` -- an existing file is replaced only when the folder's
    manifest says trackfusion wrote it (or with ``force``), never when it is an input; the name is
    then added to the folder's manifest."""

    def __init__(self, path: str | os.PathLike, force: bool = False, what: str = "--out",
                 inputs: Iterable[str | os.PathLike] = (), command: str = "trackfusion"):
        self.path = Path(path)
        self.force, self.what, self.command = force, what, command
        self.inputs = [Path(p) for p in inputs]

    def _fail(self, message: str) -> OutputError:
        return OutputError(f"{self.what} {self.path}: {message}")

    def check(self) -> None:
        """Raise :class:`OutputError` (one line) when the file cannot or must not be written."""
        p = self.path
        if p.is_dir():
            raise self._fail("is a folder, not a file")
        for source in self.inputs:
            if _same_file(source, p):
                raise self._fail("is an input of this command; write the output elsewhere")
        base = _existing_ancestor(p.parent)
        if not base.is_dir():
            raise self._fail(f"cannot be created: {base} is a file")
        if not _writable_dir(base):
            raise self._fail(f"cannot be written: {base} is not writable")
        if p.exists() and not self.force and p.name not in read_manifest(p.parent):
            raise self._fail("exists and was not written by trackfusion; choose another name, or pass "
                             "--force to replace it")

    def record(self) -> None:
        """Add the file (written) to its folder's manifest."""
        listed = read_manifest(self.path.parent)
        if self.path.name not in listed:
            OutputFolder(self.path.parent, command=self.command)._write_manifest(sorted(listed + [self.path.name]))

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """Check, yield the path for an atomic writer (a temporary name in the same folder, then a
        rename: :func:`~trackfusion.sensors.fileio.atomic_path`), then :meth:`record` it."""
        self.check()
        yield self.path
        self.record()


def check_all(outputs: Iterable[OutputFolder | OutputFile]) -> None:
    """:meth:`check` every output (before any computing)."""
    for o in outputs:
        o.check()
