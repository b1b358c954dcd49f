"""Cache what the line-segment orientation study reads: each photo's detected segments (the package's LSD, default
settings, on the upright photo) and the shipped orientation network's logits of its four turns.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_lines_cache.py --photos ../shared/data/RealPhotos \\
        --yud ../shared/data/YorkUrbanDB --manifest ../shared/data/EurasianCities/manifest.csv \\
        --nyu ../shared/data/NYU-VP --out lines_cache.pt

Sets: ``RealPhotos`` train / calibrate / test parts (:mod:`ngp_kornia.data.photo_split`), York Urban, Eurasian
Cities (segments and logits), NYU-VP 0000-0999 and 1000-1223 (the given LSD segments, filtered as the package
filters its own: at least 10 px, the 512 longest; no pixels, so no logits). Per set: ``segments`` a list of (N, 2, 2)
float32 arrays in the upright photo's pixels, ``size`` (P, 2) height and width, ``logits`` (P, 4, 5) the network's
logits of the thumbnail turned by k quarter turns (``np.rot90``'s sense), ``names``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from ngp_kornia.data.nyu import NYUVP, TRAIN_SCENES, VALIDATION_SCENES
from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.evaluation.datasets import load_manifest, load_yud
from ngp_kornia.io import read_image_file
from ngp_kornia.nets.upright import thumbnail
from ngp_kornia.nets.weights import load_network
from ngp_kornia.pipeline.segments import detect_segments, longest_segments
from ngp_kornia.pipeline.settings import SegmentSettings


@torch.no_grad()
def photo_set(paths: list[str], net) -> dict:
    segs, sizes, logits = [], [], []
    for path in paths:
        rgb = read_image_file(path)
        seg, mask = detect_segments(rgb)
        segs.append(seg[0][mask[0]].numpy().astype(np.float32))
        sizes.append(rgb.shape[:2])
        image = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None] / 255.0
        thumb = thumbnail(image, net.size)
        logits.append(torch.cat([net(torch.rot90(thumb, k, dims=(-2, -1))) for k in range(4)]))
    return {"names": paths, "segments": segs, "size": torch.tensor(sizes), "logits": torch.stack(logits)}


def nyu_set(root: str, scenes: range) -> dict:
    settings = SegmentSettings()
    segs = []
    for s in NYUVP(root, scenes):
        seg = longest_segments(s.segments.numpy(), settings.min_length, settings.max_segments)
        segs.append(seg.astype(np.float32))
    return {"names": [f"nyu-{i:04d}" for i in scenes], "segments": segs,
            "size": torch.tensor([[480, 640]] * len(segs))}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", required=True)
    ap.add_argument("--yud", required=True)
    ap.add_argument("--manifest", required=True)
    ap.add_argument("--nyu", required=True)
    ap.add_argument("--weights", default="ngp_kornia/weights/upright.pt")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    torch.set_num_threads(1)
    net = load_network(args.weights, "UprightNet").eval()
    paths = {part: [f"{args.photos}/{n}" for n in split_photos(args.photos, part)]
             for part in ("train", "calibrate", "test")}  # fmt: skip
    paths["yud"] = [str(x.image_path) for x in load_yud(args.yud)]
    paths["ecd"] = [str(x.image_path) for x in load_manifest(args.manifest)]
    out = {"temperature": net.temperature}
    for name, p in paths.items():
        start = time.perf_counter()
        out[name] = photo_set(p, net)
        print(f"{name}: {len(p)} photos, {time.perf_counter() - start:.0f} s", flush=True)
    for name, scenes in (("nyu_train", TRAIN_SCENES), ("nyu_val", VALIDATION_SCENES)):
        start = time.perf_counter()
        out[name] = nyu_set(args.nyu, scenes)
        print(f"{name}: {len(scenes)} scenes, {time.perf_counter() - start:.0f} s", flush=True)
    torch.save(out, args.out)


if __name__ == "__main__":
    main()
