"""Line detectors and working sizes for calibrate(): horizon AUC on York Urban (both ground truths) and the
Eurasian Cities manifest over several sampling seeds, and the time of the detection and of the whole call.

Usage::

    python benchmarks/detectors.py --yud /path/to/YorkUrbanDB [--ecd /path/to/EurasianCities/manifest.csv]
        [--weights default] [--seeds 0 1 2 3 4] [--option lsd:640 --option fld:640 ...] [--limit N]

Each ``--option`` is ``DETECTOR:WORKING_SIZE`` (``ParserConfig.detector`` and ``working_size``). Per image and
option the file is read and its lines detected once, exactly as :func:`ngp_kornia.calibrate` does for a path, and
the parser then runs once per seed on those lines (which gives calibrate()'s answer for that seed: the lines do not
depend on it). Accuracy: the horizon AUC (:func:`ngp_kornia.metrics.horizon_auc`), mean and range over the seeds.
Times (mean ms per image, medians in the JSON): line detection (resize + detector, from the decoded grey image),
and the whole seed-0 call (reading, detection, the parser); the options run interleaved image by image.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import cv2
import torch

from ngp_kornia.api import load_parser
from ngp_kornia.io import read_rgb
from ngp_kornia.metrics import horizon_auc, horizon_error
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.segments import detect_segments_gray, pad_segments


def _datasets(args) -> dict[str, list]:
    from ngp_kornia.data import CSVManifest
    from ngp_kornia.data.yud import YorkUrbanDB

    out = {}
    if args.yud:
        for gt in ("orthogonal", "raw"):
            out[f"YUD {args.split} ({gt})"] = list(YorkUrbanDB(args.yud, split=args.split, ground_truth=gt))
    if args.ecd:
        out["ECD"] = [s for s in CSVManifest(args.ecd) if s.horizon is not None]
    return {k: v[: args.limit] for k, v in out.items()}


def _run(images: list[Path], options: list[tuple[str, int]], weights: str, seeds: list[int]) -> dict:
    """Per option: horizons (seed -> image -> (3,) tensor), detection and whole-call seconds per image."""
    parsers = {s: load_parser(weights, replace(ParserConfig(), seed=s)) for s in seeds}
    res = {o: {"horizons": {s: {} for s in seeds}, "detect": [], "whole": []} for o in options}
    for i, path in enumerate(images):
        k = i % len(options)
        for option in options[k:] + options[:k]:
            detector, size = option
            cfg = replace(ParserConfig(), detector=detector, working_size=size)
            start = time.perf_counter()
            rgb = read_rgb(path)
            batch = torch.from_numpy(rgb).permute(2, 0, 1)[None].float().div(255.0)
            t0 = time.perf_counter()
            gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            found = detect_segments_gray(gray, cfg)
            detect = time.perf_counter() - t0
            segments, mask = pad_segments([found])
            for s in seeds:
                parser = parsers[s]
                parser.config = replace(parser.config, detector=detector, working_size=size)
                with torch.no_grad():
                    cal = parser(batch, segments, mask)
                if s == seeds[0]:
                    res[option]["whole"].append(time.perf_counter() - start)
                res[option]["horizons"][s][str(path)] = cal.horizon[0].double()
            res[option]["detect"].append(detect)
        print(f"\r{i + 1}/{len(images)}", end="", flush=True)
    print()
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--yud", type=Path, default=None, help="York Urban DB root")
    p.add_argument("--split", default="train", choices=["all", "train", "test"])
    p.add_argument("--ecd", type=Path, default=None, help="Eurasian Cities manifest.csv")
    p.add_argument("--weights", default="default")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--option", action="append", default=None, help="DETECTOR:WORKING_SIZE, e.g. fld:640")
    p.add_argument("--limit", type=int, default=None)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    options = [(o.split(":")[0], int(o.split(":")[1])) for o in (args.option or ["lsd:640", "fld:640"])]
    datasets = _datasets(args)
    if not datasets:
        p.error("give --yud and/or --ecd")
    print(
        f"{datetime.now(UTC):%Y-%m-%d %H:%M UTC}, {os.cpu_count()} CPUs, torch threads "
        f"{torch.get_num_threads()}, load {os.getloadavg()[0]:.2f}, weights {args.weights}, seeds {args.seeds}"
    )
    # the two York Urban ground truths share their images: run each image once
    by_path = {}
    for samples in datasets.values():
        for s in samples:
            by_path.setdefault(str(s.image_path), s)
    res = _run([Path(k) for k in by_path], options, args.weights, args.seeds)
    header = "| detector:size | " + " | ".join(f"{d} AUC" for d in datasets) + " | detection ms | whole call ms |"
    lines = [header, "|---|" + "---:|" * (len(datasets) + 2)]
    summary = {}
    for option in options:
        r = res[option]
        cells, summary[f"{option[0]}:{option[1]}"] = [], {}
        for name, samples in datasets.items():
            aucs = []
            for s in args.seeds:
                pred = torch.stack([r["horizons"][s][str(x.image_path)] for x in samples])
                gt = torch.stack([x.horizon.double() for x in samples])
                h = torch.tensor([float(x.height) for x in samples], dtype=torch.float64)
                w = torch.tensor([float(x.width) for x in samples], dtype=torch.float64)
                aucs.append(100 * float(horizon_auc(horizon_error(pred, gt, h, w))))
            cells.append(f"{statistics.fmean(aucs):.2f} ({min(aucs):.2f}-{max(aucs):.2f})")
            summary[f"{option[0]}:{option[1]}"][name] = aucs
        det, whole = 1000 * statistics.fmean(r["detect"]), 1000 * statistics.fmean(r["whole"])
        summary[f"{option[0]}:{option[1]}"]["detect_median_ms"] = 1000 * statistics.median(r["detect"])
        summary[f"{option[0]}:{option[1]}"]["whole_median_ms"] = 1000 * statistics.median(r["whole"])
        lines.append(f"| {option[0]}:{option[1]} | " + " | ".join(cells) + f" | {det:.1f} | {whole:.1f} |")
    print(f"images: {', '.join(f'{k} {len(v)}' for k, v in datasets.items())}; load after {os.getloadavg()[0]:.2f}")
    print("\n".join(lines))
    if args.out:
        args.out.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
