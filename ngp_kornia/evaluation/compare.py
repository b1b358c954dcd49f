"""Paired comparison of two settings on the same images and seeds, with bootstrap intervals: the rule a change to
the defaults must pass.

A set's horizon AUC on [0, T] is the mean over its images of ``max(0, 1 - e_i / T)`` (``e_i`` the horizon error in
image heights, T = 0.25), so each image has a score whose mean is exactly the AUC. For every image the candidate's
score minus the baseline's, averaged over the seeds, is its paired difference; a set's difference is their mean (the
AUC difference, in points). The pooled difference is the mean over the real sets (each York Urban horizon counts as
a set, as in the development suite's real mean). Intervals are percentile bootstraps over images, resampled within
each dataset (both York Urban horizons share the draw). Every set is also split into its odd and even images.

**The rule:** keep a change only when the pooled interval excludes zero (on the side of the candidate) and no half
of any set loses (its mean difference is below zero).

Usage::

    python -m ngp_kornia.evaluation.compare --yud ../shared/data/YorkUrbanDB \\
        --manifest ../shared/data/EurasianCities/manifest.csv --baseline default --candidate "default:margin=0.1"
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ngp_kornia.evaluation.suite import DEFAULT_SEEDS, SuiteSet, load_sets, run_suite

__all__ = ["AUC_RANGE", "compare", "comparison_table", "image_scores", "main", "run_with_records"]

#: the horizon error at which an image's AUC score falls to zero (image heights)
AUC_RANGE = 0.25


def image_scores(records: Sequence[dict], spec: str, set_name: str, truth: str) -> np.ndarray:
    """(seeds, images) AUC scores ``max(0, 1 - e / 0.25)`` of one spec on one set; a failed image scores 0."""
    rows = [r for r in records if r["weights"] == spec and r["set"] == set_name and r["truth"] == truth]
    rows.sort(key=lambda r: r["seed"])
    scores = []
    for r in rows:
        errors = np.array([p.get("horizon", np.nan) for p in r["result"]["per_image"]], dtype=np.float64)
        scores.append(np.clip(1.0 - np.nan_to_num(errors, nan=np.inf) / AUC_RANGE, 0.0, 1.0))
    return np.stack(scores)


def _interval(samples: np.ndarray) -> tuple[float, float]:
    low, high = np.percentile(samples, [2.5, 97.5])
    return float(low), float(high)


def compare(
    records: Sequence[dict],
    sets: Sequence[SuiteSet],
    baseline: str,
    candidate: str,
    samples: int = 2000,
    seed: int = 0,
) -> dict:
    """The paired differences (candidate - baseline, AUC points) of :func:`run_suite` records, with 95% intervals.

    Returns:
        ``{"pooled": {"mean", "interval"}, "sets": {name: {"mean", "interval", "odd", "even"}}, "keep": bool,
        "reason": str}``; each half ``{"mean", "interval"}``. Renders (not real) are reported and not pooled.
    """
    rng = np.random.default_rng(seed)
    diffs = {}  # (set, truth) -> (images,) per-image differences, mean over seeds
    for s in sets:
        for truth in s.truths:
            a = image_scores(records, candidate, s.name, truth) - image_scores(records, baseline, s.name, truth)
            diffs[(s.name, truth)] = 100.0 * a.mean(0)
    draws = {s.name: rng.integers(0, len(s.images), (samples, len(s.images))) for s in sets}
    real = [(s.name, t) for s in sets if s.real for t in s.truths]
    out: dict = {"sets": {}}
    for (name, truth), d in diffs.items():
        label = name if truth in ("horizon", "renders") else f"{name} ({truth})"
        halves = {}
        for half, start in (("even", 0), ("odd", 1)):
            part = d[start::2]
            boot = part[rng.integers(0, len(part), (samples, len(part)))].mean(1)
            halves[half] = {"mean": float(part.mean()), "interval": _interval(boot)}
        boot = d[draws[name]].mean(1)
        out["sets"][label] = {
            "mean": float(d.mean()),
            "interval": _interval(boot),
            **halves,
            "real": (name, truth) in real,
        }
    if real:
        pooled = np.mean([diffs[k][draws[k[0]]].mean(1) for k in real], 0)
        out["pooled"] = {"mean": float(np.mean([diffs[k].mean() for k in real])), "interval": _interval(pooled)}
    out["keep"], out["reason"] = _verdict(out)
    return out


def _verdict(result: dict) -> tuple[bool, str]:
    pooled = result.get("pooled")
    if pooled is None:
        return False, "no real set"
    if pooled["interval"][0] <= 0.0:
        return False, f"the pooled interval {pooled['interval'][0]:+.2f}..{pooled['interval'][1]:+.2f} includes 0"
    losing = [
        f"{name} ({half})"
        for name, r in result["sets"].items()
        if r["real"]
        for half in ("odd", "even")
        if r[half]["mean"] < 0.0
    ]
    if losing:
        return False, "a half loses: " + ", ".join(losing)
    return True, "the pooled interval excludes 0 and no half loses"


def comparison_table(result: dict, baseline: str, candidate: str) -> str:
    """Markdown table of :func:`compare`'s result."""

    def cell(r: dict) -> str:
        low, high = r["interval"]
        return f"{r['mean']:+.2f} ({low:+.2f}..{high:+.2f})"

    lines = [
        f"`{candidate}` against `{baseline}`: horizon AUC difference, points, mean (95% bootstrap interval)",
        "",
        "| set | all images | even images | odd images |",
        "|---|---:|---:|---:|",
    ]
    for name, r in result["sets"].items():
        lines.append(
            f"| {name}{'' if r['real'] else ' (not pooled)'} | {cell(r)} | {cell(r['even'])} | {cell(r['odd'])} |"
        )
    if "pooled" in result:
        lines.append(f"| **pooled over the real sets** | **{cell(result['pooled'])}** | | |")
    lines += ["", f"keep: {'yes' if result['keep'] else 'no'} ({result['reason']})"]
    return "\n".join(lines)


def run_with_records(specs: Sequence[str], sets, seeds: Sequence[int], path: str | None, quiet: bool) -> list[dict]:
    """:func:`run_suite` records of ``specs``, taking those a records file already holds (for every set and seed
    asked for) from it instead of running them again, and writing all of them back to it."""
    known = json.loads(Path(path).read_text()) if path and Path(path).is_file() else []
    wanted = {(s.name, t, seed) for s in sets for t in s.truths for seed in seeds}

    def held(spec: str) -> list[dict]:
        rows = [r for r in known if r["weights"] == spec and (r["set"], r["truth"], r["seed"]) in wanted]
        return rows if len(rows) == len(wanted) else []

    todo = [spec for spec in dict.fromkeys(specs) if not held(spec)]
    fresh = run_suite(todo, sets, seeds, None if quiet else sys.stderr) if todo else []
    records = [r for spec in specs if spec not in todo for r in held(spec)] + fresh
    if path:
        kept = [r for r in known if r["weights"] not in todo]
        Path(path).write_text(json.dumps(kept + fresh))
    return records


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m ngp_kornia.evaluation.compare``."""
    p = argparse.ArgumentParser(prog="python -m ngp_kornia.evaluation.compare", description=__doc__.split("\n\n")[0])
    p.add_argument("--yud", help="York Urban DB folder")
    p.add_argument("--manifest", action="append", default=[], help="CSV manifest (PATH or NAME=PATH), repeatable")
    p.add_argument("--renders", help="a folder written by ngp render (reported, not pooled)")
    p.add_argument("--nyu", help="NYU-VP folder: its validation scenes 1000-1223, given as segments (pooled)")
    p.add_argument("--baseline", default="default", help="weights spec of the current default")
    p.add_argument("--candidate", action="append", required=True,
                   help="weights spec of the change, e.g. default:margin=0.1; repeatable (each against the baseline)")
    p.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)), help="sampling seeds, comma-separated")
    p.add_argument("--split", default="all", help="York Urban split: all, train or test")
    p.add_argument("--json", help="also write the result here")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--records", help="a JSON file of earlier runs: specs found there (same sets and seeds) are not "
                   "run again, and every run is written back (a spec names a weights file by its path: a new file "
                   "there needs a new records file)")
    args = p.parse_args(argv)
    sets = load_sets(args.yud, args.manifest, args.renders, args.split, nyu=args.nyu)
    seeds = [int(s) for s in args.seeds.split(",")]
    records = run_with_records([args.baseline, *args.candidate], sets, seeds, args.records, args.quiet)
    results = []
    for candidate in args.candidate:
        result = compare(records, sets, args.baseline, candidate)
        print(comparison_table(result, args.baseline, candidate) + "\n")
        results.append({"baseline": args.baseline, "candidate": candidate, "seeds": seeds, **result})
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(results[0] if len(results) == 1 else results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
