"""Small constant tensors the parser's steps build once per dtype and device instead of on every call."""

from __future__ import annotations

from functools import lru_cache

import torch
from torch import Tensor

__all__ = ["constant_tensors"]


@lru_cache(maxsize=64)
def constant_tensors(
    values: tuple[tuple[float, ...], ...], dtype: torch.dtype, device: torch.device
) -> tuple[Tensor, ...]:
    """One tensor per row of ``values``, built once per dtype and device (read only: every use makes a new tensor
    from them). Ordinary tensors even when first built in inference mode, so callers with autograd can use them
    too."""
    with torch.inference_mode(False):
        return tuple(torch.tensor(v).to(device=device, dtype=dtype) for v in values)
