"""Ground truth of the line evidence for segments detected on a render: does a segment lie on the outline of a
structural object, and which 3D direction does it have.

* **Structure**: a segment is sampled at points along its length; at each point the object map
  (:class:`~ngp_kornia.training.synth.objects.ObjectMap`) is read a little to its left and to its right. Where the two
  sides show different primitives, the point lies on the outline of the one drawn later (the larger id: it covers
  the other), and counts when that primitive belongs to a kind of
  :data:`~ngp_kornia.training.synth.objects.STRUCTURE_KINDS` (building, room, furniture). The target is the share of
  points that count: 0 for a segment on a tree, a car, a road marking or on texture inside a face, 1 for one along a
  wall's corner, a roof line or a window's frame.
* **Direction**: the true vanishing points of the render tell it: ``vertical`` when the segment points at the
  zenith, ``horizontal`` when it points at a horizontal vanishing point of one of the scene's frames (an Atlanta
  scene has several), ``neither`` otherwise; "points at" allowing the larger of ``max_angle`` and the angle one
  pixel of endpoint error makes over half the segment's length.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry import segment_vp_angle
from ngp_kornia.training.synth.objects import ObjectMap
from ngp_kornia.training.synth.scene import yaw_axes

__all__ = [
    "DIRECTIONS",
    "MIN_OUTLINE",
    "direction_classes",
    "frame_vanishing_points",
    "line_targets",
    "outline_lengths",
    "structure_targets",
]

#: the direction classes, in the order of the labels and of the network's logits
DIRECTIONS = ("vertical", "horizontal", "neither")
#: the shortest outline (pixels at a 640-pixel long side) whose segments count as structure in
#: :func:`line_targets`: people labelling lines draw the long, clear edges of buildings, not every window pane
MIN_OUTLINE = 30.0


def _sample_ids(ids: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The ids at (..., 2) pixel positions, the nearest pixel, clamped to the image."""
    h, w = ids.shape
    x = np.clip(np.rint(points[..., 0]), 0, w - 1).astype(np.intp)
    y = np.clip(np.rint(points[..., 1]), 0, h - 1).astype(np.intp)
    return ids[y, x]


def structure_targets(segments: np.ndarray, objects: ObjectMap, points: int = 16,
                      offsets: tuple[float, ...] = (1.5, 3.0)) -> np.ndarray:
    """The share of each segment's length that lies on the outline of a structural object.

    Args:
        segments: (N, 2, 2) segments ``[[x0, y0], [x1, y1]]`` in the render's pixels.
        objects: the render's object map.
        points: sample points along each segment.
        offsets: distances (pixels) to each side at which the map is read; a point lies on an outline when the two
            sides differ at any of them (the nearest pair that differs names the outline). Several, because a
            detected segment may lie a pixel or two beside the edge it follows.

    Returns:
        (N,) float32 in [0, 1].

    Example:
        >>> ids = np.zeros((20, 20), np.int32); ids[:, 10:] = 1  # a structural primitive right of column 9.5
        >>> objects = ObjectMap(ids, np.array([0, 2], np.int16))  # the sky, a room
        >>> structure_targets(np.array([[[9.5, 2.0], [9.5, 17.0]], [[3.0, 2.0], [3.0, 17.0]]]), objects).tolist()
        [1.0, 0.0]
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    if len(seg) == 0:
        return np.zeros(0, np.float32)
    d = seg[:, 1] - seg[:, 0]
    normal = np.stack([-d[:, 1], d[:, 0]], -1) / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    t = (np.arange(points) + 0.5) / points
    at = seg[:, None, 0] + t[None, :, None] * d[:, None]  # (N, P, 2)
    front = _front_ids(objects.ids, at, normal, offsets)
    found = front >= 0
    on_structure = found & objects.structure()[np.maximum(front, 0)]
    return on_structure.mean(-1).astype(np.float32)


def _front_ids(ids: np.ndarray, at: np.ndarray, normal: np.ndarray, offsets: tuple[float, ...]) -> np.ndarray:
    """At points (N, P, 2) of lines with unit normals (N, 2): the id of the primitive whose outline passes there
    (the larger of the two ids read across, at the nearest offset where they differ), -1 where none does."""
    front = np.full(at.shape[:2], -1, np.int64)
    for off in offsets:
        left = _sample_ids(ids, at + off * normal[:, None])
        right = _sample_ids(ids, at - off * normal[:, None])
        new = (front < 0) & (left != right)
        front[new] = np.maximum(left, right)[new]
    return front


def outline_lengths(segments: np.ndarray, objects: ObjectMap, reach: float = 320.0, step: float = 2.0,
                    offsets: tuple[float, ...] = (1.5, 3.0)) -> np.ndarray:
    """How long the outline under each segment is: along the segment's line, how far on both sides of its midpoint
    the outline of the primitive it follows (the most common one under it) goes on without a break of more than
    one step.

    Args:
        segments: (N, 2, 2) pixels.
        objects: the render's object map.
        reach: how far (pixels) from the midpoint to look, each way.
        step: spacing (pixels) of the points read.
        offsets: see :func:`structure_targets`.

    Returns:
        (N,) float32 pixels; 0 where the segment follows no outline.

    Example:
        >>> ids = np.zeros((40, 40), np.int32); ids[10:30, 20:] = 1  # an outline 20 pixels long at column 19.5
        >>> outline_lengths(np.array([[[19.5, 15.0], [19.5, 25.0]]]), ObjectMap(ids, np.array([0, 2], np.int16)))
        array([20.], dtype=float32)
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    if len(seg) == 0:
        return np.zeros(0, np.float32)
    d = seg[:, 1] - seg[:, 0]
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    normal = np.stack([-u[:, 1], u[:, 0]], -1)
    t = np.arange(-reach, reach + step / 2, step)
    at = seg.mean(1)[:, None] + t[None, :, None] * u[:, None]
    front = _front_ids(objects.ids, at, normal, offsets)
    centre = np.abs(t) <= 0.5 * np.linalg.norm(d, axis=-1, keepdims=True)  # (N, T): the segment itself
    under = np.where(centre & (front >= 0), front, -1)
    followed = np.array([np.bincount(row[row >= 0]).argmax() if (row >= 0).any() else -1 for row in under])
    same = (front == followed[:, None]) & (followed[:, None] >= 0)
    same = same | (np.roll(same, 1, 1) & np.roll(same, -1, 1))  # a one-step break does not end it
    hits = same & centre
    found = hits.any(1)
    idx = np.arange(len(t))
    first = np.where(found, hits.argmax(1), 0)
    last = np.where(found, len(t) - 1 - hits[:, ::-1].argmax(1), 0)
    # the run around the segment's own points: from just after the last break before them to just before the next
    before = np.maximum.accumulate(np.where(same, -1, idx), axis=1)
    after = np.minimum.accumulate(np.where(same, len(t), idx)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(len(seg))
    lo, hi = before[rows, first] + 1, after[rows, last] - 1
    return np.where(found, (hi - lo + 1) * step, 0.0).astype(np.float32)


def frame_vanishing_points(K: Tensor, R: Tensor, frames: tuple[float, ...]) -> tuple[Tensor, Tensor]:
    """The zenith and the horizontal vanishing points of a render's frames.

    Args:
        K: (3, 3) intrinsics.
        R: (3, 3) world-to-camera rotation.
        frames: yaws (degrees) of the scene's block groups (:attr:`RenderedScene.frames`).

    Returns:
        zenith (3,) and horizontal VPs (2F, 3), homogeneous pixels, float64.
    """
    K, R = torch.as_tensor(K, dtype=torch.float64), torch.as_tensor(R, dtype=torch.float64)
    zenith = K @ R[:, 1]
    axes = np.concatenate([np.stack(yaw_axes(float(yaw))) for yaw in frames])  # (2F, 3) world directions
    return zenith, torch.from_numpy(axes) @ R.T @ K.T


def direction_classes(segments: Tensor, zenith: Tensor, horizontal: Tensor, max_angle: float = 2.0) -> Tensor:
    """Direction class (index into :data:`DIRECTIONS`) of each segment from the true vanishing points.

    Args:
        segments: (N, 2, 2) segments in pixels.
        zenith: (3,) the zenith VP, homogeneous pixels.
        horizontal: (V, 3) horizontal VPs.
        max_angle: the least angle (degrees) between a segment and the ray from its midpoint to a VP that counts as
            pointing at it; a short segment is allowed what one pixel of endpoint error makes.

    Returns:
        (N,) int64: 0 vertical, 1 horizontal, 2 neither; the nearer VP wins where both are within reach.

    Example:
        >>> seg = torch.tensor([[[10.0, 0.0], [10.0, 50.0]], [[0.0, 5.0], [50.0, 5.0]], [[0.0, 0.0], [40.0, 40.0]]])
        >>> direction_classes(seg, torch.tensor([0.0, 1.0, 0.0]), torch.tensor([[1.0, 0.0, 0.0]])).tolist()
        [0, 1, 2]
    """
    seg = torch.as_tensor(segments, dtype=torch.float64).reshape(-1, 2, 2)
    if len(seg) == 0:
        return torch.zeros(0, dtype=torch.long)
    vps = torch.cat([torch.as_tensor(zenith, dtype=torch.float64)[None],
                     torch.as_tensor(horizontal, dtype=torch.float64).reshape(-1, 3)])
    angles = segment_vp_angle(seg[None], vps[None])[0]  # (1 + V, N)
    half = 0.5 * (seg[:, 1] - seg[:, 0]).norm(dim=-1)
    reach = torch.rad2deg(torch.atan2(torch.ones_like(half), half)).clamp_min(max_angle)
    to_zenith, to_horizontal = angles[0], angles[1:].amin(0) if len(vps) > 1 else torch.full_like(half, math.inf)
    out = torch.full(half.shape, 2, dtype=torch.long)
    out[(to_horizontal <= reach) & (to_horizontal < to_zenith)] = 1
    out[(to_zenith <= reach) & (to_zenith <= to_horizontal)] = 0
    return out


def line_targets(segments: np.ndarray, objects: ObjectMap, zenith: Tensor, horizontal: Tensor,
                 min_outline: float = MIN_OUTLINE) -> tuple[np.ndarray, np.ndarray]:
    """The labels the line-evidence network is trained on: what a person labelling the lines of a man-made scene
    for its vanishing points would draw.

    A segment's structure target is its share on a structural outline (:func:`structure_targets`), where it points
    at a vanishing point of the scene's frames (its direction class is not ``neither``) and the outline it follows
    is at least ``min_outline`` long (:func:`outline_lengths`; pixels at a 640-pixel long side); 0 otherwise.

    Args:
        segments: (N, 2, 2) pixels of the render.
        objects: its object map.
        zenith: (3,) the true zenith VP, homogeneous pixels.
        horizontal: (V, 3) the true horizontal VPs.
        min_outline: see above.

    Returns:
        structure targets (N,) float32 in [0, 1] and direction classes (N,) int64.
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    direction = direction_classes(torch.from_numpy(seg), zenith, horizontal).numpy()
    scale = max(objects.ids.shape) / 640.0
    long = outline_lengths(seg, objects) >= min_outline * scale
    return structure_targets(seg, objects) * ((direction < 2) & long), direction
