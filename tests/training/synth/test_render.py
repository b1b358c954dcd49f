"""Tests of the procedural renderer (ngp_kornia.training.synth.render and its scene modules): determinism, exact ground
truth (3D edges and detected line segments meet the true vanishing points), horizon placement, configuration, sizes and
near-plane clipping."""

import json
import math

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.geometry.camera import (
    fov_from_focal,
    horizon_from_zenith,
    rotation_from_angles,
    up_from_rotation,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.training.synth.painter import Canvas, PinholeView, clip_polygon
from ngp_kornia.training.synth.pixels import sky_and_ground, view_rays
from ngp_kornia.training.synth.render import camera_ground_truth, render_dataset, render_scene
from ngp_kornia.training.synth.render_config import RenderConfig
from ngp_kornia.training.synth.scene import Item, Lighting, Scene, box_faces, draw_scene, order_items

SMALL = (160, 120)
CLEAN = dict(photometric=False)


def _angle_to_vps(p0: np.ndarray, p1: np.ndarray, vps: np.ndarray) -> np.ndarray:
    """(n, 3) angles in degrees between segments p0 -> p1 (n, 2) and the directions from their midpoints to each VP."""
    d = p1 - p0
    m = 0.5 * (p0 + p1)
    out = []
    for v in vps:
        e = v[None, :2] - m * v[2]
        cross = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]
        out.append(np.degrees(np.arctan2(np.abs(cross), np.abs((d * e).sum(1)))))  # well conditioned near 0
    return np.stack(out, 1)


def _lsd_errors(r, min_len: float = 20.0) -> np.ndarray:
    lines = cv2.createLineSegmentDetector().detect(cv2.cvtColor(r.image, cv2.COLOR_RGB2GRAY))[0]
    if lines is None:
        return np.zeros(0)
    seg = lines.reshape(-1, 4).astype(np.float64)
    seg = seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > min_len]
    return _angle_to_vps(seg[:, :2], seg[:, 2:], r.vps.numpy()).min(1)


def test_deterministic_per_seed():
    a, b, c = render_scene(11, SMALL), render_scene(11, SMALL), render_scene(12, SMALL)
    assert np.array_equal(a.image, b.image)
    assert a.to_dict() == b.to_dict()
    assert not np.array_equal(a.image, c.image)


def test_ground_truth_follows_the_camera_functions():
    r = render_scene(3, (200, 150))
    K, R = r.K, r.R
    assert K.dtype == torch.float64 and R.dtype == torch.float64
    assert torch.allclose(K[:2, 2], torch.tensor([99.5, 74.5], dtype=torch.float64))
    assert torch.allclose(K[0, 0], r.focal) and torch.allclose(K[1, 1], r.focal)
    R_ref = rotation_from_angles(r.pitch[None], r.roll[None], r.yaw[None])[0]
    assert torch.allclose(R, R_ref, atol=1e-12)
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    zenith = zenith_from_up(K[None], up_from_rotation(R[None]))[0]
    assert torch.allclose(r.zenith, zenith)
    assert torch.allclose(r.horizon, horizon_from_zenith(K[None], zenith[None])[0])
    assert torch.allclose(r.vps, vanishing_points_from_rotation(K[None], R[None])[0])
    assert math.isclose(float(fov_from_focal(r.focal[None], 200)), float(r.fov_h), rel_tol=1e-9)
    assert math.isclose(float(fov_from_focal(r.focal[None], 150)), float(r.fov_v), rel_tol=1e-9)


@pytest.mark.parametrize("kind", ["street", "indoor", "atlanta"])
def test_axis_aligned_box_edges_meet_the_true_vps(kind):
    cfg = RenderConfig(kinds={kind: 1.0}, **CLEAN)
    checked = 0
    for seed in range(4):
        r = render_scene(seed, SMALL, cfg)
        K, R = r.K.numpy(), r.R.numpy()
        for lo, hi in r.scene.boxes:
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            for axis in range(3):
                bit = 1 << (2 - axis)  # corner index bits are (x, y, z)
                pairs = [(i, i | bit) for i in range(8) if not i & bit]
                a, b = corners[[p[0] for p in pairs]], corners[[p[1] for p in pairs]]
                ca, cb = a @ R.T, b @ R.T  # the camera sits at the world origin
                ok = (ca[:, 2] > 0.5) & (cb[:, 2] > 0.5)
                if not ok.any():
                    continue
                pa, pb = ca[ok] @ K.T, cb[ok] @ K.T
                pa, pb = pa[:, :2] / pa[:, 2:], pb[:, :2] / pb[:, 2:]
                long = np.linalg.norm(pb - pa, axis=1) > 1.0
                err = _angle_to_vps(pa[long], pb[long], r.vps.numpy()[axis : axis + 1])
                assert np.all(err < 1e-6)
                checked += int(long.sum())
    assert checked > 20


@pytest.mark.parametrize("kind", ["street", "indoor", "atlanta"])
def test_lsd_segments_point_at_the_true_vps(kind):
    cfg = RenderConfig(kinds={kind: 1.0})
    errors = np.concatenate([_lsd_errors(render_scene(seed, (320, 240), cfg)) for seed in range(8)])
    assert len(errors) > 100
    assert np.median(errors) < 0.6
    assert np.mean(errors < 2.0) > 0.7


def test_atlanta_frames_explain_the_other_blocks():
    cfg = RenderConfig(kinds={"atlanta": 1.0}, **CLEAN)
    dominant, every = [], []
    for seed in range(8):
        r = render_scene(seed, (320, 240), cfg)
        assert r.frames[0] == 0.0 and len(r.frames) > 1
        lines = cv2.createLineSegmentDetector().detect(cv2.cvtColor(r.image, cv2.COLOR_RGB2GRAY))[0].reshape(-1, 4)
        seg = lines[np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1]) > 20].astype(np.float64)
        vps = [
            vanishing_points_from_rotation(
                r.K[None], rotation_from_angles(r.pitch[None], r.roll[None], r.yaw[None] - yaw)
            )[0].numpy()
            for yaw in r.frames
        ]
        assert np.allclose(vps[0], r.vps.numpy())  # the ground-truth frame is the dominant group's
        err = [_angle_to_vps(seg[:, :2], seg[:, 2:], v).min(1) for v in vps]
        dominant.append(err[0])
        every.append(np.min(err, 0))
    dominant, every = np.concatenate(dominant), np.concatenate(every)
    assert np.median(dominant) < 1.0  # the dominant frame holds most lines
    assert np.mean(every < 1.0) > np.mean(dominant < 1.0) + 0.03  # the other groups' lines meet their own VPs


@pytest.mark.parametrize("pitch,roll", [(20.0, 0.0), (-20.0, 0.0), (0.0, 10.0), (10.0, -15.0)])
def test_horizon_consistent_with_pitch_and_roll(pitch, roll):
    cfg = RenderConfig(pitch=(pitch, pitch), roll=(roll, roll), **CLEAN)
    r = render_scene(5, (160, 120), cfg)
    a, b, c = r.horizon.tolist()
    cx, cy = 79.5, 59.5
    y_mid = -(a * cx + c) / b
    if pitch > 0:
        assert y_mid > cy + 5  # looking up: the horizon is below the centre
    elif pitch < 0:
        assert y_mid < cy - 5
    else:
        assert abs(y_mid - cy) < 1e-6
    slope = -a / b  # dy / dx of the horizon in the image (y down)
    assert np.sign(slope) == np.sign(roll) or roll == 0.0
    assert math.isclose(math.degrees(math.atan(slope)), roll, abs_tol=1e-6)


def test_sky_and_ground_meet_on_the_horizon():
    gt = camera_ground_truth(60.0, 12.0, -8.0, 30.0, (160, 120))
    view = PinholeView(gt["K"].numpy(), gt["R"].numpy(), np.zeros(3), 160, 120)
    sky = (np.array([0.0, 0.0, 250.0]), np.array([0.0, 0.0, 250.0]))
    img = sky_and_ground(view, np.array([20.0, 200.0, 20.0]), sky, view_rays(view)).astype(float)
    a, b, c = gt["horizon"].tolist()
    for x in range(0, 160, 7):
        y = -(a * x + c) / b
        above, below = int(np.floor(y - 1.5)), int(np.ceil(y + 1.5))
        if 0 <= above and below < 120:
            assert img[above, x, 2] > 240 and img[above, x, 1] < 10  # sky
            assert img[below, x, 1] > 190 and img[below, x, 2] < 30  # ground


def test_config_ranges_respected():
    cfg = RenderConfig(
        fov_v=(50.0, 55.0),
        pitch=(-5.0, 5.0),
        roll=(2.0, 3.0),
        yaw=(10.0, 20.0),
        kinds={"indoor": 1.0},
        indoor_camera_height=(1.2, 1.3),
    )
    for seed in range(5):
        r = render_scene(seed, SMALL, cfg)
        assert r.kind == "indoor"
        assert 50.0 <= float(r.fov_v) <= 55.0
        assert -5.0 <= float(r.pitch) <= 5.0 and 2.0 <= float(r.roll) <= 3.0 and 10.0 <= float(r.yaw) <= 20.0
        assert 1.2 <= r.scene.ground_y <= 1.3
    kinds = {render_scene(s, (32, 24), RenderConfig(kinds={"street": 1.0, "atlanta": 1.0})).kind for s in range(12)}
    assert kinds == {"street", "atlanta"}


@pytest.mark.parametrize(
    "bad",
    [
        dict(fov_v=(10.0, 190.0)),
        dict(pitch=(5.0, -5.0)),
        dict(kinds={"forest": 1.0}),
        dict(kinds={"street": 0.0}),
        dict(jpeg_prob=1.5),
        dict(clutter=-1.0),
    ],
)
def test_bad_config_raises(bad):
    with pytest.raises(ValueError):
        RenderConfig(**bad)


@pytest.mark.parametrize(
    "bad",
    [dict(stairs=math.nan), dict(billboards=math.nan), dict(clutter=math.inf), dict(fronto_jitter=-math.inf),
     dict(stairs=True), dict(color_balance=math.nan), dict(pitch=(0.0, True)), dict(kinds={"street": math.inf})],
)
def test_numbers_that_are_not_finite_are_refused(bad):
    # NaN passes every range check (its comparisons are all false), and true is 1: each is refused by name
    (name,) = bad
    with pytest.raises(ValueError, match=f"^{name} must hold finite numbers"):
        RenderConfig(**bad)


@pytest.mark.parametrize("seed,size", [(-1, SMALL), (1.5, SMALL), (0, (0, 10)), (0, (10,)), (0, (10.5, 20))])
def test_bad_arguments_raise(seed, size):
    with pytest.raises(ValueError):
        render_scene(seed, size)


@pytest.mark.parametrize("size", [(120, 160), (100, 100), (257, 97)])
def test_sizes_and_finite_ground_truth(size):
    W, H = size
    for seed in range(3):
        r = render_scene(seed, size)
        assert r.image.shape == (H, W, 3) and r.image.dtype == np.uint8
        assert (r.width, r.height) == size
        assert torch.allclose(r.K[:2, 2], torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64))
        d = r.to_dict()
        flat = np.concatenate([np.ravel(d[k]) for k in ("K", "R", "zenith", "horizon", "vps")])
        assert np.isfinite(flat).all()
        assert all(math.isfinite(d[k]) for k in ("focal", "fov_v", "fov_h", "pitch", "roll"))
        assert r.image.std() > 5  # something was drawn


def test_to_dict_is_plain_json():
    d = render_scene(2, SMALL).to_dict()
    for key in (
        "K",
        "R",
        "focal",
        "fov_v",
        "fov_h",
        "pitch",
        "roll",
        "zenith",
        "horizon",
        "vps",
        "width",
        "height",
        "seed",
    ):
        assert key in d
    back = json.loads(json.dumps(d))
    assert back == d
    assert np.array(back["vps"]).shape == (3, 3) and np.array(back["K"]).shape == (3, 3)


def _ray_cast_mask(view: PinholeView, boxes) -> np.ndarray:
    """Pixels whose ray hits one of the axis-aligned boxes (lo, hi) in front of the near plane (slab method)."""
    H, W = view.height, view.width
    x, y = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d_cam = np.stack([(x - view.K[0, 2]) / view.focal, (y - view.K[1, 2]) / view.focal, np.ones_like(x)], -1)
    d = d_cam @ view.R  # world directions; the parameter t is the camera z
    hit = np.zeros((H, W), bool)
    for lo, hi in boxes:
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo - view.center) / d
            t1 = (hi - view.center) / d
        tn = np.nanmax(np.minimum(t0, t1), -1)
        tf = np.nanmin(np.maximum(t0, t1), -1)
        hit |= (tf >= np.maximum(tn, view.near)) & (tf > view.near)
    return hit


def test_near_plane_clipping_matches_ray_casting():
    gt = camera_ground_truth(70.0, 5.0, 3.0, 20.0, (160, 120))
    view = PinholeView(gt["K"].numpy(), gt["R"].numpy(), np.zeros(3), 160, 120)
    # a long wall passing beside and behind the camera, a box straddling the camera's plane, one fully behind
    boxes = [
        (np.array([-3.0, -4.0, -30.0]), np.array([-2.0, 1.5, 30.0])),
        (np.array([1.0, -1.0, -5.0]), np.array([4.0, 1.5, 6.0])),
        (np.array([-1.0, -2.0, -20.0]), np.array([1.0, 1.0, -15.0])),
    ]
    scene = Scene("street", 1.5)
    for lo, hi in boxes:
        c = 0.5 * (lo + hi)
        half = (0.5 * (hi[0] - lo[0]), 0.5 * (hi[2] - lo[2]))
        faces = box_faces((c[0], c[2]), half, hi[1], lo[1], 0.0, (255, 255, 255))
        fp = np.array([[lo[0], lo[2]], [hi[0], lo[2]], [hi[0], hi[2]], [lo[0], hi[2]]])
        scene.items.append(Item(fp, lo[1], hi[1], lambda v, f=faces: f))
    img = np.zeros((120, 160, 3), np.uint8)
    draw_scene(Canvas(view, img, antialias=False), scene, Lighting(ambient=1.0, sun=0.0, fill=0.0))
    drawn = img[..., 0] > 127
    truth = _ray_cast_mask(view, boxes)
    assert truth.mean() > 0.2
    assert (drawn & truth).sum() / (drawn | truth).sum() > 0.98
    # only the box behind the camera: nothing at all may be drawn
    behind = Scene("street", 1.5, items=[scene.items[2]])
    img[:] = 0
    draw_scene(Canvas(view, img), behind, Lighting())
    assert img.max() == 0


def test_clip_polygon_keeps_the_front_part():
    quad = np.array([[-1.0, 0, -2], [1, 0, -2], [1, 0, 4], [-1, 0, 4]])
    out = clip_polygon(quad, np.array([[0.0, 0, 1, -0.5]]))  # keep z >= 0.5
    assert out[:, 2].min() == pytest.approx(0.5)
    assert len(out) == 4


def test_order_items_draws_far_before_near():
    near = np.array([[2.0, 10], [2.5, 10], [2.5, 90], [2.0, 90]])  # a long wall on the right
    small = np.array([[1.0, 50.0], [1.5, 50], [1.5, 51], [1.0, 51]])  # a post in front of the wall's far part
    order = order_items(np.stack([small, near]), np.zeros(2))
    assert order == [1, 0]  # the wall first: its nearest point is closer, but the post hides it


def test_render_dataset(tmp_path):
    records = render_dataset(tmp_path, 3, seed=4, size=(64, 48))
    data = json.loads((tmp_path / "ground_truth.json").read_text())
    assert data == records and len(data) == 3
    assert len({d["seed"] for d in data}) == 3
    for d in data:
        img = cv2.imread(str(tmp_path / d["image"]))[..., ::-1]
        assert np.array_equal(img, render_scene(d["seed"], (64, 48)).image)
        assert (d["width"], d["height"]) == (64, 48)
    with pytest.raises(ValueError):
        render_dataset(tmp_path, 1, ext="gif")
