"""The files through which ``ngp predict`` writes its rows, so that a run stopped at any point (Ctrl+C, SIGTERM, a
preempted job, SIGKILL, a power cut) can be continued (``--resume``) and still ends with one row per image.

Beside the results file ``out`` a run keeps a hidden folder, its run folder ``.<out name>.ngp-run``:

* ``run.json``: what the run calibrates (the number of images, a digest of their files, one of the options that
  change a row) and the id of the current attempt; always written whole (a temporary file renamed over it).
* ``<attempt>-<rank>.rows``: the rows one process of one attempt finished, a line ``<index>\\t<json>`` per image in
  increasing index. Appended as images are done and flushed at once (a killed process loses none), synced to the
  disk every :data:`SYNC_SECONDS` (a power cut loses the last ones at most). An attempt never appends to the files of
  an earlier one. Each is locked while written (``fcntl.flock``, which the system drops when the process ends,
  however it ends), so the files of a run still going are told from those of a dead one.

A rows file is read up to its first line that is not whole and well formed (a process killed in the middle of a
line; after a power cut, a tail that never reached the disk), so every row taken is complete.

At the end the rows files are merged in index order, each index once, into a temporary file in the run folder,
which is synced and renamed over ``out``; then the run folder is renamed to ``.<out name>.ngp-done.<id>`` and
deleted. Killed anywhere in that, a run leaves the run folder whole (a resumed run merges again) or a done folder
(which the next run deletes). Without ``fcntl`` (Windows) nothing is locked, and no run folder is taken for dead.
"""

from __future__ import annotations

import glob
import heapq
import json
import os
import re
import secrets
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

try:  # POSIX
    import fcntl
except ImportError:
    fcntl = None

__all__ = ["SYNC_SECONDS", "RowsFile", "RunFolder", "count_rows", "merge_parts", "open_locked", "read_rows",
           "remove_stale_files"]

#: seconds between two syncs of a rows file to the disk
SYNC_SECONDS = 1.0
_STATE = "run.json"


def open_locked(path: Path) -> IO[bytes]:
    """``path`` opened for writing, with an exclusive lock that the system drops when the process ends, however."""
    file = path.open("wb")
    if fcntl is not None:
        fcntl.flock(file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    return file


def _in_use(path: Path) -> bool:
    """Whether a run still holds the lock of one of its files (True where that cannot be told)."""
    if fcntl is None:
        return True
    try:
        with path.open("rb") as file:
            fcntl.flock(file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except FileNotFoundError:  # gone in the meantime
        return False
    except OSError:  # BlockingIOError: locked by a run that is still going
        return True
    return False


def _sync_folder(folder: Path) -> None:
    """Make a rename or a new file in ``folder`` reach the disk (where the system lets a folder be synced)."""
    try:
        handle = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(handle)
    except OSError:  # a file system or system that does not sync folders
        pass
    finally:
        os.close(handle)


class RowsFile:
    """A rows file being written: whole rows appended, flushed, synced every :data:`SYNC_SECONDS`; closed, it is
    synced and cut back to its last whole row (a write that failed, a full disk, may have left part of one).

    Attributes:
        whole: bytes up to the last whole row.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.file: IO[bytes] | None = open_locked(path)
        self.whole = 0
        self._synced = time.monotonic()

    def append(self, data: bytes) -> None:
        """Append whole rows (lines)."""
        self.file.write(data)
        self.file.flush()
        self.whole += len(data)
        if time.monotonic() - self._synced >= SYNC_SECONDS:
            os.fsync(self.file.fileno())
            self._synced = time.monotonic()

    def close(self) -> None:
        """Sync, close, and cut back to the last whole row; errors of the flush and the sync are dropped (the rows
        that did not fit are not rows)."""
        if self.file is None:
            return
        file, self.file = self.file, None
        try:
            file.flush()
            os.fsync(file.fileno())
        except OSError:
            pass
        try:
            file.close()
        except OSError:
            pass
        os.truncate(self.path, self.whole)


def read_rows(path: Path, count: int | None = None) -> Iterator[tuple[int, str]]:
    """The ``(index, json line)`` pairs of a rows file, up to its first line that is not a whole row: not ended by a
    newline, an index that is not a whole number in ``[0, count)`` or not above the one before, or no JSON object
    with an ``"image"``.
    """
    last = -1
    with path.open("rb") as lines:
        for raw in lines:
            head, tab, row = raw.partition(b"\t")
            if not (raw.endswith(b"\n") and tab and head.isdigit()) or not last < int(head) < (count or 1 << 62):
                return
            try:
                text = row.decode("utf-8")
                whole = isinstance(parsed := json.loads(text), dict) and "image" in parsed
            except ValueError:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
                return
            if not whole:
                return
            last = int(head)
            yield last, text


def merge_parts(parts: list[Path], out: str | Path, count: int | None = None) -> int:
    """Merge rows files (:func:`read_rows`) into ``out`` in index order, writing each index once; streams, so
    memory does not grow with the number of rows.

    Returns:
        the number of rows written.
    """
    written, last = 0, -1
    with open_locked(Path(out)) as dst:
        for index, row in heapq.merge(*(read_rows(p, count) for p in parts), key=lambda pair: pair[0]):
            if index == last:  # two attempts (or a padded sampler) wrote this image: keep the first row
                continue
            dst.write(row.encode("utf-8"))
            written, last = written + 1, index
        dst.flush()
        os.fsync(dst.fileno())
    return written


def count_rows(path: str | Path) -> tuple[int, int]:
    """Rows and error rows of a results file."""
    rows = errors = 0
    with Path(path).open(encoding="utf-8") as lines:
        for line in lines:
            rows += 1
            errors += "error" in json.loads(line)
    return rows, errors


class RunFolder:
    """The run folder of the results file ``out`` (see the module docstring).

    Args:
        out: the results file (the file itself, not a link to it: the run folder goes beside it).

    Example:
        >>> RunFolder(Path("runs/results.jsonl")).path.as_posix()
        'runs/.results.jsonl.ngp-run'
    """

    def __init__(self, out: str | Path) -> None:
        self.out = Path(out)
        self.path = self.out.with_name(f".{self.out.name}.ngp-run")

    def rows_files(self) -> list[Path]:
        """The rows files of every attempt, in a fixed order."""
        if not self.path.is_dir():
            return []
        return sorted(p for p in self.path.iterdir() if p.suffix == ".rows" and p.is_file())

    def rows_file(self, attempt: str, rank: int) -> Path:
        """The rows file of one process (global ``rank``) of an attempt."""
        return self.path / f"{attempt}-{rank}.rows"

    def in_use(self) -> bool:
        """Whether a process that is still running writes one of the rows files."""
        return any(_in_use(p) for p in self.rows_files())

    def state(self) -> dict | None:
        """What ``run.json`` says (None: no run folder, or one that a run left before it was written)."""
        try:
            state = json.loads((self.path / _STATE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return state if isinstance(state, dict) else None

    def done(self, count: int) -> bytearray:
        """For each of ``count`` images, 1 where a rows file holds its row, else 0."""
        flags = bytearray(count)
        for path in self.rows_files():
            for index, _ in read_rows(path, count):
                flags[index] = 1
        return flags

    def start(self, state: dict, keep: bool) -> None:
        """Make the run folder ready for an attempt: the rows of earlier attempts kept (``keep``, a resumed run) or
        deleted (a new run), and ``state`` (with the attempt's id) written to ``run.json``."""
        if not keep:
            shutil.rmtree(self.path, ignore_errors=True)
        self.path.mkdir(parents=True, exist_ok=True)
        temporary = self.path / f"{_STATE}.{secrets.token_hex(4)}.tmp"
        with temporary.open("w", encoding="utf-8") as file:
            json.dump(state, file)
            file.flush()
            os.fsync(file.fileno())
        temporary.replace(self.path / _STATE)
        _sync_folder(self.path)
        _sync_folder(self.path.parent)

    def merge(self, count: int, complete: bool = False) -> int:
        """Merge the rows of every attempt into ``out`` (through a synced temporary file renamed over it); rows
        written. With ``complete``, ``out`` is replaced only if every one of the ``count`` images has its row. The
        temporary file is deleted whatever happens."""
        temporary = self.path / f"merged.{secrets.token_hex(4)}.tmp"
        try:
            written = merge_parts(self.rows_files(), temporary, count)
            if written == count or not complete:
                temporary.replace(self.out)
                _sync_folder(self.out.parent)
        finally:
            temporary.unlink(missing_ok=True)
        return written

    def retire(self) -> None:
        """Delete the run folder of a finished run: renamed out of the way at once, then deleted."""
        done = self.out.with_name(f".{self.out.name}.ngp-done.{secrets.token_hex(4)}")
        try:
            self.path.replace(done)
        except FileNotFoundError:
            return
        _sync_folder(self.out.parent)
        shutil.rmtree(done, ignore_errors=True)


def remove_stale_files(out: str | Path) -> list[Path]:
    """Delete what runs killed outright left beside ``out`` that no run will read: the run folders of finished runs
    that were being deleted (``.<out name>.ngp-done.<id>``), and the files of an earlier version of ``ngp
    predict`` (``.<out name>.<id>.tmp`` / ``.part<R>``) that no running process holds. Every other file stays.

    Returns:
        what was deleted.
    """
    out = Path(out)
    done = re.compile(rf"\.{re.escape(out.name)}\.ngp-done\.[0-9a-f]{{8}}")
    old = re.compile(rf"\.{re.escape(out.name)}\.[0-9a-f]{{8}}\.(tmp|part[0-9]+)")
    stale = []
    for path in out.parent.glob(f".{glob.escape(out.name)}.*"):
        if done.fullmatch(path.name) and path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
            stale.append(path)
        elif old.fullmatch(path.name) and path.is_file() and not _in_use(path):
            path.unlink(missing_ok=True)
            stale.append(path)
    return stale
