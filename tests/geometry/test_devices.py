"""Every public geometry function on every device and dtype: outputs stay on the input's device and dtype, are
finite, and agree with the float64 CPU result (the README promises any device)."""

import pytest
import torch

from ngp_kornia import geometry as G
from ngp_kornia.pipeline import NeuralGeometricParser
from tests.synthetic_camera import H, W, camera_from_angles


def _inputs(device: torch.device, dtype: torch.dtype) -> dict:
    g = torch.Generator().manual_seed(0)
    pitch, roll, yaw = torch.tensor([8.0, -12.0]), torch.tensor([3.0, -5.0]), torch.tensor([20.0, -35.0])
    K, R = camera_from_angles(pitch, roll, yaw, torch.tensor([500.0, 700.0]))
    segments = torch.rand(2, 6, 2, 2, generator=g) * torch.tensor([W - 1.0, H - 1.0])
    values = {
        "K": K,
        "R": R,
        "pitch": pitch,
        "roll": roll,
        "segments": segments,
        "mask": torch.tensor([[True] * 6, [True] * 4 + [False] * 2]),
        "vps": G.normalize(torch.randn(2, 5, 3, 3, generator=g)),
        "scores": torch.rand(2, 5, generator=g),
        "weights": torch.rand(2, 6, generator=g),
        "points": torch.randn(2, 6, 3, generator=g),
        "images": torch.rand(2, 3, 24, 32, generator=g),
    }
    return {k: v.to(device) if v.dtype == torch.bool else v.to(device, dtype) for k, v in values.items()}


def _lines(x):
    return G.segments_to_lines(G.to_pseudo_camera(x["segments"], H, W))


CASES = {
    "intrinsics_matrix": lambda x: G.intrinsics_matrix(x["K"][:, 0, 0], G.image_center(H, W, like=x["K"])),
    "fov_focal": lambda x: G.focal_from_fov(G.fov_from_focal(x["K"][:, 0, 0], H), H),
    "rotation_from_angles": lambda x: G.rotation_from_angles(x["pitch"], x["roll"]),
    "angles_from_rotation": lambda x: torch.stack(G.angles_from_rotation(x["R"]), -1),
    "pitch_roll_from_up": lambda x: torch.stack(G.pitch_roll_from_up(G.up_from_rotation(x["R"])), -1),
    "zenith_up": lambda x: G.up_from_zenith(x["K"], G.zenith_from_up(x["K"], G.up_from_rotation(x["R"]))),
    "horizon": lambda x: G.horizon_border_points(
        G.horizon_from_zenith(x["K"], G.zenith_from_up(x["K"], G.up_from_rotation(x["R"]))), W
    ),
    "zenith_from_horizon": lambda x: G.zenith_from_horizon(x["K"], G.horizon_from_zenith(x["K"], x["R"][..., 1])),
    "vanishing_points": lambda x: G.vanishing_points_from_rotation(x["K"], x["R"]),
    "focal_from_orthogonal_vps": lambda x: G.focal_from_orthogonal_vps(
        *G.vanishing_points_from_rotation(x["K"], x["R"]).unbind(1)[:2], x["K"][:, :2, 2]
    )[0],
    "rotation_from_vps": lambda x: G.canonical_manhattan_rotation(
        G.rotation_from_vps(x["K"], *G.vanishing_points_from_rotation(x["K"], x["R"]).unbind(1)[1::-1])
    ),
    "rectify_homographies": lambda x: torch.stack(
        [G.level_homography(x["K"], x["R"]), G.upright_homography(x["K"], x["R"]), G.frontal_homography(x["K"], x["R"])]
    ),
    "rectify": lambda x: G.rectify(x["images"], torch.eye(3, device=x["K"].device).expand(2, 3, 3))[0],
    "segment_lengths": lambda x: G.segment_lengths(x["segments"]),
    "lines_and_vertical": lambda x: _lines(x) * G.is_near_vertical(_lines(x))[..., None],
    "intersect_lines": lambda x: G.normalize(G.intersect_lines(_lines(x)[:, :3], _lines(x)[:, 3:])),
    "cossim": lambda x: G.cossim(x["points"], x["points"].flip(1)),
    "homogeneous_to_pseudo_camera": lambda x: G.homogeneous_to_pseudo_camera(x["points"], H, W),
    "structure_tensor": lambda x: G.dominant_eigenvector(G.weighted_structure_tensor(x["points"], x["weights"])),
    "closeness": lambda x: torch.stack([G.closeness(_lines(x), x["vps"]), G.closeness(_lines(x), x["vps"], 89.0)]),
    "closeness_of": lambda x: torch.stack([G.closeness_of(G.line_vp_cosine(_lines(x), x["vps"]) ** 2, 5.0, m)
                                           for m in G.CLOSENESS_MEASURES]),
    "segment_vp_angle": lambda x: G.segment_vp_angle(G.to_pseudo_camera(x["segments"], H, W), x["vps"][:, :, 0]),
    "frame_manhattan_scores": lambda x: G.frame_manhattan_scores(
        _lines(x), x["vps"], G.segment_lengths(x["segments"]), x["mask"]
    ),
    "topk_weighted_average": lambda x: G.topk_weighted_average(x["scores"], x["vps"], 2)[0],
    "line_maps": lambda x: G.manhattan_score_maps(
        G.line_map(x["segments"], x["mask"], H // 8, W // 8),
        G.closeness_maps(x["segments"] / 8, x["mask"], G.closeness(_lines(x), x["vps"][:, 0], 89.0), H // 8, W // 8),
    ),
    "pooled_maps": lambda x: G.line_map_and_pooled_maps(
        x["segments"] / 8, x["mask"], x["weights"][..., None], H // 8, W // 8, 4
    )[1],
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_geometry_keeps_device_and_dtype(name, device, dtype):
    out = CASES[name](_inputs(device, dtype))
    assert out.device.type == device.type and out.dtype == dtype
    assert bool(torch.isfinite(out).all())
    reference = CASES[name](_inputs(torch.device("cpu"), torch.float64))
    tol = 1e-3 if dtype == torch.float32 else 1e-8
    torch.testing.assert_close(out.cpu().double(), reference, atol=tol, rtol=tol)


def test_parser_runs_on_the_device(device, dtype):
    from tests.pipeline.test_parser import manhattan_segments

    segments, mask, focal, (h, w) = manhattan_segments(10.0, -5.0, 25.0)
    images = torch.zeros(1, 3, h, w, device=device, dtype=dtype)
    cal = NeuralGeometricParser()(images, segments.to(device), mask.to(device))
    assert cal.K.device.type == device.type and cal.K.dtype == dtype
    assert cal.focal.item() == pytest.approx(focal, rel=0.02)
