"""Fit the trust model (confidence and standard deviations) that ships in ``ngp_kornia/weights/trust.json``.

Two steps, so the expensive one runs once per data set and seed::

    # 1. run calibrate() and record, per image, the trust features, the answer and its errors
    python benchmarks/fit_confidence.py collect rendered /tmp/renders_fit --out fit.json          # renders only
    python benchmarks/fit_confidence.py collect yud /path/to/YorkUrbanDB --out yud.json           # for checking
    python benchmarks/fit_confidence.py collect manifest /path/to/manifest.csv --out ecd.json     # for checking
        options: --seed S, --weights SPEC (as benchmarks/calibration.py), --prior {none,true,exif}, --limit N
        (--prior true gives the sample's focal length: York Urban's, a render's, or a manifest's focal_px column)
    # 2. fit the coefficients on the renders' records and write them
    python benchmarks/fit_confidence.py fit fit.json --out ngp_kornia/weights/trust.json
    # 3. fit the gains of the principal-point term on renders with off-centre principal points (ngp render --config
    #    with principal_point_std), keeping the confidence and the line / spread terms of step 2
    python benchmarks/fit_confidence.py principal-point fit_pp.json --principal-point-std 0.02 \
        --model ngp_kornia/weights/trust.json --out ngp_kornia/weights/trust.json

The confidence is a logistic regression (L2 penalty 1e-2 on standardised inputs, Newton's method) of
``horizon error < threshold`` on :func:`ngp_kornia.pipeline.trust.confidence_inputs`. Each standard deviation is
``exp(a + b * log(spread + 0.01) + c * logit(confidence))``: (b, c) and a first ``a`` by least squares on
``log |error|``, then ``a`` shifted so that 68.3% of the fitting errors lie within one standard deviation (the
share a normal distribution puts there). Fit on renders only, never on the real photos used to check it.

Step 3: with the principal point off the centre by ``principal_point_std`` image heights per axis (the renders'
``RenderConfig.centre_std``; the records carry the answer's focal length and pitch), each standard
deviation becomes ``hypot(line term, k * t)`` with ``t`` from
:func:`ngp_kornia.pipeline.trust.principal_point_terms`; ``k`` per parameter is the smallest gain (by bisection)
that puts 68.3% of the errors within one standard deviation, 0 where the line term alone already does.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

import ngp_kornia.pipeline.frame_search as search_module
from ngp_kornia import calibrate
from ngp_kornia.evaluation import LabelledImage as Sample
from ngp_kornia.evaluation import load_renders as load_rendered
from ngp_kornia.evaluation import load_yud, weights_and_config
from ngp_kornia.metrics import fov_error, horizon_error, pitch_error, roll_error, up_vector_error
from ngp_kornia.pipeline.trust import (
    INPUT_NAMES,
    STD_SPREADS,
    TRUST_FILE,
    TrustFeatures,
    TrustModel,
    confidence_inputs,
    principal_point_terms,
    trust_features,
)

THRESHOLD = 0.02
#: exponent of the line-noise term of the standard deviations (TrustModel.residual_exponent), fixed, not fitted:
#: the fitting renders hardly vary in line noise, so a fitted exponent would say little about real photos
RESIDUAL_EXPONENT = 1.0
#: York Urban's calibrated horizon (its own K and vp_orthogonal) by image name; samples carry the published one
CALIBRATED_HORIZON: dict[str, torch.Tensor] = {}


# ----------------------------------------------------------------------------------------------------------
# samples


def load_manifest(path: Path) -> list[Sample]:
    """Samples of a CSV manifest; fields the manifest does not give (pitch, roll, focal for ECD) are NaN."""
    from ngp_kornia.data import CSVManifest

    nan3 = torch.full((3,), math.nan, dtype=torch.float64)
    out = []
    for s in CSVManifest(path):
        if s.horizon is None:
            raise SystemExit(f"{s.image_path}: the manifest gives no horizon")
        out.append(
            Sample(
                name=s.image_path.stem,
                image_path=s.image_path,
                K=s.K if s.K is not None else torch.full((3, 3), math.nan, dtype=torch.float64),
                up=s.up if s.up is not None else nan3,
                horizon=s.horizon,
                pitch=math.nan if s.pitch is None else s.pitch,
                roll=math.nan if s.roll is None else s.roll,
                fov_v=math.nan if s.fov_v is None else s.fov_v,
                height=s.height,
                width=s.width,
                kind="manifest",
            )
        )
    return out


def load_samples(dataset: str, path: Path) -> list[Sample]:
    if dataset == "rendered":
        return load_rendered(path)
    if dataset == "manifest":
        return load_manifest(path)
    calibrated = load_yud(path, "all", horizon="calibrated", ground_truth="orthogonal")
    CALIBRATED_HORIZON.update((s.name, s.horizon) for s in calibrated)
    return [replace(s, kind="yud") for s in load_yud(path, "all", horizon="published", ground_truth="orthogonal")]


# ----------------------------------------------------------------------------------------------------------
# collecting


def _record(s: Sample, cal, feats: dict, lines_confidence: float | None = None) -> dict:
    """One record: the trust features, the answer's trust outputs, focal length and pitch, and its errors;
    ``lines_confidence`` is the confidence before the orientation check."""
    h_err = float(horizon_error(cal.horizon[None].double(), s.horizon[None], s.height, s.width)[0])
    rec = {
        "name": s.name,
        "kind": s.kind,
        "features": feats,
        "valid": bool(cal.valid),
        "score": float(cal.score),
        "confidence": float(cal.confidence),
        "pitch_std": float(cal.pitch_std),
        "roll_std": float(cal.roll_std),
        "fov_v_std": float(cal.fov_v_std),
        "horizon": h_err,
        "focal": float(cal.focal),
        "pitch_answer": float(cal.pitch),
        "height": s.height,
    }
    if cal.upright is not None:  # the orientation and structure check: its reading and the factor it applied
        rec["upright"] = float(cal.upright)
        if lines_confidence:
            rec["upright_factor"] = float(cal.confidence) / lines_confidence
    if s.name in CALIBRATED_HORIZON:
        truth = CALIBRATED_HORIZON[s.name][None]
        calibrated = horizon_error(cal.horizon[None].double(), truth, s.height, s.width)
        rec["horizon_calibrated"] = float(calibrated[0])
    if math.isfinite(s.pitch):
        p = torch.tensor([float(cal.pitch)], dtype=torch.float64)
        r = torch.tensor([float(cal.roll)], dtype=torch.float64)
        rec["pitch_signed"] = float(cal.pitch) - s.pitch
        rec["roll_signed"] = float(cal.roll) - s.roll
        rec["pitch"] = float(pitch_error(p, torch.tensor([s.pitch], dtype=torch.float64))[0])
        rec["roll"] = float(roll_error(r, torch.tensor([s.roll], dtype=torch.float64))[0])
        rec["up"] = float(up_vector_error(cal.up[None].double(), s.up[None])[0])
    if math.isfinite(s.fov_v):
        fov = torch.tensor([float(cal.fov_v)], dtype=torch.float64)
        rec["fov_v"] = float(fov_error(fov, torch.tensor([s.fov_v], dtype=torch.float64))[0])
    return rec


def collect(samples: list[Sample], spec: str | None, seed: int, prior: str) -> list[dict]:
    """Run calibrate() on every sample; one record per image: features, answer, trust outputs, errors."""
    weights, config = weights_and_config(spec)
    captured: list[TrustFeatures] = []
    lines_confidence: list[torch.Tensor] = []  # before the orientation check
    attach = search_module.attach_trust

    def recording(result, frames, scores, segments, mask, *args, **kwargs):
        with torch.no_grad():
            scoring = args[0] if args else kwargs.get("scoring")  # attach_trust's ScoringSettings
            extra = {k: kwargs.get(k) for k in ("shared", "refinement", "residual_vps")}
            captured.append(trust_features(result, frames, scores, segments, mask, scoring.top_k,
                                           scoring.kernel_angle, **extra))
        out = attach(result, frames, scores, segments, mask, *args, **kwargs)
        lines_confidence.append(out.confidence)
        return out

    search_module.attach_trust = recording
    records = []
    try:
        for i, s in enumerate(samples):
            given = {}
            if prior == "true":
                if not math.isfinite(float(s.K[0, 0])):
                    raise SystemExit(f"{s.name}: --prior true needs a known focal length")
                given = {"focal": float(s.K[0, 0])}
            elif prior == "exif":
                given = {"exif": True}
            cal = calibrate(str(s.image_path), weights=weights, seed=seed, config=config, priors=given)
            feats = {k: float(v[0]) for k, v in captured.pop().as_dict().items()}
            records.append(_record(s, cal, feats, float(lines_confidence.pop().reshape(-1)[0])))
            print(f"\r{i + 1}/{len(samples)} {s.name}", end="", file=sys.stderr, flush=True)
    finally:
        search_module.attach_trust = attach
    print(file=sys.stderr)
    return records


# ----------------------------------------------------------------------------------------------------------
# fitting


def inputs_of(records: list[dict]) -> np.ndarray:
    feats = TrustFeatures(
        **{k: torch.tensor([r["features"][k] for r in records], dtype=torch.float64) for k in records[0]["features"]}
    )
    return confidence_inputs(feats).numpy()


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-2, steps: int = 50) -> tuple[np.ndarray, float]:
    """L2-penalised logistic regression by Newton's method; returns (weights, bias)."""
    n, d = x.shape
    xb = np.concatenate([x, np.ones((n, 1))], 1)
    w = np.zeros(d + 1)
    penalty = np.full(d + 1, l2 * n)
    penalty[-1] = 0.0
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-xb @ w))
        grad = xb.T @ (p - y) + penalty * w
        hess = (xb * (p * (1 - p))[:, None]).T @ xb + np.diag(penalty)
        step = np.linalg.solve(hess, grad)
        w -= step
        if np.abs(step).max() < 1e-10:
            break
    return w[:-1], float(w[-1])


def fit_std(
    spread: np.ndarray, logit_conf: np.ndarray, error: np.ndarray, noise: np.ndarray | None = None
) -> tuple[float, float, float]:
    """(a, b, c) of ``log std = a + b log(spread + 0.01) + c logit(conf) [+ noise]``, a set for 68.3% one-sigma
    coverage. ``b`` and ``c`` come from a regression of the log errors; ``noise``, (N,) log of the fixed line-noise
    term, only moves ``a``: the term then scales the standard deviations, on the fitting set as a whole unchanged."""
    ok = np.isfinite(error)
    s, q, e = np.log(spread[ok] + 0.01), logit_conf[ok], np.abs(error[ok])
    x = np.stack([np.ones_like(s), s, q], 1)
    coef, *_ = np.linalg.lstsq(x, np.log(e + 1e-3), rcond=None)
    pred = x @ coef + (0.0 if noise is None else noise[ok])
    # the shift that puts 68.3% of the errors within one sigma
    shift = np.quantile(np.log(e + 1e-12) - pred, 0.6827)
    return float(coef[0] + shift), float(coef[1]), float(coef[2])


def fit(records: list[dict], threshold: float) -> dict:
    x = inputs_of(records)
    y = np.array([r["horizon"] < threshold for r in records], dtype=np.float64)
    mean, scale = x.mean(0), x.std(0)
    scale = np.where(scale > 1e-6, scale, 1.0)  # a constant input (no information) is left unscaled
    w, b = fit_logistic((x - mean) / scale, y)
    conf = 1.0 / (1.0 + np.exp(-(((x - mean) / scale) @ w + b)))
    conf = np.clip(conf, 1e-4, 1 - 1e-4)
    logit_conf = np.log(conf) - np.log1p(-conf)
    std = {}
    # the line-noise term has a fixed exponent and moves only the intercept (see fit_std)
    noise = RESIDUAL_EXPONENT * np.log(np.array([r["features"]["line_residual"] for r in records]) + 0.05)
    for name, spread in STD_SPREADS.items():
        spreads = np.array([r["features"][spread] for r in records])
        errors = np.array([r.get(f"{name}_signed", r.get(name, math.nan)) for r in records], dtype=np.float64)
        std[name] = fit_std(spreads, logit_conf, errors, noise)
    return {
        "threshold": threshold,
        "inputs": list(INPUT_NAMES),
        "weights": [round(float(v), 6) for v in w],
        "bias": round(b, 6),
        "mean": [round(float(v), 6) for v in mean],
        "scale": [round(float(v), 6) for v in scale],
        "std": {k: [round(v, 6) for v in c] for k, c in std.items()},
        "residual_exponent": RESIDUAL_EXPONENT,
        "fitted_on": f"{len(records)} rendered images; {int(y.sum())} below the threshold",
    }


def fit_gain(line: np.ndarray, term: np.ndarray, error: np.ndarray, share: float = 0.6827) -> float:
    """The smallest k >= 0 with ``share`` of ``|error|`` within ``hypot(line, k * term)`` (bisection)."""
    ok = np.isfinite(error)
    line, term, e = line[ok], term[ok], np.abs(error[ok])

    def covered(k: float) -> float:
        return float((e <= np.hypot(line, k * term)).mean())

    if covered(0.0) >= share:
        return 0.0
    low, high = 0.0, 1.0
    while covered(high) < share and high < 1e4:
        high *= 2.0
    for _ in range(60):
        mid = (low + high) / 2.0
        low, high = (low, mid) if covered(mid) >= share else (mid, high)
    return high


def fit_principal_point(records: list[dict], model: TrustModel, principal_point_std: float) -> dict[str, float]:
    """Per parameter the gain of the principal-point term, on records of renders with off-centre principal
    points; the model's confidence and line terms stay as they are."""
    feats = TrustFeatures(
        **{k: torch.tensor([r["features"][k] for r in records], dtype=torch.float64) for k in records[0]["features"]}
    )
    line = model.stds(feats, model.confidence(feats))
    focal, pitch = (torch.tensor([r[k] for r in records], dtype=torch.float64) for k in ("focal", "pitch_answer"))
    heights = {r["height"] for r in records}
    if len(heights) != 1:
        raise SystemExit(f"records of one image height please, got {sorted(heights)}")
    terms = principal_point_terms(principal_point_std, focal, heights.pop(), pitch)
    gains = {}
    for name in STD_SPREADS:
        errors = np.array([r.get(f"{name}_signed", r.get(name, math.nan)) for r in records], dtype=np.float64)
        gains[name] = round(fit_gain(line[name].numpy(), terms[name].numpy(), errors), 4)
    return gains


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_col = sub.add_parser("collect", help="run calibrate() and record features and errors")
    p_col.add_argument("dataset", choices=["rendered", "yud", "manifest"])
    p_col.add_argument("path", type=Path)
    p_col.add_argument("--out", type=Path, required=True)
    p_col.add_argument("--seed", type=int, default=0)
    p_col.add_argument("--weights", default=None, help="weight set and overrides, as in benchmarks/calibration.py")
    p_col.add_argument(
        "--prior", choices=["none", "true", "exif"], default="none", help="give the true (or the EXIF) focal length"
    )
    p_col.add_argument("--limit", type=int, default=None)
    p_fit = sub.add_parser("fit", help="fit the trust model on collected render records")
    p_fit.add_argument("records", type=Path, nargs="+")
    p_fit.add_argument("--out", type=Path, required=True)
    p_fit.add_argument("--threshold", type=float, default=THRESHOLD)
    p_pp = sub.add_parser("principal-point", help="fit the principal-point gains on renders with off-centre ones")
    p_pp.add_argument("records", type=Path, nargs="+")
    p_pp.add_argument("--principal-point-std", type=float, required=True, help="the renders' RenderConfig.centre_std")
    p_pp.add_argument("--model", type=Path, default=TRUST_FILE, help="coefficients whose other terms are kept")
    p_pp.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    if args.command == "collect":
        samples = load_samples(args.dataset, args.path)[: args.limit]
        records = collect(samples, args.weights, args.seed, args.prior)
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "records": records}, indent=0))
        print(f"wrote {len(records)} records to {args.out}")
        return 0
    records = [r for path in args.records for r in json.loads(path.read_text())["records"]]
    if any(r["kind"] in ("yud", "manifest") for r in records):
        parser.error("fit on renders only: these records include real photos")
    if args.command == "principal-point":
        model = json.loads(args.model.read_text())
        model["principal_point"] = fit_principal_point(records, TrustModel.load(args.model), args.principal_point_std)
        model["principal_point_fitted_on"] = (
            f"{len(records)} rendered images, principal_point_std {args.principal_point_std}"
        )
    else:
        model = fit(records, args.threshold)
    args.out.write_text(json.dumps(model, indent=1) + "\n")
    print(json.dumps(model, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
