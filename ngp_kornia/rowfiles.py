"""The files ``ngp predict`` writes its rows through: hidden files beside the results file, each locked while a run
writes it, so that a later run can tell the files of a run still going from those a killed run left
(:func:`remove_stale_files`); and the merge of the part files of a multi-process run.

The lock is ``fcntl.flock``: the system drops it when the process ends, even on SIGKILL. Without ``fcntl`` (Windows)
nothing is locked, and nothing is taken for stale.
"""

from __future__ import annotations

import glob
import heapq
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import IO

try:  # POSIX
    import fcntl
except ImportError:
    fcntl = None

__all__ = ["count_rows", "merge_parts", "open_locked", "remove_stale_files"]


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
    except OSError:  # BlockingIOError: locked by a run that is still going
        return True
    return False


def remove_stale_files(out: str | Path) -> list[Path]:
    """Delete the hidden files that runs killed outright (SIGKILL, a power cut) left beside ``out``: their
    temporary and part files (``.<out name>.<run id>.tmp`` / ``.part<R>``). Those of a run still going are locked,
    and kept; so is every other file.

    Returns:
        the files deleted.
    """
    out = Path(out)
    pattern = re.compile(rf"\.{re.escape(out.name)}\.[0-9a-f]{{8}}\.(tmp|part[0-9]+)")
    stale = [p for p in out.parent.glob(f".{glob.escape(out.name)}.*") if pattern.fullmatch(p.name)]
    stale = [p for p in stale if p.is_file() and not _in_use(p)]
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def count_rows(path: str | Path) -> tuple[int, int]:
    """Rows and error rows of a results file."""
    rows = errors = 0
    with Path(path).open(encoding="utf-8") as lines:
        for line in lines:
            rows += 1
            errors += "error" in json.loads(line)
    return rows, errors


def _read_part(path: Path) -> Iterator[tuple[int, str]]:
    with path.open(encoding="utf-8") as lines:
        for line in lines:
            if not line.endswith("\n"):  # a process stopped in the middle of a line: that image is not done
                return
            index, row = line.split("\t", 1)
            yield int(index), row


def merge_parts(parts: list[Path], out: str | Path) -> int:
    """Merge part files (lines ``<index>\\t<json>``, increasing index in each file) into ``out`` in index order,
    writing each index once; streams, so memory does not grow with the number of rows.

    Returns:
        the number of rows written.
    """
    written, last = 0, -1
    with open_locked(Path(out)) as dst:
        for index, row in heapq.merge(*(_read_part(p) for p in parts), key=lambda pair: pair[0]):
            # a sampler that pads the last batch repeats indices: keep the first copy only
            if index == last:
                continue
            dst.write(row.encode("utf-8"))
            written, last = written + 1, index
    return written
