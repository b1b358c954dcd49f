"""ZSNet, the zenith scoring network of Sec. 3.1 (Eq. 5-7): a PointNet over near-vertical lines and zenith
candidates that scores how close each candidate is to the true zenith."""

from __future__ import annotations

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor, nn

from ngp_kornia.geometry import (
    closeness_of,
    line_vp_cosine,
    normalize,
    symmetric_dominant_eigenvector,
    weighted_structure_tensor,
)

__all__ = ["ZSNet", "canonical_homogeneous", "zenith_estimate", "zenith_weights_from_scores"]


def zenith_weights_from_scores(scores: Tensor, valid: Tensor, threshold: float = 0.5) -> Tensor:
    r"""Weights of the zenith candidates from ZSNet's probabilities (Eq. 12): :math:`p_z` on
    :math:`Z_c = \{z : p_z > \delta_c\}` and zero elsewhere; where no valid candidate passes :math:`\delta_c`,
    every valid candidate counts equally (the untrained path's weights).

    Args:
        scores: (B, Z) probabilities :math:`p_z` (the sigmoid of ZSNet's output).
        valid: (B, Z) bool, False for padded or degenerate candidates (never weighted).
        threshold: :math:`\delta_c`.

    Returns:
        (B, Z) non-negative weights.

    Example:
        >>> zenith_weights_from_scores(torch.tensor([[0.9, 0.2, 0.7]]), torch.tensor([[True, True, False]]))
        tensor([[0.9000, 0.0000, 0.0000]])
        >>> zenith_weights_from_scores(torch.tensor([[0.3, 0.2]]), torch.tensor([[True, True]]))
        tensor([[1., 1.]])
    """
    ok = valid.to(scores)
    scores = scores * ok
    weights = scores * (scores > threshold)
    return torch.where((weights > 0).any(-1, keepdim=True), weights, ok)


def zenith_estimate(candidates: Tensor, weights: Tensor) -> Tensor:
    """The zenith estimate :math:`z_{est}`: the dominant eigenvector of the weighted mean of the candidates'
    structure tensors (Eq. 10-12). (B, Z, 3), (B, Z) -> (B, 3), unit length, sign-free.

    Example:
        >>> zenith_estimate(torch.tensor([[[0.0, 2.0, 0.0], [0.1, 1.0, 0.0]]]), torch.tensor([[1.0, 0.0]])).abs()
        tensor([[0., 1., 0.]])
    """
    return symmetric_dominant_eigenvector(weighted_structure_tensor(candidates, weights))


def canonical_homogeneous(v: Tensor, axis: int) -> Tensor:
    """Unit homogeneous vectors with the sign fixed by one coordinate (made non-negative), so the network sees one
    of the two equivalent vectors. Lines near vertical are signed by ``a`` (axis 0), zeniths by ``y`` (axis 1):
    the coordinate that is large for them, so the sign does not flip between similar inputs.

    Example:
        >>> canonical_homogeneous(torch.tensor([[0.0, -2.0, 0.0]]), axis=1)
        tensor([[0., 1., 0.]])
    """
    u = normalize(v)
    return u * torch.where(u[..., axis : axis + 1] < 0, -1.0, 1.0).to(u) + 0.0


def _mlp(sizes: list[int], last_activation: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if last_activation or i < len(sizes) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class ZSNet(nn.Module):
    """Zenith scoring network.

    Point features ``h_l`` of the lines L_z and ``h_z`` of the candidates Z (shared per-point MLPs, Eq. 5); the
    lines' features are max-pooled into a global feature ``g_l`` concatenated to every candidate's feature (Eq. 6);
    an MLP scores each candidate (Eq. 7). Padding, marked by the masks, never changes an output.

    Beyond the paper, each candidate's point feature also sees its *support*: the share of the lines L_z that
    pass within about 1, 2 and 5 degrees of it (sharp closeness kernels, Eq. 14's cosine). Max-pooled line features
    cannot count how many lines meet at a point, and that count is what separates the true zenith from a
    chance crossing; ``use_support=False`` gives the paper's network.

    Args:
        width: feature width of the point MLPs (the global feature has ``4 * width`` channels).
        use_line_feature: concatenate the global line feature (the paper's design); False is the ablation that
            scores candidates from their own coordinates alone.
        use_support: add the candidates' line-support features.

    Example:
        >>> net = ZSNet(width=8)
        >>> logits = net(torch.rand(2, 16, 3), torch.ones(2, 16, dtype=torch.bool), torch.rand(2, 10, 3))
        >>> logits.shape
        torch.Size([2, 10])
    """

    SUPPORT_ANGLES = (89.0, 88.0, 85.0)

    def __init__(self, width: int = 64, use_line_feature: bool = True, use_support: bool = True) -> None:
        super().__init__()
        self.width, self.use_line_feature, self.use_support = width, use_line_feature, use_support
        feature = 4 * width
        self.line_net = _mlp([3, width, 2 * width, feature])
        extra = len(self.SUPPORT_ANGLES) if use_support else 0
        self.zenith_net = _mlp([3 + extra, width, 2 * width, feature])
        head_in = 2 * feature if use_line_feature else feature
        self.scorer = _mlp([head_in, 2 * width, width, 1], last_activation=False)

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        return {"width": self.width, "use_line_feature": self.use_line_feature, "use_support": self.use_support}

    def support(self, lines: Tensor, line_mask: Tensor, zeniths: Tensor) -> Tensor:
        """Share of the valid lines passing near each candidate, one column per kernel width: (B, Z, 3)."""
        cos = line_vp_cosine(lines, zeniths)  # (B, Z, L)
        w = line_mask.to(cos)[:, None]
        total = w.sum(-1).clamp_min(1.0)
        # the floor keeps far lines' kernel a normal float (exp(-30)), not a subnormal the CPU computes slowly
        return torch.stack([(closeness_of(cos, a, floor=-30.0) * w).sum(-1) / total for a in self.SUPPORT_ANGLES], -1)

    def forward(self, lines: Tensor, line_mask: Tensor, zeniths: Tensor) -> Tensor:
        """Score zenith candidates.

        Args:
            lines: (B, L, 3) near-vertical lines L_z in the pseudo camera.
            line_mask: (B, L) bool, False for padding.
            zeniths: (B, Z, 3) zenith candidates in the pseudo camera.

        Returns:
            (B, Z) logits; ``sigmoid`` gives the scores p_z of Eq. 7.
        """
        KORNIA_CHECK_SHAPE(lines, ["B", "L", "3"])
        KORNIA_CHECK_SHAPE(line_mask, ["B", "L"])
        KORNIA_CHECK_SHAPE(zeniths, ["B", "Z", "3"])
        point = canonical_homogeneous(zeniths, axis=1)
        if self.use_support:
            point = torch.cat([point, self.support(lines, line_mask, zeniths)], -1)
        point = self.zenith_net(point)
        if not self.use_line_feature:
            return self.scorer(point).squeeze(-1)
        feats = self.line_net(canonical_homogeneous(lines, axis=0))
        feats = feats.masked_fill(~line_mask[..., None], float("-inf")).amax(1)
        glob = torch.where(line_mask.any(1, keepdim=True), feats, torch.zeros_like(feats))  # no lines: zeros
        # the scorer's first layer on [glob, point], split in two: the global half once per image, not per candidate
        first = self.scorer[0]
        size = glob.shape[-1]
        hidden = point @ first.weight[:, size:].T + (glob @ first.weight[:, :size].T + first.bias)[:, None]
        return self.scorer[1:](hidden).squeeze(-1)
