"""A teacher for the orientation check, at training time only: how well do the frozen features of a line detector
trained on real photos (M-LSD tiny, Gu et al., "Towards light-weight and real-time line segment detection", AAAI
2022; its weights under the Apache-2.0 licence) read the turn of real photos, with a small head fitted on them?

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_teacher.py --mlsd ../shared/models/mlsd/mlsd_tiny_512_fp32.pth \\
        --photos ../shared/data/RealPhotos --yud ../shared/data/YorkUrbanDB \\
        --manifest ../shared/data/EurasianCities/manifest.csv --cache teacher.pt [--side 256] [--json out.json]

The detector is never part of the package: this script builds its backbone (a MobileNetV2 cut after its stride-16
stage, four input channels: RGB scaled to [-1, 1] and a constant plane) and loads the weights file it is given.
Each photo, squashed to ``--side`` pixels square as the check's thumbnail is, is read in its four quarter turns
(``np.rot90``) and, for the ``train`` part, mirrored too; the stride-8 and stride-16 feature maps are averaged over a
4 x 4 grid (where things are in the image is the cue) and over the whole map, and cached. A linear head (multinomial
logistic regression, weight decay chosen on the ``calibrate`` part) is fitted on the ``train`` part's features to
the four turns; its temperature is fitted on the ``calibrate`` part. Reported like ``upright_views.py``: per set the
share of turns read right and the NLL, paired per photo against the shipped network's single reading.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).parent))
from upright_views import paired, per_photo, photo_thumbs, sets_of, view_logits  # noqa: E402

from ngp_kornia.data.photo_split import split_photos  # noqa: E402
from ngp_kornia.io import read_image_file  # noqa: E402
from ngp_kornia.nets.weights import load_network  # noqa: E402
from ngp_kornia.training.upright_calibration import fit_temperature  # noqa: E402

#: the backbone's stages: (expansion, channels, blocks, stride of the first block)
STAGES = ((1, 16, 1, 1), (6, 24, 2, 2), (6, 32, 3, 2), (6, 64, 4, 2))


class ConvUnit(nn.Sequential):
    """Conv, batch norm, ReLU6; a stride-2 conv pads only right and bottom (as the weights were trained)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1, groups: int = 1) -> None:
        pad = 0 if stride == 2 else kernel // 2
        super().__init__(nn.Conv2d(cin, cout, kernel, stride, pad, groups=groups, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU6(inplace=True))  # fmt: skip
        self.stride = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(F.pad(x, (0, 1, 0, 1)) if self.stride == 2 else x)


class Inverted(nn.Module):
    """MobileNetV2's inverted residual: expand (1x1), depthwise 3x3, project (1x1, linear)."""

    def __init__(self, cin: int, cout: int, stride: int, expand: int) -> None:
        super().__init__()
        hidden = cin * expand
        layers = [ConvUnit(cin, hidden, 1)] if expand != 1 else []
        layers += [ConvUnit(hidden, hidden, 3, stride, hidden), nn.Conv2d(hidden, cout, 1, bias=False),
                   nn.BatchNorm2d(cout)]  # fmt: skip
        self.conv = nn.Sequential(*layers)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv(x) if self.residual else self.conv(x)


class Backbone(nn.Module):
    """M-LSD tiny's encoder; returns the feature maps at strides 8 and 16."""

    def __init__(self) -> None:
        super().__init__()
        blocks, cin = [ConvUnit(4, 32, 3, 2)], 32
        for expand, cout, count, stride in STAGES:
            for i in range(count):
                blocks.append(Inverted(cin, cout, stride if i == 0 else 1, expand))
                cin = cout
        self.features = nn.Sequential(*blocks)

    def forward(self, rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 3, S, S) in [0, 1] -> the stride-8 (32 channels) and stride-16 (64 channels) maps."""
        x = torch.cat([rgb * 2.0 - 1.0, torch.ones_like(rgb[:, :1])], 1)
        for i, block in enumerate(self.features):
            x = block(x)
            if i == 6:
                mid = x
        return mid, x


def load_backbone(path: str) -> Backbone:
    """The encoder with the detector's weights (the decoder's weights are left out)."""
    net = Backbone()
    state = torch.load(path, map_location="cpu", weights_only=True)
    own = {k[len("backbone."):]: v for k, v in state.items() if k.startswith("backbone.")}
    net.load_state_dict(own, strict=True)
    return net.eval()


def pooled(maps: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """(B, D) features: each map averaged over a 4 x 4 grid and over the whole image."""
    parts = [torch.cat([F.adaptive_avg_pool2d(m, 4).flatten(1), m.mean((2, 3))], 1) for m in maps]
    return torch.cat(parts, 1)


@torch.no_grad()
def teacher_features(net: Backbone, paths: list[str], side: int, mirror: bool) -> torch.Tensor:
    """(N, 4 turns, 1 or 2 mirrors, D) features of each photo squashed to ``side`` square."""
    out = []
    for path in paths:
        rgb = torch.from_numpy(np.ascontiguousarray(read_image_file(path))).permute(2, 0, 1)[None].float() / 255.0
        square = F.interpolate(rgb, (side, side), mode="area")
        views = [torch.rot90(square, k, dims=(-2, -1)) for k in range(4)]
        if mirror:  # the mirror image of the upright photo, then turned: labels as the turn
            views += [torch.rot90(square.flip(-1), k, dims=(-2, -1)) for k in range(4)]
        feats = pooled(net(torch.cat(views)))
        out.append(feats.reshape(2 if mirror else 1, 4, -1).transpose(0, 1))
    return torch.stack(out)


def fit_head(x: torch.Tensor, y: torch.Tensor, decay: float, steps: int = 300) -> nn.Linear:
    """A multinomial logistic regression on standardised features (full-batch L-BFGS)."""
    head = nn.Linear(x.shape[1], 4)
    opt = torch.optim.LBFGS(head.parameters(), max_iter=steps, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = F.cross_entropy(head(x), y) + decay * head.weight.pow(2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return head


def features_of(args: argparse.Namespace, sets: dict[str, list[str]]) -> dict[str, torch.Tensor]:
    """Every set's teacher features, from ``--cache`` where it holds them."""
    if args.cache and Path(args.cache).exists():
        return torch.load(args.cache)
    net = load_backbone(args.mlsd)
    feats = {}
    for name, paths in sets.items():
        start = time.perf_counter()
        feats[name] = teacher_features(net, paths, args.side, mirror=name == "train")
        print(f"{name}: {len(paths)} photos in {time.perf_counter() - start:.0f} s", flush=True)
    if args.cache:
        torch.save(feats, args.cache)
    return feats


def report(name: str, rows: dict[str, dict]) -> None:
    print(f"\n{name}\n| reader | turn right | NLL | paired turn right | paired NLL |\n|---|---:|---:|---|---|")
    for m, r in rows.items():
        a, n = r["accuracy vs shipped"], r["nll vs shipped"]
        print(f"| {m} | {100 * r['accuracy']:.1f}% | {r['nll']:.3f} | {100 * a['mean']:+.1f} ({100 * a['lo']:+.1f}.."
              f"{100 * a['hi']:+.1f}; halves {100 * a['even']:+.1f} / {100 * a['odd']:+.1f}) | {n['mean']:+.3f} "
              f"({n['lo']:+.3f}..{n['hi']:+.3f}) |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mlsd", required=True, help="M-LSD tiny's weights file (a state dict)")
    ap.add_argument("--photos", required=True, help="the folder of upright photos (train, calibrate, test parts)")
    ap.add_argument("--yud", help="York Urban DB folder (reported on, never chosen on)")
    ap.add_argument("--manifest", help="Eurasian Cities manifest.csv (reported on, never chosen on)")
    ap.add_argument("--weights", default="ngp_kornia/weights/upright.pt", help="the network to pair against")
    ap.add_argument("--side", type=int, default=256, help="the square side the photos are read at")
    ap.add_argument("--cache", help="a file to keep the features in (read if it exists)")
    ap.add_argument("--posteriors", help="write the teacher's turn posteriors of every set here")
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    sets = {"train": [f"{args.photos}/{n}" for n in split_photos(args.photos, "train")], **sets_of(args)}
    feats = features_of(args, sets)
    x = feats["train"].flatten(0, 2)
    y = torch.arange(4)[None, :, None].expand(feats["train"].shape[:3]).flatten()
    mean, std = x.mean(0), x.std(0).clamp_min(1e-6)
    scores = {}
    for decay in (1e-4, 1e-3, 1e-2):
        head = fit_head((x - mean) / std, y, decay)
        with torch.no_grad():
            scores[decay] = {n: head((f[:, :, 0] - mean) / std) for n, f in feats.items()}
        cal = scores[decay]["calibrate"]
        t = fit_temperature(cal.reshape(-1, 4), torch.arange(4).repeat(len(cal)))
        print(f"decay {decay}: calibrate NLL {float(per_photo(cal, t)[1].mean()):.3f}", flush=True)
        scores[decay] = (scores[decay], t)
    decay = min(scores, key=lambda d: float(per_photo(scores[d][0]["calibrate"], scores[d][1])[1].mean()))
    chosen, temp = scores[decay]
    net = load_network(args.weights, "UprightNet").eval()
    out = {"decay": decay, "temperature": temp, "sets": {}}
    for name in sets:
        if name == "train":
            continue
        shipped = per_photo(view_logits(net, photo_thumbs(sets[name], net.size))[:, :, 0, 0], net.temperature)
        teacher = per_photo(chosen[name], temp)
        rows = {}
        for m, (right, nll) in {"shipped": shipped, "teacher": teacher}.items():
            rows[m] = {"accuracy": float(right.mean()), "nll": float(nll.mean()),
                       "accuracy vs shipped": paired(shipped[0], right), "nll vs shipped": paired(shipped[1], nll)}
        out["sets"][name] = rows
        report(f"{name} ({len(sets[name])} photos), teacher decay {decay}, T {temp:.2f}", rows)
    if args.posteriors:
        torch.save({n: torch.softmax(s / temp, -1) for n, s in chosen.items()}, args.posteriors)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
