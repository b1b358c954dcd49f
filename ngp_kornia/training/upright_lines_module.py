"""Training the line reader (:class:`~ngp_kornia.nets.upright_lines.UprightLinesNet`) with Lightning: each of its
readers learns the turn of a view from its segments with a cross entropy of its own, on the same batches; they differ
by their initialisation only, so that the mean of their logits is steadier than any one of them. Validation reads the
held-back photos' four turns with the mean logits, as the network reads them (its temperature and fusion weights are
fitted after export, :mod:`ngp_kornia.training.upright_lines_fit`). AdamW with a cosine schedule over the run.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.errors import ConfigError
from ngp_kornia.nets.upright_lines import UprightLinesNet, line_turn_features
from ngp_kornia.training.base import NetworkModule
from ngp_kornia.training.upright_lines_data import LineBatch

__all__ = ["UprightLinesModule", "view_features"]


def view_features(batch: LineBatch) -> Tensor:
    """(B, N, 11) :func:`~ngp_kornia.nets.upright_lines.line_turn_features` of each view of a batch, each by its own
    image size (the views of a batch differ in size and shape).

    Example:
        >>> from ngp_kornia.training.upright_lines_data import LineSample, collate_lines
        >>> import numpy as np
        >>> seg = np.array([[[0.0, 0.0], [9.0, 0.0]]], np.float32)
        >>> batch = collate_lines([LineSample(seg, np.array([5, 10]), np.array([0]))])
        >>> tuple(view_features(batch).shape)
        (1, 1, 11)
    """
    sizes = batch.image_size.tolist()
    return torch.cat([line_turn_features(batch.segments[i : i + 1], batch.mask[i : i + 1], h, w)
                      for i, (h, w) in enumerate(sizes)])  # fmt: skip


class UprightLinesModule(NetworkModule):
    """Lightning wrapper of an :class:`~ngp_kornia.nets.upright_lines.UprightLinesNet`: the sum of its readers'
    cross entropies over the four turns (each reader's gradient is that of its own loss).

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: AdamW learning rate at the start of the cosine schedule.
        weight_decay: AdamW's decoupled weight decay.
        cosine_epochs: epochs over which the learning rate falls to zero (None: the Trainer's ``max_epochs``).
    """

    def __init__(
        self, net: UprightLinesNet, lr: float = 3e-3, weight_decay: float = 1e-3, cosine_epochs: int | None = None
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net

    def forward(self, features: Tensor, mask: Tensor) -> Tensor:
        return self.net.logits(features, mask)

    def _step(self, batch: LineBatch, stage: str, batch_idx: int) -> Tensor:
        features, mask = view_features(batch), batch.mask
        turns = batch.turns.to(features.device)
        each = torch.stack([reader(features, mask) for reader in self.net.readers])  # (members, B, 4)
        losses = torch.stack([F.cross_entropy(logits, turns) for logits in each])
        opts = {"batch_size": len(batch), "sync_dist": stage != "train"}
        self.log(f"{stage}/loss", losses.mean(), prog_bar=True, **opts)
        if stage != "train":
            with torch.no_grad():
                mean = each.mean(0)  # the network's logits
                self.log(f"{stage}/nll", F.cross_entropy(mean, turns), prog_bar=True, **opts)
                self.log(f"{stage}/accuracy", (mean.argmax(-1) == turns).float().mean(), **opts)
        return losses.sum()

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.net.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        epochs = self.hparams.cosine_epochs or self.trainer.max_epochs
        if epochs is None or epochs < 1:  # an open-ended run (max_epochs -1) has no end for the schedule
            raise ConfigError(f"the cosine schedule needs a number of epochs, got {epochs}; give trainer.max_epochs "
                              "or model.init_args.cosine_epochs")  # fmt: skip
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
        return {"optimizer": opt, "lr_scheduler": sched}
