"""FSNet's inputs (Eq. 13-15): the image and its line map L, each candidate's closeness maps A_x, A_y, A_z and its
parameters (VPs and focal length), and the combination of FSNet's score with the Manhattan score (Eq. 22). Pure
functions of the image, the segments and the frames; :mod:`ngp_kornia.nets.fsnet` is the network that reads them.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry import (
    DrawnPixels,
    canonical_manhattan_rotation,
    closeness,
    closeness_of,
    drawn_pixels,
    line_vp_cosine,
    normalize,
    pooled_maps,
    rasterize_segments,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
)
from ngp_kornia.geometry.frames import FrameCandidates

__all__ = [
    "FSNetImageInputs",
    "FSNetInputs",
    "NUM_PARAMS",
    "NUM_SUPPORT",
    "SUPPORT_ANGLES",
    "VARIANTS",
    "area_resize",
    "canonical_frame_vps",
    "draw_maps",
    "frame_closeness",
    "frame_scores",
    "frame_support",
    "fsnet_frame_inputs",
    "fsnet_image_inputs",
    "fsnet_inputs",
    "fsnet_line_inputs",
    "with_images",
]


#: per-candidate parameters: 9 VP coordinates (three unit VPs, row-major) and the focal length
NUM_PARAMS = 10
#: angles (degrees) of the line-support features of ``use_support``
SUPPORT_ANGLES = (0.25, 0.5, 1.0, 2.0, 4.0)
#: line-support features per candidate: the share per VP and for the closest VP, at each angle
NUM_SUPPORT = 4 * len(SUPPORT_ANGLES)
VARIANTS = ("faithful", "shared")
_MIN_CLOSENESS = 1e-6  # smaller closeness values are drawn as 0
_MIN_EXPONENT = -30.0  # exp(-30) < 1e-14: closeness that is drawn as 0


class FSNetInputs(NamedTuple):
    """The inputs of :class:`FSNet` at its input size ``S`` (``net(*inputs)``).

    Attributes:
        images: (B, 3, S, S) RGB in [0, 1].
        line_map: (B, 1, S, S) binary line map L (Eq. 13).
        closeness: (B, F, 3, S, S) closeness maps A_x, A_y, A_z of each candidate (Eq. 15), or their means over
            cells of ``c`` x ``c`` pixels, (B, F, 3, S / c, S / c), when built with ``pool=c`` (what the shared
            variant uses of them).
        params: (B, F, 10) each candidate's three VPs (unit vectors in the pseudo camera, flattened row-major, in the
            order of :func:`canonical_frame_vps`) and its focal length (pseudo-camera units, 0 for invalid frames).
    """

    images: Tensor
    line_map: Tensor
    closeness: Tensor
    params: Tensor


class FSNetImageInputs(NamedTuple):
    """What FSNet's inputs take from the image and its segments alone, before any frame candidate
    (:func:`fsnet_image_inputs`): this part can be built, and the shared trunk run on it, while the frames are
    still being sampled and scored.

    Attributes:
        images: (B, 3, S_h, S_w) the images resized to the network input; None in the result of
            :func:`fsnet_line_inputs`, until :func:`with_images` fills it in.
        segments: (B, N, 2, 2) the segments in the pixels of the network input.
        drawn: with pooled closeness maps, the segments' pixels at the network input and the line map
            (:class:`~ngp_kornia.geometry.DrawnPixels`); None where the line map is drawn with the full closeness
            maps.
        image_size: (H, W) of the original images.
        input_size: (S_h, S_w) of the network input.
        pool: the cell of the pooled closeness maps, or None for full maps.
    """

    images: Tensor | None
    segments: Tensor
    drawn: DrawnPixels | None
    image_size: tuple[int, int]
    input_size: tuple[int, int]
    pool: int | None


def canonical_frame_vps(frames: FrameCandidates) -> Tensor:
    """The three VPs of each frame in a canonical order and sign, as unit vectors in the pseudo camera.

    A Manhattan frame does not say which horizontal axis is "x" nor which way an axis points, so the same frame can
    come out of sampling in several labellings. They are resolved with
    :func:`~ngp_kornia.geometry.canonical_manhattan_rotation`: row 1 is the vertical (pointing down, y >= 0), row 2
    the horizontal axis closest to the optical axis (pointing forward), row 0 the remaining one (x = y cross z, so
    pointing right). The labelling is continuous except at 45 degrees of yaw, where the two horizontal axes swap.

    Args:
        frames: candidates with rotations ``R`` (B, F, 3, 3) and focal lengths ``focal`` (B, F) in the pseudo
            camera; invalid frames (focal 0) use focal 1, so their VPs stay finite.

    Returns:
        (B, F, 3, 3): row ``i`` is the VP ``K R_c[:, i]`` with ``K = diag(f, f, 1)``, normalised.

    Example:
        >>> eye = torch.eye(3)[[2, 1, 0]].T * torch.tensor([1.0, 1.0, -1.0])  # x and z swapped, same frame
        >>> fr = FrameCandidates(None, None, torch.ones(1, 1), eye.expand(1, 1, 3, 3), None, torch.ones(1, 1) > 0)
        >>> canonical_frame_vps(fr)[0, 0]
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
    """
    KORNIA_CHECK_SHAPE(frames.R, ["B", "F", "3", "3"])
    KORNIA_CHECK_SHAPE(frames.focal, ["B", "F"])
    R = canonical_manhattan_rotation(frames.R)
    f = torch.where(frames.focal > 0, frames.focal, 1.0)
    scale = F.pad(f[..., None].expand(*f.shape, 2), (0, 1), value=1.0)  # (f, f, 1)
    return normalize(R.transpose(-1, -2) * scale[..., None, :]) + 0.0


def frame_support(lines: Tensor, lengths: Tensor, mask: Tensor, vps: Tensor) -> Tensor:
    """Line support of each candidate: the length-weighted share of the lines passing within each of
    :data:`SUPPORT_ANGLES` of each VP, and of the closest of the three VPs (the Manhattan score at a hard
    threshold). Exact, where the maps are drawn at the network's low resolution.

    The angle is the one of Eq. 14's closeness, ``asin |cos(l, v)|``: between the VP's ray and the line's plane
    through the camera centre.

    Args:
        lines: (B, N, 3) lines in the pseudo camera.
        lengths: (B, N) segment lengths.
        mask: (B, N) bool.
        vps: (B, F, 3, 3) each candidate's three VPs (rows).

    Returns:
        (B, F, 20): for each angle, the shares of VP 0, 1, 2 and of the closest VP (angle-major).

    Example:
        >>> lines = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, -0.5]]])  # x = 0 and y = 0.5
        >>> vps = torch.eye(3)[[1, 0, 2]].expand(1, 1, 3, 3)  # VPs (0, 1, 0), (1, 0, 0), (0, 0, 1)
        >>> frame_support(lines, torch.tensor([[3.0, 1.0]]), torch.ones(1, 2, dtype=torch.bool), vps)[0, 0, :4]
        tensor([0.7500, 0.2500, 0.7500, 1.0000])
    """
    cosine = line_vp_cosine(lines, vps)  # (B, F, 3, N)
    cosine = torch.cat([cosine, cosine.amin(2, keepdim=True)], 2)  # (B, F, 4, N)
    w = lengths * mask.to(lengths)
    w = w / w.sum(-1, keepdim=True).clamp_min(torch.finfo(w.dtype).eps)
    limits = torch.tensor(SUPPORT_ANGLES, dtype=cosine.dtype, device=cosine.device).deg2rad().sin()
    inside = (cosine[..., None, :, :] <= limits[:, None, None]).to(w)  # (B, F, A, 4, N)
    return (inside @ w[:, None, None, :, None])[..., 0].flatten(2)


def frame_scores(s_vh: Tensor, manhattan: Tensor, valid: Tensor, use_manhattan: bool = True) -> Tensor:
    """Final scores of frame candidates (Eq. 22): ``s_i = s_vh * m_i``, the FSNet score times the Manhattan score
    (or ``s_vh`` alone without ``use_manhattan``), zero for invalid frames.

    Args:
        s_vh: (B, F) FSNet scores in [0, 1] (the sigmoid of its output).
        manhattan: (B, F) Manhattan scores ``m_i`` (Eq. 21).
        valid: (B, F) bool.
        use_manhattan: multiply by ``m_i``.

    Returns:
        (B, F) scores.

    Example:
        >>> frame_scores(torch.tensor([[0.5, 0.8]]), torch.tensor([[0.4, 0.9]]), torch.tensor([[True, False]]))
        tensor([[0.2000, 0.0000]])
    """
    scores = s_vh * manhattan if use_manhattan else s_vh
    return torch.where(valid, scores, torch.zeros_like(scores))


def fsnet_inputs(
    images: Tensor,
    segments: Tensor,
    mask: Tensor,
    frames: FrameCandidates,
    size: int | tuple[int, int] = 224,
    kernel_angle: float | None = 88.0,
    chunk_size: int = 32,
    support: bool = False,
    pool: int | None = None,
    lines: Tensor | None = None,
) -> FSNetInputs:
    r"""Build FSNet's inputs for a batch of images and their frame candidates.

    The image is resized to the network input (``size``, aspect ratio not kept, as the paper's 224 x 224), the
    segments are scaled to it and drawn as the line map (Eq. 13) and, per candidate, as closeness maps (Eq. 15)
    of :func:`frame_closeness`, measured on the segments' lines in the pseudo camera of the *original* image
    (where the candidates' VPs live), so it does not depend on ``size``.

    Args:
        images: (B, 3, H, W) RGB in [0, 1] at the size the segments were measured in.
        segments: (B, N, 2, 2) segments in the pixels of ``images``.
        mask: (B, N) bool, False for padding (never drawn).
        frames: (B, F) frame candidates in the pseudo camera of ``images`` (:mod:`ngp_kornia.pipeline.candidates`).
        size: network input size, ``S`` or ``(S_h, S_w)``.
        kernel_angle: closeness kernel width in degrees, or None for Eq. 14 (see :func:`frame_closeness`).
        chunk_size: candidates rasterised at once (bounds the memory of drawing, not of the output).
        support: append each candidate's :func:`frame_support` (20 values) to its parameters.
        pool: give the closeness maps as means over cells of ``pool`` x ``pool`` pixels (the size must be a multiple
            of it), computed without drawing the full maps (:func:`~ngp_kornia.geometry.line_map_and_pooled_maps`).
        lines: (B, N, 3) the segments' pseudo-camera lines in the images' dtype, when already computed, else None.

    Returns:
        :class:`FSNetInputs`. Invalid candidates get finite inputs (score them and mask the scores). The closeness
        maps take ``B * F * 3 * S^2`` floats: 38 MB per image for 64 candidates at 224.

    Example:
        >>> fr = FrameCandidates(None, None, torch.ones(1, 2), torch.eye(3).expand(1, 2, 3, 3), None, None)
        >>> seg = torch.tensor([[[[10.0, 5.0], [10.0, 40.0]]]])
        >>> x = fsnet_inputs(torch.rand(1, 3, 48, 64), seg, torch.ones(1, 1, dtype=torch.bool), fr, size=32)
        >>> [tuple(t.shape) for t in x]
        [(1, 3, 32, 32), (1, 1, 32, 32), (1, 2, 3, 32, 32), (1, 2, 10)]
    """
    image_inputs = fsnet_image_inputs(images, segments, mask, size, pool)
    return fsnet_frame_inputs(image_inputs, segments, mask, frames, kernel_angle, chunk_size, support, lines)


def fsnet_image_inputs(
    images: Tensor, segments: Tensor, mask: Tensor, size: int | tuple[int, int] = 224, pool: int | None = None
) -> FSNetImageInputs:
    """The part of :func:`fsnet_inputs` that needs no frame candidate: the resized images, the segments at the
    network input and, with ``pool``, the pixels they cover and the line map. Arguments as :func:`fsnet_inputs`."""
    KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(mask, ["B", "N"])
    return with_images(fsnet_line_inputs(segments.to(images), mask, images.shape[-2:], size, pool), images)


def fsnet_line_inputs(
    segments: Tensor,
    mask: Tensor,
    image_size: tuple[int, int],
    size: int | tuple[int, int] = 224,
    pool: int | None = None,
) -> FSNetImageInputs:
    """:func:`fsnet_image_inputs` without the image: the segments of an ``image_size`` (H, W) image scaled to the
    network input and, with ``pool``, their pixels and line map; ``images`` is None (see :func:`with_images`)."""
    H, W = image_size
    out_h, out_w = (size, size) if isinstance(size, int) else tuple(size)
    # pixel centres map to pixel centres: x' = (x + 0.5) * S / W - 0.5
    scale = torch.tensor([out_w / W, out_h / H], device=segments.device, dtype=segments.dtype)
    scaled = (segments + 0.5) * scale - 0.5
    drawn = None if pool is None else drawn_pixels(scaled, mask, out_h, out_w)
    return FSNetImageInputs(None, scaled, drawn, (H, W), (out_h, out_w), pool)


def with_images(inputs: FSNetImageInputs, images: Tensor) -> FSNetImageInputs:
    """``inputs`` of :func:`fsnet_line_inputs` with the (B, 3, H, W) images resized to the network input."""
    KORNIA_CHECK(tuple(images.shape[-2:]) == tuple(inputs.image_size), "the images must have the segments' size")
    same = tuple(images.shape[-2:]) == inputs.input_size
    return inputs._replace(images=images if same else area_resize(images, inputs.input_size))


def fsnet_frame_inputs(
    image_inputs: FSNetImageInputs,
    segments: Tensor,
    mask: Tensor,
    frames: FrameCandidates,
    kernel_angle: float | None = 88.0,
    chunk_size: int = 32,
    support: bool = False,
    lines: Tensor | None = None,
) -> FSNetInputs:
    """:func:`fsnet_inputs` from its frame-free part ``image_inputs`` (:func:`fsnet_image_inputs` of the same
    images, segments and mask); the other arguments as :func:`fsnet_inputs`."""
    KORNIA_CHECK(chunk_size > 0, "chunk_size must be positive")
    KORNIA_CHECK(image_inputs.images is not None, "image_inputs has no images yet: fill them in with with_images()")
    resized = image_inputs.images
    H, W = image_inputs.image_size
    segments = segments.to(resized)
    vps = canonical_frame_vps(frames).to(resized)  # (B, F, 3, 3)
    lines = segments_to_lines(to_pseudo_camera(segments, H, W)) if lines is None else lines
    values = frame_closeness(lines, vps, kernel_angle)
    lmap, closeness = draw_maps(image_inputs, mask, values, chunk_size)
    params = [vps.flatten(-2), frames.focal.to(resized)[..., None]]
    if support:
        params.append(frame_support(lines, segment_lengths(segments), mask, vps))
    return FSNetInputs(resized, lmap, closeness, torch.cat(params, -1))


def area_resize(images: Tensor, size: tuple[int, int]) -> Tensor:
    """(B, 3, H, W) images resized to ``size`` = (h, w) by pixel-area averaging, OpenCV's ``INTER_AREA``: the filter
    the training cache resized FSNet's images with. Computed on the CPU in float32 (0.8 ms for a 640x480 image,
    against 2 ms for torch's antialiased bilinear filter). Where the images need gradients these flow through torch's
    antialiased bilinear resize, a close stand-in (the values stay OpenCV's).

    Example:
        >>> area_resize(torch.arange(16.0).view(1, 1, 4, 4).expand(1, 3, 4, 4), (2, 2))[0, 0]
        tensor([[ 2.5000,  4.5000],
                [10.5000, 12.5000]])
    """
    h, w = size
    pixels = images.detach().permute(0, 2, 3, 1).to("cpu", torch.float32).numpy()  # channels last: OpenCV's layout
    small = np.stack([cv2.resize(np.ascontiguousarray(im), (w, h), interpolation=cv2.INTER_AREA) for im in pixels])
    out = torch.from_numpy(small.reshape(len(images), h, w, -1)).permute(0, 3, 1, 2).to(images)
    if torch.is_grad_enabled() and images.requires_grad:
        smooth = F.interpolate(images, size, mode="bilinear", align_corners=False, antialias=True)
        out = out + (smooth - smooth.detach())  # OpenCV's values, the bilinear filter's gradient
    return out


def frame_closeness(lines: Tensor, vps: Tensor, kernel_angle: float | None = 88.0) -> Tensor:
    r"""Closeness of each line to each VP of each frame candidate, the values the closeness maps draw (Eq. 15).

    With ``kernel_angle=None`` it is Eq. 14, :math:`1 - |\cos|` between the line and VP vectors. That is linear in
    the cosine: a line pointing exactly at the VP gets 1, one a few degrees off still about 0.95, and unrelated
    lines spread over all of [0, 1] (median about 0.5 for random frames), so the maps mostly encode line
    directions rather than which lines vanish at the VP, and the shared variant's average pooling (before any
    non-linearity) loses the small difference. The default is therefore the sharp kernel of
    :func:`~ngp_kornia.geometry.closeness` at 88 degrees (lines within about two degrees of the VP count):
    the kernel the parser uses for Eq. 21, a little wider for LSD's angular noise on short segments. A network is
    trained for one choice (:attr:`FSNet.kernel_angle`). Closeness below 1e-6 is set to 0: the kernel's tail is
    full of subnormal floats, which make CPU arithmetic on the maps many times slower.

    Args:
        lines: (B, N, 3) homogeneous lines in the pseudo camera.
        vps: (B, F, 3, 3) each frame's three VPs (rows) in the pseudo camera.
        kernel_angle: kernel width in degrees, or None for Eq. 14.

    Returns:
        (B, F, 3, N) closeness in [0, 1].

    Example:
        >>> lines = torch.tensor([[[1.0, 0.0, 0.0]]])  # the vertical line x = 0, through the VP (0, 1, 0)
        >>> frame_closeness(lines, torch.eye(3)[[1, 0, 2]].expand(1, 1, 3, 3)).squeeze()
        tensor([1., 0., 0.])
    """
    if kernel_angle is None:
        values = closeness(lines, vps)
    else:
        # the exponent floored where the kernel is far below _MIN_CLOSENESS anyway: the exponential of large
        # negative numbers underflows to subnormals, which the CPU computes slowly
        values = closeness_of(line_vp_cosine(lines, vps), kernel_angle, floor=_MIN_EXPONENT)  # (B, F, 3, N)
    return values.masked_fill(values < _MIN_CLOSENESS, 0.0)


def draw_maps(
    image_inputs: FSNetImageInputs, mask: Tensor, values: Tensor, chunk_size: int
) -> tuple[Tensor, Tensor]:
    """The line map (B, 1, S_h, S_w) and the closeness maps (B, F, 3, S_h, S_w) (or their ``pool`` x ``pool``
    cell means) of the segments of ``image_inputs``, drawn at the network input with values (B, F, 3, N)."""
    out_h, out_w = image_inputs.images.shape[-2:]
    B, num = values.shape[:2]
    values = values.flatten(1, 2).transpose(1, 2)  # (B, N, F * 3)
    drawn, pool = image_inputs.drawn, image_inputs.pool
    if drawn is None:
        # the line map L is one more channel of ones: the segments' pixels are found once for all maps
        ones = torch.ones_like(values[..., :1])
        maps = rasterize_segments(
            image_inputs.segments, mask, torch.cat([ones, values], -1), out_h, out_w, 3 * chunk_size + 1
        )
        return maps[:, :1], maps[:, 1:].reshape(B, num, 3, out_h, out_w)
    closeness = pooled_maps(drawn, values, pool)
    return drawn.line_map, closeness.reshape(B, num, 3, out_h // pool, out_w // pool)
