"""Street furniture and other clutter for the renderer: cars, trees, bushes, poles and lamps, signs, people,
benches, bins, hanging wires. Most of it breaks the Manhattan assumption on purpose (blobs, curves, tilted poles,
turned objects), as real photos do.
"""

from __future__ import annotations

import math

import numpy as np

from ngp_kornia.training.synth.facade import rotated_rect
from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.scene import UP, Decal, Face, Item, box_walls, rect_corners, yaw_axes

__all__ = [
    "blob",
    "hexahedron_faces",
    "make_bench",
    "make_bollard",
    "make_bush",
    "make_car",
    "make_person",
    "make_pole",
    "make_tree",
    "wire",
]

_CAR = [(200, 200, 205), (30, 30, 35), (150, 20, 25), (20, 50, 120), (120, 125, 130), (230, 230, 230),
        (60, 90, 60), (200, 160, 40), (90, 60, 40)]
_CAR_GLASS = [(30, 38, 48), (50, 60, 72), (70, 85, 100)]
_FOLIAGE = [(55, 85, 40), (70, 100, 45), (45, 70, 40), (85, 110, 55), (60, 80, 35)]
_BARK = [(80, 65, 50), (95, 80, 65), (60, 50, 40)]
_METAL = [(60, 65, 70), (40, 45, 45), (110, 115, 120), (30, 60, 45)]
_CLOTHES = [(30, 30, 40), (200, 200, 200), (150, 30, 30), (40, 60, 120), (90, 90, 90), (120, 90, 60),
            (230, 180, 50), (60, 110, 70)]
_SKIN = [(230, 190, 160), (200, 150, 110), (140, 95, 65), (90, 60, 40)]


def _pick(rng: np.random.Generator, colors, jitter: float = 8.0) -> np.ndarray:
    c = np.asarray(colors[rng.integers(len(colors))], dtype=np.float64)
    return np.clip(c + rng.normal(0.0, jitter, 3), 0, 255)


def _outward(face: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Unit normal of a planar quad (from its diagonals), oriented away from the point ``inside``."""
    d1, d2 = face[2] - face[0], face[3] - face[1]
    n = np.array([d1[1] * d2[2] - d1[2] * d2[1], d1[2] * d2[0] - d1[0] * d2[2], d1[0] * d2[1] - d1[1] * d2[0]])
    n /= max(float(np.sqrt(n @ n)), 1e-12)
    return -n if float(n @ (face[0] - inside)) < 0 else n


def hexahedron_faces(bottom: np.ndarray, top: np.ndarray, color, top_color=None) -> list[Face]:
    """Side and top faces of a convex hexahedron (a box that may taper or lean) with outward normals.

    Args:
        bottom: (4, 3) base corners, in order around the base.
        top: (4, 3) top corners, ``top[i]`` above ``bottom[i]``.
        color: RGB colour of the sides.
        top_color: RGB colour of the top (``color`` when None).

    Returns:
        Four side faces then the top; the base is never seen from above the ground.

    Example:
        >>> b = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]])
        >>> faces = hexahedron_faces(b, b - [0, 1, 0], (255, 0, 0))
        >>> [f.normal.round(3).tolist() for f in faces][-1]
        [0.0, -1.0, 0.0]
    """
    color = np.asarray(color, dtype=np.float64)
    top_color = color if top_color is None else np.asarray(top_color, dtype=np.float64)
    inside = 0.5 * (bottom.mean(0) + top.mean(0))
    faces = []
    for i in range(4):
        j = (i + 1) % 4
        quad = np.array([bottom[i], bottom[j], top[j], top[i]])
        faces.append(Face(quad, color, _outward(quad, inside)))
    faces.append(Face(top.copy(), top_color, _outward(top, inside)))
    return faces


def _box_corners(center, half, yaw: float, y: float) -> np.ndarray:
    ax, az = yaw_axes(yaw)
    c = np.array([center[0], y, center[1]])
    return np.array([c - half[0] * ax - half[1] * az, c + half[0] * ax - half[1] * az,
                     c + half[0] * ax + half[1] * az, c - half[0] * ax + half[1] * az])


def _footprint(center, half, yaw: float) -> np.ndarray:
    return rotated_rect(center, half, yaw)


def blob(center: np.ndarray, radius: float, e1: np.ndarray, e2: np.ndarray, rng: np.random.Generator,
         n: int = 20, rough: float = 0.12, squash: float = 1.0) -> np.ndarray:
    """(n, 3) outline of an irregular round blob around ``center`` in the plane spanned by ``e1`` and ``e2``."""
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    k = np.arange(2, 6)
    wobble = (rng.normal(0.0, rough, 4)[:, None] * np.cos(k[:, None] * a + rng.uniform(0, 6.3, 4)[:, None])).sum(0)
    r = radius * (1.0 + wobble)
    return center + (r * np.cos(a))[:, None] * e1 + (r * squash * np.sin(a))[:, None] * e2


def _facing_basis(view: PinholeView, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A horizontal axis across the line of sight and the up axis: the plane of an upright billboard."""
    d = center - view.center
    side = np.array([d[2], 0.0, -d[0]])
    side /= max(np.linalg.norm(side), 1e-9)
    return -side, UP


def _lazy(rng: np.random.Generator, footprint: np.ndarray, y_top: float, y_bottom: float, make, kind: str) -> Item:
    """An item whose details are drawn from its own seed only when it is built, i.e. seen: creating the many
    objects of a scene then costs one random draw each."""
    seed = int(rng.integers(2**31))
    return Item(footprint, y_top, y_bottom, lambda view: make(np.random.default_rng(seed), view), kind)


def make_car(rng: np.random.Generator, center, yaw: float, ground_y: float) -> Item:
    """A car (body, tapered cabin with windows, wheels, lights) with its length along the frame's z' axis.

    Example:
        >>> item = make_car(np.random.default_rng(0), (2.0, 10.0), 0.0, 1.5)
        >>> item.y_bottom, item.y_top < 0
        (1.5, True)
    """
    center = np.asarray(center, dtype=np.float64)
    return _lazy(rng, _footprint(center, (1.1, 2.6), yaw), ground_y - 2.1, ground_y,
                 lambda r, view: _car_faces(r, view, center, yaw, ground_y), "car")


def _car_faces(rng: np.random.Generator, view: PinholeView, center: np.ndarray, yaw: float, ground_y: float):
    u = rng.random(12)
    van = u[0] < 0.15
    hx, hz = 0.5 * (1.65 + 0.25 * u[1]), 0.5 * (3.8 + 1.1 * u[2])
    body_top = ground_y - (0.85 + 0.2 * u[3])
    cab_top = ground_y - (1.8 + 0.3 * u[4] if van else 1.38 + 0.17 * u[4])
    hood = 0.5 + 0.3 * u[5] if van else 0.9 + 0.4 * u[5]
    trunk = 0.1 + 0.2 * u[6] if van else 0.5 + 0.4 * u[6]
    rake_f = 0.1 + 0.2 * u[7] if van else 0.5 + 0.3 * u[7]
    rake_b = 0.1 * u[8] if van else 0.2 + 0.3 * u[8]
    color, glass = _pick(rng, _CAR), _pick(rng, _CAR_GLASS)
    ax, az = yaw_axes(yaw)
    shadow = _box_corners(center, (hx + 0.12, hz + 0.12), yaw, ground_y - 0.005)
    faces = [Face(shadow, np.array([35.0, 35.0, 38.0]), UP.copy())]
    for k, wall in enumerate(box_walls(center, (hx, hz), ground_y - 0.28, body_top, yaw)):
        face = Face(wall.corners(), color, wall.normal)
        if k in (1, 3):  # sides: wheels
            st = np.stack([_WHEEL + [0.78, 0.05], _WHEEL + [2 * hz - 0.78, 0.05]])
            face.decals.append(Decal(wall.o + st[..., :1] * wall.u + st[..., 1:] * UP, np.full(3, 25.0)))
        else:  # ends: head or tail lights
            lamp = np.array([[0.1, 0.45, 0.45, 0.62], [2 * hx - 0.45, 0.45, 2 * hx - 0.1, 0.62]])
            tint = np.array([235.0, 235.0, 220.0]) if k == 2 else np.array([180.0, 20.0, 20.0])
            face.decals.append(Decal(rect_corners(wall.o, wall.u, UP, lamp), tint, emissive=k == 2))
        faces.append(face)
    faces.append(Face(_box_corners(center, (hx, hz), yaw, body_top), color, UP.copy()))
    c = np.array([center[0], 0.0, center[1]])
    zb, zf = -hz + trunk, hz - hood  # the cabin's foot, from back to front along z'
    bot = np.array([c + s * (hx - 0.06) * ax + z * az for s, z in ((-1, zb), (1, zb), (1, zf), (-1, zf))])
    top = np.array([c + s * (hx - 0.2) * ax + z * az
                    for s, z in ((-1, zb + rake_b), (1, zb + rake_b), (1, zf - rake_f), (-1, zf - rake_f))])
    for k, f in enumerate(hexahedron_faces(bot + [0, body_top, 0], top + [0, cab_top, 0], color)):
        if k in (0, 2):  # rear and front windows
            f.color = glass
        elif k in (1, 3):  # side windows: the face shrunk towards its centre, above a sill
            m = f.verts.mean(0)
            inset = m + 0.82 * (f.verts - m) + 0.06 * UP * np.array([[0.0], [0.0], [-1.0], [-1.0]])
            f.decals.append(Decal(inset[None], glass))
        faces.append(f)
    return faces


_WHEEL = 0.32 * np.stack([np.cos(np.linspace(0, 2 * np.pi, 14, endpoint=False)),
                          np.sin(np.linspace(0, 2 * np.pi, 14, endpoint=False))], -1)


def make_tree(rng: np.random.Generator, center, ground_y: float, scale: float = 1.0) -> Item:
    """A tree: a slightly leaning trunk and a canopy of irregular blobs (or a conifer's stacked triangles)."""
    center = np.asarray(center, dtype=np.float64)
    return _lazy(rng, _footprint(center, (0.5, 0.5), 0.0), ground_y - 13.0 * scale, ground_y,
                 lambda r, view: _tree_faces(r, view, center, ground_y, scale), "tree")


def _tree_faces(rng: np.random.Generator, view: PinholeView, center: np.ndarray, ground_y: float, scale: float):
    u = rng.random(6)
    trunk_h, radius = (1.8 + 1.7 * u[0]) * scale, (1.3 + 1.9 * u[1]) * scale
    conifer = u[2] < 0.2
    lean = rng.normal(0.0, 0.04, 2) * trunk_h
    w0, w1 = (0.1 + 0.1 * u[3]) * scale, (0.05 + 0.05 * u[4]) * scale
    bark, leaves = _pick(rng, _BARK), _pick(rng, _FOLIAGE, 12.0)
    bottom = _box_corners(center, (w0, w0), 0.0, ground_y)
    top = _box_corners(center + lean, (w1, w1), 0.0, ground_y - trunk_h)
    faces = hexahedron_faces(bottom, top, bark)[:4]
    crown = np.array([center[0] + lean[0], ground_y - trunk_h - 0.7 * radius, center[1] + lean[1]])
    if conifer:
        e1, _ = _facing_basis(view, crown)
        for k in range(3):
            base = crown - (0.6 - 0.9 * k) * radius * UP
            r = radius * (1.0 - 0.25 * k)
            faces.append(Face(np.array([base - r * e1, base + r * e1, base + 1.5 * r * UP]), leaves * (0.8 + 0.12 * k)))
        return faces
    e1, e2 = view.R[0], view.R[1]  # blobs in the image plane project to round shapes
    faces.append(Face(blob(crown, radius, e1, e2, rng), leaves * 0.75, None))
    for _ in range(int(2 + 3 * u[5])):
        off = rng.normal(0.0, 0.35, 2) * radius + [-0.15 * radius, -0.2 * radius]
        c = crown + off[0] * e1 + off[1] * e2
        faces.append(Face(blob(c, radius * rng.uniform(0.35, 0.6), e1, e2, rng), leaves * rng.uniform(0.9, 1.2)))
    return faces


def make_bush(rng: np.random.Generator, center, ground_y: float) -> Item:
    """A low irregular bush."""
    center = np.asarray(center, dtype=np.float64)

    def faces(r: np.random.Generator, view: PinholeView) -> list[Face]:
        size = r.uniform(0.4, 1.1)
        leaves = _pick(r, _FOLIAGE, 12.0)
        c = np.array([center[0], ground_y - 0.55 * size, center[1]])
        e1, e2 = _facing_basis(view, c)
        return [Face(blob(c, size, e1, e2, r, squash=0.6), leaves * 0.8),
                Face(blob(c + 0.2 * size * e2, 0.6 * size, e1, e2, r, squash=0.6), leaves)]

    return _lazy(rng, _footprint(center, (0.3, 0.3), 0.0), ground_y - 1.4, ground_y, faces, "bush")


def make_pole(rng: np.random.Generator, center, ground_y: float, arm_yaw: float) -> Item:
    """A street pole, leaning by up to a couple of degrees: a lamp post with an arm towards ``arm_yaw``, a round
    or square sign, or a traffic light. Its footprint is the foot of the pole: the arm hangs high above the rest."""
    center = np.asarray(center, dtype=np.float64)
    return _lazy(rng, _footprint(center, (0.3, 0.3), 0.0), ground_y - 8.5, ground_y,
                 lambda r, view: _pole_faces(r, center, ground_y, arm_yaw), "pole")


def _pole_faces(rng: np.random.Generator, center: np.ndarray, ground_y: float, arm_yaw: float) -> list[Face]:
    u = rng.random(8)
    kind = "lamp" if u[0] < 0.5 else ("sign" if u[0] < 0.8 else "traffic")
    h = {"lamp": 5.0 + 3.0 * u[1], "sign": 2.4 + 0.8 * u[1], "traffic": 3.0 + 1.0 * u[1]}[kind]
    tilt, a = math.radians(2.0 * u[2]), 2 * math.pi * u[3]
    lean = h * math.tan(tilt) * np.array([math.cos(a), math.sin(a)])
    w = 0.05 + 0.04 * u[4]
    metal = _pick(rng, _METAL)
    ax, az = yaw_axes(arm_yaw)
    bottom = _box_corners(center, (w, w), arm_yaw, ground_y)
    top_c = center + lean
    faces = hexahedron_faces(bottom, _box_corners(top_c, (w * 0.8, w * 0.8), arm_yaw, ground_y - h), metal)
    head = np.array([top_c[0], ground_y - h, top_c[1]])
    if kind == "lamp":
        tip = head + 1.6 * az
        arm_b = _box_corners(head[[0, 2]], (0.04, 0.04), arm_yaw, head[1] + 0.05)
        arm_t = _box_corners(tip[[0, 2]], (0.04, 0.04), arm_yaw, tip[1] - 0.05)
        faces += hexahedron_faces(arm_b, arm_t, metal)[:4]
        lamp_b = _box_corners(tip[[0, 2]] + 0.15 * az[[0, 2]], (0.15, 0.3), arm_yaw, tip[1] + 0.12)
        faces += hexahedron_faces(lamp_b, lamp_b - [0, 0.2, 0], metal * 0.8)
    elif kind == "sign":
        color = np.asarray([(200, 30, 30), (30, 80, 170), (240, 240, 240), (230, 190, 30)][int(4 * u[5])], float)
        c = head - 0.35 * UP + 0.05 * ax
        if u[6] < 0.5:  # round
            t = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            verts = c + 0.35 * (np.cos(t)[:, None] * az + np.sin(t)[:, None] * UP)
        else:
            verts = rect_corners(c - 0.3 * az - 0.3 * UP, az, UP, np.array([[0.0, 0.0, 0.6, 0.6]]))[0]
        faces.append(Face(verts, color, None))
    else:
        tint = np.asarray([(200, 40, 30), (220, 170, 30), (40, 170, 80)][int(3 * u[7])], float)
        box_b = _box_corners(head[[0, 2]] + 0.2 * ax[[0, 2]], (0.18, 0.15), arm_yaw, head[1] + 0.9)
        box = hexahedron_faces(box_b, box_b - [0, 0.9, 0], np.full(3, 35.0))
        lamps = np.array([[0.06, 0.06, 0.3, 0.3], [0.06, 0.33, 0.3, 0.57], [0.06, 0.6, 0.3, 0.84]])
        for face in box[:4]:
            o = face.verts[0]
            e = (face.verts[1] - o) / np.linalg.norm(face.verts[1] - o)
            face.decals.append(Decal(rect_corners(o, e, UP, lamps), np.full(3, 60.0)))
            face.decals.append(Decal(rect_corners(o, e, UP, lamps[:1]), tint, emissive=True))
        faces += box
    return faces


_PERSON = {
    "legs": np.array([[[-0.17, 0.0], [-0.05, 0.0], [-0.02, 0.86], [-0.18, 0.86]],
                      [[0.05, 0.0], [0.17, 0.0], [0.18, 0.86], [0.02, 0.86]]]),
    "body": np.array([[[-0.2, 0.82], [0.2, 0.82], [0.24, 1.45], [-0.24, 1.45]]]),
    "arms": np.array([[[-0.33, 0.8], [-0.24, 0.8], [-0.22, 1.42], [-0.3, 1.42]],
                      [[0.24, 0.8], [0.33, 0.8], [0.3, 1.42], [0.22, 1.42]]]),
    "head": np.stack([0.11 * np.cos(np.linspace(0, 2 * np.pi, 12, endpoint=False)),
                      1.6 + 0.13 * np.sin(np.linspace(0, 2 * np.pi, 12, endpoint=False))], -1),
    "hair": np.stack([0.115 * np.cos(np.linspace(0, np.pi, 7)), 1.62 + 0.125 * np.sin(np.linspace(0, np.pi, 7))], -1),
}


def make_person(rng: np.random.Generator, center, ground_y: float) -> Item:
    """A pedestrian as a flat silhouette turned towards the camera (legs, body, arms, head)."""
    center = np.asarray(center, dtype=np.float64)
    return _lazy(rng, _footprint(center, (0.3, 0.3), 0.0), ground_y - 2.0, ground_y,
                 lambda r, view: _person_faces(r, view, center, ground_y), "person")


def _person_faces(rng: np.random.Generator, view: PinholeView, center: np.ndarray, ground_y: float) -> list[Face]:
    s = rng.uniform(1.5, 1.9) / 1.75
    pants, shirt, skin = _pick(rng, _CLOTHES), _pick(rng, _CLOTHES), _pick(rng, _SKIN)
    hair = np.asarray([(30, 25, 20), (90, 60, 30), (180, 150, 90), (120, 120, 120)][rng.integers(4)], float)
    stride = np.zeros((2, 4, 2))
    stride[:, :2, 0] = rng.uniform(-0.12, 0.12) * np.array([[-1.0], [1.0]])
    base = np.array([center[0], ground_y, center[1]])
    e1, _ = _facing_basis(view, base)

    def place(st: np.ndarray) -> np.ndarray:
        return base + s * (st[..., :1] * e1 + st[..., 1:] * UP)

    faces = [Face(place(q), pants) for q in _PERSON["legs"] + stride]
    faces += [Face(place(q), shirt) for q in _PERSON["body"]]
    faces += [Face(place(q), shirt * 0.85) for q in _PERSON["arms"]]
    return faces + [Face(place(_PERSON["head"]), skin), Face(place(_PERSON["hair"]), hair)]


def make_bench(rng: np.random.Generator, center, yaw: float, ground_y: float) -> Item:
    """A bench: seat and back boxes on the ground, along the frame's z' axis."""
    center = np.asarray(center, dtype=np.float64)

    def faces(r: np.random.Generator, view: PinholeView) -> list[Face]:
        length = r.uniform(1.5, 2.2)
        color = _pick(r, [(110, 80, 50), (60, 60, 60), (40, 80, 50)])
        ax, _ = yaw_axes(yaw)
        seat = _box_corners(center, (0.25, length / 2), yaw, ground_y)
        seat_f = hexahedron_faces(seat, seat - [0, 0.45, 0], color)
        back = _box_corners(center + 0.22 * ax[[0, 2]], (0.04, length / 2), yaw, ground_y - 0.45)
        # the back stands above the seat's rear edge: it may hide the seat, never the other way round
        return seat_f + hexahedron_faces(back, back - [0, 0.45, 0], color * 0.9)

    return _lazy(rng, _footprint(center, (0.3, 1.1), yaw), ground_y - 0.9, ground_y, faces, "bench")


def make_bollard(rng: np.random.Generator, center, ground_y: float) -> Item:
    """A bin, bollard or hydrant: a short box turned at random."""
    center = np.asarray(center, dtype=np.float64)

    def faces(r: np.random.Generator, view: PinholeView) -> list[Face]:
        h, w = r.uniform(0.6, 1.1), r.uniform(0.12, 0.3)
        bottom = _box_corners(center, (w, w), r.uniform(0, 90), ground_y)
        return hexahedron_faces(bottom, bottom - [0, h, 0], _pick(r, _METAL + [(170, 40, 30), (40, 90, 60)]))

    return _lazy(rng, _footprint(center, (0.45, 0.45), 0.0), ground_y - 1.1, ground_y, faces, "bollard")


def wire(a: np.ndarray, b: np.ndarray, sag: float, color=(30, 30, 30), n: int = 16) -> Face:
    """A hanging wire from ``a`` to ``b`` (a parabola sagging by ``sag``), as a decal-only face."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + s * (b - a) - (4.0 * sag * s * (1 - s)) * UP
    segs = np.stack([pts[:-1], pts[1:]], 1)
    return Face(pts[:3].copy(), None, None, [Decal(segs, np.asarray(color, float), width=0.0)])
