"""``ngp render OUTDIR``: synthetic scenes with exact ground truth, as PNG images plus ``ground_truth.json``.

Its arguments are parsed, and --size and --count checked, without importing torch; the renderer is imported when
the command runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ngp_kornia.errors import OutputError

__all__ = ["add_render_command", "read_render_config", "render_command"]

#: the limits of :mod:`ngp_kornia.io` (``MIN_SIZE``, ``MAX_PIXELS``, which ``NGP_MAX_PIXELS`` overrides), here without
#: importing it (and torch) so that an argument error answers at once; a test holds them equal
MIN_SIDE = 32
MAX_PIXELS = 2**27
#: seconds before a progress bar appears: short runs show none
PROGRESS_DELAY = 2.0


def _size(text: str) -> tuple[int, int]:
    """``--size WxH`` as ``(W, H)``."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must look like 640x480, got {text!r}") from None
    if min(width, height) < MIN_SIDE:
        raise argparse.ArgumentTypeError(
            f"width and height must be at least {MIN_SIDE} pixels (smaller images cannot be calibrated), got {text!r}"
        )
    limit = os.environ.get("NGP_MAX_PIXELS", "")
    limit = int(limit) if limit.isdigit() and int(limit) > 0 else MAX_PIXELS
    if width * height > limit:
        raise argparse.ArgumentTypeError(
            f"at most {limit:,} pixels, the largest image the parser reads, got {text!r}; e.g. 1920x1080"
        )
    return width, height


def _count(text: str) -> int:
    try:
        count = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if count < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {count}")
    return count


def add_render_command(sub) -> None:
    """Add ``render`` to the ``ngp`` command's subparsers (``argparse``'s ``add_subparsers()`` object)."""
    render = sub.add_parser(
        "render",
        help="render synthetic scenes with exact ground truth",
        description="Render procedural street, room and plaza scenes seen by random cameras, as PNG images plus "
        "ground_truth.json (one record per image: K, R, focal, fov_v, fov_h, pitch, roll, zenith, horizon, vps).",
    )
    render.add_argument("outdir", help="folder to write the images and ground_truth.json into (created)")
    render.add_argument("--count", type=_count, default=16, help="number of scenes")
    render.add_argument("--seed", type=int, default=0, help="dataset seed: each image gets its own seed from it")
    render.add_argument("--size", type=_size, default="640x480", help="image size WxH in pixels")
    render.add_argument("--force", action="store_true", help="write into a folder that is not empty")
    render.add_argument(
        "--config",
        help='a JSON file of RenderConfig settings, e.g. {"stairs": 1.5, "fronto_prob": 0.3, "pitch": [-45, 55]} '
        "(the hard cases, the camera imperfections centre_std and radial_distortion, and every range of "
        "ngp_kornia.training.synth.render_config.RenderConfig)",
    )


def render_command(args: argparse.Namespace) -> int:
    """Run ``ngp render`` with its parsed arguments; the exit status (2: a bad --config file).

    Raises:
        OutputError: OUTDIR is a file, or a folder that is not empty (without --force).
    """
    try:
        config = read_render_config(args.config)
    except ValueError as err:
        print(f"ngp: error: --config {args.config}: {err}", file=sys.stderr)
        return 2
    outdir = Path(args.outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError(f"{outdir} is a file; give a folder to render into")
    if outdir.is_dir() and any(outdir.iterdir()) and not args.force:
        raise OutputError(f"{outdir} is not empty; add --force to write into it (same names are replaced)")
    from tqdm import tqdm

    from ngp_kornia.training.synth.render import render_dataset

    # a progress bar on a terminal only, and only for runs long enough to need one
    with tqdm(
        total=args.count, unit="scene", delay=PROGRESS_DELAY, disable=not sys.stderr.isatty(), desc="rendering"
    ) as bar:
        render_dataset(args.outdir, args.count, args.seed, args.size, config, progress=bar.update)
    print(f"wrote {args.count} images and ground_truth.json to {args.outdir}")
    return 0


def read_render_config(path: str | None):
    """The :class:`~ngp_kornia.training.synth.render_config.RenderConfig` of a JSON settings file (None: the defaults).

    Raises:
        ValueError: not a readable JSON object, an unknown setting, or a value RenderConfig refuses (the message
            names it).
    """
    from dataclasses import fields

    from ngp_kornia.training.synth.render_config import RenderConfig

    if path is None:
        return None
    try:
        settings = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"not a readable JSON file ({err})") from None
    if not isinstance(settings, dict):
        raise ValueError('give a JSON object of settings, e.g. {"stairs": 1.5}')
    known = [f.name for f in fields(RenderConfig)]
    unknown = sorted(set(settings) - set(known))
    if unknown:
        raise ValueError(f"unknown settings {unknown}; RenderConfig has {', '.join(known)}")
    try:
        return RenderConfig(**settings)
    except (TypeError, ValueError) as err:
        raise ValueError(str(err)) from None
