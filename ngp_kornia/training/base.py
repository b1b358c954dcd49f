"""What the networks' LightningModules share: one step function for all stages, the optimiser and schedule of
the paper (Adam, learning rate halved every ``lr_step`` epochs), and the network description that
``ngp-train export`` needs."""

from __future__ import annotations

import lightning as L
import torch
from torch import Tensor

from ngp_kornia.training.scene_data import SceneBatch

__all__ = ["NetworkModule"]


class NetworkModule(L.LightningModule):
    """Base of :class:`ZSNetModule` and :class:`FSNetModule`: subclasses set ``self.net``, hyperparameters ``lr``
    and ``lr_step``, and implement ``_step(batch, stage, batch_idx)``."""

    net: torch.nn.Module

    def _step(self, batch: SceneBatch, stage: str, batch_idx: int) -> Tensor:
        raise NotImplementedError

    def training_step(self, batch: SceneBatch, batch_idx: int) -> Tensor:
        return self._step(batch, "train", batch_idx)

    def validation_step(self, batch: SceneBatch, batch_idx: int) -> Tensor:
        return self._step(batch, "val", batch_idx)

    def test_step(self, batch: SceneBatch, batch_idx: int) -> Tensor:
        return self._step(batch, "test", batch_idx)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # what ngp-train export needs to rebuild the bare network without this module
        checkpoint["ngp_network"] = {"name": type(self.net).__name__, "settings": self.net.settings()}

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.net.parameters(), lr=self.hparams.lr)
        sched = torch.optim.lr_scheduler.StepLR(opt, step_size=self.hparams.lr_step, gamma=0.5)
        return {"optimizer": opt, "lr_scheduler": sched}
