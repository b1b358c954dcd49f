"""Which decoder gives an image file's pixels: time ratios and pixel differences, in one run.

For every JPEG under the folders given (York Urban, Eurasian Cities, ...), interleaved file by file over several
passes on one thread, from the file's bytes in memory:

- ``cv2.imdecode`` (+ BGR-to-RGB), what ``ngp_kornia.io`` decoded with before it moved to Pillow: the reference;
- Pillow (``Image.open(...).convert("RGB")``);
- libjpeg-turbo through kornia-rs (``kornia_rs.io.decode_image_jpegturbo``), which ``ngp_kornia.io`` uses;
- and :func:`ngp_kornia.io.read_rgb` on the file: the whole read (open, checks, EXIF, decode, orientation).

It prints each one's total time over cv2's, and how many pixels of each differ from cv2's (and from cv2's turned by
the file's EXIF orientation, for ``read_rgb``). The same for PNG on synthetic renders (cv2 against Pillow), which
need no data set.

Usage: python benchmarks/image_decoders.py /path/to/YorkUrbanDB /path/to/EurasianCities [--passes 5]
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import cv2
import kornia_rs
import numpy as np
import torch
from PIL import Image

from ngp_kornia.data.synth.render import render_scene
from ngp_kornia.io import apply_orientation, exif_orientation, read_rgb


def _cv2(data: bytes) -> np.ndarray:
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _pillow(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _turbo(data: bytes) -> np.ndarray:
    return kornia_rs.io.decode_image_jpegturbo(data, "rgb")


def _time(decoders: dict, files: list[Path], passes: int) -> dict[str, float]:
    """Total seconds of each decoder over ``passes`` passes, the order turned round file by file."""
    blobs = [f.read_bytes() for f in files]
    totals = dict.fromkeys(decoders, 0.0)
    for p in range(passes):
        for i, (path, data) in enumerate(zip(files, blobs, strict=True)):
            order = list(decoders.items())
            for name, fn in order if (i + p) % 2 else order[::-1]:
                start = time.perf_counter()
                fn(path if name == "read_rgb" else data)
                totals[name] += time.perf_counter() - start
    return totals


def _differences(decoders: dict, files: list[Path]) -> dict[str, tuple[int, int]]:
    """Per decoder: (pixels that differ from cv2's, files with any such pixel)."""
    counts = {name: [0, 0] for name in decoders if name != "cv2"}
    for path in files:
        data = path.read_bytes()
        reference = _cv2(data)
        for name in counts:
            if name == "read_rgb":
                got, want = read_rgb(path), apply_orientation(reference, exif_orientation(data))
            else:
                got, want = decoders[name](data), reference
            differ = int((got != want).any(axis=-1).sum()) if got.shape == want.shape else got.shape[0] * got.shape[1]
            counts[name][0] += differ
            counts[name][1] += differ > 0
    return {name: (c[0], c[1]) for name, c in counts.items()}


def _report(title: str, files: list[Path], decoders: dict, passes: int) -> None:
    totals = _time(decoders, files, passes)
    pixels = sum(int(np.prod(_cv2(f.read_bytes()).shape[:2])) for f in files)
    print(f"{title}: {len(files)} files, {pixels / 1e6:.1f} megapixels, {passes} passes")
    for name, (count, in_files) in {"cv2": (0, 0), **_differences(decoders, files)}.items():
        ratio = totals[name] / totals["cv2"]
        print(f"  {name:9s} time / cv2's {ratio:.3f}   pixels differing {count} in {in_files} files")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--passes", type=int, default=5)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    jpegs = sorted(f for folder in args.folders for f in folder.rglob("*") if f.suffix.lower() in (".jpg", ".jpeg"))
    tags = [exif_orientation(f.read_bytes()) for f in jpegs]
    print(f"EXIF orientation tags of the JPEGs: { {int(t): tags.count(t) for t in sorted(set(tags))} }")
    jpeg_decoders = {"cv2": _cv2, "Pillow": _pillow, "kornia-rs": _turbo, "read_rgb": read_rgb}
    _report("JPEG", jpegs, jpeg_decoders, args.passes)
    with tempfile.TemporaryDirectory() as folder:
        pngs = []
        for seed in range(8):
            pngs.append(Path(folder) / f"{seed}.png")
            cv2.imwrite(str(pngs[-1]), cv2.cvtColor(render_scene(seed, size=(640, 480)).image, cv2.COLOR_RGB2BGR))
        _report("PNG (renders)", pngs, {"cv2": _cv2, "Pillow": _pillow, "read_rgb": read_rgb}, args.passes)


if __name__ == "__main__":
    main()
