"""Zenith estimates of the parser's first stage (the paper's Table 3 / ZSNet rows of Table 4).

For every image: LSD segments, zenith candidates sampled exactly as ``calibrate()`` samples them, and the zenith
estimate z_est (dominant eigenvector of the weighted structure tensor, Eq. 10-12) with the candidates weighted

* uniformly (the untrained geometric path),
* by each ZSNet weights file given with ``--zsnet`` (e.g. the shipped one and an ablation),

scored as the angle between the estimated and the true up directions, using the true focal length. The peer
lu-vp-detect (given the true focal length) is scored the same way on York Urban.

Usage::

    python benchmarks/zenith.py rendered --count 500 --zsnet ngp_kornia/weights/zsnet.pt
    python benchmarks/zenith.py yud /path/to/YorkUrbanDB --zsnet ngp_kornia/weights/zsnet.pt
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import cv2
import numpy as np
import torch

from ngp_kornia.data.yud import YorkUrbanDB
from ngp_kornia.evaluation import LabelledImage, load_yud, lu_vp_detect_method
from ngp_kornia.geometry import homogeneous_to_pseudo_camera, pseudo_focal
from ngp_kornia.metrics import zenith_error_deg
from ngp_kornia.nets.weights import load_network
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.segments import detect_segments, detect_segments_gray
from ngp_kornia.training.synth.render import render_scene

#: the seeds of the rendered test split of ``ngp-train``'s RenderedDataModule (scene i is ``render_scene(seed + i)``)
TEST_SEED = 2_000_000
SIZE = (640, 480)


def samples_rendered(count: int):
    """(segments, K, zenith, height, width) of the fixed rendered test set (the training DataModule's test scenes,
    with its line detection: working size 640, segments of at least 10 px, the 512 longest)."""
    for seed in range(TEST_SEED, TEST_SEED + count):
        scene = render_scene(seed, SIZE)
        gray = cv2.cvtColor(scene.image, cv2.COLOR_RGB2GRAY)
        segments = detect_segments_gray(gray, ParserConfig())
        yield segments, torch.as_tensor(scene.K), torch.as_tensor(scene.zenith), SIZE[1], SIZE[0]


#: York Urban's segments: the parser's settings but 1,024 segments (not 512), as the figures in BENCHMARKS.md
YUD_DETECTION = ParserConfig(max_segments=1024)


def samples_yud(root: str):
    for s in YorkUrbanDB(root):
        yield detect_segments(s.image_path, YUD_DETECTION)[0][0], s.K, s.zenith, s.height, s.width


def zenith_errors(parsers: dict[str, NeuralGeometricParser], segments: np.ndarray, K, zenith, height, width):
    """Error (degrees) of each parser's zenith estimate z_est (from its trace) on one image."""
    seg = torch.as_tensor(segments, dtype=torch.float32)[None]
    mask = torch.ones(seg.shape[:2], dtype=torch.bool)
    blank = torch.zeros(1, 3, height, width)  # the parsers have no FSNet: only the segments matter
    gt = homogeneous_to_pseudo_camera(torch.as_tensor(zenith, dtype=torch.float32)[None], height, width)
    focal = torch.tensor([float(K[0, 0]) / pseudo_focal(height, width)])
    out = {}
    with torch.no_grad():
        for name, parser in parsers.items():
            _, trace = parser(blank, seg, mask, return_trace=True)
            out[name] = float(zenith_error_deg(trace.zenith_estimate, gt, focal)[0])
    return out


def lu_errors(images) -> list[float]:
    """Up-direction error (degrees) of lu-vp-detect given the true focal; ``images`` are LabelledImages."""
    run = lu_vp_detect_method()
    errors = []
    for image in images:
        up = run(image).up
        cos = float(torch.dot(up, image.up).abs().clamp(max=1.0))
        errors.append(float(np.degrees(np.arccos(cos))))
    return errors


def rendered_files(count: int, folder: Path):
    """The rendered test scenes written as PNG files, for the peer that reads files."""
    folder.mkdir(parents=True, exist_ok=True)
    for seed in range(TEST_SEED, TEST_SEED + count):
        scene = render_scene(seed, SIZE)
        path = folder / f"{seed}.png"
        if not path.exists():
            cv2.imwrite(str(path), cv2.cvtColor(scene.image, cv2.COLOR_RGB2BGR))
        K = torch.as_tensor(scene.K, dtype=torch.float64)
        up = -torch.as_tensor(scene.R, dtype=torch.float64)[:, 1]
        yield LabelledImage(str(seed), path, SIZE[1], SIZE[0], K=K, up=up)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", choices=["rendered", "yud"])
    p.add_argument("root", nargs="?", help="York Urban DB folder (yud)")
    p.add_argument("--count", type=int, default=500, help="rendered test images")
    p.add_argument("--zsnet", action="append", default=[], help="ZSNet weights file (repeatable)")
    p.add_argument("--lu-dir", help="rendered: also score lu-vp-detect, writing the test images to this folder")
    args = p.parse_args()
    parsers = {"uniform (untrained)": NeuralGeometricParser()}
    for path in args.zsnet:
        parsers[f"ZSNet {Path(path).name}"] = NeuralGeometricParser(zsnet=load_network(path, "ZSNet"))
    source = samples_rendered(args.count) if args.dataset == "rendered" else samples_yud(args.root)
    errors: dict[str, list[float]] = {name: [] for name in parsers}
    for sample in source:
        for name, e in zenith_errors(parsers, *sample).items():
            errors[name].append(e)
    if args.dataset == "yud":
        errors["lu-vp-detect (true focal)"] = lu_errors(load_yud(args.root))
    elif args.lu_dir:
        errors["lu-vp-detect (true focal)"] = lu_errors(rendered_files(args.count, Path(args.lu_dir)))
    n = len(next(iter(errors.values())))
    print(f"zenith (up direction) error in degrees, {args.dataset}, {n} images\n")
    print("| zenith estimate | mean | median |\n|---|---|---|")
    for name, e in errors.items():
        print(f"| {name} | {statistics.mean(e):.2f} | {statistics.median(e):.2f} |")


if __name__ == "__main__":
    main()
