"""Small constant tensors the parser's steps build once per dtype and device instead of on every call."""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import torch
from torch import Tensor

__all__ = ["cached", "constant_tensors", "numbers_like", "rows_like"]


@lru_cache(maxsize=64)
def constant_tensors(
    values: tuple[tuple[float, ...], ...], dtype: torch.dtype, device: torch.device
) -> tuple[Tensor, ...]:
    """One tensor per row of ``values``, built once per dtype and device (read only: every use makes a new tensor
    from them). Ordinary tensors even when first built in inference mode, so callers with autograd can use them
    too."""
    with torch.inference_mode(False):
        return tuple(torch.tensor(v).to(device=device, dtype=dtype) for v in values)


#: tensors built once per key (which names their dtype and device)
_CACHE: dict[tuple, Any] = {}


def cached(key: tuple, build: Callable[[], Any]) -> Any:
    """``build()`` once per ``key``, then the same tensors: constants that cost more to build than the arithmetic
    that uses them. Built as ordinary tensors even inside inference mode (inference tensors could not serve callers
    with autograd)."""
    if key not in _CACHE:
        with torch.inference_mode(False):
            _CACHE[key] = build()
    return _CACHE[key]


def rows_like(like: Tensor, *rows: list) -> tuple[Tensor, ...]:
    """Constant tensors of ``rows`` in ``like``'s dtype and device, built once."""
    key = ("rows", repr(rows), like.dtype, like.device)
    return cached(key, lambda: tuple(torch.tensor(r, dtype=like.dtype, device=like.device) for r in rows))


def numbers_like(like: Tensor, *values: float) -> tuple[Tensor, ...]:
    """The numbers as 0-dim tensors of ``like``'s dtype and device, built once: an operation given a Python number
    converts it to such a tensor (the same value) on every call, which costs more than the arithmetic on small
    tensors."""
    key = ("numbers", *values, like.dtype, like.device)
    return cached(key, lambda: tuple(torch.tensor(v, dtype=like.dtype, device=like.device) for v in values))
