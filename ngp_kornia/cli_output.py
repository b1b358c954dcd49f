"""What ``ngp calibrate`` prints per image: a short table on a terminal (for people), JSON lines otherwise (for
programs: ``--json``, or when the output goes to a pipe or a file), and a warning line on stderr for every photo
whose orientation the check doubts. The JSON rows are :func:`ngp_kornia.rows.result_row`, the rows ``ngp predict``
writes.

Example:
    >>> table = Table(["a.jpg", "photos/b.png"])
    >>> print(table.header())
    image         focal px  FoV v deg  pitch deg  roll deg  confidence  warning
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence

__all__ = ["Table", "orientation_doubt", "print_result", "warn_if_turned", "warnings_of"]

#: the widest image column of the table; longer names keep their end (the file name)
_NAME_WIDTH = 40
#: a confidence below this is flagged in the table's warning column
LOW_CONFIDENCE = 0.5


class Table:
    """The terminal table: one header, then one line per image, columns as wide as the longest name needs."""

    def __init__(self, images: Sequence[str]) -> None:
        self.width = max(5, min(_NAME_WIDTH, max((len(name) for name in images), default=5)))
        self.started = False

    def header(self) -> str:
        titles = ("focal px", "FoV v deg", "pitch deg", "roll deg", "confidence")
        return f"{'image':<{self.width}}  " + "  ".join(titles) + "  warning"

    def line(self, image: str, result, doubt: float = 0.5) -> str:
        """The table line of one image's (unbatched) calibration."""
        name = image if len(image) <= self.width else "..." + image[-(self.width - 3) :]
        confidence = "" if result.confidence is None else f"{float(result.confidence):.2f}"
        pitch, roll = (round(float(v), 2) + 0.0 for v in (result.pitch, result.roll))  # no "-0.00"
        cells = (f"{float(result.focal):8.1f}", f"{float(result.fov_v):9.1f}", f"{pitch:9.2f}", f"{roll:8.2f}",
                 f"{confidence:>10}")
        return f"{name:<{self.width}}  " + "  ".join(cells) + f"  {'; '.join(warnings_of(result, doubt))}".rstrip()


def warnings_of(result, doubt: float = 0.5) -> list[str]:
    """Short warnings for the table's last column: no camera found, a low confidence, a photo that looks turned or
    whose upright probability is below ``doubt``."""
    if not bool(result.valid):
        return ["no camera found (valid false)"]
    found = []
    if result.confidence is not None and float(result.confidence) < LOW_CONFIDENCE:
        found.append("low confidence")
    turned = 0 if result.turned is None else int(result.turned)
    if turned:
        found.append(f"looks turned {turned} deg")
    elif result.upright is not None and float(result.upright) < doubt:
        found.append(f"upright {float(result.upright):.2f}")
    return found


def print_result(image: str, result, table: Table | None, doubt: float) -> None:
    """Print one image's result: a table line (the header first) with ``table``, else its JSON row."""
    if table is None:
        from ngp_kornia.rows import result_row

        print(json.dumps(result_row(image, result)), flush=True)
        return
    if not table.started:
        table.started = True
        print(table.header(), flush=True)
    print(table.line(image, result, doubt), flush=True)


def warn_if_turned(image: str, result, doubt: float) -> None:
    """One line on stderr for every photo whose orientation the check doubts (:func:`orientation_doubt`)."""
    doubted = orientation_doubt(image, result, doubt)
    if doubted is not None:
        print(f"ngp: warning: {doubted}", file=sys.stderr, flush=True)


def orientation_doubt(image: str, result, doubt: float) -> str | None:
    """What the orientation check says of a valid (unbatched) answer whose photo it reports turned, or whose upright
    probability is below ``doubt`` (``--upright.doubt``), with that probability; None where it does not doubt (or did
    not run). ``ngp calibrate`` prints it as a warning, ``ngp rectify`` as the reason it refuses the photo."""
    if result.upright is None or not bool(result.valid):
        return None
    upright, turned = float(result.upright), 0 if result.turned is None else int(result.turned)
    if not turned and upright >= doubt:
        return None
    head = f"{image}: upright probability {upright:.2f}"
    if turned and abs(float(result.roll)) > 45.0:
        return (f"{head}, looks turned by {turned} degrees counter-clockwise: answered as the camera of the turned "
                f"photo (roll {float(result.roll):.1f})")  # fmt: skip
    if turned:
        return f"{head}, looks turned by {turned} degrees counter-clockwise: turn it back or give it an orientation tag"
    return f"{head} (below {doubt:g}): it may be turned; if it is, turn it back or give it an orientation tag"
