"""The orientation check on real photos it never trained on: fit its temperature on the ``calibrate`` part of a
folder of upright photos, and report how well it reads each turn of the ``calibrate`` and ``test`` parts.

Usage::

    python benchmarks/upright_calibration.py --photos ../shared/data/RealPhotos --weights upright.pt \\
        [--fit calibrated.pt] [--priors 0.25,0.5,0.75] [--sure 0.9] [--json out.json]

* ``--fit OUT``: the temperature that minimises the negative log-likelihood of the ``calibrate`` part's turns is
  written with the network to OUT (the figures below then use it).
* per part and turn (each photo turned counter-clockwise by 0, 90, 180, 270 degrees, ``np.rot90``): the share whose
  likeliest turn is right, the mean probability of the true turn, the negative log-likelihood and the expected
  calibration error of the likeliest turn's probability (10 bins), over the four turns alone (a real photo's
  structure is not known);
* per prior (the share of upright photos, as ``UprightSettings.prior``): what the parser would do with the reading
  alone (no pitch cue, the lines' own confidence taken as 1): upright photos whose upright probability is below
  ``--doubt`` (warned), turned photos answered right (their turn above ``--sure``), unsure (the answer's
  orientation probability below 0.2) and confidently wrong (above 0.5).
"""

from __future__ import annotations

import argparse
import json

import torch

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.nets.weights import load_network, save_network
from ngp_kornia.training.upright_calibration import calibration_error, fit_temperature, turned_logits


def turn_rows(probs: torch.Tensor, turns: torch.Tensor) -> list[dict]:
    rows = []
    four = probs[:, :4] / probs[:, :4].sum(-1, keepdim=True)
    for k in range(4):
        p = four[turns == k]
        right = p.argmax(-1) == k
        rows.append({"turn": 90 * k, "photos": len(p), "accuracy": float(right.double().mean()),
                     "p_true": float(p[:, k].mean()), "nll": float(-p[:, k].clamp_min(1e-12).log().mean()),
                     "ece": calibration_error(p.max(-1).values, right)})  # fmt: skip
    return rows


def decisions(probs: torch.Tensor, turns: torch.Tensor, prior: float, sure: float, doubt: float) -> list[dict]:
    """The parser's decisions from the reading alone (the rules of ``pipeline/upright_check.py``)."""
    weights = probs.new_tensor([prior, *([(1.0 - prior) / 3] * 3)]) * 4.0
    four = probs[:, :4] * weights
    four = four / four.sum(-1, keepdim=True)
    likeliest, turn = four.max(-1)
    back = (turn > 0) & (likeliest >= sure)
    factor = torch.where(back, likeliest, four[:, 0])
    right = torch.where(back, turn == turns, turns == 0)
    rows = []
    for k in range(4):
        pick = turns == k
        rows.append({"prior": prior, "turn": 90 * k, "turned right": float((back & right)[pick].double().mean()),
                     "right or unsure": float((right | (factor < 0.2))[pick].double().mean()),
                     "confidently wrong": float((~right & (factor > 0.5))[pick].double().mean()),
                     "doubted": float((four[:, 0] < doubt)[pick].double().mean()),
                     "mean factor": float(factor[pick].mean())})  # fmt: skip
    return rows


def print_rows(title: str, rows: list[dict]) -> None:
    keys = list(rows[0])
    print(f"\n{title}\n| " + " | ".join(keys) + " |\n|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for k, v in r.items()) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", required=True, help="the folder of upright photos (its calibrate and test parts)")
    ap.add_argument("--weights", default="ngp_kornia/weights/upright.pt", help="an UprightNet weights file")
    ap.add_argument("--fit", help="fit the temperature on the calibrate part and write the network here")
    ap.add_argument("--priors", default="0.25,0.5,0.75", help="comma-separated priors of an upright photo")
    ap.add_argument("--sure", type=float, default=0.9, help="the probability a turn needs to be answered")
    ap.add_argument("--doubt", type=float, default=0.5, help="the upright probability below which a photo is doubted")
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    net = load_network(args.weights, "UprightNet")
    parts = {part: turned_logits(net, args.photos, split_photos(args.photos, part)) for part in ("calibrate", "test")}
    if args.fit:
        net.temperature = fit_temperature(*parts["calibrate"])
        meta = {**torch.load(args.weights, weights_only=False).get("metadata", {}),
                "temperature": f"fitted on the calibrate part of {args.photos} ({len(parts['calibrate'][1])} photo "
                               "turns)"}  # fmt: skip
        save_network(net, args.fit, net.settings(), meta)
        print(f"temperature {net.temperature:.3f} written with the network to {args.fit}")
    out = {"temperature": net.temperature}
    for part, (logits, turns) in parts.items():
        probs = torch.softmax(logits / net.temperature, -1)
        out[part] = {"turns": turn_rows(probs, turns)}
        print_rows(f"{part} part ({len(turns) // 4} photos), temperature {net.temperature:.3f}", out[part]["turns"])
        out[part]["decisions"] = [row for prior in (float(p) for p in args.priors.split(","))
                                  for row in decisions(probs, turns, prior, args.sure, args.doubt)]  # fmt: skip
        print_rows(f"{part} part: the parser's decisions (sure {args.sure}, doubt {args.doubt})",
                   out[part]["decisions"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
