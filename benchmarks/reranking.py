"""How much a frame re-ranker (FSNet's job) could win: the horizon AUC of the top-1 frame by Manhattan score, of the
best frame among the top K (chosen with the ground truth: an upper bound), and of the top-1 under other kernel
widths of the Manhattan score.

Usage::

    python benchmarks/reranking.py yud /path/to/YorkUrbanDB [--top 16 64] [--kernels 85 88 89 89.5]
    python benchmarks/reranking.py rendered /path/to/render_dir

Frames come from the untrained path (``weights="none"``, seed 0) on the LSD segments ``calibrate()`` uses. The
horizon error of a frame is the one of the metrics (border distances over the image height). Also reported: how
many images have a top-1 error above 0.05 image heights, and for how many of those some frame of the top K is
within 0.02, i.e. how many gross failures a perfect re-ranker could repair.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from ngp_kornia.api import load_parser
from ngp_kornia.evaluation import load_renders, load_yud
from ngp_kornia.geometry import frame_manhattan_scores, segment_lengths
from ngp_kornia.geometry.frames import select_frames, top_frames
from ngp_kornia.io import load_image
from ngp_kornia.metrics import frame_horizon_error, horizon_auc


def image_rows(sample, parser, tops: list[int], kernels: list[float]) -> dict[str, float]:
    image = load_image(sample.image_path)
    h, w = image.shape[-2:]
    with torch.no_grad():
        _, t = parser(image, return_trace=True)
        kept = select_frames(t.frames, top_frames(t.frames, t.manhattan, max(tops)))
        errors = frame_horizon_error(kept, sample.horizon[None].float(), h, w)[0]
        row = {"top-1 by m (89 deg)": float(errors[0])}
        for k in tops:
            row[f"best of top {k} (oracle)"] = float(errors[:k].min())
        lengths = segment_lengths(t.segments) * t.mask
        first = select_frames(kept, torch.arange(min(tops), device=errors.device)[None])
        for angle in kernels:
            score = frame_manhattan_scores(t.lines, first.vps, lengths, t.mask, angle)[0]
            score = torch.where(first.valid[0], score, torch.full_like(score, -1.0))
            row[f"top-1 of top {min(tops)} by m at {angle:g} deg"] = float(errors[score.argmax()])
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", choices=["yud", "rendered"])
    p.add_argument("root", type=Path)
    p.add_argument("--top", type=int, nargs="+", default=[16, 64])
    p.add_argument("--kernels", type=float, nargs="*", default=[85.0, 88.0, 89.5])
    args = p.parse_args()
    samples = load_yud(args.root) if args.dataset == "yud" else load_renders(args.root)
    parser = load_parser("none")
    rows = [image_rows(s, parser, sorted(args.top), args.kernels) for s in samples]
    print(f"{args.dataset}: {len(rows)} images (frames of the untrained path, seed 0)\n")
    print("| frame chosen | horizon AUC (%) |\n|---|---:|")
    for key in rows[0]:
        print(f"| {key} | {100 * float(horizon_auc(torch.tensor([r[key] for r in rows]))):.2f} |")
    gross = [r for r in rows if r["top-1 by m (89 deg)"] > 0.05]
    k = min(args.top)
    fixable = sum(r[f"best of top {k} (oracle)"] < 0.02 for r in gross)
    print(
        f"\n{len(gross)} images with a top-1 error above 0.05; {fixable} of them have a frame within 0.02 in top {k}"
    )


if __name__ == "__main__":
    main()
