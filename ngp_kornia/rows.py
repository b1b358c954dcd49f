"""The rows the package writes for a calibrated image (``ngp calibrate --json``, ``ngp predict``): made here only,
so that the two commands give the same row for the same file.

A row is ``{"image": <name>, **Calibration.to_dict()}`` with every float rounded to :data:`SIGNIFICANT` significant
digits: a float32 result carries about seven, of which the last is noise (``660.2574462890625`` is ``660.257``
within a millionth). Rounding happens here, at output; the result's tensors keep every digit.

Example:
    >>> rounded({"focal": 660.2574462890625, "K": [[1.0, 0.0], [2e-09, 319.5]], "valid": True, "turned": 0})
    {'focal': 660.257, 'K': [[1.0, 0.0], [2e-09, 319.5]], 'valid': True, 'turned': 0}
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ngp_kornia.pipeline.result import Calibration

__all__ = ["SIGNIFICANT", "result_row", "rounded"]

#: significant digits of the floats in a row
SIGNIFICANT = 6


def rounded(value: object, digits: int = SIGNIFICANT) -> object:
    """``value`` with every float in it (in nested dicts, lists and tuples, as lists) rounded to ``digits``
    significant digits; other values as they are."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}")
    if isinstance(value, dict):
        return {key: rounded(item, digits) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(item, digits) for item in value]
    return value


def result_row(image: str, result: Calibration) -> dict:
    """The row of one image's (unbatched) calibration: its name first, then the result's fields, rounded.

    Example:
        >>> import torch
        >>> from ngp_kornia import calibrate
        >>> result = calibrate(torch.rand(3, 48, 64))
        >>> row = result_row("x.png", result)
        >>> list(row)[:3], row["focal"] == float(f"{float(result.focal):.6g}")
        (['image', 'K', 'R'], True)
    """
    return {"image": image, **rounded(result.to_dict())}
