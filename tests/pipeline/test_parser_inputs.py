"""What the parser refuses and what it accepts: ParserConfig fields checked by name, what a caller passed quoted in one
line, half-precision images computed in float32 and returned in their dtype, NaN segments refused (NaN padding
ignored)."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia import ConfigError, InputError, NeuralGeometricParser, ParserConfig, calibrate
from ngp_kornia.api import CALL_PRIORS, shared_focal
from ngp_kornia.pipeline.priors import PRIOR_NAMES


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("fallback_fov", float("nan"), "ScoringSettings.fallback_fov must be a finite number"),
        ("fallback_fov", 0.0, r"ScoringSettings.fallback_fov must be a number in \(0, 180\), got 0.0"),
        ("focal_range", (0.0, 4.0), "SamplingSettings.focal_range must be two numbers 0 < low < high"),
        ("focal_range", (2.0, 1.0), "SamplingSettings.focal_range must be \\(low, high\\) with low < high"),
        ("working_size", 0, r"SegmentSettings.working_size must be an integer in \[32, 16384\], got 0"),
        ("num_frames", 0, r"SamplingSettings.num_frames must be an integer in \[1, 65536\], got 0"),
        ("num_frames", 10**7, r"SamplingSettings.num_frames must be an integer in \[1, 65536\]"),
        ("top_k", -1, "ScoringSettings.top_k"),
        ("top_k", True, "ScoringSettings.top_k must be an integer"),
        ("min_length", float("inf"), "SegmentSettings.min_length must be a finite number"),
        ("kernel_angle", 90.0, "ScoringSettings.kernel_angle"),
        ("use_manhattan", "yes", "ScoringSettings.use_manhattan must be True or False"),
        ("horizon.margin", -0.1, "HorizonSettings.margin"),
        ("focal_scales", (), "HorizonSettings.focal_scales must be positive numbers"),
        ("trust.centre_std", 0.3, "TrustSettings.centre_std"),
    ],
)
def test_settings_are_checked_by_name(key, value, message):
    with pytest.raises(ConfigError, match=message):
        ParserConfig().replace(**{key: value})


def test_unknown_and_ambiguous_settings_name_the_stages():
    with pytest.raises(ConfigError, match="unknown setting 'seed'; settings are stage.field"):
        ParserConfig().replace(seed=3)  # a call argument, not a setting
    with pytest.raises(ConfigError, match="unknown setting 'segments.refine'"):
        ParserConfig().replace(**{"segments.refine": True})
    with pytest.raises(ConfigError, match="ParserConfig.horizon must be a HorizonSettings"):
        ParserConfig(horizon={"refine": False})


def test_numpy_numbers_are_taken_as_python_ones():
    cfg = ParserConfig().replace(working_size=np.int64(640), margin=np.float32(0.5))
    assert type(cfg.segments.working_size) is int and cfg.segments.working_size == 640
    assert type(cfg.horizon.margin) is float


@pytest.mark.parametrize(
    "seed, message",
    [(2**70, r"seed must be in \[0, 2\*\*64 - 1\]"), (-1, "seed must be in"), (1.5, "seed must be an integer")]
    + [(True, "seed must be an integer")],
)
def test_bad_seeds_are_refused_by_the_call(seed, message):
    with pytest.raises(InputError, match=message):
        calibrate(torch.rand(3, 64, 64), seed=seed)
    with pytest.raises(InputError, match=message):
        NeuralGeometricParser()(torch.rand(1, 3, 64, 64), seed=seed)


def test_numpy_seeds_and_the_largest_seed_are_accepted():
    image = torch.rand(3, 64, 64)
    assert torch.equal(calibrate(image, seed=np.int64(5)).K, calibrate(image, seed=5).K)
    calibrate(image, seed=2**64 - 1)


@pytest.mark.parametrize(
    "kwargs, message",
    [({"focal": True}, r"focal must be a number of pixels in \(0, 1e8\)"), ({"fov_v": 180.0}, "fov_v must be an angle")]
    + [({"focal": 1e15}, r"focal must be a number of pixels in \(0, 1e8\)")]
    + [({"gravity": (0, 0), "gravity_std": 1e9}, r"gravity_std must be a number of degrees in \(0, 90\)")]
    + [({"focal": float("nan")}, "focal must be"), ({"num_threads": -1}, "expected a thread count")]
    + [({"weights": None}, "weights must be one of default")]
    + [({"exif": "yes"}, r"priors\['exif'\] must be True or False")],
)
def test_bad_call_arguments_are_one_clear_error(kwargs, message):
    with pytest.raises((InputError, ValueError, TypeError), match=message):
        _calibrate(**kwargs)


def _calibrate(**kwargs):
    """calibrate() on a small image, with the priors among ``kwargs`` passed as ``priors=``."""
    priors = {name: kwargs.pop(name) for name in list(kwargs) if name in (*PRIOR_NAMES, *CALL_PRIORS)}
    return calibrate(torch.rand(3, 64, 64), priors=priors, **kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [({"gravity": np.zeros(1000)}, r"gravity must be .* got <ndarray of shape \(1000,\)>$")]
    + [({"principal_point": np.zeros(1000)}, "principal_point must be .* got <ndarray of shape")]
    + [({"k1": torch.zeros(5, 100)}, r"k1 must be .* got <Tensor of shape \(5, 100\)>$")]
    + [({"weights": NeuralGeometricParser()}, "NeuralGeometricParser.*; a parser runs on tensors")]
    + [({"config": 5}, "config must be a ParserConfig, a mapping of settings"), ({"config": {"seed": 1}}, "'seed'")],
)
def test_what_a_caller_passed_is_quoted_in_one_line(kwargs, message):
    """A network or a large array passed where a number or a name belongs is named by its type, not printed."""
    with pytest.raises((InputError, ValueError), match=message) as err:
        _calibrate(**kwargs)
    assert "\n" not in str(err.value)


def test_pairs_and_settings_are_taken_in_the_forms_a_caller_has():
    image = torch.rand(3, 64, 80)
    plain = calibrate(image, priors={"principal_point": (41.0, 30.0), "gravity": (2.0, -1.0)})
    for pp, gravity in ((np.array([41, 30]), torch.tensor([2.0, -1.0])), ([41, 30], np.array([2.0, -1.0]))):
        other = calibrate(image, priors={"principal_point": pp, "gravity": gravity})
        assert torch.equal(other.K, plain.K) and torch.equal(other.R, plain.R)
    mapped = calibrate(image, config={"horizon.refine": False})
    built = calibrate(image, config=ParserConfig().replace(**{"horizon.refine": False}))
    assert torch.equal(mapped.K, built.K) and torch.equal(mapped.horizon, built.horizon)


def test_bad_seed_through_the_command_line(tmp_path):
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.full((64, 64, 3), 100, np.uint8))
    run = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", "--seed", str(2**70), str(image)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 1 and run.stderr.count("\n") == 1 and "seed must be in" in run.stderr


def test_the_defaults_and_edges_are_accepted():
    ParserConfig()
    ParserConfig().replace(num_horizontal_frames=0, min_length=0.0, working_size=32, focal_range=[0.5, 5])


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


def test_the_parser_takes_its_settings_as_calibrate_does_and_names_a_wrong_input():
    mapped = NeuralGeometricParser({"horizon.refine": False})
    assert mapped.config == ParserConfig().replace(**{"horizon.refine": False})
    with pytest.raises(TypeError, match="images must be a \\(B, 3, H, W\\) float tensor .* got list"):
        NeuralGeometricParser()([torch.rand(3, 64, 64)])


def test_one_path_is_not_taken_for_a_list_of_photos():
    with pytest.raises(TypeError, match="takes a list of photo paths, got 'x.jpg'"):
        shared_focal("x.jpg")
