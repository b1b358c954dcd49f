"""Scores of one method on a list of labelled images (:func:`evaluate`) and markdown tables of several.

Errors are in degrees, the horizon error in image heights (:mod:`ngp_kornia.metrics`); the horizon AUC is the area
under its cumulative distribution on [0, 0.25]. An image whose estimate failed counts as a miss in the AUC and is
left out of the means and medians (the failures are counted). A metric whose ground truth an image lacks (a CSV
manifest with a horizon only, say) is computed over the images that have it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from ngp_kornia.evaluation.datasets import LabelledImage
from ngp_kornia.evaluation.methods import Estimate
from ngp_kornia.metrics import (
    fov_error,
    horizon_auc,
    horizon_error,
    pitch_error,
    roll_error,
    summarize,
    up_vector_error,
)
from ngp_kornia.pipeline.camera_model import OPTION_METRICS, option_errors

__all__ = ["CAMERA_METRICS", "evaluate", "kind_table", "markdown_table"]

#: the errors of the camera options where the truth and the estimate have them, with their words in tables
#: (:data:`~ngp_kornia.pipeline.camera_model.OPTION_METRICS`)
CAMERA_METRICS = OPTION_METRICS

#: scene kinds of ``ngp render`` in table order
RENDER_KINDS = ("street", "indoor", "atlanta")


def _f64(values: list) -> Tensor:
    return torch.tensor(values, dtype=torch.float64)


def _pairs(images, estimates, key: str, idx: list[int]) -> tuple[Tensor, Tensor]:
    pred = [getattr(estimates[i], key) for i in idx]
    gt = [getattr(images[i], key) for i in idx]
    if isinstance(gt[0], Tensor):
        return torch.stack(pred).double(), torch.stack(gt).double()
    return _f64(pred), _f64(gt)


_ERRORS: dict[str, Callable[..., Tensor]] = {
    "up": lambda p, g, h, w: up_vector_error(p, g),
    "pitch": lambda p, g, h, w: pitch_error(p, g),
    "roll": lambda p, g, h, w: roll_error(p, g),
    "horizon": horizon_error,
    "fov_v": lambda p, g, h, w: fov_error(p, g),
}


def _error_table(images: Sequence[LabelledImage], estimates: Sequence[Estimate]) -> dict[str, Tensor]:
    """(N,) errors per metric, NaN where the ground truth is unknown; metrics no image can score are left out."""
    n = len(images)
    out = {}
    for key, fn in _ERRORS.items():
        if key == "fov_v" and any(e.fov_v is None for e in estimates):
            continue  # the method does not estimate it
        idx = [i for i, im in enumerate(images) if getattr(im, key) is not None]
        if not idx:
            continue
        pred, gt = _pairs(images, estimates, key, idx)
        heights = _f64([float(images[i].height) for i in idx])
        widths = _f64([float(images[i].width) for i in idx])
        values = torch.full((n,), math.nan, dtype=torch.float64)
        values[idx] = fn(pred, gt, heights, widths).double()
        out[key] = values
    out.update(_camera_errors(images, estimates))
    return out


def _known(image: LabelledImage, metric: str) -> bool:
    """Whether the image has the ground truth a metric needs."""
    if metric in CAMERA_METRICS:
        return option_errors({}, image.K, image.lens)[metric] is not None
    return getattr(image, metric) is not None


def _camera_errors(images: Sequence[LabelledImage], estimates: Sequence[Estimate]) -> dict[str, Tensor]:
    """The camera options' errors (:data:`CAMERA_METRICS`) where the truth and the estimate have them."""
    rows = [option_errors(e.extra, im.K, im.lens) for im, e in zip(images, estimates, strict=True)]
    out = {}
    for key in CAMERA_METRICS:
        values = [math.nan if row[key] is None else row[key] for row in rows]
        if any(math.isfinite(v) for v in values):
            out[key] = _f64(values)
    return out


def evaluate(images: Sequence[LabelledImage], estimates: Sequence[Estimate]) -> dict:
    """Per-image errors and summaries of one method.

    Args:
        images: the labelled images.
        estimates: the method's estimate of each, in the same order.

    Returns:
        ``{"summary": {metric: {"mean", "median", "count"}}, "horizon_auc": float (NaN when no image has a
        horizon), "horizon_auc_by_kind": {kind: {"count", "horizon_auc"}}, "failures": int, "per_image": [...]}``
        with metrics ``up``, ``pitch``, ``roll``, ``horizon`` (image heights), ``fov_v`` and the camera options'
        (:data:`CAMERA_METRICS`) where the ground truth and the method give them.

    Raises:
        ValueError: ``images`` and ``estimates`` differ in length.
    """
    if len(images) != len(estimates):
        raise ValueError(f"{len(images)} images but {len(estimates)} estimates; give one estimate per image")
    ok = torch.tensor([math.isfinite(e.pitch) for e in estimates], dtype=torch.bool)
    errors = _error_table(images, estimates)
    known = {k: torch.tensor([_known(im, k) for im in images], dtype=torch.bool) for k in errors}
    errors = {k: torch.where(ok, v, torch.full_like(v, math.nan)) for k, v in errors.items()}
    summary = {k: summarize(v[ok & known[k]]) for k, v in errors.items()}
    has_horizon = known.get("horizon", torch.zeros(len(images), dtype=torch.bool))
    auc = horizon_auc(errors["horizon"][has_horizon]).item() if bool(has_horizon.any()) else math.nan
    by_kind = {}
    for kind in sorted({im.kind for im in images if im.kind is not None}):
        idx = torch.tensor([im.kind == kind for im in images]) & has_horizon
        if not bool(idx.any()):
            continue
        by_kind[kind] = {"count": int(idx.sum()), "horizon_auc": horizon_auc(errors["horizon"][idx]).item()}
    per_image = []
    for i, im in enumerate(images):
        row = {"name": im.name, **({"kind": im.kind} if im.kind is not None else {})}
        row.update({k: float(v[i]) for k, v in errors.items() if _known(im, k)})
        per_image.append({**row, **estimates[i].extra})
    return {
        "summary": summary,
        "horizon_auc": auc,
        "horizon_auc_by_kind": by_kind,
        "failures": int((~ok).sum()),
        "per_image": per_image,
    }


def _mean_median(summary: dict, key: str) -> str:
    if key not in summary or summary[key]["count"] == 0:
        return "n.a."
    s = summary[key]
    return f"{s['mean']:.2f} / {s['median']:.2f}"


def markdown_table(results: dict[str, dict], n_images: int) -> str:
    """One row per method: up, pitch, roll and FoV errors (mean / median), horizon AUC, seconds per image and
    failures. ``results`` maps a method's name to :func:`evaluate`'s output, optionally with ``seconds_per_image``
    (``None``: not timed) and ``fov_note`` (the FoV cell of a method that gives none)."""
    head = (
        "| method | up error (deg) mean / median | pitch error (deg) mean / median "
        "| roll error (deg) mean / median | FoV_v error (deg) mean / median | horizon AUC (%) "
        "| s / image | failures |"
    )
    rows = [head, "|" + "---|" * 8]
    for name, r in results.items():
        s = r["summary"]
        fov = _mean_median(s, "fov_v") if "fov_v" in s else r.get("fov_note", "n.a.")
        sec = f"{r['seconds_per_image']:.3f}" if r.get("seconds_per_image") is not None else "n.a."
        rows.append(
            f"| {name} | {_mean_median(s, 'up')} | {_mean_median(s, 'pitch')} | {_mean_median(s, 'roll')} | {fov} "
            f"| {100 * r['horizon_auc']:.2f} | {sec} | {r['failures']}/{n_images} |"
        )
    return "\n".join(rows)


def kind_table(results: dict[str, dict]) -> str:
    """Horizon AUC (%) per rendered scene kind, one row per method; empty when the images carry no kind."""
    kinds: dict[str, int] = {}
    for r in results.values():
        for k, v in r["horizon_auc_by_kind"].items():
            kinds[k] = v["count"]
    if not kinds:
        return ""
    order = [k for k in RENDER_KINDS if k in kinds] + sorted(set(kinds) - set(RENDER_KINDS))
    rows = [
        "| method | " + " | ".join(f"{k} (n={kinds[k]})" for k in order) + f" | all (n={sum(kinds.values())}) |",
        "|" + "---|" * (len(order) + 2),
    ]
    for name, r in results.items():
        cells = [f"{100 * r['horizon_auc_by_kind'][k]['horizon_auc']:.2f}" for k in order]
        rows.append(f"| {name} | " + " | ".join(cells) + f" | {100 * r['horizon_auc']:.2f} |")
    return "\n".join(rows)
