"""Distil the line detector's turn reading (``benchmarks/upright_teacher.py``) into the orientation check's own
network, at training time only: the network is fine-tuned from its weights on the ``train`` part of the photo
folder, each photo's loss the mean of the cross entropy of its true turn and of the teacher's turn posteriors, with
renders and structure-free images as in ``ngp-train fit --config upright`` beside them.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_distil.py --photos ../shared/data/RealPhotos \\
        --features teacher.pt --cache cache --out distilled.pt [--epochs 8] [--teacher-share 0.5]

``--features`` is the feature cache written by ``upright_teacher.py --cache`` (the detector itself is not loaded
here). The teacher's posteriors for the training photos are cross-fitted (a head fitted on three quarters of the
photos reads the fourth), so they are those of photos it never fitted, as on new photos; per photo and turn they
are averaged over the photo and its mirror image. Thumbnails come from the training cache of
``ngp-train fit --config upright`` (128 px, ``--cache``; filled if absent). The epoch with the lowest loss of the
``calibrate`` part's turns is kept; the network is written with its temperature fitted on that part.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).parent))
from upright_teacher import fit_head  # noqa: E402

from ngp_kornia.data.photo_split import split_photos  # noqa: E402
from ngp_kornia.nets.weights import load_network, save_network  # noqa: E402
from ngp_kornia.training.synth.render_config import RenderConfig  # noqa: E402
from ngp_kornia.training.upright_calibration import fit_temperature, turned_logits  # noqa: E402
from ngp_kornia.training.upright_data import STRUCTURELESS_SEEDS, PhotoThumbs, UprightThumbs, sample_keys  # noqa: E402
from ngp_kornia.training.upright_module import NO_STRUCTURE, photometric, random_crops, turned  # noqa: E402


def cross_fitted(feats: torch.Tensor, folds: int = 4, decay: float = 0.03) -> torch.Tensor:
    """(N, 4) turn posteriors of each training photo's four turns, each from a head fitted on the other folds,
    averaged over the photo and its mirror image."""
    n = len(feats)
    out = torch.zeros(n, 4, 4)
    fold = torch.arange(n) % folds
    for f in range(folds):
        train = feats[fold != f]
        x = train.flatten(0, 2)
        y = torch.arange(4)[None, :, None].expand(train.shape[:3]).flatten()
        mean, std = x.mean(0), x.std(0).clamp_min(1e-6)
        head = fit_head((x - mean) / std, y, decay)
        with torch.no_grad():
            probs = torch.softmax(head((feats[fold == f] - mean) / std), -1)  # (n_f, 4, 2, 4)
        out[fold == f] = probs.mean(2)
    return out


def feature_targets(feats: torch.Tensor, dims: int = 64) -> torch.Tensor:
    """(N, 4, dims) whitened principal components of the teacher's features of each training photo's four turns,
    averaged over the photo and its mirror image (the network's input is mirrored at random)."""
    x = feats.flatten(0, 2)
    mean, std = x.mean(0), x.std(0).clamp_min(1e-6)
    _, _, v = torch.pca_lowrank((x - mean) / std, q=dims, center=False)
    scores = ((feats.mean(2) - mean) / std) @ v
    return scores / scores.flatten(0, 1).std(0)


def thumbs_of(dataset) -> torch.Tensor:
    return torch.from_numpy(np.stack([dataset[i].thumb for i in range(len(dataset))]))


def load_data(args: argparse.Namespace) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    names = split_photos(args.photos, "train")
    photos = PhotoThumbs(args.photos, names, [f"p{i}" for i in range(len(names))], 128, args.cache)
    keys = sample_keys(0, STRUCTURELESS_SEEDS["train"], args.renders, 6)
    renders = UprightThumbs(keys, 128, RenderConfig(foliage=0.5), args.cache)
    photos.prepare(0), renders.prepare(0)
    structured = torch.tensor([k[0] == "r" for k in keys])
    return thumbs_of(photos), thumbs_of(renders), structured


def real_loss(logits: torch.Tensor, turns: torch.Tensor, target: torch.Tensor, share: float) -> torch.Tensor:
    logp = torch.log_softmax(logits[:, :NO_STRUCTURE], -1)
    hard = F.nll_loss(logp, turns)
    soft = -(target * logp).sum(-1).mean()
    return (1 - share) * hard + share * soft


def epoch(net, opt, photos, posts, renders, structured, args, gen) -> float:
    """One epoch: each photo ``--repeats`` times, each render once, shuffled into mixed batches."""
    net.train()
    items = torch.cat([torch.arange(len(photos)).repeat(args.repeats), -1 - torch.arange(len(renders))])
    items = items[torch.randperm(len(items), generator=gen)]
    total = 0.0
    for batch in items.split(64):
        real, rend = batch[batch >= 0], -1 - batch[batch < 0]
        thumbs = torch.cat([photos[real], renders[rend]]).float() / 255.0
        turns = torch.randint(0, 4, (len(batch),), generator=gen)
        x = turned(photometric(random_crops(thumbs, 64, args.crop, gen), gen), turns)
        hidden = net.head[:4](net.features(x * 2.0 - 1.0))
        logits = net.head[4](hidden)
        k = len(real)
        loss_real = real_loss(logits[:k], turns[:k], posts[real, turns[:k]], args.teacher_share) if k else 0.0
        labels = torch.where(structured[rend], turns[k:], NO_STRUCTURE)
        loss_rend = F.cross_entropy(logits[k:], labels, reduction="sum") if len(rend) else 0.0
        loss = (loss_real * k + loss_rend) / len(batch)
        if args.feature_weight > 0 and k:  # the photos' hidden layer predicts the teacher's features
            aux = F.mse_loss(args.project(hidden[:k]), args.targets[real, turns[:k]])
            loss = loss + args.feature_weight * aux
        opt.zero_grad()
        loss.backward()
        opt.step()
        total += float(loss.detach()) * len(batch)
    return total / len(items)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", required=True)
    ap.add_argument("--features", required=True, help="upright_teacher.py's feature cache")
    ap.add_argument("--cache", default="cache", help="the training thumbnails' cache folder")
    ap.add_argument("--init", default="ngp_kornia/weights/upright.pt")
    ap.add_argument("--out", required=True)
    ap.add_argument("--renders", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--lr-step", type=int, default=4)
    ap.add_argument("--crop", type=float, default=0.5)
    ap.add_argument("--teacher-share", type=float, default=0.5, help="the teacher's share of a photo's loss")
    ap.add_argument("--feature-weight", type=float, default=0.0,
                    help="weight of the teacher's features predicted from the hidden layer (0: not)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    feats = torch.load(args.features)["train"]
    posts = cross_fitted(feats) if args.teacher_share > 0 else torch.full((len(feats), 4, 4), 0.25)
    if args.teacher_share > 0:
        right = float((posts.argmax(-1) == torch.arange(4)).float().mean())
        print(f"teacher, cross-fitted, on the train part: turn right {right:.3f}", flush=True)
    photos, renders, structured = load_data(args)
    net = load_network(args.init, "UprightNet")
    temperature = net.temperature
    args.targets = feature_targets(feats)
    args.project = torch.nn.Linear(64, args.targets.shape[-1])  # a training-time head only, not kept
    opt = torch.optim.Adam([*net.parameters(), *args.project.parameters()], lr=args.lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, args.lr_step, 0.5)
    names = split_photos(args.photos, "calibrate")
    best = (float("inf"), None)
    for e in range(args.epochs):
        start = time.perf_counter()
        loss = epoch(net, opt, photos, posts, renders, structured, args, gen)
        sched.step()
        net.eval()
        logits, turns = turned_logits(net, args.photos, names)
        val = float(F.cross_entropy(logits[:, :4], turns))
        right = float((logits[:, :4].argmax(-1) == turns).float().mean())
        print(f"epoch {e}: train loss {loss:.3f}, calibrate loss {val:.3f}, turn right {right:.3f}, "
              f"{time.perf_counter() - start:.0f} s", flush=True)
        if val < best[0]:
            best = (val, {k: v.clone() for k, v in net.state_dict().items()}, e, logits, turns)
    net.load_state_dict(best[1])
    net.temperature = fit_temperature(best[3], best[4])
    settings = {k: v for k, v in vars(args).items() if k not in ("targets", "project")}
    meta = {"distilled": settings, "epoch": best[2], "temperature": "fitted on the calibrate part",
            "init_temperature": temperature}
    save_network(net, args.out, net.settings(), meta)
    print(f"kept epoch {best[2]}, temperature {net.temperature:.3f}, written to {args.out}")


if __name__ == "__main__":
    main()
