"""The frame search: the parser's stages after the line evidence, for a camera centred on its image without
distortion (:mod:`~ngp_kornia.pipeline.camera_model` brings every photo to that camera first).

zenith, horizontal-VP and frame candidates (:mod:`~ngp_kornia.pipeline.candidates`, scored by ZSNet where given)
-> Manhattan scores, rescored by FSNet where given (Eq. 22) -> the top-k answer (:mod:`~ngp_kornia.pipeline.answer`)
-> optional polish (:mod:`~ngp_kornia.pipeline.polish`) -> horizon search and choice
(:mod:`~ngp_kornia.pipeline.horizon`) -> trust fields (:mod:`~ngp_kornia.pipeline.trust`).

:class:`FrameSearch` is the stage object: it holds the settings, the networks and the seed, and each call returns
what it computed (:class:`Search`), from which the parser's trace is made.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import NamedTuple

import torch
from torch import Tensor, nn

from ngp_kornia.geometry import (
    FrameCandidates,
    frame_manhattan_scores,
    segment_lengths,
    segments_to_lines,
    select_frames,
    to_pseudo_camera,
    top_frames,
)
from ngp_kornia.nets.fsnet_inputs import FSNetImageInputs, frame_scores
from ngp_kornia.nets.zsnet import zenith_estimate, zenith_weights_from_scores
from ngp_kornia.pipeline.answer import calibration_from_camera, topk_calibration
from ngp_kornia.pipeline.candidates import (
    Generators,
    horizontal_line_mask,
    sample_candidate_frames,
    sample_horizontal_vps,
    sample_zenith_candidates,
    split_by_pseudo_horizon,
)
from ngp_kornia.pipeline.gravity import allowed_ups, gravity_frame_scores, gravity_zenith_weights
from ngp_kornia.pipeline.horizon import choose_horizon, search_horizon
from ngp_kornia.pipeline.polish import polish_frame
from ngp_kornia.pipeline.priors import Priors
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import strip_threads
from ngp_kornia.pipeline.settings import ParserConfig
from ngp_kornia.pipeline.trust import SharedInputs, attach_trust
from ngp_kornia.threads import beside

__all__ = ["Candidates", "FrameSearch", "Search", "View", "pseudo_lines"]


class View(NamedTuple):
    """A batch on its way through the stages.

    Attributes:
        images: (B, 3, H, W) float RGB in [0, 1] (only the networks that read pixels read them).
        segments: (B, N, 2, 2) segments in the images' pixels.
        mask: (B, N) bool, the segments used.
        weights: (B, N) the line evidence's structure weights, multiplying the segments' lengths; None for none.
        resized: gives ``images`` resized to FSNet's input (:meth:`~ngp_kornia.nets.fsnet.FSNet.input_images`),
            made on a second thread meanwhile; None: resized where FSNet needs them.
    """

    images: Tensor
    segments: Tensor
    mask: Tensor
    weights: Tensor | None = None
    resized: Callable[[], Tensor] | None = None


class Candidates(NamedTuple):
    """The sampled candidates and their Manhattan scores (the fields of the same names of
    :class:`~ngp_kornia.pipeline.trace.ParserTrace`)."""

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


class Search(NamedTuple):
    """What one :class:`FrameSearch` call computed: the answer and the stages it came from.

    Attributes:
        result: the batched :class:`~ngp_kornia.pipeline.result.Calibration`.
        candidates: the candidates and their Manhattan scores.
        final_frames, final_scores: the frames the answer is chosen from and their scores (FSNet's kept frames and
            ``s_vh * m_i`` with FSNet, the candidates and ``m_i`` without).
        top_k_weights: (B, F') the weights of the top-k average.
        scored_index, fsnet_scores: (B, K) the frames FSNet scored and its ``s_vh``; None without FSNet.
    """

    result: Calibration
    candidates: Candidates
    final_frames: FrameCandidates
    final_scores: Tensor
    top_k_weights: Tensor
    scored_index: Tensor | None = None
    fsnet_scores: Tensor | None = None


def pseudo_lines(segments: Tensor, mask: Tensor, height: int, width: int) -> tuple[Tensor, Tensor, Tensor]:
    """(B, N, 2, 2) pixel segments -> the pseudo camera's segments, their (B, N, 3) lines and (B, N) pixel lengths
    (zero where the mask is False)."""
    seg = to_pseudo_camera(segments, height, width)
    return seg, segments_to_lines(seg), segment_lengths(segments, mask)


class FrameSearch:
    """The stages for a centred, distortion-free camera, as one callable stage (module docstring).

    Args:
        config: the settings.
        zsnet: a ZSNet scoring the zenith candidates, or None (every valid candidate counts equally).
        fsnet: an FSNet scoring the best frames, or None (the Manhattan score alone).
        seed: seed of the candidate sampling; every image draws from its own generator seeded with it.

    Example:
        >>> segments = torch.tensor([[[[10.0, 10.0], [14.0, 200.0]], [[50.0, 20.0], [300.0, 60.0]]]])
        >>> view = View(torch.zeros(1, 3, 240, 320), segments, torch.ones(1, 2, dtype=torch.bool))
        >>> found = FrameSearch(ParserConfig())(view, Priors())
        >>> found.result.K.shape, found.candidates.manhattan.shape[0]
        (torch.Size([1, 3, 3]), 1)
    """

    def __init__(
        self, config: ParserConfig, zsnet: nn.Module | None = None, fsnet: nn.Module | None = None, seed: int = 0
    ) -> None:
        self.config, self.zsnet, self.fsnet, self.seed = config, zsnet, fsnet, seed

    @property
    def reads_pixels(self) -> bool:
        """Whether a stage reads the images' pixels (FSNet), so that a moved camera must move them too."""
        return self.fsnet is not None

    def __call__(self, view: View, priors: Priors, centre_std: float | Tensor | None = None) -> Search:
        """The answer for the view's centred, distortion-free camera.

        Args:
            view: the images, segments, mask and line-evidence weights.
            priors: the focal length and gravity priors (the principal point and distortion are the camera
                model's, :mod:`~ngp_kornia.pipeline.camera_model`).
            centre_std: the uncertainty of the camera's centre as a fraction of the height, in place of the
                trust setting's (0 where it is known): one for all, or (B,); None: the setting's.

        Returns:
            the :class:`Search`.
        """
        cfg = self.config
        trust = cfg.trust if centre_std is None else centre_std
        images, segments, mask, weights = view[:4]
        height, width = images.shape[-2:]
        # one generator per image, each seeded alike: an image's answer does not depend on its batch or position
        generators = [torch.Generator().manual_seed(self.seed) for _ in range(len(images))]
        image_side = self.image_side_beside(view)  # FSNet's trunk on the helper thread, beside the candidates
        # the segments' lines and lengths serve the scores, FSNet's inputs and the trust fields: computed once
        pseudo = pseudo_lines(segments, mask, height, width)
        if weights is not None:
            pseudo = (pseudo[0], pseudo[1], pseudo[2] * weights)
        found = self.candidates(pseudo, mask, (height, width), generators, priors)
        frames, scores, index, s_vh = found.frames, found.manhattan, None, None
        if self.fsnet is not None:
            frames, scores, index, s_vh = self.rescore(
                images, segments, mask, frames, scores, pseudo[1], view.resized, image_side
            )
        known = priors.focal_units(height, width, like=pseudo[1])
        result, top_k_weights = topk_calibration(frames, scores, height, width, cfg.scoring, known)
        result = self._refined(result, view, priors, frames, scores, SharedInputs(*pseudo[1:], top_k_weights), trust)
        return Search(result, found, frames, scores, top_k_weights, index, s_vh)

    def _refined(self, result, view: View, priors: Priors, frames, scores, shared: SharedInputs, trust) -> Calibration:
        """The top-k answer polished, its horizon searched and chosen, its trust fields and gravity prior added."""
        cfg = self.config
        _, segments, mask, weights = view[:4]
        height, width = view.images.shape[-2:]
        search_vps = result.vps  # the frame search's VPs: the residual of their lines is a trust input
        if cfg.polish.enabled:
            result = self.polished(result, segments, mask, priors.known_focal, (height, width))
        # the horizon search serves the refinement and the confidence (how well the lines support a rival horizon);
        # with a known focal length only the horizon moves, never the focal length
        keep = None if priors.gravity is None else partial(allowed_ups, priors=priors)  # within a gravity prior
        found = search_horizon(result, segments, mask, cfg.horizon, priors.known_focal, keep, weights)
        if cfg.horizon.refine:
            result = choose_horizon(result, found, cfg.horizon.margin)
        result = attach_trust(
            result, frames, scores, segments, mask, cfg.scoring, trust, priors.known_focal,
            shared=shared, refinement=found, residual_vps=search_vps,
        )  # fmt: skip
        if priors.gravity is None:
            return result
        count = len(result.focal)
        given = zip(priors.each("gravity", count), priors.each("gravity_std", count), strict=True)
        return replace(result, gravity=result.focal.new_tensor([[*up, std] for up, std in given]))

    def candidates(
        self,
        pseudo: tuple[Tensor, Tensor, Tensor],
        mask: Tensor,
        size: tuple[int, int],
        generators: Generators,
        priors: Priors | None = None,
    ) -> Candidates:
        """Sample frame candidates (pseudo camera) and score each one (zero for invalid frames).

        Args:
            pseudo: the segments' :func:`pseudo_lines` (segments, lines, lengths).
            mask: (B, N) bool.
            size: the images' ``(height, width)``.
            generators: one generator per image (or one for the batch).
            priors: a known focal length and a gravity prior; None for none.
        """
        cfg = self.config.sampling
        seg, lines, lengths = pseudo
        lines_z, lines_z_ok, zenith, zenith_ok = sample_zenith_candidates(
            lines, lengths, mask, cfg.num_zenith_lines, cfg.num_zenith, cfg.vertical_threshold, generators
        )
        weights = gravity_zenith_weights(self.zenith_weights(lines_z, lines_z_ok, zenith, zenith_ok), zenith, priors)
        z_est = zenith_estimate(zenith, weights)
        horizontal = horizontal_line_mask(seg, mask, z_est, cfg.vertical_tol, cfg.junction_radius)
        right = split_by_pseudo_horizon(lines, z_est)
        h_vps, h_ok = sample_horizontal_vps(lines, lengths, horizontal, right, cfg.num_horizontal, generators)
        known = None if priors is None else priors.focal_units(*size, like=lines)
        frames = sample_candidate_frames(
            zenith, weights, h_vps, h_ok, cfg.num_frames, cfg.num_horizontal_frames, cfg.focal_range, generators, known
        )
        # zero for the invalid frames, which it does not score
        kernel = self.config.scoring.kernel_angle
        scores = gravity_frame_scores(frame_manhattan_scores(lines, frames.vps, lengths, mask, kernel, frames.valid),
                                      frames.R, priors)  # a gravity prior's agreement (gravity.py)
        return Candidates(lines, lines_z, lines_z_ok, zenith, zenith_ok, weights, z_est, horizontal, right, h_vps, h_ok,
                          frames, scores)  # fmt: skip

    def rescore(
        self,
        images: Tensor,
        segments: Tensor,
        mask: Tensor,
        frames: FrameCandidates,
        manhattan: Tensor,
        lines: Tensor | None = None,
        resized: Callable[[], Tensor] | None = None,
        image_side: Callable[[], tuple[FSNetImageInputs, tuple | None]] | None = None,
    ) -> tuple[FrameCandidates, Tensor, Tensor, Tensor]:
        """Keep the best ``num_scored`` frames by Manhattan score and score them with FSNet: ``s_vh * m_i`` (Eq. 22),
        or ``s_vh`` alone without ``use_manhattan``. ``lines``: the segments' pseudo-camera lines when already
        computed; ``resized``: as :attr:`View.resized`; ``image_side``: gives :meth:`fsnet_image_side`'s result
        when it is computed elsewhere (:meth:`image_side_beside`).

        Returns:
            the kept frames, their (B, K) scores, their (B, K) indices into ``frames`` and FSNet's (B, K) ``s_vh``.
        """
        cfg = self.config.scoring
        index = top_frames(frames, manhattan, cfg.num_scored)
        frames, manhattan = select_frames(frames, index), manhattan.gather(1, index)
        # FSNet runs in its own dtype (float32 weights on a float64 image, say): lines in another dtype are redone
        dtype = next(self.fsnet.parameters()).dtype
        lines = lines if lines is not None and lines.dtype == dtype else None
        if image_side is None:
            image_inputs, context = self.fsnet_image_side(images, segments, mask, resized)
        else:
            image_inputs, context = image_side()
        inputs = self.fsnet.prepare_inputs(images.to(dtype), segments.to(dtype), mask, frames, lines, image_inputs)
        s_vh = torch.sigmoid(self.fsnet(*inputs, context=context)).to(manhattan)
        return frames, frame_scores(s_vh, manhattan, frames.valid, cfg.use_manhattan), index, s_vh

    def fsnet_image_side(
        self, images: Tensor, segments: Tensor, mask: Tensor, resized: Callable[[], Tensor] | None = None
    ) -> tuple[FSNetImageInputs, tuple | None]:
        """FSNet's inputs that need no frame candidate (:meth:`FSNet.prepare_image_inputs`; ``resized`` as
        :attr:`View.resized`) and its shared trunk's output on them (:meth:`FSNet.image_context`), in FSNet's dtype."""
        dtype = next(self.fsnet.parameters()).dtype
        if resized is None:
            image_inputs = self.fsnet.prepare_image_inputs(images.to(dtype), segments.to(dtype), mask)
        else:
            lines = self.fsnet.prepare_line_inputs(segments.to(dtype), mask, tuple(images.shape[-2:]))
            image_inputs = lines._replace(images=resized())
        return image_inputs, self.fsnet.image_context(image_inputs)

    def resize_beside(self, images: Tensor) -> Callable[[], Tensor] | None:
        """:attr:`View.resized` for ``images``: FSNet's image resized on the helper thread
        (:func:`~ngp_kornia.threads.beside`: C code that releases the GIL, beside the line evidence and the frame
        sampling), where the search has FSNet, a second core is free and the images ask for no gradient; else None."""
        if self.fsnet is None or images.requires_grad or strip_threads(2) < 2:
            return None
        dtype = next(self.fsnet.parameters()).dtype
        return beside(self.fsnet.input_images, images.to(dtype))

    def image_side_beside(self, view: View) -> Callable[[], tuple[FSNetImageInputs, tuple | None]] | None:
        """:meth:`fsnet_image_side` of the view started on the helper thread (:func:`~ngp_kornia.threads.beside`),
        where it runs beside the candidates: it needs no frame, and its trunk's convolutions are C code that
        releases the GIL. Only where the search has FSNet, a second core is free and no gradient is recorded (the
        helper thread keeps the caller's grad mode only in that case); else None."""
        if self.fsnet is None or torch.is_grad_enabled() or strip_threads(2) < 2:
            return None
        inference = torch.is_inference_mode_enabled()

        def side() -> tuple[FSNetImageInputs, tuple | None]:
            with torch.inference_mode(inference), torch.no_grad():
                return self.fsnet_image_side(view.images, view.segments, view.mask, view.resized)

        return beside(side)

    def zenith_weights(self, lines_z: Tensor, lines_z_ok: Tensor, zenith: Tensor, zenith_ok: Tensor) -> Tensor:
        """Weights of the zenith candidates: the ZSNet score p_z on Z_c (p_z > delta_c, Eq. 12) and zero elsewhere;
        without ZSNet, or where no candidate passes delta_c, every valid candidate counts equally. (B, Z)."""
        if self.zsnet is None:
            return zenith_ok.to(zenith)
        dtype = next(self.zsnet.parameters()).dtype  # ZSNet runs in its own dtype (float32 on float64 input, say)
        scores = torch.sigmoid(self.zsnet(lines_z.to(dtype), lines_z_ok, zenith.to(dtype))).to(zenith.dtype)
        return zenith_weights_from_scores(scores, zenith_ok, self.config.sampling.zenith_threshold)

    def polished(
        self, result: Calibration, segments: Tensor, mask: Tensor, known_focal: bool, size: tuple[int, int]
    ) -> Calibration:
        """The frame refitted on its inlier segments (:func:`~ngp_kornia.pipeline.polish.polish_frame`; with a known
        focal length only the rotation), where that raises its line support."""
        scales = (1.0,) if known_focal else self.config.polish.scales
        K, R, use = polish_frame(result.K, result.R, segments, mask, scales)
        use = use & result.valid
        if not bool(use.any()):
            return result
        # the other images keep their K and R, from which the same fields are rebuilt
        K, R = torch.where(use[:, None, None], K, result.K), torch.where(use[:, None, None], R, result.R)
        return calibration_from_camera(K, R, result.score, result.valid, *size)
