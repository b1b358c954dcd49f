"""Priors per image: one batch (or list) carries different priors, and each image gets what it gets alone with its own,
for every kind of prior; a bad value names the prior and the image."""

import pytest
import torch

from ngp_kornia import InputError, Priors, calibrate
from ngp_kornia.pipeline import Calibration
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig

#: per prior kind, each image's value (two images; gravity_std rides with gravity)
KINDS = {
    "focal": {"focal": [300.0, 360.0]},
    "focal_35mm": {"focal_35mm": [24.0, 35.0]},
    "fov_v": {"fov_v": [45.0, 60.0]},
    "gravity": {"gravity": [(4.0, -2.0), (-3.0, 5.0)], "gravity_std": [1.0, 3.0]},
    "principal_point": {"principal_point": [(150.0, 125.0), (166.0, 112.0)]},
    "principal_point_estimate": {"principal_point": ["estimate", "estimate"]},
    "k1": {"k1": [-0.05, -0.15]},
    "k1_estimate": {"k1": ["estimate", "estimate"]},
}


@pytest.fixture(scope="module")
def scenes():
    config = RenderConfig(kinds={"street": 1.0}, k1_range=(-0.1, -0.1))
    return [render_scene(seed, (320, 240), config) for seed in (2, 5)]


@pytest.fixture(scope="module")
def batch(scenes):
    return torch.stack([torch.from_numpy(s.image).permute(2, 0, 1).float() / 255 for s in scenes])


def _close(got: Calibration, want: Calibration, what: str) -> None:
    for name in Calibration.FIELDS:
        a, b = getattr(got, name), getattr(want, name)
        assert (a is None) == (b is None), f"{what}: {name}"
        if a is not None:
            torch.testing.assert_close(a.double(), b.double(), atol=1e-3, rtol=1e-4, msg=f"{what}: {name}")


def _one(values: dict, i: int) -> dict:
    return {name: value[i] for name, value in values.items()}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_each_image_of_a_batch_gets_what_it_gets_alone_with_its_own_prior(batch, kind):
    values = KINDS[kind]
    together = calibrate(batch, priors=values)
    for i in range(len(batch)):
        _close(together[i], calibrate(batch[i], priors=_one(values, i)), f"{kind}, image {i}")


@pytest.mark.parametrize("kind", ["focal", "gravity", "principal_point", "k1_estimate"])
def test_tensors_and_arrays_per_image_are_the_lists(batch, kind):
    values = KINDS[kind]
    as_tensors = {name: torch.tensor(value) for name, value in values.items() if not isinstance(value[0], str)}
    if not as_tensors:
        pytest.skip("'estimate' has no tensor form")
    _close(calibrate(batch, priors=as_tensors), calibrate(batch, priors=values), kind)


def test_a_list_mixes_priors_given_and_not(scenes):
    images = [s.image for s in scenes]
    mixed = {"focal": [300.0, None], "k1": [None, "estimate"], "gravity": [None, (3.0, 1.0)]}
    results = calibrate(images, weights="none", priors=mixed)
    for i, image in enumerate(images):
        _close(results[i], calibrate(image, weights="none", priors=_one(mixed, i)), f"item {i}")
    assert float(results[1].fov_v_std) > 0 and float(results[0].fov_v_std) == 0  # the focal prior of item 0 only
    assert results[0].k1 is None and results[1].k1 is not None and results[0].gravity is None


def test_one_value_for_all_is_every_image_given_it(batch):
    alike = calibrate(batch, weights="none", priors={"gravity": (4.0, -2.0), "focal": 330.0})
    each = calibrate(batch, weights="none", priors={"gravity": [(4.0, -2.0)] * 2, "focal": torch.tensor([330.0] * 2)})
    _close(alike, each, "one for all")


@pytest.mark.parametrize(
    "priors, message",
    [
        ({"focal": [300.0, -1.0]}, r"^image 1: focal must be a number of pixels"),
        ({"gravity": [(4.0, -2.0), (95.0, 0.0)]}, r"^image 1: gravity's pitch must be in \(-90, 90\)"),
        ({"principal_point": [(150.0, 125.0), "middle"]}, r"^image 1: principal_point must be \(cx, cy\)"),
        ({"k1": torch.tensor([-0.1, 2.0])}, r"^image 1: k1 must be a number in \[-1, 1\]"),
        ({"focal": [300.0, 360.0, 400.0]}, r"^focal was given for 3 images, one per image, but the batch has 2"),
        ({"focal": [300.0, None]}, r"^focal is given for image 0 but not given for image 1: in one batched tensor"),
        ({"k1": ["estimate", -0.1]}, r"^k1 is 'estimate' for image 0 but given for image 1"),
        ({"focal": [300.0, 35.0]}, r"^image 1: focal=35.0 px on this 320x240 image"),
        ({"gravity": [(1.0, 2.0), None], "gravity_std": [1.0, 2.0]}, "gravity_std was given without gravity for "
                                                                     "image 1"),
        ({"focal": [300.0, 360.0], "gravity": [(1.0, 2.0)] * 3}, r"different numbers of images \(focal for 2"),
    ],
)
def test_a_bad_prior_per_image_is_one_line_naming_the_prior_and_the_image(batch, priors, message):
    with pytest.raises(InputError, match=message) as err:
        calibrate(batch, weights="none", priors=priors)
    assert "\n" not in str(err.value)


def test_a_list_names_the_item_whose_prior_is_bad(scenes):
    with pytest.raises(InputError, match=r"^item 1 of the list: focal=35.0 px on this 320x240 image"):
        calibrate([s.image for s in scenes], weights="none", priors={"focal": [300.0, 35.0]})
    with pytest.raises(InputError, match="focal was given for 3 images, one per image, but the list has 2"):
        calibrate([s.image for s in scenes], weights="none", priors={"focal": [300.0, 360.0, 400.0]})


def test_shared_intrinsics_take_the_camera_once_and_gravity_per_photo(scenes):
    images = [s.image for s in scenes]
    with pytest.raises(InputError, match="shared_intrinsics: the photos are one camera, so focal is one value"):
        calibrate(images, weights="none", priors={"focal": [300.0, 360.0], "shared_intrinsics": True})
    gravity = [(4.0, -2.0), (-3.0, 5.0)]
    shared = calibrate(images, weights="none", priors={"gravity": gravity, "shared_intrinsics": True})
    assert [r.gravity[:2].tolist() for r in shared] == [[4.0, -2.0], [-3.0, 5.0]]
    assert float(shared[0].focal) == pytest.approx(float(shared[1].focal))


def test_priors_per_image_keep_their_values():
    priors = Priors(focal=torch.tensor([500.0, 600.0]), gravity=[(1.0, 2.0), (3.0, 4.0)], gravity_std=2.0)
    assert priors.count == 2
    assert priors.image(1) == Priors(focal=600.0, gravity=(3.0, 4.0), gravity_std=2.0)
    assert priors.to_dict() == {"focal": [500.0, 600.0], "gravity": [[1.0, 2.0], [3.0, 4.0]], "gravity_std": [2.0, 2.0]}
    assert Priors(focal=[500.0]) == Priors(focal=500.0)  # one value per image of one: one for all
    assert Priors(gravity=[1.0, 2.0]).gravity == (1.0, 2.0)  # two numbers are one pair
