"""The strip below an overlay (:func:`ngp_kornia.viz.draw_calibration`): the answer's numbers, then a key of what is
drawn (each colour and shape with a sample of it), laid out left to right and wrapped to the image's width, on a
dark band of its own, so that it never covers the photo or the lines drawn on it.

Example:
    >>> strip = key_strip(320, ["focal 500 px", "pitch 2.0 deg"], [KeyEntry("horizon", (255, 220, 0), "thick")])
    >>> strip.shape[1], strip.dtype.name, strip.shape[0] < 80
    (320, 'uint8', True)
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

__all__ = ["ICONS", "KeyEntry", "key_strip"]

#: the samples a key entry may show: a thin line, a thick one, a dashed one, an up arrow, a ring, a border pointer
ICONS = ("line", "thick", "dashed", "up", "ring", "arrow")
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BACKGROUND = (24, 24, 24)
_TEXT = (255, 255, 255)


class KeyEntry(NamedTuple):
    """One entry of the key: its words, the colour of its sample and the sample's shape (one of :data:`ICONS`)."""

    label: str
    colour: tuple[int, int, int]
    icon: str


def key_strip(width: int, numbers: list[str], entries: list[KeyEntry]) -> np.ndarray:
    """A dark (height, width, 3) uint8 RGB band: the ``numbers`` in white, then the ``entries`` with their samples,
    each group starting on a new row, rows wrapped to ``width``; the text scales with the width."""
    scale = float(np.clip(width / 1300.0, 0.35, 1.1))
    widest = max(cv2.getTextSize(text, _FONT, scale, 1)[0][0] for text in [*numbers, *(e.label for e in entries)])
    scale *= min(1.0, (width - 12 - 3 * scale * 22) / max(widest, 1))  # a narrow image: its longest words still fit
    thick = 1 if scale < 0.8 else 2
    (_, text_h), base = cv2.getTextSize("Mg", _FONT, scale, thick)
    pad, gap, icon = max(4, int(8 * scale)), max(8, int(22 * scale)), int(2.6 * text_h)
    row = text_h + base + pad
    items = [(text, None) for text in numbers]
    placed, x, y = [], pad, pad + text_h
    for index, (label, entry) in enumerate([*items, *((e.label, e) for e in entries)]):
        size = cv2.getTextSize(label, _FONT, scale, thick)[0][0] + (icon + pad if entry else 0)
        new_group = index == len(items) and index > 0  # the key starts on a row of its own
        if x > pad and (x + size > width - pad or new_group):
            x, y = pad, y + row
        placed.append((x, y, label, entry))
        x += size + gap
    strip = np.empty((y + base + pad, width, 3), np.uint8)
    strip[:] = _BACKGROUND
    for x, y, label, entry in placed:
        if entry is not None:
            _icon(strip, entry, (x, y - text_h // 2), icon, text_h, max(1, int(round(2 * scale))))
            x += icon + pad
        colour = _TEXT if entry is None or entry.icon in ("ring", "arrow", "up") else entry.colour
        cv2.putText(strip, label, (x, y), _FONT, scale, colour, thick, cv2.LINE_AA)
    return strip


def _icon(strip: np.ndarray, entry: KeyEntry, left: tuple[int, int], length: int, text_h: int, width: int) -> None:
    """Draw an entry's sample from ``left`` (its left end at mid text height) over ``length`` pixels."""
    x, y = left
    end = (x + length, y)
    if entry.icon == "line":
        cv2.line(strip, (x, y), end, entry.colour, max(1, width // 2 + 1), cv2.LINE_AA)
    elif entry.icon == "thick":
        cv2.line(strip, (x, y), end, entry.colour, 2 * width, cv2.LINE_AA)
    elif entry.icon == "dashed":
        step = max(3, length // 5)
        for start in range(x, x + length, 2 * step):
            cv2.line(strip, (start, y), (min(start + step, x + length), y), entry.colour, width + 1, cv2.LINE_AA)
    elif entry.icon == "up":
        mid, reach = x + length // 2, max(3, text_h * 3 // 4)
        cv2.arrowedLine(strip, (mid, y + reach), (mid, y - reach), entry.colour, width, cv2.LINE_AA, tipLength=0.45)
        cv2.circle(strip, (mid, y + reach), width + 1, entry.colour, -1, cv2.LINE_AA)
    elif entry.icon == "ring":
        mid, radius = (x + length // 2, y), max(3, text_h * 2 // 3)
        cv2.circle(strip, mid, radius, entry.colour, width, cv2.LINE_AA)
        cv2.drawMarker(strip, mid, entry.colour, cv2.MARKER_CROSS, radius, max(1, width // 2), cv2.LINE_AA)
    else:  # a pointer at the border, towards a vanishing point off the image
        size = max(3, text_h * 2 // 3)
        tip = x + length // 2 + size
        triangle = np.array([(tip, y), (tip - 2 * size, y - size), (tip - 2 * size, y + size)])
        cv2.fillPoly(strip, [triangle], entry.colour, cv2.LINE_AA)
