"""Buildings for the procedural renderer: box blocks with facades (window grids, doors, shop fronts, string
courses, sills, shutters, curtain walls), cornices and ledges, and set-back towers.

Facade details are painted as decals (coplanar polygons drawn right after their wall), cornices and ledges are
real 3D bands around the block. Details are generated only for walls that face the camera, with a level of
detail driven by their size in pixels, so distant blocks cost almost nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ngp_kornia.training.synth.painter import PinholeView
from ngp_kornia.training.synth.scene import UP, Decal, Face, Item, Wall, box_walls, rect_corners

__all__ = [
    "FacadeStyle",
    "band_faces",
    "facade_decals",
    "facing",
    "make_building",
    "pixels_per_metre",
    "random_facade_style",
    "rotated_rect",
]

_WALLS = {
    "brick": [(150, 75, 55), (170, 95, 70), (125, 60, 50), (160, 110, 85), (110, 70, 60)],
    "plaster": [(225, 215, 195), (235, 225, 205), (210, 190, 160), (200, 205, 210), (230, 200, 170),
                (190, 205, 190), (240, 235, 225), (215, 180, 150)],
    "concrete": [(170, 170, 165), (150, 150, 150), (190, 185, 175), (130, 135, 140), (205, 200, 190)],
    "glass": [(70, 95, 115), (90, 120, 135), (60, 80, 90), (110, 130, 140), (50, 70, 95)],
}
_TRIM = [(240, 240, 235), (225, 220, 210), (60, 60, 60), (90, 80, 70), (200, 200, 200), (150, 140, 120)]
_GLASS = [(45, 55, 65), (60, 75, 90), (35, 40, 50), (80, 95, 110)]
_SKY_GLASS = [(150, 175, 200), (175, 190, 205), (130, 155, 180)]  # windows reflecting the sky
_LIT = [(230, 205, 140), (215, 200, 170)]
_CURTAIN = [(205, 195, 175), (180, 170, 160)]
_DOOR = [(90, 55, 35), (60, 40, 30), (40, 40, 45), (120, 30, 30), (30, 60, 50), (150, 110, 70)]
_SIGN = [(180, 30, 30), (30, 60, 140), (20, 110, 60), (230, 180, 40), (40, 40, 40), (230, 230, 230)]
_ROOF = [(90, 90, 90), (110, 105, 100), (70, 70, 75), (130, 125, 120)]


def _pick(colors, u: np.ndarray, jitter: float = 10.0) -> np.ndarray:
    """A palette colour chosen by ``u[0]`` in [0, 1), jittered by ``u[1:4]``."""
    c = colors[min(int(u[0] * len(colors)), len(colors) - 1)]
    return np.array([min(max(c[i] + jitter * (2.0 * float(u[i + 1]) - 1.0), 0.0), 255.0) for i in range(3)])


@dataclass
class FacadeStyle:
    """The look of one building's facades. Lengths in metres, colours RGB 0..255."""

    wall: np.ndarray
    trim: np.ndarray
    glass: list[tuple[np.ndarray, bool, float]]  # (colour, emissive, probability)
    door: np.ndarray
    sign: np.ndarray
    roof: np.ndarray
    floor_h: float = 3.2
    ground_h: float = 4.0
    bay: float = 3.0
    win_w: float = 1.2
    win_h: float = 1.6
    sill: float = 0.9
    frame: float = 0.1
    mullion: int = 1  # 0 none, 1 vertical bar, 2 cross
    arched: bool = False
    shutters: bool = False
    courses: bool = True
    shop: bool = False
    curtain_wall: bool = False
    coping: bool = True
    blank_sides: float = 0.5  # probability that a non-front wall has no windows
    cornice: float = 0.0  # cornice protrusion, 0 for none
    fascia: bool = False  # a ledge above the ground floor


def random_facade_style(rng: np.random.Generator, district: str = "mixed") -> FacadeStyle:
    """A random facade style for a district (``"residential"``, ``"downtown"`` or ``"mixed"``).

    Example:
        >>> style = random_facade_style(np.random.default_rng(0))
        >>> bool(style.win_w < style.bay and style.sill + style.win_h < style.floor_h)
        True
    """
    if district not in ("residential", "downtown", "mixed"):
        raise ValueError(f"unknown district {district!r}")
    u = rng.random(64)  # one draw for everything: this runs for every visible building of every render
    material_p = {"residential": [0.35, 0.5, 0.15, 0.0], "downtown": [0.2, 0.2, 0.35, 0.25],
                  "mixed": [0.3, 0.35, 0.25, 0.1]}[district]
    material = ["brick", "plaster", "concrete", "glass"][int(np.searchsorted(np.cumsum(material_p), u[0] * 0.9999))]
    floor_h = 2.8 + 1.0 * u[1]
    bay = 2.2 + 2.0 * u[2]
    win_w = bay * (0.3 + 0.35 * u[3])
    win_h = floor_h * (0.4 + 0.22 * u[4])
    sill = min(0.6 + 0.4 * u[5], floor_h - win_h - 0.25)
    glass = [(_pick(_GLASS, u[8:12]), False, 1.0)]
    if u[6] < 0.7:
        glass.append((_pick(_SKY_GLASS, u[12:16]), True, 0.1 + 0.4 * u[7]))
    if u[16] < 0.5:
        glass.append((_pick(_CURTAIN, u[20:24]), False, 0.05 + 0.25 * u[17]))
    if u[18] < 0.25:
        glass.append((_pick(_LIT, u[24:28]), True, 0.05 + 0.15 * u[19]))
    mullion = 0 if u[29] < 0.35 else (1 if u[29] < 0.7 else 2)
    style = FacadeStyle(
        wall=_pick(_WALLS[material], u[32:36]),
        trim=_pick(_TRIM, u[36:40]),
        glass=glass,
        door=_pick(_DOOR, u[40:44]),
        sign=_pick(_SIGN, u[44:48], 20.0),
        roof=_pick(_ROOF, u[48:52]),
        floor_h=floor_h,
        ground_h=floor_h + (0.5 + u[53] if u[52] < 0.6 else 0.0),
        bay=bay,
        win_w=win_w,
        win_h=win_h,
        sill=sill,
        frame=0.05 + 0.11 * u[55] if u[54] < 0.75 else 0.0,
        mullion=mullion,
        arched=material in ("brick", "plaster") and u[56] < 0.15,
        shutters=material == "plaster" and u[57] < 0.25 and bay > 2.0 * win_w + 0.3,
        courses=u[58] < 0.55,
        shop=u[59] < {"residential": 0.2, "downtown": 0.7, "mixed": 0.5}[district],
        curtain_wall=material == "glass",
        coping=u[60] < 0.7,
        blank_sides=0.2 + 0.6 * u[61],
        cornice=0.2 + 0.5 * u[63] if u[62] < 0.5 else 0.0,
        fascia=u[28] < 0.3,
    )
    if style.curtain_wall:
        style.mullion, style.arched, style.shutters, style.courses = 0, False, False, False
    return style


def facing(center: np.ndarray, wall: Wall) -> bool:
    """Whether the camera at ``center`` sees the outside of ``wall``."""
    return float(wall.normal @ (center - wall.o)) > 0


def pixels_per_metre(view: PinholeView, wall: Wall) -> float:
    """Image size in pixels of one metre at the point of ``wall`` nearest to the camera (an upper bound over the
    wall, used for level of detail)."""
    rel = view.center - wall.o
    s = min(max(float(rel @ wall.u), 0.0), wall.width)
    t = min(max(float(rel @ UP), 0.0), wall.height)
    d = np.linalg.norm(wall.o + s * wall.u + t * UP - view.center)
    return view.focal / max(float(d), view.near)


def _wall_polys(wall: Wall, st: np.ndarray) -> np.ndarray:
    """Wall-plane 2D coordinates (m, k, 2) (along, up) to world polygons (m, k, 3)."""
    return st @ np.stack([wall.u, UP]) + wall.o


def _window_shapes(r: np.ndarray, arched: bool) -> np.ndarray:
    """(m, 4) rectangles ``(s0, t0, s1, t1)`` to (m, k, 2) window outlines, round-topped when ``arched``."""
    if not arched:
        return r[:, [[0, 1], [2, 1], [2, 3], [0, 3]]]
    rad = 0.5 * (r[:, 2] - r[:, 0])
    sc = 0.5 * (r[:, 0] + r[:, 2])
    tc = np.maximum(r[:, 3] - rad, r[:, 1])
    a = np.linspace(0.0, np.pi, 9)
    arc = np.stack([sc[:, None] + rad[:, None] * np.cos(a), tc[:, None] + rad[:, None] * np.sin(a)], -1)
    base = r[:, [[0, 1], [2, 1]]]
    return np.concatenate([base, arc], 1)


def _grid(n_cols: int, n_rows: int, s0: float, bay: float, t0: float, pitch: float, w: float, h: float):
    """(n_rows * n_cols, 4) rectangles of a regular grid: column i centred at ``s0 + (i + 0.5) bay``, row j
    starting at ``t0 + j pitch``."""
    S = np.tile(s0 + (np.arange(n_cols) + 0.5) * bay, n_rows)
    T = np.repeat(t0 + np.arange(n_rows) * pitch, n_cols)
    return np.stack([S - w / 2, T, S + w / 2, T + h], -1)


def _grow(r: np.ndarray, d: float) -> np.ndarray:
    return r + np.array([-d, -d, d, d])


def facade_decals(wall: Wall, style: FacadeStyle, rng: np.random.Generator, ppm: float, front: bool) -> list[Decal]:
    """The details painted on one wall.

    Args:
        wall: the wall.
        style: the building's style.
        rng: random generator for per-window choices.
        ppm: pixels per metre on this wall (level of detail).
        front: a street-facing wall (gets doors and shop fronts; other walls may stay blank).

    Returns:
        Decals in drawing order.

    Example:
        >>> wall = Wall(np.zeros(3), np.array([1.0, 0, 0]), 12.0, 10.0)
        >>> decals = facade_decals(wall, random_facade_style(np.random.default_rng(1)), np.random.default_rng(2),
        ...                        50.0, True)
        >>> len(decals) > 0
        True
    """
    if style.curtain_wall:
        return _curtain_decals(wall, style, rng, ppm)
    out: list[Decal] = []
    W, H = wall.width, wall.height
    if style.coping and ppm * 0.3 > 0.7 and H > 3.0:
        out.append(Decal(rect_corners(wall.o, wall.u, UP, np.array([[0.0, H - 0.35, W, H]])), style.trim))
    if not front and rng.random() < style.blank_sides:
        return out
    if ppm * style.win_w < 2.5:
        return out  # windows would be a pixel: leave the wall plain
    margin = max(0.4, 0.5 * (style.bay - style.win_w))
    n_cols = int((W - 2 * margin + (style.bay - style.win_w)) // style.bay)
    if n_cols < 1:
        return out
    s_off = 0.5 * (W - n_cols * style.bay)
    n_up = int((H - style.ground_h - 0.4) // style.floor_h) if H > style.ground_h + style.floor_h * 0.8 else 0
    if style.courses and ppm * 0.24 > 0.6:
        lines = style.ground_h + np.arange(n_up) * style.floor_h
        course = np.stack([np.zeros_like(lines), lines - 0.12, np.full_like(lines, W), lines + 0.12], -1)
        if len(course):
            out.append(Decal(rect_corners(wall.o, wall.u, UP, course), style.trim))
    wins = _grid(n_cols, n_up, s_off, style.bay, style.ground_h + style.sill, style.floor_h, style.win_w,
                 style.win_h)
    shop = style.shop and front and style.ground_h >= 3.4
    door_bay = int(rng.integers(n_cols))
    if not shop:
        ground = _grid(n_cols, 1, s_off, style.bay, min(style.sill, style.ground_h - style.win_h - 0.2),
                       style.floor_h, style.win_w, style.win_h)
        if front:
            ground = np.delete(ground, door_bay, axis=0)
        wins = np.concatenate([ground, wins], 0)
    out += _window_decals(wall, style, rng, ppm, wins)
    if front:
        out += _ground_floor_decals(wall, style, rng, ppm, n_cols, s_off, door_bay, shop)
    return out


def _window_decals(wall: Wall, style: FacadeStyle, rng: np.random.Generator, ppm: float, wins: np.ndarray):
    out: list[Decal] = []
    if len(wins) == 0:
        return out
    if style.shutters:
        left = np.stack([wins[:, 0] - 0.5 * style.win_w - 0.05, wins[:, 1], wins[:, 0] - 0.05, wins[:, 3]], -1)
        right = np.stack([wins[:, 2] + 0.05, wins[:, 1], wins[:, 2] + 0.5 * style.win_w + 0.05, wins[:, 3]], -1)
        out.append(Decal(rect_corners(wall.o, wall.u, UP, np.concatenate([left, right])), style.door))
    if style.frame > 0 and ppm * style.frame > 0.8:
        out.append(Decal(_wall_polys(wall, _window_shapes(_grow(wins, style.frame), style.arched)), style.trim))
    shapes = _window_shapes(wins, style.arched)
    cum = np.cumsum([p for _, _, p in style.glass])
    pick = np.searchsorted(cum, rng.random(len(wins)) * cum[-1])
    for g, (color, emissive, _) in enumerate(style.glass):
        sel = pick == g
        if sel.any():
            out.append(Decal(_wall_polys(wall, shapes[sel]), color, emissive=emissive))
    if style.mullion and ppm * 0.05 > 0.35:
        sc = 0.5 * (wins[:, 0] + wins[:, 2])
        top = wins[:, 3] if not style.arched else wins[:, 3] - 0.02
        segs = [np.stack([np.stack([sc, wins[:, 1]], -1), np.stack([sc, top], -1)], 1)]
        if style.mullion == 2:
            tt = wins[:, 1] + 0.62 * (wins[:, 3] - wins[:, 1])
            if style.arched:
                tt = np.minimum(tt, wins[:, 3] - 0.5 * (wins[:, 2] - wins[:, 0]))
            segs.append(np.stack([np.stack([wins[:, 0], tt], -1), np.stack([wins[:, 2], tt], -1)], 1))
        out.append(Decal(_wall_polys(wall, np.concatenate(segs)), style.trim, width=0.06))
    if ppm * 0.1 > 0.8:
        sills = np.stack([wins[:, 0] - 0.1, wins[:, 1] - 0.12, wins[:, 2] + 0.1, wins[:, 1]], -1)
        out.append(Decal(rect_corners(wall.o, wall.u, UP, sills), 0.9 * style.trim + 0.1 * style.wall))
    return out


def _ground_floor_decals(wall: Wall, style: FacadeStyle, rng: np.random.Generator, ppm: float, n_cols: int,
                         s_off: float, door_bay: int, shop: bool) -> list[Decal]:
    out: list[Decal] = []
    dc = s_off + (door_bay + 0.5) * style.bay
    dw = min(rng.uniform(1.0, 1.8), style.bay - 0.3)
    dh = min(rng.uniform(2.1, 2.6), style.ground_h - 0.4)
    door = np.array([[dc - dw / 2, 0.0, dc + dw / 2, dh]])
    if shop:
        bays = np.delete(np.arange(n_cols), door_bay)
        s0 = s_off + bays * style.bay + 0.15
        panes = np.stack([s0, np.full_like(s0, 0.45), s0 + style.bay - 0.3, np.full_like(s0, style.ground_h - 1.0)],
                         -1)
        sign = np.array([[s_off, style.ground_h - 0.85, s_off + n_cols * style.bay, style.ground_h - 0.2]])
        out.append(Decal(rect_corners(wall.o, wall.u, UP, sign), style.sign))
        if len(panes):
            out.append(Decal(rect_corners(wall.o, wall.u, UP, _grow(panes, 0.08)), style.trim * 0.5))
            out.append(Decal(rect_corners(wall.o, wall.u, UP, panes), style.glass[-1][0] * 0.8, emissive=True))
    if ppm * dw > 1.5:
        frame = np.array([[dc - dw / 2 - 0.12, 0.0, dc + dw / 2 + 0.12, dh + 0.12]])
        out.append(Decal(rect_corners(wall.o, wall.u, UP, frame), style.trim))
        out.append(Decal(rect_corners(wall.o, wall.u, UP, door), style.door))
        if ppm * 0.04 > 0.3:
            split = np.array([[[dc, 0.0], [dc, dh]]])
            out.append(Decal(_wall_polys(wall, split), style.door * 0.6, width=0.04))
    return out


def _curtain_decals(wall: Wall, style: FacadeStyle, rng: np.random.Generator, ppm: float) -> list[Decal]:
    W, H = wall.width, wall.height
    n_cols = max(1, int(W // (style.bay * 0.6)))
    n_rows = max(1, int(H // style.floor_h))
    sw, th = W / n_cols, H / n_rows
    out: list[Decal] = []
    if ppm * sw > 2.0:
        cells = _grid(n_cols, n_rows, 0.0, sw, 0.0, th, sw, th)
        alt = rng.random(len(cells)) < rng.uniform(0.1, 0.5)
        if alt.any():
            tone = style.glass[1][0] if len(style.glass) > 1 else style.wall * 1.3
            out.append(Decal(rect_corners(wall.o, wall.u, UP, cells[alt]), tone, emissive=len(style.glass) > 1))
        spandrel = np.stack([np.zeros(n_rows), np.arange(n_rows) * th, np.full(n_rows, W),
                             np.arange(n_rows) * th + 0.25 * th], -1)
        out.append(Decal(rect_corners(wall.o, wall.u, UP, spandrel), style.wall * 0.7))
    s = np.arange(n_cols + 1) * sw
    t = np.arange(n_rows + 1) * th
    vert = np.stack([np.stack([s, np.zeros_like(s)], -1), np.stack([s, np.full_like(s, H)], -1)], 1)
    hori = np.stack([np.stack([np.zeros_like(t), t], -1), np.stack([np.full_like(t, W), t], -1)], 1)
    mullion_color = style.trim if style.trim.mean() > 120 else np.array([40.0, 45.0, 50.0])
    out.append(Decal(_wall_polys(wall, np.concatenate([vert, hori])), mullion_color, width=0.1))
    return out


def band_faces(center, half, yaw: float, y_bottom: float, y_top: float, out: float, color, view: PinholeView,
               top_color=None) -> list[Face]:
    """A ledge (or cornice) around a box: a band ``out`` wide between heights ``y_top < y_bottom``.

    Only the sides whose wall faces the camera are built (the others are hidden by the block). With
    ``top_color`` the band caps the block (a cornice) and its top is one roof face.

    Returns:
        Faces in drawing order: undersides or top strips, outer faces, then the roof.
    """
    color = np.asarray(color, dtype=np.float64)
    inner = box_walls(np.asarray(center), half, y_bottom, y_top, yaw)
    outer = box_walls(np.asarray(center), (half[0] + out, half[1] + out), y_bottom, y_top, yaw)
    C = view.center
    strips, sides = [], []
    for wi, wo in zip(inner, outer, strict=True):
        if not facing(C, wi):
            continue
        ci, co = wi.corners(), wo.corners()
        if C[1] > y_bottom:  # camera below the band: its underside shows
            strips.append(Face(np.array([ci[0], co[0], co[1], ci[1]]), color, np.array([0.0, 1.0, 0.0])))
        if C[1] < y_top and top_color is None:
            strips.append(Face(np.array([ci[3], ci[2], co[2], co[3]]), color, UP.copy()))
        sides.append(Face(co, color, wo.normal))
    faces = strips + sides
    if top_color is not None:
        faces.append(Face(np.array([w.corners()[3] for w in outer]), np.asarray(top_color, float), UP.copy()))
    return faces


def rotated_rect(center, half, yaw: float) -> np.ndarray:
    """(4, 2) corners ``(x, z)`` of a rectangle with half sizes ``half`` along a frame turned by ``yaw``."""
    # plain floats: this runs for every object of every scene
    t = math.radians(yaw)
    cs, sn = math.cos(t), math.sin(t)
    ax, az = (cs * half[0], -sn * half[0]), (sn * half[1], cs * half[1])  # x' and z' axes, scaled, as (x, z)
    cx, cz = float(center[0]), float(center[1])
    return np.array([[cx - ax[0] - az[0], cz - ax[1] - az[1]], [cx + ax[0] - az[0], cz + ax[1] - az[1]],
                     [cx + ax[0] + az[0], cz + ax[1] + az[1]], [cx - ax[0] + az[0], cz - ax[1] + az[1]]])


def _block_faces(center, half, yaw, y_bottom, y_top, style: FacadeStyle, fronts, plain, view: PinholeView,
                 rng: np.random.Generator, base: bool) -> list[Face]:
    faces = []
    walls = box_walls(np.asarray(center), half, y_bottom, y_top, yaw)
    ppm = 0.0  # the block's largest scale in pixels per metre, for the level of detail of its ledges
    for k, wall in enumerate(walls):
        if not facing(view.center, wall):
            continue
        corners = wall.corners()
        decals = []
        if view.sees(corners):
            wall_ppm = pixels_per_metre(view, wall)
            ppm = max(ppm, wall_ppm)
            if k not in plain:
                decals = facade_decals(wall, style, rng, wall_ppm, front=base and k in fronts)
        faces.append(Face(corners, style.wall, wall.normal, decals))
    if base and style.fascia and y_bottom - y_top > style.ground_h + 1.0 and ppm * 0.35 > 1.0:
        y = y_bottom - style.ground_h
        faces += band_faces(center, half, yaw, y + 0.35, y, 0.3, style.trim, view)
    if style.cornice > 0 and ppm * 0.6 > 1.0:
        faces += band_faces(center, half, yaw, y_top + 0.6, y_top, style.cornice, style.trim, view,
                            top_color=style.roof)
    elif view.center[1] < y_top:  # the roof shows only from above
        faces.append(Face(np.array([w.corners()[3] for w in walls]), style.roof, UP.copy()))
    return faces


def make_building(seed: int, center, half, yaw: float, ground_y: float, height: float, district: str = "mixed",
                  fronts=(0,), plain=()) -> tuple[Item, tuple[np.ndarray, np.ndarray]]:
    """A block with facades, maybe a set-back tower, as a lazily built :class:`Item`.

    Args:
        seed: seed of the block's details (style, windows, tower), drawn when it is built.
        center: (2,) footprint centre ``(x, z)``.
        half: half sizes along the block's axes.
        yaw: the block's yaw in degrees.
        ground_y: world y of the ground.
        height: height of the main block.
        district: style family, see :func:`random_facade_style`.
        fronts: indices of the street-facing walls (0: -z', 1: +x', 2: +z', 3: -x').
        plain: indices of walls left blank (party walls against a neighbour, backs).

    Returns:
        The item and the ``(lo, hi)`` corners of its main block (axis-aligned when ``yaw`` is 0).

    Example:
        >>> item, (lo, hi) = make_building(7, (0.0, 20.0), (5.0, 4.0), 0.0, 1.6, 12.0)
        >>> lo.tolist(), hi.tolist()
        ([-5.0, -10.4, 16.0], [5.0, 1.6, 24.0])
    """
    y_top = ground_y - height
    center = np.asarray(center, dtype=np.float64)
    lo = np.array([center[0] - half[0], y_top, center[1] - half[1]])
    hi = np.array([center[0] + half[0], ground_y, center[1] + half[1]])
    reach = 0.8  # room for cornices and ledges

    def build(view: PinholeView) -> list[Face]:
        drng = np.random.default_rng(seed)
        style = random_facade_style(drng, district)
        u = drng.random(4)
        base = _block_faces(center, half, yaw, ground_y, y_top, style, fronts, plain, view, drng, True)
        if height <= 15 or u[0] > 0.3:
            return base
        inner = (max(1.0, half[0] - 1.5 - 3.5 * u[1]), max(1.0, half[1] - 1.5 - 3.5 * u[2]))
        tower_top = y_top - 4.0 - (max(5.0, height) - 4.0) * u[3]
        up = _block_faces(center, inner, yaw, y_top, tower_top, style, (), (), view, drng, False)
        # seen from below the base's roof, the base hides the tower's foot: draw the tower first
        return up + base if view.center[1] > y_top else base + up

    # the top is a bound: a tower may rise up to max(5, height) above the block
    item = Item(rotated_rect(center, (half[0] + reach, half[1] + reach), yaw), y_top - max(5.0, height), ground_y,
                build, "building")
    return item, (lo, hi)
