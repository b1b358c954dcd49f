"""Indoor rooms for the renderer: a box room seen from inside (walls with doors, windows, pictures, skirting;
tiled, planked or carpeted floors with rugs; ceilings with lights) and furniture (shelves with books, cabinets,
wardrobes, tables, chairs, beds, sofas, plants).

The room is axis-aligned with the world (its walls carry the ground-truth Manhattan frame); chairs, rugs and
some tables are turned by a random yaw, as clutter.
"""

from __future__ import annotations

import math

import numpy as np

from ngp_kornia.training.synth.clutter import blob, hexahedron_faces
from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.scene import UP, Decal, Face, Item, Scene, Wall, box_walls, rect_corners, yaw_axes

__all__ = ["make_room"]

_WALL = [(235, 230, 220), (225, 215, 195), (210, 220, 225), (240, 240, 240), (200, 190, 170), (215, 200, 185),
         (190, 205, 195), (230, 210, 200)]
_FLOOR = {"tiles": [(200, 195, 185), (170, 165, 160), (220, 220, 215), (140, 120, 100)],
          "planks": [(160, 115, 75), (185, 145, 100), (130, 90, 60), (200, 170, 130)],
          "carpet": [(120, 110, 100), (90, 95, 110), (150, 140, 125), (110, 70, 60)]}
_WOOD = [(160, 115, 75), (120, 85, 55), (200, 170, 130), (90, 65, 45), (235, 235, 230), (60, 60, 60)]
_FABRIC = [(140, 40, 40), (40, 60, 110), (90, 90, 90), (180, 160, 120), (60, 100, 70), (200, 200, 195)]
_BOOKS = [(150, 30, 30), (30, 50, 120), (30, 100, 60), (200, 180, 60), (230, 230, 220), (40, 40, 40),
          (180, 90, 40), (100, 60, 120)]


def _pick(rng: np.random.Generator, colors, jitter: float = 8.0) -> np.ndarray:
    c = np.asarray(colors[rng.integers(len(colors))], dtype=np.float64)
    return np.clip(c + rng.normal(0.0, jitter, 3), 0, 255)


def _inside(wall: Wall) -> Wall:
    """The same rectangle seen from the other side (a room wall seen from inside)."""
    return Wall(wall.o + wall.width * wall.u, -wall.u, wall.width, wall.height)


def _rects(wall: Wall, r) -> np.ndarray:
    return rect_corners(wall.o, wall.u, UP, np.asarray(r, dtype=np.float64).reshape(-1, 4))


def _outline(wall: Wall, r: np.ndarray) -> np.ndarray:
    """(4m, 2, 3) segments along the borders of (m, 4) rectangles on a wall."""
    c = _rects(wall, r)
    return np.stack([c, np.roll(c, -1, axis=1)], 2).reshape(-1, 2, 3)


class _Slots:
    """Free intervals along a wall, to place doors, windows and furniture without overlaps."""

    def __init__(self, width: float) -> None:
        self.width = width
        self.used: list[tuple[float, float, str]] = []

    def take(self, rng: np.random.Generator, w: float, tag: str, margin: float = 0.15) -> float | None:
        for _ in range(8):
            s = rng.uniform(margin, self.width - w - margin) if self.width - w - 2 * margin > 0 else None
            if s is None:
                return None
            if all(s + w + margin <= a or s >= b + margin for a, b, _ in self.used):
                self.used.append((s, s + w, tag))
                return s
        return None


def _door(wall: Wall, rng: np.random.Generator, s: float, trim: np.ndarray) -> list[Decal]:
    dw, dh = rng.uniform(0.8, 1.0), rng.uniform(2.0, 2.2)
    leaf = _pick(rng, _WOOD)
    out = [Decal(_rects(wall, [s - 0.08, 0.0, s + dw + 0.08, dh + 0.08]), trim)]
    if rng.random() < 0.25:  # an open doorway onto a dark corridor
        out.append(Decal(_rects(wall, [s, 0.0, s + dw, dh]), np.array([50.0, 45.0, 40.0])))
        return out
    out.append(Decal(_rects(wall, [s, 0.0, s + dw, dh]), leaf))
    panels = np.array([[s + 0.12, 0.15, s + dw - 0.12, 0.95], [s + 0.12, 1.1, s + dw - 0.12, dh - 0.15]])
    out.append(Decal(_outline(wall, panels), leaf * 0.7, width=0.015))
    a = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    knob = np.stack([s + dw - 0.1 + 0.03 * np.cos(a), 1.0 + 0.03 * np.sin(a)], -1)
    out.append(Decal((wall.o + knob[:, :1] * wall.u + knob[:, 1:] * UP)[None], np.array([190.0, 170.0, 90.0])))
    return out


def _window(wall: Wall, rng: np.random.Generator, s: float, w: float, trim: np.ndarray, sky: np.ndarray):
    t0, t1 = rng.uniform(0.8, 1.0), min(wall.height - 0.25, rng.uniform(2.0, 2.4))
    out = [Decal(_rects(wall, [s - 0.08, t0 - 0.08, s + w + 0.08, t1 + 0.08]), trim),
           Decal(_rects(wall, [s, t0, s + w, t1]), sky, emissive=True)]
    cross = [[[s + w / 2, t0], [s + w / 2, t1]], [[s, t0 + 0.6 * (t1 - t0)], [s + w, t0 + 0.6 * (t1 - t0)]]]
    cross = np.array(cross)
    out.append(Decal(wall.o + cross[..., :1] * wall.u + cross[..., 1:] * UP, trim, width=0.05))
    out.append(Decal(_rects(wall, [s - 0.15, t0 - 0.12, s + w + 0.15, t0 - 0.06]), trim * 0.95))
    if rng.random() < 0.5:  # curtains
        cw = rng.uniform(0.2, 0.4)
        cloth = _pick(rng, _FABRIC)
        out.append(Decal(_rects(wall, [[s - cw, t0 - 0.3, s + 0.05, t1 + 0.15],
                                       [s + w - 0.05, t0 - 0.3, s + w + cw, t1 + 0.15]]), cloth))
    return out


def _picture(wall: Wall, rng: np.random.Generator, s: float, w: float) -> list[Decal]:
    h = w * rng.uniform(0.6, 1.3)
    t0 = rng.uniform(1.3, 1.6)
    frame = _pick(rng, _WOOD)
    out = [Decal(_rects(wall, [s, t0, s + w, t0 + h]), frame),
           Decal(_rects(wall, [s + 0.05, t0 + 0.05, s + w - 0.05, t0 + h - 0.05]), _pick(rng, _FABRIC, 40.0))]
    if rng.random() < 0.5:  # something on the picture: a sun or a horizon
        a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        r = 0.15 * min(w, h)
        spot = np.stack([s + w * 0.6 + r * np.cos(a), t0 + h * 0.6 + r * np.sin(a)], -1)
        out.append(Decal((wall.o + spot[:, :1] * wall.u + spot[:, 1:] * UP)[None], _pick(rng, _BOOKS, 30.0)))
    return out


def _wall_decals(wall: Wall, rng: np.random.Generator, slots: _Slots, trim: np.ndarray, sky: np.ndarray,
                 doors: int) -> list[Decal]:
    out = [Decal(_rects(wall, [0.0, 0.0, wall.width, 0.1]), trim)]
    if rng.random() < 0.4:
        out.append(Decal(_rects(wall, [0.0, wall.height - 0.08, wall.width, wall.height]), trim))
    for _ in range(doors):
        s = slots.take(rng, 1.15, "door")
        if s is not None:
            out += _door(wall, rng, s + 0.08, trim)
    for _ in range(rng.integers(0, 3)):
        w = rng.uniform(0.8, 2.0)
        s = slots.take(rng, w + 0.5, "window")
        if s is not None:
            out += _window(wall, rng, s + 0.25, w, trim, sky)
    for _ in range(rng.integers(1, 4)):
        w = rng.uniform(0.3, 1.0)
        s = slots.take(rng, w, "picture")
        if s is not None:
            out += _picture(wall, rng, s, w)
    if rng.random() < 0.6:
        s = rng.uniform(0.2, max(0.3, wall.width - 0.3))
        plate = [[s, 0.3, s + 0.08, 0.4], [s + 0.5, 1.05, s + 0.58, 1.17]]
        out.append(Decal(_rects(wall, plate), np.array([235.0, 235.0, 230.0])))
    return out


def _floor_decals(rng: np.random.Generator, x0, x1, z0, z1, y, kind: str, color: np.ndarray) -> list[Decal]:
    out: list[Decal] = []
    if kind == "tiles":
        step = rng.uniform(0.3, 0.8)
        xs = np.arange(x0 + rng.uniform(0, step), x1, step)
        zs = np.arange(z0 + rng.uniform(0, step), z1, step)
        segs = [[[x, y, z0], [x, y, z1]] for x in xs] + [[[x0, y, z], [x1, y, z]] for z in zs]
        out.append(Decal(np.array(segs), color * 0.75, width=0.012))
    elif kind == "planks":
        step = rng.uniform(0.1, 0.22)
        along_x = rng.random() < 0.5
        lo, hi, a0, a1 = (z0, z1, x0, x1) if along_x else (x0, x1, z0, z1)
        rows = np.arange(lo + step, hi, step)
        segs = []
        for k, r in enumerate(rows):
            segs.append([a0, r, a1, r])
            joints = np.arange(a0 + rng.uniform(0.2, 1.2), a1, rng.uniform(0.9, 1.8))
            segs += [[j, r - step, j, r] for j in joints] if k % 2 else [[j, r, j, r + step] for j in joints]
        segs = np.array(segs)
        if along_x:
            pts = np.stack([np.stack([segs[:, 0], np.full(len(segs), y), segs[:, 1]], -1),
                            np.stack([segs[:, 2], np.full(len(segs), y), segs[:, 3]], -1)], 1)
        else:
            pts = np.stack([np.stack([segs[:, 1], np.full(len(segs), y), segs[:, 0]], -1),
                            np.stack([segs[:, 3], np.full(len(segs), y), segs[:, 2]], -1)], 1)
        out.append(Decal(pts, color * 0.7, width=0.008))
    return out


def _rug(rng: np.random.Generator, center, y: float) -> list[Decal]:
    half = (rng.uniform(0.6, 1.4), rng.uniform(0.8, 1.8))
    yaw = rng.uniform(-30, 30) if rng.random() < 0.5 else 0.0
    ax, az = yaw_axes(yaw)
    c = np.array([center[0], y, center[1]])

    def quad(hx, hz):
        return np.array([[c - hx * ax - hz * az, c + hx * ax - hz * az, c + hx * ax + hz * az, c - hx * ax + hz * az]])

    color = _pick(rng, _FABRIC, 20.0)
    return [Decal(quad(*half), color), Decal(quad(half[0] - 0.15, half[1] - 0.15), color * 0.75 + 40)]


def _ceiling_decals(rng: np.random.Generator, x0, x1, z0, z1, y) -> list[Decal]:
    out: list[Decal] = []
    light = np.array([250.0, 248.0, 240.0])
    cx, cz = 0.5 * (x0 + x1), 0.5 * (z0 + z1)
    if rng.random() < 0.35:  # office ceiling: a grid of tiles with light panels
        step = 0.6
        xs = np.arange(x0 + step, x1, step)
        zs = np.arange(z0 + step, z1, step)
        segs = [[[x, y, z0], [x, y, z1]] for x in xs] + [[[x0, y, z], [x1, y, z]] for z in zs]
        out.append(Decal(np.array(segs), np.array([170.0, 170.0, 165.0]), width=0.015))
        if len(xs) > 2 and len(zs) > 2:
            i = rng.choice(len(xs) - 1, size=min(3, len(xs) - 1), replace=False)
            j = rng.choice(len(zs) - 1, size=min(2, len(zs) - 1), replace=False)
            panels = [[[xs[a], y, zs[b]], [xs[a + 1], y, zs[b]], [xs[a + 1], y, zs[b + 1]], [xs[a], y, zs[b + 1]]]
                      for a in i for b in j]
            out.append(Decal(np.array(panels) + [0.0, 0.0, 0.0], light, emissive=True))
    else:
        a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        r = rng.uniform(0.15, 0.35)
        lamp = np.stack([cx + r * np.cos(a), np.full_like(a, y), cz + r * np.sin(a)], -1)
        out.append(Decal(lamp[None], light, emissive=True))
    return out


def _box(center, half, yaw, y_bottom, height, color, top=None) -> list[Face]:
    ax, az = yaw_axes(yaw)
    c = np.array([center[0], y_bottom, center[1]])
    base = np.array([c - half[0] * ax - half[1] * az, c + half[0] * ax - half[1] * az,
                     c + half[0] * ax + half[1] * az, c - half[0] * ax + half[1] * az])
    return hexahedron_faces(base, base - height * np.array([0.0, 1.0, 0.0]), color, top)


def _front_wall(center, half, yaw, ground_y, height, side: int) -> Wall:
    return box_walls(np.asarray(center), half, ground_y, ground_y - height, yaw)[side]


def _bookshelf(rng, center, half, side, ground_y, height) -> list[Face]:
    color = _pick(rng, _WOOD)
    faces = _box(center, half, 0.0, ground_y, height, color)
    wall = _front_wall(center, half, 0.0, ground_y, height, side)
    n = int(rng.integers(3, 7))
    pitch = (height - 0.1) / n
    boards = np.array([[0.0, k * pitch, wall.width, k * pitch + 0.04] for k in range(n + 1)])
    sides = np.array([[0.0, 0.0, 0.04, height], [wall.width - 0.04, 0.0, wall.width, height]])
    back = color * 0.55
    inner = np.array([[0.04, k * pitch + 0.04, wall.width - 0.04, (k + 1) * pitch] for k in range(n)])
    decals = [Decal(_rects(wall, inner), back), Decal(_rects(wall, np.concatenate([boards, sides])), color)]
    books = []
    for k in range(n):
        s = 0.05 + rng.uniform(0, 0.2)
        while s < wall.width - 0.1:
            bw = rng.uniform(0.02, 0.06)
            books.append([s, k * pitch + 0.04, s + bw, k * pitch + 0.04 + rng.uniform(0.5, 0.92) * (pitch - 0.04)])
            s += bw + (rng.uniform(0.1, 0.5) if rng.random() < 0.08 else 0.003)
    if books:
        books = np.array(books)
        groups = rng.integers(len(_BOOKS), size=len(books))
        for g in np.unique(groups):
            decals.append(Decal(_rects(wall, books[groups == g]), _pick(rng, _BOOKS, 20.0)))
    faces[side].decals += decals
    return faces


def _cabinet(rng, center, half, side, ground_y, height) -> list[Face]:
    color = _pick(rng, _WOOD)
    faces = _box(center, half, 0.0, ground_y, height, color)
    wall = _front_wall(center, half, 0.0, ground_y, height, side)
    w = wall.width
    if height > 1.5:  # wardrobe: two doors
        lines = np.array([[[w / 2, 0.05], [w / 2, height - 0.05]]])
        handles = np.array([[w / 2 - 0.08, 0.9, w / 2 - 0.05, 1.2], [w / 2 + 0.05, 0.9, w / 2 + 0.08, 1.2]])
    else:
        n = int(rng.integers(2, 5))
        ts = np.linspace(0.08, height - 0.04, n + 1)
        lines = np.array([[[0.03, t], [w - 0.03, t]] for t in ts] + [[[0.03, ts[0]], [0.03, ts[-1]]],
                                                                       [[w - 0.03, ts[0]], [w - 0.03, ts[-1]]]])
        mid = 0.5 * (ts[:-1] + ts[1:])
        handles = np.stack([np.full(n, w / 2 - 0.1), mid - 0.015, np.full(n, w / 2 + 0.1), mid + 0.015], -1)
    pts = wall.o + lines[..., :1] * wall.u + lines[..., 1:] * UP
    faces[side].decals += [Decal(pts, color * 0.6, width=0.012), Decal(_rects(wall, handles), np.full(3, 180.0))]
    return faces


def _table(center, half, yaw, ground_y, view: PinholeView, height, color) -> list[Face]:
    """Four legs, far ones first, then the top (the camera is above it)."""
    ax, az = yaw_axes(yaw)
    legs = []
    for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        c = np.asarray(center) + (sx * (half[0] - 0.05) * ax + sz * (half[1] - 0.05) * az)[[0, 2]]
        legs.append((np.linalg.norm(c - view.center[[0, 2]]), _box(c, (0.03, 0.03), yaw, ground_y, height - 0.04,
                                                                     color * 0.8)[:4]))
    faces = [f for _, fs in sorted(legs, key=lambda t: -t[0]) for f in fs]
    return faces + _box(center, half, yaw, ground_y - height + 0.04, 0.04, color)


def _chair(rng, center, yaw, ground_y, view: PinholeView) -> list[Face]:
    color = _pick(rng, _WOOD + _FABRIC)
    faces = _table(center, (0.22, 0.22), yaw, ground_y, view, 0.46, color)
    ax, az = yaw_axes(yaw)
    back_c = np.asarray(center) - 0.2 * az[[0, 2]]
    return faces + _box(back_c, (0.22, 0.025), yaw, ground_y - 0.46, rng.uniform(0.4, 0.5), color)


def make_room(rng: np.random.Generator, cam_height: float, clutter: float = 1.0,
              view_yaw: float | None = None) -> Scene:
    """A furnished room around a camera at the origin, ``cam_height`` above the floor.

    Args:
        rng: random generator.
        cam_height: camera height above the floor (metres).
        clutter: amount of furniture, 0 for an empty room, 1 normal, 2 crowded.
        view_yaw: the camera's heading (degrees); when given, the camera stands in the back part of the room, as
            photographers do, rather than facing a wall at arm's length.

    Returns:
        The scene; its ``boxes`` hold the room and the axis-aligned furniture.

    Example:
        >>> scene = make_room(np.random.default_rng(0), 1.5)
        >>> scene.kind, len(scene.shell)
        ('indoor', 6)
    """
    room_h = max(rng.uniform(2.4, 3.4), cam_height + 0.5)
    sx, sz = rng.uniform(3.5, 9.0), rng.uniform(3.5, 11.0)
    fx, fz = (0.0, 0.0) if view_yaw is None else (math.sin(math.radians(view_yaw)), math.cos(math.radians(view_yaw)))
    # where the camera stands across the room, 0 at the low wall: behind the middle along the view direction
    ax = 0.5 - 0.35 * fx + rng.uniform(-0.15, 0.15)
    az = 0.5 - 0.35 * fz + rng.uniform(-0.15, 0.15)
    x0 = -min(max(ax * sx, 0.7), sx - 0.7)
    z0 = -min(max(az * sz, 0.7), sz - 0.7)
    x1, z1 = x0 + sx, z0 + sz
    gy, cy = cam_height, cam_height - room_h
    wall_color = _pick(rng, _WALL)
    trim = _pick(rng, [(245, 245, 240), (230, 225, 215), (120, 90, 60), (200, 200, 200)])
    floor_kind = ["tiles", "planks", "carpet"][rng.choice(3, p=[0.35, 0.45, 0.2])]
    floor_color = _pick(rng, _FLOOR[floor_kind])
    sky = _pick(rng, [(215, 230, 245), (235, 240, 245), (190, 210, 235)])
    center, half = np.array([(x0 + x1) / 2, (z0 + z1) / 2]), (sx / 2, sz / 2)
    walls = [_inside(w) for w in box_walls(center, half, gy, cy, 0.0)]
    slots = [_Slots(w.width) for w in walls]
    n_doors = rng.multinomial(int(rng.integers(1, 3)), [0.25] * 4)
    scene = Scene("indoor", gy)
    scene.boxes.append((np.array([x0, cy, z0]), np.array([x1, gy, z1])))
    floor = np.array([[x0, gy, z0], [x1, gy, z0], [x1, gy, z1], [x0, gy, z1]])
    floor_face = Face(floor, floor_color, UP.copy(), _floor_decals(rng, x0, x1, z0, z1, gy, floor_kind, floor_color))
    if rng.random() < 0.45:
        floor_face.decals += _rug(rng, (rng.uniform(x0 + 1.5, x1 - 1.5), rng.uniform(z0 + 1.5, z1 - 1.5)), gy)
    ceiling = Face(floor[::-1] + [0.0, cy - gy, 0.0], _pick(rng, [(245, 245, 245), (235, 232, 225)]),
                   np.array([0.0, 1.0, 0.0]), _ceiling_decals(rng, x0, x1, z0, z1, cy))
    scene.shell = [floor_face, ceiling]
    for k, w in enumerate(walls):
        tone = wall_color * rng.uniform(0.95, 1.05)
        scene.shell.append(Face(w.corners(), tone, w.normal, _wall_decals(w, rng, slots[k], trim, sky, n_doors[k])))
    # furniture stands in front of windows and pictures (it is drawn after the walls), but not of doors
    floor_slots = [_Slots(w.width) for w in walls]
    for fs, ws in zip(floor_slots, slots, strict=True):
        fs.used = [u for u in ws.used if u[2] == "door"]
    _furnish(rng, scene, walls, floor_slots, (x0, x1, z0, z1), gy, clutter)
    return scene


def _furnish(rng, scene: Scene, walls, slots, bounds, gy: float, clutter: float) -> None:
    x0, x1, z0, z1 = bounds
    taken: list[np.ndarray] = [np.array([-0.7, -0.7, 0.7, 0.7])]  # keep the camera free

    def free(r: np.ndarray) -> bool:
        ok = r[0] > x0 - 1e-9 and r[2] < x1 + 1e-9 and r[1] > z0 - 1e-9 and r[3] < z1 + 1e-9
        return ok and all(r[0] >= t[2] or r[2] <= t[0] or r[1] >= t[3] or r[3] <= t[1] for t in taken)

    n = int(rng.poisson(7.0 * clutter))
    for _ in range(n):
        kind = rng.choice(["shelf", "cabinet", "wardrobe", "table", "sofa", "bed", "plant", "chair"],
                          p=[0.2, 0.2, 0.08, 0.14, 0.1, 0.08, 0.1, 0.1])
        if kind in ("table", "chair", "plant"):
            _free_standing(rng, scene, kind, bounds, gy, free, taken)
            continue
        k = int(rng.integers(4))
        wall = walls[k]
        w = {"shelf": rng.uniform(0.8, 2.0), "cabinet": rng.uniform(0.6, 1.8), "wardrobe": rng.uniform(1.0, 2.0),
             "sofa": rng.uniform(1.6, 2.4), "bed": rng.uniform(1.0, 1.8)}[kind]
        depth = {"shelf": rng.uniform(0.28, 0.4), "cabinet": rng.uniform(0.4, 0.6), "wardrobe": 0.6,
                 "sofa": 0.9, "bed": 2.0}[kind]
        s = slots[k].take(rng, w, kind, margin=0.05)
        if s is None:
            continue
        # footprint: along the wall from s to s + w, from the wall inwards by depth
        a = wall.o + s * wall.u
        b = a + w * wall.u
        # the room's walls face inwards: their normal points into the room
        pts = np.array([a, b, a + depth * wall.normal, b + depth * wall.normal])[:, [0, 2]]
        r = np.array([pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()])
        if not free(r):
            slots[k].used.pop()
            continue
        taken.append(r)
        _place(rng, scene, kind, r, k, gy)


def _place(rng, scene: Scene, kind: str, r: np.ndarray, wall_k: int, gy: float) -> None:
    # the furniture's front faces the room: the side opposite to its wall (room walls 0..3 are the -z, +x, +z
    # and -x sides of the room, and box walls 0..3 face -z', +x', +z', -x')
    front = {0: 2, 1: 3, 2: 0, 3: 1}[wall_k]
    if kind in ("sofa", "bed"):  # a back or headboard against the wall, as its own item
        t = 0.12
        back = r.copy()
        if wall_k == 0:
            back[3], r = r[1] + t, np.array([r[0], r[1] + t, r[2], r[3]])
        elif wall_k == 1:
            back[0], r = r[2] - t, np.array([r[0], r[1], r[2] - t, r[3]])
        elif wall_k == 2:
            back[1], r = r[3] - t, np.array([r[0], r[1], r[2], r[3] - t])
        else:
            back[2], r = r[0] + t, np.array([r[0] + t, r[1], r[2], r[3]])
        _add_box_item(scene, back, gy, rng.uniform(0.8, 1.1), _pick(rng, _WOOD + _FABRIC))
    center = np.array([(r[0] + r[2]) / 2, (r[1] + r[3]) / 2])
    half = ((r[2] - r[0]) / 2, (r[3] - r[1]) / 2)
    height = {"shelf": rng.uniform(1.4, 2.2), "cabinet": rng.uniform(0.7, 1.2), "wardrobe": rng.uniform(1.9, 2.3),
              "sofa": 0.48, "bed": 0.48}[kind]
    seed = int(rng.integers(2**31))

    def build(view: PinholeView) -> list[Face]:
        drng = np.random.default_rng(seed)
        if kind == "shelf":
            return _bookshelf(drng, center, half, front, gy, height)
        if kind in ("cabinet", "wardrobe"):
            faces = _cabinet(drng, center, half, front, gy, height)
            if kind == "cabinet" and drng.random() < 0.5:  # something standing on it
                thing = _box(center, (0.12, 0.12), 0.0, gy - height, drng.uniform(0.15, 0.4), _pick(drng, _BOOKS))
                faces = faces + thing if view.center[1] < gy - height else thing + faces
            return faces
        fabric = _pick(drng, _FABRIC)
        faces = _box(center, half, 0.0, gy, 0.28, _pick(drng, _WOOD))
        return faces + _box(center, (half[0] - 0.04, half[1] - 0.04), 0.0, gy - 0.28, 0.2, fabric,
                            fabric * 1.1 if kind == "sofa" else np.array([235.0, 235.0, 230.0]))

    scene.items.append(Item(_rect_fp(r), gy - height - 0.5, gy, build, "furniture"))
    if kind in ("shelf", "cabinet", "wardrobe"):
        scene.boxes.append((np.array([r[0], gy - height, r[1]]), np.array([r[2], gy, r[3]])))


def _rect_fp(r: np.ndarray) -> np.ndarray:
    return np.array([[r[0], r[1]], [r[2], r[1]], [r[2], r[3]], [r[0], r[3]]])


def _add_box_item(scene: Scene, r: np.ndarray, gy: float, height: float, color: np.ndarray) -> None:
    center = np.array([(r[0] + r[2]) / 2, (r[1] + r[3]) / 2])
    half = ((r[2] - r[0]) / 2, (r[3] - r[1]) / 2)
    scene.items.append(Item(_rect_fp(r), gy - height, gy, lambda view: _box(center, half, 0.0, gy, height, color),
                            "furniture"))
    scene.boxes.append((np.array([r[0], gy - height, r[1]]), np.array([r[2], gy, r[3]])))


def _free_standing(rng, scene: Scene, kind: str, bounds, gy: float, free, taken) -> None:
    x0, x1, z0, z1 = bounds
    half = {"table": (rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.9)), "chair": (0.25, 0.25),
            "plant": (0.2, 0.2)}[kind]
    yaw = 0.0 if kind != "chair" and rng.random() < 0.7 else rng.uniform(-45, 45)
    reach = float(np.hypot(*half))
    c = np.array([rng.uniform(x0 + reach, x1 - reach), rng.uniform(z0 + reach, z1 - reach)]) \
        if x1 - x0 > 2 * reach and z1 - z0 > 2 * reach else None
    if c is None:
        return
    r = np.array([c[0] - reach, c[1] - reach, c[0] + reach, c[1] + reach])
    if not free(r):
        return
    taken.append(r)
    seed = int(rng.integers(2**31))
    ax, az = yaw_axes(yaw)
    a, b = ax[[0, 2]] * half[0], az[[0, 2]] * half[1]
    fp = np.array([c - a - b, c + a - b, c + a + b, c - a + b])
    height = {"table": rng.uniform(0.7, 0.78), "chair": 1.0, "plant": rng.uniform(0.8, 1.6)}[kind]

    def build(view: PinholeView) -> list[Face]:
        drng = np.random.default_rng(seed)
        if kind == "table":
            return _table(c, half, yaw, gy, view, height, _pick(drng, _WOOD))
        if kind == "chair":
            return _chair(drng, c, yaw, gy, view)
        pot = _box(c, (0.15, 0.15), yaw, gy, 0.3, _pick(drng, [(170, 90, 60), (220, 220, 215), (60, 60, 60)]))
        e1, e2 = view.R[0], view.R[1]
        crown = np.array([c[0], gy - 0.3 - 0.5 * (height - 0.3), c[1]])
        leaves = _pick(drng, [(60, 110, 50), (40, 90, 40), (90, 130, 60)])
        return pot + [Face(blob(crown, 0.5 * (height - 0.3), e1, e2, drng, rough=0.2), leaves, None)]

    scene.items.append(Item(fp, gy - height, gy, build, {"table": "furniture"}.get(kind, kind)))
