"""Training the line-evidence network with Lightning on rendered scenes: binary cross entropy of the structure
logit against the share of each segment on a structural outline, plus cross entropy of the direction logits
(vertical / horizontal / neither) from the true vanishing points."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.training.base import NetworkModule
from ngp_kornia.training.evidence_data import LineBatch

__all__ = ["LineEvidenceModule", "evidence_figures"]


def evidence_figures(structure: Tensor, direction: Tensor, batch: LineBatch, keep: float = 0.1) -> dict[str, Tensor]:
    """The figures the line evidence is judged by, on labelled segments.

    Args:
        structure: (B, N) structure logits.
        direction: (B, N, 3) direction logits.
        batch: the labels (a segment counts as structure when at least half of it lies on a structural outline).
        keep: the weight at or above which a segment is kept.

    Returns:
        ``keep_structure`` (share of the structural segments kept), ``drop_other`` (share of the others dropped),
        ``direction_accuracy`` (on the structural segments), scalar tensors; NaN where a set is empty.
    """
    valid = batch.mask
    positive = valid & (batch.structure >= 0.5)
    negative = valid & (batch.structure < 0.5)
    kept = torch.sigmoid(structure) >= keep
    right = direction.argmax(-1) == batch.direction

    def share(hit: Tensor, among: Tensor) -> Tensor:
        return (hit & among).sum().float() / among.sum().float() if bool(among.any()) else structure.new_tensor(
            float("nan"))

    return {"keep_structure": share(kept, positive), "drop_other": share(~kept, negative),
            "direction_accuracy": share(right, positive)}


class LineEvidenceModule(NetworkModule):
    """Lightning wrapper of a :class:`~ngp_kornia.nets.line_evidence.LineEvidenceNet`.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate.
        lr_step: epochs between halvings of the learning rate.
        direction_weight: weight of the direction loss against the structure loss.
        keep: the weight at or above which a segment counts as kept in the logged figures.
    """

    def __init__(self, net: LineEvidenceNet, lr: float = 3e-3, lr_step: int = 4, direction_weight: float = 0.5,
                 keep: float = 0.1) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net

    def forward(self, features: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        return self.net.classify(features, mask)

    def _step(self, batch: LineBatch, stage: str, batch_idx: int) -> Tensor:
        structure, direction = self.net.classify(batch.features, batch.mask)
        valid = batch.mask
        count = valid.sum().clamp_min(1)
        bce = F.binary_cross_entropy_with_logits(structure, batch.structure, reduction="none")
        structure_loss = (bce * valid).sum() / count
        ce = F.cross_entropy(direction.flatten(0, 1), batch.direction.flatten(), reduction="none")
        direction_loss = (ce * valid.flatten()).sum() / count
        loss = structure_loss + self.hparams.direction_weight * direction_loss
        # validation and test figures are epoch means, averaged over the processes of a multi-process run
        opts = {"batch_size": len(batch), "sync_dist": stage != "train"}
        self.log(f"{stage}/loss", loss, prog_bar=True, **opts)
        self.log(f"{stage}/loss_structure", structure_loss, **opts)
        self.log(f"{stage}/loss_direction", direction_loss, **opts)
        if stage != "train":
            with torch.no_grad():
                for name, value in evidence_figures(structure, direction, batch, self.hparams.keep).items():
                    if not bool(value.isnan()):
                        self.log(f"{stage}/{name}", value, **opts)
        return loss
