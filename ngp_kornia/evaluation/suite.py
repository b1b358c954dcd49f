"""The development suite: every weight set, over several sampling seeds, on every labelled dataset, in one run.

For each weight set it reports the mean and the range (min-max) over the seeds of:

* York Urban with both ground-truth horizons (``calibrated`` and ``published``, see :func:`load_yud`): horizon AUC,
  median horizon error, up-vector and vertical FoV errors (mean and median);
* each CSV manifest (e.g. the Eurasian Cities development part, or your own labelled photos): horizon AUC and median
  horizon error, plus the up and FoV errors where the manifest gives them;
* a folder written by ``ngp render``: the same as York Urban;
* seconds per image (wall time of one ``calibrate(path)`` call, weight sets interleaved image by image);
* the **real mean**: the mean horizon AUC over the photo sets (York Urban calibrated, York Urban published and every
  CSV manifest), the figure to choose defaults by, so that no single set decides.

Usage::

    python -m ngp_kornia.evaluation --yud /path/to/YorkUrbanDB --manifest /path/to/EurasianCities/manifest.csv \\
        --renders /tmp/render_test --weights none --weights fsnet --seeds 0,1,2,3,4 --json suite.json
    python -m ngp_kornia.evaluation --manifest my_photos/labels.csv --weights default   # your own photos

Weight specs are those of :func:`~ngp_kornia.evaluation.methods.parse_weights_spec` (``full:top_k=4``, ``a.pt+b.pt``).
The suite seed replaces the spec's ``seed``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import torch

from ngp_kornia.evaluation.datasets import (
    YUD_HORIZONS,
    LabelledImage,
    load_manifest,
    load_nyu,
    load_renders,
    load_yud,
)
from ngp_kornia.evaluation.methods import calibrate_method, run_interleaved
from ngp_kornia.evaluation.scoring import CAMERA_METRICS, evaluate

__all__ = [
    "DEFAULT_SEEDS",
    "DEFAULT_WEIGHTS",
    "SuiteSet",
    "load_sets",
    "main",
    "run_suite",
    "suite_rows",
    "suite_table",
    "write_sheets",
]

#: sampling seeds of the development suite
DEFAULT_SEEDS = (0, 1, 2, 3, 4)
#: weight sets compared when none are named
DEFAULT_WEIGHTS = ("none", "zsnet", "fsnet", "full")


@dataclass(frozen=True)
class SuiteSet:
    """One dataset of the suite: the same images under one or more ground truths.

    Attributes:
        name: shown in the tables, e.g. ``"York Urban"``.
        truths: ground-truth name -> images; every list holds the same image files in the same order (the
            methods run once on the first list and are scored against each).
        real: photos (counted in the real mean) rather than renders.
    """

    name: str
    truths: dict[str, list[LabelledImage]]
    real: bool = True

    @property
    def images(self) -> list[LabelledImage]:
        """The images the methods run on."""
        return next(iter(self.truths.values()))


def _label(path: Path) -> str:
    return path.parent.name if path.stem == "manifest" else path.stem


def load_sets(
    yud: Path | None,
    manifests: Sequence[str],
    renders: Path | None,
    split: str = "all",
    limit: int | None = None,
    nyu: Path | None = None,
) -> list[SuiteSet]:
    """The suite's datasets from their paths; ``manifests`` entries are ``PATH`` or ``NAME=PATH``; ``nyu`` an NYU-VP
    folder, of which the validation scenes (1000-1223) with a horizon truth are a real set, given as segments.

    A manifest's name defaults to its file's stem, or its folder's name for a file called ``manifest.csv``.

    Raises:
        FileNotFoundError: a missing folder or file.
        ValueError: a set without images, two sets of the same name, or a malformed file.
    """
    sets = []
    if yud is not None:
        sets.append(SuiteSet("York Urban", {h: load_yud(yud, split, h)[:limit] for h in YUD_HORIZONS}))
    for entry in manifests:
        name, sep, path = entry.partition("=")
        path = Path(path if sep else name)
        sets.append(SuiteSet(name if sep else _label(path), {"horizon": load_manifest(path)[:limit]}))
    if nyu is not None:
        sets.append(SuiteSet("NYU-VP", {"horizon": load_nyu(nyu)[:limit]}))
    if renders is not None:
        sets.append(SuiteSet("renders", {"renders": load_renders(renders)[:limit]}, real=False))
    names = [s.name for s in sets]
    for s in sets:
        if names.count(s.name) > 1:
            raise ValueError(f"two sets are named {s.name!r}; name the manifests with --manifest NAME=PATH")
        if not s.images:
            raise ValueError(f"the set {s.name!r} has no images")
    return sets


def run_suite(
    specs: Sequence[str], sets: Sequence[SuiteSet], seeds: Sequence[int], progress: TextIO | None = sys.stderr
) -> list[dict]:
    """Run every weight spec with every seed on every set, the specs interleaved image by image.

    Returns:
        one record per (spec, set, ground truth, seed): ``{"weights", "set", "truth", "seed", "images",
        "seconds", "exceptions", "result"}`` with ``result`` the output of :func:`evaluate` and ``seconds`` the wall
        time of all the calls on the set (the same for each ground truth of a set).
    """
    records = []
    for suite_set in sets:
        for seed in seeds:
            if progress is not None:
                print(f"{suite_set.name}, seed {seed}", file=progress)
            methods = {spec: calibrate_method(spec, seed, suite_set.images) for spec in specs}
            for spec, run in run_interleaved(methods, suite_set.images, progress).items():
                for truth, images in suite_set.truths.items():
                    records.append(
                        {
                            "weights": spec,
                            "set": suite_set.name,
                            "truth": truth,
                            "seed": seed,
                            "images": len(images),
                            "seconds": run.seconds,
                            "exceptions": run.exceptions,
                            "result": evaluate(images, run.estimates),
                        }
                    )
    return records


def _variant_rows(title: str, set_name: str, result: dict, first: bool) -> dict[str, float]:
    """The figures of one (set, ground truth) run, labelled with ``title``; ``first`` adds the up and FoV errors,
    labelled with the set's name (the same for every ground truth of York Urban, whose horizons differ but whose up
    and FoV do not)."""
    rows = {f"{title}: horizon AUC (%)": 100 * result["horizon_auc"]}
    summary = result["summary"]
    if summary.get("horizon", {}).get("count"):
        rows[f"{title}: median horizon error (% of height)"] = 100 * summary["horizon"]["median"]
    for key, what in (("up", "up error (deg)"), ("fov_v", "FoV_v error (deg)"), *CAMERA_METRICS.items()):
        if first and summary.get(key, {}).get("count"):
            rows[f"{set_name}: {what} mean"] = summary[key]["mean"]
            rows[f"{set_name}: {what} median"] = summary[key]["median"]
    return rows


def suite_rows(records: list[dict], sets: Sequence[SuiteSet]) -> dict[str, dict[str, list[float]]]:
    """Row label -> weight spec -> one value per seed (in seed order), from :func:`run_suite`'s records.

    Rows: each set's figures (:func:`_variant_rows`), ``seconds per image`` over all the sets, and ``real mean
    horizon AUC (%)``, the mean over the real sets' ground truths, when there is one.
    """
    rows: dict[str, dict[str, list[float]]] = {}
    real = {(s.name, t) for s in sets if s.real for t in s.truths}
    first_truth = {s.name: next(iter(s.truths)) for s in sets}
    titles = {(s.name, t): s.name if len(s.truths) == 1 else f"{s.name} ({t})" for s in sets for t in s.truths}
    per_seed: dict[tuple[str, int], dict[str, list[float]]] = {}
    for rec in records:
        first = rec["truth"] == first_truth[rec["set"]]
        title = titles[rec["set"], rec["truth"]]
        for label, value in _variant_rows(title, rec["set"], rec["result"], first).items():
            rows.setdefault(label, {}).setdefault(rec["weights"], []).append(value)
        acc = per_seed.setdefault((rec["weights"], rec["seed"]), {"seconds": [], "images": [], "real": []})
        if first:
            acc["seconds"].append(rec["seconds"])
            acc["images"].append(rec["images"])
        if (rec["set"], rec["truth"]) in real:
            acc["real"].append(100 * rec["result"]["horizon_auc"])
    for (spec, _seed), acc in per_seed.items():
        rows.setdefault("seconds per image", {}).setdefault(spec, []).append(sum(acc["seconds"]) / sum(acc["images"]))
        if acc["real"]:
            rows.setdefault("real mean horizon AUC (%)", {}).setdefault(spec, []).append(statistics.mean(acc["real"]))
    return rows


def _cell(values: list[float], digits: int) -> str:
    if not values or any(math.isnan(v) for v in values):
        return "n.a."
    mean = f"{statistics.mean(values):.{digits}f}"
    return mean if len(values) == 1 else f"{mean} ({min(values):.{digits}f}-{max(values):.{digits}f})"


def suite_table(rows: dict[str, dict[str, list[float]]], specs: Sequence[str]) -> str:
    """Markdown table: one row per figure, one column per weight spec, cells ``mean (min-max)`` over the seeds."""
    lines = ["| figure | " + " | ".join(specs) + " |", "|---|" + "---:|" * len(specs)]
    for label, by_spec in rows.items():
        digits = 3 if label == "seconds per image" else 2
        lines.append(f"| {label} | " + " | ".join(_cell(by_spec.get(s, []), digits) for s in specs) + " |")
    return "\n".join(lines)


def _aggregate(rows: dict[str, dict[str, list[float]]]) -> dict:
    return {
        label: {
            spec: {"mean": statistics.mean(v), "min": min(v), "max": max(v), "per_seed": v}
            for spec, v in by_spec.items()
        }
        for label, by_spec in rows.items()
    }


def machine() -> dict:
    """What the timings were taken on."""
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
    }


def build_parser() -> argparse.ArgumentParser:
    usage = __doc__.split("Usage::")[1].split("Weight specs")[0]
    p = argparse.ArgumentParser(
        prog="python -m ngp_kornia.evaluation",
        description=__doc__.split("\n\n")[0],
        epilog="examples:"
        + usage
        + "Every figure is the mean (min-max) over the seeds; see ngp_kornia.evaluation.suite.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--yud", type=Path, help="York Urban DB folder (official layout): scored against both horizons")
    p.add_argument("--yud-split", default="all", choices=["all", "train", "test"], help="York Urban images to use")
    p.add_argument("--manifest", action="append", default=[], metavar="[NAME=]PATH", help="CSV manifest (repeatable)")
    p.add_argument("--renders", type=Path, help="folder written by `ngp render`")
    p.add_argument("--nyu", type=Path, help="NYU-VP folder: its validation scenes (1000-1223), given as segments")
    p.add_argument(
        "--weights",
        action="append",
        default=None,
        help=f"weight spec, repeatable (default: {', '.join(DEFAULT_WEIGHTS)})",
    )
    p.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)), help="comma-separated sampling seeds")
    p.add_argument("--limit", type=int, default=None, help="only the first N images of each set (quick checks)")
    p.add_argument("--json", type=Path, default=None, help="also write every figure and per-image error here")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--sheets", type=Path, default=None, help="write worst-case sheets (PNG) of the first seed here")
    p.add_argument("--sheet-count", type=int, default=8, help="images on each worst-case sheet")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: ``python -m ngp_kornia.evaluation --help``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.yud is None and not args.manifest and args.renders is None and args.nyu is None:
        parser.error("nothing to evaluate: give --yud, --manifest, --nyu or --renders")
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        parser.error(f"--seeds must be comma-separated integers, got {args.seeds!r}")
    specs = args.weights or list(DEFAULT_WEIGHTS)
    try:
        sets = load_sets(args.yud, args.manifest, args.renders, args.yud_split, args.limit, args.nyu)
    except (FileNotFoundError, ValueError) as e:
        parser.error(str(e))
    started = datetime.datetime.now(datetime.UTC)
    load_before = os.getloadavg()
    records = run_suite(specs, sets, seeds, None if args.quiet else sys.stderr)
    rows = suite_rows(records, sets)
    load = {"before": load_before, "after": os.getloadavg()}
    sizes = ", ".join(f"{s.name} {len(s.images)}" for s in sets)
    print(f"development suite, {started:%Y-%m-%d %H:%M} UTC; images: {sizes}; seeds {seeds}")
    print(f"{machine()}; load average (1 min) {load['before'][0]:.2f} before / {load['after'][0]:.2f} after\n")
    print(suite_table(rows, specs))
    first_truth = {s.name: next(iter(s.truths)) for s in sets}
    for rec in (r for r in records if r["truth"] == first_truth[r["set"]]):
        for msg in rec["exceptions"][:3]:
            print(f"  [{rec['weights']}, {rec['set']}, seed {rec['seed']}] {msg}")
    if args.sheets is not None:
        write_sheets(args.sheets, records, sets, seeds[0], args.sheet_count)
    if args.json is not None:
        write_json(args.json, argv, started, load, seeds, specs, sets, rows, records)
    return 0


def write_sheets(folder: Path, records: list[dict], sets: Sequence[SuiteSet], seed: int, count: int) -> None:
    """One worst-case sheet per set and weight spec, of ``seed``'s run (:mod:`~ngp_kornia.evaluation.sheets`),
    scored against the set's first ground truth."""
    from ngp_kornia.evaluation.methods import calibration_method
    from ngp_kornia.evaluation.sheets import sheet_name, worst_sheet

    for suite_set in sets:
        truth = next(iter(suite_set.truths))
        for rec in records:
            if rec["set"] == suite_set.name and rec["truth"] == truth and rec["seed"] == seed:
                calibration = calibration_method(rec["weights"], seed, suite_set.images)
                path = folder / sheet_name(suite_set.name, rec["weights"])
                worst_sheet(suite_set.truths[truth], rec["result"]["per_image"], calibration, path, count)
                print(f"wrote {path}")


def write_json(path: Path, argv, started, load: dict, seeds, specs, sets, rows, records) -> None:
    """Every figure (mean, min, max and per seed), the per-image errors of every run, the command and machine."""
    payload = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if argv is None else " ".join(argv),
        "date": started.isoformat(timespec="seconds"),
        "machine": machine(),
        "load_average": load,
        "seeds": list(seeds),
        "weights": list(specs),
        "sets": {s.name: {t: [im.name for im in ims] for t, ims in s.truths.items()} for s in sets},
        "figures": _aggregate(rows),
        "runs": records,
    }
    path.write_text(json.dumps(payload, indent=1, allow_nan=True))
    print(f"\nwrote {path}")
