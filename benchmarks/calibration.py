"""Benchmark single-image calibration on the York Urban Database, a CSV manifest or a folder written by ``ngp render``.

Compares, on the same images and in the same process:

* ``ngp_kornia.calibrate`` (this package; it estimates the focal length itself), once per ``--weights`` value,
* lu-vp-detect (Lu et al., WACV 2017, the ``lu_vp_detect`` package), given the TRUE focal length and principal
  point, so its field of view is exact by construction (skipped where the ground truth has no focal length),
* a trivial baseline: a level horizon through the image centre (pitch = roll = 0).

Usage::

    python benchmarks/calibration.py yud /path/to/YorkUrbanDB [--split all] [--horizon calibrated|published]
                                     [--ground-truth orthogonal|raw]
    python benchmarks/calibration.py rendered /path/to/render_dir      # written by `ngp render`
    python benchmarks/calibration.py manifest /path/to/labels.csv     # a CSV manifest (ngp_kornia.data.CSVManifest)
    common options: [--limit N] [--weights default] [--weights none] [--weights full:top_k=4] [--weights w.pt]
                    [--no-lu] [--out r.json]

The images and methods come from :mod:`ngp_kornia.evaluation` (every dataset is read into one ``LabelledImage``
type, so every method and metric is shared); this script only chooses them and prints the tables. For the
development suite (every weight set over sampling seeds 0-4 on every dataset) see ``benchmarks/devsuite.py``.

Errors are in degrees; the horizon AUC is the area under the cumulative horizon-error curve on [0, 0.25] of
the image height (:func:`ngp_kornia.metrics.horizon_auc`). Seconds per image is the wall time of one call
including reading the image, measured with the methods interleaved image by image after one warm-up call each.
The load average is printed with the results: timings taken while other jobs run are slower than on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import cv2
import torch

from ngp_kornia.evaluation import (
    LabelledImage,
    Method,
    calibrate_method,
    evaluate,
    kind_table,
    level_centre,
    load_manifest,
    load_renders,
    load_yud,
    lu_vp_detect_method,
    markdown_table,
    run_interleaved,
)

LU_NAME = "lu-vp-detect (true f, pp)"
BASELINE_NAME = "level horizon through the centre"


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--limit", type=int, default=None, help="use only the first N images")
    common.add_argument(
        "--weights",
        action="append",
        default=None,
        help="weights for ngp_kornia.calibrate: default, none, zsnet, fsnet, full or .pt paths joined by '+', "
        "optionally with ParserConfig overrides (full:top_k=4,use_manhattan=false); repeat to compare several "
        "(default: one run with the package default)",
    )
    common.add_argument("--methods", default="ngp,lu", help="comma-separated subset of: ngp, lu")
    common.add_argument("--no-lu", action="store_true", help="skip the peer lu-vp-detect")
    common.add_argument("--out", type=Path, default=None, help="write per-image results to this JSON file")

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="dataset", required=True)
    p_yud = sub.add_parser("yud", parents=[common], help="York Urban DB folder (official layout)")
    p_yud.add_argument("root", type=Path)
    p_yud.add_argument("--split", default="all", choices=["all", "train", "test"])
    p_yud.add_argument(
        "--horizon",
        default="calibrated",
        choices=["calibrated", "published"],
        help="ground-truth horizon: K^-T up with the true K (calibrated) or the line through the raw horizontal "
        "VPs (published, the literature's)",
    )
    p_yud.add_argument(
        "--ground-truth",
        default="orthogonal",
        choices=["orthogonal", "raw"],
        help="York Urban ground truth: vp_orthogonal (default) or the vertical of the raw vp",
    )
    p_ren = sub.add_parser("rendered", parents=[common], help="folder written by `ngp render`")
    p_ren.add_argument("root", type=Path)
    p_man = sub.add_parser("manifest", parents=[common], help="CSV manifest (ngp_kornia.data.CSVManifest)")
    p_man.add_argument("root", type=Path, help="the CSV file")
    return parser


def load_images(args: argparse.Namespace) -> tuple[list[LabelledImage], str]:
    """The images the arguments name, and a title for the tables."""
    if args.dataset == "yud":
        images = load_yud(args.root, args.split, args.horizon, args.ground_truth)
        title = f"York Urban DB, split={args.split}, horizon={args.horizon}, ground truth={args.ground_truth}"
    elif args.dataset == "manifest":
        images, title = load_manifest(args.root), f"CSV manifest {args.root}"
    else:
        images, title = load_renders(args.root), "rendered (ngp render)"
    return images[: args.limit] if args.limit is not None else images, title


def weights_label(spec: str | None) -> str:
    return "ngp_kornia.calibrate" + (f" (weights={spec})" if spec is not None else " (weights=default)")


def build_methods(args: argparse.Namespace, images: list[LabelledImage]) -> tuple[dict[str, Method], list[str]]:
    """The methods the arguments ask for, and notes on those skipped."""
    wanted = [m.strip() for m in args.methods.split(",") if m.strip()]
    if args.no_lu:
        wanted = [m for m in wanted if m != "lu"]
    unknown = sorted(set(wanted) - {"ngp", "lu"})
    if unknown:
        raise SystemExit(f"unknown --methods {unknown}; choose from ngp, lu")
    methods: dict[str, Method] = {}
    notes = []
    if "ngp" in wanted:
        for spec in args.weights or [None]:
            methods[weights_label(spec)] = calibrate_method(spec)
    if "lu" in wanted and any(im.K is None for im in images):
        notes.append("[lu] skipped: the ground truth gives no focal length, which lu-vp-detect needs")
    elif "lu" in wanted:
        try:
            methods[LU_NAME] = lu_vp_detect_method()
        except ImportError as e:
            notes.append(f"[lu] skipped: {e} (pip install 'ngp-kornia[bench]')")
    return methods, notes


def score(methods: dict[str, Method], images: list[LabelledImage]) -> dict[str, dict]:
    """Run the methods interleaved and evaluate them and the level baseline."""
    results = {}
    for name, run in run_interleaved(methods, images).items():
        r = evaluate(images, run.estimates)
        r["seconds_per_image"] = run.seconds_per_image
        r["exceptions"] = run.exceptions
        if name == LU_NAME:
            r["fov_note"] = "0 (given)"
        results[name] = r
    base = evaluate(images, [level_centre(im) for im in images])
    base["seconds_per_image"] = None
    results[BASELINE_NAME] = base
    return results


def report(title: str, args, images, results: dict[str, dict], notes: list[str], load: tuple) -> None:
    print(f"{title}: {len(images)} images ({args.root})")
    print(
        f"timing: {os.cpu_count()} CPUs, torch threads {torch.get_num_threads()}, load average (1 min) "
        f"{load[0][0]:.2f} before / {load[1][0]:.2f} after the run (other jobs running slow the timings)"
    )
    print()
    print(markdown_table(results, len(images)))
    by_kind = kind_table(results)
    if by_kind:
        print("\nhorizon AUC (%) by scene kind\n")
        print(by_kind)
    for name, r in results.items():
        for msg in r.get("exceptions", [])[:5]:
            print(f"  [{name}] {msg}")
    for note in notes:
        print(f"  {note}")


def write_json(path: Path, args, images, results: dict[str, dict], load: tuple) -> None:
    options = {"split": args.split, "horizon": args.horizon, "ground_truth": args.ground_truth}
    payload = {
        "command": " ".join(sys.argv),
        "dataset": args.dataset,
        "root": str(args.root),
        **(options if args.dataset == "yud" else {}),
        "images": [im.name for im in images],
        "load_average": {"before": load[0], "after": load[1]},
        "versions": {"python": platform.python_version(), "torch": torch.__version__, "opencv": cv2.__version__},
        "methods": results,
    }
    path.write_text(json.dumps(payload, indent=1, allow_nan=True))
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    images, title = load_images(args)
    if not images:
        parser.error(f"no images found in {args.root}")
    methods, notes = build_methods(args, images)
    load_before = os.getloadavg()
    results = score(methods, images)
    load = (load_before, os.getloadavg())
    report(title, args, images, results, notes, load)
    if args.out is not None:
        write_json(args.out, args, images, results, load)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
