"""Images per second of calibrate() over a list of files and of ``ngp predict`` on a folder, with 1 and 2
processes, on the CPU or a GPU.

Usage::

    python benchmarks/throughput.py --yud /path/to/YorkUrbanDB [--split train] [--copies 2] [--processes 1 2]
                                    [--weights default] [--accelerator cpu] [--workers 0]
    python benchmarks/throughput.py --render 51 [--size 640x480] ...   # rendered scenes, where no data set is
    python benchmarks/throughput.py --folder photos/ ...               # the images of any folder

The images (York Urban's, rendered scenes or a folder's; ``--copies`` times each, as symbolic links in a temporary
folder, so the work is long enough to see past start-up costs) are calibrated

* by ``calibrate(path)`` in a loop, split over N fresh Python processes (each takes every N-th file); the time is
  the wall time from starting the processes to the last one's end, and each process also reports its own loop
  time (without importing and loading) and then the time of one ``calibrate(list of its files)`` call (which reads
  the next file while the parser works on the current one), and
* by ``ngp predict FOLDER --devices N --accelerator A --workers W`` (Lightning DDP), wall time of the whole
  command, once on the whole folder and once on a folder of one copy of each image; the rate per process is the
  rate after start-up over N. (``--no-calibrate`` leaves out the calibrate() runs, which use the CPU only.)

Images per second = files / wall time. Start-up (importing torch, loading weights, starting DDP) is included in the
wall times; the loop-only figure of the calibrate() runs shows what a long-running process reaches, and for
``ngp predict`` the rate after start-up is the difference of the two runs: (files - files of one copy) / (wall time
- wall time of one copy), which leaves out every fixed cost (importing Lightning alone takes seconds).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

_WORKER = """
import json, sys, time
from ngp_kornia import calibrate
files, weights = json.loads(sys.argv[1]), sys.argv[2]
calibrate(files[0], weights=weights)  # warm-up: loads the weights
start = time.perf_counter()
for f in files:
    calibrate(f, weights=weights)
loop = time.perf_counter() - start
start = time.perf_counter()
calibrate(files, weights=weights)
print(json.dumps({"loop_s": loop, "list_s": time.perf_counter() - start, "images": len(files)}))
"""


def calibrate_processes(files: list[str], processes: int, weights: str) -> dict:
    start = time.perf_counter()
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _WORKER, json.dumps(files[i::processes]), weights],
            stdout=subprocess.PIPE,
            text=True,
        )
        for i in range(processes)
    ]
    reports = [json.loads(p.communicate()[0]) for p in procs]
    wall = time.perf_counter() - start
    loop, listed = max(r["loop_s"] for r in reports), max(r["list_s"] for r in reports)
    return {
        "wall_s": wall,
        "images_per_s": len(files) / wall,
        "loop_images_per_s": len(files) / loop,
        "list_images_per_s": len(files) / listed,
    }


def predict_processes(folder: Path, count: int, processes: int, args) -> dict:
    cmd = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder)]
    cmd += ["--out", str(folder.parent / f"out_{folder.name}_{processes}.jsonl"), "--devices", str(processes)]
    cmd += ["--weights", args.weights, "--accelerator", args.accelerator, "--workers", str(args.workers)]
    start = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if run.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {run.stderr[-2000:]}")
    return {"wall_s": wall, "images_per_s": count / wall}


def predict_rows(folder: Path, files: list[str], per_copy: int, args) -> list[str]:
    """``ngp predict`` on the whole folder and on one copy of each image, for every process count."""
    small = folder.parent / "one_copy"
    small.mkdir(exist_ok=True)
    for f in files[:per_copy]:
        (small / Path(f).name).symlink_to(Path(f).resolve())
    rows = []
    what = f"ngp predict --accelerator {args.accelerator} --workers {args.workers}"
    for n in args.processes:
        whole = predict_processes(folder, len(files), n, args)
        first = predict_processes(small, per_copy, n, args)
        extra = len(files) - per_copy
        after = extra / (whole["wall_s"] - first["wall_s"]) if extra else float("nan")
        rows.append(
            f"| {what} --devices {n} | {n} | {len(files)} | {whole['wall_s']:.1f} | "
            f"{whole['images_per_s']:.2f} | {after:.2f} ({after / n:.2f} per process) |"
        )
        print(rows[-1], f"(one copy: {per_copy} images, {first['wall_s']:.1f} s)", flush=True)
    return rows


def source_images(args, tmp: Path) -> list[Path]:
    """The images to calibrate: York Urban's, a folder's, or ``--render`` scenes written to ``tmp``."""
    if args.yud is not None:
        from ngp_kornia.data.yud import YorkUrbanDB

        return [s.image_path for s in YorkUrbanDB(args.yud, split=args.split)]
    if args.folder is not None:
        from ngp_kornia.data.folder import ImageFolder

        return ImageFolder(args.folder).paths
    import cv2

    from ngp_kornia.training.synth.render import render_scene

    width, height = (int(v) for v in args.size.split("x"))
    (tmp / "rendered").mkdir()
    paths = [tmp / "rendered" / f"scene{seed:04d}.png" for seed in range(args.render)]
    for seed, path in enumerate(paths):
        cv2.imwrite(str(path), cv2.cvtColor(render_scene(seed, size=(width, height)).image, cv2.COLOR_RGB2BGR))
    return paths


def calibrate_rows(files: list[str], args) -> list[str]:
    """``calibrate(path)`` in a loop and ``calibrate(list)``, for every process count."""
    rows = []
    for n in args.processes:
        r = calibrate_processes(files, n, args.weights)
        rows.append(
            f"| calibrate(path) loop | {n} | {len(files)} | {r['wall_s']:.1f} | {r['images_per_s']:.2f} | "
            f"{r['loop_images_per_s']:.2f} |"
        )
        print(rows[-1], flush=True)
        rows.append(f"| calibrate(list of paths) | {n} | {len(files)} | | | {r['list_images_per_s']:.2f} |")
        print(rows[-1], flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--yud", type=Path, help="York Urban DB folder")
    source.add_argument("--folder", type=Path, help="a folder of images")
    source.add_argument("--render", type=int, help="this many rendered scenes (seeds 0, 1, ...)")
    p.add_argument("--size", default="640x480", help="size of the rendered scenes")
    p.add_argument("--split", default="train", choices=["all", "train", "test"])
    p.add_argument("--copies", type=int, default=2, help="times each image is listed")
    p.add_argument("--processes", type=int, nargs="+", default=[1, 2])
    p.add_argument("--weights", default="default")
    p.add_argument("--accelerator", default="cpu", choices=["cpu", "gpu"], help="ngp predict's")
    p.add_argument("--workers", type=int, default=0, help="ngp predict's DataLoader workers per process")
    p.add_argument("--no-predict", action="store_true")
    p.add_argument("--no-calibrate", action="store_true")
    args = p.parse_args(argv)
    rows = ["| what | processes | images | wall s | images / s | images / s, loop only or after start-up |"]
    rows.append("|---|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        images = source_images(args, Path(tmp))
        print(
            f"{datetime.now(UTC):%Y-%m-%d %H:%M UTC}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}, "
            f"{len(images)} images x {args.copies}, weights {args.weights}, OMP_NUM_THREADS="
            f"{os.environ.get('OMP_NUM_THREADS')}", flush=True,
        )
        folder = Path(tmp) / "images"
        folder.mkdir()
        files = []
        for c in range(args.copies):
            for path in images:
                link = folder / f"{c}_{path.name}"
                link.symlink_to(Path(path).resolve())
                files.append(str(link))
        if not args.no_calibrate:
            rows += calibrate_rows(files, args)
        if not args.no_predict:
            rows += predict_rows(folder, files, len(images), args)
    print(f"load after {os.getloadavg()[0]:.2f}")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
