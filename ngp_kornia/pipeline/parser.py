"""The Neural Geometric Parser as an ``nn.Module``: it runs the pipeline's stages in order.

segments (:mod:`~ngp_kornia.pipeline.segments`) -> line evidence (:mod:`~ngp_kornia.pipeline.evidence`, where
the parser has its network) -> zenith, horizontal-VP and frame candidates
(:mod:`~ngp_kornia.pipeline.candidates`, scored by ZSNet where given) -> Manhattan scores, rescored by FSNet where
given (Eq. 22) -> the top-k answer (:mod:`~ngp_kornia.pipeline.answer`) -> optional polish
(:mod:`~ngp_kornia.pipeline.polish`) -> horizon search and choice (:mod:`~ngp_kornia.pipeline.horizon`) -> trust
fields (:mod:`~ngp_kornia.pipeline.trust`).

Without networks this is the paper's geometric baseline: zenith candidates count uniformly (instead of ZSNet's
scores) and frames are ranked by the Manhattan score ``m_i`` of Eq. 21 alone (instead of ``s_vh * m_i``). With
FSNet, gradients flow from the outputs to FSNet's parameters and to the image's pixels.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import partial

import torch
from torch import Tensor, nn

from ngp_kornia.errors import ConfigError, InputError, shown
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
from ngp_kornia.pipeline.camera_model import calibrate_camera_model
from ngp_kornia.pipeline.candidates import (
    Generators,
    horizontal_line_mask,
    sample_candidate_frames,
    sample_horizontal_vps,
    sample_zenith_candidates,
    split_by_pseudo_horizon,
)
from ngp_kornia.pipeline.evidence import apply_evidence
from ngp_kornia.pipeline.gravity import allowed_ups, gravity_frame_scores, gravity_zenith_weights
from ngp_kornia.pipeline.horizon import choose_horizon, search_horizon
from ngp_kornia.pipeline.polish import polish_frame
from ngp_kornia.pipeline.priors import Priors, checked_seed
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import ParserConfig
from ngp_kornia.pipeline.trace import ParserTrace
from ngp_kornia.pipeline.trust import SharedInputs, attach_trust
from ngp_kornia.pipeline.upright_check import apply_upright, read_beside, weigh_by_pitch

__all__ = ["NeuralGeometricParser", "ParserConfig", "checked_config", "checked_segments", "pseudo_lines"]


def checked_config(config: object) -> ParserConfig:
    """The settings a caller passed as ``config``: a :class:`ParserConfig`, a mapping of the settings to change
    (keys as :meth:`ParserConfig.replace` takes them), or None for the defaults.

    Raises:
        ConfigError: anything else, or an unknown setting or bad value in the mapping.

    Example:
        >>> checked_config({"horizon.refine": False}).horizon.refine
        False
    """
    if config is None:
        return ParserConfig()
    if isinstance(config, ParserConfig):
        return config
    if isinstance(config, Mapping) and all(isinstance(key, str) for key in config):
        return ParserConfig().replace(**config)
    raise ConfigError(
        f"config must be a ParserConfig, a mapping of settings such as {{'horizon.refine': False}}, or None; "
        f"got {shown(config)}"
    )


def _checked_call(images: object, seed: object, priors: object) -> tuple[int, Priors]:
    """The seed and priors of a :meth:`NeuralGeometricParser.forward` call, once its images are a tensor."""
    if not isinstance(images, Tensor):
        raise TypeError(
            f"images must be a (B, 3, H, W) float tensor in [0, 1], got {type(images).__name__}; "
            "ngp_kornia.calibrate() takes files, arrays and lists"
        )
    if priors is not None and not isinstance(priors, Priors):
        raise TypeError(f"priors must be a Priors, got {type(priors).__name__}")
    return checked_seed(seed), priors or Priors()


class NeuralGeometricParser(nn.Module):
    """Single-image calibration of a Manhattan / Atlanta-world scene.

    Args:
        config: the stages' settings (:class:`~ngp_kornia.pipeline.settings.ParserConfig`, or a mapping of the settings
            to change).
        zsnet: a :class:`~ngp_kornia.nets.zsnet.ZSNet` scoring the zenith candidates; None weights every valid
            candidate equally (the geometric path).
        fsnet: an :class:`~ngp_kornia.nets.fsnet.FSNet` scoring the best frames; None ranks the frames by the
            Manhattan score alone.
        evidence: a :class:`~ngp_kornia.nets.line_evidence.LineEvidenceNet` whose structure weights drop segments
            on no man-made structure (:class:`~ngp_kornia.pipeline.settings.EvidenceSettings`); None keeps every
            segment. :func:`ngp_kornia.api.load_parser` gives every weight set the shipped one.
        upright: a :class:`~ngp_kornia.nets.upright.UprightNet`, the orientation and structure check that scales
            the confidence (:mod:`ngp_kornia.pipeline.upright_check`); None leaves the confidence to the lines alone.
            :func:`ngp_kornia.api.load_parser` gives every weight set the shipped one.

    Example:
        >>> img = torch.rand(1, 3, 96, 128)
        >>> out = NeuralGeometricParser()(img)
        >>> out.K.shape, out.horizon.shape, bool(torch.isfinite(out.focal).all())
        (torch.Size([1, 3, 3]), torch.Size([1, 3]), True)
    """

    def __init__(
        self,
        config: ParserConfig | None = None,
        zsnet: nn.Module | None = None,
        fsnet: nn.Module | None = None,
        evidence: nn.Module | None = None,
        upright: nn.Module | None = None,
    ) -> None:
        super().__init__()
        self.config = checked_config(config)
        self.zsnet = zsnet
        self.fsnet = fsnet
        self.evidence = evidence
        self.upright = upright

    def forward(
        self,
        images: Tensor,
        segments: Tensor | None = None,
        mask: Tensor | None = None,
        *,
        seed: int = 0,
        priors: Priors | None = None,
        return_trace: bool = False,
    ) -> Calibration | tuple[Calibration, ParserTrace]:
        """Calibrate a batch.

        Args:
            images: (B, 3, H, W) float RGB in [0, 1]; float16 and bfloat16 are computed in float32 and the result
                returned in the input's dtype. Only the networks read the pixels (FSNet, the line evidence, the
                orientation check): without them, a tensor of the images' shape will do when ``segments`` are
                given.
            segments: optional (B, N, 2, 2) precomputed segments in the images' pixels (skips LSD). Segments the
                mask keeps must be finite (NaN or infinite ones are refused); padding may hold anything.
            mask: (B, N) bool, required with ``segments``.
            seed: seed of the candidate sampling; every image draws from its own generator seeded with it, so an
                image gets the same answer alone and at any place in any batch.
            priors: what is known of the camera (:class:`~ngp_kornia.pipeline.priors.Priors`), for every image of
                the batch.
            return_trace: also return the intermediate stages.

        Returns:
            a batched :class:`Calibration`; with ``return_trace``, the pair ``(calibration, trace)``, the trace a
            :class:`ParserTrace` of the stages (the same computation: the calibration does not change).
        """
        seed, priors = _checked_call(images, seed, priors)
        priors.check_image(*images.shape[-2:])  # a focal length no camera has on this image: a mistake of units
        if images.dtype in (torch.float16, torch.bfloat16):  # computed in float32, returned in the input's dtype
            low = None if segments is None else segments.float()
            out = self.forward(images.float(), low, mask, seed=seed, priors=priors, return_trace=return_trace)
            return (out[0].to(images.dtype), out[1]) if return_trace else out.to(images.dtype)
        reading = None
        if self.upright is not None and self.config.upright.enabled:  # read on a second core meanwhile
            reading = read_beside(self.upright, images, self.config.upright.prior)
        segments, mask = self._segments(images, segments, mask)
        stages = {"segments": segments, "detected": mask} if return_trace else None
        weights = None
        if self.evidence is not None and self.config.evidence.enabled:
            weights, mask = apply_evidence(self.evidence, images, segments, mask, self.config.evidence.keep)
            if stages is not None:
                stages["evidence"] = weights
            weights = weights if self.config.evidence.weigh else None
        if stages is not None:
            stages["mask"] = mask

        def run(images_, segments_, mask_, priors_, principal_point_std):  # a centred, distortion-free camera
            return self._calibrate(images_, segments_, mask_, seed, priors_, stages, principal_point_std, weights)

        # the principal point and the distortion, given or estimated, around the stages (camera_model.py)
        result = calibrate_camera_model(run, images, segments, mask, priors, self.config, self.fsnet is not None)
        if reading is not None:
            result = self._check_upright(result, reading())
        return (result, ParserTrace(**stages)) if return_trace else result

    def _check_upright(self, result: Calibration, probs: Tensor) -> Calibration:
        """The orientation and structure check's reading applied to the answer (pipeline/upright_check.py)."""
        check = self.config.upright
        if check.pitch_spread > 0:  # a steep answer is likelier that of a photo turned by a quarter
            probs = weigh_by_pitch(probs, result.pitch, check.pitch_spread)
        return apply_upright(result, probs, check.sure, check.turn_back, self.config.scoring.fallback_fov, check.doubt)

    def _segments(self, images: Tensor, segments: Tensor | None, mask: Tensor | None) -> tuple[Tensor, Tensor]:
        """The segments given (checked) or detected, never an empty tensor."""
        if segments is None:
            segments, mask = detect_segments(images, self.config.segments)
        else:
            segments, mask = checked_segments(segments, mask, len(images))
        segments = segments.to(images)
        if segments.shape[1] == 0:  # no lines anywhere in the batch: one masked dummy keeps every shape non-empty
            segments, mask = segments.new_zeros(len(images), 1, 2, 2), mask.new_zeros(len(images), 1)
        return segments, mask

    def _calibrate(
        self,
        images: Tensor,
        segments: Tensor,
        mask: Tensor,
        seed: int,
        priors: Priors,
        stages: dict | None,
        principal_point_std: float | None = None,
        weights: Tensor | None = None,
    ) -> Calibration:
        """The stages after the line evidence; ``weights`` (B, N), when given, multiply the segments' lengths."""
        cfg = self.config
        trust = cfg.trust
        if principal_point_std is not None and principal_point_std != trust.principal_point_std:
            trust = replace(trust, principal_point_std=principal_point_std)
        height, width = images.shape[-2:]
        # one generator per image, each seeded alike: an image's answer does not depend on its batch or position
        generators = [torch.Generator().manual_seed(seed) for _ in range(len(images))]
        # the segments' lines and lengths serve the scores, FSNet's inputs and the trust fields: computed once
        pseudo = pseudo_lines(segments, mask, height, width)
        if weights is not None:
            pseudo = (pseudo[0], pseudo[1], pseudo[2] * weights)
        frames, scores = self.score_frames(segments, mask, height, width, generators, stages, pseudo, priors)
        if self.fsnet is not None:
            frames, scores = self.rescore_frames(images, segments, mask, frames, scores, stages, pseudo[1])
        known = priors.focal_in_units(height, width)
        result, top_k_weights = topk_calibration(frames, scores, height, width, cfg.scoring, known)
        if stages is not None:
            best = scores.argmax(-1)
            stages.update(final_frames=frames, final_scores=scores, top_k_weights=top_k_weights, best=best)
        search_vps = result.vps  # the frame search's VPs: the residual of their lines is a trust input
        if cfg.polish.enabled:
            result = self._polished(result, segments, mask, priors.known_focal, height, width)
        # the horizon search serves the refinement and the confidence (how well the lines support a rival horizon);
        # with a known focal length only the horizon moves, never the focal length
        keep = None if priors.gravity is None else partial(allowed_ups, priors=priors)  # within a gravity prior
        found = search_horizon(result, segments, mask, cfg.horizon, priors.known_focal, keep, weights)
        if cfg.horizon.refine:
            result = choose_horizon(result, found, cfg.horizon.margin)
        result = attach_trust(
            result, frames, scores, segments, mask, cfg.scoring, trust, priors.known_focal,
            shared=SharedInputs(*pseudo[1:], top_k_weights), refinement=found, residual_vps=search_vps,
        )  # fmt: skip
        if priors.gravity is None:
            return result
        given = result.focal.new_tensor([*priors.gravity, priors.gravity_std]).expand(len(result.focal), 3)
        return replace(result, gravity=given)

    def _polished(
        self, result: Calibration, segments: Tensor, mask: Tensor, known_focal: bool, height: int, width: int
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
        return calibration_from_camera(K, R, result.score, result.valid, height, width)

    def score_frames(
        self,
        segments: Tensor,
        mask: Tensor,
        height: int,
        width: int,
        generator: Generators,
        stages: dict | None = None,
        pseudo: tuple[Tensor, Tensor, Tensor] | None = None,
        priors: Priors | None = None,
    ) -> tuple[FrameCandidates, Tensor]:
        """Sample frame candidates (pseudo camera) and score each one: (B, F) scores, zero for invalid frames.
        ``stages``, a dict, receives the intermediate tensors (the fields of :class:`ParserTrace`); ``pseudo``,
        the segments' :func:`pseudo_lines` when already computed; ``priors``, a known focal length."""
        cfg = self.config.sampling
        seg, lines, lengths = pseudo_lines(segments, mask, height, width) if pseudo is None else pseudo
        lines_z, lines_z_ok, zenith, zenith_ok = sample_zenith_candidates(
            lines, lengths, mask, cfg.num_zenith_lines, cfg.num_zenith, cfg.vertical_threshold, generator
        )
        weights = gravity_zenith_weights(self.zenith_weights(lines_z, lines_z_ok, zenith, zenith_ok), zenith, priors)
        z_est = zenith_estimate(zenith, weights)
        horizontal = horizontal_line_mask(seg, mask, z_est, cfg.vertical_tol, cfg.junction_radius)
        right = split_by_pseudo_horizon(lines, z_est)
        h_vps, h_ok = sample_horizontal_vps(lines, lengths, horizontal, right, cfg.num_horizontal, generator)
        known = None if priors is None else priors.focal_in_units(height, width)
        frames = sample_candidate_frames(
            zenith, weights, h_vps, h_ok, cfg.num_frames, cfg.num_horizontal_frames, cfg.focal_range, generator, known
        )
        # zero for the invalid frames, which it does not score
        kernel = self.config.scoring.kernel_angle
        scores = gravity_frame_scores(frame_manhattan_scores(lines, frames.vps, lengths, mask, kernel, frames.valid),
                                      frames.R, priors)  # a gravity prior's agreement (gravity.py)
        if stages is not None:
            stages.update(lines=lines, zenith_lines=lines_z, zenith_lines_ok=lines_z_ok, zenith_candidates=zenith)
            stages.update(zenith_ok=zenith_ok, zenith_weights=weights, zenith_estimate=z_est, horizontal=horizontal)
            stages.update(right=right, horizontal_vps=h_vps, horizontal_ok=h_ok, frames=frames, manhattan=scores)
        return frames, scores

    def rescore_frames(
        self,
        images: Tensor,
        segments: Tensor,
        mask: Tensor,
        frames: FrameCandidates,
        manhattan: Tensor,
        stages: dict | None = None,
        lines: Tensor | None = None,
    ) -> tuple[FrameCandidates, Tensor]:
        """Keep the best ``num_scored`` frames by Manhattan score and score them with FSNet: ``s_vh * m_i`` (Eq. 22),
        or ``s_vh`` alone without ``use_manhattan``. Returns the kept frames and their (B, K) scores. ``lines``: the
        segments' pseudo-camera lines when already computed."""
        cfg = self.config.scoring
        index = top_frames(frames, manhattan, cfg.num_scored)
        frames, manhattan = select_frames(frames, index), manhattan.gather(1, index)
        # FSNet runs in its own dtype (float32 weights on a float64 image, say): lines in another dtype are redone
        dtype = next(self.fsnet.parameters()).dtype
        lines = lines if lines is not None and lines.dtype == dtype else None
        image_inputs, context = self.fsnet_image_side(images, segments, mask)
        inputs = self.fsnet.prepare_inputs(images.to(dtype), segments.to(dtype), mask, frames, lines, image_inputs)
        s_vh = torch.sigmoid(self.fsnet(*inputs, context=context)).to(manhattan)
        if stages is not None:
            stages.update(scored_index=index, fsnet_scores=s_vh)
        return frames, frame_scores(s_vh, manhattan, frames.valid, cfg.use_manhattan)

    def fsnet_image_side(self, images: Tensor, segments: Tensor, mask: Tensor) -> tuple[FSNetImageInputs, tuple | None]:
        """FSNet's inputs that need no frame candidate (:meth:`FSNet.prepare_image_inputs`) and its shared trunk's
        output on them (:meth:`FSNet.image_context`), in FSNet's dtype."""
        dtype = next(self.fsnet.parameters()).dtype
        image_inputs = self.fsnet.prepare_image_inputs(images.to(dtype), segments.to(dtype), mask)
        return image_inputs, self.fsnet.image_context(image_inputs)

    def zenith_weights(self, lines_z: Tensor, lines_z_ok: Tensor, zenith: Tensor, zenith_ok: Tensor) -> Tensor:
        """Weights of the zenith candidates: the ZSNet score p_z on Z_c (p_z > delta_c, Eq. 12) and zero elsewhere;
        without ZSNet, or where no candidate passes delta_c, every valid candidate counts equally. (B, Z)."""
        if self.zsnet is None:
            return zenith_ok.to(zenith)
        dtype = next(self.zsnet.parameters()).dtype  # ZSNet runs in its own dtype (float32 on float64 input, say)
        scores = torch.sigmoid(self.zsnet(lines_z.to(dtype), lines_z_ok, zenith.to(dtype))).to(zenith.dtype)
        return zenith_weights_from_scores(scores, zenith_ok, self.config.sampling.zenith_threshold)

    def calibrate_from_frames(
        self, frames: FrameCandidates, scores: Tensor, height: int, width: int, priors: Priors | None = None
    ) -> Calibration:
        """Top-k average (Eq. 23) of focal and zenith, yaw from the best frame, everything mapped to pixels."""
        known = None if priors is None else priors.focal_in_units(height, width)
        return topk_calibration(frames, scores, height, width, self.config.scoring, known)[0]


def pseudo_lines(segments: Tensor, mask: Tensor, height: int, width: int) -> tuple[Tensor, Tensor, Tensor]:
    """(B, N, 2, 2) pixel segments -> the pseudo camera's segments, their (B, N, 3) lines and (B, N) pixel lengths
    (zero where the mask is False)."""
    seg = to_pseudo_camera(segments, height, width)
    return seg, segments_to_lines(seg), segment_lengths(segments, mask)


def checked_segments(segments: Tensor, mask: Tensor | None, batch: int) -> tuple[Tensor, Tensor]:
    """Segments given to the parser: (B, N, 2, 2) with a (B, N) bool mask, finite where the mask keeps them;
    padding (mask False) is set to zero whatever it holds.

    Raises:
        InputError: no mask, shapes that do not match, or NaN / infinite coordinates in a kept segment.
    """
    if mask is None:
        raise InputError("segments were given without their (B, N) mask; pass mask=torch.ones(B, N, dtype=bool)")
    if segments.dim() != 4 or segments.shape[0] != batch or segments.shape[2:] != (2, 2):
        raise InputError(f"segments must be ({batch}, N, 2, 2), got {tuple(segments.shape)}")
    if mask.shape != segments.shape[:2] or mask.dtype != torch.bool:
        raise InputError(
            f"mask must be a bool tensor of shape {tuple(segments.shape[:2])}, got {mask.dtype} {tuple(mask.shape)}"
        )
    # a finite sum means every coordinate is finite, the usual case: no per-segment test then
    if not bool(torch.isfinite(segments.sum())):
        bad = mask & ~torch.isfinite(segments).flatten(2).all(-1)
        if bool(bad.any()):
            b, n = (int(v) for v in bad.nonzero()[0])
            raise InputError(
                f"segment {n} of image {b} has NaN or infinite coordinates ({int(bad.sum())} such segments); "
                "drop them or set their mask to False"
            )
    return torch.where(mask[..., None, None], segments, torch.zeros_like(segments)), mask
