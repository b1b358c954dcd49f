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
from dataclasses import dataclass, replace

from ngp_kornia.errors import InputError, shown
from ngp_kornia.io.exif import FILM_DIAGONAL_MM

__all__ = ["DEFAULT_GRAVITY_STD", "ESTIMATE", "FOCAL_35MM_RANGE", "MAX_SEED", "Priors", "checked_seed"]

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


#: the 35 mm-equivalent focal lengths (millimetres) a focal-length prior may amount to on its image, whatever its
#: units: from a little wider than the widest rectilinear lenses made (about 9 mm, 135 degrees on the diagonal; a
#: pinhole camera's field of view must stay below 180) to a long telephoto (2000 mm, 1.2 degrees). Beyond, the prior
#: is far likelier a mistake of units (35 millimetres given as 35 pixels is a 2 mm lens on a 640 x 480 photo) than
#: a photo, and a line-based calibration could not use it anyway.
FOCAL_35MM_RANGE = (8.0, 2000.0)

#: the largest focal length a prior may give, in pixels: a field of view of a few ten-thousandths of a degree, where
#: the frame's arithmetic in float32 still holds (at 1e15 it no longer gives a rotation)
MAX_FOCAL = 1e8


#: the three forms of the focal-length prior, of which one may be given
_FOCAL_PRIORS = ("focal", "fov_v", "focal_35mm")


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


def _focal_35mm(value: object) -> float | None:
    low, high = FOCAL_35MM_RANGE
    what = f"a 35 mm-equivalent focal length in [{low:g}, {high:g}] millimetres"
    f35 = _positive(value, "focal_35mm (--focal-35mm)", what)
    if f35 is not None and not low <= f35 <= high:
        raise InputError(f"focal_35mm (--focal-35mm) must be {what} (the widest rectilinear lenses are about 9 mm), "
                         f"got {shown(value)}")
    return f35


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
        fov_v: the vertical field of view in degrees (the same prior in other units).
        focal_35mm: the 35 mm-equivalent focal length in millimetres (the same prior, in the units cameras and
            EXIF give): ``focal = focal_35mm * hypot(W, H) / 43.27``, the diagonal of a 36 x 24 mm frame.
            At most one of ``focal``, ``fov_v`` and ``focal_35mm`` may be given; on an image, the prior must
            amount to a 35 mm-equivalent focal length in :data:`FOCAL_35MM_RANGE` (:meth:`check_image`).
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
    focal_35mm: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "focal", _positive(self.focal, "focal", "a number of pixels in (0, 1e8)", MAX_FOCAL))
        object.__setattr__(self, "fov_v", _positive(self.fov_v, "fov_v", "an angle in (0, 180) degrees", 180.0))
        object.__setattr__(self, "focal_35mm", _focal_35mm(self.focal_35mm))
        given = [f"{name}={shown(getattr(self, name))}" for name in _FOCAL_PRIORS if getattr(self, name) is not None]
        if len(given) > 1:
            raise InputError(f"{' and '.join(given)} were both given; they are one prior in different units: give "
                             "one of focal= (pixels), fov_v= (degrees) and focal_35mm= (millimetres)")
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
        for name in (*_FOCAL_PRIORS, "gravity", "gravity_std", "principal_point", "k1"):
            value = getattr(self, name)
            if value is not None:
                out[name] = list(value) if isinstance(value, tuple) else value
        return out

    @property
    def known_focal(self) -> bool:
        """Whether the focal length is given (in pixels, as a field of view or as a 35 mm equivalent)."""
        return any(getattr(self, name) is not None for name in _FOCAL_PRIORS)

    def focal_pixels(self, height: int, width: int | None = None) -> float | None:
        """The known focal length in pixels of an image ``height`` x ``width`` pixels, or None (``width`` is needed
        for ``focal_35mm`` only).

        Example:
            >>> round(Priors(focal_35mm=35.0).focal_pixels(480, 640), 1)  # diag 800 px: 35 * 800 / 43.27
            647.2
        """
        if self.focal is not None:
            return self.focal
        if self.fov_v is not None:
            return (height / 2.0) / math.tan(math.radians(self.fov_v) / 2.0)
        if self.focal_35mm is not None:
            if width is None:
                raise TypeError("focal_pixels() needs the image's width for a focal_35mm prior")
            return self.focal_35mm * math.hypot(height, width) / FILM_DIAGONAL_MM
        return None

    def focal_in_units(self, height: int, width: int) -> float | None:
        """The known focal length in pseudo-camera units (half the image's long side), or None."""
        focal = self.focal_pixels(height, width)
        return None if focal is None else focal / (max(height, width) / 2.0)

    def with_focal(self, focal: float) -> Priors:
        """These priors with the focal length ``focal`` pixels in place of the one given, in whatever units.

        Example:
            >>> Priors(fov_v=50.0, k1=-0.1).with_focal(500.0).to_dict()
            {'focal': 500.0, 'k1': -0.1}
        """
        return replace(self, focal=focal, fov_v=None, focal_35mm=None)

    def check_image(self, height: int, width: int) -> None:
        """Refuse a focal-length prior that is no camera's on a ``height`` x ``width`` image: one whose 35 mm
        equivalent is outside :data:`FOCAL_35MM_RANGE` (a field of view wider than any rectilinear lens, or
        narrower than a long telephoto's); the message names the likely mistake.

        Raises:
            InputError: e.g. ``focal=35`` on a 640 x 480 image (a 164 degree vertical field of view).

        Example:
            >>> Priors(focal=35.0).check_image(480, 640)
            Traceback (most recent call last):
            ...
            ngp_kornia.errors.InputError: focal=35.0 px on this 640x480 image is a 163.4 degree vertical field ...
        """
        focal = self.focal_pixels(height, width)
        if focal is None or self.focal_35mm is not None:  # checked on construction
            return
        f35 = focal * FILM_DIAGONAL_MM / math.hypot(height, width)
        low, high = FOCAL_35MM_RANGE
        if low <= f35 <= high:
            return
        fov = math.degrees(2.0 * math.atan(height / 2.0 / focal))
        lens, where = f"a {f35:.3g} mm lens on a 35 mm camera", f"on this {width}x{height} image"
        if self.focal is not None:
            head = f"focal={shown(self.focal)} px {where} is a {fov:.1f} degree vertical field of view, {lens}"
        else:
            head = f"fov_v={shown(self.fov_v)} degrees {where} is {lens}"
        if f35 < low and self.focal is not None:
            raise InputError(f"{head}, wider than any rectilinear lens (about {low:g} mm at the widest): is it in "
                             f"millimetres? give it as focal_35mm= (--focal-35mm), or the focal length in pixels")
        if f35 < low:
            raise InputError(f"{head}, wider than any rectilinear lens (about {low:g} mm at the widest): give the "
                             "vertical field of view of the image as displayed (not a fisheye's or the diagonal's)")
        raise InputError(f"{head}, narrower than a {high:g} mm telephoto: give the focal length in pixels of this "
                         "image (scaled with it where the image was resized)")
