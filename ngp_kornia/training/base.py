"""What the networks' LightningModules share: one step function for all stages, the optimiser and schedule of
the paper (Adam, learning rate halved every ``lr_step`` epochs), and the network description that
``ngp-train export`` needs."""

from __future__ import annotations

import lightning as L
import torch
from torch import Tensor

from ngp_kornia.errors import ConfigError
from ngp_kornia.nets.weights import load_network, shipped_weights
from ngp_kornia.training.scene_data import SceneBatch

__all__ = ["NetworkModule", "start_from"]


def start_from(net: torch.nn.Module, init_weights: str, shipped: str) -> None:
    """Copy a weights file of ``net``'s kind into ``net`` (fine-tuning), whose settings must be the file's.

    Args:
        net: the network to start.
        init_weights: a weights file, or ``shipped`` for the shipped one.
        shipped: the shipped weights' name (``"fsnet"``, ``"evidence"``).

    Raises:
        ConfigError: the file's network was built with other settings (they are named).
    """
    path = shipped_weights(shipped) if init_weights == shipped else init_weights
    start = load_network(path, type(net).__name__)
    theirs, ours = start.settings(), net.settings()
    differ = sorted(k for k in {*theirs, *ours} if theirs.get(k) != ours.get(k))
    if differ:
        wanted = ", ".join(f"{k}={theirs.get(k)!r}" for k in differ)
        kind = type(net).__name__
        raise ConfigError(f"init_weights {init_weights}: its {kind} was built with {wanted}; give model.net these")
    net.load_state_dict(start.state_dict())


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
