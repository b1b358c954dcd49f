"""Labels for real photos that have none: the answers the parser is sure of, written as a CSV manifest.

A photo is labelled when every run agrees: the parser with each weight set of the rule and each sampling seed
finds a camera, the first weight set is confident on every seed, all the horizons lie within a small share of the
image height (and the focal lengths within a small relative spread) of the first run's, and the camera is not
rolled far (the photos are taken to be handed over upright). The first run's focal
length, pitch and roll become the label (:mod:`ngp_kornia.data.manifest`'s columns), so
:class:`~ngp_kornia.training.scene_data.ManifestScenes` and the FSNet training read them as they read true ones.

Usage::

    python -m ngp_kornia.training.pseudo_labels RealPhotos labels_train.csv --part train
    python -m ngp_kornia.training.pseudo_labels RealPhotos labels_calibrate.csv --part calibrate
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import torch

from ngp_kornia.data.photo_split import PARTS, split_photos
from ngp_kornia.errors import OutputError
from ngp_kornia.io import load_image
from ngp_kornia.metrics import horizon_error
from ngp_kornia.pipeline.parser import NeuralGeometricParser

__all__ = ["LABEL_COLUMNS", "LabelRule", "label_photo", "main", "pseudo_labels", "sure_label", "write_labels"]

#: the manifest's columns (``image`` relative to the photo folder) and what the runs said of the photo
LABEL_COLUMNS = ("image", "focal_px", "pitch_deg", "roll_deg", "confidence", "horizon_spread", "focal_spread")


@dataclass(frozen=True)
class LabelRule:
    """When the answers for a photo count as a label.

    Attributes:
        weights: the weight sets run on every photo; the first one's answer (first seed) is the label.
        seeds: the sampling seeds each weight set runs with.
        min_confidence: the least confidence of the first weight set's answers (every seed).
        max_horizon_spread: the largest horizon distance (image heights, at the borders) of any run from the first.
        max_focal_spread: the largest relative difference of any run's focal length from the first's.
        max_roll: the largest roll (degrees) of the label: photos handed over upright seldom roll further, and an
            answer that does is likelier a wrong zenith (a facade's vanishing point taken for it) than a tilted
            camera, however well the runs agree.

    Example:
        >>> LabelRule().weights
        ('default', 'none')
    """

    weights: tuple[str, ...] = ("default", "none")
    seeds: tuple[int, ...] = (0, 1)
    min_confidence: float = 0.5
    max_horizon_spread: float = 0.015
    max_focal_spread: float = 0.1
    max_roll: float = 20.0

    def __post_init__(self) -> None:
        if not self.weights or not self.seeds:
            raise ValueError("a LabelRule needs at least one weight set and one seed")
        if not 0.0 <= self.max_roll <= 180.0:
            raise ValueError(f"LabelRule.max_roll must lie in [0, 180] degrees, got {self.max_roll}")
        for f in fields(self)[2:-1]:
            if not 0.0 <= getattr(self, f.name) <= 1.0:
                raise ValueError(f"LabelRule.{f.name} must lie in [0, 1], got {getattr(self, f.name)}")


def sure_label(answers: Sequence, height: int, width: int, rule: LabelRule) -> dict | None:
    """The label a photo's answers give (focal, pitch, roll and how far they spread), or None where they are unsure.

    Args:
        answers: one-image :class:`~ngp_kornia.pipeline.calibration.Calibration` objects, the first weight set's
            seeds first (``len(rule.seeds)`` of them), then the others'.
        height: image height in pixels.
        width: image width in pixels.
        rule: the :class:`LabelRule`.

    Returns:
        ``{"focal_px", "pitch_deg", "roll_deg", "confidence", "horizon_spread", "focal_spread"}`` or None.
    """
    if not all(bool(a.valid) for a in answers):
        return None
    confidence = min(float(a.confidence) for a in answers[: len(rule.seeds)])
    if confidence < rule.min_confidence:
        return None
    first = answers[0]
    horizons = torch.stack([a.horizon.reshape(3).double() for a in answers])
    spread = float(horizon_error(horizons, horizons[:1].expand_as(horizons), height, width).max())
    focal = float(first.focal)
    focal_spread = max(abs(float(a.focal) - focal) / focal for a in answers)
    rolled = abs(float(first.roll)) > rule.max_roll
    if rolled or spread > rule.max_horizon_spread or focal_spread > rule.max_focal_spread:
        return None
    return {"focal_px": focal, "pitch_deg": float(first.pitch), "roll_deg": float(first.roll),
            "confidence": confidence, "horizon_spread": spread, "focal_spread": focal_spread}  # fmt: skip


def label_photo(parsers: Sequence[NeuralGeometricParser], path: str | Path, rule: LabelRule) -> dict | None:
    """Run every parser and seed on one photo (stopping at the first unsure answer) and return :func:`sure_label`.

    Args:
        parsers: one parser per weight set of ``rule``, in its order.
        path: the photo.
        rule: the :class:`LabelRule`.
    """
    image = load_image(path)
    height, width = image.shape[-2:]
    answers = []
    for i, parser in enumerate(parsers):
        for seed in rule.seeds:
            with torch.no_grad():
                answer = parser(image, seed=seed)[0]
            answers.append(answer)
            if not bool(answer.valid) or (i == 0 and float(answer.confidence) < rule.min_confidence):
                return None  # unsure already: the other runs cannot make it a label
    return sure_label(answers, height, width, rule)


def pseudo_labels(root: str | Path, part: str = "train", rule: LabelRule | None = None, progress: bool = False):
    """The labelled photos of one part of a folder (:func:`ngp_kornia.data.photo_split.split_photos`).

    Args:
        root: the photo folder (searched recursively).
        part: ``"train"``, ``"calibrate"`` or ``"test"``.
        rule: the :class:`LabelRule` (None: the defaults).
        progress: a progress bar on stderr.

    Returns:
        a list of rows, one dict per labelled photo with the keys of :data:`LABEL_COLUMNS` (``image`` relative to
        ``root``).
    """
    rule = rule or LabelRule()
    parsers = [NeuralGeometricParser.from_pretrained(w).eval() for w in rule.weights]
    from tqdm import tqdm

    rows = []
    for name in tqdm(split_photos(root, part), desc=f"labelling {part}", unit="photo", disable=not progress):
        label = label_photo(parsers, Path(root) / name, rule)
        if label is not None:
            rows.append({"image": name, **label})
    return rows


def write_labels(rows: Sequence[dict], out: str | Path, force: bool = False) -> Path:
    """Write the rows as a CSV manifest whose image paths are relative to the photo folder.

    Raises:
        OutputError: ``out`` exists and ``force`` is not set.
    """
    out = Path(out)
    if out.exists() and not force:
        raise OutputError(f"{out} exists; give another file or --force to overwrite it")
    with out.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, LABEL_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return out


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m ngp_kornia.training.pseudo_labels",
        description="Label the photos of one part of a folder with the answers the parser is sure of, as a CSV "
        "manifest (read it with CSVManifest(OUT, root=ROOT)).",
    )
    p.add_argument("root", help="the photo folder (searched recursively)")
    p.add_argument("out", help="the CSV file to write")
    p.add_argument("--part", default="train", choices=list(PARTS), help="which part of the folder (default: train)")
    p.add_argument("--weights", default="default,none", help="weight sets, comma-separated; the first gives labels")
    p.add_argument("--seeds", default="0,1", help="sampling seeds, comma-separated")
    p.add_argument("--min-confidence", type=float, default=LabelRule.min_confidence)
    p.add_argument("--max-horizon-spread", type=float, default=LabelRule.max_horizon_spread)
    p.add_argument("--max-focal-spread", type=float, default=LabelRule.max_focal_spread)
    p.add_argument("--max-roll", type=float, default=LabelRule.max_roll, help="degrees")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m ngp_kornia.training.pseudo_labels ROOT OUT.csv``."""
    args = _parser().parse_args(argv)
    try:
        limits = (args.min_confidence, args.max_horizon_spread, args.max_focal_spread, args.max_roll)
        rule = LabelRule(tuple(args.weights.split(",")), tuple(int(s) for s in args.seeds.split(",")), *limits)
        if Path(args.out).exists() and not args.force:
            raise OutputError(f"{args.out} exists; give another file or --force to overwrite it")
        rows = pseudo_labels(args.root, args.part, rule, progress=sys.stderr.isatty())
        write_labels(rows, args.out, args.force)
    except (ValueError, OSError, OutputError) as err:
        print(f"pseudo_labels: error: {err}", file=sys.stderr)
        return 2
    print(f"{len(rows)} photos of {len(split_photos(args.root, args.part))} labelled: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
