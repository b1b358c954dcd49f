"""Manhattan-frame candidates: the batched container of the pipeline's frames and their construction from pairs of
orthogonal vanishing points (focal length from orthogonality, rotation, third VP).

Everything is in the pseudo camera (:func:`ngp_kornia.geometry.to_pseudo_camera`): principal point at 0, one unit
half the image's long side. All of it is ours: kornia has no calibration from vanishing points.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry.camera import normalize

__all__ = ["FrameCandidates", "cat_frames", "frames_from_vps", "select_frames", "top_frames"]

@dataclass
class FrameCandidates:
    """Manhattan-frame candidates in the pseudo camera.

    Attributes:
        zenith: (B, F, 3) zenith VP of each frame.
        horizontal: (B, F, 3) horizontal VP it was built from.
        focal: (B, F) focal length in pseudo-camera units (0 where invalid).
        R: (B, F, 3, 3) world-to-camera rotations (columns: horizontal axis, down, third axis).
        vps: (B, F, 3, 3) the three VPs (rows, matching R's columns) in pseudo-camera units.
        valid: (B, F) bool.
    """

    zenith: Tensor
    horizontal: Tensor
    focal: Tensor
    R: Tensor
    vps: Tensor
    valid: Tensor


def select_frames(frames: FrameCandidates, index: Tensor) -> FrameCandidates:
    """The candidates ``index`` (B, K) of each image: every (B, F, ...) field gathered along F.

    Example:
        >>> fr = FrameCandidates(torch.rand(1, 3, 3), None, torch.tensor([[1.0, 2.0, 3.0]]), None, None, None)
        >>> select_frames(fr, torch.tensor([[2, 0]])).focal
        tensor([[3., 1.]])
    """

    def gather(t: Tensor | None) -> Tensor | None:
        if t is None:
            return None
        idx = index.reshape(*index.shape, *([1] * (t.dim() - 2))).expand(*index.shape, *t.shape[2:])
        return t.gather(1, idx)

    return FrameCandidates(**{f.name: gather(getattr(frames, f.name)) for f in dataclasses.fields(frames)})


def top_frames(frames: FrameCandidates, scores: Tensor, k: int) -> Tensor:
    """Indices (B, min(k, F)) of the best valid frames by ``scores``, best first; invalid frames come last.

    Example:
        >>> fr = FrameCandidates(None, None, None, None, None, torch.tensor([[True, False, True]]))
        >>> top_frames(fr, torch.tensor([[0.2, 0.9, 0.5]]), 2)
        tensor([[2, 0]])
    """
    ranked = torch.where(frames.valid, scores, torch.full_like(scores, -1.0))
    return ranked.topk(min(k, ranked.shape[-1]), dim=-1).indices


def frames_from_vps(
    first: Tensor,
    second: Tensor,
    valid: Tensor,
    focal_range: tuple[float, float] = (0.8, 4.0),
    focal: float | Tensor | None = None,
) -> FrameCandidates:
    """Complete pairs of orthogonal VPs into Manhattan frames: focal length from orthogonality, rotation and the
    third VP.

    The pair is a zenith and a horizontal VP (the paper's frames) or two horizontal VPs, which still fix the focal
    length when the zenith is at infinity (a level camera, where a zenith-horizontal pair cannot). The first VP's
    direction is kept exactly, the second is made orthogonal to it, and the axis closest to the image's y axis is
    labelled vertical.

    Args:
        first: (B, F, 3) VPs (pseudo camera).
        second: (B, F, 3) VPs orthogonal to ``first``.
        valid: (B, F) bool validity of the pairs.
        focal_range: allowed focal lengths in pseudo-camera units; (0.8, 4.0) spans long-side fields of view from
            about 28 to 103 degrees.
        focal: a known focal length (pseudo-camera units), one for all or (B,) one per image. Every pair then makes
            a frame: the first VP is kept and the second is moved onto the first's orthogonal plane (for a zenith,
            onto its horizon), instead of deriving the focal length from the pair and dropping pairs that disagree
            with ``focal_range``.

    Returns:
        :class:`FrameCandidates`; frames whose VPs cannot be orthogonal or whose focal is out of range are invalid
        (and carry a finite placeholder frame).
    """
    KORNIA_CHECK_SHAPE(first, ["B", "F", "3"])
    KORNIA_CHECK_SHAPE(second, ["B", "F", "3"])
    pair = torch.stack([first, second])  # both VPs through each step at once
    if focal is None:
        focal, ok = _focal_from_pair(pair)
        ok = ok & valid & (focal >= focal_range[0]) & (focal <= focal_range[1])
    else:  # one for all, or (B,): the same for every frame of an image
        known = torch.as_tensor(focal, dtype=first.dtype, device=first.device)
        focal, ok = (known[:, None] if known.dim() else known).expand_as(first[..., 0]).contiguous(), valid
    f = torch.where(ok, focal, 1.0)
    scale = torch.stack([f, f, torch.ones_like(f)], -1)  # K = diag(f, f, 1)
    a, b = normalize(pair / scale).unbind(0)
    b = b - (b * a).sum(-1, keepdim=True) * a
    b_norm = torch.linalg.vector_norm(b, dim=-1, keepdim=True)
    ok = ok & (b_norm[..., 0] > 1e-6)  # a second VP along the first has no orthogonal part
    b = b / b_norm.clamp_min(torch.finfo(b.dtype).eps)  # normalize(b), reusing its norm
    R = _vertical_axis_first(b, a)
    columns = R * scale[..., :, None]  # K R: its columns are the VPs
    vps = (columns / _column_norm(columns).clamp_min(torch.finfo(R.dtype).eps)).transpose(-1, -2)  # unit rows
    zenith, horizontal = vps[..., 1, :], vps[..., 0, :]
    return FrameCandidates(zenith, horizontal, torch.where(ok, focal, 0.0), R, vps, ok)


def _column_norm(m: Tensor) -> Tensor:
    """``m.norm(dim=-2, keepdim=True)`` of (..., 3, 3) matrices: the norms of their columns, (..., 1, 3), with the
    same values at a tenth of the cost.

    PyTorch reduces a dim that is not the innermost one in a generic loop, one vector at a time (about 0.1 us
    each): it sums the squares in order and takes a correctly rounded square root. The elementwise operations
    below do the same; the root is taken in float64 because PyTorch's vectorised float32 ``sqrt`` can differ from
    the correctly rounded one in the last bit, while a float64 root rounded to float32 cannot.
    """
    if m.dtype != torch.float32:
        return torch.linalg.vector_norm(m, dim=-2, keepdim=True)
    sq = m * m
    return (sq[..., 0, :] + sq[..., 1, :] + sq[..., 2, :]).double().sqrt_().float()[..., None, :]


def _focal_from_pair(pair: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`~ngp_kornia.geometry.focal_from_orthogonal_vps` for the pseudo camera's principal point (0, 0), on
    the stacked (2, ..., 3) VPs: the same focal lengths and validity with fewer operations."""
    v = normalize(pair)
    px, py, ww = (v[0] * v[1]).unbind(-1)
    num = -(px + py)  # the sum over x and y, up to the sign of a zero, which decides nothing below
    tiny = 1e-12 if pair.dtype == torch.float64 else 1e-9
    # num / ww has the sign of num * sign(ww) where |ww| > tiny (|ww| <= 1: no underflow to zero), and is the f^2
    # of the valid pairs: one division serves the test and the value
    f2 = num / ww
    valid = (ww.abs() > tiny) & (f2 > 0)
    return torch.where(valid, f2.clamp_min(torch.finfo(f2.dtype).eps).sqrt(), 0.0), valid


def cat_frames(*frames: FrameCandidates) -> FrameCandidates:
    """Concatenate frame candidates along the frame dim."""
    return FrameCandidates(
        *(torch.cat([getattr(f, k) for f in frames], 1) for k in FrameCandidates.__dataclass_fields__)
    )


def _vertical_axis_first(b: Tensor, a: Tensor) -> Tensor:
    """The rotation whose columns are the orthonormal axes ``b``, ``a``, ``b x a``, relabelled so the down axis
    (column 1) is the one closest to the image's y axis.

    Three orthogonal VPs do not say which one is vertical: a candidate whose "zenith" came from two steep lines
    meeting at a horizontal VP is still a valid frame, only mislabelled. Taking the most image-vertical axis as the
    vertical assumes |roll| and |pitch| below about 45 degrees, the range of hand-held photos.
    """
    third = torch.linalg.cross(b, a)
    vertical = torch.stack([b[..., 1], a[..., 1], third[..., 1]], -1).abs().argmax(-1, keepdim=True)
    # pick the down axis by two selections rather than stacking the three axes and gathering one
    down = torch.where(vertical == 0, b, torch.where(vertical == 1, a, third))
    down = torch.where(down[..., 1:2] < 0, -down, down)
    first = torch.where(vertical == 0, a, b)
    return torch.stack([first, down, torch.linalg.cross(first, down)], -1)
