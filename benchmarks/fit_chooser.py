"""A learned choice between the frame's horizon and the horizon refinement's best hypothesis, fitted on renders
and measured against the shipped rule (replace the frame's horizon where the hypothesis' line support is higher
by more than 8%, :func:`ngp_kornia.pipeline.horizon.refine_horizon`). Measured not better on the real sets, so not
shipped; see BENCHMARKS.md, "A learned horizon chooser".

The chooser is a logistic model of "the hypothesis is closer to the truth" on what both candidates carry
(:data:`FEATURE_NAMES`): their supports, difference and ratio, how far apart the two horizons are, the focal scale
and zenith turn the hypothesis needs, the horizontal-VP peak weights along each, the frame's score, confidence and
pitch spread, and FSNet's and the Manhattan score's verdict on the two frames.

Three steps, so the expensive one runs once per data set::

    # 1. per image and sampling seed: the frame search's calibration, the refinement's best hypothesis, the
    #    chooser's features and the horizon error of each candidate (and of the shipped margin rule)
    python benchmarks/fit_chooser.py collect rendered /tmp/fit_renders --seeds 0,1 --out fit.json     # fitting
    python benchmarks/fit_chooser.py collect yud /path/to/YorkUrbanDB --seeds 0,1,2,3,4 --out yud.json  # checking
    python benchmarks/fit_chooser.py collect manifest /path/to/manifest.csv --seeds 0,1,2,3,4 --out ecd.json
    # 2. fit on the renders' records only
    python benchmarks/fit_chooser.py fit fit.json [more.json] [--inputs log_ratio,log_shift] [--l2 1] --out chooser.json
    # 3. horizon AUC per seed of each rule (frame only, the shipped margin, the chooser, the per-image oracle)
    python benchmarks/fit_chooser.py check yud.json ecd.json --model chooser.json [--fsnet-override T]
    # or many input sets and penalties at once, each against the shipped margin seed by seed
    python benchmarks/fit_chooser.py sweep --fit fit.json --on yud.json ecd.json --variants all:0.01 log_ratio:1.0

The fit is a logistic regression (L2 penalty on standardised inputs, Newton's method) of "the hypothesis' horizon
error is below the frame's", each record weighted by how much the choice moves the horizon AUC (the difference of
the two errors, each capped at 0.25 image heights); records where both candidates are the same are left out.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.api import _inputs, load_parser
from ngp_kornia.evaluation import load_manifest, load_renders, load_yud
from ngp_kornia.geometry import (
    frame_manhattan_scores,
    horizon_from_zenith,
    normalize,
    pseudo_focal,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
    zenith_from_up,
)
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.metrics import horizon_auc, horizon_error
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.horizon import Refinement, _with_up, search_horizon
from ngp_kornia.pipeline.result import Calibration

MARGIN = 0.08  # the shipped rule


class Chooser(NamedTuple):
    """A fitted chooser: the hypothesis is taken where ``sigmoid(((x - mean) / std) . weights + bias) > threshold``."""

    inputs: tuple
    mean: tuple
    std: tuple
    weights: tuple
    bias: float
    threshold: float = 0.5

    @classmethod
    def load(cls, path: Path) -> Chooser:
        d = json.loads(Path(path).read_text())
        return cls(
            tuple(d["inputs"]),
            tuple(d["mean"]),
            tuple(d["std"]),
            tuple(d["weights"]),
            d["bias"],
            d.get("threshold", 0.5),
        )


#: every feature :func:`chooser_features` computes, in its order
FEATURE_NAMES = (
    "log_ratio",
    "gain",
    "frame_support",
    "log_shift",
    "log_scale",
    "zenith_turn",
    "roll_change",
    "peak1",
    "peak2",
    "frame_peak1",
    "frame_peak2",
    "peak_gain",
    "log_score",
    "frame_confidence",
    "log_pitch_std",
    "fsnet_gain",
    "manhattan_gain",
)
#: the last two are computed by :func:`frame_scores_of`, not :func:`chooser_features`
_SCORED = ("fsnet_gain", "manhattan_gain")


def hypothesis_horizon(found: Refinement) -> Tensor:
    """(B, 3) pixel horizon of the refinement's best hypothesis, ``K^-T up`` (``found``: a
    :class:`Refinement`)."""
    zenith = zenith_from_up(found.K, found.up)
    zenith = zenith / zenith.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return horizon_from_zenith(found.K, zenith)


def _border_y(lines: Tensor, height: Tensor, width: Tensor) -> Tensor:
    """(B, 3) pixel lines -> (B, 2) their y at the left and right borders, in image heights (clamped)."""
    a, b, c = lines.unbind(-1)
    b = torch.where(b.abs() < 1e-9, torch.full_like(b, 1e-9), b)
    xs = torch.stack([torch.full_like(width, -0.5), width - 0.5], -1)
    y = -(a[:, None] * xs + c[:, None]) / b[:, None]
    return (y / height[:, None]).clamp(-100.0, 100.0)


def _angle(u: Tensor, v: Tensor) -> Tensor:
    """Degrees between unit vectors (B, 3)."""
    return torch.rad2deg(torch.acos((u * v).sum(-1).clamp(-1.0, 1.0)))


def _or_zero(value, cal: Calibration) -> Tensor:
    return torch.zeros_like(cal.focal) if value is None else value.to(cal.focal)


def chooser_features(cal: Calibration, found: Refinement) -> Tensor:
    """The chooser's inputs but :data:`_SCORED`, (B, len(FEATURE_NAMES) - 2) in the order of :data:`FEATURE_NAMES`,
    finite.

    Args:
        cal: the frame search's calibration (batched).
        found: the refinement's :class:`Refinement` for it.
    """
    tiny = 1e-6
    height, width = cal.image_size[:, 0].to(cal.K), cal.image_size[:, 1].to(cal.K)
    shift = (_border_y(cal.horizon, height, width) - _border_y(hypothesis_horizon(found), height, width)).abs()
    roll_change = (found.up[:, 0] - cal.up[:, 0]).abs()  # sin of the roll change, about
    p, fp = found.peaks, found.frame_peaks
    cols = [
        torch.log(found.support.clamp_min(tiny) / found.frame_support.clamp_min(tiny)),
        found.support - found.frame_support,
        found.frame_support,
        torch.log(shift.amax(-1) + 0.01),
        found.scale.clamp_min(tiny).log().abs(),
        torch.log1p(_angle(found.up_refined, cal.up)),
        torch.log1p(torch.rad2deg(torch.asin(roll_change.clamp_max(1.0)))),
        p[:, 0],
        p[:, 1] if p.shape[1] > 1 else torch.zeros_like(p[:, 0]),
        fp[:, 0],
        fp[:, 1] if fp.shape[1] > 1 else torch.zeros_like(fp[:, 0]),
        p.sum(-1) - fp.sum(-1),
        torch.log(cal.score.to(cal.K).clamp_min(tiny)),
        torch.logit(_or_zero(cal.confidence, cal).clamp(0.001, 0.999)),
        torch.log(_or_zero(cal.pitch_std, cal).clamp_min(0.01)),
    ]
    out = torch.stack(cols, -1)
    return torch.where(torch.isfinite(out), out, torch.zeros_like(out))


def load_set(kind: str, path: Path) -> list[tuple]:
    """(name, image path, height, width, {ground truth: horizon}) per image."""
    if kind == "yud":
        cal = {s.name: s for s in load_yud(path, horizon="calibrated")}
        pub = {s.name: s for s in load_yud(path, horizon="published")}
        return [
            (n, s.image_path, s.height, s.width, {"calibrated": s.horizon, "published": pub[n].horizon})
            for n, s in cal.items()
        ]
    samples = load_renders(path) if kind == "rendered" else load_manifest(path)
    return [(s.name, s.image_path, s.height, s.width, {"horizon": s.horizon}) for s in samples]


def _errors(line: torch.Tensor, truths: dict, height: int, width: int) -> dict:
    return {gt: float(horizon_error(line.double(), t[None].double(), height, width)[0]) for gt, t in truths.items()}


def frame_scores_of(parser, batch, segments, mask, cals: list[Calibration]) -> tuple[Tensor, Tensor]:
    """FSNet logits (B, C) and Manhattan scores (B, C) of the Manhattan frames of ``C`` calibrations (each one's
    ``R`` and focal length, in the pseudo camera), scored as the parser scores its frame candidates."""
    height, width = (int(v) for v in cals[0].image_size[0])
    f = torch.stack([c.focal for c in cals], 1) / pseudo_focal(height, width)  # (B, C)
    R = torch.stack([c.R for c in cals], 1)  # (B, C, 3, 3)
    scale = torch.stack([f, f, torch.ones_like(f)], -1)
    vps = normalize(R.transpose(-1, -2) * scale[..., None, :])
    frames = FrameCandidates(vps[..., 1, :], vps[..., 0, :], f, R, vps, torch.ones_like(f, dtype=torch.bool))
    fs = parser.fsnet
    logits = fs(*fs.prepare_inputs(batch.to(R), segments.to(R), mask, frames))
    seg = to_pseudo_camera(segments.to(R), height, width)
    lengths = segment_lengths(segments.to(R)) * mask.to(R)
    manhattan = frame_manhattan_scores(segments_to_lines(seg), vps, lengths, mask, parser.config.kernel_angle)
    return logits, manhattan


def collect_image(parser, image: tuple, seeds: list[int]) -> list[dict]:
    name, path, height, width, truths = image
    cfg = parser.config
    batch, segments, mask, orientation, _ = _inputs(str(path), cfg)
    if orientation not in (None, 1):
        print(f"warning: {name} has EXIF orientation {orientation}; horizons compared unrotated", file=sys.stderr)
    out = []
    for seed in seeds:
        parser.config = replace(cfg, seed=seed, refine_horizon=False)
        with torch.no_grad():
            cal = parser(batch, segments, mask)
            seg = segments.to(batch)
            found = search_horizon(cal, seg, mask)
            feats = chooser_features(cal, found)[0].tolist()
            keep_focal = _with_up(cal, torch.ones_like(cal.valid), cal.K, found.up, found.horizontal).horizon
            hyp = _with_up(cal, torch.ones_like(cal.valid), found.K, found.up, found.horizontal)
            logits, manhattan = frame_scores_of(parser, batch, seg, mask, [cal, hyp])
            feats += [float(logits[0, 1] - logits[0, 0]), float(torch.log(manhattan[0, 1] / manhattan[0, 0]))]
        shipped = bool(cal.valid[0]) and float(found.support[0]) > float(found.frame_support[0]) * (1 + MARGIN)
        out.append(
            dict(
                name=name,
                seed=seed,
                features=feats,
                valid=bool(cal.valid[0] & torch.isfinite(found.up).all()),
                better_support=bool(found.support[0] > found.frame_support[0]),
                shipped=shipped,
                frame=_errors(cal.horizon, truths, height, width),
                hypothesis=_errors(hypothesis_horizon(found), truths, height, width),
                keep_focal=_errors(keep_focal, truths, height, width),
            )
        )
    parser.config = cfg
    return out


def collect(args) -> None:
    seeds = [int(s) for s in args.seeds.split(",")]
    images = load_set(args.kind, args.path)[: args.limit]
    parser = load_parser(args.weights, ParserConfig())
    records = []
    for i, image in enumerate(images):
        records += collect_image(parser, image, seeds)
        print(f"\r{i + 1}/{len(images)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    payload = dict(command=" ".join(sys.argv), kind=args.kind, features=list(FEATURE_NAMES), records=records)
    args.out.write_text(json.dumps(payload))
    print(f"wrote {len(records)} records to {args.out}")


def training_arrays(records: list[dict], inputs: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs, labels (hypothesis better) and weights of the records where the choice matters."""
    index = [FEATURE_NAMES.index(n) for n in inputs]
    xs, ys, ws = [], [], []
    for r in records:
        if not (r["valid"] and r["better_support"]):
            continue
        for gt in r["frame"]:
            ef, eh = min(r["frame"][gt], 0.25), min(r["hypothesis"][gt], 0.25)
            if abs(ef - eh) < 1e-4:
                continue
            xs.append([r["features"][i] for i in index])
            ys.append(float(eh < ef))
            ws.append(abs(ef - eh))
    return np.asarray(xs), np.asarray(ys), np.asarray(ws)


def logistic_fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, l2: float) -> tuple[np.ndarray, float]:
    """Weighted L2-penalised logistic regression by Newton's method: (coefficients, bias)."""
    X = np.hstack([x, np.ones((len(x), 1))])
    beta = np.zeros(X.shape[1])
    w = w / w.sum()
    pen = np.full(X.shape[1], l2)
    pen[-1] = 0.0
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-X @ beta))
        grad = X.T @ (w * (p - y)) + pen * beta
        hess = (X * (w * p * (1 - p))[:, None]).T @ X + np.diag(pen)
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.abs(step).max() < 1e-10:
            break
    return beta[:-1], float(beta[-1])


def fit_model(records: list[dict], inputs: list[str], l2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(mean, std, coefficients, bias) of the chooser on ``inputs`` fitted on ``records``."""
    x, y, w = training_arrays(records, inputs)
    mean, std = x.mean(0), x.std(0) + 1e-9
    coef, bias = logistic_fit((x - mean) / std, y, w, l2)
    return mean, std, coef, bias


def fit(args) -> None:
    records = [r for path in args.records for r in json.loads(path.read_text())["records"]]
    inputs = args.inputs.split(",") if args.inputs else list(FEATURE_NAMES)
    x, y, _ = training_arrays(records, inputs)
    mean, std, coef, bias = fit_model(records, inputs, args.l2)
    model = dict(
        fitted_on=[str(p) for p in args.records],
        records=len(x),
        l2=args.l2,
        threshold=args.threshold,
        inputs=inputs,
        mean=[round(float(v), 6) for v in mean],
        std=[round(float(v), 6) for v in std],
        weights=[round(float(v), 6) for v in coef],
        bias=round(bias, 6),
    )
    args.out.write_text(json.dumps(model, indent=1) + "\n")
    print(f"fitted on {len(x)} choices ({int(y.sum())} for the hypothesis); wrote {args.out}")
    for name, c in zip(inputs, coef, strict=True):
        print(f"  {name:14s} {c:+.3f}")


def probabilities(model: Chooser, records: list[dict]) -> np.ndarray:
    index = [FEATURE_NAMES.index(n) for n in model.inputs]
    x = np.asarray([[r["features"][i] for i in index] for r in records])
    z = ((x - np.asarray(model.mean)) / np.asarray(model.std)) @ np.asarray(model.weights) + model.bias
    return 1.0 / (1.0 + np.exp(-z))


def rule_errors(
    records: list[dict], gt: str, model: Chooser | None, fsnet_override: float | None = None
) -> dict[str, list[float]]:
    """Per rule, the horizon errors of the records against one ground truth: the frame's horizon, the shipped
    margin, the per-image oracle, with ``model`` the chooser (with the hypothesis' focal length, and with the frame's
    kept), with ``fsnet_override`` the shipped margin or else FSNet's logit of the hypothesis' frame above the
    frame's by more than that."""
    prob = probabilities(model, records) if model is not None else np.zeros(len(records))
    out: dict[str, list[float]] = {"frame": [], "shipped": [], "oracle": []}
    if model is not None:
        out["chooser"], out["chooser_keep_focal"] = [], []
    if fsnet_override is not None:
        out["shipped_or_fsnet"] = []
    gain = FEATURE_NAMES.index("fsnet_gain")
    for r, p in zip(records, prob, strict=True):
        ok = r["valid"] and r["better_support"]
        ef, eh, ek = r["frame"][gt], r["hypothesis"][gt], r["keep_focal"][gt]
        out["frame"].append(ef)
        out["shipped"].append(eh if r["shipped"] and ok else ef)
        out["oracle"].append(min(ef, eh) if ok else ef)
        if model is not None:
            out["chooser"].append(eh if ok and p > model.threshold else ef)
            out["chooser_keep_focal"].append(ek if ok and p > model.threshold else ef)
        if fsnet_override is not None:
            take = ok and (r["shipped"] or r["features"][gain] > fsnet_override)
            out["shipped_or_fsnet"].append(eh if take else ef)
    return out


def check(args) -> None:
    model = Chooser.load(args.model) if args.model else None
    if model is not None and args.threshold is not None:
        model = model._replace(threshold=args.threshold)
    table: dict[str, dict[str, list[float]]] = {}
    for path in args.records:
        data = json.loads(path.read_text())
        records = data["records"]
        seeds = sorted({r["seed"] for r in records})
        for gt in records[0]["frame"]:
            label = f"{path.stem}:{gt}"
            for seed in seeds:
                errs = rule_errors([r for r in records if r["seed"] == seed], gt, model, args.fsnet_override)
                for rule, e in errs.items():
                    table.setdefault(label, {}).setdefault(rule, []).append(100 * float(horizon_auc(e)))
    rules = list(next(iter(table.values())))
    print("| set | " + " | ".join(rules) + " |")
    print("|---|" + "---:|" * len(rules))
    for label, row in table.items():
        print(f"| {label} | " + " | ".join(f"{statistics.mean(v):.2f}" for v in row.values()) + " |")
    if len(table) > 1:
        mean = {
            rule: [statistics.mean(row[rule][i] for row in table.values()) for i in range(len(row[rule]))]
            for rule in rules
        }
        print("| mean | " + " | ".join(f"{statistics.mean(v):.2f}" for v in mean.values()) + " |")
        for rule in rules:
            print(f"{rule} per seed: " + ", ".join(f"{v:.2f}" for v in mean[rule]))
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))


def mean_per_seed(paths: list[Path], rule: str, model: Chooser | None) -> list[float]:
    """Horizon AUC (%) per seed of one rule, averaged over every ground truth of every record file."""
    rows = []
    for path in paths:
        records = json.loads(path.read_text())["records"]
        seeds = sorted({r["seed"] for r in records})
        for gt in records[0]["frame"]:
            errs = [rule_errors([r for r in records if r["seed"] == s], gt, model)[rule] for s in seeds]
            rows.append([100 * float(horizon_auc(e)) for e in errs])
    return [statistics.mean(col) for col in zip(*rows, strict=True)]


def sweep(args) -> None:
    """Fit every variant (``INPUTS:L2``, inputs comma-separated or ``all``) on the fitting records and compare it
    with the shipped margin on the checked records, seed by seed."""
    fit_records = [r for path in args.fit for r in json.loads(path.read_text())["records"]]
    shipped = mean_per_seed(args.on, "shipped", None)
    print(f"shipped: {statistics.mean(shipped):.2f} per seed " + ", ".join(f"{v:.2f}" for v in shipped))
    for variant in args.variants:
        names, _, l2 = variant.rpartition(":")
        inputs = list(FEATURE_NAMES) if names == "all" else names.split(",")
        mean, std, coef, bias = fit_model(fit_records, inputs, float(l2))
        model = Chooser(tuple(inputs), tuple(mean), tuple(std), tuple(coef), bias)
        vals = mean_per_seed(args.on, "chooser", model)
        wins = sum(v > s + 1e-9 for v, s in zip(vals, shipped, strict=True))
        print(
            f"{variant}: {statistics.mean(vals):.2f} per seed "
            + ", ".join(f"{v:.2f}" for v in vals)
            + f" (above the shipped margin on {wins} of {len(vals)} seeds)"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("kind", choices=["rendered", "yud", "manifest"])
    c.add_argument("path", type=Path)
    c.add_argument("--seeds", default="0")
    c.add_argument("--weights", default="default")
    c.add_argument("--limit", type=int, default=None)
    c.add_argument("--out", type=Path, required=True)
    f = sub.add_parser("fit")
    f.add_argument("records", type=Path, nargs="+")
    f.add_argument("--inputs", default=None, help="comma-separated feature names (default: all)")
    f.add_argument("--l2", type=float, default=1e-2)
    f.add_argument("--threshold", type=float, default=0.5)
    f.add_argument("--out", type=Path, required=True)
    k = sub.add_parser("check")
    k.add_argument("records", type=Path, nargs="+")
    k.add_argument("--model", type=Path, default=None)
    k.add_argument("--threshold", type=float, default=None)
    k.add_argument("--json", type=Path, default=None)
    k.add_argument("--fsnet-override", type=float, default=None, help="add the rule: shipped margin or FSNet gain > T")
    w = sub.add_parser("sweep")
    w.add_argument("--fit", type=Path, nargs="+", required=True)
    w.add_argument("--on", type=Path, nargs="+", required=True)
    w.add_argument("--variants", nargs="+", required=True, help="INPUTS:L2, e.g. log_ratio,log_shift:1.0 or all:0.01")
    args = ap.parse_args(argv)
    {"collect": collect, "fit": fit, "check": check, "sweep": sweep}[args.cmd](args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
