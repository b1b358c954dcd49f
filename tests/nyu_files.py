"""NYU-VP folders written for the tests: scenes of a known camera with NYU's intrinsics, in the set's file layout."""

from pathlib import Path

import numpy as np
import torch

from ngp_kornia.data import NYU_K
from ngp_kornia.geometry.camera import rotation_from_angles, vanishing_points_from_rotation

HEADER_LINES = ("line_hom_a line_hom_b line_hom_c centroid_x centroid_y centroid_z point1_x point1_y point1_z "
                "point2_x point2_y point2_z")


def true_vps(pitch: float, roll: float, yaw: float) -> np.ndarray:
    """The three vanishing points (pixels, z = 1) of a camera with NYU's K, the vertical one second."""
    R = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (pitch, roll, yaw)))
    vps = vanishing_points_from_rotation(NYU_K[None], R)[0]
    return (vps[:, :2] / vps[:, 2:]).numpy()


def write_scene(root: Path, index: int, vps: np.ndarray, segments: list, labelled: dict) -> None:
    data = root / "data"
    data.mkdir(parents=True, exist_ok=True)
    tag = f"{index:04d}"
    (data / f"vps_{tag}.csv").write_text("idx X Y\n" + "".join(f"{i} {x} {y}\n" for i, (x, y) in enumerate(vps)))
    rows = []
    for (x0, y0), (x1, y1) in segments:
        line = np.cross([x0, y0, 1.0], [x1, y1, 1.0])
        rows.append(" ".join(map(str, [*line, (x0 + x1) / 2, (y0 + y1) / 2, 1.0, x0, y0, 1.0, x1, y1, 1.0])))
    (data / f"lsd_lines_{tag}.csv").write_text(HEADER_LINES + "\n" + "\n".join(rows) + "\n")
    header = "idx " + " ".join(f"line{k}_x1 line{k}_y1 line{k}_x2 line{k}_y2" for k in range(1, 4))
    body = "".join(f"{i} " + " ".join(str(v) for seg in segs for v in seg) + "    \n" for i, segs in labelled.items())
    (data / f"labelled_lines_{tag}.csv").write_text(header + "\n" + body)



def segments_towards(vps: np.ndarray, per_vp: int, seed: int = 0) -> list:
    """``per_vp`` segments 60 px long pointing at each vanishing point, at random places in a 640x480 image."""
    rng = np.random.default_rng(seed)
    out = []
    for vp in vps:
        for mid in rng.uniform([60.0, 60.0], [580.0, 420.0], (per_vp, 2)):
            d = (vp - mid) / np.linalg.norm(vp - mid)
            out.append((tuple(mid - 30 * d), tuple(mid + 30 * d)))
    return out


def write_fake_nyu(root: Path, scenes: int = 2) -> Path:
    """Scene 0: pitch -10, roll 3, yaw 25 degrees, three segments (one at the zenith, one at a horizontal VP, one
    short and pointing nowhere) and 12 more at each vanishing point; scene 1: two horizontal VPs only (no horizon
    truth); scenes 2.. repeat scene 0's camera with other yaws."""
    vps = true_vps(-10.0, 3.0, 25.0)
    mid = np.array([300.0, 240.0])
    towards = [(vps[j] - mid) / np.linalg.norm(vps[j] - mid) for j in (1, 0)]
    segments = [(tuple(mid - 40 * d), tuple(mid + 40 * d)) for d in towards] + [((10.0, 10.0), (16.0, 24.0))]
    labelled = {0: [[1, 2, 3, 4]], 1: [[5, 6, 7, 8], [9, 10, 11, 12]]}
    write_scene(root, 0, vps, segments + segments_towards(vps, 12), labelled)
    flat = np.array([[2000.0, 250.0], [-1500.0, 260.0]])
    write_scene(root, 1, flat, segments[:1], {0: []})
    for index in range(2, scenes):
        more = true_vps(-10.0, 3.0, 25.0 + 7 * index)
        write_scene(root, index, more, segments + segments_towards(more, 12, index), {0: []})
    return root
