"""How close the calibration gets to what the York Urban ground truth allows.

The York Urban ground truth (``vp_orthogonal``) was made from hand-labelled segments and the calibrated camera,
whose principal point is (307.6, 251.5), 12 px from the image centre in each direction. This benchmark scores,
with the same metrics as ``benchmarks/calibration.py``:

* the true up vector with the principal point at the image centre (what every method that assumes a centred
  principal point, as this package does, would report if its rotation were exact);
* the parser on LSD segments (what ``calibrate()`` does) and on the hand-labelled segments of the database, with
  each ``--weights`` spec: the gap between the two is what line detection costs;
* the least-squares Manhattan frame of the hand-labelled segments with their labels: the rotation (and the focal
  length, with the centred principal point) that minimises the length-weighted squared sine between each
  segment's interpretation plane and its direction. Started from the ground truth; it is the best a
  least-squares fit of perfect lines does against this ground truth;
* with ``--oracle-zenith DEG``: the parser on LSD segments with the zenith candidates weighted by the ground truth
  (1 where the candidate's up direction, through the true camera, is within DEG degrees of the true one; uniform
  where none is): what a perfect ZSNet would give the whole calibration.

Usage::

    python benchmarks/ceiling.py /path/to/YorkUrbanDB [--weights none] [--weights full] [--seeds 0,1,2,3,4]
                                 [--oracle-zenith 0.5 --oracle-zenith 2] [--gt published]

``--gt`` picks the horizon the AUCs are scored against (``calibrated``, the default, or ``published``, the line
through the two raw horizontal vanishing points; see :func:`ngp_kornia.evaluation.load_yud`). Up and FoV errors do
not depend on it.
"""

from __future__ import annotations

import argparse
import math
import statistics
from dataclasses import replace
from pathlib import Path

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from ngp_kornia.api import load_parser
from ngp_kornia.data.yud import YorkUrbanDB, load_labelled_segments
from ngp_kornia.evaluation import (
    YUD_HORIZONS,
    Estimate,
    LabelledImage,
    estimate_from_calibration,
    evaluate,
    load_yud,
    weights_and_config,
)
from ngp_kornia.geometry import (
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    pitch_roll_from_up,
    pseudo_focal,
    segment_lengths,
    zenith_from_up,
)
from ngp_kornia.io import read_image_file
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.segments import detect_segments


def estimate_from_camera(K: torch.Tensor, R: torch.Tensor, height: int) -> Estimate:
    up = -R[:, 1]
    pitch, roll = pitch_roll_from_up(up[None])
    horizon = horizon_from_zenith(K[None], zenith_from_up(K[None], up[None]))[0]
    return Estimate(up, horizon, float(pitch), float(roll), float(fov_from_focal(K[0, 0], height)))


def centred(K: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """K with its principal point moved to the image centre."""
    return intrinsics_matrix(K[0, 0][None], image_center(height, width, like=K[0, 0][None]))[0]


def least_squares_frame(
    segments: torch.Tensor, labels: torch.Tensor, K: torch.Tensor, R: torch.Tensor, free_focal: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation (and focal length) minimising sum_i len_i * (n_i . R[:, label_i])^2, n_i the unit normal of
    segment i's interpretation plane K^T l_i. Starts from (K, R); returns the fitted (K, R)."""
    ends = torch.cat([segments, torch.ones_like(segments[..., :1])], -1)
    lines = torch.linalg.cross(ends[:, 0], ends[:, 1])
    weights = segment_lengths(segments)
    rotvec = torch.zeros(3, dtype=R.dtype, requires_grad=True)
    log_f = torch.zeros((), dtype=R.dtype, requires_grad=True)

    def camera() -> tuple[torch.Tensor, torch.Tensor]:
        scale = torch.stack([log_f.exp(), log_f.exp(), log_f.new_ones(())])
        return K * scale[:, None], axis_angle_to_rotation_matrix(rotvec[None])[0] @ R

    def loss() -> torch.Tensor:
        K_, R_ = camera()
        sines = (normalize(lines @ K_) @ R_).gather(1, labels[:, None])[:, 0]
        return (weights * sines.square()).sum() / weights.sum() * 1e4  # scaled: LBFGS tolerances are absolute

    opt = torch.optim.LBFGS([rotvec, log_f] if free_focal else [rotvec], max_iter=100, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        value = loss()
        value.backward()
        return value

    opt.step(closure)
    with torch.no_grad():
        return camera()


def summary_row(name: str, runs: list[dict]) -> str:
    aucs = [100 * r["horizon_auc"] for r in runs]
    cells = [f"{statistics.mean(aucs):.2f}" + (f" ({min(aucs):.2f}-{max(aucs):.2f})" if len(aucs) > 1 else "")]
    for key in ("up", "fov_v"):
        if key in runs[0]["summary"]:
            mean = statistics.mean(r["summary"][key]["mean"] for r in runs)
            median = statistics.mean(r["summary"][key]["median"] for r in runs)
            cells.append(f"{mean:.2f} / {median:.2f}")
        else:
            cells.append("n.a.")
    return f"| {name} | " + " | ".join(cells) + " |"


class OracleZenithParser(NeuralGeometricParser):
    """The parser with its zenith candidates weighted by the ground truth instead of ZSNet (set ``true_K`` and
    ``true_up`` before each call): 1 within ``max_angle`` degrees of the true up direction, else 0."""

    def __init__(self, base: NeuralGeometricParser, max_angle: float, height: int, width: int) -> None:
        super().__init__(base.config, base.zsnet, base.fsnet)
        self.cos_limit = math.cos(math.radians(max_angle))
        f = torch.tensor([pseudo_focal(height, width)])
        self.K_pseudo = intrinsics_matrix(f, image_center(height, width, like=f))[0]  # pseudo camera -> pixels
        self.true_K = self.true_up = None

    def zenith_weights(self, lines_z, lines_z_ok, zenith, zenith_ok):
        pixels = zenith.double() @ self.K_pseudo.double().T
        up = normalize(pixels @ torch.linalg.inv(self.true_K).T)
        near = zenith_ok & ((up @ self.true_up).abs() > self.cos_limit)
        return torch.where(near.any(-1, keepdim=True), near, zenith_ok).to(zenith)


def with_mask(segments: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return segments, torch.ones(segments.shape[:2], dtype=torch.bool)


def parser_for(spec: str) -> NeuralGeometricParser:
    return load_parser(*weights_and_config(spec))


def seed_runs(parser: NeuralGeometricParser, samples: list[LabelledImage], seeds: list[int], inputs, before=None):
    """:func:`evaluate` of the parser on every image, once per seed; ``inputs(i)`` gives image i's
    (image, segments, mask) and ``before(parser, i)``, when given, runs before each call."""
    runs = []
    base = parser.config
    for seed in seeds:
        parser.config = replace(base, seed=seed)
        estimates = []
        for i in range(len(samples)):
            if before is not None:
                before(parser, i)
            image, seg, mask = inputs(i)
            with torch.no_grad():
                out = parser(image.float(), seg.float(), mask)
            estimates.append(estimate_from_calibration(out[0]))
        runs.append(evaluate(samples, estimates))
    parser.config = base
    return runs


def read_inputs(samples: list[LabelledImage]) -> tuple[list, list, list]:
    """Each image as a (1, 3, H, W) tensor, its LSD segments as calibrate() finds them, its hand-labelled ones."""
    images, detected, labelled = [], [], []
    for s in samples:
        rgb = read_image_file(s.image_path)
        images.append(torch.from_numpy(rgb).permute(2, 0, 1)[None].double() / 255.0)
        detected.append(detect_segments(rgb, ParserConfig()))
        labelled.append(load_labelled_segments(s.image_path.parent / f"{s.name}LinesAndVP.mat"))
    return images, detected, labelled


def parser_rows(spec: str, samples, inputs: tuple[list, list, list], seeds: list[int], oracle_angles) -> list[str]:
    """Rows of the parser under one weights spec: on LSD and on hand-labelled segments, and with oracle zeniths."""
    images, detected, labelled = inputs
    parser = parser_for(spec)
    rows = []
    runs = seed_runs(parser, samples, seeds, lambda i: (images[i], *detected[i]))
    rows.append(summary_row(f"parser ({spec}) on LSD segments", runs))
    runs = seed_runs(parser, samples, seeds, lambda i: (images[i], *with_mask(labelled[i][0][None])))
    rows.append(summary_row(f"parser ({spec}) on hand-labelled segments", runs))
    for max_angle in oracle_angles:
        oracle = OracleZenithParser(parser, max_angle, samples[0].height, samples[0].width)

        def set_truth(model, i):
            model.true_K, model.true_up = samples[i].K, samples[i].up

        runs = seed_runs(oracle, samples, seeds, lambda i: (images[i], *detected[i]), set_truth)
        name = f"parser ({spec}) on LSD segments, zenith candidates within {max_angle:g} deg of the truth"
        rows.append(summary_row(name, runs))
    return rows


def least_squares_rows(samples, rotations, labelled) -> list[str]:
    rows = []
    for label, free_focal, use_centre in (
        ("true K", False, False),
        ("principal point at the image centre, focal fitted", True, True),
    ):
        estimates = []
        for s, R0, (seg, labels) in zip(samples, rotations, labelled, strict=True):
            K0 = centred(s.K, s.height, s.width) if use_centre else s.K
            K, R = least_squares_frame(seg, labels, K0, R0, free_focal)
            estimates.append(estimate_from_camera(K, R, s.height))
        rows.append(
            summary_row(f"least-squares frame of the hand-labelled segments, {label}", [evaluate(samples, estimates)])
        )
    return rows


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--weights", action="append", default=None, help="weight spec as in calibration.py; repeatable")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated sampling seeds (results are averaged)")
    ap.add_argument("--gt", choices=YUD_HORIZONS, default="calibrated", help="ground-truth horizon of the AUCs")
    ap.add_argument(
        "--oracle-zenith", type=float, action="append", default=[], help="add rows with ground-truth zenith weights"
    )
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(1)
    samples = load_yud(args.root, horizon=args.gt)
    rotations = [s.R for s in YorkUrbanDB(args.root)]  # same images, same order; column 1 = world down
    seeds = [int(s) for s in args.seeds.split(",")]
    # the exact rotation, reported through a centred principal point
    exact = [
        estimate_from_camera(centred(s.K, s.height, s.width), R, s.height)
        for s, R in zip(samples, rotations, strict=True)
    ]
    rows = [summary_row("true rotation and focal, principal point at the image centre", [evaluate(samples, exact)])]
    inputs = read_inputs(samples)
    for spec in args.weights or ["none"]:
        rows += parser_rows(spec, samples, inputs, seeds, args.oracle_zenith)
    rows += least_squares_rows(samples, rotations, inputs[2])
    print(f"York Urban DB: {len(samples)} images ({args.root}), {args.gt} horizon; seeds {seeds}")
    print(f"torch {torch.__version__}")
    print()
    print("| estimate | horizon AUC (%) mean (range) | up error (deg) mean / median | FoV_v error (deg) mean / med. |")
    print("|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
