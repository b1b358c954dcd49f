"""Choosing among more than two horizons: the frame's and the refinement's best few coarse hypotheses.

The refinement (:mod:`ngp_kornia.pipeline.horizon`) scores a grid of hypotheses (pitch offsets at the refined roll,
times focal scales). Here every image's hypotheses are ranked by line support and thinned so that no two kept
horizons lie within ``--separation`` image heights of each other; the best ``--count`` of them and the frame's own
horizon are the candidates. Three rules pick one:

* ``support``: the candidate of highest support (what the refinement does, without its margin or fine grid);
* ``ranker``: a conditional logit (softmax over an image's candidates) on per-candidate features, fitted on
  renders only to put its mass on the candidate of least horizon error;
* ``oracle``: the candidate of least error (a ceiling).

Usage::

    python benchmarks/chooser_candidates.py collect rendered /tmp/fit_renders --seeds 0,1 --out c_fit.json
    python benchmarks/chooser_candidates.py collect yud /path/to/YorkUrbanDB --seeds 0,1,2,3,4 --out c_yud.json
    python benchmarks/chooser_candidates.py collect manifest manifest.csv --seeds 0,1,2,3,4 --out c_ecd.json
    python benchmarks/chooser_candidates.py check --fit c_fit.json [more] --on c_yud.json c_ecd.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from fit_chooser import _errors, load_set

from ngp_kornia.api import _inputs, load_parser
from ngp_kornia.geometry import horizon_from_zenith, zenith_from_up
from ngp_kornia.metrics import horizon_auc
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.horizon import (
    FOCAL_SCALES,
    _camera_segments,
    _coarse_search,
    _lengths,
    _pitch_grid,
    _scaled_focal,
    _Search,
)

FEATURES = ("log_vs_frame", "log_vs_best", "log_shift", "log_scale", "is_frame", "rank", "frame_support")


def _border_y(line: torch.Tensor, width: int) -> torch.Tensor:
    a, b, c = line.unbind(-1)
    xs = torch.tensor([-0.5, width - 0.5], dtype=line.dtype)
    return -(a[..., None] * xs + c[..., None]) / b[..., None]


def candidates(cal, segments, mask, count: int, separation: float) -> list[dict]:
    """The frame's horizon and the ``count`` best separated coarse hypotheses of one image (batch of 1)."""
    height, width = (int(v) for v in cal.image_size[0])
    cam, lengths = _camera_segments(segments.to(cal.K.dtype), cal.K), _lengths(segments.to(cal.K.dtype), mask)
    grid = _pitch_grid(cal.up, cam, lengths, mask, 8.0, 1.0, 2.0, False)
    scales = [1.0] + [x for x in FOCAL_SCALES if x != 1.0]
    coarse = _coarse_search(cal.K, cam, lengths, mask, grid, scales, _Search(4, 1.0, True))
    n_hyp = grid.ups.shape[1]
    support = coarse.support[0]
    lines, scale_of = [], []
    for j in range(len(support)):
        K = _scaled_focal(cal.K, torch.tensor([scales[j // n_hyp]], dtype=cal.K.dtype))
        up = grid.ups[:, j % n_hyp]
        zenith = zenith_from_up(K, up)
        lines.append(horizon_from_zenith(K, zenith / zenith.norm(dim=-1, keepdim=True))[0])
        scale_of.append(scales[j // n_hyp])
    ys = torch.stack([_border_y(line, width) / height for line in lines])  # (S*H, 2)
    frame_y = _border_y(cal.horizon[0], width) / height
    order = support.argsort(descending=True).tolist()
    kept: list[int] = []
    for j in order:
        if len(kept) >= count:
            break
        if j == 0 or all(float((ys[j] - ys[k]).abs().amax()) > separation for k in kept):
            kept.append(j)
    frame_s, best_s = float(support[0]), float(support[order[0]])
    out = [dict(line=cal.horizon[0], feats=_feats(frame_s, frame_s, best_s, 0.0, 1.0, True, 0))]
    for rank, j in enumerate(k for k in kept if k != 0):
        shift = float((ys[j] - frame_y).abs().amax())
        out.append(
            dict(line=lines[j], feats=_feats(float(support[j]), frame_s, best_s, shift, scale_of[j], False, rank + 1))
        )
    return out


def _feats(s: float, frame_s: float, best_s: float, shift: float, scale: float, is_frame: bool, rank: int) -> list:
    tiny = 1e-6
    return [
        float(np.log(max(s, tiny) / max(frame_s, tiny))),
        float(np.log(max(s, tiny) / max(best_s, tiny))),
        float(np.log(shift + 0.01)),
        abs(float(np.log(scale))),
        float(is_frame),
        float(rank),
        frame_s,
    ]


def collect(args) -> None:
    seeds = [int(s) for s in args.seeds.split(",")]
    images = load_set(args.kind, args.path)[: args.limit]
    parser = load_parser("default", ParserConfig())
    cfg = parser.config
    records = []
    for i, (name, path, height, width, truths) in enumerate(images):
        batch, segments, mask, _, _ = _inputs(str(path), cfg)
        for seed in seeds:
            parser.config = replace(cfg, seed=seed, refine_horizon=False)
            with torch.no_grad():
                cal = parser(batch, segments, mask)
                cands = candidates(cal, segments.to(batch), mask, args.count, args.separation)
            records.append(
                dict(
                    name=name,
                    seed=seed,
                    candidates=[
                        dict(features=c["feats"], errors=_errors(c["line"][None], truths, height, width)) for c in cands
                    ],
                )
            )
        print(f"\r{i + 1}/{len(images)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    args.out.write_text(json.dumps(dict(command=" ".join(sys.argv), features=FEATURES, records=records)))
    print(f"wrote {len(records)} records to {args.out}")


def fit_ranker(
    records: list[dict], l2: float = 1e-2, temperature: float = 0.01
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Conditional logit: softmax over each image's candidates of ``w . standardised features``, the target a
    softmax of ``-error / temperature`` (per ground truth); gradient descent with an L2 penalty."""
    groups = []
    for r in records:
        for gt in r["candidates"][0]["errors"]:
            x = np.asarray([c["features"] for c in r["candidates"]])
            e = np.minimum([c["errors"][gt] for c in r["candidates"]], 0.25)
            if len(x) > 1 and e.max() - e.min() > 1e-4:
                t = np.exp(-(e - e.min()) / temperature)
                groups.append((x, t / t.sum()))
    allx = np.vstack([g[0] for g in groups])
    mean, std = allx.mean(0), allx.std(0) + 1e-9
    w = np.zeros(allx.shape[1])
    for _ in range(500):
        grad = l2 * w
        for x, t in groups:
            z = (x - mean) / std
            p = np.exp(z @ w - (z @ w).max())
            p /= p.sum()
            grad += z.T @ (p - t) / len(groups)
        w -= 0.5 * grad
    return w, mean, std


def pick(records: list[dict], gt: str, rule: str, model=None) -> list[float]:
    out = []
    for r in records:
        cands = r["candidates"]
        errs = [c["errors"][gt] for c in cands]
        if rule == "frame":
            out.append(errs[0])
        elif rule == "support":
            out.append(errs[int(np.argmax([c["features"][0] for c in cands]))])
        elif rule == "oracle":
            out.append(min(errs))
        else:
            w, mean, std = model
            z = (np.asarray([c["features"] for c in cands]) - mean) / std
            out.append(errs[int(np.argmax(z @ w))])
    return out


def check(args) -> None:
    fit_records = [r for p in args.fit for r in json.loads(p.read_text())["records"]]
    model = fit_ranker(fit_records, args.l2, args.temperature)
    print("ranker weights: " + ", ".join(f"{n} {v:+.3f}" for n, v in zip(FEATURES, model[0], strict=True)))
    rules = ("frame", "support", "ranker", "oracle")
    table = {}
    for path in args.on + args.fit:
        records = json.loads(path.read_text())["records"]
        seeds = sorted({r["seed"] for r in records})
        for gt in records[0]["candidates"][0]["errors"]:
            table[f"{path.stem}:{gt}"] = {
                rule: [
                    100 * float(horizon_auc(pick([r for r in records if r["seed"] == s], gt, rule, model)))
                    for s in seeds
                ]
                for rule in rules
            }
    print("| set | " + " | ".join(rules) + " |\n|---|" + "---:|" * len(rules))
    for label, row in table.items():
        print(f"| {label} | " + " | ".join(f"{statistics.mean(v):.2f}" for v in row.values()) + " |")
    real = [label for label in table if any(label.startswith(p.stem + ":") for p in args.on)]
    for rule in rules:
        per_seed = [statistics.mean(table[k][rule][i] for k in real) for i in range(len(table[real[0]][rule]))]
        print(
            f"{rule} mean of {len(real)} checked sets per seed: "
            + ", ".join(f"{v:.2f}" for v in per_seed)
            + f" (mean {statistics.mean(per_seed):.2f})"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("kind", choices=["rendered", "yud", "manifest"])
    c.add_argument("path", type=Path)
    c.add_argument("--seeds", default="0")
    c.add_argument("--limit", type=int, default=None)
    c.add_argument("--count", type=int, default=4, help="hypotheses kept besides the frame's horizon")
    c.add_argument("--separation", type=float, default=0.02, help="least distance between kept horizons")
    c.add_argument("--out", type=Path, required=True)
    k = sub.add_parser("check")
    k.add_argument("--fit", type=Path, nargs="+", required=True)
    k.add_argument("--on", type=Path, nargs="+", required=True)
    k.add_argument("--l2", type=float, default=1e-2)
    k.add_argument("--temperature", type=float, default=0.01)
    args = ap.parse_args(argv)
    {"collect": collect, "check": check}[args.cmd](args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
