"""The line-evidence stage on York Urban's hand-labelled segments: what it keeps, what it drops, its direction
classes, its cost, and (with ``--horizon``) what the parser's horizon does when given only the kept segments.

A detected segment (LSD as the parser runs it, the default :class:`~ngp_kornia.pipeline.settings.SegmentSettings`)
*matches* when at least half of its length lies within 3 px and 3 degrees of hand-labelled segments
(:func:`ngp_kornia.evaluation.lines.match_segments`); the labelled segment covering most of it gives its direction
(the database's vertical VP column: vertical, the other two: horizontal). The stage keeps a segment when its weight
(the sigmoid of its structure logit) is at least ``--keep`` (0.1).

Rows: LSD alone (everything kept), trivial baselines (a length threshold; the shortest segments dropped at the
stage's own drop rate; orientation alone for the direction: vertical when closer to the image's vertical axis than
to its horizontal one) and the stage. Also, before any of it, what is reachable: how many detected segments match,
and how many of the others point at one of the true vanishing points.

Cost: each image's line detection (as the parser runs it, and on one thread) and the stage (one thread), timed in
CPU time interleaved image by image; the stage's time as a ratio to LSD's.

Usage::

    python benchmarks/line_evidence.py ../shared/data/YorkUrbanDB [--weights ngp_kornia/weights/evidence.pt]
        [--horizon --manifest ../shared/data/EurasianCities/manifest.csv --seeds 0,1,2,3,4]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ngp_kornia.api import load_parser
from ngp_kornia.data.yud import YorkUrbanDB, load_labelled_segments
from ngp_kornia.evaluation import (
    estimate_from_calibration,
    evaluate,
    labelled_directions,
    load_manifest,
    load_yud,
    match_segments,
    weights_and_config,
)
from ngp_kornia.geometry import segment_vp_angle
from ngp_kornia.io import read_image_file
from ngp_kornia.nets import LineEvidenceNet, structure_weights
from ngp_kornia.nets.weights import load_network, shipped_weights
from ngp_kornia.pipeline import SegmentSettings
from ngp_kornia.pipeline.segments import detect_segments, line_workers


@dataclass
class Image:
    """One photo: its tensor (1, 3, H, W), LSD segments and mask, the stage's weights (N,) and direction classes,
    and, on York Urban, which segments match (N,), their labelled direction, their angle to the nearest true VP."""

    image: torch.Tensor
    segments: torch.Tensor
    mask: torch.Tensor
    weights: torch.Tensor
    direction: torch.Tensor
    lsd_time: float
    lsd_one_thread: float
    stage_time: float
    matched: torch.Tensor | None = None
    labelled: torch.Tensor | None = None
    vp_angle: torch.Tensor | None = None


def run_stage(path: Path, net: LineEvidenceNet) -> Image:
    """Read one photo, detect its segments (as the parser does, and on one thread) and score them (one torch
    thread), timing each in CPU seconds of the process (all its threads): on a shared machine wall-clock times of a
    few milliseconds mostly measure the other processes."""
    rgb = read_image_file(path)
    t0 = time.process_time()
    segments, mask = detect_segments(rgb, SegmentSettings())
    t1 = time.process_time()
    with line_workers(1):
        detect_segments(rgb, SegmentSettings())
    t2 = time.process_time()
    image = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255.0
    t3 = time.process_time()
    with torch.no_grad():
        structure, direction = net(image, segments, mask)
    t4 = time.process_time()
    return Image(image, segments, mask, structure_weights(structure, mask)[0], direction[0].argmax(-1),
                 t1 - t0, t2 - t1, t4 - t3)


def yud_images(root: Path, net: LineEvidenceNet) -> list[Image]:
    out = []
    for sample in YorkUrbanDB(root, ground_truth="raw"):  # the raw VPs: the ones the segments were labelled with
        im = run_stage(sample.image_path, net)
        seg = im.segments[0][im.mask[0]]
        labelled, vp_index = load_labelled_segments(sample.lines_path)
        matched, best = match_segments(seg, labelled)
        im.matched = matched
        im.labelled = torch.where(matched, labelled_directions(vp_index)[best.clamp_min(0)], -1)
        im.vp_angle = segment_vp_angle(seg[None].double(), sample.vps[None])[0].amin(0)
        out.append(im)
    return out


def reach_table(images: list[Image]) -> list[str]:
    matched = torch.cat([im.matched for im in images])
    angle = torch.cat([im.vp_angle for im in images])
    n = len(images)
    rows = ["| detected segments per image | matched | unmatched | unmatched within 1 / 2 deg of a true VP | "
            "matched within 1 / 2 deg |", "|---:|---:|---:|---:|---:|"]
    um = ~matched
    rows.append(f"| {len(matched) / n:.1f} | {matched.sum().item() / n:.1f} | {um.sum().item() / n:.1f} | "
                f"{100 * (angle[um] <= 1).double().mean():.1f}% / {100 * (angle[um] <= 2).double().mean():.1f}% | "
                f"{100 * (angle[matched] <= 1).double().mean():.1f}% / "
                f"{100 * (angle[matched] <= 2).double().mean():.1f}% |")
    return rows


def _row(name: str, kept: torch.Tensor, matched: torch.Tensor, direction: str) -> str:
    keep = (kept & matched).sum() / matched.sum()
    drop = (~kept & ~matched).sum() / (~matched).sum()
    precision = (kept & matched).sum() / kept.sum().clamp_min(1)
    return (f"| {name} | {100 * keep:.1f}% | {100 * drop:.1f}% | {100 * precision:.1f}% | "
            f"{kept.double().mean() * 100:.1f}% | {direction} |")


def evidence_table(images: list[Image], keep: float) -> list[str]:
    """The targets' terms: kept share of the matched (>= 95%), dropped share of the unmatched (>= 50%), precision,
    and direction-class accuracy on the matched (>= 90%)."""
    matched = torch.cat([im.matched for im in images])
    labelled = torch.cat([im.labelled for im in images])
    weights = torch.cat([im.weights[im.mask[0]] for im in images])
    direction = torch.cat([im.direction[im.mask[0]] for im in images])
    seg = torch.cat([im.segments[0][im.mask[0]] for im in images])
    d = seg[:, 1] - seg[:, 0]
    length = d.norm(dim=-1)
    upright = torch.where(d[:, 1].abs() > d[:, 0].abs(), 0, 1)
    orient = f"{100 * (upright[matched] == labelled[matched]).double().mean():.1f}% (orientation alone)"
    stage = f"{100 * (direction[matched] == labelled[matched]).double().mean():.1f}%"
    kept = weights >= keep
    dropped = 1 - kept.double().mean()
    shortest = length <= torch.quantile(length.double(), dropped).float()
    rows = ["| segments kept | kept of matched | dropped of unmatched | precision (matched of kept) | kept of all | "
            "direction right, of matched |", "|---|---:|---:|---:|---:|---:|",
            _row("LSD alone (all kept)", torch.ones_like(kept), matched, orient)]
    for px in (15, 20, 30):
        rows.append(_row(f"length >= {px} px", length >= px, matched, "n.a."))
    rows.append(_row(f"length: the shortest {100 * dropped:.1f}% dropped (the stage's share)", ~shortest, matched,
                     "n.a."))
    rows.append(_row(f"line evidence, weight >= {keep:g}", kept, matched, stage))
    return rows


def cost_lines(images: list[Image]) -> list[str]:
    stage = sum(im.stage_time for im in images)
    out = []
    for name, times in (("LSD as the parser runs it (its strips side by side)", [im.lsd_time for im in images]),
                        ("LSD on one thread", [im.lsd_one_thread for im in images])):
        per = [im.stage_time / t for im, t in zip(images, times, strict=True)]
        out.append(f"- stage / {name}: {stage / sum(times):.3f} over {len(images)} images (per image median "
                   f"{statistics.median(per):.3f}, max {max(per):.3f}); mean {1000 * sum(times) / len(images):.1f} ms")
    stage_ms = sorted(1000 * im.stage_time for im in images)
    out.append(f"- stage, one thread: mean {statistics.mean(stage_ms):.2f} ms, median {statistics.median(stage_ms):.2f}"
               f" ms, max {stage_ms[-1]:.2f} ms (CPU time)")
    return out


def horizon_runs(sets: dict, images: list[Image], seeds: list[int], keep: float) -> dict[str, dict[str, list]]:
    """Horizon AUC (%) per seed of the default parser on all LSD segments and on the kept ones only, against each
    ground truth of ``sets`` (name -> labelled images, in the order of ``images``)."""
    parser = load_parser(*weights_and_config("default"))
    out = {name: {"LSD": [], "kept": []} for name in sets}
    for seed in seeds:
        for given in ("LSD", "kept"):
            estimates = []
            for im in images:
                mask = im.mask if given == "LSD" else im.mask & (im.weights >= keep)[None]
                with torch.no_grad():
                    result = parser(im.image, im.segments, mask, seed=seed)
                estimates.append(estimate_from_calibration(result[0]))
            for name, samples in sets.items():
                out[name][given].append(100 * evaluate(samples, estimates)["horizon_auc"])
    return out


def horizon_rows(title: str, runs: dict[str, list[float]]) -> list[str]:
    rows = []
    for name, label in (("LSD", "all LSD segments"), ("kept", "only the kept segments")):
        v = runs[name]
        rows.append(f"| {title} | {label} | {statistics.mean(v):.2f} ({min(v):.2f}-{max(v):.2f}) |")
    diff = [k - a for k, a in zip(runs["kept"], runs["LSD"], strict=True)]
    rows.append(f"| {title} | kept minus all, per seed | {statistics.mean(diff):+.2f} "
                f"({min(diff):+.2f} to {max(diff):+.2f}) |")
    return rows


def horizon_table(args: argparse.Namespace, images: list[Image], net: LineEvidenceNet) -> list[str]:
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = ["| data | segments given to the parser | horizon AUC (%) mean (range) over seeds |", "|---|---|---:|"]
    sets = {f"York Urban, {h} horizon": load_yud(args.root, horizon=h) for h in ("published", "calibrated")}
    for name, runs in horizon_runs(sets, images, seeds, args.keep).items():
        rows += horizon_rows(name, runs)
    if args.manifest is not None:
        samples = load_manifest(args.manifest)
        photos = [run_stage(s.image_path, net) for s in samples]
        name = f"{args.manifest.parent.name} ({len(samples)} images)"
        rows += horizon_rows(name, horizon_runs({name: samples}, photos, seeds, args.keep)[name])
    return rows


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", type=Path, help="the York Urban DB folder")
    ap.add_argument("--weights", type=Path, default=shipped_weights("evidence"), help="line-evidence weights file")
    ap.add_argument("--keep", type=float, default=0.1, help="weight at or above which a segment is kept")
    ap.add_argument("--horizon", action="store_true", help="also run the parser on the kept segments")
    ap.add_argument("--manifest", type=Path, default=None, help="a CSV manifest for the horizon check too")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="sampling seeds of the horizon check")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(1)
    net = load_network(args.weights, "LineEvidenceNet")
    first = next(iter(YorkUrbanDB(args.root)))
    run_stage(first.image_path, net)  # warm-up: the first call of a process pays for its set-up
    images = yud_images(args.root, net)
    print(f"York Urban DB: {len(images)} images ({args.root}); weights {args.weights}; torch {torch.__version__}")
    print("\nWhat is reachable:\n")
    print("\n".join(reach_table(images)))
    print("\nThe stage against LSD alone and trivial baselines:\n")
    print("\n".join(evidence_table(images, args.keep)))
    print("\nCost in CPU time, interleaved image by image:\n")
    print("\n".join(cost_lines(images)))
    if args.horizon:
        print(f"\nHorizon check, default weights, seeds {args.seeds}:\n")
        print("\n".join(horizon_table(args, images, net)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
