"""Throughput of the procedural renderer, alone and followed by OpenCV's LSD, per CPU core.

One process, one thread (OpenCV, torch and the BLAS / OpenMP pools are limited to one thread), ``--count`` scenes
rendered with :func:`ngp_kornia.training.synth.render.render_scene` from fixed seeds (derived from ``(--seed, i)``
exactly as :func:`ngp_kornia.training.synth.render.render_dataset` does: the scenes of ``ngp render --seed S``),
at each size. For every scene it times ``render_scene`` and then the greyscale conversion plus
:func:`ngp_kornia.pipeline.segments.detect_segments_gray` on the rendered image (the line detection the training
data needs).

Usage::

    python benchmarks/render_speed.py [--count 200] [--seed 0] [--sizes 320x240,640x480]

Prints a markdown table of samples / s and ms / sample, by scene kind and overall. Wall-clock timings: other jobs
running on the machine slow them down; the load average is printed with the table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy / torch / cv2 are imported

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from ngp_kornia.pipeline.segments import detect_segments_gray  # noqa: E402
from ngp_kornia.training.synth.render import KINDS, render_scene  # noqa: E402


def scene_seed(seed: int, i: int) -> int:
    """The seed of image ``i`` of a dataset written by ``render_dataset(..., seed=seed)``."""
    return int(np.random.SeedSequence([int(seed), i]).generate_state(1)[0] >> 1)


def time_size(size: tuple[int, int], seeds: list[int]) -> list[dict]:
    """Per-scene timings (seconds) at one size, after one untimed warm-up scene."""
    warm = render_scene(seeds[0], size)
    detect_segments_gray(cv2.cvtColor(warm.image, cv2.COLOR_RGB2GRAY))
    rows = []
    for s in seeds:
        t0 = time.perf_counter()
        scene = render_scene(s, size)
        t1 = time.perf_counter()
        segments = detect_segments_gray(cv2.cvtColor(scene.image, cv2.COLOR_RGB2GRAY))
        t2 = time.perf_counter()
        rows.append({"kind": scene.kind, "render": t1 - t0, "lsd": t2 - t1, "segments": len(segments)})
    return rows


def _cells(times: list[float]) -> str:
    total = sum(times)
    return f"{len(times) / total:.1f} | {1000 * total / len(times):.1f}"


def markdown(results: dict[str, list[dict]]) -> str:
    lines = [
        "| size | scenes | n | render: samples/s | render: ms/sample | render + LSD: samples/s "
        "| render + LSD: ms/sample | LSD segments / image |",
        "|" + "---|" * 8,
    ]
    for size, rows in results.items():
        groups = [(k, [r for r in rows if r["kind"] == k]) for k in KINDS] + [("all", rows)]
        for kind, g in groups:
            if not g:
                continue
            render = [r["render"] for r in g]
            both = [r["render"] + r["lsd"] for r in g]
            segs = np.mean([r["segments"] for r in g])
            name = f"**{kind}**" if kind == "all" else kind
            lines.append(f"| {size} | {name} | {len(g)} | {_cells(render)} | {_cells(both)} | {segs:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=200, help="scenes per size")
    parser.add_argument("--seed", type=int, default=0, help="dataset seed the scene seeds derive from")
    parser.add_argument("--sizes", default="320x240,640x480", help="comma-separated WxH sizes")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("--count must be positive")
    sizes = []
    for text in args.sizes.split(","):
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            parser.error(f"sizes must look like 640x480, got {text!r}")
        sizes.append((w, h))

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    seeds = [scene_seed(args.seed, i) for i in range(args.count)]
    load_before = os.getloadavg()
    results = {f"{w}x{h}": time_size((w, h), seeds) for w, h in sizes}
    load_after = os.getloadavg()

    print(
        f"render_scene throughput, one process, one thread; {args.count} scenes per size (seeds of "
        f"`ngp render --seed {args.seed}`); python {platform.python_version()}, opencv {cv2.__version__}, "
        f"torch {torch.__version__}"
    )
    print(
        f"machine: {os.cpu_count()} CPUs, load average (1 min) {load_before[0]:.2f} before / {load_after[0]:.2f} "
        "after (other jobs running on the machine slow these wall-clock timings)"
    )
    print()
    print(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
