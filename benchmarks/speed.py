"""calibrate() against lu-vp-detect on York Urban photos, on a quiet machine and beside busy processes.

Usage::

    python benchmarks/speed.py --yud /path/to/YorkUrbanDB [--split train] [--limit N] [--busy 0 1 2]
                               [--weights default --weights none] [--passes 1] [--out speed.json]
    python benchmarks/speed.py --manifest /path/to/EurasianCities/manifest.csv --weights default \
                               --weights default:working_size=640 --busy 0

``--manifest`` times the photos of a CSV manifest instead (lu-vp-detect is then given a focal length of half the
image's width plus height where the manifest has none: its cost does not depend on it). Weight sets take overrides
of the parser's settings, as in the development suite (``default:working_size=640``).

For each condition (0, 1 and 2 busy background processes: plain Python loops this script starts before the timed
calls and kills afterwards, each bounded to ``--busy-seconds`` in case the script dies), every image is calibrated
by each ``--weights`` set and by lu-vp-detect (given the true focal length and principal point), interleaved image
by image in this one process, the order rotating from image to image, after one warm-up call of each. Every call
reads the file itself.

Printed (and written as JSON with ``--out``): per method the mean and median ms per image and the ratio of the
means to lu-vp-detect's in the same condition; per weight set the stages of the call (reading and decoding the file,
line detection, the rest), and the whole call over the line detection alone. A further row, "LSD alone", times
the line detector by itself as a single-threaded call would run it (the whole working image, one strip, on the
decoded greyscale image; decoding not timed), interleaved with the others: the floor a calibration call on one
core cannot go below. The whole call of each weight set over it is printed below the table.

The thread count is left as the environment sets it (run it without ``OMP_NUM_THREADS`` to see what users get);
the load average before and after each condition is printed, since other jobs on the machine slow every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import cv2
import torch

import ngp_kornia.pipeline.runner as runner
from ngp_kornia import calibrate
from ngp_kornia.evaluation import load_manifest, load_yud
from ngp_kornia.evaluation import lu_vp_detect_method as make_lu
from ngp_kornia.evaluation.methods import weights_and_config
from ngp_kornia.io import read_rgb_oriented
from ngp_kornia.pipeline import SegmentSettings
from ngp_kornia.pipeline.segments import detect_segments_gray

_BUSY = "import time\nend = time.time() + {seconds}\nwhile time.time() < end:\n    pass\n"


class _Timer:
    """Wall time of one function, accumulated until taken."""

    def __init__(self) -> None:
        self.total = 0.0

    def wrap(self, fn):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.total += time.perf_counter() - start

        return timed

    def take(self) -> float:
        out, self.total = self.total, 0.0
        return out


def start_busy(count: int, seconds: float) -> list[subprocess.Popen]:
    """``count`` processes that each keep one core busy for at most ``seconds``."""
    return [
        subprocess.Popen([sys.executable, "-c", _BUSY.format(seconds=seconds)], stdin=subprocess.DEVNULL)
        for _ in range(count)
    ]


def stop_busy(procs: list[subprocess.Popen]) -> None:
    for proc in procs:
        proc.kill()
    for proc in procs:
        proc.wait()


FLOOR = "LSD alone"


def lsd_alone():
    """The line detector by itself on the whole working image in one strip (decoding done before the timer)."""
    grays: dict[Path, object] = {}
    config = SegmentSettings(line_strips=1)

    def call(sample):
        if sample.image_path not in grays:
            rgb = read_rgb_oriented(sample.image_path)[0]
            grays[sample.image_path] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        start = time.perf_counter()
        detect_segments_gray(grays[sample.image_path], config)
        return {"whole call": time.perf_counter() - start}

    return call


def run_condition(samples, weights: list[str], lu, passes: int, floor: bool = True) -> dict[str, dict]:
    """Per method, per stage, the seconds of every call (methods interleaved image by image)."""
    read, lsd = _Timer(), _Timer()
    original = runner.read_rgb_oriented, runner.detect_segments  # where calibrate() reads files and finds lines
    runner.read_rgb_oriented, runner.detect_segments = read.wrap(original[0]), lsd.wrap(original[1])
    times: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))

    def ngp(spec):
        w, config = weights_and_config(spec)

        def call(sample):
            read.take(), lsd.take()
            start = time.perf_counter()
            calibrate(sample.image_path, weights=w, config=config)
            total = time.perf_counter() - start
            r, d = read.take(), lsd.take()
            return {"whole call": total, "reading": r, "line detection": d, "the rest": total - r - d}

        return call

    def peer(sample):
        sample = sample if sample.K is not None else replace(sample, K=_stand_in_K(sample.width, sample.height))
        start = time.perf_counter()
        lu(sample)
        return {"whole call": time.perf_counter() - start}

    methods = [(w, ngp(w)) for w in weights] + ([("lu-vp-detect", peer)] if lu is not None else [])
    methods += [(FLOOR, lsd_alone())] if floor else []
    try:
        for _, fn in methods:  # warm-up: first calls load weights and build detectors
            fn(samples[0])
        for p in range(passes):
            for i, sample in enumerate(samples):
                k = (i + p) % len(methods)
                for name, fn in methods[k:] + methods[:k]:
                    for stage, seconds in fn(sample).items():
                        times[name][stage].append(seconds)
    finally:
        runner.read_rgb_oriented, runner.detect_segments = original
    return times


def _stand_in_K(width: int, height: int) -> torch.Tensor:
    """A focal length of half the width plus height, principal point at the centre: lu-vp-detect's input where the
    true K is unknown (its cost does not depend on it)."""
    f = (width + height) / 2.0
    rows = [[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
    return torch.tensor(rows, dtype=torch.float64)


def summarize(times: dict[str, dict[str, list[float]]]) -> dict[str, dict]:
    lu = times.get("lu-vp-detect", {}).get("whole call")
    lu_mean = statistics.fmean(lu) if lu else None
    out = {}
    for name, stages in times.items():
        whole = stages["whole call"]
        row = {
            "mean_ms": 1000 * statistics.fmean(whole),
            "median_ms": 1000 * statistics.median(whole),
            "ratio_to_lu": statistics.fmean(whole) / lu_mean if lu_mean else None,
            "stages_mean_ms": {s: 1000 * statistics.fmean(v) for s, v in stages.items()},
        }
        if "line detection" in stages:
            row["whole_over_line_detection"] = statistics.fmean(whole) / statistics.fmean(stages["line detection"])
        if "line detection" in stages and FLOOR in times:
            row["whole_over_lsd_alone"] = statistics.fmean(whole) / statistics.fmean(times[FLOOR]["whole call"])
        out[name] = row
    return out


def table(results: dict[int, dict]) -> str:
    lines = [
        "| busy processes | method | mean ms | median ms | ratio to lu (means) | reading | line detection | the rest "
        "| whole / line detection | load before / after |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for busy, res in results.items():
        load = f"{res['load_before']:.2f} / {res['load_after']:.2f}"
        for name, row in res["methods"].items():
            st = row["stages_mean_ms"]
            ratio = f"{row['ratio_to_lu']:.2f}x" if row["ratio_to_lu"] else "-"
            cells = [f"{st[s]:.1f}" if s in st else "-" for s in ("reading", "line detection", "the rest")]
            over = f"{row['whole_over_line_detection']:.2f}x" if "whole_over_line_detection" in row else "-"
            lines.append(
                f"| {busy} | {name} | {row['mean_ms']:.1f} | {row['median_ms']:.1f} | {ratio} | "
                + " | ".join(cells)
                + f" | {over} | {load} |"
            )
    floors = []
    for busy, res in results.items():
        over = [f"{name} {row['whole_over_lsd_alone']:.2f}x" for name, row in res["methods"].items()
                if "whole_over_lsd_alone" in row]
        floors += [f"{busy} busy: whole call over {FLOOR} (whole image, one strip): " + ", ".join(over)] if over else []
    lines += [""] + floors if floors else []
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--yud", type=Path, help="York Urban DB root")
    p.add_argument("--manifest", type=Path, help="a CSV manifest of photos instead of York Urban")
    p.add_argument("--split", default="train", choices=["all", "train", "test"], help="default: the ECCV half")
    p.add_argument("--limit", type=int, default=None, help="use only the first N images")
    p.add_argument("--weights", action="append", default=None, help="weight sets (default: default and none)")
    p.add_argument("--busy", type=int, nargs="+", default=[0, 1, 2], help="busy background processes per condition")
    p.add_argument("--busy-seconds", type=float, default=600.0, help="upper bound of a busy process's life")
    p.add_argument("--passes", type=int, default=1, help="passes over the images per condition")
    p.add_argument("--no-lu", action="store_true", help="skip lu-vp-detect (no ratios then)")
    p.add_argument("--no-floor", action="store_true", help=f"skip the {FLOOR!r} row")
    p.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    args = p.parse_args(argv)
    if (args.yud is None) == (args.manifest is None):
        p.error("give one of --yud and --manifest")
    samples = (load_yud(args.yud, split=args.split) if args.yud else load_manifest(args.manifest))[: args.limit]
    if not samples:
        p.error(f"no images under {args.yud or args.manifest}")
    weights = args.weights or ["default", "none"]
    lu = None if args.no_lu else make_lu()
    header = {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
        "torch": torch.__version__,
        "caller torch threads": torch.get_num_threads(),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
        "NGP_NUM_THREADS": os.environ.get("NGP_NUM_THREADS"),
        "images": len(samples),
        "passes": args.passes,
    }
    print(json.dumps(header))
    results = {}
    for busy in args.busy:
        procs = start_busy(busy, args.busy_seconds)
        try:
            time.sleep(0.5 if busy else 0.0)  # let them start
            load_before = os.getloadavg()[0]
            times = run_condition(samples, weights, lu, args.passes, floor=not args.no_floor)
            load_after = os.getloadavg()[0]
        finally:
            stop_busy(procs)
        results[busy] = {"load_before": load_before, "load_after": load_after, "methods": summarize(times)}
        print(f"condition: {busy} busy processes done (load {load_before:.2f} -> {load_after:.2f})", flush=True)
    print(table(results))
    if args.out:
        args.out.write_text(json.dumps({"header": header, "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
