"""The orientation check read in several views of one thumbnail: does averaging the network's readings of the
thumbnail turned four ways (and mirrored) read the turn of real photos better than one reading?

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_views.py --photos ../shared/data/RealPhotos \\
        --yud ../shared/data/YorkUrbanDB --manifest ../shared/data/EurasianCities/manifest.csv \\
        [--weights ngp_kornia/weights/upright.pt] [--cache views.pt] [--json out.json]

A view of a thumbnail turned by k quarter turns is the thumbnail turned by r more and, for a mirrored view,
flipped left to right: the view is turned by k + r, or by -(k + r) when mirrored (a mirror image of an upright photo
is upright, of a photo turned by 90 degrees one turned by 270). Each view's reading is mapped back to the turns of
the thumbnail itself and the views' log-probabilities are averaged (``log``) or their probabilities (``prob``);
the temperature of each method is fitted on the ``calibrate`` part of the photo folder
(:mod:`ngp_kornia.data.photo_split`) and applied everywhere else. Each photo is read in its four turns. Reported per
set: the share whose likeliest of the four turns is right and the mean negative log-likelihood of the true turn,
then each method paired per photo against the single reading (mean difference of the per-photo figure over its
four turns, 95% bootstrap interval over photos, and the difference on the even and odd halves of the photos).
The thumbnail of a turned image is the turned thumbnail (an average over square cells is the same either way), so
each photo is read once and its thumbnail turned.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.evaluation.datasets import load_manifest, load_yud
from ngp_kornia.io import read_image_file
from ngp_kornia.nets.upright import thumbnail
from ngp_kornia.nets.weights import load_network
from ngp_kornia.training.upright_calibration import fit_temperature

#: the views: (quarter turns added, mirrored)
VIEWS = {"one": [(0, False)], "turns4": [(r, False) for r in range(4)],
         "turns4+mirror": [(r, m) for m in (False, True) for r in range(4)]}  # fmt: skip


def photo_thumbs(paths: list[str], size: int) -> torch.Tensor:
    """(N, 3, size, size) thumbnails of the upright photos."""
    out = []
    for path in paths:
        rgb = torch.from_numpy(np.ascontiguousarray(read_image_file(path))).permute(2, 0, 1)[None] / 255.0
        out.append(thumbnail(rgb, size)[0])
    return torch.stack(out)


def sets_of(args: argparse.Namespace) -> dict[str, list[str]]:
    sets = {part: [f"{args.photos}/{n}" for n in split_photos(args.photos, part)] for part in ("calibrate", "test")}
    if args.yud:
        sets["York Urban"] = [str(x.image_path) for x in load_yud(args.yud)]
    if args.manifest:
        sets["Eurasian Cities"] = [str(x.image_path) for x in load_manifest(args.manifest)]
    return sets


@torch.no_grad()
def view_logits(net, thumbs: torch.Tensor) -> torch.Tensor:
    """(N, 4 turns, 4 rotations, 2 mirrors, 5) logits of every view of every turn of every thumbnail, each view's
    reading already mapped back to the classes of the turned thumbnail it was made from."""
    out = torch.zeros(len(thumbs), 4, 4, 2, 5)
    for k in range(4):
        x = torch.rot90(thumbs, k, dims=(-2, -1))
        for r in range(4):
            for m in (False, True):
                v = torch.rot90(x, r, dims=(-2, -1))
                v = v.flip(-1) if m else v
                logits = net(v)
                # the view is turned by j = k + r (mirrored: -(k + r)); the turned thumbnail's turn t reads j
                t = torch.arange(4)
                j = (-(t + r)) % 4 if m else (t + r) % 4
                out[:, k, r, int(m), :4] = logits[:, j]
                out[:, k, r, int(m), 4] = logits[:, 4]
    return out


def combine(logits: torch.Tensor, views: list[tuple[int, bool]], how: str) -> torch.Tensor:
    """(N, 4, 5) log-scores of each turned thumbnail from its views (log-probabilities averaged, or the log of the
    averaged probabilities); a temperature divides them like logits."""
    picked = torch.stack([logits[:, :, r, int(m)] for r, m in views], 2)
    logp = torch.log_softmax(picked, -1)
    if how == "log" or len(views) == 1:
        return logp.mean(2)
    return torch.logsumexp(logp, 2) - math.log(len(views))


def per_photo(scores: torch.Tensor, temperature: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Per photo, from (N, 4, >= 4) scores of its four turns: the share of its turns whose likeliest turn is right,
    and the mean NLL of the true turn."""
    logp = torch.log_softmax(scores[..., :4] / temperature, -1)
    turns = torch.arange(4)
    right = (logp.argmax(-1) == turns).double().mean(1)
    nll = -logp[:, turns, turns].double().mean(1)
    return right, nll


def paired(a: torch.Tensor, b: torch.Tensor, draws: int = 4000, seed: int = 0) -> dict:
    """Mean of b - a with a 95% bootstrap interval over photos, and on the even and odd halves."""
    d = (b - a).numpy()
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), (draws, len(d)))].mean(1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return {"mean": float(d.mean()), "lo": float(lo), "hi": float(hi),
            "even": float(d[0::2].mean()), "odd": float(d[1::2].mean())}  # fmt: skip


def time_views(net, count: int, repeats: int = 200) -> float:
    """Milliseconds per reading of ``count`` views in one batched forward (one thread)."""
    x = torch.rand(count, 3, net.size, net.size)
    with torch.no_grad():
        for _ in range(20):
            net(x)
        start = time.perf_counter()
        for _ in range(repeats):
            net(x)
    return (time.perf_counter() - start) / repeats * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", required=True, help="the folder of upright photos (its calibrate and test parts)")
    ap.add_argument("--yud", help="York Urban DB folder (reported on, never chosen on)")
    ap.add_argument("--manifest", help="Eurasian Cities manifest.csv (reported on, never chosen on)")
    ap.add_argument("--weights", default="ngp_kornia/weights/upright.pt", help="an UprightNet weights file")
    ap.add_argument("--against", help="pair against this network's single reading instead (its own temperature)")
    ap.add_argument("--cache", help="a file to keep the thumbnails in (read if it exists)")
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    net = load_network(args.weights, "UprightNet").eval()
    sets = sets_of(args)
    if args.cache and Path(args.cache).exists():
        thumbs = torch.load(args.cache)
    else:
        thumbs = {name: photo_thumbs(paths, net.size) for name, paths in sets.items()}
        if args.cache:
            torch.save(thumbs, args.cache)
    logits = {name: view_logits(net, t) for name, t in thumbs.items()}
    methods = {"one": ("one", "log")}
    methods |= {f"{v} {h}": (v, h) for v in ("turns4", "turns4+mirror") for h in ("log", "prob")}
    out = {"ms": {n: time_views(net, n) for n in (1, 4, 8)}, "sets": {}}
    print("ms per batched reading (1 thread):", {k: round(v, 3) for k, v in out["ms"].items()})
    temps = {}
    for m, (v, h) in methods.items():
        cal = combine(logits["calibrate"], VIEWS[v], h)
        temps[m] = fit_temperature(cal.reshape(-1, 5), torch.arange(4).repeat(len(cal)))
    out["temperature"] = temps
    against = None if args.against is None else load_network(args.against, "UprightNet").eval()
    for name, lg in logits.items():
        base = per_photo(combine(lg, VIEWS["one"], "log"), temps["one"])
        if against is not None:
            base = per_photo(view_logits(against, thumbs[name])[:, :, 0, 0], against.temperature)
        rows = {}
        for m, (v, h) in methods.items():
            right, nll = per_photo(combine(lg, VIEWS[v], h), temps[m])
            rows[m] = {"accuracy": float(right.mean()), "nll": float(nll.mean()),
                       "accuracy vs one": paired(base[0], right), "nll vs one": paired(base[1], nll)}  # fmt: skip
        out["sets"][name] = rows
        if against is not None:
            right, nll = float(base[0].mean()), float(base[1].mean())
            print(f"\n{name}: {args.against}, one reading: {100 * right:.1f}%, NLL {nll:.3f}")
        print(f"\n{name} ({len(lg)} photos)\n| method | T | turn right | NLL | paired turn right | paired NLL |")
        print("|---|---:|---:|---:|---|---|")
        for m, r in rows.items():
            a, n = r["accuracy vs one"], r["nll vs one"]
            print(f"| {m} | {temps[m]:.2f} | {100 * r['accuracy']:.1f}% | {r['nll']:.3f} | "
                  f"{100 * a['mean']:+.1f} ({100 * a['lo']:+.1f}..{100 * a['hi']:+.1f}; halves {100 * a['even']:+.1f}"
                  f" / {100 * a['odd']:+.1f}) | {n['mean']:+.3f} ({n['lo']:+.3f}..{n['hi']:+.3f}) |")  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
