"""Training FSNet with Lightning: frame candidates are sampled from each batch's segments by the parser (its
geometric path, or with a ZSNet), the best ones by Manhattan score (plus, in training, a few random valid ones as
negatives) are labelled against the true zenith and horizon (Eq. 16-20) and scored; loss = binary cross entropy.

Validation also reports whether FSNet re-ranks the candidates better than the Manhattan score alone: the horizon
error (in image heights) of the top-1 frame by ``s_i = sigmoid(logit) * m_i`` (Eq. 22) and by ``m_i``.
"""

from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ngp_kornia.geometry.frames import FrameCandidates, select_frames, top_frames
from ngp_kornia.metrics import frame_horizon_error, horizon_auc
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.fsnet_inputs import FSNetInputs, frame_scores
from ngp_kornia.nets.weights import load_network, shipped_weights
from ngp_kornia.pipeline.evidence import apply_evidence
from ngp_kornia.pipeline.parser import NeuralGeometricParser
from ngp_kornia.pipeline.settings import ParserConfig
from ngp_kornia.training.base import NetworkModule, start_from
from ngp_kornia.training.losses import frame_classification_loss, frame_labels
from ngp_kornia.training.scene_data import SceneBatch

__all__ = ["FSNetModule"]


class FSNetModule(NetworkModule):
    """Lightning wrapper of an :class:`FSNet`.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate (the paper: 4e-4).
        lr_step: epochs between halvings of the learning rate.
        num_candidates: frames kept per image, the best by Manhattan score.
        num_random: extra random valid frames per image in training (mostly negatives; 0 for none).
        sigma: sigma of Eq. 20.
        label_threshold: delta_s of Eq. 19.
        horizon_scale: unit of the horizon distance of Eq. 17, in image heights (see :func:`frame_labels`). The
            default makes a frame positive within about 2.6% of the image height; with 1.0 nearly every frame of the
            top 16 is positive and the network learns nothing (BENCHMARKS.md).
        parser_config: settings of the :class:`NeuralGeometricParser` sampling the candidates (a dict of
            settings by ``stage.field`` or unique field name, see :meth:`ParserConfig.replace`; None for the
            defaults).
        zsnet: an optional trained ZSNet weighting the zenith candidates (frozen, not saved with this module).
        zsnet_weights: instead of ``zsnet``, a ZSNet weights file to load, or ``"zsnet"`` for the shipped one (the
            form a YAML config can give).
        init_weights: start ``net`` from an FSNet weights file of the same settings (fine-tuning), or ``"fsnet"``
            for the shipped one; None: from its own initialisation.
        evidence_weights: a line-evidence weights file, or ``"evidence"`` for the shipped one: the segments it reads
            as clutter (structure weight below ``evidence_keep``) are dropped before the candidates are sampled and
            the line maps drawn, as the default weight set does at run time (frozen, not saved with this module).
        evidence_keep: the least structure weight of a segment kept (the parser's ``evidence.keep``).
    """

    def __init__(
        self,
        net: FSNet,
        lr: float = 4e-4,
        lr_step: int = 5,
        num_candidates: int = 16,
        num_random: int = 4,
        sigma: float = 0.1,
        label_threshold: float = 0.5,
        horizon_scale: float = 0.05,
        parser_config: dict | None = None,
        zsnet: nn.Module | None = None,
        zsnet_weights: str | None = None,
        init_weights: str | None = None,
        evidence_weights: str | None = None,
        evidence_keep: float = 0.1,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net", "zsnet"])
        self.net = net
        evidence = None
        if evidence_weights is not None:
            path = shipped_weights("evidence") if evidence_weights == "evidence" else evidence_weights
            evidence = load_network(path, "LineEvidenceNet").eval().requires_grad_(False)
        object.__setattr__(self, "evidence", evidence)  # not a submodule: neither trained nor saved
        if init_weights is not None:
            start_from(net, init_weights, "fsnet")
        if zsnet is None and zsnet_weights is not None:
            path = shipped_weights("zsnet") if zsnet_weights == "zsnet" else zsnet_weights
            zsnet = load_network(path, "ZSNet")
        if zsnet is not None:
            zsnet = zsnet.eval().requires_grad_(False)
        parser = NeuralGeometricParser(ParserConfig().replace(**(parser_config or {})), zsnet)
        # not a submodule: it is neither trained, switched to train mode, nor saved with the checkpoint
        object.__setattr__(self, "parser", parser)

    def forward(self, images: Tensor, line_map: Tensor, closeness: Tensor, params: Tensor) -> Tensor:
        return self.net(images, line_map, closeness, params)

    def _candidates(
        self, batch: SceneBatch, generator: torch.Generator, training: bool
    ) -> tuple[FrameCandidates, Tensor]:
        """Sample frames with the parser and keep the top ones by Manhattan score (plus random ones in training)."""
        height, width = (int(v) for v in batch.image_size[0])
        self.parser.to(self.device)
        with torch.no_grad():
            frames, manhattan = self.parser.score_frames(batch.segments, batch.mask, height, width, generator)
        valid = frames.valid
        num = valid.shape[1]
        index = top_frames(frames, manhattan, self.hparams.num_candidates)
        k = index.shape[1]
        extra = min(self.hparams.num_random, num - k) if training else 0
        if extra > 0:
            noise = torch.rand(valid.shape, generator=generator).to(manhattan)
            noise = torch.where(valid, noise, torch.full_like(noise, -1.0)).scatter(1, index, -2.0)
            index = torch.cat([index, noise.topk(extra, dim=-1).indices], 1)
        return select_frames(frames, index), manhattan.gather(1, index)

    def _inputs(self, batch: SceneBatch, frames: FrameCandidates) -> FSNetInputs:
        if batch.images is None:
            raise ValueError(
                "FSNet needs the images: set the DataModule's input_size (e.g. input_size: [224, 224]) so batches "
                "carry them"
            )
        height, width = (int(v) for v in batch.image_size[0])
        images = batch.images.to(self.device, torch.float32)
        # the segments and frames live in the original image's pixels / pseudo camera: give fsnet_inputs an image
        # of that size, then put back the stored image when it already has the network's input size
        full = images
        if images.shape[-2:] != (height, width):
            full = F.interpolate(images, (height, width), mode="bilinear", align_corners=False)
        inputs = self.net.prepare_inputs(full, batch.segments.to(full), batch.mask, frames)
        if inputs.images.shape[-2:] == images.shape[-2:]:
            inputs = inputs._replace(images=images)
        return inputs

    def _kept(self, batch: SceneBatch) -> SceneBatch:
        """The batch with the segments the line evidence reads as clutter masked out (as it was without one)."""
        if self.evidence is None:
            return batch
        height, width = (int(v) for v in batch.image_size[0])
        stand_in = batch.segments.new_zeros(len(batch), 3, height, width)  # the network reads the size, not pixels
        self.evidence.to(batch.segments.device)
        _, mask = apply_evidence(self.evidence, stand_in, batch.segments, batch.mask, self.hparams.evidence_keep)
        return replace(batch, mask=mask)

    def _step(self, batch: SceneBatch, stage: str, batch_idx: int) -> Tensor:
        training = stage == "train"
        batch = self._kept(batch)
        # validation and test sample the same candidates every epoch, so their figures are comparable
        seed = int(torch.randint(2**31 - 1, (1,))) if training else batch_idx
        generator = torch.Generator().manual_seed(seed)
        frames, manhattan = self._candidates(batch, generator, training)
        logits = self.net(*self._inputs(batch, frames))
        height, width = (int(v) for v in batch.image_size[0])
        hp = self.hparams
        _, labels, valid = frame_labels(
            frames, batch.zenith, batch.horizon, height, width, hp.sigma, hp.label_threshold, hp.horizon_scale
        )
        loss = frame_classification_loss(logits, labels, valid)
        # validation and test figures are averaged over DDP processes, so checkpoints are chosen on the whole set
        opts = {"batch_size": len(batch), "sync_dist": not training}
        self.log(f"{stage}/loss", loss, prog_bar=True, **opts)
        if not training:
            ok = valid.to(logits)
            correct = ((logits > 0).to(labels) == labels).to(logits) * ok
            self.log(f"{stage}/accuracy", correct.sum() / ok.sum().clamp_min(1), **opts)
            self.log(f"{stage}/positive_rate", (labels * ok).sum() / ok.sum().clamp_min(1), **opts)
            error = frame_horizon_error(frames, batch.horizon, height, width)
            rows = torch.arange(len(batch), device=error.device)
            final = frame_scores(torch.sigmoid(logits), manhattan, valid)  # Eq. 22, ranked among the labelled frames
            final = torch.where(valid, final, torch.full_like(final, -1.0))
            by_m = torch.where(valid, manhattan, torch.full_like(manhattan, -1.0))
            top1, top1_m = error[rows, final.argmax(-1)], error[rows, by_m.argmax(-1)]
            self.log(f"{stage}/horizon_error", top1.mean(), **opts)
            self.log(f"{stage}/horizon_error_manhattan", top1_m.mean(), **opts)
            # the horizon AUC on [0, 0.25] is a mean over the images, so the batch means average to the epoch's
            self.log(f"{stage}/horizon_auc", horizon_auc(top1), **opts)
            self.log(f"{stage}/horizon_auc_manhattan", horizon_auc(top1_m), **opts)
        return loss
