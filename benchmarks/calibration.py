"""Benchmark single-image calibration on the York Urban Database or on a folder written by ``ngp render``.

Compares, on the same images and in the same process:

* ``ngp_kornia.calibrate`` (this package; it estimates the focal length itself), once per ``--weights`` value,
* lu-vp-detect (Lu et al., WACV 2017, the ``lu_vp_detect`` package), given the TRUE focal length and principal
  point, so its field of view is exact by construction,
* a trivial baseline: a level horizon through the image centre (pitch = roll = 0).

Usage::

    python benchmarks/calibration.py yud /path/to/YorkUrbanDB [--split all] [--ground-truth orthogonal]
    python benchmarks/calibration.py rendered /path/to/render_dir      # written by `ngp render`
    common options: [--limit N] [--weights default] [--weights none] [--weights full:top_k=4] [--weights w.pt]
                    [--no-lu] [--out r.json]

Both datasets are turned into the same :class:`Sample` (image path, K, up, horizon, pitch, roll, fov_v, height,
width, and the scene kind for rendered data), so every method and metric is shared. For a render folder the
ground truth is read from ``ground_truth.json`` (up = -R[:, 1], the stored horizon / pitch / roll / fov_v).

Errors are in degrees; the horizon AUC is the area under the cumulative horizon-error curve on [0, 0.25] of
the image height (:func:`ngp_kornia.metrics.horizon_auc`). Seconds per image is the wall time of one call
including reading the image, measured with the methods interleaved image by image after one warm-up call each.
The load average is printed with the results: timings taken while other jobs run are slower than on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from ngp_kornia.geometry.camera import (
    horizon_from_zenith,
    pitch_roll_from_up,
    zenith_from_up,
)
from ngp_kornia.metrics import (
    fov_error,
    horizon_auc,
    horizon_error,
    pitch_error,
    roll_error,
    summarize,
    up_vector_error,
)


@dataclass(frozen=True)
class Sample:
    """Ground truth of one image, in this package's conventions (float64 tensors, degrees)."""

    name: str
    image_path: Path
    K: torch.Tensor  # (3, 3)
    up: torch.Tensor  # (3,) unit up vector in camera coordinates, -R[:, 1]
    horizon: torch.Tensor  # (3,)
    pitch: float
    roll: float
    fov_v: float
    height: int
    width: int
    kind: str | None = None  # rendered scene kind (street / indoor / atlanta); None for photos


# ----------------------------------------------------------------------------------------------------------
# datasets


def load_yud(root: Path, split: str = "all", ground_truth: str = "orthogonal") -> list[Sample]:
    from ngp_kornia.data.yud import YorkUrbanDB

    db = YorkUrbanDB(root, split=split, ground_truth=ground_truth)
    return [Sample(s.name, s.image_path, s.K, s.up, s.horizon, s.pitch, s.roll, s.fov_v, s.height, s.width) for s in db]


def _t(x) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float64))


def load_rendered(root: Path) -> list[Sample]:
    """Samples of a folder written by ``ngp render`` (``ground_truth.json`` + images).

    The stored horizon, pitch and roll are checked against the ones recomputed from K and R (they must agree,
    they come from the same functions); a mismatch is an error, not a silent re-definition of the ground truth.
    """
    gt_path = root / "ground_truth.json"
    if not gt_path.is_file():
        raise FileNotFoundError(f"not a render folder (no ground_truth.json): {root}")
    records = json.loads(gt_path.read_text())
    samples = []
    for rec in records:
        K, R = _t(rec["K"]), _t(rec["R"])
        up = -R[:, 1]
        horizon = _t(rec["horizon"])
        z = zenith_from_up(K[None], up[None])
        h2 = horizon_from_zenith(K[None], z)[0]
        p2, r2 = pitch_roll_from_up(up[None])
        h_err = horizon_error(h2[None], horizon[None], int(rec["height"]), int(rec["width"]))[0]
        if h_err > 1e-6 or abs(float(p2[0]) - rec["pitch"]) > 1e-6 or abs(float(r2[0]) - rec["roll"]) > 1e-6:
            raise ValueError(f"{rec['image']}: stored horizon / pitch / roll disagree with K and R")
        samples.append(
            Sample(
                name=Path(rec["image"]).stem,
                image_path=root / rec["image"],
                K=K,
                up=up,
                horizon=horizon,
                pitch=float(rec["pitch"]),
                roll=float(rec["roll"]),
                fov_v=float(rec["fov_v"]),
                height=int(rec["height"]),
                width=int(rec["width"]),
                kind=rec.get("kind"),
            )
        )
    return samples


# ----------------------------------------------------------------------------------------------------------
# this package (and shared estimate type)


@dataclass
class Estimate:
    """One method's answer for one image, in this package's conventions (float64, degrees)."""

    up: torch.Tensor  # (3,)
    horizon: torch.Tensor  # (3,)
    pitch: float
    roll: float
    fov_v: float | None = None  # None: the method does not estimate it
    extra: dict = field(default_factory=dict)


def _failed() -> Estimate:
    nan3 = torch.full((3,), math.nan, dtype=torch.float64)
    return Estimate(nan3, nan3.clone(), math.nan, math.nan, math.nan)


def estimate_from_calibration(result, sample: Sample) -> Estimate:
    """The fields of one image's ``Calibration`` that the evaluation uses, as float64 on the CPU."""

    def f64(t: torch.Tensor) -> torch.Tensor:
        return t.detach().cpu().double()

    return Estimate(
        up=f64(result.up),
        horizon=f64(result.horizon),
        pitch=float(result.pitch),
        roll=float(result.roll),
        fov_v=float(result.fov_v),
        extra={"focal": float(result.focal), "valid": bool(result.valid), "score": float(result.score)},
    )


def parse_weights_spec(spec: str | None) -> tuple[object, dict]:
    """``NAME[:key=value,...]`` -> (weights for calibrate, ParserConfig overrides).

    NAME is a weight set (none, zsnet, fsnet, full, default) or .pt paths joined by ``+``; the overrides set
    :class:`ngp_kornia.models.ParserConfig` fields, e.g. ``full:top_k=1`` or ``fsnet:use_manhattan=false``.
    """
    if spec is None:
        return "default", {}
    name, _, rest = spec.partition(":")
    weights: object = name.split("+") if "+" in name else name
    overrides = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        overrides[key] = {"true": True, "false": False}.get(value.lower(), value)
    return weights, overrides


def weights_and_config(spec: str | None) -> tuple[object, object]:
    """``--weights`` spec -> (weights for calibrate, :class:`ngp_kornia.models.ParserConfig` with the overrides)."""
    from dataclasses import fields

    from ngp_kornia.models import ParserConfig

    weights, overrides = parse_weights_spec(spec)
    types = {f.name: type(getattr(ParserConfig(), f.name)) for f in fields(ParserConfig)}
    unknown = set(overrides) - set(types)
    if unknown:
        raise SystemExit(f"unknown ParserConfig fields {sorted(unknown)} in --weights {spec!r}")
    return weights, ParserConfig(**{k: v if isinstance(v, bool) else types[k](v) for k, v in overrides.items()})


def make_ngp(spec: str | None) -> Callable[[Sample], Estimate]:
    from ngp_kornia import calibrate

    weights, config = weights_and_config(spec)

    def run(sample: Sample) -> Estimate:
        result = calibrate(str(sample.image_path), weights=weights, seed=config.seed, config=config)
        return estimate_from_calibration(result, sample)

    return run


# ----------------------------------------------------------------------------------------------------------
# lu-vp-detect


class _LSDReshaper:
    """OpenCV >= 5 returns LSD lines as (N, 4); lu-vp-detect indexes them as (N, 1, 4)."""

    def __init__(self, lsd) -> None:
        self._lsd = lsd

    def detect(self, image, *args, **kwargs):
        out = self._lsd.detect(image, *args, **kwargs)
        lines = out[0]
        if lines is not None:
            lines = np.asarray(lines).reshape(-1, 1, 4)
        return (lines, *out[1:])

    def __getattr__(self, name):
        return getattr(self._lsd, name)


class _Cv2Proxy:
    """Stands in for ``cv2`` inside ``lu_vp_detect.vp_detection`` only; everything else is the real module."""

    def __getattr__(self, name):
        return getattr(cv2, name)

    @staticmethod
    def createLineSegmentDetector(*args, **kwargs):  # noqa: N802 (OpenCV's name)
        return _LSDReshaper(cv2.createLineSegmentDetector(*args, **kwargs))


def make_lu() -> Callable[[Sample], Estimate]:
    """lu-vp-detect with the true focal length and principal point.

    Its VPs are unit directions in the OpenCV camera frame (x right, y down, z forward: it lifts a pixel p to
    ``(p - pp, f)``), checked against the York Urban ground truth. The vertical is the VP with the largest |y|.
    """
    import lu_vp_detect.vp_detection as vp_detection
    from lu_vp_detect import VPDetection

    if not isinstance(vp_detection.cv2, _Cv2Proxy):
        vp_detection.cv2 = _Cv2Proxy()

    def run(sample: Sample) -> Estimate:
        image = cv2.imread(str(sample.image_path), cv2.IMREAD_COLOR)
        if image is None:
            raise FileNotFoundError(sample.image_path)
        K = sample.K
        detector = VPDetection(
            length_thresh=30,
            principal_point=(float(K[0, 2]), float(K[1, 2])),
            focal_length=float(K[0, 0]),
            seed=0,
        )
        vps = torch.as_tensor(np.asarray(detector.find_vps(image), dtype=np.float64))
        if vps.shape != (3, 3) or not bool(torch.isfinite(vps).all()):
            raise RuntimeError("lu-vp-detect returned no valid vanishing points")
        v = vps[int(vps[:, 1].abs().argmax())]
        up = -v if v[1] > 0 else v
        up = up / up.norm()
        zenith = zenith_from_up(K[None], up[None])
        horizon = horizon_from_zenith(K[None], zenith)[0]
        pitch, roll = pitch_roll_from_up(up[None])
        return Estimate(up, horizon, float(pitch[0]), float(roll[0]), None)

    return run


# ----------------------------------------------------------------------------------------------------------
# trivial baseline


def level_centre(sample: Sample) -> Estimate:
    """A level camera: up = (0, -1, 0), horizon y = (H - 1) / 2 (through the image centre)."""
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    horizon = torch.tensor([0.0, 1.0, -(sample.height - 1) / 2.0], dtype=torch.float64)
    return Estimate(up, horizon, 0.0, 0.0, None)


# ----------------------------------------------------------------------------------------------------------
# evaluation


def evaluate(samples: list[Sample], estimates: list[Estimate]) -> dict:
    """Per-image errors and summaries of one method; failed images count as misses in the AUC."""
    ok = torch.tensor([math.isfinite(e.pitch) for e in estimates])
    up = torch.stack([e.up for e in estimates])
    hor = torch.stack([e.horizon for e in estimates])
    gt_up = torch.stack([s.up for s in samples])
    gt_hor = torch.stack([s.horizon for s in samples])
    heights = torch.tensor([float(s.height) for s in samples], dtype=torch.float64)
    widths = torch.tensor([float(s.width) for s in samples], dtype=torch.float64)
    pitch = torch.tensor([e.pitch for e in estimates], dtype=torch.float64)
    roll = torch.tensor([e.roll for e in estimates], dtype=torch.float64)
    gt_pitch = torch.tensor([s.pitch for s in samples], dtype=torch.float64)
    gt_roll = torch.tensor([s.roll for s in samples], dtype=torch.float64)
    errors = {
        "up": up_vector_error(up, gt_up),
        "pitch": pitch_error(pitch, gt_pitch),
        "roll": roll_error(roll, gt_roll),
        "horizon": horizon_error(hor, gt_hor, heights, widths),
    }
    has_fov = all(e.fov_v is not None for e in estimates)
    if has_fov:
        fov = torch.tensor([e.fov_v for e in estimates], dtype=torch.float64)
        errors["fov_v"] = fov_error(fov, torch.tensor([s.fov_v for s in samples], dtype=torch.float64))
    for k in errors:
        errors[k] = torch.where(ok, errors[k], torch.full_like(errors[k], math.nan))
    summary = {k: summarize(v[ok]) for k, v in errors.items()}
    auc = horizon_auc(errors["horizon"]).item() if len(samples) else math.nan
    by_kind = {}
    for kind in sorted({s.kind for s in samples if s.kind is not None}):
        idx = torch.tensor([s.kind == kind for s in samples])
        by_kind[kind] = {"count": int(idx.sum()), "horizon_auc": horizon_auc(errors["horizon"][idx]).item()}
    return {
        "summary": summary,
        "horizon_auc": auc,
        "horizon_auc_by_kind": by_kind,
        "failures": int((~ok).sum()),
        "per_image": [
            {
                "name": s.name,
                **({"kind": s.kind} if s.kind is not None else {}),
                **{k: float(v[i]) for k, v in errors.items()},
                **estimates[i].extra,
            }
            for i, s in enumerate(samples)
        ],
    }


def _mm(summary: dict, key: str) -> str:
    if key not in summary or summary[key]["count"] == 0:
        return "n.a."
    s = summary[key]
    return f"{s['mean']:.2f} / {s['median']:.2f}"


def markdown_table(results: dict[str, dict], n_images: int) -> str:
    head = (
        "| method | up error (deg) mean / median | pitch error (deg) mean / median "
        "| roll error (deg) mean / median | FoV_v error (deg) mean / median | horizon AUC (%) "
        "| s / image | failures |"
    )
    rows = [head, "|" + "---|" * 8]
    for name, r in results.items():
        s = r["summary"]
        fov = _mm(s, "fov_v") if "fov_v" in s else r.get("fov_note", "n.a.")
        sec = f"{r['seconds_per_image']:.3f}" if r.get("seconds_per_image") is not None else "n.a."
        rows.append(
            f"| {name} | {_mm(s, 'up')} | {_mm(s, 'pitch')} | {_mm(s, 'roll')} | {fov} "
            f"| {100 * r['horizon_auc']:.2f} | {sec} | {r['failures']}/{n_images} |"
        )
    return "\n".join(rows)


def kind_table(results: dict[str, dict]) -> str:
    """Horizon AUC (%) per rendered scene kind; empty when the samples carry no kind."""
    kinds: dict[str, int] = {}
    for r in results.values():
        for k, v in r["horizon_auc_by_kind"].items():
            kinds[k] = v["count"]
    if not kinds:
        return ""
    known = ("street", "indoor", "atlanta")
    order = [k for k in known if k in kinds] + sorted(set(kinds) - set(known))
    rows = [
        "| method | " + " | ".join(f"{k} (n={kinds[k]})" for k in order) + f" | all (n={sum(kinds.values())}) |",
        "|" + "---|" * (len(order) + 2),
    ]
    for name, r in results.items():
        cells = [f"{100 * r['horizon_auc_by_kind'][k]['horizon_auc']:.2f}" for k in order]
        rows.append(f"| {name} | " + " | ".join(cells) + f" | {100 * r['horizon_auc']:.2f} |")
    return "\n".join(rows)


def _weights_label(w: str | None) -> str:
    return "ngp_kornia.calibrate" + (f" (weights={w})" if w is not None else " (weights=default)")


def main(argv: list[str] | None = None) -> int:
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
        "--ground-truth",
        default="orthogonal",
        choices=["orthogonal", "raw"],
        help="York Urban ground truth: vp_orthogonal (default) or the vertical of the raw vp",
    )
    p_ren = sub.add_parser("rendered", parents=[common], help="folder written by `ngp render`")
    p_ren.add_argument("root", type=Path)
    args = parser.parse_args(argv)

    if args.dataset == "yud":
        samples = load_yud(args.root, args.split, args.ground_truth)
        title = f"York Urban DB, split={args.split}, ground truth={args.ground_truth}"
    else:
        samples = load_rendered(args.root)
        title = "rendered (ngp render)"
    if args.limit is not None:
        samples = samples[: args.limit]
    if not samples:
        parser.error(f"no images found in {args.root}")

    wanted = [m.strip() for m in args.methods.split(",") if m.strip()]
    if args.no_lu:
        wanted = [m for m in wanted if m != "lu"]
    methods: dict[str, Callable[[Sample], Estimate]] = {}
    notes: dict[str, str] = {}
    for m in wanted:
        try:
            if m == "ngp":
                for w in args.weights or [None]:
                    methods[_weights_label(w)] = make_ngp(w)
            elif m == "lu":
                methods["lu-vp-detect (true f, pp)"] = make_lu()
            else:
                parser.error(f"unknown method {m!r}")
        except ImportError as e:
            notes[m] = f"skipped: {e}"
            print(f"[{m}] skipped: {e}", file=sys.stderr)

    load_before = os.getloadavg()
    # warm-up: one untimed call per method
    for name, fn in methods.items():
        try:
            fn(samples[0])
        except Exception as e:  # reported again, per image, below
            print(f"[{name}] warm-up failed: {e!r}", file=sys.stderr)

    estimates: dict[str, list[Estimate]] = {name: [] for name in methods}
    seconds: dict[str, float] = {name: 0.0 for name in methods}
    errors_seen: dict[str, list[str]] = {name: [] for name in methods}
    names = list(methods)
    for i, sample in enumerate(samples):
        order = names[i % len(names) :] + names[: i % len(names)] if names else []  # alternate who goes first
        for name in order:
            t0 = time.perf_counter()
            try:
                est = methods[name](sample)
            except Exception as e:
                est = _failed()
                errors_seen[name].append(f"{sample.name}: {e!r}")
            seconds[name] += time.perf_counter() - t0
            estimates[name].append(est)
        print(f"\r{i + 1}/{len(samples)} {sample.name}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    load_after = os.getloadavg()

    results: dict[str, dict] = {}
    for name in names:
        r = evaluate(samples, estimates[name])
        r["seconds_per_image"] = seconds[name] / len(samples)
        r["exceptions"] = errors_seen[name]
        if name.startswith("lu-vp-detect"):
            r["fov_note"] = "0 (given)"
        results[name] = r
    base = evaluate(samples, [level_centre(s) for s in samples])
    base["seconds_per_image"] = None
    results["level horizon through the centre"] = base

    print(f"{title}: {len(samples)} images ({args.root})")
    print(
        f"timing: {os.cpu_count()} CPUs, torch threads {torch.get_num_threads()}, load average (1 min) "
        f"{load_before[0]:.2f} before / {load_after[0]:.2f} after the run (other jobs running slow the timings)"
    )
    print()
    print(markdown_table(results, len(samples)))
    by_kind = kind_table(results)
    if by_kind:
        print()
        print("horizon AUC (%) by scene kind")
        print()
        print(by_kind)
    for name, r in results.items():
        for msg in r.get("exceptions", [])[:5]:
            print(f"  [{name}] {msg}")
    for m, note in notes.items():
        print(f"  [{m}] {note}")

    if args.out is not None:
        payload = {
            "command": " ".join(sys.argv),
            "dataset": args.dataset,
            "root": str(args.root),
            **({"split": args.split, "ground_truth": args.ground_truth} if args.dataset == "yud" else {}),
            "images": [s.name for s in samples],
            "load_average": {"before": load_before, "after": load_after},
            "versions": {
                "python": platform.python_version(),
                "torch": torch.__version__,
                "opencv": cv2.__version__,
            },
            "methods": results,
        }
        args.out.write_text(json.dumps(payload, indent=1, allow_nan=True))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
