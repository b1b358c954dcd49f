"""The intermediate stages of one :class:`~ngp_kornia.pipeline.NeuralGeometricParser` call, as typed tensors:
``parser(images, return_trace=True)`` returns ``(calibration, trace)``. Notebooks and benchmarks read the stages
here instead of rebuilding them from the sampling functions.

Coordinates: ``segments`` are in the input's pixels; every line, VP and focal length after them is in the pseudo
camera (principal point at the image centre, unit = ``pseudo_focal(height, width)`` pixels, Eq. 1-2).
"""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from ngp_kornia.geometry.frames import FrameCandidates

__all__ = ["ParserTrace"]


@dataclass
class ParserTrace:
    """What the parser computed on its way to a :class:`~ngp_kornia.pipeline.Calibration` (B images, N segments,
    L near-vertical lines, Z zenith candidates, H horizontal VP candidates, F frame candidates, K frames scored by
    FSNet).

    Attributes:
        segments: (B, N, 2, 2) the line segments used, in input pixels (detected or given).
        mask: (B, N) bool, False for padding and for the segments the line evidence dropped.
        lines: (B, N, 3) the segments' homogeneous lines in the pseudo camera (Eq. 1-2).
        zenith_lines: (B, L, 3) the near-vertical lines L_z sampled for the zenith candidates (Eq. 3-4).
        zenith_lines_ok: (B, L) bool.
        zenith_candidates: (B, Z, 3) the zenith candidates Z (intersections of pairs of L_z).
        zenith_ok: (B, Z) bool.
        zenith_weights: (B, Z) the weights of the candidates in the zenith estimate: ZSNet's ``p_z`` on Z_c and zero
            elsewhere (Eq. 12), or uniform on the valid ones (no ZSNet, or no candidate above the threshold).
        zenith_estimate: (B, 3) z_est, the dominant direction of the weighted structure tensor (Eq. 10-12).
        horizontal: (B, N) bool, the segments used for the horizontal VPs (junction filter, Fig. 3).
        right: (B, N) bool, the segments crossing the pseudo-horizon right of the pivot (the line through z_est
            and the image centre): the second of the two groups of horizontal lines (Fig. 3); the rest are left.
        horizontal_vps: (B, H, 3) horizontal VP candidates (both pseudo-horizon groups together).
        horizontal_ok: (B, H) bool.
        frames: (B, F) every Manhattan-frame candidate sampled: ``zenith``, ``horizontal``, ``focal`` (per frame,
            pseudo-camera units), ``R``, ``vps``, ``valid``.
        manhattan: (B, F) the Manhattan score m_i of each frame (Eq. 21), zero for invalid frames.
        scored_index: (B, K) indices into ``frames`` of the frames FSNet scored (the best ``num_scored`` by
            ``manhattan``); None without FSNet.
        fsnet_scores: (B, K) FSNet's s_vh of those frames; None without FSNet.
        final_frames: (B, F') the frames the answer is chosen from: ``frames`` selected by ``scored_index`` with
            FSNet (F' = K), ``frames`` itself without (F' = F).
        final_scores: (B, F') their final scores: ``s_vh * m_i`` (Eq. 22) or ``s_vh`` with FSNet, ``m_i`` without;
            zero for invalid frames. ``final_scores.amax(-1)`` is the calibration's ``score``.
        top_k_weights: (B, F') weights of the top-k average of focal length and zenith (Eq. 23): zero outside the
            top ``top_k`` valid frames, summing to 1 where any frame is valid.
        best: (B,) index into ``final_frames`` of the best frame, whose horizontal VP fixes the yaw.
        evidence: (B, N) the line evidence's structure weight of every segment (0 for padding); None where the stage
            is off.
        detected: (B, N) bool, the segments before the line evidence (the mask of ``segments`` as detected or given).
    """

    segments: Tensor
    mask: Tensor
    lines: Tensor
    zenith_lines: Tensor
    zenith_lines_ok: Tensor
    zenith_candidates: Tensor
    zenith_ok: Tensor
    zenith_weights: Tensor
    zenith_estimate: Tensor
    horizontal: Tensor
    right: Tensor
    horizontal_vps: Tensor
    horizontal_ok: Tensor
    frames: FrameCandidates
    manhattan: Tensor
    final_frames: FrameCandidates
    final_scores: Tensor
    top_k_weights: Tensor
    best: Tensor
    scored_index: Tensor | None = None
    fsnet_scores: Tensor | None = None
    evidence: Tensor | None = None
    detected: Tensor | None = None
