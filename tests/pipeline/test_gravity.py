"""The gravity prior: its checks, its gates on zenith candidates, frames and horizon hypotheses, and what a wrong
prior does to the confidence."""

import pytest
import torch

from ngp_kornia import Priors, calibrate
from ngp_kornia.errors import InputError
from ngp_kornia.geometry import rotation_from_angles
from ngp_kornia.pipeline.gravity import GATE, allowed_ups, frame_agreement, zenith_agreement
from ngp_kornia.pipeline.horizon_support import up_from_pitch_roll
from ngp_kornia.training.synth.render import RenderConfig, render_scene


def test_priors_check_the_gravity_prior():
    assert Priors(gravity=(3.0, -2.0)).gravity_std == 1.0  # the default standard deviation
    assert Priors(gravity=[3, -2], gravity_std=2).to_dict() == {"gravity": [3.0, -2.0], "gravity_std": 2.0}
    for bad in ((1.0,), (95.0, 0.0), ("a", 0.0), (float("nan"), 0.0)):
        with pytest.raises(InputError, match="gravity"):
            Priors(gravity=bad)
    with pytest.raises(InputError, match="without gravity"):
        Priors(gravity_std=1.0)
    with pytest.raises(InputError, match="gravity_std"):
        Priors(gravity=(0.0, 0.0), gravity_std=0.0)


def test_a_gravity_prior_out_of_range_is_refused_naming_the_angle():
    for bad, name in (((10.0, 1e300), "roll"), ((0.0, 190.0), "roll"), ((0.0, -180.5), "roll"), ((95.0, 0.0), "pitch"),
                      ((-90.0, 0.0), "pitch")):
        with pytest.raises(InputError, match=f"gravity's {name} must be in"):
            Priors(gravity=bad)
    assert Priors(gravity=(89.0, -180.0)).gravity == (89.0, -180.0)  # the ends that are angles


@pytest.mark.parametrize(("seed", "gravity"), [(4, (10.0, 40.0)), (2, (45.0, 40.0)), (5, (10.0, 40.0))])
def test_a_prior_far_from_every_frame_gives_an_answer_not_an_error(seed, gravity):
    # every frame's score fell below 1e-38 (its agreement with the prior), the top-k weights summed to 1e-35, the
    # averaged up vector was zero and linalg.eigh raised from inside calibrate(); York Urban showed it at (45, 40)
    result = calibrate(render_scene(seed).image, priors={"gravity": gravity})
    fields = torch.stack([result.pitch, result.roll, result.focal, result.confidence])
    assert bool(torch.isfinite(fields).all()) and bool(torch.isfinite(result.R).all())
    assert abs(float(torch.linalg.det(result.R)) - 1.0) < 1e-4


def test_frames_within_the_gate_keep_their_score_and_far_ones_lose_it():
    priors = Priors(gravity=(10.0, 5.0), gravity_std=1.0)
    pitches = torch.tensor([10.0, 12.0, 20.0, 40.0])
    R = rotation_from_angles(pitches, torch.full((4,), 5.0), torch.zeros(4))[None]
    factor = frame_agreement(R, priors)[0]
    assert factor[:2].tolist() == pytest.approx([1.0, 1.0])  # 0 and 2 deg off: inside 3 sigma
    assert 0 < float(factor[2]) < 1e-3 and float(factor[3]) < 1e-30


def test_zenith_candidates_and_hypotheses_off_the_prior_are_dropped():
    priors = Priors(gravity=(5.0, 10.0), gravity_std=1.0)
    ups = up_from_pitch_roll(torch.tensor([5.0, 5.0, 5.0]), torch.tensor([10.0, 12.0, 30.0]))[None]
    assert allowed_ups(ups, priors).tolist() == [[True, True, False]]
    # a zenith candidate's roll is its direction from the centre, whatever the focal length
    zenith = torch.stack([ups[0, :, 0] * 2.0, ups[0, :, 1] * 2.0, ups[0, :, 2]], -1)[None]
    assert zenith_agreement(zenith, priors).tolist() == [[True, True, False]]
    assert GATE == 3.0


@pytest.fixture(scope="module")
def scene():
    return render_scene(11, (480, 360), RenderConfig(kinds={"street": 1.0}))


def test_a_true_prior_keeps_the_answer_and_a_wrong_one_lowers_the_confidence(scene):
    truth = (float(scene.pitch), float(scene.roll))
    alone = calibrate(scene.image, weights="none")
    right = calibrate(scene.image, weights="none", priors={"gravity": truth, "gravity_std": 1.0})
    off = (truth[0] + 12.0, truth[1] - 9.0)
    wrong = calibrate(scene.image, weights="none", priors={"gravity": off, "gravity_std": 1.0})
    assert abs(float(right.pitch) - truth[0]) < 1.0 and abs(float(right.roll) - truth[1]) < 1.0
    assert float(right.confidence) > 0.5
    assert float(wrong.confidence) < 0.5 * float(right.confidence)
    assert alone.gravity is None
    assert right.to_dict()["gravity"] == pytest.approx({"pitch": truth[0], "roll": truth[1], "std": 1.0})
