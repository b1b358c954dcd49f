"""The line-evidence stage, between line detection and candidate sampling: the learned per-segment structure weight
(:class:`~ngp_kornia.nets.line_evidence.LineEvidenceNet`, trained on renders) decides which segments the rest of the
pipeline sees.

A segment whose structure weight is below :attr:`EvidenceSettings.keep` (default 0.1) is dropped: masked out
for the candidates, the Manhattan score, FSNet's maps, the horizon search and the trust fields alike. Segments given
to the parser by the caller go through the same stage (turn it off with ``EvidenceSettings(enabled=False)``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ngp_kornia.nets.line_evidence import structure_weights
from ngp_kornia.pipeline.settings import EvidenceSettings

__all__ = ["LineEvidence", "apply_evidence"]


class LineEvidence(nn.Module):
    """The stage as a module: the network and the settings that turn its weights into the segments kept.

    Args:
        net: a :class:`~ngp_kornia.nets.line_evidence.LineEvidenceNet` (in eval mode for inference).
        settings: :class:`~ngp_kornia.pipeline.settings.EvidenceSettings`; None for the defaults.
    """

    def __init__(self, net: nn.Module, settings: EvidenceSettings | None = None) -> None:
        super().__init__()
        self.net = net
        self.settings = settings or EvidenceSettings()

    def forward(self, images: Tensor, segments: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        """The (B, N) structure weights in [0, 1] (0 for padding) and the (B, N) mask of the segments kept."""
        return apply_evidence(self.net, images, segments, mask, self.settings.keep)


def apply_evidence(
    net: nn.Module, images: Tensor, segments: Tensor, mask: Tensor, keep: float = 0.1
) -> tuple[Tensor, Tensor]:
    """Structure weights (B, N) of the segments (B, N, 2, 2) and the mask (B, N) of those at or above ``keep``.

    The network reads only the images' size, never their pixels (so a stand-in tensor of their shape will do), and
    runs without gradients: the weights are a selection, not part of the differentiable answer.

    Example:
        >>> from ngp_kornia.nets.line_evidence import LineEvidenceNet
        >>> seg = torch.tensor([[[[10.0, 10.0], [10.0, 90.0]], [[5.0, 50.0], [9.0, 52.0]]]])
        >>> net, mask = LineEvidenceNet(8, 4).eval(), torch.ones(1, 2, dtype=torch.bool)
        >>> w, kept = apply_evidence(net, torch.zeros(1, 3, 100, 100), seg, mask)
        >>> w.shape, kept.dtype
        (torch.Size([1, 2]), torch.bool)
    """
    with torch.no_grad():
        dtype = next(net.parameters()).dtype
        logits, _ = net(images.to(dtype), segments.to(dtype), mask)
        weights = structure_weights(logits, mask).to(segments.dtype)
    return weights, mask & (weights >= keep)
