"""The street layout of the renderer: a street crossing in a city grid, and the ground helpers the other outdoor
layout shares (:mod:`~ngp_kornia.training.synth.plaza`; rooms are in :mod:`~ngp_kornia.training.synth.interior`).
The camera is at the world origin, ``cam_height`` above the ground.

Street scenes are Manhattan: the main street runs along world z, the cross street along world x, every building
is aligned with the world axes.
"""

from __future__ import annotations

import math

import numpy as np

from ngp_kornia.training.synth.clutter import (
    make_bench,
    make_bollard,
    make_bush,
    make_car,
    make_person,
    make_pole,
    make_tree,
    wire,
)
from ngp_kornia.training.synth.facade import make_building
from ngp_kornia.training.synth.hard import Additions, make_billboard, make_stairs
from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.scene import UP, Decal, Face, Scene

__all__ = ["PAVEMENT", "Spots", "building_height", "ground_rects", "make_street", "pick_color"]

_ASPHALT = [(85, 85, 88), (100, 98, 95), (70, 72, 75), (115, 112, 108)]
PAVEMENT = [(165, 160, 150), (180, 175, 165), (150, 150, 148), (190, 180, 160)]
_PAINT = [(235, 235, 230), (230, 190, 60)]


def pick_color(rng: np.random.Generator, colors, jitter: float = 6.0) -> np.ndarray:
    c = np.asarray(colors[rng.integers(len(colors))], dtype=np.float64)
    return np.clip(c + rng.normal(0.0, jitter, 3), 0, 255)


def ground_rects(x0, x1, z0, z1, y) -> np.ndarray:
    """(m, 4, 3) ground rectangles from arrays of bounds (counter-clockwise seen from above)."""
    x0, x1, z0, z1 = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (x0, x1, z0, z1)))
    y = np.full(x0.shape, float(y))
    return np.stack([np.stack([x0, y, z0], -1), np.stack([x1, y, z0], -1), np.stack([x1, y, z1], -1),
                     np.stack([x0, y, z1], -1)], 1)


def building_height(rng: np.random.Generator, district: str) -> float:
    floors = {"residential": lambda: rng.integers(2, 6), "downtown": lambda: int(4 + rng.exponential(8)),
              "mixed": lambda: rng.integers(2, 11)}[district]()
    return float(min(floors, 40)) * rng.uniform(3.0, 3.6) + rng.uniform(0.3, 1.5)


def _dashes(lo: float, hi: float, dash: float, gap: float, skip: tuple[float, float]) -> np.ndarray:
    """(m, 2) dash intervals along [lo, hi], leaving out the interval ``skip``."""
    s = np.arange(lo, hi - dash, dash + gap)
    d = np.stack([s, s + dash], -1)
    return d[(d[:, 1] < skip[0]) | (d[:, 0] > skip[1])]


class Spots:
    """Discs ``(x, z, r)`` kept free of each other, in a hash grid so a check looks at a few neighbours only."""

    def __init__(self, cell: float = 8.0) -> None:
        self.cell = cell
        self.grid: dict[tuple[int, int], list[tuple[float, float, float]]] = {}

    def take(self, x: float, z: float, r: float) -> bool:
        """Claim the disc if it overlaps no claimed one (radii must stay under half a cell)."""
        i, j = int(math.floor(x / self.cell)), int(math.floor(z / self.cell))
        reach = 1 + int(2 * r // self.cell)
        for di in range(-reach, reach + 1):
            for dj in range(-reach, reach + 1):
                for a, b, c in self.grid.get((i + di, j + dj), ()):
                    if (x - a) ** 2 + (z - b) ** 2 <= (r + c) ** 2:
                        return False
        self.grid.setdefault((i, j), []).append((x, z, r))
        return True


class _Street:
    """The parameters of a street crossing: main street along z at x = xs, cross street along x at z = zs."""

    def __init__(self, rng: np.random.Generator, cam_height: float) -> None:
        self.gy = cam_height
        self.rw = rng.uniform(3.5, 9.0)  # half width of the main road
        self.cw = rng.uniform(3.5, 7.0)  # half width of the cross road
        self.sw = rng.uniform(1.8, 5.0)  # sidewalk width
        self.curb = rng.uniform(0.1, 0.18)
        self.xs = rng.uniform(-(self.rw + 0.7 * self.sw), self.rw + 0.7 * self.sw)
        self.zs = rng.uniform(-70.0, 70.0)
        self.zfar = rng.uniform(150.0, 250.0)
        self.xfar = rng.uniform(100.0, 160.0)
        self.district = ["residential", "downtown", "mixed"][rng.integers(3)]
        self.asphalt = pick_color(rng, _ASPHALT)
        self.pavement = pick_color(rng, PAVEMENT)
        self.view: PinholeView | None = None
        self.pending: list[tuple] = []  # blocks waiting for the visibility test


def make_street(rng: np.random.Generator, cam_height: float, clutter: float = 1.0,
                view: PinholeView | None = None, additions: Additions | None = None) -> Scene:
    """A street crossing in a city grid around a camera standing on the road or a sidewalk at the origin.

    Args:
        rng: random generator.
        cam_height: camera height above the road.
        clutter: amount of cars, trees, poles, people (0 for none, 1 normal, 2 busy).
        view: the camera, when known: blocks it cannot see are left out (they would be culled anyway).
        additions: hard cases (stairs, billboards) on the sidewalks, drawn from their own generator.

    Returns:
        The scene; ``boxes`` holds every building's main block (all aligned with the world axes).

    Example:
        >>> scene = make_street(np.random.default_rng(0), 1.6)
        >>> scene.kind, len(scene.items) > 20
        ('street', True)
    """
    st = _Street(rng, cam_height)
    st.view = view
    scene = Scene("street", st.gy)
    scene.ground_color = st.asphalt
    _street_ground(rng, st, scene)
    _street_buildings(rng, st, scene)
    _flush_buildings(st, scene)
    spots = Spots()
    spots.take(0.0, 0.0, 1.5)  # keep the camera free
    if clutter > 0:
        _street_clutter(rng, st, scene, clutter, spots)
    if additions is not None:
        _street_additions(additions, st, scene, spots)
    return scene


def _street_ground(rng: np.random.Generator, st: _Street, scene: Scene) -> None:
    gy, top = st.gy, st.gy - st.curb
    for sx in (1, -1):
        for sz in (1, -1):
            # a raised block (pavement) from the curbs outwards; buildings stand on it and hide most of it
            xa, xb = sorted((st.xs + sx * st.rw, sx * (st.xfar + 50)))
            za, zb = sorted((st.zs + sz * st.cw, sz * (st.zfar + 50)))
            block = ground_rects(xa, xb, za, zb, top)[0]
            scene.ground.append(Face(block, st.pavement, UP.copy(), _sidewalk_joints(rng, st, sx, sz, top)))
            # curbs, facing the roads
            xc, zc = st.xs + sx * st.rw, st.zs + sz * st.cw
            main = np.array([[xc, gy, za], [xc, gy, zb], [xc, top, zb], [xc, top, za]])
            cross = np.array([[xa, gy, zc], [xb, gy, zc], [xb, top, zc], [xa, top, zc]])
            scene.ground.append(Face(main, st.pavement * 0.85, np.array([-sx, 0.0, 0.0])))
            scene.ground.append(Face(cross, st.pavement * 0.85, np.array([0.0, 0.0, -sz])))
    scene.ground.append(Face(ground_rects(0, 1, 0, 1, gy)[0], None, UP.copy(), _road_markings(rng, st)))


def _sidewalk_joints(rng: np.random.Generator, st: _Street, sx: int, sz: int, y: float) -> list[Decal]:
    step = rng.uniform(1.2, 2.5)
    x_in = st.xs + sx * st.rw
    x_out = x_in + sx * st.sw
    z_lo, z_hi = sorted((st.zs + sz * st.cw, sz * min(st.zfar, 120.0)))
    zs = np.arange(z_lo, z_hi, step)
    segs = np.stack([np.stack([np.full_like(zs, x_in), np.full_like(zs, y), zs], -1),
                     np.stack([np.full_like(zs, x_out), np.full_like(zs, y), zs], -1)], 1)
    z_in = st.zs + sz * st.cw
    z_out = z_in + sz * st.sw
    x_lo, x_hi = sorted((x_out, sx * min(st.xfar, 100.0)))
    xs = np.arange(x_lo, x_hi, step)
    segs2 = np.stack([np.stack([xs, np.full_like(xs, y), np.full_like(xs, z_in)], -1),
                      np.stack([xs, np.full_like(xs, y), np.full_like(xs, z_out)], -1)], 1)
    edge = np.array([[[x_out, y, z_lo], [x_out, y, z_hi]], [[x_lo, y, z_out], [x_hi, y, z_out]]])
    return [Decal(np.concatenate([segs, segs2, edge]), st.pavement * 0.72, width=0.02)]


def _road_markings(rng: np.random.Generator, st: _Street) -> list[Decal]:
    y = st.gy
    paint = pick_color(rng, _PAINT[:1] if rng.random() < 0.6 else _PAINT)
    white = np.array([235.0, 235.0, 230.0])
    skip_z = (st.zs - st.cw - 6.0, st.zs + st.cw + 6.0)
    skip_x = (st.xs - st.rw - 6.0, st.xs + st.rw + 6.0)
    w = 0.14
    rects = []  # (x0, x1, z0, z1)
    d = _dashes(-st.zfar, st.zfar, 3.0, rng.uniform(4.0, 9.0), skip_z)
    rects.append(np.stack([np.full(len(d), st.xs - w), np.full(len(d), st.xs + w), d[:, 0], d[:, 1]], -1))
    d = _dashes(-st.xfar, st.xfar, 3.0, rng.uniform(4.0, 9.0), skip_x)
    rects.append(np.stack([d[:, 0], d[:, 1], np.full(len(d), st.zs - w), np.full(len(d), st.zs + w)], -1))
    center = np.concatenate(rects)
    out = [Decal(ground_rects(center[:, 0], center[:, 1], center[:, 2], center[:, 3], y), paint)]
    edges = []
    for s in (1, -1):
        x = st.xs + s * (st.rw - 0.35)
        for lo, hi in ((-st.zfar, skip_z[0]), (skip_z[1], st.zfar)):
            edges.append([x - 0.07, x + 0.07, lo, hi])
        z = st.zs + s * (st.cw - 0.35)
        for lo, hi in ((-st.xfar, skip_x[0]), (skip_x[1], st.xfar)):
            edges.append([lo, hi, z - 0.07, z + 0.07])
    # crosswalks: stripes across the main road on both sides of the crossing, and across the cross road
    for s in (1, -1):
        z0 = st.zs + s * (st.cw + 1.0)
        z1 = z0 + s * 3.0
        xs = np.arange(st.xs - st.rw + 0.4, st.xs + st.rw - 0.6, 1.0)
        edges += [[x, x + 0.5, min(z0, z1), max(z0, z1)] for x in xs]
        x0 = st.xs + s * (st.rw + 1.0)
        x1 = x0 + s * 3.0
        zz = np.arange(st.zs - st.cw + 0.4, st.zs + st.cw - 0.6, 1.0)
        edges += [[min(x0, x1), max(x0, x1), z, z + 0.5] for z in zz]
    e = np.array(edges)
    out.append(Decal(ground_rects(e[:, 0], e[:, 1], e[:, 2], e[:, 3], y), white))
    # manholes and patches: round and odd shapes on the asphalt
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    holes = []
    for z in rng.uniform(-80, 80, int(rng.integers(1, 5))):
        if skip_z[0] - 3 < z < skip_z[1] + 3:
            continue
        x = st.xs + rng.uniform(-st.rw + 1, st.rw - 1)
        holes.append(np.stack([x + 0.35 * np.cos(a), np.full_like(a, y), z + 0.35 * np.sin(a)], -1))
    if holes:
        out.append(Decal(np.array(holes), st.asphalt * 0.6))
    return out


def _lot_width(rng: np.random.Generator, st: _Street, along: float) -> float:
    """Frontage of a lot; far down the street lots get wider: they are a few pixels there, and each costs time."""
    w = rng.uniform(6, 16) if st.district == "residential" else rng.uniform(8, 28)
    return w * (1.0 + max(0.0, abs(along) - 60.0) / 60.0)


def _street_buildings(rng: np.random.Generator, st: _Street, scene: Scene) -> None:
    for sx in (1, -1):
        for sz in (1, -1):
            x_face = st.xs + sx * (st.rw + st.sw)
            z = st.zs + sz * (st.cw + st.sw)
            first = True
            corner_depth = corner_width = 0.0
            while abs(z) < st.zfar:
                width = _lot_width(rng, st, z)
                if first:
                    width = max(width, 14.0)
                setback = 0.0 if rng.random() < 0.65 or first else rng.uniform(0.5, 4.0)
                depth = rng.uniform(10, 25)
                cx = x_face + sx * (setback + depth / 2)
                cz = z + sz * width / 2
                fronts = (3 if sx > 0 else 1,) + (((0 if sz > 0 else 2),) if first else ())
                # the walls between neighbours and the back are blank (and mostly hidden)
                plain = tuple(k for k in range(4) if k not in fronts)
                _add_building(rng, scene, st, (cx, cz), (depth / 2, width / 2), fronts, plain)
                if first:
                    corner_depth, corner_width = setback + depth, width
                first = False
                z += sz * (width + (rng.uniform(1.0, 4.0) if rng.random() < 0.15 else 0.0))
            _cross_buildings(rng, st, scene, sx, sz, corner_depth, corner_width)


def _add_building(rng: np.random.Generator, scene: Scene, st: _Street, center, half, fronts, plain) -> None:
    """Queue a street block; :func:`_flush_buildings` makes the ones the camera can see."""
    st.pending.append((center, half, building_height(rng, st.district), int(rng.integers(2**31)), fronts, plain))


def _flush_buildings(st: _Street, scene: Scene) -> None:
    """Make the queued blocks, leaving out those the camera (when known) cannot see, all tested at once: a city
    has a hundred blocks, a photo a dozen."""
    if not st.pending:
        return
    c = np.array([p[0] for p in st.pending])
    h = np.array([p[1] for p in st.pending]) + 1.0  # room for cornices
    top = np.array([st.gy - p[2] - max(5.0, p[2]) for p in st.pending])  # a tower may rise above the block
    keep = np.ones(len(c), dtype=bool)
    if st.view is not None:
        sx = np.array([-1, 1, 1, -1, -1, 1, 1, -1])
        sz = np.array([-1, -1, 1, 1, -1, -1, 1, 1])
        prism = np.stack([c[:, :1] + sx * h[:, :1], np.where(np.arange(8) < 4, st.gy, top[:, None]),
                          c[:, 1:] + sz * h[:, 1:]], -1)  # (n, 8, 3)
        planes = st.view.world_frustum
        s = prism @ planes[:, :3].T + planes[:, 3]  # (n, 8, 5)
        keep = ~(s < 0).all(1).any(1)
    for k in np.flatnonzero(keep):
        center, half, height, seed, fronts, plain = st.pending[k]
        item, box = make_building(seed, center, half, 0.0, st.gy, height, st.district, fronts, plain)
        scene.items.append(item)
        scene.boxes.append(box)
    st.pending = []


def _cross_buildings(rng: np.random.Generator, st: _Street, scene: Scene, sx: int, sz: int, corner_depth: float,
                     corner_width: float) -> None:
    z_face = st.zs + sz * (st.cw + st.sw)
    x = st.xs + sx * (st.rw + st.sw + corner_depth)
    while abs(x) < st.xfar:
        width = _lot_width(rng, st, x)
        setback = 0.0 if rng.random() < 0.65 else rng.uniform(0.5, 3.0)
        # no deeper than the corner lot, so it never runs into the buildings of the main street behind it
        depth = min(rng.uniform(10, 25), corner_width - setback - 0.2)
        if depth < 4:
            break
        cx = x + sx * width / 2
        cz = z_face + sz * (setback + depth / 2)
        front = 0 if sz > 0 else 2
        plain = tuple(k for k in range(4) if k != front)
        _add_building(rng, scene, st, (cx, cz), (width / 2, depth / 2), (front,), plain)
        x += sx * width


def _street_clutter(rng: np.random.Generator, st: _Street, scene: Scene, clutter: float, spots: Spots) -> None:
    gy, top = st.gy, st.gy - st.curb
    reach = 80.0  # beyond, clutter is a few pixels
    free = spots.take

    def along(lo: float, hi: float, step: tuple[float, float]):
        p = lo + rng.uniform(0, step[1])
        while p < hi:
            yield p
            p += rng.uniform(*step) / clutter

    skip = (st.zs - st.cw - st.sw - 2, st.zs + st.cw + st.sw + 2)
    skip_x = (st.xs - st.rw - st.sw - 2, st.xs + st.rw + st.sw + 2)
    for s in (1, -1):
        # parked cars along the curbs of both roads
        if rng.random() < 0.85:
            for z in along(-reach, reach, (5.0, 14.0)):
                x = st.xs + s * (st.rw - 1.15)
                if not skip[0] < z < skip[1] and rng.random() < 0.75 and free(x, z, 2.4):
                    yaw = (0.0 if rng.random() < 0.5 else 180.0) + rng.normal(0, 1.5)
                    scene.items.append(make_car(rng, (x, z), yaw, gy))
            for x in along(-reach, reach, (5.0, 14.0)):
                z = st.zs + s * (st.cw - 1.15)
                if not skip_x[0] < x < skip_x[1] and rng.random() < 0.6 and free(x, z, 2.4):
                    scene.items.append(make_car(rng, (x, z), 90.0 + rng.normal(0, 1.5), gy))
        # trees, lamps, people, bins on the sidewalks
        x_tree = st.xs + s * (st.rw + 0.9)
        if rng.random() < 0.5:
            for z in along(-reach, reach, (6.0, 14.0)):
                if not skip[0] < z < skip[1] and free(x_tree, z, 0.8):
                    scene.items.append(make_tree(rng, (x_tree, z), top))
        for z in along(-reach, reach, (14.0, 30.0)):
            x = st.xs + s * (st.rw + 0.4)
            if free(x, z, 0.5):
                scene.items.append(make_pole(rng, (x, z), top, 90.0 * -s))
        for z in along(-reach / 2, reach / 2, (3.0, 12.0)):
            x = st.xs + s * (st.rw + rng.uniform(0.8, max(0.9, st.sw - 0.5)))
            if free(x, z, 0.5):
                kind = rng.choice(3, p=[0.6, 0.2, 0.2])
                maker = [make_person, make_bollard, make_bush][kind]
                scene.items.append(maker(rng, (x, z), top))
        if rng.random() < 0.3:
            z = rng.uniform(-30, 30)
            x = st.xs + s * (st.rw + st.sw - 0.6)
            if free(x, z, 1.3):
                scene.items.append(make_bench(rng, (x, z), 180.0 if s > 0 else 0.0, top))
    _street_traffic(rng, st, scene, clutter, free)


def _street_traffic(rng: np.random.Generator, st: _Street, scene: Scene, clutter: float, free) -> None:
    """People crossing, cars driving and wires across the street (after the parked clutter: same random draws)."""
    gy = st.gy
    for _ in range(rng.poisson(2.0 * clutter)):
        x, z = st.xs + rng.uniform(-st.rw, st.rw), rng.uniform(-60, 60)
        if free(x, z, 0.5):
            scene.items.append(make_person(rng, (x, z), gy))
    for _ in range(rng.poisson(1.5 * clutter)):
        x, z = st.xs + rng.choice([-1, 1]) * st.rw * rng.uniform(0.2, 0.5), rng.uniform(-80, 80)
        if free(x, z, 2.6):
            scene.items.append(make_car(rng, (x, z), rng.normal(0, 2.0), gy))
    if rng.random() < 0.4 * clutter:  # wires across the street
        for z in rng.uniform(-40, 60, int(rng.integers(1, 4))):
            y = gy - rng.uniform(5.0, 8.0)
            a = np.array([st.xs - st.rw - st.sw + 0.3, y, z])
            b = np.array([st.xs + st.rw + st.sw - 0.3, y + rng.uniform(-1, 1), z + rng.uniform(-3, 3)])
            scene.overlay.append(wire(a, b, rng.uniform(0.3, 1.5)))


def _street_additions(add: Additions, st: _Street, scene: Scene, spots: Spots) -> None:
    """Stairs along the facades and billboards turned off the axes, on the sidewalks, within 60 m."""
    rng, top = add.rng, st.gy - st.curb
    skip = (st.zs - st.cw - st.sw - 1, st.zs + st.cw + st.sw + 1)
    for _ in range(rng.poisson(add.stairs)):
        s, z = rng.choice([-1, 1]), rng.uniform(-60, 60)
        width = min(rng.uniform(1.0, 2.2), st.sw - 0.4)
        length = rng.uniform(3.0, 7.0)
        x = st.xs + s * (st.rw + st.sw - 0.5 * width - 0.05)
        if width > 0.8 and not skip[0] < z < skip[1] and spots.take(x, z, 0.5 * length + 0.2):
            scene.items.append(make_stairs(rng, (x, z), 0.0, top, length, width))
    for _ in range(rng.poisson(add.billboards)):
        s, z = rng.choice([-1, 1]), rng.uniform(-50, 50)
        turn = rng.choice([-1, 1]) * rng.uniform(15.0, 75.0)  # from the street's axis z
        width = min(rng.uniform(2.5, 7.0), (st.sw - 0.4) / math.sin(math.radians(abs(turn))))
        x = st.xs + s * (st.rw + 0.5 * st.sw)
        if width > 1.2 and not skip[0] < z < skip[1] and spots.take(x, z, 0.5 * width + 0.2):
            scene.items.append(make_billboard(rng, (x, z), turn + 90.0, top, width))
