"""Check the trust model on records written by ``benchmarks/fit_confidence.py collect``: calibration of the
confidence, risk-coverage, one- and two-sigma coverage of the standard deviations, and the focal-length prior.

The confidence and the standard deviations are recomputed from each record's features with the coefficients file
(``--model``, the shipped one by default), so records collected once serve any fit. Usage::

    python benchmarks/trust_report.py --renders test_s0.json --real yud_s0.json ecd_s0.json \\
        [--prior-pairs test_s0.json:testprior_s0.json ...] [--plots docs/] \\
        [--principal-point-std 0.02] [--renders-principal-point-std 0]

The principal-point term of the standard deviations uses ``--principal-point-std`` for the real photos (the
parser's default by default) and ``--renders-principal-point-std`` for the renders (0: centred, as renders are
unless ``RenderConfig.centre_std`` moved them).

* expected calibration error (ECE): 10 equal-width confidence bins, the count-weighted mean of
  |mean confidence - share of errors below the threshold|;
* flagging: the confidence threshold that flags (puts below it) at most 10% of the answers whose error is below the
  threshold, and the share of gross errors (> 0.1 image heights) it flags;
* risk-coverage: horizon AUC of the answers kept after dropping the 10% / 20% least confident, beside dropping
  by the raw score and beside the oracle that drops the truly worst; "share of the oracle's gain" is
  (AUC kept - AUC all) / (AUC oracle - AUC all);
* sigma coverage: the share of |signed error| within one and two standard deviations (pitch, roll, vertical FoV).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch

from ngp_kornia.metrics import horizon_auc
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.trust import TRUST_FILE, TrustFeatures, TrustModel, principal_point_terms

GROSS = 0.1


def load(paths: list[Path]) -> list[dict]:
    return [r for p in paths for r in json.loads(Path(p).read_text())["records"]]


def trust_of(records: list[dict], model: TrustModel, principal_point_std: float = 0.0) -> dict[str, np.ndarray]:
    """Confidence and standard deviations of the records from their features (answers without a frame: 0)."""
    feats = TrustFeatures(
        **{k: torch.tensor([r["features"][k] for r in records], dtype=torch.float64) for k in records[0]["features"]}
    )
    conf = model.confidence(feats)
    # the orientation and structure check scales the confidence after the trust model (records that carry it)
    upright = torch.tensor([r.get("upright_factor", r.get("upright", 1.0)) for r in records], dtype=torch.float64)
    floor = None
    if principal_point_std > 0:
        if any("pitch_answer" not in r for r in records):
            raise SystemExit("records without the answer's focal length and pitch: collect them again")
        focal, pitch = (torch.tensor([r[k] for r in records], dtype=torch.float64) for k in ("focal", "pitch_answer"))
        floor = principal_point_terms(principal_point_std, focal, records[0]["height"], pitch)
    stds = model.stds(feats, conf, floor)
    valid = torch.tensor([r["valid"] for r in records])
    out = {"confidence": torch.where(valid, conf * upright, torch.zeros_like(conf)).numpy()}
    out.update({name: v.numpy() for name, v in stds.items()})
    return out


def ece(conf: np.ndarray, hit: np.ndarray, bins: int = 10) -> float:
    edges = np.linspace(0, 1, bins + 1)
    idx = np.clip(np.digitize(conf, edges) - 1, 0, bins - 1)
    total = 0.0
    for b in range(bins):
        sel = idx == b
        if sel.any():
            total += sel.sum() * abs(conf[sel].mean() - hit[sel].mean())
    return float(total / len(conf))


def auc(errors: np.ndarray) -> float:
    return float(horizon_auc(torch.as_tensor(errors, dtype=torch.float64)))


def kept_auc(errors: np.ndarray, order_key: np.ndarray, drop: float) -> float:
    """AUC after dropping the ``drop`` share with the lowest ``order_key``."""
    keep = np.argsort(-order_key, kind="stable")[: int(round(len(errors) * (1 - drop)))]
    return auc(errors[keep])


def risk_coverage(errors: np.ndarray, conf: np.ndarray, score: np.ndarray) -> dict:
    out = {"all": auc(errors)}
    for drop in (0.1, 0.2):
        oracle = kept_auc(errors, -errors, drop)
        c, s = kept_auc(errors, conf, drop), kept_auc(errors, score, drop)
        gain = oracle - out["all"]
        out[f"drop{int(drop * 100)}"] = {
            "oracle": oracle,
            "confidence": c,
            "score": s,
            "confidence_share": (c - out["all"]) / gain if gain > 0 else math.nan,
            "score_share": (s - out["all"]) / gain if gain > 0 else math.nan,
        }
    return out


def flagging(conf: np.ndarray, errors: np.ndarray, threshold: float) -> dict:
    good, gross = errors < threshold, errors > GROSS
    # the highest cut that flags at most 10% of the good answers
    cut = float(np.sort(conf[good])[int(0.10 * good.sum())]) if good.any() else 0.0
    return {
        "cut": cut,
        "good_flagged": float((conf[good] < cut).mean()) if good.any() else math.nan,
        "gross": int(gross.sum()),
        "gross_flagged": float((conf[gross] < cut).mean()) if gross.any() else math.nan,
    }


def sigma_coverage(records: list[dict], trust: dict[str, np.ndarray]) -> dict:
    out = {}
    for name in ("pitch", "roll", "fov_v"):
        key = f"{name}_signed" if name != "fov_v" else "fov_v"
        err = np.array([abs(r.get(key, math.nan)) for r in records], dtype=np.float64)
        ok = np.isfinite(err) & np.array([r["valid"] for r in records])
        if not ok.any():
            continue
        std = trust[name][ok]
        out[name] = {
            "n": int(ok.sum()),
            "within1": float((err[ok] <= std).mean()),
            "within2": float((err[ok] <= 2 * std).mean()),
            "median_std": float(np.median(std)),
            "median_error": float(np.median(err[ok])),
        }
    return out


def centred_yud_records(records: list[dict], root: Path) -> list[dict]:
    """York Urban records with pitch and roll errors against what a method that puts the principal point at the
    image centre can reach: the true horizon line (pixels) read back through a K with the same focal length and a
    centred principal point. The database's principal point is 12 px below the centre, about 1 degree of pitch."""
    from ngp_kornia.data.yud import YorkUrbanDB
    from ngp_kornia.geometry.camera import pitch_roll_from_up

    truth = {}
    for s in YorkUrbanDB(root):
        K_c = s.K.clone()
        K_c[0, 2], K_c[1, 2] = (s.width - 1) / 2.0, (s.height - 1) / 2.0
        up = K_c.T @ torch.linalg.solve(s.K.T, s.up)  # the horizon K^-T up seen through K_c
        up = up if up[1] <= 0 else -up
        pitch, roll = pitch_roll_from_up(up[None])
        truth[s.name] = (s.pitch - float(pitch[0]), s.roll - float(roll[0]))
    return [
        {
            **r,
            "pitch_signed": r["pitch_signed"] + truth[r["name"]][0],
            "roll_signed": r["roll_signed"] + truth[r["name"]][1],
        }
        for r in records
    ]


def section(records: list[dict], model: TrustModel, principal_point_std: float = 0.0) -> dict:
    trust = trust_of(records, model, principal_point_std)
    errors = np.array([r["horizon"] for r in records])
    hit = (errors < model.threshold).astype(np.float64)
    score = np.array([r["score"] for r in records])
    return {
        "n": len(records),
        "below_threshold": float(hit.mean()),
        "mean_confidence": float(trust["confidence"].mean()),
        "ece": ece(trust["confidence"], hit),
        "ece_score": ece(score, hit),
        "flagging": flagging(trust["confidence"], errors, model.threshold),
        "risk_coverage": risk_coverage(errors, trust["confidence"], score),
        "sigma": sigma_coverage(records, trust),
        "_conf": trust["confidence"],
        "_hit": hit,
        "_errors": errors,
        "_score": score,
    }


def prior_effect(pairs: list[tuple[Path, Path]]) -> list[dict]:
    """Horizon AUC and up-error median without and with the true focal length, per pair of record files."""
    rows = []
    for without, with_prior in pairs:
        a, b = load([without]), load([with_prior])
        row = {"without": str(without), "with": str(with_prior)}
        for label, recs in (("none", a), ("prior", b)):
            row[f"auc_{label}"] = auc(np.array([r["horizon"] for r in recs]))
            if "horizon_calibrated" in recs[0]:
                row[f"auc_calibrated_{label}"] = auc(np.array([r["horizon_calibrated"] for r in recs]))
            up = np.array([r.get("up", math.nan) for r in recs])
            row[f"up_median_{label}"] = float(np.nanmedian(up))
        rows.append(row)
    return rows


def reliability_plot(sections: dict[str, dict], path: Path, threshold: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="perfect calibration")
    edges = np.linspace(0, 1, 11)
    for (name, sec), marker in zip(sections.items(), "os^", strict=False):
        conf, hit = sec["_conf"], sec["_hit"]
        idx = np.clip(np.digitize(conf, edges) - 1, 0, 9)
        xs, ys, ns = [], [], []
        for b in range(10):
            sel = idx == b
            if sel.sum() >= 3:
                xs.append(conf[sel].mean())
                ys.append(hit[sel].mean())
                ns.append(sel.sum())
        ax.plot(xs, ys, marker=marker, label=f"{name} (n={sec['n']}, ECE {sec['ece']:.3f})")
    ax.set_xlabel("confidence (mean of the bin)")
    ax.set_ylabel(f"share with horizon error < {threshold}")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("Reliability of the confidence\n(bins of width 0.1 holding >= 3 answers)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def risk_coverage_plot(sections: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(sections), figsize=(5 * len(sections), 4), squeeze=False)
    for ax, (name, sec) in zip(axes[0], sections.items(), strict=True):
        errors = sec["_errors"]
        drops = np.linspace(0, 0.5, 26)
        for key, label, style in (
            (-errors, "oracle (drop the worst)", "k--"),
            (sec["_conf"], "drop the least confident", "C0-"),
            (sec["_score"], "drop the lowest score", "C1:"),
        ):
            ax.plot(1 - drops, [100 * kept_auc(errors, key, d) for d in drops], style, label=label)
        ax.set_xlabel("coverage (share of answers kept)")
        ax.set_ylabel("horizon AUC of the kept answers (%)")
        ax.set_title(f"{name} (n={sec['n']})")
        ax.invert_xaxis()
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def strip(sec: dict) -> dict:
    return {k: v for k, v in sec.items() if not k.startswith("_")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--renders", type=Path, nargs="+", required=True, help="records of test renders")
    parser.add_argument("--real", type=Path, nargs="+", default=[], help="records of real photos (pooled)")
    parser.add_argument("--yud", type=Path, nargs="*", default=[], help="York Urban records for sigma coverage")
    parser.add_argument(
        "--yud-root", type=Path, default=None, help="York Urban folder: also errors against a centred principal point"
    )
    parser.add_argument("--prior-pairs", nargs="*", default=[], help="WITHOUT.json:WITH.json record pairs")
    parser.add_argument("--model", type=Path, default=TRUST_FILE)
    parser.add_argument("--plots", type=Path, default=None, help="folder for the PNGs")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--principal-point-std", type=float, default=ParserConfig().trust.centre_std)
    parser.add_argument("--renders-principal-point-std", type=float, default=0.0)
    args = parser.parse_args(argv)

    model, pp = TrustModel.load(args.model), args.principal_point_std
    sections = {"renders": section(load(args.renders), model, args.renders_principal_point_std)}
    if args.real:
        sections["real photos pooled"] = section(load(args.real), model, pp)
    if args.yud:
        sections["York Urban"] = section(load(args.yud), model, pp)
        if args.yud_root is not None:
            sections["York Urban, centred principal point"] = section(
                centred_yud_records(load(args.yud), args.yud_root), model, pp
            )
    report = {name: strip(sec) for name, sec in sections.items()}
    pairs = [tuple(Path(p) for p in pair.split(":")) for pair in args.prior_pairs]
    if pairs:
        report["prior"] = prior_effect(pairs)
    print(json.dumps(report, indent=1))
    if args.plots is not None:
        args.plots.mkdir(parents=True, exist_ok=True)
        shown = {k: v for k, v in sections.items() if not k.startswith("York Urban")}
        reliability_plot(shown, args.plots / "confidence_reliability.png", model.threshold)
        risk_coverage_plot(shown, args.plots / "confidence_risk_coverage.png")
    if args.out is not None:
        args.out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
