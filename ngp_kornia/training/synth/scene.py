"""3D scene description for the procedural renderer: faces with decals, items, lighting, and the painter's
algorithm that draws them.

A scene is made of

* ``ground``: faces lying on (or just above) the ground plane, drawn first in list order (sidewalks, markings);
* ``shell``: faces of a room seen from inside (walls, floor, ceiling), drawn next; from inside a convex room
  they never hide each other;
* ``items``: objects standing on the ground (buildings, cars, furniture, trees, ...). Each has a convex
  footprint quad on the ground; visible items are drawn far to near in the order of :func:`order_items`, which is
  exact for disjoint convex footprints seen from a point (in the plane that relation has no cycles). An item's
  faces are built only when the item is visible, so the cost of a render follows what the camera sees;
* ``overlay``: faces drawn last (wires hanging over a street).

Everything is in world coordinates (y down, the ground is ``y = ground_y > 0`` below a camera at height 0).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ngp_kornia.training.synth.painter import Canvas, DrawList, PinholeView

__all__ = [
    "OBJECT_KINDS",
    "UP",
    "Decal",
    "Face",
    "Item",
    "Lighting",
    "Scene",
    "Wall",
    "box_faces",
    "box_walls",
    "draw_ground",
    "draw_objects",
    "draw_scene",
    "faces_viewer",
    "order_items",
    "ordered_items",
    "rect_corners",
    "visible_items",
    "yaw_axes",
]

UP = np.array([0.0, -1.0, 0.0])  # world up: y points down

#: what a pixel of a render can show: the sky, the ground plane with what lies on it (pavements, markings), a room's
#: shell (walls, floor, ceiling with their doors and windows), and the kinds of :class:`Item`
OBJECT_KINDS = ("sky", "ground", "room", "building", "furniture", "stairs", "billboard", "car", "tree", "bush",
                "pole", "person", "bench", "bollard", "plant", "chair", "wire", "other")


@dataclass
class Decal:
    """Details painted on a face, drawn right after it with the face's lighting.

    Attributes:
        polys: (m, k, 3) non-overlapping polygons, or (m, 2, 3) segments when ``width`` is set.
        color: RGB albedo in 0..255.
        width: world line width for segments; None for filled polygons.
        emissive: drawn with its own colour, unlit (lamps, windows reflecting the sky).
    """

    polys: np.ndarray
    color: np.ndarray
    width: float | None = None
    emissive: bool = False


@dataclass
class Face:
    """A planar polygon of the scene.

    Attributes:
        verts: (k, 3) vertices in world coordinates.
        color: RGB albedo in 0..255, or None to draw only the decals.
        normal: outward unit normal; faces turned away from the camera are skipped. None: two-sided.
        decals: details drawn after the face, in order.
        emissive: unlit colour (lamps).
    """

    verts: np.ndarray
    color: np.ndarray | None
    normal: np.ndarray | None = None
    decals: list[Decal] = field(default_factory=list)
    emissive: bool = False


@dataclass
class Item:
    """An object standing on the ground, built lazily.

    Attributes:
        footprint: (4, 2) convex quad ``(x, z)`` on the ground containing the object.
        y_top: smallest world y of the object (its top; y points down).
        y_bottom: largest world y (its base).
        build: ``build(view) -> list[Face]`` returns the faces in drawing order for that camera.
        kind: what the object is, one of :data:`OBJECT_KINDS` (``"building"``, ``"car"``, ``"tree"``, ...): the
            object map of :mod:`ngp_kornia.training.synth.objects` labels its pixels with it.
    """

    footprint: np.ndarray
    y_top: float
    y_bottom: float
    build: Callable[[PinholeView], list[Face]]
    kind: str = "other"

    def __post_init__(self) -> None:
        if self.kind not in OBJECT_KINDS:
            raise ValueError(f"unknown item kind {self.kind!r}; choose one of {', '.join(OBJECT_KINDS)}")


@dataclass
class Lighting:
    """Flat shading: ambient plus two directional lights, then aerial perspective (haze) with distance.

    Attributes:
        ambient: ambient factor.
        sun_dir: (3,) unit direction towards the main light (world).
        sun: main light strength.
        fill_dir: (3,) unit direction towards a secondary light.
        fill: secondary light strength.
        haze: RGB colour distant surfaces fade to.
        visibility: distance (world units) at which ~63% of the colour is haze; ``inf`` for none.
    """

    ambient: float = 0.55
    sun_dir: np.ndarray = field(default_factory=lambda: np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5]))
    sun: float = 0.5
    fill_dir: np.ndarray = field(default_factory=lambda: np.array([-0.6, -0.2, -0.77]))
    fill: float = 0.1
    haze: np.ndarray = field(default_factory=lambda: np.array([200.0, 210.0, 220.0]))
    visibility: float = math.inf

    def factor(self, normal: np.ndarray | None) -> float:
        """The light factor of a surface with this normal (two-sided surfaces get a fixed share)."""
        if normal is None:
            return self.ambient + 0.5 * self.sun + 0.5 * self.fill
        return (
            self.ambient
            + self.sun * max(0.0, float(normal @ self.sun_dir))
            + self.fill * max(0.0, float(normal @ self.fill_dir))
        )

    def haze_weight(self, distance: float) -> float:
        return 0.0 if math.isinf(self.visibility) else 1.0 - math.exp(-distance / self.visibility)


@dataclass
class Scene:
    """A procedural scene. ``boxes`` lists ``(lo, hi)`` corners of boxes aligned with the world axes (the ground
    truth Manhattan frame), kept for checks; ``frames`` the yaws (degrees) of every block orientation used, the
    dominant (ground-truth) one first; ``ground_color`` the albedo of the bare ground (None: not visible)."""

    kind: str
    ground_y: float
    ground: list[Face] = field(default_factory=list)
    shell: list[Face] = field(default_factory=list)
    items: list[Item] = field(default_factory=list)
    overlay: list[Face] = field(default_factory=list)
    boxes: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    frames: list[float] = field(default_factory=lambda: [0.0])
    ground_color: np.ndarray | None = None


def yaw_axes(yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal axes ``(x', z')`` of a frame turned by ``yaw_deg`` about the vertical, with the yaw sign of
    :func:`ngp_kornia.geometry.camera.rotation_from_angles` (z turns towards x).

    Example:
        >>> [np.round(a, 6).tolist() for a in yaw_axes(90.0)]
        [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]
    """
    a = math.radians(yaw_deg)
    return np.array([math.cos(a), 0.0, -math.sin(a)]), np.array([math.sin(a), 0.0, math.cos(a)])


def rect_corners(o: np.ndarray, u: np.ndarray, v: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """Corners of rectangles given in a plane's 2D frame.

    Args:
        o: (3,) origin of the frame.
        u: (3,) first axis.
        v: (3,) second axis.
        rects: (m, 4) rectangles ``(s0, t0, s1, t1)``.

    Returns:
        (m, 4, 3) corners ``o + s u + t v`` in the order (s0,t0), (s1,t0), (s1,t1), (s0,t1).

    Example:
        >>> rect_corners(np.zeros(3), np.eye(3)[0], np.eye(3)[1], np.array([[0, 0, 2, 1.0]]))[0].tolist()
        [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
    """
    r = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    st = np.empty((len(r), 4, 2))
    st[:, 0, 0] = st[:, 3, 0] = r[:, 0]
    st[:, 1, 0] = st[:, 2, 0] = r[:, 2]
    st[:, 0, 1] = st[:, 1, 1] = r[:, 1]
    st[:, 2, 1] = st[:, 3, 1] = r[:, 3]
    return st @ np.stack([u, v]) + o  # a matrix product: numpy broadcasts slowly over a last axis of 3


@dataclass
class Wall:
    """A vertical rectangle seen from outside: ``o`` is its bottom-left corner, ``u`` points right along it,
    ``v`` up; ``width`` and ``height`` in world units; ``normal = u x v`` points outwards."""

    o: np.ndarray
    u: np.ndarray
    width: float
    height: float

    @property
    def v(self) -> np.ndarray:
        return UP

    @property
    def normal(self) -> np.ndarray:
        u = self.u
        return np.array([u[2], 0.0, -u[0]])  # u x (0, -1, 0)

    def corners(self) -> np.ndarray:
        """(4, 3): bottom-left, bottom-right, top-right, top-left."""
        a, b = self.o, self.o + self.width * self.u
        up = np.array([0.0, -self.height, 0.0])
        return np.array([a, b, b + up, a + up])


def box_walls(center: np.ndarray, half: tuple[float, float], y_bottom: float, y_top: float, yaw: float) -> list[Wall]:
    """The four walls of a box standing on ``y_bottom`` with its top at ``y_top`` (< y_bottom).

    Args:
        center: (2,) footprint centre ``(x, z)``.
        half: half sizes along the box's own x' and z' axes.
        y_bottom: world y of the base.
        y_top: world y of the top.
        yaw: the box's yaw in degrees (see :func:`yaw_axes`).

    Returns:
        Walls facing -z', +x', +z', -x' (front, right, back, left for yaw 0).
    """
    # plain floats: this runs for every visible block of every render
    t = math.radians(yaw)
    cs, sn = math.cos(t), math.sin(t)
    hx, hz = float(half[0]), float(half[1])
    cx, cz, y = float(center[0]), float(center[1]), float(y_bottom)
    height = y - y_top
    ax, az = (cs, -sn), (sn, cs)  # the box's x' and z' axes as (x, z)

    def corner(i: float, j: float) -> np.ndarray:
        return np.array([cx + i * hx * ax[0] + j * hz * az[0], y, cz + i * hx * ax[1] + j * hz * az[1]])

    # each wall: its bottom-left corner seen from outside, the direction along it, its width
    return [
        Wall(corner(-1, -1), np.array([ax[0], 0.0, ax[1]]), 2 * hx, height),
        Wall(corner(1, -1), np.array([az[0], 0.0, az[1]]), 2 * hz, height),
        Wall(corner(1, 1), np.array([-ax[0], 0.0, -ax[1]]), 2 * hx, height),
        Wall(corner(-1, 1), np.array([-az[0], 0.0, -az[1]]), 2 * hz, height),
    ]


def box_faces(center, half, y_bottom: float, y_top: float, yaw: float, color, top_color=None) -> list[Face]:
    """Faces of a box (four walls and the top; the base is never seen), with outward normals.

    Example:
        >>> faces = box_faces((0.0, 10.0), (1.0, 2.0), 1.5, -3.0, 0.0, (200, 100, 50))
        >>> len(faces), faces[0].normal.tolist(), faces[4].normal.tolist()
        (5, [0.0, 0.0, -1.0], [0.0, -1.0, 0.0])
    """
    color = np.asarray(color, dtype=np.float64)
    top_color = color if top_color is None else np.asarray(top_color, dtype=np.float64)
    faces = [Face(w.corners(), color, w.normal) for w in box_walls(np.asarray(center), half, y_bottom, y_top, yaw)]
    top = np.array([w.o for w in box_walls(np.asarray(center), half, y_top, y_top, yaw)])
    faces.append(Face(top, top_color, UP.copy()))
    return faces


def visible_items(items: list[Item], view: PinholeView) -> list[int]:
    """Indices of the items whose bounding prism is not entirely outside the view (near plane or a side)."""
    if not items:
        return []
    fp = np.stack([it.footprint for it in items])  # (n, 4, 2)
    ys = np.array([[it.y_top, it.y_bottom] for it in items])  # (n, 2)
    n = len(items)
    corners = np.empty((n, 8, 3))
    corners[:, :, 0] = np.tile(fp[:, :, 0], 2)
    corners[:, :, 2] = np.tile(fp[:, :, 1], 2)
    corners[:, :4, 1] = ys[:, :1]
    corners[:, 4:, 1] = ys[:, 1:]
    Xc = view.to_camera(corners)
    s = Xc @ view.frustum[:, :3].T + view.frustum[:, 3]  # (n, 8, 5)
    dead = (s < 0).all(axis=1).any(axis=1)
    return np.flatnonzero(~dead).tolist()


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _entry_distance(fp: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Distance from the origin along unit rays ``u`` (P, 2) to where they enter convex quads ``fp`` (P, 4, 2)."""
    e = np.roll(fp, -1, axis=1) - fp
    normal = np.stack([e[..., 1], -e[..., 0]], -1)
    # orient the edge normals outwards, whatever the winding of the quad
    inward = ((fp.mean(1, keepdims=True) - fp) * normal).sum(-1) > 0
    normal = np.where(inward[..., None], -normal, normal)
    nu = (normal * u[:, None]).sum(-1)
    nv = (normal * fp).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = nv / nu
    return np.where(nu < 0, t, -np.inf).max(-1)


def order_items(footprints: np.ndarray, eye: np.ndarray) -> list[int]:
    """Painter's order (far to near) of objects with disjoint convex footprints seen from ``eye``.

    For every pair whose angular extents seen from the eye overlap, a ray through the middle of the overlap tells
    which one is in front; the resulting "is behind" relation is sorted topologically, farthest first among the
    free ones (a cycle, only possible with overlapping footprints, is broken by distance).

    Args:
        footprints: (n, 4, 2) convex quads ``(x, z)``.
        eye: (2,) the camera position ``(x, z)``.

    Returns:
        Indices into ``footprints``, to be drawn in that order.

    Example:
        >>> near = np.array([[-1.0, 2], [1, 2], [1, 3], [-1, 3]])
        >>> far = near + [0.5, 10.0]
        >>> order_items(np.stack([near, far]), np.zeros(2))
        [1, 0]
    """
    n = len(footprints)
    if n <= 1:
        return list(range(n))
    fp = np.asarray(footprints, dtype=np.float64) - eye
    dist = np.linalg.norm(fp.mean(1), axis=-1)
    # angular extent of each footprint around the direction of its centroid (no wrap-around: the eye is outside)
    mid = np.arctan2(fp.mean(1)[:, 1], fp.mean(1)[:, 0])
    rel = _wrap(np.arctan2(fp[..., 1], fp[..., 0]) - mid[:, None])
    lo, hi = rel.min(1), rel.max(1)
    i, j = np.triu_indices(n, 1)
    shift = _wrap(mid[j] - mid[i])
    a = np.maximum(lo[i], shift + lo[j])
    b = np.minimum(hi[i], shift + hi[j])
    overlap = b > a + 1e-9
    i, j, ang = i[overlap], j[overlap], mid[i[overlap]] + 0.5 * (a[overlap] + b[overlap])
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    ti, tj = _entry_distance(fp[i], u), _entry_distance(fp[j], u)
    # edge far -> near
    far = np.where(ti > tj, i, j)
    near = np.where(ti > tj, j, i)
    return _toposort(n, far, near, dist)


def _toposort(n: int, src: np.ndarray, dst: np.ndarray, dist: np.ndarray) -> list[int]:
    succ: list[list[int]] = [[] for _ in range(n)]
    indeg = [0] * n
    for s, d in zip(src.tolist(), dst.tolist(), strict=True):
        succ[s].append(d)
        indeg[d] += 1
    heap = [(-dist[k], k) for k in range(n) if indeg[k] == 0]
    heapq.heapify(heap)
    done = [False] * n
    out: list[int] = []
    while len(out) < n:
        if not heap:  # a cycle: release the farthest node left
            k = max((k for k in range(n) if not done[k]), key=lambda k: dist[k])
            indeg[k] = 0
            heap.append((-dist[k], k))
        _, k = heapq.heappop(heap)
        if done[k]:
            continue
        done[k] = True
        out.append(k)
        for d in succ[k]:
            indeg[d] -= 1
            if indeg[d] == 0 and not done[d]:
                heapq.heappush(heap, (-dist[d], d))
    return out


def faces_viewer(face: Face, center: np.ndarray) -> bool:
    """Whether a face is seen from its front by a camera at ``center`` (3,): False for a back face (two-sided
    faces, without a normal, always True)."""
    if face.normal is None:
        return True
    n, v0 = face.normal, face.verts[0]
    return n[0] * (center[0] - v0[0]) + n[1] * (center[1] - v0[1]) + n[2] * (center[2] - v0[2]) > 0


def _queue_face(todo: DrawList, view: PinholeView, face: Face, light: Lighting, haze: bool = True) -> None:
    center = view.center
    if not faces_viewer(face, center):
        return
    w = 0.0
    if haze and not math.isinf(light.visibility):
        w = light.haze_weight(float(np.linalg.norm(face.verts.mean(0) - center)))
    k = light.factor(face.normal)

    def shade(color: np.ndarray, emissive: bool) -> np.ndarray:
        c = color if emissive else color * k
        return c + w * (light.haze - c) if w > 0 else c

    under = None
    if face.color is not None:
        under = shade(face.color, face.emissive)
        todo.fill(face.verts[None], under)
    for d in face.decals:
        color = shade(d.color, d.emissive)
        if d.width is None:
            todo.fill(d.polys, color)
        else:
            todo.lines(d.polys, color, d.width, under=under)


def draw_ground(canvas: Canvas, scene: Scene, light: Lighting) -> None:
    """Draw the ground faces in order, lit but without haze (haze on the ground is applied per pixel, exactly)."""
    todo = DrawList()
    for face in scene.ground:
        _queue_face(todo, canvas.view, face, light, haze=False)
    todo.draw(canvas.view, canvas.image, canvas.antialias)


def draw_objects(canvas: Canvas, scene: Scene, light: Lighting) -> None:
    """Draw the room shell, the visible items far to near, then the overlay."""
    view = canvas.view
    todo = DrawList()
    for face in scene.shell:
        _queue_face(todo, view, face, light)
    for item in ordered_items(scene, view):
        for face in item.build(view):
            _queue_face(todo, view, face, light)
    for face in scene.overlay:
        _queue_face(todo, view, face, light)
    todo.draw(view, canvas.image, canvas.antialias)


def ordered_items(scene: Scene, view: PinholeView) -> list[Item]:
    """The items of a scene the view may see, in drawing order (far to near, :func:`order_items`)."""
    vis = visible_items(scene.items, view)
    if not vis:
        return []
    order = order_items(np.stack([scene.items[k].footprint for k in vis]), view.center[[0, 2]])
    return [scene.items[vis[k]] for k in order]


def draw_scene(canvas: Canvas, scene: Scene, light: Lighting) -> None:
    """Draw a scene over whatever the canvas holds (normally sky and ground): ground faces, room shell, the visible
    items far to near, then the overlay."""
    draw_ground(canvas, scene, light)
    draw_objects(canvas, scene, light)
