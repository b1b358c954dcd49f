"""What ``ngp calibrate`` prints per image: a short table on a terminal (for people), JSON lines otherwise (for
programs: ``--json``, or when the output goes to a pipe or a file), and a warning line on stderr for a photo that
looks turned. The JSON rows are :func:`ngp_kornia.rows.result_row`, the rows ``ngp predict`` writes.

Example:
    >>> table = Table(["a.jpg", "photos/b.png"])
    >>> print(table.header())
    image         focal px  FoV v deg  pitch deg  roll deg  confidence  warning
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence

__all__ = ["Table", "print_result", "warn_if_turned", "warnings_of"]

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

    def line(self, image: str, result, sure: float = 0.995) -> str:
        """The table line of one image's (unbatched) calibration."""
        name = image if len(image) <= self.width else "..." + image[-(self.width - 3) :]
        confidence = "" if result.confidence is None else f"{float(result.confidence):.2f}"
        pitch, roll = (round(float(v), 2) + 0.0 for v in (result.pitch, result.roll))  # no "-0.00"
        cells = (f"{float(result.focal):8.1f}", f"{float(result.fov_v):9.1f}", f"{pitch:9.2f}", f"{roll:8.2f}",
                 f"{confidence:>10}")
        return f"{name:<{self.width}}  " + "  ".join(cells) + f"  {'; '.join(warnings_of(result, sure))}".rstrip()


def warnings_of(result, sure: float = 0.995) -> list[str]:
    """Short warnings for the table's last column: no camera found, a low confidence, a photo that looks turned."""
    if not bool(result.valid):
        return ["no camera found (valid false)"]
    found = []
    if result.confidence is not None and float(result.confidence) < LOW_CONFIDENCE:
        found.append("low confidence")
    turned = 0 if result.turned is None else int(result.turned)
    if turned and result.upright is not None and float(result.upright) < 1.0 - sure:
        found.append(f"looks turned {turned} deg")
    return found


def print_result(image: str, result, table: Table | None, sure: float) -> None:
    """Print one image's result: a table line (the header first) with ``table``, else its JSON row."""
    if table is None:
        from ngp_kornia.rows import result_row

        print(json.dumps(result_row(image, result)), flush=True)
        return
    if not table.started:
        table.started = True
        print(table.header(), flush=True)
    print(table.line(image, result, sure), flush=True)


def warn_if_turned(image: str, result, sure: float) -> None:
    """One line on stderr where the orientation check is sure enough that the photo is turned to act on it (its
    upright probability below ``1 - sure``): either the answer is the turned camera's (its roll beyond 45 degrees,
    ``upright.turn_back``), or it is that of a camera rolled the other way and its confidence was scaled."""
    turned = 0 if result.turned is None else int(result.turned)
    if turned and bool(result.valid) and float(result.upright) < 1.0 - sure:
        head = f"ngp: warning: {image} looks turned by {turned} degrees counter-clockwise"
        if abs(float(result.roll)) > 45.0:
            tail = f"answered as the camera of a turned photo (roll {float(result.roll):.1f})"
        else:
            tail = "turn it back or give it an orientation tag, then calibrate it again"
        print(f"{head} (upright probability {float(result.upright):.2f}): {tail}", file=sys.stderr, flush=True)
