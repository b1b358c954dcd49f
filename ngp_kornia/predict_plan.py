"""The plan of an ``ngp predict`` run, made before it starts: the results file checked, and with ``--resume`` the
images an earlier run of the same images and options left without a row (:func:`plan_run`). It reads files and
writes none, so every process of a run over several machines makes the same plan from the same files before they
start together.
"""

from __future__ import annotations

import hashlib
import json
import os
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ngp_kornia.data.image_list import ImageList
from ngp_kornia.errors import OutputError
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.priors import Priors
from ngp_kornia.preflight import same_file
from ngp_kornia.rowfiles import RunFolder

__all__ = ["RunPlan", "plan_run"]


@dataclass(frozen=True)
class RunPlan:
    """What a run will do (:func:`plan_run`): every process of a run over several machines makes the same plan
    from the same files before they start together.

    Attributes:
        images: the collection.
        out: the file the rows go to (a link's target).
        todo: the indices of the images still without a row, in input order.
        keep: continue an earlier run (its rows stay); else the run starts with no rows.
        state: what identifies the run (the images and the options), as its run folder records it.
        settings: the options a row depends on: weights, seed, config, priors, exif, same_camera.
    """

    images: ImageList
    out: Path
    todo: Sequence[int]
    keep: bool
    state: dict
    settings: dict

    @property
    def done(self) -> int:
        """Images that have their row from an earlier run."""
        return len(self.images) - len(self.todo)


def plan_run(images: ImageList, out: str | Path, resume: bool = False, **settings) -> RunPlan:
    """Check ``out`` and, with ``resume``, find which images an earlier run of the same images and options left
    without a row (all of them when there is no such run); reads files, writes none.

    Args:
        images: the collection.
        out: the ``.jsonl`` file to write.
        resume: continue the unfinished run for ``out``.
        settings: ``weights``, ``seed``, ``config``, ``priors``, ``exif``, ``same_camera`` as for
            :func:`predict_folder`.

    Raises:
        OutputError: ``out`` is refused (see :func:`predict_folder`), a run still going writes it, or the
            unfinished run to resume had other images or other options.
    """
    from ngp_kornia import __version__

    settings = {"weights": "default", "seed": 0, "config": None, "priors": None, "exif": False,
                "same_camera": False, **settings}
    target = _check_out(Path(out), images)
    folder = RunFolder(target)
    if folder.in_use():
        raise OutputError(f"another ngp predict is writing {out} (its run folder {folder.path} is in use); wait for "
                          "it to end, or give another --out")
    shown = {**settings, "weights": str(settings["weights"]), "config": settings["config"] or ParserConfig(),
             "priors": settings["priors"] or Priors()}
    options = json.dumps({key: repr(value) for key, value in shown.items()} | {"version": __version__})
    state = {"format": 1, "images": len(images), "inputs": images.fingerprint(),
             "options": hashlib.sha256(options.encode()).hexdigest()}
    earlier = folder.state() if resume else None
    if earlier is None:
        return RunPlan(images, target, range(len(images)), False, state, settings)
    _check_same_run(earlier, state, out)
    flags = folder.done(len(images))
    todo = array("q", (i for i, flag in enumerate(flags) if not flag))
    return RunPlan(images, target, todo, True, state, settings)


def _check_same_run(earlier: dict, state: dict, out) -> None:
    if (earlier.get("images"), earlier.get("inputs")) != (state["images"], state["inputs"]):
        raise OutputError(
            f"--resume: the unfinished run for {out} calibrates other images ({earlier.get('images')} then, "
            f"{state['images']} now, or other files or order); give the same folder or list, or run without "
            "--resume to start over"
        )
    if (earlier.get("format"), earlier.get("options")) != (state["format"], state["options"]):
        raise OutputError(
            f"--resume: the unfinished run for {out} had other options (weights, seed, priors, settings, or "
            "another version of ngp-kornia); give the same ones, or run without --resume to start over"
        )


def _check_out(out: Path, images: ImageList) -> Path:
    """The file the rows replace: ``out``, or the file it links to (the link stays a link). Refused: a folder, a
    device or pipe, one of the images (by any name, hard links too), and an existing file that holds no rows of
    ``ngp predict`` (it would be lost)."""
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the .jsonl file to write, e.g. {out / 'results.jsonl'}")
    target = out.resolve()
    if target.exists() and not target.is_file():
        raise OutputError(f"--out {out} is not a regular file (a device or a pipe); give a file, e.g. results.jsonl")
    rows = target.is_file() and _holds_rows(target)
    # an existing file of rows is no image: only a file that is not one is looked for among the images
    if target.exists() and (not rows or target.stat().st_size == 0):
        if any(same_file(path, target) for path in images.paths):
            raise OutputError(f"--out {out} is one of the input images; give another file, e.g. results.jsonl")
    if target.is_file() and not rows:
        raise OutputError(
            f"--out {out} exists and holds no rows of ngp predict, so it would be lost; give another file or remove it"
        )
    folder = next(p for p in target.parents if p.exists())  # the folders below it are made
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"--out {out}: cannot write in {folder}; give a file in a folder you may write to")
    return target


def _holds_rows(path: Path) -> bool:
    """Whether a file may be replaced: empty, or its first line a row as ``ngp predict`` writes them."""
    try:
        with path.open("rb") as f:
            first = f.readline(1 << 20)
    except OSError:
        return False
    if not first.strip():
        return True
    try:
        row = json.loads(first)
    except (ValueError, UnicodeDecodeError):
        return False
    return isinstance(row, dict) and "image" in row
