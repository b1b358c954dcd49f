"""The renderer's object map and the line-evidence labels made from it: the image does not change when the map is
asked for, the map says what each pixel shows, and detected segments on a known scene get the labels they should."""

import hashlib

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.training.synth.line_labels import (
    direction_classes,
    frame_vanishing_points,
    line_targets,
    outline_lengths,
    structure_targets,
)
from ngp_kornia.training.synth.objects import STRUCTURE_KINDS, ObjectMap, draw_object_map
from ngp_kornia.training.synth.painter import Canvas, PinholeView
from ngp_kornia.training.synth.pixels import sky_and_ground, view_rays
from ngp_kornia.training.synth.render import camera_ground_truth, render_scene
from ngp_kornia.training.synth.render_config import RenderConfig
from ngp_kornia.training.synth.scene import OBJECT_KINDS, Item, Lighting, Scene, box_faces, draw_scene

SMALL = (160, 120)
HARD = RenderConfig(stairs=1.5, billboards=1.0, radial_distortion=0.05)
# digests of renders with this config made before the object map existed: they must not move
HARD_BEFORE = {7: "46c4487f749c933c", 11: "7caa176c3fb6a6de"}


def _digest(image: np.ndarray) -> str:
    return hashlib.sha256(image.tobytes()).hexdigest()[:16]


def test_asking_for_the_map_leaves_the_image_as_before():
    for seed in range(4):
        assert _digest(render_scene(seed, SMALL, objects=True).image) == _digest(render_scene(seed, SMALL).image)
    assert {s: _digest(render_scene(s, SMALL, HARD, objects=True).image) for s in HARD_BEFORE} == HARD_BEFORE


def test_no_map_unless_asked():
    assert render_scene(0, SMALL).objects is None


@pytest.mark.parametrize("config", [RenderConfig(), HARD])
def test_the_map_covers_the_image_with_known_kinds(config):
    for seed in range(3):
        r = render_scene(seed, SMALL, config, objects=True)
        ids = r.objects.ids
        assert ids.shape == r.image.shape[:2] and ids.dtype == np.int32
        assert 0 <= ids.min() and ids.max() < len(r.objects.kinds)
        assert set(r.objects.kinds.tolist()) <= set(range(len(OBJECT_KINDS)))


def test_every_item_of_the_renders_has_a_kind():
    for seed in range(6):
        scene = render_scene(seed, SMALL, RenderConfig(clutter=2.0, stairs=1.0, billboards=1.0)).scene
        assert all(item.kind != "other" for item in scene.items)


def test_an_unknown_item_kind_is_refused():
    with pytest.raises(ValueError, match="unknown item kind"):
        Item(np.zeros((4, 2)), -1.0, 0.0, lambda view: [], "spaceship")


def _two_boxes() -> tuple[PinholeView, Scene, np.ndarray]:
    """A level camera 1.5 above the ground, a building on the left, a car-kind box on the right, plain colours."""
    gt = camera_ground_truth(60.0, 0.0, 0.0, 0.0, (320, 240))
    view = PinholeView(gt["K"].numpy(), gt["R"].numpy(), np.zeros(3), 320, 240)
    building = Item(np.array([[-6.0, 14], [-1, 14], [-1, 18], [-6, 18]]), -6.0, 1.5,
                    lambda v: box_faces((-3.5, 16.0), (2.5, 2.0), 1.5, -6.0, 0.0, (200, 90, 60)), "building")
    car = Item(np.array([[1.0, 9], [3, 9], [3, 11], [1, 11]]), 0.0, 1.5,
               lambda v: box_faces((2.0, 10.0), (1.0, 1.0), 1.5, 0.0, 0.0, (40, 60, 200)), "car")
    scene = Scene("street", 1.5, items=[building, car], ground_color=np.array([90.0, 90.0, 90.0]))
    light = Lighting()
    image = sky_and_ground(view, scene.ground_color * light.factor(np.array([0.0, -1.0, 0.0])),
                           (np.array([80.0, 120, 200]), np.array([200.0, 210, 230])), view_rays(view))
    draw_scene(Canvas(view, image), scene, light)
    return view, scene, image


def test_the_map_of_a_known_scene():
    view, scene, _ = _two_boxes()
    kinds = draw_object_map(view, scene).kind_map()
    f, cx, cy = view.K[0, 0], view.K[0, 2], view.K[1, 2]

    def kind_at(x, y, z):
        return OBJECT_KINDS[kinds[round(f * y / z + cy), round(f * x / z + cx)]]

    assert kind_at(-3.5, -3.0, 14.0) == "building"
    assert kind_at(2.0, 0.75, 9.0) == "car"
    assert kind_at(0.0, -3.0, 10.0) == "sky"
    assert kind_at(0.0, 1.5, 5.0) == "ground"


def test_labels_of_segments_detected_on_a_known_scene():
    view, scene, image = _two_boxes()
    objects = draw_object_map(view, scene)
    lines = cv2.createLineSegmentDetector().detect(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))[0].reshape(-1, 2, 2)
    seg = lines[np.linalg.norm(lines[:, 1] - lines[:, 0], axis=-1) > 15]
    target = structure_targets(seg, objects)
    f, cx, cy = view.K[0, 0], view.K[0, 2], view.K[1, 2]

    def inside(x0, x1, y0, y1, z0, z1):  # both ends within the image box of a box's corners (2 px margin)
        xs = [f * x / z + cx for x in (x0, x1) for z in (z0, z1)]
        ys = [f * y / z + cy for y in (y0, y1) for z in (z0, z1)]
        return ((seg[..., 0] > min(xs) - 2) & (seg[..., 0] < max(xs) + 2) & (seg[..., 1] > min(ys) - 2)
                & (seg[..., 1] < max(ys) + 2)).all(1)

    on_building = inside(-6.0, -1.0, -6.0, 1.5, 14.0, 18.0)
    on_car = inside(1.0, 3.0, 0.0, 1.5, 9.0, 11.0)
    assert on_building.sum() >= 3 and on_car.sum() >= 3
    assert (target[on_building] >= 0.5).all()
    assert (target[on_car] < 0.5).all()
    # a level camera: vertical edges point at the zenith, the boxes' other edges at a horizontal VP
    zenith, horizontal = frame_vanishing_points(torch.as_tensor(view.K), torch.as_tensor(view.R), (0.0,))
    classes = direction_classes(torch.as_tensor(seg), zenith, horizontal)
    upright = np.abs(seg[:, 1, 0] - seg[:, 0, 0]) < 0.5
    level = np.abs(seg[:, 1, 1] - seg[:, 0, 1]) < 0.5
    assert upright.any() and level.any()
    assert (classes[torch.as_tensor(upright)] == 0).all() and (classes[torch.as_tensor(level)] == 1).all()


def test_structure_kinds_are_kinds():
    assert set(STRUCTURE_KINDS) <= set(OBJECT_KINDS)
    m = ObjectMap(np.zeros((2, 2), np.int32), np.array([OBJECT_KINDS.index(k) for k in ("sky", *STRUCTURE_KINDS)]))
    assert m.structure().tolist() == [False, True, True, True]


def test_labels_of_no_segments():
    m = ObjectMap(np.zeros((4, 4), np.int32), np.zeros(1, np.int16))
    assert structure_targets(np.zeros((0, 2, 2)), m).shape == (0,)
    assert direction_classes(torch.zeros(0, 2, 2), torch.tensor([0.0, 1, 0]), torch.zeros(0, 3)).shape == (0,)


def test_foliage_texture_changes_only_the_leaves():
    outdoor = {"street": 1.0}
    for seed in range(3):
        plain = render_scene(seed, SMALL, RenderConfig(kinds=outdoor, photometric=False), objects=True)
        leafy = render_scene(seed, SMALL, RenderConfig(kinds=outdoor, photometric=False, foliage=0.8))
        again = render_scene(seed, SMALL, RenderConfig(kinds=outdoor, photometric=False, foliage=0.8))
        assert np.array_equal(leafy.image, again.image)
        kinds = plain.objects.kind_map()
        leaves = np.isin(kinds, [OBJECT_KINDS.index(k) for k in ("tree", "bush", "plant")])
        changed = (leafy.image != plain.image).any(-1)
        assert not changed[~leaves].any()
        assert changed[leaves].mean() > 0.5 or not leaves.any()


def test_foliage_off_keeps_the_config_digest():
    from ngp_kornia.training.synth.render_config import config_spec

    assert "foliage" not in config_spec(RenderConfig()) and config_spec(RenderConfig(foliage=0.5))["foliage"] == 0.5
    with pytest.raises(ValueError, match="foliage"):
        RenderConfig(foliage=2.0)


def test_line_targets_keep_long_manhattan_outlines_only():
    # a 640 x 480 map: a room (structural) wall right of column 299.5 over rows 40-439, and a small window in it;
    # the level camera's zenith is straight down the image, a horizontal VP far to the right
    ids = np.zeros((480, 640), np.int32)
    ids[40:440, 300:] = 1
    ids[200:212, 400:412] = 2  # a 12-pixel window pane
    objects = ObjectMap(ids, np.array([OBJECT_KINDS.index(k) for k in ("sky", "room", "room")], np.int16))
    segments = np.array([
        [[299.5, 100.0], [299.5, 300.0]],  # on the wall's long edge, vertical
        [[399.5, 201.0], [399.5, 210.0]],  # on the window's 12-pixel edge, vertical
        [[299.5, 100.0], [310.0, 300.0]],  # across the wall's edge at a slant: points at no VP
    ])
    zenith, horizontal = torch.tensor([0.0, 1.0, 0.0]), torch.tensor([[1.0, 0.0, 0.0]])
    structure, direction = line_targets(segments, objects, zenith, horizontal)
    assert direction.tolist()[:2] == [0, 0] and direction[2] == 2
    assert structure[0] == 1.0 and structure[1] == 0.0 and structure[2] == 0.0
    assert outline_lengths(segments[:2], objects).tolist() == [400.0, 12.0]
