"""The Neural Geometric Parser pipeline as an ``nn.Module``: segments -> zenith candidates -> horizontal VP
candidates -> Manhattan frames -> scores -> top-k calibration.

Without networks this is the paper's geometric baseline: zenith candidates count uniformly (instead of ZSNet's
scores) and frames are ranked by the Manhattan score ``m_i`` of Eq. 21 alone (instead of ``s_vh * m_i``). With
FSNet, the best ``num_scored`` frames by Manhattan score are scored again from the image (Eq. 22); gradients then
flow from the outputs to FSNet's parameters and to the image's pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ngp_kornia.detect import detect_segments
from ngp_kornia.geometry import (
    angles_from_rotation,
    canonical_manhattan_rotation,
    dominant_eigenvector,
    fov_from_focal,
    frame_manhattan_scores,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    pitch_roll_from_up,
    pseudo_focal,
    rotation_from_vps,
    segment_lengths,
    segments_to_lines,
    structure_tensor,
    to_pseudo_camera,
    topk_weighted_average,
    vanishing_points_from_rotation,
    weighted_structure_tensor,
    zenith_from_up,
)
from ngp_kornia.models.refine import refine_horizon
from ngp_kornia.models.result import Calibration
from ngp_kornia.sampling import (
    FrameCandidates,
    cat_frames,
    horizontal_line_mask,
    sample_frames,
    sample_horizontal_pair_frames,
    sample_horizontal_vps,
    sample_zenith_candidates,
    select_frames,
    split_by_pseudo_horizon,
    top_frames,
)

__all__ = ["NeuralGeometricParser", "ParserConfig"]


@dataclass
class ParserConfig:
    """Settings of the pipeline; the defaults are the paper's where it gives them.

    Attributes:
        working_size: LSD runs at this long side, in pixels.
        min_length: shorter segments (working-resolution pixels) are dropped.
        max_segments: at most this many segments per image, the longest kept (512 keeps the cost of scoring
            frames well under the line detector's; 1024 is 0.1 points of horizon AUC better on the York Urban half).
        num_zenith_lines: |L_z|.
        num_zenith: |Z|.
        vertical_threshold: delta_z of Eq. 4, degrees.
        zenith_threshold: delta_c of Eq. 12.
        vertical_tol: a segment within this angle (degrees) of the ray to the zenith estimate counts as vertical in
            the junction filter.
        junction_radius: endpoint distance for a junction, in units of half the image's long side.
        num_horizontal: horizontal VP candidates (half per group).
        num_frames: Manhattan-frame candidates from a zenith and a horizontal VP (the paper's) per image.
        num_horizontal_frames: further candidates from two horizontal VPs, which fix the focal length of a level
            camera (zenith at infinity), where a zenith and a horizontal VP cannot; 0 disables them.
        focal_range: allowed focal lengths, in units of half the image's long side.
        kernel_angle: width of the sharp closeness kernel of the Manhattan score, degrees.
        top_k: k of Eq. 23.
        num_scored: frames FSNet scores per image, the best by Manhattan score (unused without FSNet).
        use_manhattan: with FSNet, the final score is ``s_vh * m_i`` (Eq. 22); False uses ``s_vh`` alone.
        fallback_fov: long-side field of view (degrees) reported when an image has no valid frame.
        seed: seed of the candidate sampling; every call with the same input gives the same result.
        refine_horizon: after the frame search, move the horizon (and the focal length) to the one that the
            segments support best, searching horizontal VPs of every building block along it
            (:mod:`ngp_kornia.models.refine`); measured better on real photos, see BENCHMARKS.md.
    """

    working_size: int = 640
    min_length: float = 10.0
    max_segments: int = 512
    num_zenith_lines: int = 256
    num_zenith: int = 256
    vertical_threshold: float = 67.5
    zenith_threshold: float = 0.5
    vertical_tol: float = 5.0
    junction_radius: float = 0.03
    num_horizontal: int = 256
    num_frames: int = 1024
    num_horizontal_frames: int = 512
    focal_range: tuple[float, float] = (0.8, 4.0)
    kernel_angle: float = 89.0
    top_k: int = 8
    num_scored: int = 16
    use_manhattan: bool = True
    fallback_fov: float = 60.0
    seed: int = 0
    refine_horizon: bool = True


class NeuralGeometricParser(nn.Module):
    """Single-image calibration of a Manhattan / Atlanta-world scene.

    Args:
        config: pipeline settings.
        zsnet: a :class:`~ngp_kornia.models.zsnet.ZSNet` scoring the zenith candidates; None weights every valid
            candidate equally (the geometric path).
        fsnet: an :class:`~ngp_kornia.models.fsnet.FSNet` scoring the best frames; None ranks the frames by the
            Manhattan score alone.

    Example:
        >>> img = torch.rand(1, 3, 96, 128)
        >>> out = NeuralGeometricParser()(img)
        >>> out.K.shape, out.horizon.shape, bool(torch.isfinite(out.focal).all())
        (torch.Size([1, 3, 3]), torch.Size([1, 3]), True)
    """

    def __init__(
        self, config: ParserConfig | None = None, zsnet: nn.Module | None = None, fsnet: nn.Module | None = None
    ) -> None:
        super().__init__()
        self.config = config or ParserConfig()
        self.zsnet = zsnet
        self.fsnet = fsnet

    def forward(self, images: Tensor, segments: Tensor | None = None, mask: Tensor | None = None) -> Calibration:
        """Calibrate a batch.

        Args:
            images: (B, 3, H, W) float RGB in [0, 1].
            segments: optional (B, N, 2, 2) precomputed segments in the images' pixels (skips LSD).
            mask: (B, N) bool, required with ``segments``.

        Returns:
            a batched :class:`Calibration`.
        """
        cfg = self.config
        height, width = images.shape[-2:]
        if segments is None:
            segments, mask = detect_segments(images, cfg.working_size, cfg.min_length, cfg.max_segments)
        elif mask is None:
            raise ValueError("segments were given without their (B, N) mask; pass mask=torch.ones(B, N, dtype=bool)")
        segments = segments.to(images)
        if segments.shape[1] == 0:  # no lines anywhere in the batch: one masked dummy keeps every shape non-empty
            segments, mask = segments.new_zeros(len(images), 1, 2, 2), mask.new_zeros(len(images), 1)
        generator = torch.Generator().manual_seed(cfg.seed)
        frames, scores = self.score_frames(segments, mask, height, width, generator)
        if self.fsnet is not None:
            frames, scores = self.rescore_frames(images, segments, mask, frames, scores)
        out = self.calibrate_from_frames(frames, scores, height, width)
        return refine_horizon(out, segments, mask) if cfg.refine_horizon else out

    def score_frames(
        self, segments: Tensor, mask: Tensor, height: int, width: int, generator: torch.Generator
    ) -> tuple[FrameCandidates, Tensor]:
        """Sample frame candidates (pseudo camera) and score each one: (B, F) scores, zero for invalid frames."""
        cfg = self.config
        seg = to_pseudo_camera(segments, height, width)
        lines = segments_to_lines(seg)
        lengths = segment_lengths(segments) * mask.to(segments)
        lines_z, lines_z_ok, zenith, zenith_ok = sample_zenith_candidates(
            lines, lengths, mask, cfg.num_zenith_lines, cfg.num_zenith, cfg.vertical_threshold, generator
        )
        weights = self.zenith_weights(lines_z, lines_z_ok, zenith, zenith_ok)
        z_est = dominant_eigenvector(weighted_structure_tensor(zenith, weights))
        horizontal = horizontal_line_mask(seg, mask, z_est, cfg.vertical_tol, cfg.junction_radius)
        right = split_by_pseudo_horizon(lines, z_est)
        h_vps, h_ok = sample_horizontal_vps(lines, lengths, horizontal, right, cfg.num_horizontal, generator)
        frames = sample_frames(zenith, weights, h_vps, h_ok, cfg.num_frames, cfg.focal_range, generator)
        if cfg.num_horizontal_frames > 0:
            pairs = sample_horizontal_pair_frames(h_vps, h_ok, cfg.num_horizontal_frames, cfg.focal_range, generator)
            frames = cat_frames(frames, pairs)
        scores = frame_manhattan_scores(lines, frames.vps, lengths, mask, cfg.kernel_angle)
        return frames, torch.where(frames.valid, scores, torch.zeros_like(scores))

    def rescore_frames(
        self, images: Tensor, segments: Tensor, mask: Tensor, frames: FrameCandidates, manhattan: Tensor
    ) -> tuple[FrameCandidates, Tensor]:
        """Keep the best ``num_scored`` frames by Manhattan score and score them with FSNet: ``s_vh * m_i`` (Eq. 22),
        or ``s_vh`` alone without ``use_manhattan``. Returns the kept frames and their (B, K) scores."""
        cfg = self.config
        index = top_frames(frames, manhattan, cfg.num_scored)
        frames, manhattan = select_frames(frames, index), manhattan.gather(1, index)
        # FSNet runs in its own dtype (float32 weights on a float64 image, say)
        dtype = next(self.fsnet.parameters()).dtype
        inputs = self.fsnet.prepare_inputs(images.to(dtype), segments.to(dtype), mask, frames)
        s_vh = torch.sigmoid(self.fsnet(*inputs)).to(manhattan)
        scores = s_vh * manhattan if cfg.use_manhattan else s_vh
        return frames, torch.where(frames.valid, scores, torch.zeros_like(scores))

    def zenith_weights(self, lines_z: Tensor, lines_z_ok: Tensor, zenith: Tensor, zenith_ok: Tensor) -> Tensor:
        """Weights of the zenith candidates: the ZSNet score p_z on Z_c (p_z > delta_c, Eq. 12) and zero elsewhere;
        without ZSNet, or where no candidate passes delta_c, every valid candidate counts equally. (B, Z)."""
        ok = zenith_ok.to(zenith)
        if self.zsnet is None:
            return ok
        scores = torch.sigmoid(self.zsnet(lines_z, lines_z_ok, zenith)) * ok
        weights = scores * (scores > self.config.zenith_threshold)
        return torch.where((weights > 0).any(-1, keepdim=True), weights, ok)

    def calibrate_from_frames(self, frames: FrameCandidates, scores: Tensor, height: int, width: int) -> Calibration:
        """Top-k average (Eq. 23) of focal and zenith, yaw from the best frame, everything mapped to pixels."""
        cfg = self.config
        valid = frames.valid.any(-1)
        focal, _ = topk_weighted_average(scores, frames.focal, cfg.top_k, frames.valid)
        st, _ = topk_weighted_average(scores, structure_tensor(frames.zenith), cfg.top_k, frames.valid)
        zenith = dominant_eigenvector(st)
        best = scores.argmax(-1)
        horizontal = frames.horizontal[torch.arange(len(best)), best]
        fallback = 1.0 / math.tan(math.radians(cfg.fallback_fov) / 2.0)
        focal = torch.where(valid, focal, torch.full_like(focal, fallback))
        level = torch.tensor([0.0, 1.0, 0.0]).to(zenith)
        zenith = torch.where(valid[:, None], zenith, level)
        horizontal = torch.where(valid[:, None], horizontal, torch.tensor([1.0, 0.0, 0.0]).to(zenith))
        # the pseudo camera has K = diag(f, f, 1); pixels need K_p = [[f_p, 0, c], [0, f_p, c], [0, 0, 1]]
        K_unit = intrinsics_matrix(focal, zenith.new_zeros(2))
        R = canonical_manhattan_rotation(rotation_from_vps(K_unit, zenith, horizontal))
        f_px = focal * pseudo_focal(height, width)
        K = intrinsics_matrix(f_px, image_center(height, width, like=f_px))
        return self._result(K, R, scores.amax(-1), valid, height, width)

    @staticmethod
    def _result(K: Tensor, R: Tensor, score: Tensor, valid: Tensor, height: int, width: int) -> Calibration:
        up = -R[..., :, 1]
        zenith = zenith_from_up(K, up)
        zenith = zenith / zenith.norm(dim=-1, keepdim=True)
        pitch, roll = pitch_roll_from_up(up)
        _, _, yaw = angles_from_rotation(R)
        f = K[:, 0, 0]
        size = torch.tensor([height, width], device=K.device).expand(len(f), 2)
        return Calibration(
            K=K,
            R=R,
            focal=f,
            fov_v=fov_from_focal(f, height),
            fov_h=fov_from_focal(f, width),
            pitch=pitch,
            roll=roll,
            yaw=yaw,
            up=up,
            zenith=zenith,
            horizon=horizon_from_zenith(K, zenith),
            vps=vanishing_points_from_rotation(K, R),
            score=score,
            valid=valid,
            image_size=size,
        )
