"""Training the orientation and structure check with Lightning: each upright thumbnail is turned by a random number
of quarter turns (the label), structure-free ones are labelled "no structure" whatever their turn, and the
training thumbnails get photometric changes (exposure, contrast, colour, gamma, grain, blur, a mirror image) so that
the renders' clean look is not what the network learns. Validation turns the k-th thumbnail by ``k mod 4`` quarter
turns, unchanged otherwise, so its figures are the same on every run.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.nets.upright import CLASSES, UprightNet
from ngp_kornia.training.base import NetworkModule
from ngp_kornia.training.upright_data import ThumbBatch

__all__ = ["UprightModule", "photometric", "turned"]

NO_STRUCTURE = len(CLASSES) - 1


def turned(thumbs: Tensor, turns: Tensor) -> Tensor:
    """Each thumbnail turned counter-clockwise by its ``turns`` (B,) quarter turns (as ``np.rot90``)."""
    out = thumbs.clone()
    for k in range(1, 4):
        pick = turns == k
        if bool(pick.any()):
            out[pick] = torch.rot90(thumbs[pick], k, dims=(-2, -1))
    return out


def photometric(thumbs: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """Random exposure, contrast, saturation, gamma, grain, blur and mirroring of (B, 3, S, S) thumbnails in [0, 1]."""
    b = len(thumbs)

    def u(lo: float, hi: float) -> Tensor:
        return lo + (hi - lo) * torch.rand(b, 1, 1, 1, generator=generator)

    x = thumbs.clamp(1e-4, 1.0) ** u(0.6, 1.6)
    grey = x.mean(1, keepdim=True)
    x = grey + (x - grey) * u(0.0, 1.6)  # saturation, down to grey
    mean = x.mean((1, 2, 3), keepdim=True)
    x = mean + (x - mean) * u(0.6, 1.4)  # contrast
    x = x * u(0.6, 1.4) + u(-0.1, 0.1)  # exposure
    blur = torch.rand(b, generator=generator) < 0.25
    if bool(blur.any()):
        x[blur] = F.avg_pool2d(x[blur], 3, stride=1, padding=1, count_include_pad=False)
    x = x + torch.randn(x.shape, generator=generator) * u(0.0, 0.04)
    mirror = torch.rand(b, generator=generator) < 0.5
    x[mirror] = x[mirror].flip(-1)  # a mirror image is as upright as the original
    return x.clamp(0.0, 1.0)


class UprightModule(NetworkModule):
    """Lightning wrapper of an :class:`~ngp_kornia.nets.upright.UprightNet`: cross entropy over its five classes.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate.
        lr_step: epochs between halvings of the learning rate.
    """

    def __init__(self, net: UprightNet, lr: float = 2e-3, lr_step: int = 4) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net

    def forward(self, thumbs: Tensor) -> Tensor:
        return self.net(thumbs)

    def _inputs(self, batch: ThumbBatch, stage: str, batch_idx: int) -> tuple[Tensor, Tensor]:
        b = len(batch)
        if stage == "train":
            turns = torch.randint(0, 4, (b,))
            thumbs = photometric(batch.thumbs)
        else:
            turns = (torch.arange(b) + batch_idx * b) % 4
            thumbs = batch.thumbs
        labels = torch.where(batch.structured, turns, torch.full_like(turns, NO_STRUCTURE))
        return turned(thumbs, turns), labels.to(thumbs.device)

    def _step(self, batch: ThumbBatch, stage: str, batch_idx: int) -> Tensor:
        thumbs, labels = self._inputs(batch, stage, batch_idx)
        logits = self.net(thumbs)
        loss = F.cross_entropy(logits, labels)
        opts = {"batch_size": len(batch), "sync_dist": stage != "train"}
        self.log(f"{stage}/loss", loss, prog_bar=True, **opts)
        if stage != "train":
            with torch.no_grad():
                probs = torch.softmax(logits, -1)
                upright = labels == 0
                self.log(f"{stage}/accuracy", (probs.argmax(-1) == labels).float().mean(), **opts)
                if bool(upright.any()):  # upright renders the check would doubt: their confidence would drop
                    self.log(f"{stage}/upright_doubted", (probs[upright, 0] < 0.5).float().mean(), **opts)
        return loss
