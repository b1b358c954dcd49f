r"""FSNet, the frame scoring network of Sec. 3.2 (Eq. 13-20): scores how well each Manhattan-frame candidate (three
VPs and a focal length) fits an image, from the image, its line map L (Eq. 13) and the candidate's closeness maps
A_x, A_y, A_z (Eq. 14-15). ``sigmoid`` of the output estimates the score :math:`s_{vh}` of Eq. 20.

Two variants share one interface (:class:`FSNet` with ``variant=...``):

* ``"faithful"``, the paper's network: a ResNet over a 17-channel tensor per candidate (3 image + 1 line map +
  3 closeness maps + 10 constant planes holding the candidate's 9 VP coordinates and its focal length), globally
  pooled, then a linear layer. One full CNN pass per candidate, so its cost grows linearly with the candidates
  (about 2.4 GMAC per candidate with the default ResNet-18 at 224 x 224: the 17-channel 7x7 stem alone is 0.67).
* ``"shared"``: the trunk runs once per image on the image and the line map (4 channels) to a stride-16 feature
  map; each candidate only adds a light head on that low-resolution map: its closeness maps are average-pooled to
  the trunk's resolution (as line density and as mean closeness of the line pixels, a local form of Eq. 21), its
  VPs and focal length go through an MLP, and two 3x3 convolutions, global average and max pooling and an MLP give
  the score. Scoring many candidates then costs little more than scoring one.

Both are equivariant to the candidates' order (each candidate is scored independently; with BatchNorm, in eval
mode) and differentiable with respect to every input.

The ablations of the paper's Table 4 are constructor switches: ``use_image=False`` ("FSNet w/o image") drops the
image channels, ``use_maps=False`` ("w/o L and A") drops the line and closeness maps; inputs that are dropped are
still passed (one interface) but ignored.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor, nn

from ngp_kornia.geometry import (
    DrawnPixels,
    canonical_manhattan_rotation,
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
from ngp_kornia.nets.resnet import LAYOUTS, ResNet

__all__ = [
    "FSNet",
    "FSNetImageInputs",
    "FSNetInputs",
    "NUM_PARAMS",
    "NUM_SUPPORT",
    "VARIANTS",
    "canonical_frame_vps",
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
_DEFAULT_LAYOUT = {"faithful": LAYOUTS["resnet18"], "shared": LAYOUTS["resnet18-half-s16"]}
_DEFAULT_NORM = {"faithful": "batch", "shared": "group"}


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
    lmap, closeness = _draw_maps(image_inputs, mask, values, chunk_size)
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
    :func:`~ngp_kornia.geometry.sharp_closeness` at 88 degrees (lines within about two degrees of the VP count):
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
    cosine = line_vp_cosine(lines, vps)  # (B, F, 3, N)
    if kernel_angle is None:
        values = 1.0 - cosine
    else:
        # sharp_kernel's exponent, floored where the kernel is far below _MIN_CLOSENESS anyway: the exponential of
        # large negative numbers underflows to subnormals, which the CPU computes slowly
        exponent = cosine.square() / (-2.0 * math.cos(math.radians(kernel_angle)) ** 2)  # -(c^2) / (2 cos^2 a)
        values = exponent.clamp_min(_MIN_EXPONENT).exp()
    return values.masked_fill(values < _MIN_CLOSENESS, 0.0)


def _draw_maps(
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


def _mlp(sizes: Sequence[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class FSNet(nn.Module):
    """Frame scoring network (Sec. 3.2), in the paper's per-candidate form or with a shared image trunk.

    Input channels (:attr:`in_channels`, the backbone's input):

    =================  ==============================  ==================================
    switches           ``"faithful"`` (per candidate)  ``"shared"`` (trunk, once/image)
    =================  ==============================  ==================================
    default            17 = 3 image + 1 L + 3 A + 10   4 = 3 image + 1 L
    use_image=False    14 = 1 L + 3 A + 10             1 = L
    use_maps=False     13 = 3 image + 10               3 = image
    both False         10 = params planes              0 (no trunk: params MLP only)
    =================  ==============================  ==================================

    In the shared variant each candidate's head also takes 6 low-resolution map channels (A pooled as line density
    and as mean closeness over line pixels; dropped with ``use_maps=False``) and the 10 parameters (30 with
    ``use_support``).

    Args:
        variant: ``"faithful"`` or ``"shared"`` (see the module notes).
        widths: backbone stage widths; default ResNet-18's ``(64, 128, 256, 512)`` for faithful, ``(32, 64, 128)``
            (stride 16) for shared. Two stages give a stride-8 trunk.
        depths: blocks per stage; default ``(2, 2, 2, 2)`` for faithful, ``(2, 2, 2)`` for shared (the first three
            stages of ResNet-18 at half width).
        norm: ``"batch"`` or ``"group"`` for the backbone; default BatchNorm for faithful (its statistics come from
            each backbone pass, B times the chunk's candidates, and it is a free affine map at inference) and
            GroupNorm for shared, whose trunk only sees the B images of a batch (the paper trains with B = 2).
        head_width: channels of the shared variant's head.
        input_size: the side the inputs are built at (:meth:`prepare_inputs`); the network itself is fully
            convolutional and accepts any size.
        use_image: feed the image (False: "FSNet w/o image").
        use_maps: feed L and A (False: "FSNet w/o L and A").
        use_support: also give each candidate its exact line support (:func:`frame_support`, 20 values) with its
            parameters (30 instead of 10; in the faithful variant as 20 more constant planes). The maps are drawn at
            the network's resolution, where frames a few pixels apart look the same; the support tells them apart.
        kernel_angle: closeness kernel of the inputs (:func:`fsnet_inputs`); None for Eq. 14.
        chunk_size: at most this many candidate images per backbone pass (faithful) or head pass (shared), so
            memory at inference does not grow with the candidates. (With gradients every pass stays in memory.)
        backbone: a custom backbone (interface in :mod:`ngp_kornia.nets.resnet`) replacing the built-in ResNet;
            its ``in_channels`` must match the table. Such a network has no :meth:`settings`.

    Example:
        >>> net = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8).eval()
        >>> x = (torch.rand(2, 3, 64, 64), torch.rand(2, 1, 64, 64), torch.rand(2, 5, 3, 64, 64), torch.rand(2, 5, 10))
        >>> net(*x).shape, net.in_channels
        (torch.Size([2, 5]), 4)
    """

    def __init__(
        self,
        variant: str = "shared",
        widths: Sequence[int] | None = None,
        depths: Sequence[int] | None = None,
        norm: str | None = None,
        head_width: int = 32,
        input_size: int = 224,
        use_image: bool = True,
        use_maps: bool = True,
        use_support: bool = False,
        kernel_angle: float | None = 88.0,
        chunk_size: int = 32,
        backbone: nn.Module | None = None,
    ) -> None:
        super().__init__()
        KORNIA_CHECK(variant in VARIANTS, f"unknown FSNet variant {variant!r}: use one of {VARIANTS}")
        KORNIA_CHECK(chunk_size > 0, "chunk_size must be positive")
        self.variant, self.head_width, self.input_size, self.chunk_size = variant, head_width, input_size, chunk_size
        self.use_image, self.use_maps, self.kernel_angle = use_image, use_maps, kernel_angle
        self.use_support = use_support
        self.num_params = NUM_PARAMS + (NUM_SUPPORT if use_support else 0)
        layout = _DEFAULT_LAYOUT[variant]
        self.widths = tuple(layout[0] if widths is None else widths)
        self.depths = tuple(layout[1] if depths is None else depths)
        self.norm = _DEFAULT_NORM[variant] if norm is None else norm
        self.custom_backbone = backbone is not None
        image_ch = 3 if use_image else 0
        if variant == "faithful":
            self.in_channels = image_ch + (4 if use_maps else 0) + self.num_params
        else:
            self.in_channels = image_ch + (1 if use_maps else 0)
        if backbone is None and self.in_channels > 0:
            backbone = ResNet(self.in_channels, self.widths, self.depths, self.norm)
            if variant == "shared":  # its trunk runs channels-last (_trunk): so do its weights, sparing a conversion
                backbone = backbone.to(memory_format=torch.channels_last)
        if backbone is not None:
            got = getattr(backbone, "in_channels", self.in_channels)
            KORNIA_CHECK(got == self.in_channels, f"the backbone takes {got} channels, FSNet feeds {self.in_channels}")
        self.backbone = backbone
        feat = 0 if backbone is None else int(backbone.out_channels)
        if variant == "faithful":
            self.fc = nn.Linear(feat, 1)
            return
        d = head_width
        self.context = nn.Conv2d(feat, d, 1) if backbone is not None else None
        self.map_proj = nn.Conv2d(6, d, 1, bias=False) if use_maps else None
        self.param_mlp = _mlp([self.num_params, d, d])
        self.conv1 = nn.Conv2d(d, d, 3, padding=1)
        self.conv2 = nn.Conv2d(d, d, 3, padding=1)
        self.scorer = _mlp([2 * d, d, 1])
        if backbone is not None and not self.custom_backbone:
            # the head adds every candidate's maps to the trunk's channels-last context map: channels-last weights
            # give its convolutions channels-last outputs and spare a weight conversion per call (the same values)
            for conv in (self.map_proj, self.conv1, self.conv2):
                if conv is not None:
                    conv.to(memory_format=torch.channels_last)

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        if self.custom_backbone:
            raise ValueError("an FSNet with a custom backbone cannot be rebuilt from settings; save the module itself")
        return {
            "variant": self.variant,
            "widths": list(self.widths),
            "depths": list(self.depths),
            "norm": self.norm,
            "head_width": self.head_width,
            "input_size": self.input_size,
            "use_image": self.use_image,
            "use_maps": self.use_maps,
            "use_support": self.use_support,
            "kernel_angle": self.kernel_angle,
            "chunk_size": self.chunk_size,
        }

    def prepare_inputs(
        self,
        images: Tensor,
        segments: Tensor,
        mask: Tensor,
        frames: FrameCandidates,
        lines: Tensor | None = None,
        image_inputs: FSNetImageInputs | None = None,
    ) -> FSNetInputs:
        """:func:`fsnet_inputs` at this network's input size and closeness kernel; the shared variant gets its
        closeness maps already pooled to the trunk's resolution (the same scores, without the full maps).
        ``lines``: the segments' pseudo-camera lines when already computed; ``image_inputs``: the frame-free part
        (:meth:`prepare_image_inputs`) when already built."""
        if image_inputs is None:
            image_inputs = self.prepare_image_inputs(images, segments, mask)
        return fsnet_frame_inputs(
            image_inputs, segments, mask, frames, self.kernel_angle, self.chunk_size, self.use_support, lines
        )

    def prepare_image_inputs(self, images: Tensor, segments: Tensor, mask: Tensor) -> FSNetImageInputs:
        """The part of :meth:`prepare_inputs` that needs no frame candidate (:func:`fsnet_image_inputs`)."""
        size = self.input_size
        return fsnet_image_inputs(images, segments, mask, size, pool=self.pool_cell(size, size))

    def prepare_line_inputs(self, segments: Tensor, mask: Tensor, image_size: tuple[int, int]) -> FSNetImageInputs:
        """:meth:`prepare_image_inputs` without the image (:func:`fsnet_line_inputs`; :func:`with_images` adds
        it), for segments of an ``image_size`` (H, W) image."""
        size = self.input_size
        return fsnet_line_inputs(segments, mask, image_size, size, pool=self.pool_cell(size, size))

    def image_context(self, image_inputs: FSNetImageInputs) -> tuple[Tensor | None, Tensor | None] | None:
        """What the shared trunk makes of an image before any candidate (for ``forward(..., context=...)``): its
        context map and the line map pooled to it; None where the trunk needs the full maps of :meth:`forward`'s
        arguments (the faithful variant, or maps drawn at full resolution)."""
        if self.variant == "faithful" or image_inputs.drawn is None:
            return None
        return self._trunk(image_inputs.images, image_inputs.drawn.line_map)

    def pool_cell(self, height: int, width: int) -> int | None:
        """The cell size (the trunk's stride) at which the shared variant takes pooled closeness maps for an input
        of this size, or None where it needs full maps (faithful variant, custom backbone, no maps, or a size that
        is not a multiple of the stride)."""
        stride = getattr(self.backbone, "stride", None) if not self.custom_backbone else None
        if self.variant != "shared" or not self.use_maps or stride is None:
            return None
        return stride if height % stride == 0 and width % stride == 0 else None

    def forward(
        self,
        images: Tensor,
        line_map: Tensor,
        closeness: Tensor,
        params: Tensor,
        context: tuple[Tensor | None, Tensor | None] | None = None,
    ) -> Tensor:
        """Score frame candidates.

        Args:
            images: (B, 3, H, W) RGB in [0, 1].
            line_map: (B, 1, H, W) line map L (Eq. 13).
            closeness: (B, F, 3, H, W) closeness maps A_x, A_y, A_z per candidate (Eq. 15); the shared variant
                also takes them pooled to (B, F, 3, H / c, W / c) with ``c`` = :meth:`pool_cell`.
            params: (B, F, 10) per candidate: three unit VPs (pseudo camera, row-major) and the focal length.
            context: the shared trunk's output for these images and line map (:meth:`image_context`) when already
                computed; None runs the trunk.

        Returns:
            (B, F) logits; ``sigmoid`` estimates s_vh (Eq. 20).
        """
        KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
        KORNIA_CHECK_SHAPE(line_map, ["B", "1", "H", "W"])
        KORNIA_CHECK_SHAPE(closeness, ["B", "F", "3", "H", "W"])
        KORNIA_CHECK_SHAPE(params, ["B", "F", str(self.num_params)])
        B, _, H, W = images.shape
        KORNIA_CHECK(
            line_map.shape[0] == B and line_map.shape[-2:] == (H, W) and closeness.shape[0] == B,
            "images, line_map and closeness must share batch and size",
        )
        cell = self.pool_cell(H, W)
        pooled = cell is not None and closeness.shape[-2:] == (H // cell, W // cell)
        KORNIA_CHECK(
            closeness.shape[-2:] == (H, W) or pooled,
            "closeness maps must have the images' size" + (f" or be pooled by {cell}" if cell else ""),
        )
        KORNIA_CHECK(params.shape[:2] == closeness.shape[:2], "params and closeness must share (B, F)")
        num = params.shape[1]
        if num == 0:
            return params.new_zeros(B, 0)
        step = max(1, self.chunk_size // B)
        if self.variant == "faithful":
            chunks = [
                self._faithful(images, line_map, closeness[:, i : i + step], params[:, i : i + step])
                for i in range(0, num, step)
            ]
        else:
            context, low_l = self._trunk(images, line_map) if context is None else context
            chunks = [
                self._head(context, low_l, closeness[:, i : i + step], params[:, i : i + step], W)
                for i in range(0, num, step)
            ]
        return torch.cat(chunks, 1)

    def _faithful(self, images: Tensor, line_map: Tensor, closeness: Tensor, params: Tensor) -> Tensor:
        B, c, _, H, W = closeness.shape
        parts = []
        if self.use_image:
            parts.append(images[:, None].expand(B, c, 3, H, W))
        if self.use_maps:
            parts += [line_map[:, None].expand(B, c, 1, H, W), closeness]
        parts.append(params[..., None, None].expand(B, c, self.num_params, H, W))
        x = torch.cat(parts, 2).flatten(0, 1)
        feats = self.backbone(x)
        return self.fc(feats.mean((-2, -1))).reshape(B, c)

    def _trunk(self, images: Tensor, line_map: Tensor) -> tuple[Tensor | None, Tensor | None]:
        """Once per image: the trunk's context map (B, D, h, w) and the line map pooled to it (B, 1, h, w)."""
        if self.backbone is None:
            return None, None
        parts = ([images] if self.use_image else []) + ([line_map] if self.use_maps else [])
        # channels-last lets the CPU convolutions take their faster kernels (the same values to float round-off)
        feats = self.backbone(torch.cat(parts, 1).contiguous(memory_format=torch.channels_last))
        low_l = F.adaptive_avg_pool2d(line_map, feats.shape[-2:]) if self.use_maps else None
        return self.context(feats), low_l

    def _head(
        self, context: Tensor | None, low_l: Tensor | None, closeness: Tensor, params: Tensor, width: int
    ) -> Tensor:
        B, c = params.shape[:2]
        # without autograd the sums and ReLUs reuse the fresh maps they read: allocating a new one (128 KB for 16
        # candidates) costs more than the arithmetic
        inplace = not torch.is_grad_enabled()
        x = self.param_mlp(params)[..., None, None]  # (B, c, D, 1, 1)
        if context is not None:
            x = x + context[:, None]
        if self.map_proj is not None and low_l is not None:
            h, w = low_l.shape[-2:]
            low_a = closeness.flatten(0, 1)
            if low_a.shape[-2:] != (h, w):
                low_a = F.adaptive_avg_pool2d(low_a, (h, w))
            low_a = low_a.reshape(B, c, 3, h, w)
            density = low_a * (width / w)  # about the length of line per cell, in cells
            mean = low_a / low_l[:, None].clamp_min(1e-6)  # mean closeness of the cell's line pixels (local Eq. 21)
            maps = torch.cat([density, mean], 2).flatten(0, 1)
            proj = self.map_proj(maps).reshape(B, c, -1, h, w)
            x = proj.add_(x) if inplace else x + proj
        x = x.flatten(0, 1).relu_() if inplace else torch.relu(x.flatten(0, 1))
        if inplace:
            y = self.conv2(self.conv1(x).relu_()).add_(x).relu_()
        else:
            y = torch.relu(self.conv2(torch.relu(self.conv1(x))) + x)
        pooled = torch.cat([y.mean((-2, -1)), y.amax((-2, -1))], -1)
        return self.scorer(pooled).reshape(B, c)
