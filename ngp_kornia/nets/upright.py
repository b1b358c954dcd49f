"""UprightNet: is the photo the right way up, turned, or without man-made structure at all?

The parser reads the camera's up direction from the lines, and lines alone cannot tell a photo turned by 90 or 180
degrees from a camera rolled that far: a photo without its orientation tag gets a confident answer for the wrong
way up. Appearance can tell (sky above, ground below, how things stand), and so can the look of an image that holds
no structure to calibrate from (noise, clouds, water, foliage). This small network reads a thumbnail of the whole
image and gives five probabilities: upright, turned by 90, 180 or 270 degrees (counter-clockwise, as ``np.rot90``
turns an array), and no structure. It is trained on renders turned every way and on structure-free images
(:mod:`ngp_kornia.training.upright_module`); the parser uses it to say how far its answer can be trusted
(:mod:`ngp_kornia.pipeline.upright_check`).

Example:
    >>> net = UprightNet().eval()
    >>> probs = net.probabilities(torch.rand(2, 3, 120, 160))
    >>> probs.shape, bool(torch.allclose(probs.sum(-1), torch.ones(2)))
    (torch.Size([2, 5]), True)
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["CLASSES", "UprightNet", "thumbnail"]

#: the network's classes, in the order of its outputs: quarter turns counter-clockwise, then no structure
CLASSES = ("upright", "turned 90", "turned 180", "turned 270", "no structure")


def thumbnail(images: Tensor, size: int) -> Tensor:
    """(B, 3, size, size): the images averaged down to a square (the aspect is not kept: a turned photo must not be
    told by its shape, since portrait photos are as common as landscape ones)."""
    return F.adaptive_avg_pool2d(images.float(), (size, size))


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True), nn.MaxPool2d(2)
    )


class UprightNet(nn.Module):
    """Four conv blocks on a ``size`` x ``size`` thumbnail, then two linear layers that keep where things are (sky
    above is the cue, so the map is not pooled away).

    Args:
        size: thumbnail side in pixels (a multiple of 16).
        width: channels of the first block (doubled in the second and third).
        temperature: what the logits are divided by before the softmax of :meth:`probabilities`, fitted after
            training on photos held back from it so that the probabilities are calibrated (1: as trained).
    """

    def __init__(self, size: int = 64, width: int = 16, temperature: float = 1.0) -> None:
        super().__init__()
        if size % 16 or size < 16:
            raise ValueError(f"size must be a positive multiple of 16, got {size}")
        if not 0.0 < temperature < float("inf"):
            raise ValueError(f"temperature must be a positive number, got {temperature}")
        self.size, self.width, self.temperature = size, width, float(temperature)
        w = (width, 2 * width, 4 * width, 4 * width)
        self.features = nn.Sequential(_block(3, w[0]), _block(w[0], w[1]), _block(w[1], w[2]), _block(w[2], w[3]))
        cells = (size // 16) ** 2
        self.head = nn.Sequential(nn.Flatten(), nn.Dropout(0.2), nn.Linear(w[3] * cells, 64), nn.ReLU(inplace=True),
                                  nn.Linear(64, len(CLASSES)))  # fmt: skip

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        return {"size": self.size, "width": self.width, "temperature": self.temperature}

    def forward(self, thumbs: Tensor) -> Tensor:
        """(B, 3, size, size) thumbnails in [0, 1] -> (B, 5) logits."""
        return self.head(self.features(thumbs * 2.0 - 1.0))

    @torch.no_grad()
    def probabilities(self, images: Tensor) -> Tensor:
        """(B, 3, H, W) RGB images in [0, 1] -> (B, 5) probabilities of :data:`CLASSES` (the logits divided by
        ``temperature``)."""
        return torch.softmax(self(thumbnail(images, self.size)) / self.temperature, -1)
