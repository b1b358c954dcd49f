"""Fitting the line reader's temperature and fusion weights on real photos held back from its training.

After ``ngp-train export``, an :class:`~ngp_kornia.nets.upright_lines.UprightLinesNet` weights file holds trained
readers with a temperature of 1 and fusion weights of 1: neither is fitted. Both are fitted here on the ``calibrate``
part of the photo folder (:mod:`ngp_kornia.data.photo_split`), each photo in its four quarter turns: the temperature
of the readers' mean logits (:func:`~ngp_kornia.training.upright_calibration.fit_temperature`), then the two weights
of the thumbnail network's and the lines' log-probabilities that minimise the NLL of the fused reading
(:meth:`~ngp_kornia.nets.upright_lines.UprightLinesNet.fuse`), with the thumbnail network the parser uses with it.

Usage::

    python -m ngp_kornia.training.upright_lines_fit upright_lines.pt --photos RealPhotos [--upright upright.pt]

The fitted buffers are written into the given weights file (its readers and metadata kept, the fit noted).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.errors import ConfigError, NGPError, WeightsError
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.weights import load_network, load_tensors_safely, save_network, shipped_weights
from ngp_kornia.training.upright_calibration import fit_temperature, turned_logits
from ngp_kornia.training.upright_lines_data import PhotoSegments, TurnedViews, collate_lines
from ngp_kornia.training.upright_lines_module import view_features

__all__ = ["fit_fusion", "fit_line_reader", "line_logits", "main"]


def fit_fusion(thumbs: Tensor, lines: Tensor, turns: Tensor) -> tuple[float, float]:
    """The weights (u, v) that minimise the NLL of ``turns`` (M,) under softmax(u * thumbs + v * lines), both (M, 4)
    log-probabilities (a logistic model on the two readings, fitted by L-BFGS from (1, 1)).

    Example:
        >>> turns = torch.arange(4).repeat(50)
        >>> sure = torch.log_softmax(4.0 * F.one_hot(turns, 4).double(), -1)
        >>> noise = torch.log_softmax(torch.randn(200, 4, generator=torch.Generator().manual_seed(0)), -1)
        >>> u, v = fit_fusion(sure, noise, turns)
        >>> u > 1.0 and abs(v) < 0.5
        True
    """
    weights = torch.ones(2, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([weights], max_iter=200, line_search_fn="strong_wolfe")
    thumbs, lines = thumbs.detach().double(), lines.detach().double()

    def closure() -> Tensor:
        opt.zero_grad()
        loss = F.cross_entropy(weights[0] * thumbs + weights[1] * lines, turns)
        loss.backward()
        return loss

    opt.step(closure)
    return float(weights[0].detach()), float(weights[1].detach())


@torch.no_grad()
def line_logits(net: UprightLinesNet, photos: PhotoSegments, batch_size: int = 256) -> tuple[Tensor, Tensor]:
    """The readers' (4 N, 4) mean logits of each photo's four turns, photo by photo, and the (4 N,) turns."""
    views = TurnedViews(photos, mirrors=False)
    logits, turns = [], []
    for start in range(0, len(views), batch_size):
        batch = collate_lines([views[i] for i in range(start, min(start + batch_size, len(views)))])
        logits.append(net.logits(view_features(batch).to(net.temperature), batch.mask))
        turns.append(batch.turns)
    return torch.cat(logits), torch.cat(turns)


def fit_line_reader(
    weights: str | Path, photos: str | Path, upright: str | Path | None = None, cache_dir: str | Path | None = None
) -> dict:
    """Fit the temperature and fusion weights of the line reader in ``weights`` on the calibrate part of ``photos``
    and write them into that file.

    Args:
        weights: an ``UprightLinesNet`` weights file (``ngp-train export``'s); rewritten with the fitted buffers.
        photos: the folder of upright photos the reader was trained on (its calibrate part is read).
        upright: the thumbnail network's weights (None: the shipped ``upright.pt``).
        cache_dir: where the detected segments are cached (the training's ``cache`` reuses them; None: detect).

    Returns:
        the fit: temperature, fusion weights, the calibrate views' NLL of the lines alone and of the fused reading
        before and after, and the number of photos.

    Raises:
        WeightsError: a file that is not a weights file of the expected network.
        ConfigError: no photo folder, or no photo in its calibrate part.
    """
    net = load_network(weights, "UprightLinesNet")
    thumb_net = load_network(upright or shipped_weights("upright"), "UprightNet")
    names = _calibrate_names(photos)
    lines_raw, turns = line_logits(net, PhotoSegments(photos, names, cache_dir))
    thumb_logits, _ = turned_logits(thumb_net, photos, names)  # photo by photo, turns 0-3, as the lines'
    thumbs = torch.log_softmax(thumb_logits[:, :4] / thumb_net.temperature, -1)
    temperature = fit_temperature(lines_raw, turns)
    lines = torch.log_softmax(lines_raw.double() / temperature, -1)
    u, v = fit_fusion(thumbs, lines, turns)
    fit = {"photos": len(names), "temperature": temperature, "fusion": [u, v],
           "lines_nll": float(F.cross_entropy(lines, turns)),
           "thumbnail_nll": float(F.cross_entropy(thumbs.double(), turns)),
           "fused_nll_unweighted": float(F.cross_entropy(thumbs.double() + lines, turns)),
           "fused_nll": float(F.cross_entropy(u * thumbs.double() + v * lines, turns))}  # fmt: skip
    _write(net, weights, fit, photos, upright)
    return fit


def _calibrate_names(photos: str | Path) -> list[str]:
    if not Path(photos).is_dir():
        raise ConfigError(f"photo folder not found: {photos}; give the folder the reader was trained on")
    names = split_photos(photos, "calibrate")
    if not names:
        raise ConfigError(f"{photos} has no photo in its calibrate part; the fit needs held-back photos")
    return names


def _write(net: UprightLinesNet, weights: str | Path, fit: dict, photos, upright) -> None:
    """The fitted buffers into the weights file, its metadata kept and the fit added (written whole, then moved)."""
    net.temperature.fill_(fit["temperature"])
    net.fusion.copy_(torch.tensor(fit["fusion"]))
    old = load_tensors_safely(Path(weights), WeightsError, "weights file").get("metadata", {})
    note = {**fit, "photos folder": str(photos), "upright": str(upright or "shipped"),
            "date": time.strftime("%Y-%m-%d", time.gmtime())}  # fmt: skip
    tmp = Path(f"{weights}.fitting")
    save_network(net, tmp, net.settings(), {**old, "fit": note})
    tmp.replace(weights)


def main(argv: list[str] | None = None) -> int:
    """``python -m ngp_kornia.training.upright_lines_fit WEIGHTS --photos ROOT``; its exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m ngp_kornia.training.upright_lines_fit",
        description="Fit the line reader's temperature and fusion weights on the calibrate part of the photo folder "
        "and write them INTO the given weights file (that is its purpose: the file's readers and metadata are kept, "
        "its temperature and fusion weights replaced; copy it first to keep the unfitted one).",
    )
    parser.add_argument("weights", help="the UprightLinesNet weights file ngp-train export wrote (rewritten)")
    parser.add_argument("--photos", required=True, help="the folder of upright photos the reader was trained on")
    parser.add_argument("--upright", help="the thumbnail network's weights (default: the shipped upright.pt)")
    parser.add_argument("--cache-dir", help="the segments cache of the training (e.g. cache); default: detect anew")
    args = parser.parse_args(argv)
    try:
        fit = fit_line_reader(args.weights, args.photos, args.upright, args.cache_dir)
    except (NGPError, OSError) as err:
        print(f"upright_lines_fit: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    print(f"{args.weights}: temperature {fit['temperature']:.3f}, fusion {fit['fusion'][0]:.3f} / "
          f"{fit['fusion'][1]:.3f} on {fit['photos']} photos; NLL lines {fit['lines_nll']:.3f}, thumbnail "
          f"{fit['thumbnail_nll']:.3f}, fused {fit['fused_nll']:.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
