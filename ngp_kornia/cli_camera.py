"""The command line's camera options: a gravity prior, the principal point, lens distortion and one camera for many
photos (``--same-camera``), and the ground truth an overlay draws beside the estimate (``--truth``, read by
:func:`load_truth`). Imports nothing heavy, so ``--help`` stays fast.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_camera_arguments(parser)
    >>> camera_arguments(parser.parse_args(["--gravity", "2", "-1", "--k1", "estimate"]))
    {'gravity': (2.0, -1.0), 'gravity_std': None, 'principal_point': None, 'k1': 'estimate'}
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_camera_arguments", "camera_arguments", "images_after_the_point", "load_truth"]


def images_after_the_point(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """``--principal-point`` takes one or two values, and argparse gives it every word that follows, the images
    too: what is beyond its values goes back to the images."""
    point = args.principal_point or []
    size = 1 if point[:1] == ["estimate"] else 2
    if len(point) > size:
        args.principal_point, args.images = point[:size], point[size:] + args.images
    if not args.images:
        parser.error("the following arguments are required: images")


def add_camera_arguments(group, same_camera: str | None = None) -> None:
    """Add ``--gravity``, ``--gravity-std``, ``--principal-point``, ``--k1`` and, with its help text
    ``same_camera``, ``--same-camera`` to ``group`` (a parser or an argument group)."""
    group.add_argument("--gravity", type=float, nargs=2, metavar=("PITCH", "ROLL"),
                       help="pitch and roll in degrees (a phone's sensor)")
    group.add_argument("--gravity-std", type=float, metavar="DEG", help="uncertainty of --gravity (default: 1)")
    point = group.add_argument("--principal-point", nargs="+", metavar="CX CY|estimate",
                               help="in pixels, or estimate (default: the image centre)")
    point.shown_args = "X Y"
    group.add_argument("--k1", metavar="K1|estimate", help="lens distortion, or estimate (default: none)")
    if same_camera:
        group.add_argument("--same-camera", action="store_true", help=same_camera)


def camera_arguments(args: argparse.Namespace) -> dict:
    """``calibrate()``'s camera arguments of the command line.

    Raises:
        ValueError: a ``--principal-point`` that is neither two numbers nor ``estimate``, a ``--k1`` that is
            neither a number nor ``estimate``.
    """
    point = args.principal_point
    if point is not None and point != ["estimate"]:
        try:
            point = tuple(float(v) for v in point)
        except ValueError:
            point = ()
        if len(point) != 2:
            given = " ".join(args.principal_point)
            raise ValueError(f"--principal-point takes CX CY in pixels or 'estimate', got {given}")
    k1 = args.k1
    if k1 is not None and k1 != "estimate":
        try:
            k1 = float(k1)
        except ValueError:
            raise ValueError(f"--k1 takes a number or 'estimate', got {k1!r}") from None
    return {
        "gravity": None if args.gravity is None else tuple(args.gravity),
        "gravity_std": args.gravity_std,
        "principal_point": "estimate" if point == ["estimate"] else point,
        "k1": k1,
    }


def load_truth(path: str | None) -> dict[Path, object]:
    """The labelled images of a CSV manifest or of a folder written by ``ngp render`` (``--truth``), by their
    resolved paths; empty without a path.

    Raises:
        FileNotFoundError: no such file or folder; ValueError: a malformed one.
    """
    if path is None:
        return {}
    from ngp_kornia.evaluation.datasets import load_manifest, load_renders

    source = Path(path)
    if not source.exists():
        raise FileNotFoundError(f"--truth {path}: no such file or folder")
    images = load_renders(source if source.is_dir() else source.parent) if (
        source.is_dir() or source.name == "ground_truth.json") else load_manifest(source)
    return {Path(image.image_path).resolve(): image for image in images}
