"""Reading and checking input images: files, numpy arrays and tensors become (B, 3, H, W) float RGB in [0, 1].

Every problem raises :class:`ImageError` (a ``ValueError``) with a message that names the input, what is wrong
and what to do about it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

__all__ = ["MIN_SIZE", "ImageError", "as_batch", "load_image", "read_image_file", "read_rgb"]

MIN_SIZE = 32


class ImageError(ValueError):
    """An input image that cannot be calibrated, with the reason and the fix."""


def read_image_file(path: str | Path) -> np.ndarray:
    """Decode an image file to an HxWx3 uint8 RGB array (greyscale, 16-bit and RGBA files are converted).

    Raises:
        ImageError: missing, empty, undecodable or truncated files.
    """
    path = Path(path)
    if not path.exists():
        raise ImageError(f"{path}: file not found")
    if path.is_dir():
        raise ImageError(f"{path}: is a directory, expected an image file")
    data = np.fromfile(str(path), dtype=np.uint8)
    if data.size == 0:
        raise ImageError(f"{path}: file is empty")
    if _is_truncated(data):
        raise ImageError(f"{path}: image data is truncated (the file ends before the image does); re-export it")
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageError(f"{path}: not a readable image (supported: JPEG, PNG, TIFF, BMP, WebP, ...)")
    try:
        return to_rgb_uint8(image, bgr=True)
    except ImageError as err:
        raise ImageError(f"{path}: {err}") from None


def _is_truncated(data: np.ndarray) -> bool:
    head, tail = data[:8].tobytes(), data[-32:].tobytes()
    if head.startswith(b"\xff\xd8"):  # JPEG: must end with the end-of-image marker
        return b"\xff\xd9" not in tail
    if head.startswith(b"\x89PNG"):  # PNG: must end with the IEND chunk
        return b"IEND" not in tail
    return False


def to_rgb_uint8(image: np.ndarray, bgr: bool = False) -> np.ndarray:
    """Convert an HxW, HxWx1, HxWx3 or HxWx4 array (uint8, uint16 or float in [0, 1]) to HxWx3 uint8 RGB."""
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in (1, 3, 4):
        raise ImageError(f"expected an HxW, HxWx3 or HxWx4 image, got an array of shape {image.shape}")
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) / 257.0).round().astype(np.uint8)
    elif image.dtype in (np.float32, np.float64):
        if not np.isfinite(image).all():
            raise ImageError("image contains NaN or infinite values")
        if image.min() < 0.0 or image.max() > 1.0:
            raise ImageError("float images must lie in [0, 1]; divide 8-bit values by 255")
        image = (image * 255.0).round().astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ImageError(f"unsupported pixel type {image.dtype}; use uint8, uint16 or float in [0, 1]")
    channels = image.shape[2]
    if channels == 1:
        return np.repeat(image, 3, axis=2)
    if bgr and image.dtype == np.uint8:  # OpenCV's swap is many times faster than numpy's reversed copy
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if channels == 4 else cv2.COLOR_BGR2RGB)
    image = image[..., :3]  # drop alpha
    return np.ascontiguousarray(image[..., ::-1] if bgr else image)


def _check_size(height: int, width: int, name: str) -> None:
    if min(height, width) < MIN_SIZE:
        raise ImageError(
            f"{name} is {width}x{height} pixels; at least {MIN_SIZE} px on each side is needed to find lines"
        )


def load_image(image: str | Path | np.ndarray) -> Tensor:
    """A file path or an HxWx3 uint8 RGB array as a (1, 3, H, W) float tensor in [0, 1].

    Example:
        >>> load_image(np.zeros((40, 50, 3), np.uint8)).shape
        torch.Size([1, 3, 40, 50])
    """
    return torch.from_numpy(read_rgb(image)).permute(2, 0, 1)[None].float().div(255.0)


def read_rgb(image: str | Path | np.ndarray) -> np.ndarray:
    """A file path or an image array as a checked HxWx3 uint8 RGB array (see :func:`to_rgb_uint8`).

    Example:
        >>> read_rgb(np.zeros((40, 50), np.uint16)).shape
        (40, 50, 3)
    """
    if isinstance(image, (str, Path)):
        rgb, name = read_image_file(image), str(image)
    elif isinstance(image, np.ndarray):
        rgb, name = to_rgb_uint8(image), "image array"
    else:
        raise TypeError(f"expected a path, a numpy array or a torch tensor, got {type(image).__name__}")
    _check_size(rgb.shape[0], rgb.shape[1], name)
    return rgb


def as_batch(image: str | Path | np.ndarray | Tensor) -> tuple[Tensor, bool]:
    """Any supported input as a checked (B, 3, H, W) float tensor in [0, 1], and whether the input was batched.

    Example:
        >>> x, batched = as_batch(torch.rand(3, 40, 40))
        >>> x.shape, batched
        (torch.Size([1, 3, 40, 40]), False)
    """
    if not isinstance(image, Tensor):
        return load_image(image), False
    if not image.is_floating_point():
        raise TypeError(f"expected a float tensor in [0, 1], got {image.dtype}; for uint8 use image.float() / 255")
    if image.dim() not in (3, 4) or image.shape[-3] != 3:
        raise ImageError(f"expected a (3, H, W) or (B, 3, H, W) RGB tensor, got shape {tuple(image.shape)}")
    if image.numel() == 0:
        raise ImageError(f"empty image tensor of shape {tuple(image.shape)}: expected at least one 3xHxW image")
    if not bool(torch.isfinite(image).all()):
        raise ImageError("image tensor contains NaN or infinite values")
    if float(image.min()) < 0.0 or float(image.max()) > 1.0:
        raise ImageError("image tensor values must lie in [0, 1]; divide 8-bit values by 255")
    batched = image.dim() == 4
    batch = image if batched else image[None]
    _check_size(batch.shape[-2], batch.shape[-1], "image tensor")
    return batch, batched
