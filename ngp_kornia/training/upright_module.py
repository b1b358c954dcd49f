"""Training the orientation and structure check with Lightning: each upright thumbnail is turned by a random number
of quarter turns (the label), structure-free ones are labelled "no structure" whatever their turn, and the
training thumbnails get a random crop and photometric changes (exposure, contrast, colour, gamma, grain, blur, a
mirror image) so that neither a render's clean look nor one photo's framing is what the network learns. A real
photo's structure is not known: it teaches only its turn (the cross entropy over the four turns' logits). Validation
turns the k-th thumbnail by ``k mod 4`` quarter turns, unchanged otherwise, so its figures are the same on every run.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.nets.upright import CLASSES, UprightNet
from ngp_kornia.nets.weights import load_network
from ngp_kornia.training.base import NetworkModule
from ngp_kornia.training.upright_data import ThumbBatch

__all__ = ["UprightModule", "photometric", "random_crops", "turned"]

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


def random_crops(thumbs: Tensor, size: int, smallest: float, generator: torch.Generator | None = None) -> Tensor:
    """(B, 3, size, size): a random crop of each (B, 3, S, S) thumbnail, of ``smallest`` to all of its area and an
    aspect between 3:4 and 4:3, averaged down to ``size`` as the parser makes a thumbnail (``smallest`` 1: the
    whole thumbnail)."""
    if smallest >= 1.0:
        return F.adaptive_avg_pool2d(thumbs, size)
    side = thumbs.shape[-1]
    area = smallest + (1.0 - smallest) * torch.rand(len(thumbs), generator=generator)
    aspect = torch.exp((torch.rand(len(thumbs), generator=generator) - 0.5) * 2 * math.log(4 / 3))
    widths = (side * (area * aspect).sqrt()).clamp(max=side).round().long().clamp(min=1)
    heights = (side * (area / aspect).sqrt()).clamp(max=side).round().long().clamp(min=1)
    x0 = (torch.rand(len(thumbs), generator=generator) * (side - widths + 1)).long()
    y0 = (torch.rand(len(thumbs), generator=generator) * (side - heights + 1)).long()
    crops = [
        F.adaptive_avg_pool2d(t[:, y : y + h, x : x + w], size)
        for t, x, y, w, h in zip(thumbs, x0.tolist(), y0.tolist(), widths.tolist(), heights.tolist(), strict=True)
    ]
    return torch.stack(crops)


class UprightModule(NetworkModule):
    """Lightning wrapper of an :class:`~ngp_kornia.nets.upright.UprightNet`: cross entropy over its five classes.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate.
        lr_step: epochs between halvings of the learning rate.
        crop: the smallest share of a training thumbnail's area a random crop keeps (1: no crop).
        init: a weights file of the same network to start from (fine-tuning; its temperature is not kept), or None.
    """

    def __init__(self, net: UprightNet, lr: float = 2e-3, lr_step: int = 4, crop: float = 1.0,
                 init: str | None = None) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net
        if init is not None:
            self.net.load_state_dict(load_network(init, "UprightNet").state_dict())

    def forward(self, thumbs: Tensor) -> Tensor:
        return self.net(thumbs)

    def _inputs(self, batch: ThumbBatch, stage: str, batch_idx: int) -> tuple[Tensor, Tensor]:
        b = len(batch)
        if stage == "train":
            turns = torch.randint(0, 4, (b,))
            thumbs = photometric(random_crops(batch.thumbs, self.net.size, self.hparams.crop))
        else:
            turns = (torch.arange(b) + batch_idx * b) % 4
            thumbs = F.adaptive_avg_pool2d(batch.thumbs, self.net.size)
        labels = torch.where(batch.structured, turns, torch.full_like(turns, NO_STRUCTURE))
        return turned(thumbs, turns), labels.to(thumbs.device)

    def _step(self, batch: ThumbBatch, stage: str, batch_idx: int) -> Tensor:
        thumbs, labels = self._inputs(batch, stage, batch_idx)
        logits = self.net(thumbs)
        real = batch.real.to(logits.device)
        # a real photo's structure is not known: its loss is that of its turn among the four turns
        losses = torch.where(real, F.cross_entropy(logits[:, :NO_STRUCTURE], labels.clamp(max=NO_STRUCTURE - 1),
                                                   reduction="none"), F.cross_entropy(logits, labels, reduction="none"))
        loss = losses.mean()
        opts = {"batch_size": len(batch), "sync_dist": stage != "train"}
        self.log(f"{stage}/loss", loss, prog_bar=True, **opts)
        if stage != "train":
            self._log_figures(logits, labels, real, losses, stage, opts)
        return loss

    def _log_figures(self, logits: Tensor, labels: Tensor, real: Tensor, losses: Tensor, stage: str,
                     opts: dict) -> None:
        """Accuracy and doubted upright renders; on real photos the turn's accuracy and loss."""
        with torch.no_grad():
            probs = torch.softmax(logits, -1)
            rendered = ~real
            if bool(rendered.any()):
                right = probs[rendered].argmax(-1) == labels[rendered]
                self.log(f"{stage}/accuracy", right.float().mean(), **{**opts, "batch_size": int(rendered.sum())})
                upright = rendered & (labels == 0)
                if bool(upright.any()):  # upright renders the check would doubt: their confidence would drop
                    doubted = (probs[upright, 0] < 0.5).float().mean()
                    self.log(f"{stage}/upright_doubted", doubted, **{**opts, "batch_size": int(upright.sum())})
            if bool(real.any()):
                real_opts = {**opts, "batch_size": int(real.sum())}
                right = logits[real, :NO_STRUCTURE].argmax(-1) == labels[real]
                self.log(f"{stage}/real_accuracy", right.float().mean(), **real_opts)
                self.log(f"{stage}/real_loss", losses[real].mean(), **real_opts)
