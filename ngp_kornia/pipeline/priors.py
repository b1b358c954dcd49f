"""What a caller already knows of the camera, given per call: :class:`Priors`, and the checks of the other per-call
arguments (the sampling seed).

Beside the focal length, a caller may know the direction of gravity (a phone's IMU: pitch and roll with their
uncertainty), the principal point and the lens's radial distortion; the last two may also be asked for: the string
``"estimate"`` estimates them from the image (:mod:`~ngp_kornia.pipeline.principal_point`,
:mod:`~ngp_kornia.pipeline.distortion`) where None keeps the distortion-free pinhole with its principal point at
the image centre.

Priors are inputs, not settings: one parser serves a folder of photos, each with its own priors. Reading a prior
from a file (its EXIF focal length) is done where files are read, in :mod:`ngp_kornia.api`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ngp_kornia.errors import InputError, shown

__all__ = ["DEFAULT_GRAVITY_STD", "ESTIMATE", "MAX_SEED", "Priors", "checked_seed"]

#: seeds are 64-bit: torch.Generator.manual_seed takes [0, 2**64 - 1]
MAX_SEED = 2**64 - 1
#: the value of ``principal_point`` and ``k1`` that asks for an estimate
ESTIMATE = "estimate"
#: the gravity prior's standard deviation when none is given, degrees (a phone's IMU at rest)
DEFAULT_GRAVITY_STD = 1.0


def checked_seed(seed: object) -> int:
    """The sampling seed as an ``int`` (numpy integers and integral tensors accepted).

    Raises:
        InputError: a bool, a non-integer or a seed outside [0, 2**64 - 1].

    Example:
        >>> checked_seed(5)
        5
    """
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise InputError(f"seed must be an integer in [0, 2**64 - 1], got {shown(seed)}")
    if not 0 <= int(seed) <= MAX_SEED:
        raise InputError(f"seed must be in [0, 2**64 - 1], got {shown(seed)}")
    return int(seed)


#: the largest focal length a prior may give, in pixels: a field of view of a few ten-thousandths of a degree, where
#: the frame's arithmetic in float32 still holds (at 1e15 it no longer gives a rotation)
MAX_FOCAL = 1e8


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
        raise InputError(f"{name} must be {what} or None, got {shown(value)}")
    return number


def _finite(value: object) -> float:
    """``float(value)`` for a real number (numpy scalars and one-element tensors too), NaN for anything else."""
    if isinstance(value, (bool, str)):
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _pair(value: object) -> tuple[float, ...]:
    """The numbers of a pair given as a tuple, a list, a 1-d numpy array or a 1-d tensor (NaN for a non-number;
    an empty tuple for anything else)."""
    if hasattr(value, "ndim") and hasattr(value, "tolist") and value.ndim == 1:
        try:
            value = value.tolist()  # numpy arrays and tensors
        except (RuntimeError, NotImplementedError):  # a tensor without values (on the meta device)
            return ()
    return tuple(_finite(v) for v in value) if isinstance(value, (tuple, list)) else ()


def _estimate(value: object) -> bool:
    return isinstance(value, str) and value == ESTIMATE


def _gravity(value: object) -> tuple[float, float] | None:
    if value is None:
        return None
    numbers_ = _pair(value)
    if len(numbers_) != 2 or not all(math.isfinite(v) for v in numbers_):
        raise InputError(
            f"gravity must be (pitch, roll) in degrees, pitch in (-90, 90), roll in [-180, 180], or None; "
            f"got {shown(value)}"
        )
    pitch, roll = numbers_
    if not abs(pitch) < 90.0:  # beyond +-90 the camera would be upside down: a roll of 180 says that
        raise InputError(f"gravity's pitch must be in (-90, 90) degrees (90 looks straight up), got {shown(pitch)}; "
                         "a camera turned upside down has a roll near 180 instead")
    if not abs(roll) <= 180.0:
        raise InputError(f"gravity's roll must be in [-180, 180] degrees, got {shown(roll)}; "
                         "give the angle itself, not a multiple of a full turn (e.g. 10, not 370)")
    return numbers_


def _principal_point(value: object) -> tuple[float, float] | str | None:
    if value is None or _estimate(value):
        return value
    numbers_ = _pair(value)
    if len(numbers_) != 2 or not all(math.isfinite(v) for v in numbers_):
        raise InputError(f"principal_point must be (cx, cy) in pixels, 'estimate' or None; got {shown(value)}")
    return numbers_


def _k1(value: object) -> float | str | None:
    if value is None or _estimate(value):
        return value
    number = _finite(value)
    if not -1.0 <= number <= 1.0:
        raise InputError(f"k1 must be a number in [-1, 1] (the division model's coefficient), 'estimate' or None; "
                         f"got {shown(value)}")
    return number


@dataclass(frozen=True)
class Priors:
    """What is known of the camera before calibration (checked on construction).

    Attributes:
        focal: the focal length in pixels of the input image; every frame candidate then uses it.
        fov_v: the vertical field of view in degrees (the same prior in other units); ignored when ``focal`` is
            given.
        gravity: ``(pitch, roll)`` in degrees, the camera's up direction as an IMU measures it (the conventions of
            :class:`~ngp_kornia.pipeline.result.Calibration`); the frame and horizon searches keep to it
            (:mod:`~ngp_kornia.pipeline.gravity`).
        gravity_std: its standard deviation per angle, degrees (:data:`DEFAULT_GRAVITY_STD` when omitted); only
            with ``gravity``.
        principal_point: ``(cx, cy)`` in pixels of the input image, ``"estimate"``, or None for the image centre.
            Pairs (this and ``gravity``) may be tuples, lists, 1-d numpy arrays or 1-d tensors.
        k1: the division model's radial distortion (:mod:`ngp_kornia.geometry.lens`), ``"estimate"``, or None
            for a distortion-free pinhole.

    Example:
        >>> Priors(fov_v=90.0).focal_in_units(480, 640)
        0.75
        >>> Priors(focal=True)
        Traceback (most recent call last):
        ...
        ngp_kornia.errors.InputError: focal must be a number of pixels in (0, 1e8) or None, got True
    """

    focal: float | None = None
    fov_v: float | None = None
    gravity: tuple[float, float] | None = None
    gravity_std: float | None = None
    principal_point: tuple[float, float] | str | None = None
    k1: float | str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "focal", _positive(self.focal, "focal", "a number of pixels in (0, 1e8)", MAX_FOCAL))
        object.__setattr__(self, "fov_v", _positive(self.fov_v, "fov_v", "an angle in (0, 180) degrees", 180.0))
        object.__setattr__(self, "gravity", _gravity(self.gravity))
        std = _positive(self.gravity_std, "gravity_std", "a number of degrees in (0, 90)", 90.0)
        if std is not None and self.gravity is None:
            raise InputError("gravity_std was given without gravity; give gravity=(pitch, roll) too, or neither")
        object.__setattr__(self, "gravity_std", DEFAULT_GRAVITY_STD if std is None and self.gravity else std)
        object.__setattr__(self, "principal_point", _principal_point(self.principal_point))
        object.__setattr__(self, "k1", _k1(self.k1))

    def to_dict(self) -> dict:
        """The priors given, as plain JSON-able values (the entries that are not None).

        Example:
            >>> Priors(focal=500.0, gravity=(2.0, -1.0)).to_dict()
            {'focal': 500.0, 'gravity': [2.0, -1.0], 'gravity_std': 1.0}
        """
        out = {}
        for name in ("focal", "fov_v", "gravity", "gravity_std", "principal_point", "k1"):
            value = getattr(self, name)
            if value is not None:
                out[name] = list(value) if isinstance(value, tuple) else value
        return out

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
