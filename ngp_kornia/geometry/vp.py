r"""Vanishing points: structure tensors (Eq. 9-10), closeness of lines to VPs (Eq. 14), the Manhattan score
(Eq. 21) and top-k averaging (Eq. 23).

Every function is batched, differentiable and defined on degenerate input (zero weights, points at infinity,
padded lines), where it returns finite values. All of it is ours: kornia has no vanishing-point estimation.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry.camera import normalize

__all__ = [
    "CLOSENESS_MEASURES",
    "closeness",
    "closeness_of",
    "dominant_eigenvector",
    "line_vp_cosine",
    "frame_manhattan_scores",
    "manhattan_score",
    "segment_vp_angle",
    "structure_tensor",
    "symmetric_dominant_eigenvector",
    "topk_weighted_average",
    "weighted_structure_tensor",
]


def structure_tensor(v: Tensor) -> Tensor:
    r"""Structure tensor of an l2-normalised homogeneous point, :math:`\hat v \hat v^T` (Eq. 9).

    Invariant to the sign and scale of ``v``, so averaging tensors averages points on the projective plane.

    Args:
        v: (..., 3) homogeneous points.

    Returns:
        (..., 3, 3) symmetric tensors with unit trace (zero for a zero vector).

    Example:
        >>> structure_tensor(torch.tensor([0.0, 0.0, -2.0]))
        tensor([[0., 0., 0.],
                [0., 0., 0.],
                [0., 0., 1.]])
    """
    KORNIA_CHECK_SHAPE(v, ["*", "3"])
    u = normalize(v)
    return u.unsqueeze(-1) * u.unsqueeze(-2)


def weighted_structure_tensor(v: Tensor, weights: Tensor) -> Tensor:
    r"""Weighted mean of structure tensors, :math:`\sum_i w_i ST(v_i) / \sum_i w_i` (Eq. 10 and 22).

    Args:
        v: (B, N, 3) homogeneous points.
        weights: (B, N) non-negative weights (zero for padding).

    Returns:
        (B, 3, 3). A row whose weights are all zero gives the zero matrix.

    Example:
        >>> v = torch.tensor([[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]])
        >>> weighted_structure_tensor(v, torch.tensor([[3.0, 1.0]]))
        tensor([[[0.2500, 0.0000, 0.0000],
                 [0.0000, 0.7500, 0.0000],
                 [0.0000, 0.0000, 0.0000]]])
    """
    KORNIA_CHECK_SHAPE(v, ["B", "N", "3"])
    KORNIA_CHECK_SHAPE(weights, ["B", "N"])
    total = weights.sum(-1)[:, None, None]
    st = (weights[..., None, None] * structure_tensor(v)).sum(1)
    return st / total.clamp_min(torch.finfo(st.dtype).tiny ** 0.5)


def dominant_eigenvector(tensor: Tensor, fallback: Tensor | None = None) -> Tensor:
    """Unit eigenvector of the largest eigenvalue of a symmetric (B, 3, 3) tensor: the mean point of Eq. 10-12.

    The sign is fixed so the largest-magnitude component is positive. A zero tensor, or one with NaN or infinite
    entries, has no dominant direction and gives ``fallback`` (default ``(0, 1, 0)``, the zenith of a level camera).

    Args:
        tensor: (B, 3, 3) symmetric positive semi-definite tensors.
        fallback: (3,) or (B, 3) vector returned for zero tensors.

    Returns:
        (B, 3) unit vectors.

    Example:
        >>> dominant_eigenvector(torch.diag(torch.tensor([0.1, 0.2, 0.7]))[None])
        tensor([[0., 0., 1.]])
    """
    KORNIA_CHECK_SHAPE(tensor, ["B", "3", "3"])
    return _dominant(0.5 * (tensor + tensor.transpose(-1, -2)), tensor, fallback)


def symmetric_dominant_eigenvector(tensor: Tensor, fallback: Tensor | None = None) -> Tensor:
    """:func:`dominant_eigenvector` of (B, 3, 3) tensors that are exactly symmetric, such as the weighted sums of
    structure tensors (whose entries ``(i, j)`` and ``(j, i)`` are the same products summed in the same order):
    the same vectors without symmetrising, which changes nothing then.

    Example:
        >>> symmetric_dominant_eigenvector(torch.diag(torch.tensor([0.1, 0.2, 0.7]))[None])
        tensor([[0., 0., 1.]])
    """
    KORNIA_CHECK_SHAPE(tensor, ["B", "3", "3"])
    return _dominant(tensor, tensor, fallback)


def _dominant(sym: Tensor, tensor: Tensor, fallback: Tensor | None) -> Tensor:
    # a tensor with NaN or infinite entries has no dominant direction either (eigh fails on it): the fallback
    finite = torch.isfinite(sym).flatten(1).all(-1, keepdim=True)
    _, vecs = torch.linalg.eigh(torch.where(finite[..., None], sym, torch.zeros_like(sym)))
    v = vecs[..., -1]
    # the sign that makes the largest-magnitude component positive (a zero one counts as negative, as sign() did)
    v = torch.where(torch.gather(v, -1, v.abs().argmax(-1, keepdim=True)) > 0, v, -v)
    empty = ~finite | (tensor.flatten(1).abs().amax(-1, keepdim=True) <= torch.finfo(tensor.dtype).tiny ** 0.5)
    return torch.where(empty, (_LEVEL_ZENITH if fallback is None else fallback).to(v).expand_as(v), v)


#: the default fallback of :func:`dominant_eigenvector`, the zenith of a level camera, made once
_LEVEL_ZENITH = torch.tensor([0.0, 1.0, 0.0])


def line_vp_cosine(lines: Tensor, vps: Tensor) -> Tensor:
    r"""Absolute cosine between homogeneous line and point vectors, :math:`|l \cdot v| / (\|l\| \|v\|)`: zero when
    the line passes through the VP. All pairs: lines (B, N, 3), vps (B, ..., 3) -> (B, ..., N).

    Not kornia's ``point_line_distance``: a distance in pixels, infinite for a VP at infinity.

    Example:
        >>> line_vp_cosine(torch.tensor([[[1.0, 0.0, -2.0]]]), torch.tensor([[[2.0, 5.0, 1.0]]]))
        tensor([[[0.]]])
    """
    KORNIA_CHECK_SHAPE(lines, ["B", "N", "3"])
    KORNIA_CHECK_SHAPE(vps, ["*", "3"])
    ln, vn = normalize(lines), normalize(vps)
    flat = vn.reshape(vn.shape[0], -1, 3)
    cos = (flat @ ln.transpose(-1, -2)).abs()
    return cos.reshape(*vn.shape[:-1], lines.shape[1])


def segment_vp_angle(segments: Tensor, vps: Tensor) -> Tensor:
    """Angle in degrees between each segment and the ray from its midpoint to each VP, in [0, 90].

    A geometric consistency measure that does not depend on the image scale; a VP at infinity is a direction.
    All pairs: segments (B, N, 2, 2), vps (B, ..., 3) -> (B, ..., N). A degenerate pair (zero-length segment, VP
    at the midpoint, zero VP) gives 0.

    Example:
        >>> seg = torch.tensor([[[[0.0, 0.0], [0.0, 1.0]]]])
        >>> segment_vp_angle(seg, torch.tensor([[[0.0, 1.0, 0.0], [1.0, 1.5, 1.0]]]))
        tensor([[[ 0.],
                 [45.]]])
    """
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(vps, ["*", "3"])
    v = normalize(vps).reshape(vps.shape[0], -1, 1, 3)  # (B, V, 1, 3)
    start, end = segments[..., 0, :], segments[..., 1, :]
    # mean(-2) sums the two endpoints and halves them too (a zero's sign aside, which the absolute values drop), but
    # reduces over a dim that is not the innermost one in a slow generic loop
    mid = ((start + end) * 0.5)[:, None]  # (B, 1, N, 2)
    s = (end - start)[:, None]
    d = v[..., :2] - mid * v[..., 2:]
    cross = (s[..., 0] * d[..., 1] - s[..., 1] * d[..., 0]).abs()
    dot = (s * d).sum(-1).abs()
    angle = torch.rad2deg(torch.atan2(cross, dot))
    return angle.reshape(*vps.shape[:-1], segments.shape[1])


def closeness(lines: Tensor, vps: Tensor, angle_deg: float | None = None) -> Tensor:
    r"""Closeness of every line to every VP: :func:`closeness_of` the cosine between a line's homogeneous vector
    and the VP (:func:`line_vp_cosine`).

    With ``angle_deg=None`` it is the paper's Eq. 14, :math:`1 - |l \cdot v| / (\|l\| \|v\|)`, linear in the cosine.
    With an angle it is the sharp kernel, :math:`\exp(-\cos^2 / (2 \cos^2 \alpha))`, so a line counts only when its
    vector is within about ``90 - angle_deg`` degrees of orthogonal to the VP: the kernel of the Manhattan score
    (Eq. 21), where Eq. 14 cannot tell a line that points at the VP from one a few degrees off.

    Args:
        lines: (B, N, 3) homogeneous lines.
        vps: (B, ..., 3) homogeneous VPs.
        angle_deg: the sharp kernel's width as an angle (89 degrees keeps lines within about a degree), or None for
            Eq. 14.

    Returns:
        (B, ..., N) values in [0, 1]; 1 when the line passes through the VP (the sharp kernel underflows to 0 far
        from it).

    Example:
        >>> lines, vps = torch.tensor([[[1.0, 0.0, -2.0]]]), torch.tensor([[[2.0, 5.0, 1.0], [0.0, 0.0, 1.0]]])
        >>> closeness(lines, vps), closeness(lines, vps, 89.0)
        (tensor([[[1.0000],
                 [0.1056]]]), tensor([[[1.],
                 [0.]]]))
    """
    return closeness_of(line_vp_cosine(lines, vps), angle_deg)


#: the angle measures :func:`closeness_of` maps to a closeness
CLOSENESS_MEASURES = ("cosine", "squared_cosine", "squared_sine")


def closeness_of(
    value: Tensor, angle_deg: float | None = None, measure: str = "cosine", floor: float | None = None,
    inplace: bool = False,
) -> Tensor:
    r"""The package's closeness kernel: how close a line is to a vanishing point, in [0, 1], from a measure of the
    angle between them that the caller has computed (each caller computes its measure its fastest way).

    * ``"cosine"``: ``|cos|`` between a line's homogeneous vector and the VP (:func:`line_vp_cosine`). Without an
      angle, Eq. 14: :math:`1 - \cos`; with one, the sharp kernel of the Manhattan score (Eq. 21, the authors'
      code) :math:`\exp(-\cos^2 / (2 \cos^2 \alpha))`: a line counts only within about ``90 - angle_deg``
      degrees. It falls with the cosine, so the best closeness to several VPs is that of the smallest cosine.
    * ``"squared_cosine"``: the square of that cosine, for the sharp kernel (its exponent as the value times
      :math:`-1 / (2 \cos^2 \alpha)`; :func:`frame_manhattan_scores`).
    * ``"squared_sine"``: :math:`\sin^2 \theta` of the image angle between a segment and the ray from its midpoint
      to the VP (:mod:`ngp_kornia.pipeline.line_kernel`, the horizon search and the polish):
      :math:`\max(0, 1 - \sin^2 \theta / (4 \sin^2 \alpha))`: 1 on the VP, 3/4 at ``angle_deg``, 0 from
      :math:`\sin \theta = 2 \sin \alpha` (about twice the width) on: a cheap stand-in for a Gaussian of that width.

    Args:
        value: the measure, any shape.
        angle_deg: the kernel's width; None only for ``"cosine"`` (Eq. 14).
        measure: one of :data:`CLOSENESS_MEASURES`.
        floor: the sharp kernel's lowest exponent (e.g. -30): far from the VP the exponential then stays a normal
            float instead of underflowing to the subnormals CPUs compute slowly.
        inplace: compute in ``value``'s memory (without autograd; ``value`` is used up) with the numbers as 0-dim
            tensors built once, which saves passes and conversions where this dominates a search's time.

    Returns:
        the closeness, ``value``'s shape.

    Example:
        >>> closeness_of(torch.tensor([0.0, 1.0]), 89.0)
        tensor([1., 0.])
        >>> closeness_of(torch.tensor([0.0, 0.0076, 0.5]), 5.0, "squared_sine")
        tensor([1.0000, 0.7499, 0.0000])
    """
    if measure not in CLOSENESS_MEASURES:
        raise ValueError(f"unknown closeness measure {measure!r}; choose one of {', '.join(CLOSENESS_MEASURES)}")
    if angle_deg is None:
        if measure != "cosine":
            raise ValueError(f"the {measure} kernel needs its width, angle_deg")
        return 1.0 - value
    if measure == "squared_sine":
        return _tent(value, 4.0 * math.sin(math.radians(angle_deg)) ** 2, inplace)
    if measure == "squared_cosine":
        exponent = value.mul_(_scale(angle_deg)) if inplace else value * _scale(angle_deg)
    else:
        exponent = -(value**2) / (2.0 * math.cos(math.radians(angle_deg)) ** 2)
    if floor is None:
        return exponent.exp_() if inplace else exponent.exp()
    return exponent.clamp_min_(floor).exp_() if inplace else exponent.clamp_min(floor).exp()


def _scale(angle_deg: float) -> float:
    """The sharp kernel's exponent per squared cosine, ``-1 / (2 cos^2 a)``."""
    return -1.0 / (2.0 * math.cos(math.radians(angle_deg)) ** 2)


def _tent(sin2: Tensor, c: float, inplace: bool) -> Tensor:
    """``max(0, 1 - sin2 / c)``; ``sin2`` clamped at 1 first where ``c > 1`` (a clamped 1 and anything above both
    give 0 below that)."""
    if c > 1.0:
        sin2 = sin2.clamp_max(1.0)
    if not inplace:
        return (1.0 - sin2 / c).clamp_min(0.0)
    c_t, one = _numbers(c, 1.0, dtype=sin2.dtype, device=sin2.device)
    return sin2.div_(c_t).neg_().add_(one).clamp_min_(0.0)  # 1 - x as -x + 1: the same value


@lru_cache(maxsize=64)
def _numbers(*values: float, dtype: torch.dtype, device: torch.device) -> tuple[Tensor, ...]:
    """The numbers as 0-dim tensors, built once per dtype and device: an in-place operation given a Python number
    converts it on every call, which costs more than the arithmetic on small tensors. Ordinary tensors even when
    first built in inference mode."""
    with torch.inference_mode(False):
        return tuple(torch.tensor(v, dtype=dtype, device=device) for v in values)


def manhattan_score(closeness_to_vps: Tensor, lengths: Tensor, mask: Tensor) -> Tensor:
    r"""Manhattan score of Eq. 21 on line segments: the length-weighted mean over lines of their best closeness to
    the frame's three VPs. This equals Eq. 21's ratio of rasterised maps, :math:`\sum \max(A_x, A_y, A_z) /
    \sum L`, when segments do not overlap, without drawing a map per candidate.

    Args:
        closeness_to_vps: (B, F, V, N) closeness of each line to each of the V (usually three) VPs of each frame.
        lengths: (B, N) segment lengths (the number of pixels a segment covers).
        mask: (B, N) bool, False for padding.

    Returns:
        (B, F) scores in [0, 1]; 0 for an image with no lines.

    Example:
        >>> c = torch.tensor([[[[1.0, 0.0], [0.0, 0.0], [0.0, 0.5]]]])
        >>> manhattan_score(c, torch.tensor([[1.0, 3.0]]), torch.tensor([[True, True]]))
        tensor([[0.6250]])
    """
    KORNIA_CHECK_SHAPE(closeness_to_vps, ["B", "F", "V", "N"])
    KORNIA_CHECK_SHAPE(lengths, ["B", "N"])
    w = lengths * mask.to(lengths)
    best = closeness_to_vps.amax(-2)
    return (best * w[:, None]).sum(-1) / w.sum(-1, keepdim=True).clamp_min(torch.finfo(w.dtype).eps)


def true_positions(mask: Tensor, count: int) -> Tensor:
    """Indices (B, count) of the True entries of each row of a (B, M) bool ``mask``, in order, then (where a row has
    fewer than ``count``) of False ones: a stable descending argsort, or for one row its nonzero positions.

    Example:
        >>> true_positions(torch.tensor([[False, True, False, True]]), 2)
        tensor([[1, 3]])
    """
    if len(mask) == 1 and count == int(mask.sum()):  # one row: no sort needed
        return mask[0].nonzero()[:count, 0][None]
    return mask.to(torch.uint8).argsort(dim=-1, descending=True, stable=True)[:, :count]


def frame_manhattan_scores(
    lines: Tensor, vps: Tensor, lengths: Tensor, mask: Tensor, angle_deg: float = 89.0, valid: Tensor | None = None
) -> Tensor:
    """Manhattan score (Eq. 21) of many frames at once with the sharp kernel: the values (to rounding) of
    ``manhattan_score(closeness(lines, vps, angle_deg).amax(-2, keepdim=True), lengths, mask)`` with fewer passes
    over the (B, F, 3, N) cosines, which dominate the parser's cost: the sharp kernel (:func:`closeness_of`) is
    evaluated in place on the nearest VP's squared cosine.

    Kernel values below ``exp(-80)`` (lines more than about 13 degrees off every VP at 89 degrees) are clamped
    there instead of underflowing to subnormal floats, which CPUs handle slowly; they add less than 1e-34 per
    line to a score.

    Args:
        lines: (B, N, 3) homogeneous lines.
        vps: (B, F, V, 3) the V vanishing points of each of F frames.
        lengths: (B, N) segment lengths.
        mask: (B, N) bool, False for padding.
        angle_deg: the sharp kernel's width (:func:`closeness_of`).
        valid: optional (B, F) bool; frames marked False are not scored (their score is 0), which saves their
            share of the work (about half the sampled candidates are invalid).

    Returns:
        (B, F) scores in [0, 1].

    Example:
        >>> lines = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])  # x = 0 and y = 0
        >>> vps = torch.tensor([[[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]]])
        >>> frame_manhattan_scores(lines, vps, torch.ones(1, 2), torch.ones(1, 2, dtype=torch.bool))
        tensor([[1.]])
    """
    KORNIA_CHECK_SHAPE(lines, ["B", "N", "3"])
    KORNIA_CHECK_SHAPE(vps, ["B", "F", "V", "3"])
    if valid is not None:
        KORNIA_CHECK_SHAPE(valid, ["B", "F"])
        count = int(valid.sum(-1).max()) if valid.numel() else 0
        if count == 0:
            return lines.new_zeros(valid.shape)
        if count < vps.shape[1]:  # score each image's valid frames (moved to the front) and scatter them back
            order = true_positions(valid, count)  # (B, count)
            picked = vps.gather(1, order[..., None, None].expand(*order.shape, *vps.shape[2:]))
            scores = frame_manhattan_scores(lines, picked, lengths, mask, angle_deg)
            scattered = scores.new_zeros(valid.shape).scatter(1, order, scores)
            return torch.where(valid, scattered, torch.zeros_like(scattered))
    nearest = _nearest_squared_cosine(normalize(lines), normalize(vps))  # (B, F, N)
    kernel = closeness_of(nearest, angle_deg, "squared_cosine", floor=-80.0, inplace=True)
    w = lengths * mask.to(lengths)
    return (kernel @ w[..., None])[..., 0] / w.sum(-1, keepdim=True).clamp_min(torch.finfo(w.dtype).eps)


#: below these sizes the BLAS picks small-matrix kernels, which may round a product of (F, 3) rows differently
#: from one of (F V, 3) rows; above them both go through the same blocked kernel
_PER_VP_MIN_FRAMES, _PER_VP_MIN_LINES = 256, 32


def _nearest_squared_cosine(lines: Tensor, vps: Tensor) -> Tensor:
    """Squared cosine between each unit line (B, N, 3) and the closest of each frame's unit VPs (B, F, V, 3):
    (B, F, N).

    For many frames and lines, one (B, F, N) product per VP, folded in place into the first with ``clamp_max_``
    (a minimum), is faster than a (B, F V, N) product reduced over V: its buffers stay in cache. Both give the
    same values.
    """
    B, F, V = vps.shape[:3]
    lines_t = lines.transpose(-1, -2)
    if F < _PER_VP_MIN_FRAMES or lines.shape[1] < _PER_VP_MIN_LINES:
        return (vps.reshape(B, F * V, 3) @ lines_t).square_().reshape(B, F, V, -1).amin(2)
    nearest = (vps[:, :, 0] @ lines_t).square_()
    for v in range(1, V):
        nearest = nearest.clamp_max_((vps[:, :, v] @ lines_t).square_())
    return nearest


def topk_weighted_average(
    scores: Tensor, values: Tensor, k: int = 8, mask: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    r"""Score-weighted mean of the values of the ``k`` best candidates (Eq. 23).

    Args:
        scores: (B, F) non-negative candidate scores.
        values: (B, F, ...) per-candidate values (focal lengths, structure tensors, ...).
        k: number of candidates kept (fewer when fewer are valid).
        mask: (B, F) bool, False for invalid candidates, which are never kept.

    Returns:
        the weighted mean (B, ...) and the weights (B, F) used (zero outside the top k, summing to 1 where any
        candidate is valid). Where the kept scores are all zero the kept candidates count equally; where no
        candidate is valid the mean is zero and so are the weights.

    Example:
        >>> topk_weighted_average(torch.tensor([[0.1, 0.6, 0.3]]), torch.tensor([[10.0, 20.0, 40.0]]), k=2)[0]
        tensor([26.6667])
    """
    KORNIA_CHECK_SHAPE(scores, ["B", "F"])
    if mask is None:
        mask = torch.ones_like(scores, dtype=torch.bool)
    k = max(1, min(k, scores.shape[1]))
    ranked = torch.where(mask, scores, torch.full_like(scores, -1.0))
    top = ranked.topk(k, dim=1).indices
    keep = torch.zeros_like(mask).scatter(1, top, True) & mask
    w = torch.where(keep, scores.clamp_min(0.0), torch.zeros_like(scores))
    # all kept scores zero: count the kept candidates equally rather than divide by zero
    w = torch.where((w.sum(1, keepdim=True) > 0) | ~keep, w, keep.to(w))
    # divided by their sum whatever its size: scores far below eps (a gravity prior far from every frame leaves
    # subnormal ones, 1e-42) still give weights summing to 1; a zero sum (no valid candidate) leaves them zero
    total = w.sum(1, keepdim=True)
    w = w / torch.where(total > 0, total, torch.ones_like(total))
    mean = (w.reshape(*w.shape, *([1] * (values.dim() - 2))) * values).sum(1)
    return mean, w
