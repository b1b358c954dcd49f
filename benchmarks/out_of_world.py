"""Photos outside the parser's world: York Urban photos turned by 90, 180 and 270 degrees with no orientation tag,
and images without man-made structure.

Usage::

    python benchmarks/out_of_world.py --yud ../shared/data/YorkUrbanDB [--weights default] [--seeds 0]
        [--structureless 200] [--json out.json]

* turned photos: each photo is turned counter-clockwise by k quarter turns (``np.rot90``) and handed over as an
  array (so no tag can say how it was turned). The true roll of the turned photo follows from its up vector. Per
  turn: the share of answers whose roll is within 5 degrees of the truth *or* whose confidence is below 0.2 (the
  answer is right or says it is unsure), the share wrong (roll off by more than 5) with confidence above 0.5, the
  mean confidence and the share the orientation check calls turned.
* structure-free images: ``--structureless`` images of the kinds of
  :func:`ngp_kornia.training.synth.structureless.structureless_image`, on seeds from 5,000,000 (the training data
  of the orientation check draws below 3,000,000): the share with confidence below 0.1, the largest confidence and
  the share ``valid``.
"""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np
import torch

from ngp_kornia.api import calibrate
from ngp_kornia.evaluation.datasets import load_yud
from ngp_kornia.geometry.camera import pitch_roll_from_up
from ngp_kornia.metrics import roll_error
from ngp_kornia.training.synth.structureless import KINDS, structureless_image

STRUCTURELESS_SEED = 5_000_000


def turned_up(up: torch.Tensor, turns: int) -> torch.Tensor:
    """The up vector of a photo turned counter-clockwise by ``turns`` quarter turns (x right, y down)."""
    u = up.clone()
    for _ in range(turns % 4):
        u = torch.stack([u[1], -u[0], u[2]])
    return u


def _turn(out) -> int:
    turn = getattr(out, "turned", None)
    return 0 if turn is None else int(turn)


def _upright(out) -> float:
    return 1.0 if out.upright is None else float(out.upright)


def turned_rows(yud: str, parser, seeds: list[int]) -> list[dict]:
    rows = []
    for item in load_yud(yud):
        rgb = cv2.cvtColor(cv2.imread(str(item.image_path)), cv2.COLOR_BGR2RGB)
        for turns in range(4):
            _, roll = pitch_roll_from_up(turned_up(item.up.double(), turns)[None])
            image = np.ascontiguousarray(np.rot90(rgb, turns))
            for seed in seeds:
                out = calibrate(image, parser, seed=seed)
                err = float(roll_error(out.roll.double().reshape(1), roll.reshape(1)))
                rows.append({"name": item.name, "turn": 90 * turns, "seed": seed, "roll_error": err,
                             "confidence": float(out.confidence), "turned": _turn(out), "upright": _upright(out)})
    return rows


def structureless_rows(count: int, parser) -> list[dict]:
    rows = []
    for i in range(count):
        kind = KINDS[i % len(KINDS)]
        out = calibrate(structureless_image(STRUCTURELESS_SEED + i, (640, 480), kind), parser)
        rows.append({"kind": kind, "confidence": float(out.confidence), "valid": bool(out.valid),
                     "upright": _upright(out)})
    return rows


def print_turned(rows: list[dict]) -> None:
    print("| turn | photos | right or conf < 0.2 | wrong with conf > 0.5 | roll within 5 | mean conf | called turned |")
    print("|---|---|---|---|---|---|---|")
    for turn in (0, 90, 180, 270):
        r = [x for x in rows if x["turn"] == turn]
        right = np.array([x["roll_error"] <= 5.0 for x in r])
        conf = np.array([x["confidence"] for x in r])
        called = np.array([x["turned"] != 0 for x in r])
        print(f"| {turn} | {len(r)} | {np.mean(right | (conf < 0.2)):.1%} | {np.mean(~right & (conf > 0.5)):.1%} | "
              f"{right.mean():.1%} | {conf.mean():.3f} | {called.mean():.1%} |")


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
    ap.add_argument("--yud", help="York Urban DB folder (turned photos skipped without it)")
    ap.add_argument("--weights", default="default")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds of the turned photos")
    ap.add_argument("--structureless", type=int, default=200, help="structure-free images (0: none)")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    parser = args.weights  # loaded once, then shared by every call
    out = {}
    if args.yud:
        out["turned"] = turned_rows(args.yud, parser, [int(s) for s in args.seeds.split(",")])
        print_turned(out["turned"])
    if args.structureless:
        out["structureless"] = structureless_rows(args.structureless, parser)
        print_structureless(out["structureless"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f)


if __name__ == "__main__":
    main()
