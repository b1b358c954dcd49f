"""Fixtures shared by the tests: the devices and dtypes every batched function must support.

``device`` runs a test on the CPU and, where a CUDA GPU is present, on it too (skipped otherwise); ``dtype`` runs it
in float32 and float64. A test asks for them by name (``def test_x(device, dtype): ...``).
"""

import pytest
import torch


@pytest.fixture(params=["cpu", "cuda"])
def device(request) -> torch.device:
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device(request.param)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request) -> torch.dtype:
    return request.param
