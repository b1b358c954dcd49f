"""The line-evidence network: for each detected segment, how likely it lies on man-made structure (the outline of a
building, a wall, a window, a door, box-like furniture) and which 3D direction it has (vertical, horizontal,
neither).

It is small on purpose (it runs on every image, between line detection and candidate sampling): the segment
features of :mod:`ngp_kornia.nets.line_features` (geometry and what the image's other segments say, fixed and
cheap) go through a per-segment MLP; a summary of all
the image's segments (masked mean and max of their embeddings) is put back beside each one, and a second MLP gives
one structure logit and three direction logits per segment. Trained on renders only
(:class:`ngp_kornia.training.evidence_module.LineEvidenceModule`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ngp_kornia.nets.line_features import FEATURE_NAMES, segment_features

__all__ = ["DIRECTION_CLASSES", "LineEvidenceNet", "structure_weights"]

#: the direction classes, in the order of the direction logits
DIRECTION_CLASSES = ("vertical", "horizontal", "neither")


def _mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


def structure_weights(logits: Tensor, mask: Tensor) -> Tensor:
    """Per-segment weights in [0, 1] from the structure logits: their sigmoid, 0 for padding. (B, N) -> (B, N).

    Example:
        >>> structure_weights(torch.tensor([[0.0, 20.0, 3.0]]), torch.tensor([[True, True, False]]))
        tensor([[0.5000, 1.0000, 0.0000]])
    """
    return torch.sigmoid(logits) * mask.to(logits)


class LineEvidenceNet(nn.Module):
    """Structure and direction logits of detected segments.

    Args:
        width: hidden width of the per-segment MLPs.
        context: width of the image summary put back beside each segment.

    Example:
        >>> net = LineEvidenceNet(width=16, context=8).eval()
        >>> images = torch.rand(2, 3, 48, 64)
        >>> segments = torch.rand(2, 5, 2, 2) * 40
        >>> structure, direction = net(images, segments, torch.ones(2, 5, dtype=torch.bool))
        >>> structure.shape, direction.shape
        (torch.Size([2, 5]), torch.Size([2, 5, 3]))
    """

    def __init__(self, width: int = 64, context: int = 32) -> None:
        super().__init__()
        if width < 1 or context < 1:
            raise ValueError(f"width and context must be positive, got {width} and {context}")
        self.width, self.context = width, context
        features = len(FEATURE_NAMES)
        self.norm = nn.BatchNorm1d(features)
        self.embed = _mlp([features, width, width])
        self.summary = nn.Linear(width, context)
        self.head = _mlp([width + 2 * context, width, 1 + len(DIRECTION_CLASSES)])
        # added to every structure logit: set after training so that a weight of 0.1 sits at a chosen share of the
        # structural segments kept (LineEvidenceModule's keep_share), saved with the weights
        self.register_buffer("structure_offset", torch.zeros(()))

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        return {"width": self.width, "context": self.context}

    def forward(self, images: Tensor, segments: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        """Score the segments of a batch of images.

        Args:
            images: (B, 3, H, W) RGB in [0, 1].
            segments: (B, N, 2, 2) pixels ``[[x0, y0], [x1, y1]]`` of those images.
            mask: (B, N) bool, False for padding.

        Returns:
            structure logits (B, N) (:func:`structure_weights` makes them weights) and direction logits (B, N, 3)
            in the order of :data:`DIRECTION_CLASSES`; zeros where ``mask`` is False. An image's output does not
            depend on the other images of its batch (in eval mode).
        """
        return self.classify(segment_features(images, segments, mask), mask)

    def classify(self, features: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        """The logits from precomputed :func:`~ngp_kornia.nets.line_features.segment_features`.

        Args:
            features: (B, N, F) segment features.
            mask: (B, N) bool.

        Returns:
            As :meth:`forward`.
        """
        if features.ndim != 3 or features.shape[-1] != len(FEATURE_NAMES) or mask.shape != features.shape[:2]:
            raise ValueError(f"expected features (B, N, {len(FEATURE_NAMES)}) and mask (B, N), got "
                             f"{tuple(features.shape)} and {tuple(mask.shape)}")
        mask = mask.bool()
        b, n = mask.shape
        if n and bool(mask.all()):  # nothing to pack (one image's detected segments): the same rows in the same order
            image = torch.arange(b, device=mask.device).repeat_interleave(n)
            out = self._score(features.flatten(0, 1), image, b).unflatten(0, (b, n))
            return out[..., 0] + self.structure_offset, out[..., 1:]
        out = features.new_zeros(b, n, 1 + len(DIRECTION_CLASSES))
        if bool(mask.any()):
            out[mask] = self._score(features[mask], mask.nonzero()[:, 0], b)
        return torch.where(mask, out[..., 0] + self.structure_offset, out[..., 0]), out[..., 1:]

    def _score(self, packed: Tensor, image: Tensor, batch: int) -> Tensor:
        """Logits (M, 4) of the valid segments packed together (M, F), ``image`` (M,) the index of each one's image."""
        embedded = torch.relu(self.embed(self.norm(packed)))
        summary = self.summary(embedded)
        count = torch.zeros(batch, 1, dtype=packed.dtype, device=packed.device).index_add_(
            0, image, torch.ones_like(packed[:, :1]))
        mean = torch.zeros(batch, self.context, dtype=packed.dtype, device=packed.device).index_add_(0, image, summary)
        mean = mean / count.clamp_min(1.0)
        peak = torch.full((batch, self.context), -torch.inf, dtype=packed.dtype, device=packed.device)
        peak = peak.scatter_reduce(0, image[:, None].expand_as(summary), summary, "amax")
        return self.head(torch.cat([embedded, mean[image], peak[image]], -1))
