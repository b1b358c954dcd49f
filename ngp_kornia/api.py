"""One-call calibration, ``ngp_kornia.calibrate(image)``: the call's arguments are checked here, then handed to the
runner of its input (:mod:`ngp_kornia.pipeline.runner` for an image, a batch or a list;
:mod:`ngp_kornia.pipeline.shared_camera` for photos of one camera)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.errors import InputError, shown
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.priors import CALL_PRIORS, PRIOR_NAMES, Priors, checked_priors, checked_seed
from ngp_kornia.pipeline.runner import (
    Run,
    calibrate_input,
    calibrate_list,
    file_priors,
    read_input,
    with_orientation,
)
from ngp_kornia.pipeline.shared_camera import SharedFocal, calibrate_shared, shared_camera
from ngp_kornia.pipeline.weight_sets import (
    DEFAULT_SETTINGS,
    DEFAULT_WEIGHTS,
    WEIGHTS,
    check_weights,
    network_roles,
    weight_set_config,
)
from ngp_kornia.suggest import did_you_mean
from ngp_kornia.threads import pipeline_threads, resolve_num_threads

__all__ = [
    "CALL_PRIORS",
    "DEFAULT_SETTINGS",
    "DEFAULT_WEIGHTS",
    "WEIGHTS",
    "calibrate",
    "check_weights",
    "file_priors",
    "load_parser",
    "shared_focal",
    "weight_set_config",
    "with_orientation",
]

def load_parser(
    weights: str | Path | Sequence[str | Path] = "default", config: ParserConfig | Mapping | None = None
) -> NeuralGeometricParser:
    """The parser of a weight set: :meth:`NeuralGeometricParser.from_pretrained` (its networks the caller's own
    copies, in eval mode)."""
    return NeuralGeometricParser.from_pretrained(weights, config)


def calibrate(
    image: str | Path | np.ndarray | Tensor | Sequence[str | Path | np.ndarray | Tensor],
    weights: str | Path | Sequence[str | Path] = "default",
    *,
    priors: Priors | Mapping | None = None,
    config: ParserConfig | Mapping | None = None,
    seed: int = 0,
    device: str | torch.device | None = None,
    num_threads: int | None = None,
    **flat: object,
) -> Calibration | list[Calibration]:
    """Calibrate a camera from one photo (or a batch, or a list of photos) of a man-made scene.

    Args:
        image: a file path (decoded as displayed, :func:`ngp_kornia.io.read_image`: its EXIF orientation applied,
            transparency over grey), an HxWx3 uint8 RGB array (HxW greyscale, RGBA and uint16 converted), a Pillow
            image (as displayed), a tensor (3, H, W) or (B, 3, H, W), float in [0, 1] or uint8 in [0, 255], on any
            device; or a list (or tuple) of any of these, mixed.
        weights: ``"default"`` (the best path shipped), ``"none"`` (the untrained geometric path), ``"zsnet"``,
            ``"fsnet"``, ``"full"``, or weights files (:meth:`NeuralGeometricParser.from_pretrained`).
        priors: what is known of the cameras, a mapping or a :class:`Priors`: ``focal`` (pixels), ``fov_v``
            (degrees) or ``focal_35mm`` (millimetres), ``gravity`` ``(pitch, roll)`` with ``gravity_std``
            (degrees), ``principal_point`` ``(cx, cy)`` or ``"estimate"``, ``k1`` or ``"estimate"``; each one value
            for every image, or one per image of a batch or list ((B,) or (B, 2) tensors, arrays or lists, None in
            a list where an item has none). The mapping also takes ``"exif": True`` (a file's EXIF focal length
            where no focal length is given) and ``"shared_intrinsics": True`` (the photos, of one size, are one
            camera's: :mod:`ngp_kornia.pipeline.shared_camera`).
        config: a :class:`~ngp_kornia.pipeline.settings.ParserConfig`, or a mapping ``{"horizon.refine": False, ...}``.
        seed: seed of the random candidate sampling; the same input and seed give the same result.
        device: where to compute (``"cuda"``, say); None: where the input is (the CPU for files and arrays).
        num_threads: torch threads during the call, then restored (:mod:`ngp_kornia.threads`; 0: the caller's).

    Returns:
        a :class:`Calibration` in the input's pixels (``exif_orientation`` says how a file was turned), batched for
        batched tensor input; for a list, one per item, each what that item gives alone unless shared.

    Raises:
        ImageReadError: unreadable, truncated, corrupt, too small (< 32 px), too large or NaN input.
        InputError: a seed, prior, device or thread count that is not one, two focal-length priors, or a prior per
            image for another number of images (the message names the prior and the image).
        ValueError: ``shared_intrinsics`` with photos of different sizes or with ``exif``; a bad ``config`` or weights.
        TypeError: an input type or dtype that is not supported, or a prior passed as a keyword of its own.

    Example:
        >>> cals = calibrate([torch.rand(3, 64, 64), torch.rand(3, 48, 80)], priors={"fov_v": [60.0, 50.0]})
        >>> [c.image_size.tolist() for c in cals], [round(float(c.fov_v)) for c in cals]
        ([[64, 64], [48, 80]], [60, 50])
    """
    _refuse_flat(flat)
    given, exif, shared = _split(priors)
    run = _run(weights, config, seed, given)._replace(exif=exif, device=_device(device))
    resolve_num_threads(num_threads)  # a bad count is refused before any image is read
    many = isinstance(image, (list, tuple))
    with pipeline_threads(num_threads):  # one thread unless asked otherwise; the caller's count is restored
        if shared:
            results = calibrate_shared(list(image) if many else [image], run)
            return results if many else results[0]
        if many:
            return calibrate_list(image, run)
        return calibrate_input(image, read_input(image, run), run)


def _run(weights: object, config: object, seed: object, priors: Priors) -> Run:
    """The call's weights, settings and seed checked, its parser built on the shared networks."""
    nets = check_weights(weights)
    parser = NeuralGeometricParser(weight_set_config(weights, config), **network_roles(nets, copy=False))
    return Run(parser, checked_seed(seed), priors)


def _refuse_flat(flat: dict) -> None:
    """A prior passed as a keyword of its own (``focal=500``, as ``calibrate`` once took them) is refused, saying
    how to pass it."""
    if not flat:
        return
    name, value = next(iter(flat.items()))
    if name in PRIOR_NAMES or name in CALL_PRIORS:
        raise TypeError(f"calibrate() takes what is known of the camera in one mapping: priors={{{name!r}: "
                        f"{shown(value)}}}, not {name}= (a Priors works too)")
    hint = did_you_mean(name, ["weights", "priors", "config", "seed", "device", "num_threads"])
    raise TypeError(f"calibrate() got an unexpected keyword argument {name!r}; {hint}".rstrip("; "))


def _split(priors: object) -> tuple[Priors, bool, bool]:
    """The priors of a call, and its ``exif`` and ``shared_intrinsics`` flags (:data:`CALL_PRIORS`)."""
    flags = dict.fromkeys(CALL_PRIORS, False)
    if isinstance(priors, Mapping):
        priors = dict(priors)
        for name in CALL_PRIORS:
            flags[name] = priors.pop(name, False)
            if not isinstance(flags[name], bool):
                raise InputError(f"priors['{name}'] must be True or False, got {shown(flags[name])}")
    return checked_priors(priors, extra=CALL_PRIORS), flags["exif"], flags["shared_intrinsics"]


def _device(device: object) -> torch.device | None:
    """The device a call computes on, checked (None: where each input is)."""
    if device is None:
        return None
    try:
        checked = torch.device(device)
    except (RuntimeError, TypeError):
        raise InputError(f"device must be a torch device such as 'cpu' or 'cuda', got {shown(device)}") from None
    if checked.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"device={shown(device)} but torch sees no CUDA device here; use device='cpu' (or None)")
    return checked


def shared_focal(
    images: Sequence[str | Path],
    weights: str | Path | Sequence[str | Path] = "default",
    seed: int = 0,
    config: ParserConfig | Mapping | None = None,
    priors: Priors | None = None,
) -> SharedFocal:
    """The focal length that ``calibrate(images, priors={"shared_intrinsics": True})`` gives every photo, without
    calibrating them again with it (``ngp predict --same-camera`` does that as it writes its rows). Files that
    cannot be read or calibrated are left out (they give no evidence).

    Raises:
        ValueError: photos of different sizes, or none readable.
        TypeError: one path instead of a list of them.
    """
    run = _run(weights, config, seed, checked_priors(priors))
    if isinstance(images, (str, Path)) or not isinstance(images, Sequence):
        raise TypeError(f"shared_focal() takes a list of photo paths, got {shown(images)}; for one photo: [path]")
    if not images:
        raise ValueError("shared_focal() got no images")
    with pipeline_threads(None):
        return shared_camera(list(images), run)
