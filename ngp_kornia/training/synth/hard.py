"""Hard cases for the renderer, all off by default: the structures that mislead a Manhattan-frame search on real
street photos.

* stairs with railings (:func:`make_stairs`): their handrails, stringers and side faces are sloped lines, along no
  axis of the scene, whose vanishing points lie above or below the horizon;
* billboards turned off the scene's axes (:func:`make_billboard`): long horizontal edges and text lines that meet
  at a false horizontal vanishing point on the horizon.

They are drawn from their own random generator (:class:`Additions`), after everything else of the scene, so a
render with every option off is the render of old, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ngp_kornia.training.synth.clutter import hexahedron_faces
from ngp_kornia.training.synth.facade import rotated_rect
from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.scene import UP, Decal, Face, Item, rect_corners, yaw_axes

__all__ = ["Additions", "make_billboard", "make_stairs"]

_STONE = [(170, 165, 155), (140, 135, 130), (190, 180, 165), (120, 110, 100)]
_METAL = [(60, 65, 70), (40, 45, 45), (150, 150, 150), (30, 60, 45)]
_PRINT = [(220, 40, 30), (30, 80, 170), (240, 200, 40), (240, 240, 240), (20, 20, 25), (40, 140, 70)]


@dataclass
class Additions:
    """Hard-case objects to add to an outdoor scene.

    Attributes:
        rng: their own random generator (the scene's draws stay as they were).
        stairs: mean number of flights of stairs (Poisson).
        billboards: mean number of billboards (Poisson).
    """

    rng: np.random.Generator
    stairs: float = 0.0
    billboards: float = 0.0


def _pick(rng: np.random.Generator, colors, jitter: float = 8.0) -> np.ndarray:
    c = np.asarray(colors[rng.integers(len(colors))], dtype=np.float64)
    return np.clip(c + rng.normal(0.0, jitter, 3), 0, 255)


def _normal(verts: np.ndarray, inside: np.ndarray) -> np.ndarray:
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    n /= max(float(np.linalg.norm(n)), 1e-12)
    return -n if float(n @ (verts[0] - inside)) < 0 else n


def _bar(a: np.ndarray, b: np.ndarray, across: np.ndarray, w: float, color) -> list[Face]:
    """A thin bar ``2 w`` wide and high on the line from ``a`` to ``b`` (any slope), as a hexahedron."""
    bottom = np.array([a - w * across, a + w * across, b + w * across, b - w * across])
    return hexahedron_faces(bottom, bottom + 2 * w * UP, color)


def make_stairs(rng: np.random.Generator, center, yaw: float, ground_y: float, length: float, width: float) -> Item:
    """A flight of stairs rising along the frame's z' axis (turned by ``yaw``) to a landing, with a handrail on
    each side: the rails, the stringers and the side faces slope at 25-40 degrees.

    Args:
        rng: random generator (one draw; the details come from their own seed when the item is seen).
        center: (2,) footprint centre ``(x, z)``.
        yaw: the frame's yaw in degrees; the stairs rise towards +z' or -z' at random.
        ground_y: world y of the ground.
        length: length of the footprint along z' (flight and landing).
        width: width across.

    Example:
        >>> item = make_stairs(np.random.default_rng(0), (0.0, 10.0), 0.0, 1.5, 5.0, 1.5)
        >>> item.y_bottom, item.y_top < 0
        (1.5, True)
    """
    center = np.asarray(center, dtype=np.float64)
    seed = int(rng.integers(2**31))
    rise_max = length * math.tan(math.radians(40.0)) + 1.2
    return Item(rotated_rect(center, (0.5 * width + 0.1, 0.5 * length + 0.1), yaw), ground_y - rise_max, ground_y,
                lambda view: _stairs_faces(np.random.default_rng(seed), view, center, yaw, ground_y, length, width),
                "stairs")


def _stairs_faces(rng: np.random.Generator, view: PinholeView, center: np.ndarray, yaw: float, ground_y: float,
                  length: float, width: float) -> list[Face]:
    ax, az = yaw_axes(yaw)
    u = az if rng.random() < 0.5 else -az  # the direction of ascent
    landing = rng.uniform(0.8, 1.6)
    run = length - landing
    rise = run * math.tan(math.radians(rng.uniform(25.0, 40.0)))
    stone, metal = _pick(rng, _STONE), _pick(rng, _METAL)
    c = np.array([center[0], ground_y, center[1]])
    lo = c - 0.5 * length * u  # foot of the flight, middle of its width
    hi = lo + run * u
    top = rise * UP  # from the ground to the landing's top
    h = width / 2
    p = [lo - h * ax, lo + h * ax, hi + h * ax + top, hi - h * ax + top]  # the sloped top, foot first
    inside = 0.5 * (lo + hi) + 0.3 * top
    slope = Face(np.array(p), stone, None)
    slope.normal = _normal(slope.verts, inside)
    n_steps = max(2, int(round(rise / rng.uniform(0.15, 0.19))))
    s = np.arange(n_steps) / n_steps
    risers = np.stack([np.zeros(n_steps), s, np.full(n_steps, width), s + 0.35 / n_steps], -1)
    along = p[3] - p[0]  # up the slope, foot to top: the risers are bands across it
    slope.decals.append(Decal(rect_corners(p[0], ax, along, risers), stone * 0.72))
    sides = [Face(np.array([lo + k * h * ax, hi + k * h * ax, hi + k * h * ax + top]), stone * 0.9, None)
             for k in (-1, 1)]
    for f in sides:
        f.normal = _normal(f.verts, inside)
    block = hexahedron_faces(*_landing(hi, ax, u, h, landing, top), stone)
    rails = [_railing(lo + k * (h - 0.05) * ax, hi + k * (h - 0.05) * ax, top, u, landing, ax, metal)
             for k in (-1, 1)]
    far, near = sorted(rails, key=lambda r: -float(np.linalg.norm(r[1] - view.center)))
    return far[0] + [*sides, slope] + block + near[0]


def _landing(hi: np.ndarray, ax: np.ndarray, u: np.ndarray, h: float, landing: float, top: np.ndarray):
    bottom = np.array([hi - h * ax, hi + h * ax, hi + h * ax + landing * u, hi - h * ax + landing * u])
    return bottom, bottom + top


def _railing(a: np.ndarray, b: np.ndarray, top: np.ndarray, u: np.ndarray, landing: float, ax: np.ndarray,
             color) -> tuple[list[Face], np.ndarray]:
    """Posts and a sloped handrail 0.9 m above the flight from ``a`` (foot) to ``b`` (top), then level over the
    landing. Returns the faces and the rail's midpoint (to order the two railings)."""
    rail_h = 0.9 * UP
    faces = []
    for t in np.linspace(0.0, 1.0, 4):
        foot = a + t * (b + top - a)
        faces += _bar(foot, foot + rail_h, ax, 0.025, color)[:4]
    end = b + top + landing * u
    faces += _bar(end, end + rail_h, ax, 0.025, color)[:4]
    faces += _bar(a + rail_h, b + top + rail_h, ax, 0.03, color)
    faces += _bar(b + top + rail_h, end + rail_h, ax, 0.03, color)
    return faces, 0.5 * (a + b + top) + rail_h


def make_billboard(rng: np.random.Generator, center, yaw: float, ground_y: float, width: float) -> Item:
    """A billboard on two posts, its panel along the frame's x' axis turned by ``yaw``: a printed panel with
    horizontal bands and lines of text, two-sided.

    Example:
        >>> item = make_billboard(np.random.default_rng(0), (3.0, 12.0), 30.0, 1.5, 4.0)
        >>> item.y_bottom, item.y_top < 0
        (1.5, True)
    """
    center = np.asarray(center, dtype=np.float64)
    seed = int(rng.integers(2**31))
    return Item(rotated_rect(center, (0.5 * width + 0.1, 0.3), yaw), ground_y - 7.5, ground_y,
                lambda view: _billboard_faces(np.random.default_rng(seed), center, yaw, ground_y, width),
                "billboard")


def _billboard_faces(rng: np.random.Generator, center: np.ndarray, yaw: float, ground_y: float,
                     width: float) -> list[Face]:
    ax, _ = yaw_axes(yaw)
    height = min(width * rng.uniform(0.35, 0.6), 3.0)
    bottom = rng.uniform(0.4, 3.5)
    metal = _pick(rng, _METAL)
    c = np.array([center[0], ground_y, center[1]])
    faces = []
    for k in (-1, 1):
        foot = c + k * 0.35 * width * ax
        faces += _bar(foot, foot + (bottom + 0.1) * UP, ax, 0.08, metal)[:4]
    o = c - 0.5 * width * ax + bottom * UP
    panel = Face(np.array([o, o + width * ax, o + width * ax + height * UP, o + height * UP]), _pick(rng, _PRINT))
    frame = 0.06
    ground = _pick(rng, _PRINT)
    split = rng.uniform(0.3, 0.7)
    panel.decals.append(Decal(rect_corners(o, ax, UP, np.array([[frame, frame, width - frame, split * height]])),
                              ground))
    lines = []
    t = split * height + 0.1
    while t + 0.12 < height - frame:
        lh = rng.uniform(0.1, 0.3)
        if t + lh > height - frame:
            break
        lines.append([frame + 0.2, t, frame + 0.2 + rng.uniform(0.4, 0.95) * (width - 2 * frame - 0.4), t + lh])
        t += lh + rng.uniform(0.08, 0.2)
    if lines:
        panel.decals.append(Decal(rect_corners(o, ax, UP, np.array(lines)), _pick(rng, _PRINT)))
    return faces + [panel]
