"""What a caller already knows of the camera, given per call: :class:`Priors`, and the checks of the other per-call
arguments (the sampling seed).

Beside the focal length, a caller may know the direction of gravity (a phone's IMU: pitch and roll with their
uncertainty), the principal point and the lens's radial distortion; the last two may also be asked for: the string
``"estimate"`` estimates them from the image (:mod:`~ngp_kornia.pipeline.principal_point`,
:mod:`~ngp_kornia.pipeline.distortion`) where None keeps the distortion-free pinhole with its principal point at
the image centre.

Priors are inputs, not settings: one parser serves a folder of photos, each with its own priors. Each prior is one
value for every image, or one per image of a batch or a list ((B,) or (B, 2) tensors, arrays or lists; in a list an
image without the prior has None), so one call carries different priors and each image gets what it gets alone
with its own. Reading a prior from a file (its EXIF focal length) is done where files are read
(:mod:`~ngp_kornia.pipeline.runner`).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ngp_kornia.errors import InputError, shown
from ngp_kornia.pipeline.focal_prior import (
    FOCAL_35MM_RANGE,
    check_focal_on_image,
    checked_focal,
    checked_focal_35mm,
    checked_fov_v,
    focal_pixels_of,
    positive_number,
)
from ngp_kornia.suggest import did_you_mean

__all__ = [
    "CALL_PRIORS",
    "DEFAULT_GRAVITY_STD",
    "ESTIMATE",
    "FOCAL_35MM_RANGE",
    "INTRINSIC_PRIORS",
    "MAX_SEED",
    "PRIOR_NAMES",
    "PerImage",
    "Priors",
    "checked_priors",
    "checked_seed",
]

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


#: the three forms of the focal-length prior, of which one may be given
_FOCAL_PRIORS = ("focal", "fov_v", "focal_35mm")
#: every prior, as :class:`Priors` names them
PRIOR_NAMES = (*_FOCAL_PRIORS, "gravity", "gravity_std", "principal_point", "k1")
#: the priors of the camera itself (its lens and sensor), which photos of one camera share; gravity is the pose's
INTRINSIC_PRIORS = (*_FOCAL_PRIORS, "principal_point", "k1")
#: the entries of ``ngp_kornia.calibrate(priors=...)`` beside :class:`Priors`' own: whether to read a file's EXIF
#: focal length, and whether the photos are one camera's (read where files are read and photos run together)
CALL_PRIORS = ("exif", "shared_intrinsics")


def _gravity_std(value: object) -> float | None:
    return positive_number(value, "gravity_std", "a number of degrees in (0, 90)", 90.0)


def _finite(value: object) -> float:
    """``float(value)`` for a real number (numpy scalars and one-element tensors too), NaN for anything else."""
    if isinstance(value, (bool, str)):
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError, RuntimeError):
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


#: each prior's check of one value, and whether its value is a pair
_CHECKS: dict[str, tuple[Callable[[object], object], bool]] = {
    "focal": (checked_focal, False),
    "fov_v": (checked_fov_v, False),
    "gravity": (_gravity, True),
    "gravity_std": (_gravity_std, False),
    "principal_point": (_principal_point, True),
    "k1": (_k1, False),
    "focal_35mm": (checked_focal_35mm, False),
}


class PerImage(tuple):
    """A prior's values, one per image (None where an image has none); :class:`Priors` makes them of what a caller
    gives per image."""

    __slots__ = ()

    def __repr__(self) -> str:
        return f"PerImage({list(self)!r})"


def _scalar(value: object) -> bool:
    """A number (a numpy scalar, a 0-d tensor), not a sequence of them."""
    return isinstance(value, numbers.Number) or (hasattr(value, "ndim") and value.ndim == 0)


def _per_image(value: object, pair: bool) -> list | None:
    """The entries of a prior given per image, or None for one value for all: a (B,) tensor, array, list or tuple
    of values, or (B, 2) of pairs (a tuple or list of two numbers, or a 1-d tensor, is one pair)."""
    if isinstance(value, PerImage):
        return list(value)
    if hasattr(value, "ndim") and hasattr(value, "tolist"):
        if value.ndim != (2 if pair else 1):
            return None
        try:
            return value.tolist()
        except (RuntimeError, NotImplementedError):  # a tensor without values (on the meta device)
            return None
    if not isinstance(value, (list, tuple)) or (pair and all(_scalar(v) for v in value)):
        return None
    return list(value)


def _checked(name: str, value: object) -> object:
    """A prior's value checked: one value, or :class:`PerImage` entries, each checked (the error names the image)."""
    check, pair = _CHECKS[name]
    entries = _per_image(value, pair)
    if entries is None:
        return check(value)
    if not entries:
        raise InputError(f"{name} was given as an empty list; give one value, or one per image")
    out = []
    for i, entry in enumerate(entries):
        try:
            out.append(check(entry))
        except InputError as err:
            raise InputError(f"image {i}: {err}") from None
    return PerImage(out) if len(out) > 1 else out[0]  # one value given per image of one: one for all


def _entries(value: object, count: int) -> list:
    """A checked value as ``count`` per-image entries (one value for all repeated)."""
    return list(value) if isinstance(value, PerImage) else [value] * count


@dataclass(frozen=True)
class Priors:
    """What is known of the camera before calibration (checked on construction).

    Every prior is one value for every image, or one per image of a batch or a list: a (B,) or (B, 2) tensor or
    array, or a list of B values (None where an image has none; in one batched tensor a prior is given for every
    image or for none, as one batched result has one set of fields). Per-image values are kept as
    :class:`PerImage`; :meth:`image` gives one image's priors.

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
        >>> Priors(focal=torch.tensor([500.0, 600.0])).image(1).focal
        600.0
        >>> Priors(focal=True)
        Traceback (most recent call last):
        ...
        ngp_kornia.errors.InputError: focal must be a number of pixels in (0, 1e8) or None, got True
    """

    focal: float | PerImage | None = None
    fov_v: float | PerImage | None = None
    gravity: tuple[float, float] | PerImage | None = None
    gravity_std: float | PerImage | None = None
    principal_point: tuple[float, float] | str | PerImage | None = None
    k1: float | str | PerImage | None = None
    focal_35mm: float | PerImage | None = None

    def __post_init__(self) -> None:
        for name in PRIOR_NAMES:
            object.__setattr__(self, name, _checked(name, getattr(self, name)))
        given = [f"{name}={shown(getattr(self, name))}" for name in _FOCAL_PRIORS if _given(getattr(self, name))]
        if len(given) > 1:
            raise InputError(f"{' and '.join(given)} were both given; they are one prior in different units: give "
                             "one of focal= (pixels), fov_v= (degrees) and focal_35mm= (millimetres)")
        self._default_gravity_std()

    def _default_gravity_std(self) -> None:
        """``gravity_std`` checked against ``gravity`` image by image, :data:`DEFAULT_GRAVITY_STD` where omitted."""
        count = self.count or 1
        gravity, std = _entries(self.gravity, count), _entries(self.gravity_std, count)
        for i, (up, spread) in enumerate(zip(gravity, std, strict=True)):
            if spread is not None and up is None:
                where = f" for image {i}" if self.count else ""
                raise InputError(f"gravity_std was given without gravity{where}; give gravity=(pitch, roll) too, "
                                 "or neither")
        if any(up is not None for up in gravity):
            pairs = zip(gravity, std, strict=True)
            stds = [DEFAULT_GRAVITY_STD if spread is None and up is not None else spread for up, spread in pairs]
            object.__setattr__(self, "gravity_std", PerImage(stds) if self.count else stds[0])

    @property
    def count(self) -> int | None:
        """How many images the priors give values for (None: one value for every image; a single value given per
        image is one for every image).

        Raises:
            InputError: priors given for different numbers of images.
        """
        counts = {name: len(v) for name in PRIOR_NAMES if isinstance(v := getattr(self, name), PerImage)}
        if len(set(counts.values())) > 1:
            named = " and ".join(f"{name} for {n}" for name, n in counts.items())
            raise InputError(f"priors given per image for different numbers of images ({named}); give one per image")
        return next(iter(counts.values()), None)

    def image(self, index: int) -> Priors:
        """The priors of image ``index`` (one value each).

        Example:
            >>> Priors(k1=["estimate", -0.1], gravity=(2.0, 1.0)).image(1).to_dict()
            {'gravity': [2.0, 1.0], 'gravity_std': 1.0, 'k1': -0.1}
        """
        count = self.count
        if not count:
            return self
        if not 0 <= index < count:
            raise IndexError(f"image {index} of priors given for {count} images")
        return Priors(**{name: _entries(getattr(self, name), count)[index] for name in PRIOR_NAMES})

    def for_batch(self, batch: int, what: str = "batch") -> Priors:
        """These priors for a ``batch`` of images: one value each where every image has the same, :class:`PerImage`
        where they differ.

        Raises:
            InputError: priors given for another number of images; in a batched tensor (``what="batch"``), a prior
                given for some images and not others, or estimated for some and given for others.
        """
        count = self.count
        if count is not None and count != batch:
            given = next(n for n in PRIOR_NAMES if isinstance(v := getattr(self, n), PerImage) and len(v) == count)
            raise InputError(f"{given} was given for {count} images, one per image, but the {what} has {batch}; "
                             "give one value for all or one per image")
        changes = {}
        for name in PRIOR_NAMES:
            value = getattr(self, name)
            if not isinstance(value, PerImage):
                continue
            entries = _entries(value, batch)
            if all(e == entries[0] for e in entries):
                changes[name] = entries[0]
            elif what == "batch":
                _check_one_kind(name, entries)
        return replace(self, **changes) if changes else self

    def each(self, name: str, count: int) -> list:
        """The values of prior ``name`` for ``count`` images, one per image (None where an image has none).

        Example:
            >>> Priors(gravity=(2.0, 1.0)).each("gravity", 2)
            [(2.0, 1.0), (2.0, 1.0)]
        """
        return _entries(getattr(self, name), count)

    def to_dict(self) -> dict:
        """The priors given, as plain JSON-able values (the entries that are not None; a list per image for those
        given per image).

        Example:
            >>> Priors(focal=500.0, gravity=(2.0, -1.0)).to_dict()
            {'focal': 500.0, 'gravity': [2.0, -1.0], 'gravity_std': 1.0}
        """
        out = {}
        for name in PRIOR_NAMES:
            value = getattr(self, name)
            if isinstance(value, PerImage):
                out[name] = [list(v) if isinstance(v, tuple) else v for v in value]
            elif value is not None:
                out[name] = list(value) if isinstance(value, tuple) else value
        return out

    @property
    def known_focal(self) -> bool:
        """Whether the focal length is given (in pixels, as a field of view or as a 35 mm equivalent; for priors
        per image, for any image)."""
        return any(_given(getattr(self, name)) for name in _FOCAL_PRIORS)

    def focal_pixels(self, height: int, width: int | None = None) -> float | None:
        """The known focal length in pixels of an image ``height`` x ``width`` pixels, or None (``width`` is needed
        for ``focal_35mm`` only); one value for all images (:meth:`focal_units` for one per image).

        Example:
            >>> round(Priors(focal_35mm=35.0).focal_pixels(480, 640), 1)  # diag 800 px: 35 * 800 / 43.27
            647.2
        """
        if self.count:
            raise TypeError("focal_pixels() takes one focal length for all images; these priors give one per image")
        return focal_pixels_of(self.focal, self.fov_v, self.focal_35mm, height, width)

    def focal_in_units(self, height: int, width: int) -> float | None:
        """The known focal length in pseudo-camera units (half the image's long side), or None; one for all."""
        focal = self.focal_pixels(height, width)
        return None if focal is None else focal / (max(height, width) / 2.0)

    def focal_units(self, height: int, width: int, like: Tensor) -> Tensor | None:
        """The known focal length of each image in pseudo-camera units (half the image's long side), (B,) in
        ``like``'s dtype and device for ``B = len(like)``, or None without one (a batch has one for every image).

        Example:
            >>> Priors(fov_v=[90.0, 60.0]).focal_units(480, 640, torch.zeros(2)).tolist()
            [0.75, 1.299038052558899]
        """
        focal = self.focal_each(height, width, len(like))
        if focal is None:
            return None
        half = max(height, width) / 2.0
        return torch.tensor([f / half for f in focal], dtype=torch.float64, device=like.device).to(like.dtype)

    def focal_each(self, height: int, width: int, count: int) -> list[float] | None:
        """The known focal length in pixels of each of ``count`` images of ``height`` x ``width`` pixels, or None
        without one.

        Example:
            >>> Priors(focal=[500.0, 600.0]).focal_each(480, 640, 2)
            [500.0, 600.0]
        """
        if not self.known_focal:
            return None
        if not self.count:
            return [self.focal_pixels(height, width)] * count
        return [self.image(i).focal_pixels(height, width) for i in range(count)]

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
        narrower than a long telephoto's); the message names the likely mistake (and the image, per image).

        Raises:
            InputError: e.g. ``focal=35`` on a 640 x 480 image (a 164 degree vertical field of view).

        Example:
            >>> Priors(focal=35.0).check_image(480, 640)
            Traceback (most recent call last):
            ...
            ngp_kornia.errors.InputError: focal=35.0 px on this 640x480 image is a 163.4 degree vertical field ...
        """
        if self.count:
            for i in range(self.count):
                try:
                    self.image(i).check_image(height, width)
                except InputError as err:
                    raise InputError(f"image {i}: {err}") from None
            return
        check_focal_on_image(self.focal, self.fov_v, self.focal_35mm, height, width)


def _given(value: object) -> bool:
    """Whether a checked prior is given (for any image)."""
    return any(v is not None for v in value) if isinstance(value, PerImage) else value is not None


def _check_one_kind(name: str, entries: list) -> None:
    """Refuse a prior given for some images of a batch and not for others (or estimated for some)."""
    kinds = ["none" if e is None else "estimate" if _estimate(e) else "value" for e in entries]
    first = next((i for i, kind in enumerate(kinds) if kind != kinds[0]), None)
    if first is None:
        return
    words = {"none": "not given", "estimate": "'estimate'", "value": "given"}
    raise InputError(f"{name} is {words[kinds[0]]} for image 0 but {words[kinds[first]]} for image {first}: in one "
                     "batched tensor a prior is given (or estimated) for every image or for none, as the result has "
                     "one set of fields; calibrate a list of images to mix them")


def checked_priors(priors: object, extra: tuple[str, ...] = ()) -> Priors:
    """The priors a caller passed: a :class:`Priors`, a mapping of its entries (``{"focal": 500.0}``), or None for
    none. ``extra``: the names a caller's mapping may also hold, taken out before (said in the message).

    Raises:
        InputError: an unknown entry (the closest names suggested), or anything else.

    Example:
        >>> checked_priors({"fov_v": 50.0}).fov_v
        50.0
    """
    if priors is None:
        return Priors()
    if isinstance(priors, Priors):
        return priors
    if isinstance(priors, Mapping) and all(isinstance(key, str) for key in priors):
        unknown = [key for key in priors if key not in PRIOR_NAMES]
        if unknown:
            names = (*PRIOR_NAMES, *extra)
            raise InputError(f"unknown prior {unknown[0]!r}; {did_you_mean(unknown[0], names)}the priors are "
                             f"{', '.join(names)}")
        return Priors(**priors)
    raise InputError(f"priors must be a mapping such as {{'focal': 500.0}}, a Priors or None; got {shown(priors)}")
