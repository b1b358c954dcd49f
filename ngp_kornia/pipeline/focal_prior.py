"""The focal-length prior in its three units (pixels, the vertical field of view in degrees, the 35 mm equivalent in
millimetres): each value's check, the conversion to pixels, and the refusal of one that no camera has on its image
(:class:`~ngp_kornia.pipeline.priors.Priors` holds the priors)."""

from __future__ import annotations

import math

from ngp_kornia.errors import InputError, shown
from ngp_kornia.io.exif import FILM_DIAGONAL_MM

__all__ = [
    "FOCAL_35MM_RANGE",
    "MAX_FOCAL",
    "check_focal_on_image",
    "checked_focal",
    "checked_focal_35mm",
    "checked_fov_v",
    "focal_pixels_of",
    "positive_number",
]

#: the 35 mm-equivalent focal lengths (millimetres) a focal-length prior may amount to on its image, whatever its
#: units: from a little wider than the widest rectilinear lenses made (about 9 mm, 135 degrees on the diagonal; a
#: pinhole camera's field of view must stay below 180) to a long telephoto (2000 mm, 1.2 degrees). Beyond, the prior
#: is far likelier a mistake of units (35 millimetres given as 35 pixels is a 2 mm lens on a 640 x 480 photo) than
#: a photo, and a line-based calibration could not use it anyway.
FOCAL_35MM_RANGE = (8.0, 2000.0)

#: the largest focal length a prior may give, in pixels: a field of view of a few ten-thousandths of a degree, where
#: the frame's arithmetic in float32 still holds (at 1e15 it no longer gives a rotation)
MAX_FOCAL = 1e8


def positive_number(value: object, name: str, what: str, high: float = math.inf) -> float | None:
    """``value`` as a float in (0, ``high``), or None for None.

    Raises:
        InputError: anything else, named ``name`` and described as ``what``.

    Example:
        >>> positive_number(2, "gravity_std", "a number of degrees")
        2.0
    """
    if value is None:
        return None
    number = float("nan")
    if not isinstance(value, bool):
        try:
            number = float(value)  # numbers, numpy scalars and one-element tensors
        except (TypeError, ValueError, RuntimeError):
            pass
    if not (math.isfinite(number) and 0 < number < high):
        raise InputError(f"{name} must be {what} or None, got {shown(value)}")
    return number


def checked_focal(value: object) -> float | None:
    """A focal length in pixels, or None (:func:`positive_number`)."""
    return positive_number(value, "focal", "a number of pixels in (0, 1e8)", MAX_FOCAL)


def checked_fov_v(value: object) -> float | None:
    """A vertical field of view in degrees, or None (:func:`positive_number`)."""
    return positive_number(value, "fov_v", "an angle in (0, 180) degrees", 180.0)


def checked_focal_35mm(value: object) -> float | None:
    """A 35 mm-equivalent focal length in millimetres within :data:`FOCAL_35MM_RANGE`, or None."""
    low, high = FOCAL_35MM_RANGE
    what = f"a 35 mm-equivalent focal length in [{low:g}, {high:g}] millimetres"
    f35 = positive_number(value, "focal_35mm (--focal-35mm)", what)
    if f35 is not None and not low <= f35 <= high:
        raise InputError(f"focal_35mm (--focal-35mm) must be {what} (the widest rectilinear lenses are about 9 mm), "
                         f"got {shown(value)}")
    return f35


def focal_pixels_of(
    focal: float | None, fov_v: float | None, focal_35mm: float | None, height: int, width: int | None = None
) -> float | None:
    """The focal length in pixels of a ``height`` x ``width`` image given in one of the three units (the others
    None), or None; ``width`` is needed for ``focal_35mm`` only.

    Example:
        >>> round(focal_pixels_of(None, 90.0, None, 480), 1)
        240.0
    """
    if focal is not None:
        return focal
    if fov_v is not None:
        return (height / 2.0) / math.tan(math.radians(fov_v) / 2.0)
    if focal_35mm is not None:
        if width is None:
            raise TypeError("the focal length in pixels needs the image's width for a focal_35mm prior")
        return focal_35mm * math.hypot(height, width) / FILM_DIAGONAL_MM
    return None


def check_focal_on_image(
    focal_px: float | None, fov_v: float | None, focal_35mm: float | None, height: int, width: int
) -> None:
    """Refuse a focal length (one of the three units, checked values) that no camera has on a ``height`` x ``width``
    image: a 35 mm equivalent outside :data:`FOCAL_35MM_RANGE`; the message names the likely mistake.

    Raises:
        InputError: e.g. ``focal=35`` on a 640 x 480 image (a 164 degree vertical field of view).
    """
    given = focal_px
    focal = focal_pixels_of(focal_px, fov_v, focal_35mm, height, width)
    if focal is None or focal_35mm is not None:  # checked on construction
        return
    f35 = focal * FILM_DIAGONAL_MM / math.hypot(height, width)
    low, high = FOCAL_35MM_RANGE
    if low <= f35 <= high:
        return
    fov = math.degrees(2.0 * math.atan(height / 2.0 / focal))
    lens, where = f"a {f35:.3g} mm lens on a 35 mm camera", f"on this {width}x{height} image"
    if given is not None:
        head = f"focal={shown(given)} px {where} is a {fov:.1f} degree vertical field of view, {lens}"
    else:
        head = f"fov_v={shown(fov_v)} degrees {where} is {lens}"
    if f35 < low and given is not None:
        raise InputError(f"{head}, wider than any rectilinear lens (about {low:g} mm at the widest): is it in "
                         f"millimetres? give it as focal_35mm= (--focal-35mm), or the focal length in pixels")
    if f35 < low:
        raise InputError(f"{head}, wider than any rectilinear lens (about {low:g} mm at the widest): give the "
                         "vertical field of view of the image as displayed (not a fisheye's or the diagonal's)")
    raise InputError(f"{head}, narrower than a {high:g} mm telephoto: give the focal length in pixels of this "
                     "image (scaled with it where the image was resized)")
