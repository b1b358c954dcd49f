"""The parser on what :func:`ngp_kornia.calibrate` takes: files, arrays, Pillow images and tensors, alone or in a list.

Each input is read once (:func:`read_input`): a tensor as it is (the parser detects its lines), a file, an array or a
Pillow image decoded to 8-bit RGB as displayed with its lines detected on those pixels, and its priors (a file's
EXIF focal length where asked for). It travels as an :class:`Input` to :func:`calibrate_input`, which runs the
parser on it. :func:`calibrate_list` runs a list, reading the next item on a second thread meanwhile.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.errors import NGPError
from ngp_kornia.io import as_batch, exif_focal, read_rgb_oriented
from ngp_kornia.pipeline.parser import NeuralGeometricParser
from ngp_kornia.pipeline.priors import Priors
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.threads import Lookahead

__all__ = [
    "Input",
    "Run",
    "calibrate_input",
    "calibrate_list",
    "file_priors",
    "item_run",
    "naming_item",
    "on_device",
    "pixels",
    "read_input",
    "with_orientation",
]


class Run(NamedTuple):
    """What one :func:`ngp_kornia.calibrate` call asks for, checked once.

    Attributes:
        parser: the parser of the call's weight set and settings (its networks shared read-only).
        seed: the sampling seed.
        priors: what is known of the cameras.
        exif: take a file's EXIF focal length where the priors give none.
        device: where the parser runs; None: where each input is (the CPU for files, arrays and Pillow images).
    """

    parser: NeuralGeometricParser
    seed: int
    priors: Priors
    exif: bool = False
    device: torch.device | None = None


class Input(NamedTuple):
    """One input on its way to the parser.

    Attributes:
        batch: (B, 3, H, W) float pixels in [0, 1]; where no network reads pixels
            (:attr:`~ngp_kornia.pipeline.parser.NeuralGeometricParser.reads_pixels`), a stand-in of the image's
            shape (no pixel converted).
        segments: (B, N, 2, 2) the lines detected on the 8-bit pixels of a file, array or Pillow image; None for a
            tensor (the parser detects them).
        mask: (B, N) bool, with ``segments``.
        orientation: the EXIF orientation tag applied to a file or Pillow image; None for arrays and tensors.
        priors: the priors of this input.
    """

    batch: Tensor
    segments: Tensor | None
    mask: Tensor | None
    orientation: int | None
    priors: Priors


def file_priors(image: object, height: int, width: int, priors: Priors, exif: bool) -> Priors:
    """The priors of one input: ``priors`` as given, or, with ``exif`` for a file whose priors give no focal length,
    the focal length its EXIF block records (in pixels of the image as displayed; none when it records none or one
    no camera has on the image).

    Example:
        >>> file_priors("photo.jpg", 480, 640, Priors(focal=500.0), exif=True).focal
        500.0
    """
    if exif and not priors.known_focal and isinstance(image, (str, Path)):
        recorded = replace(priors, focal=exif_focal(image, height, width))
        try:
            recorded.check_image(height, width)
        except NGPError:  # a damaged or odd tag (a focal length no camera has on this image): no prior
            return priors
        return recorded
    return priors


def pixels(rgb: np.ndarray) -> Tensor:
    """The (1, 3, H, W) float batch of an 8-bit RGB image: numpy divides the pixels straight into float32 (the same
    values as float() then / 255, in one pass over the image instead of two); the permuted view keeps the
    channels-last layout.

    Example:
        >>> pixels(np.full((2, 3, 3), 255, np.uint8)).shape
        torch.Size([1, 3, 2, 3])
    """
    return torch.from_numpy(np.divide(rgb, np.float32(255.0), dtype=np.float32)).permute(2, 0, 1)[None]


def read_input(image: object, run: Run) -> Input:
    """An input as the parser takes it (module docstring).

    Raises:
        ImageReadError: unreadable, corrupt, too small or too large input; TypeError: an unsupported type.
    """
    if isinstance(image, Tensor):
        return Input(as_batch(image)[0], None, None, None, run.priors)
    rgb, orientation = read_rgb_oriented(image)
    if run.parser.reads_pixels:  # converted while this thread would wait for line detection's last strip
        converted = []
        segments, mask = detect_segments(rgb, run.parser.config.segments, lambda: converted.append(pixels(rgb)))
        batch = converted[0]
    else:
        segments, mask = detect_segments(rgb, run.parser.config.segments)
        batch = torch.zeros((), dtype=torch.float32).expand(1, 3, *rgb.shape[:2])
    return Input(batch, segments, mask, orientation, file_priors(image, *rgb.shape[:2], run.priors, run.exif))


def item_run(run: Run, index: int) -> Run:
    """The call for item ``index`` of a list: its own priors where they are given per item."""
    return run._replace(priors=run.priors.image(index)) if run.priors.count else run


def on_device(parser: NeuralGeometricParser, device: torch.device) -> NeuralGeometricParser:
    """The parser with its networks on ``device``."""
    # moving walks every submodule: skip it when the networks are already there (the usual CPU case)
    first = next(parser.parameters(), None)
    return parser if first is None or first.device == device else parser.to(device)


def calibrate_input(image: object, given: Input, run: Run) -> Calibration:
    """The calibration of one input read by :func:`read_input`: batched for a batched tensor, else one image's
    with the EXIF orientation of a file."""
    batch, segments, mask = given.batch, given.segments, given.mask
    if run.device is not None and batch.device != run.device:
        batch = batch.to(run.device)
        segments, mask = (None, None) if segments is None else (segments.to(run.device), mask.to(run.device))
    parser = on_device(run.parser, batch.device)  # the cached networks, read only
    # inference mode skips autograd's per-operation bookkeeping (about a tenth of the parser's time); the fields
    # are cloned out of it, so the caller gets ordinary tensors that can be edited in place or used with autograd
    with torch.inference_mode():
        result = parser(batch, segments, mask, seed=run.seed, priors=given.priors)
    result = result.clone()
    if isinstance(image, Tensor) and image.dim() == 4:
        return result
    result = result[0]
    # the parser's results already say 1 (nothing turned): only other orientations need a new result
    return result if given.orientation in (None, 1) else with_orientation(result, given.orientation)


def with_orientation(result: Calibration, orientation: int) -> Calibration:
    """An unbatched result with the EXIF orientation of the file it came from (see ``Calibration.exif_orientation``)."""
    return replace(result, exif_orientation=torch.tensor(orientation, device=result.focal.device))


def calibrate_list(images: list | tuple, run: Run) -> list[Calibration]:
    """One result per item, each computed alone (so it equals what the item gives alone, whatever its size), with
    its own priors where they are given per item (None where an item has none).

    Raises:
        ValueError: an empty list; TypeError: a list of lists; InputError: priors given for another number of
            items; an item's error names the item.
    """
    if not images:
        raise ValueError("calibrate() got an empty list; give at least one image (path, array or tensor)")
    for index, item in enumerate(images):
        if isinstance(item, (list, tuple)):
            raise TypeError(f"calibrate(): item {index} is a {type(item).__name__}; lists of lists are not supported")
    last = len(images) - 1
    run = run._replace(priors=run.priors.for_batch(len(images), "list"))  # one for all, or one per item
    # the next item is read and its lines detected on a second thread while the parser works on this one: the
    # same inputs as one call per item (the segments do not depend on threads), so the same results
    results = []
    with Lookahead(lambda i: read_input(images[i], item_run(run, i))) as ahead:
        for i, item in enumerate(images):
            try:
                results.append(calibrate_input(item, ahead.get(i, i + 1 if i < last else None), run))
            except (NGPError, TypeError, ValueError) as err:
                raise naming_item(err, i) from err
    return results


def naming_item(err: Exception, index: int) -> Exception:
    """The error of one item of a list, its message naming the item (the same type, for ``except`` clauses).

    Example:
        >>> naming_item(ValueError("too small"), 2)
        ValueError('item 2 of the list: too small')
    """
    try:
        return type(err)(f"item {index} of the list: {err}")
    except TypeError:  # an exception type that takes other arguments: as it was
        return err
