"""The overlay's vanishing points (rings inside the image, arrows at the border towards the others) and the true
horizon drawn beside the estimate."""

import numpy as np
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.geometry import intrinsics_matrix, rotation_from_angles
from ngp_kornia.pipeline.answer import calibration_from_camera
from ngp_kornia.viz import AXIS_COLOURS, TRUTH_COLOUR, draw_calibration, draw_vanishing_points, truth_horizon


def _camera(pitch: float, yaw: float):
    K = intrinsics_matrix(torch.tensor([200.0]), torch.tensor([159.5, 119.5]))
    R = rotation_from_angles(torch.tensor([pitch]), torch.tensor([0.0]), torch.tensor([yaw]))
    return calibration_from_camera(K, R, torch.ones(1), torch.ones(1, dtype=torch.bool), 240, 320)[0]


def _near(image: np.ndarray, colour) -> np.ndarray:
    return np.abs(image.astype(int) - np.array(colour)).sum(-1) < 30


def test_a_vp_in_the_image_gets_a_ring_where_it_is():
    cal = _camera(0.0, 10.0)  # world z's VP is 35 px right of the centre, on the horizon
    vp = cal.vps[2]
    x, y = (vp[:2] / vp[2]).tolist()
    out = draw_vanishing_points(np.zeros((240, 320, 3), np.uint8), cal)
    ring = _near(out, AXIS_COLOURS[2])
    ys, xs = np.nonzero(ring)
    assert abs(xs.mean() - x) < 2 and abs(ys.mean() - y) < 2


def test_vps_off_the_image_get_arrows_at_the_border():
    cal = _camera(40.0, 45.0)  # every VP outside a 320x240 image
    out = draw_vanishing_points(np.zeros((240, 320, 3), np.uint8), cal)
    inner = np.zeros((240, 320), bool)
    inner[40:-40, 40:-40] = True
    for colour in AXIS_COLOURS:
        drawn = _near(out, colour)
        assert drawn.sum() > 20 and not (drawn & inner).any(), colour  # near the border only


def test_the_true_horizon_is_drawn_dashed_beside_the_estimate():
    cal = calibrate(torch.rand(3, 240, 320), weights="none")
    line = [0.0, 1.0, -60.0]  # y = 60
    out = draw_calibration(np.zeros((240, 320, 3), np.uint8), cal, truth={"horizon": line}, vps=False)
    row = _near(out[58:63], TRUTH_COLOUR).any(0)
    assert 0.3 < row.mean() < 0.8  # dashes: about half the row
    assert np.array_equal(truth_horizon(torch.tensor(line)), np.array(line))
    with pytest.raises(ValueError, match="true horizon"):
        truth_horizon({"horizon": [0.0, 0.0, 1.0]})
