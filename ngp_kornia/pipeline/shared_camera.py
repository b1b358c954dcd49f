"""One camera across many photos: a focal length estimated jointly from the line evidence of every photo.

Photos taken with one camera (and one zoom setting) share their focal length, so every photo's lines speak to the
same number. Averaging the per-photo answers would count a photo whose frame search went astray as much as a clear
one, and would keep each photo's own noise; instead every photo's evidence is scored on a common grid of focal
lengths and the scores are summed:

1. **A common grid.** Focal lengths ``focal_step`` apart (relative, log-spaced) over the frame search's
   ``focal_range``, in pixels of the photos (one size, or its transpose: one camera).
2. **Each photo's support at each focal length** within ``window`` of its own answer. The photo's frame (from its
   own calibration) is moved to the grid's focal length keeping its three vanishing points where they are in the
   image as far as a rotation can
   (the nearest rotation to the directions ``K_g^-1 v``), refitted on the segments that point at its VPs
   (:func:`~ngp_kornia.pipeline.polish.refit_rotation`), and scored by its line support: the share of the segments'
   length its three VPs explain (the closeness kernel of :mod:`~ngp_kornia.pipeline.line_kernel`). A photo whose
   lines fix the focal length (three finite VPs with lines) has a peaked profile; one that does not (a single
   horizontal VP) a flat one, which moves the sum little.
3. **The joint answer.** The grid point of the largest summed support, refined by a parabola through it and its
   neighbours (in log focal length); its standard deviation is that of the same answer over ``bootstrap``
   resamples of the photos (a fixed seed: the same photos give the same answer).

Each photo's rotation is then found again with the shared focal length as a known one (``ngp_kornia.calibrate``).
The camera options asked for as ``"estimate"`` (the principal point, the distortion) are shared too
(:func:`~ngp_kornia.pipeline.camera_model.joint_options`); the second pass then takes them as known.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from typing import NamedTuple

import torch
from torch import Tensor

from ngp_kornia.errors import InputError, NGPError, NGPWarning
from ngp_kornia.geometry import intrinsics_matrix, segment_lengths
from ngp_kornia.io import read_rgb_oriented
from ngp_kornia.pipeline.camera_model import (
    SharedOptions,
    estimates,
    joint_options,
    option_evidence,
    tied_to_pixels,
    with_shared_options,
)
from ngp_kornia.pipeline.line_kernel import (
    camera_segments,
    closeness_kernel,
    scaled_camera_segments,
)
from ngp_kornia.pipeline.polish import refit_rotation
from ngp_kornia.pipeline.priors import INTRINSIC_PRIORS, PerImage
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.runner import Input, Run, calibrate_input, item_run, pixels, read_input
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import SamplingSettings, SharedSettings
from ngp_kornia.threads import Lookahead

__all__ = [
    "SharedFocal",
    "calibrate_shared",
    "focal_grid",
    "focal_support",
    "joint_focal",
    "nearest_rotation",
    "not_shared_folders",
    "not_shared_message",
    "shared_camera",
    "with_shared_focal",
]


class SharedFocal(NamedTuple):
    """The focal length of one camera estimated from many photos (:func:`joint_focal`).

    Attributes:
        focal: the focal length, pixels.
        std: its standard deviation over resamples of the photos, pixels (0 for a single photo).
        photos: how many photos gave evidence (those with a valid frame).
        options: the camera options the photos share where estimated
            (:class:`~ngp_kornia.pipeline.camera_model.SharedOptions`); None where none is.
    """

    focal: float
    std: float
    photos: int
    options: SharedOptions | None = None


def focal_grid(height: int, width: int, settings: SharedSettings, sampling: SamplingSettings) -> Tensor:
    """The common grid (G,) float64 of focal lengths in pixels: ``settings.focal_step`` apart (relative) over
    ``sampling.focal_range`` (units of half the long side), the same for every photo of one size.

    Example:
        >>> grid = focal_grid(480, 640, SharedSettings(), SamplingSettings())
        >>> round(float(grid[0]), 1), round(float(grid[-1]), 1), round(float(grid[1] / grid[0]), 3)
        (256.0, 1280.0, 1.01)
    """
    half = max(height, width) / 2.0
    low, high = (v * half for v in sampling.focal_range)
    count = max(2, int(math.ceil(math.log(high / low) / math.log1p(settings.focal_step))) + 1)
    return torch.logspace(math.log10(low), math.log10(high), count, dtype=torch.float64)


def nearest_rotation(directions: Tensor) -> Tensor:
    """The rotations (..., 3, 3) nearest, in the Frobenius norm, to matrices (..., 3, 3) whose columns are unit
    directions (Procrustes: ``U V^T`` of their SVD, with the sign that makes the determinant +1)."""
    U, _, Vh = torch.linalg.svd(directions)
    sign = torch.linalg.det(U @ Vh).sign()
    flip = torch.ones_like(U[..., 0, :])
    flip[..., 2] = sign
    return (U * flip[..., None, :]) @ Vh


def focal_support(
    K: Tensor, R: Tensor, segments: Tensor, mask: Tensor, focals: Tensor, settings: SharedSettings | None = None
) -> Tensor:
    """Each photo's line support at each focal length of the grid (step 2 of the module docstring).

    Only the grid points within ``settings.window`` (relative) of a photo's own focal length are scored; the others
    take the least support scored, so a photo says nothing about focal lengths far from its own answer.

    Args:
        K: (B, 3, 3) the photos' intrinsics (their principal points are kept); R: (B, 3, 3) their rotations.
        segments: (B, N, 2, 2) segments in the photos' pixels; mask: (B, N) bool.
        focals: (G,) focal lengths, pixels (:func:`focal_grid`).
        settings: window, kernel, inlier angle and iterations; None for the defaults.

    Returns:
        (B, G) float64 supports in [0, 1] (0 for a photo without segments).
    """
    settings = settings or SharedSettings()
    rows = []
    for k, r, seg, keep in zip(K.double(), R.double(), segments.double(), mask, strict=True):  # one photo at a time
        near = (focals / k[0, 0]).log().abs() <= math.log1p(settings.window)
        if not bool(near.any()):  # its own focal length is off the grid: the nearest grid point
            near = (focals / k[0, 0]).log().abs() == (focals / k[0, 0]).log().abs().min()
        scored = _support_at(k, r, seg, keep, focals[near].to(k), settings)
        row = torch.full_like(focals, float(scored.min()), dtype=torch.float64)
        rows.append(row.masked_scatter(near, scored))
    return torch.stack(rows) if rows else focals.new_zeros(0, len(focals), dtype=torch.float64)


def _support_at(K: Tensor, R: Tensor, segments: Tensor, mask: Tensor, focals: Tensor, settings: SharedSettings):
    """The (G,) line support of one photo's frame ``K`` (3, 3), ``R`` (3, 3) moved to each of the (G,) focal
    lengths and refitted there; ``segments`` (N, 2, 2), ``mask`` (N,)."""
    G = len(focals)
    Kg = intrinsics_matrix(focals, K[:2, 2])  # (G, 3, 3)
    directions = torch.linalg.solve(Kg, (K @ R).expand(G, 3, 3))  # the VPs seen with each focal length
    start = nearest_rotation(directions / torch.linalg.vector_norm(directions, dim=-2, keepdim=True))
    # the segments seen with focal length f are those seen with K's, scaled by K's focal length / f
    inv = (K[0, 0] / focals)[:, None, None, None]
    stretch = torch.cat([1.0 / inv, 1.0 / inv, torch.ones_like(inv)], -1)
    cam = scaled_camera_segments(camera_segments(segments[None], K[None]), inv, stretch)
    keep, lengths = mask.expand(G, -1), segment_lengths(segments[None], mask[None]).expand(G, -1)
    fitted = refit_rotation(cam, lengths, keep, start, settings.inlier_deg, settings.iterations)
    close = closeness_kernel(cam, fitted.transpose(1, 2)[:, None], settings.kernel_deg, keep)[:, 0]
    return (close * lengths).sum(-1) / lengths.sum(-1).clamp_min(1e-12)


def _peak(total: Tensor, log_focals: Tensor) -> Tensor:
    """The log focal length of the largest of (..., G) summed supports, refined by a parabola through it and its
    neighbours (the grid point itself at the grid's ends or where the three are not concave)."""
    i = total.argmax(-1).clamp(1, total.shape[-1] - 2)
    y0, y1, y2 = (total.gather(-1, (i + d)[..., None])[..., 0] for d in (-1, 0, 1))
    curve = y0 - 2.0 * y1 + y2
    offset = torch.where(curve < 0, 0.5 * (y0 - y2) / curve.clamp_max(-1e-300), torch.zeros_like(curve))
    at_end = (total.argmax(-1) == 0) | (total.argmax(-1) == total.shape[-1] - 1)
    offset = torch.where(at_end, torch.zeros_like(offset), offset.clamp(-0.5, 0.5))
    step = log_focals[1] - log_focals[0]
    return torch.where(at_end, log_focals[total.argmax(-1)], log_focals[i] + offset * step)


def joint_focal(support: Tensor, focals: Tensor, valid: Tensor, bootstrap: int = 200) -> SharedFocal:
    """The focal length of the largest summed support over the photos (step 3 of the module docstring).

    Args:
        support: (P, G) supports of :func:`focal_support`; focals: (G,) the grid, pixels; valid: (P,) bool, the
            photos that count (those with a valid frame).
        bootstrap: resamples of the photos for the standard deviation (a fixed seed).

    Returns:
        the :class:`SharedFocal`; without a valid photo, the grid's geometric middle with an infinite std.

    Example:
        >>> focals = torch.tensor([400.0, 500.0, 625.0], dtype=torch.float64)  # log-spaced
        >>> support = torch.tensor([[0.2, 0.5, 0.3], [0.1, 0.4, 0.4]], dtype=torch.float64)
        >>> round(joint_focal(support, focals, torch.tensor([True, True])).focal)  # between 500 and 625
        529
    """
    log_focals = focals.double().log()
    used = support.double()[valid]
    if len(used) == 0:
        return SharedFocal(float(log_focals.mean().exp()), math.inf, 0)
    focal = float(_peak(used.sum(0), log_focals).exp())
    std = 0.0
    if len(used) > 1 and bootstrap > 0:
        draws = torch.randint(len(used), (bootstrap, len(used)), generator=torch.Generator().manual_seed(0))
        resampled = _peak(used[draws].sum(1), log_focals).exp()
        std = float(resampled.std())
    return SharedFocal(focal, std, len(used))


def with_shared_focal(result: Calibration, shared: SharedFocal) -> Calibration:
    """A photo's calibration with the shared focal length as its known one: ``shared_photos`` says how many photos
    it came from, and ``fov_v_std`` is the field of view's share of the shared focal length's standard deviation
    (``|d fov_v / d f| = H / (f^2 + H^2 / 4)`` radians per pixel)."""
    f, height = result.focal, result.image_size[..., 0].to(result.focal)
    fov_std = torch.rad2deg(shared.std * height / (f.square() + height.square() / 4.0))
    photos = torch.full_like(result.focal, shared.photos, dtype=torch.long)
    return with_shared_options(replace(result, fov_v_std=fov_std, shared_photos=photos), shared.options)


def not_shared_message(photos: int, total: int) -> str:
    """What is said where a camera was to be shared by ``total`` photos of which ``photos`` (fewer than two) have
    lines to measure it by.

    Example:
        >>> not_shared_message(1, 2)
        'only 1 of the 2 photos has lines to measure the camera by, so nothing is shared: each photo is ...'
    """
    if total == 1:
        return "one photo cannot share a camera: it is calibrated alone (its own focal length and uncertainty)"
    some = f"only {photos}" if photos else "none"
    return (f"{some} of the {total} photos has lines to measure the camera by, so nothing is shared: each photo is "
            "calibrated alone (its own focal length and uncertainty)")


def not_shared_folders(folders: list[str], total: int) -> str:
    """What is said where the photos of each folder were to share a camera, but in ``folders`` (of ``total``)
    fewer than two photos have lines.

    Example:
        >>> not_shared_folders(["a", "b"], 3)
        '2 of the 3 folders have fewer than two photos with lines (a, b), so their photos share nothing: ...'
    """
    named = ", ".join(folders[:3]) + (f" and {len(folders) - 3} more" if len(folders) > 3 else "")
    return (f"{len(folders)} of the {total} folders have fewer than two photos with lines ({named}), so their photos "
            "share nothing: each is calibrated alone (its own focal length and uncertainty)")


# --- the two passes over the photos (``ngp_kornia.calibrate(photos, priors={"shared_intrinsics": True})``) ---


def calibrate_shared(items: list, run: Run) -> list[Calibration]:
    """Every photo calibrated alone, one camera from the evidence of all of them (the module docstring), then every
    photo again with that camera as a known one. Between the passes only each photo's segments are kept (the
    pixels of a file are read again), so a long list fits in memory. With fewer than two photos that have lines,
    the photos' own calibrations are returned and an ``NGPWarning`` says so.

    Args:
        items: the photos (paths, arrays, Pillow images or tensors), of one size (or its transpose).
        run: the call (:class:`~ngp_kornia.pipeline.runner.Run`).

    Raises:
        ValueError: an empty list, photos of different sizes (not one camera), or ``run.exif`` (a focal length per
            photo, where one is shared).
    """
    if run.exif:
        raise ValueError("shared_intrinsics estimates one focal length for all the photos; exif gives each its own: "
                         "use one of them (or give the known focal length as priors={'focal': ...})")
    if not items:
        raise ValueError("calibrate() got an empty list; give at least one image (path, array or tensor)")
    run = _checked_run(run, len(items))
    kept, shared, alone = _first_pass(items, run)
    if alone and shared.photos < 2:  # one photo's lines, or none: nothing to share between photos
        warnings.warn(NGPWarning(not_shared_message(shared.photos, len(items))), stacklevel=3)
        return alone
    priors = run.priors.with_focal(shared.focal)
    if shared.options is not None:
        priors = replace(priors, **shared.options.priors)
    results = []
    with Lookahead(lambda i: _pixels_again(items[i], kept[i])) as ahead:
        for i, item in enumerate(items):
            given = ahead.get(i, i + 1 if i < len(items) - 1 else None)
            own = priors.image(i) if priors.count else priors  # a gravity prior per photo stays its own
            results.append(with_shared_focal(calibrate_input(item, given._replace(priors=own), run), shared))
    return results


def _checked_run(run: Run, photos: int) -> Run:
    """The call with its priors for ``photos`` photos: the camera's own one for all (a gravity prior may differ)."""
    priors = run.priors.for_batch(photos, "list")
    for name in INTRINSIC_PRIORS:
        if isinstance(getattr(priors, name), PerImage):
            raise InputError(f"shared_intrinsics: the photos are one camera, so {name} is one value for all of "
                             "them, not one per photo")
    return run._replace(priors=priors)


def shared_camera(items: list, run: Run) -> SharedFocal:
    """The camera :func:`calibrate_shared` gives every photo, without calibrating them again with it; photos that
    cannot be read or calibrated are left out (they give no evidence).

    Raises:
        ValueError: photos of different sizes, or none readable.
    """
    return _first_pass(items, _checked_run(run, len(items)), skip_unreadable=True)[1]


def _first_pass(items: list, run: Run, skip_unreadable: bool = False) -> tuple[list[Input], SharedFocal, list]:
    """Each photo calibrated alone and scored on the common focal grid: what is kept of each photo's inputs (its
    pixels only where they are the caller's tensor or a stand-in), the joint camera and the photos' own results
    (none where nothing is estimated jointly). With ``skip_unreadable`` a photo that cannot be read or calibrated
    is left out (and nothing is kept of any)."""
    kept, found, sizes, alone = [], {"support": [], "valid": [], "options": []}, [], []
    priors = run.priors
    with Lookahead(lambda i: _with_segments(read_input(items[i], item_run(run, i)), run)) as ahead:
        for i, item in enumerate(items):
            try:
                given = ahead.get(i, i + 1 if i < len(items) - 1 else None)
            except (NGPError, ValueError, TypeError, OSError):
                if not skip_unreadable:
                    raise
                continue
            sizes.append(tuple(given.batch.shape[-2:]))
            height, width = _one_size(sizes, tied_to_pixels(priors))
            if not priors.known_focal or estimates(priors):
                alone.append(calibrate_input(item, given, run))
                _evidence(found, alone[-1], given, run, height, width)
            # the caller's pixels, or a stand-in, are kept; a file's are read again
            keep_pixels = isinstance(item, Tensor) or given.batch.stride() == (0, 0, 0, 0)
            kept.append(given._replace(batch=given.batch if keep_pixels else None))
    if not kept:
        raise ValueError("no photo could be read, so no focal length can be shared")
    return kept, _joint_camera(found, run, len(kept), height, width), alone


def _evidence(found: dict, alone: Calibration, given: Input, run: Run, height: int, width: int) -> None:
    """What one photo's own calibration says of the camera: its support on the focal grid and of the options
    asked for as estimates (:func:`~ngp_kornia.pipeline.camera_model.option_evidence`), appended to ``found``."""
    K, R, ok = (t if alone.batched else t[None] for t in (alone.K, alone.R, alone.valid))
    config, priors = run.parser.config, run.priors
    found["valid"].append(ok.cpu())  # the photos with lines to measure the camera by
    if not priors.known_focal:
        grid = focal_grid(height, width, config.shared, config.sampling)
        found["support"].append(focal_support(K, R, given.segments.to(K), given.mask, grid, config.shared))
    found["options"].append({name: value.cpu() for name, value in option_evidence(alone, priors).items()})


def _joint_camera(found: dict, run: Run, photos: int, height: int, width: int) -> SharedFocal:
    """The shared camera of the photos' evidence (the module docstring)."""
    config, priors = run.parser.config, run.priors
    if priors.known_focal:  # nothing to estimate: the known focal length is every photo's
        photos = int(torch.cat(found["valid"]).sum()) if found["valid"] else photos  # those that tell the rest
        shared = SharedFocal(priors.focal_pixels(height, width), 0.0, photos)
    else:
        grid = focal_grid(height, width, config.shared, config.sampling)
        shared = joint_focal(torch.cat(found["support"]), grid, torch.cat(found["valid"]), config.shared.bootstrap)
    if estimates(priors):
        shared = shared._replace(options=joint_options(found["options"], config, height, width))
    return shared


def _pixels_again(item: object, kept: Input) -> Input:
    """The second pass's input of a photo: its kept input, with the pixels of a file or array read again."""
    if kept.batch is not None:
        return kept
    rgb, _ = read_rgb_oriented(item)
    return kept._replace(batch=pixels(rgb))


def _with_segments(given: Input, run: Run) -> Input:
    """An input with a tensor's segments detected here (the shared focal length reads them)."""
    if given.segments is not None:
        return given
    segments, mask = detect_segments(given.batch, run.parser.config.segments)
    return given._replace(segments=segments, mask=mask)


def _one_size(sizes: list[tuple[int, int]], upright: bool = False) -> tuple[int, int]:
    """The photos' ``(height, width)``, one for all (a turned photo's transpose counts as the same, unless
    ``upright``: an option tied to the pixels turns with the photo)."""
    first = sizes[0]
    for size in sizes[1:]:
        if size not in ((first,) if upright else (first, first[::-1])):
            raise ValueError(
                f"shared_intrinsics needs photos of one camera, so of one size; got {first[1]}x{first[0]} and "
                f"{size[1]}x{size[0]} pixels: calibrate photos of different sizes apart"
            )
    return first
