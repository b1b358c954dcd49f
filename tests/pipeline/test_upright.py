"""The orientation and structure check: the confidence scaled by the probability of an upright image with
structure, the turn reported, ``valid`` dropped where no structure is the likeliest reading; and the shipped
network on renders it never trained on."""

import numpy as np
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.api import load_parser
from ngp_kornia.nets.upright import UprightNet, thumbnail
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.upright_check import apply_upright
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.structureless import KINDS, structureless_image

HELD_OUT = 2_500_000  # render seeds no training, validation or test set of the network draws


def _answer():
    return calibrate(torch.rand(3, 48, 64), config=ParserConfig().replace(**{"upright.enabled": False}))


def _batched(result):
    return result.apply(lambda t: t[None])


def test_confidence_is_the_lines_own_unless_doubted_then_lowered_continuously():
    result = _batched(_answer())
    for upright, factor in ((0.9, 1.0), (0.5, 1.0), (0.499, 0.998), (0.25, 0.5), (0.0, 0.0)):
        probs = torch.tensor([[upright, 1.0 - upright, 0.0, 0.0, 0.0]])
        out = apply_upright(result, probs, sure=1.0, doubt=0.5)
        assert torch.allclose(out.confidence, result.confidence * factor)
        assert out.turned.tolist() == [0] and out.upright.tolist() == pytest.approx([upright])
    assert torch.equal(apply_upright(result, probs, sure=1.0).confidence, result.confidence)  # doubt 0: never


def test_a_doubted_photo_loses_confidence_by_the_power_of_its_doubt():
    result = _batched(_answer())
    for upright, factor in ((0.6, 1.0), (0.5, 1.0), (0.4, 0.64), (0.25, 0.25), (0.1, 0.04), (0.0, 0.0)):
        probs = torch.tensor([[upright, 1.0 - upright, 0.0, 0.0, 0.0]])
        out = apply_upright(result, probs, sure=1.0, doubt=0.5, doubt_power=2.0)
        assert torch.allclose(out.confidence, result.confidence * factor)
    below = apply_upright(result, torch.tensor([[0.4999, 0.5001, 0.0, 0.0, 0.0]]), sure=1.0, doubt=0.5, doubt_power=2.0)
    assert torch.allclose(below.confidence, result.confidence, rtol=1e-3)  # continuous at the level: no cliff


def test_the_parser_lowers_a_doubted_confidence_by_its_settings_power():
    image = render_scene(1).image
    configs = {p: ParserConfig().replace(**{"upright.doubt": 1.0, "upright.sure": 1.0, "upright.doubt_power": p})
               for p in (1.0, 3.0)}  # fmt: skip
    linear, steep = (calibrate(image, config=c) for c in configs.values())
    upright = float(linear.upright)
    assert 0.0 < upright < 1.0 and float(steep.upright) == pytest.approx(upright)
    assert float(steep.confidence) == pytest.approx(float(linear.confidence) * upright**2, rel=1e-4)


def _sure_answer(confidence=0.9):
    result = _camera(3.0, 1.0, 10.0)
    return type(result)(**{**result.__dict__, "confidence": torch.tensor([confidence], dtype=torch.float64)})


def test_a_turn_is_reported_only_where_the_check_is_sure_of_it():
    result = _sure_answer()
    doubted = apply_upright(result, torch.tensor([[0.3, 0.6, 0.05, 0.03, 0.02]]), sure=0.9, doubt=0.5)
    assert doubted.turned.tolist() == [0] and doubted.upright.tolist() == pytest.approx([0.3])
    assert torch.allclose(doubted.confidence, result.confidence * 0.6)  # 0.3 / 0.5
    sure = apply_upright(result, torch.tensor([[0.02, 0.01, 0.95, 0.01, 0.01]]), sure=0.9, doubt=0.5)
    assert sure.turned.tolist() == [180] and torch.allclose(sure.confidence, result.confidence * 0.04)
    spread = apply_upright(result, torch.tensor([[0.05, 0.3, 0.35, 0.3, 0.0]]), sure=0.9, doubt=0.5)
    assert spread.turned.tolist() == [0] and torch.allclose(spread.confidence, result.confidence * 0.1)


def test_an_upside_down_reading_is_never_answered_confidently_upside_down():
    result = _sure_answer(0.95)
    for probs in ([0.1, 0.05, 0.8, 0.05, 0.0], [0.02, 0.0, 0.97, 0.01, 0.0]):
        out = apply_upright(result, torch.tensor([probs]), sure=0.9, turn_back=False, doubt=0.5)
        assert float(out.upright) < 0.5  # doubted: warned about, refused by rectify
        assert float(out.confidence) <= 0.95 * probs[0] / 0.5 + 1e-6  # and its confidence lowered with the doubt


def test_no_structure_makes_the_answer_a_level_camera_with_nothing_known():
    lines = calibrate(render_scene(4).image, config=ParserConfig().replace(**{"upright.enabled": False}))
    result = _batched(lines)
    assert bool(lines.valid) and abs(float(lines.roll)) > 5 and abs(float(lines.pitch)) > 5
    out = apply_upright(result, torch.tensor([[0.1, 0.05, 0.05, 0.1, 0.7]]))
    assert out.valid.tolist() == [False] and out.confidence.tolist() == [0.0]
    assert out.roll_std.tolist() == [90.0] and out.fov_v_std.tolist() == [180.0]
    # what an answer without a frame is (the README's "a level camera"), not the lines' rolled guess
    assert [float(v) for v in (out.pitch, out.roll, out.yaw)] == pytest.approx([0.0, 0.0, 0.0], abs=1e-5)
    assert float(out.fov_h) == pytest.approx(60.0) and torch.equal(out.K[:, :2, 2], result.K[:, :2, 2])
    assert torch.allclose(out.R, torch.eye(3)[None]) and torch.allclose(out.up, torch.tensor([[0.0, -1.0, 0.0]]))


def test_an_answer_without_evidence_is_a_level_camera_whichever_check_finds_it():
    # white noise was once answered valid false at pitch -22.8, roll 21.6
    noise = np.random.default_rng(1).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    out = calibrate(noise)
    assert not bool(out.valid) and float(out.confidence) == 0.0
    assert [float(v) for v in (out.pitch, out.roll, out.yaw)] == pytest.approx([0.0, 0.0, 0.0], abs=1e-5)
    known = calibrate(noise, priors={"focal": 500.0})  # a known focal length is kept
    assert not bool(known.valid) and float(known.focal) == pytest.approx(500.0) and float(known.fov_v_std) == 0.0


def test_thumbnail_ignores_the_shape_of_the_image():
    assert thumbnail(torch.rand(2, 3, 48, 64), 16).shape == (2, 3, 16, 16)
    assert thumbnail(torch.rand(1, 3, 64, 48), 16).shape == (1, 3, 16, 16)


def test_network_settings_are_checked():
    with pytest.raises(ValueError, match="multiple of 16"):
        UprightNet(size=40)
    with pytest.raises(ValueError, match="temperature must be a positive number"):
        UprightNet(temperature=0.0)


def test_the_temperature_softens_the_probabilities_and_keeps_their_order():
    net = UprightNet(size=16, width=4).eval()
    images = torch.rand(3, 3, 20, 24, generator=torch.Generator().manual_seed(0))
    net.temperature = 2.0
    soft = net.probabilities(images)
    assert torch.allclose(soft, torch.softmax(net(thumbnail(images, 16)) / 2.0, -1))
    net.temperature = 1.0
    sharp = net.probabilities(images)
    assert torch.equal(soft.argmax(-1), sharp.argmax(-1)) and bool((soft.max(-1).values <= sharp.max(-1).values).all())


def test_to_dict_reports_the_check():
    out = calibrate(render_scene(HELD_OUT, (320, 240)).image)
    d = out.to_dict()
    assert 0.0 <= d["upright"] <= 1.0 and d["turned"] in (0, 90, 180, 270)


@pytest.fixture(scope="module")
def shipped():
    return load_parser("none").upright


def test_shipped_network_reads_turned_renders(shipped):
    images = [render_scene(HELD_OUT + i, (320, 240)).image for i in range(8)]
    right = 0
    for k in range(4):
        batch = torch.from_numpy(np.stack([np.rot90(img, k).copy() for img in images])).permute(0, 3, 1, 2) / 255.0
        right += int((shipped.probabilities(batch.float()).argmax(-1) == k).sum())
    assert right >= 20  # of 32 (chance: 8); on 200 held-out render turns it is right for 68% (orientation-check.md)


def test_shipped_network_finds_no_structure_in_structure_free_images(shipped):
    images = [structureless_image(HELD_OUT + i, (320, 240), KINDS[i % len(KINDS)]) for i in range(10)]
    batch = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() / 255.0
    assert int((shipped.probabilities(batch).argmax(-1) == 4).sum()) >= 9


def test_calibrating_noise_gives_no_confidence():
    noise = torch.rand(3, 240, 320, generator=torch.Generator().manual_seed(0))
    assert float(calibrate(noise).confidence) < 0.1


def test_the_check_can_be_turned_off():
    image = render_scene(HELD_OUT, (320, 240)).image
    off = calibrate(np.rot90(image).copy(), config=ParserConfig().replace(**{"upright.enabled": False}))
    assert off.upright is None and off.turned is None


class _Fixed(torch.nn.Module):
    """A stand-in network whose readings are given."""

    def __init__(self, probs):
        super().__init__()
        self.probs = torch.tensor([probs])

    def probabilities(self, images):
        return self.probs.expand(len(images), -1)


def test_the_prior_weighs_the_turns_and_keeps_the_structure_free_reading():
    from ngp_kornia.pipeline.upright_check import upright_probabilities

    net, images = _Fixed([0.25, 0.25, 0.2, 0.1, 0.2]), torch.rand(1, 3, 8, 8)
    assert torch.allclose(upright_probabilities(net, images, prior=0.25), net.probs)  # the training's own shares
    leaning = upright_probabilities(net, images, prior=0.9)[0]
    assert float(leaning[0]) > 0.75 and abs(float(leaning.sum()) - 1) < 1e-6
    sure = upright_probabilities(_Fixed([0.01, 0.97, 0.01, 0.005, 0.005]), images, prior=0.9)[0]
    assert int(sure[:4].argmax()) == 1  # a clear reading of a turn outweighs the prior


def test_a_steep_answer_leans_to_a_quarter_turn_and_a_level_one_to_upright():
    from ngp_kornia.pipeline.upright_check import weigh_by_pitch

    probs = torch.tensor([[0.3, 0.2, 0.1, 0.2, 0.2], [0.3, 0.2, 0.1, 0.2, 0.2]])
    out = weigh_by_pitch(probs, torch.tensor([2.0, -30.0]), spread=15.0)
    assert float(out[0, 0]) > 0.3 and float(out[0, 1]) < 0.2  # near level: upright is likelier than the network said
    assert float(out[1, 0]) < 0.3 and float(out[1, 1]) > 0.2  # 30 degrees down: a quarter turn is likelier
    assert float(out[1, 2] / out[1, 0]) == pytest.approx(1 / 3)  # 180 keeps the pitch's size: it moves with upright
    assert torch.allclose(out[:, 4], probs[:, 4]) and torch.allclose(out.sum(-1), torch.ones(2))


def test_the_pitch_cue_can_be_left_out():
    image = np.rot90(render_scene(HELD_OUT + 3, (320, 240)).image).copy()
    on = ParserConfig().replace(**{"upright.turn_back": False})
    off = on.replace(**{"upright.pitch_spread": 0.0})
    with_cue, without = calibrate(image, config=on), calibrate(image, config=off)
    assert torch.equal(with_cue.horizon, without.horizon)  # the cue changes only the check's reading
    assert not torch.equal(with_cue.upright, without.upright)


def test_the_reading_beside_the_frame_search_is_the_reading_here(shipped):
    from ngp_kornia.pipeline.upright_check import read_beside, upright_probabilities

    images = torch.rand(2, 3, 96, 128, generator=torch.Generator().manual_seed(1))
    beside = read_beside(shipped, images, 0.5)()
    assert torch.equal(beside, upright_probabilities(shipped, images, 0.5))  # the same computation, bit for bit


def _camera(pitch, roll, yaw, size=400):
    """A square image's calibration (its centre stays where it is under a quarter turn)."""
    from ngp_kornia.geometry.camera import rotation_from_angles
    from ngp_kornia.pipeline.answer import calibration_from_camera

    c = (size - 1) / 2
    K = torch.tensor([[[300.0, 0.0, c], [0.0, 300.0, c], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    R = rotation_from_angles(*(torch.tensor([a], dtype=torch.float64) for a in (pitch, roll, yaw)))
    score, valid = torch.ones(1, dtype=torch.float64), torch.ones(1, dtype=torch.bool)
    return calibration_from_camera(K, R, score, valid, size, size)


@pytest.mark.parametrize("turns", [1, 2, 3])
@pytest.mark.parametrize(("pitch", "roll", "yaw"), [(0.0, 0.0, 0.0), (8.0, -3.0, 25.0), (-12.0, 6.0, -40.0)])
def test_the_turned_answer_is_the_camera_of_the_turned_photo(turns, pitch, roll, yaw):
    from ngp_kornia.pipeline.answer import calibration_from_camera
    from ngp_kornia.pipeline.upright_check import turned_answer

    upright = _camera(pitch, roll, yaw)
    quarter = torch.tensor([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    truth = torch.linalg.matrix_power(quarter, turns) @ upright.R  # np.rot90's turn, in camera directions
    # what the lines answer for the turned photo: the same frame, its axis nearest the image's vertical as up
    answered = turned_answer(
        calibration_from_camera(upright.K, truth, upright.score, upright.valid, 400, 400),
        torch.tensor([0]),
        torch.tensor([True]),
    )
    assert abs(float(answered.roll)) <= 45.0
    out = turned_answer(answered, torch.tensor([turns]), torch.tensor([True]))
    assert torch.allclose(out.up, -truth[:, :, 1], atol=1e-9)
    assert float(out.pitch) == pytest.approx(pitch, abs=1e-6)
    assert (float(out.roll) - (roll - 90.0 * turns) + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)
    true = calibration_from_camera(upright.K, truth, upright.score, upright.valid, 400, 400)
    assert torch.allclose(out.horizon, true.horizon, atol=1e-9) and torch.allclose(out.zenith.abs(), true.zenith.abs())
    assert torch.equal(out.K, answered.K) and torch.equal(out.score, answered.score)
    kept = turned_answer(answered, torch.tensor([turns]), torch.tensor([False]))
    assert torch.equal(kept.R, answered.R)


def test_a_sure_turn_is_answered_as_turned_and_an_unsure_one_is_scaled():
    result = _camera(5.0, 2.0, 20.0)
    result = type(result)(**{**result.__dict__, "confidence": torch.tensor([0.9], dtype=torch.float64)})
    sure = torch.tensor([[0.002, 0.997, 0.0005, 0.0005, 0.0]])
    back = apply_upright(result, sure, sure=0.9, turn_back=True)
    assert back.turned.tolist() == [90] and -135.0 < float(back.roll) < -45.0  # up points left in the image
    columns = torch.cat([result.R, -result.R], -1)[0].T
    assert torch.isclose(columns, back.up).all(-1).any()  # one of the frame's axes is now up
    assert float(back.confidence) == pytest.approx(0.9 * 0.997)
    scaled = apply_upright(result, sure, sure=0.9, turn_back=False, doubt=0.5)
    assert float(scaled.roll) == pytest.approx(2.0) and float(scaled.confidence) == pytest.approx(0.9 * 0.004)
    spread = apply_upright(result, torch.tensor([[0.002, 0.5, 0.4, 0.098, 0.0]]), sure=0.9, turn_back=True, doubt=0.5)
    assert float(spread.roll) == pytest.approx(2.0)  # not upright, but no turn alone is sure: scaled, not turned
    assert float(spread.confidence) == pytest.approx(0.9 * 0.004)
    given = type(result)(**{**result.__dict__, "gravity": torch.tensor([[5.0, 2.0, 1.0]], dtype=torch.float64)})
    assert float(apply_upright(given, sure, sure=0.9, turn_back=True).roll) == pytest.approx(2.0)


def test_a_render_the_check_is_sure_of_is_calibrated_right_when_turned():
    from ngp_kornia.geometry.camera import pitch_roll_from_up
    from ngp_kornia.metrics import roll_error

    scene = render_scene(HELD_OUT + 29, (320, 240))  # read as turned by 90 with probability 0.99
    image = np.rot90(scene.image).copy()
    out = calibrate(image)
    up = -torch.as_tensor(scene.R, dtype=torch.float64)[:, 1]
    _, roll = pitch_roll_from_up(torch.stack([up[1], -up[0], up[2]])[None])  # the up of the turned photo
    assert int(out.turned) == 90 and float(out.upright) < 0.1 and float(out.confidence) > 0.5
    assert float(roll_error(out.roll.double().reshape(1), roll)) < 5.0
    off = calibrate(image, config=ParserConfig().replace(**{"upright.turn_back": False}))
    assert float(roll_error(off.roll.double().reshape(1), roll)) > 45.0 and float(off.confidence) < 0.1
