"""One camera across many photos: ``calibrate(photos, shared_intrinsics=True)`` and its stage."""

import numpy as np
import pytest
import torch

from ngp_kornia import NGPWarning, calibrate
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import SamplingSettings, SharedSettings
from ngp_kornia.pipeline.shared_camera import focal_grid, focal_support, joint_focal, nearest_rotation
from ngp_kornia.training.synth.render import RenderConfig, render_scene

#: six streets seen by one camera (a 55 degree vertical field of view), each from its own place
CAMERA = RenderConfig(fov_v=(55.0, 55.0), kinds={"street": 1.0})


@pytest.fixture(scope="module")
def scenes():
    return [render_scene(seed, (320, 240), CAMERA) for seed in range(10, 16)]


def test_shared_intrinsics_give_every_photo_one_focal_length_near_the_truth(scenes):
    images = [s.image for s in scenes]
    truth = float(scenes[0].focal)
    alone = [float(r.focal) for r in calibrate(images, weights="none")]
    shared = calibrate(images, weights="none", priors={"shared_intrinsics": True})
    focals = [float(r.focal) for r in shared]
    # alone, each photo has its own error (several percent here); shared, one number for all
    assert max(alone) - min(alone) > 0.02 * truth
    assert max(focals) - min(focals) < 1e-3 * truth
    # the grid is 1% apart and six photos vote: within 1.5% of the truth, closer than the worst photo alone
    assert abs(focals[0] - truth) < 0.015 * truth
    assert abs(focals[0] - truth) < max(abs(f - truth) for f in alone)
    row = shared[0].to_dict()
    assert row["shared"] == ["focal"] and row["shared_photos"] == 6 and row["fov_v_std"] > 0


def test_a_photo_without_lines_gets_its_own_flagged_answer_and_the_others_theirs(scenes):
    # a line-free photo once ended the whole call (RuntimeError: amin() of its empty segments)
    blank = np.full_like(scenes[0].image, 128)
    images = [scenes[0].image, blank, scenes[1].image]
    results = calibrate(images, weights="none", priors={"shared_intrinsics": True})
    assert [bool(r.valid) for r in results] == [True, False, True]
    assert float(results[1].confidence) == 0.0
    assert [int(r.shared_photos) for r in results] == [2, 2, 2]  # the two photos with lines
    assert float(results[0].focal) == pytest.approx(float(results[2].focal), rel=1e-5)


def test_fewer_than_two_photos_with_lines_share_nothing_and_say_so(scenes):
    alone = calibrate(scenes[0].image, weights="none")
    blank = np.full_like(scenes[0].image, 128)
    for images in ([scenes[0].image], [scenes[0].image, blank]):
        with pytest.warns(NGPWarning, match="calibrated alone"):
            results = calibrate(images, weights="none", priors={"shared_intrinsics": True})
        # the photo keeps its own answer and uncertainty (it once said fov_v_std 0 at confidence 0.99)
        assert float(results[0].fov_v_std) == pytest.approx(float(alone.fov_v_std)) and float(alone.fov_v_std) > 0
        assert float(results[0].focal) == pytest.approx(float(alone.focal))
        assert results[0].shared_photos is None and "shared" not in results[0].to_dict()
    with pytest.warns(NGPWarning, match="one photo cannot share"):
        assert calibrate(scenes[0].image, weights="none", priors={"shared_intrinsics": True}).shared_photos is None


def test_focal_support_of_a_photo_without_segments_is_zero():
    grid = focal_grid(240, 320, SharedSettings(), SamplingSettings())
    K = torch.tensor([[[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]])
    support = focal_support(K, torch.eye(3)[None], torch.zeros(1, 0, 2, 2), torch.zeros(1, 0, dtype=torch.bool), grid)
    assert support.shape == (1, len(grid)) and not bool(support.any())


def test_a_batch_shares_its_focal_length_and_stays_batched(scenes):
    batch = torch.stack([torch.from_numpy(s.image).permute(2, 0, 1).float() / 255 for s in scenes[:4]])
    result = calibrate(batch, weights="none", priors={"shared_intrinsics": True})
    assert result.batched and len(result) == 4
    assert torch.allclose(result.focal, result.focal[:1].expand(4), rtol=1e-5)
    assert result.shared_photos.tolist() == [4, 4, 4, 4]


def test_a_known_focal_length_is_every_photos(scenes):
    images = [s.image for s in scenes[:2]]
    results = calibrate(images, weights="none", priors={"focal": 250.0, "shared_intrinsics": True})
    assert [float(r.focal) for r in results] == pytest.approx([250.0, 250.0], rel=1e-5)
    assert [float(r.fov_v_std) for r in results] == [0.0, 0.0]


def test_photos_of_different_sizes_or_exif_are_refused(scenes):
    small = render_scene(3, (200, 160), CAMERA).image
    with pytest.raises(ValueError, match="of one size"):
        calibrate([scenes[0].image, small], weights="none", priors={"shared_intrinsics": True})
    with pytest.raises(ValueError, match="exif"):
        calibrate([scenes[0].image], weights="none", priors={"shared_intrinsics": True, "exif": True})
    with pytest.raises(ValueError, match="shared_intrinsics.*True or False"):
        calibrate(scenes[0].image, weights="none", priors={"shared_intrinsics": "yes"})


def test_a_turned_photo_counts_as_the_same_camera(scenes):
    turned = np.ascontiguousarray(np.rot90(scenes[1].image))
    results = calibrate([scenes[0].image, turned], weights="none", priors={"shared_intrinsics": True})
    assert float(results[0].focal) == pytest.approx(float(results[1].focal), rel=1e-6)


def test_focal_support_peaks_at_the_true_focal_length(scenes):
    scene = scenes[2]
    segments, mask = detect_segments(scene.image)
    K, R = scene.K[None], scene.R[None]
    grid = focal_grid(240, 320, SharedSettings(), SamplingSettings())
    support = focal_support(K, R, segments, mask, grid)
    assert support.shape == (1, len(grid))
    peak = float(grid[support[0].argmax()])
    # the true frame scores best within a few grid steps (1% each) of the true focal length
    assert abs(peak / float(scene.focal) - 1) < 0.04
    assert float(support[0].max()) > float(support[0].min()) + 0.05  # a peak, not a plateau


def test_joint_focal_ignores_invalid_photos_and_resamples_for_its_std():
    focals = torch.logspace(2, 3, 21, dtype=torch.float64)
    peak = torch.exp(-(((focals.log() - focals[10].log()) / 0.1) ** 2))
    support = torch.stack([peak, peak.flip(0), peak * 0.9])
    one = joint_focal(support[[0]], focals, torch.tensor([True]))
    assert one.focal == pytest.approx(float(focals[10]), rel=1e-6) and one.std == 0.0 and one.photos == 1
    ignored = joint_focal(support, focals, torch.tensor([True, False, True]))
    assert ignored.focal == pytest.approx(float(focals[10]), rel=1e-6) and ignored.photos == 2
    assert joint_focal(support, focals, torch.tensor([False, False, False])).photos == 0


def test_nearest_rotation_is_a_rotation_and_keeps_one():
    R = torch.linalg.qr(torch.randn(4, 3, 3, dtype=torch.float64))[0]
    R = R * torch.linalg.det(R).sign()[:, None, None]
    assert torch.allclose(nearest_rotation(R), R, atol=1e-12)
    noisy = nearest_rotation(R + 0.05 * torch.randn(4, 3, 3, dtype=torch.float64))
    eye = torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    assert torch.allclose(noisy @ noisy.transpose(1, 2), eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(noisy), torch.ones(4, dtype=torch.float64), atol=1e-12)
