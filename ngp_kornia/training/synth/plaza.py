"""The Atlanta-world plaza layout of the renderer: blocks of several yaws sharing the vertical. The ground-truth
Manhattan frame is that of the *dominant* group (yaw 0, the world axes): it owns the largest block, placed straight
ahead of the camera, about half of the other blocks and the paving grid.
"""

from __future__ import annotations

import math

import numpy as np

from ngp_kornia.training.synth.clutter import make_bench, make_bush, make_person, make_pole, make_tree
from ngp_kornia.training.synth.facade import make_building
from ngp_kornia.training.synth.hard import Additions, make_billboard, make_stairs
from ngp_kornia.training.synth.layouts import PAVEMENT, Spots, building_height, ground_rects, pick_color
from ngp_kornia.training.synth.scene import UP, Decal, Face, Scene

__all__ = ["make_atlanta"]


def make_atlanta(rng: np.random.Generator, cam_height: float, clutter: float = 1.0, view_yaw: float = 0.0,
                 additions: Additions | None = None) -> Scene:
    """An Atlanta world: a paved plaza with blocks of several yaws sharing the vertical.

    The dominant group has yaw 0 (the ground-truth Manhattan frame): it owns the largest block, placed ahead of
    the camera (whose heading is ``view_yaw`` degrees), about half of the other blocks, and the paving grid.

    Args:
        rng: random generator.
        cam_height: camera height above the plaza.
        clutter: amount of trees, people, poles.
        view_yaw: the camera's yaw in degrees, to put the dominant block in view.
        additions: hard cases (stairs, billboards) on the plaza, drawn from their own generator.

    Returns:
        The scene; ``frames`` lists the yaws of the groups, dominant first.

    Example:
        >>> scene = make_atlanta(np.random.default_rng(0), 1.6)
        >>> scene.kind, scene.frames[0], len(scene.frames) > 1
        ('atlanta', 0.0, True)
    """
    gy = cam_height
    scene = Scene("atlanta", gy)
    scene.ground_color = pick_color(rng, PAVEMENT)
    n_groups = int(rng.integers(2, 4))
    yaws = [0.0]
    while len(yaws) < n_groups:
        y = float(rng.choice([-1, 1]) * rng.uniform(15.0, 75.0))
        if all(abs(((y - o + 45) % 90) - 45) > 12 for o in yaws):
            yaws.append(y)
    scene.frames = yaws
    district = ["downtown", "mixed"][rng.integers(2)]
    spots = Spots(cell=60.0)  # blocks are large: few per cell
    spots.take(0.0, 0.0, 3.0)  # keep the camera free
    place = spots.take

    # the dominant block, ahead
    h = (rng.uniform(10, 25), rng.uniform(8, 20))
    d = rng.uniform(12.0, 35.0) + math.hypot(*h)
    head = math.radians(view_yaw + rng.uniform(-15, 15))
    c = (d * math.sin(head), d * math.cos(head))
    place(c[0], c[1], math.hypot(*h) + 1.0)
    _add_block(rng, scene, c, h, 0.0, gy, rng.uniform(15.0, 60.0), district)
    p = np.array([0.5, 0.3, 0.2][:n_groups])
    for _ in range(int(rng.integers(6, 15))):
        g = int(rng.choice(n_groups, p=p / p.sum()))
        h = (rng.uniform(5, 18), rng.uniform(5, 18))
        r = math.hypot(*h) + 1.0
        # most blocks around the view direction (a plaza is photographed towards its buildings), some anywhere
        spread = math.radians(70.0) if rng.random() < 0.7 else math.pi
        ang, dist = math.radians(view_yaw) + rng.uniform(-spread, spread), rng.uniform(r + 8, 120)
        x, z = dist * math.sin(ang), dist * math.cos(ang)
        if place(x, z, r):
            _add_block(rng, scene, (x, z), h, yaws[g], gy, building_height(rng, district), district)
    _plaza_ground(rng, scene, gy)
    if clutter > 0:
        _plaza_clutter(rng, scene, gy, clutter, place)
    return _plaza_additions(additions, scene, gy, view_yaw, place)


def _plaza_additions(add: Additions | None, scene: Scene, gy: float, view_yaw: float, place) -> Scene:
    """Stairs along the axes of a block group and billboards at any yaw, towards the view direction."""
    if add is None:
        return scene
    rng = add.rng
    for n, stairs in ((rng.poisson(add.stairs), True), (rng.poisson(add.billboards), False)):
        for _ in range(n):
            ang, dist = math.radians(view_yaw + rng.uniform(-50, 50)), rng.uniform(6.0, 40.0)
            x, z = dist * math.sin(ang), dist * math.cos(ang)
            yaw = float(scene.frames[rng.integers(len(scene.frames))]) + (0.0 if stairs else rng.uniform(0, 180))
            size = rng.uniform(3.0, 7.0) if stairs else rng.uniform(2.5, 7.0)
            if not place(x, z, 0.5 * size + 0.3):
                continue
            if stairs:
                scene.items.append(make_stairs(rng, (x, z), yaw, gy, size, rng.uniform(1.2, 3.0)))
            else:
                scene.items.append(make_billboard(rng, (x, z), yaw, gy, size))
    return scene


def _add_block(rng, scene: Scene, center, half, yaw: float, gy: float, height: float, district: str) -> None:
    item, box = make_building(int(rng.integers(2**31)), center, half, yaw, gy, height, district, fronts=(0, 1, 2, 3))
    scene.items.append(item)
    if yaw == 0.0:
        scene.boxes.append(box)


def _plaza_ground(rng: np.random.Generator, scene: Scene, gy: float) -> None:
    step = rng.uniform(2.0, 6.0)
    r = 60.0
    ticks = np.arange(-r, r + 1e-9, step) + rng.uniform(0, step)
    segs = [[[t, gy, -r], [t, gy, r]] for t in ticks] + [[[-r, gy, t], [r, gy, t]] for t in ticks]
    color = scene.ground_color * 0.78
    scene.ground.append(Face(ground_rects(0, 1, 0, 1, gy)[0], None, UP.copy(),
                             [Decal(np.array(segs), color, width=0.05)]))


def _plaza_clutter(rng: np.random.Generator, scene: Scene, gy: float, clutter: float, place) -> None:
    for _ in range(rng.poisson(14 * clutter)):
        x, z = rng.uniform(-60, 60, 2)
        kind = rng.choice(5, p=[0.3, 0.35, 0.15, 0.1, 0.1])
        if not place(x, z, [1.0, 0.5, 0.6, 1.3, 0.8][kind]):
            continue
        if kind == 0:
            scene.items.append(make_tree(rng, (x, z), gy))
        elif kind == 1:
            scene.items.append(make_person(rng, (x, z), gy))
        elif kind == 2:
            scene.items.append(make_pole(rng, (x, z), gy, rng.uniform(0, 360)))
        elif kind == 3:
            scene.items.append(make_bench(rng, (x, z), rng.uniform(0, 360), gy))
        else:
            scene.items.append(make_bush(rng, (x, z), gy))
