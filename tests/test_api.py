"""calibrate(): input formats, bad input, result shapes and conventions."""

import json

import cv2
import numpy as np
import pytest
import torch

import ngp_kornia
from ngp_kornia import ImageError, calibrate
from ngp_kornia.api import load_parser
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.weights import WeightsError, save_network
from ngp_kornia.nets.zsnet import ZSNet


@pytest.fixture
def photo(tmp_path):
    """A small synthetic facade: a grid of rectangles in perspective, written as JPEG."""
    img = np.full((120, 160, 3), 90, np.uint8)
    for x in range(10, 150, 22):
        for y in range(10, 110, 25):
            cv2.rectangle(img, (x, y), (x + 12, y + 15), (230, 230, 230), -1)
    path = tmp_path / "facade.jpg"
    cv2.imwrite(str(path), img)
    return path


def test_path_array_and_tensor_inputs_agree(photo):
    rgb = cv2.cvtColor(cv2.imread(str(photo)), cv2.COLOR_BGR2RGB)
    a = calibrate(photo)
    b = calibrate(rgb)
    c = calibrate(torch.from_numpy(rgb).permute(2, 0, 1).float() / 255)
    assert torch.allclose(a.K, b.K) and torch.allclose(b.K, c.K)
    assert torch.allclose(a.horizon, c.horizon)


@pytest.mark.parametrize("weights", ["none", "zsnet"])
def test_weights_without_fsnet_give_the_same_answer_from_a_file_as_from_its_pixels(photo, weights):
    """A file gives the answer of the tensor of its pixels (whose lines are detected from them) also where no
    network of the weight set but the orientation check reads the pixels."""
    rgb = cv2.cvtColor(cv2.imread(str(photo)), cv2.COLOR_BGR2RGB)
    tensor = torch.from_numpy(rgb).permute(2, 0, 1).float() / 255
    a, b = calibrate(photo, weights=weights), calibrate(tensor, weights=weights)
    for name in ("K", "R", "horizon", "vps", "score", "confidence", "pitch_std"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


def test_result_fields_and_shapes(photo):
    cal = calibrate(photo)
    assert cal.K.shape == (3, 3) and cal.R.shape == (3, 3) and cal.vps.shape == (3, 3)
    assert cal.zenith.shape == (3,) and cal.horizon.shape == (3,)
    for name in ("focal", "fov_v", "fov_h", "pitch", "roll", "yaw"):
        assert getattr(cal, name).dim() == 0
        assert torch.isfinite(getattr(cal, name))
    assert torch.allclose(cal.R @ cal.R.T, torch.eye(3), atol=1e-5)
    # K is in the input's pixels with the principal point at the image centre
    assert cal.K[0, 2] == pytest.approx(79.5) and cal.K[1, 2] == pytest.approx(59.5)
    d = cal.to_dict()
    assert json.loads(json.dumps(d))["width"] == 160
    for key in ("K", "R", "focal", "fov_v", "fov_h", "pitch", "roll", "zenith", "horizon", "vps"):
        assert key in d


def test_result_tensors_are_ordinary_tensors(photo):
    """The parser runs in inference mode; what comes back can still be edited in place and used with autograd."""
    for cal in (calibrate(photo), calibrate(torch.rand(2, 3, 48, 64), weights="none"), calibrate([photo])[0]):
        for name in ("K", "R", "focal", "horizon", "vps", "confidence", "pitch_std", "valid"):
            assert not getattr(cal, name).is_inference(), name
        cal.K[..., 0, 0] = 100.0  # the caller's copy to change
        focal = cal.focal.clone().requires_grad_()
        (focal * cal.fov_v).sum().backward()
        assert torch.equal(focal.grad, cal.fov_v)


def test_parser_with_autograd_after_calibrate(photo):
    """calibrate() builds the parser's cached constants in inference mode; a differentiable call after it (as in
    training, or a loss through the calibration) must still backpropagate to the image."""
    calibrate(photo, weights="full")
    rgb = cv2.cvtColor(cv2.imread(str(photo)), cv2.COLOR_BGR2RGB)
    image = (torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255).requires_grad_()
    out = load_parser("full")(image)
    (out.score + out.focal + out.confidence + out.pitch_std).sum().backward()
    assert image.grad is not None and torch.isfinite(image.grad).all() and image.grad.abs().sum() > 0


def test_cached_constants_first_built_in_inference_mode_are_ordinary_tensors():
    """The parser's caches serve calibrate() (inference mode) and differentiable callers alike."""
    from ngp_kornia.geometry import line_maps
    from ngp_kornia.pipeline.constants import constant_tensors

    built = [
        (constant_tensors, (((0.0, 1.0), (0.5, 1.5)), torch.float32, torch.device("cpu"))),
        (line_maps._cell_index, (1, 8, 8, 4, torch.device("cpu"))),
    ]
    for cached, args in built:
        cached.cache_clear()
        with torch.inference_mode():
            cached(*args)
        value = cached(*args)  # from the cache
        assert not any(t.is_inference() for t in (value if isinstance(value, (tuple, list)) else [value])), cached
        cached.cache_clear()


def test_batched_tensor_gives_batched_result():
    images = torch.rand(3, 3, 48, 64)
    cal = calibrate(images, weights="none")
    assert cal.batched and len(cal) == 3 and cal.K.shape == (3, 3, 3)
    assert isinstance(cal.to_dict(), list) and len(cal.to_dict()) == 3
    single = calibrate(images[1], weights="none")
    assert torch.allclose(single.K, cal[1].K)


def test_same_seed_same_answer_and_seed_changes_sampling(photo):
    assert torch.equal(calibrate(photo, seed=3).K, calibrate(photo, seed=3).K)


def test_float64_tensor_keeps_dtype():
    cal = calibrate(torch.rand(1, 3, 40, 40, dtype=torch.float64))
    assert cal.K.dtype == torch.float64


def test_greyscale_rgba_and_16bit_files_are_converted(tmp_path, photo):
    rgb = cv2.imread(str(photo))
    grey = cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY)
    rgba = cv2.cvtColor(rgb, cv2.COLOR_BGR2BGRA)
    deep = rgb.astype(np.uint16) * 257
    ref = calibrate(cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB))
    for name, img in (("grey.png", grey), ("rgba.png", rgba), ("deep.png", deep)):
        cv2.imwrite(str(tmp_path / name), img)
        cal = calibrate(tmp_path / name)
        assert torch.isfinite(cal.focal)
    assert torch.allclose(calibrate(tmp_path / "grey.png").K, ref.K)
    assert torch.allclose(calibrate(tmp_path / "deep.png").K, calibrate(photo.with_suffix(".jpg")).K, rtol=0.05)


def _write(path, data):
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p / "nope.jpg", "file not found"),
        (lambda p: _write(p / "empty.jpg", b""), "empty"),
        (lambda p: _write(p / "text.jpg", b"not an image"), "not a readable image"),
        (lambda p: p, "directory"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, make, message):
    with pytest.raises(ImageError, match=message):
        calibrate(make(tmp_path))


def test_truncated_jpeg_is_reported(tmp_path, photo):
    data = photo.read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageError, match="truncated"):
        calibrate(tmp_path / "cut.jpg")


def test_tiny_image_is_rejected_with_the_minimum_size():
    with pytest.raises(ImageError, match="at least 32 px"):
        calibrate(np.zeros((20, 100, 3), np.uint8))


@pytest.mark.parametrize(
    ("tensor", "error", "message"),
    [
        (torch.full((3, 40, 40), float("nan")), ImageError, "NaN"),
        (torch.rand(4, 40, 40), ImageError, r"\(3, H, W\)"),
        (torch.rand(40, 40), ImageError, r"\(3, H, W\)"),
        (torch.zeros(3, 40, 40, dtype=torch.int32), TypeError, r"float tensor in \[0, 1\] or a uint8"),
        (torch.rand(3, 40, 40) * 255, ImageError, r"\[0, 1\]"),
        (torch.rand(0, 3, 40, 40), ImageError, "empty image tensor"),
    ],
)
def test_bad_tensors_name_the_problem(tensor, error, message):
    with pytest.raises(error, match=message):
        calibrate(tensor)


def test_unknown_weights_lists_the_choices():
    with pytest.raises(ValueError, match="default, none, zsnet"):
        calibrate(torch.rand(3, 40, 40), weights="imagenet")


def test_weights_files_are_recognised_by_the_network_they_hold(tmp_path):
    zs = save_network(ZSNet(), tmp_path / "z.pt", ZSNet().settings())
    fs_net = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)
    fs = save_network(fs_net, tmp_path / "f.pt", fs_net.settings())
    assert load_parser(zs).zsnet is not None and load_parser(zs).fsnet is None
    assert load_parser(str(fs)).fsnet is not None and load_parser(str(fs)).zsnet is None
    both = load_parser([zs, fs])
    assert both.zsnet is not None and both.fsnet is not None
    cal = calibrate(torch.rand(3, 48, 64), weights=[zs, fs])
    assert bool(torch.isfinite(cal.focal))


@pytest.mark.parametrize(
    ("weights", "zsnet", "fsnet"),
    [("none", False, False), ("zsnet", True, False), ("fsnet", False, True), ("full", True, True)],
)
def test_shipped_weight_sets(photo, weights, zsnet, fsnet):
    parser = load_parser(weights)
    assert (parser.zsnet is not None, parser.fsnet is not None) == (zsnet, fsnet)
    cal = calibrate(photo, weights=weights)
    assert bool(torch.isfinite(cal.K).all()) and cal.K.shape == (3, 3)


def test_training_a_loaded_parser_leaves_calibrate_unchanged(photo):
    before = calibrate(photo, weights="fsnet")
    parser = load_parser("fsnet").train()
    with torch.no_grad():
        for p in parser.fsnet.parameters():
            p.add_(1.0)
    after = calibrate(photo, weights="fsnet")
    assert torch.equal(before.K, after.K) and torch.equal(before.R, after.R)
    assert not load_parser("fsnet").fsnet.training


def test_missing_weights_file_is_named(tmp_path):
    with pytest.raises(WeightsError, match="nope.pt"):
        calibrate(torch.rand(3, 40, 40), weights=str(tmp_path / "nope.pt"))


@pytest.mark.parametrize("weights", ["none", "fsnet", "full"])
def test_image_without_lines_gives_a_defined_level_camera(weights):
    cal = calibrate(torch.full((3, 64, 80), 0.5), weights=weights)
    assert not bool(cal.valid)
    assert float(cal.pitch) == pytest.approx(0.0, abs=1e-5) and float(cal.roll) == pytest.approx(0.0, abs=1e-5)
    assert float(cal.fov_h) == pytest.approx(60.0, abs=1e-3)  # the documented fallback on the long side


def test_version_is_exposed():
    assert ngp_kornia.__version__.count(".") == 2


@pytest.mark.parametrize("weights", ["none", "fsnet", "full"])
def test_an_image_gets_the_same_answer_in_a_batch_as_alone(weights):
    from ngp_kornia.training.synth.render import render_scene

    scenes = [render_scene(s, size=(320, 240)).image for s in (1, 2, 3)]
    images = [torch.from_numpy(image).permute(2, 0, 1).float() / 255 for image in scenes]
    order = [0, 1, 2, 0]  # the same image at positions 0 and 3, beside images with other line counts
    batch = calibrate(torch.stack([images[i] for i in order]), weights=weights)
    for position, i in enumerate(order):
        alone = calibrate(images[i], weights=weights)
        assert torch.allclose(batch[position].K, alone.K, rtol=1e-5), (position, batch.focal, alone.focal)
        assert torch.allclose(batch[position].R, alone.R, atol=1e-5)
        assert torch.allclose(batch[position].horizon, alone.horizon, atol=1e-4)
