"""Tests of the renderer's hard cases (RenderConfig.stairs, billboards, fronto_prob): off by default and then
invisible, bit for bit; deterministic per seed; doing what they say when on."""

import hashlib
import math

import numpy as np
import pytest

from ngp_kornia.training.synth.hard import make_billboard, make_stairs
from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.render import camera_ground_truth, render_scene
from ngp_kornia.training.synth.render_config import HARD_DEFAULTS, RenderConfig, config_spec

SMALL = (160, 120)
OUTDOOR = {"street": 1.0, "atlanta": 1.0}
OPTIONS = [dict(stairs=4.0), dict(billboards=4.0), dict(fronto_prob=1.0)]

# digests of default renders made before the hard cases existed (seeds 0-5 at 160x120): they must not move
BEFORE = {0: "d27db61ebd3b9497", 1: "5036d3b51cfb5e29", 2: "950d6454dba3e8e3", 3: "bd680861320e14d3",
          4: "987823d0c44494aa", 5: "d7a6b093e124d201"}


def _digest(image: np.ndarray) -> str:
    return hashlib.sha256(image.tobytes()).hexdigest()[:16]


def test_default_renders_as_before():
    assert {seed: _digest(render_scene(seed, SMALL).image) for seed in BEFORE} == BEFORE


def test_defaults_are_off():
    cfg = RenderConfig()
    assert {k: getattr(cfg, k) for k in HARD_DEFAULTS} == HARD_DEFAULTS
    assert config_spec(cfg).keys().isdisjoint(HARD_DEFAULTS)


@pytest.mark.parametrize("option", OPTIONS)
def test_option_off_leaves_the_render_unchanged(option):
    off = {k: 0.0 for k in option}
    for seed in range(4):
        a = render_scene(seed, SMALL, RenderConfig(kinds=OUTDOOR))
        b = render_scene(seed, SMALL, RenderConfig(kinds=OUTDOOR, **off))
        assert np.array_equal(a.image, b.image) and a.to_dict() == b.to_dict()


@pytest.mark.parametrize("option", OPTIONS)
def test_option_deterministic_per_seed_and_visible(option):
    cfg = RenderConfig(kinds=OUTDOOR, **option)
    changed = 0
    for seed in range(6):
        a, b = render_scene(seed, SMALL, cfg), render_scene(seed, SMALL, cfg)
        assert np.array_equal(a.image, b.image) and a.to_dict() == b.to_dict()
        changed += not np.array_equal(a.image, render_scene(seed, SMALL, RenderConfig(kinds=OUTDOOR)).image)
    assert changed >= 3


@pytest.mark.parametrize("option", OPTIONS[:2])
def test_additions_leave_the_camera_and_the_scene_draws(option):
    """Stairs and billboards come from their own random stream: the camera and every other object stay put."""
    for seed in range(4):
        a = render_scene(seed, SMALL, RenderConfig(kinds=OUTDOOR))
        b = render_scene(seed, SMALL, RenderConfig(kinds=OUTDOOR, **option))
        assert a.to_dict() == b.to_dict()
        assert len(b.scene.items) >= len(a.scene.items)


def test_fronto_faces_a_facade():
    for kind in OUTDOOR:
        cfg = RenderConfig(kinds={kind: 1.0}, fronto_prob=1.0, fronto_jitter=0.0)
        for seed in range(6):
            yaw = float(render_scene(seed, (32, 24), cfg).yaw)
            step = 180.0 if kind == "street" else 90.0
            assert math.isclose((yaw - 90.0) % step, 0.0, abs_tol=1e-9) or math.isclose((yaw - 90.0) % step, step)


def test_indoor_renders_ignore_the_hard_cases():
    hard = RenderConfig(kinds={"indoor": 1.0}, stairs=3.0, billboards=3.0, fronto_prob=1.0)
    for seed in range(3):
        a, b = render_scene(seed, SMALL, RenderConfig(kinds={"indoor": 1.0})), render_scene(seed, SMALL, hard)
        assert np.array_equal(a.image, b.image)


@pytest.mark.parametrize("bad", [dict(stairs=-1.0), dict(billboards=-0.5), dict(fronto_prob=1.5),
                                 dict(fronto_jitter=-1.0)])
def test_bad_hard_options_raise(bad):
    with pytest.raises(ValueError):
        RenderConfig(**bad)


def _view() -> PinholeView:
    gt = camera_ground_truth(60.0, 0.0, 0.0, 0.0, SMALL)
    return PinholeView(gt["K"].numpy(), gt["R"].numpy(), np.zeros(3), *SMALL)


def test_stairs_have_sloped_edges():
    item = make_stairs(np.random.default_rng(1), (0.0, 8.0), 0.0, 1.5, 5.0, 1.5)
    faces = item.build(_view())
    edges = np.concatenate([np.diff(np.concatenate([f.verts, f.verts[:1]]), axis=0) for f in faces])
    edges = edges[np.linalg.norm(edges, axis=1) > 0.5]
    slope = np.degrees(np.arctan2(np.abs(edges[:, 1]), np.hypot(edges[:, 0], edges[:, 2])))
    assert ((slope > 20) & (slope < 45)).any()  # along no axis of the world
    assert all(item.y_top <= f.verts[:, 1].min() and f.verts[:, 1].max() <= item.y_bottom + 1e-9 for f in faces)


def test_billboard_turned_by_its_yaw():
    item = make_billboard(np.random.default_rng(2), (0.0, 10.0), 30.0, 1.5, 4.0)
    panel = item.build(_view())[-1]
    d = panel.verts[1] - panel.verts[0]
    assert math.isclose(math.degrees(math.atan2(-d[2], d[0])), 30.0, abs_tol=1e-6)
