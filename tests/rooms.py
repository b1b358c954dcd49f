"""Shared inputs of the dtype and device tests of pipeline/ and nets/ (tests/pipeline/test_pipeline_dtypes.py,
tests/nets/test_nets_dtypes.py): two synthetic Manhattan scenes, the parser's answer and trace on them, made in
float64 on the CPU and cast to a given device and dtype; and the checks those tests make of an output (device,
dtype, finite values, close to float64 on the CPU).
"""

from __future__ import annotations

import dataclasses
import inspect
from functools import lru_cache
from types import SimpleNamespace

import torch

from ngp_kornia.geometry import segment_lengths, segments_to_lines, to_pseudo_camera
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.line_kernel import camera_segments
from ngp_kornia.pipeline.priors import Priors
from tests.pipeline.test_parser import manhattan_segments

SIZE = (240, 320)  # (H, W)
F64 = torch.float64


@lru_cache(maxsize=8)
def scene(device: str, dtype: torch.dtype) -> SimpleNamespace:
    """Two scenes (B = 2; the second with fewer segments, padded) and what the parser makes of them."""
    first, _, _, _ = manhattan_segments(12.0, -6.0, 25.0, size=SIZE, seed=0)
    second, _, _, _ = manhattan_segments(-8.0, 4.0, -30.0, size=SIZE, seed=1)
    n = max(first.shape[1], second.shape[1])
    segments = torch.zeros(2, n, 2, 2, dtype=torch.float64)
    mask = torch.zeros(2, n, dtype=torch.bool)
    for i, seg in enumerate((first, second)):
        segments[i, : seg.shape[1]], mask[i, : seg.shape[1]] = seg[0].double(), True
    g = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, *SIZE, generator=g, dtype=torch.float64)
    segments, mask, images = segments.to(device, dtype), mask.to(device), images.to(device, dtype)
    parser = NeuralGeometricParser(ParserConfig().replace(num_scored=8))
    with torch.no_grad():
        cal, trace = parser(images, segments, mask, return_trace=True)
    return SimpleNamespace(images=images, segments=segments, mask=mask, cal=cal, trace=trace, device=device,
                           dtype=dtype, height=SIZE[0], width=SIZE[1])  # fmt: skip


def tensors(out) -> list[torch.Tensor]:
    """Every tensor in an output: a tensor, a tuple or list (NamedTuples too), a dict, a dataclass (a Calibration's
    :data:`~ngp_kornia.pipeline.Calibration.FIELDS`)."""
    if isinstance(out, torch.Tensor):
        return [out]
    if isinstance(out, Calibration):
        return tensors([getattr(out, name) for name in Calibration.FIELDS])
    if dataclasses.is_dataclass(out) and not isinstance(out, type):
        return tensors([getattr(out, f.name) for f in dataclasses.fields(out)])
    if isinstance(out, dict):
        return tensors(list(out.values()))
    if isinstance(out, (tuple, list)):
        return [t for item in out for t in tensors(item)]
    return []


def check_output(out, reference, device: str, dtype: torch.dtype, float_dtype: torch.dtype | None = None, tol=None):
    """``out`` lies on ``device``, its floating tensors are of ``float_dtype`` (default: ``dtype``) and finite, and
    match ``reference`` (the float64 CPU output) within ``tol`` (absolute and relative; None: float32's 1e-3, float64's
    1e-8; False: not compared, for outputs that branch on rounding)."""
    got, want = tensors(out), tensors(reference)
    assert got, "no tensor in the output"
    assert len(got) == len(want)
    for t, r in zip(got, want, strict=True):
        assert t.device.type == torch.device(device).type
        if t.is_floating_point():
            assert t.dtype == (float_dtype or dtype), t.dtype
            assert bool(torch.isfinite(t).all())
        if tol is False or not t.is_floating_point():
            continue
        bound = tol if tol is not None else (1e-3 if dtype == torch.float32 else 1e-8)
        torch.testing.assert_close(t.detach().cpu().double(), r.detach().cpu().double(), atol=bound, rtol=bound)


def public_functions(package) -> dict[str, object]:
    """``module.name`` -> function, for every function in the ``__all__`` of every module of a package."""
    import importlib
    import pkgutil

    found = {}
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for name in getattr(module, "__all__", []):
            if inspect.isfunction(getattr(module, name, None)):
                found[f"{info.name}.{name}"] = getattr(module, name)
    return found


def _cast(value, device, dtype):
    """The float64 CPU inputs in another device and dtype: floating tensors cast, the others moved."""
    if isinstance(value, torch.Tensor):
        return value.to(device, dtype) if value.is_floating_point() else value.to(device)
    if isinstance(value, Calibration):
        return value.to(device, dtype)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return type(value)(**{f.name: _cast(getattr(value, f.name), device, dtype) for f in dataclasses.fields(value)})
    if isinstance(value, tuple) and hasattr(value, "_fields"):
        return type(value)(*(_cast(v, device, dtype) for v in value))
    if isinstance(value, (tuple, list)):
        return type(value)(_cast(v, device, dtype) for v in value)
    return value


def inputs(device: str, dtype: torch.dtype):
    """The scenes of :func:`tests.rooms.scene` made in float64 on the CPU, cast: the same inputs in every dtype."""
    s = scene("cpu", F64)
    cast = {k: _cast(v, device, dtype) for k, v in vars(s).items() if k not in ("device", "dtype")}
    x = type(s)(**cast, device=device, dtype=dtype)
    x.pseudo = to_pseudo_camera(x.segments, x.height, x.width)
    x.lines = segments_to_lines(x.pseudo)
    x.lengths = segment_lengths(x.segments, x.mask)
    x.generators = [torch.Generator().manual_seed(0) for _ in range(2)]
    x.cam = camera_segments(x.segments, x.cal.K)
    x.ups = x.cal.up[:, None].expand(2, 3, 3).contiguous()
    x.priors = Priors(gravity=(5.0, -2.0), gravity_std=3.0)
    return x
