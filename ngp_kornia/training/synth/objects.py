"""The object map of a render: for every pixel, which face or decal of the scene it shows and what kind of object
that belongs to (sky, ground, building, room, car, tree, ...), the ground truth of the line-evidence labels.

The map is drawn with the same painter's algorithm, the same clipping and the same order as the image, without
anti-aliasing and with each face and each decal in a flat colour of its own that encodes its id: ids count up in
drawing order, so where two ids meet, the larger one was drawn over the smaller and the edge between them is an
outline of the larger one's primitive (a tree in front of a wall: the tree's outline; a window on a wall: the
window's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ngp_kornia.training.synth.painter import DrawList, PinholeView
from ngp_kornia.training.synth.pixels import view_rays
from ngp_kornia.training.synth.scene import OBJECT_KINDS, Face, Scene, faces_viewer, ordered_items

__all__ = ["STRUCTURE_KINDS", "ObjectMap", "draw_object_map"]

#: kinds of object whose outlines a person labelling the lines of a man-made scene draws: buildings, the walls,
#: floor and ceiling of a room (with their doors and windows), box-like furniture
STRUCTURE_KINDS = ("room", "building", "furniture")

#: lines thinner than this (pixels) are left out of the map: in the image they are blended into the face below them
#: and barely change it
_MIN_LINE_WIDTH = 0.5


@dataclass
class ObjectMap:
    """What each pixel of a render shows.

    Attributes:
        ids: (H, W) int32, the primitive (face or decal) drawn last at each pixel: 0 the sky, larger ids drawn later.
        kinds: (n,) int16, ``kinds[id]`` the index into :data:`~ngp_kornia.training.synth.scene.OBJECT_KINDS` of the
            object primitive ``id`` belongs to.
    """

    ids: np.ndarray
    kinds: np.ndarray

    def kind_map(self) -> np.ndarray:
        """(H, W) int16: the kind index of every pixel."""
        return self.kinds[self.ids]

    def structure(self) -> np.ndarray:
        """(n,) bool: whether primitive ``id`` belongs to a kind of :data:`STRUCTURE_KINDS`."""
        return np.isin(self.kinds, [OBJECT_KINDS.index(k) for k in STRUCTURE_KINDS])


def _code(index: int) -> tuple[float, float, float]:
    """An id as the three 8-bit channels of a colour (exact: the map is drawn without anti-aliasing)."""
    return float(index & 255), float((index >> 8) & 255), float((index >> 16) & 255)


def _decode_ids(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 colours written by :func:`draw_object_map` -> (H, W) int32 ids."""
    c = image.astype(np.int32)
    return c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16)


def _queue(todo: DrawList, view: PinholeView, faces: list[Face], kind: str, table: list[int]) -> None:
    code = OBJECT_KINDS.index(kind)
    for face in faces:
        if not faces_viewer(face, view.center):
            continue
        if face.color is not None:
            todo.fill(face.verts[None], _code(len(table)))
            table.append(code)
        for decal in face.decals:
            if decal.width is None:
                todo.fill(decal.polys, _code(len(table)))
            else:
                todo.lines(decal.polys, _code(len(table)), decal.width)
            table.append(code)


def draw_object_map(view: PinholeView, scene: Scene) -> ObjectMap:
    """Draw the object map of a scene seen by a view.

    Args:
        view: the camera.
        scene: the scene (its items are built again for the view; they come out the same, from their own seeds).

    Returns:
        The map, ``(view.height, view.width)``.

    Example:
        >>> from ngp_kornia.training.synth.scene import Item, box_faces
        >>> view = PinholeView(np.array([[50.0, 0, 15.5], [0, 50, 15.5], [0, 0, 1]]), np.eye(3), np.zeros(3), 32, 32)
        >>> box = Item(np.array([[-1.0, 4], [1, 4], [1, 6], [-1, 6]]), -1.0, 1.0,
        ...            lambda v: box_faces((0.0, 5.0), (1.0, 1.0), 1.0, -1.0, 0.0, (200, 100, 50)), "building")
        >>> m = draw_object_map(view, Scene("street", 1.5, items=[box], ground_color=np.full(3, 90.0)))
        >>> [OBJECT_KINDS[k] for k in m.kind_map()[[0, 15, 31], 15]]
        ['sky', 'building', 'ground']
    """
    image = np.zeros((view.height, view.width, 3), np.uint8)
    table = [OBJECT_KINDS.index("sky")]
    if scene.ground_color is not None:  # outdoors: the bare ground plane below the horizon
        image[view_rays(view) > 0] = _code(len(table))
        table.append(OBJECT_KINDS.index("ground"))
    todo = DrawList()
    _queue(todo, view, scene.ground, "ground", table)
    _queue(todo, view, scene.shell, "room", table)
    for item in ordered_items(scene, view):
        _queue(todo, view, item.build(view), item.kind, table)
    _queue(todo, view, scene.overlay, "wire", table)
    todo.draw(view, image, antialias=False, min_width=_MIN_LINE_WIDTH)
    return ObjectMap(_decode_ids(image), np.asarray(table, np.int16))
