"""What a caller already knows of the camera, given per call: :class:`Priors`, and the checks of the other per-call
arguments (the sampling seed).

Priors are inputs, not settings: one parser serves a folder of photos, each with its own priors. Reading a prior
from a file (its EXIF focal length) is done where files are read, in :mod:`ngp_kornia.api`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ngp_kornia.errors import InputError

__all__ = ["MAX_SEED", "Priors", "checked_seed"]

#: seeds are 64-bit: torch.Generator.manual_seed takes [0, 2**64 - 1]
MAX_SEED = 2**64 - 1


def checked_seed(seed: object) -> int:
    """The sampling seed as an ``int`` (numpy integers and integral tensors accepted).

    Raises:
        InputError: a bool, a non-integer or a seed outside [0, 2**64 - 1].

    Example:
        >>> checked_seed(5)
        5
    """
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise InputError(f"seed must be an integer in [0, 2**64 - 1], got {seed!r}")
    if not 0 <= int(seed) <= MAX_SEED:
        raise InputError(f"seed must be in [0, 2**64 - 1], got {seed!r}")
    return int(seed)


def _positive(value: object, name: str, what: str, high: float = math.inf) -> float | None:
    if value is None:
        return None
    number = float("nan")
    if not isinstance(value, bool):
        try:
            number = float(value)  # numbers, numpy scalars and one-element tensors
        except (TypeError, ValueError):
            pass
    if not (math.isfinite(number) and 0 < number < high):
        raise InputError(f"{name} must be {what} or None, got {value!r}")
    return number


@dataclass(frozen=True)
class Priors:
    """What is known of the camera before calibration (checked on construction).

    Attributes:
        focal: the focal length in pixels of the input image; every frame candidate then uses it.
        fov_v: the vertical field of view in degrees (the same prior in other units); ignored when ``focal`` is
            given.

    Example:
        >>> Priors(fov_v=90.0).focal_in_units(480, 640)
        0.75
        >>> Priors(focal=True)
        Traceback (most recent call last):
        ...
        ngp_kornia.errors.InputError: focal must be a positive number of pixels or None, got True
    """

    focal: float | None = None
    fov_v: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "focal", _positive(self.focal, "focal", "a positive number of pixels"))
        object.__setattr__(self, "fov_v", _positive(self.fov_v, "fov_v", "an angle in (0, 180) degrees", 180.0))

    @property
    def known_focal(self) -> bool:
        """Whether the focal length is given (in pixels or as a field of view)."""
        return self.focal is not None or self.fov_v is not None

    def focal_pixels(self, height: int) -> float | None:
        """The known focal length in pixels of an image ``height`` pixels high, or None."""
        if self.focal is not None:
            return self.focal
        if self.fov_v is not None:
            return (height / 2.0) / math.tan(math.radians(self.fov_v) / 2.0)
        return None

    def focal_in_units(self, height: int, width: int) -> float | None:
        """The known focal length in pseudo-camera units (half the image's long side), or None."""
        focal = self.focal_pixels(height)
        return None if focal is None else focal / (max(height, width) / 2.0)
