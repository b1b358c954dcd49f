"""The Neural Geometric Parser as an ``nn.Module``: it runs the pipeline's stages in order.

segments (:mod:`~ngp_kornia.pipeline.segments`) -> line evidence (:mod:`~ngp_kornia.pipeline.evidence`, where
the parser has its network) -> the camera model (:mod:`~ngp_kornia.pipeline.camera_model`: a principal point or a
distortion, given or estimated) around the frame search (:mod:`~ngp_kornia.pipeline.frame_search`: zenith,
horizontal-VP and frame candidates scored by ZSNet and FSNet where given, the top-k answer, polish, horizon search
and trust fields) -> the orientation check (:mod:`~ngp_kornia.pipeline.upright_check`).

Without networks this is the paper's geometric baseline: zenith candidates count uniformly (instead of ZSNet's
scores) and frames are ranked by the Manhattan score ``m_i`` of Eq. 21 alone (instead of ``s_vh * m_i``). With
FSNet, gradients flow from the outputs to FSNet's parameters and to the image's pixels.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import torch
from torch import Tensor, nn

from ngp_kornia.errors import InputError
from ngp_kornia.geometry import FrameCandidates
from ngp_kornia.pipeline.camera_model import calibrate_camera_model
from ngp_kornia.pipeline.candidates import Generators
from ngp_kornia.pipeline.evidence import apply_evidence
from ngp_kornia.pipeline.frame_search import FrameSearch, Search, View, pseudo_lines
from ngp_kornia.pipeline.priors import Priors, checked_seed
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import ParserConfig
from ngp_kornia.pipeline.trace import ParserTrace
from ngp_kornia.pipeline.upright_check import (
    apply_upright,
    fuse_line_reading,
    read_beside,
    read_lines_beside,
    weigh_by_pitch,
    with_prior,
)
from ngp_kornia.pipeline.weight_sets import check_weights, checked_config, network_roles, weight_set_config

__all__ = ["NeuralGeometricParser", "ParserConfig", "checked_segments"]


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
            segment. :meth:`from_pretrained` gives every weight set the shipped one.
        upright: a :class:`~ngp_kornia.nets.upright.UprightNet`, the orientation and structure check that scales
            the confidence (:mod:`ngp_kornia.pipeline.upright_check`); None leaves the confidence to the lines alone.
            :meth:`from_pretrained` gives every weight set the shipped one.
        upright_lines: a :class:`~ngp_kornia.nets.upright_lines.UprightLinesNet` that reads the turn from the
            detected segments, its reading fused with ``upright``'s (``UprightSettings.lines``); None: ``upright``'s
            reading alone. :meth:`from_pretrained` gives every weight set the shipped one.

    The bare constructor gives the geometric path without networks; :meth:`from_pretrained` the trained parser.

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
        upright_lines: nn.Module | None = None,
    ) -> None:
        super().__init__()
        self.config = checked_config(config)
        self.zsnet = zsnet
        self.fsnet = fsnet
        self.evidence = evidence
        self.upright = upright
        self.upright_lines = upright_lines

    @classmethod
    def from_pretrained(
        cls,
        weights: str | Path | Sequence[str | Path] = "default",
        config: ParserConfig | Mapping | None = None,
        device: str | torch.device | None = None,
    ) -> NeuralGeometricParser:
        """The parser of a weight set, with its networks loaded.

        ``"none"`` is the geometric path: uniform zenith scores and frames ranked by the Manhattan score (Eq. 21).
        ``"zsnet"`` scores the zenith candidates with the shipped ZSNet, ``"fsnet"`` rescores the best frames with
        the shipped FSNet, ``"full"`` uses both (the paper's parser). ``"default"`` is
        :data:`~ngp_kornia.pipeline.weight_sets.DEFAULT_WEIGHTS` with
        :data:`~ngp_kornia.pipeline.weight_sets.DEFAULT_SETTINGS` (a mapping ``config`` changes settings on top of
        them). A path (or a list of paths) loads weights files written by ``ngp-train export``: a ZSNet file, an
        FSNet file, or one of each. Every weight set has the shipped line evidence and orientation check.

        Args:
            weights: the weight set's name or weights files.
            config: a :class:`ParserConfig`, or a mapping of the settings to change.
            device: where the networks go (None: the CPU).

        Returns:
            the parser; its networks are the caller's own copies, in eval mode: training them (as a layer of a
            larger model) or moving them does not change what :func:`ngp_kornia.calibrate` computes.

        Raises:
            ValueError: an unknown weight set; WeightsError: a missing, corrupt or mismatched weights file;
            ConfigError: a bad ``config``.

        Example:
            >>> parser = NeuralGeometricParser.from_pretrained("zsnet")
            >>> parser.zsnet is not None, parser.fsnet is None, parser.config.evidence.enabled
            (True, True, False)
        """
        parser = cls(weight_set_config(weights, config), **network_roles(check_weights(weights), copy=True))
        return parser if device is None else parser.to(device)

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
            priors: what is known of the camera (:class:`~ngp_kornia.pipeline.priors.Priors`): each prior one value
                for every image, or one per image ((B,) or (B, 2)); a prior is given (or estimated) for every image
                of the batch or for none. Each image gets what it gets alone with its own.
            return_trace: also return the intermediate stages.

        Returns:
            a batched :class:`Calibration`; with ``return_trace``, the pair ``(calibration, trace)``, the trace a
            :class:`ParserTrace` of the stages (the same computation: the calibration does not change).
        """
        seed, priors = _checked_call(images, seed, priors)
        priors = priors.for_batch(len(images))  # one value for all, or one per image of the batch
        priors.check_image(*images.shape[-2:])  # a focal length no camera has on this image: a mistake of units
        if images.dtype in (torch.float16, torch.bfloat16):  # computed in float32, returned in the input's dtype
            low = None if segments is None else segments.float()
            out = self.forward(images.float(), low, mask, seed=seed, priors=priors, return_trace=return_trace)
            return (out[0].to(images.dtype), out[1]) if return_trace else out.to(images.dtype)
        resized, reading = self._search().resize_beside(images), None  # on a second core meanwhile, where free
        if self.upright is not None and self.config.upright.enabled:  # a flat prior where the lines' reading joins
            reading = read_beside(self.upright, images, 0.25 if self._fuses_lines else self.config.upright.prior)
        segments, detected = self._segments(images, segments, mask)
        lines = read_lines_beside(self.upright_lines, segments, detected, images.shape[-2:]) if (
            reading is not None and self._fuses_lines) else None  # fmt: skip
        evidence, mask = None, detected
        if self.evidence is not None and self.config.evidence.enabled:
            evidence, mask = apply_evidence(self.evidence, images, segments, detected, self.config.evidence.keep)
        view = View(images, segments, mask, evidence if self.config.evidence.weigh else None, resized)
        # the principal point and the distortion, given or estimated, around the frame search (camera_model.py)
        found = calibrate_camera_model(self._search(seed), view, priors)
        result = found.result
        if reading is not None:
            result = self._check_upright(result, reading(), lines)
        return (result, _trace(found, view, detected, evidence)) if return_trace else result

    @property
    def reads_pixels(self) -> bool:
        """Whether a network of the parser reads the images' pixels (FSNet, the line evidence or the orientation
        check, where enabled); without one, a tensor of the images' shape will do beside given segments."""
        cfg = self.config
        return (self.fsnet is not None or (self.upright is not None and cfg.upright.enabled)
                or (self.evidence is not None and cfg.evidence.enabled))  # fmt: skip

    def _search(self, seed: int = 0) -> FrameSearch:
        """The stages after the line evidence, with this parser's settings and networks (frame_search.py)."""
        return FrameSearch(self.config, self.zsnet, self.fsnet, seed)

    @property
    def _fuses_lines(self) -> bool:
        return self.upright_lines is not None and self.config.upright.lines

    def _check_upright(self, result: Calibration, probs: Tensor, lines: Callable[[], Tensor] | None) -> Calibration:
        """The orientation and structure check's reading (fused with the lines' where given, then weighed by the
        prior) applied to the answer (pipeline/upright_check.py)."""
        check = self.config.upright
        if lines is not None:
            probs = with_prior(fuse_line_reading(self.upright_lines, probs, lines()), check.prior)
        if check.pitch_spread > 0:  # a steep answer is likelier that of a photo turned by a quarter
            probs = weigh_by_pitch(probs, result.pitch, check.pitch_spread)
        return apply_upright(result, probs, check.sure, check.turn_back, self.config.scoring.fallback_fov, check.doubt,
                             check.doubt_power)

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

    def score_frames(
        self,
        segments: Tensor,
        mask: Tensor,
        height: int,
        width: int,
        generator: Generators,
        priors: Priors | None = None,
    ) -> tuple[FrameCandidates, Tensor]:
        """Sample frame candidates (pseudo camera) and score each one: the frames and their (B, F) Manhattan scores,
        zero for invalid frames (:meth:`~ngp_kornia.pipeline.frame_search.FrameSearch.candidates`, which returns
        every intermediate stage); ``priors``, a known focal length and a gravity prior."""
        pseudo = pseudo_lines(segments, mask, height, width)
        found = self._search().candidates(pseudo, mask, (height, width), generator, priors)
        return found.frames, found.manhattan

    def rescore_frames(
        self, images: Tensor, segments: Tensor, mask: Tensor, frames: FrameCandidates, manhattan: Tensor
    ) -> tuple[FrameCandidates, Tensor]:
        """Keep the best ``num_scored`` frames by Manhattan score and score them with FSNet: ``s_vh * m_i`` (Eq. 22),
        or ``s_vh`` alone without ``use_manhattan``. Returns the kept frames and their (B, K) scores
        (:meth:`~ngp_kornia.pipeline.frame_search.FrameSearch.rescore`)."""
        return self._search().rescore(images, segments, mask, frames, manhattan)[:2]


def _trace(found: Search, view: View, detected: Tensor, evidence: Tensor | None) -> ParserTrace:
    """The trace of a forward call: the view's segments and mask, and what its last frame search returned."""
    return ParserTrace(
        segments=view.segments, mask=view.mask, detected=detected, evidence=evidence,
        **found.candidates._asdict(), final_frames=found.final_frames, final_scores=found.final_scores,
        top_k_weights=found.top_k_weights, best=found.final_scores.argmax(-1), scored_index=found.scored_index,
        fsnet_scores=found.fsnet_scores,
    )  # fmt: skip


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
