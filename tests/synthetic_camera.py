"""Synthetic pinhole cameras and test grids shared by the geometry and sampling tests."""

from ngp_kornia.geometry.camera import image_center, intrinsics_matrix, rotation_from_angles

BATCHES = [1, 2, 5]
H, W = 480, 640


def camera_from_angles(pitch, roll, yaw, focal, h=H, w=W):
    """Intrinsics K with the principal point at the image centre and rotation R from (pitch, roll, yaw) in degrees.

    All inputs are (B,) tensors; K has focal's dtype and R the angles' dtype.
    """
    K = intrinsics_matrix(focal, image_center(h, w, like=focal))
    return K, rotation_from_angles(pitch, roll, yaw)
