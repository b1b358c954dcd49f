"""One-call calibration: ``ngp_kornia.calibrate(image)``, and the one place where a file's priors (its EXIF focal
length) are read."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from copy import deepcopy
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.errors import NGPError, NGPWarning, WeightsError, shown
from ngp_kornia.geometry import image_center
from ngp_kornia.io import as_batch, exif_focal, read_rgb_oriented
from ngp_kornia.nets.weights import load_network, network_name, shipped_weights
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.parser import checked_config
from ngp_kornia.pipeline.priors import ESTIMATE, Priors, checked_seed
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.shared_camera import (
    SharedFocal,
    focal_grid,
    focal_support,
    joint_focal,
    joint_k1,
    joint_principal_point,
    not_shared_message,
    with_shared_focal,
)
from ngp_kornia.threads import Lookahead, pipeline_threads, resolve_num_threads

__all__ = [
    "DEFAULT_SETTINGS",
    "DEFAULT_WEIGHTS",
    "WEIGHTS",
    "calibrate",
    "calibrate_shared",
    "check_weights",
    "file_priors",
    "load_parser",
    "shared_focal",
    "weight_set_config",
    "with_orientation",
]

#: weight sets ``calibrate`` accepts by name; paths to weights files (``.pt``) work too.
WEIGHTS = ("default", "none", "zsnet", "fsnet", "full")
#: what "default" means: the networks of this weight set with :data:`DEFAULT_SETTINGS`, the configuration that beats
#: the geometric path on the real sets by the paired rule (BENCHMARKS.md, docs/lab-notes/real-scenes.md).
DEFAULT_WEIGHTS = "full"
#: the settings "default" changes (a ``config`` mapping changes them further; a whole ParserConfig replaces them):
#: the line evidence drops the segments it reads as clutter before the candidates are sampled
DEFAULT_SETTINGS = {"evidence.enabled": True}
#: the shipped networks each named weight set uses
_NAMED = {"none": (), "zsnet": ("zsnet",), "fsnet": ("fsnet",), "full": ("zsnet", "fsnet")}


#: the networks every weight set has (the line evidence, the orientation and structure check), by shipped file
_ALWAYS = {"LineEvidenceNet": "evidence", "UprightNet": "upright"}


#: said where a network (a parser from load_parser(), say) is passed as a weight set
_PARSER_HINT = (
    "; a parser from load_parser() runs on tensors itself (parser(images)), or save its networks with "
    "ngp_kornia.nets.weights.save_network and pass those files"
)


@lru_cache(maxsize=8)
def _network(path: str) -> torch.nn.Module:
    return load_network(path, network_name(path))


def check_weights(weights: object) -> list[torch.nn.Module]:
    """The networks of a weight set (see :func:`load_parser`), loaded once and shared read-only.

    Raises:
        ValueError: an unknown name, or something that is neither a name nor paths of ``.pt`` files.
        WeightsError: a missing, corrupt or mismatched weights file, or two files of one network.
    """
    if weights is None or not isinstance(weights, (str, Path, list, tuple)):
        raise ValueError(
            f"weights must be one of {', '.join(WEIGHTS)} or the path of a .pt weights file (or a list of paths), "
            f"got {shown(weights)}{_PARSER_HINT if isinstance(weights, torch.nn.Module) else ''}"
        )
    if isinstance(weights, str) and weights == "default":
        weights = DEFAULT_WEIGHTS
    if isinstance(weights, str) and weights in _NAMED:
        return [_network(str(shipped_weights(name))) for name in (*_NAMED[weights], *_ALWAYS.values())]
    paths = [weights] if isinstance(weights, (str, Path)) else list(weights)
    if not paths or not all(isinstance(p, Path) or str(p).endswith(".pt") for p in paths):
        raise ValueError(
            f"unknown weights {shown(weights)}; choose one of {', '.join(WEIGHTS)} or give paths to .pt weights files"
        )
    nets, seen = [], {}
    for path in paths:
        net = _network(str(path))
        name = type(net).__name__
        if name in seen:
            raise WeightsError(
                f"two {name} weights files given ({seen[name]}, {path}); give at most one file of each network"
            )
        seen[name] = path
        nets.append(net)
    for name, file in _ALWAYS.items():  # every weight set has these unless a file of its own is given
        if name not in seen:
            nets.append(_network(str(shipped_weights(file))))
    return nets


def load_parser(
    weights: str | Path | Sequence[str | Path] = "default", config: ParserConfig | None = None
) -> NeuralGeometricParser:
    """The parser for a weight set.

    ``"none"`` is the geometric path: uniform zenith scores and frames ranked by the Manhattan score (Eq. 21).
    ``"zsnet"`` scores the zenith candidates with the shipped ZSNet, ``"fsnet"`` rescores the best frames with the
    shipped FSNet, ``"full"`` uses both (the paper's parser). ``"default"`` is :data:`DEFAULT_WEIGHTS` with
    :data:`DEFAULT_SETTINGS` (a mapping ``config`` changes settings on top of them). A path (or
    a list of paths) loads weights files written by ``ngp-train export``: a ZSNet file, an FSNet file, or one of each.

    The networks are the caller's own copies, in eval mode: training them (as a layer of a larger model) or moving
    them does not change what :func:`calibrate` computes.
    """
    return _parser(check_weights(weights), weight_set_config(weights, config), copy=True)


def weight_set_config(weights: object, config: object) -> ParserConfig:
    """The settings of a call: ``config`` as :func:`~ngp_kornia.pipeline.parser.checked_config` takes it; for the
    ``"default"`` weight set with :data:`DEFAULT_SETTINGS` on top, unless a ``config`` mapping names them (a whole
    :class:`ParserConfig` cannot tell a setting left alone from one chosen: name it in a mapping, or choose
    ``weights="full"``, to turn one off).

    Example:
        >>> weight_set_config("default", None).evidence.enabled, weight_set_config("none", None).evidence.enabled
        (True, False)
        >>> weight_set_config("default", {"evidence.enabled": False}).evidence.enabled
        False
        >>> weight_set_config("default", ParserConfig()).evidence.enabled
        True
    """
    settings = checked_config(config)
    if not (isinstance(weights, str) and weights == "default"):
        return settings
    named = config if isinstance(config, Mapping) else {}
    return settings.replace(**{key: value for key, value in DEFAULT_SETTINGS.items() if key not in named})


def _parser(nets: list[torch.nn.Module], config: ParserConfig | None, copy: bool) -> NeuralGeometricParser:
    nets = {type(net).__name__: deepcopy(net) if copy else net for net in nets}
    return NeuralGeometricParser(
        config, nets.get("ZSNet"), nets.get("FSNet"), nets.get("LineEvidenceNet"), nets.get("UprightNet")
    )


def calibrate(
    image: str | Path | np.ndarray | Tensor | Sequence[str | Path | np.ndarray | Tensor],
    weights: str | Path | Sequence[str | Path] = "default",
    seed: int = 0,
    config: ParserConfig | None = None,
    focal: float | None = None,
    fov_v: float | None = None,
    exif: bool = False,
    num_threads: int | None = None,
    *,
    gravity: tuple[float, float] | None = None,
    gravity_std: float | None = None,
    principal_point: tuple[float, float] | str | None = None,
    k1: float | str | None = None,
    shared_intrinsics: bool = False,
    focal_35mm: float | None = None,
) -> Calibration | list[Calibration]:
    """Calibrate a camera from one photo (or a batch, or a list of photos) of a man-made scene.

    Args:
        image: a file path (decoded as displayed, :func:`ngp_kornia.io.read_image`: its EXIF orientation applied,
            transparency over grey), an HxWx3 uint8 RGB array (HxW greyscale, RGBA and uint16 converted), or a float
            tensor (3, H, W) or (B, 3, H, W) in [0, 1] on any device; or a list (or tuple) of any of these, mixed.
        weights: ``"default"`` (the best path shipped), ``"none"`` (the untrained geometric path), ``"zsnet"`` (zenith
            candidates scored by the shipped ZSNet), ``"fsnet"`` (frames rescored by the shipped FSNet), ``"full"``
            (both), or the path of a weights file (or a list of paths: one ZSNet and one FSNet file).
        seed: seed of the random candidate sampling; the same input and seed give the same result.
        config: a :class:`~ngp_kornia.pipeline.settings.ParserConfig`, or a mapping ``{"horizon.refine": False, ...}``.
        focal, fov_v, focal_35mm: a known focal length (one of them, :class:`Priors`): pixels of the input, the
            vertical field of view in degrees, or millimetres of a 35 mm equivalent as EXIF gives it. One that no
            camera has on the image (millimetres given as pixels, say) is refused with the likely mistake.
        exif: for a file without such a prior, the focal length its EXIF block records, where it records a
            plausible one (``FocalLengthIn35mmFilm``, or ``FocalLength`` with the sensor resolution).
        num_threads: torch threads during the call, then restored (:mod:`ngp_kornia.threads`; 0: the caller's).
        gravity, gravity_std, principal_point, k1: a known ``(pitch, roll)`` and its standard deviation, degrees;
            the principal point ``(cx, cy)`` and radial distortion, known or ``"estimate"`` (:class:`Priors`).
        shared_intrinsics: the photos (of one size) are one camera's (:mod:`ngp_kornia.pipeline.shared_camera`;
            with fewer than two that have lines, each is calibrated alone and an ``NGPWarning`` says so).

    Returns:
        a :class:`Calibration` in the input's pixels (``exif_orientation`` says how a file was turned), batched for
        batched tensor input; for a list, one per item, each what that item gives alone unless ``shared_intrinsics``.

    Raises:
        ImageReadError: unreadable, truncated, corrupt, too small (< 32 px), too large or NaN input.
        InputError: a seed, prior or thread count that is not one (a bool as a focal length, say), or two priors.
        ValueError: ``shared_intrinsics`` with photos of different sizes, or with ``exif``; a bad ``config``.
        WeightsError: a missing, corrupt or mismatched weights file.
        TypeError: an input type or dtype that is not supported.

    Example:
        >>> cal = calibrate(torch.rand(3, 64, 64))
        >>> {"K", "R", "focal", "fov_h"} <= set(cal.to_dict())
        True
        >>> [c.image_size.tolist() for c in calibrate([torch.rand(3, 64, 64), torch.rand(3, 48, 80)])]
        [[64, 64], [48, 80]]
    """
    call = _Call(check_weights(weights), weight_set_config(weights, config), checked_seed(seed),
                 Priors(focal, fov_v, gravity, gravity_std, principal_point, k1, focal_35mm), exif)
    return _calibrate_call(image, call, num_threads, shared_intrinsics)


def _calibrate_call(image, call: _Call, num_threads: int | None, shared_intrinsics: bool):
    """The rest of :func:`calibrate` once its weights, settings and priors are checked."""
    for name, flag in (("exif", call.exif), ("shared_intrinsics", shared_intrinsics)):
        if not isinstance(flag, bool):
            raise TypeError(f"{name} must be True or False, got {shown(flag)}")
    resolve_num_threads(num_threads)  # a bad count is refused before any image is read
    if shared_intrinsics:
        return calibrate_shared(image, call, num_threads)
    if isinstance(image, (list, tuple)):
        return _calibrate_list(image, call, num_threads)
    with pipeline_threads(num_threads):  # one thread unless asked otherwise; the caller's count is restored
        return _calibrate_inputs(image, _inputs(image, call), call)


class _Call(NamedTuple):
    """What one ``calibrate()`` call asks for, checked once."""

    nets: list[torch.nn.Module]
    config: ParserConfig
    seed: int
    priors: Priors
    exif: bool


def file_priors(image: object, height: int, width: int, priors: Priors, exif: bool) -> Priors:
    """The priors of one input: ``priors`` as given, or, with ``exif`` for a file whose priors give no focal length,
    the focal length its EXIF block records (in pixels of the image as displayed; none when it records none).

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


def _inputs(image, call: _Call) -> tuple:
    """(batch, segments, mask, EXIF orientation, priors) of one input: tensors as they are (the parser detects their
    lines), files and arrays read once with their lines detected on the 8-bit pixels. Where no network reads pixels
    (FSNet, the line evidence, the orientation check; :func:`_reads_pixels`) the parser reads only the image's shape,
    so the batch is then a stand-in of that shape and no pixel is converted."""
    if isinstance(image, Tensor):
        return as_batch(image)[0], None, None, None, call.priors
    rgb, orientation = read_rgb_oriented(image)
    segments, mask = detect_segments(rgb, call.config.segments)
    if _reads_pixels(call):
        batch = _pixels(rgb)
    else:
        batch = torch.zeros((), dtype=torch.float32).expand(1, 3, *rgb.shape[:2])
    return batch, segments, mask, orientation, file_priors(image, *rgb.shape[:2], call.priors, call.exif)


def _reads_pixels(call: _Call) -> bool:
    """Whether a network of the call reads the image's pixels."""
    names = {type(net).__name__ for net in call.nets}
    cfg = call.config
    return ("FSNet" in names or ("UprightNet" in names and cfg.upright.enabled)
            or ("LineEvidenceNet" in names and cfg.evidence.enabled))  # fmt: skip


def _calibrate_inputs(image, inputs: tuple, call: _Call) -> Calibration:
    """The rest of :func:`calibrate` for one input, given what :func:`_inputs` made of it."""
    batch, segments, mask, orientation, priors = inputs
    parser = _on_device(_parser(call.nets, call.config, copy=False), batch.device)  # the cached networks, read only
    # inference mode skips autograd's per-operation bookkeeping (about a tenth of the parser's time); the fields
    # are cloned out of it, so the caller gets ordinary tensors that can be edited in place or used with autograd
    with torch.inference_mode():
        result = parser(batch, segments, mask, seed=call.seed, priors=priors)
    result = result.clone()
    if isinstance(image, Tensor) and image.dim() == 4:
        return result
    result = result[0]
    # the parser's results already say 1 (nothing turned): only other orientations need a new result
    return result if orientation in (None, 1) else with_orientation(result, orientation)


def _pixels(rgb: np.ndarray) -> Tensor:
    """The (1, 3, H, W) float batch of an 8-bit RGB image: numpy divides the pixels straight into float32 (the same
    values as float() then / 255, in one pass over the image instead of two); the permuted view keeps the
    channels-last layout."""
    return torch.from_numpy(np.divide(rgb, np.float32(255.0), dtype=np.float32)).permute(2, 0, 1)[None]


def _on_device(parser: NeuralGeometricParser, device: torch.device) -> NeuralGeometricParser:
    # moving walks every submodule: skip it when the networks are already there (the usual CPU case)
    first = next(parser.parameters(), None)
    return parser if first is None or first.device == device else parser.to(device)


def with_orientation(result: Calibration, orientation: int) -> Calibration:
    """An unbatched result with the EXIF orientation of the file it came from (see ``Calibration.exif_orientation``)."""
    return replace(result, exif_orientation=torch.tensor(orientation, device=result.focal.device))


def _calibrate_list(images, call: _Call, num_threads: int | None) -> list[Calibration]:
    """One result per item, each computed alone (so it equals what the item gives alone, whatever its size)."""
    if not images:
        raise ValueError("calibrate() got an empty list; give at least one image (path, array or tensor)")
    for index, item in enumerate(images):
        if isinstance(item, (list, tuple)):
            raise TypeError(f"calibrate(): item {index} is a {type(item).__name__}; lists of lists are not supported")
    last = len(images) - 1
    # the next item is read and its lines detected on a second thread while the parser works on this one: the
    # same inputs as one call per item (the segments do not depend on threads), so the same results
    results = []
    with pipeline_threads(num_threads), Lookahead(lambda i: _inputs(images[i], call)) as ahead:
        for i, item in enumerate(images):
            try:
                results.append(_calibrate_inputs(item, ahead.get(i, i + 1 if i < last else None), call))
            except (NGPError, TypeError, ValueError) as err:
                raise _naming_item(err, i) from err
    return results


def _naming_item(err: Exception, index: int) -> Exception:
    """The error of one item of a list, its message naming the item (the same type, for ``except`` clauses)."""
    try:
        return type(err)(f"item {index} of the list: {err}")
    except TypeError:  # an exception type that takes other arguments: as it was
        return err


def calibrate_shared(image, call: _Call, num_threads: int | None) -> Calibration | list[Calibration]:
    """:func:`calibrate` with ``shared_intrinsics=True``: every photo calibrated alone, one focal length from the
    line support of all of them on a common grid (:mod:`ngp_kornia.pipeline.shared_camera`), then every photo again
    with that focal length as a known one. ``image`` and the result are as in :func:`calibrate`. Between the passes
    only each photo's segments are kept (the pixels of a file are read again), so a long list fits in memory.

    Raises:
        ValueError: an empty list, photos of different sizes (not one camera), or ``exif`` (a focal length per
            photo, where one is shared).
    """
    if call.exif:
        raise ValueError("shared_intrinsics=True estimates one focal length for all the photos; exif=True gives each "
                         "its own: use one of them (or give the known focal length as focal=)")
    items = list(image) if isinstance(image, (list, tuple)) else [image]
    if not items:
        raise ValueError("calibrate() got an empty list; give at least one image (path, array or tensor)")
    with pipeline_threads(num_threads):
        kept, shared, alone = _first_pass(items, call)
        if alone and shared.photos < 2:  # one photo's lines, or none: nothing to share between photos
            warnings.warn(NGPWarning(not_shared_message(shared.photos, len(items))), stacklevel=4)
            return alone if isinstance(image, (list, tuple)) else alone[0]
        priors = call.priors.with_focal(shared.focal)
        if shared.principal_point is not None:
            priors = replace(priors, principal_point=shared.principal_point)
        if shared.k1 is not None:
            priors = replace(priors, k1=shared.k1)
        results = []
        with Lookahead(lambda i: _pixels_again(items[i], kept[i], call)) as ahead:
            for i, item in enumerate(items):
                batch, segments, mask, orientation, _ = ahead.get(i, i + 1 if i < len(items) - 1 else None)
                alone = _calibrate_inputs(item, (batch, segments, mask, orientation, priors), call)
                results.append(with_shared_focal(alone, shared))
    return results if isinstance(image, (list, tuple)) else results[0]


def shared_focal(
    images: Sequence[str | Path],
    weights: str | Path | Sequence[str | Path] = "default",
    seed: int = 0,
    config: ParserConfig | None = None,
    priors: Priors | None = None,
) -> SharedFocal:
    """The focal length that ``calibrate(images, shared_intrinsics=True)`` gives every photo, without calibrating
    them again with it (``ngp predict --same-camera`` does that as it writes its rows). Files that cannot be read
    or calibrated are left out (they give no evidence).

    Raises:
        ValueError: photos of different sizes, or none readable.
        TypeError: one path instead of a list of them.
    """
    call = _Call(check_weights(weights), weight_set_config(weights, config), checked_seed(seed), priors or Priors(),
                 False)
    if isinstance(images, (str, Path)) or not isinstance(images, Sequence):
        raise TypeError(f"shared_focal() takes a list of photo paths, got {shown(images)}; for one photo: [path]")
    if not images:
        raise ValueError("shared_focal() got no images")
    with pipeline_threads(None):
        return _first_pass(list(images), call, skip_unreadable=True)[1]


def _first_pass(items: list, call: _Call, skip_unreadable: bool = False) -> tuple[list[tuple], SharedFocal, list]:
    """Each photo calibrated alone and scored on the common focal grid: what is kept of each photo's inputs (its
    pixels only where they are the caller's tensor or a stand-in), the joint camera and the photos' own results
    (none where nothing is estimated jointly). With ``skip_unreadable`` a photo that cannot be read or calibrated
    is left out (and nothing is kept of any)."""
    kept, found, sizes, alone = [], {"support": [], "valid": [], "point": [], "point_std": [], "k1": []}, [], []
    estimates = call.priors.principal_point == ESTIMATE or call.priors.k1 == ESTIMATE
    with Lookahead(lambda i: _with_segments(_inputs(items[i], call), call)) as ahead:
        for i, item in enumerate(items):
            try:
                given = ahead.get(i, i + 1 if i < len(items) - 1 else None)
            except (NGPError, ValueError, TypeError, OSError):
                if not skip_unreadable:
                    raise
                continue
            sizes.append(tuple(given[0].shape[-2:]))
            height, width = _one_size(sizes, call.priors.principal_point == ESTIMATE)
            if not call.priors.known_focal or estimates:
                alone.append(_calibrate_inputs(item, given, call))
                _evidence(found, alone[-1], given, call, height, width)
            keep_pixels = isinstance(item, Tensor) or given[0].stride() == (0, 0, 0, 0)  # the caller's, or a stand-in
            kept.append((given[0] if keep_pixels else None, *given[1:]) if not skip_unreadable else (None, given[1]))
    if not kept:
        raise ValueError("no photo could be read, so no focal length can be shared")
    return kept, _joint_camera(found, call, len(kept), height, width), alone


def _evidence(found: dict, alone: Calibration, given: tuple, call: _Call, height: int, width: int) -> None:
    """What one photo's own calibration says of the camera: its support on the focal grid, its principal point
    and distortion (where estimated), appended to ``found``."""
    K, R, ok = (t if alone.batched else t[None] for t in (alone.K, alone.R, alone.valid))
    settings = call.config.shared
    found["valid"].append(ok.cpu())  # the photos with lines to measure the camera by
    if not call.priors.known_focal:
        grid = focal_grid(height, width, settings, call.config.sampling)
        found["support"].append(focal_support(K, R, given[1].to(K), given[2], grid, settings))
    if call.priors.principal_point == ESTIMATE:
        std = alone.principal_point_std
        found["point"].append(K[:, :2, 2].cpu())
        found["point_std"].append((std if alone.batched else std[None]).cpu())
    if call.priors.k1 == ESTIMATE:
        found["k1"].append((alone.k1 if alone.batched else alone.k1[None]).cpu())


def _joint_camera(found: dict, call: _Call, photos: int, height: int, width: int) -> SharedFocal:
    """The shared camera of the photos' evidence (:mod:`ngp_kornia.pipeline.shared_camera`)."""
    if call.priors.known_focal:  # nothing to estimate: the known focal length is every photo's
        photos = int(torch.cat(found["valid"]).sum()) if found["valid"] else photos  # those that tell the rest
        shared = SharedFocal(call.priors.focal_pixels(height, width), 0.0, photos)
    else:
        grid = focal_grid(height, width, call.config.shared, call.config.sampling)
        shared = joint_focal(torch.cat(found["support"]), grid, torch.cat(found["valid"]), call.config.shared.bootstrap)
    if found["point"]:
        centre = image_center(height, width)
        prior = call.config.trust.principal_point_std * height
        point, std = joint_principal_point(torch.cat(found["point"]), torch.cat(found["point_std"]), centre, prior)
        shared = shared._replace(principal_point=point, principal_point_std=std)
    if found["k1"]:
        shared = shared._replace(k1=joint_k1(torch.cat(found["k1"])))
    return shared


def _pixels_again(item, kept: tuple, call: _Call) -> tuple:
    """The second pass's inputs of a photo: its kept inputs, with the pixels of a file or array read again."""
    if kept[0] is not None:
        return kept
    rgb, _ = read_rgb_oriented(item)
    return (_pixels(rgb), *kept[1:])


def _with_segments(inputs: tuple, call: _Call) -> tuple:
    """The inputs of :func:`_inputs`, with a tensor's segments detected here (the shared focal length reads them)."""
    batch, segments, mask, orientation, priors = inputs
    if segments is None:
        segments, mask = detect_segments(batch, call.config.segments)
    return batch, segments, mask, orientation, priors


def _one_size(sizes: list[tuple[int, int]], upright: bool = False) -> tuple[int, int]:
    """The photos' ``(height, width)``, one for all (a turned photo's transpose counts as the same, unless
    ``upright``: a shared principal point turns with the photo)."""
    first = sizes[0]
    for size in sizes[1:]:
        if size not in ((first,) if upright else (first, first[::-1])):
            raise ValueError(
                f"shared_intrinsics=True needs photos of one camera, so of one size; got {first[1]}x{first[0]} and "
                f"{size[1]}x{size[0]} pixels: calibrate photos of different sizes apart"
            )
    return first
