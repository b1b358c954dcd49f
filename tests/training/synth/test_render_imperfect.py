"""Renders with an off-centre principal point (RenderConfig.centre_std): off by default and then invisible,
bit for bit; the label carries the true K, and the image is drawn through it."""

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.evaluation import load_renders
from ngp_kornia.geometry.camera import horizon_from_zenith, pitch_roll_from_up, zenith_from_up
from ngp_kornia.training.synth.render import render_dataset, render_scene
from ngp_kornia.training.synth.render_config import IMPERFECTION_DEFAULTS, RenderConfig, config_spec

SIZE = (320, 240)
OFF = RenderConfig(centre_std=0.08)


def test_off_by_default_and_bit_for_bit_unchanged():
    assert RenderConfig().centre_std == IMPERFECTION_DEFAULTS["centre_std"] == 0.0
    assert "centre_std" not in config_spec(RenderConfig())
    assert config_spec(OFF)["centre_std"] == 0.08
    for seed in range(3):
        a, b = render_scene(seed, (160, 120)), render_scene(seed, (160, 120), RenderConfig(centre_std=0.0))
        assert np.array_equal(a.image, b.image) and a.to_dict() == b.to_dict()


def test_only_the_principal_point_moves():
    for seed in range(4):
        a, b = render_scene(seed, SIZE), render_scene(seed, SIZE, OFF)
        assert a.kind == b.kind and torch.equal(a.R, b.R) and float(a.focal) == float(b.focal)
        offset = (b.K[:2, 2] - a.K[:2, 2]).abs()
        assert float(offset.max()) > 0 and float(offset.max()) <= 3 * 0.08 * SIZE[1] + 1e-9
        assert not np.array_equal(a.image, b.image)
        again = render_scene(seed, SIZE, OFF)
        assert np.array_equal(again.image, b.image) and again.to_dict() == b.to_dict()


@pytest.mark.parametrize("bad", [-0.01, 0.3, "0.1", float("nan")])
def test_bad_centre_std_raises(bad):
    with pytest.raises(ValueError, match="centre_std"):
        RenderConfig(centre_std=bad)


def test_label_carries_the_true_k(tmp_path):
    records = render_dataset(tmp_path, 3, seed=7, size=SIZE, config=OFF)
    samples = load_renders(tmp_path)  # checks horizon, pitch and roll against the stored K and R
    for rec, s in zip(records, samples, strict=True):
        K = torch.tensor(rec["K"], dtype=torch.float64)
        assert torch.equal(s.K, K) and K[0, 2] != (SIZE[0] - 1) / 2 and K[1, 2] != (SIZE[1] - 1) / 2
        up = -torch.tensor(rec["R"], dtype=torch.float64)[:, 1]
        horizon = horizon_from_zenith(K[None], zenith_from_up(K[None], up[None]))[0]
        assert torch.allclose(s.horizon, horizon, atol=1e-9)
        pitch, roll = pitch_roll_from_up(up[None])
        assert s.pitch == pytest.approx(float(pitch[0])) and s.roll == pytest.approx(float(roll[0]))
        vps = torch.tensor(rec["vps"], dtype=torch.float64)  # the horizontal VPs lie on the true horizon
        for v in (vps[0], vps[2]):
            assert abs(float(horizon @ v)) <= 1e-6 * float(v.norm())


def _median_vp_error(image: np.ndarray, vps: np.ndarray) -> float:
    """Median angle (degrees) between the LSD segments longer than 20 px and the direction to their nearest VP."""
    lines = cv2.createLineSegmentDetector().detect(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))[0].reshape(-1, 4)
    seg = lines.astype(np.float64)
    seg = seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 20]
    d, m = seg[:, 2:] - seg[:, :2], 0.5 * (seg[:, :2] + seg[:, 2:])
    angles = []
    for v in vps:
        e = v[None, :2] - m * v[2]
        cross = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]
        angles.append(np.degrees(np.arctan2(np.abs(cross), np.abs((d * e).sum(1)))))
    return float(np.median(np.stack(angles, 1).min(1)))


def test_the_image_is_drawn_through_the_true_k():
    """Detected segments point at the VPs of the true K, not at those of a centred one."""
    cfg = RenderConfig(centre_std=0.08, kinds={"street": 1.0}, photometric=False)
    for seed in range(3):
        r = render_scene(seed, SIZE, cfg)
        K_c = r.K.clone()
        K_c[0, 2], K_c[1, 2] = (SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2
        centred = torch.nn.functional.normalize((K_c @ r.R).T, dim=-1).numpy()
        assert _median_vp_error(r.image, r.vps.numpy()) < 0.5 * _median_vp_error(r.image, centred)


def test_radial_distortion_off_unchanged_on_bends_and_is_labelled(tmp_path):
    lens = RenderConfig(radial_distortion=0.05)
    assert "radial_distortion" not in config_spec(RenderConfig()) and IMPERFECTION_DEFAULTS["radial_distortion"] == 0
    for seed in range(3):
        a = render_scene(seed, (160, 120))
        b = render_scene(seed, (160, 120), RenderConfig(radial_distortion=0.0))
        assert np.array_equal(a.image, b.image) and a.to_dict() == b.to_dict() and "k1" not in a.to_dict()
        c = render_scene(seed, (160, 120), lens)
        assert c.k1 != 0 and abs(c.k1) <= 0.15 and c.to_dict()["k1"] == c.k1
        assert torch.equal(a.K, c.K) and torch.equal(a.R, c.R)  # the pinhole ground truth is kept
        assert not np.array_equal(a.image, c.image)
    render_dataset(tmp_path, 2, seed=1, size=(160, 120), config=lens)
    assert all(s.K.shape == (3, 3) for s in load_renders(tmp_path))
    with pytest.raises(ValueError, match="radial_distortion"):
        RenderConfig(radial_distortion=0.5)


def test_distorted_lines_point_at_the_vps_less_well():
    """The warp does what it says: straight 3D edges stop pointing exactly at the pinhole camera's VPs."""
    plain = RenderConfig(kinds={"street": 1.0}, photometric=False)
    bent = RenderConfig(kinds={"street": 1.0}, photometric=False, radial_distortion=0.1)
    worse = 0
    for seed in range(4):
        a, b = render_scene(seed, SIZE, plain), render_scene(seed, SIZE, bent)
        worse += _median_vp_error(b.image, b.vps.numpy()) > _median_vp_error(a.image, a.vps.numpy())
    assert worse >= 3
