"""ngp predict on a GPU: the networks run there, and the rows are the CPU's up to float rounding. Skipped where
torch sees no CUDA device (``make test-gpu`` runs the ``gpu`` tests where one is)."""

import json
import math
import subprocess
import sys

import cv2
import pytest
import torch

from ngp_kornia.predict import predict_folder
from ngp_kornia.training.synth.render import render_scene

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device"),
]

#: the largest difference between a GPU row and the CPU row of the same image, per field (degrees; the field of
#: view's in degrees too): float32 kernels that add in another order, not another answer
TOLERANCE = {"pitch": 0.05, "roll": 0.05, "fov_v": 0.1}


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("photos")
    for seed in range(6):
        image = render_scene(seed, size=(320, 240)).image
        cv2.imwrite(str(root / f"scene{seed:02d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    (root / "broken.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    return root


@pytest.fixture(scope="module")
def cpu_rows(folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("cpu") / "rows.jsonl"
    predict_folder(folder, out)
    return _rows(out)


def _close(gpu: dict, cpu: dict) -> list[str]:
    """The fields of two rows of one image that differ by more than TOLERANCE."""
    return [
        f"{gpu['image']} {key}: {gpu[key]:.4f} on the GPU, {cpu[key]:.4f} on the CPU"
        for key, tolerance in TOLERANCE.items()
        if not math.isclose(gpu[key], cpu[key], abs_tol=tolerance)
    ]


def test_the_networks_run_on_the_gpu_and_give_the_cpus_rows(folder, cpu_rows, tmp_path):
    torch.cuda.reset_peak_memory_stats()
    counts = predict_folder(folder, tmp_path / "gpu.jsonl", accelerator="gpu", devices=1)
    assert torch.cuda.max_memory_allocated() > 0  # the networks and the images went to the GPU
    rows = _rows(tmp_path / "gpu.jsonl")
    assert counts == {"images": 7, "errors": 1, "interrupted": False, "rank": 0}
    assert [r["image"] for r in rows] == [r["image"] for r in cpu_rows]
    assert rows[0] == cpu_rows[0] and "error" in rows[0]  # broken.jpg
    assert [line for g, c in zip(rows[1:], cpu_rows[1:], strict=True) for line in _close(g, c)] == []


def test_the_command_on_one_gpu_with_loader_workers(folder, cpu_rows, tmp_path):
    out = tmp_path / "rows.jsonl"
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out),
               "--accelerator", "gpu", "--devices", "1", "--workers", "2"]
    run = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert run.returncode == 1 and "7 rows written" in run.stdout, run.stderr[-2000:]  # 1: broken.jpg
    rows = _rows(out)
    assert [r["image"] for r in rows] == [r["image"] for r in cpu_rows]
    assert [line for g, c in zip(rows[1:], cpu_rows[1:], strict=True) for line in _close(g, c)] == []
