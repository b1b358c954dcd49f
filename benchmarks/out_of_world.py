"""Photos outside the parser's world: photos turned by 90, 180 and 270 degrees with no orientation tag, and images
without man-made structure.

Usage::

    python benchmarks/out_of_world.py --yud ../shared/data/YorkUrbanDB \
        --manifest ../shared/data/EurasianCities/manifest.csv --photos ../shared/data/RealPhotos \
        [--weights default] [--seeds 0] [--structureless 200] [--json out.json]

* turned photos: each photo is turned counter-clockwise by k quarter turns (``np.rot90``) and handed over as an
  array (so no tag can say how it was turned). The true roll of the turned photo is the upright photo's true roll
  minus 90 k degrees. York Urban and the manifest's photos (Eurasian Cities) have a true roll; the held-back
  ``test`` part of a folder of upright photos (:mod:`ngp_kornia.data.photo_split`, never trained on) has none, so
  there the roll the parser answers for the upright photo stands in for it. Per set and turn: the share of answers
  whose roll is within 5 degrees of the truth *or* whose confidence is below 0.2 (the answer is right or says it is
  unsure), the share wrong (roll off by more than 5) with confidence above 0.5, the share within 5 degrees, the mean
  confidence, the share the orientation check reports turned (``turned`` != 0) and the share it doubts (upright
  probability below ``UprightSettings.doubt``; ``ngp calibrate`` warns for those).
* structure-free images: ``--structureless`` images of the kinds of
  :func:`ngp_kornia.training.synth.structureless.structureless_image`, on seeds from 5,000,000 (the training data
  of the orientation check draws below 3,000,000): the share with confidence below 0.1, the largest confidence and
  the share ``valid``.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from ngp_kornia.api import calibrate
from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.evaluation.datasets import load_manifest, load_yud
from ngp_kornia.evaluation.methods import weights_and_config
from ngp_kornia.io import read_image_file
from ngp_kornia.metrics import roll_error
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.training.synth.structureless import KINDS, structureless_image

STRUCTURELESS_SEED = 5_000_000


def _turn(out) -> int:
    turn = getattr(out, "turned", None)
    return 0 if turn is None else int(turn)


def _upright(out) -> float:
    return 1.0 if out.upright is None else float(out.upright)


def photo_sets(args: argparse.Namespace) -> dict[str, list[tuple[str, str, float | None]]]:
    """Per set, its photos as ``(name, path, true roll)`` (None: the upright answer's roll stands in)."""
    sets = {}
    if args.yud:
        sets["York Urban"] = [(x.name, str(x.image_path), x.roll) for x in load_yud(args.yud)]
    if args.manifest:
        sets["Eurasian Cities"] = [(x.name, str(x.image_path), x.roll) for x in load_manifest(args.manifest)]
    if args.photos:
        names = split_photos(args.photos, args.part)
        sets[f"RealPhotos {args.part} part"] = [(n, f"{args.photos}/{n}", None) for n in names]
    return sets


def turned_rows(photos: list[tuple[str, str, float | None]], parser, seeds: list[int]) -> list[dict]:
    rows = []
    for name, path, truth in photos:
        rgb = read_image_file(path)
        for seed in seeds:
            roll = truth
            for turns in range(4):
                out = calibrate(np.ascontiguousarray(np.rot90(rgb, turns)), parser[0], config=parser[1], seed=seed)
                if roll is None:  # no truth: the upright answer's roll stands in
                    roll = float(out.roll)
                want = torch.tensor([roll - 90.0 * turns], dtype=torch.float64)
                err = float(roll_error(out.roll.double().reshape(1), want))
                rows.append({"name": name, "turn": 90 * turns, "seed": seed, "roll_error": err,
                             "confidence": float(out.confidence), "turned": _turn(out), "upright": _upright(out)})
    return rows


def structureless_rows(count: int, parser) -> list[dict]:
    rows = []
    for i in range(count):
        kind = KINDS[i % len(KINDS)]
        out = calibrate(structureless_image(STRUCTURELESS_SEED + i, (640, 480), kind), parser[0], config=parser[1])
        rows.append({"kind": kind, "confidence": float(out.confidence), "valid": bool(out.valid),
                     "upright": _upright(out)})
    return rows


def print_turned(title: str, rows: list[dict], doubt: float) -> None:
    print(f"\n{title}\n| turn | answers | right or conf < 0.2 | wrong with conf > 0.5 | roll within 5 | mean conf | "
          "reported turned | doubted |\n|---|---|---|---|---|---|---|---|")
    for turn in (0, 90, 180, 270):
        r = [x for x in rows if x["turn"] == turn]
        right = np.array([x["roll_error"] <= 5.0 for x in r])
        conf = np.array([x["confidence"] for x in r])
        called = np.array([x["turned"] != 0 for x in r])
        doubted = np.array([x["upright"] < doubt for x in r])
        print(f"| {turn} | {len(r)} | {np.mean(right | (conf < 0.2)):.1%} | {np.mean(~right & (conf > 0.5)):.1%} | "
              f"{right.mean():.1%} | {conf.mean():.3f} | {called.mean():.1%} | {doubted.mean():.1%} |")


def print_structureless(rows: list[dict]) -> None:
    print("| kind | images | conf < 0.1 | max conf | valid |")
    print("|---|---|---|---|---|")
    for kind in (*KINDS, "all"):
        r = [x for x in rows if kind in ("all", x["kind"])]
        conf = np.array([x["confidence"] for x in r])
        print(f"| {kind} | {len(r)} | {np.mean(conf < 0.1):.1%} | {conf.max():.3f} | "
              f"{np.mean([x['valid'] for x in r]):.1%} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--yud", help="York Urban DB folder")
    ap.add_argument("--manifest", help="a CSV manifest with true horizons (Eurasian Cities)")
    ap.add_argument("--photos", help="a folder of upright photos: its held-back test part")
    ap.add_argument("--part", default="test", help="the photo folder's part (photo_split: test, calibrate)")
    ap.add_argument("--weights", default="default", help="a weight set, with settings as the development suite "
                    "takes them (default:upright.lines=false)")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds of the turned photos")
    ap.add_argument("--structureless", type=int, default=200, help="structure-free images (0: none)")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    parser = weights_and_config(args.weights)  # loaded once, then shared by every call
    out = {}
    doubt = ParserConfig().upright.doubt
    for title, photos in photo_sets(args).items():
        out[title] = turned_rows(photos, parser, [int(s) for s in args.seeds.split(",")])
        print_turned(title, out[title], doubt)
    if args.structureless:
        out["structureless"] = structureless_rows(args.structureless, parser)
        print_structureless(out["structureless"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f)


if __name__ == "__main__":
    main()
