"""Where the time of calibrate() goes, how many images per second a batch reaches, and the peak memory of the CLI.

Usage::

    python benchmarks/stages.py IMAGE [--weights full] [--repeat 20] [--batches 1 8 32] [--no-lu] [--no-memory]

1. Seconds per image of one ``calibrate(path)`` call and of its stages, and, in the same run and interleaved
   call by call, lu-vp-detect on the same file (given a focal length of half the image width plus height, as a
   stand-in: its cost does not depend on it). Stages: reading the file, line detection (LSD), candidate sampling
   and Manhattan scores, ZSNet, FSNet (its inputs and the network, separately) and the rest (top-k average and
   the result). Stage times come from timers around the parser's parts in the same calls as the whole time.
2. Throughput of ``calibrate(batch)`` on (B, 3, H, W) tensors made of copies of the image, for each batch size:
   images per second, including line detection.
3. Peak resident memory of ``ngp calibrate IMAGE`` in a fresh process (``/usr/bin/time -v``, or the
   ``resource`` module's figure for a child process where that is missing).

Times are medians over ``--repeat`` calls after a warm-up, with torch's thread count as it is; the load average
is printed, since other jobs on the machine slow every figure.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import resource
import shutil
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import torch

from ngp_kornia import calibrate
from ngp_kornia.api import load_parser
from ngp_kornia.evaluation import LabelledImage, lu_vp_detect_method
from ngp_kornia.geometry import intrinsics_matrix
from ngp_kornia.io import load_image


class StageTimer:
    """Accumulates wall time of the parser's parts by wrapping its methods and its networks' forward calls."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, owner, name: str, label: str) -> None:
        inner = getattr(owner, name)

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds[label] += time.perf_counter() - start

        setattr(owner, name, timed)

    def take(self) -> dict[str, float]:
        out, self.seconds = dict(self.seconds), defaultdict(float)
        return out


def instrument(parser) -> StageTimer:
    timer = StageTimer()
    timer.wrap(parser, "score_frames", "sampling + Manhattan score")
    timer.wrap(parser, "rescore_frames", "FSNet")
    timer.wrap(parser, "calibrate_from_frames", "top-k + result")
    if parser.zsnet is not None:
        timer.wrap(parser.zsnet, "forward", "ZSNet")
    if parser.fsnet is not None:
        timer.wrap(parser.fsnet, "prepare_inputs", "FSNet inputs")
        timer.wrap(parser.fsnet, "forward", "FSNet network")
    return timer


def stage_table(image: str, weights: str, repeat: int, with_lu: bool) -> str:
    import ngp_kornia.api as api
    import ngp_kornia.pipeline.segments as lines

    parser = load_parser(weights)
    timer = instrument(parser)
    original_parser = api._parser
    api._parser = lambda *a, **k: parser  # calibrate() uses the instrumented parser (and its config's seed)
    detect = lines.detect_segments_gray
    lsd = StageTimer()
    lines.detect_segments_gray = lambda *a, **k: _timed(lsd, "line detection (LSD)", detect, *a, **k)
    rows: dict[str, list[float]] = defaultdict(list)
    lu = _lu_runner(image) if with_lu else None
    try:
        for i in range(repeat + 1):
            order = [_run_ngp, _run_lu] if i % 2 == 0 else [_run_lu, _run_ngp]
            for fn in order:
                fn(image, weights, timer, lsd, lu, rows, keep=i > 0)
    finally:
        api._parser = original_parser
        lines.detect_segments_gray = detect
    lines_out = [f"| stage ({weights}) | ms per image |", "|---|---:|"]
    for name, values in rows.items():
        lines_out.append(f"| {name} | {1000 * statistics.median(values):.1f} |")
    return "\n".join(lines_out)


def _timed(timer: StageTimer, label: str, fn, *args, **kwargs):
    start = time.perf_counter()
    try:
        return fn(*args, **kwargs)
    finally:
        timer.seconds[label] += time.perf_counter() - start


def _run_ngp(image, weights, timer, lsd, lu, rows, keep):
    timer.take(), lsd.take()
    start = time.perf_counter()
    calibrate(image, weights=weights)
    total = time.perf_counter() - start
    if not keep:
        return
    stages = {**lsd.take(), **timer.take()}
    if "FSNet" in stages:  # report the FSNet total as its two parts
        stages["FSNet other"] = stages.pop("FSNet") - stages.get("FSNet inputs", 0) - stages.get("FSNet network", 0)
    if "ZSNet" in stages:
        stages["sampling + Manhattan score"] -= stages["ZSNet"]
    rows["calibrate(path), whole call"].append(total)
    for name, seconds in stages.items():
        rows[f"  {name}"].append(seconds)
    rows["  reading + the rest"].append(total - sum(stages.values()))


def _run_lu(image, weights, timer, lsd, lu, rows, keep):
    if lu is None:
        return
    start = time.perf_counter()
    lu()
    if keep:
        rows["lu-vp-detect, whole call"].append(time.perf_counter() - start)


def _lu_runner(image: str):
    img = load_image(image)
    h, w = img.shape[-2:]
    f = torch.tensor([(h + w) / 2.0], dtype=torch.float64)
    K = intrinsics_matrix(f, torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], dtype=torch.float64))[0]
    labelled = LabelledImage("x", Path(image), h, w, K=K)
    run = lu_vp_detect_method()
    return lambda: run(labelled)


def throughput_table(image: str, weights: str, batches: list[int], repeat: int) -> str:
    one = load_image(image)
    rows = [f"| batch ({weights}) | images / s | s per batch |", "|---:|---:|---:|"]
    for b in batches:
        batch = one.expand(b, -1, -1, -1).contiguous()
        calibrate(batch, weights=weights)  # warm-up
        times = []
        for _ in range(max(1, repeat // b)):
            start = time.perf_counter()
            calibrate(batch, weights=weights)
            times.append(time.perf_counter() - start)
        t = statistics.median(times)
        rows.append(f"| {b} | {b / t:.1f} | {t:.3f} |")
    return "\n".join(rows)


def peak_memory_mb(image: str, weights: str) -> float:
    ngp = Path(sys.executable).with_name("ngp")
    cmd = [str(ngp), "calibrate", image, "--weights", weights]
    gnu_time = shutil.which("time") or ("/usr/bin/time" if Path("/usr/bin/time").exists() else None)
    if gnu_time:
        out = subprocess.run([gnu_time, "-v", *cmd], capture_output=True, text=True, check=True)
        kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
        return kb / 1024
    subprocess.run(cmd, capture_output=True, check=True)
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("image")
    p.add_argument("--weights", action="append", default=None, help="weight sets to time (default: default)")
    p.add_argument("--repeat", type=int, default=20)
    p.add_argument("--batches", type=int, nargs="*", default=[1, 8, 32])
    p.add_argument("--no-lu", action="store_true")
    p.add_argument("--no-memory", action="store_true")
    args = p.parse_args()
    load = os.getloadavg()[0]
    machine = platform.processor() or platform.machine()
    print(f"{machine}, {os.cpu_count()} CPUs, torch {torch.__version__}, torch threads {torch.get_num_threads()}")
    print(f"load average (1 min) before: {load:.2f}\n")
    for weights in args.weights or ["default"]:
        print(stage_table(args.image, weights, args.repeat, not args.no_lu), "\n")
        if args.batches:
            print(throughput_table(args.image, weights, args.batches, args.repeat), "\n")
        if not args.no_memory:
            mb = peak_memory_mb(args.image, weights)
            print(f"peak memory of `ngp calibrate IMAGE --weights {weights}`: {mb:.0f} MB\n")
    print(f"load average (1 min) after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
