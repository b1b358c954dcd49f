"""Overlays: the virtual box and axes follow the Manhattan frame of a known camera, and drawing never mutates."""

import numpy as np
import pytest
import torch

from ngp_kornia.geometry import Camera, segment_vp_angle
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.training.synth.render import camera_ground_truth
from ngp_kornia.viz import AXIS_COLOURS, BOX_EDGES, draw_axes, draw_calibration, draw_frame_box, frame_box_points

SIZE = (320, 240)  # (W, H)


def _calibration(pitch: float = 0.0, roll: float = 0.0, yaw: float = 0.0, fov_v: float = 60.0) -> Calibration:
    """The exact calibration of a camera with these angles (degrees)."""
    gt = camera_ground_truth(fov_v, pitch, roll, yaw, SIZE)
    camera = Camera.from_matrix(gt["K"], gt["R"], torch.tensor([SIZE[1], SIZE[0]]))
    return Calibration(camera=camera, score=torch.tensor(1.0), valid=torch.tensor(True))


def _edges(points: np.ndarray, axis: int) -> torch.Tensor:
    return torch.tensor(np.stack([points[[i, j]] for i, j, a in BOX_EDGES if a == axis]))[None]


@pytest.mark.parametrize("pitch, roll, yaw", [(10.0, 5.0, 20.0), (-25.0, -15.0, -40.0), (30.0, 12.0, 3.0)])
def test_box_edges_vanish_at_the_frame_vps(pitch, roll, yaw):
    cal = _calibration(pitch, roll, yaw)
    points = frame_box_points(cal)
    assert np.isfinite(points).all()
    for axis in range(3):  # extended, every edge along world axis i passes through VP i (row 1: the zenith)
        angle = segment_vp_angle(_edges(points, axis), cal.vps[axis].reshape(1, 1, 3))
        assert float(angle.max()) < 1e-6


def test_level_camera_gives_vertical_edges_and_an_upright_box():
    points = frame_box_points(_calibration(yaw=25.0))
    for i, j, axis in BOX_EDGES:
        if axis == 1:  # i is the bottom corner, j the top one
            assert points[i, 0] == pytest.approx(points[j, 0], abs=1e-9)
            assert points[j, 1] < points[i, 1]


def test_default_box_stands_in_the_lower_middle_of_the_image():
    points = frame_box_points(_calibration(pitch=-10.0))
    w, h = SIZE
    bottom = points[[i for i in range(8) if not i & 2]].mean(0)
    assert bottom[0] == pytest.approx((w - 1) / 2, abs=1.0)
    assert bottom[1] == pytest.approx(0.8 * (h - 1), abs=0.1 * h)
    assert (points >= 0).all() and (points[:, 0] < w).all() and (points[:, 1] < h).all()
    height = bottom[1] - points[[i for i in range(8) if i & 2], 1].mean()
    assert 0.1 * h < height < 0.3 * h


def test_draw_frame_box_draws_axis_colours_on_a_copy():
    cal = _calibration(pitch=-20.0, roll=-8.0, yaw=30.0)  # looking down: no face is seen edge-on
    image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    out = draw_frame_box(image, cal)
    assert out is not image and not image.any() and out.shape == image.shape and out.dtype == np.uint8
    points = frame_box_points(cal)
    t = np.linspace(0.2, 0.8, 13)[:, None]
    for i, j, axis in BOX_EDGES:
        x, y = np.round(points[i] + t * (points[j] - points[i])).astype(int).T
        # most of each edge shows its axis' colour (where edges cross, the one drawn last wins)
        assert np.all(out[y, x] == AXIS_COLOURS[axis], -1).mean() > 0.5


def test_draw_axes_points_up_for_a_level_camera():
    cal = _calibration(yaw=30.0)  # turned, so the z arrow does not hide the up arrow
    out = draw_axes(np.zeros((SIZE[1], SIZE[0], 3), np.uint8), cal)
    bottom = frame_box_points(cal)[[i for i in range(8) if not i & 2]].mean(0)
    x, y = np.round(bottom).astype(int)
    green = np.all(out[:, x] == AXIS_COLOURS[1], -1)
    assert green[y - 20 : y - 5].all() and not green[y + 5 :].any()


def test_corners_behind_the_camera_are_clipped_not_drawn():
    cal = _calibration(yaw=0.0)  # looking along world +z
    behind = np.array([0.0, 1.0, -3.0])
    assert np.isnan(frame_box_points(cal, center=behind)).all()
    image = np.full((SIZE[1], SIZE[0], 3), 7, np.uint8)
    assert (draw_frame_box(image, cal, center=behind) == image).all()
    assert (draw_axes(image, cal, origin=behind, length=1.0) == image).all()
    # a large box around the camera: some corners in front, some behind
    straddling = np.array([0.0, 1.0, 0.5])
    points = frame_box_points(cal, center=straddling, size=3.0)
    assert np.isnan(points).any() and np.isfinite(points).any()
    out = draw_frame_box(image, cal, center=straddling, size=3.0)
    assert (out != image).any()


def test_batched_calibration_is_refused():
    cal = _calibration()
    batch = cal.apply(lambda t: torch.stack([t] * 2))
    image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for draw in (draw_frame_box, draw_axes, draw_calibration):
        with pytest.raises(ValueError, match="index the batch"):
            draw(image, batch)
    with pytest.raises(ValueError, match="index the batch"):
        frame_box_points(batch)
    assert draw_frame_box(image, batch[1]).any()
