"""The files ``ngp calibrate --overlay``, ``ngp rectify -o`` and ``ngp demo --overlay`` write: checked before any
image is read (never an input, never an existing file without ``--force``, an extension OpenCV can write), then
written. Imports nothing heavy until a file is checked or written."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ngp_kornia.errors import OutputError
from ngp_kornia.preflight import same_file

if TYPE_CHECKING:
    import numpy as np

    from ngp_kornia.pipeline import ParserConfig

__all__ = ["check_output", "check_overlays", "overlay_path", "write_image", "write_overlay"]


def overlay_path(target: str, image: str, many: bool) -> Path:
    """Where ``--overlay target`` puts the overlay of ``image``: ``target`` itself, or for ``many`` images the file
    ``<image name>_overlay.png`` in the folder ``target``."""
    if not many:
        return Path(target)
    return Path(target) / f"{Path(image).stem}_overlay.png"


def check_overlays(target: str, images: list[str], force: bool) -> None:
    """Refuse ``--overlay`` where it names a file for several images, or where two images would write one overlay
    (the same name in two folders): the second would replace the first within the run."""
    if len(images) == 1:
        return check_output(Path(target), force, images)
    if Path(target).is_file() or (not Path(target).is_dir() and Path(target).suffix.lower() in (".png", ".jpg")):
        raise OutputError(f"--overlay {target} names a file, but {len(images)} images were given; give a folder")
    first: dict[Path, str] = {}
    for image in images:
        other = first.setdefault(overlay_path(target, image, True), image)
        if other != image:
            raise OutputError(
                f"{other} and {image} would both write {overlay_path(target, image, True)}; calibrate them in "
                "separate runs, or give one of them another name"
            )
    return None


def check_output(path: Path, force: bool, inputs: list[str] = ()) -> None:
    """Refuse an output image path that OpenCV cannot write (no or unknown extension), that is one of the inputs,
    or that exists already (unless ``force``).

    Raises:
        OutputError: with the fix in the message.
    """
    import cv2

    if path.is_dir():
        raise OutputError(f"{path} is a folder; give the image file to write, e.g. {path / 'out.png'}")
    if not cv2.haveImageWriter(str(path)):
        raise OutputError(f"{path}: cannot tell the image format from the extension; end the name with .png or .jpg")
    if path.exists():
        if any(same_file(path, i) for i in inputs):
            raise OutputError(f"{path} is one of the input images; write the output to another file")
        if not force:
            raise OutputError(f"{path} exists; add --force to overwrite it, or choose another name")


def write_image(path: Path, rgb: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 RGB image, making its folder.

    Raises:
        OutputError: OpenCV could not write it.
    """
    import cv2
    import numpy as np

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise OutputError(f"could not write {path}")


def write_overlay(path: Path, rgb: np.ndarray, calibration, config: ParserConfig | None = None, truth=None) -> None:
    """Draw and write the overlay of a calibration (:func:`ngp_kornia.viz.draw_calibration`) over the lines it saw."""
    from ngp_kornia.pipeline.segments import detect_segments
    from ngp_kornia.viz import draw_calibration

    settings = None if config is None else config.segments
    segments = detect_segments(rgb, settings)[0][0].numpy()  # the lines the calibration saw (same settings)
    write_image(path, draw_calibration(rgb, calibration, segments, truth=truth))
