"""The Neural Geometric Parser pipeline as an ``nn.Module``: segments -> zenith candidates -> horizontal VP
candidates -> Manhattan frames -> scores -> top-k calibration.

Without networks this is the paper's geometric baseline: zenith candidates count uniformly (instead of ZSNet's
scores) and frames are ranked by the Manhattan score ``m_i`` of Eq. 21 alone (instead of ``s_vh * m_i``). With
FSNet, the best ``num_scored`` frames by Manhattan score are scored again from the image (Eq. 22); gradients then
flow from the outputs to FSNet's parameters and to the image's pixels.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ngp_kornia.errors import ConfigError, InputError
from ngp_kornia.geometry import (
    angles_from_rotation,
    canonical_manhattan_rotation,
    dominant_eigenvector,
    fov_from_focal,
    frame_manhattan_scores,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    pseudo_focal,
    rotation_from_vps,
    segment_lengths,
    segments_to_lines,
    structure_tensor,
    to_pseudo_camera,
    topk_weighted_average,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.geometry.frames import FrameCandidates, select_frames, top_frames
from ngp_kornia.nets.fsnet import FSNetImageInputs, frame_scores, with_images
from ngp_kornia.nets.zsnet import zenith_estimate, zenith_weights_from_scores
from ngp_kornia.pipeline.candidates import (
    Generators,
    horizontal_line_mask,
    sample_candidate_frames,
    sample_horizontal_vps,
    sample_zenith_candidates,
    split_by_pseudo_horizon,
)
from ngp_kornia.pipeline.constants import constant_tensors
from ngp_kornia.pipeline.horizon import FOCAL_SCALES, choose_horizon, search_horizon
from ngp_kornia.pipeline.polish import POLISH_SCALES, polish_frame
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import DETECTORS, detect_segments
from ngp_kornia.pipeline.trace import ParserTrace
from ngp_kornia.pipeline.trust import SharedInputs, attach_trust
from ngp_kornia.threads import Beside, pipeline_threads, run_beside

__all__ = ["NeuralGeometricParser", "ParserConfig", "ParserTrace", "prior_focal"]


@dataclass
class ParserConfig:
    """Settings of the pipeline; the defaults are the paper's where it gives them.

    Attributes:
        working_size: LSD runs on the image resized to this long side, in pixels; smaller images at their own size.
            1280 keeps the detail of most photos' lines (on the 1152-pixel Eurasian Cities photos 2.3 points of
            horizon AUC above 640, at 1.5x the time of a call on them; BENCHMARKS.md); 640 is faster on large
            images and the same on images of 640 pixels or less.
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
        num_threads: torch and OpenCV threads for a call (:func:`ngp_kornia.threads.pipeline_threads`): None takes
            ``$NGP_NUM_THREADS`` or else 1, the fastest for these small tensors and independent of the machine;
            0 keeps the caller's setting; more may pay for large batches on an idle machine. The caller's
            setting is restored after the call.
        detector: the line detector, ``"lsd"`` (the most accurate) or ``"fld"`` (OpenCV's FastLineDetector,
            faster and less accurate; :func:`ngp_kornia.pipeline.segments.detect_segments_gray`).
        line_strips: LSD runs on this many horizontal strips of the image, at once on up to that many threads
            (OpenCV releases the GIL), and the pieces of a line cut between strips are joined again
            (:func:`~ngp_kornia.pipeline.segments.detect_segments_gray`). 2 takes 0.6x the time of 1 on two idle
            cores and is
            as accurate within seed noise on the development suite; beside busy processes, which leave no core
            idle, a call takes 2-6% longer (the strips' overlap and the join; BENCHMARKS.md). 1 is the whole image
            in one piece. The segments depend on this number only, never on how many threads run them.
        focal: a known focal length in pixels of the input image (a prior): every frame candidate then uses it, so
            frames are built from one zenith or horizontal VP plus another VP moved onto its orthogonal plane, not
            filtered by it. None estimates it.
        fov_v: a known vertical field of view in degrees (the same prior in other units); ignored when ``focal``
            is given.
        exif: when calibrating a file (:func:`ngp_kornia.calibrate`, ``ngp predict``), take ``focal`` from its EXIF
            focal length where it has one and neither prior is set (:mod:`ngp_kornia.exif`); the parser itself
            only sees tensors and ignores it.
        refine_horizon: after the frame search, move the horizon (and the focal length) to the one that the
            segments support best, searching horizontal VPs of every building block along it
            (:mod:`ngp_kornia.pipeline.horizon`); measured better on real photos, see BENCHMARKS.md. The search runs
            either way, because the confidence uses its line support; False keeps the frame search's horizon.
        polish_frame: before that, refit the frame's rotation and focal length on the segments that point at its
            three VPs (:mod:`ngp_kornia.pipeline.polish`) where that raises their line support; with a known focal
            length only the rotation.
        principal_point_std: how far the principal point may be from the image centre, a standard deviation per
            axis as a fraction of the image height. The parser always assumes the centre; this only widens
            ``pitch_std``, ``roll_std`` and ``fov_v_std`` by the error such an offset causes (answers and
            ``confidence`` do not change). The default 0.025 (12 pixels at 480) is a prior for photos of unknown
            cameras, whose principal points lie typically 1-3% of the image size off the centre: the one calibrated
            real camera of the development photos (York Urban's) sits 0.025 of the height off along each axis. 0
            says it is known to be at the centre (renders, or images corrected by a calibration).
    """

    working_size: int = 1280
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
    num_threads: int | None = None
    detector: str = "lsd"
    line_strips: int = 2
    focal: float | None = None
    fov_v: float | None = None
    exif: bool = False
    refine_horizon: bool = True
    polish_frame: bool = False
    principal_point_std: float = 0.025

    def __post_init__(self) -> None:
        check_config(self)


def prior_focal(config: ParserConfig, height: int, width: int) -> float | None:
    """The config's known focal length (``focal`` in pixels, else ``fov_v`` in degrees) in pseudo-camera units
    (half the long side), or None when neither is set.

    Example:
        >>> prior_focal(ParserConfig(fov_v=90.0), 480, 640)
        0.75
    """
    if config.focal is not None:
        focal = _number(config.focal)
        if not (math.isfinite(focal) and focal > 0):
            raise ValueError(f"focal must be a positive number of pixels, got {config.focal!r}")
    elif config.fov_v is not None:
        fov = _number(config.fov_v)
        if not 0 < fov < 180:
            raise ValueError(f"fov_v must be a vertical field of view in (0, 180) degrees, got {config.fov_v!r}")
        focal = (height / 2.0) / math.tan(math.radians(fov) / 2.0)
    else:
        return None
    return focal / pseudo_focal(height, width)


def _number(value: object) -> float:
    try:
        return float(value)  # numbers, numpy scalars and one-element tensors
    except (TypeError, ValueError):
        return math.nan


#: field: (kind, low, high, what the bounds mean); kind "int" or "float"; None: no bound; bounds inclusive unless
#: the meaning says otherwise (checked as written in the message)
_FIELDS = {
    "working_size": ("int", 32, None, "at least 32 pixels"),
    "min_length": ("float", 0.0, None, "a length in pixels, at least 0"),
    "max_segments": ("int", 1, None, "at least 1"),
    "line_strips": ("int", 1, 16, "from 1 to 16"),
    "num_zenith_lines": ("int", 1, None, "at least 1"),
    "num_zenith": ("int", 1, None, "at least 1"),
    "vertical_threshold": ("float", 0.0, 90.0, "an angle in degrees, in (0, 90)"),
    "zenith_threshold": ("float", 0.0, 1.0, "a score in [0, 1)"),
    "vertical_tol": ("float", 0.0, 90.0, "an angle in degrees, in [0, 90)"),
    "junction_radius": ("float", 0.0, None, "a distance, at least 0"),
    "num_horizontal": ("int", 2, None, "at least 2 (half per group)"),
    "num_frames": ("int", 1, None, "at least 1"),
    "num_horizontal_frames": ("int", 0, None, "at least 0 (0 disables them)"),
    "kernel_angle": ("float", 0.0, 90.0, "an angle in degrees, in (0, 90)"),
    "top_k": ("int", 1, None, "at least 1"),
    "num_scored": ("int", 1, None, "at least 1"),
    "fallback_fov": ("float", 0.0, 180.0, "an angle in degrees, in (0, 180)"),
    "seed": ("int", 0, 2**64 - 1, "in [0, 2**64 - 1]"),
    "principal_point_std": ("float", 0.0, 0.25, "a fraction of the image height in [0, 0.25]"),
}
_OPEN_LOW = {"vertical_threshold", "kernel_angle", "fallback_fov"}
_OPEN_HIGH = {"vertical_threshold", "zenith_threshold", "vertical_tol", "kernel_angle", "fallback_fov"}


def check_config(config: ParserConfig) -> None:
    """Check every field of a :class:`ParserConfig`; called on construction and by ``dataclasses.replace``.

    Raises:
        ConfigError: a field of the wrong type, NaN, or out of range; the message names the field and the range.

    Example:
        >>> ParserConfig(num_frames=0)
        Traceback (most recent call last):
        ...
        ngp_kornia.errors.ConfigError: ParserConfig.num_frames must be an integer at least 1, got 0
    """
    for name, (kind, low, high, meaning) in _FIELDS.items():
        value = getattr(config, name)
        if kind == "int":
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ConfigError(f"ParserConfig.{name} must be an integer {meaning}, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
            raise ConfigError(f"ParserConfig.{name} must be a finite number, {meaning}; got {value!r}")
        below = value <= low if name in _OPEN_LOW else value < low
        above = high is not None and (value >= high if name in _OPEN_HIGH else value > high)
        if below or above:
            article = "an integer " if kind == "int" else ""
            raise ConfigError(f"ParserConfig.{name} must be {article}{meaning}, got {value!r}")
    focal = config.focal_range
    if (
        not isinstance(focal, (tuple, list))
        or len(focal) != 2
        or not all(isinstance(f, numbers.Real) and not isinstance(f, bool) and math.isfinite(f) for f in focal)
        or not 0 < focal[0] < focal[1]
    ):
        raise ConfigError(
            f"ParserConfig.focal_range must be two finite numbers 0 < low < high (half image widths), got {focal!r}"
        )
    if not isinstance(config.use_manhattan, bool):
        raise ConfigError(f"ParserConfig.use_manhattan must be True or False, got {config.use_manhattan!r}")
    if config.detector not in DETECTORS:
        raise ConfigError(f"ParserConfig.detector must be one of {', '.join(DETECTORS)}, got {config.detector!r}")
    if config.focal is not None and not (math.isfinite(_number(config.focal)) and _number(config.focal) > 0):
        raise ConfigError(f"ParserConfig.focal must be a positive number of pixels or None, got {config.focal!r}")
    if config.fov_v is not None and not 0 < _number(config.fov_v) < 180:
        raise ConfigError(f"ParserConfig.fov_v must be an angle in (0, 180) degrees or None, got {config.fov_v!r}")
    for name in ("refine_horizon", "polish_frame"):
        if not isinstance(getattr(config, name), bool):
            raise ConfigError(f"ParserConfig.{name} must be True or False, got {getattr(config, name)!r}")
    if not isinstance(config.exif, bool):
        raise ConfigError(f"ParserConfig.exif must be True or False, got {config.exif!r}")


class NeuralGeometricParser(nn.Module):
    """Single-image calibration of a Manhattan / Atlanta-world scene.

    Args:
        config: pipeline settings.
        zsnet: a :class:`~ngp_kornia.nets.zsnet.ZSNet` scoring the zenith candidates; None weights every valid
            candidate equally (the geometric path).
        fsnet: an :class:`~ngp_kornia.nets.fsnet.FSNet` scoring the best frames; None ranks the frames by the
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

    def forward(
        self,
        images: Tensor,
        segments: Tensor | None = None,
        mask: Tensor | None = None,
        return_trace: bool = False,
        fsnet_images: Tensor | None = None,
    ) -> Calibration | tuple[Calibration, ParserTrace]:
        """Calibrate a batch.

        Args:
            images: (B, 3, H, W) float RGB in [0, 1]; float16 and bfloat16 are computed in float32 and the result
                returned in the input's dtype.
            segments: optional (B, N, 2, 2) precomputed segments in the images' pixels (skips LSD). Segments the
                mask keeps must be finite (NaN or infinite ones are refused); padding may hold anything.
            mask: (B, N) bool, required with ``segments``.
            return_trace: also return the intermediate stages.
            fsnet_images: optional (B, 3, S, S) images already resized to FSNet's input side ``S`` with its filter
                (:func:`~ngp_kornia.nets.fsnet.area_resize`): FSNet reads these instead of resizing ``images``,
                whose pixels are then not read (a tensor of their shape will do). Ignored without FSNet.

        Returns:
            a batched :class:`Calibration`; with ``return_trace``, the pair ``(calibration, trace)``, the trace a
            :class:`ParserTrace` of the stages (the same computation: the calibration does not change).
        """
        with pipeline_threads(self.config.num_threads):  # one thread unless configured; the caller's count is restored
            return self._forward(images, segments, mask, return_trace, fsnet_images)

    def _forward(
        self,
        images: Tensor,
        segments: Tensor | None,
        mask: Tensor | None,
        return_trace: bool,
        fsnet_images: Tensor | None = None,
    ) -> Calibration | tuple[Calibration, ParserTrace]:
        if images.dtype in (torch.float16, torch.bfloat16):  # computed in float32, returned in the input's dtype
            low = None if segments is None else segments.float()
            resized = None if fsnet_images is None else fsnet_images.float()
            out = self._forward(images.float(), low, mask, return_trace, resized)
            return (out[0].to(images.dtype), out[1]) if return_trace else out.to(images.dtype)
        cfg = self.config
        height, width = images.shape[-2:]
        if segments is None:
            segments, mask = detect_segments(images, cfg)
        else:
            segments, mask = checked_segments(segments, mask, len(images))
        segments = segments.to(images)
        if segments.shape[1] == 0:  # no lines anywhere in the batch: one masked dummy keeps every shape non-empty
            segments, mask = segments.new_zeros(len(images), 1, 2, 2), mask.new_zeros(len(images), 1)
        # one generator per image, each seeded alike: an image's answer does not depend on its batch or position
        generators = [torch.Generator().manual_seed(cfg.seed) for _ in range(len(images))]
        stages = {"segments": segments, "mask": mask} if return_trace else None
        # FSNet's image side (resized image, line map, shared trunk) needs no frame: on a spare core it runs while
        # this thread samples and scores the frames
        image_side = None if self.fsnet is None else self._start_fsnet_image_side(images, segments, mask, fsnet_images)
        # the segments' lines and lengths serve the scores, FSNet's inputs and the trust fields: computed once
        pseudo = pseudo_lines(segments, mask, height, width)
        frames, scores = self.score_frames(segments, mask, height, width, generators, stages, pseudo)
        if self.fsnet is not None:
            frames, scores = self.rescore_frames(
                images, segments, mask, frames, scores, stages, pseudo[1], image_side.result()
            )
        result, top_k_weights = self._calibrate(frames, scores, height, width, stages)
        known_focal = cfg.focal is not None or cfg.fov_v is not None
        search_vps = result.vps  # the frame search's VPs: the residual of their lines is a trust input
        if cfg.polish_frame:
            result = self._polished(result, segments, mask, known_focal, height, width)
        # the horizon search serves the refinement and the confidence (how well the lines support a rival horizon);
        # with a known focal length only the horizon moves, never the focal length
        found = search_horizon(result, segments, mask, focal_scales=() if known_focal else FOCAL_SCALES)
        if cfg.refine_horizon:
            result = choose_horizon(result, found)
        result = attach_trust(
            result, frames, scores, segments, mask, cfg.top_k, cfg.kernel_angle, known_focal,
            principal_point_std=cfg.principal_point_std, shared=SharedInputs(*pseudo[1:], top_k_weights),
            refinement=found, residual_vps=search_vps,
        )
        return (result, ParserTrace(**stages)) if return_trace else result

    def _polished(
        self, result: Calibration, segments: Tensor, mask: Tensor, known_focal: bool, height: int, width: int
    ) -> Calibration:
        """The frame refitted on its inlier segments (:func:`~ngp_kornia.pipeline.polish.polish_frame`; with a known
        focal length only the rotation), where that raises its line support."""
        K, R, use = polish_frame(result.K, result.R, segments, mask, (1.0,) if known_focal else POLISH_SCALES)
        use = use & result.valid
        if not bool(use.any()):
            return result
        # the other images keep their K and R, from which _result rebuilds the same fields
        K, R = torch.where(use[:, None, None], K, result.K), torch.where(use[:, None, None], R, result.R)
        return self._result(K, R, result.score, result.valid, height, width)

    def score_frames(
        self,
        segments: Tensor,
        mask: Tensor,
        height: int,
        width: int,
        generator: Generators,
        stages: dict | None = None,
        pseudo: tuple[Tensor, Tensor, Tensor] | None = None,
    ) -> tuple[FrameCandidates, Tensor]:
        """Sample frame candidates (pseudo camera) and score each one: (B, F) scores, zero for invalid frames.
        ``stages``, a dict, receives the intermediate tensors (the fields of :class:`ParserTrace`); ``pseudo``,
        the segments' :func:`pseudo_lines` when already computed."""
        cfg = self.config
        seg, lines, lengths = pseudo_lines(segments, mask, height, width) if pseudo is None else pseudo
        lines_z, lines_z_ok, zenith, zenith_ok = sample_zenith_candidates(
            lines, lengths, mask, cfg.num_zenith_lines, cfg.num_zenith, cfg.vertical_threshold, generator
        )
        weights = self.zenith_weights(lines_z, lines_z_ok, zenith, zenith_ok)
        z_est = zenith_estimate(zenith, weights)
        horizontal = horizontal_line_mask(seg, mask, z_est, cfg.vertical_tol, cfg.junction_radius)
        right = split_by_pseudo_horizon(lines, z_est)
        h_vps, h_ok = sample_horizontal_vps(lines, lengths, horizontal, right, cfg.num_horizontal, generator)
        known = prior_focal(cfg, height, width)
        frames = sample_candidate_frames(
            zenith, weights, h_vps, h_ok, cfg.num_frames, cfg.num_horizontal_frames, cfg.focal_range, generator, known
        )
        # zero for the invalid frames, which it does not score
        scores = frame_manhattan_scores(lines, frames.vps, lengths, mask, cfg.kernel_angle, frames.valid)
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
        image_side: tuple[FSNetImageInputs, tuple | None] | None = None,
    ) -> tuple[FrameCandidates, Tensor]:
        """Keep the best ``num_scored`` frames by Manhattan score and score them with FSNet: ``s_vh * m_i`` (Eq. 22),
        or ``s_vh`` alone without ``use_manhattan``. Returns the kept frames and their (B, K) scores. ``lines``: the
        segments' pseudo-camera lines when already computed; ``image_side``: :meth:`fsnet_image_side` of the same
        images, segments and mask when already computed."""
        cfg = self.config
        index = top_frames(frames, manhattan, cfg.num_scored)
        frames, manhattan = select_frames(frames, index), manhattan.gather(1, index)
        # FSNet runs in its own dtype (float32 weights on a float64 image, say): lines in another dtype are redone
        dtype = next(self.fsnet.parameters()).dtype
        lines = lines if lines is not None and lines.dtype == dtype else None
        image_inputs, context = self.fsnet_image_side(images, segments, mask) if image_side is None else image_side
        inputs = self.fsnet.prepare_inputs(images.to(dtype), segments.to(dtype), mask, frames, lines, image_inputs)
        s_vh = torch.sigmoid(self.fsnet(*inputs, context=context)).to(manhattan)
        if stages is not None:
            stages.update(scored_index=index, fsnet_scores=s_vh)
        return frames, frame_scores(s_vh, manhattan, frames.valid, cfg.use_manhattan)

    def fsnet_image_side(self, images: Tensor, segments: Tensor, mask: Tensor) -> tuple[FSNetImageInputs, tuple | None]:
        """FSNet's inputs that need no frame candidate (:meth:`FSNet.prepare_image_inputs`) and its shared trunk's
        output on them (:meth:`FSNet.image_context`), in FSNet's dtype."""
        return self._start_fsnet_image_side(images, segments, mask, beside=False).result()

    def _start_fsnet_image_side(
        self, images: Tensor, segments: Tensor, mask: Tensor, resized: Tensor | None = None, beside: bool = True
    ) -> Beside:
        """:meth:`fsnet_image_side`, its image part (resizing, the trunk) run beside the caller where a core is
        free (:func:`~ngp_kornia.threads.run_beside`). The segments' part stays in this thread: it is many small
        operations, which would slow both threads down. On a GPU it all stays in this thread: work queued from
        another thread would not follow the caller's CUDA stream. ``resized``: the images at FSNet's input, when
        already made (the ``fsnet_images`` of :meth:`forward`)."""
        dtype = next(self.fsnet.parameters()).dtype
        partial = self.fsnet.prepare_line_inputs(segments.to(dtype), mask, images.shape[-2:])
        if resized is not None:
            partial = partial._replace(images=self._checked_fsnet_images(resized, len(images)).to(dtype))
        start = run_beside if beside and images.device.type == "cpu" else Beside.inline
        return start(self._fsnet_image_context, images.to(dtype), partial)

    def _checked_fsnet_images(self, resized: Tensor, batch: int) -> Tensor:
        side = self.fsnet.input_size
        if not isinstance(resized, Tensor) or tuple(resized.shape) != (batch, 3, side, side):
            shape = tuple(resized.shape) if isinstance(resized, Tensor) else type(resized).__name__
            raise ValueError(
                f"fsnet_images must be the {batch} images resized to FSNet's input, shape {(batch, 3, side, side)}; "
                f"got {shape}. Leave it out to let the parser resize the images."
            )
        return resized

    def _fsnet_image_context(self, images: Tensor, partial: FSNetImageInputs) -> tuple[FSNetImageInputs, tuple | None]:
        image_inputs = partial if partial.images is not None else with_images(partial, images)
        return image_inputs, self.fsnet.image_context(image_inputs)

    def zenith_weights(self, lines_z: Tensor, lines_z_ok: Tensor, zenith: Tensor, zenith_ok: Tensor) -> Tensor:
        """Weights of the zenith candidates: the ZSNet score p_z on Z_c (p_z > delta_c, Eq. 12) and zero elsewhere;
        without ZSNet, or where no candidate passes delta_c, every valid candidate counts equally. (B, Z)."""
        if self.zsnet is None:
            return zenith_ok.to(zenith)
        scores = torch.sigmoid(self.zsnet(lines_z, lines_z_ok, zenith))
        return zenith_weights_from_scores(scores, zenith_ok, self.config.zenith_threshold)

    def calibrate_from_frames(
        self, frames: FrameCandidates, scores: Tensor, height: int, width: int, stages: dict | None = None
    ) -> Calibration:
        """Top-k average (Eq. 23) of focal and zenith, yaw from the best frame, everything mapped to pixels."""
        return self._calibrate(frames, scores, height, width, stages)[0]

    def _calibrate(
        self, frames: FrameCandidates, scores: Tensor, height: int, width: int, stages: dict | None
    ) -> tuple[Calibration, Tensor]:
        """:meth:`calibrate_from_frames` and the (B, F) top-k weights of its average."""
        cfg = self.config
        valid = frames.valid.any(-1)
        focal, top_k_weights = topk_weighted_average(scores, frames.focal, cfg.top_k, frames.valid)
        # the zenith's average has the same weights: the top-k average of the structure tensors, without ranking again
        zenith = dominant_eigenvector(_weighted_zenith_tensor(frames.zenith, top_k_weights, cfg.top_k))
        best = scores.argmax(-1)
        if stages is not None:
            stages.update(final_frames=frames, final_scores=scores, top_k_weights=top_k_weights, best=best)
        horizontal = frames.horizontal.gather(1, best[:, None, None].expand(-1, 1, 3))[:, 0]
        fallback = prior_focal(cfg, height, width) or 1.0 / math.tan(math.radians(cfg.fallback_fov) / 2.0)
        focal = torch.where(valid, focal, fallback)
        level, ahead = constant_tensors(((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)), zenith.dtype, zenith.device)
        zenith = torch.where(valid[:, None], zenith, level)
        horizontal = torch.where(valid[:, None], horizontal, ahead)
        # the pseudo camera has K = diag(f, f, 1); pixels need K_p = [[f_p, 0, c], [0, f_p, c], [0, 0, 1]]
        K_unit = intrinsics_matrix(focal, constant_tensors(((0.0, 0.0),), focal.dtype, focal.device)[0])
        R = canonical_manhattan_rotation(rotation_from_vps(K_unit, zenith, horizontal))
        f_px = focal * pseudo_focal(height, width)
        K = intrinsics_matrix(f_px, image_center(height, width, like=f_px))
        return self._result(K, R, scores.amax(-1), valid, height, width), top_k_weights

    @staticmethod
    def _result(K: Tensor, R: Tensor, score: Tensor, valid: Tensor, height: int, width: int) -> Calibration:
        up = -R[..., :, 1]
        zenith = zenith_from_up(K, up)
        zenith = zenith / torch.linalg.vector_norm(zenith, dim=-1, keepdim=True)
        pitch, roll, yaw = angles_from_rotation(R)  # its pitch and roll are those of up = -R[:, :, 1]
        f = K[:, 0, 0]
        size = torch.tensor([height, width], device=K.device)
        fov_v, fov_h = fov_from_focal(f[:, None], size).unbind(-1)  # both sides at once, the same values
        return Calibration(
            K=K,
            R=R,
            focal=f,
            fov_v=fov_v,
            fov_h=fov_h,
            pitch=pitch,
            roll=roll,
            yaw=yaw,
            up=up,
            zenith=zenith,
            horizon=horizon_from_zenith(K, zenith),
            vps=vanishing_points_from_rotation(K, R),
            score=score,
            valid=valid,
            image_size=size.expand(len(f), 2),
            exif_orientation=torch.ones(len(f), dtype=torch.long, device=K.device),  # tensors are taken as they are
        )


def _weighted_zenith_tensor(zenith: Tensor, weights: Tensor, k: int) -> Tensor:
    """``(weights[..., None, None] * structure_tensor(zenith)).sum(1)`` for (B, F) weights that are zero outside their
    top ``k``: the tensors of those k frames only, laid among zeros so that the sum adds the same values in the same
    order (the F tensors cost 0.25 ms on the parser's 1536 frames).

    The rows are normalised as torch normalises ``zenith`` (B, F, 3) in its layout: where a row's entries are not
    adjacent (the frames' zeniths are columns of their VP matrices) it sums the squares in order and takes a
    correctly rounded root; where they are, fused multiply-adds, which :func:`normalize` of the gathered rows repeats.
    """
    B, F = weights.shape
    if F <= k or (zenith.stride(-1) != 1 and zenith.dtype != torch.float32):  # the root below is float32's
        return (weights[..., None, None] * structure_tensor(zenith)).sum(1)
    index = weights.topk(k, dim=1).indices  # every frame with weight (and some without)
    rows = zenith.gather(1, index[..., None].expand(B, k, 3))
    if zenith.stride(-1) == 1:
        unit = normalize(rows)
    else:
        sq = rows * rows
        norm = (sq[..., 0] + sq[..., 1] + sq[..., 2]).double().sqrt_().float()
        unit = rows / norm[..., None].clamp_min(torch.finfo(rows.dtype).eps)
    tensors = weights.gather(1, index)[..., None, None] * (unit.unsqueeze(-1) * unit.unsqueeze(-2))
    return tensors.new_zeros(B, F, 3, 3).scatter_(1, index[..., None, None].expand(B, k, 3, 3), tensors).sum(1)


def pseudo_lines(segments: Tensor, mask: Tensor, height: int, width: int) -> tuple[Tensor, Tensor, Tensor]:
    """(B, N, 2, 2) pixel segments -> the pseudo camera's segments, their (B, N, 3) lines and (B, N) pixel lengths
    (zero where the mask is False)."""
    seg = to_pseudo_camera(segments, height, width)
    return seg, segments_to_lines(seg), segment_lengths(segments) * mask.to(segments)


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
