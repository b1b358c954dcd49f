"""The camera model around the frame search: a principal point off the image centre and radial distortion, known or
estimated, while every stage inside assumes a distortion-free camera centred on its image.

The stages work in the pseudo camera, whose principal point is the image centre. A photo with another principal
point ``c`` or with distortion is brought to that model first: its segments are undistorted about ``c``
(:func:`~ngp_kornia.geometry.lens.undistort_points`, with the coefficient in pseudo units) and moved by the centre
minus ``c``, so that its principal point lands on the centre; the calibration found there is moved back (``K``, the
zenith, VPs and horizon; rotations and angles do not move). FSNet, which reads the pixels, gets the image warped the
same way. An estimate runs the stages twice: once as a centred pinhole for the frame whose vanishing points the
principal point is fitted to (:mod:`~ngp_kornia.pipeline.principal_point`), once with the estimate. The distortion
is estimated before any frame (:mod:`~ngp_kornia.pipeline.distortion`), as it needs none; where it finds one,
the stages run on the photo with and without it, and the distortion is kept where its answer is the more
confident (the confidence reads how well the lines fit the frame). On 500 renders with ``k1`` in [-0.3, 0] and
the same 500 scenes without distortion, horizon AUC: the estimate alone (a stricter gain, 0.2) 93.4 and 94.9,
with the choice 93.9 and 95.3 (95.3 without the option).

With neither a principal point nor a distortion asked for, the stages run once on the inputs as they are.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import torch
from kornia.geometry import create_meshgrid
from kornia.geometry.transform import remap
from torch import Tensor

from ngp_kornia.geometry import (
    coefficient_from_pseudo,
    coefficient_to_pseudo,
    distort_points,
    image_center,
    pseudo_intrinsics,
    undistort_points,
)
from ngp_kornia.pipeline.distortion import estimate_distortion, joint_distortion
from ngp_kornia.pipeline.frame_search import FrameSearch, Search, View
from ngp_kornia.pipeline.principal_point import estimate_principal_point, joint_principal_point
from ngp_kornia.pipeline.priors import ESTIMATE, Priors
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.settings import ParserConfig

__all__ = [
    "OPTION_METRICS",
    "SharedOptions",
    "calibrate_camera_model",
    "estimates",
    "joint_options",
    "moved_calibration",
    "option_errors",
    "option_evidence",
    "option_values",
    "tied_to_pixels",
    "with_shared_options",
]


def moved_calibration(cal: Calibration, offset: Tensor) -> Calibration:
    """A batched calibration with its pixels moved by ``offset`` (B, 2): the camera's principal point, so ``K``, the
    zenith, VPs and horizon follow (points move as ``p + offset``).

    Example:
        >>> from ngp_kornia.pipeline.answer import calibration_from_camera
        >>> K = torch.tensor([[[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]])
        >>> level = calibration_from_camera(K, torch.eye(3)[None], torch.ones(1), torch.ones(1, dtype=torch.bool),
        ...                                 480, 640)
        >>> moved_calibration(level, torch.tensor([[2.0, -10.0]])).horizon.tolist()
        [[0.0, 1.0, -229.5]]
    """
    params = cal.camera.params
    shift = torch.cat([torch.zeros_like(offset), offset], -1).to(params)  # (0, 0, dx, dy): f stays
    return replace(cal, camera=cal.camera.replace(params=params + shift))


def _moved_segments(segments: Tensor, point: Tensor, lam: Tensor | None, height: int, width: int) -> Tensor:
    """The segments undistorted about ``point`` (B, 2) by ``lam`` (B,) pseudo units, then moved so that ``point``
    lands on the image centre."""
    B, N = segments.shape[:2]
    flat = segments.reshape(B, 2 * N, 2)
    if lam is not None:
        flat = undistort_points(flat, pseudo_intrinsics(height, width, flat, point), lam.to(flat))
    shift = image_center(height, width, like=flat) - point.to(flat)
    return (flat + shift[:, None]).reshape(segments.shape)


def _moved_images(images: Tensor, point: Tensor, lam: Tensor | None) -> Tensor:
    """The images warped as :func:`_moved_segments` moves the segments (bilinear, zeros outside)."""
    B, _, height, width = images.shape
    grid = create_meshgrid(height, width, False, images.device, images.dtype).reshape(1, -1, 2).expand(B, -1, 2)
    shift = image_center(height, width, like=grid) - point.to(grid)
    source = grid - shift[:, None]
    if lam is not None:
        source = distort_points(source, pseudo_intrinsics(height, width, grid, point), lam.to(grid))
    source = source.reshape(B, height, width, 2)
    return remap(images, source[..., 0], source[..., 1], align_corners=True)


def _search_at(
    search: FrameSearch, view: View, priors: Priors, point: Tensor, lam: Tensor | None, std: float | Tensor
) -> Search:
    """The frame search on the photo brought to a centred pinhole (module docstring), its answer moved back;
    ``std``, the uncertainty of the principal point as a fraction of the height (one for all, or (B,))."""
    height, width = view.images.shape[-2:]
    centre = image_center(height, width, like=view.segments).expand(len(view.segments), 2)
    if lam is None and bool((point.to(centre) == centre).all()):
        return search(view, priors, std)
    moved = _moved_segments(view.segments, point, lam, height, width)
    images = _moved_images(view.images, point, lam) if search.reads_pixels else view.images
    found = search(view._replace(images=images, segments=moved, resized=None), priors, std)  # not the moved image
    return found._replace(result=moved_calibration(found.result, point.to(centre) - centre))


def calibrate_camera_model(search: FrameSearch, view: View, priors: Priors) -> Search:
    """The frame search with the principal point and distortion of ``priors`` (module docstring): the distortion
    first (estimated, or the given ``k1`` in the search's units), then the principal point (estimated on a first
    search's frame, or given), then the search on the photo brought to a centred pinhole, its answer moved back.

    Args:
        search: the stages for a centred, distortion-free camera (their settings: ``trust.centre_std``,
            the prior of an estimate; ``distortion``).
        view: the images (B, 3, H, W), segments (B, N, 2, 2) in pixels, mask (B, N) and line-evidence weights.
        priors: what is known of the camera; ``principal_point`` and ``k1`` are handled here.

    Returns:
        the last search (:class:`~ngp_kornia.pipeline.frame_search.Search`), its calibration with
        ``principal_point_std`` where a principal point was given (0) or estimated, and ``k1`` where a distortion
        was given or estimated.
    """
    config = search.config
    height, width = view.images.shape[-2:]
    B = len(view.segments)
    centre = image_center(height, width, like=view.segments.double()).expand(B, 2)
    given = priors.principal_point is not None and priors.principal_point != ESTIMATE
    point = view.segments.new_tensor(priors.each("principal_point", B), dtype=torch.float64) if given else centre
    std = 0.0 if given else config.trust.centre_std
    lam = _distortion(search, view, priors, point)
    if priors.principal_point == ESTIMATE:
        frame = _search_at(search, view, priors, centre, lam, std).result
        undistorted = _moved_segments(view.segments, centre, lam, height, width)  # about the centre: not moved
        prior = config.trust.centre_std * height
        found = estimate_principal_point(frame.K, frame.R, undistorted, view.mask, prior)
        point, point_std = found.point.double(), found.std
        std = point_std.mean(-1).double() / height  # each image's own
    last = _search_at(search, view, priors, point, lam, std)
    result = last.result
    if priors.principal_point == ESTIMATE:
        result = replace(result, principal_point_std=point_std.to(result.K))
    elif given:
        result = replace(result, principal_point_std=torch.zeros_like(result.K[:, :2, 2]))
    if priors.k1 == ESTIMATE:
        k1 = coefficient_from_pseudo(lam.to(result.focal), result.focal, height, width)
        result = replace(result, camera=result.camera.replace(lens=k1))
    elif priors.k1 is not None:  # given: reported as given (undistorted at the first run's focal length)
        k1 = result.focal.new_tensor(priors.each("k1", B))
        result = replace(result, camera=result.camera.replace(lens=k1))
    return last._replace(result=result)


def _distortion(search: FrameSearch, view: View, priors: Priors, point: Tensor) -> Tensor | None:
    """The distortion ``lam`` (B,) in pseudo units: estimated, or the given ``k1`` at the known focal length (else
    at the focal length of a first, distortion-free search); None without one."""
    height, width = view.images.shape[-2:]
    if priors.k1 is None:
        return None
    if priors.k1 == ESTIMATE:
        config = search.config
        lam = estimate_distortion(view.segments, view.mask, point, height, width, config.distortion).double()
        if not bool((lam != 0).any()):
            return lam
        # the lines say which camera they fit: the undistorted photo is kept where its answer is the more confident
        std = config.trust.centre_std
        bent = _search_at(search, view, priors, point, lam, std).result.confidence
        straight = _search_at(search, view, priors, point, None, std).result.confidence
        return torch.where(bent > straight, lam, torch.zeros_like(lam))
    B = len(view.segments)
    known = priors.focal_each(height, width, B)
    if known is None:
        focal = _search_at(search, view, priors, point, None, 0.0).result.focal.double()
    else:
        focal = torch.tensor(known, dtype=torch.float64, device=view.segments.device)
    k1 = torch.tensor(priors.each("k1", B), dtype=torch.float64, device=focal.device)
    return coefficient_to_pseudo(k1, focal, height, width)


# --- the options of one camera shared by many photos (pipeline/shared_camera.py) ---


class SharedOptions(NamedTuple):
    """The camera options photos of one camera share, where asked for as ``"estimate"`` (:func:`joint_options`).

    Attributes:
        priors: the values every photo then takes as known, as :class:`~ngp_kornia.pipeline.priors.Priors` names
            them.
        point_std: the shared principal point's standard deviation per axis, pixels; None where not estimated.
    """

    priors: dict
    point_std: tuple[float, float] | None = None


def estimates(priors: Priors) -> bool:
    """Whether the priors ask for an option to be estimated (the principal point or the distortion)."""
    return priors.principal_point == ESTIMATE or priors.k1 == ESTIMATE


def tied_to_pixels(priors: Priors) -> bool:
    """Whether an option the photos share is tied to their pixels, so that a turned photo is another camera (an
    estimated principal point turns with the photo; a focal length or a radial distortion does not)."""
    return priors.principal_point == ESTIMATE


def option_evidence(alone: Calibration, priors: Priors) -> dict[str, Tensor]:
    """What one photo's own calibration (batched or not) says of the options asked for as ``"estimate"``: its
    principal point and that point's standard deviation (B, 2), its distortion (B,)."""
    batch = (lambda t: t) if alone.batched else (lambda t: t[None])
    out = {}
    if priors.principal_point == ESTIMATE:
        out["point"], out["point_std"] = batch(alone.principal_point), batch(alone.principal_point_std)
    if priors.k1 == ESTIMATE:
        out["k1"] = batch(alone.k1)
    return out


def joint_options(evidence: list[dict[str, Tensor]], config: ParserConfig, height: int, width: int) -> SharedOptions:
    """The options photos of one camera share, from each photo's :func:`option_evidence`: the principal point
    combines every photo's own estimate (:func:`~ngp_kornia.pipeline.principal_point.joint_principal_point`, each
    photo's evidence added once to the prior ``trust.centre_std``), the distortion is the median of theirs
    (:func:`~ngp_kornia.pipeline.distortion.joint_distortion`)."""
    found = {name: torch.cat([e[name] for e in evidence]) for name in (evidence[0] if evidence else {})}
    priors, point_std = {}, None
    if "point" in found:
        prior = config.trust.centre_std * height
        point, point_std = joint_principal_point(found["point"], found["point_std"], image_center(height, width), prior)
        priors["principal_point"] = point
    if "k1" in found:
        priors["k1"] = joint_distortion(found["k1"])
    return SharedOptions(priors, point_std)


def with_shared_options(result: Calibration, options: SharedOptions | None) -> Calibration:
    """A photo's calibration with the shared options' uncertainty: the shared principal point's standard
    deviation where it was estimated jointly."""
    if options is None or options.point_std is None:
        return result
    return replace(result, principal_point_std=result.K.new_tensor(options.point_std).expand_as(result.K[..., 0, :2]))


# --- the options' figures in an evaluation (ngp_kornia.evaluation) ---

#: the error of each camera option where the truth and the estimate have it (:func:`option_errors`), with its words
#: in tables
OPTION_METRICS = {"principal_point": "principal point error (px)", "k1": "k1 error"}


def option_values(result: Calibration) -> dict[str, float]:
    """One photo's camera options as plain numbers (unbatched): the principal point ``cx``, ``cy`` and ``k1`` (0 for
    a distortion-free pinhole)."""
    lens = result.k1
    return {"cx": float(result.K[0, 2]), "cy": float(result.K[1, 2]), "k1": 0.0 if lens is None else float(lens)}


def option_errors(values: dict, K: Tensor | None, lens: float | None) -> dict[str, float | None]:
    """The error of each option (:data:`OPTION_METRICS`) of an estimate's :func:`option_values` against the truth,
    the intrinsics ``K`` (3, 3) and the lens distortion: the principal point's distance (pixels) and ``k1``'s
    absolute difference; None where the truth lacks the option, NaN where the estimate does.

    Example:
        >>> K = torch.tensor([[500.0, 0, 320.0], [0, 500, 240.0], [0, 0, 1]])
        >>> option_errors({"cx": 323.0, "cy": 244.0, "k1": 0.0}, K, None)
        {'principal_point': 5.0, 'k1': None}
    """
    point = None
    if K is not None:
        point = math.hypot(values["cx"] - float(K[0, 2]), values["cy"] - float(K[1, 2])) if "cx" in values else math.nan
    distortion = None if lens is None else abs(values["k1"] - lens) if "k1" in values else math.nan
    return {"principal_point": point, "k1": distortion}
