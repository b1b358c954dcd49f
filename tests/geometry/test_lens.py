"""The division model of radial distortion and OpenCV's polynomial closest to it."""

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.geometry.lens import distort_points, opencv_radial, undistort_points

K = torch.tensor([[[400.0, 0.0, 321.0], [0.0, 400.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)


def _grid(count: int = 15) -> torch.Tensor:
    xs, ys = torch.meshgrid(torch.linspace(0, 639, count), torch.linspace(0, 479, count), indexing="xy")
    return torch.stack([xs, ys], -1).reshape(1, -1, 2).double()


@pytest.mark.parametrize("k1", [-0.3, -0.05, 0.0, 0.1])
def test_distort_inverts_undistort(k1):
    points = _grid()
    again = distort_points(undistort_points(points, K, torch.tensor([k1])), K, torch.tensor([k1]))
    # two closed forms of one model in float64: equal to rounding
    assert torch.allclose(again, points, atol=1e-9)


def test_convention_barrel_distortion_has_negative_k1():
    # k1 < 0: the photo's points lie closer to the centre than the pinhole's, so undistorting moves them outwards
    corner = torch.tensor([[[0.0, 0.0]]], dtype=torch.float64)
    moved = undistort_points(corner, K, torch.tensor([-0.2]))
    centre = K[0, :2, 2]
    assert float((moved[0, 0] - centre).norm()) > float((corner[0, 0] - centre).norm())
    assert torch.equal(undistort_points(corner, K, torch.tensor([0.0])), corner)


def test_opencv_coefficients_undistort_like_the_division_model():
    k1 = torch.tensor([-0.2])
    radial = opencv_radial(k1, K, 480, 640)[0].tolist()
    dist = np.array([radial[0], radial[1], 0.0, 0.0, radial[2]])
    points = _grid()
    rays = (undistort_points(points, K, k1)[0] - K[0, :2, 2]) / K[0, 0, 0]  # the division model's pinhole rays
    rays = np.concatenate([rays.numpy(), np.ones((len(rays), 1))], 1)
    # OpenCV distorts them (in closed form) back onto the photo's pixels
    theirs = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K[0].numpy(), dist)[0][:, 0]
    # a three-term polynomial fitted to another model over the image, at a strong distortion (70 px at the
    # corners): within 0.15 px everywhere on it
    assert np.abs(theirs - points[0].numpy()).max() < 0.15
    assert opencv_radial(torch.tensor([0.0]), K, 480, 640).abs().max() == 0
