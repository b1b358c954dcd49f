"""What the parser refuses and what it accepts: ParserConfig fields checked by name, half-precision images computed
in float32 and returned in their dtype, NaN segments refused (NaN padding ignored)."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia import ConfigError, InputError, NeuralGeometricParser, ParserConfig, calibrate


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("fallback_fov", float("nan"), "ParserConfig.fallback_fov must be a finite number"),
        ("fallback_fov", 0.0, r"ParserConfig.fallback_fov must be an angle in degrees, in \(0, 180\), got 0.0"),
        ("focal_range", (0.0, 4.0), "ParserConfig.focal_range must be two finite numbers 0 < low < high"),
        ("focal_range", (2.0, 1.0), "ParserConfig.focal_range"),
        ("working_size", 0, "ParserConfig.working_size must be an integer at least 32 pixels, got 0"),
        ("num_frames", 0, "ParserConfig.num_frames must be an integer at least 1, got 0"),
        ("top_k", -1, "ParserConfig.top_k"),
        ("seed", 2**70, r"ParserConfig.seed must be an integer in \[0, 2\*\*64 - 1\]"),
        ("seed", -1, "ParserConfig.seed"),
        ("seed", 1.5, "ParserConfig.seed must be an integer"),
        ("min_length", float("inf"), "ParserConfig.min_length must be a finite number"),
        ("kernel_angle", 90.0, "ParserConfig.kernel_angle"),
        ("use_manhattan", "yes", "ParserConfig.use_manhattan must be True or False"),
    ],
)
def test_config_fields_are_checked_by_name(field, value, message):
    with pytest.raises(ConfigError, match=message):
        ParserConfig(**{field: value})


def test_bad_seed_through_calibrate_and_the_command_line(tmp_path):
    with pytest.raises(ConfigError, match="ParserConfig.seed"):
        calibrate(torch.rand(3, 64, 64), seed=2**70)
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.full((64, 64, 3), 100, np.uint8))
    run = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", "--seed", str(2**70), str(image)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 1 and run.stderr.count("\n") == 1 and "ParserConfig.seed must be" in run.stderr


def test_the_defaults_and_edges_are_accepted():
    ParserConfig()
    ParserConfig(num_horizontal_frames=0, min_length=0.0, seed=2**64 - 1, working_size=32, focal_range=[0.5, 5])


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_is_computed_in_float32_and_returned_in_its_dtype(dtype):
    from ngp_kornia.training.synth.render import render_scene

    image = torch.from_numpy(render_scene(2, size=(320, 240)).image).permute(2, 0, 1).float() / 255
    reference = calibrate(image, weights="fsnet")
    half = calibrate(image.to(dtype), weights="fsnet")
    assert half.K.dtype == dtype and half.valid.dtype == torch.bool
    # the same answer, up to the rounding of the image to the half type and of the result
    assert abs(float(half.fov_v) - float(reference.fov_v)) < 1.0
    assert abs(float(half.pitch) - float(reference.pitch)) < 0.5 and abs(float(half.roll) - float(reference.roll)) < 0.5


def test_nan_segments_are_refused_and_nan_padding_is_ignored():
    parser = NeuralGeometricParser()
    images = torch.rand(1, 3, 64, 64)
    segments = torch.tensor([[[[5.0, 5.0], [5.0, 60.0]], [[40.0, 5.0], [42.0, 60.0]], [[1.0, 1.0], [9.0, 9.0]]]])
    mask = torch.tensor([[True, True, False]])
    clean = parser(images, segments, mask)
    padded = segments.clone()
    padded[0, 2] = float("nan")
    assert torch.equal(parser(images, padded, mask).K, clean.K)
    poisoned = segments.clone()
    poisoned[0, 1, 0, 0] = float("nan")
    with pytest.raises(InputError, match="segment 1 of image 0 has NaN or infinite coordinates"):
        parser(images, poisoned, mask)
    with pytest.raises(InputError, match="without their"):
        parser(images, segments)
