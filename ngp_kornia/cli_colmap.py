"""``ngp predict FOLDER --out rows.jsonl --colmap DATABASE``: after the run, each photo's camera and gravity prior
written into a COLMAP database (:mod:`ngp_kornia.colmap`, the ``colmap`` extra).

The option is checked (pycolmap installed, the file a COLMAP database or new) before anything heavy is imported,
so a wrong one is refused before the run; pycolmap is imported when the rows are written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ngp_kornia.errors import OutputError
from ngp_kornia.preflight import check_database, check_extra

__all__ = ["add_colmap_argument", "check_colmap", "write_colmap"]


def add_colmap_argument(command: argparse.ArgumentParser) -> None:
    """``--colmap DATABASE``."""
    command.add_argument(
        "--colmap", metavar="DATABASE",
        help="then write each photo's camera and gravity prior into this COLMAP database, new or existing, matching "
        "its images by name (extra: colmap)",
    )


def check_colmap(args: argparse.Namespace) -> None:
    """Refuse ``--colmap`` without pycolmap, or naming a file that is not a COLMAP database.

    Raises:
        ImportError: pycolmap is not installed (the message names the extra).
        OutputError: the file is ``--out``, or exists and is not a COLMAP database, or is a folder.
    """
    if args.colmap:
        check_extra(["pycolmap"], "ngp predict --colmap", "colmap")
        if Path(args.colmap).resolve() == Path(args.out).resolve():
            raise OutputError(f"--colmap {args.colmap} is also --out; give the COLMAP database another name")
        check_database(args.colmap)


def write_colmap(database: str, rows: str) -> None:
    """The cameras and gravity priors of the rows of ``ngp predict`` into the database: a summary line on stdout,
    one line on stderr per image skipped or whose shared camera was kept."""
    from ngp_kornia.colmap import read_predictions, write_colmap_database

    report = write_colmap_database(database, read_predictions(rows))
    for name, reason in {**report.skipped, **report.camera_kept}.items():
        print(f"ngp: colmap: {name}: {reason}", file=sys.stderr)
    print(f"COLMAP database {database}: {report.summary()}")
