"""calibrate() on a list: paths, arrays and tensors of different sizes, each result exactly what the item gets alone."""

import cv2
import pytest
import torch

from ngp_kornia import Calibration, ImageReadError, calibrate
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def items(tmp_path_factory):
    """A path (JPEG), an HxWx3 uint8 array and a (3, H, W) float tensor, all of different sizes."""
    path = tmp_path_factory.mktemp("photos") / "street.jpg"
    cv2.imwrite(str(path), cv2.cvtColor(render_scene(3, (320, 240)).image, cv2.COLOR_RGB2BGR))
    array = render_scene(4, (200, 260)).image
    tensor = torch.from_numpy(render_scene(5, (288, 192)).image).permute(2, 0, 1).float() / 255
    return [path, array, tensor]


def _same(a, b) -> bool:
    def same(x, y):
        return (x is None and y is None) or (x is not None and y is not None and torch.equal(x, y))

    return all(same(getattr(a, name), getattr(b, name)) for name in Calibration.FIELDS)


@pytest.mark.parametrize("weights", ["none", "default"])
def test_list_gives_one_result_per_item_each_as_alone(items, weights):
    results = calibrate(items, weights=weights, seed=1)
    assert isinstance(results, list) and len(results) == 3
    assert [r.image_size.tolist() for r in results] == [[240, 320], [260, 200], [192, 288]]
    for item, result in zip(items, results, strict=True):
        assert not result.batched
        assert _same(result, calibrate(item, weights=weights, seed=1))


def test_tuple_and_reversed_order_give_the_same_per_item_results(items):
    forward = calibrate(tuple(items), weights="none")
    backward = calibrate(items[::-1], weights="none")
    for a, b in zip(forward, backward[::-1], strict=True):
        assert _same(a, b)


def test_batched_tensor_inside_a_list_stays_batched(items):
    batch = torch.stack([items[2], items[2].flip(-1)])
    result = calibrate([batch, items[1]], weights="none")
    assert result[0].batched and len(result[0]) == 2 and not result[1].batched


def test_empty_list_is_refused():
    with pytest.raises(ValueError, match="empty list"):
        calibrate([])


def test_bad_weights_are_reported_before_any_image_is_read(tmp_path):
    with pytest.raises(ValueError, match="unknown weights"):
        calibrate([tmp_path / "missing.jpg"], weights="nonsense")


def test_nested_list_is_refused(items):
    with pytest.raises(TypeError, match="item 1"):
        calibrate([items[1], [items[1]]], weights="none")


def test_a_bad_item_is_named_by_its_place_in_the_list(items):
    with pytest.raises(ImageReadError, match=r"^item 1 of the list: image array is 3x3 pixels"):
        calibrate([items[0], torch.zeros(3, 3, 3).numpy().astype("uint8")])
    with pytest.raises(TypeError, match=r"^item 2 of the list: expected a path.*got NoneType"):
        calibrate([items[0], items[0], None])
