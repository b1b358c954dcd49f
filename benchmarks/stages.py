"""Where the time of one calibrate() call goes: reading, line detection, the parser after LSD, the whole call.

Usage::

    python benchmarks/stages.py IMAGE [--repeat 20]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from ngp_kornia import calibrate
from ngp_kornia.io import load_image, read_image_file
from ngp_kornia.lines import detect_segments
from ngp_kornia.models import NeuralGeometricParser


def median_ms(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("image")
    p.add_argument("--repeat", type=int, default=20)
    args = p.parse_args()
    image = load_image(args.image)
    parser = NeuralGeometricParser()
    segments, mask = detect_segments(image, max_segments=parser.config.max_segments)
    with torch.no_grad():
        rows = {
            "read + decode": median_ms(lambda: read_image_file(args.image), args.repeat),
            "line detection (LSD)": median_ms(lambda: detect_segments(image), args.repeat),
            "parser after LSD": median_ms(lambda: parser(image, segments, mask), args.repeat),
            "calibrate(path), whole call": median_ms(lambda: calibrate(args.image), args.repeat),
        }
    print(f"median of {args.repeat} calls, torch threads {torch.get_num_threads()}\n")
    print("| stage | ms |\n|---|---|")
    for name, ms in rows.items():
        print(f"| {name} | {ms:.1f} |")


if __name__ == "__main__":
    main()
