"""Training the line-evidence network with Lightning on rendered scenes: binary cross entropy of the structure
logit against the share of each segment on a structural outline, plus cross entropy of the direction logits
(vertical / horizontal / neither) from the true vanishing points."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.training.base import NetworkModule, start_from
from ngp_kornia.training.evidence_data import LineBatch

__all__ = ["LineEvidenceModule", "evidence_figures", "structure_offset"]


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


def structure_offset(counts: Tensor, histogram: tuple[float, float, int], keep: float, keep_share: float) -> float:
    """The offset to add to raw structure logits so that ``keep_share`` of the segments counted get a weight of at
    least ``keep``.

    Args:
        counts: (bins,) how many structural segments' raw logits fall in each bin.
        histogram: ``(lowest, highest, bins)``, the bins' range.
        keep: the weight at or above which a segment is kept.
        keep_share: the share to keep.

    Returns:
        The offset; a segment whose raw logit lies in the bin where the dropped share is reached, or above, is kept.

    Example:
        >>> counts = torch.zeros(100); counts[[10, 50, 60, 70]] = 1.0  # logits about -4, 0, 1, 2 on (-5, 5)
        >>> round(structure_offset(counts, (-5.0, 5.0, 100), 0.5, 0.75), 3)  # keep 3 of 4: the one at 0 and above
        -0.0
    """
    lo, hi, bins = histogram
    below = torch.cumsum(counts.double(), 0) / counts.sum()  # share at or below each bin's upper edge
    edge = int(torch.searchsorted(below, torch.tensor(1.0 - keep_share, dtype=below.dtype), right=True))
    logit = lo + (hi - lo) * edge / bins  # the lower edge of the first bin kept
    return float(torch.logit(torch.tensor(keep, dtype=torch.float64))) - logit


class LineEvidenceModule(NetworkModule):
    """Lightning wrapper of a :class:`~ngp_kornia.nets.line_evidence.LineEvidenceNet`.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate.
        lr_step: epochs between halvings of the learning rate.
        direction_weight: weight of the direction loss against the structure loss.
        keep: the weight at or above which a segment is kept.
        keep_share: after each validation, the network's structure offset is set so that this share of the
            validation set's structural segments gets a weight of at least ``keep`` (None: left as it is).
        init_weights: start ``net`` from a line-evidence weights file of the same settings (fine-tuning), or
            ``"evidence"`` for the shipped one; None: from its own initialisation.
    """

    #: bins of the histogram of validation logits the offset is read from (logits beyond the range fall in the
    #: first or last bin)
    HISTOGRAM = (-30.0, 30.0, 60000)

    def __init__(self, net: LineEvidenceNet, lr: float = 3e-3, lr_step: int = 4, direction_weight: float = 0.5,
                 keep: float = 0.1, keep_share: float | None = 0.97, init_weights: str | None = None) -> None:
        super().__init__()
        if keep_share is not None and not 0.0 < keep_share < 1.0:
            raise ValueError(f"keep_share must lie in (0, 1) or be None, got {keep_share}")
        self.save_hyperparameters(ignore=["net"])
        self.net = net
        if init_weights is not None:
            start_from(net, init_weights, "evidence")
        self._positives: Tensor | None = None

    def on_validation_epoch_start(self) -> None:
        self._positives = torch.zeros(self.HISTOGRAM[2], dtype=torch.float64, device=self.device)

    def _count_positives(self, raw: Tensor, batch: LineBatch) -> None:
        lo, hi, bins = self.HISTOGRAM
        positive = raw[batch.mask & (batch.structure >= 0.5)].detach().double()
        index = ((positive - lo) / (hi - lo) * bins).long().clamp(0, bins - 1)
        self._positives.index_add_(0, index, torch.ones_like(positive))

    def on_validation_epoch_end(self) -> None:
        if self.hparams.keep_share is None or self._positives is None or self.trainer.sanity_checking:
            return
        counts = self.trainer.strategy.reduce(self._positives, reduce_op="sum")  # every process's share of the set
        if float(counts.sum()) == 0:
            return
        self.net.structure_offset.fill_(structure_offset(counts, self.HISTOGRAM, self.hparams.keep,
                                                         self.hparams.keep_share))

    def forward(self, features: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        return self.net.classify(features, mask)

    def _step(self, batch: LineBatch, stage: str, batch_idx: int) -> Tensor:
        structure, direction = self.net.classify(batch.features, batch.mask)
        raw = structure - self.net.structure_offset  # the loss and the offset's calibration use the raw logits
        if stage == "val" and self._positives is not None:
            self._count_positives(raw, batch)
        valid = batch.mask
        count = valid.sum().clamp_min(1)
        bce = F.binary_cross_entropy_with_logits(raw, batch.structure, reduction="none")
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
