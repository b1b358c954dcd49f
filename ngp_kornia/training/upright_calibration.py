"""Calibrating the orientation check on real photos held back from its training.

A network trained with cross entropy is seldom calibrated: on photos unlike its training data its largest
probability is larger than its accuracy. Temperature scaling (Guo et al., "On calibration of modern neural
networks", ICML 2017) divides the logits by one number fitted to the negative log-likelihood of photos the network
never saw, which keeps the network's ranking and makes its probabilities mean what they say. The photos are the
``calibrate`` part of a folder of upright photos (:mod:`ngp_kornia.data.photo_split`), each turned four ways, as
the parser reads them (the whole image averaged down to the network's thumbnail).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.io import read_image_file
from ngp_kornia.nets.upright import UprightNet, thumbnail

__all__ = ["calibration_error", "fit_temperature", "turned_logits"]


@torch.no_grad()
def turned_logits(net: UprightNet, root: str | Path, names: list[str]) -> tuple[Tensor, Tensor]:
    """The network's (4 N, 5) logits for each photo turned counter-clockwise by 0, 1, 2 and 3 quarter turns (as
    ``np.rot90``), and the (4 N,) turns, photo by photo.

    Args:
        net: the network, in eval mode.
        root: the photo folder.
        names: the photos, relative to ``root``.
    """
    logits, turns = [], []
    for name in names:
        rgb = read_image_file(Path(root) / name)
        images = [np.ascontiguousarray(np.rot90(rgb, k)) for k in range(4)]
        thumbs = torch.stack([thumbnail(torch.from_numpy(i).permute(2, 0, 1)[None] / 255.0, net.size)[0]
                              for i in images])  # fmt: skip
        logits.append(net(thumbs))
        turns.append(torch.arange(4))
    return torch.cat(logits), torch.cat(turns)


def fit_temperature(logits: Tensor, turns: Tensor) -> float:
    """The temperature T > 0 that minimises the negative log-likelihood of ``turns`` (N,) under the softmax of the
    four turns' logits (N, >= 4) divided by T: a one-dimensional convex problem in log T, solved by golden-section
    search on [0.05, 20].

    Example:
        >>> logits = torch.tensor([[4.0, 0.0, 0.0, 0.0], [4.0, 0.0, 0.0, 0.0]])
        >>> round(fit_temperature(logits, torch.tensor([0, 1])), 1) > 1.0   # wrong half the time: softer
        True
    """
    four = logits[:, :4].double()

    def nll(log_t: float) -> float:
        return float(F.cross_entropy(four / math.exp(log_t), turns))

    lo, hi = math.log(0.05), math.log(20.0)
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        lo, hi = (lo, b) if nll(a) < nll(b) else (a, hi)
    return math.exp((lo + hi) / 2.0)


def calibration_error(probs: Tensor, right: Tensor, bins: int = 10) -> float:
    """Expected calibration error: over ``bins`` equal-width bins of the probability ``probs`` (N,), the
    count-weighted mean of |mean probability - share ``right``| (N,) bool.

    Example:
        >>> calibration_error(torch.tensor([0.9, 0.9, 0.2, 0.2]), torch.tensor([True, False, False, False]))
        0.3
    """
    index = (probs.double() * bins).long().clamp(max=bins - 1)
    error = 0.0
    for b in range(bins):
        pick = index == b
        if bool(pick.any()):
            error += float(pick.sum()) * abs(float(probs[pick].double().mean()) - float(right[pick].double().mean()))
    return round(error / len(probs), 6)
