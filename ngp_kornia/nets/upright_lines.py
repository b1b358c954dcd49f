"""UprightLinesNet: which way is up, read from where a photo's line segments lie and how they point.

The orientation check's thumbnail network (:class:`~ngp_kornia.nets.upright.UprightNet`) sees a 64x64 picture, in
which thin lines vanish. The segments the parser detects carry a cue of their own: which image axis the scene's
verticals follow, whether they converge, where the lines crowd (an outdoor sky holds none). This reader turns them
into four turn logits (upright, turned 90, 180, 270 degrees counter-clockwise, as
:data:`~ngp_kornia.nets.upright.CLASSES` orders them): each segment's fixed features (:func:`line_turn_features`)
through a small MLP, their length-weighted mean and their maximum over the image, and a second MLP; the mean of a few
such readers trained from different seeds.
Its reading is fused with the thumbnail network's (:meth:`UprightLinesNet.fuse`, two weights fitted on real photos
held back from both networks' training), which reads which end is up far better than the lines do. Trained on the
four turns and mirror images of real photos (``ngp-train fit --config upright_lines``, first studied in
``benchmarks/upright_lines.py``; docs/lab-notes/orientation-check.md).

Example:
    >>> net = UprightLinesNet(width=8, members=2).eval()
    >>> segments = torch.tensor([[[[10.0, 5.0], [12.0, 90.0]], [[5.0, 50.0], [60.0, 52.0]]]])
    >>> reading = net(segments, torch.ones(1, 2, dtype=torch.bool), 100, 80)
    >>> reading.shape, bool(torch.allclose(reading.exp().sum(-1), torch.ones(1)))
    (torch.Size([1, 4]), True)
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["UprightLinesNet", "line_turn_features", "mirror_segments", "turn_segments"]

#: the features of :func:`line_turn_features`, in order
FEATURES = (
    "mid_x", "mid_y", "cos_2theta", "sin_2theta", "cos_4theta", "sin_4theta", "log_length",
    "radial_cos_2", "radial_sin_2", "radius", "offset",
)  # fmt: skip


def turn_segments(segments: Tensor, height: int, width: int, turns: int) -> tuple[Tensor, int, int]:
    """Segments (..., 2, 2) of a ``height`` x ``width`` image as they lie in the image turned by ``turns`` quarter
    turns counter-clockwise (``np.rot90(image, turns)``: the pixel (x, y) goes to (y, W - 1 - x)), and the turned
    image's height and width.

    Example:
        >>> seg, h, w = turn_segments(torch.tensor([[[0.0, 0.0], [9.0, 0.0]]]), 5, 10, 1)
        >>> seg.tolist(), h, w
        ([[[0.0, 9.0], [0.0, 0.0]]], 10, 5)
    """
    for _ in range(turns % 4):
        segments = torch.stack([segments[..., 1], width - 1 - segments[..., 0]], -1)
        height, width = width, height
    return segments, height, width


def mirror_segments(segments: Tensor, width: int) -> Tensor:
    """Segments (..., 2, 2) of an image ``width`` pixels wide as they lie in its mirror image (``np.fliplr``: the
    pixel (x, y) goes to (W - 1 - x, y)); a mirror image is as upright as the photo, so it keeps the turn's label.

    Example:
        >>> mirror_segments(torch.tensor([[[0.0, 2.0], [3.0, 4.0]]]), 10).tolist()
        [[[9.0, 2.0], [6.0, 4.0]]]
    """
    return torch.stack([width - 1 - segments[..., 0], segments[..., 1]], -1)


def line_turn_features(segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
    """(B, N, 11) features of segments (B, N, 2, 2) in pixels of a ``height`` x ``width`` image, zero where ``mask``
    (B, N) is False: the midpoint in [-1, 1] on each axis by that axis' half size (so the aspect ratio is no cue: a
    turned landscape photo is a portrait one), the direction as cos / sin of twice and four times its angle, the log
    of the length over the long side, and against the ray from the image centre to the midpoint the cos / sin of
    twice the angle between them times the midpoint's distance from the centre, that distance and the line's
    distance from the centre (both over half the long side)."""
    seg = segments
    half = max(height, width) / 2
    mid, d = seg.mean(-2), seg[..., 1, :] - seg[..., 0, :]
    length = torch.linalg.vector_norm(d, dim=-1).clamp_min(1e-6)
    ux, uy = d[..., 0] / length, d[..., 1] / length
    c2, s2 = ux * ux - uy * uy, 2 * ux * uy
    cx, cy = mid[..., 0] - (width - 1) / 2, mid[..., 1] - (height - 1) / 2
    vx, vy = cx / half, cy / half
    r = torch.sqrt(vx * vx + vy * vy + 1e-12)
    rc2, rs2 = (vx * vx - vy * vy) / r, 2 * vx * vy / r  # r cos 2phi, r sin 2phi of the ray to the midpoint
    features = torch.stack([
        cx / (width / 2), cy / (height / 2), c2, s2, c2 * c2 - s2 * s2, 2 * c2 * s2, torch.log(length / (2 * half)),
        c2 * rc2 + s2 * rs2, s2 * rc2 - c2 * rs2, r, (ux * vy - uy * vx).abs(),
    ], -1)  # fmt: skip
    return torch.where(mask[..., None], features, torch.zeros_like(features))


class _Reader(nn.Module):
    """One reader: a per-segment MLP, the length-weighted mean and the maximum of its outputs, an MLP to 4 logits."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.point = nn.Sequential(nn.Linear(len(FEATURES), width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(2 * width, width), nn.ReLU(), nn.Linear(width, 4))

    def forward(self, features: Tensor, mask: Tensor) -> Tensor:
        embedded = self.point(features)
        weight = features[..., 6].exp() * mask  # the length over the long side
        mean = (embedded * weight[..., None]).sum(1) / weight.sum(1, keepdim=True).clamp_min(1e-9)
        peak = embedded.masked_fill(~mask[..., None], 0.0).amax(1)
        return self.head(torch.cat([mean, peak], -1))


class UprightLinesNet(nn.Module):
    """The turn of each image read from its segments: the mean logits of ``members`` readers of hidden ``width``.

    The temperature of the mean logits and the two fusion weights (:meth:`fuse`) are buffers, fitted on real photos
    held back from training and saved with the weights.

    Args:
        width: hidden width of each reader's MLPs.
        members: readers whose logits are averaged.
    """

    def __init__(self, width: int = 32, members: int = 3) -> None:
        super().__init__()
        if width < 1 or members < 1:
            raise ValueError(f"width and members must be positive, got {width} and {members}")
        self.width, self.members = width, members
        self.readers = nn.ModuleList(_Reader(width) for _ in range(members))
        self.register_buffer("temperature", torch.ones(()))
        self.register_buffer("fusion", torch.ones(2))  # the weights of the thumbnail's and the lines' log-probabilities

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        return {"width": self.width, "members": self.members}

    def logits(self, features: Tensor, mask: Tensor) -> Tensor:
        """(B, 4) mean logits of the readers on precomputed :func:`line_turn_features` (B, N, 11) and mask (B, N)."""
        return torch.stack([reader(features, mask) for reader in self.readers]).mean(0)

    def forward(self, segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
        """(B, 4) log-probabilities of the four turns for segments (B, N, 2, 2) in pixels of ``height`` x ``width``
        images and their mask (B, N); uniform for an image without segments (its lines say nothing)."""
        if segments.ndim != 4 or segments.shape[2:] != (2, 2) or mask.shape != segments.shape[:2]:
            raise ValueError(f"expected segments (B, N, 2, 2) and mask (B, N), got {tuple(segments.shape)} and "
                             f"{tuple(mask.shape)}")  # fmt: skip
        mask = mask.bool()
        segments = segments.to(self.temperature.dtype)  # the network's dtype (float32 weights on float64 input, say)
        read = torch.log_softmax(self.logits(line_turn_features(segments, mask, height, width), mask)
                                 / self.temperature, -1)  # fmt: skip
        return torch.where(mask.any(-1, keepdim=True), read, torch.full_like(read, -math.log(4.0)))

    def fuse(self, turns: Tensor, lines: Tensor) -> Tensor:
        """(B, 4) probabilities of the four turns from the thumbnail network's (B, 4) probabilities ``turns`` and this
        network's (B, 4) log-probabilities ``lines``: the softmax of their log-probabilities weighed by
        :attr:`fusion` (a logistic model on both readings).

        Example:
            >>> net = UprightLinesNet(width=4, members=1)
            >>> fused = net.fuse(torch.tensor([[0.7, 0.1, 0.1, 0.1]]), torch.full((1, 4), -math.log(4.0)))
            >>> [round(p, 2) for p in fused[0].tolist()]
            [0.7, 0.1, 0.1, 0.1]
        """
        own = torch.log(turns / turns.sum(-1, keepdim=True).clamp_min(1e-30)).clamp_min(-80.0)
        return torch.softmax(self.fusion[0] * own + self.fusion[1] * lines.to(own), -1)
